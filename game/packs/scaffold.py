"""Pack scaffolding: writes a new, valid pack folder a modder edits from there (no Python needed)."""

from __future__ import annotations

import re
from pathlib import Path

from chainsim.engine.errors import UserError

PACK_TOML = """# {title}: a chainsim asset pack. Reference: `chainsim docs components`.
[pack]
name = "{name}"
format = 1
title = "{title}"
version = "0.1.0"
description = "Describe the procedure or demo here."
license = "CC-BY-4.0"

[settings]
steps = 600

[meshes.body]
primitive = "tet_block"          # or: path = "meshes/body.ply" with units = "mm"
extents = [60.0, 40.0, 20.0]
resolution = [6.0, 4.0, 2.0]
role = "deformable"

[meshes.probe]
primitive = "sphere"
radius = 3.0

[materials.tissue]
color = [0.85, 0.55, 0.5, 1.0]
alpha_min = 0.8
alpha_max = 1.3
beta = 0.2
relax = 2

[materials.steel]
color = [0.75, 0.77, 0.8, 1.0]

[entities.body.mesh]
mesh = "body"
material = "tissue"

[entities.body.deformable]
source = "volume"

[entities.probe.transform]
position = [0.0, 0.0, 40.0]
[entities.probe.mesh]
mesh = "probe"
material = "steel"
pickable = false
[entities.probe.scripted_motion]
waypoints = [0.0, 0.0, 40.0,  30.0, 0.0, 40.0]
speed = 20.0

[scenes.main]
description = "The body and a moving probe."
layout = "main"

[layouts.main]
[[layouts.main.viewports]]
name = "view"
kind = "orbit"
rect = [0.0, 0.0, 0.75, 1.0]
distance = 200.0
yaw = 30.0
pitch = 25.0

[[layouts.main.viewports]]
name = "panel"
kind = "panel"
rect = [0.75, 0.0, 0.25, 1.0]
title = "Controls"

[[steps]]
id = "explore"
title = "Explore"
instruction = "Drag to orbit; click the body to pull it."
docs = "readme"

[docs.readme]
title = "About"
path = "docs/readme.md"
"""


def create(name: str, parent: Path, title: str | None = None) -> Path:
    if not re.match(r"^[A-Za-z0-9][A-Za-z0-9_-]*$", name):
        raise UserError(f"pack name '{name}' must use letters, digits, - and _ only")
    root = Path(parent) / name
    if root.exists():
        raise UserError(f"{root} already exists; choose another name or folder")
    (root / "docs").mkdir(parents=True)
    (root / "meshes").mkdir()
    (root / "scripts").mkdir()
    (root / "pack.toml").write_text(
        PACK_TOML.format(name=name, title=title or name.replace("-", " ").title()), encoding="utf-8"
    )
    (root / "docs" / "readme.md").write_text(
        f"# {title or name}\n\nWhat this pack teaches, and how to use it.\n", encoding="utf-8"
    )
    return root
