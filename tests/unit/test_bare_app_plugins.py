"""Each feature alone: a bare App (no pack loader, no other plugin) with exactly one feature plugin,
its entities made by hand, checked through its components and events.

A feature that works here needs nothing of the others: no EntityIndex or HudState it does not make
itself, and no system another plugin would have added. The tissue, motion and input features need no
pack at all; the view draws and picks the pack's meshes in the pack's layout, so its test hands it a
PackResource over a two-method stand-in for a pack (a mesh by name, a section by name).
"""

from __future__ import annotations

import esper
import numpy as np
import pytest

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Name, ScriptedMotion, Transform
from chainsim.components.input_events import Key, MouseButton, MouseMove
from chainsim.components.resources import InputState, PackResource, PendingInput
from chainsim.components.stages import STAGES
from chainsim.components.view_events import Picked
from chainsim.systems.engine.meshes import MeshData, primitive
from chainsim.systems.engine.meshgen import triangulated_grid
from chainsim.systems.motion import input as input_feature
from chainsim.systems.motion import scripted
from chainsim.systems.tissue import deformation
from chainsim.systems.tissue.deformable import Deformable, setup_deformable
from chainsim.systems.tissue.events import Deformed, GrabRequest, ReleaseRequest
from chainsim.systems.view import cameras

DT = 0.01


def _systems(app: App) -> dict[str, list[str]]:
    return {stage: app.systems(stage) for stage in STAGES if app.systems(stage)}


def _sheet(n: int = 6, size: float = 10.0) -> tuple[Deformable, np.ndarray]:
    """A deformable n x n sheet in the x-y plane, from the default material (no pack, no [materials])."""
    pos, tris, _links = triangulated_grid(n, n, size / (n - 1), dim=3)
    d = Deformable()
    setup_deformable(d, MeshData(np.asarray(pos, dtype=np.float64), np.asarray(tris, dtype=np.int64)), {})
    return d, d.body.positions.copy()


# -- tissue: the deformation plugin ----------------------------------------------------------------


def test_the_deformation_plugin_alone_serves_grab_and_release_on_a_hand_made_body():
    with App(dt=DT, name="tissue-alone") as app:
        d, rest = _sheet()
        with app.active():
            ent = esper.create_entity(d)  # no Transform: the body's local frame is the world
        app.add_plugin(deformation.plugin)
        assert _systems(app) == {"simulation": ["deformation"]}
        deformed = app.events.reader(Deformed)

        corner = 0
        target = rest[corner] + np.array([0.0, 0.0, 3.0])
        app.events.emit(GrabRequest(ent, [corner], [target]))
        app.run_steps(1)

        np.testing.assert_allclose(d.body.positions[corner], target, atol=1e-9)
        (ev,) = deformed.read()
        assert ev.entity == ent and ev.moved_count > 1  # the cascade carried neighbours along
        moved = np.linalg.norm(d.body.positions - rest, axis=1) > 1e-9
        assert moved.sum() == ev.moved_count
        assert corner in d.body.held

        app.events.emit(ReleaseRequest(ent))
        app.run_steps(1)
        assert len(d.body.held) == 0
        np.testing.assert_allclose(d.body.positions[corner], target, atol=1e-9)  # a release lets go, it does not undo


def test_the_deformation_plugin_adds_nothing_to_an_app_without_deformable_bodies():
    with App(dt=DT) as app:
        app.add_plugin(deformation.plugin)
        assert _systems(app) == {}
        assert not app.has_resource(deformation.DeformationState)


# -- motion: scripted motion -------------------------------------------------------------------------


def test_scripted_motion_alone_moves_an_entity_along_its_waypoints_in_simulated_time():
    with App(dt=DT, name="motion-alone") as app:
        with app.active():
            tr = Transform()
            mo = ScriptedMotion(waypoints=np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0]), speed=20.0, loop=False)
            esper.create_entity(tr, mo)
        app.add_plugin(scripted.plugin)
        assert _systems(app) == {"simulation": ["motion"]}

        app.run_steps(10)  # 0.1 s at 20 mm/s
        np.testing.assert_allclose(tr.position, [2.0, 0.0, 0.0], atol=1e-9)
        app.run_steps(100)  # well past the end of a path that does not loop: it stops at the last point
        np.testing.assert_allclose(tr.position, [10.0, 0.0, 0.0], atol=1e-9)


