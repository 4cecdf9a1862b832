"""The records server scores an attempt by replaying its recording: the tissue's figures it stores are the
simulator's own (peak force, punctures per layer, re-punctures), because the needle and the tissue replay
bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from chainsim.game.records.provenance import encode_recording
from chainsim.game.records.store import RecordStore
from chainsim.game.trainer.headless import run_pack

ASSETS = Path(__file__).resolve().parents[2] / "assets"


def test_the_scoring_replay_stores_the_tissue_figures_the_simulator_saved(tmp_path):
    pytest.importorskip("starlette")  # the server's scoring lives with the server extra
    from chainsim.game.server.scoring import replay_record

    db, rec = tmp_path / "r.db", tmp_path / "a.json"
    # the pack's attempt in the window's form (mouse only), which is what a server takes
    run_pack("prp", script=str(ASSETS / "prp" / "scripts" / "correct-mouse.toml"), record=str(rec),
             settings={"db": str(db), "class": "c", "trainee": "t"})  # fmt: skip
    with RecordStore(db) as store:
        (saved,) = store.list_attempts("c", "t")
    # as an upload carries it
    replayed = replay_record(encode_recording(json.loads(rec.read_text())), str(ASSETS / "prp"), [])["record"]
    for name in ("peak_force_N", "skin_punctures", "repunctures"):
        assert replayed["metrics"][name] == pytest.approx(saved["metrics"][name], rel=0, abs=1e-9)
    assert saved["metrics"]["skin_punctures"] == 1 and saved["metrics"]["peak_force_N"] > 1.0
    assert replayed["details"]["punctures"] == saved["details"]["punctures"] == {
        "skin": 1, "subcutaneous": 1, "muscle": 1, "deep": 1,
    }  # fmt: skip
