"""Compiling the numba kernels ahead, so no interaction ever waits on compilation.

numba compiles a kernel the first time it runs (seconds each on a fresh install) and caches the
result on disk (cache=True). `warm_up()` runs every kernel the simulator uses once on a tiny input,
with a progress bar: `chainsim warmup` after installing, and `chainsim play` before its window takes
input. With a warm cache it costs a fraction of a second (loading the cached machine code).
"""

from __future__ import annotations

import numpy as np

from chainsim.engine.bodies.chainmail import ChainMailBody
from chainsim.engine.bodies.projective import ProjectiveBody
from chainsim.engine.bodies.xpbd import XPBDBody
from chainsim.engine.chainmail_params import ORDERS
from chainsim.engine.kernels.chainmail import cascade
from chainsim.engine.kernels.normals import _normals_parallel, moved_normals_kernel, vertex_normals_kernel
from chainsim.engine.meshgen import tet_grid, triangulated_grid
from chainsim.engine.progress import progress
from chainsim.engine.segment_tree import SegmentTree


def _chainmail(rest, links, surface_tris):
    # numba compiles one version per argument type: with and without anchors, both precisions
    for order in ORDERS:
        for dtype, fixed in ((np.float64, [0]), (np.float64, None), (np.float32, [0]), (np.float32, None)):
            body = ChainMailBody(rest, links, relax=2, exact=True, order=order, dtype=dtype, fixed=fixed)
            body.grab([len(rest) - 1], rest[-1] + 0.5)
            body.cut(rest[0] - 1.0, rest[-1] + 1.0, normal=[0.0, 0.0, 1.0], depth=10.0)
    # the level-parallel cascade, which a body takes by itself on large meshes with many threads
    for dtype in (np.float64, np.float32):
        body = ChainMailBody(rest, links, dtype=dtype)
        t = (body.rest[-1] + 0.5)[None]
        cascade(body.rest, body.positions, body.graph, body.amin, body.amax, body.beta, [len(rest) - 1], t,
                workspace=body.workspace, parallel=True)  # fmt: skip


def _models(rest, tets, tris):
    for make in (
        lambda: XPBDBody(rest, tets, fixed=[0]),  # corotational, the default
        lambda: XPBDBody(rest, tets, constraints="neohookean", fixed=[0]),
        lambda: XPBDBody(rest, tets, constraints="stvk", fixed=[0]),
        lambda: XPBDBody(rest[: tris.max() + 1], triangles=tris, fixed=[0]),
        lambda: ProjectiveBody(rest, tets, fixed=[0]),
        lambda: ProjectiveBody(rest[: tris.max() + 1], triangles=tris, fixed=[0]),
    ):
        body = make()
        body.grab([1], body.rest[1] + 0.1)
        body.step(1 / 60)


def _geometry(rest, tris):
    # the argument types the app passes: float64 positions from the engine, float32 from the window's
    # GPU meshes (chainsim.game.gl.meshbuf: whole-mesh normals into float32 or float64, and the moved
    # vertices' normals while a tool drags tissue); missing one froze a first forceps grip for seconds
    tris = np.ascontiguousarray(tris, dtype=np.int64)
    n = int(tris.max()) + 1
    flat = tris.ravel()
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=ptr[1:])
    idx = (np.argsort(flat, kind="stable") // 3).astype(np.int64)
    for pos_type, out_types in ((np.float64, (np.float64,)), (np.float32, (np.float32, np.float64))):
        pos = np.ascontiguousarray(rest[:n], dtype=pos_type)
        for out_type in out_types:
            vertex_normals_kernel(pos, tris, np.zeros((n, 3), out_type))
        normals = np.zeros((n, 3), pos_type)
        moved_normals_kernel(pos, tris, ptr, idx, np.arange(2, dtype=np.int64), np.zeros(n, np.bool_), normals)
    # large meshes on machines with several cores take the parallel gather (float32, the GPU copy)
    pos32 = np.ascontiguousarray(rest[:n], dtype=np.float32)
    _normals_parallel(pos32, tris, ptr, idx, np.zeros((n, 3), np.float32), 2)
    SegmentTree.build(rest, tris).first_hit(rest[0] - 1.0, rest[-1] + 1.0)


def warm_up() -> None:
    """Run every kernel once (compiling it, or loading it from numba's cache)."""
    rest, tets, links = tet_grid(3, 3, 3, spacing=1.0)
    _p2, tris, _l2 = triangulated_grid(3, 3, spacing=1.0, dim=3)
    jobs = [
        ("ChainMail", lambda: _chainmail(rest, links, tris)),
        ("XPBD and projective", lambda: _models(rest, tets, tris)),
        ("normals and collision", lambda: _geometry(rest, tris)),
    ]
    bar = progress(total=len(jobs), desc="compiling kernels", unit="group")
    try:
        for name, job in jobs:
            bar.set_postfix_str(name)
            job()
            bar.update(1)
    finally:
        bar.close()
