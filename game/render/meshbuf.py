"""GPU buffers of one mesh: positions and normals (float32), triangle and link index buffers.

A deformed mesh is updated in place: only the vertices the deformation moved are written, as a few
contiguous ranges (`buffer.write` with an offset, straight from the arrays, no byte copies), and normals
are recomputed only around them - the moved vertices and the other corners of their triangles, from
the triangles touching those. ChainMail moves a local patch per pull (thesis 5.2.3), so an update costs
in proportion to the patch, not the mesh. When most of the mesh moved, everything is rewritten: for
meshes of GPU_NORMALS_MIN vertices or more only the float32 positions cross to the GPU and one
transform-feedback pass there writes both vertex buffers (chainsim.game.render.gpunormals); smaller meshes
recompute normals on the CPU, on all threads where there are several (chainsim.systems.engine.kernels.normals).
"""

from __future__ import annotations

import itertools
import time

import moderngl
import numpy as np

from chainsim.game.render import gpunormals
from chainsim.game.render.gpunormals import GpuNormals
from chainsim.systems.engine.kernels.normals import moved_normals_kernel, normals_into, vertex_normals_kernel
from chainsim.systems.engine.meshgen import links_from_polygons

_SERIALS = itertools.count()

#: vertex-id gaps smaller than this are written through rather than split into two writes
RUN_GAP = 256
#: above this fraction of moved vertices a full rewrite is cheaper than the bookkeeping
FULL_FRACTION = 0.3
#: full rewrites of meshes with this many vertices or more compute normals on the GPU (below it the
#: CPU kernel is quicker than the texture upload and pass)
GPU_NORMALS_MIN = 50_000
#: where full rewrites compute normals: "auto" (the GPU pass on a hardware renderer, the CPU kernel on a
#: software one such as llvmpipe, where the pass runs on the same CPUs several times slower), "gpu", "cpu"
GPU_NORMALS = "auto"
_SOFTWARE = ("llvmpipe", "softpipe", "swiftshader", "lavapipe", "swrast")
#: opaque meshes of this many triangles or more, never changed since loading, also keep their triangles
#: in ORDER_DIRECTIONS orders, each sorted nearest-first as seen from one direction: drawn in the one
#: nearest the eye's, a surface hidden behind another (the inner face of the skull, the far side of the
#: cranium) mostly fails the depth test before it is shaded
SORTED_MIN = 4000
ORDER_DIRECTIONS = np.array(
    [[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)], float
)
ORDER_DIRECTIONS /= np.linalg.norm(ORDER_DIRECTIONS, axis=1)[:, None]


def gpu_normals_used(renderer: str, n_vertices: int) -> bool:
    """Whether a full rewrite of a mesh this size computes its normals on the GPU (GPU_NORMALS), given
    the context's GL_RENDERER string."""
    if GPU_NORMALS == "cpu" or n_vertices < GPU_NORMALS_MIN:
        return False
    if GPU_NORMALS == "gpu":
        return True
    return not any(name in renderer.lower() for name in _SOFTWARE)


#: whether the normals kernel may be called in this process; False while a window's kernels are still
#: compiling in another process (chainsim.game.trainer.compiling), when numpy computes the first uploads'
KERNEL_NORMALS = True


def _numpy_normals(pos: np.ndarray, tris: np.ndarray, out: np.ndarray) -> None:
    """The kernel's normals with numpy: face cross products summed per vertex, normalised."""
    p = np.asarray(pos, np.float64)
    t = np.asarray(tris, np.int64)
    face = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    acc = np.zeros((len(p), 3))
    for k in range(3):
        for c in range(3):
            acc[:, c] += np.bincount(t[:, k], weights=face[:, c], minlength=len(p))
    ln = np.linalg.norm(acc, axis=1)
    ok = ln > 1e-30
    out[ok] = acc[ok] / ln[ok, None]
    out[~ok] = 0.0


