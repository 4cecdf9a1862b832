"""The two-level tissue body (chainsim.systems.engine.bodies.hybrid) and its kernels, against plain references
written here: trilinear weights from the textbook formula, the element stiffness from finite differences
of the projective body's own forces and from an independent linear FEM, the wake front from a
breadth-first search, and the settled shape from projective dynamics solved to convergence."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.bodies.hybrid import HybridBody, first_share
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.twolevel import trilinear_weights, wake_front
from chainsim.systems.engine.meshgen import links_from_cells, tet_grid


def _block(n=5, spacing=1.0):
    pos, tets, _ = tet_grid(n, n, n, spacing=spacing)
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    top = np.flatnonzero((pos[:, 2] > pos[:, 2].max() - 1e-9) & (np.abs(pos[:, 0] - pos[:, 0].mean()) < spacing))
    return pos, tets, fixed, top


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(*[st.floats(0.0, 5.0)] * 3), min_size=1, max_size=20),
    st.floats(0.5, 2.0),
)
def test_trilinear_weights_match_the_formula(points, h):
    p = np.array(points)
    lo = np.zeros(3)
    dims = np.array([int(np.ceil(5.0 / h)) + 1] * 3, dtype=np.int64)
    ids, w = trilinear_weights(p, lo, h, dims)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    # the weights reproduce any linear function of the grid's node positions exactly
    gx = np.stack(np.meshgrid(*[np.arange(d) * h for d in dims], indexing="ij"), -1).transpose(2, 1, 0, 3)
    nodes = gx.reshape(-1, 3)
    np.testing.assert_allclose((w[:, :, None] * nodes[ids]).sum(axis=1), p, atol=1e-9)
    for i, q in enumerate(p):  # plain formula for one corner: the cell's lower corner
        c = np.minimum(np.floor(q / h).astype(int), dims - 2)
        t = q / h - c
        flat = c[0] + dims[0] * (c[1] + dims[1] * c[2])
        k = list(ids[i]).index(flat)
        assert w[i, k] == pytest.approx(np.prod(1 - t), abs=1e-12)


def test_element_stiffness_is_the_projective_energys_hessian_at_rest():
    pos, tets, _, _ = _block(3)
    body = HybridBody(pos, tets, E=1000.0, nu=0.3, coarse=0.0)
    n = len(pos)
    dof = (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)
    K = np.zeros((3 * n, 3 * n))
    np.add.at(K, (np.repeat(dof, 12, axis=1).ravel(), np.tile(dof, (1, 12)).ravel()), body.K_e.ravel())
    u = np.random.default_rng(1).normal(size=(n, 3)) * 1e-7
    body.positions = pos + u
    f = body.elastic_forces()
    np.testing.assert_allclose(f.ravel(), -K @ u.ravel(), atol=1e-5 * np.abs(K @ u.ravel()).max())


def test_element_stiffness_matches_an_independent_linear_fem():
    from chainsim.tools.study.fem_linear import LinearFEM

    pos, tets, fixed, top = _block(4)
    lin = LinearFEM(pos, tets, 2000.0, 0.4, np.concatenate([fixed, top]))
    disp = np.zeros((len(fixed) + len(top), 3))
    disp[len(fixed) :, 2] = 1e-4
    u_ref = lin.solve(disp).u
    # the body's own K, solved directly on the free dofs
    body = HybridBody(pos, tets, E=2000.0, nu=0.4, coarse=0.0)
    n = len(pos)
    dof = (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)
    K = np.zeros((3 * n, 3 * n))
    np.add.at(K, (np.repeat(dof, 12, axis=1).ravel(), np.tile(dof, (1, 12)).ravel()), body.K_e.ravel())
    held = np.zeros(n, bool)
    held[fixed] = held[top] = True
    hd = np.flatnonzero(np.repeat(held, 3))
    fd = np.flatnonzero(np.repeat(~held, 3))
    u = np.zeros(3 * n)
    u[3 * top + 2] = 1e-4
    u[fd] = np.linalg.solve(K[np.ix_(fd, fd)], -K[np.ix_(fd, hd)] @ u[hd])
    np.testing.assert_allclose(u.reshape(n, 3), u_ref, atol=1e-9)


def _bfs_wake(adj, awake, change, threshold, rings):
    awake = awake.copy()
    front = {j for i in np.flatnonzero(awake & (change > threshold)) for j in adj[i] if not awake[j]}
    woke = 0
    for _ in range(rings):
        if not front:
            break
        for j in front:
            awake[j] = True
        woke += len(front)
        front = {k for j in front for k in adj[j] if not awake[k]}
    return awake, woke


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 4))
def test_wake_front_matches_breadth_first_search(seed, rings):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 40))
    links = rng.integers(0, n, size=(int(rng.integers(1, 3 * n)), 2))
    links = links[links[:, 0] != links[:, 1]]
    if len(links) == 0:
        links = np.array([[0, 1]])
    g = build_graph(n, links)
    adj = [set(g.indices[g.indptr[i] : g.indptr[i + 1]]) for i in range(n)]
    awake = rng.random(n) < 0.3
    change = rng.random(n)
    want, woke_ref = _bfs_wake(adj, awake, change, 0.5, rings)
    got = awake.copy()
    woke = wake_front(g.indptr, g.indices, got, change, 0.5, rings)
    np.testing.assert_array_equal(got, want)
    assert woke == woke_ref


def _converged_projective(pos, tets, fixed, top, lift, E=3000.0, nu=0.45):
    pd = ProjectiveBody(pos, tets, E=E, nu=nu, dynamic=False, fixed=fixed, iterations=10_000, tolerance=1e-10)
    pd.grab(top, pos[top] + [0.0, 0.0, lift])
    pd.step()
    return pd.positions.copy()


# without the coarse step the release is projective dynamics' slow creep back (a few tenths of a percent of
# the lift still to go after 300 frames); with it, the body is back to round-off of the lift
@pytest.mark.parametrize(
    "kw, back",
    [({}, 1e-3), ({"coarse": 0.0, "start": "chainmail"}, 1e-2), ({"coarse": 2.0, "cg_iterations": 20}, 1e-3)],
)
def test_settles_to_the_static_projective_solution_and_back_to_rest(kw, back):
    pos, tets, fixed, top = _block(6)
    lift = 0.5  # 10 % of the block's height
    ref = _converged_projective(pos, tets, fixed, top, lift)
    body = HybridBody(pos, tets, E=3000.0, nu=0.45, fixed=fixed, **kw)
    body.grab(top, pos[top] + [0.0, 0.0, lift])
    for _ in range(300):
        body.step()
    err = np.sqrt(np.mean(np.sum((body.positions - ref) ** 2, axis=1))) / lift
    assert err < 1e-3
    body.release()
    for _ in range(300):
        body.step()
    assert np.abs(body.positions - pos).max() < back * lift


def test_coarse_correction_settles_in_fewer_frames_than_cg_alone():
    pos, tets, fixed, top = _block(8)
    lift = 0.7
    ref = _converged_projective(pos, tets, fixed, top, lift)

    def frames(**kw):
        body = HybridBody(pos, tets, E=3000.0, nu=0.45, fixed=fixed, cg_iterations=6, **kw)
        body.grab(top, pos[top] + [0.0, 0.0, lift])
        for f in range(1, 200):
            body.step()
            if np.sqrt(np.mean(np.sum((body.positions - ref) ** 2, axis=1))) / lift < 0.01:
                return f
        return 200

    # measured on this 512-node block: 36 frames against 57; on 10k nodes the gap is wider (bench models)
    assert frames(coarse=3.0) < 0.8 * frames(coarse=0.0)


def test_the_coarse_grid_is_finer_for_nearly_incompressible_tissue_only():
    # coarse = "auto": a trilinear grid of 3 edges cannot follow a nearly volume-keeping answer, so from
    # nu 0.497 the body takes 2 (docs/choosing-a-model.md, the stiffness tables); tissue layers given
    # per tetrahedron after construction move the grid too
    pos, tets, fixed, _ = _block(4)
    soft = HybridBody(pos, tets, E=3e4, nu=0.45, fixed=fixed)
    stiff = HybridBody(pos, tets, E=3e4, nu=0.499, fixed=fixed)
    told = HybridBody(pos, tets, E=3e4, nu=0.499, fixed=fixed, coarse=3.0)
    assert (soft.coarse, stiff.coarse, told.coarse) == (3.0, 2.0, 3.0)
    assert len(np.unique(stiff._cids)) > len(np.unique(soft._cids))
    nu = np.full(len(tets), 0.45)
    nu[:3] = 0.499
    soft.set_materials(np.full(len(tets), 3e4), nu)
    told.set_materials(np.full(len(tets), 3e4), np.full(len(tets), 0.45))
    assert (soft.coarse, told.coarse) == (2.0, 3.0)
    with pytest.raises(UserError, match=r"coarse: expected auto, 0 \(off\) or a grid spacing"):
        HybridBody(pos, tets, nu=0.45, fixed=fixed, coarse="fine")
    with pytest.raises(UserError, match=r"^coarse: expected a number or auto, got 'fine'$"):
        make_body("hybrid", pos, tets=tets, fixed=fixed, coarse="fine")


_coords = st.floats(-10.0, 10.0, allow_nan=False)


@settings(max_examples=80, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 12), st.just(3)), elements=_coords), st.data())
def test_a_grabs_first_far_field_never_carries_the_grabbed_nodes_past_the_tool(far, data):
    moved = data.draw(arrays(np.float64, far.shape, elements=_coords))
    a = first_share(far, moved)
    assert 0.0 <= a <= 1.0
    # the best fit of the scaled field to the grabbed nodes' own move, against a plain search over shares
    shares = np.linspace(0.0, 1.0, 2001)
    misfit = [float(np.sum((t * far - moved) ** 2)) for t in shares]
    assert float(np.sum((a * far - moved) ** 2)) <= min(misfit) + 1e-9 * (1.0 + min(misfit))
    # a field carrying them twice as far as the tool moved them is taken at half; one short of it whole
    if float(np.sum(far * far)) > 1e-12:  # a field, not rounding (a grab moves nodes microns at least)
        assert first_share(far, far / 2.0) == pytest.approx(0.5)
        assert first_share(far / 2.0, far) == 1.0


def test_sleeping_solves_only_near_the_tool_and_stays_close_to_the_full_solve():
    pos, tets, _ = tet_grid(25, 9, 5, spacing=1.0)  # a long slab, base fixed, pulled at one end
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    top = np.flatnonzero((pos[:, 2] > 3.9) & (pos[:, 0] < 1.1) & (np.abs(pos[:, 1] - 4.0) < 1.1))
    lift = 0.4

    def run(sleep):
        body = HybridBody(pos, tets, E=3000.0, nu=0.45, fixed=fixed, sleep=sleep, wake_rings=2)
        body.grab(top, pos[top] + [0.0, 0.0, lift])
        for _ in range(60):
            body.step()
        return body

    full, asleep = run(0.0), run(0.01)
    # the far end sleeps (the lift moves about 500 of the 1,125 nodes by more than the threshold; the
    # awake region covers them with a few rings to spare)
    assert asleep.stats.extra["awake"] < 0.8 * len(pos)
    err = np.sqrt(np.mean(np.sum((asleep.positions - full.positions) ** 2, axis=1))) / lift
    assert err < 0.02
    # released and settled, the body falls asleep at rest
    asleep.release()
    for _ in range(200):
        asleep.step()
    assert np.abs(asleep.positions - pos).max() < 0.02 * lift
    assert asleep.stats.extra["awake"] == 0


def test_a_body_the_pull_mostly_wakes_wakes_whole_and_keeps_one_set_up_while_held():
    """A block lifted at its top centre: the wake front crosses most of it within frames. Each new awake
    set costs a set-up (a coarse factorisation, 0.2-0.5 s at 10k nodes), and a front that crept on over
    the last sleepers paid one a frame. Past WAKE_ALL of the free nodes the whole body wakes at once; from
    then on the hold, and a further pull of the same nodes, reuse one set-up, and the shape is the whole
    solve's."""
    from chainsim.systems.engine.bodies.hybrid import WAKE_ALL  # noqa: PLC0415

    pos, tets, _ = tet_grid(13, 13, 10, spacing=1.0)
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    top = np.flatnonzero((pos[:, 2] > 8.9) & (np.abs(pos[:, 0] - 6.0) < 1.1) & (np.abs(pos[:, 1] - 6.0) < 1.1))
    whole = HybridBody(pos, tets, E=3e4, nu=0.45, fixed=fixed, unit=1e-3)
    body = HybridBody(pos, tets, E=3e4, nu=0.45, fixed=fixed, unit=1e-3, sleep=0.015, wake_rings=2)
    awake, built = [], []
    for lift in (0.8, 1.2):
        for b in (whole, body):
            b.grab(top, pos[top] + [0.0, 0.0, lift])
        for _ in range(30):
            whole.step(1 / 60)
            extra = body.step(1 / 60).extra
            awake.append(extra["awake"])
            built.append(extra["setups_built"])
    # asleep at first (a grab wakes only around the tool), never left with most but not all of it awake
    assert awake[0] < 0.5 * len(pos)
    most = WAKE_ALL * (len(pos) - len(fixed)) + len(fixed)
    assert all(a < most or a == len(pos) for a in awake), awake
    woke = awake.index(len(pos))
    assert awake[woke:] == [len(pos)] * (len(awake) - woke)
    # the set-up made for the whole body (the frame after it woke) serves every later frame
    assert built[-1] == built[woke + 1]
    err = np.sqrt(np.mean(np.sum((body.positions - whole.positions) ** 2, axis=1))) / 1.2
    assert err < 0.01


