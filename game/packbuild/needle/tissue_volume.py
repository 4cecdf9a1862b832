"""The layered soft-tissue volume a needle pack's needle meets, built from the pack's skin and bone meshes.

    python -m chainsim.game.packbuild.needle.tissue_volume [--pack prp|mental-block] [--check]

A needle crosses skin, the fat under it, muscle and deep tissue before it reaches bone (thesis 3.2 for
the rhizotomy approach). This builder fills that region along each side's textbook path (the pack's
anatomy `[paths]`) with a layered tetrahedral volume, without a general mesher: the volume is a bundle
of columns parallel to the path, so its top is exactly the skin and its layer boundaries are surfaces
the path crosses at known depths.

- A square grid (`spacing` mm, `half_width` either way, the path down the middle of a cell) in the
  plane normal to the path is cast along the path onto the skin: each ray's first hit is a top node,
  on the skin surface itself.
- Below each top node, nodes follow the path's direction at the layer boundaries: a layer's thickness
  is measured along the skin normal (the published figures are), so along the column it is divided by
  the cosine between normal and path (clamped). The deep layer goes on in slabs of `deep_slice` mm as
  far as each column has room above bone (skull or mandible, ray cast; at most `max_depth`): a cell of
  it exists where all four of its columns reach below it, so the volume follows a bony channel (prp's
  path between the mandible and the maxilla to the skull base) in whole, regular cells.
- Each hexahedron of the (i, j, k) grid is split into six tetrahedra around its main diagonal (the
  split conforms between neighbours), oriented positively.
- The drawn skin (`skin_around_tissue.ply`) is the pack's display skin less the triangles over the
  volumes, whose own skin face moves with the tissue and is drawn in their place.
- Point data `fixed` pins every boundary node but the skin's (on bone, and at the rim where the tissue
  goes on beyond the modelled region); cell data `layer` numbers each tetrahedron's layer (1 = the first in the
  pack's list); the file's triangle cells are the skin face only, so only the skin is drawn.

Quality is checked on the result (`check_quality`): no tetrahedron with a non-positive volume, the
smallest ratio of inscribed to circumscribed radius (x3, 1 for a regular tetrahedron) above
MIN_RADIUS_RATIO, and every top node within SKIN_TOLERANCE mm of the skin. Deterministic.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import meshio
import numpy as np
import trimesh

from chainsim.assets import ASSETS_DIR
from chainsim.systems.engine import meshgen
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshes import boundary_triangles

#: no tetrahedron flatter than this (3 r_in / r_circ; a regular tetrahedron has 1)
MIN_RADIUS_RATIO = 0.02
#: top nodes lie on the skin to this distance (mm)
SKIN_TOLERANCE = 0.05
#: the drawn skin is cut this far inside the rim of the volume's skin face: that rim is a chain of chords of
#: the skin, up to 0.05 mm off it, and a strip this narrow closes that crack without a visible overlap
SEAM_MM = 0.25
#: a column leaning further than this from the skin normal divides thickness by no less than this cosine
MIN_COS = 0.35


@dataclass(frozen=True)
class LayerSpec:
    name: str
    thickness_mm: float  # along the skin normal; the deep layer's is its minimum
    slices: int  # node levels inside the layer (elements across it)


@dataclass(frozen=True)
class VolumeSpec:
    """Where and how finely one pack's tissue is built (per pack, both sides alike)."""

    paths: tuple[str, ...]  # anatomy [paths] names, one volume each
    skin: str
    display: str  # the drawn skin, from which skin_around_tissue.ply is cut
    bones: tuple[str, ...]
    layers: tuple[LayerSpec, ...]  # the last one is deep: it reaches bone
    half_width: float
    spacing: float
    max_depth: float
    deep_slice: float


# Layer thicknesses: docs/tissue-layers.md gives each figure's source.
SPECS = {
    "prp": VolumeSpec(
        paths=("left", "right"),
        skin="meshes/skin.ply",
        display="meshes/skin_display.ply",
        bones=("meshes/skull.ply", "meshes/mandible.ply"),
        layers=(
            LayerSpec("skin", 1.8, 1),
            LayerSpec("subcutaneous", 6.0, 2),
            LayerSpec("muscle", 8.0, 2),
            LayerSpec("deep", 4.0, 0),
        ),
        half_width=24.0,
        spacing=2.0,
        max_depth=72.0,
        deep_slice=4.0,
    ),
    "mental-block": VolumeSpec(
        paths=("mental_left", "mental_right"),
        skin="prp:meshes/skin.ply",
        display="prp:meshes/skin_display.ply",
        bones=("prp:meshes/mandible.ply", "prp:meshes/skull.ply"),
        layers=(
            LayerSpec("skin", 2.0, 1),
            LayerSpec("subcutaneous", 5.0, 2),
            LayerSpec("muscle", 5.0, 2),
            LayerSpec("deep", 1.0, 0),
        ),
        half_width=14.0,
        spacing=2.0,
        max_depth=25.0,
        deep_slice=2.0,
    ),
}


