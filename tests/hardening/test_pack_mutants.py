"""What validate accepts, run accepts: mutants of the built-in needle packs either fail `validate` with
one line per problem, each naming its key, or run their scripted attempts to the end and save them.

Hypothesis takes the prp and mental-block manifests (pack.toml and the pack's own anatomy.toml) and
changes one or two things a modder could get wrong: a key removed or renamed, a value of another
type or out of range, a text given format fields ({, {x}, {dist_mm:.1q}, {patient.name}), a name
pointed at another name of the pack or at nothing. A mutant that validates then runs one of the
pack's scripts (assets/PACK/scripts/*.toml) headlessly with a Save pressed at the end: the run must
reach its last step and store the attempt; a traceback anywhere fails the test.

The number of mutants per pack is CHAINSIM_MUTANTS (default 25: about a minute on two cores).
"""

from __future__ import annotations

import copy
import math
import os
import shutil
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from chainsim.game.trainer.headless import run_pack, validate_pack
from chainsim.game.trainer.inputscript import read_file
from chainsim.systems.engine.errors import UserError

from .conftest import ROOT

EXAMPLES = int(os.environ.get("CHAINSIM_MUTANTS", "25"))
#: the pack's own manifest files that are mutated
FILES = ("pack.toml", "anatomy.toml")
#: sections left alone: mesh sizes and run settings change how long a run takes, not whether it fails
SKIP = ("meshes", "settings")
#: what a text may become: format fields good and bad, braces, nothing, and very long
TEXTS = ("{", "}", "{x}", "{dist_mm:.1q}", "{side}", "{patient.name}", "{n:d}", "{what:.1f}", "{0}", "{{}}", "{side!r}")
#: what a number may become
NUMBERS = (-1, 0, 1, -1e9, 1e9, 2**62, 1e300, math.inf, -math.inf, math.nan, 0.5)
OTHER_TYPES = (0, 2.5, "text", True, [], {}, [1.0, 2.0, 3.0], ["a", "b"], {"x": 1})
#: what the procedure may refuse a save for, in the trainee's own hands (the landmarks not all placed)
TRAINEE_REFUSALS = ("place all the landmarks before saving",)


def _paths(node, path=()):
    """Every key path below `node` (tables by key, arrays by index)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield (*path, k)
            yield from _paths(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield (*path, i)
            yield from _paths(v, (*path, i))


def _names(node) -> list[str]:
    """Every short text and table name of a manifest: the names a reference may be pointed at."""
    out = set()
    for p in _paths(node):
        if isinstance(p[-1], str):
            out.add(p[-1])
        v = _get(node, p)
        if isinstance(v, str) and len(v) < 40:
            out.add(v)
    return sorted(out)


def _get(node, path):
    for k in path:
        node = node[k]
    return node


class Pack:
    """A built-in pack copied once; each mutant rewrites its manifest files in place."""

    def __init__(self, name: str, folder: Path):
        self.name = name
        self.root = folder / name
        shutil.copytree(ROOT / "assets" / name, self.root)
        self.data = {f: tomllib.loads((self.root / f).read_text()) for f in FILES if (self.root / f).is_file()}
        self.paths = [(f, p) for f, d in self.data.items() for p in _paths(d) if p[0] not in SKIP]
        self.names = _names(self.data)
        self.scripts = sorted((self.root / "scripts").glob("*.toml"))

    def write(self, data: dict) -> None:
        for f, d in data.items():
            (self.root / f).write_text(tomli_w.dumps(d))


@pytest.fixture(scope="module")
def needle_packs(tmp_path_factory):
    # apart, so that mental-block finds the built-in prp and not the mutant
    return {n: Pack(n, tmp_path_factory.mktemp(n)) for n in ("prp", "mental-block")}


@st.composite
def mutations(draw, pack: Pack):
    """A copy of the pack's manifest files with one or two changes, and what was changed."""
    data = copy.deepcopy(pack.data)
    done = []
    for _ in range(draw(st.integers(1, 2))):
        f, path = draw(st.sampled_from(pack.paths))
        try:
            parent, old = _get(data[f], path[:-1]), _get(data[f], path)
        except (KeyError, IndexError, TypeError):
            continue  # the first change removed it
        key = path[-1]
        op = draw(st.sampled_from(["remove", "rename", "retype", "range", "format", "reference"]))
        if op == "remove" or (op == "rename" and isinstance(parent, list)):
            del parent[key]
        elif op == "rename":
            parent[draw(st.sampled_from([f"{key}x", f"{key}_", "x", str(key).upper()]))] = parent.pop(key)
        elif op == "retype":
            parent[key] = draw(st.sampled_from([v for v in OTHER_TYPES if type(v) is not type(old)]))
        elif op == "range":
            if isinstance(old, (int, float)) and not isinstance(old, bool):
                parent[key] = draw(st.sampled_from(NUMBERS))
            elif isinstance(old, str):
                parent[key] = draw(st.sampled_from(["", "x" * 25_000, " ", "a b"]))
            elif isinstance(old, list):
                parent[key] = [] if draw(st.booleans()) else old * 300
            else:
                parent[key] = {}
        elif op == "format":
            if not isinstance(old, str):
                continue
            at = draw(st.integers(0, len(old)))
            parent[key] = old[:at] + draw(st.sampled_from(TEXTS)) + old[at:]
        else:
            parent[key] = draw(st.sampled_from([*pack.names, "nowhere"]))
        done.append((f, ".".join(map(str, path)), op))
    return Mutant(data, done)


