"""Normals computed on the GPU for full rewrites (game/render/gpunormals.py) against the plain numpy reference,
and a frame drawn with them against the same frame drawn with the CPU kernel's normals."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_normals_kernel import reference_normals

from chainsim.game.render import meshbuf
from chainsim.game.render.gpunormals import GpuNormals, corner_incidence
from chainsim.systems.engine.meshgen import triangulated_grid


@pytest.fixture
def gpu_always(monkeypatch):
    monkeypatch.setattr(meshbuf, "GPU_NORMALS", "gpu")
    monkeypatch.setattr(meshbuf, "GPU_NORMALS_MIN", 0)


def test_corner_incidence_turns_each_triangle_to_start_at_its_vertex():
    tris = np.array([[0, 1, 2], [2, 1, 3]])
    ptr, adj = corner_incidence(4, tris)
    assert ptr.tolist() == [0, 1, 3, 5, 6]
    assert adj.tolist() == [[1, 2], [2, 0], [3, 2], [0, 1], [1, 3], [2, 1]]


def test_gpu_pass_matches_the_reference_on_random_meshes(gl_ctx):
    @settings(max_examples=25, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.integers(3, 3000), st.integers(1, 4000))
    def check(seed, n, f):
        rng = np.random.default_rng(seed)
        pos = (rng.normal(size=(n, 3)) * 10.0).astype(np.float32)
        tris = np.array([rng.choice(n, 3, replace=False) for _ in range(f)], np.int64)
        g = GpuNormals(gl_ctx, n, tris)
        vp, vn = gl_ctx.buffer(reserve=n * 12), gl_ctx.buffer(reserve=n * 12)
        try:
            g.pos[:] = pos
            g.run(vp, vn)
            got_pos = np.frombuffer(vp.read(), np.float32).reshape(-1, 3)
            got = np.frombuffer(vn.read(), np.float32).reshape(-1, 3)
        finally:
            g.release()
            vp.release()
            vn.release()
        np.testing.assert_array_equal(got_pos, pos)
        want, defined = reference_normals(pos, tris)
        np.testing.assert_allclose(got[defined], want[defined], atol=2e-4)

    check()


def test_full_then_partial_uploads_keep_the_drawn_normals_right(gl_ctx, gpu_always):
    pos0, tris, _ = triangulated_grid(30, 20, 2.0, dim=3)
    pos0 = np.asarray(pos0, float)
    gm = meshbuf.GpuMesh(gl_ctx, pos0, tris)
    rng = np.random.default_rng(3)
    try:
        current = pos0 + rng.normal(scale=0.8, size=pos0.shape)
        gm.mark(np.arange(gm.n))
        gm.upload(current)
        assert gm._gpu is not None  # the full rewrite took the GPU pass
        for _ in range(5):
            ids = rng.choice(gm.n, 25, replace=False)
            current[ids] += rng.normal(scale=1.5, size=(25, 3))
            gm.mark(ids)
            gm.upload(current)
            drawn = np.frombuffer(gm.vbo_pos.read(), np.float32).reshape(-1, 3)
            np.testing.assert_array_equal(drawn, current.astype(np.float32))
            want, _ = reference_normals(current.astype(np.float32), gm.tris)
            np.testing.assert_allclose(gm.read_normals(), want, atol=2e-5)
    finally:
        gm.release()


def _draw(gl_ctx, pos, tris):
    from chainsim.game.render.context import offscreen_framebuffer, release_framebuffer
    from chainsim.game.render.renderer import Renderer
    from chainsim.tools.bench.render import _frame

    renderer = Renderer(gl_ctx)
    fbo = offscreen_framebuffer(gl_ctx, (320, 200))
    try:
        gm = renderer.mesh("sheet", pos, tris)
        gm.mark(np.arange(gm.n))
        gm.upload(pos)
        used = gm._gpu is not None
        renderer.render(_frame(gm, (320, 200)), fbo)
        img = np.frombuffer(fbo.read(components=3), np.uint8).reshape(200, 320, 3).astype(int)
    finally:
        renderer.release()
        release_framebuffer(gl_ctx, fbo)
    return img, used


def test_a_frame_lit_with_gpu_normals_looks_like_one_lit_with_cpu_normals(gl_ctx, monkeypatch):
    pos, tris, _ = triangulated_grid(60, 60, 4.0, dim=3)
    pos = np.asarray(pos, float) - [120.0, 120.0, 0.0]
    pos[:, 2] += 12.0 * np.cos(pos[:, 0] / 25.0) * np.sin(pos[:, 1] / 31.0)
    monkeypatch.setattr(meshbuf, "GPU_NORMALS_MIN", 0)
    monkeypatch.setattr(meshbuf, "GPU_NORMALS", "cpu")
    cpu, used_cpu = _draw(gl_ctx, pos, tris)
    monkeypatch.setattr(meshbuf, "GPU_NORMALS", "gpu")
    gpu, used_gpu = _draw(gl_ctx, pos, tris)
    assert (used_cpu, used_gpu) == (False, True)
    assert (cpu.sum(axis=2) > 0).mean() > 0.2  # the sheet fills a good part of the frame
    assert np.abs(cpu - gpu).max() <= 2  # float32 rounding of the normals, at most a level or two
