"""The App: stage order, fixed step, resources, event readers, isolation between Apps."""

from __future__ import annotations

import esper
import pytest

from chainsim.components.app import App
from chainsim.components.stages import ORDER_COLLISION, ORDER_DEFORMATION, ORDER_KINEMATICS


class Ping:
    def __init__(self, n):
        self.n = n


def test_stages_run_in_fixed_order_and_simulation_steps_follow_frame_time():
    log = []
    with App(dt=0.01) as app:
        for stage in ("render", "procedure", "simulation", "input"):  # added out of order on purpose
            app.add_system(stage, lambda a, s=stage: log.append(s), name=stage)
        assert app.update(0.0) == 0  # a frame shorter than dt runs no fixed step
        assert log == ["input", "procedure", "render"]
        log.clear()
        assert app.update(0.035) == 3  # 3.5 steps of time: 3 now, the half kept
        assert log == ["input", "simulation", "simulation", "simulation", "procedure", "render"]
        assert app.time.tick == 3
        log.clear()
        assert app.update(0.005) == 1  # the kept half plus this half make one more step
        assert app.time.tick == 4
        assert app.time.sim_time == pytest.approx(0.04)


def test_systems_within_a_stage_follow_their_order_then_insertion():
    log = []
    with App() as app:
        app.add_system("simulation", lambda a: log.append("deform"), order=ORDER_DEFORMATION)
        app.add_system("simulation", lambda a: log.append("collide"), order=ORDER_COLLISION)
        app.add_system("simulation", lambda a: log.append("kin1"), order=ORDER_KINEMATICS)
        app.add_system("simulation", lambda a: log.append("kin2"), order=ORDER_KINEMATICS)
        app.update()
        assert log == ["kin1", "kin2", "collide", "deform"]


def test_each_app_owns_its_world():
    a, b = App(name="a"), App(name="b")
    try:
        with a.active():
            ea = esper.create_entity(Ping(1))
        with b.active():
            assert esper.get_component(Ping) == []
            esper.create_entity(Ping(2))
        with a.active():
            assert [p.n for _, p in esper.get_component(Ping)] == [1]
            assert esper.entity_exists(ea)
    finally:
        a.close()
        b.close()
    assert a.world not in esper.list_worlds()


def test_systems_see_their_own_world_during_update():
    seen = []
    a, b = App(), App()
    with a.active():
        esper.create_entity(Ping(10))
    with b.active():
        esper.create_entity(Ping(20))
    a.add_system("simulation", lambda app: seen.append([p.n for _, p in esper.get_component(Ping)]))
    b.add_system("simulation", lambda app: seen.append([p.n for _, p in esper.get_component(Ping)]))
    a.update()
    b.update()
    a.close()
    b.close()
    assert seen == [[10], [20]]


def test_event_readers_see_each_event_once_across_stages_and_steps():
    with App(dt=0.01) as app:
        got_sim, got_proc = [], []
        r_sim = app.events.reader(Ping)
        r_proc = app.events.reader(Ping)
        app.add_system("input", lambda a: a.events.emit(Ping(a.time.frame)))
        app.add_system("simulation", lambda a: got_sim.extend(p.n for p in r_sim.read()))
        app.add_system("procedure", lambda a: got_proc.extend(p.n for p in r_proc.read()))
        app.update(0.0)  # no simulation step: the simulation reader catches up next frame
        app.update(0.02)
        app.update(0.01)
        assert got_proc == [0, 1, 2]
        assert got_sim == [0, 1, 2]


def test_reader_ignores_other_types_and_old_events():
    with App() as app:
        app.events.emit(Ping(1))
        r = app.events.reader(Ping)  # made after the first event: does not see it
        app.events.emit("not a ping")
        app.events.emit(Ping(2))
        assert [p.n for p in r.read()] == [2]
        assert r.read() == []


def test_resources_are_typed_singletons():
    with App() as app:
        app.insert_resource(Ping(1))
        app.insert_resource(Ping(2))
        assert app.resource(Ping).n == 2
        with pytest.raises(KeyError, match="int"):
            app.resource(int)
        assert app.get_resource(float, "none") == "none"


def test_bad_dt_and_closed_app_are_refused():
    with pytest.raises(ValueError):
        App(dt=0.0)
    app = App()
    app.close()
    with pytest.raises(RuntimeError):
        app.update()
