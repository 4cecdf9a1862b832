"""The shipped prp pack: its scripted attempts reach the foramen / hit the skull (thesis 3.3.6, 6.1.5).

These run the real anatomy (assets/prp/anatomy.toml and meshes) headless through
chainsim.game.trainer.headless.run_pack, exactly as `chainsim run prp --headless --input FILE --out DIR` does.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from chainsim.components.input_events import Widget
from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import run_pack
from chainsim.game.trainer.inputscript import load_script

ROOT = Path(__file__).resolve().parents[2]
PACK = Path(os.environ.get("CHAINSIM_PRP_TEST_PACK", ROOT / "assets" / "prp"))
SCRIPTS = PACK / "scripts"


@pytest.fixture(scope="module")
def correct(tmp_path_factory):
    out = tmp_path_factory.mktemp("correct")
    run_pack(str(PACK), script=str(SCRIPTS / "correct.toml"), out=str(out))
    return json.loads((out / "summary.json").read_text())["assessment"]


@pytest.fixture(scope="module")
def skull_hit(tmp_path_factory):
    out = tmp_path_factory.mktemp("skull")
    run_pack(str(PACK), script=str(SCRIPTS / "skull-hit.toml"), out=str(out))
    return json.loads((out / "summary.json").read_text())["assessment"]


def test_pack_validates_with_meshes():
    pack, problems = packs.validate(PACK)
    assert problems == []
    assert pack.manifest["pack"]["procedure"] == "needle"  # the generic needle procedure, driven by the pack's data


def test_correct_attempt_reaches_the_foramen_with_small_errors(correct):
    side = correct["side"]
    assert correct["target"] == f"foramen_ovale_{side}"
    assert correct["target_reached"] is True
    assert correct["needle_error_mm"] < 1.0
    # the ideal landmarks themselves work: a perfect set scores about nothing and still reaches the target
    assert correct["landmark_error_mm"] < 1.0
    assert correct["D1"] < 1.0 and correct["d1"] < 1.0
    assert correct["skull_contacts"] == 0
    assert correct["rotation_refused"] == 0
    assert correct["lights"] == {"skull": "off", "target": "green"}
    # E = Dist - R, from the reported contact point
    assert correct["needle_error_mm"] == pytest.approx(correct["needle_dist_mm"] - correct["foramen_radius_mm"])


def test_skull_hit_attempt_bounces_back_and_reports_its_distance(skull_hit):
    assert skull_hit["target"] == "skull"
    assert skull_hit["skull_contacts"] >= 1
    assert skull_hit["lights"]["skull"] == "red"
    entry = np.asarray(skull_hit["landmarks"][0])
    hit = np.asarray(skull_hit["hit_point"])
    tip = np.asarray(skull_hit["tip"])
    # the tip retreated from the contact point along the needle
    assert np.linalg.norm(tip - entry) < np.linalg.norm(hit - entry) - 2.0
    assert skull_hit["needle_dist_mm"] > skull_hit["foramen_radius_mm"]
    assert skull_hit["needle_error_mm"] == pytest.approx(skull_hit["needle_dist_mm"] - skull_hit["foramen_radius_mm"])
    # the script tries to re-aim after inserting: refused, the orientation is unchanged
    assert skull_hit["rotation_refused"] >= 1 and skull_hit["rotation_locked"] is True


def test_rotation_events_after_insertion_are_refused(correct):
    events = load_script(SCRIPTS / "correct.toml")
    last_t = max(t for t, _ in events)
    extra = [(last_t + 0.2, Widget("rotate_horizontal", 30.0)), (last_t + 0.3, Widget("rotate_vertical", -20.0))]
    s = run_pack(str(PACK), events=events + extra)
    a = s["assessment"]
    assert a["rotation_refused"] == 2
    assert a["rotation_horizontal_deg"] == pytest.approx(correct["rotation_horizontal_deg"])
    assert a["rotation_vertical_deg"] == pytest.approx(correct["rotation_vertical_deg"])
    assert a["target"] == correct["target"]


def test_one_huge_insertion_step_never_passes_the_skull():
    events = [
        (t, e) for t, e in load_script(SCRIPTS / "skull-hit.toml") if not (isinstance(e, Widget) and e.name == "insert")
    ]
    events.append((3.0, Widget("insert", 400.0)))  # far past the far side of the head, in one command
    events.sort(key=lambda te: te[0])
    # the pack advances the needle at its insert_speed: time for it to get to the skull and spring back
    s = run_pack(str(PACK), 1000, events=events)
    a = s["assessment"]
    assert a["target"] == "skull" and a["skull_contacts"] == 1
    entry = np.asarray(a["landmarks"][0])
    assert np.linalg.norm(np.asarray(a["tip"]) - entry) < np.linalg.norm(np.asarray(a["hit_point"]) - entry)


def test_default_headless_run_plays_the_scene_script():
    s = run_pack(str(PACK), 600)
    assert s["steps"] == 600
    assert "assessment" in s and s["assessment"]["landmarks"][0] is not None


def test_variant_scripts_are_imperfect_but_complete():
    for k in (1, 2, 3):
        a = run_pack(str(PACK), script=str(SCRIPTS / f"variant-{k}.toml"))["assessment"]
        assert a["landmark_error_mm"] is not None and a["landmark_error_mm"] > 0.5
        assert a["target"] != "none"


def test_the_scripted_attempts_end_with_one_saved_attempt(cli, tmp_path):
    """`chainsim run prp --headless --input SCRIPT --db PATH` as the docs show it stores the attempt."""
    db = tmp_path / "r.sqlite3"
    for name in ("correct", "skull-hit"):
        code, _, err = cli("run", str(PACK), "--headless", "--input", SCRIPTS / f"{name}.toml", "--db", db)
        assert code == 0, err
    code, out, err = cli("records", "--db", db, "list")
    assert code == 0, err
    rows = [line for line in out.splitlines()[2:] if line.strip()]  # below the header and its rule
    assert len(rows) == 2  # one attempt per run, whatever else presses Save again
    targets = set()
    for n in (1, 2):
        code, out, err = cli("records", "--db", db, "show", str(n))
        targets.add(dict(line.split(None, 1) for line in out.splitlines() if line.strip())["target"].strip())
    assert targets == {"foramen_ovale_left", "skull"}
