"""Study scenes on structured tetrahedral meshes (chainsim.systems.engine.meshgen.tet_grid): a block with a fixed base
pulled up at a top patch, a thin sheet with a fixed edge pulled at a corner (the grip-and-pull task of
thesis 4.5.2) and a cantilever with a fixed end whose tip is pulled down.

Each scene fixes one set of nodes, grabs a small patch and imposes displacement `strain * length`
on it along `direction`; the patch is defined in physical units so that every resolution of a
scene poses the same problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from chainsim.systems.engine.meshgen import tet_grid


@dataclass
class Scene:
    name: str
    shape: tuple[int, int, int]  # grid nodes per axis
    spacing: float
    pos: np.ndarray
    tets: np.ndarray
    links: np.ndarray
    fixed: np.ndarray  # node ids held at rest
    grabbed: np.ndarray  # node ids moved by the imposed displacement
    direction: np.ndarray  # unit vector of the pull
    length: float  # displacement = strain * length

    @property
    def n_nodes(self) -> int:
        return len(self.pos)

    @property
    def constrained(self) -> np.ndarray:
        return np.unique(np.concatenate([self.fixed, self.grabbed]))

    def constrained_disp(self, strain: float) -> np.ndarray:
        """Prescribed displacements of `constrained` (np.unique order): zero on fixed nodes."""
        c = self.constrained
        d = np.zeros((len(c), 3))
        d[np.isin(c, self.grabbed)] = strain * self.length * self.direction
        return d

    def grab_disp(self, strain: float) -> np.ndarray:
        return np.tile(strain * self.length * self.direction, (len(self.grabbed), 1))

    def interpolate(self, u: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Trilinear interpolation of a nodal field of this (structured) mesh at `points`."""
        nx, ny, nz = self.shape
        axes = [np.arange(m) * self.spacing for m in (nx, ny, nz)]
        grid = u.reshape(nz, ny, nx, 3).transpose(2, 1, 0, 3)
        out = np.empty((len(points), 3))
        pts = np.clip(points, 0.0, [a[-1] for a in axes])
        for c in range(3):
            out[:, c] = RegularGridInterpolator(axes, grid[..., c])(pts)
        return out


def _make(name, shape, spacing, fixed_mask, grab_mask, direction, length):
    pos, tets, links = tet_grid(*shape, spacing=spacing)
    fixed = np.flatnonzero(fixed_mask(pos))
    grabbed = np.flatnonzero(grab_mask(pos))
    if len(grabbed) == 0:
        raise ValueError(f"scene {name}: grab patch holds no node at shape {shape}")
    d = np.asarray(direction, dtype=np.float64)
    return Scene(name, tuple(shape), spacing, pos, tets, links, fixed, grabbed, d / np.linalg.norm(d), length)


def block(n: int) -> Scene:
    """Unit cube, n^3 nodes; base z=0 fixed; top nodes within 0.2 of the top centre pulled up."""
    h = 1.0 / (n - 1)
    eps = 1e-9
    return _make(
        "block",
        (n, n, n),
        h,
        lambda p: p[:, 2] < eps,
        lambda p: (p[:, 2] > 1 - eps) & (np.hypot(p[:, 0] - 0.5, p[:, 1] - 0.5) <= 0.2 + eps),
        (0, 0, 1),
        1.0,
    )


def sheet(n: int) -> Scene:
    """Unit square slab one element thick (n x n x 2 nodes); edge y=0 fixed; the corner patch at
    (1, 1) (radius 0.1, through the thickness) pulled in-plane away from the fixed edge."""
    h = 1.0 / (n - 1)
    eps = 1e-9
    return _make(
        "sheet",
        (n, n, 2),
        h,
        lambda p: p[:, 1] < eps,
        lambda p: np.hypot(p[:, 0] - 1.0, p[:, 1] - 1.0) <= max(0.1, 1.01 * h) + eps,
        (0, 1, 0),
        1.0,
    )


def cantilever(n: int) -> Scene:
    """Beam 1 x 0.2 x 0.2 with n nodes across the section; end x=0 fixed; tip face pulled down."""
    h = 0.2 / (n - 1)
    eps = 1e-9
    nx = 5 * (n - 1) + 1
    return _make("cantilever", (nx, n, n), h, lambda p: p[:, 0] < eps, lambda p: p[:, 0] > 1.0 - eps, (0, 0, -1), 1.0)


SCENES = {"block": block, "sheet": sheet, "cantilever": cantilever}

# resolution parameter per scene, roughly 10^3, 10^4, 10^5 nodes
RESOLUTIONS = {
    "block": [10, 22, 46],
    "sheet": [22, 71, 224],
    "cantilever": [7, 13, 28],
}
QUICK_RESOLUTIONS = {
    "block": [8, 12],
    "sheet": [16, 30],
    "cantilever": [5, 8],
}
