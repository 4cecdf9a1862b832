"""`chainsim chainmail`: the OUT.npz invariants on curves, sheets, surfaces, volumes and random graphs, and
the refusal of bad input (exit 2, one line, nothing written)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.game.cli.main import main
from chainsim.systems.engine import meshgen

ROOT = Path(__file__).resolve().parents[2]


def save_graph(path: Path, pos, links, fixed=None) -> Path:
    arrays = {"positions": pos, "links": links}
    if fixed is not None:
        arrays["fixed"] = fixed
    np.savez(path, **arrays)
    return path


def run_cli(mesh: Path, out: Path, grab: int, to, amin, amax, beta, *extra) -> int:
    argv = [
        "chainmail",
        str(mesh),
        "--grab",
        str(grab),
        "--to",
        *map(str, to),
        "--alpha-min",
        str(amin),
        "--alpha-max",
        str(amax),
        "--beta",
        str(beta),
        "--out",
        str(out),
        *extra,
    ]
    return main(argv)


def box(rest, pos, e, s, amin, amax, beta):
    """Valid region of e w.r.t. sponsor s (thesis 5.2.2 / 5.2.6), plain numpy."""
    d = rest[e] - rest[s]
    ad = np.abs(d)
    other = ad.sum() - ad
    lo_off = amin * ad - beta * other
    hi_off = amax * ad + beta * other
    lo = np.where(d >= 0, pos[s] + lo_off, pos[s] - hi_off)
    hi = np.where(d >= 0, pos[s] + hi_off, pos[s] - lo_off)
    return lo, hi


def check_result(out: Path, rest, links, grab, target, amin, amax, beta, fixed=(), relaxed=False):
    with np.load(out) as z:
        pos, order, sponsor = z["positions"], z["order"], z["sponsor"]
    n = len(rest)
    assert pos.shape == rest.shape and pos.dtype == np.float64
    assert order.dtype == np.int64 and sponsor.dtype == np.int64 and sponsor.shape == (n,)
    assert np.all(np.isfinite(pos))
    assert len(np.unique(order)) == len(order)
    if grab in set(np.asarray(fixed).tolist()):
        assert len(order) == 0 and np.array_equal(pos, rest)
        return pos, order, sponsor
    assert order[0] == grab and sponsor[grab] == -1
    np.testing.assert_allclose(pos[grab], target)
    moved = np.zeros(n, bool)
    moved[order] = True
    assert np.all(sponsor[~moved] == -1)
    assert not moved[list(fixed)].any() if len(fixed) else True
    unmoved = ~moved
    np.testing.assert_array_equal(pos[unmoved], rest[unmoved])
    linkset = {tuple(sorted(pair)) for pair in links.tolist()}
    rank = np.full(n, -1)
    rank[order] = np.arange(len(order))
    for e in order[1:]:
        s = sponsor[e]
        assert s >= 0 and rank[s] < rank[e], "a sponsor moves before the element it moves"
        assert tuple(sorted((e, s))) in linkset, "sponsor and element are linked"
        if not relaxed:
            lo, hi = box(rest, pos, e, s, amin, amax, beta)
            tol = 1e-9 * (1 + np.abs(pos[s]).max())
            assert np.all(pos[e] >= lo - tol) and np.all(pos[e] <= hi + tol)
    return pos, order, sponsor


CASES = {
    "curve-1d": lambda: meshgen.chain(30, 1.0, dim=1),
    "curve-2d": lambda: meshgen.chain(30, 1.0, dim=2),
    "curve-3d": lambda: meshgen.chain(30, 1.0, dim=3),
    "grid-2d": lambda: meshgen.grid((11, 11)),
    "sheet-3d": lambda: meshgen.triangulated_grid(9, 9, 1.0, dim=3)[::2],
    "tet-volume": lambda: meshgen.tet_grid(5, 5, 5)[::2],
    "random-graph": lambda: meshgen.random_graph(80, 200, 3, np.random.default_rng(3), scale=10.0),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("material", [(1.0, 1.0, 0.0), (0.8, 1.2, 0.1), (0.5, 2.5, 0.3)])
def test_outputs_satisfy_the_invariants(tmp_path, case, material):
    pos, links = CASES[case]()
    mesh = save_graph(tmp_path / "m.npz", pos, links)
    grab = len(pos) // 2
    target = pos[grab] + np.linspace(2.5, -1.5, pos.shape[1])
    out = tmp_path / "out.npz"
    assert run_cli(mesh, out, grab, target, *material) == 0
    check_result(out, pos, links, grab, target, *material)


@pytest.mark.parametrize("case", ["grid-2d", "sheet-3d", "tet-volume"])
def test_rigid_material_translates_a_connected_mesh(tmp_path, case):
    pos, links = CASES[case]()
    mesh = save_graph(tmp_path / "m.npz", pos, links)
    shift = np.linspace(3.0, 1.0, pos.shape[1])
    out = tmp_path / "out.npz"
    assert run_cli(mesh, out, 4, pos[4] + shift, 1.0, 1.0, 0.0) == 0
    with np.load(out) as z:
        np.testing.assert_allclose(z["positions"], pos + shift, atol=1e-12)
        assert len(z["order"]) == len(pos)


def test_fixed_elements_stay_and_block(tmp_path):
    pos, links = meshgen.chain(10, 1.0, dim=1)
    mesh = save_graph(tmp_path / "m.npz", pos, links, fixed=np.array([5]))
    out = tmp_path / "out.npz"
    assert run_cli(mesh, out, 0, [-4.0], 1.0, 1.0, 0.0) == 0
    p, order, _ = check_result(out, pos, links, 0, [-4.0], 1.0, 1.0, 0.0, fixed=[5])
    assert set(order.tolist()) == {0, 1, 2, 3, 4}
    np.testing.assert_array_equal(p[5:], pos[5:])


def test_small_move_inside_soft_limits_moves_only_the_grabbed_element(tmp_path):
    pos, links = meshgen.grid((11, 11))
    mesh = save_graph(tmp_path / "m.npz", pos, links)
    out = tmp_path / "out.npz"
    assert run_cli(mesh, out, 60, pos[60] + [0.1, 0.0], 0.5, 2.5, 0.3) == 0
    with np.load(out) as z:
        assert z["order"].tolist() == [60]


def test_relaxation_keeps_the_grab_and_reports_the_same_cascade(tmp_path):
    pos, links = meshgen.grid((11, 11))
    mesh = save_graph(tmp_path / "m.npz", pos, links)
    raw, relaxed = tmp_path / "raw.npz", tmp_path / "relaxed.npz"
    target = pos[60] + [3.0, 2.0]
    assert run_cli(mesh, raw, 60, target, 0.8, 1.2, 0.1, "--relax", "0") == 0
    assert run_cli(mesh, relaxed, 60, target, 0.8, 1.2, 0.1, "--relax", "5") == 0
    check_result(relaxed, pos, links, 60, target, 0.8, 1.2, 0.1, relaxed=True)
    with np.load(raw) as a, np.load(relaxed) as b:
        np.testing.assert_array_equal(a["order"], b["order"])
        np.testing.assert_array_equal(a["sponsor"], b["sponsor"])
        assert not np.array_equal(a["positions"], b["positions"])


def test_mesh_files_are_read_through_the_importer(tmp_path):
    import meshio

    p, tets, links = meshgen.tet_grid(4, 4, 4)
    meshio.write(tmp_path / "v.vtu", meshio.Mesh(p, [("tetra", tets)]))
    out = tmp_path / "out.npz"
    assert run_cli(tmp_path / "v.vtu", out, 0, [-2.0, -2.0, -2.0], 0.8, 1.2, 0.1) == 0
    check_result(out, p, links, 0, [-2.0, -2.0, -2.0], 0.8, 1.2, 0.1)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 10_000),
    dim=st.integers(1, 3),
    amin=st.floats(0.0, 1.0),
    amax=st.floats(1.0, 3.0),
    beta=st.floats(0.0, 0.5),
    order=st.sampled_from(["fifo", "balanced", "schill"]),
)
def test_random_graphs_and_materials(tmp_path, seed, dim, amin, amax, beta, order):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 60))
    pos, links = meshgen.random_graph(n, int(rng.integers(n - 1, 3 * n)), dim, rng, scale=5.0)
    mesh = save_graph(tmp_path / f"m{seed}.npz", pos, links)
    grab = int(rng.integers(0, n))
    target = pos[grab] + rng.normal(0, 3.0, size=dim)
    out = tmp_path / f"o{seed}.npz"
    assert run_cli(mesh, out, grab, target, amin, amax, beta, "--order", order) == 0
    check_result(out, pos, links, grab, target, amin, amax, beta)


# -- bad input ---------------------------------------------------------------------------------


def _bad_npz(tmp_path: Path, name: str, **arrays) -> Path:
    path = tmp_path / f"{name}.npz"
    np.savez(path, **arrays)
    return path


GOOD = dict(grab=3, to=["1.0", "2.0"], amin="0.8", amax="1.2", beta="0.1")


def _bad_cases(tmp_path: Path, good: Path):
    pos, links = meshgen.grid((5, 5))
    return [
        ("--alpha-min", good, dict(amin="1.5")),
        ("--alpha-min", good, dict(amin="-0.1")),
        ("--alpha-max", good, dict(amax="0.9")),
        ("--beta", good, dict(beta="-1")),
        ("--beta", good, dict(beta="nan")),
        ("--alpha-max", good, dict(amax="inf")),
        ("--to", good, dict(to=["1.0", "nan"])),
        ("--to", good, dict(to=["1.0"])),
        ("--to", good, dict(to=["1", "2", "3"])),
        ("--grab", good, dict(grab=25)),
        ("--grab", good, dict(grab=-1)),
        ("links", _bad_npz(tmp_path, "outofrange", positions=pos, links=np.array([[0, 99]])), {}),
        ("itself", _bad_npz(tmp_path, "self", positions=pos, links=np.array([[0, 1], [2, 2]])), {}),
        ("more than once", _bad_npz(tmp_path, "dup", positions=pos, links=np.array([[0, 1], [1, 0]])), {}),
        ("links", _bad_npz(tmp_path, "shape", positions=pos, links=np.arange(6)), {}),
        ("links", _bad_npz(tmp_path, "float", positions=pos, links=links.astype(float)), {}),
        ("positions", _bad_npz(tmp_path, "pos4d", positions=np.zeros((5, 4)), links=np.array([[0, 1]])), {}),
        ("positions", _bad_npz(tmp_path, "nanpos", positions=np.full((3, 2), np.nan), links=np.array([[0, 1]])), {}),
        ("links", _bad_npz(tmp_path, "nolinks", positions=pos), {}),
        ("fixed", _bad_npz(tmp_path, "fixed", positions=pos, links=links, fixed=np.array([40])), {}),
        ("not a readable", _write(tmp_path / "garbage.npz", b"this is not a zip file"), {}),
        ("not found", tmp_path / "missing.npz", {}),
        ("unsupported", _write(tmp_path / "mesh.xyz", b"1 2 3"), {}),
    ]


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys):
    pos, links = meshgen.grid((5, 5))
    good = save_graph(tmp_path / "good.npz", pos, links)
    for i, (needle, mesh, change) in enumerate(_bad_cases(tmp_path, good)):
        a = dict(GOOD, **change)
        out = tmp_path / f"out{i}.npz"
        code = run_cli(mesh, out, a["grab"], a["to"], a["amin"], a["amax"], a["beta"])
        err = capsys.readouterr().err
        assert code == 2, (needle, err)
        assert len(err.strip().splitlines()) == 1, err
        assert needle in err, (needle, err)
        assert not out.exists()
        assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def _subprocess(*args, cwd=ROOT):
    env = dict(os.environ)
    return subprocess.run(
        [sys.executable, "-m", "chainsim.game", "chainmail", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_command_line_success_and_failure(tmp_path):
    pos, links = meshgen.grid((7, 7))
    mesh = save_graph(tmp_path / "g.npz", pos, links)
    out = tmp_path / "out.npz"
    ok = _subprocess(
        mesh, "--grab", 24, "--to", 3, 5, "--alpha-min", 0.8, "--alpha-max", 1.2, "--beta", 0.1, "--out", out
    )
    assert ok.returncode == 0, ok.stderr
    check_result(out, pos, links, 24, [3.0, 5.0], 0.8, 1.2, 0.1)
    before = out.read_bytes()
    bad = _subprocess(
        mesh, "--grab", 24, "--to", 3, 5, "--alpha-min", 0.8, "--alpha-max", 0.5, "--beta", 0.1, "--out", out
    )
    assert bad.returncode == 2
    assert bad.stderr.strip().count("\n") == 0 and "--alpha-max" in bad.stderr
    assert "Traceback" not in bad.stderr
    assert out.read_bytes() == before, "a refused run leaves an earlier result alone"
    typo = _subprocess(
        mesh,
        "--grab",
        "x",
        "--to",
        3,
        5,
        "--alpha-min",
        0.8,
        "--alpha-max",
        1.2,
        "--beta",
        0.1,
        "--out",
        tmp_path / "never.npz",
    )
    assert typo.returncode == 2 and "--grab" in typo.stderr and typo.stderr.strip().count("\n") == 0
    assert not (tmp_path / "never.npz").exists()


# -- orders, conformance and --exact -------------------------------------------------------------


def test_fifo_is_the_breadth_first_order(tmp_path):
    pos, links = meshgen.grid((9, 9))
    mesh = save_graph(tmp_path / "m.npz", pos, links)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    target = pos[40] + [2.5, -1.0]
    assert run_cli(mesh, a, 40, target, 0.8, 1.2, 0.1, "--order", "fifo") == 0
    assert run_cli(mesh, b, 40, target, 0.8, 1.2, 0.1, "--order", "breadth-first") == 0
    with np.load(a) as za, np.load(b) as zb:
        assert za.files == zb.files == ["positions", "order", "sponsor"]  # no exact-pass arrays without --exact
        for k in za.files:
            np.testing.assert_array_equal(za[k], zb[k])


@pytest.mark.parametrize("order", ["breadth-first", "balanced", "schill", "depth-first"])
def test_without_exact_the_cli_is_the_plain_cascade(tmp_path, order):
    """Conformance: the CLI's result is the cascade kernel's, bit for bit (the kernel itself is checked
    against the thesis-rule reference in tests/kernels)."""
    from chainsim.systems.engine.chainmail_params import order_code
    from chainsim.systems.engine.kernels.chainmail import cascade, material_arrays
    from chainsim.systems.engine.kernels.graph import build_graph

    pos, _, links = meshgen.triangulated_grid(10, 10, dim=3)
    fixed = np.arange(10)
    mesh = save_graph(tmp_path / "m.npz", pos, links, fixed=fixed)
    out = tmp_path / "o.npz"
    target = pos[55] + [3.0, 1.0, 4.0]
    assert run_cli(mesh, out, 55, target, 0.8, 1.2, 0.1, "--order", order) == 0
    graph = build_graph(len(pos), links)
    mask = np.zeros(len(pos), bool)
    mask[fixed] = True
    p = pos.copy()
    moved, _ = cascade(
        pos,
        p,
        graph,
        *material_arrays(len(links), 0.8, 1.2, 0.1),
        [55],
        target[None],
        fixed=mask,
        order=order_code(order),
    )
    with np.load(out) as z:
        np.testing.assert_array_equal(z["positions"], p)
        np.testing.assert_array_equal(z["order"], moved)


def test_exact_writes_residual_shortfall_and_changed(tmp_path):
    pos, links = meshgen.chain(6, 1.0, dim=1)
    mesh = save_graph(tmp_path / "m.npz", pos, links, fixed=np.array([0]))
    out = tmp_path / "o.npz"
    assert run_cli(mesh, out, 5, [10.0], 0.8, 1.2, 0.0, "--exact") == 0
    with np.load(out) as z:
        np.testing.assert_allclose(z["positions"][:, 0], 1.2 * np.arange(6), atol=1e-12)
        assert float(z["shortfall"]) == pytest.approx(4.0)
        assert float(z["residual"]) <= 1e-12
        assert 5 in z["changed"].tolist()


def test_exact_without_relaxation_is_one_exact_step(tmp_path):
    """--exact with --relax 0 is the exact step (kernels.exact.exact_move, bit for bit): every link inside,
    fixed elements kept, each element on every axis no further from rest than the cascade followed by the
    exact-limit pass puts it (the step's shape is the nearest); with --relax N the cascade path is kept."""
    from chainsim.systems.engine.kernels.chainmail import cascade, material_arrays
    from chainsim.systems.engine.kernels.exact import exact_limits, exact_move, violations
    from chainsim.systems.engine.kernels.graph import build_graph

    pos, _, links = meshgen.tet_grid(6, 6, 6)
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    base = np.flatnonzero(pos[:, 2] <= pos[:, 2].min() + 1e-9)
    mesh = save_graph(tmp_path / "m.npz", pos, links, fixed=base)
    grab = int(np.argmax(pos.sum(axis=1)))
    graph = build_graph(len(pos), links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    mask = np.zeros(len(pos), bool)
    mask[base] = True
    for lift in ([1.5, -0.5, 2.0], [0.0, 0.0, 40.0]):  # in reach, then out of reach
        target = pos[grab] + np.array(lift)
        out = tmp_path / "o.npz"
        assert run_cli(mesh, out, grab, target, 0.8, 1.2, 0.1, "--exact") == 0
        step = pos.copy()
        changed, res = exact_move(pos, step, graph, *mats, [grab], target[None], mask)
        old = pos.copy()
        moved, _ = cascade(pos, old, graph, *mats, [grab], target[None], fixed=mask)
        exact_limits(pos, old, graph, *mats, moved, [grab], target[None], mask)
        with np.load(out) as z:
            np.testing.assert_array_equal(z["positions"], step)
            np.testing.assert_array_equal(z["order"], changed)
            np.testing.assert_array_equal(z["changed"], changed)
            assert np.all(z["sponsor"] == -1)
            assert float(z["shortfall"]) == pytest.approx(res.shortfall, abs=0.0)
            assert float(z["residual"]) <= 1e-12
            p = z["positions"]
        assert violations(pos, p, graph, *mats).outside == 0
        np.testing.assert_array_equal(p[base], pos[base])
        assert np.all(np.abs(p - pos) <= np.abs(old - pos) + 1e-9)
    out = tmp_path / "r.npz"
    assert run_cli(mesh, out, grab, pos[grab] + [1.5, -0.5, 2.0], 0.8, 1.2, 0.1, "--exact", "--relax", "2") == 0
    with np.load(out) as z:
        assert np.any(z["sponsor"] >= 0)  # the cascade path, relaxation and the exact-limit pass
        assert violations(pos, z["positions"], graph, *mats).outside == 0
