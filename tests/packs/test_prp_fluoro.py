"""The C-arm of the prp pack without a screen: images, live seconds, dose, projections, attempts (thesis 3.2.3).

These run the shipped pack headless (no GL): the counts a trainee is scored on must not depend on
whether anything is drawn.
"""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, MouseDrag, Widget
from chainsim.components.resources import Assessment, EntityIndex, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.procedures.needle.carm import DOSE_RATE_MGY_S, SHOT_S, CArm
from chainsim.systems.procedures.needle.fluoro import OBLIQUE_DEG
from chainsim.systems.view.ui.viewports import carm_source_direction

ROOT = Path(__file__).resolve().parents[2]
PACK = Path(os.environ.get("CHAINSIM_PRP_TEST_PACK", ROOT / "assets" / "prp"))


def run(events, steps=240, settings=None):
    app = build_app(str(PACK), settings=settings)
    app.resource(PendingInput).extend(sorted(events, key=lambda e: e[0]))
    for _ in range(steps):
        app.update(app.time.dt)
    with app.active():
        carm = esper.component_for_entity(app.resource(EntityIndex).get("carm"), CArm)
    return app, carm


def test_each_image_is_counted_with_its_exposure_and_dose():
    app, carm = run([(0.1, Widget("xray_take", None)), (0.2, Widget("xray_take", None))])
    a = app.resource(Assessment).values
    assert a["xray_shots"] == 2 and carm.image_id == 2
    assert a["exposure_s"] == pytest.approx(2 * SHOT_S)
    assert a["dose_mgy"] == pytest.approx(2 * SHOT_S * DOSE_RATE_MGY_S)
    assert a["fluoro_s"] == 0.0
    app.close()


def test_live_fluoroscopy_counts_the_seconds_the_pedal_is_held_and_pulses_images():
    # the pedal (key f) held from 0.5 s to 2.5 s of simulated time
    app, carm = run([(0.5, Key("f", True)), (2.5, Key("f", False))], steps=480)
    assert carm.live_s == pytest.approx(2.0, abs=2 * app.time.dt)
    assert carm.shots == 0
    assert 28 <= carm.image_id <= 32  # 15 images a second
    assert not carm.live
    # the panel's Live switch does the same
    app2, carm2 = run([(0.5, Widget("fluoro_live", True)), (1.5, Widget("fluoro_live", False))], steps=360)
    assert carm2.live_s == pytest.approx(1.0, abs=2 * app2.time.dt)
    assert carm2.exposure_s == pytest.approx(carm2.live_s)
    app.close()
    app2.close()


def test_projections_point_the_beam_as_surgeons_use_them():
    app, carm = run([(0.1, Widget("xray_lateral", None))])
    # lateral: the beam runs across the head, the detector on the entry side (left, -X)
    beam = -carm_source_direction(carm.azimuth_deg, carm.elevation_deg)
    assert beam == pytest.approx([-1.0, 0.0, 0.0], abs=1e-9)
    app.close()
    app, carm = run([(0.1, Widget("xray_submental", None))])
    beam = -carm_source_direction(carm.azimuth_deg, carm.elevation_deg)
    axis = np.asarray(tomllib.loads((PACK / "anatomy.toml").read_text())["foramina"]["left"]["axis"], float)
    # up from under the chin, as steep as the foramen's canal, turned OBLIQUE_DEG about the vertical
    # toward the entry side (the left lies at azimuth 180)
    assert beam[2] > 0.8
    src = -axis / np.linalg.norm(axis)
    assert carm.elevation_deg == pytest.approx(np.degrees(np.arcsin(-src[2])), abs=1e-6)
    canal_azimuth = np.degrees(np.arctan2(src[1], src[0]))
    assert carm.azimuth_deg - canal_azimuth == pytest.approx(OBLIQUE_DEG, abs=1e-6)
    assert 90.0 < carm.azimuth_deg < 180.0  # the source in front of the face, toward the left
    centre = tomllib.loads((PACK / "anatomy.toml").read_text())["foramina"]["left"]["centre"]
    np.testing.assert_allclose(carm.iso, centre)  # centred on the foramen
    app.close()


