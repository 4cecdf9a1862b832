"""A procedure's words live in its folder: no module outside systems/procedures/ names one.

The needle procedure marks landmarks and aims at a foramen; the cutting procedure holds forceps and
scissors. The rest of the house (the ECS kernel, the engine, the tissue, view and motion features, the
shell and the research tools) stores and shows what a procedure or a pack declares, by the names the
declarations give, so it never names those things itself: not in code, not in a docstring or comment.
The pack-building code (game/packbuild/) turns one procedure's sources into its pack and is excluded
with the procedure folders.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("components", "systems", "game", "tools")
EXEMPT = (ROOT / "systems" / "procedures", ROOT / "game" / "packbuild")
WORDS = re.compile(r"forceps|landmark|foramen|foramina|scissors", re.IGNORECASE)


def _modules() -> list[Path]:
    out = []
    for folder in SCANNED:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if not any(path.is_relative_to(e) for e in EXEMPT):
                out.append(path)
    return out


def test_the_scan_sees_the_house():
    """The scan reads the shell, the kernel and the features, and skips exactly the procedure folders."""
    found = {p.relative_to(ROOT).as_posix() for p in _modules()}
    assert {
        "components/app.py",
        "game/records/store.py",
        "game/server/dashboard.py",
        "systems/view/picking.py",
    } <= found
    assert not any(f.startswith(("systems/procedures/", "game/packbuild/")) for f in found)
    # the words are there to find: the needle procedure's own folder names them
    assert WORDS.search((ROOT / "systems" / "procedures" / "needle" / "records.py").read_text(encoding="utf-8"))


def test_no_module_outside_the_procedures_names_a_procedures_words():
    hits = []
    for path in _modules():
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            m = WORDS.search(line)
            if m:
                hits.append(f"{path.relative_to(ROOT).as_posix()}:{n}: {m.group(0)!r} in {line.strip()[:100]}")
    assert not hits, "a procedure's words outside systems/procedures/ (move them into its folder):\n" + "\n".join(hits)
