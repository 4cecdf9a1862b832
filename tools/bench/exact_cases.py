"""The pulls the exact-limit benchmark and its tests measure (docs/chainmail.md, "Exact limits").

    skin_case(fixed_rim, volume)   the prp face (assets/prp/meshes/skin.ply, 4426 elements; or filled with
                                   tetrahedra): the bottom rim (every element within 3 mm of the lowest
                                   point) fixed or not, one cheek element (the nearest to the left ideal
                                   entry point, where the needle enters) pulled along the outward surface normal
    block_case()                   a 21^3 tetrahedral block (9261 elements), its base fixed, a top-centre
                                   element pulled up and sideways
    whole_body_cases(max_elements) tet blocks of 12^3, 38^3 and 100^3 elements (1.7k, 55k, 1M), base fixed,
                                   the top-centre element pulled 1.5 block heights: every element moves

All with the thesis's medium material (6.2.1: alpha 0.8 / 1.2) and beta 0.1.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.meshimport import load_mesh
from chainsim.tools.bench.meshes import fast_tet_grid

SKIN = Path(__file__).resolve().parents[2] / "assets" / "prp" / "meshes" / "skin.ply"
#: the left ideal entry point of assets/prp/anatomy.toml (mm, head frame): the cheek the needle enters
CHEEK = np.array([-47.493, 52.487, -48.654])
RIM_MM = 3.0
PULLS_MM = (8.0, 22.0, 46.0)
MATERIAL = (0.8, 1.2, 0.1)


class Case(NamedTuple):
    name: str
    rest: np.ndarray  # (N, 3) float64
    links: np.ndarray  # (M, 2)
    fixed: np.ndarray | None  # bool (N,)
    grab: int
    direction: np.ndarray  # unit pull direction
    pulls: tuple  # pull lengths (mm)


def _outward_normal(verts: np.ndarray, tris: np.ndarray, v: int) -> np.ndarray:
    fn = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    nrm = fn[np.any(tris == v, axis=1)].sum(axis=0)
    nrm /= np.linalg.norm(nrm)
    # outward: away from the centroid of the closed face surface
    return nrm if np.dot(nrm, verts[v] - verts.mean(axis=0)) >= 0 else -nrm


def skin_case(fixed_rim: bool = True, volume: bool = False) -> Case:
    surf = load_mesh(SKIN)
    verts = np.ascontiguousarray(surf.vertices, dtype=np.float64)
    tris = np.asarray(surf.triangles, dtype=np.int64)
    v = int(np.argmin(np.sum((verts - CHEEK) ** 2, axis=1)))
    direction = _outward_normal(verts, tris, v)
    if volume:
        vol = load_mesh(SKIN, kind="volume")
        assert vol.tets is not None  # a volume mesh has its tetrahedra
        rest = np.ascontiguousarray(vol.vertices, dtype=np.float64)
        links = meshgen.links_from_cells(vol.tets)
        grab = int(np.argmin(np.sum((rest - verts[v]) ** 2, axis=1)))
    else:
        rest, links, grab = verts, meshgen.links_from_polygons(tris), v
    fixed = rest[:, 2] <= rest[:, 2].min() + RIM_MM if fixed_rim else None
    name = f"skin {'volume' if volume else 'surface'}, {'rim fixed' if fixed_rim else 'nothing fixed'}"
    return Case(name, rest, links, fixed, grab, direction, PULLS_MM)


def block_case(side: int = 21) -> Case:
    rest, _, links = fast_tet_grid(side, side, side, spacing=2.0)
    fixed = rest[:, 2] <= 1e-9
    top = np.flatnonzero(rest[:, 2] >= rest[:, 2].max() - 1e-9)
    grab = int(top[np.argmin(np.sum((rest[top, :2] - rest[:, :2].mean(axis=0)) ** 2, axis=1))])
    direction = np.array([0.6, 0.0, 0.8])
    return Case(f"tet block {side}^3, base fixed", rest, links, fixed, grab, direction, PULLS_MM)


def cases(quick: bool = False) -> list[Case]:
    out = [skin_case(True), skin_case(False)]
    if not quick:
        out += [skin_case(True, volume=True), block_case()]
    return out


WHOLE_SIDES = (12, 38, 100)


def whole_body_cases(max_elements: float = 1e6) -> list[Case]:
    out = []
    for side in WHOLE_SIDES:
        if side**3 > max_elements:
            break
        c = block_case(side)
        height = 2.0 * (side - 1)
        out.append(c._replace(name=f"whole body: tet block {side}^3, base fixed", pulls=(1.5 * height,)))
    return out
