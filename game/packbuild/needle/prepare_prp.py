"""Build the anatomy of the prp pack from the shared BodyParts3D skull and HRA skin meshes.

    python -m chainsim.game.packbuild.needle.prepare_prp --shared ../shared/data/anatomy --out assets/prp

This is the only code that reads the shared anatomy folder; the pack ships what it writes:
meshes/{skull,mandible,skin,foramen_ovale_left,foramen_ovale_right}.ply, anatomy.toml and
docs/anatomy.png. The run is deterministic (fixed seeds, no wall clock).

Steps (thesis 3.3.3 geometric modelling, 3.3.4 landmarks and reference planes, 6.1.5 metrics):
1. measure both foramina ovalia on the sphenoid (prp_foramen) and define the head frame: millimetres,
   +Y anterior, +Z up, origin halfway between the foramen centres;
2. pose the mandible (BodyParts3D poses it open): shut about the condylar axis, set back to an edge
   to edge bite, opened to a relaxed jaw (BuildParams);
3. merge the cranial and facial bones into one surface (hyoid dropped) and cap the small gaps of the
   source surfaces, so skull and mandible are closed (the C-arm view integrates bone thickness);
4. crop the HRA skin to head and upper neck and fit it to the skull, with the mouth placed where
   this skull puts it (prp_skin);
5. find the landmarks, ideal landmarks, reference planes, check the aiming rule and store a clear
   straight needle path per side (prp_landmarks); paint eyes and lips on the skin (prp_face);
6. write everything.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from chainsim.assets import ASSETS_DIR
from chainsim.game.packbuild.needle import prp_face, prp_foramen, prp_landmarks, prp_skin
from chainsim.game.packbuild.needle.prp_preview import marker, render

logger = logging.getLogger(__name__)

# the source meshes sit beside the repository in a development checkout
DEFAULT_SHARED = ASSETS_DIR.parent.parent / "shared" / "data" / "anatomy"

SKULL_DIR = "bodyparts3d_skull"
SKIN_FILE = "hra_skin/VH_M_Skin.glb"
MANDIBLE = "FJ699_BP62994_FMA52748_Mandible.obj"
SPHENOID = "FJ119_BP63007_FMA52736_Sphenoid_bone.obj"
HYOID = "FJ346_BP62980_FMA52749_Hyoid_bone.obj"
MAXILLAE = ("FJ20_BP62955_FMA53649_Right_maxilla.obj", "FJ850_BP63015_FMA53650_Left_maxilla.obj")
N_BONES = 23

PLUG_HEIGHT_MM = 3.0  # thesis 3.3.3: the target is 6-7 mm wide and 3 mm high
NECK_BELOW_CHIN_MM = 35.0


@dataclass(frozen=True)
class BuildParams:
    """The modelling choices of the build (docs/anatomy.md gives the sources)."""

    # The patient's jaw during the procedure: relaxed, not clenched (a finger lies in the cheek
    # beside the teeth, and the jaw snaps shut when the needle enters the foramen).
    jaw_open_mm: float = 12.0
    # The data's mandible, rotated shut, bites with its lower incisors in front of the upper ones;
    # moved back this far it bites about edge to edge (its condyles still in the glenoid fossae).
    mandible_setback_mm: float = 4.0
    # Mouth width (cheilion to cheilion) of adult men in anthropometric surveys.
    mouth_width_mm: float = 54.0
    # At rest about 2 mm of the upper incisors shows below the lip: the mouth line lies that far
    # above the upper incisal edge.
    commissure_above_incisal_mm: float = 2.0


def say(msg: str) -> None:
    logger.info(msg)


def fail(msg: str) -> None:
    print(f"prepare_prp: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


# ---------------------------------------------------------------- frames


def bp3d_to_head(points: np.ndarray, origin_bp: np.ndarray) -> np.ndarray:
    """BodyParts3D (mm, +X left, -Y anterior, +Z up) -> head frame (+Y anterior)."""
    p = np.asarray(points, float) - origin_bp
    return p * np.array([1.0, -1.0, 1.0])


def hra_to_bp3d(points: np.ndarray) -> np.ndarray:
    """The rough placement of the HRA skin in the BodyParts3D frame given with the data."""
    x, y, z = points.T
    return np.c_[1000 * x - 0.6, -1000 * z - 78.7, 1000 * y + 729.3]


def reflect_mesh(mesh: trimesh.Trimesh, origin_bp: np.ndarray) -> trimesh.Trimesh:
    """Map a BodyParts3D-frame mesh to the head frame. Negating Y is a reflection, so the face
    winding is reversed to keep cross-product normals pointing out of the bone."""
    return trimesh.Trimesh(bp3d_to_head(mesh.vertices, origin_bp), mesh.faces[:, ::-1], process=False)


MIRROR_X = np.array([-1.0, 1.0, 1.0])


def mirror_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Negate X; a reflection, so the winding is reversed to keep normals pointing outward."""
    return trimesh.Trimesh(mesh.vertices * MIRROR_X, mesh.faces[:, ::-1], process=False)


