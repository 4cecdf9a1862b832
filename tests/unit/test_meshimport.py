"""Mesh import for ChainMail: surfaces (merged duplicates, edge links), tet volumes, the built-in
tetrahedraliser, locality reordering, and one-line errors for bad files."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshes import MeshData
from chainsim.systems.engine.meshimport import check_graph, load_graph, load_mesh
from chainsim.systems.engine.reorder import inverse, morton_permutation, permute_mesh, rcm_permutation, reorder_mesh
from chainsim.systems.engine.tetra import TetraError, tetrahedralize


def _links_set(links):
    return {tuple(sorted(lk)) for lk in np.asarray(links).tolist()}


def test_surface_duplicates_are_merged_and_edges_become_links(tmp_path):
    # two triangles of a square written with their shared corners duplicated (as STL-like exports do)
    (tmp_path / "sq.obj").write_text(
        textwrap.dedent("""
        v 0 0 0
        v 1 0 0
        v 1 1 0
        v 0 0 0
        v 1 1 0
        v 0 1 0
        f 1 2 3
        f 4 5 6
    """)
    )
    pos, links, fixed = load_graph(tmp_path / "sq.obj")
    assert pos.shape == (4, 3) and len(fixed) == 0
    assert len(links) == 5  # four sides and the diagonal
    lengths = sorted(np.linalg.norm(pos[links[:, 0]] - pos[links[:, 1]], axis=1))
    np.testing.assert_allclose(lengths, [1, 1, 1, 1, np.sqrt(2)])


def test_tet_volume_files_give_tetrahedron_edges(tmp_path):
    import meshio

    p, tets, links = meshgen.tet_grid(4, 3, 3)
    for ext in ("vtu", "msh", "vtk"):
        meshio.write(tmp_path / f"v.{ext}", meshio.Mesh(p, [("tetra", tets)]))
        pos, got, _ = load_graph(tmp_path / f"v.{ext}")
        np.testing.assert_allclose(pos, p)
        assert _links_set(got) == _links_set(links)
    surf = load_graph(tmp_path / "v.vtu", kind="surface")[1]
    assert len(surf) < len(links)  # only the boundary triangles' edges


def test_tetrahedraliser_fills_a_closed_surface_from_inside(tmp_path):
    sphere = trimesh.creation.icosphere(3, radius=10.0)
    vol = tetrahedralize(MeshData(np.asarray(sphere.vertices), np.asarray(sphere.faces)), cells=8)
    assert vol.tets is not None and len(vol.tets) > 100
    assert np.linalg.norm(vol.vertices, axis=1).max() <= 10.0 + 1e-6  # kept inside the surface
    a, b, c, d = (vol.vertices[vol.tets[:, i]] for i in range(4))
    volumes = np.abs(np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))) / 6
    assert volumes.min() > 0
    assert 0.6 * (4 / 3 * np.pi * 1000) < volumes.sum() <= 4 / 3 * np.pi * 1000
    deg = np.bincount(meshgen.links_from_cells(vol.tets).ravel())
    assert deg.max() == 14 and deg.min() >= 3
    # the same through the importer, from a file
    sphere.export(tmp_path / "s.ply")
    mesh = load_mesh(tmp_path / "s.ply", kind="volume", cells=6)
    assert mesh.tets is not None and len(mesh.tets)


def test_open_surfaces_cannot_be_filled(tmp_path):
    pos, tris, _ = meshgen.triangulated_grid(5, 5, 1.0, dim=3)
    with pytest.raises(TetraError):
        tetrahedralize(MeshData(pos, tris))
    trimesh.Trimesh(pos, tris).export(tmp_path / "open.ply")
    with pytest.raises(UserError, match="closed"):
        load_mesh(tmp_path / "open.ply", kind="volume")


def _bandwidth(links):
    return int(np.abs(links[:, 0] - links[:, 1]).max())


def _spread(links):
    """Mean id distance between linked elements (what the cache sees on a cascade)."""
    return float(np.abs(links[:, 0] - links[:, 1]).mean())


@pytest.mark.parametrize("method", ["rcm", "morton"])
def test_reordering_keeps_the_mesh_and_restores_locality(method):
    pos, tets, links = meshgen.tet_grid(8, 8, 8)
    rng = np.random.default_rng(1)
    shuffle = rng.permutation(len(pos))
    shuffled = permute_mesh(MeshData(pos, np.zeros((0, 3), np.int64), tets), shuffle)
    out = reorder_mesh(shuffled, method)

    # same shape: link lengths and tetrahedron volumes survive the renumbering
    def lengths(m):
        lk = m.edge_links()
        return np.sort(np.linalg.norm(m.vertices[lk[:, 0]] - m.vertices[lk[:, 1]], axis=1))

    np.testing.assert_allclose(lengths(out), lengths(MeshData(pos, np.zeros((0, 3), np.int64), tets)))
    assert sorted(map(tuple, out.vertices.tolist())) == sorted(map(tuple, pos.tolist()))
    assert _spread(out.edge_links()) < _spread(shuffled.edge_links()) / 4


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 80))
def test_rcm_permutation_is_a_graph_isomorphism(seed, n):
    rng = np.random.default_rng(seed)
    pos, links = meshgen.random_graph(n, 2 * n, 3, rng)
    perm = rcm_permutation(n, links)
    assert sorted(perm.tolist()) == list(range(n))
    inv = inverse(perm)
    assert _links_set(inv[links]) == _links_set(meshgen.unique_links(inv[links]))
    mapped = {tuple(sorted((perm[a], perm[b]))) for a, b in meshgen.unique_links(inv[links]).tolist()}
    assert mapped == _links_set(links)
    m = morton_permutation(pos)
    assert sorted(m.tolist()) == list(range(n))


def test_pack_meshes_with_reorder_true_are_renumbered(tmp_path):
    import meshio

    from chainsim.game.packs import pack as packs

    p, tets, _ = meshgen.tet_grid(6, 6, 6)
    shuffle = np.random.default_rng(0).permutation(len(p))
    inv = inverse(shuffle)
    root = tmp_path / "rp"
    (root / "meshes").mkdir(parents=True)
    meshio.write(root / "meshes" / "v.vtu", meshio.Mesh(p[shuffle], [("tetra", inv[tets])]))
    (root / "pack.toml").write_text(
        '[pack]\nname = "rp"\nformat = 1\n[meshes.v]\npath = "meshes/v.vtu"\nreorder = true\n'
    )
    mesh = packs.load(root).mesh("v")
    assert _bandwidth(mesh.edge_links()) < _bandwidth(meshgen.unique_links(inv[meshgen.links_from_cells(tets)])) / 4


@pytest.mark.parametrize(
    "content, ext, needle",
    [
        (b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n", "ply", "bad.ply"),
        (b"\x00\x01garbage", "stl", "bad.stl"),
        (b"not a gmsh file", "msh", "bad.msh"),
        (b"", "obj", "bad.obj"),
    ],
)
def test_bad_mesh_files_are_one_line_user_errors(tmp_path, content, ext, needle):
    path = tmp_path / f"bad.{ext}"
    path.write_bytes(content)
    with pytest.raises(UserError) as err:
        load_graph(path)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_check_graph_accepts_integer_positions_and_empty_fixed():
    pos, links, fixed = check_graph(np.arange(4).reshape(4, 1), np.array([[0, 1], [1, 2], [2, 3]], np.int32))
    assert pos.dtype == np.float64 and links.dtype == np.int64 and fixed.shape == (0,)
