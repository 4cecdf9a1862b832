"""A records database of every schema version opens and finds every attempt with the same figures.

A database is built at each version from 1 to the current one, on SQLite and on PostgreSQL, as the
chainsim of that version left it: the tables its migrations made, attempts stored in the columns that
version had (each figure a later version added at its default, as the migration that added it gave
it), the version number set. The store opens it (migrating it in place) and must read every attempt
with the same figures, of the same type (counts whole, the rest real, a missing needle error None),
and the same procedure-neutral metrics. An attempt of another procedure (the cutting trainer) goes
through the same path with its own figures.
"""

from __future__ import annotations

import json
import sqlite3

import pytest

from chainsim.game.records.backend import PgConnection, is_postgres
from chainsim.game.records.migrations import MIGRATIONS, SCHEMA_VERSION
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import AIDS as RECORDED_AIDS
from chainsim.systems.engine.errors import UserError

#: the attempts as the first version stored them (its columns), then what versions 3 and 5 added
FIRST = (
    {
        "created_at": "2025-01-01T10:00:00Z",
        "duration_s": 30.0,
        "landmark_error_mm": 5.0,
        "needle_error_mm": None,  # the needle touched nothing
        "target": "skull",
        "skull_contacts": 0,
        "path_length_mm": 50.0,
    },
    {
        "created_at": "2025-01-02T10:00:00Z",
        "duration_s": 31.25,
        "landmark_error_mm": 0.1 + 0.2,  # every digit of a float survives
        "needle_error_mm": -1.5,  # inside the opening
        "target": "foramen_ovale_left",
        "skull_contacts": 3,
        "path_length_mm": 48.5,
    },
)
ADDED = {
    3: ({"redirections": 2}, {"redirections": 0}),
    5: (
        {"xray_shots": 4, "exposure_s": 1.2, "dose_mgy": 0.24},
        {"xray_shots": 1, "exposure_s": 0.3, "dose_mgy": 0.06},
    ),
}
DEFAULTS = {"redirections": 0, "xray_shots": 0, "exposure_s": 0.0, "dose_mgy": 0.0}
AIDS = {name: name == "tip_view" for name in RECORDED_AIDS}


def _expected(version: int) -> list[dict]:
    out = []
    for i, first in enumerate(FIRST):
        a = {**first, **DEFAULTS}
        for added_in, values in ADDED.items():
            if version >= added_in:
                a.update(values[i])
        out.append(a)
    return out


class _Raw:
    """The database as an old chainsim wrote it: plain SQL on either backend."""

    def __init__(self, where: str) -> None:
        self.pg = is_postgres(where)
        self.conn = PgConnection(where) if self.pg else sqlite3.connect(where)

    def run(self, sql: str, params: tuple = ()) -> None:
        self.conn.execute(sql, params)

    def close(self, version: int) -> None:
        if self.pg:
            self.conn.set_user_version(version)
        else:
            self.conn.execute(f"PRAGMA user_version = {version}")
            self.conn.commit()
        self.conn.close()


def _build(where: str, version: int) -> None:
    """A database at `version` holding FIRST, with what versions 3 and 5 added where it has them."""
    db = _Raw(where)
    for step in MIGRATIONS[:1]:
        for statement in step:
            db.run(statement)
    db.run("INSERT INTO classes (name) VALUES ('c1')")
    db.run("INSERT INTO trainees (class_id, name) VALUES (1, 'alice')")
    for a in FIRST:
        db.run(
            "INSERT INTO attempts (trainee_id, pack, created_at, duration_s, landmark_error_mm, needle_error_mm, "
            "target, skull_contacts, path_length_mm, aids, step_times) VALUES (1, 'prp', ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                a["created_at"],
                a["duration_s"],
                a["landmark_error_mm"],
                a["needle_error_mm"],
                a["target"],
                a["skull_contacts"],
                a["path_length_mm"],
                json.dumps(AIDS),
                json.dumps({"insert": 12.5}),
            ),
        )
    for v in range(2, version + 1):
        for statement in MIGRATIONS[v - 1]:
            db.run(statement)
        for i, values in enumerate(ADDED.get(v, ())):  # an attempt of that version stores its new figures
            sets = ", ".join(f"{k} = ?" for k in values)
            db.run(f"UPDATE attempts SET {sets} WHERE id = ?", (*values.values(), i + 1))
    db.close(version)


def _saved_now(where: str) -> None:
    """The current version: the same attempts saved through the store."""
    with RecordStore(where) as s:
        for a in _expected(SCHEMA_VERSION):
            s.save_attempt("c1", "alice", {**a, "pack": "prp", "aids": AIDS, "step_times": {"insert": 12.5}})


@pytest.mark.parametrize("version", range(1, SCHEMA_VERSION + 1))
def test_a_database_of_every_version_reads_every_attempt_with_the_same_figures(records_db, version):
    if version == SCHEMA_VERSION:
        _saved_now(records_db)
    else:
        _build(records_db, version)
    expected = _expected(version)
    with RecordStore(records_db) as s:
        assert s.schema_version == SCHEMA_VERSION
        got = s.list_attempts()
    assert len(got) == len(expected)
    for old, new in zip(expected, got):
        for key, value in old.items():
            assert new[key] == value and type(new[key]) is type(value), (version, key, new[key], value)
        assert new["pack"] == "prp" and new["aids"] == AIDS and new["step_times"] == {"insert": 12.5}
        # the procedure-neutral metrics hold every figure too, as version 6 copied them
        figures = {k: v for k, v in old.items() if k not in ("created_at", "target")}
        assert new["metrics"] == {k: None if v is None else float(v) for k, v in figures.items()}


def test_an_attempt_of_another_procedure_keeps_its_own_figures_by_name(records_db):
    """The cutting trainer's attempt goes through the same path: its figures are those its layout
    declares, read back by name with their types, and it names its procedure; the needle's figures it
    never had stay absent (not zero)."""
    from chainsim.systems.procedures import procedure_for

    layout = procedure_for("cutting").layout
    figures = {c.name: (3 if c.whole else 2.5) for c in layout.columns}
    attempt = {"procedure": "cutting", "pack": "cutting", "target": "dura", **figures, "metrics": {"links_cut": 3.0}}
    with RecordStore(records_db) as s:
        rid = s.save_attempt("c1", "ann", attempt)
        got = s.get_attempt(rid)
        with pytest.raises(UserError, match="missing field 'cut_length_mm'"):
            s.save_attempt("c1", "ann", {k: v for k, v in attempt.items() if k != "cut_length_mm"})
        with pytest.raises(UserError, match="attempts are kept of: cutting, needle, prp"):
            s.save_attempt("c1", "ann", {**attempt, "procedure": "demo"})
    assert got["procedure"] == "cutting" and list(got)[3:5] == ["procedure", "pack"]
    for name, value in figures.items():
        assert got[name] == value and type(got[name]) is type(value), name
    assert "needle_error_mm" not in got and got["target"] == "dura" and got["aids"] == {}
    assert got["metrics"] == {**{k: float(v) for k, v in figures.items()}, "links_cut": 3.0}
