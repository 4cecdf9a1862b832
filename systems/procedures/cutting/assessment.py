"""The cutting trainer's assessment (thesis 4.5.2): links cut, stretch, displacement and time per instrument.

Procedure stage, ORDER_ASSESSMENT."""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.deformable import Deformable
from chainsim.components.resources import Assessment
from chainsim.components.tools import Forceps, Scissors
from chainsim.systems.deformation import DeformationState
from chainsim.systems.procedures.cutting.state import MOVED_MM, CuttingState, link_stretch

# -- assessment ------------------------------------------------------------------------------------


def layer_values(ent: int, d: Deformable) -> dict:
    disp = np.linalg.norm(np.asarray(d.pos, dtype=np.float64) - d.rest, axis=1)
    return {
        "links_cut": int(len(d.alive) - np.count_nonzero(d.alive)),
        "max_stretch_ratio": link_stretch(d),
        "elements_moved": int(np.count_nonzero(disp > MOVED_MM)),
        "max_displacement_mm": float(disp.max()) if len(disp) else 0.0,
    }


class AssessmentSystem:
    """Procedure stage, after the steps: the summary's assessment values (recomputed only for layers
    that changed since the last frame)."""

    def __init__(self, st: CuttingState):
        self.st = st

    def __call__(self, app) -> None:
        st = self.st
        per = {}
        for ent in st.layers:
            d = esper.component_for_entity(ent, Deformable)
            key = (d.version, int(np.count_nonzero(d.alive)))
            hit = st.cache.get(ent)
            if hit is None or hit[0] != key:
                hit = (key, layer_values(ent, d))
                st.cache[ent] = hit
            per[st.names[ent]] = hit[1]
        f = esper.component_for_entity(st.forceps, Forceps)
        s = esper.component_for_entity(st.scissors, Scissors)
        now = app.time.sim_time
        f_time = f.time_used + (now - f.use_start if f.held_entity >= 0 else 0.0)
        s_time = s.time_used + (now - s.use_start if s.stroke_entity >= 0 else 0.0)
        uses = []
        for u in st.uses:
            dur = (now - u.start_s) if u is st.open_use else u.duration_s
            uses.append({"tool": u.tool, "layer": u.layer, "start_s": round(u.start_s, 6), "duration_s": round(dur, 6)})
        values = {
            "tool": st.tool,
            "step": next((sid for sid in st.step_ids if sid not in st.steps_done), "done"),
            "steps_done": list(st.steps_done),
            "links_cut": sum(p["links_cut"] for p in per.values()),
            "links_cut_by_layer": {k: p["links_cut"] for k, p in per.items()},
            "layers_cut": [k for k, p in per.items() if p["links_cut"]],
            "top_layer": st.names[st.top],
            "cut_length_mm": st.cut_length,
            "max_stretch_ratio": max(p["max_stretch_ratio"] for p in per.values()),
            "max_stretch_by_layer": {k: p["max_stretch_ratio"] for k, p in per.items()},
            "elements_moved": sum(p["elements_moved"] for p in per.values()),
            "elements_moved_by_layer": {k: p["elements_moved"] for k, p in per.items()},
            "max_displacement_mm": max(p["max_displacement_mm"] for p in per.values()),
            "forceps_uses": f.uses,
            "scissors_uses": s.uses,
            "forceps_time_s": f_time,
            "scissors_time_s": s_time,
            "tool_uses": uses,
            "resets": st.resets,
            "wireframe": st.wireframe,
        }

        ds = app.get_resource(DeformationState)
        if ds is not None and ds.errors:
            values["deformation_errors"] = list(ds.errors)
        app.resource(Assessment).values = values
