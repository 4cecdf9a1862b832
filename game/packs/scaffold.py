"""Pack scaffolding: writes a new, valid pack folder a modder edits from there (no Python needed)."""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import tomli_w

from chainsim.engine.errors import UserError


def manifest(name: str, title: str) -> dict:
    """The new pack's pack.toml as data (written by tomli-w, so any title stays valid TOML)."""
    return {
        "pack": {
            "name": name,
            "format": 1,
            "title": title,
            "version": "0.1.0",
            "description": "Describe the procedure or demo here.",
            "license": "CC-BY-4.0",
        },
        "settings": {"steps": 600},
        "meshes": {
            # or: path = "meshes/body.ply" with units = "mm"
            "body": {"primitive": "tet_block", "extents": [60.0, 40.0, 20.0], "resolution": [6.0, 4.0, 2.0]},
            "probe": {"primitive": "sphere", "radius": 3.0},
        },
        "materials": {
            "tissue": {"color": [0.85, 0.55, 0.5, 1.0], "alpha_min": 0.8, "alpha_max": 1.3, "beta": 0.2, "relax": 2},
            "steel": {"color": [0.75, 0.77, 0.8, 1.0]},
        },
        "entities": {
            "body": {
                "mesh": {"mesh": "body", "material": "tissue"},
                # drag = true: a mouse drag on the body pulls it, as the step below says
                "deformable": {"source": "volume", "drag": True},
            },
            "probe": {
                "transform": {"position": [0.0, 0.0, 40.0]},
                "mesh": {"mesh": "probe", "material": "steel", "pickable": False},
                "scripted_motion": {"waypoints": [0.0, 0.0, 40.0, 30.0, 0.0, 40.0], "speed": 20.0},
            },
        },
        "scenes": {"main": {"description": "The body and a moving probe.", "layout": "main"}},
        "layouts": {
            "main": {
                "viewports": [
                    {
                        "name": "view",
                        "kind": "orbit",
                        "rect": [0.0, 0.0, 0.75, 1.0],
                        "distance": 200.0,
                        "yaw": 30.0,
                        "pitch": 25.0,
                    },
                    {"name": "panel", "kind": "panel", "rect": [0.75, 0.0, 0.25, 1.0], "title": "Controls"},
                ]
            }
        },
        "steps": [
            {
                "id": "explore",
                "title": "Explore",
                "instruction": "Drag on the body to pull it; drag beside it to orbit.",
                "docs": "readme",
            }
        ],
        "docs": {"readme": {"title": "About", "path": "docs/readme.md"}},
    }


def create(name: str, parent: Path, title: str | None = None) -> Path:
    """Write the pack folder `parent/name`; built in a temporary folder and renamed, so a failure
    leaves nothing behind."""
    if not re.match(r"^[A-Za-z0-9][A-Za-z0-9_-]*$", name):
        raise UserError(f"pack name '{name}' must use letters, digits, - and _ only")
    title = title if title is not None else name.replace("-", " ").title()
    if any(ord(c) < 32 for c in title) or len(title) > 200:
        raise UserError("--title: at most 200 characters and no control characters")
    root = Path(parent) / name
    if root.exists():
        raise UserError(f"{root} already exists; choose another name or folder")
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=parent))
    try:
        (tmp / "docs").mkdir()
        (tmp / "meshes").mkdir()
        (tmp / "scripts").mkdir()
        header = f"# {title}: a chainsim asset pack. Reference: `chainsim docs components`.\n"
        (tmp / "pack.toml").write_text(header + tomli_w.dumps(manifest(name, title)), encoding="utf-8")
        (tmp / "docs" / "readme.md").write_text(
            f"# {title}\n\nWhat this pack teaches, and how to use it.\n", encoding="utf-8"
        )
        tmp.rename(root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return root
