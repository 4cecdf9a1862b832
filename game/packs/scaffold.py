"""Pack scaffolding: `chainsim new-pack NAME --template empty|tissue|needle` writes a new pack folder a
modder edits from there (no Python needed).

The templates are data: folders under `assets/templates/` (chainsim.assets), copied whole with the
placeholders `"__NAME__"` and `"__TITLE__"` in pack.toml replaced by TOML strings (so any title stays
valid TOML) and `__TITLE__` in the docs replaced by the title. Each template validates, runs headless
and does what its own step text says (tests/unit/test_new_pack.py); the `needle` template builds on
the built-in prp pack through pack dependencies (chainsim.game.packs.requires).
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

import tomli_w

from chainsim.assets import ASSETS_DIR
from chainsim.systems.engine.errors import UserError

TEMPLATES_DIR = ASSETS_DIR / "templates"
#: template name -> what it gives (the `--template` help)
TEMPLATES = {
    "tissue": "a soft block to pull with a button or the mouse (the default)",
    "needle": "a needle procedure on the prp pack's head: points to mark, aiming, insertion, assessment",
    "empty": "one box in a view you can turn: the least a pack needs",
}
DEFAULT_TEMPLATE = "tissue"


def _toml_string(text: str) -> str:
    """`text` as a TOML basic string, quotes and escapes included (tomli-w writes it)."""
    return tomli_w.dumps({"v": text}).split("=", 1)[1].strip()


def create(name: str, parent: Path, title: str | None = None, template: str = DEFAULT_TEMPLATE) -> Path:
    """Write the pack folder `parent/name` from `template`; built in a temporary folder and renamed, so
    a failure leaves nothing behind."""
    if not re.match(r"^[A-Za-z0-9][A-Za-z0-9_-]*$", name):
        raise UserError(f"pack name '{name}' must use letters, digits, - and _ only")
    if template not in TEMPLATES:
        raise UserError(f"--template {template}: expected one of {', '.join(TEMPLATES)}")
    title = title if title is not None else name.replace("-", " ").replace("_", " ").title()
    if any(ord(c) < 32 for c in title) or len(title) > 200:
        raise UserError("--title: at most 200 characters and no control characters")
    root = Path(parent) / name
    if root.exists():
        raise UserError(f"{root} already exists; choose another name or folder")
    # root ignores permission bits, so the check is made both ways: access first, then any OSError
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"--dir {parent}: cannot write in this folder (read-only?); choose another with --dir")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=parent))
    except OSError as e:
        raise UserError(f"--dir {parent}: cannot write in this folder ({e.strerror or e}); choose another") from None
    try:
        shutil.copytree(TEMPLATES_DIR / template, tmp, dirs_exist_ok=True)
        for f in (tmp / "meshes",):
            f.mkdir(exist_ok=True)  # where the pack's own mesh files go
        manifest = tmp / "pack.toml"
        text = manifest.read_text(encoding="utf-8")
        text = text.replace('"__NAME__"', _toml_string(name)).replace('"__TITLE__"', _toml_string(title))
        # the header comment is plain text, not a TOML string
        manifest.write_text(text.replace("__TITLE__", title.replace("\n", " ")), encoding="utf-8")
        for doc in (tmp / "docs").glob("*.md"):
            doc.write_text(doc.read_text(encoding="utf-8").replace("__TITLE__", title), encoding="utf-8")
        tmp.rename(root)
    except OSError as e:  # a full disk or a folder made read-only meanwhile: nothing is left behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise UserError(f"cannot create {root}: {e.strerror or e}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return root
