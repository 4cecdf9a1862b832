"""Corrupt, degenerate and hostile mesh files: one line naming the file, exit 2, nothing written.

Through `chainsim chainmail` (the importer the CLI and benchmarks use) and the pack loader's
load_file. Bombs are small files that declare or expand to far more than CHAINSIM_MAX_MESH_MB; they
must be refused from their headers, before the data is read.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from chainsim.systems.engine.meshes import MeshError, load_file

from . import badfiles as bf
from .conftest import assert_one_line_error

CM = ["--grab", "0", "--to", "1", "1", "1", "--alpha-min", "0.8", "--alpha-max", "1.2", "--beta", "0.1"]
TRI = ["0 0 0", "1 0 0", "0 1 0"]


def _put(path, content):
    """Write text or bytes to `path` and return it."""
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


def _folder(path):
    path.mkdir()
    return path


def _glb(path, json_text: str):
    import struct

    body = json_text.encode()
    body += b" " * (-len(body) % 4)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body)
    return path


# id -> (writer(folder) -> path, words); CHAINSIM_MAX_MESH_MB is 1 for these
CASES = {
    "obj-nan": (lambda d: bf.obj(d / "m.obj", ["0 0 0", "1 0 0", "nan 1 0"]), ("m.obj", "non-finite")),
    "obj-1e309": (lambda d: bf.obj(d / "m.obj", ["0 0 0", "1e309 0 0", "0 1 0"]), ("non-finite",)),
    "obj-1e308": (lambda d: bf.obj(d / "m.obj", ["0 0 0", "1e308 0 0", "0 -1e308 0"]), ("within +-1e+06",)),
    "obj-empty": (lambda d: _put(d / "m.obj", ""), ("m.obj",)),
    "obj-binary-garbage": (lambda d: _put(d / "m.obj", bytes(range(256)) * 10), ("m.obj",)),
    "obj-face-index-out-of-range": (lambda d: bf.obj(d / "m.obj", TRI, faces=((1, 2, 99),)), ("m.obj",)),
    "obj-no-faces": (lambda d: bf.obj(d / "m.obj", TRI, faces=()), ("m.obj",)),
    "stl-truncated": (
        lambda d: _put(d / "m.stl", b"\0" * 80 + b"\xff\xff\xff\x7f" + b"\0" * 10),
        ("m.stl",),
    ),
    "ply-declares-10**12": (lambda d: bf.ply_declaring(d / "m.ply", 10**12), ("declares", "vertices")),
    "ply-declares-more-than-it-holds": (lambda d: bf.ply_declaring(d / "m.ply", 1000), ("m.ply",)),
    "off-declares-10**10": (
        lambda d: _put(d / "m.off", "OFF\n10000000000 1 0\n0 0 0\n"),
        ("declares",),
    ),
    "vtk-declares-10**10": (
        lambda d: _put(
            d / "m.vtk",
            "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 10000000000 double\n0 0 0\n",
        ),
        ("declares",),
    ),
    "msh-garbage": (
        lambda d: _put(d / "m.msh", "$MeshFormat\n9 9 9\n$EndMeshFormat\n"),
        ("m.msh",),
    ),
    "npz-bomb": (lambda d: bf.npz_bomb(d / "m.npz", 64 * 2**20), ("expand to", "mesh limit")),
    "npz-lying-shape": (lambda d: bf.npz_lying_header(d / "m.npz", 10**6), ("declares shape",)),
    "npz-object-array": (
        lambda d: bf.npz_arrays(d / "m.npz", positions=np.array([[0.0]], dtype=object), links=np.zeros((0, 2), int)),
        ("objects",),
    ),
    "npz-positions-1e308": (
        lambda d: bf.npz_arrays(d / "m.npz", positions=np.array([[0, 0, 0], [1e308, 0, 0]]), links=[[0, 1]]),
        ("within +-1e+06",),
    ),
    "npz-positions-nan": (
        lambda d: bf.npz_arrays(d / "m.npz", positions=np.array([[0, 0, 0], [np.nan, 0, 0]]), links=[[0, 1]]),
        ("finite",),
    ),
    "npz-links-out-of-range": (
        lambda d: bf.npz_arrays(d / "m.npz", positions=np.zeros((2, 3)), links=[[0, 7]]),
        ("outside 0..1",),
    ),
    "npz-links-uint64-huge": (
        lambda d: bf.npz_arrays(d / "m.npz", positions=np.zeros((2, 3)), links=np.array([[0, 2**63 + 5]], np.uint64)),
        ("outside",),
    ),
    "npz-not-a-zip": (lambda d: _put(d / "m.npz", b"PK\x03\x04garbage"), ("npz",)),
    "vtu-zlib-bomb-declared": (lambda d: bf.vtu_bomb(d / "m.vtu", 2**20, points=10**7), ("declares", "points")),
    "vtu-zlib-bomb-lying-points": (lambda d: bf.vtu_bomb(d / "m.vtu", 32 * 2**20, points=4), ("mesh limit",)),
    "vtu-zlib-bomb-lying-block": (
        lambda d: bf.vtu_bomb(d / "m.vtu", 32 * 2**20, points=4, declared_block=96),
        ("expands past",),
    ),
    "vtu-appended-raw-bomb": (
        lambda d: bf.vtu_bomb(d / "m.vtu", 32 * 2**20, points=4, declared_block=96, appended_raw=True),
        ("expands past",),
    ),
    "vtu-entity-expansion": (
        lambda d: _put(d / "m.vtu", '<?xml version="1.0"?><!DOCTYPE x [<!ENTITY a "aaaa">]><VTKFile/>'),
        ("entities",),
    ),
    "gltf-buffer-outside": (
        lambda d: _put(
            d / "m.gltf", '{"asset": {"version": "2.0"}, "buffers": [{"uri": "../../../etc/passwd", "byteLength": 4}]}'
        ),
        ("escapes",),
    ),
    "gltf-buffer-absolute": (
        lambda d: _put(
            d / "m.gltf", '{"asset": {"version": "2.0"}, "buffers": [{"uri": "/etc/passwd", "byteLength": 4}]}'
        ),
        ("next to the mesh",),
    ),
    "glb-deep-json": (lambda d: _glb(d / "m.glb", "[" * 5000 + "]" * 5000), ("nested",)),
    "unknown-extension": (lambda d: _put(d / "m.xyz", "1 2 3"), ("unsupported mesh type",)),
    "a-folder": (lambda d: _folder(d / "dir.obj"), ("dir.obj",)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_mesh_file_is_one_line_and_nothing_is_written(case, cli, tmp_path, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "1")
    make, words = CASES[case]
    path = make(tmp_path)
    t0 = time.perf_counter()
    code, out, err = cli("chainmail", path, *CM, "--out", tmp_path / "out.npz")
    assert time.perf_counter() - t0 < 30
    assert_one_line_error(code, err, *words)
    assert err.count("\n") == 1, err
    assert not (tmp_path / "out.npz").exists()


@pytest.mark.parametrize("case", sorted(c for c in CASES if not c.startswith("npz")))
def test_the_pack_loader_raises_only_mesh_errors(case, tmp_path, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "1")
    path = CASES[case][0](tmp_path)
    with pytest.raises(MeshError):
        load_file(path, 1.0, True, label=path.name)


def test_bombs_are_small_files(tmp_path):
    """The bombs above are refused by what they declare: their files are well within the limit."""
    for case in ("npz-bomb", "vtu-zlib-bomb-lying-points", "vtu-appended-raw-bomb"):
        assert CASES[case][0](tmp_path).stat().st_size < 1024 * 1024


def test_a_valid_compressed_vtu_within_the_limit_still_loads(tmp_path):
    import meshio

    from chainsim.systems.engine import meshgen

    p, tets, _ = meshgen.tet_grid(5, 5, 5)
    for kw in ({"compression": "zlib"}, {"compression": "lzma"}, {"binary": False}):
        meshio.write(tmp_path / "v.vtu", meshio.Mesh(p, [("tetra", tets)]), **kw)
        m = load_file(tmp_path / "v.vtu")
        np.testing.assert_allclose(m.vertices, p)
        assert len(m.tets) == len(tets)
