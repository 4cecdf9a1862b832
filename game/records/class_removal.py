"""Removing a class whole from a records database: its uploads, its accounts and the class itself.

A benchmark of the records server files its uploads under a class of its own and removes it afterwards
(``chainsim.tools.bench.records``), so a database it ran against keeps nothing of it. The class's
trainees, attempts and their recordings go with the class (``ON DELETE CASCADE``); uploads and accounts
name it by text, so they are removed by name. Each function runs inside the caller's transaction
(``RecordStore.transaction()``), so the removal is one transaction.
"""

from __future__ import annotations

import sqlite3


def delete_uploads(conn: sqlite3.Connection, class_name: str) -> None:
    """Every upload filed under ``class_name``, whatever its state."""
    conn.execute("DELETE FROM uploads WHERE class_name = ?", (class_name,))


def delete_users_named_like(conn: sqlite3.Connection, pattern: str) -> None:
    """Every account whose name matches the SQL ``LIKE`` pattern ``pattern``."""
    conn.execute("DELETE FROM users WHERE name LIKE ?", (pattern,))


def delete_class(conn: sqlite3.Connection, class_name: str) -> None:
    """The class ``class_name``, with its trainees and their attempts."""
    conn.execute("DELETE FROM classes WHERE name = ?", (class_name,))