def test_scripted_motion_adds_nothing_to_an_app_without_moving_entities():
    with App(dt=DT) as app:
        app.add_plugin(scripted.plugin)
        assert _systems(app) == {}


# -- input ---------------------------------------------------------------------------------------------


def test_the_input_plugin_alone_releases_due_events_into_input_state_and_the_event_queue():
    with App(dt=DT, name="input-alone") as app:
        app.add_plugin(input_feature.plugin)
        assert _systems(app) == {"input": ["input"]}
        keys = app.events.reader(Key)
        everything = app.events.reader()
        pending = app.resource(PendingInput)
        pending.extend([(0.0, MouseMove(5.0, 6.0)), (0.0, Key("space")), (0.05, MouseButton(7.0, 8.0, "left"))])

        app.run_steps(1)  # simulated time 0: the two events due at t = 0 only
        state = app.resource(InputState)
        assert state.mouse == (5.0, 6.0) and state.keys == {"space"} and state.buttons == set()
        assert keys.read() == [Key("space")]
        assert everything.read() == [MouseMove(5.0, 6.0), Key("space")]

        app.run_steps(5)  # reaches t = 0.05
        assert state.mouse == (7.0, 8.0) and state.buttons == {"left"}
        assert everything.read() == [MouseButton(7.0, 8.0, "left")]
        assert keys.read() == []
        assert pending.exhausted
        log = app.resource(input_feature.InputLog)
        assert [ev for _t, ev in log.items] == [MouseMove(5.0, 6.0), Key("space"), MouseButton(7.0, 8.0, "left")]
        assert [t for t, _ev in log.items] == pytest.approx([0.0, 0.0, 0.05])


# -- view ------------------------------------------------------------------------------------------------


class _Pack:
    """What the view reads of a pack: its meshes by name and its sections (no layout: the default view)."""

    def __init__(self, meshes: dict[str, MeshData]):
        self.meshes = meshes

    def mesh(self, name: str) -> MeshData:
        return self.meshes[name]

    def section(self, name: str) -> dict:
        return {}


def test_the_view_plugin_alone_picks_the_mesh_under_a_click():
    with App(dt=DT, name="view-alone") as app:
        box = primitive("box", extents=(20.0, 20.0, 20.0), radius=1.0, height=1.0, resolution=(1, 1, 1))
        app.insert_resource(PackResource(_Pack({"box": box}), "main", {}))
        with app.active():
            ent = esper.create_entity(Name("block"), MeshRef("box"), Transform(position=np.array([5.0, 0.0, 0.0])))
        app.add_plugin(cameras.plugin)
        assert _systems(app) == {"input": ["view"]}
        picked = app.events.reader(Picked)

        # the default view frames every mesh: a click in the middle of the window lands on the box
        w, h = app.resource(InputState).window_size
        app.events.emit(MouseButton(w / 2, h / 2, "left", pressed=True))
        app.events.emit(MouseButton(w / 2, h / 2, "left", pressed=False))
        app.update()
        (ev,) = picked.read()
        assert (ev.entity, ev.entity_name, ev.viewport) == (ent, "block", "main")
        assert np.all(np.abs(np.asarray(ev.point) - [5.0, 0.0, 0.0]) <= 10.0 + 1e-9)  # on the box
        assert max(np.abs(np.asarray(ev.point) - [5.0, 0.0, 0.0])) == pytest.approx(10.0)  # on its surface

        app.events.emit(MouseButton(2.0, 2.0, "left", pressed=True))  # a corner of the window: nothing there
        app.events.emit(MouseButton(2.0, 2.0, "left", pressed=False))
        app.update()
        assert picked.read() == []