def _pack_path(pack_dir: Path, ref: str) -> Path:
    if ":" in ref:
        other, rel = ref.split(":", 1)
        return ASSETS_DIR / other / rel
    return pack_dir / ref


def _basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u, v with (u, v, d) right-handed and orthonormal."""
    a = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(a, d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    return u, v


def _first_hits(mesh: trimesh.Trimesh, origins: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance along d to the first hit of each ray (inf for a miss) and the hit triangle (-1)."""
    dirs = np.repeat(d[None], len(origins), axis=0)
    locs, ray, tri = mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    dist = np.full(len(origins), np.inf)
    face = np.full(len(origins), -1, dtype=np.int64)
    if len(ray) == 0:
        return dist, face
    t = np.einsum("ij,j->i", locs - origins[ray], d)
    order = np.lexsort((t, ray))
    for r, tt, f in zip(ray[order], t[order], tri[order]):
        if tt > 1e-9 and tt < dist[r]:
            dist[r], face[r] = tt, f
    return dist, face


def _skin_columns(skin: trimesh.Trimesh, bones: list, entry: np.ndarray, d: np.ndarray, spec: VolumeSpec):
    """The columns' grid size, top nodes on the skin, thickness cosines and depth to bone (mm)."""
    u, v = _basis(d)
    # an even count of nodes a side: the path runs down the middle of cells, not along a line of nodes
    n = 2 * int(round(spec.half_width / spec.spacing))
    s = (np.arange(n) - (n - 1) / 2) * spec.spacing
    gi, gj = np.meshgrid(s, s, indexing="ij")
    start = entry - 60.0 * d
    origins = start + gi.reshape(-1, 1) * u + gj.reshape(-1, 1) * v
    t_skin, face = _first_hits(skin, origins, d)
    if not np.all(np.isfinite(t_skin)):
        raise UserError(f"the grid around {entry.round(1).tolist()} leaves the skin; narrow half_width")
    top = origins + t_skin[:, None] * d
    normal = skin.face_normals[face]
    # the thickness factor 1/cos varies smoothly across columns (per-triangle normals would step)
    cos = 1.0 / _smooth(1.0 / np.clip(np.abs(normal @ d), MIN_COS, 1.0), n, passes=4)
    # bone below each top node: the nearest hit over the bone meshes, from just under the skin
    depth_bone = np.full(len(top), np.inf)
    for bone in bones:
        t_b, _ = _first_hits(bone, top + 0.01 * d, d)
        depth_bone = np.minimum(depth_bone, t_b + 0.01)
    return n, top, cos, depth_bone


