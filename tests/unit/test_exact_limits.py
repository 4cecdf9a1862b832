"""Exact limits as a user meets them: `chainsim chainmail --exact` on the prp face and on tetrahedral
volumes leaves every link inside its limits, fixed elements where they were and the target reached
where it can be; `--stats` reports what each order's plain cascade leaves outside."""

from __future__ import annotations

import numpy as np
import pytest

from chainsim.game.cli.commands.chainmail import make_body, move
from chainsim.systems.engine.kernels.chainmail import material_arrays
from chainsim.systems.engine.kernels.exact import violations
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.tools.bench import exact_cases

A_MIN, A_MAX, BETA = exact_cases.MATERIAL


def save_case(path, case):
    arrays = {"positions": case.rest, "links": case.links}
    if case.fixed is not None:
        arrays["fixed"] = np.flatnonzero(case.fixed)
    np.savez(path, **arrays)
    return path


def run_exact(cli, tmp_path, case, mm, *extra):
    mesh = save_case(tmp_path / "case.npz", case)
    out = tmp_path / f"o{mm:g}.npz"
    target = case.rest[case.grab] + mm * case.direction
    code, stdout, err = cli(
        "chainmail", mesh, "--grab", case.grab, "--to", *target, "--alpha-min", A_MIN, "--alpha-max", A_MAX,
        "--beta", BETA, "--exact", "--out", out, *extra,
    )  # fmt: skip
    assert code == 0, err
    with np.load(out) as z:
        result = {k: z[k] for k in z.files}
    return result, target, stdout


def limits_of(case, pos):
    graph = build_graph(len(case.rest), case.links)
    return violations(case.rest, pos, graph, *material_arrays(graph.n_links, A_MIN, A_MAX, BETA))


@pytest.fixture(scope="module")
def skin():
    return exact_cases.skin_case(fixed_rim=True)


@pytest.mark.parametrize("mm", exact_cases.PULLS_MM)
def test_skin_pulled_with_the_rim_fixed_keeps_every_link_inside(cli, tmp_path, skin, mm):
    z, target, _ = run_exact(cli, tmp_path, skin, mm)
    pos = z["positions"]
    v = limits_of(skin, pos)
    assert v.outside == 0 and v.worst <= 1e-6
    assert float(z["residual"]) <= 1e-6
    np.testing.assert_array_equal(pos[skin.fixed], skin.rest[skin.fixed])
    reached = np.linalg.norm(pos[skin.grab] - target)
    assert float(z["shortfall"]) == pytest.approx(reached, abs=1e-9)
    if mm == 8.0:
        assert reached == 0.0  # the small pull is within reach of the rim
    # the plain cascade, same pull, leaves links outside: what --exact is for
    assert mm == 8.0 or limits_of(skin, plain_move(skin, target)).outside > 0


def plain_move(case, target):
    fixed = np.flatnonzero(case.fixed) if case.fixed is not None else []
    return move(make_body(case.rest, case.links, fixed, *exact_cases.MATERIAL), case.grab, target).positions


@pytest.mark.parametrize("mm", exact_cases.PULLS_MM)
def test_skin_with_nothing_fixed_reaches_every_target(cli, tmp_path, mm):
    case = exact_cases.skin_case(fixed_rim=False)
    z, target, _ = run_exact(cli, tmp_path, case, mm)
    assert float(z["shortfall"]) == 0.0
    np.testing.assert_array_equal(z["positions"][case.grab], target)
    v = limits_of(case, z["positions"])
    assert v.outside == 0 and v.worst <= 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("volume", ["skin", "block"])
def test_tetrahedral_volumes_end_inside(cli, tmp_path, volume):
    case = exact_cases.skin_case(True, volume=True) if volume == "skin" else exact_cases.block_case(9)
    for mm in (8.0, 46.0):
        z, _, _ = run_exact(cli, tmp_path, case, mm)
        v = limits_of(case, z["positions"])
        assert v.outside == 0 and v.worst <= 1e-6
        np.testing.assert_array_equal(z["positions"][case.fixed], case.rest[case.fixed])


def test_stats_report_this_result_and_every_order(cli, tmp_path, skin):
    _, _, out = run_exact(cli, tmp_path, skin, 22.0, "--stats", "--order", "depth-first")
    lines = out.splitlines()
    assert lines[0].startswith("result (depth-first, exact)") and "0 of" in lines[0]
    assert "shortfall" in lines[1] and "target out of reach" in lines[1]
    for name in ("breadth-first", "balanced", "schill", "depth-first"):
        row = next(line for line in lines if line.strip().startswith(name))
        share = float(row.split()[2])
        assert share > 0.0  # every order's plain cascade leaves some of this pull's links outside