def test_a_drag_in_the_carm_view_turns_the_arm_and_makes_it_free():
    from chainsim.systems.view.cameras import ViewState

    app = build_app(str(PACK), size=(1280, 800))
    vs = app.resource(ViewState)
    r = vs.get("carm").rect
    x, y = r.x + r.w / 2, r.y + r.h / 2
    app.resource(PendingInput).extend(
        [
            (0.1, MouseButton(x, y, "left", True)),
            (0.12, MouseDrag(x + 25, y, 25.0, 0.0, "left")),
            (0.14, MouseDrag(x + 25, y + 10, 0.0, 10.0, "left")),
            (0.16, MouseButton(x + 25, y + 10, "left", False)),
        ]
    )
    with app.active():
        before = esper.component_for_entity(app.resource(EntityIndex).get("carm"), CArm)
        az0, el0 = before.azimuth_deg, before.elevation_deg
    for _ in range(60):
        app.update(app.time.dt)
    with app.active():
        carm = esper.component_for_entity(app.resource(EntityIndex).get("carm"), CArm)
    assert carm.view == "free"
    assert (carm.azimuth_deg - az0) % 360 == pytest.approx(360 - 10.0)  # 25 px at 0.4 deg/px
    assert carm.elevation_deg - el0 == pytest.approx(4.0)
    assert carm.shots == 0  # turning the arm takes no image
    app.close()


def test_a_new_attempt_counts_its_own_images(tmp_path):
    events = load_script(PACK / "scripts" / "correct.toml")
    last = max(t for t, _ in events)
    events += [(last + 0.2, Widget("save", None)), (last + 0.4, Widget("reset", None))]
    events += [(last + 0.6, Widget("xray_take", None))]
    app, carm = run(events, steps=int((last + 1.0) / (1 / 120.0)), settings={"db": str(tmp_path / "r.sqlite3")})
    assert carm.shots == 1  # the three of the saved attempt are not carried over
    app.close()


def test_headless_run_reports_the_xray_of_the_correct_attempt(tmp_path, cli):
    code, out, err = cli(
        "run", str(PACK), "--headless", "--input", str(PACK / "scripts" / "correct.toml"), "--out", tmp_path
    )
    assert code == 0, err
    a = json.loads((tmp_path / "summary.json").read_text())["assessment"]
    assert a["xray_shots"] == 3
    assert a["exposure_s"] == pytest.approx(3 * SHOT_S)
    assert a["dose_mgy"] == pytest.approx(3 * SHOT_S * DOSE_RATE_MGY_S)
    assert a["xray_view"] == "submental"  # the last image: is the tip in the oval?


def test_saved_attempt_shows_its_xray_in_records(tmp_path, cli):
    script = tmp_path / "saved.toml"
    text = (PACK / "scripts" / "correct.toml").read_text()
    last = max(t for t, _ in load_script(PACK / "scripts" / "correct.toml"))
    script.write_text(text + f'\n[[event]]\nt = {last + 0.3}\nkind = "widget"\nname = "save"\n')
    db = tmp_path / "r.sqlite3"
    code, _, err = cli(
        "run", str(PACK), "--headless", "--input", script, "--db", db, "--class", "c1", "--trainee", "ann"
    )
    assert code == 0, err
    code, out, err = cli("records", "--db", db, "show", "1")
    assert code == 0, err
    fields = dict(line.split(None, 1) for line in out.splitlines() if line.strip())
    assert fields["xray_shots"].strip() == "3"
    assert float(fields["exposure_s"]) == pytest.approx(3 * SHOT_S)
    code, out, err = cli("records", "--db", db, "list")
    assert "xrays" in out.splitlines()[0]


