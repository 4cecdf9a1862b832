"""Blinded rating's tables: ``rating_sets``, ``rating_items``, ``raters`` and ``ratings``.

``chainsim.game.study.rating`` decides what a rating set holds and who may rate what; the statements
that keep it are here. A set has coded items (one attempt each) and raters (known by the hash of
their secret token); a rating is one rater's marks of one item, its ``total`` their sum.

Functions taking ``conn`` run inside the caller's transaction (``RecordStore.transaction()``), so a
set is made, or a rating replaced, whole; those taking ``store`` read outside one.
"""

from __future__ import annotations

import sqlite3
from typing import Any

from chainsim.game.records.backend import inserted_id
from chainsim.game.records.store import RecordStore

# -- inside a transaction --------------------------------------------------------------------------


def set_exists(conn: sqlite3.Connection, name: str) -> bool:
    """Whether a rating set is named ``name``."""
    return bool(conn.execute("SELECT 1 FROM rating_sets WHERE name = ?", (name,)).fetchone())


def attempt_exists(conn: sqlite3.Connection, attempt_id: int) -> bool:
    """Whether attempt ``attempt_id`` is stored."""
    return conn.execute("SELECT 1 FROM attempts WHERE id = ?", (attempt_id,)).fetchone() is not None


def has_recording(conn: sqlite3.Connection, attempt_id: int) -> bool:
    """Whether attempt ``attempt_id`` keeps its recording (so raters can see it replayed)."""
    return conn.execute("SELECT 1 FROM attempt_recordings WHERE attempt_id = ?", (attempt_id,)).fetchone() is not None


def insert_set(conn: sqlite3.Connection, name: str, created_by: str, created_at: str, form_json: str) -> int:
    """A new rating set with its form (JSON); its id."""
    cur = conn.execute(
        "INSERT INTO rating_sets (name, created_by, created_at, form) VALUES (?, ?, ?, ?)",
        (name, created_by, created_at, form_json),
    )
    return inserted_id(cur)


def insert_item(conn: sqlite3.Connection, set_id: int, code: str, attempt_id: int) -> None:
    """Attempt ``attempt_id`` joins the set under ``code``."""
    conn.execute("INSERT INTO rating_items (set_id, code, attempt_id) VALUES (?, ?, ?)", (set_id, code, attempt_id))


def insert_rater(conn: sqlite3.Connection, set_id: int, name: str, token_hash: str) -> None:
    """Rater ``name`` joins the set, known by the hash of their secret token."""
    conn.execute("INSERT INTO raters (set_id, name, token_hash) VALUES (?, ?, ?)", (set_id, name, token_hash))


def item_id(conn: sqlite3.Connection, set_id: int, code: str) -> int | None:
    """The id of the set's item coded ``code``, or None."""
    row = conn.execute("SELECT id FROM rating_items WHERE set_id = ? AND code = ?", (set_id, code)).fetchone()
    return None if row is None else row[0]


def replace_rating(
    conn: sqlite3.Connection, item: int, rater_id: int, scores_json: str, total: float, rated_at: str
) -> None:
    """The rater's marks of the item, replacing any given before."""
    conn.execute("DELETE FROM ratings WHERE item_id = ? AND rater_id = ?", (item, rater_id))
    conn.execute(
        "INSERT INTO ratings (item_id, rater_id, scores, total, rated_at) VALUES (?, ?, ?, ?, ?)",
        (item, rater_id, scores_json, total, rated_at),
    )


# -- reads -----------------------------------------------------------------------------------------


def rater_by_token_hash(store: RecordStore, token_hash: str) -> Any | None:
    """The rater and their set (``r.id, r.name, s.id, s.name, s.form``, by index) whose token hashes to
    ``token_hash``, or None."""
    rows = store.query(
        "SELECT r.id, r.name, s.id, s.name, s.form FROM raters r JOIN rating_sets s ON s.id = r.set_id "
        "WHERE r.token_hash = ?",
        (token_hash,),
    )
    return rows[0] if rows else None


def rater_items(store: RecordStore, rater_id: int, set_id: int) -> list[tuple[Any, Any]]:
    """``(code, total)`` of each item of the set, by code; ``total`` is None where the rater gave none."""
    rows = store.query(
        "SELECT i.code, g.total FROM rating_items i LEFT JOIN ratings g ON g.item_id = i.id AND g.rater_id = ? "
        "WHERE i.set_id = ? ORDER BY i.code",
        (rater_id, set_id),
    )
    return [(code, total) for code, total in rows]


def item_attempt(store: RecordStore, set_id: int, code: str) -> int | None:
    """The attempt coded ``code`` in the set, or None."""
    rows = store.query("SELECT attempt_id FROM rating_items WHERE set_id = ? AND code = ?", (set_id, code))
    return int(rows[0][0]) if rows else None


def set_id_named(store: RecordStore, name: str) -> int | None:
    """The id of the rating set named ``name``, or None."""
    sets = store.query("SELECT id FROM rating_sets WHERE name = ?", (name,))
    return sets[0][0] if sets else None


def set_names(store: RecordStore) -> list[str]:
    """Every rating set's name, in order."""
    return [r[0] for r in store.query("SELECT name FROM rating_sets ORDER BY name")]


def set_raters(store: RecordStore, set_id: int) -> list[tuple[int, str]]:
    """``(id, name)`` of the set's raters, by name."""
    return [
        (int(i), str(n))
        for i, n in store.query("SELECT id, name FROM raters WHERE set_id = ? ORDER BY name", (set_id,))
    ]


def set_items(store: RecordStore, set_id: int) -> list[tuple[Any, Any, Any]]:
    """``(id, code, attempt_id)`` of the set's items, by attempt."""
    return [
        (i, code, attempt)
        for i, code, attempt in store.query(
            "SELECT id, code, attempt_id FROM rating_items WHERE set_id = ? ORDER BY attempt_id", (set_id,)
        )
    ]


def item_totals(store: RecordStore, item: int) -> dict[Any, Any]:
    """Each rater's score of the item: ``{rater_id: total}``."""
    return dict(store.query("SELECT rater_id, total FROM ratings WHERE item_id = ?", (item,)))