class Mutant:
    """A mutated manifest, shown by its changes only (a falsifying example stays readable)."""

    def __init__(self, data: dict, changes: list):
        self.data, self.changes = data, changes

    def __repr__(self) -> str:
        return f"Mutant({self.changes})"


def _script_with_save(script: Path, out: Path) -> tuple[Path, float]:
    """The script with Save pressed after its last event; returns it and the time that event is at."""
    data = read_file(script)
    end = max((e["t"] for e in data.get("event", [])), default=0.0) + 0.5
    data.setdefault("event", []).append({"t": end, "kind": "widget", "name": "save"})
    data.pop("description", None)
    out.write_text(tomli_w.dumps(data))
    return out, end


def check_mutant(pack: Pack, data: dict, script: Path, tmp: Path) -> str:
    """Validate the mutant; if it validates, run the script with a save; returns which way it went."""
    pack.write(data)
    pack_problems = validate_pack(pack.root)[1]
    if pack_problems:
        for p in pack_problems:
            line = str(p)
            assert "\n" not in line and "Traceback" not in line, line
        assert any(p.key for p in pack_problems), [str(p) for p in pack_problems]
        return "refused"
    saved, end = _script_with_save(script, tmp / "script.toml")
    dt = float(data["pack.toml"].get("settings", {}).get("dt", 1 / 120))
    db = tmp / f"records-{os.getpid()}.sqlite3"
    try:
        summary = run_pack(str(pack.root), math.ceil((end + 0.5) / dt), script=str(saved), settings={"db": str(db)})
    except UserError as e:
        assert any(w in str(e) for w in TRAINEE_REFUSALS), f"a pack that validates fails its run: {e}"
        return "not saved (landmarks)"
    if data["pack.toml"]["pack"].get("procedure") not in ("needle", "prp"):
        return "ran (no needle procedure: nothing to save)"
    assert summary["assessment"]["saved"], summary["assessment"].get("save_errors")
    return "ran and saved"


@pytest.mark.parametrize("name", ["prp", "mental-block"])
def test_a_mutant_that_validates_runs_its_scripts_and_saves(name, needle_packs, tmp_path_factory):
    pack = needle_packs[name]
    tmp = tmp_path_factory.mktemp("runs")
    seen: dict[str, int] = {}

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
        database=None,
        phases=[Phase.explicit, Phase.generate],  # no shrinking: a failing mutant is shown by its changes
    )
    @given(mutant=mutations(pack), script=st.sampled_from(pack.scripts))
    def check(mutant, script):
        way = check_mutant(pack, mutant.data, script, tmp)
        seen[way] = seen.get(way, 0) + 1

    try:
        check()
    finally:
        pack.write(pack.data)
    # both ways are exercised, so the property is not vacuous
    assert seen.get("refused") and seen.get("ran and saved"), seen


@pytest.mark.slow
def test_the_unmutated_packs_run_every_script_and_save(needle_packs, tmp_path):
    for pack in needle_packs.values():
        pack.write(pack.data)
        for script in pack.scripts:
            assert check_mutant(pack, pack.data, script, tmp_path) == "ran and saved", script
