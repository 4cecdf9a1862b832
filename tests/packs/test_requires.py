"""Pack dependencies: `requires = ["prp"]`, paths `PACK:PATH` into a required pack, and the one-line
refusals of `chainsim validate` (missing pack, cycle, a path into an unlisted pack or out of one)."""

from __future__ import annotations

from pathlib import Path

import pytest

from chainsim.assets import ASSETS_DIR
from chainsim.game.packs import pack as packs


def write_pack(folder: Path, name: str, body: str = "", requires=()) -> Path:
    root = folder / name
    root.mkdir(parents=True)
    req = ", ".join(f'"{r}"' for r in requires)
    (root / "pack.toml").write_text(f'[pack]\nname = "{name}"\nformat = 1\nrequires = [{req}]\n' + body)
    return root


SKULL = '[meshes.skull]\npath = "prp:meshes/skull.ply"\n[entities.skull.mesh]\nmesh = "skull"\n'


def test_a_mesh_of_a_required_pack_is_the_same_mesh_and_the_pack_runs(tmp_path, cli):
    root = write_pack(tmp_path, "uses-prp", SKULL, ["prp"])
    code, out, err = cli("validate", root)
    assert code == 0, err
    mine = packs.load(root).mesh("skull")
    theirs = packs.load(ASSETS_DIR / "prp").mesh("skull")
    assert mine.vertices.shape == theirs.vertices.shape and (mine.vertices == theirs.vertices).all()
    code, out, err = cli("run", root, "--headless", "--steps", "3")
    assert code == 0, err


def test_includes_and_docs_may_come_from_a_required_pack(tmp_path):
    body = '[docs.anatomy]\ntitle = "Anatomy"\npath = "prp:docs/anatomy.md"\n'
    root = write_pack(tmp_path, "anat", body, ["prp"])
    text = (root / "pack.toml").read_text().replace("requires", 'includes = ["prp:anatomy.toml"]\nrequires')
    (root / "pack.toml").write_text(text)
    pack, problems = packs.validate(root)
    assert problems == [], [str(p) for p in problems]
    assert "foramen_ovale_left" in pack.section("points")
    assert "foramen" in pack.doc_text("anatomy").lower()


@pytest.mark.parametrize(
    ("requires", "path", "words"),
    [
        (["prp"], "prp:../cutting/pack.toml", "escapes the folder of pack 'prp'"),
        (["prp"], "prp:/etc/passwd", "escapes the folder of pack 'prp'"),
        (["prp"], "cutting:meshes/tissue.ply", "points into pack 'cutting', which [pack] requires does not list"),
        ([], "prp:meshes/skull.ply", "points into pack 'prp', which [pack] requires does not list"),
        (["prp"], "../prp/meshes/skull.ply", "escapes the pack folder"),
    ],
)
def test_a_path_outside_the_pack_and_its_required_packs_is_one_line(tmp_path, cli, requires, path, words):
    body = f'[meshes.m]\npath = "{path}"\n'
    root = write_pack(tmp_path, "p", body, requires)
    code, out, err = cli("validate", root)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 2 and words in lines[0] and lines[0].startswith("pack.toml:6: meshes.m.path:"), err
    assert "Traceback" not in err


def test_a_symlink_out_of_a_required_pack_is_refused(tmp_path, cli):
    dep = write_pack(tmp_path, "dep", '[meshes.b]\nprimitive = "box"\n')
    (tmp_path / "secret.ply").write_text("ply\n")
    (dep / "leak.ply").symlink_to(tmp_path / "secret.ply")
    root = write_pack(tmp_path, "user", '[meshes.m]\npath = "dep:leak.ply"\n', ["dep"])
    code, _, err = cli("validate", root)
    assert code == 2 and "escapes the folder of pack 'dep'" in err


def test_a_missing_required_pack_is_one_line_naming_it(tmp_path, cli):
    root = write_pack(tmp_path, "p", "", ["no-such-pack"])
    code, _, err = cli("validate", root)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2
    assert lines[0].startswith("pack.toml:4: pack.requires: pack 'no-such-pack' not found"), lines[0]
    code, _, err = cli("run", root, "--headless", "--steps", "1")
    assert code == 2 and "no-such-pack" in err and "Traceback" not in err


