"""The needle and the tissue at the extremes: a whole insertion in one frame, re-entry through the same hole
and through a new one, bone behind the tissue, a needle that misses the tissue or grazes the skin, the
stiffest and softest published materials at nu up to 0.499, and bad tissue data refused in one line."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import esper
import meshio
import numpy as np
import pytest
from needle_insertion import ASSETS, insertion_script

from chainsim.components.resources import PendingInput
from chainsim.game.trainer.headless import build_app, validate_pack
from chainsim.game.trainer.inputscript import parse_events, read_file
from chainsim.systems.procedures.needle.components import NeedleState
from chainsim.systems.procedures.needle.tissue import NeedleTissue, NeedleTissueScene, NeedleTrace
from chainsim.systems.tissue.deformable import Deformable

PRP = ASSETS / "prp"


def pack_copy(tmp_path: Path, edit=None) -> Path:
    """A copy of prp whose pack.toml `edit(text)` changes."""
    root = tmp_path / "prp"
    shutil.copytree(PRP, root)
    if edit is not None:
        toml = root / "pack.toml"
        toml.write_text(edit(toml.read_text()))
    return root


def run_app(root: Path, script: str, seconds: float, tmp_path: Path):
    """Build the App for `root`, play `script`, step `seconds` checking the tissue every few frames (finite,
    nothing inverted away from the needle); returns the App (the caller closes it)."""
    sp = tmp_path / "script.toml"
    sp.write_text(script)
    app = build_app(str(root), save="test")
    app.resource(PendingInput).extend(parse_events(read_file(sp), str(sp)))
    for i in range(int(seconds / app.time.dt)):
        app.update(app.time.dt)
        if i % 4 == 0:
            tissue_checks(app)
    return app


def trace_events(app) -> list[str]:
    return [e for row in app.resource(NeedleTrace).rows for e in row[5].split(";") if e]


def signed_volumes(pos: np.ndarray, tets: np.ndarray) -> np.ndarray:
    a, b, c, d = (pos[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def tissue_checks(app, pressed_ok: bool = True) -> None:
    """Every tissue position finite; no tetrahedron turned inside out unless it holds a node the needle holds
    or pressed (the nodes grabbed at any time are what the needle pressed)."""
    scene: NeedleTissueScene = app.resource(NeedleTissueScene)
    with app.active():
        for body in scene.bodies:
            d = esper.component_for_entity(body.entity, Deformable)
            assert np.all(np.isfinite(d.body.positions))
            vol = signed_volumes(d.body.positions, d.body.mesh.tets)
            bad = vol <= 0
            if pressed_ok:
                held = np.zeros(len(d.body.positions), bool)
                held[d.body.held] = True
                bad &= ~held[d.body.mesh.tets].any(axis=1)
            assert not bad.any(), f"{body.name}: {int(bad.sum())} tetrahedra inverted away from the needle"


def needle_tissue(app) -> NeedleTissue:
    with app.active():
        ((ent, nt),) = esper.get_component(NeedleTissue)
        return nt


def test_full_depth_in_one_frame_punctures_every_layer_in_order(tmp_path):
    root = pack_copy(tmp_path, lambda s: s.replace("insert_speed = 100.0", "insert_speed = 0.0"))
    app = run_app(root, insertion_script("prp", "left", 60.0), 4.0, tmp_path)
    try:
        rows = [r for r in app.resource(NeedleTrace).rows if r[5]]
        first = [r for r in rows if "puncture:" in r[5]]
        assert len(first) == 1  # all in one frame
        assert first[0][5] == "contact;puncture:skin;puncture:subcutaneous;puncture:muscle;puncture:deep"
        tissue_checks(app)
        assert np.isfinite(needle_tissue(app).axial)
    finally:
        app.close()


def test_reentry_through_the_same_hole_makes_no_new_puncture(tmp_path):
    script = insertion_script("prp", "left", 20.0, [(4.5, 0.0), (6.0, 20.0)])
    app = run_app(PRP, script, 7.5, tmp_path)
    try:
        ev = trace_events(app)
        assert ev.count("puncture:skin") == 1
        assert "exit:skin" in ev  # it left
        nt = needle_tissue(app)
        assert nt.reentries >= 1 and nt.repunctures == 0
        assert nt.tip_layer  # and it is back in the tissue
        tissue_checks(app)
    finally:
        app.close()


def test_a_new_entry_point_is_a_new_hole(tmp_path):
    script = insertion_script("prp", "left", 20.0, [(4.5, 0.0)])
    app = run_app(PRP, script, 5.5, tmp_path)
    try:
        with app.active():
            ((_, st),) = esper.get_component(NeedleState)
            nt = needle_tissue(app)
            # the same direction from a skin point 6 mm along the skin: another hole
            scene = app.resource(NeedleTissueScene)
            top = scene.bodies[0].rest_world
            d = st.direction()
            side = np.cross(d, [0, 0, 1.0])
            side /= np.linalg.norm(side)
            near = top[np.argmin(np.linalg.norm(top - (st.entry + 6.0 * side), axis=1))]
            st.entry = near.copy()
        for _ in range(10):
            app.update(app.time.dt)
        from chainsim.components.input_events import Widget

        app.resource(PendingInput).push(app.time.sim_time, Widget("insert", 20.0))
        for _ in range(120):
            app.update(app.time.dt)
        assert trace_events(app).count("puncture:skin") == 2
        assert nt.repunctures == 1 and nt.punctures["skin"] == 2
        tissue_checks(app)
    finally:
        app.close()


def test_bone_behind_the_tissue_still_stops_the_needle(tmp_path):
    script = (PRP / "scripts" / "skull-hit.toml").read_text()
    app = run_app(PRP, script, 8.0, tmp_path)
    try:
        ev = trace_events(app)
        assert "bone" in ev and "puncture:skin" in ev
        assert ev.index("puncture:skin") < ev.index("bone")
        tissue_checks(app)
    finally:
        app.close()


def test_a_needle_that_misses_the_tissue_feels_nothing(tmp_path):
    # entry on the forehead, far from both cheeks' tissue
    script = insertion_script("prp", "left", 30.0).replace("[-46.431, 52.596, -38.154]", "[0.0, 90.0, 60.0]")
    import tomllib

    data = tomllib.loads(script)
    data["event"][0]["point"] = [-20.0, 80.0, 60.0]
    app = build_app(str(PRP), save="test")
    try:
        from chainsim.game.trainer.inputscript import parse_events as pe

        app.resource(PendingInput).extend(pe(data, "script"))
        for _ in range(int(5.0 / app.time.dt)):
            app.update(app.time.dt)
        rows = app.resource(NeedleTrace).rows
        assert not trace_events(app) or set(trace_events(app)) <= {"bone"}
        assert all(r[2] == 0.0 and r[3] == 0.0 and r[4] == "" for r in rows)
        tissue_checks(app)
    finally:
        app.close()


def test_grazing_the_skin_stays_finite(tmp_path):
    script = insertion_script("prp", "left", 25.0)
    # turn the needle 75 degrees off the path, towards the skin's plane
    script = re.sub(
        r'(name = "rotate_horizontal"\nvalue = )([-0-9.e]+)',
        lambda m: m.group(1) + str(float(m.group(2)) - 75.0),
        script,
    )
    app = run_app(PRP, script, 5.0, tmp_path)
    try:
        nt = needle_tissue(app)
        assert np.isfinite(nt.axial) and np.isfinite(nt.lateral)
        tissue_checks(app)
    finally:
        app.close()


MATERIALS = {
    # epidermis in vitro (Geerligs et al. 2011, 1-2 MPa), and the softest fat (porcine, mu 0.53 kPa: E ~ 1.6 kPa)
    "stiffest": (2000.0, 0.45),
    "softest": (1.6, 0.45),
    "incompressible": (40.0, 0.499),
}


@pytest.mark.parametrize("case", sorted(MATERIALS))
def test_extreme_materials_stay_finite_and_whole(tmp_path, case):
    E, nu = MATERIALS[case]

    def edit(s: str) -> str:
        s = re.sub(r"^E_kPa = [0-9.]+$", f"E_kPa = {E}", s, flags=re.M)
        s = re.sub(r"^nu = 0\.45$", f"nu = {nu}", s, flags=re.M)
        return re.sub(r"^E = 16200\.0$", f"E = {E * 1000.0}", s, flags=re.M)

    app = run_app(pack_copy(tmp_path, edit), insertion_script("prp", "left", 30.0), 4.5, tmp_path)
    try:
        nt = needle_tissue(app)
        assert np.isfinite(nt.axial) and nt.peak_axial > 0
        ev = trace_events(app)
        assert ev[0] == "contact"
        if case == "stiffest":  # a stiff layer gives after a fraction of a millimetre
            assert "puncture:skin" in ev
        tissue_checks(app)
    finally:
        app.close()


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda s: s.replace("puncture_N = 1.22", "puncture_N = -1.0"), "tissue_layers.skin.puncture_N"),
        (lambda s: re.sub(r"\[tissue_layers\.deep\]\nmesh_layer = 4", "[tissue_layers.deep]\nmesh_layer = 9", s),
         "tissue_layers"),
        (lambda s: s + '\n[tissue_layers.fascia]\nmesh_layer = 7\nE_kPa = 30.0\npuncture_N = 1.0\n',
         "tissue_layers.fascia.mesh_layer"),
        (lambda s: s.replace('bodies = ["tissue_{side}"]', 'bodies = ["skin"]'), "needle_tissue.bodies"),
    ],
    ids=["negative-threshold", "missing-layer", "layer-not-in-mesh", "rigid-body"],
)  # fmt: skip
def test_bad_tissue_data_fails_validate_naming_the_key(tmp_path, edit, key):
    root = pack_copy(tmp_path, edit)
    _, problems = validate_pack(root)
    assert problems, "the bad data was accepted"
    text = " ".join(str(p) for p in problems)
    assert key in text, text
    assert "Traceback" not in text


def test_turning_the_needle_inside_the_tissue_moves_the_tissue(tmp_path):
    # a pack that lets the needle turn while it is in (lock_on_insert = false)
    root = pack_copy(
        tmp_path, lambda s: s.replace("contact_epsilon = 0.2\n", "contact_epsilon = 0.2\nlock_on_insert = false\n", 1)
    )
    script = insertion_script("prp", "left", 20.0)
    turned = re.search(r'name = "rotate_horizontal"\nvalue = ([-0-9.e]+)', script)
    yaw = float(turned.group(1))
    script += f'\n[[event]]\nt = 4.0\nkind = "widget"\nname = "rotate_horizontal"\nvalue = {yaw + 6.0}\n'
    app = run_app(root, script, 3.9, tmp_path)
    try:
        scene = app.resource(NeedleTissueScene)
        with app.active():
            d = esper.component_for_entity(scene.bodies[0].entity, Deformable)
            held = d.body.held.copy()
            before = d.body.positions[held].copy()
        assert len(held) and needle_tissue(app).lateral < 1e-6
        for _ in range(60):
            app.update(app.time.dt)
        nt = needle_tissue(app)
        with app.active():
            moved = np.linalg.norm(d.body.positions[held] - before, axis=1)
        assert nt.lateral > 0.01  # the tissue pushes back on the turned shaft
        assert moved.max() > 0.5  # and the tissue held on the shaft went with it
        tissue_checks(app)
    finally:
        app.close()


@pytest.mark.parametrize(
    "offset", [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.7, 0.3)], ids=["node", "edge", "diagonal", "face"]
)
def test_a_tip_on_a_node_an_edge_or_a_face_punctures_each_layer_once(tmp_path, offset):
    """From a node of the volume's skin face the needle runs down a line of nodes (the grid's columns are
    parallel to the path); moved half the prp grid's 2 mm off it, along an edge line, a diagonal, or
    inside faces."""
    app = run_app(PRP, insertion_script("prp", "left", 0.0), 2.8, tmp_path)
    try:
        scene = app.resource(NeedleTissueScene)
        with app.active():
            ((_, st),) = esper.get_component(NeedleState)
            d = st.direction()
            u = np.cross(d, [0.0, 0.0, 1.0])
            u /= np.linalg.norm(u)
            v = np.cross(d, u)
            top = scene.bodies[0].rest_world
            node = top[np.argmin(np.linalg.norm(top - st.entry, axis=1))]
            # the new entry, exactly the node nearest the path's, moved by the offset across the needle
            st.entry = node + offset[0] * u + offset[1] * v
        from chainsim.components.input_events import Widget

        # after the script's own last event (its insert to depth 0 at 3 s), which it would otherwise undo
        app.resource(PendingInput).push(3.0, Widget("insert", 25.0))
        for i in range(150):
            app.update(app.time.dt)
            if i % 4 == 0:
                tissue_checks(app)
        ev = [e for e in trace_events(app) if e.startswith("puncture:")]
        assert ev == ["puncture:skin", "puncture:subcutaneous", "puncture:muscle", "puncture:deep"]
    finally:
        app.close()


def test_the_gauge_shows_once_the_needle_is_placed_and_reads_the_needle_force(tmp_path):
    from chainsim.components.hud import HudState

    app = run_app(PRP, insertion_script("prp", "left", 5.5), 0.3, tmp_path)
    try:
        hud = app.resource(HudState)
        assert hud.force_gauge == ()  # no needle on the face yet: nothing to read
        for _ in range(int(3.2 / app.time.dt)):
            app.update(app.time.dt)
        axial, lateral, full, caption, pop = hud.force_gauge
        nt = needle_tissue(app)
        assert axial == nt.axial and full > axial > 0 and caption
        assert "skin" in pop or "pressing" in caption  # it gave at about 5 mm, or is about to
    finally:
        app.close()


def test_a_tissue_mesh_with_a_layer_below_one_fails_validate_in_one_line(tmp_path):
    root = pack_copy(tmp_path)
    path = root / "meshes" / "tissue_left.vtu"
    mesh = meshio.read(path)
    layers = [np.asarray(b).copy() for b in mesh.cell_data["layer"]]
    layers[0][0] = 0  # a tetrahedron in no layer
    mesh.cell_data["layer"] = layers
    meshio.write(path, mesh)
    _, problems = validate_pack(root)
    text = " ".join(str(p) for p in problems)
    assert "tissue_left" in text and "'layer' must be 1 or more" in text, text
    assert "Traceback" not in text
