"""The scoring queue's table, ``uploads``: every statement that reads or writes it.

The records server keeps each upload in ``uploads`` until a scorer has replayed it
(``chainsim.game.server.scoring`` decides what to claim, when, and what a replay's result means).
An upload's ``state`` is ``scoring`` (waiting, or claimed by ``claimed_by`` at ``claimed_at``),
``scored`` (its attempt is ``attempt_id``) or ``refused`` (``error`` says why).

Functions taking ``conn`` run inside the caller's transaction (``RecordStore.transaction()``), so a
claim or a result stays one transaction however many statements it takes; those taking ``store``
read outside one. Rows come back as the database gives them (readable by index and column name)
unless a function says ``dict``.
"""

from __future__ import annotations

import sqlite3
from typing import Any

from chainsim.game.records.backend import inserted_id
from chainsim.game.records.store import RecordStore

#: the columns ``chainsim records uploads`` lists, with the recording's length in characters
_LISTED = (
    "id, class_name, trainee, filed_by, received_at, pack, state, claimed_by, claimed_at, tries, "
    "witnessed, error, length(recording) AS recording_chars"
)
#: which uploads each listing state names
_LISTING_WHERE = {"waiting": "state = 'scoring'", "refused": "state = 'refused'", "all": "1 = 1"}
#: the attempts of one trainee, named by class and trainee: a FROM ... WHERE with two parameters
_TRAINEE_ATTEMPTS = (
    "FROM attempts a JOIN trainees t ON a.trainee_id = t.id JOIN classes c ON t.class_id = c.id "
    "WHERE c.name = ? AND t.name = ?"
)
#: what a scorer looks at when choosing a claim
_CANDIDATE = "SELECT id, class_name, trainee, claimed_by, claimed_at, tries FROM uploads "


# -- one upload ------------------------------------------------------------------------------------


def find_by_key(conn: sqlite3.Connection, key: str) -> Any | None:
    """The upload filed with idempotency key ``key`` (every column), or None."""
    return conn.execute("SELECT * FROM uploads WHERE idem_key = ?", (key,)).fetchone()


def find(conn: sqlite3.Connection, upload_id: int) -> Any | None:
    """Upload ``upload_id`` (every column), or None."""
    return conn.execute("SELECT * FROM uploads WHERE id = ?", (upload_id,)).fetchone()


def read_by_key(store: RecordStore, key: str) -> dict | None:
    """The upload filed with idempotency key ``key``, as a dict, or None; outside a transaction."""
    rows = store.query("SELECT * FROM uploads WHERE idem_key = ?", (key,))
    return dict(rows[0]) if rows else None


def read(store: RecordStore, upload_id: int) -> dict | None:
    """Upload ``upload_id`` as a dict, or None; outside a transaction."""
    rows = store.query("SELECT * FROM uploads WHERE id = ?", (upload_id,))
    return dict(rows[0]) if rows else None


def insert(
    conn: sqlite3.Connection,
    *,
    key: str | None,
    body_hash: str,
    filed_by: str,
    class_name: str,
    trainee: str,
    received_at: str,
    identity: dict,
    claimed_json: str,
    recording: str,
    witnessed: bool,
) -> int:
    """A new upload, waiting to be scored; its id. ``identity``: the pack's ``name``, ``version``, ``hash``."""
    cur = conn.execute(
        """
        INSERT INTO uploads (idem_key, body_hash, filed_by, class_name, trainee, received_at, pack, pack_version,
            pack_hash, claimed, recording, state, witnessed)
        VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'scoring', ?)
        """,
        (
            key,
            body_hash,
            filed_by,
            class_name,
            trainee,
            received_at,
            identity["name"],
            identity["version"],
            identity["hash"],
            claimed_json,
            recording,
            1 if witnessed else 0,
        ),
    )
    return inserted_id(cur)


def state_and_class(conn: sqlite3.Connection, upload_id: int) -> Any | None:
    """``id``, ``state`` and ``class_name`` of upload ``upload_id``, or None."""
    return conn.execute("SELECT id, state, class_name FROM uploads WHERE id = ?", (upload_id,)).fetchone()


def claim_of(conn: sqlite3.Connection, upload_id: int) -> Any | None:
    """``state`` and ``claimed_by`` of upload ``upload_id``, or None."""
    return conn.execute("SELECT state, claimed_by FROM uploads WHERE id = ?", (upload_id,)).fetchone()


# -- claiming and scoring --------------------------------------------------------------------------


def waiting_heads(conn: sqlite3.Connection) -> list[Any]:
    """Each trainee's oldest upload waiting and unclaimed (``id, class_name, trainee, claimed_by,
    claimed_at, tries``)."""
    return list(
        conn.execute(
            _CANDIDATE + "WHERE id IN "
            "(SELECT MIN(id) FROM uploads WHERE state = 'scoring' AND claimed_by IS NULL GROUP BY class_name, trainee)"
        )
    )


def claimed_waiting(conn: sqlite3.Connection, limit: int) -> list[Any]:
    """Up to ``limit`` claimed uploads not scored yet, oldest first (the columns of ``waiting_heads``)."""
    return list(
        conn.execute(_CANDIDATE + f"WHERE state = 'scoring' AND claimed_by IS NOT NULL ORDER BY id LIMIT {int(limit)}")
    )


