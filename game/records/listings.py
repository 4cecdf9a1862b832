"""The records server's pages read classes, trainees and accounts through these lookups.

The dashboard and the class page (``chainsim.game.server``) decide who may see what; the statements
that find the rows they show (and the class's count of attempts the records benchmark checks) are kept
here, with the rest of the records database's SQL. Each reads outside a transaction, through
``RecordStore.query``, and returns plain dicts (or a single value).
"""

from __future__ import annotations

from typing import Any

from chainsim.game.records.store import RecordStore


def class_summaries(store: RecordStore, classes: list[str]) -> list[dict[str, Any]]:
    """``id``, ``name``, ``trainees`` and ``attempts`` (counts) of each of these classes, by name."""
    marks = ",".join("?" for _ in classes)
    rows = store.query(
        f"""
        SELECT c.id, c.name, COUNT(DISTINCT t.id) AS trainees, COUNT(a.id) AS attempts
        FROM classes c LEFT JOIN trainees t ON t.class_id = c.id LEFT JOIN attempts a ON a.trainee_id = t.id
        WHERE c.name IN ({marks}) GROUP BY c.id, c.name ORDER BY c.name
        """,
        tuple(classes),
    )
    return [dict(r) for r in rows]


def trainee_by_id(store: RecordStore, trainee_id: int) -> dict[str, Any] | None:
    """``id``, ``name``, ``class_id`` and ``class_name`` of trainee ``trainee_id``, or None."""
    rows = store.query(
        "SELECT t.id, t.name, c.id AS class_id, c.name AS class_name FROM trainees t "
        "JOIN classes c ON c.id = t.class_id WHERE t.id = ?",
        (trainee_id,),
    )
    return dict(rows[0]) if rows else None


def id_of_trainee(store: RecordStore, class_name: str, trainee: str) -> int | None:
    """The id of ``trainee`` of class ``class_name``, or None."""
    rows = store.query(
        "SELECT t.id FROM trainees t JOIN classes c ON c.id = t.class_id WHERE c.name = ? AND t.name = ?",
        (class_name, trainee),
    )
    return rows[0][0] if rows else None


def name_of_class(store: RecordStore, class_id: int) -> str | None:
    """The name of class ``class_id``, or None."""
    rows = store.query("SELECT id, name FROM classes WHERE id = ?", (class_id,))
    return rows[0]["name"] if rows else None


def class_trainees(store: RecordStore, class_id: int) -> list[dict[str, Any]]:
    """``id``, ``name`` and ``account`` (the trainee's user name, or None) of each trainee of the class, by name."""
    rows = store.query(
        "SELECT t.id, t.name, u.name AS account FROM trainees t LEFT JOIN users u ON u.trainee_id = t.id "
        "WHERE t.class_id = ? ORDER BY t.name",
        (class_id,),
    )
    return [dict(r) for r in rows]


def trainee_account(store: RecordStore, class_id: int, name: str) -> str | None:
    """The user name ``name`` when it is the account of a trainee of class ``class_id``, else None."""
    rows = store.query(
        "SELECT u.name FROM users u JOIN trainees t ON t.id = u.trainee_id WHERE t.class_id = ? AND u.name = ?",
        (class_id, name),
    )
    return rows[0][0] if rows else None


def class_attempt_count(store: RecordStore, class_name: str) -> int:
    """How many attempts the trainees of class ``class_name`` have stored."""
    return store.query(
        "SELECT COUNT(*) FROM attempts a JOIN trainees t ON t.id = a.trainee_id "
        "JOIN classes c ON c.id = t.class_id WHERE c.name = ?",
        (class_name,),
    )[0][0]