def vertex_normals(pos: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Unit per-vertex normals: the area-weighted mean of the incident face normals (numba kernel)."""

    out = np.zeros((len(pos), 3))
    if len(pos) and len(tris) and not KERNEL_NORMALS:
        _numpy_normals(pos, tris, out)
    elif len(pos) and len(tris):
        vertex_normals_kernel(np.ascontiguousarray(pos), np.ascontiguousarray(tris, dtype=np.int64), out)
    return out


def runs(ids: np.ndarray, gap: int = RUN_GAP) -> list[tuple[int, int]]:
    """Sorted ids -> [start, end) ranges covering them, merging gaps shorter than `gap`."""
    if len(ids) == 0:
        return []
    breaks = np.flatnonzero(np.diff(ids) > gap)
    starts = np.r_[ids[0], ids[breaks + 1]]
    ends = np.r_[ids[breaks], ids[-1]] + 1
    return list(zip(starts.tolist(), ends.tolist()))


def incidence(n: int, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR vertex -> incident triangles: triangles of v are idx[ptr[v]:ptr[v+1]]."""
    flat = tris.ravel()
    order = np.argsort(flat, kind="stable")
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=ptr[1:])
    return ptr, (order // 3).astype(np.int64)


def _closed_outward(pos: np.ndarray, tris: np.ndarray) -> bool:
    if len(tris) < 4:
        return False
    _, ids = np.unique(np.round(np.asarray(pos, np.float64), 6), axis=0, return_inverse=True)
    t = ids.reshape(-1)[tris]
    if np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])):
        return False
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    n = int(t.max()) + 1
    code = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    if len(np.unique(code)) != len(code):
        return False  # an edge run twice the same way: inconsistent winding or more than two faces
    if not np.all(np.isin(reverse, code)):
        return False  # an open edge
    p = np.asarray(pos, np.float64)[tris]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return bool(volume > 0.0)