def last_claimed_at(conn: sqlite3.Connection, class_name: str, trainee: str) -> float | None:
    """When the trainee last had an upload claimed; None when never."""
    return conn.execute(
        "SELECT MAX(claimed_at) FROM uploads WHERE class_name = ? AND trainee = ?", (class_name, trainee)
    ).fetchone()[0]


def mark_claimed(conn: sqlite3.Connection, upload_id: int, worker: str, now: float) -> None:
    """``worker`` claims the upload at ``now``; its claims are counted (``tries``)."""
    conn.execute(
        "UPDATE uploads SET claimed_by = ?, claimed_at = ?, tries = tries + 1 WHERE id = ?", (worker, now, upload_id)
    )


def renew_claim(conn: sqlite3.Connection, upload_id: int, worker: str, now: float) -> bool:
    """Move the claim's time to ``now`` if the upload still waits and is still ``worker``'s; whether it was."""
    return (
        conn.execute(
            "UPDATE uploads SET claimed_at = ? WHERE id = ? AND claimed_by = ? AND state = 'scoring'",
            (now, upload_id, worker),
        ).rowcount
        == 1
    )


def release_claim(conn: sqlite3.Connection, upload_id: int) -> None:
    """Free the upload's claim so that another scorer takes it (its count of claims stays)."""
    conn.execute("UPDATE uploads SET claimed_by = NULL WHERE id = ?", (upload_id,))


def mark_refused(conn: sqlite3.Connection, upload_id: int, error: str, at: str) -> None:
    """The upload is refused at ``at``; ``error`` says why."""
    conn.execute("UPDATE uploads SET state = 'refused', error = ?, scored_at = ? WHERE id = ?", (error, at, upload_id))


def mark_scored(conn: sqlite3.Connection, upload_id: int, attempt_id: int, at: str) -> None:
    """The upload became attempt ``attempt_id`` at ``at``; its recording is dropped (the attempt keeps it)."""
    conn.execute(
        "UPDATE uploads SET state = 'scored', attempt_id = ?, scored_at = ?, recording = '' WHERE id = ?",
        (attempt_id, at, upload_id),
    )


# -- listings --------------------------------------------------------------------------------------


def count_before_waiting(store: RecordStore, class_name: str, trainee: str, upload_id: int) -> int:
    """The trainee's stored attempts plus their uploads still waiting up to ``upload_id``, in one statement
    (so an upload scored meanwhile is counted once)."""
    rows = store.query(
        f"SELECT (SELECT COUNT(*) {_TRAINEE_ATTEMPTS}) + (SELECT COUNT(*) FROM uploads WHERE state = 'scoring' "
        "AND class_name = ? AND trainee = ? AND id <= ?)",
        (class_name, trainee, class_name, trainee, upload_id),
    )
    return int(rows[0][0])


def count_up_to_attempt(store: RecordStore, class_name: str, trainee: str, attempt_id: int) -> int:
    """The trainee's attempts made before attempt ``attempt_id`` (by time, then id), it included."""
    rows = store.query(
        f"SELECT COUNT(*) {_TRAINEE_ATTEMPTS} AND (a.created_at < (SELECT created_at FROM attempts WHERE id = ?) "
        "OR (a.created_at = (SELECT created_at FROM attempts WHERE id = ?) AND a.id <= ?))",
        (class_name, trainee, attempt_id, attempt_id, attempt_id),
    )
    return int(rows[0][0])


def not_scored(store: RecordStore, classes: list[str], trainee: str | None) -> list[dict]:
    """Uploads of these classes (and of ``trainee`` when given) waiting or refused, oldest first."""
    marks = ", ".join("?" for _ in classes)
    rows = store.query(
        "SELECT id, class_name, trainee, received_at, pack, state, error, filed_by FROM uploads "
        f"WHERE state != 'scored' AND class_name IN ({marks}) AND (? IS NULL OR trainee = ?) ORDER BY id",
        (*classes, trainee, trainee),
    )
    return [dict(r) for r in rows]


def ids_done(store: RecordStore, class_name: str) -> list[int]:
    """The ids of the class's uploads no longer waiting (scored or refused)."""
    return [
        int(r[0])
        for r in store.query("SELECT id FROM uploads WHERE class_name = ? AND state != 'scoring'", (class_name,))
    ]


def outcomes(store: RecordStore, class_name: str) -> list[Any]:
    """``id``, ``state``, ``attempt_id`` and ``error`` of each of the class's uploads."""
    return store.query("SELECT id, state, attempt_id, error FROM uploads WHERE class_name = ?", (class_name,))


def listing(store: RecordStore, state: str) -> list[dict]:
    """Uploads ``waiting`` (not scored yet), ``refused`` or ``all``, oldest first, with their recording's length."""
    rows = store.query(f"SELECT {_LISTED} FROM uploads WHERE {_LISTING_WHERE[state]} ORDER BY id")
    return [dict(r) for r in rows]
