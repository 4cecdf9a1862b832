"""Facial landmarks, reference planes, the aiming check and clear needle paths (thesis 3.3.4, 6.1.5).

All inputs are meshes in the prp head frame (mm; +X subject's left, +Y anterior, +Z up). The skin
points are found on the fitted skin itself: the closed lips are traced as a ridge in a frontal
depth map and its lateral ends are the oral commissures; the pupils are taken in front of the
centres of the bony orbital openings; the tragus is where the skin closes over the bony external
auditory meatus. The ideal landmarks follow thesis 3.3.4: 25 mm lateral to the commissure in its
axial plane, at the medial aspect of the pupil, and 30 mm anterior to the meatus in its axial plane.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

PUPIL_RADIUS_MM = 2.0  # medial aspect = pupil centre moved this far toward the midline
#: the last stretch of a path, inside the bony canal of the foramen, where bone around the needle is expected
CANAL_MM = 4.0


def first_hits(mesh: trimesh.Trimesh, origins: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance along `direction` (one shared unit vector) to the first hit for every origin
    (inf where none)."""
    dirs = np.broadcast_to(direction, origins.shape).copy()
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    loc, ray_idx, _ = inter.intersects_location(origins, dirs, multiple_hits=True)
    t = np.full(len(origins), np.inf)
    if len(ray_idx):
        d = np.einsum("ij,ij->i", loc - origins[ray_idx], dirs[ray_idx])
        ok = d > 0
        np.minimum.at(t, ray_idx[ok], d[ok])
    return t