def column_volume(skin: trimesh.Trimesh, bones: list[trimesh.Trimesh], entry, target, spec: VolumeSpec) -> meshio.Mesh:
    """The layered tetrahedral volume around one path (module docstring)."""
    entry = np.asarray(entry, float)
    d = np.asarray(target, float) - entry
    d /= np.linalg.norm(d)
    n, top, cos, depth_bone = _skin_columns(skin, bones, entry, d, spec)
    fixed_layers = spec.layers[:-1]
    shallow = sum(layer.thickness_mm for layer in fixed_layers) / cos
    # the deep layer in slabs of deep_slice mm under the shallow ones, each column as many as fit above
    # its bone (at least one): where the bone steps, the volume steps with it in whole cells, so the
    # elements stay regular however steep the bone's wall (a staircase at most one slab off the bone)
    room = np.minimum(depth_bone, spec.max_depth) - shallow
    slabs = np.clip(np.floor(room / spec.deep_slice), 1, None).astype(np.int64)
    deep_slices = int(slabs.max())
    # node depths along the column, level by level
    levels = [np.zeros(len(top))]
    layer_of_slab: list[int] = []
    acc = np.zeros(len(top))
    for li, layer in enumerate(fixed_layers, start=1):
        for k in range(1, layer.slices + 1):
            levels.append(acc + layer.thickness_mm / cos * k / layer.slices)
            layer_of_slab.append(li)
        acc = levels[-1]
    n_shallow = len(layer_of_slab)
    for k in range(1, deep_slices + 1):
        levels.append(shallow + spec.deep_slice * k)
        layer_of_slab.append(len(spec.layers))
    nz = len(levels)
    z = np.stack(levels, axis=1)  # (columns, levels)
    pts = (top[:, None, :] + z[:, :, None] * d).reshape(n, n, nz, 3)
    idx = meshgen.grid_index((n, n, nz))
    points = np.zeros((n * n * nz, 3))
    points[idx.ravel()] = pts.reshape(-1, 3)
    _, tets, _ = meshgen.tet_grid(n, n, nz)
    # tet_grid gives six tetrahedra per cell, cell by cell within each of the six: keep a cell of the
    # deep layer only where all four of its columns reach below it
    sl = slabs.reshape(n, n)
    reach = np.minimum.reduce([sl[:-1, :-1], sl[1:, :-1], sl[:-1, 1:], sl[1:, 1:]])
    kd = np.arange(nz - 1) - n_shallow
    keep_cell = (kd[None, None, :] < reach[:, :, None]) | (kd[None, None, :] < 0)
    tets = tets[np.tile(keep_cell.ravel(), 6)]
    level = np.zeros(len(points), dtype=np.int64)
    level[idx.ravel()] = np.broadcast_to(np.arange(nz), (n, n, nz)).ravel()
    rim = np.zeros((n, n, nz), dtype=bool)
    rim[0], rim[-1], rim[:, 0], rim[:, -1] = True, True, True, True
    on_rim = np.zeros(len(points), dtype=bool)
    on_rim[idx.ravel()] = rim.ravel()
    # drop the nodes no kept cell uses, renumbering the rest
    used = np.unique(tets)
    new_id = np.full(len(points), -1, dtype=np.int64)
    new_id[used] = np.arange(len(used))
    points, tets, level, on_rim = points[used], new_id[tets], level[used], on_rim[used]
    tets = _orient(points, tets)
    # the layer of each tetrahedron: its slab, from its nodes' level
    slab = level[tets].min(axis=1)
    layer = np.asarray(layer_of_slab, dtype=np.int64)[slab]
    faces = boundary_triangles(tets)
    skin_faces = faces[np.all(level[faces] == 0, axis=1)]
    # pinned: every boundary node but the skin's (bone below and beside, the rim where tissue goes on)
    fixed = np.zeros(len(points), dtype=np.int64)
    fixed[np.unique(faces)] = 1
    fixed[np.unique(skin_faces)] = 0
    fixed[on_rim] = 1
    return meshio.Mesh(
        points,
        [("tetra", tets), ("triangle", skin_faces)],
        point_data={"fixed": fixed},
        cell_data={"layer": [layer, np.zeros(len(skin_faces), dtype=np.int64)]},
    )


def _smooth(field: np.ndarray, n: int, passes: int) -> np.ndarray:
    """Jacobi smoothing of a field on the n x n column grid (each node with its 4 neighbours)."""
    f = field.reshape(n, n).copy()
    for _ in range(passes):
        p = np.pad(f, 1, mode="edge")
        f = (4 * f + p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]) / 8
    return f.ravel()


