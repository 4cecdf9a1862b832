"""A synthetic cohort: attempts with a known difference between novices and experts, drawn, not simulated.

The statistics of a validity study (``chainsim.game.study.validity``) are checked, and shown, on
data whose truth is known: each participant's level on a metric is drawn from their group's normal
distribution (``Draw``), and each of their attempts adds a learning term that shrinks trial by trial
and a trial-to-trial noise. With one trial, no learning and no noise, a participant's value is their
level, so the effect between the groups is exactly the one asked for (Cohen's d = ``effect``; Cliff's
delta = 2 Phi(d / sqrt 2) - 1 for two normal groups of one spread).

The attempts are records the store accepts (``RecordStore.save_attempt``): the drawn values go in the
procedure-neutral ``metrics``, the fixed fields hold zeros and the target ``none``, and
``details.protocol`` carries the participant, their group, years of training and procedures, the
trial and ``synthetic: true`` (``scripted: true`` too, so a study's tables of people never count them).
Every report made from them says that its data are synthetic and not evidence.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np

from chainsim.game.records.validate import REQUIRED
from chainsim.game.study.validity_data import GROUPS, Participant
from chainsim.systems.engine.errors import UserError

#: participants and trials one synthetic cohort may have
MAX_PARTICIPANTS = 2000
MAX_TRIALS = 100
STUDY = "synthetic-cohort"
#: the first attempt's time: obviously not a real session's
EPOCH = datetime(2000, 1, 1, tzinfo=UTC)
#: the experts' learning term is this share of the novices'
EXPERT_LEARNING = 0.25
#: the learning term shrinks by this factor from one trial to the next
LEARNING_DECAY = 0.6


@dataclass(frozen=True)
class Draw:
    """One metric's groups: each participant's level is N(mean, sd) of their group."""

    novice_mean: float
    novice_sd: float
    expert_mean: float
    expert_sd: float

    @property
    def d(self) -> float:
        """Cohen's d of the levels (pooled spread of equal groups), novices minus experts."""
        return (self.novice_mean - self.expert_mean) / math.sqrt((self.novice_sd**2 + self.expert_sd**2) / 2)


def draws_for(metrics: dict[str, dict[str, Any]], effect: float) -> dict[str, Draw]:
    """A Draw per metric of a pack: the experts centred on its benchmark (1 without one), both groups with
    a spread of a quarter of that (at least 1), the novices `effect` spreads worse (by lower_is_better)."""
    out = {}
    for name, spec in metrics.items():
        bench = spec.get("benchmark")
        centre = float(bench) if isinstance(bench, (int, float)) and not isinstance(bench, bool) else 1.0
        sd = max(0.25 * abs(centre), 1.0)
        worse = 1.0 if spec.get("lower_is_better", True) else -1.0
        out[name] = Draw(centre + worse * effect * sd, sd, centre, sd)
    return out


def participants(count: int, rng: np.random.Generator) -> list[Participant]:
    """`count` participants, the first half novices (1-2 years, under 10 procedures), the rest experts."""
    if not 2 <= count <= MAX_PARTICIPANTS:
        raise UserError(f"a synthetic cohort has 2 to {MAX_PARTICIPANTS} participants, got {count}")
    width = len(str(count))
    out = []
    for i in range(count):
        novice = i < count // 2
        years = int(rng.integers(1, 3) if novice else rng.integers(4, 10))
        procedures = int(rng.integers(0, 10) if novice else rng.integers(50, 300))
        out.append(Participant(f"synthetic-{i + 1:0{width}d}", GROUPS[0 if novice else 1], years, procedures))
    return out


def _record(pack: str, person: Participant, trial: int, when: datetime, values: dict[str, float]) -> dict[str, Any]:
    fixed: dict[str, Any] = {name: 0 for name in REQUIRED}
    fixed.update(pack=pack, target="none")
    return {
        **fixed,
        "created_at": when.isoformat(),
        "metrics": values,
        "details": {
            "protocol": {
                "study": STUDY,
                "participant": person.name,
                "group": person.group,
                "year_of_training": person.year_of_training,
                "procedures_performed": person.procedures_performed,
                "trial": f"trial-{trial}",
                "order": trial,
                "scripted": True,
                "synthetic": True,
            }
        },
    }


def build(
    metrics: dict[str, dict[str, Any]],
    count: int,
    *,
    pack: str,
    effect: float = 0.8,
    trials: int = 1,
    seed: int = 0,
    draws: dict[str, Draw] | None = None,
    learning: float = 0.0,
    trial_sd: float = 0.0,
) -> list[tuple[str, dict[str, Any]]]:
    """(trainee, attempt record) for `count` participants with `trials` attempts each.

    `learning` is the novices' extra on their first trial, in spreads of the metric (experts have
    EXPERT_LEARNING of it); `trial_sd` the noise of one attempt around the participant's level, in spreads."""
    if not 1 <= trials <= MAX_TRIALS:
        raise UserError(f"a synthetic participant makes 1 to {MAX_TRIALS} attempts, got {trials}")
    rng = np.random.default_rng(seed)
    draws = draws if draws is not None else draws_for(metrics, effect)
    people = participants(count, rng)
    out = []
    for i, person in enumerate(people):
        novice = person.group == GROUPS[0]
        levels = {
            name: rng.normal(d.novice_mean if novice else d.expert_mean, d.novice_sd if novice else d.expert_sd)
            for name, d in draws.items()
        }
        for t in range(1, trials + 1):
            values = {}
            for name, d in draws.items():
                sd = d.novice_sd if novice else d.expert_sd
                worse = 1.0 if metrics.get(name, {}).get("lower_is_better", True) else -1.0
                extra = learning * (1.0 if novice else EXPERT_LEARNING) * LEARNING_DECAY ** (t - 1)
                values[name] = float(
                    levels[name] + worse * extra * sd + (rng.normal(0, trial_sd * sd) if trial_sd else 0)
                )
            when = EPOCH + timedelta(days=i, minutes=10 * t)
            out.append((person.name, _record(pack, person, t, when, values)))
    return out


def as_listed(cohort: Iterable[tuple[str, dict[str, Any]]], class_name: str = "synthetic") -> list[dict[str, Any]]:
    """The cohort as ``RecordStore.list_attempts`` returns attempts (ids from 1), without a database."""
    out = []
    for i, (trainee, record) in enumerate(cohort, 1):
        out.append({**record, "id": i, "class_name": class_name, "trainee": trainee, "source": "local", "flags": []})
    return out


def register_csv(people: Iterable[Participant]) -> str:
    """A register (the CSV ``chainsim study-report --groups`` reads) of these participants."""
    rows = ["participant,group,year_of_training,procedures_performed"]
    for p in people:
        years, done = ("" if v is None else str(v) for v in (p.year_of_training, p.procedures_performed))
        rows.append(f"{p.name},{p.group},{years},{done}")
    return "\n".join(rows) + "\n"


def people(cohort: Iterable[tuple[str, dict[str, Any]]]) -> list[Participant]:
    """The cohort's participants, in order, as their attempts record them."""
    seen: dict[str, Participant] = {}
    for _trainee, record in cohort:
        p = record["details"]["protocol"]
        seen.setdefault(
            p["participant"],
            Participant(p["participant"], p["group"], p["year_of_training"], p["procedures_performed"]),
        )
    return list(seen.values())
