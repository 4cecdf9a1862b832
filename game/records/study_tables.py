"""A study's register tables: ``study_participants`` (the register and its allocation slots) and
``study_designs`` (each study's design, filed once).

``chainsim.game.study.register`` decides what an entry holds and when a second one is refused; the
statements that keep them are here. A participant row's group is stored as ``grp`` (``group`` is an
SQL word); rows come back with that column name, readable by index and by name.

Functions taking ``conn`` run inside the caller's transaction (``RecordStore.transaction()``): the
next slot is read and taken in the one write transaction, so two registrations never share a slot;
those taking ``store`` read outside one.
"""

from __future__ import annotations

import sqlite3
from typing import Any

from chainsim.game.records.store import RecordStore

#: a participant row's columns, in the order ``insert_participant`` takes them
PARTICIPANT_COLUMNS = (
    "study, class_name, code, grp, year_of_training, procedures_performed, slot, registered_by, registered_at"
)


def participant(conn: sqlite3.Connection, study: str, code: str) -> Any | None:
    """Participant ``code``'s row in ``study``'s register (``PARTICIPANT_COLUMNS``), or None."""
    return conn.execute(
        f"SELECT {PARTICIPANT_COLUMNS} FROM study_participants WHERE study = ? AND code = ?", (study, code)
    ).fetchone()


def next_slot(conn: sqlite3.Connection, study: str) -> int:
    """The study's next allocation slot: one past the highest taken, 0 for the first participant."""
    return int(
        conn.execute("SELECT COALESCE(MAX(slot) + 1, 0) FROM study_participants WHERE study = ?", (study,)).fetchone()[
            0
        ]
    )


def insert_participant(conn: sqlite3.Connection, values: tuple[Any, ...]) -> None:
    """A new register row: ``values`` in the order of ``PARTICIPANT_COLUMNS``."""
    conn.execute(f"INSERT INTO study_participants ({PARTICIPANT_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", values)


def read_participant(store: RecordStore, study: str, code: str) -> Any | None:
    """Participant ``code``'s row in ``study``'s register, or None; outside a transaction."""
    rows = store.query(
        f"SELECT {PARTICIPANT_COLUMNS} FROM study_participants WHERE study = ? AND code = ?", (study, code)
    )
    return rows[0] if rows else None


def participants(store: RecordStore, study: str) -> list[Any]:
    """The study's register rows in slot order."""
    return store.query(f"SELECT {PARTICIPANT_COLUMNS} FROM study_participants WHERE study = ? ORDER BY slot", (study,))


def design_text(conn: sqlite3.Connection, study: str) -> str | None:
    """The design filed for ``study`` (its JSON text), or None."""
    row = conn.execute("SELECT design FROM study_designs WHERE study = ?", (study,)).fetchone()
    return None if row is None else row["design"]


def insert_design(conn: sqlite3.Connection, study: str, text: str, filed_by: str, filed_at: str) -> None:
    """File ``study``'s design (JSON text)."""
    conn.execute(
        "INSERT INTO study_designs (study, design, filed_by, filed_at) VALUES (?, ?, ?, ?)",
        (study, text, filed_by, filed_at),
    )


def read_design_text(store: RecordStore, study: str) -> str | None:
    """The design filed for ``study`` (its JSON text), or None; outside a transaction."""
    rows = store.query("SELECT design FROM study_designs WHERE study = ?", (study,))
    return rows[0]["design"] if rows else None
