"""The debrief a trainee reads after an attempt: verdicts against the pack's benchmarks, critical
errors that fail an attempt whatever the rest, advice for what failed, and a box that fits the window."""

from __future__ import annotations

from pathlib import Path

from chainsim.components.hud import HudState
from chainsim.components.resources import Assessment, PendingInput
from chainsim.game.packs.pack import load
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.procedures import verdicts as vd
from chainsim.systems.procedures.needle import debrief as db

REPO = Path(__file__).resolve().parents[2]

SPEC = {
    "needle_error_mm": {
        "label": "Needle error",
        "units": "mm",
        "benchmark": 0.0,
        "critical": 0.0,
        "critical_note": "outside the foramen",
        "advice": "aim again",
    },
    "skull_contacts": {"label": "Bone contacts", "benchmark": 1.0, "critical": 3.0, "critical_note": "over 3 contacts"},
    "xray_shots": {"label": "X-ray images", "benchmark": 10.0, "advice": "fewer images"},
    "first_contact_dist_mm": {"label": "Distance at first contact", "units": "mm"},
}


def test_a_critical_error_fails_the_attempt_whatever_the_rest():
    rows = vd.verdicts(SPEC, {"needle_error_mm": -1.0, "skull_contacts": 4.0, "xray_shots": 2.0})
    o = vd.outcome(rows)
    assert not o["passed"] and o["critical"] == ["over 3 contacts"]
    assert vd.verdict_line(o).startswith("FAILED: critical error - over 3 contacts")


def test_every_benchmark_met_passes_and_a_missing_value_is_critical():
    ok = vd.outcome(vd.verdicts(SPEC, {"needle_error_mm": -1.0, "skull_contacts": 0.0, "xray_shots": 3.0}))
    assert ok["passed"] and (ok["met"], ok["judged"]) == (3, 3)
    rows = vd.verdicts(SPEC, {"needle_error_mm": None, "skull_contacts": 0.0, "xray_shots": 12.0})
    by = {r["name"]: r for r in rows}
    assert by["needle_error_mm"]["critical"] and by["needle_error_mm"]["advice"] == "aim again"
    assert by["xray_shots"]["passed"] is False and by["xray_shots"]["advice"] == "fewer images"
    assert by["xray_shots"]["threshold"] == "\u2264 10" and by["first_contact_dist_mm"]["passed"] is None


def test_numbers_are_rounded_with_their_units():
    assert vd.number(6.721578213131352e-05, "mm") == "0.0 mm"
    assert vd.number(-1.1727, "mm") == "-1.2 mm" and vd.number(3.0) == "3" and vd.number(0.1812, "mGy") == "0.18 mGy"


def test_the_shipped_packs_declare_benchmarks_critical_errors_and_an_ideal_path():
    for name in ("prp", "mental-block"):
        pack = load(REPO / "assets" / name)
        metrics = pack.section("metrics")
        assert any(m.get("critical") is not None for m in metrics.values())
        benchmarked = [m for m in metrics.values() if m.get("benchmark") is not None]
        assert all(m.get("benchmark_source") for m in benchmarked)
        # nothing a shipped pack benchmarks rests on a study of people yet: each says provisional
        assert all(m["benchmark_basis"] == "provisional" for m in benchmarked)
        assert pack.section("needle_procedure")["ideal_path"]


def test_a_bone_hit_attempt_ends_with_a_failed_debrief_that_says_why_and_what_to_do():
    app = build_app("prp")
    try:
        events = load_script(REPO / "docs" / "images" / "prp-debrief.toml")
        app.resource(PendingInput).extend(events)
        app.run_steps(int(5.0 * 120))
        h = app.resource(HudState)
        texts = [t for t, _ in h.debrief]
        assert texts[0].startswith("Debrief, attempt 1 (left side): FAILED: critical error")
        assert any(t.startswith("Needle error:") and "CRITICAL" in t for t in texts)
        assert any(tone == db.ADVICE and t.startswith("Needle error: ") for t, tone in h.debrief)
        # the ideal path and the trainee's, for the surgeon's view and the X-ray image
        assert len(h.debrief_paths) == 2 and len(h.debrief_paths[1][0]) > 10
        v = app.resource(Assessment).values
        assert v["verdict"]["passed"] is False and len(v["ideal_landmarks"]) == 3
        # every benchmark prp ships is provisional: said beside each threshold, under the verdicts, and kept
        assert any(t.startswith("Needle error:") and "\u2264 0.0 mm, provisional)" in t for t in texts)
        assert any(t.startswith("Provisional: every benchmark here rests on no study") for t in texts)
        kept = v["verdict"]["benchmarks"]
        assert kept["landmark_error_mm"]["basis"] == "provisional" and kept["landmark_error_mm"]["benchmark"] == 3.0
        assert "Shakur et al. 2015" in kept["landmark_error_mm"]["source"]
    finally:
        app.close()


def test_a_benchmark_says_what_it_rests_on_and_the_debrief_says_when_it_is_provisional():
    spec = dict(SPEC, xray_shots=dict(SPEC["xray_shots"], benchmark_basis="programme", benchmark_source="our data"))
    rows = vd.verdicts(spec, {"needle_error_mm": -1.0, "skull_contacts": 0.0, "xray_shots": 3.0})
    by = {r["name"]: r for r in rows}
    # no basis stated: provisional; no benchmark: nothing to rest on
    assert (by["needle_error_mm"]["basis"], by["xray_shots"]["basis"]) == ("provisional", "programme")
    assert by["first_contact_dist_mm"]["basis"] == ""
    assert vd.basis_note(rows).startswith("Provisional: 2 of 3 benchmarks here rest")
    assert vd.rested_on(rows)["xray_shots"] == {"benchmark": 10.0, "basis": "programme", "source": "our data"}
    published = {k: dict(m, benchmark_basis="published") for k, m in SPEC.items()}
    assert vd.basis_note(vd.verdicts(published, {})) == ""
