"""The attempt page's display meshes and the class page's figures, without a server or a browser.

The meshes the browser gets are thinned by vertex clustering (``replay3d.cluster``): checked on
random meshes that the result is a valid, smaller mesh close to the original, and that each pack's
GLB holds its anatomy within the triangle budget. The class page's trend and verdicts come from
the pack's benchmarks.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.game.packs import pack as packs
from chainsim.game.server import classpage, replay3d

REPO = Path(__file__).resolve().parents[2]


def sphere(subdivisions: int):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=50.0)
    return np.asarray(m.vertices), np.asarray(m.faces)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 5), st.integers(20, 3000), st.integers(0, 2**32 - 1))
def test_cluster_gives_a_valid_smaller_mesh_near_the_original(sub, most, seed):
    v, f = sphere(sub)
    v = v + np.random.default_rng(seed).normal(0.0, 0.2, v.shape)  # not on a grid
    nv, nf = replay3d.cluster(v, f, most)
    assert nf.min() >= 0 and nf.max() < len(nv)
    assert np.all((nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2]))
    if len(f) > most:
        assert 0 < len(nf) <= most
        # a plain reference: every new vertex lies within the cells' size of the original surface
        r = np.linalg.norm(nv, axis=1)
        cell = 2 * (np.ptp(v, axis=0).max() / len(nf) ** 0.5)
        assert np.all(np.abs(r - 50.0) < cell + 1.0)
    else:
        assert np.array_equal(nf, f)


@pytest.mark.parametrize("name", ["prp", "mental-block"])
def test_each_pack_sends_its_anatomy_within_the_budget(name):
    glb = replay3d.display_glb(str(REPO / "assets" / name), [])
    assert glb[:4] == b"glTF" and len(glb) < 2_000_000
    scene = trimesh.load(io.BytesIO(glb), file_type="glb")
    pack = packs.load(REPO / "assets" / name, [])
    drawn = {
        e
        for e, spec in pack.manifest["entities"].items()
        if "mesh" in spec and not pack.manifest["meshes"][spec["mesh"]["mesh"]].get("primitive")
    }
    assert drawn and set(scene.geometry) == drawn  # every anatomy mesh, no instrument
    assert all(len(g.faces) <= replay3d.MAX_TRIANGLES for g in scene.geometry.values())


def test_trend_compares_the_later_attempts_with_the_earlier():
    assert classpage.trend([3, 4, 8, 9]) == "better"
    assert classpage.trend([9, 9, 4, 3]) == "worse"
    assert classpage.trend([5, 5, 5]) == "steady"
    assert classpage.trend([7]) == "-"


def test_an_attempt_passes_only_when_every_benchmark_is_met_without_critical_error():
    specs = {
        "errors_mm": {"benchmark": 2.0, "critical": 5.0},
        "score": {"benchmark": 80.0, "lower_is_better": False},
    }
    ok = classpage.judged({"id": 1, "created_at": "", "metrics": {"errors_mm": 1.0, "score": 90.0}}, specs)
    low = classpage.judged({"id": 2, "created_at": "", "metrics": {"errors_mm": 1.0, "score": 70.0}}, specs)
    crit = classpage.judged({"id": 3, "created_at": "", "metrics": {"errors_mm": 6.0, "score": 99.0}}, specs)
    assert (ok["passed"], ok["met"], ok["judged"]) == (True, 2, 2)
    assert (low["passed"], low["met"]) == (False, 1)
    assert crit["passed"] is False
    # a record's own fixed figures count where the pack's metric has their name
    top = classpage.judged({"id": 4, "created_at": "", "errors_mm": 1.0, "metrics": {"score": 85.0}}, specs)
    assert top["passed"] is True
