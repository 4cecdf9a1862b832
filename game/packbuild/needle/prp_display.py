"""Lighter copies of the prp pack's densest surfaces, drawn in the window in place of the full ones.

    python -m chainsim.game.packbuild.needle.prp_display [--pack assets/prp] [--faces 16000]

Under a software renderer (Mesa llvmpipe) the window's frame time grows with the triangles it sets
up; the skull (67k triangles, thesis 3.3.3) is most of them although the trainee sees it only
through the transparent skin or from the needle tip. Quadric-error decimation (fast-simplification,
needed only to run this) keeps its shape to a fraction of a millimetre at about a quarter of the
triangles. Picking, bone contacts and the C-arm image keep using the full mesh; the pack names the
copy in its mesh table as `display`. Deterministic: the same input gives the same file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

from chainsim.assets import ASSETS_DIR
from chainsim.systems.engine.errors import UserError

#: meshes decimated for display, with their target triangle counts
TARGETS = {"skull": 16_000}
#: the skin's display copy is cut level here (mm, head frame) and closed by a flat cap: the source
#: skin ends in a ragged rim (8 mm of saw-tooth) closed by a fan whose normals, shared with the neck
#: wall, streak the smooth shading; the cut lies below the mandible and skull, so nothing shows
NECK_CUT_Z = -100.0


def decimate(vertices: np.ndarray, faces: np.ndarray, n_faces: int) -> trimesh.Trimesh:
    """About `n_faces` triangles of the same surface (quadric error metric)."""
    try:
        import fast_simplification  # noqa: PLC0415 - needed only to rebuild the copies, not to run
    except ImportError:
        raise UserError(
            "rebuilding the display meshes needs fast-simplification: pip install 'chainsim[packbuild]'"
        ) from None

    reduction = max(0.0, 1.0 - n_faces / max(len(faces), 1))
    v, f = fast_simplification.simplify(
        np.asarray(vertices, np.float32), np.asarray(faces, np.int32), target_reduction=reduction
    )
    m = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f, np.int64), process=True)
    m.remove_unreferenced_vertices()
    return m


def neck_cut(skin: trimesh.Trimesh, z: float) -> trimesh.Trimesh:
    """The skin above the plane Z = z, closed by a flat cap with its own vertices (so its normals are
    not averaged with the neck wall's): a fan from the centroid of each boundary loop of the cut."""
    v, f = trimesh.intersections.slice_faces_plane(
        skin.vertices, skin.faces, plane_normal=np.array([0.0, 0.0, 1.0]), plane_origin=np.array([0.0, 0.0, z])
    )[:2]
    top = trimesh.Trimesh(v, f, process=True)  # merges the cut's duplicated vertices
    edges = top.edges_sorted
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    open_edges = unique[counts == 1]
    on_cut = np.abs(top.vertices[open_edges, 2] - z).max(axis=1) < 1e-6
    # directed boundary edges as the faces run them, so the cap's winding matches the wall's
    directed = top.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    wanted = {tuple(e) for e in open_edges[on_cut]}
    nxt = {int(a): int(b) for a, b in directed if (min(a, b), max(a, b)) in wanted}
    verts, faces = [top.vertices], [top.faces]
    n = len(top.vertices)
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        while nxt.get(loop[-1], start) != start:
            loop.append(nxt.pop(loop[-1]))
        nxt.pop(loop[-1], None)
        ring = top.vertices[loop]
        k = len(loop)
        verts.append(ring)
        faces.append(n + ear_clip(ring[:, :2])[:, ::-1])  # counter-clockwise from above: face down
        n += k
    return trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False)


def ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangles (indices into `poly`) covering a simple 2-D polygon, counter-clockwise or not; no
    triangle overlaps another (a fan from the centroid does when the outline is not star-shaped,
    and coplanar overlaps flicker as streaks)."""
    pts = np.asarray(poly, float)
    idx = list(range(len(pts)))
    area = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    sign = 1.0 if area > 0 else -1.0

    def cross(a, b, c):
        return sign * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    out = []
    guard = 0
    while len(idx) > 3 and guard < 10 * len(pts) ** 2:
        guard += 1
        m = len(idx)
        for j in range(m):
            i0, i1, i2 = idx[j - 1], idx[j], idx[(j + 1) % m]
            a, b, c = pts[i0], pts[i1], pts[i2]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex or flat corner
            others = [q for q in idx if q not in (i0, i1, i2)]
            if others:
                p = pts[others]
                inside = (
                    (sign * ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])) >= 0)
                    & (sign * ((c[0] - b[0]) * (p[:, 1] - b[1]) - (c[1] - b[1]) * (p[:, 0] - b[0])) >= 0)
                    & (sign * ((a[0] - c[0]) * (p[:, 1] - c[1]) - (a[1] - c[1]) * (p[:, 0] - c[0])) >= 0)
                )
                if inside.any():
                    continue
            out.append((i0, i1, i2) if sign > 0 else (i2, i1, i0))
            del idx[j]
            break
        else:
            break  # no ear left (a degenerate outline): close the rest as a fan
    for j in range(1, len(idx) - 1):
        out.append((idx[0], idx[j], idx[j + 1]) if sign > 0 else (idx[j + 1], idx[j], idx[0]))
    return np.asarray(out, np.int64)


def deviation(full: trimesh.Trimesh, light: trimesh.Trimesh) -> float:
    """Largest distance (mm) from a vertex of the light copy to the full surface."""
    _, dist, _ = trimesh.proximity.closest_point(full, light.vertices)
    return float(np.max(dist))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pack", default=str(ASSETS_DIR / "prp"), help="pack folder (default assets/prp)")
    p.add_argument("--faces", type=int, default=None, help="target triangles (default per mesh)")
    args = p.parse_args(argv)
    root = Path(args.pack)
    for name, n in TARGETS.items():
        src = root / "meshes" / f"{name}.ply"
        if not src.is_file():
            print(f"error: {src} not found", file=sys.stderr)
            return 2
        full = trimesh.load(src, process=False)
        light = decimate(full.vertices, full.faces, args.faces or n)
        out = root / "meshes" / f"{name}_display.ply"
        light.export(out, encoding="binary")
        print(
            f"{out}: {len(light.faces)} triangles (from {len(full.faces)}), "
            f"largest deviation {deviation(full, light):.2f} mm"
        )
    skin = trimesh.load(root / "meshes" / "skin.ply", process=False)
    cut = neck_cut(skin, NECK_CUT_Z)
    out = root / "meshes" / "skin_display.ply"
    cut.export(out, encoding="binary")
    print(f"{out}: {len(cut.faces)} triangles, cut level at Z = {NECK_CUT_Z} mm, its cap has its own vertices")
    return 0


if __name__ == "__main__":
    sys.exit(main())
