"""A replay skips the window's work (RunInfo.replay) and still reaches the window session's state: the same
world digest at the Save, the same saved figures, and the same assessment whenever it is read.

The session is made as the window makes it (chainsim.tools.bench.replay.record_session: a stretched,
mouse-only correct attempt driven frame by frame) with every shortcut off - the replay's skipping, the
assessment's reuse of an unchanged frame's debrief, the hybrid body's first look at the element that
failed its start last time and its skipping of a frame that repeats the last - so it is the
computation as written before them; the replay runs with all of them on."""

from __future__ import annotations

import json
from contextlib import contextmanager

import pytest

from chainsim.components.digest import world_digest
from chainsim.components.resources import Assessment, PackResource, PendingInput, Records, RunInfo
from chainsim.game.packs import pack as packs
from chainsim.game.records import provenance
from chainsim.game.trainer.headless import app_for_pack
from chainsim.game.trainer.inputscript import parse_events
from chainsim.systems.engine.bodies import hybrid
from chainsim.systems.engine.kernels.twolevel import min_det
from chainsim.systems.procedures.needle import assessment
from chainsim.systems.procedures.needle.manifest import NeedleScene
from chainsim.tools.bench import replay as bench

#: long enough for every gesture of an attempt to have its own second or so, with idle frames between
MINUTES = 0.45
#: the assessment is read (and so worked out, where a replay deferred it) this often, in steps
SAMPLE_EVERY = 97


@contextmanager
def as_written(monkeypatch):
    """Every shortcut off: the assessment worked out in full each frame, every start checked in full."""
    with monkeypatch.context() as m:

        def values(self, app):
            v = assessment.compute(app)
            assessment.geometry(app, v, self.trace.points)
            self.memo_hit = False
            return v

        def rows(self, app, v):
            return assessment.debrief_rows(v, app.resource(NeedleScene), app.resource(PackResource).pack)

        def start_ratio(self, s, x, floor):
            return min_det(x, self.tets, self.D, s["elems"])

        solve = hybrid.HybridBody._solve

        def solve_in_full(self, dt):
            self._quiet = None  # no frame is taken for a repeat of the last
            stats = solve(self, dt)
            self._kept = False  # every step compares the positions it leaves with those it found
            return stats

        m.setattr(assessment.AssessmentSystem, "values", values)
        m.setattr(assessment.AssessmentSystem, "rows", rows)
        m.setattr(hybrid.HybridBody, "_start_ratio", start_ratio)
        m.setattr(hybrid.HybridBody, "_solve", solve_in_full)
        yield


def replay(session: dict, root, pack_paths, *, lean: bool) -> dict:
    """Replay `session` as the records server does, `lean` or not: the digest and figures at its Save, and
    the assessment read every SAMPLE_EVERY steps until then."""
    recording = provenance.decode_recording(session["recording"])
    app = app_for_pack(packs.load(root, pack_paths), recording["scene"], dt=recording["dt"], save="test", replay=lean)
    try:
        assert app.resource(RunInfo).replay is lean
        saved: list[tuple[dict, str]] = []

        def save_attempt(class_name: str, trainee: str, record: dict) -> int:
            saved.append((record, world_digest(app)))  # where the simulator takes the upload's digest
            return len(saved)

        app.insert_resource(Records(save_attempt=save_attempt, list_attempts=lambda c, t: []))
        app.resource(PendingInput).extend(parse_events(recording, "recording"))
        read = []
        for step in range(recording["steps"]):
            app.update(app.time.dt)
            if step % SAMPLE_EVERY == 0:
                read.append(json.dumps(app.resource(Assessment).values, sort_keys=True, default=repr))
    finally:
        app.close()
    ((record, digest),) = saved
    return {"record": bench.canonical(record), "digest": digest, "read": read}


def check(root, pack_paths, monkeypatch) -> None:
    with as_written(monkeypatch):
        session = bench.record_session(root, pack_paths, MINUTES)
        full = replay(session, root, pack_paths, lean=False)
    lean = replay(session, root, pack_paths, lean=True)
    assert full["digest"] == session["digest"] and full["record"] == bench.canonical(session["record"])
    assert lean["digest"] == session["digest"]
    assert lean["record"] == full["record"]
    assert lean["read"] == full["read"]
    assert json.loads(lean["record"])["target"] == json.loads(full["record"])["target"] != ""


@pytest.mark.parametrize("pack", ["prp", "mental-block"])
def test_a_replay_without_the_windows_work_reaches_the_sessions_state(pack, tmp_path, monkeypatch):
    check(*bench.pack_variant(pack, False, tmp_path), monkeypatch)


def test_a_replay_with_tissue_reaches_the_sessions_state(tmp_path, monkeypatch):
    """mental-block's needle rests in converged tissue: frames that repeat the last are skipped."""
    skipped = []
    solve = hybrid.HybridBody._solve

    def spy(self, dt):
        stats = solve(self, dt)
        skipped.append(bool(self._kept and len(self.grab_ids)))
        return stats

    monkeypatch.setattr(hybrid.HybridBody, "_solve", spy)
    check(*bench.pack_variant("mental-block", True, tmp_path), monkeypatch)
    assert sum(skipped) > 100


@pytest.mark.slow
def test_a_needle_held_short_in_tissue_replays_to_the_sessions_state(tmp_path, monkeypatch):
    """prp's needle rests in tissue pulling its held nodes further than any shape allows: every frame's
    start fails, which is where the hybrid body looks at the last failing element first."""
    first_looks = []
    start_ratio = hybrid.HybridBody._start_ratio

    def spy(self, s, x, floor):
        first_looks.append(s.get("squeezed", -1) >= 0)
        return start_ratio(self, s, x, floor)

    root, pack_paths = bench.pack_variant("prp", True, tmp_path)
    with as_written(monkeypatch):
        session = bench.record_session(root, pack_paths, MINUTES)
    monkeypatch.setattr(hybrid.HybridBody, "_start_ratio", spy)
    lean = replay(session, root, pack_paths, lean=True)
    assert sum(first_looks) > 100
    assert lean["digest"] == session["digest"] and lean["record"] == bench.canonical(session["record"])


def test_a_run_that_saves_nothing_and_draws_nothing_is_a_replay(tmp_path):
    root, pack_paths = bench.pack_variant("prp", False, tmp_path)
    pack = packs.load(root, pack_paths)
    for kwargs, expected in (({"save": "test"}, True), ({}, False), ({"save": "test", "replay": False}, False)):
        app = app_for_pack(pack, None, **kwargs)
        try:
            assert app.resource(RunInfo).replay is expected
        finally:
            app.close()
