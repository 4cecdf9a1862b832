"""Importing meshes as ChainMail objects: elements, links and anchors from files (thesis 5.2.1).

Accepted inputs:
    .npz                     positions (N, D) float, D in 1..3; links (M, 2) int, each undirected pair
                             once, no self links; optional fixed (K,) int element ids
    .obj .ply .stl .off ...  triangle surfaces through trimesh: duplicate vertices merged, triangle
                             edges become links
    .msh .vtk .vtu .mesh     tetrahedral volumes through meshio: tetrahedron edges become links

`load_mesh` returns a MeshData (optionally filled with tetrahedra by chainsim.systems.engine.tetra, optionally reordered
by chainsim.systems.engine.reorder); `load_graph` returns the flat arrays the CLI and the benchmarks use. Every problem
becomes a one-line UserError naming the file (or the argument) and what is expected. Sizes, counts
and coordinates are bounded (chainsim.systems.engine.limits): an .npz's zip directory and array headers are
read before its arrays (chainsim.systems.engine.meshcheck), and positions must be finite and within MAX_COORD.
"""

from __future__ import annotations

import contextlib
import io
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine import limits, meshcheck
from chainsim.systems.engine import reorder as ro
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshes import MeshData, MeshError, load_file
from chainsim.systems.engine.reorder import reorder_mesh
from chainsim.systems.engine.tetra import DEFAULT_CELLS, TetraError, tetrahedralize

GRAPH_EXT = ".npz"


def load_mesh(
    path: str | os.PathLike,
    *,
    kind: str = "auto",
    pitch: float | None = None,
    cells: int | None = None,
    reorder: str | None = None,
    scale_to_mm: float = 1.0,
    where: str | None = None,
) -> MeshData:
    """A MeshData from a mesh file.

    kind: "surface" (triangle links), "volume" (tetrahedra; a closed surface is filled with the built-in
    tetrahedraliser, cube size `pitch` or `cells` along the longest side), or "auto" (as the file is).
    reorder: None, "rcm" or "morton" (chainsim.systems.engine.reorder).
    """
    where = where or str(path)
    try:
        # meshio reports some unreadable files by printing and calling sys.exit: keep both inside
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            mesh = load_file(Path(path), scale_to_mm)
    except MeshError as e:
        raise UserError(str(e)) from None
    except SystemExit:
        raise UserError(f"{where}: not a readable mesh file") from None
    if kind not in ("auto", "surface", "volume"):
        raise UserError(f"{where}: kind must be auto, surface or volume, got {kind!r}")
    has_tets = mesh.tets is not None and len(mesh.tets) > 0
    if kind == "volume" and not has_tets:
        try:
            mesh = tetrahedralize(mesh, pitch=pitch, cells=cells or DEFAULT_CELLS)
        except TetraError as e:
            raise UserError(f"{where}: cannot fill with tetrahedra: {e}") from None
    elif kind == "surface" and has_tets:
        mesh = MeshData(mesh.vertices, mesh.triangles, None, mesh.links)
    if reorder:
        try:
            mesh = reorder_mesh(mesh, reorder)
        except ValueError as e:
            raise UserError(f"{where}: {e}") from None
    return mesh