def axis_line_hits(mesh: trimesh.Trimesh, points: np.ndarray, axis: int, cell: float = 2.0):
    """All crossings of the lines through `points` parallel to coordinate `axis` with the mesh.

    Returns (point index, coordinate along the axis) pairs. Triangles are bucketed on a 2-D grid
    across the axis, so this is fast for many parallel rays (depth maps, inside tests), where a
    general ray tracer would test every triangle along each long ray.
    """
    uv = [i for i in range(3) if i != axis]
    tri = mesh.triangles
    t2 = tri[:, :, uv]
    lo = np.floor(t2.min(1) / cell).astype(np.int64)
    hi = np.floor(t2.max(1) / cell).astype(np.int64)
    p2 = points[:, uv]
    pc = np.floor(p2 / cell).astype(np.int64)
    key_base = np.int64(1 << 20)
    pkey = (pc[:, 0] + (1 << 19)) * key_base + (pc[:, 1] + (1 << 19))
    order = np.argsort(pkey)
    skeys = pkey[order]
    pi_list, ti_list = [], []
    span = hi - lo + 1
    for dx in range(int(span[:, 0].max())):
        for dy in range(int(span[:, 1].max())):
            sel = np.flatnonzero((span[:, 0] > dx) & (span[:, 1] > dy))
            if len(sel) == 0:
                continue
            k = (lo[sel, 0] + dx + (1 << 19)) * key_base + (lo[sel, 1] + dy + (1 << 19))
            left = np.searchsorted(skeys, k, "left")
            right = np.searchsorted(skeys, k, "right")
            cnt = right - left
            if cnt.sum() == 0:
                continue
            rep_t = np.repeat(sel, cnt)
            starts = np.repeat(left, cnt)
            offs = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            pi_list.append(order[starts + offs])
            ti_list.append(rep_t)
    if not pi_list:
        return np.zeros(0, int), np.zeros(0)
    pi = np.concatenate(pi_list)
    ti = np.concatenate(ti_list)
    a, b, c = t2[ti, 0], t2[ti, 1], t2[ti, 2]
    q = p2[pi]
    den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    good = np.abs(den) > 1e-12
    den = np.where(good, den, 1.0)
    l0 = ((b[:, 1] - c[:, 1]) * (q[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (q[:, 1] - c[:, 1])) / den
    l1 = ((c[:, 1] - a[:, 1]) * (q[:, 0] - c[:, 0]) + (a[:, 0] - c[:, 0]) * (q[:, 1] - c[:, 1])) / den
    l2 = 1.0 - l0 - l1
    inside = good & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    # Half-open rule on shared edges is not needed for depth maps; inside tests use a jittered axis.
    za = tri[ti, 0, axis] * l0 + tri[ti, 1, axis] * l1 + tri[ti, 2, axis] * l2
    return pi[inside], za[inside]


def inside_closed(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Parity test along +Z for a closed mesh (points exactly on edges are vanishingly unlikely
    with real coordinates; a tiny fixed offset of the query keeps it deterministic)."""
    q = points + np.array([1.234e-4, 2.345e-4, 0.0])
    pi, z = axis_line_hits(mesh, q, 2)
    above = z > q[pi, 2]
    count = np.bincount(pi[above], minlength=len(points))
    return count % 2 == 1


def depth_map(mesh, xs, zs):
    """Frontal depth map: the most anterior y of the mesh at each (x, z) (nan where none)."""
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    pts = np.c_[gx.ravel(), np.zeros(gx.size), gz.ravel()]
    pi, y = axis_line_hits(mesh, pts, 1)
    out = np.full(gx.size, -np.inf)
    np.maximum.at(out, pi, y)
    out[~np.isfinite(out)] = np.nan
    return out.reshape(gx.shape)


def _rim(values: np.ndarray, start: int, step: int, rise: bool, jump: float = 12.0) -> int:
    """Walk from `start` to the orbital margin: the first place where the frontal depth steps
    forward (medial, superior, inferior margins) or falls back (lateral margin, beyond which the
    temporal fossa lies) by more than `jump` mm within two samples. Returns the margin's index."""
    i = start
    while 0 <= i + 2 * step < len(values):
        a, b = values[i], values[i + 2 * step]
        if np.isnan(b):
            return i
        if (rise and b - a > jump) or (not rise and a - b > jump):
            # The margin is the more anterior of the samples across the step.
            k = i + 2 * step if rise else i
            return k if not rise else (i + step if values[i + step] - a > jump else k)
        i += step
    return i


def orbit_centres(skull: trimesh.Trimesh) -> dict[str, np.ndarray]:
    """Centres (x, z) of the orbital openings: midpoints between the margins found on the frontal
    depth map (medial/lateral along a row, superior/inferior along a column), iterated."""
    xs = np.arange(-70.0, 70.01, 1.0)
    zs = np.arange(-30.0, 70.01, 1.0)
    y = depth_map(skull, xs, zs)
    out = {}
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        cx, cz = sgn * 28.0, 20.0  # a start inside the orbit of an adult skull in this frame
        for _ in range(3):
            i = int(np.argmin(np.abs(xs - cx)))
            j = int(np.argmin(np.abs(zs - cz)))
            med = _rim(y[:, j], i, -int(sgn), rise=True)
            lat = _rim(y[:, j], i, int(sgn), rise=False)
            inf = _rim(y[i, :], j, -1, rise=True)
            sup = _rim(y[i, :], j, 1, rise=True)
            cx, cz = 0.5 * (xs[med] + xs[lat]), 0.5 * (zs[inf] + zs[sup])
        out[side] = np.array([cx, cz])
        out[side + "_box"] = np.array([xs[med], xs[lat], zs[inf], zs[sup]])
    return out


def skin_point_in_front(skin: trimesh.Trimesh, x: float, z: float) -> np.ndarray:
    t = first_hits(skin, np.array([[x, 400.0, z]]), np.array([0.0, -1.0, 0.0]))[0]
    if not np.isfinite(t):
        raise RuntimeError(f"no skin in front of x={x:.1f} z={z:.1f}")
    return np.array([x, 400.0 - t, z])


def mouth_corners(skin: trimesh.Trimesh, z_lo: float, z_hi: float, res: float = 0.5, fade: float = 0.5):
    """Trace the closed lips on a frontal depth map of the skin and return their lateral ends.

    On this coarse skin the lip fissure itself is not resolved, but the lips are: they form a
    horizontal ridge (skin standing out from the profile above and below it), about a millimetre
    high. The ridge is taken at the midline between z_lo and z_hi and followed sideways, row by row
    within 2 mm of the previous one; its strength is smoothed over 7 mm along the mouth so one weak
    column does not end it, and the commissures are where the smoothed strength falls below `fade`
    times its median over the middle 20 mm. Returns (trace (K, 3) points on the skin, ends
    {"left"/"right": (x, z)}) in the work frame (+X the subject's left)."""
    xs = np.arange(-50.0, 50.01, res)
    zs = np.arange(z_lo - 10.0, z_hi + 10.0 + 1e-9, res)
    y = depth_map(skin, xs, zs)
    h = int(round(3.0 / res))
    ridge = np.full_like(y, np.nan)
    ridge[:, h:-h] = y[:, h:-h] - 0.5 * (y[:, : -2 * h] + y[:, 2 * h :])
    i0 = int(np.argmin(np.abs(xs)))
    window = (zs >= z_lo) & (zs <= z_hi)
    j0 = int(np.nanargmax(np.where(window, ridge[i0], -np.inf)))
    # follow the ridge row outward from the midline
    rows = np.full(len(xs), -1)
    rows[i0] = j0
    for step in (1, -1):
        i, j = i0, j0
        while 0 <= i + step < len(xs):
            lo, hi = max(j - 4, 0), min(j + 5, len(zs))
            col = ridge[i + step, lo:hi]
            if np.all(np.isnan(col)):
                break
            i, j = i + step, lo + int(np.nanargmax(col))
            rows[i] = j
    strength = np.array([ridge[i, j] if j >= 0 else np.nan for i, j in enumerate(rows)])
    k = int(round(3.5 / res))
    filled = np.where(np.isfinite(strength), strength, 0.0)
    smooth = np.convolve(filled, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    smooth[~np.isfinite(strength)] = np.nan
    mid = np.abs(xs) < 10.0
    threshold = fade * float(np.nanmedian(smooth[mid]))
    ends, keep = {}, {i0}
    for step, side in ((1, "left"), (-1, "right")):
        i = i0
        while 0 <= i + step < len(xs) and rows[i + step] >= 0 and smooth[i + step] >= threshold:
            i += step
            keep.add(i)
        ends[side] = (xs[i], zs[rows[i]])
    pts = np.array([[xs[i], y[i, rows[i]], zs[rows[i]]] for i in sorted(keep)])
    return pts, ends


def meatus_centres(skull: trimesh.Trimesh) -> dict[str, np.ndarray]:
    """Bony external acoustic meatus openings: canals in a lateral depth map of the skull."""
    ys = np.arange(-50.0, 20.01, 1.0)
    zs = np.arange(-25.0, 25.01, 1.0)
    gy, gz = np.meshgrid(ys, zs, indexing="ij")
    out = {}
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        pts = np.c_[np.zeros(gy.size), gy.ravel(), gz.ravel()]
        pi, xh = axis_line_hits(skull, pts, 0)
        lat = np.full(gy.size, -np.inf)
        np.maximum.at(lat, pi, sgn * xh)  # the most lateral bone on this side of each line
        t = np.where(np.isfinite(lat) & (lat > 0), 300.0 - lat, np.inf).reshape(gy.shape)
        x = sgn * (300.0 - t)  # x of the first bone met coming from the side
        ax = np.abs(np.where(np.isfinite(x), x, 0.0))
        # A canal is where a lateral ray goes at least 10 mm deeper than the bone around it.
        around = ndimage.maximum_filter(ax, size=12)
        deep = (ax < around - 10.0) & np.isfinite(t)
        lab, n = ndimage.label(deep)
        near_void = ndimage.binary_dilation(~np.isfinite(t), iterations=2)
        best, best_score = None, -1.0
        for i in range(1, n + 1):
            inside = lab == i
            cells = np.argwhere(inside)
            if len(cells) < 4 or (inside & near_void).any():
                continue  # a notch open to the edge of the skull, not a canal
            ext = np.ptp(cells, axis=0) + 1.0
            # The meatus is a compact, roughly round canal some 5-12 mm across.
            if ext.max() > 14.0 or ext.max() / ext.min() > 2.5 or len(cells) < 0.5 * ext[0] * ext[1]:
                continue
            score = len(cells) * float(np.mean(around[inside] - ax[inside]))
            if score > best_score:
                best, best_score = cells, score
        if best is None:
            raise RuntimeError(f"no {side} external acoustic meatus found")
        yc, zc = ys[best[:, 0]].mean(), zs[best[:, 1]].mean()
        rim = float(np.median(around[lab == lab[best[0, 0], best[0, 1]]]))
        out[side] = np.array([sgn * rim, yc, zc])
    return out


def skin_out_from(skin: trimesh.Trimesh, inside: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """First skin crossing going from a point inside the head along `direction`."""
    t = first_hits(skin, inside[None], direction)[0]
    if not np.isfinite(t):
        raise RuntimeError("ray left the head without meeting the skin")
    return inside + t * direction


def contour_point_at(skin, plane_point, plane_normal, centre, dist, accept):
    """Point on the skin contour of a plane at `dist` from `centre` that `accept` allows.

    Several contour points can qualify; the one `accept` scores highest is returned.
    """
    segs = trimesh.intersections.mesh_plane(skin, plane_normal, plane_point)
    cands = []
    for a, b in segs:
        d = b - a
        fa = a - centre
        qa, qb, qc = d @ d, 2 * fa @ d, fa @ fa - dist * dist
        disc = qb * qb - 4 * qa * qc
        if qa < 1e-12 or disc < 0:
            continue
        for t in ((-qb - np.sqrt(disc)) / (2 * qa), (-qb + np.sqrt(disc)) / (2 * qa)):
            if 0.0 <= t <= 1.0:
                cands.append(a + t * d)
    scored = [(accept(p), p) for p in cands]
    scored = [s for s in scored if s[0] is not None]
    if not scored:
        raise RuntimeError("no skin point at the required distance")
    return max(scored, key=lambda s: s[0])[1]


def aiming_miss(lm1: np.ndarray, x_sag: float, y_cor: float, target: np.ndarray) -> dict:
    """Thesis 3.3.4 aiming rule: from landmark 1 toward the line where the sagittal plane x = x_sag
    meets the coronal plane y = y_cor. The needle can be swung vertically in the plane through
    lm1 and that (vertical) line; the miss is the target's distance from that plane."""
    line_pt = np.array([x_sag, y_cor, lm1[2]])
    horiz = line_pt - lm1
    horiz[2] = 0.0
    n = np.cross(horiz, [0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    miss = float(abs((target - lm1) @ n))
    # The needle in that plane that passes closest to the target: aim at the target's projection.
    proj = target - ((target - lm1) @ n) * n
    return {
        "miss_mm": miss,
        "line_offset_mm": [float(target[0] - x_sag), float(target[1] - y_cor)],
        "closest_aim": proj,
    }


def path_hits(bone: trimesh.Trimesh, plug: trimesh.Trimesh, entry: np.ndarray, target: np.ndarray):
    """Distances along entry->target to the first bone hit and to the plug (inf where none)."""
    d = target - entry
    d = d / np.linalg.norm(d)
    tb = first_hits(bone, entry[None], d)[0]
    tp = first_hits(plug, entry[None], d)[0]
    return float(tb), float(tp)


def path_clearance(bone: trimesh.Trimesh, entry: np.ndarray, target: np.ndarray, stop_before_mm: float, step_mm=0.5):
    """Smallest distance (mm) from the segment entry -> target, up to `stop_before_mm` short of the
    target, to the bone surface: how far the straight needle passes from the nearest bone."""
    d = target - entry
    length = float(np.linalg.norm(d))
    ts = np.arange(0.0, max(length - stop_before_mm, 0.0), step_mm)
    pts = entry + np.outer(ts / length, d)
    _, dist, _ = trimesh.proximity.closest_point(bone, pts)
    return float(dist.min())


def clear_entry(skin, bone, plug, lm1, target, radius=15.0, step=0.5):
    """lm1 if its straight path to `target` reaches the plug before bone, else the nearest skin
    point within `radius` of lm1 whose path is clear. Returns (entry, t_bone, t_plug, moved_mm)."""
    tb, tp = path_hits(bone, plug, lm1, target)
    if tp < tb:
        return lm1, tb, tp, 0.0
    # Candidates: a fine grid on the skin's tangent plane at lm1, projected onto the skin.
    normal = skin.face_normals[skin.nearest.on_surface(lm1[None])[2][0]]
    a = np.cross(normal, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    offs = np.arange(-radius, radius + 1e-9, step)
    uv = np.array([(u, v) for u in offs for v in offs if u * u + v * v <= radius * radius])
    cand = skin.nearest.on_surface(lm1 + uv[:, :1] * a + uv[:, 1:] * b)[0]
    dist = np.linalg.norm(cand - lm1, axis=1)
    order = np.lexsort((cand[:, 2], cand[:, 1], cand[:, 0], np.round(dist, 6)))
    cand, dist = cand[order], dist[order]
    keep = dist <= radius
    cand, dist = cand[keep], dist[keep]
    dirs = target - cand
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]

    bone_rays = trimesh.ray.ray_triangle.RayMeshIntersector(bone)
    plug_rays = trimesh.ray.ray_triangle.RayMeshIntersector(plug)

    def first(inter, o, d):
        loc, ray, _ = inter.intersects_location(o, d, multiple_hits=True)
        t = np.full(len(o), np.inf)
        tt = np.einsum("ij,ij->i", loc - o[ray], d[ray])
        ok = tt > 0
        np.minimum.at(t, ray[ok], tt[ok])
        return t

    # Nearest first, in small batches: long rays through a dense mesh cost memory.
    for s0 in range(0, len(cand), 64):
        o, d = cand[s0 : s0 + 64], dirs[s0 : s0 + 64]
        t_plug = first(plug_rays, o, d)
        t_bone = first(bone_rays, o, d)
        clear = np.flatnonzero(t_plug < t_bone)
        if len(clear):
            i = clear[0]
            return o[i], float(t_bone[i]), float(t_plug[i]), float(dist[s0 + i])
    return lm1, tb, tp, float("nan")


# Typical adult soft-tissue depths (mm) at craniometric landmarks, rounded from published
# facial tissue-depth tables; used only to fit the skin of another body to this skull.
TISSUE_DEPTH_MM = {
    "vertex": 6.0,
    "opisthocranion": 6.5,
    "glabella": 5.5,
    "nasion": 6.5,
    "rhinion": 3.0,
    "supraorbital": 7.0,
    "infraorbital": 8.5,
    "zygion": 9.0,
    "euryon": 7.0,
    "pogonion": 11.0,
    "menton": 7.5,
    "gonion": 14.0,
}


def bony_landmarks(skull: trimesh.Trimesh, mandible: trimesh.Trimesh, orbits: dict) -> list[tuple]:
    """(name, point on bone, outward unit direction, expected soft-tissue depth) for the fit."""
    out = []
    X, Y, Z = np.eye(3)
    zs = np.arange(-40.0, 110.0, 0.5)
    prof = depth_map(skull, np.array([0.0]), zs)[0]
    # Nasion: deepest point of the midline profile between the nasal bones and the glabella.
    i_rh = int(np.nanargmax(np.where(zs < 25.0, prof, -np.inf)))
    upper = (zs > zs[i_rh]) & (zs < zs[i_rh] + 60.0)
    i_gl = int(np.nanargmax(np.where(upper & (zs > zs[i_rh] + 25.0), prof, -np.inf)))
    i_na = int(np.nanargmin(np.where((zs > zs[i_rh]) & (zs < zs[i_gl]), prof, np.inf)))
    for name, i in (("nasion", i_na), ("glabella", i_gl)):
        out.append((name, np.array([0.0, prof[i], zs[i]]), Y))
    v = skull.vertices
    # Rhinion: the tip of the nasal bones, which need not lie exactly on x = 0.
    nasal = (np.abs(v[:, 0]) < 8.0) & (v[:, 2] > zs[i_rh] - 10.0) & (v[:, 2] < zs[i_na])
    out.append(("rhinion", v[nasal][np.argmax(v[nasal][:, 1])], Y))
    mid = np.abs(v[:, 0]) < 3.0
    out.append(("vertex", v[mid][np.argmax(v[mid][:, 2])], Z))
    back = mid & (v[:, 2] > 0.0)
    out.append(("opisthocranion", v[back][np.argmin(v[back][:, 1])], -Y))
    mz = np.arange(-90.0, -20.0, 0.5)
    mp = depth_map(mandible, np.array([0.0]), mz)[0]
    i_pg = int(np.nanargmax(mp))
    out.append(("pogonion", np.array([0.0, mp[i_pg], mz[i_pg]]), Y))
    w = mandible.vertices
    chin = np.abs(w[:, 0]) < 3.0
    out.append(("menton", w[chin][np.argmin(w[chin][:, 2])], -Z))
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        med, lat, inf, sup = orbits[side + "_box"]
        ox = orbits[side][0]
        for name, z0, dz in (("supraorbital", sup, 3.0), ("infraorbital", inf, -3.0)):
            y = depth_map(skull, np.array([ox]), np.array([z0 + dz]))[0, 0]
            out.append((f"{name}_{side}", np.array([ox, y, z0 + dz]), Y))
        arch = (v[:, 0] * sgn > 0) & (np.abs(v[:, 2]) < 15.0) & (v[:, 1] > -15.0) & (v[:, 1] < 40.0)
        out.append((f"zygion_{side}", v[arch][np.argmax(v[arch][:, 0] * sgn)], sgn * X))
        vault = (v[:, 0] * sgn > 0) & (v[:, 2] > 20.0)
        out.append((f"euryon_{side}", v[vault][np.argmax(v[vault][:, 0] * sgn)], sgn * X))
        ang = w[:, 0] * sgn > 20.0
        # Gonion: the ramus corner, the point furthest back-and-down on this side.
        g = w[ang][np.argmax(-w[ang][:, 1] - w[ang][:, 2])]
        out.append((f"gonion_{side}", g, sgn * X))

    def depth(name: str) -> float:
        return TISSUE_DEPTH_MM[name.rsplit("_", 1)[0] if name.endswith(("_left", "_right")) else name]

    return [(n, p, d, depth(n)) for n, p, d in out]


def scalp_rays(
    skull: trimesh.Trimesh,
    centre: np.ndarray,
    z_min: float,
    n_az: int = 12,
    elevations=(5.0, 15.0, 30.0, 45.0, 65.0, 85.0),
    depth_mm: float = 6.0,
):
    """Points on the outer cranial vault and forehead with radial outward directions.

    Rays leave `centre` at the given elevations (degrees above the axial plane) and azimuths; the
    farthest bone crossing is the outer table. Points below z_min (brows, temples, face) are
    left to the facial landmarks."""
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(skull)
    out = []
    for el in elevations:
        n = 1 if el >= 85.0 else n_az
        for k in range(n):
            az = 2 * np.pi * k / n
            d = np.array(
                [np.cos(np.radians(el)) * np.sin(az), np.cos(np.radians(el)) * np.cos(az), np.sin(np.radians(el))]
            )
            loc, _, _ = inter.intersects_location(centre[None], d[None], multiple_hits=True)
            if len(loc) == 0:
                continue
            far = loc[np.argmax((loc - centre) @ d)]
            if far[2] < z_min:
                continue
            out.append((f"scalp_{int(el)}_{k}", far, d, depth_mm))
    return out
