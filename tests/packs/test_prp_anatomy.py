"""The shipped prp anatomy (assets/prp): units, foramina, landmarks, skin fit, clear needle paths.

These check the facts a trainee and the procedure code rely on (thesis 3.3.3-3.3.4, 6.1.5), on the
meshes and anatomy.toml exactly as shipped; nothing here reads the shared source meshes.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

PACK = Path(__file__).resolve().parents[2] / "assets" / "prp"
MESHES = ("skull", "mandible", "skin", "foramen_ovale_left", "foramen_ovale_right")
PAINTED = ("eyes", "irises", "pupils", "lips", "lip_line")
CANAL_MM = 4.0  # the last stretch of the path, inside the bony canal of the foramen
SIDES = ("left", "right")
SKIN_POINTS = ("oral_commissure", "pupil_medial", "tragus", "landmark1_ideal", "landmark2_ideal", "landmark3_ideal")


@pytest.fixture(scope="module")
def meshes() -> dict[str, trimesh.Trimesh]:
    return {n: trimesh.load(PACK / "meshes" / f"{n}.ply", force="mesh") for n in MESHES}


@pytest.fixture(scope="module")
def anatomy() -> dict:
    with open(PACK / "anatomy.toml", "rb") as f:
        return tomllib.load(f)


def first_hit(mesh: trimesh.Trimesh, origin, direction) -> float:
    d = np.array(direction, float)
    d = d / np.linalg.norm(d)
    loc, _, _ = mesh.ray.intersects_location([origin], [d], multiple_hits=True)
    if len(loc) == 0:
        return np.inf
    t = (loc - origin) @ d
    t = t[t > 1e-9]
    return float(t.min()) if len(t) else np.inf


def test_manifest_has_only_the_tables_the_pack_merges(anatomy):
    assert set(anatomy) == {"points", "foramina", "planes", "paths"}
    for side in SIDES:
        for base in (*SKIN_POINTS, "foramen_ovale"):
            p = anatomy["points"][f"{base}_{side}"]
            assert len(p["position"]) == 3 and p["help"]
        f = anatomy["foramina"][side]
        assert {"centre", "axis", "width_mm", "height_mm", "radius_mm"} <= set(f)
        for plane in ("axial_commissure", "sagittal_pupil", "coronal_landmark3", "axial_tragus"):
            pl = anatomy["planes"][f"{plane}_{side}"]
            assert np.isclose(np.linalg.norm(pl["normal"]), 1.0) and pl["help"]


def test_meshes_are_in_millimetres_in_the_head_frame(meshes):
    skull = meshes["skull"]
    width, length, height = skull.extents
    assert 120 < width < 160  # biparietal breadth of an adult skull
    assert 160 < length < 215  # glabella to opisthocranion
    lo, hi = skull.bounds
    # +Y is the face: the skull reaches much further forward (nasal bones) than the origin.
    assert hi[1] > 60 and lo[1] < -90
    # The origin lies between the foramina, at the skull base: vault above, teeth below.
    assert hi[2] > 100 and lo[2] < -30
    assert abs(lo[0] + hi[0]) < 10  # roughly symmetric about the midline x = 0


def test_surfaces_face_outward_in_the_head_frame(meshes):
    # A renderer or a ray test relying on normals needs them pointing out of the bone and the head.
    skin = meshes["skin"]
    assert skin.is_watertight and skin.volume > 0
    skull = meshes["skull"]
    top = np.argsort(skull.triangles_center[:, 2])[-50:]
    assert (skull.face_normals[top, 2] > 0).mean() > 0.9
    front = np.argsort(skull.triangles_center[:, 1])[-50:]
    assert (skull.face_normals[front, 1] > 0).mean() > 0.7


def test_foramina_have_the_measured_size_and_sit_either_side_of_the_midline(anatomy, meshes):
    for side, sgn in (("left", -1.0), ("right", 1.0)):  # RAS head frame: the left is -X
        f = anatomy["foramina"][side]
        c = np.array(f["centre"])
        assert 5.0 <= f["width_mm"] <= 8.0
        assert 2.0 <= f["height_mm"] <= 4.5
        assert f["radius_mm"] == pytest.approx(f["width_mm"] / 2, abs=0.01)
        assert 20.0 <= sgn * c[0] <= 35.0
        assert np.linalg.norm(f["axis"]) == pytest.approx(1.0, abs=1e-3)
        assert f["axis"][2] > 0.5  # opens upward, into the middle cranial fossa
        plug = meshes[f"foramen_ovale_{side}"]
        assert plug.is_watertight
        assert plug.contains([c])[0]
        assert np.allclose(plug.centroid, c, atol=0.2)
        # Plug dimensions: height along the axis, width across it.
        ax = np.array(f["axis"])
        along = (plug.vertices - c) @ ax
        assert np.ptp(along) == pytest.approx(f["height_mm"], abs=0.05)
        across = np.linalg.norm((plug.vertices - c) - np.outer(along, ax), axis=1)
        assert across.max() == pytest.approx(f["width_mm"] / 2, abs=0.05)
    assert anatomy["points"]["foramen_ovale_left"]["position"] == anatomy["foramina"]["left"]["centre"]
    mid = 0.5 * (np.array(anatomy["foramina"]["left"]["centre"]) + np.array(anatomy["foramina"]["right"]["centre"]))
    assert np.allclose(mid, 0.0, atol=1e-2)  # the frame's origin


def test_foramen_plug_sits_in_a_hole_of_the_skull(anatomy, meshes):
    skull = meshes["skull"]
    for side in SIDES:
        f = anatomy["foramina"][side]
        c, ax = np.array(f["centre"]), np.array(f["axis"])
        # Along the opening's axis there is no bone right at the centre, but bone all around.
        assert first_hit(skull, c - 20 * ax, ax) > 20 - 2.5
        helper = np.cross(ax, [1.0, 0.0, 0.0])
        helper /= np.linalg.norm(helper)
        ring = 0
        for ang in np.linspace(0, 2 * np.pi, 8, endpoint=False):
            d = np.cos(ang) * helper + np.sin(ang) * np.cross(ax, helper)
            ring += first_hit(skull, c, d) < 8.0
        assert ring >= 6


def test_landmarks_lie_on_the_skin(anatomy, meshes):
    skin = meshes["skin"]
    names = [f"{b}_{s}" for b in SKIN_POINTS for s in SIDES]
    pts = np.array([anatomy["points"][n]["position"] for n in names])
    _, dist, _ = trimesh.proximity.closest_point(skin, pts)
    bad = {n: round(float(d), 2) for n, d in zip(names, dist) if d > 1.0}
    assert not bad


def test_landmarks_follow_the_thesis_definitions(anatomy):
    P = {k: np.array(v["position"]) for k, v in anatomy["points"].items()}
    for side, sgn in (("left", -1.0), ("right", 1.0)):  # RAS head frame: the left is -X
        c, l1 = P[f"oral_commissure_{side}"], P[f"landmark1_ideal_{side}"]
        assert np.linalg.norm(l1 - c) == pytest.approx(25.0, abs=0.3)
        assert l1[2] == pytest.approx(c[2], abs=0.3) and sgn * l1[0] > sgn * c[0]
        t, l3 = P[f"tragus_{side}"], P[f"landmark3_ideal_{side}"]
        assert np.linalg.norm(l3 - t) == pytest.approx(30.0, abs=0.3)
        assert l3[2] == pytest.approx(t[2], abs=0.3) and l3[1] > t[1]
        assert np.allclose(P[f"landmark2_ideal_{side}"], P[f"pupil_medial_{side}"])
        # Face features in front, ears to the side, each on its own side of the midline.
        for name in ("oral_commissure", "pupil_medial", "landmark1_ideal"):
            assert sgn * P[f"{name}_{side}"][0] > 0 and P[f"{name}_{side}"][1] > 40
        assert 60 < sgn * t[0] < 90


def test_reference_planes_pass_through_their_landmarks(anatomy):
    P = {k: np.array(v["position"]) for k, v in anatomy["points"].items()}
    for side in SIDES:
        for plane, point in (
            ("axial_commissure", "oral_commissure"),
            ("sagittal_pupil", "pupil_medial"),
            ("coronal_landmark3", "landmark3_ideal"),
            ("axial_tragus", "tragus"),
        ):
            pl = anatomy["planes"][f"{plane}_{side}"]
            d = (P[f"{point}_{side}"] - np.array(pl["point"])) @ np.array(pl["normal"])
            assert abs(d) < 1e-6
        assert anatomy["planes"][f"sagittal_pupil_{side}"]["normal"] == [1.0, 0.0, 0.0]
        assert anatomy["planes"][f"coronal_landmark3_{side}"]["normal"] == [0.0, 1.0, 0.0]


def test_stored_correct_paths_reach_the_foramen_before_any_bone(anatomy, meshes):
    bone = trimesh.util.concatenate([meshes["skull"], meshes["mandible"]])
    P = {k: np.array(v["position"]) for k, v in anatomy["points"].items()}
    for side in SIDES:
        p = anatomy["paths"][side]
        entry, target = np.array(p["entry"]), np.array(p["target"])
        assert p["clear"] is True
        assert np.allclose(target, anatomy["foramina"][side]["centre"])
        d = target - entry
        t_plug = first_hit(meshes[f"foramen_ovale_{side}"], entry, d)
        t_bone = first_hit(bone, entry, d)
        assert t_plug < np.linalg.norm(d) and t_plug < t_bone
        # The entry is on the cheek near ideal landmark 1, not somewhere else on the face.
        assert np.linalg.norm(entry - P[f"landmark1_ideal_{side}"]) <= 15.0


def test_ideal_landmark_1_has_a_straight_path_to_the_foramen_on_both_sides(anatomy, meshes):
    """The textbook aim works on this head: from ideal landmark 1 (as the pack defines and scores it)
    the straight line to the foramen centre meets no bone before the bony canal, at a cadaver-like
    depth (thesis 3.3.4; 76.7 / 79.9 mm measured in female / male donors)."""
    bone = trimesh.util.concatenate([meshes["skull"], meshes["mandible"]])
    for side in SIDES:
        entry = np.array(anatomy["points"][f"landmark1_ideal_{side}"]["position"])
        target = np.array(anatomy["foramina"][side]["centre"])
        depth = float(np.linalg.norm(target - entry))
        assert 65.0 <= depth <= 90.0
        assert first_hit(bone, entry, target - entry) >= depth - CANAL_MM
        t_plug = first_hit(meshes[f"foramen_ovale_{side}"], entry, target - entry)
        assert t_plug < depth  # the needle meets the target plug on the way in
        # and the stored correct path is that very line
        assert np.allclose(anatomy["paths"][side]["entry"], entry, atol=1e-3)


def test_bones_are_closed_surfaces(meshes):
    """The radiograph integrates bone between where each ray enters and leaves it, which needs closed,
    consistently wound surfaces: every edge a -> b of a triangle is matched by an edge b -> a of
    another (where bones touch, an edge may be shared by four triangles; it is still closed)."""
    for name in ("skull", "mandible", "foramen_ovale_left", "foramen_ovale_right", "skin"):
        f = meshes[name].faces
        directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        forward = np.unique(directed, axis=0, return_counts=True)
        backward = np.unique(directed[:, ::-1], axis=0, return_counts=True)
        assert np.array_equal(forward[0], backward[0]) and np.array_equal(forward[1], backward[1]), name


@pytest.mark.slow
def test_eyes_and_lips_are_painted_where_the_landmarks_are(anatomy, meshes):
    painted = {n: trimesh.load(PACK / "meshes" / f"{n}.ply", force="mesh") for n in PAINTED}
    skin = meshes["skin"]
    P = {k: np.array(v["position"]) for k, v in anatomy["points"].items()}
    for name, m in painted.items():
        _, d, _ = trimesh.proximity.closest_point(skin, m.vertices)
        assert d.max() < 1.0, name  # a shell on the skin, not a floating object
        assert skin.contains(m.vertices).mean() < 0.01, name  # in front of it
    for side in SIDES:
        # the pupil's medial edge (landmark 2) lies on the rim of the painted pupil
        pupil = painted["pupils"].vertices
        near = pupil[np.linalg.norm(pupil - P[f"pupil_medial_{side}"], axis=1) < 4.0]
        centre = near.mean(0)
        assert np.linalg.norm(centre - P[f"pupil_medial_{side}"]) == pytest.approx(2.0, abs=0.6)
        # the lip line ends at the oral commissure (landmark 1 is measured from it)
        line = painted["lip_line"].vertices
        sgn = -1.0 if side == "left" else 1.0
        end = line[np.argmax(sgn * line[:, 0])]
        assert np.linalg.norm(end - P[f"oral_commissure_{side}"]) < 1.5


def test_mouth_and_jaw_fit_the_skull(anatomy, meshes):
    P = {k: np.array(v["position"]) for k, v in anatomy["points"].items()}
    width = np.linalg.norm(P["oral_commissure_left"] - P["oral_commissure_right"])
    assert 48.0 < width < 60.0  # adult mouth widths
    v = meshes["skull"].vertices
    upper_incisal = v[(np.abs(v[:, 0]) < 6.0) & (v[:, 1] > 55.0)][:, 2].min()
    for side in SIDES:
        assert 0.0 <= P[f"oral_commissure_{side}"][2] - upper_incisal <= 4.0
    w = meshes["mandible"].vertices
    lower_incisal = w[(np.abs(w[:, 0]) < 6.0) & (w[:, 1] > 50.0)][:, 2].max()
    assert 5.0 < upper_incisal - lower_incisal < 20.0  # a relaxed jaw, slightly open


@pytest.mark.slow
def test_skin_encloses_the_skull_with_plausible_facial_tissue(meshes):
    skin, skull = meshes["skin"], meshes["skull"]
    v = skull.vertices
    face = v[(v[:, 1] > 20) & (v[:, 2] > -40)]
    rng = np.random.default_rng(0)
    sample = face[rng.choice(len(face), size=min(3000, len(face)), replace=False)]
    assert skin.contains(sample).mean() > 0.999
    # Soft tissue over cheek bones and forehead: neither paper thin nor a balloon.
    s = skin.vertices
    front = s[(s[:, 1] > 40) & (s[:, 2] > -30) & (s[:, 2] < 70) & (np.abs(s[:, 0]) > 10)]
    _, d, _ = trimesh.proximity.closest_point(trimesh.util.concatenate([skull, meshes["mandible"]]), front)
    assert np.percentile(d, 5) > 2.0
    assert np.median(d) < 25.0


def test_pack_meshes_are_small(meshes):
    total = sum((PACK / "meshes" / f"{n}.ply").stat().st_size for n in MESHES)
    assert total < 5_000_000
    for n in MESHES:
        assert (PACK / "meshes" / f"{n}.ply").read_bytes()[:3] == b"ply"


def test_head_frame_is_right_handed_and_unmirrored():
    """Seen from the front (+Y), the subject's left must be on the viewer's right: with +Z up and a
    right-handed frame that puts the left side at -X. A mirrored frame would swap the foramina."""
    anat = tomllib.loads((PACK / "anatomy.toml").read_text())
    left = np.array(anat["foramina"]["left"]["centre"])
    right = np.array(anat["foramina"]["right"]["centre"])
    pupil_l = np.array(anat["points"]["pupil_medial_left"]["position"])
    assert left[0] < 0 < right[0] and pupil_l[0] < 0
