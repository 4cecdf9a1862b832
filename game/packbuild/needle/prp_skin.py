"""Head skin for the prp pack: crop the whole-body HRA skin and fit it to the BodyParts3D skull.

The skin and the skull come from two different bodies (thesis 3.3.3 used one laser-scanned head;
we have none), so the skin is fitted, not just placed. Fitting is landmark based: from bony
landmarks (nasion, glabella, orbital rims, zygomatic arches, chin, jaw angles, points on the vault)
rays go outward, and the skin should be met after the soft-tissue depth typical at that landmark.
First a global rotation + translation + (nearly uniform) scale fits those depths in the least
squares sense; then a smooth Gaussian radial-basis warp removes the remaining differences of
shape, since the two heads differ in proportions, not just size; finally constraints are added
wherever bone still pokes through the skin.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation


def apply_fit(points: np.ndarray, params: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    rot = Rotation.from_rotvec(params[:3]).as_matrix()
    s = np.exp(params[3:6])
    return ((points - pivot) * s) @ rot.T + pivot + params[6:9]


def invert_fit(points: np.ndarray, params: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    rot = Rotation.from_rotvec(params[:3]).as_matrix()
    s = np.exp(params[3:6])
    return ((points - pivot - params[6:9]) @ rot) / s + pivot


def fit_depths(
    skin: trimesh.Trimesh,
    origins: np.ndarray,
    directions: np.ndarray,
    depths: np.ndarray,
    anisotropy_weight: float = 50.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmark fit: move and scale the skin so that, going out from each bony landmark along its
    direction, the skin is met after the expected soft-tissue depth.

    The transform is rotation + translation + one scale per axis, with the spread of the three
    log-scales penalised (anisotropy_weight mm per unit) so proportions change only where the
    landmarks demand it. Rays are mapped back into the unmoved skin (an affine map keeps the ray
    parameter), so one ray intersector serves the whole fit. Returns (params, pivot, residuals).
    """
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(skin)
    pivot = origins.mean(0)

    def depth_along(params):
        o = invert_fit(origins, params, pivot)
        d = invert_fit(origins + directions, params, pivot) - o
        loc, ray, _ = inter.intersects_location(o, d, multiple_hits=True)
        t = np.full(len(o), 60.0)  # no skin within reach: a large, finite penalty
        tt = np.einsum("ij,ij->i", loc - o[ray], d[ray]) / np.einsum("ij,ij->i", d[ray], d[ray])
        pos = tt > 0
        np.minimum.at(t, ray[pos], tt[pos])
        return t

    def residual(params):
        ls = params[3:6]
        return np.concatenate([depth_along(params) - depths, anisotropy_weight * (ls - ls.mean())])

    sol = least_squares(residual, np.zeros(9), diff_step=1e-3, x_scale=np.r_[[0.05] * 3, [0.05] * 3, [5.0] * 3])
    return sol.x, pivot, depth_along(sol.x) - depths


def skin_depths(skin: trimesh.Trimesh, origins: np.ndarray, directions: np.ndarray):
    """Distance from each bony landmark to the skin along its direction, and the skin points."""
    inter = trimesh.ray.ray_triangle.RayMeshIntersector(skin)
    loc, ray, _ = inter.intersects_location(origins, directions, multiple_hits=True)
    t = np.full(len(origins), np.inf)
    tt = np.einsum("ij,ij->i", loc - origins[ray], directions[ray])
    pos = tt > 0
    np.minimum.at(t, ray[pos], tt[pos])
    return t, origins + t[:, None] * directions


def warp_to_depths(
    skin: trimesh.Trimesh,
    origins: np.ndarray,
    directions: np.ndarray,
    depths: np.ndarray,
    sigma_mm: float = 22.0,
    rounds: int = 3,
    anchors: np.ndarray | None = None,
    anchor_targets: np.ndarray | None = None,
    carry: np.ndarray | None = None,
):
    """Smooth local warp after the global fit: Gaussian radial basis displacements, solved so the
    skin sits at the expected depth along every landmark ray and fading out some 2-3 sigma away
    from the landmarks.

    `anchors` (K, 3) are skin points that must move to `anchor_targets` (K, 3) (a soft-tissue
    feature the depth tables do not fix, such as the corners of the mouth); `carry` (M, 3) are
    further points moved with the skin (a traced lip line). Returns (warped skin, final depth
    residuals), plus (anchors, carried points) after the warp when anchors or carry are given."""
    out = skin.copy()
    anchors = np.zeros((0, 3)) if anchors is None else np.asarray(anchors, float).copy()
    goals = np.zeros((0, 3)) if anchor_targets is None else np.asarray(anchor_targets, float)
    carried = np.zeros((0, 3)) if carry is None else np.asarray(carry, float).copy()
    for _ in range(rounds):
        t, p = skin_depths(out, origins, directions)
        ok = np.isfinite(t)
        disp = np.vstack([-(t - depths)[ok, None] * directions[ok], goals - anchors])
        c = np.vstack([p[ok], anchors])
        k = np.exp(-np.sum((c[:, None] - c[None]) ** 2, axis=2) / (2 * sigma_mm**2))
        w = np.linalg.solve(k + 1e-6 * np.eye(len(c)), disp)

        def moved(q, c=c, w=w):
            kq = np.exp(-np.sum((q[:, None] - c[None]) ** 2, axis=2) / (2 * sigma_mm**2))
            return q + kq @ w

        out.vertices = moved(np.asarray(out.vertices))
        anchors = moved(anchors) if len(anchors) else anchors
        carried = moved(carried) if len(carried) else carried
    t, _ = skin_depths(out, origins, directions)
    if anchor_targets is None and carry is None:
        return out, t - depths
    return out, t - depths, anchors, carried


