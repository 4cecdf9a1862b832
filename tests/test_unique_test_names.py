"""Every test module has a name no other test module has: pytest imports them by their file name (the
folders hold no __init__.py), so a second one of the same name stops the whole run at collection."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_no_two_test_modules_share_a_file_name():
    names = Counter(p.name for p in TESTS.rglob("test_*.py"))
    assert not [n for n, k in names.items() if k > 1]
    assert names["test_unique_test_names.py"] == 1  # this file is found: the walk covers the tree
