"""Vertex normals and positions of a whole deforming mesh produced on the GPU in one pass.

A full re-upload (most of the mesh moved) would otherwise convert, compute normals on the CPU and
write two buffers. Here only the float32 positions cross to the GPU, once, into a 2-D single-channel
R32F texture (x, y, z of vertex v in texels 3v .. 3v + 2: a one-channel upload is a plain copy for every
driver, where three-channel textures are widened to four on the CPU by some);
one transform-feedback pass (GL 3.3 core, no rasteriser) runs a vertex shader per vertex that copies
its position into the position buffer and gathers the face normals of its triangles, found through
the vertex -> triangle incidence held in two static integer textures (CSR offsets; for each entry the
vertex's two other corners in the triangle's winding). The normal is the normalised sum of those face
normals, the definition of chainsim.systems.engine.kernels.normals, summed in the same CSR order; float32 on
the GPU instead of float64 on the CPU, so the two agree to float32 rounding, not bit for bit.
"""

from __future__ import annotations

import moderngl
import numpy as np

from chainsim.game.render.context import release_framebuffer

#: texture width of the position / incidence textures (rows = ceil(count / width))
WIDTH = 4096

_VS = """
#version 330
uniform sampler2D u_pos;     // R32F: coordinate k of vertex v in texel 3 v + k, texel i at (i % W, i / W)
uniform isampler2D u_ptr;    // R32I: CSR offsets, n + 1 of them
uniform isampler2D u_adj;    // RG32I: per incidence entry, the other two corners in winding order
uniform int u_width;
out vec3 out_pos;
out vec3 out_normal;

ivec2 at(int i) { return ivec2(i % u_width, i / u_width); }

vec3 vertex(int v) {
    int i = 3 * v;
    return vec3(texelFetch(u_pos, at(i), 0).x, texelFetch(u_pos, at(i + 1), 0).x, texelFetch(u_pos, at(i + 2), 0).x);
}

void main() {
    int v = gl_VertexID;
    vec3 p = vertex(v);
    int lo = texelFetch(u_ptr, at(v), 0).x;
    int hi = texelFetch(u_ptr, at(v + 1), 0).x;
    vec3 s = vec3(0.0);
    for (int j = lo; j < hi; ++j) {
        ivec2 bc = texelFetch(u_adj, at(j), 0).xy;
        vec3 u = vertex(bc.x) - p;
        vec3 w = vertex(bc.y) - p;
        s += cross(u, w);
    }
    float ln = length(s);
    out_pos = p;
    out_normal = ln > 1e-30 ? s / ln : vec3(0.0);
}
"""


def _rows(count: int) -> int:
    return max(1, -(-count // WIDTH))


def corner_incidence(n: int, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR vertex -> (next, prev) corners of each incident triangle, in the order of
    chainsim.game.render.meshbuf.incidence (triangle id ascending): (next - v) x (prev - v) is the
    triangle's normal (a cyclic turn of the corners leaves the cross product unchanged)."""
    tris = np.ascontiguousarray(tris, dtype=np.int64).reshape(-1, 3)
    flat = tris.ravel()
    order = np.argsort(flat, kind="stable")
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=ptr[1:])
    t, corner = order // 3, order % 3
    adj = np.stack([tris[t, (corner + 1) % 3], tris[t, (corner + 2) % 3]], axis=1)
    return ptr, adj


def fits(ctx, n: int, n_triangles: int) -> bool:
    """Whether the textures of a mesh this size stay within the context's largest texture."""
    limit = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 0) or 0)
    return _rows(3 * max(n, n_triangles)) <= limit


class GpuNormals:
    """The pass for one mesh: static incidence textures, a position texture rewritten per upload, and
    a staging array padded to the texture's size (`pos` is an (n, 3) view of its start, so converting
    into it is the only copy on the CPU)."""

    def __init__(self, ctx, n: int, tris: np.ndarray):
        self.ctx = ctx
        self.n = n
        rows = _rows(3 * n)
        self.staging = np.zeros(rows * WIDTH, np.float32)
        self.pos = self.staging[: 3 * n].reshape(n, 3)
        ptr, adj = corner_incidence(n, tris)
        ptr_pad = np.zeros(_rows(n + 1) * WIDTH, np.int32)
        ptr_pad[: n + 1] = ptr
        adj_pad = np.zeros((_rows(len(adj)) * WIDTH, 2), np.int32)
        adj_pad[: len(adj)] = adj
        self.tex_pos = ctx.texture((WIDTH, rows), 1, dtype="f4")
        self.tex_ptr = ctx.texture((WIDTH, _rows(n + 1)), 1, ptr_pad.tobytes(), dtype="i4")
        self.tex_adj = ctx.texture((WIDTH, _rows(len(adj))), 2, adj_pad.tobytes(), dtype="i4")
        for tex in (self.tex_pos, self.tex_ptr, self.tex_adj):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.prog = ctx.program(vertex_shader=_VS, varyings=["out_pos", "out_normal"], varyings_capture_mode="separate")
        self.prog["u_width"].value = WIDTH
        self.prog["u_pos"].value = 0
        self.prog["u_ptr"].value = 1
        self.prog["u_adj"].value = 2
        self.vao = ctx.vertex_array(self.prog, [])
        # the pass draws nothing, but GL refuses any draw (transform feedback too) without a complete
        # framebuffer, and a surfaceless context has none of its own
        self.rb = ctx.renderbuffer((1, 1))
        self.fbo = ctx.framebuffer(color_attachments=[self.rb])

    def run(self, vbo_pos, vbo_nrm) -> None:
        """Upload `pos` (fill it first) and rewrite both vertex buffers from it on the GPU."""
        self.tex_pos.write(self.staging)
        self.tex_pos.use(0)
        self.tex_ptr.use(1)
        self.tex_adj.use(2)
        previous = self.ctx.fbo
        self.fbo.use()
        self.vao.transform([vbo_pos, vbo_nrm], moderngl.POINTS, vertices=self.n)
        if previous is not None:
            previous.use()

    def release(self) -> None:
        release_framebuffer(self.ctx, self.fbo)
        for obj in (self.vao, self.prog, self.tex_pos, self.tex_ptr, self.tex_adj, self.rb):
            obj.release()