def enclose(
    skin,
    skull_vertices,
    origins,
    directions,
    depths,
    inside_fn,
    min_depth_mm: float = 3.0,
    rounds: int = 4,
    cluster_mm: float = 12.0,
    anchors: np.ndarray | None = None,
    carry: np.ndarray | None = None,
):
    """Add depth constraints where bone still pokes through the skin, and re-warp, until the
    skull is enclosed (or `rounds` is spent); `anchors` are held where they are and `carry` moves
    with the skin. Returns (skin, origins, directions, depths, anchors, carried)."""
    anchors = np.zeros((0, 3)) if anchors is None else np.asarray(anchors, float)
    carry = np.zeros((0, 3)) if carry is None else np.asarray(carry, float)
    for _ in range(rounds):
        outside = np.flatnonzero(~inside_fn(skin, skull_vertices))
        if len(outside) == 0:
            break
        # One new constraint per cluster of offending vertices.
        picked: list[np.intp] = []
        for i in outside:
            if all(np.linalg.norm(skull_vertices[i] - skull_vertices[j]) > cluster_mm for j in picked):
                picked.append(i)
        # Push out radially from the middle of the head: bone normals on thin plates (nasal
        # bones, orbital walls) can point sideways.
        n = skull_vertices[picked] - np.array([0.0, -10.0, 20.0])
        n = n / np.linalg.norm(n, axis=1)[:, None]
        # the ray starts 10 mm back inside the head: from the bone point itself, which already lies
        # outside the skin, it would meet no skin and the constraint would be void
        origins = np.vstack([origins, skull_vertices[picked] - 10.0 * n])
        directions = np.vstack([directions, n])
        depths = np.r_[depths, np.full(len(picked), min_depth_mm + 10.0)]
        skin, _, anchors, carry = warp_to_depths(
            skin, origins, directions, depths, anchors=anchors, anchor_targets=anchors.copy(), carry=carry
        )
    return skin, origins, directions, depths, anchors, carry


def crop_head(skin: trimesh.Trimesh, z_cut: float) -> trimesh.Trimesh:
    """Keep the part above z = z_cut (the head and upper neck) and close the cut with a fan."""
    # Whole triangles above the cut: the jagged edge is closed by the cap below.
    keep = np.flatnonzero((skin.vertices[skin.faces][:, :, 2] > z_cut).all(axis=1))
    part = skin.submesh([keep], append=True)
    part.merge_vertices()
    # Largest connected piece (scipy here: trimesh's split would need networkx).
    adj = part.face_adjacency
    graph = coo_matrix((np.ones(len(adj)), (adj[:, 0], adj[:, 1])), shape=(len(part.faces),) * 2)
    _, label = connected_components(graph, directed=False)
    part = part.submesh([np.flatnonzero(label == np.bincount(label).argmax())], append=True)
    edges = part.edges[trimesh.grouping.group_rows(part.edges_sorted, require_count=1)]
    if len(edges) == 0:
        return part
    # Order the boundary edges into one loop, then cap it from its centroid (the neck section is
    # star-shaped about its centre, so a fan is a valid triangulation).
    nxt = {int(a): int(b) for a, b in edges}
    start = int(edges[0, 0])
    loop = [start]
    while True:
        n = nxt[loop[-1]]
        if n == start:
            break
        loop.append(n)
    if len(loop) != len(edges):
        raise RuntimeError("neck cut is not a single loop; choose another cut height")
    centre = part.vertices[loop].mean(0)
    ci = len(part.vertices)
    verts = np.vstack([part.vertices, centre])
    loop_arr = np.array(loop)
    cap = np.c_[loop_arr, np.full(len(loop), ci), np.roll(loop_arr, -1)]
    capped = trimesh.Trimesh(verts, np.vstack([part.faces, cap]), process=True)
    if capped.volume < 0:
        capped.invert()
    return capped