class GpuMesh:
    """Vertex/normal/index buffers of one mesh plus the CPU copy needed for partial updates."""

    # kept by the render system (chainsim.game.render.render_system), absent until it first sets it: how
    # many links were cut when the links were last set
    dead_links: int

    def __init__(self, ctx, vertices: np.ndarray, triangles: np.ndarray, links: np.ndarray | None = None):
        self.ctx = ctx
        self.pos = np.ascontiguousarray(vertices, dtype=np.float32)
        self.tris = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
        self.n = len(self.pos)
        self.normals = vertex_normals(self.pos, self.tris).astype(np.float32)
        self.vbo_pos = ctx.buffer(self.pos.tobytes(), dynamic=True)
        self.vbo_nrm = ctx.buffer(self.normals.tobytes(), dynamic=True)
        self.ibo = ctx.buffer(self.tris.astype(np.uint32).tobytes() or b"\0" * 12)
        self.n_indices = self.tris.size
        self.tri_ids = np.arange(len(self.tris))  # drawn triangles (all, until a cut removes some)
        self._links = None if links is None else np.ascontiguousarray(links, dtype=np.int64)
        self.lbo = None
        self.n_line_indices = 0
        self._csr: tuple[np.ndarray, np.ndarray] | None = None  # vertex -> triangles incidence (ptr, idx)
        self._mark: np.ndarray | None = None
        self.pending = np.zeros(self.n, np.bool_)  # vertices moved since the last upload
        self.stale = False  # everything must be rewritten
        self.bytes_written = 0  # statistics for benchmarks and tests
        self.timing: dict | None = None  # set to {} to get the split of each full upload (ms), for benchmarks
        self._gpu: GpuNormals | None = None
        self._renderer: str | None = None
        self._normals_behind = False
        self.version = 0  # bumped by every change of what is drawn (cached views compare it)
        self.serial = next(_SERIALS)  # never reused, unlike id(): a new mesh never matches an old key
        self._closed: bool | None = None  # closed_outward(), once known
        self.vaos: dict[str, moderngl.VertexArray] = {}
        self._box: tuple[np.ndarray, np.ndarray] | None = None
        self._ordered = None  # index buffer of the triangles in every ORDER_DIRECTIONS order (made on first use)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) corners of a box holding the mesh, in its own frame. After partial uploads it
        only grows (cheap and still holds the mesh), which is all sorting and plane sizing need."""
        if self._box is None:
            if self.n:
                self._box = (self.pos.min(axis=0).astype(np.float64), self.pos.max(axis=0).astype(np.float64))
            else:
                self._box = (np.zeros(3), np.zeros(3))
        return self._box

    def closed_outward(self) -> bool:
        """Whether the drawn triangles close a surface wound outward (vertices merged by position, so
        a crease split into two vertices still counts as closed): every edge is used twice, once each
        way, and the enclosed volume is positive. Then from outside only its front faces can show.
        Checked once for the mesh as loaded; False after any upload or cut."""
        if self.version:
            return False
        if self._closed is None:
            self._closed = _closed_outward(self.pos, self.tris[self.tri_ids])
        return self._closed

    def center(self) -> np.ndarray:
        """Box centre in the mesh frame (sorting transparent meshes)."""
        lo, hi = self.box()
        return 0.5 * (lo + hi)

    # -- vertex arrays -----------------------------------------------------------------------
    def vao(self, prog, kind: str):
        """A vertex array for `prog`: kind 'tri' (positions, normals, triangles), 'ordered' (the same
        with the triangles in every nearest-first order, after `nearest_first`) or 'line' (links)."""
        key = f"{kind}:{prog.glo}"
        if key not in self.vaos:
            if kind in ("tri", "ordered"):
                attrs = [(self.vbo_pos, "3f", "in_pos")]
                if "in_normal" in prog:
                    attrs.append((self.vbo_nrm, "3f", "in_normal"))
                self.vaos[key] = self.ctx.vertex_array(prog, attrs, self.ibo if kind == "tri" else self._ordered)
            else:
                self._ensure_lines()
                self.vaos[key] = self.ctx.vertex_array(prog, [(self.vbo_pos, "3f", "in_pos")], self.lbo)
        return self.vaos[key]

    @property
    def orderable(self) -> bool:
        """Whether the mesh is drawn from nearest-first orders: as loaded, with SORTED_MIN triangles or more."""
        return not self.version and len(self.tris) >= SORTED_MIN and self.n_indices == self.tris.size

    def nearest_first(self, eye) -> int | None:
        """For an `orderable` mesh: the first index, in the 'ordered' vertex array, of its triangles
        sorted nearest-first for an eye at `eye` (mesh frame). None otherwise (draw the 'tri' array)."""
        if not self.orderable:
            return None
        if self._ordered is None:
            centroids = self.pos[self.tris].astype(np.float64).mean(axis=1)
            depth = centroids @ ORDER_DIRECTIONS.T  # larger: nearer an eye far out along that direction
            order = np.argsort(-depth, axis=0, kind="stable").T  # (directions, triangles)
            self._ordered = self.ctx.buffer(self.tris[order].astype(np.uint32).tobytes())
        d = np.asarray(eye, np.float64) - self.center()
        return int(np.argmax(ORDER_DIRECTIONS @ d)) * self.n_indices

    def _ensure_lines(self):
        if self.lbo is None:
            links = self._links
            if links is None:
                links = links_from_polygons(self.tris) if len(self.tris) else np.zeros((0, 2), np.int64)
                self._links = links
            self.lbo = self.ctx.buffer(links.astype(np.uint32).tobytes() or b"\0" * 8, dynamic=True)
            self.n_line_indices = links.size

    def set_links(self, links: np.ndarray) -> None:
        """Replace the drawn links (after a cut)."""
        links = np.ascontiguousarray(links, dtype=np.int64).reshape(-1, 2)
        self._links = links
        self.version += 1
        if self.lbo is not None:
            data = links.astype(np.uint32).tobytes()
            if len(data) > self.lbo.size:
                self.lbo.orphan(len(data))
            if data:
                self.lbo.write(data)
            self.n_line_indices = links.size

    def set_triangles(self, tri_ids: np.ndarray) -> None:
        """Draw only these triangles (ids into the original list), e.g. after a cut."""
        self.tri_ids = np.asarray(tri_ids, np.int64)
        self.version += 1
        data = self.tris[self.tri_ids].astype(np.uint32).tobytes()
        if data:
            self.ibo.write(data)
        self.n_indices = len(self.tri_ids) * 3

    # -- deformation uploads -----------------------------------------------------------------
    def mark(self, ids) -> None:
        ids = np.asarray(ids)
        if ids.dtype == np.bool_:
            self.pending |= ids[: self.n]
        elif len(ids):
            self.pending[ids] = True

    def upload(self, positions: np.ndarray) -> int:
        """Write moved vertices (those marked, or all when stale) from `positions`; returns their count."""
        if self.stale:
            self.stale = False
            self.pending[:] = False
            return self._upload_all(positions)
        moved = int(np.count_nonzero(self.pending))  # a count first: a full rewrite needs no id list
        if moved == 0:
            return 0
        self.version += 1
        if moved > FULL_FRACTION * self.n:
            self.pending[:] = False
            return self._upload_all(positions)
        ids = np.flatnonzero(self.pending)
        self.pending[ids] = False
        self.pos[ids] = positions[ids]
        if self._box is not None:
            moved = self.pos[ids]
            self._box = (np.minimum(self._box[0], moved.min(axis=0)), np.maximum(self._box[1], moved.max(axis=0)))
        if self._csr is None:
            self._csr = incidence(self.n, self.tris)
        ptr, idx = self._csr
        if self._mark is None:
            self._mark = np.zeros(self.n, np.bool_)  # scratch for the kernel
        if self._normals_behind:
            # the last full rewrite computed normals on the GPU; the ranges below write some untouched
            # vertices through (RUN_GAP), so fetch the current normals once before mixing them in
            self.vbo_nrm.read_into(self.normals)
            self._normals_behind = False
        verts = moved_normals_kernel(self.pos, self.tris, ptr, idx, ids, self._mark, self.normals)
        for a, b in runs(ids):
            self.vbo_pos.write(self.pos[a:b], offset=a * 12)
            self.bytes_written += (b - a) * 12
        for a, b in runs(verts):
            self.vbo_nrm.write(self.normals[a:b], offset=a * 12)
            self.bytes_written += (b - a) * 12
        return len(ids)

    def _upload_all(self, positions: np.ndarray) -> int:
        self._box = None
        self.version += 1
        t0 = time.perf_counter()
        if self._renderer is None:
            self._renderer = str(self.ctx.info.get("GL_RENDERER", ""))
        gpu = len(self.tris) > 0 and gpu_normals_used(self._renderer, self.n)
        if gpu and self._gpu is None and not gpunormals.fits(self.ctx, self.n, len(self.tris)):
            gpu = False  # larger than the context's textures: the CPU path
        if gpu and self._gpu is None:
            self._gpu = GpuNormals(self.ctx, self.n, self.tris)
            self.pos = self._gpu.pos  # convert straight into the texture's staging rows from now on
        self.pos[:] = positions
        t1 = time.perf_counter()
        if gpu:
            assert self._gpu is not None  # made above when first needed
            self._gpu.run(self.vbo_pos, self.vbo_nrm)
            self._normals_behind = True  # the CPU copy of the normals is fetched when a partial upload needs it
            self.bytes_written += self.n * 12
            t2 = t3 = time.perf_counter()
        else:
            if self.n and len(self.tris):
                if self._csr is None:
                    self._csr = incidence(self.n, self.tris)
                normals_into(self.pos, self.tris, *self._csr, self.normals)
            self._normals_behind = False
            t2 = time.perf_counter()
            self.vbo_pos.write(self.pos)
            self.vbo_nrm.write(self.normals)
            self.bytes_written += self.n * 24
            t3 = time.perf_counter()
        if self.timing is not None:
            self.timing.update(
                convert=(t1 - t0) * 1e3, normals=(t2 - t1) * 1e3 if not gpu else 0.0,
                write=(t3 - t2) * 1e3 if not gpu else 0.0, gpu_pass=(t2 - t1) * 1e3 if gpu else 0.0,
            )  # fmt: skip
        return self.n

    @property
    def normals_on_gpu(self) -> bool:
        """Whether full rewrites of this mesh have used the GPU pass."""
        return self._gpu is not None

    def read_normals(self) -> np.ndarray:
        """The normals the GPU draws with, read back (N, 3) float32 (for tests)."""
        return np.frombuffer(self.vbo_nrm.read(), np.float32).reshape(-1, 3)[: self.n].copy()

    def release(self) -> None:
        for v in self.vaos.values():
            v.release()
        for b in (self.vbo_pos, self.vbo_nrm, self.ibo, self.lbo, self._ordered):
            if b is not None:
                b.release()
        if self._gpu is not None:
            self._gpu.release()
            self._gpu = None
        self.vaos.clear()
