"""Offscreen preview renders of the prp anatomy (skull, skin, foramina, landmarks, planes).

Used by prepare_prp to write a picture people can check at a glance (thesis 3.3.3: the
anatomy is what the trainee builds spatial skill on, so it must look right). Orthographic views,
flat two-light shading, order-independent enough for a few translucent layers (opaque first, then
translucent sorted back to front per mesh). Needs an EGL context (Mesa llvmpipe is enough).
"""

from __future__ import annotations

import moderngl
import numpy as np
import trimesh

from chainsim.systems.view.ui.viewports import look_at

_VS = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
in vec3 in_nrm;
out vec3 v_nrm;
void main() { v_nrm = in_nrm; gl_Position = mvp * vec4(in_pos, 1.0); }
"""
_FS = """
#version 330
uniform vec4 color;
uniform vec3 light;
in vec3 v_nrm;
out vec4 f_color;
void main() {
    vec3 n = normalize(v_nrm);
    float l = 0.35 + 0.55 * abs(dot(n, light)) + 0.10 * abs(n.z);
    f_color = vec4(color.rgb * l, color.a);
}
"""


def _look(view_dir: np.ndarray, up: np.ndarray, centre: np.ndarray, half: float) -> np.ndarray:
    """Orthographic view-projection looking along view_dir (the direction the camera faces)."""
    view = look_at(centre - view_dir / np.linalg.norm(view_dir), centre, up)
    depth = 4.0 * half
    proj = np.diag([1.0 / half, 1.0 / half, -1.0 / depth, 1.0])
    return proj @ view


def _uniform(prog: moderngl.Program, name: str) -> moderngl.Uniform:
    u = prog[name]
    assert isinstance(u, moderngl.Uniform), f"{name} is not a uniform of the program"
    return u


def render(layers, view_dir, up, centre, half, size=(640, 640)) -> np.ndarray:
    """layers: list of (trimesh.Trimesh, (r, g, b, a)). Returns an RGB uint8 image."""

    # moderngl's stub types each keyword setting as a dict; backend is a str
    ctx = moderngl.create_standalone_context(backend="egl")  # type: ignore[arg-type]
    try:
        prog = ctx.program(vertex_shader=_VS, fragment_shader=_FS)
        fbo = ctx.simple_framebuffer(size, components=4)
        fbo.use()
        ctx.clear(1.0, 1.0, 1.0, 1.0)
        mvp = _look(np.asarray(view_dir, float), np.asarray(up, float), np.asarray(centre, float), half)
        _uniform(prog, "mvp").write(mvp.T.astype("f4").tobytes())
        light = -np.asarray(view_dir, float) + 0.5 * np.asarray(up, float)
        _uniform(prog, "light").value = tuple((light / np.linalg.norm(light)).tolist())
        opaque = [layer for layer in layers if layer[1][3] >= 1.0]
        clear = [layer for layer in layers if layer[1][3] < 1.0]
        ctx.enable(moderngl.DEPTH_TEST)
        for mesh, color in opaque + clear:
            tri = mesh.triangles.reshape(-1, 3)
            nrm = np.repeat(mesh.face_normals, 3, axis=0)
            if color[3] < 1.0:
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
                # Back to front within the translucent mesh so overlapping folds blend sensibly.
                key = mesh.triangles_center @ np.asarray(view_dir, float)
                order = np.argsort(-key)
                tri = mesh.triangles[order].reshape(-1, 3)
                nrm = np.repeat(mesh.face_normals[order], 3, axis=0)
                fbo.depth_mask = False
            else:
                ctx.disable(moderngl.BLEND)
                fbo.depth_mask = True
            fbo.use()  # moderngl hands a framebuffer's masks to GL when it is bound
            data = np.hstack([tri, nrm]).astype("f4")
            vbo = ctx.buffer(data.tobytes())
            vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_pos", "in_nrm")])
            _uniform(prog, "color").value = tuple(float(c) for c in color)
            vao.render(moderngl.TRIANGLES)
            vao.release()
            vbo.release()
        img = np.frombuffer(fbo.read(components=3), dtype=np.uint8).reshape(size[1], size[0], 3)
        return img[::-1].copy()
    finally:
        ctx.release()


def marker(p, radius=1.5) -> trimesh.Trimesh:
    s = trimesh.creation.icosphere(subdivisions=1, radius=radius)
    s.apply_translation(p)
    return s
