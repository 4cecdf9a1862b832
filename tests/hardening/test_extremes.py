"""Finite but extreme input (every number at its limit) is handled without an inf or NaN in the world.

Input scripts may hold coordinates up to +-MAX_COORD: drags and scrolls of a million pixels, picks a
kilometre away, dials turned a million degrees. Each built-in pack is driven with such events; the
run must not raise, and afterwards every number in every component and in the summary is finite.
"""

from __future__ import annotations

import dataclasses
import math

import esper
import numpy as np
import pytest

from chainsim.components.core import MeshRef
from chainsim.components.digest import world_digest
from chainsim.components.input_events import (
    Key,
    MouseButton,
    MouseDrag,
    MouseMove,
    PickPoint,
    Resize,
    Scroll,
    Widget,
)
from chainsim.components.resources import EntityIndex, PackResource, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine import limits

BIG = limits.MAX_COORD


def _events(pick_entity: str, widgets: list[str]):
    evs = [
        MouseMove(BIG, -BIG),
        MouseButton(640, 400, "left", True),
        MouseDrag(640, 400, BIG, -BIG, "left"),
        MouseDrag(640, 400, -BIG, BIG, "right"),
        MouseDrag(640, 400, -BIG, BIG, "middle"),
        MouseButton(640, 400, "left", False),
        Scroll(640, 400, -BIG),
        Scroll(640, 400, BIG),
        Scroll(10, 10, -BIG),
        Resize(limits.MAX_PIXELS, 1),
        Resize(1280, 800),
        PickPoint(pick_entity, (BIG, BIG, -BIG)),
        PickPoint(pick_entity, (-BIG, 0.0, 0.0)),
        PickPoint(pick_entity, (0.0, BIG, 0.0)),
        Key("left"),
        Key("up"),
    ]
    for w in widgets:
        evs += [Widget(w, BIG), Widget(w, -BIG)]
    return [(0.02 * (i + 1), ev) for i, ev in enumerate(evs)]


def _assert_finite(value, where: str) -> None:
    """No infinity anywhere (NaN alone marks "not set yet", e.g. a contact point before any contact)."""
    if isinstance(value, np.ndarray) and np.issubdtype(value.dtype, np.floating):
        assert not np.isinf(value).any(), where
    elif isinstance(value, float):
        assert not math.isinf(value), where
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            _assert_finite(getattr(value, f.name), f"{where}.{f.name}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _assert_finite(v, f"{where}[{i}]")


@pytest.mark.parametrize("pack", ["prp", "cutting", "chainmail-demo", "loop-demo"])
def test_extreme_events_leave_every_number_finite(pack):
    app = build_app(pack)
    try:
        index: EntityIndex = app.resource(EntityIndex)
        with app.active():  # the first entity with a mesh to pick on (runtime entities have none)
            pick = next(n for n in sorted(index.by_name) if esper.try_component(index.by_name[n], MeshRef))
        layout = app.resource(PackResource).layout
        widgets = [w["name"] for w in layout.get("widgets", []) if w.get("name") != "save"]
        app.resource(PendingInput).extend(_events(pick, widgets))
        for _ in range(240):
            app.update(app.time.dt)
        with app.active():
            for ent in sorted(esper._entities):
                for comp in esper.components_for_entity(ent):
                    _assert_finite(comp, f"{pack}:{ent}:{type(comp).__name__}")
                    for name in ("pos", "position", "rotation"):  # geometry is never "not set"
                        v = getattr(comp, name, None)
                        if isinstance(v, np.ndarray) and v.size:
                            assert np.isfinite(v).all() and np.abs(v).max() < 1e9, (pack, type(comp).__name__, name)
        assert len(world_digest(app)) == 64
    finally:
        app.close()
