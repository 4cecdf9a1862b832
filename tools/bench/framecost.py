"""The frame-cost estimates of chainsim.systems.engine.framecost against real frames, and the fit of its
per-unit costs.

`python -m chainsim.tools.bench.framecost` builds the 30 x 30 x 20 mm tissue block (base fixed, a 6 mm
patch on top grabbed) at about 1k, 10k and 30k nodes (`--sizes`), runs XPBD under its substep rule and
projective dynamics at its defaults, each with the setting its notice offers, and prints each frame's
estimate beside the measured one. `--fit` times a spread of settings on 1k, 4k and 10k-node blocks and a
10k-node sheet and prints the per-unit costs that fit them best (non-negative least squares on the
relative error), the constants framecost.py carries.

A frame is timed as the app runs it, one 60 Hz step, while the patch is pulled 0.2 mm further every
frame (the body keeps moving, so no iteration stops early): the median CPU time (thread_time) of
`FRAMES` frames after one that pays the set-up (compiling, factorising), with one numba thread.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numba
import numpy as np
from scipy.optimize import nnls

from chainsim.systems.engine import framecost, meshgen
from chainsim.systems.engine.bodies.base import Body
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.errors import UserError

FRAMES = 4
PULL_MM = 0.2  # the patch's rise each frame
BLOCK_MM = (30.0, 30.0, 20.0)
PATCH_MM = 6.0
SIZES = (1_000, 10_000, 30_000)


@contextmanager
def one_thread() -> Iterator[None]:
    """numba's parallel loops on the calling thread only, so thread_time counts all their work (other
    threads waiting for work would add their spinning to a process's CPU time)."""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def block(nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tissue block with about `nodes` nodes: (positions mm, tets, fixed ids, grabbed ids)."""
    n = max(3, round((nodes * BLOCK_MM[0] / BLOCK_MM[2]) ** (1.0 / 3.0)))
    spacing = BLOCK_MM[0] / (n - 1)
    nz = round(BLOCK_MM[2] / spacing) + 1
    pos, tets, _ = meshgen.tet_grid(n, n, nz, spacing=spacing)
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    top = pos[:, 2] > pos[:, 2].max() - 1e-9
    near = np.all(np.abs(pos[:, :2] - np.asarray(BLOCK_MM[:2]) / 2) <= PATCH_MM / 2 + 1e-9, axis=1)
    grab = np.flatnonzero(top & near)
    if len(grab) == 0:  # a coarse block: the top node nearest the centre
        centre = np.array([BLOCK_MM[0] / 2, BLOCK_MM[1] / 2, pos[:, 2].max()])
        grab = np.array([int(np.argmin(np.linalg.norm(pos - centre, axis=1)))])
    return pos, tets, fixed, grab


