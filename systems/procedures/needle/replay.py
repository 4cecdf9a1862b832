"""The needle scene as the records server's 3-D replay reads it (chainsim.game.server.replay3d): per
step, the attempt and its clock, the tip and the needle's direction, and a contact made since the last
step (an obstacle's, or the target reached).

Contacts are counted as the needle counts them (NeedleState.contacts, every role's); a new attempt
counts from zero, so the reader does too.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.systems.procedures.needle.components import Needle, NeedleState
from chainsim.systems.procedures.needle.handles import NeedleHandles
from chainsim.systems.procedures.needle.manifest import NeedleScene, ProcedureState
from chainsim.systems.procedures.procedure import ReplayFrame, ReplayReader


def reader(app: App) -> ReplayReader:
    """A reader of this App's needle scene (its handles are read once, the components at each call)."""
    handles = app.resource(NeedleHandles)
    scene = app.resource(NeedleScene)
    with app.active():
        length = float(esper.component_for_entity(handles.needle, Needle).length)
    seen = [0]  # contacts counted at the last frame

    def attempt() -> int:
        return esper.component_for_entity(handles.procedure, ProcedureState).attempt

    def frame() -> ReplayFrame:
        ps = esper.component_for_entity(handles.procedure, ProcedureState)
        st = esper.component_for_entity(handles.needle, NeedleState)
        tip = st.tip() if st.placed else np.full(3, np.nan)
        n = sum(st.contacts.values())
        if n < seen[0]:  # a new attempt counts from zero
            seen[0] = 0
        contact = None
        if n > seen[0]:
            point = st.contact_point if np.all(np.isfinite(st.contact_point)) else st.tip()
            role = scene.role_of(st.contact, scene.side_of(st.entry))
            contact = (st.contact, point, role is not None and role.kind == "target")
            seen[0] = n
        return ReplayFrame(ps.attempt, round(float(ps.elapsed), 3), tip, st.direction(), contact)

    return ReplayReader(attempt=attempt, frame=frame, length_mm=length)
