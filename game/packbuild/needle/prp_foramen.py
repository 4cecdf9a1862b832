"""Find and measure the foramina ovalia in the sphenoid mesh; build the target plugs (thesis 3.3.3).

The thesis added two holes of about 6-7 mm by 3 mm to a skull model by hand. Here the openings are
measured on the real BodyParts3D sphenoid instead: the bone is projected along a direction onto a
fine raster, and a foramen is an empty raster region fully enclosed by bone (a through-hole seen
along that direction). The canal axis is the direction along which the hole looks largest; its
cross-section there gives width (long axis) and height (short axis); the centre sits on that axis
halfway through the bone around the rim.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

RASTER_MM = 0.1


@dataclass(frozen=True)
class Foramen:
    """One measured opening, in the frame of the mesh it was found in."""

    centre: np.ndarray  # (3,) mm
    axis: np.ndarray  # (3,) unit, pointing from the outer (extracranial) side into the cranium
    major: np.ndarray  # (3,) unit, in-plane direction of the width
    width_mm: float
    height_mm: float
    area_mm2: float
    tilt_deg: float  # angle between axis and the search's reference "up"
    canal_mm: float = 0.0  # length along the axis over which bone surrounds the opening


def _basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(d, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(d, a)


def coverage(vertices: np.ndarray, faces: np.ndarray, direction: np.ndarray, res: float = RASTER_MM):
    """Raster of where a line along `direction` meets the mesh: (mask, origin_2d, a, b)."""
    d = direction / np.linalg.norm(direction)
    a, b = _basis(d)
    p = np.c_[vertices @ a, vertices @ b]
    lo = p.min(0) - 1.0
    shape = np.ceil((p.max(0) + 1.0 - lo) / res).astype(int) + 1
    mask = np.zeros(shape, bool)
    for t in p[faces]:
        mn = np.floor((t.min(0) - lo) / res).astype(int)
        mx = np.ceil((t.max(0) - lo) / res).astype(int)
        gx, gy = np.meshgrid(np.arange(mn[0], mx[0] + 1), np.arange(mn[1], mx[1] + 1), indexing="ij")
        px, py = lo[0] + gx * res, lo[1] + gy * res
        (x0, y0), (x1, y1), (x2, y2) = t
        den = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(den) < 1e-12:
            continue
        l0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / den
        l1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / den
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l0 + l1 <= 1 + 1e-9)
        mask[gx[inside], gy[inside]] = True
    return mask, lo, a, b


def enclosed_holes(mask: np.ndarray, res: float, min_area_mm2: float) -> list[np.ndarray]:
    """Empty raster regions that do not reach the raster border: list of (n, 2) cell indices."""
    labels, n = ndimage.label(~mask)
    border = set(np.unique(np.r_[labels[0], labels[-1], labels[:, 0], labels[:, -1]]).tolist())
    out = []
    for i in range(1, n + 1):
        if i in border:
            continue
        cells = np.argwhere(labels == i)
        if len(cells) * res * res >= min_area_mm2:
            out.append(cells)
    return out


def find_hole_seeds(mesh: trimesh.Trimesh, up: np.ndarray, min_area_mm2: float = 3.0) -> list[np.ndarray]:
    """3-D points (on the projection plane) of every through-hole seen along `up`."""
    up = up / np.linalg.norm(up)
    mask, lo, a, b = coverage(mesh.vertices, mesh.faces, up)
    seeds = []
    for cells in enclosed_holes(mask, RASTER_MM, min_area_mm2):
        c2 = lo + cells.mean(0) * RASTER_MM
        p = c2[0] * a + c2[1] * b
        # Lift the seed to the bone's height along the line, so tilted projections keep it in view.
        rel = mesh.vertices - p
        along = rel @ up
        radial = np.linalg.norm(rel - np.outer(along, up), axis=1)
        seeds.append(p + float(np.median(along[radial < 6.0])) * up)
    return seeds


def _measure_along(local: trimesh.Trimesh, seed_line_point: np.ndarray, d: np.ndarray):
    """Hole through `local` along d nearest the seed line: (area, cells-in-3d-plane, a, b) or None."""
    mask, lo, a, b = coverage(local.vertices, local.faces, d)
    holes = enclosed_holes(mask, RASTER_MM, 0.5)
    if not holes:
        return None
    s2 = np.array([seed_line_point @ a, seed_line_point @ b])
    best = min(holes, key=lambda c: np.linalg.norm(lo + c.mean(0) * RASTER_MM - s2))
    if np.linalg.norm(lo + best.mean(0) * RASTER_MM - s2) > 5.0:
        return None
    pts2 = lo + best * RASTER_MM
    return len(best) * RASTER_MM**2, pts2, a, b


def measure_foramen(mesh: trimesh.Trimesh, seed: np.ndarray, up: np.ndarray, max_tilt_deg: float = 50.0) -> Foramen:
    """Measure the hole around `seed`: axis by maximal projected area, then size and centre."""
    up = up / np.linalg.norm(up)
    # Only bone near the hole: elsewhere the tilted projection would be blocked by unrelated parts.
    near = np.linalg.norm(mesh.triangles_center - seed, axis=1) < 14.0
    local = mesh.submesh([np.flatnonzero(near)], append=True)

    def area(d):
        r = _measure_along(local, seed, d)
        return -1.0 if r is None else r[0]

    # Coarse grid over tilts of `up`, then local refinement, maximising the visible hole area.
    e1, e2 = _basis(up)
    best_d, best_a = up, area(up)
    for tx in range(-40, 41, 10):
        for ty in range(-40, 41, 10):
            cand = up + np.tan(np.radians(tx)) * e1 + np.tan(np.radians(ty)) * e2
            cand /= np.linalg.norm(cand)
            if np.degrees(np.arccos(np.clip(cand @ up, -1, 1))) > max_tilt_deg:
                continue
            a_c = area(cand)
            if a_c > best_a + 1e-9:
                best_d, best_a = cand, a_c
    e1, e2 = _basis(best_d)
    step = 5.0
    while step >= 0.6:
        improved = True
        while improved:
            improved = False
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                cand = best_d + np.tan(np.radians(step)) * (dx * e1 + dy * e2)
                cand /= np.linalg.norm(cand)
                if np.degrees(np.arccos(np.clip(cand @ up, -1, 1))) > max_tilt_deg:
                    continue
                a_c = area(cand)
                if a_c > best_a + 1e-9:
                    best_d, best_a, improved = cand, a_c, True
            e1, e2 = _basis(best_d)
        step /= 2.0
    res = _measure_along(local, seed, best_d)
    if res is None:
        raise RuntimeError("foramen lost while refining its axis")
    area_mm2, pts2, a, b = res
    c2 = pts2.mean(0)
    cov = np.cov((pts2 - c2).T)
    evals, evecs = np.linalg.eigh(cov)
    # A filled ellipse with semi-axis s has variance s^2/4 along that axis.
    width = 4.0 * np.sqrt(evals[1])
    height = 4.0 * np.sqrt(evals[0])
    major = evecs[0, 1] * a + evecs[1, 1] * b
    line_point = c2[0] * a + c2[1] * b
    line_point = line_point + ((seed - line_point) @ best_d) * best_d  # level with the bone
    centre, canal = _canal_centre(local, line_point, best_d, width)
    tilt = float(np.degrees(np.arccos(np.clip(best_d @ up, -1, 1))))
    return Foramen(
        centre, best_d, major / np.linalg.norm(major), float(width), float(height), float(area_mm2), tilt, canal
    )


def _canal_centre(local: trimesh.Trimesh, line_point: np.ndarray, d: np.ndarray, width: float):
    """Where along the axis the bone closes all round it: the canal. Its middle is the centre.

    At each station along the axis, rays go out in 16 directions across it; the station is
    enclosed when every ray meets bone within the opening's width. The longest run of enclosed
    stations is the canal; returns (centre, canal length in mm)."""
    e1, e2 = _basis(d)
    angles = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    dirs = np.outer(np.cos(angles), e1) + np.outer(np.sin(angles), e2)
    stations = np.arange(-15.0, 15.0 + 1e-9, 0.25)
    origins = np.repeat(line_point + np.outer(stations, d), len(dirs), axis=0)
    rays = np.tile(dirs, (len(stations), 1))
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(local)
    loc, idx, _ = inter.intersects_location(origins, rays, multiple_hits=True)
    loc = np.asarray(loc, float).reshape(-1, 3)
    t = np.full(len(origins), np.inf)
    tt = np.einsum("ij,ij->i", loc - origins[idx], rays[idx])
    ok = tt > 0
    np.minimum.at(t, idx[ok], tt[ok])
    enclosed = np.all(t.reshape(len(stations), len(dirs)) < width, axis=1)
    best, run, start = (0, 0), 0, 0
    for i, e in enumerate(enclosed):
        if e:
            if run == 0:
                start = i
            run += 1
            if run > best[1] - best[0]:
                best = (start, start + run)
        else:
            run = 0
    if best[1] == best[0]:
        raise RuntimeError("the opening is not enclosed by bone anywhere along its axis")
    mid = 0.5 * (stations[best[0]] + stations[best[1] - 1])
    return line_point + mid * d, float(stations[best[1] - 1] - stations[best[0]])


def plug_mesh(f: Foramen, thickness_mm: float = 3.0, sections: int = 32) -> trimesh.Trimesh:
    """Closed elliptic cylinder filling the opening: the needle's target object (thesis 3.6)."""
    minor = np.cross(f.axis, f.major)
    ang = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = np.outer(np.cos(ang) * 0.5 * f.width_mm, f.major) + np.outer(np.sin(ang) * 0.5 * f.height_mm, minor)
    h = 0.5 * thickness_mm * f.axis
    verts = np.vstack([f.centre + ring - h, f.centre + ring + h, [f.centre - h, f.centre + h]])
    n = sections
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, j, n + j], [i, n + j, n + i], [2 * n, j, i], [2 * n + 1, n + i, n + j]]
    m = trimesh.Trimesh(verts, np.array(faces), process=True)
    if m.volume < 0:
        m.invert()
    return m
