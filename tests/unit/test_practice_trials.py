"""Practice trials of a study (protocol `practice = N`) count in no statistic: Table 6.1's rows and the
validity report's selection leave them out, saying how many."""

from __future__ import annotations

from chainsim.game.study.table61 import study_rows
from chainsim.game.study.validity_data import select


def trial(i: int, practice: bool) -> dict:
    protocol = {"study": "s", "participant": "ann", "task": "location", "condition": "c", "group": "novice"}
    return {
        "id": i,
        "pack": "prp",
        "created_at": f"2026-01-0{i}T10:00:00Z",
        "landmark_error_mm": 1.0 * i,
        "details": {"protocol": {**protocol, "practice": practice}},
    }


def test_practice_trials_are_left_out_of_the_tables_and_the_report():
    attempts = [trial(1, True), trial(2, False), trial(3, False)]
    assert [r["attempt_id"] for r in study_rows(attempts, "s")] == [2, 3]
    sel = select(attempts, None, pack="prp", study="s")
    assert [a["id"] for a in sel.series["ann"]] == [2, 3]
    assert sel.left_out["practice trials"] == 1
