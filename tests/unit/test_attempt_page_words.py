"""An attempt's page on the records server says each figure in its own procedure's words: a cutting attempt's
cut length as the cutting trainer declares it, a needle attempt's errors as the needle procedure does."""

from __future__ import annotations

import pytest

pytest.importorskip("jinja2")

from chainsim.game.server.dashboard import attempt_view  # noqa: E402
from chainsim.systems.procedures import procedure_for  # noqa: E402


def _row(view: dict, name: str) -> dict:
    return next(r for r in view["rows"] if r["name"] == name)


def test_a_cutting_attempt_is_said_in_the_cutting_trainers_words():
    cols = procedure_for("cutting").layout.columns
    a = {"procedure": "cutting", "pack": "cutting", "target": "skin", "details": {}, "metrics": {}}
    a |= {c.name: 1.5 for c in cols}
    view = attempt_view(a, {})
    for c in cols:
        row = _row(view, c.name)
        assert row["label"] == c.words and (row.get("units") or "") == c.units
    assert ("Opened", "skin") in view["facts"]  # what the trainer calls the target reached
    assert not view["marks"] and view["marks_heading"] == ""  # no marked points: none drawn


def test_a_needle_attempt_is_said_in_the_needle_procedures_words():
    lay = procedure_for("needle").layout
    a = {"pack": "prp", "target": "none", "details": {}, "metrics": {}}
    a |= {c.name: 2.0 for c in lay.columns}
    view = attempt_view(a, {})
    words = {c.name: c.words for c in lay.columns}
    assert _row(view, lay.mark_error)["label"] == words[lay.mark_error]
    assert _row(view, lay.target_error)["label"] == words[lay.target_error]
    assert view["marks_heading"] == lay.marks_heading