def test_settings_are_checked_and_the_factory_builds_it():
    pos, tets, fixed, _ = _block(3)
    for bad in ({"coarse": 1.0}, {"start": "cascade"}, {"sleep": 1.5}, {"wake_rings": 0}):
        with pytest.raises(UserError):
            HybridBody(pos, tets, **bad)
    with pytest.raises(UserError):
        make_body("hybrid", pos, triangles=np.array([[0, 1, 2]]))
    body = make_body("hybrid", pos, tets=tets, fixed=fixed, coarse=2.0, cg_iterations=4)
    assert isinstance(body, HybridBody) and body.cg_iterations == 4 and body.coarse == 2.0
    assert len(links_from_cells(tets)) == body.graph.n_links


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0, 80]), st.floats(0.0, 0.08))
def test_local_forces_match_the_projective_local_step_on_the_listed_elements(seed, rot, scale):
    """With no refinement both use the given rotations; refined to convergence both reach F's polar
    rotation (their updates differ on the way: the batched one has no trigonometry)."""
    from chainsim.systems.engine.kernels.projective import local_step
    from chainsim.systems.engine.kernels.twolevel import local_forces

    pos, tets, _, _ = _block(3)
    rng = np.random.default_rng(seed)
    body = HybridBody(pos, tets, E=2000.0, nu=0.4, coarse=0.0)
    x = pos * (1.0 + scale * rng.normal(size=pos.shape))
    q0 = rng.normal(size=(len(tets), 4))
    if rot:  # start within a quarter turn of the answer, as a warm start is
        q0 = np.tile([1.0, 0.0, 0.0, 0.0], (len(tets), 1)) + 0.2 * q0
    q0 /= np.linalg.norm(q0, axis=1)[:, None]
    pick = rng.random(len(tets)) < 0.6
    ref_q, got_q = q0.copy(), q0.copy()
    ref, got = np.zeros_like(x), np.full_like(x, np.nan)
    local_step(x, tets, body.D, pick, body.w_arap, body.w_vol, ref_q, rot, ref)
    # with the compression barrier off (j_barrier 0) the forces are projective dynamics' own
    local_forces(x, tets, body.D, np.flatnonzero(pick), body.w_arap, body.w_vol, got_q, rot, got, 0.0)
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-7 * np.abs(ref).max())
    sign = np.sign(np.sum(got_q * ref_q, axis=1))[:, None]  # q and -q are one rotation
    np.testing.assert_allclose((got_q * sign)[pick], ref_q[pick], atol=1e-7)
    assert np.array_equal(got_q[~pick], q0[~pick])  # elements not listed keep their rotation


