"""Every SQL statement of the program lives in ``game/records/``, the records feature.

The records database's tables are one feature's: its schema, its migrations and every statement that
reads or writes it are kept together, so a change of a table is made and reviewed in one folder and
both backends (SQLite, PostgreSQL through ``game/records/backend.py``) are served by the same text.
The other features call named functions of ``game/records``. This scan reads the string constants
(f-strings included) of every module of the program outside that folder (tests are not scanned),
with ``ast`` so that comments are not read, and fails on text shaped like a statement: SQL words in
capitals, as the program writes them, followed by a table's name (prose in docstrings has them in
lower case).
"""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("components", "systems", "game", "tools")
RECORDS = ROOT / "game" / "records"

#: the shapes of a statement
STATEMENT = re.compile(
    r"\bSELECT\s+(?:DISTINCT\s+)?[\w.*,()\s]+?\s+FROM\s+\w+"
    r"|\bINSERT\s+INTO\s+\w+"
    r"|\bUPDATE\s+\w+\s+SET\b"
    r"|\bDELETE\s+FROM\s+\w+"
    r"|\bCREATE\s+(?:TABLE|INDEX|UNIQUE\s+INDEX)\b"
    # a statement built in pieces: its FROM clause alone
    r"|\bFROM\s+\w+(?:\s+\w+)?\s+(?:WHERE|JOIN|LEFT\s+JOIN|ORDER\s+BY|GROUP\s+BY)\b",
)


def sql_in(source: str) -> list[str]:
    """The string constants (f-string parts included) of ``source`` that hold statement text."""
    found = []
    tree = ast.parse(source)
    parts = {id(v) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for v in node.values}
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):  # an f-string: its text with each value as {}
            text = "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in parts:
            text = node.value
        else:
            continue
        if STATEMENT.search(text):
            found.append(text.strip().splitlines()[0][:80])
    return found


def outside_records() -> list[Path]:
    return [
        path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if RECORDS not in path.parents and ".venv" not in path.parts
    ]


def test_the_scan_finds_statements_and_passes_prose():
    code = (
        'q = "SELECT id, name FROM classes WHERE id = ?"\n'
        'w = f"UPDATE uploads SET state = {s!r}"\n'
        'd = "DELETE FROM outbox WHERE id = ?"\n'
        'f = "FROM attempts a JOIN trainees t ON a.trainee_id = t.id "\n'
        "c = 'CREATE TABLE t (x INTEGER)'\n"
        "i = 'INSERT INTO ratings (item_id) VALUES (?)'\n"
        '"""Select the oldest upload from the queue; insert into it later; update the row, then set it."""\n'
    )
    assert len(sql_in(code)) == 6
    assert sql_in('x = "choose what to select from the list"') == []


def test_no_sql_outside_the_records_feature():
    offenders = {
        str(path.relative_to(ROOT)): found for path in outside_records() if (found := sql_in(path.read_text()))
    }
    assert offenders == {}, f"SQL statements outside game/records/ (move them into a records module): {offenders}"
