"""A pack's meshes are parsed once: a later load of the same file (or trimesh primitive) gives the same
arrays from chainsim's mesh cache without importing trimesh or meshio (the window's warm start); an
edited file, a broken entry or a cache folder that cannot be written only mean parsing again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chainsim.systems.engine import meshcache, meshes

ROOT = Path(__file__).resolve().parents[2]

LOAD = """
import hashlib, json, sys
from pathlib import Path
from chainsim.systems.engine import meshes
m = Path(sys.argv[1])
out = {}
for name, mesh in (
    ("skin", meshes.load_file(m / "skin.ply")),
    ("tissue", meshes.load_file(m / "tissue_left.vtu")),
    ("cylinder", meshes.primitive("cylinder", extents=[1, 1, 1], radius=0.5, height=40.0, resolution=[12, 1, 1])),
):
    arrays = {f: getattr(mesh, f) for f in ("vertices", "triangles", "tets", "fixed", "layers")}
    out[name] = {f: a if a is None else [str(a.dtype), a.shape, hashlib.sha256(a.tobytes()).hexdigest()]
                 for f, a in arrays.items()}
out["parsers"] = [n for n in ("trimesh", "meshio") if n in sys.modules]
print(json.dumps(out))
"""


def _load(cache: Path) -> dict:
    cmd = [sys.executable, "-c", LOAD, str(ROOT / "assets" / "prp" / "meshes")]
    env = {**os.environ, "CHAINSIM_CACHE_DIR": str(cache)}
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_a_second_load_gives_the_same_meshes_without_the_parsers(tmp_path):
    first, second = _load(tmp_path), _load(tmp_path)
    assert first["parsers"] == ["trimesh", "meshio"]
    assert second["parsers"] == []
    assert {k: v for k, v in first.items() if k != "parsers"} == {k: v for k, v in second.items() if k != "parsers"}
    assert first["tissue"]["tets"] is not None and first["tissue"]["layers"] is not None


OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 {z}\nf 1 2 3\nf 1 2 4\n"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CHAINSIM_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "meshes"


def test_an_edited_file_is_parsed_again(tmp_path, cache):
    path = tmp_path / "m.obj"
    path.write_text(OBJ.format(z=1), encoding="utf-8")
    assert meshes.load_file(path).vertices[3, 2] == 1.0
    path.write_text(OBJ.format(z=7), encoding="utf-8")
    assert meshes.load_file(path).vertices[3, 2] == 7.0
    assert meshes.load_file(path, scale_to_mm=10.0).vertices[3, 2] == 70.0  # another scale, another entry
    assert len(list(cache.glob("*.npz"))) == 3


def test_a_broken_entry_or_an_unwritable_folder_only_means_parsing(tmp_path, cache, monkeypatch):
    path = tmp_path / "m.obj"
    path.write_text(OBJ.format(z=2), encoding="utf-8")
    want = meshes.load_file(path)
    (entry,) = cache.glob("*.npz")
    entry.write_bytes(b"cut short")
    got = meshes.load_file(path)
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.triangles, want.triangles)
    blocked = tmp_path / "a-file"
    blocked.write_text("", encoding="utf-8")
    monkeypatch.setenv("CHAINSIM_CACHE_DIR", str(blocked))  # its meshes folder cannot be made
    np.testing.assert_array_equal(meshes.load_file(path).vertices, want.vertices)
    assert meshcache.read(meshcache.key(path.read_bytes(), ".obj", 1.0, True)) is None
