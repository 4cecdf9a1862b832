"""What one frame of an XPBD or projective-dynamics body costs on this machine's CPU, estimated when the
body is built, and the setting of the same model that fits a 60 Hz frame.

This module owns the per-unit costs of those two models here (`XPBD_*`, `PD_*`, with the command that
measured them), the estimates made from what a constructor knows (nodes, elements, the substeps the
rule asks for at a 60 Hz step, iterations, solver, CG steps and, for the direct solver, the size of the
sparse factor, estimated from the mesh's shape: `factor_entries`), and the one line a body puts in its
`notice` when its setting costs more than a frame (`xpbd_notice`, `projective_notice`).

An estimate is one thread's CPU time for a frame in which the body keeps moving (a pull that goes on),
so every iteration runs and every rotation is refined: a body that has settled stops early and costs
less. The first frame of a new grab also pays the direct solver's factorisation (0.4 s at 10k nodes of
the tissue block), which is not in the estimate; with numba's threads the CG steps' wall time is lower.

Checked against real frames with `python -m chainsim.tools.bench.framecost` (the 30 x 30 x 20 mm
tissue block, base fixed, a 6 mm patch on top pulled 0.2 mm further every frame, E = 3 kPa, nu = 0.45,
unit 1 mm; median CPU of 4 moving frames after one that pays the set-up, one numba thread; two runs,
load average 6-7 on this 2-core machine shared with other work), each body at its defaults and with
the setting its notice offers:

| nodes | body | estimate ms | measured ms | measured / estimate |
|---:|---|---:|---:|---:|
| 968 | xpbd, 12 substeps by the rule | 11.3 | 11.0-11.2 | 0.98-0.99 |
| 968 | projective, dynamic, direct, 10 iterations | 10.9 | 10.9-14.5 | 1.00-1.33 |
| 10,625 | xpbd, 28 substeps by the rule | 346 | 338-363 | 0.97-1.05 |
| 10,625 | xpbd, substeps=1 (offered) | 12.4 | 11.9-12.1 | 0.96-0.98 |
| 10,625 | projective, dynamic, direct, 10 iterations | 191 | 202-209 | 1.06-1.10 |
| 10,625 | projective, iterations=1, rotation_iterations=1 (offered) | 11.2 | 11.7-12.4 | 1.04-1.11 |
| 31,104 | xpbd, 40 substeps by the rule | 1512 | 1432-1507 | 0.95-1.00 |
| 31,104 | projective, dynamic, CG 20 (above 25k free nodes), 10 iterations | 549 | 527-534 | 0.96-0.97 |

Other shapes, one run: a 50 x 50 x 5 slab (12,500 nodes, also turned about two axes) and a 12 x 12 x 75
bar (10,800) at projective's defaults 1.15-1.19 (the factor estimate at work), XPBD by the rule 1.00;
a 100 x 100 sheet: projective 1.12, XPBD with 8 substeps 1.00. CG 6 with four rotation refinements
came out at 0.56-0.65 on them: the rotations of elements far from the pull converge before their
fourth refinement, so the estimate is the higher side there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

#: one 60 Hz frame, the step the app takes and the budget a body's frame should fit
FRAME_S = 1.0 / 60.0
FRAME_MS = 1e3 * FRAME_S

# Per-unit CPU costs in ms (one thread), fitted by non-negative least squares to the frames of
# `python -m chainsim.tools.bench.framecost --fit` (1k, 4k and 10k-node tissue blocks and a 10k-node
# sheet, each setting's median of 4 moving frames), 2026-12-01, load average 5-6 on this 2-core machine;
# measured / fitted 0.94-1.11 over XPBD's 33 settings, 0.87-1.21 over projective's 33.
#: XPBD: one sweep of one tetrahedron by constraint set (corotational refines its rotation twice a sweep)
XPBD_TET_MS = {"corotational": 2.21e-4, "neohookean": 1.08e-4, "stvk": 4.59e-4}
#: XPBD: one sweep of one distance constraint (surfaces: stretch and bending)
XPBD_PAIR_MS = 1.15e-5
#: XPBD: the per-node work of one substep (prediction, the velocity update)
XPBD_NODE_MS = 1.41e-5
#: projective: one local step of one tetrahedron, and each refinement of its rotation
PD_TET_MS = 1.21e-5
PD_ROTATION_MS = 4.73e-5
#: projective: one direct solve per entry of the sparse LU factor (three right-hand sides)
PD_FACTOR_MS = 1.68e-6
#: projective: one CG step per entry of the global matrix, and per free node
PD_CG_ENTRY_MS = 1.52e-6
PD_CG_NODE_MS = 5.45e-6
#: projective: the per-node work of one iteration (gathers, the right-hand side, the step size; a
#: membrane's local step too, which the fit could not tell apart from it: two triangles a node)
PD_NODE_MS = 1.60e-4

# The direct solver's factor (L + U entries per free node), fitted to the factors scipy's SuperLU makes
# of the free block (minimum degree on A + A^T) of box meshes with the base fixed, a <= b <= c the box's
# node counts along its sides: 13 solids from 6 x 6 x 4 to 100 x 10 x 9 and 29 x 29 x 18 (cubes, slabs,
# bars; within 0.76-1.39 of the fit; scipy 1.17.1's SuperLU fills slabs and bars 1.6-1.8 times as
# much as the version first fitted, whose constants were (1.32, 1.17, 0.75)) and 8 sheets from 10 x 9 to
# 1000 x 9 (within 0.84-1.21).
_FILL_3D = (3.45, 1.01, 0.66)  # c0 * a**p * b**q
_FILL_2D = (5.34, 0.455)  # c0 * a**p

#: CG steps a suggestion goes down to; fewer barely move the body between frames
MIN_CG_STEPS = 3


def box_sides(points: np.ndarray, dims: int) -> list[float]:
    """The node counts along the sides of a box with the points' extents and as many nodes, smallest
    first: the shape a mesh's factor grows with. `dims` is 3 for a volume, 2 for a sheet. The extents
    are those of the tighter of two boxes, the one along the axes and the one along the principal axes
    (a rotated slab is thin only along the latter; a cube's principal axes are any)."""
    n = len(points)
    if n < 2:
        return [1.0] * dims
    centred = points - points.mean(axis=0)
    principal = np.linalg.svd(centred, full_matrices=False)[2]
    boxes = [np.sort(np.ptp(centred @ axes.T, axis=0))[-dims:] for axes in (np.eye(points.shape[1]), principal)]
    ext = min(boxes, key=lambda e: float(np.prod(e)))
    ext = np.maximum(ext, 1e-9 * max(float(ext[-1]), 1e-300))
    # the spacing h with prod(ext / h + 1) = n: the count falls as h grows, so bisect on log h
    lo, hi = math.log(float(ext[-1])) - 30.0, math.log(float(ext[-1])) + 1.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if float(np.prod(ext / math.exp(mid) + 1.0)) > n:
            lo = mid
        else:
            hi = mid
    return [float(v) for v in ext / math.exp(hi) + 1.0]


def factor_entries(points: np.ndarray, surface: bool) -> float:
    """Estimated entries of the direct solver's L + U for a mesh whose free nodes are `points`."""
    if surface:
        c0, p = _FILL_2D
        a = box_sides(points, 2)[0]
        return len(points) * c0 * a**p
    c0, p, q = _FILL_3D
    a, b = box_sides(points, 3)[:2]
    return len(points) * c0 * a**p * b**q


@dataclass(frozen=True, slots=True)
class XPBDFrame:
    """What an XPBD body's frame is made of: its nodes, live tetrahedra (and their constraint set) and
    distance constraints, the substeps it takes a 60 Hz frame (`rule`: what the substep rule asks for;
    `by_rule`: whether it follows it) and iterations per substep."""

    nodes: int
    tets: int
    pairs: int
    constraints: str
    substeps: int
    rule: int
    by_rule: bool
    iterations: int

    def ms(self, substeps: int | None = None, iterations: int | None = None) -> float:
        """Estimated CPU ms of one frame, at the body's own substeps and iterations unless given."""
        s = self.substeps if substeps is None else substeps
        it = self.iterations if iterations is None else iterations
        sweep = self.tets * XPBD_TET_MS.get(self.constraints, 0.0) + self.pairs * XPBD_PAIR_MS
        return s * (it * sweep + self.nodes * XPBD_NODE_MS)

    def fits(self) -> dict[str, int] | None:
        """The settings to change for a frame within FRAME_MS ({} when it is already; None when even one
        substep of one iteration is over): one iteration at the same substeps if that does it, else the
        most substeps of one iteration that fit, at most the rule's."""
        if self.ms() <= FRAME_MS:
            return {}
        if self.iterations > 1 and self.ms(iterations=1) <= FRAME_MS:
            return {"iterations": 1}
        one = self.ms(1, 1)
        fits = min(int(FRAME_MS // one), self.rule) if one > 0.0 else self.rule
        if fits < 1:
            return None
        return {"substeps": fits} | ({"iterations": 1} if self.iterations > 1 else {})


def xpbd_notice(f: XPBDFrame) -> str:
    """One line when the frame costs more than a 60 Hz frame: about what it costs here, and the setting
    that fits with what that costs in accuracy (or that none does); else the empty string."""
    ms = f.ms()
    if ms <= FRAME_MS:
        return ""
    how = "by the rule" if f.by_rule else "as given"
    line = (
        f"xpbd: about {ms:.0f} ms of CPU a frame here ({f.substeps} substeps {how}, {f.iterations} "
        f"iteration{'s' if f.iterations > 1 else ''}, {f.nodes} nodes), more than a 60 Hz frame's "
        f"{FRAME_MS:.1f} ms; "
    )
    fit = f.fits()
    if not fit:
        return line + f"even 1 substep costs about {f.ms(1, 1):.0f} ms: only a coarser mesh fits"
    setting = ", ".join(f"{k}={v}" for k, v in fit.items())
    cost = f.ms(fit.get("substeps"), fit.get("iterations"))
    if fit.get("substeps", f.rule) >= f.rule:
        return line + f"{setting} fits (about {cost:.0f} ms)"
    return line + (
        f"{setting} fits (about {cost:.0f} ms) but, under the rule's {f.rule} substeps, settles 0.08-0.13 "
        "off where the rule's settle 0.02-0.08 (RMS over a lift, docs/choosing-a-model.md)"
    )


@dataclass(frozen=True, slots=True)
class ProjectiveFrame:
    """What a projective-dynamics body's frame is made of: free nodes, live elements (triangles when
    `surface`), entries of the global matrix's free block (one axis) and, for the direct solver, of its
    LU factor (`factor_entries`), and the settings that set the work."""

    free: int
    elements: int
    surface: bool
    dynamic: bool
    matrix_entries: int
    factor: float
    solver: str
    iterations: int
    cg_iterations: int
    rotation_iterations: int

    def ms(self, **setting: object) -> float:
        """Estimated CPU ms of one frame, with any of solver, iterations, cg_iterations and
        rotation_iterations changed."""
        f = replace(self, **setting)  # type: ignore[arg-type]
        local = 0.0 if f.surface else f.elements * (PD_TET_MS + f.rotation_iterations * PD_ROTATION_MS)
        if f.solver == "direct":
            solve = f.factor * PD_FACTOR_MS
        else:
            solve = f.cg_iterations * (f.matrix_entries * PD_CG_ENTRY_MS + f.free * PD_CG_NODE_MS)
        return f.iterations * (local + solve + f.free * PD_NODE_MS)

    def cheaper(self) -> list[dict]:
        """Settings that cost less, the nearest to the body's own first: fewer iterations of its solver,
        then one rotation refinement, then one iteration of CG with as many steps as fit (at most its
        own, or 20 coming from the direct solver)."""
        own = dict(iterations=self.iterations, rotation_iterations=self.rotation_iterations)
        out: list[dict] = [dict(own, iterations=k) for k in range(self.iterations - 1, 0, -1)]
        rotations = self.rotation_iterations if self.surface else 1  # membranes refine no rotation
        if rotations < self.rotation_iterations:
            out.append(dict(iterations=1, rotation_iterations=1))
        top = self.cg_iterations - 1 if self.solver == "cg" else max(self.cg_iterations, 20)
        steps = range(top, MIN_CG_STEPS - 1, -1)
        out += [dict(solver="cg", iterations=1, rotation_iterations=rotations, cg_iterations=s) for s in steps]
        return out

    def fits(self) -> dict | None:
        """The settings to change for a frame within FRAME_MS, the nearest to the body's own
        (`cheaper`): {} when it is already, None when none of them does."""
        if self.ms() <= FRAME_MS:
            return {}
        for setting in self.cheaper():
            if self.ms(**setting) <= FRAME_MS:
                return {k: v for k, v in setting.items() if getattr(self, k) != v}
        return None


def projective_notice(f: ProjectiveFrame) -> str:
    """One line when the frame costs more than a 60 Hz frame: about what it costs here and the nearest
    setting that fits (or that none does); else the empty string."""
    ms = f.ms()
    if ms <= FRAME_MS:
        return ""
    kind = "dynamic" if f.dynamic else "statics"
    solver = f"CG {f.cg_iterations}" if f.solver == "cg" else "direct"
    line = (
        f"projective: about {ms:.0f} ms of CPU a frame here ({kind}, {solver}, {f.iterations} iterations, "
        f"{f.free} free nodes), more than a 60 Hz frame's {FRAME_MS:.1f} ms; "
    )
    fit = f.fits()
    if not fit:
        least = f.ms(solver="cg", iterations=1, cg_iterations=MIN_CG_STEPS, rotation_iterations=1)
        return line + f"even {MIN_CG_STEPS} CG steps cost about {least:.0f} ms: only a coarser mesh fits"
    setting = ", ".join(f"{k}={v!r}" for k, v in fit.items())
    return line + f"{setting} fits (about {f.ms(**fit):.0f} ms; the body settles over more frames)"


def matrix_entries(free: np.ndarray, links: np.ndarray) -> int:
    """Entries of the global matrix's free block (one axis): its diagonal and two per link between free
    nodes. `free` is the free-node mask, `links` (M, 2) the mesh's edges."""
    both = free[links[:, 0]] & free[links[:, 1]] if len(links) else np.zeros(0, dtype=np.bool_)
    return int(free.sum()) + 2 * int(np.count_nonzero(both))


def join(notice: str, line: str) -> str:
    """Two notices in one line; the second's model prefix goes when the first has it already."""
    if not notice or not line:
        return notice or line
    head, _, rest = line.partition(": ")
    if rest and notice.startswith(head + ":"):
        line = rest
    return f"{notice}; {line}"