def _fluoro_first_pack(tmp_path) -> Path:
    """A copy of the pack whose [needle_procedure] turns fluoroscopy-first on."""
    import shutil

    dst = tmp_path / "prp-ff"
    shutil.copytree(PACK, dst)
    toml = dst / "pack.toml"
    text = toml.read_text()
    assert "\nfluoro_first = false" in text
    toml.write_text(text.replace("\nfluoro_first = false", "\nfluoro_first = true", 1))
    return dst


def test_fluoro_first_takes_the_ring_and_distance_off_the_tip_view_and_is_recorded(tmp_path):
    events = load_script(PACK / "scripts" / "correct.toml")
    steps = int((max(t for t, _ in events) + 0.2) * 120)
    for settings, pack, on in (
        (None, PACK, False),
        ({"fluoro_first": True}, PACK, True),  # play/run --fluoro-first
        (None, _fluoro_first_pack(tmp_path), True),  # the pack's own setting
    ):
        app = build_app(str(pack), settings=settings)
        app.resource(PendingInput).extend(sorted(events, key=lambda e: e[0]))
        for _ in range(steps):
            app.update(app.time.dt)
        h = app.resource(HudState)
        a = app.resource(Assessment).values
        assert a["fluoro_first"] is on
        assert a["target_reached"]  # the X-ray alone still lets the attempt be scored as ever
        if on:
            assert h.aim_target is None and "mm" not in h.aim_note and "X-ray" in h.aim_note
        else:
            assert h.aim_target is not None and h.aim_note.endswith(" mm")
        app.close()


def test_fluoro_first_is_stored_with_the_saved_attempt(tmp_path, cli):
    script = tmp_path / "saved.toml"
    text = (PACK / "scripts" / "correct.toml").read_text()
    last = max(t for t, _ in load_script(PACK / "scripts" / "correct.toml"))
    script.write_text(text + f'\n[[event]]\nt = {last + 0.3}\nkind = "widget"\nname = "save"\n')
    db = tmp_path / "r.sqlite3"
    code, _, err = cli(
        "run", str(PACK), "--headless", "--input", script, "--db", db, "--trainee", "ann", "--fluoro-first"
    )
    assert code == 0, err
    code, out, err = cli("records", "--db", db, "show", "1")
    assert code == 0, err
    assert "fluoro_first" in out and "true" in out.split("fluoro_first", 1)[1].splitlines()[0].lower()


def test_fluoro_first_must_be_true_or_false(tmp_path, cli):
    pack = _fluoro_first_pack(tmp_path)
    toml = pack / "pack.toml"
    toml.write_text(toml.read_text().replace("\nfluoro_first = true", '\nfluoro_first = "yes"', 1))
    code, out, err = cli("validate", str(pack))
    assert code == 2
    assert "needle_procedure.fluoro_first: expected true or false" in out + err


def test_fluoro_first_aiming_steps_say_to_aim_by_the_x_ray_not_the_ring():
    events = [(t, e) for t, e in load_script(PACK / "scripts" / "correct.toml") if t <= 1.6]  # the landmarks
    for settings, ring in ((None, True), ({"fluoro_first": True}, False)):
        app, _carm = run(events, steps=int(1.8 * 120), settings=settings)
        h = app.resource(HudState)
        assert h.step_title.lower().startswith("aim")
        assert ("ring" in h.step_instruction) is ring
        assert ring or "X-ray" in h.step_instruction
        app.close()


def test_a_fluoro_first_recording_replays_in_that_mode(tmp_path, cli):
    rec, out = tmp_path / "ff.json", tmp_path / "replayed"
    code, _, err = cli("run", str(PACK), "--headless", "--steps", "60", "--fluoro-first", "--record", rec)
    assert code == 0, err
    assert json.loads(rec.read_text())["settings"]["fluoro_first"] is True
    code, _, err = cli("replay", rec, "--out", out)
    assert code == 0, err
    assert json.loads((out / "summary.json").read_text())["assessment"]["fluoro_first"] is True