def mirror_foramen(f: prp_foramen.Foramen) -> prp_foramen.Foramen:
    return dataclasses.replace(f, centre=f.centre * MIRROR_X, axis=f.axis * MIRROR_X, major=f.major * MIRROR_X)


def mirror_anatomy(anat: dict) -> dict:
    """Points, planes (point and normal) and paths with X negated; normals of x-planes stay +X."""
    points = {k: np.asarray(p, float) * MIRROR_X for k, p in anat["points"].items()}
    planes = {}
    for k, (p, n) in anat["planes"].items():
        n = np.asarray(n, float) * MIRROR_X
        if n[0] < 0 and abs(n[1]) < 1e-12 and abs(n[2]) < 1e-12:
            n = -n  # a sagittal plane keeps a +X normal; the plane is the same
        planes[k] = (np.asarray(p, float) * MIRROR_X, n.tolist())
    paths = {
        s: dict(v, entry=np.asarray(v["entry"], float) * MIRROR_X, target=np.asarray(v["target"], float) * MIRROR_X)
        for s, v in anat["paths"].items()
    }
    return dict(anat, points=points, planes=planes, paths=paths)


# ---------------------------------------------------------------- meshes


def clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Merge coincident vertices, drop degenerate and duplicate faces and unused vertices."""
    m = mesh.copy()
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces(height=1e-6))
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    return m


def condyle_axis(mandible: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """(centre, unit axis) of the line through the two condyles, about which the jaw opens.

    A condyle is the top of the ramus behind the mandibular notch: the highest point on each side,
    then the bone within 6 mm below it and 12 mm of it horizontally (so the coronoid process, which
    can reach nearly as high further forward, is not averaged in)."""
    v = mandible.vertices
    tops = []
    for sgn in (1.0, -1.0):
        side = v[v[:, 0] * sgn > 25.0]
        top = side[np.argmax(side[:, 2])]
        near = (side[:, 2] > top[2] - 6.0) & (np.linalg.norm(side[:, :2] - top[:2], axis=1) < 12.0)
        tops.append(side[near].mean(0))
    c_left, c_right = tops
    axis = c_left - c_right
    return 0.5 * (c_left + c_right), axis / np.linalg.norm(axis)


def _rotate_about(v: np.ndarray, deg: float, axis: np.ndarray, point: np.ndarray) -> np.ndarray:
    return trimesh.transform_points(v, trimesh.transformations.rotation_matrix(np.radians(deg), axis, point))


def close_mandible(mandible: trimesh.Trimesh, maxillae: trimesh.Trimesh, gap_mm: float = 1.0):
    """Rotate the mandible about its condylar axis until its front teeth come within gap_mm of
    the maxillae. Returns (closed mesh, angle in degrees, axis point, axis direction)."""
    v = mandible.vertices
    pivot, axis = condyle_axis(mandible)
    front = v[:, 1] > pivot[1] + 45.0
    tree_pts, _ = trimesh.sample.sample_surface(maxillae, 60_000, seed=3)
    tree = cKDTree(np.vstack([tree_pts, maxillae.vertices]))

    # Closing raises the chin: pick the sign that does.
    sign = 1.0 if _rotate_about(v, 1.0, axis, pivot)[front, 2].mean() > v[front, 2].mean() else -1.0
    deg = 0.0
    while deg < 40.0:
        nxt = deg + 0.1
        d, _ = tree.query(_rotate_about(v, sign * nxt, axis, pivot)[front])
        if d.min() < gap_mm:
            break
        deg = nxt
    closed = trimesh.Trimesh(_rotate_about(v, sign * deg, axis, pivot), mandible.faces, process=False)
    return closed, sign * deg, pivot, axis


def incisal_edges(skull: trimesh.Trimesh, mandible: trimesh.Trimesh) -> tuple[float, float]:
    """Heights (z, mm) of the upper incisal edge (lowest point of the upper incisors) and of the lower
    incisal edge (highest point of the lower incisors), both within 6 mm of the midline."""
    v, w = skull.vertices, mandible.vertices
    upper = float(v[(np.abs(v[:, 0]) < 6.0) & (v[:, 1] > 55.0)][:, 2].min())
    lower = float(w[(np.abs(w[:, 0]) < 6.0) & (w[:, 1] > 50.0)][:, 2].max())
    return upper, lower


def occlusion(skull: trimesh.Trimesh, mandible: trimesh.Trimesh) -> dict:
    """How the closed jaw bites: overjet (mm the upper incisors' labial face lies in front of the
    lower incisors'; negative when the lower ones stand in front) and the room (mm) between the back
    of each condyle and the bone behind it (the back of the glenoid fossa), left then right."""
    v, w = skull.vertices, mandible.vertices
    upper, _ = incisal_edges(skull, mandible)
    up_inc = v[(np.abs(v[:, 0]) < 5.0) & (v[:, 2] < upper + 4.0) & (v[:, 1] > 50.0)]
    lo_inc = w[(np.abs(w[:, 0]) < 5.0) & (w[:, 1] > 50.0)]
    lo_inc = lo_inc[lo_inc[:, 2] > lo_inc[:, 2].max() - 4.0]
    room = []
    for sgn in (1.0, -1.0):
        side = w[w[:, 0] * sgn > 25.0]
        top = side[np.argmax(side[:, 2])]
        # from the top of the condyle straight back: the postglenoid process behind the fossa
        room.append(float(prp_landmarks.first_hits(skull, top[None], np.array([0.0, -1.0, 0.0]))[0]))
    return {"overjet_mm": float(up_inc[:, 1].max() - lo_inc[:, 1].max()), "condyle_room_mm": room}


def open_mandible(mandible: trimesh.Trimesh, skull: trimesh.Trimesh, opening_mm: float):
    """Rotate the closed mandible open about its condylar axis until the lower incisal edge lies
    `opening_mm` below the upper one (pure rotation: the first 20-25 mm of opening is mostly hinge
    movement of the condyles). Returns (mesh, angle in degrees)."""
    pivot, axis = condyle_axis(mandible)
    v = mandible.vertices
    upper, _ = incisal_edges(skull, mandible)
    chin = (np.abs(v[:, 0]) < 6.0) & (v[:, 1] > 50.0)
    sign = 1.0 if _rotate_about(v, 1.0, axis, pivot)[chin, 2].max() < v[chin, 2].max() else -1.0
    deg = 0.0
    while deg < 30.0 and upper - _rotate_about(v, sign * deg, axis, pivot)[chin, 2].max() < opening_mm:
        deg += 0.05
    opened = trimesh.Trimesh(_rotate_about(v, sign * deg, axis, pivot), mandible.faces, process=False)
    return opened, sign * deg


def close_holes(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """Cap every boundary loop with a fan from its centroid, wound like the faces around it, so the
    surface becomes closed (the radiograph integrates bone thickness between entry and exit faces,
    which needs every ray that enters a bone to leave it). Returns (mesh, loops capped)."""
    f = np.asarray(mesh.faces)
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    have = set(map(tuple, directed.tolist()))
    boundary = [(a, b) for a, b in directed.tolist() if (b, a) not in have]
    if not boundary:
        return mesh, 0
    nxt: dict[int, list[int]] = {}
    for a, b in boundary:
        nxt.setdefault(a, []).append(b)
    used: set = set()
    verts = [np.asarray(mesh.vertices)]
    caps = []
    n = len(mesh.vertices)
    loops = 0
    for a, b in boundary:
        if (a, b) in used:
            continue
        loop = [(a, b)]
        used.add((a, b))
        cur = b
        while cur != a:
            cand = [c for c in nxt.get(cur, []) if (cur, c) not in used]
            if not cand:
                break
            used.add((cur, cand[0]))
            loop.append((cur, cand[0]))
            cur = cand[0]
        ids = [e[0] for e in loop]
        centre = np.asarray(mesh.vertices)[ids].mean(0)
        verts.append(centre[None])
        # each boundary edge a->b of a face is matched by the cap edge b->a
        caps += [(e[1], e[0], n) for e in loop]
        n += 1
        loops += 1
    out = trimesh.Trimesh(np.vstack(verts), np.vstack([f, np.asarray(caps)]), process=False)
    return out, loops


def load_inputs(shared: Path):
    skull_dir = shared / SKULL_DIR
    skin_path = shared / SKIN_FILE
    if not skull_dir.is_dir():
        fail(f"missing {skull_dir} (expected the 23 BodyParts3D skull OBJ files)")
    objs = sorted(skull_dir.glob("*.obj"))
    if len(objs) != N_BONES:
        fail(f"{skull_dir} holds {len(objs)} .obj files, expected {N_BONES}")
    for need in (MANDIBLE, SPHENOID, *MAXILLAE):
        if not (skull_dir / need).is_file():
            fail(f"missing {skull_dir / need}")
    if not skin_path.is_file():
        fail(f"missing {skin_path} (expected the HRA VH_M_Skin.glb)")
    bones = {}
    for p in objs:
        bones[p.name] = trimesh.load(p, force="mesh", process=False)
    skin = trimesh.load(skin_path).to_geometry()
    return bones, skin, objs, skin_path


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------- main


def build(shared: Path, out: Path, params: BuildParams | None = None) -> dict:
    params = params or BuildParams()
    say(f"prepare_prp: reading {shared}")
    bones, skin_raw, objs, skin_path = load_inputs(shared)

    say("[1/6] measuring the foramina ovalia on the sphenoid")
    sphenoid = clean(bones[SPHENOID])
    up = np.array([0.0, 0.0, 1.0])
    seeds = prp_foramen.find_hole_seeds(sphenoid, up)
    if len(seeds) != 2:
        raise RuntimeError(f"expected 2 through-holes in the sphenoid greater wings, found {len(seeds)}")
    found = {}
    for s in seeds:
        f = prp_foramen.measure_foramen(sphenoid, s, up)
        side = "left" if f.centre[0] > 0 else "right"  # BodyParts3D +X is the subject's left
        found[side] = f
        say(
            f"  {side}: centre {np.round(f.centre, 2)} (BodyParts3D mm), {f.width_mm:.2f} x {f.height_mm:.2f} mm, "
            f"axis tilted {f.tilt_deg:.1f} deg from vertical, canal {f.canal_mm:.1f} mm long"
        )
    if set(found) != {"left", "right"}:
        raise RuntimeError("the two holes are not one per side")
    origin_bp = 0.5 * (found["left"].centre + found["right"].centre)
    flip = np.array([1.0, -1.0, 1.0])
    foramina = {}
    for side, f in found.items():
        foramina[side] = prp_foramen.Foramen(
            bp3d_to_head(f.centre[None], origin_bp)[0],
            f.axis * flip,
            f.major * flip,
            f.width_mm,
            f.height_mm,
            f.area_mm2,
            f.tilt_deg,
            f.canal_mm,
        )

    say("[2/6] moving the bones to the head frame, posing the mandible")
    head = {name: clean(reflect_mesh(m, origin_bp)) for name, m in bones.items()}
    maxillae = trimesh.util.concatenate([head[n] for n in MAXILLAE])
    mandible, jaw_deg, jaw_pivot, _ = close_mandible(head[MANDIBLE], maxillae)
    say(f"  mandible closed: rotated {jaw_deg:+.1f} deg about the condylar axis through {np.round(jaw_pivot, 1)}")
    skull = clean(trimesh.util.concatenate([m for n, m in head.items() if n not in (MANDIBLE, HYOID)]))
    bite_before = occlusion(skull, mandible)
    mandible = trimesh.Trimesh(
        mandible.vertices - np.array([0.0, params.mandible_setback_mm, 0.0]), mandible.faces, process=False
    )
    bite_after = occlusion(skull, mandible)
    say(
        f"  set back {params.mandible_setback_mm:.1f} mm: overjet {bite_before['overjet_mm']:+.1f} -> "
        f"{bite_after['overjet_mm']:+.1f} mm, room behind the condyles "
        f"{bite_after['condyle_room_mm'][0]:.1f} / {bite_after['condyle_room_mm'][1]:.1f} mm"
    )
    mandible, open_deg = open_mandible(mandible, skull, params.jaw_open_mm)
    mandible = clean(mandible)
    upper_incisal, lower_incisal = incisal_edges(skull, mandible)
    say(
        f"  mandible opened {open_deg:+.1f} deg: incisal edges {upper_incisal - lower_incisal:.1f} mm apart "
        f"(upper at z = {upper_incisal:.1f} mm)"
    )

    say("[3/6] closing the bone surfaces")
    skull, skull_caps = close_holes(skull)
    mandible, mandible_caps = close_holes(mandible)
    bone = trimesh.util.concatenate([skull, mandible])
    say(
        f"  skull {len(skull.faces)} faces ({skull_caps} holes capped), "
        f"mandible {len(mandible.faces)} faces ({mandible_caps} holes capped)"
    )

    say("[4/6] cropping and fitting the skin")
    skin0 = trimesh.Trimesh(
        bp3d_to_head(hra_to_bp3d(skin_raw.vertices), origin_bp), skin_raw.faces[:, ::-1], process=False
    )
    skin0.merge_vertices()
    z_chin = float(mandible.vertices[:, 2].min())
    # Crop generously first (the fit moves the skin), then again below the chin once fitted.
    skin_big = prp_skin.crop_head(skin0, z_chin - NECK_BELOW_CHIN_MM - 40.0)
    orbits = prp_landmarks.orbit_centres(skull)
    mouth_goal = {
        "z": upper_incisal + params.commissure_above_incisal_mm,
        "half_width": 0.5 * params.mouth_width_mm,
        "upper_incisal_z": upper_incisal,
    }
    skin_fit, fit_info, mouth = fit_skin(skin_big, skull, mandible, orbits, mouth_goal)
    skin = prp_skin.crop_head(skin_fit, z_chin - NECK_BELOW_CHIN_MM)
    thick = tissue_report(skin, skull, mandible)
    fit_info["thickness"] = thick
    fit_info["jaw"] = {
        "setback_mm": params.mandible_setback_mm,
        "bite_closed": bite_before,
        "bite_set_back": bite_after,
        "closure_deg": jaw_deg,
        "opening_deg": open_deg,
        "incisal_opening_mm": upper_incisal - lower_incisal,
        "upper_incisal_z_mm": upper_incisal,
    }
    fit_info["holes_capped"] = {"skull": skull_caps, "mandible": mandible_caps}
    say(
        f"  skull vertices outside the skin: {thick['skull_vertices_outside']} of {thick['skull_vertices']}"
        f" {thick['outside_where']}"
    )

    say("[5/6] landmarks, planes, aiming rule, needle paths")
    plugs = {s: prp_foramen.plug_mesh(foramina[s], PLUG_HEIGHT_MM) for s in ("left", "right")}
    anat = landmarks_and_paths(skin, skull, mandible, bone, foramina, plugs, orbits, mouth)
    face = prp_face.eye_meshes(
        skin, {s: orbits[s] for s in ("left", "right")}, prp_landmarks.PUPIL_RADIUS_MM
    ) | prp_face.lip_meshes(
        skin, anat["points"]["oral_commissure_left"], anat["points"]["oral_commissure_right"], mouth["line"]
    )
    say(f"  painted features: {', '.join(f'{k} ({len(m.faces)} faces)' for k, m in face.items())}")

    say("[6/6] writing the pack")
    # The work above runs in the BodyParts3D axes with Y negated (a reflection). Negating X as well
    # makes the shipped frame a proper rotation of the source (180 deg about +Z): right-handed, with
    # +X the subject's right, so a renderer shows the patient unmirrored.
    skull, mandible, skin = (mirror_mesh(m) for m in (skull, mandible, skin))
    plugs = {s: mirror_mesh(m) for s, m in plugs.items()}
    face = {k: mirror_mesh(m) for k, m in face.items()}
    foramina = {s: mirror_foramen(f) for s, f in foramina.items()}
    anat = mirror_anatomy(anat)
    meshes = out / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    written = {
        "skull.ply": skull,
        "mandible.ply": mandible,
        "skin.ply": skin,
        "foramen_ovale_left.ply": plugs["left"],
        "foramen_ovale_right.ply": plugs["right"],
        **{f"{k}.ply": m for k, m in face.items()},
    }
    for name, m in written.items():
        (meshes / name).write_bytes(trimesh.exchange.ply.export_ply(m, encoding="binary", include_attributes=False))
    sizes = {n: (meshes / n).stat().st_size for n in written}
    info = {
        "origin_bp3d_mm": origin_bp.tolist(),
        "foramina": {
            s: {
                "width_mm": f.width_mm,
                "height_mm_opening": f.height_mm,
                "area_mm2": f.area_mm2,
                "centre": f.centre.tolist(),
                "axis": f.axis.tolist(),
                "tilt_deg": f.tilt_deg,
                "canal_mm": f.canal_mm,
            }
            for s, f in foramina.items()
        },
        "mandible_closure_deg": jaw_deg,
        "fit": fit_info,
        "sizes": sizes,
        "inputs": {p.name: sha256(p) for p in [*objs, skin_path]},
    }
    info.update(anat["report"])
    write_toml(out / "anatomy.toml", foramina, anat, info)
    (out / "docs").mkdir(exist_ok=True)
    preview(out / "docs" / "anatomy.png", skull, mandible, skin, plugs, anat, face)
    say(f"prepare_prp: wrote {sum(sizes.values()) / 1e6:.2f} MB of meshes to {meshes}")
    return info


def fit_skin(skin: trimesh.Trimesh, skull: trimesh.Trimesh, mandible: trimesh.Trimesh, orbits: dict, mouth_goal: dict):
    """Landmark-depth fit of the skin to the skull: global, then a smooth warp that also moves the
    corners of the mouth to where this skull puts them, then enclosure.

    Returns (skin, report, mouth) with mouth = {"left"/"right": commissure, "line": traced lip line
    (K, 3), "mid": lip midline point}, all after the warp."""
    L = prp_landmarks
    face = L.bony_landmarks(skull, mandible, orbits)
    glabella = next(p for n, p, _, _ in face if n == "glabella")
    vault_centre = np.array([0.0, -10.0, 40.0])  # inside the braincase, level with the brows
    marks = face + L.scalp_rays(skull, vault_centre, glabella[2] + 6.0)
    names = [m[0] for m in marks]
    origins = np.array([m[1] for m in marks])
    dirs = np.array([m[2] for m in marks])
    depths = np.array([m[3] for m in marks])
    t0, _ = prp_skin.skin_depths(skin, origins, dirs)
    params, pivot, res = prp_skin.fit_depths(skin, origins, dirs, depths)
    say(
        f"  global fit on {len(marks)} landmark depths: rms {np.sqrt(np.mean(res**2)):.2f} mm "
        f"(rough placement {np.sqrt(np.mean((t0 - depths) ** 2)):.2f} mm)"
    )
    fitted = skin.copy()
    fitted.vertices = prp_skin.apply_fit(skin.vertices, params, pivot)

    # The mouth of the other body: its lips traced on the fitted skin. The depth tables fix how thick
    # the tissue is, not where the lips part, so the corners and the midline of the lip line are
    # moved explicitly: to the mouth line above the upper incisal edge, half a mouth width out.
    # The lips are traced on the skin as placed (the global fit can stretch the faint lip ridge
    # below what the tracer sees) and carried through the fit.
    upper = mouth_goal["upper_incisal_z"]
    line, ends = L.mouth_corners(skin, upper - 25.0, upper + 5.0)
    line = prp_skin.apply_fit(line, params, pivot)
    corners = prp_skin.apply_fit(
        np.array([L.skin_point_in_front(skin, *ends[s]) for s in ("left", "right")]), params, pivot
    )
    mid = line[np.argmin(np.abs(line[:, 0]))]
    anchors = np.vstack([corners, mid])
    hw, zg = mouth_goal["half_width"], mouth_goal["z"]
    goals = anchors.copy()
    goals[0, [0, 2]] = (hw, zg)  # work frame: +X is the subject's left
    goals[1, [0, 2]] = (-hw, zg)
    goals[2, 2] = zg
    warped, res_w, anchors_w, line_w = prp_skin.warp_to_depths(
        fitted, origins, dirs, depths, anchors=anchors, anchor_targets=goals, carry=line
    )
    say(
        f"  local warp: max landmark residual {np.abs(res_w).max():.3f} mm; mouth corners moved "
        f"{np.linalg.norm(goals[0] - corners[0]):.1f} / {np.linalg.norm(goals[1] - corners[1]):.1f} mm"
    )
    # bone must stay under the skin everywhere, not only at its vertices: test the triangle centres too
    bone_points = np.vstack([skull.vertices, skull.triangles_center])
    enclosed, o2, _, _, anchors_e, line_e = prp_skin.enclose(
        warped, bone_points, origins, dirs, depths, L.inside_closed, rounds=8, anchors=anchors_w, carry=line_w
    )
    say(f"  enclosure: {len(o2) - len(origins)} extra constraints where bone touched the skin")
    # How far the warp had to move the skin: the part of the body difference a global fit misses.
    moved = np.linalg.norm(enclosed.vertices - fitted.vertices, axis=1)
    info = {
        "landmarks": {
            n: {"depth_mm": float(d), "rough_mm": float(a), "global_fit_mm": float(b + d)}
            for n, d, a, b in zip(names, depths, t0, res)
        },
        "rough_rms_mm": float(np.sqrt(np.mean((t0 - depths) ** 2))),
        "global_rms_mm": float(np.sqrt(np.mean(res**2))),
        "global_max_abs_mm": float(np.abs(res).max()),
        "warp_max_residual_mm": float(np.abs(res_w).max()),
        "warp_displacement_mm": {
            "median": float(np.median(moved)),
            "p95": float(np.percentile(moved, 95)),
            "max": float(moved.max()),
        },
        "extra_enclosure_constraints": int(len(o2) - len(origins)),
        "scales": np.exp(params[3:6]).tolist(),
        "rotation_deg": float(np.degrees(np.linalg.norm(params[:3]))),
        "translation_mm": params[6:9].tolist(),
        "mouth": {
            "traced_corners": corners.tolist(),
            "traced_width_mm": float(corners[0, 0] - corners[1, 0]),
            "traced_mid": mid.tolist(),
            "goal": goals.tolist(),
            "after": anchors_e.tolist(),
            "corner_moves_mm": [float(np.linalg.norm(goals[k] - corners[k])) for k in (0, 1)],
            "mid_move_mm": float(np.linalg.norm(goals[2] - mid)),
        },
    }
    mouth = {"left": anchors_e[0], "right": anchors_e[1], "mid": anchors_e[2], "line": line_e}
    return enclosed, info, mouth


def tissue_report(skin, skull, mandible) -> dict:
    """Soft-tissue depth (skin to nearest bone) over face regions, and skull containment."""
    inside = prp_landmarks.inside_closed(skin, skull.vertices)
    bone = trimesh.util.concatenate([skull, mandible])
    pts, _ = trimesh.sample.sample_surface(bone, 300_000, seed=11)
    tree = cKDTree(np.vstack([pts, bone.vertices]))
    v = skin.vertices
    d, _ = tree.query(v)
    ax, y, z = np.abs(v[:, 0]), v[:, 1], v[:, 2]

    def box(x0, x1, z0, z1, y0):
        """Skin in front of y0 with x0 < |x| < x1 and z0 < z < z1 (head frame, mm)."""
        return (ax > x0) & (ax < x1) & (z > z0) & (z < z1) & (y > y0)

    regions = {
        "forehead": box(-1, 30, 45, 75, 40),
        "cheek_zygoma": box(30, 60, -5, 15, 40),
        "cheek_maxilla": box(15, 40, -35, -5, 45),
        "buccal_landmark1": box(30, 55, -60, -35, 30),
        "chin": box(-1, 12, -68, -45, 60),
        "vault": z > 80,
    }
    out = {
        "skull_vertices_outside": int((~inside).sum()),
        "skull_vertices": int(len(inside)),
        "outside_where": np.round(skull.vertices[~inside], 1).tolist()[:10],
    }
    for k, m in regions.items():
        if m.sum() == 0:
            out[k] = None
            continue
        out[k] = {
            "n": int(m.sum()),
            "min": float(d[m].min()),
            "p5": float(np.percentile(d[m], 5)),
            "median": float(np.median(d[m])),
            "p95": float(np.percentile(d[m], 95)),
            "max": float(d[m].max()),
        }
    face = (v[:, 1] > 30) & (v[:, 2] > -70) & (v[:, 2] < 75)
    out["face_all"] = {
        "n": int(face.sum()),
        "min": float(d[face].min()),
        "p5": float(np.percentile(d[face], 5)),
        "median": float(np.median(d[face])),
        "p95": float(np.percentile(d[face], 95)),
    }
    return out


def landmarks_and_paths(skin, skull, mandible, bone, foramina, plugs, orbits, mouth) -> dict:
    L = prp_landmarks
    points: dict = {}
    planes: dict = {}
    paths: dict = {}
    report: dict[str, dict] = {"aiming": {}, "paths": {}}
    meatus = L.meatus_centres(skull)
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        comm = L.skin_point_in_front(skin, float(mouth[side][0]), float(mouth[side][2]))
        ox, oz = orbits[side]
        pupil_med = L.skin_point_in_front(skin, ox - sgn * L.PUPIL_RADIUS_MM, oz)
        m = meatus[side]
        tragus = L.skin_out_from(skin, m - sgn * np.array([5.0, 0, 0]), np.array([sgn, 0.0, 0.0]))
        lm1 = L.contour_point_at(
            skin,
            comm,
            [0, 0, 1],
            comm,
            25.0,
            lambda p, sgn=sgn, comm=comm: p[1] if p[0] * sgn > abs(comm[0]) else None,
        )
        lm3 = L.contour_point_at(
            skin,
            tragus,
            [0, 0, 1],
            tragus,
            30.0,
            lambda p, sgn=sgn, tragus=tragus: abs(p[0]) if (p[0] * sgn > 0 and p[1] > tragus[1] + 10) else None,
        )
        points[f"oral_commissure_{side}"] = comm
        points[f"pupil_medial_{side}"] = pupil_med
        points[f"tragus_{side}"] = tragus
        points[f"foramen_ovale_{side}"] = foramina[side].centre
        points[f"landmark1_ideal_{side}"] = lm1
        points[f"landmark2_ideal_{side}"] = pupil_med
        points[f"landmark3_ideal_{side}"] = lm3
        planes[f"axial_commissure_{side}"] = (comm, [0.0, 0.0, 1.0])
        planes[f"sagittal_pupil_{side}"] = (pupil_med, [1.0, 0.0, 0.0])
        planes[f"coronal_landmark3_{side}"] = (lm3, [0.0, 1.0, 0.0])
        planes[f"axial_tragus_{side}"] = (tragus, [0.0, 0.0, 1.0])
        fc = foramina[side].centre
        aim = L.aiming_miss(lm1, pupil_med[0], lm3[1], fc)
        report["aiming"][side] = {"miss_mm": aim["miss_mm"], "foramen_minus_line_xy_mm": aim["line_offset_mm"]}
        entry, tb, tp, moved = L.clear_entry(skin, bone, plugs[side], lm1, fc)
        paths[side] = {"entry": entry, "target": fc, "clear": bool(tp < tb)}
        tb1, tp1 = L.path_hits(bone, plugs[side], lm1, fc)
        length = float(np.linalg.norm(fc - lm1))
        report["paths"][side] = {
            "from_landmark1_mm": moved,
            "t_plug_mm": tp,
            "t_bone_mm": tb,
            "lm1_direct": {
                "t_plug_mm": tp1,
                "t_bone_mm": tb1,
                "length_mm": length,
                "clear": bool(tp1 < tb1),
                "bone_free_until_mm": float(min(tb1, length)),
                "clearance_mm": L.path_clearance(bone, lm1, fc, stop_before_mm=L.CANAL_MM),
            },
        }
        report.setdefault("raw", {})[side] = {"orbit_xz": orbits[side].tolist(), "meatus": meatus[side].tolist()}
    return {"points": points, "planes": planes, "paths": paths, "report": report}


HELP = {
    "oral_commissure": "corner of the mouth on the skin ({side})",
    "pupil_medial": (
        "medial aspect of the {side} pupil, on the skin under the painted eye; pupil centre in front of the orbit"
    ),
    "tragus": "{side} tragus: the skin over the bony external acoustic meatus",
    "foramen_ovale": "centre of the {side} foramen ovale (needle target)",
    "landmark1_ideal": (
        "ideal landmark 1 ({side}): skin 25 mm lateral to the oral commissure in its axial plane; needle entry"
    ),
    "landmark2_ideal": "ideal landmark 2 ({side}): skin at the medial aspect of the pupil",
    "landmark3_ideal": "ideal landmark 3 ({side}): skin 30 mm anterior to the tragus in its axial plane",
}
PLANE_HELP = {
    "axial_commissure": "axial plane through the {side} oral commissure (landmark 1 lies in it)",
    "sagittal_pupil": "sagittal plane through the medial aspect of the {side} pupil (landmark 2)",
    "coronal_landmark3": "coronal plane through ideal landmark 3 ({side}), 30 mm anterior to the meatus",
    "axial_tragus": "axial plane through the {side} tragus (landmark 3 lies in it; d3 of thesis 6.1.5)",
}


def _vec(v) -> str:
    return "[" + ", ".join(f"{float(x):.3f}" for x in v) + "]"


def write_toml(path: Path, foramina, anat, info) -> None:
    lines = [
        "# prp anatomy: generated by `python -m chainsim.game.packbuild.needle.prepare_prp`; do not edit by hand.",
        "# Head frame: millimetres, +X = subject's right, +Y = anterior (the face), +Z = up",
        "# (right-handed, as RAS in neuroimaging); origin = midpoint of the two foramen-ovale centres.",
        "# It is the BodyParts3D frame turned 180 degrees about +Z (see docs/anatomy.md).",
        "# Foramen width_mm / breadth: long and short axis of the measured opening, seen along its",
        "# axis; height_mm: the target plug's height along the axis (thesis 3.3.3);",
        "# radius_mm = width_mm / 2 is the R of thesis 6.1.5.",
        "",
    ]
    for name, p in anat["points"].items():
        base, side = name.rsplit("_", 1)
        lines += [f"[points.{name}]", f"position = {_vec(p)}", f'help = "{HELP[base].format(side=side)}"', ""]
    for side in ("left", "right"):
        f = foramina[side]
        lines += [
            f"[foramina.{side}]",
            f"centre = {_vec(f.centre)}",
            f"axis = {_vec(f.axis)}",
            f"width_mm = {f.width_mm:.2f}",
            f"height_mm = {PLUG_HEIGHT_MM:.2f}",
            f"radius_mm = {0.5 * f.width_mm:.2f}",
            f"# measured opening: {f.width_mm:.2f} x {f.height_mm:.2f} mm (area {f.area_mm2:.1f} mm2)",
            "",
        ]
    for name, (p, n) in anat["planes"].items():
        base, side = name.rsplit("_", 1)
        lines += [
            f"[planes.{name}]",
            f"point = {_vec(p)}",
            f"normal = {_vec(n)}",
            f'help = "{PLANE_HELP[base].format(side=side)}"',
            "",
        ]
    for side, pth in anat["paths"].items():
        lines += [
            f"[paths.{side}]",
            f"entry = {_vec(pth['entry'])}",
            f"target = {_vec(pth['target'])}",
            f"clear = {'true' if pth['clear'] else 'false'}",
            "",
        ]
    path.write_text("\n".join(lines))


def preview(path: Path, skull, mandible, skin, plugs, anat, face) -> None:
    layers = [(skull, (0.92, 0.88, 0.78, 1.0)), (mandible, (0.85, 0.82, 0.72, 1.0))]
    layers += [(p, (0.1, 0.8, 0.2, 1.0)) for p in plugs.values()]
    for name, p in anat["points"].items():
        if not name.startswith("foramen"):
            layers.append((marker(p, 2.0), (0.9, 0.1, 0.1, 1.0) if "ideal" in name else (0.1, 0.3, 0.9, 1.0)))
    for pth in anat["paths"].values():
        seg = trimesh.creation.cylinder(radius=0.6, segment=[pth["entry"], pth["target"]])
        layers.append((seg, (0.2, 0.2, 0.2, 1.0)))
    layers.append((skin, (0.95, 0.72, 0.62, 0.28)))
    views = [
        ("front", np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
        ("left", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
        ("below", np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
    ]
    centre = np.array([0.0, 20.0, 5.0])
    imgs = [render(layers, d, u, centre, 115.0, size=(400, 400)) for _, d, u in views]
    # the face as the trainee sees it: opaque skin with the painted eyes and lips
    colours = {
        "eyes": (0.93, 0.92, 0.88, 1.0),
        "irises": (0.33, 0.42, 0.50, 1.0),
        "pupils": (0.05, 0.05, 0.06, 1.0),
        "lips": (0.72, 0.42, 0.42, 1.0),
        "lip_line": (0.30, 0.10, 0.10, 1.0),
    }
    painted = [(skin, (0.87, 0.70, 0.60, 1.0))] + [(m, colours[k]) for k, m in face.items()]
    imgs.append(render(painted, views[0][1], views[0][2], np.array([0.0, 60.0, -10.0]), 80.0, size=(400, 400)))
    Image.fromarray(np.hstack(imgs)).save(path, optimize=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m chainsim.game.packbuild.needle.prepare_prp", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--shared", type=Path, default=DEFAULT_SHARED, help="the shared anatomy folder")
    ap.add_argument("--out", type=Path, default=ASSETS_DIR / "prp", help="the prp pack folder")
    ap.add_argument("--report", type=Path, default=None, help="also write the fit/measurement report (JSON)")
    d = BuildParams()
    ap.add_argument("--jaw-open-mm", type=float, default=d.jaw_open_mm, help="incisal opening of the posed jaw")
    ap.add_argument(
        "--mandible-setback-mm", type=float, default=d.mandible_setback_mm, help="move the closed mandible back"
    )
    ap.add_argument("--mouth-width-mm", type=float, default=d.mouth_width_mm, help="commissure to commissure")
    ap.add_argument(
        "--commissure-above-incisal-mm",
        type=float,
        default=d.commissure_above_incisal_mm,
        help="height of the mouth line above the upper incisal edge",
    )
    args = ap.parse_args(argv)
    if not args.shared.is_dir():
        fail(f"shared anatomy folder not found: {args.shared} (pass --shared PATH)")
    for name in ("jaw_open_mm", "mandible_setback_mm", "mouth_width_mm"):
        if not 0.0 <= getattr(args, name) <= 80.0:
            fail(f"--{name.replace('_', '-')} must be between 0 and 80 mm, got {getattr(args, name)}")
    params = BuildParams(
        args.jaw_open_mm, args.mandible_setback_mm, args.mouth_width_mm, args.commissure_above_incisal_mm
    )
    info = build(args.shared, args.out, params)
    if args.report:
        args.report.write_text(json.dumps(info, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