def check_graph(
    positions: ArrayLike, links: ArrayLike, fixed: ArrayLike | None = None, where: str = "mesh"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate the flat arrays of a ChainMail object; returns (positions float64, links int64, fixed int64)."""
    pos = np.asarray(positions)
    if pos.ndim == 1:
        pos = pos.reshape(-1, 1)
    if pos.ndim != 2 or pos.shape[0] == 0 or pos.shape[1] not in (1, 2, 3):
        raise UserError(
            f"{where}: positions must be an (N, D) array with N >= 1 and D = 1, 2 or 3, got shape {pos.shape}"
        )
    if not (np.issubdtype(pos.dtype, np.floating) or np.issubdtype(pos.dtype, np.integer)):
        raise UserError(f"{where}: positions must be numbers, got dtype {pos.dtype}")
    if len(pos) > limits.MAX_VERTICES:
        raise UserError(f"{where}: {len(pos):,} elements, over the {limits.MAX_VERTICES:,} limit (docs/limits.md)")
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    if not np.all(np.isfinite(pos)):
        bad = int(np.flatnonzero(~np.isfinite(pos).all(axis=1))[0])
        raise UserError(f"{where}: positions must be finite (row {bad} is not)")
    biggest = float(np.abs(pos).max()) if len(pos) else 0.0
    if biggest > limits.MAX_COORD:
        raise UserError(f"{where}: positions must be within +-{limits.MAX_COORD:g} (docs/limits.md), found {biggest:g}")
    n = len(pos)
    lk = np.asarray(links)
    if lk.size == 0:
        lk = np.zeros((0, 2), dtype=np.int64)
    if lk.ndim != 2 or lk.shape[1] != 2:
        raise UserError(f"{where}: links must be an (M, 2) array of element ids, got shape {lk.shape}")
    if not np.issubdtype(lk.dtype, np.integer):
        raise UserError(f"{where}: links must be integers, got dtype {lk.dtype}")
    if len(lk) > limits.MAX_CELLS:
        raise UserError(f"{where}: {len(lk):,} links, over the {limits.MAX_CELLS:,} limit (docs/limits.md)")
    lk = np.ascontiguousarray(lk, dtype=np.int64)
    if len(lk):
        if lk.min() < 0 or lk.max() >= n:
            raise UserError(
                f"{where}: links refer to elements outside 0..{n - 1} (found {int(lk.min())}..{int(lk.max())})"
            )
        selfl = np.flatnonzero(lk[:, 0] == lk[:, 1])
        if len(selfl):
            raise UserError(f"{where}: link {int(selfl[0])} joins element {int(lk[selfl[0], 0])} to itself")
        key = np.sort(lk, axis=1)
        uniq, counts = np.unique(key, axis=0, return_counts=True)
        if np.any(counts > 1):
            dup = uniq[np.flatnonzero(counts > 1)[0]]
            raise UserError(
                f"{where}: link {int(dup[0])}-{int(dup[1])} is listed more than once (each undirected pair once)"
            )
    fx = np.zeros(0, dtype=np.int64) if fixed is None else np.asarray(fixed)
    if fx.size == 0:
        fx = np.zeros(0, dtype=np.int64)
    if fx.ndim != 1 or not np.issubdtype(fx.dtype, np.integer):
        raise UserError(f"{where}: fixed must be a 1-D array of element ids, got shape {fx.shape} dtype {fx.dtype}")
    fx = fx.astype(np.int64)
    if len(fx) and (fx.min() < 0 or fx.max() >= n):
        raise UserError(f"{where}: fixed ids must be in 0..{n - 1}")
    return pos, lk, fx


def load_graph(
    path: str | os.PathLike, *, kind: str = "auto", reorder: str | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (N, D), links (M, 2), fixed (K,)) from a .npz graph or any mesh file load_mesh reads."""
    path = Path(path)
    if "\x00" in str(path):
        raise UserError(f"{str(path)!r}: a file name cannot contain a NUL byte")
    if path.suffix.lower() == GRAPH_EXT:
        limit = limits.max_mesh_bytes()
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            raise UserError(f"{path}: file not found") from None
        except OSError as e:
            raise UserError(f"{path}: cannot read ({e.strerror or e})") from None
        if size > limit:
            raise UserError(f"{path}: {size / 1048576:.2f} MB is over the {limit / 1048576:.3g} MB mesh limit")
        try:
            meshcheck.check_npz(path, limit)
        except meshcheck.MeshCheckError as e:
            raise UserError(f"{path}: {e}") from None
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in ("positions", "links") if k not in z.files]
                if missing:
                    raise UserError(
                        f"{path}: missing array(s) {', '.join(missing)}; expected positions (N, D) and links (M, 2)"
                    )
                pos, links = z["positions"], z["links"]
                fixed = z["fixed"] if "fixed" in z.files else None
        except UserError:
            raise
        except FileNotFoundError:
            raise UserError(f"{path}: file not found") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise UserError(f"{path}: not a readable .npz file ({type(e).__name__})") from None
        pos, links, fixed = check_graph(pos, links, fixed, str(path))
        if reorder:
            perm = ro.rcm_permutation(len(pos), links) if reorder == "rcm" else ro.morton_permutation(pos)
            inv = ro.inverse(perm)
            pos, links, fixed = pos[perm], ro.permute_links(links, inv), np.sort(inv[fixed])
        return pos, links, fixed
    if not path.exists():
        raise UserError(f"{path}: file not found")
    mesh = load_mesh(path, kind=kind, reorder=reorder)
    return check_graph(mesh.vertices, mesh.edge_links(), None, str(path))