def _orient(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    vol = _signed_volumes(points, tets)
    out = tets.copy()
    flip = vol < 0
    out[flip, 1], out[flip, 2] = tets[flip, 2], tets[flip, 1]
    return out


def _signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, e = (points[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), e - a) / 6.0


def radius_ratio(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """3 r_in / r_circ of each tetrahedron (1 regular, 0 flat)."""
    a, b, c, e = (points[tets[:, i]] for i in range(4))
    vol = np.abs(_signed_volumes(points, tets))
    area = sum(
        0.5 * np.linalg.norm(np.cross(q - p, r - p), axis=1) for p, q, r in ((a, b, c), (a, b, e), (a, c, e), (b, c, e))
    )
    r_in = 3 * vol / np.maximum(area, 1e-300)
    # circumradius from the edge lengths: R = sqrt((aA+bB+cC)(aA+bB-cC)(aA-bB+cC)(-aA+bB+cC)) / (24 V)
    la, lb, lc = np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1), np.linalg.norm(e - a, axis=1)
    lA, lB, lC = np.linalg.norm(e - c, axis=1), np.linalg.norm(e - b, axis=1), np.linalg.norm(c - b, axis=1)
    p, q, r = la * lA, lb * lB, lc * lC
    prod = np.clip((p + q + r) * (p + q - r) * (p - q + r) * (-p + q + r), 0, None)
    r_circ = np.sqrt(prod) / np.maximum(24 * vol, 1e-300)
    return 3 * r_in / np.maximum(r_circ, 1e-300)


def check_quality(mesh: meshio.Mesh, skin: trimesh.Trimesh) -> dict:
    """The figures the module docstring promises, raising UserError where one fails."""
    pts = mesh.points
    tets = mesh.cells_dict["tetra"]
    vol = _signed_volumes(pts, tets)
    rr = radius_ratio(pts, tets)
    tris = mesh.cells_dict["triangle"]
    top = np.unique(tris)
    _, dist, _ = trimesh.proximity.closest_point(skin, pts[top])
    out = {
        "nodes": len(pts),
        "tetrahedra": len(tets),
        "min_volume_mm3": float(vol.min()),
        "min_radius_ratio": float(rr.min()),
        "median_radius_ratio": float(np.median(rr)),
        "max_skin_distance_mm": float(dist.max()),
    }
    if out["min_volume_mm3"] <= 0:
        raise UserError(f"tissue volume: a tetrahedron has volume {out['min_volume_mm3']:.3g} mm3 (expected > 0)")
    if out["min_radius_ratio"] < MIN_RADIUS_RATIO:
        raise UserError(f"tissue volume: radius ratio {out['min_radius_ratio']:.3f} below {MIN_RADIUS_RATIO}")
    if out["max_skin_distance_mm"] > SKIN_TOLERANCE:
        raise UserError(f"tissue volume: skin nodes {out['max_skin_distance_mm']:.3f} mm off the skin")
    return out


def _slice(mesh: trimesh.Trimesh, normal: np.ndarray, origin: np.ndarray) -> trimesh.Trimesh:
    """The part of `mesh` on the side of the plane `normal` points to (triangles cut along it)."""
    if not len(mesh.faces):
        return mesh
    v, f = trimesh.intersections.slice_faces_plane(mesh.vertices, mesh.faces, plane_normal=normal, plane_origin=origin)[
        :2
    ]
    return trimesh.Trimesh(v, f, process=False)


def skin_with_holes(display: trimesh.Trimesh, volumes: list[tuple[np.ndarray, np.ndarray, float]]) -> trimesh.Trimesh:
    """The drawn skin less the part each volume's own skin face (which moves) draws instead; `volumes`:
    (entry, direction, half width of the volume's face) each. The face's rim lies in the four planes
    u = +-half, v = +-half across the path (its columns are parallel to the path), so the skin is cut
    along those planes: the two surfaces meet edge to edge, neither overlapping (two coplanar surfaces
    would show whichever was drawn first) nor leaving a gap the bone could show through."""
    out = display
    for entry, d, half in volumes:
        u, v = _basis(d)
        near = np.abs((out.triangles_center - entry) @ d) < 30.0  # this side of the head only
        keep = [out.submesh([np.nonzero(~near)[0]], append=True)] if (~near).any() else []
        front = out.submesh([np.nonzero(near)[0]], append=True)
        # outside the square across the path: u beyond +-half, else v beyond +-half
        for normal, origin in ((u, entry + half * u), (-u, entry - half * u)):
            keep.append(_slice(front, normal, origin))
        band = _slice(_slice(front, -u, entry + half * u), u, entry - half * u)
        for normal, origin in ((v, entry + half * v), (-v, entry - half * v)):
            keep.append(_slice(band, normal, origin))
        out = trimesh.util.concatenate([m for m in keep if len(m.faces)])
        out.merge_vertices()
    out.remove_unreferenced_vertices()
    return out


def build(pack: str, write: bool = True) -> dict:
    """Build (and write, unless `write` is false) every path's volume of `pack`; returns the quality figures."""
    spec = SPECS[pack]
    pack_dir = ASSETS_DIR / pack
    anatomy = tomllib.loads((pack_dir / "anatomy.toml").read_text())
    skin = trimesh.load(_pack_path(pack_dir, spec.skin), process=False)
    bones = [trimesh.load(_pack_path(pack_dir, b), process=False) for b in spec.bones]
    report = {}
    footprints = []
    for name in spec.paths:
        path = anatomy["paths"][name]
        mesh = column_volume(skin, bones, path["entry"], path["target"], spec)
        report[name] = check_quality(mesh, skin)
        entry = np.asarray(path["entry"], float)
        d = np.asarray(path["target"], float) - entry
        # the volume's skin face ends half a cell inside half_width (the grid's outer columns)
        footprints.append((entry, d / np.linalg.norm(d), spec.half_width - 0.5 * spec.spacing - SEAM_MM))
        if write:
            out = pack_dir / "meshes" / f"tissue_{name.split('_')[-1]}.vtu"
            out.parent.mkdir(exist_ok=True)
            meshio.write(str(out), mesh, binary=True, compression="zlib")
    if write:
        display = trimesh.load(_pack_path(pack_dir, spec.display), process=False)
        skin_with_holes(display, footprints).export(pack_dir / "meshes" / "skin_around_tissue.ply")
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pack", choices=sorted(SPECS), action="append", help="pack to build (default: all)")
    ap.add_argument("--check", action="store_true", help="build and check only; write nothing")
    args = ap.parse_args(argv)
    try:
        for pack in args.pack or sorted(SPECS):
            for name, fig in build(pack, write=not args.check).items():
                print(f"{pack} {name}: " + ", ".join(f"{k} {v:.4g}" for k, v in fig.items()))
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
