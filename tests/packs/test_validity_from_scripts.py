"""The validity analysis on cohorts made by the simulator itself: every participant's attempt is the prp
pack's correct input script played headless, with the dials' angles moved by a stated amount. Novices'
aim is off by AIM_OFFSET_DEG more than experts', so the analysis must find that the distance from the
needle's tip to the foramen separates the groups, with the contrasting-groups mark between them; with
both groups made from the very same perturbed scripts it must find no difference."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from chainsim.components.input_events import Widget
from chainsim.components.resources import Assessment, PendingInput
from chainsim.game.study.cohort import Participant, _record
from chainsim.game.study.validity_data import select
from chainsim.game.study.validity_report import analyse
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

PACK = Path(__file__).resolve().parents[2] / "assets" / "prp"
DIALS = ("rotate_horizontal", "rotate_vertical")
#: how much further off novices aim than experts, degrees, and everyone's spread about their aim
AIM_OFFSET_DEG, AIM_SD_DEG = 4.0, 0.75
METRIC = {"tip_to_target_mm": {"label": "Tip to target", "units": "mm", "lower_is_better": True}}
PER_GROUP = 8


def perturbed(events, turn: tuple[float, float]):
    """The script's events with each dial's angle moved by `turn` (horizontal, vertical) degrees."""
    out = []
    for t, ev in events:
        if isinstance(ev, Widget) and ev.name in DIALS:
            ev = dataclasses.replace(ev, value=float(ev.value) + turn[DIALS.index(ev.name)])
        out.append((t, ev))
    return out


def test_a_perturbed_script_turns_each_dial_by_the_stated_amount():
    events = load_script(PACK / "scripts" / "correct.toml")
    moved = perturbed(events, (2.5, -1.5))
    dials = [
        (a[1], b[1]) for a, b in zip(events, moved, strict=True) if isinstance(a[1], Widget) and a[1].name in DIALS
    ]
    assert {a.name for a, _ in dials} == set(DIALS)
    for a, b in dials:
        assert b.value - a.value == pytest.approx(2.5 if a.name == DIALS[0] else -1.5)
    assert [e for e in moved if not (isinstance(e[1], Widget) and e[1].name in DIALS)] == [
        e for e in events if not (isinstance(e[1], Widget) and e[1].name in DIALS)
    ]


def _played(events) -> float:
    app = build_app(str(PACK), render=False, headless=True)
    try:
        app.resource(PendingInput).extend(events)
        for _ in range(int((max(t for t, _ in events) + 0.3) / app.time.dt)):
            app.update(app.time.dt)
        return float(app.resource(Assessment).values["tip_to_target_mm"])
    finally:
        app.close()


def _attempts(values: list[tuple[str, float]]) -> list[dict]:
    out = []
    for i, (group, value) in enumerate(values, 1):
        person = Participant(f"p{i:02d}", group, None, None)
        record = _record("prp", person, 1, np.datetime64("2026-01-01").astype(object), {"tip_to_target_mm": value})
        out.append({**record, "id": i, "class_name": "scripts", "trainee": person.name, "source": "local", "flags": []})
    return out


@pytest.mark.slow
def test_the_analysis_finds_the_aim_difference_and_none_between_copies():
    events = load_script(PACK / "scripts" / "correct.toml")
    rng = np.random.default_rng(7)
    experts, novices = [], []
    for _ in range(PER_GROUP):
        experts.append(_played(perturbed(events, tuple(rng.normal(0.0, AIM_SD_DEG, 2)))))
        off = AIM_OFFSET_DEG * rng.choice([-1.0, 1.0], 2) / np.sqrt(2)  # AIM_OFFSET_DEG off, in a random direction
        novices.append(_played(perturbed(events, tuple(off + rng.normal(0.0, AIM_SD_DEG, 2)))))
    assert np.median(novices) > np.median(experts)

    found = analyse(
        select(_attempts([("novice", v) for v in novices] + [("expert", v) for v in experts]), None, pack="prp"),
        METRIC, pack="prp", source="the correct script, perturbed", resamples=2000,
    ).results[0]  # fmt: skip
    assert found.separates and found.delta_ci[0] > 0
    mark = found.mark["mark"]
    assert np.median(experts) < mark < np.median(novices)

    same = analyse(
        select(_attempts([("novice", v) for v in experts] + [("expert", v) for v in experts]), None, pack="prp"),
        METRIC, pack="prp", source="the same scripts twice", resamples=2000,
    ).results[0]  # fmt: skip
    assert not same.separates and same.delta == 0.0 and same.delta_ci[0] <= 0.0 <= same.delta_ci[1]
