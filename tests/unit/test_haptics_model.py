"""The servo's local contact model: the compiled tick against its plain-Python reference on drawn tissue and
hand paths, and what a trainee's hand relies on (the wall holds, a puncture happens in the tick the press
reaches the layer's puncture force, a refresh of the same line keeps what the servo punctured)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.haptics import model as M
from chainsim.systems.engine.haptics.reference import Crossing, Reference

K_C, B_C, DT, F_MAX = 0.6, 0.0006, 1e-3, 3.3


@st.composite
def lines(draw):
    """Crossings along a needle's line (deepening, the layer entered by each) and a wall depth."""
    n = draw(st.integers(0, 5))
    depth = draw(st.floats(0.0, 3.0))
    end = depth + draw(st.floats(5.0, 80.0))
    out = []
    for _ in range(n):
        if depth >= end:
            break
        dyn = draw(st.floats(0.0, 0.05))
        out.append(
            Crossing(
                depth=depth,
                room=end - depth,
                k=draw(st.floats(0.02, 2.0)),
                threshold=draw(st.floats(0.05, 3.0)),
                cutting=draw(st.floats(0.0, 0.5)),
                static=dyn + draw(st.floats(0.0, 0.05)),
                dyn=dyn,
                visc=draw(st.floats(0.0, 1e-3)),
                hole=draw(st.booleans()),
            )
        )
        depth += draw(st.floats(0.2, 12.0))
    wall = draw(st.one_of(st.just(math.inf), st.floats(1.0, 90.0)))
    return out, wall


def compiled(crossings, wall):
    model = M.new_model()
    rows = [(c.depth, c.room, c.k, c.threshold, c.cutting, c.static, c.dyn, c.visc, float(c.hole)) for c in crossings]
    M.set_crossings(model, rows)
    model[M.M_PLACED], model[M.M_GEN], model[M.M_WALL] = 1.0, 1.0, wall
    state = M.new_state()
    M.apply_model(model.copy(), model, state)
    return model, state


@settings(max_examples=150, deadline=None)
@given(lines(), st.lists(st.floats(-1.5, 2.5), min_size=1, max_size=60), st.floats(-4.0, 0.0))
def test_the_compiled_tick_is_the_reference(line, steps, start):
    crossings, wall = line
    cfg = M.new_cfg(K_C, B_C, DT, F_MAX)
    model, state = compiled(crossings, wall)
    ref = Reference(crossings, wall, K_C, B_C, DT, F_MAX)
    x = start
    for dx in [0.0, *steps]:
        x += dx
        f = M.contact_tick(cfg, model, state, x)
        assert f == ref.tick(x)
        assert state[M.S_XT] == ref.tool.x
        assert int(state[M.S_P]) == ref.tool.passed
        assert int(state[M.S_EVENT]) == ref.tool.events
        assert abs(f) <= F_MAX
        assert state[M.S_XT] <= wall  # the needle never passes the wall, however far the hand goes


def test_the_wall_holds_and_the_force_says_how_hard_the_hand_pushes():
    cfg = M.new_cfg()
    model, state = compiled([], 10.0)
    forces = [M.contact_tick(cfg, model, state, x) for x in np.linspace(0.0, 14.0, 141)]
    assert state[M.S_XT] == 10.0 and state[M.S_WALL] == 1.0
    # held: the hand 4 mm past the wall feels the coupling spring, clipped at the device's largest
    held = [M.contact_tick(cfg, model, state, 14.0) for _ in range(5)]
    assert held[-1] == pytest.approx(min(K_C * 4.0, F_MAX))
    assert max(np.abs(forces[:100])) < 1e-12  # nothing before the wall


def test_a_puncture_happens_in_the_tick_the_press_reaches_the_puncture_force():
    skin = Crossing(0.0, 60.0, 0.2, 1.0, 0.3, 0.02, 0.01, 2e-4)
    cfg = M.new_cfg()
    model, state = compiled([skin], math.inf)
    x, forces = -1.0, []
    while not int(state[M.S_EVENT]) & M.EV_PUNCTURE:
        x += 0.01
        forces.append(M.contact_tick(cfg, model, state, x))
        assert x < 20.0
    assert max(forces[:-1]) < skin.threshold <= max(forces[:-1]) + 0.01  # it gave at its puncture force
    assert forces[-1] < forces[-2] - 0.2  # and the hand felt it give in that same tick
    assert state[M.S_P] == 1.0 and state[M.S_HOLE0] == 1.0


def test_a_refresh_of_the_same_line_keeps_what_the_servo_punctured_and_a_new_line_starts_over():
    skin = (0.0, 60.0, 0.2, 1.0, 0.3, 0.02, 0.01, 2e-4, 0.0)
    fat = (2.0, 58.0, 0.1, 0.3, 0.1, 0.02, 0.01, 2e-4, 0.0)
    cfg = M.new_cfg()
    frame = M.new_model()
    M.set_crossings(frame, [skin, fat])
    frame[M.M_PLACED], frame[M.M_GEN] = 1.0, 1.0
    model, state = M.new_model(), M.new_state()
    M.apply_model(frame, model, state)
    for x in np.linspace(-1.0, 12.0, 400):
        M.contact_tick(cfg, model, state, x)
    assert state[M.S_P] == 2.0
    M.apply_model(frame, model, state)  # the frame has not seen the punctures yet: the servo keeps them
    assert state[M.S_P] == 2.0
    frame[M.M_GEN] = 2.0  # the needle was placed again: the crossings behind the tool are passed, no holes
    state[M.S_XT] = 1.0
    M.apply_model(frame, model, state)
    assert state[M.S_P] == 1.0 and state[M.S_HOLE0] == 0.0


def test_an_unplaced_needle_goes_with_the_hand_and_feels_nothing():
    cfg = M.new_cfg()
    model, state = compiled([Crossing(0.0, 60.0, 0.2, 1.0, 0.3, 0.02, 0.01, 2e-4)], 5.0)
    model[M.M_PLACED] = 0.0
    assert [M.contact_tick(cfg, model, state, x) for x in (0.0, 3.0, 9.0)] == [0.0, 0.0, 0.0]
    assert state[M.S_XT] == 9.0


def test_a_coupling_that_would_not_be_passive_is_refused():
    with pytest.raises(ValueError, match="b_c > k_c dt / 2"):
        M.new_cfg(k_c=2.0, b_c=0.0005, dt=1e-3)