def sheet(nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 30 x 30 mm sheet of about `nodes` nodes, one edge fixed, a central patch grabbed:
    (positions mm, triangles, fixed ids, grabbed ids)."""
    n = max(3, round(nodes**0.5))
    pos, tris, _ = meshgen.triangulated_grid(n, n, spacing=BLOCK_MM[0] / (n - 1), dim=3)
    fixed = np.flatnonzero(pos[:, 1] < 1e-9)
    grab = np.flatnonzero(np.all(np.abs(pos[:, :2] - BLOCK_MM[0] / 2) <= PATCH_MM / 2 + 1e-9, axis=1))
    return pos, tris, fixed, grab


def frame_ms(body: Body, pos: np.ndarray, grab: np.ndarray, frames: int = FRAMES) -> tuple[float, list]:
    """Median CPU ms of `frames` frames of a pull that keeps moving, after one frame that pays the set-up;
    also each timed frame's stats."""
    times, stats = [], []
    with one_thread(), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # fewer substeps than the rule: measured on purpose
        for f in range(frames + 1):
            body.grab(grab, pos[grab] + [0.0, 0.0, PULL_MM * (f + 1)])
            t0 = time.thread_time()
            st = body.step(framecost.FRAME_S)
            if f:
                times.append(1e3 * (time.thread_time() - t0))
                stats.append(st)
    return float(np.median(times)), stats


def build(model: str, mesh: tuple, **settings: Any) -> XPBDBody | ProjectiveBody:
    """An xpbd or projective body on `mesh` (block or sheet), millimetre units."""
    pos, cells, fixed, _ = mesh
    key = "tets" if cells.shape[1] == 4 else "triangles"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        body = make_body(model, pos, fixed=fixed, unit=1e-3, **{key: cells}, **settings)
    assert isinstance(body, XPBDBody | ProjectiveBody)  # the models this module estimates
    return body


def check(sizes: tuple[int, ...] = SIZES) -> list[dict]:
    """Estimate against measured frame for XPBD by the rule and projective at its defaults, and for the
    setting each notice offers, on the tissue block at each size."""
    rows = []
    for nodes in sizes:
        mesh = block(nodes)
        for model in ("xpbd", "projective"):
            body = build(model, mesh)
            settings: dict = {}
            for _ in range(2):  # the body's default, then the setting its notice offers
                est = body.frame_cost().ms()
                ms, _ = frame_ms(body, mesh[0], mesh[3])
                rows.append(dict(nodes=len(mesh[0]), model=model, settings=settings, estimate=est, measured=ms))
                print(
                    f"{rows[-1]['nodes']:>6} {model:<10} {settings or 'defaults'}: estimate {est:.1f} ms, "
                    f"measured {ms:.1f} ms, ratio {ms / est:.2f}   {body.notice}",
                    flush=True,
                )
                settings = body.frame_cost().fits() or {}
                if not settings or not body.notice:
                    break
                body = build(model, mesh, **settings)
    return rows


#: the settings `--fit` times: (model, mesh kind, nodes, settings)
FIT_RUNS: list[tuple[str, str, int, dict[str, Any]]] = [
    *[
        ("xpbd", "block", n, dict(substeps=s, iterations=i, constraints=c))
        for n in (1_000, 4_000, 10_000)
        for c in ("corotational", "neohookean", "stvk")
        for s, i in ((1, 1), (4, 1), (2, 3))
    ],
    *[
        ("xpbd", "sheet", n, dict(substeps=s, iterations=i))
        for n in (2_000, 10_000)
        for s, i in ((1, 1), (4, 1), (2, 3))
    ],
    *[
        ("projective", "block", n, dict(solver="direct", dynamic=d, iterations=i, rotation_iterations=r))
        for n in (1_000, 4_000, 10_000)
        for d in (True, False)
        for i, r in ((1, 1), (4, 1), (2, 4))
    ],
    *[
        ("projective", "block", n, dict(solver="cg", iterations=i, cg_iterations=c, rotation_iterations=1))
        for n in (1_000, 4_000, 10_000)
        for i, c in ((1, 5), (1, 20), (4, 10))
    ],
    *[
        ("projective", "sheet", n, dict(solver=s, iterations=i))
        for n in (2_000, 10_000)
        for s, i in (("direct", 1), ("direct", 4), ("cg", 2))
    ],
]


def features(b: XPBDBody | ProjectiveBody, stats: list) -> dict[str, float]:
    """The counts each per-unit cost multiplies in the frames measured (iterations as they ran)."""
    if isinstance(b, XPBDBody):
        sweeps = b.substeps * b.iterations
        tets = int(b.tet_active.sum()) if b.tets is not None else 0
        out: dict[str, float] = {f"XPBD_TET_MS[{b.constraints}]": sweeps * tets}
        return out | {"XPBD_PAIR_MS": sweeps * len(b.pairs), "XPBD_NODE_MS": b.substeps * b.n}
    it = float(np.median([s.iterations for s in stats]))
    free = int(b.n - b.fixed.sum())
    el = int(b.active.sum())
    out = {"PD_NODE_MS": it * free}
    if not b.surface:
        out |= {"PD_TET_MS": it * el, "PD_ROTATION_MS": it * el * b.rotation_iterations}
    if b.solver == "direct":
        out["PD_FACTOR_MS"] = it * (b._factor.L.nnz + b._factor.U.nnz)
    else:
        cg = b.cg_iterations
        out |= {"PD_CG_ENTRY_MS": it * cg * b._csr[2].size, "PD_CG_NODE_MS": it * cg * free}
    return out


def fit() -> dict[str, float]:
    """Time FIT_RUNS and fit each model's per-unit costs; prints and returns them."""
    meshes: dict = {}
    rows = []
    for model, kind, nodes, settings in FIT_RUNS:
        key = (kind, nodes)
        if key not in meshes:
            meshes[key] = (block if kind == "block" else sheet)(nodes)
        mesh = meshes[key]
        try:
            body = build(model, mesh, **settings)
            ms, stats = frame_ms(body, mesh[0], mesh[3])
        except UserError as e:
            print(f"{model} {kind} {nodes} {settings}: {e}")
            continue
        rows.append((model, features(body, stats), ms))
        print(f"{model} {kind} {len(mesh[0])} {settings}: {ms:.2f} ms", flush=True)
    out: dict[str, float] = {}
    for model in ("xpbd", "projective"):
        mine = [(f, ms) for m, f, ms in rows if m == model]
        names = sorted({k for f, _ in mine for k in f})
        a = np.array([[f.get(k, 0.0) / ms for k in names] for f, ms in mine])
        coef, _ = nnls(a, np.ones(len(mine)))
        ratio = [ms / float(np.dot([f.get(k, 0.0) for k in names], coef)) for f, ms in mine]
        print(f"{model}: measured / fitted {min(ratio):.2f}-{max(ratio):.2f} over {len(mine)} settings")
        out |= dict(zip(names, (float(c) for c in coef)))
    for k, v in out.items():
        print(f"{k} = {v:.4g}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m chainsim.tools.bench.framecost", description=__doc__)
    p.add_argument("--fit", action="store_true", help="fit the per-unit costs instead of checking them")
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), help="block node counts, comma-separated")
    args = p.parse_args(argv)
    if args.fit:
        fit()
    else:
        check(tuple(int(s) for s in args.sizes.split(",")))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
