"""Painted features on the prp skin: open eyes (sclera, iris, pupil) and the lips with their fissure.

The skin mesh is coarse (edges of about 6 mm) and comes from a body with closed eyes, so neither the
pupils nor the corners of the mouth - the features landmarks 1 and 2 are measured from (thesis
3.3.4) - can be seen on it. They are added as thin shells that follow the skin a fraction of a
millimetre in front of it, like paint: a shape is laid out in the frontal (x, z) plane, each of its
vertices is projected straight back onto the skin and lifted off it along the skin's normal. The skin
itself stays closed and unchanged, so picking and the landmark positions are those of the skin;
the shells are drawn but not picked.

All coordinates are in the work frame of prepare_prp (mm, +X the subject's left, +Y anterior, +Z up).
"""

from __future__ import annotations

import numpy as np
import trimesh

#: eye opening (palpebral fissure) and iris sizes of adults, mm
FISSURE_UPPER_MM = 5.5  # upper lid above the pupil centre
FISSURE_LOWER_MM = 4.5  # lower lid below it
IRIS_RADIUS_MM = 5.9
#: lip vermilion heights above / below the mouth line at the midline, mm
UPPER_LIP_MM = 8.0
LOWER_LIP_MM = 9.0
FISSURE_HALF_MM = 0.7  # half the width of the dark line between the lips at the midline


def project(skin: trimesh.Trimesh, xz: np.ndarray, lift_mm: float) -> np.ndarray:
    """Frontal (x, z) points -> points `lift_mm` in front of the skin along its normal."""
    n = len(xz)
    origins = np.c_[xz[:, 0], np.full(n, 400.0), xz[:, 1]]
    dirs = np.tile([0.0, -1.0, 0.0], (n, 1))
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(skin)
    tri, ray, loc = inter.intersects_id(origins, dirs, multiple_hits=True, return_locations=True)
    best = np.full(n, -np.inf)
    face = np.full(n, -1)
    for t, r, p in zip(tri, ray, loc):
        if p[1] > best[r]:
            best[r], face[r] = p[1], t
    if np.any(face < 0):
        raise RuntimeError(f"{int(np.sum(face < 0))} decal points have no skin in front of them")
    surface = np.c_[xz[:, 0], best, xz[:, 1]]
    return surface + lift_mm * skin.face_normals[face]


def grid_mesh(skin: trimesh.Trimesh, xz: np.ndarray, lift_mm: float) -> trimesh.Trimesh:
    """A (nu, nv, 2) grid of frontal points -> a triangle mesh on the skin (normals facing out)."""
    nu, nv, _ = xz.shape
    verts = project(skin, xz.reshape(-1, 2), lift_mm)
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.vstack([np.c_[a, b, c], np.c_[a, c, d]])
    # wind the triangles so their normals face forward (+Y), out of the face
    t = verts[faces]
    flip = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, 1] < 0
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(verts, faces, process=False)


def _lids(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper and lower lid heights (mm above / below the pupil centre) across the opening, u in [0, 1]."""
    s = np.sin(np.pi * np.clip(u, 0.0, 1.0)) ** 0.8
    return FISSURE_UPPER_MM * s, FISSURE_LOWER_MM * s


def eye_meshes(skin: trimesh.Trimesh, pupils: dict, pupil_radius_mm: float) -> dict[str, trimesh.Trimesh]:
    """Sclera, iris and pupil shells for both eyes. `pupils`: side -> (x, z) of the pupil centre;
    the opening reaches 14 mm toward the nose and 16 mm toward the ear from it."""
    sclera, iris, pupil = [], [], []
    for side, (px, pz) in pupils.items():
        sgn = 1.0 if side == "left" else -1.0  # lateral is +X on the left
        x_med, x_lat = px - sgn * 14.0, px + sgn * 16.0

        def lid_at(x, x_med=x_med, x_lat=x_lat, pz=pz):
            u = (x - x_med) / (x_lat - x_med)
            up, lo = _lids(u)
            return pz + up, pz - lo

        u = np.linspace(0.0, 1.0, 61)
        x = x_med + u * (x_lat - x_med)
        top, bottom = lid_at(x)
        v = np.linspace(0.0, 1.0, 13)
        g = np.stack([np.repeat(x[:, None], len(v), 1), bottom[:, None] + v[None] * (top - bottom)[:, None]], axis=2)
        sclera.append(grid_mesh(skin, g, 0.35))

        def disc(radius, lift, px=px, pz=pz, lid_at=lid_at):
            r = np.linspace(0.0, radius, 9)
            a = np.linspace(0.0, 2 * np.pi, 49)
            gx = px + np.outer(r, np.cos(a))
            gz = pz + np.outer(r, np.sin(a))
            hi, lo = lid_at(gx)
            gz = np.clip(gz, lo, hi)  # the lids cover what lies beyond them
            return grid_mesh(skin, np.stack([gx, gz], axis=2), lift)

        iris.append(disc(IRIS_RADIUS_MM, 0.55))
        pupil.append(disc(pupil_radius_mm, 0.75))
    cat = trimesh.util.concatenate
    return {"eyes": cat(sclera), "irises": cat(iris), "pupils": cat(pupil)}


def lip_meshes(skin: trimesh.Trimesh, left: np.ndarray, right: np.ndarray, line: np.ndarray) -> dict:
    """Lip (vermilion) and lip-line shells between the commissures `left` and `right` (3-D points),
    following the traced mouth line `line` (K, 3) in between."""
    xl, xr = float(left[0]), float(right[0])
    order = np.argsort(line[:, 0])
    lx, lz = line[order, 0], line[order, 2]
    x = np.linspace(xr, xl, 121)
    z = np.interp(x, lx, lz)
    # straight from the traced line's ends to the commissures themselves, then smoothed
    z = z + np.interp(x, [xr, xl], [right[2] - np.interp(xr, lx, lz), left[2] - np.interp(xl, lx, lz)])
    z = np.convolve(np.pad(z, 6, mode="edge"), np.ones(13) / 13, mode="valid")
    z[0], z[-1] = right[2], left[2]
    t = 2.0 * (x - xr) / (xl - xr) - 1.0  # -1 .. 1 from corner to corner
    shape = np.clip(1.0 - t**2, 0.0, 1.0) ** 0.6
    v = np.linspace(0.0, 1.0, 9)

    def band(lo, hi, lift):
        g = np.stack([np.repeat(x[:, None], len(v), 1), lo[:, None] + v[None] * (hi - lo)[:, None]], axis=2)
        return grid_mesh(skin, g, lift)

    lips = trimesh.util.concatenate([band(z, z + UPPER_LIP_MM * shape, 0.35), band(z - LOWER_LIP_MM * shape, z, 0.35)])
    gap = FISSURE_HALF_MM * shape**0.5
    return {"lips": lips, "lip_line": band(z - gap, z + gap, 0.55)}
