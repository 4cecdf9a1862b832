"""`chainsim bench sheet`: the slab reference behaves as the FEM must (point symmetry, a linear response to a
small lift, a coarser slab close to the finer one), the table has a row for every setting and baseline,
and bad arguments are one clear line (exit 2)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from chainsim.game.cli.main import main
from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import sheet as S


def test_reference_small_lift_is_linear_with_the_symmetry_of_its_mesh():
    s = S.sheet(5.0, 2)
    d = 0.01
    refs = S.reference(s, 1e4, 0.45, [d, 2 * d])
    u1, u2 = refs[d], refs[2 * d]
    assert u1[s.surf_grabbed, 2] == pytest.approx(d) and u1[s.surf_fixed].max() == 0.0
    # u(d) = L d + Q d^2 + ...: the linear and the quadratic response, from two lifts
    lin, quad = 2 * u1 - u2 / 2, (u2 - 2 * u1) / 2
    assert np.abs(quad).max() < 1e-3 * np.abs(lin).max()  # a small lift is in the linear range
    # the mesh (cubes split about their main diagonal) is its own image under the point reflection P through
    # the sheet's centre, which turns a lift into a push: the linear response is even under P and the
    # quadratic one odd (the mirror x -> 40 - x, which the mesh lacks, breaks both by several %)
    flip = np.lexsort((S.SIDE_MM - s.surf[:, 0], S.SIDE_MM - s.surf[:, 1]))
    assert np.allclose(s.surf[flip, :2], S.SIDE_MM - s.surf[:, :2])
    assert np.abs(lin[flip] - lin).max() < 1e-6 * np.abs(lin).max()
    assert np.abs(quad[flip] + quad).max() < 0.05 * np.abs(quad).max()


def test_the_reference_resolves_more_than_a_no_physics_shape():
    fine, coarse = S.sheet(2.0, 2), S.sheet(4.0, 2)
    lift = 4.0
    ref, check = S.reference(fine, 1e4, 0.45, [lift])[lift], S.reference(coarse, 1e4, 0.45, [lift])[lift]
    disc = S._errors(check, fine.interpolate(ref, coarse.surf), lift)[0]
    cone = S._errors(S.baselines(fine, lift)[S.BASELINES[1]], ref, lift)[0]
    assert disc < 0.8 * cone  # the coarser slab is nearer the finer one than the cone is
    assert ref[fine.surf_fixed].max() == 0.0 and ref[fine.surf_grabbed, 2] == pytest.approx(lift)


def test_the_table_has_every_setting_and_baseline(tmp_path):
    args = SimpleNamespace(quick=True, E=1e4, nu=0.45, lifts="2,6", frames=4, out=str(tmp_path))
    assert S.run(args) == 0
    info = json.loads((tmp_path / "results.json").read_text())
    names = [r["setting"] for r in info["rows"]]
    assert names == [n for _, n, _ in S.SETTINGS] + list(S.BASELINES)
    md = (tmp_path / "results.md").read_text()
    assert all(f"| {n} |" in md for n in names) and "load average" in md
    assert (tmp_path / "speed_accuracy.png").stat().st_size > 10_000
    patch_only = next(r for r in info["rows"] if r["setting"] == S.BASELINES[0])
    for r in info["rows"]:
        assert set(r["lifts"]) == {"2.0", "6.0"}
        if r["model"] != "baseline":
            assert r["ms_per_frame"] > 0 and r["ms_per_frame_one_element"] > 0
            assert 1 <= r["lifts"]["6.0"]["frames_to_settle"] <= 4
        if r["model"] == "projective":  # a membrane solve beats moving the patch alone
            assert r["lifts"]["6.0"]["rms_error"] < patch_only["lifts"]["6.0"]["rms_error"]
    assert info["reference"]["coarse_against_reference"]["6.0"]["rms_error"] > 0


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"E": 5.0}, "--E"),
        ({"nu": 0.5}, "--nu"),
        ({"frames": 0}, "--frames"),
        ({"lifts": "2,x"}, "--lifts"),
        ({"lifts": "0.01"}, "--lifts"),
        ({"lifts": "1,2,3,4,5,6"}, "--lifts"),
    ],
)
def test_bad_arguments_are_refused(tmp_path, kw, word):
    args = SimpleNamespace(
        **{"quick": True, "E": 1e4, "nu": 0.45, "lifts": "2", "frames": 2, "out": str(tmp_path), **kw}
    )
    with pytest.raises(UserError, match=word):
        S.run(args)
    assert not (tmp_path / "results.json").exists()


def test_bad_lifts_exit_2_with_one_line(tmp_path, capsys):
    assert main(["bench", "sheet", "--quick", "--lifts", "20", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--lifts" in err and len(err.splitlines()) == 1
