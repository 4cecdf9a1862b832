"""Needle behaviour in the rhizotomy procedure (thesis 3.3.4-3.3.6) on a small synthetic head.

The synthetic pack is the real assets/prp/pack.toml with generated anatomy: a spherical skin, a skull
plate with two oval-ish holes plugged by the foramina, mandible rami, and named points. It keeps these
tests independent of the shipped anatomy meshes.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.components.input_events import PickPoint, Widget
from chainsim.game.trainer.headless import build_app
from chainsim.systems.procedures.needle.components import NeedleState
from chainsim.systems.procedures.needle.manifest import ProcedureState
from chainsim.tools.bench.replay import without_tissue  # the cut the replay bench makes too

ROOT = Path(__file__).resolve().parents[2]
PACK = ROOT / "assets" / "prp"
SKIN_R = 90.0
HOLE = (3.5, 2.0)  # half sizes of the foramen holes in x and y
PLATE_Z = (-2.0, 2.0)
FORAMEN = {"left": np.array([25.0, 0.0, 0.0]), "right": np.array([-25.0, 0.0, 0.0])}
RADIUS = 3.0


def _boxes(specs):
    import trimesh

    ms = []
    for lo, hi in specs:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b = trimesh.creation.box(extents=hi - lo)
        b.apply_translation((lo + hi) / 2)
        ms.append(b)
    return trimesh.util.concatenate(ms)


def make_synthetic_pack(root: Path) -> Path:
    """Write the prp pack with synthetic anatomy under `root`; returns the pack folder."""
    import trimesh

    root = Path(root)
    (root / "meshes").mkdir(parents=True, exist_ok=True)
    # the display copies, the enclosure claims and the ideal path belong to the real anatomy, not to this one
    manifest = (PACK / "pack.toml").read_text(encoding="utf-8").splitlines()
    keep = [ln for ln in manifest if not ln.startswith(("display = ", "inside = ", "ideal_path = "))]
    (root / "pack.toml").write_text(without_tissue("\n".join(keep) + "\n"), encoding="utf-8")
    shutil.copytree(PACK / "docs", root / "docs", dirs_exist_ok=True)
    (root / "scripts").mkdir(exist_ok=True)
    (root / "scripts" / "correct.toml").write_text("format = 1\n")
    (root / "ATTRIBUTION.md").write_text("synthetic test anatomy\n")
    hx, hy = HOLE
    z0, z1 = PLATE_Z
    plate = [
        ((-60, -50, z0), (-25 - hx, 40, z1)),
        ((-25 + hx, -50, z0), (25 - hx, 40, z1)),
        ((25 + hx, -50, z0), (60, 40, z1)),
    ]
    for cx in (-25, 25):
        plate += [((cx - hx, -50, z0), (cx + hx, -hy, z1)), ((cx - hx, hy, z0), (cx + hx, 40, z1))]
    _boxes(plate).export(root / "meshes" / "skull.ply")
    _boxes([((52, -10, -80), (56, 30, -15)), ((-56, -10, -80), (-52, 30, -15))]).export(
        root / "meshes" / "mandible.ply"
    )
    for side, c in FORAMEN.items():
        _boxes([((c[0] - hx, -hy, z0), (c[0] + hx, hy, z1))]).export(root / "meshes" / f"foramen_ovale_{side}.ply")
    skin = trimesh.creation.icosphere(subdivisions=4, radius=SKIN_R)
    skin.export(root / "meshes" / "skin.ply")
    # the painted eyes and lips: small flat patches just in front of the sphere (drawn, never picked)
    for k, name in enumerate(("eyes", "irises", "pupils", "lips", "lip_line")):
        _boxes([((-10 + 4 * k, SKIN_R + 0.2, -1), (-8 + 4 * k, SKIN_R + 0.3, 1))]).export(
            root / "meshes" / f"{name}.ply"
        )
    lines = []
    for side, sx in (("left", 1.0), ("right", -1.0)):
        lines += [
            f"[points.oral_commissure_{side}]\nposition = [{25 * sx}, 80.0, -40.0]",
            f"[points.pupil_medial_{side}]\nposition = [{30 * sx}, 80.0, 30.0]",
            f"[points.tragus_{side}]\nposition = [{85 * sx}, -10.0, 0.0]",
            f"[planes.axial_mouth_{side}]\npoint = [{25 * sx}, 80.0, -40.0]\nnormal = [0.0, 0.0, 1.0]",
            f"[planes.sagittal_pupil_{side}]\npoint = [{30 * sx}, 80.0, 30.0]\nnormal = [1.0, 0.0, 0.0]",
            f"[planes.axial_ear_{side}]\npoint = [{85 * sx}, -10.0, 0.0]\nnormal = [0.0, 0.0, 1.0]",
            f"[foramina.{side}]\ncentre = [{FORAMEN[side][0]}, 0.0, 0.0]\naxis = [0.0, 0.0, 1.0]\n"
            f"width_mm = 7.0\nheight_mm = 4.0\nradius_mm = {RADIUS}",
        ]
    (root / "anatomy.toml").write_text("\n\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="module")
def pack_dir(tmp_path_factory):
    return make_synthetic_pack(tmp_path_factory.mktemp("prp_synth"))


def on_skin(p) -> np.ndarray:
    p = np.asarray(p, float)
    return p / np.linalg.norm(p) * SKIN_R


class Run:
    """An App on the synthetic pack, with helpers to send events and read the needle."""

    def __init__(self, pack_dir, settings=None):
        self.app = build_app(str(pack_dir), settings=settings)
        self.app.events.log = []
        self.t = 0.0

    def send(self, *events, steps: int = 2):
        from chainsim.components.resources import PendingInput

        pend = self.app.resource(PendingInput)
        for ev in events:
            pend.push(self.app.time.sim_time, ev)
        self.app.run_steps(steps)

    @property
    def needle(self) -> NeedleState:
        from chainsim.systems.procedures.needle.handles import NeedleHandles as PrpHandles

        with self.app.active():
            return esper.component_for_entity(self.app.resource(PrpHandles).needle, NeedleState)

    @property
    def proc(self) -> ProcedureState:
        from chainsim.systems.procedures.needle.handles import NeedleHandles as PrpHandles

        with self.app.active():
            return esper.component_for_entity(self.app.resource(PrpHandles).procedure, ProcedureState)

    def emitted(self, kind):
        return [e for e in self.app.events.log if isinstance(e, kind)]

    def aim_at(self, point):
        """Dial angles that aim the placed needle at `point`, sent as widget events."""
        from chainsim.game.packbuild.needle.make_prp_scripts import dial_angles

        yaw, pitch = dial_angles(self.needle.entry, np.asarray(point, float) - self.needle.entry)
        self.send(Widget("rotate_horizontal", yaw), Widget("rotate_vertical", pitch))
        return yaw, pitch

    def close(self):
        self.app.close()


@pytest.fixture
def run(pack_dir):
    r = Run(pack_dir)
    yield r
    r.close()


L1 = on_skin([50.0, 60.0, -40.0])


def test_landmark1_places_needle_level_and_toward_midline(run):
    run.send(PickPoint("skin", tuple(L1)))
    st = run.needle
    assert st.placed
    assert np.allclose(st.tip(), L1, atol=0.5)
    d = st.direction()
    assert abs(d[2]) < 1e-12  # in the axial plane
    toward_axis = -st.entry[:2] / np.linalg.norm(st.entry[:2])
    assert np.allclose(d[:2], toward_axis, atol=1e-12)
    assert run.proc.side == "left"
    # the tip transform is the needle entity's: origin at the tip, local +Z along insertion
    from chainsim.components.core import Transform
    from chainsim.systems.engine import quaternion as Q
    from chainsim.systems.procedures.needle.handles import NeedleHandles as PrpHandles

    with run.app.active():
        tr = esper.component_for_entity(run.app.resource(PrpHandles).needle, Transform)
    assert np.allclose(tr.position, st.tip())
    assert np.allclose(Q.rotate(tr.rotation, [0, 0, 1]), d)


def test_dials_are_absolute_and_compose_horizontal_then_vertical(run):
    run.send(PickPoint("skin", tuple(L1)))
    d0 = run.needle.direction()
    az0 = math.atan2(d0[1], d0[0])
    run.send(Widget("rotate_horizontal", 30.0))
    run.send(Widget("rotate_horizontal", 10.0))  # absolute: ends 10 degrees from the start
    run.send(Widget("rotate_vertical", 25.0))
    run.send(Widget("rotate_horizontal", -5.0))  # turning keeps the tilt
    d = run.needle.direction()
    assert math.degrees(math.asin(d[2])) == pytest.approx(25.0, abs=1e-9)
    assert math.degrees(math.atan2(d[1], d[0]) - az0) == pytest.approx(-5.0, abs=1e-9)
    assert abs(np.linalg.norm(run.needle.q) - 1.0) < 1e-14


def test_rotation_refused_once_inserted_until_reset(run):
    from chainsim.systems.procedures.needle.kinematics import RotationRefused
    from chainsim.systems.view.ui.widgets import WidgetState

    run.send(PickPoint("skin", tuple(L1)))
    run.send(Widget("rotate_horizontal", 12.0))
    run.send(Widget("insert", 5.0))
    before = run.needle.q.copy()
    run.send(Widget("rotate_horizontal", 40.0), Widget("rotate_vertical", 10.0))
    assert np.array_equal(run.needle.q, before)
    refused = run.emitted(RotationRefused)
    assert [r.reason for r in refused] == ["locked", "locked"]
    assert run.needle.rotation_refused == 2
    ws = run.app.resource(WidgetState)
    assert {"rotate_horizontal", "rotate_vertical"} <= ws.disabled
    msgs = [
        m for m, _ in run.app.resource(__import__("chainsim.components.hud", fromlist=["HudState"]).HudState).messages
    ]
    assert any("locked" in m for m in msgs)
    run.send(Widget("reset"), steps=3)
    st = run.needle
    assert not st.locked and st.depth == 0.0 and np.allclose(st.tip(), st.entry)
    assert not ({"rotate_horizontal", "rotate_vertical"} & ws.disabled)
    run.send(Widget("rotate_horizontal", 3.0))
    assert run.needle.yaw == pytest.approx(3.0)


def test_picks_off_the_skin_are_ignored_with_a_message(run):
    from chainsim.components.hud import HudState

    run.send(PickPoint("skull", (30.0, 10.0, 2.0)))
    assert run.proc.placed == 0 and not run.needle.placed
    assert any("skin" in m for m, _ in run.app.resource(HudState).messages)


def _marker(run, k):
    from chainsim.components.core import Label, Marker, Transform
    from chainsim.components.resources import EntityIndex

    ent = run.app.resource(EntityIndex)[f"landmark{k}"]
    with run.app.active():
        return (
            esper.component_for_entity(ent, Marker),
            esper.component_for_entity(ent, Label),
            esper.component_for_entity(ent, Transform),
        )


def test_landmarks_in_order_and_reset_all_clears_them(run):
    pts = [L1, on_skin([30, 80, 30]), on_skin([80, 20, 0])]
    mk, lb, _ = _marker(run, 2)
    assert not mk.visible and lb.text == ""  # nothing drawn before it is placed
    for p in pts:
        run.send(PickPoint("skin", tuple(p)))
    mk, lb, tr = _marker(run, 2)
    assert mk.visible and lb.text == "2" and np.allclose(tr.position, pts[1], atol=0.5)
    ps = run.proc
    assert ps.placed == 3 and ps.step_id == "orient_horizontal"
    assert np.allclose(ps.landmarks, pts, atol=0.5)
    run.send(PickPoint("skin", tuple(pts[0])))  # a fourth click changes nothing
    assert run.proc.placed == 3
    run.send(Widget("reset", "all"))
    assert run.proc.placed == 0 and not run.needle.placed
    assert not _marker(run, 1)[0].visible and _marker(run, 1)[1].text == ""
    assert run.proc.step_id == "landmark1"


def test_right_side_entry_is_detected_from_landmark1(run):
    run.send(PickPoint("skin", tuple(on_skin([-50.0, 60.0, -40.0]))))
    assert run.proc.side == "right"


def test_foramen_entry_is_green_and_scored_dist_minus_r(run):
    from chainsim.components.hud import HudState
    from chainsim.systems.procedures.needle.collision import NeedleHit

    run.send(PickPoint("skin", tuple(L1)))
    run.aim_at(FORAMEN["left"] + [0.0, 0.0, PLATE_Z[0]])
    run.send(Widget("insert", 300.0))
    hits = run.emitted(NeedleHit)
    assert [h.object for h in hits] == ["foramen_ovale_left"]
    st = run.needle
    assert st.done and run.proc.target == "foramen_ovale_left"
    tip = st.tip()
    assert tip[2] < PLATE_Z[0]  # stopped at the plug's lower face
    dist = float(np.linalg.norm(np.asarray(hits[0].point) - FORAMEN["left"]))
    a = run.app.resource(__import__("chainsim.game.trainer.headless", fromlist=["Assessment"]).Assessment).values
    assert a["needle_error_mm"] == pytest.approx(dist - RADIUS)
    assert run.app.resource(HudState).lights["target"] == "green"
    run.send(Widget("insert", 320.0))  # no further once in the foramen
    assert run.needle.depth == pytest.approx(st.depth)


def test_huge_insertion_step_stops_at_bone_and_bounces_back(run):
    from chainsim.components.hud import HudState
    from chainsim.systems.procedures.needle.collision import NeedleHit
    from chainsim.systems.procedures.needle.components import Needle
    from chainsim.systems.procedures.needle.handles import NeedleHandles as PrpHandles

    with run.app.active():
        esper.component_for_entity(run.app.resource(PrpHandles).needle, Needle).max_depth = 1000.0
    run.send(PickPoint("skin", tuple(L1)))
    aim = np.array([0.0, 0.0, PLATE_Z[0]])  # plate between the holes
    run.aim_at(aim)
    run.send(Widget("insert", 200.0), steps=1)  # 200 mm in one step: far past the 4 mm plate
    assert run.needle.target_depth < 200.0  # the contact cut the jump short
    st = run.needle
    hits = run.emitted(NeedleHit)
    assert [h.object for h in hits] == ["skull"]
    assert st.tip()[2] < PLATE_Z[0]  # never inside or beyond the bone
    contact_depth = st.depth
    run.send(steps=60)
    st = run.needle
    assert st.depth == pytest.approx(contact_depth - 4.0)  # sprang back by `bounce`
    assert st.contacts == {"skull": 1}  # the pack's bone role
    assert run.app.resource(HudState).lights["skull"] == "red"
    expect = float(np.linalg.norm(np.asarray(hits[0].point) - FORAMEN["left"]))
    assert hits[0].distance_to_target_mm == pytest.approx(expect)
    assert run.proc.target == "skull"


def test_hidden_collision_signals_are_still_recorded(run):
    from chainsim.components.hud import HudState

    run.send(Widget("collision_signals", False))
    run.send(PickPoint("skin", tuple(L1)))
    run.aim_at([0.0, 0.0, PLATE_Z[0]])
    run.send(Widget("insert", 200.0))
    assert run.app.resource(HudState).lights["skull"] == "off"
    assert run.proc.lights["skull"] == "red"
    assert (
        run.app.resource(__import__("chainsim.game.trainer.headless", fromlist=["Assessment"]).Assessment).values[
            "skull_contacts"
        ]
        == 1
    )


def test_keys_rotate_and_insert_by_steps(run):
    from chainsim.components.input_events import Key

    run.send(PickPoint("skin", tuple(L1)))
    # the right arrow raises the horizontal dial, as its "+" on the right and a drag to the right do
    run.send(Key("right"), Key("right"), Key("up"))
    assert run.needle.yaw == pytest.approx(2.0) and run.needle.pitch == pytest.approx(1.0)
    run.send(Key("left"))
    assert run.needle.yaw == pytest.approx(1.0)
    run.send(Key("i"), Key("i"))
    assert run.needle.depth == pytest.approx(4.0) and run.needle.locked


def test_shift_gives_fine_steps(run):
    from chainsim.components.input_events import Key

    run.send(PickPoint("skin", tuple(L1)))
    run.send(Key("lshift", True), Key("right"), Key("right"), Key("down"), Key("i"))
    assert run.needle.yaw == pytest.approx(0.5) and run.needle.pitch == pytest.approx(-0.25)
    assert run.needle.target_depth == pytest.approx(0.5)
    run.send(Key("lshift", False), Key("i"))
    assert run.needle.target_depth == pytest.approx(2.5)


def test_full_withdrawal_unlocks_the_dials_where_they_are_and_counts_a_redirection(run):
    run.send(PickPoint("skin", tuple(L1)))
    run.send(Widget("rotate_horizontal", 7.0), Widget("rotate_vertical", 3.0), Widget("insert", 6.0))
    assert run.needle.locked
    run.send(Widget("rotate_horizontal", 9.0))
    assert run.needle.yaw == pytest.approx(7.0)  # locked while inserted
    run.send(Widget("insert", 0.0), steps=40)  # withdrawal runs at withdraw_speed
    st = run.needle
    assert st.depth == 0.0 and not st.locked
    assert st.yaw == pytest.approx(7.0) and st.pitch == pytest.approx(3.0)  # not zeroed
    run.send(Widget("rotate_horizontal", 9.0))
    assert st.yaw == pytest.approx(9.0) and st.redirections == 1
    run.send(Widget("rotate_vertical", 4.0))
    assert st.redirections == 1  # one redirection per withdrawal, however many turns


def test_needle_is_hidden_until_landmark_1_places_it(run):
    from chainsim.components.core import MeshRef

    with run.app.active():
        refs = [ref for _, ref in __import__("esper").get_component(MeshRef) if ref.layer == "needle"]
        assert refs and not any(r.visible for r in refs)
        run.send(PickPoint("skin", tuple(L1)))
        assert all(r.visible for r in refs)


def test_insert_before_landmark_is_refused(run):
    from chainsim.systems.procedures.needle.kinematics import InsertRefused

    run.send(Widget("insert", 10.0), Widget("rotate_horizontal", 5.0))
    assert not run.needle.placed and run.needle.depth == 0.0
    assert [e.reason for e in run.emitted(InsertRefused)] == ["not_placed"]