def test_the_linear_start_brings_a_grab_near_its_answer_in_one_frame():
    pos, tets, fixed, top = _block(8)
    lift = 0.7
    ref = _converged_projective(pos, tets, fixed, top, lift)

    def first_frame(start):
        body = HybridBody(pos, tets, E=3000.0, nu=0.45, fixed=fixed, start=start)
        body.grab(top, pos[top] + [0.0, 0.0, lift])
        body.step()
        return np.sqrt(np.mean(np.sum((body.positions - ref) ** 2, axis=1))) / lift

    assert first_frame("linear") < 0.5 * first_frame("none")


def test_release_returns_to_rest_in_one_frame_after_a_cut_too():
    pos, tets, fixed, top = _block(5)
    body = HybridBody(pos, tets, E=2000.0, nu=0.4, fixed=fixed)
    body.grab(top, pos[top] + [0.0, 0.0, 0.8])
    for _ in range(3):
        body.step()
    assert np.abs(body.positions - pos).max() > 0.5
    body.cut([1.0, -1.0, 3.5], [1.0, 5.0, 3.5], normal=[0.0, 0.0, -1.0], depth=2.0)
    body.step()
    body.release()
    body.step()
    # no load and the supports at rest: the static answer is the rest shape, reached at once
    np.testing.assert_allclose(body.positions, pos, atol=1e-12)
    body.step()
    np.testing.assert_allclose(body.positions, pos, atol=1e-12)


