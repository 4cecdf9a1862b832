"""Generates the layered tissue meshes of the cutting pack (thesis 4.5.2: two layers of soft tissue,
cut and teased apart), deterministically, as ASCII PLY files in assets/cutting/meshes/.

Each layer is a flat sheet in the x-y plane (z up, millimetres) meshed as a grid of quadrilaterals,
each split into two triangles along alternating diagonals so the sheet has no preferred shear
direction. Interior vertices are shifted by a small seeded in-plane jitter: the sheet is an
unstructured triangle mesh as Generalised ChainMail expects (5.2.1), and a cut path never runs
exactly along a grid line. Rim vertices keep their rim coordinate so the fixed edge is straight.

    python -m chainsim.game.packbuild.cutting.make_cutting_pack            # (re)write the meshes
    python -m chainsim.game.packbuild.cutting.make_cutting_pack --check    # exit 1 if the committed files differ
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chainsim.assets import ASSETS_DIR

logger = logging.getLogger(__name__)

PACK_DIR = ASSETS_DIR / "cutting"


@dataclass(frozen=True)
class Layer:
    name: str
    size: tuple[float, float]  # x, y extent in mm
    cells: tuple[int, int]  # quads along x, y
    z: float  # height of the sheet
    jitter: float  # max in-plane shift of interior vertices, as a fraction of the spacing
    seed: int


#: top layer (dura-like, coarser) and the layer underneath (finer), 2.5 mm apart
LAYERS = (
    Layer("dura", (80.0, 60.0), (40, 30), 0.0, 0.18, 4501),
    Layer("arachnoid", (80.0, 60.0), (48, 36), -2.5, 0.18, 4502),
)


def sheet(layer: Layer) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3), triangles (F, 3)) of one layer; vertex id = i + (nx + 1) * j."""
    cx, cy = layer.cells
    sx, sy = layer.size
    nx, ny = cx + 1, cy + 1
    hx, hy = sx / cx, sy / cy
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    i, j = i.ravel(), j.ravel()
    x = -sx / 2 + i * hx
    y = -sy / 2 + j * hy
    rng = np.random.default_rng(layer.seed)
    jx = rng.uniform(-1.0, 1.0, len(x)) * layer.jitter * hx
    jy = rng.uniform(-1.0, 1.0, len(y)) * layer.jitter * hy
    jx[(i == 0) | (i == cx)] = 0.0  # rim vertices stay on their rim line
    jy[(j == 0) | (j == cy)] = 0.0
    verts = np.column_stack([x + jx, y + jy, np.full(len(x), layer.z)])
    verts = np.round(verts, 4)  # what the file holds, so a reload gives the same numbers
    vid = lambda a, b: a + nx * b  # noqa: E731
    tris = []
    for b in range(cy):
        for a in range(cx):
            v00, v10, v11, v01 = vid(a, b), vid(a + 1, b), vid(a + 1, b + 1), vid(a, b + 1)
            if (a + b) % 2 == 0:  # alternate the diagonal, counter-clockwise seen from +z
                tris += [(v00, v10, v11), (v00, v11, v01)]
            else:
                tris += [(v00, v10, v01), (v10, v11, v01)]
    return verts, np.asarray(tris, dtype=np.int64)


def ply_text(verts: np.ndarray, tris: np.ndarray, comment: str) -> str:
    lines = [
        "ply",
        "format ascii 1.0",
        f"comment {comment}",
        f"element vertex {len(verts)}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(tris)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    lines += [f"{v[0]:.4f} {v[1]:.4f} {v[2]:.4f}" for v in verts]
    lines += [f"3 {t[0]} {t[1]} {t[2]}" for t in tris]
    return "\n".join(lines) + "\n"


def outputs() -> dict[Path, str]:
    out = {}
    for layer in LAYERS:
        v, t = sheet(layer)
        comment = (
            f"chainsim cutting pack: {layer.name}, {layer.size[0]:g} x {layer.size[1]:g} mm, "
            f"{layer.cells[0]} x {layer.cells[1]} quads, z = {layer.z:g} mm"
        )
        out[PACK_DIR / "meshes" / f"{layer.name}.ply"] = ply_text(v, t, comment)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare with the files on disk")
    args = ap.parse_args(argv)
    stale = []
    for path, text in outputs().items():
        current = path.read_text(encoding="utf-8") if path.exists() else None
        if current == text:
            continue
        stale.append(path)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            logger.info(f"wrote {path}")
    if args.check and stale:
        logger.warning("out of date: " + ", ".join(str(p) for p in stale))
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