def test_a_missing_pack_further_down_the_chain_is_named(tmp_path, cli):
    write_pack(tmp_path, "middle", "", ["gone"])
    root = write_pack(tmp_path, "top", "", ["middle"])
    code, _, err = cli("validate", root)
    assert code == 2 and "'middle' requires pack 'gone' not found" in err


@pytest.mark.parametrize(
    ("graph", "cycle"),
    [
        ({"a": ["b"], "b": ["a"]}, "a -> b -> a"),
        ({"a": ["b"], "b": ["c"], "c": ["b"]}, "b -> c -> b"),
    ],
)
def test_a_cycle_is_one_line(tmp_path, cli, graph, cycle):
    for name, req in graph.items():
        write_pack(tmp_path, name, "", req)
    code, _, err = cli("validate", tmp_path / "a")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2, err
    assert cycle + " is a cycle" in lines[0]


def test_a_pack_cannot_require_itself(tmp_path, cli):
    root = write_pack(tmp_path, "me", "", ["me"])
    code, _, err = cli("validate", root)
    assert code == 2 and "cannot require itself" in err


def test_required_packs_are_found_beside_the_pack_or_through_pack_path(tmp_path, cli):
    write_pack(tmp_path / "lib", "base", '[meshes.b]\nprimitive = "box"\n')
    (tmp_path / "lib" / "base" / "cube.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    body = '[meshes.m]\npath = "base:cube.obj"\n[entities.e.mesh]\nmesh = "m"\n'
    apart = write_pack(tmp_path / "mine", "user", body, ["base"])
    code, _, err = cli("validate", apart)
    assert code == 2 and "pack 'base' not found" in err
    code, _, err = cli("validate", apart, "--pack-path", tmp_path / "lib")
    assert code == 0, err
    code, _, err = cli("run", apart, "--headless", "--steps", "2", "--pack-path", tmp_path / "lib")
    assert code == 0, err
    beside = write_pack(tmp_path / "lib", "user", body, ["base"])
    code, _, err = cli("validate", beside)
    assert code == 0, err


def _diamond(folder: Path, levels: int) -> Path:
    """`top` requiring a0 and b0; a_i and b_i each requiring a_(i+1) and b_(i+1): 2 * levels packs
    below the top and 2 ** levels paths from it to the last level."""
    for i in range(levels):
        below = [f"a{i + 1}", f"b{i + 1}"] if i + 1 < levels else []
        for side in "ab":
            write_pack(folder, f"{side}{i}", "", below)
    return write_pack(folder, "top", "", ["a0", "b0"])


def test_a_deep_diamond_reads_each_required_pack_once(tmp_path, monkeypatch):
    from chainsim.game.packs import requires

    top = _diamond(tmp_path, 24)
    reads: list[Path] = []
    real = requires.requires_of
    monkeypatch.setattr(requires, "requires_of", lambda folder: reads.append(Path(folder)) or real(folder))
    pack, problems = packs.validate(top)
    assert problems == [] and pack is not None
    assert sorted(p.name for p in reads) == sorted(f"{s}{i}" for i in range(24) for s in "ab")


@pytest.mark.parametrize("levels", [3, 9])
def test_reads_grow_with_the_packs_not_with_the_paths(tmp_path, monkeypatch, levels):
    from chainsim.game.packs import requires

    top = _diamond(tmp_path, levels)
    calls = []
    real = requires.requires_of
    monkeypatch.setattr(requires, "requires_of", lambda folder: calls.append(folder) or real(folder))
    assert packs.validate(top)[1] == []
    assert len(calls) == 2 * levels


def test_a_cycle_at_the_bottom_of_a_diamond_is_found(tmp_path, cli):
    _diamond(tmp_path, 6)
    (tmp_path / "b5" / "pack.toml").write_text('[pack]\nname = "b5"\nformat = 1\nrequires = ["a2"]\n')
    code, _, err = cli("validate", tmp_path / "top")
    assert code == 2 and "a2 -> " in err and "-> b5 -> a2 is a cycle" in err


def test_more_required_packs_than_the_limit_is_one_line(tmp_path, cli, monkeypatch):
    from chainsim.systems.engine import limits

    monkeypatch.setattr(limits, "MAX_REQUIRED_PACKS", 5)
    top = _diamond(tmp_path, 4)
    code, _, err = cli("validate", top)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2, err
    assert "pack.requires" in lines[0] and "more than 5 packs" in lines[0]