def test_a_small_awake_region_with_more_coarse_nodes_than_it_can_span_still_solves():
    # a 10 x 10 x 20 mm slab of 2.5 mm tetrahedra: the first wake covers fewer solved nodes than coarse
    # nodes, so the coarse matrix is singular in directions the forces never reach
    from chainsim.tools.bench.sleeping import SETTING, slab

    pos, tets, fixed, patch = slab(10.0, 2.5)
    body = HybridBody(pos, tets, E=3e4, nu=0.45, fixed=fixed, unit=1e-3, sleep=0.015, **SETTING)
    for k in range(1, 5):
        body.grab(patch, pos[patch] + [0.0, 0.0, 0.25 * k])
        body.step(1 / 60)
        assert np.all(np.isfinite(body.positions))
    assert np.allclose(body.positions[patch, 2], pos[patch, 2] + 1.0)
    # the free nodes follow: the lift reaches the nodes within 8 mm below the patch
    below = np.flatnonzero((np.abs(pos[:, 0] - 5.0) < 1e-9) & (np.abs(pos[:, 1] - 5.0) < 1e-9) & (pos[:, 2] > 12.0))
    assert np.all(body.positions[below, 2] - pos[below, 2] > 0.0)


def _plain_energy(x, tets, D, elems, mu_v, lam_v, j_b):
    """The hybrid body's energy written out per element with numpy's polar decomposition (SVD), the
    compression barrier included: the reference the kernel's energy and forces are checked against."""
    total = 0.0
    for t in elems:
        F = x[tets[t]].T @ D[t]
        U, S, Vt = np.linalg.svd(F)
        R = U @ Vt
        if np.linalg.det(R) < 0:  # the nearest rotation (not reflection)
            U[:, -1] *= -1
            R = U @ Vt
        total += mu_v[t] * np.sum((F - R) ** 2) + 0.5 * lam_v[t] * (np.trace(R.T @ F) - 3.0) ** 2
        J = np.linalg.det(F)
        if J < j_b:
            kappa = lam_v[t] + 2.0 * mu_v[t] / 3.0
            jc = max(J, 0.01)
            slope = -kappa * (j_b - jc) * (j_b + jc) / jc**2
            total += kappa * (j_b - jc) ** 2 / jc + slope * (J - jc)
    return total


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 0.35), st.sampled_from([0.0, 0.5, 0.9]))
def test_local_forces_are_minus_the_gradient_of_the_energy_they_return_barrier_included(seed, squeeze, j_b):
    """Energy and min det F against a plain SVD reference, forces against its finite differences, on
    random shapes that squeeze some elements below the barrier's ratio."""
    from chainsim.systems.engine.kernels.twolevel import local_forces

    pos, tets, _, _ = _block(2)
    rng = np.random.default_rng(seed)
    body = HybridBody(pos, tets, E=2000.0, nu=0.4, coarse=0.0)
    x = pos + 0.05 * rng.normal(size=pos.shape)
    x[:, 2] *= 1.0 - squeeze  # squeezed flat by up to a third: ratios near and under j_b
    elems = np.flatnonzero(rng.random(len(tets)) < 0.7)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (len(tets), 1))
    rhs = np.zeros_like(x)
    energy, min_j = local_forces(x, tets, body.D, elems, body.w_arap, body.w_vol, quats, 100, rhs, j_b)
    mu_v, lam_v = body.w_arap / 2.0, body.w_vol / 3.0
    ref = _plain_energy(x, tets, body.D, elems, mu_v, lam_v, j_b)
    assert energy == pytest.approx(ref, rel=1e-8, abs=1e-12 * abs(ref))
    dets = [np.linalg.det(x[tets[t]].T @ body.D[t]) for t in elems]
    assert min_j == pytest.approx(min(dets), rel=1e-10)
    # forces = rhs - L x over the listed elements: minus the energy's gradient
    L = np.zeros((len(x), len(x)))
    for t in elems:
        L[np.ix_(tets[t], tets[t])] += (body.w_arap[t] + body.w_vol[t]) * body.D[t] @ body.D[t].T
    forces = rhs - L @ x
    h = 1e-6
    for i, a in zip(rng.integers(0, len(x), 6), rng.integers(0, 3, 6)):
        xp, xm = x.copy(), x.copy()
        xp[i, a] += h
        xm[i, a] -= h
        grad = (
            _plain_energy(xp, tets, body.D, elems, mu_v, lam_v, j_b)
            - _plain_energy(xm, tets, body.D, elems, mu_v, lam_v, j_b)
        ) / (2 * h)
        assert -grad == pytest.approx(forces[i, a], rel=1e-4, abs=1e-6 * np.abs(forces).max())
