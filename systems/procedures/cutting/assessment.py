"""The cutting trainer's assessment (thesis 4.5.2): links cut, stretch, displacement and time per instrument,
and the attempt it saves.

Procedure stage, ORDER_ASSESSMENT. Reads CuttingState, the layers, the instruments, Widget `save`,
Settings ("class", "trainee") and Records; writes Assessment.values (the summary's `assessment`), HUD
messages and FailedSaves (a headless run whose save failed then exits 2).

An attempt runs from the session's start, or from the last Reset tissue, to Save attempt; Save closes
it (a second Save stores nothing) and Reset tissue begins the next. The record saved names this
procedure and holds its figures (time, cut length, links cut, stretch, displacement, instrument times:
chainsim.systems.procedures.cutting.records): `target` is the top layer once every step is done (the
opening made) and "none" before. `step_times` holds, per step done, the seconds from the
attempt's start to when it was done (the steps may be done in any order). `metrics` carries the pack's
own [metrics.NAME], each the assessment value of that name (a list counts its items), and `details`
the per-layer figures and the instrument uses. Records that refuse saves (a replay) store nothing and
the attempt closes as it did when recorded; the records server's replay scores it from here too.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import Assessment, FailedSaves, PackResource, Records, SavedLocally, Settings
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.cutting import records
from chainsim.systems.procedures.cutting.state import MOVED_MM, CuttingState, link_stretch
from chainsim.systems.procedures.cutting.tools import Forceps, Scissors
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.deformation import DeformationState

DEFAULT_CLASS = "default"
DEFAULT_TRAINEE = "anonymous"
#: assessment values kept in a saved attempt's details
DETAIL_KEYS = (
    "steps_done",
    "links_cut_by_layer",
    "layers_cut",
    "max_stretch_by_layer",
    "elements_moved_by_layer",
    "max_displacement_mm",
    "forceps_uses",
    "scissors_uses",
    "tool_uses",
    "resets",
)

# -- assessment ------------------------------------------------------------------------------------


def layer_values(ent: int, d: Deformable) -> dict:
    b = d.body
    disp = np.linalg.norm(np.asarray(b.positions, dtype=np.float64) - b.rest, axis=1)
    return {
        "links_cut": int(len(b.alive) - np.count_nonzero(b.alive)),
        "max_stretch_ratio": link_stretch(d),
        "elements_moved": int(np.count_nonzero(disp > MOVED_MM)),
        "max_displacement_mm": float(disp.max()) if len(disp) else 0.0,
    }


def metric_values(pack, v: dict) -> dict:
    """The pack's [metrics.NAME] with their values, in the order declared: the assessment value of that
    name, a list as its length (layers cut), None where the assessment has no such number."""
    out: dict = {}
    for name in pack.section("metrics"):
        x = v.get(name)
        if isinstance(x, (list, tuple)):
            x = len(x)
        out[name] = None if x is None or isinstance(x, (bool, dict, str)) else float(x)
    return out


def attempt_record(pack, v: dict) -> dict:
    """The records-store attempt (chainsim.game.records.store) for assessment values `v` (see the module):
    this procedure's figures by the names its layout declares (chainsim.systems.procedures.cutting.records)."""
    return {
        "procedure": "cutting",
        "pack": pack.name,
        **{c.name: v[c.name] for c in records.COLUMNS},
        "target": v["top_layer"] if v["step"] == "done" else "none",
        "step_times": dict(v["step_times"]),
        "details": {k: v[k] for k in DETAIL_KEYS if k in v},
        "metrics": metric_values(pack, v),
    }


class AssessmentSystem:
    """Procedure stage, after the steps: the summary's assessment values (recomputed only for layers
    that changed since the last frame) and Save attempt."""

    def __init__(self, st: CuttingState, app: App | None = None):
        self.st = st
        # made at build time, so no Save pressed before the first frame is missed
        self.widgets = app.events.reader(Widget) if app is not None else None
        self.attempt = 1
        self.start_s = 0.0
        self.elapsed = 0.0
        self.closed = False
        self.resets = 0
        self.step_times: dict = {}
        self.saved: list = []
        self.errors: list = []

    def attempt_clock(self, app: App) -> None:
        """A Reset tissue begins the next attempt; a step done is timed from the attempt's start."""
        st, now = self.st, app.time.sim_time
        if st.resets != self.resets:
            self.resets = st.resets
            if self.closed:
                self.attempt += 1
            self.closed = False
            self.start_s, self.step_times = now, {}
        for sid in st.steps_done:
            self.step_times.setdefault(sid, now - self.start_s)
        if not self.closed:
            self.elapsed = now - self.start_s

    def save(self, app: App, v: dict) -> None:
        hud = app.get_resource(HudState)

        def say(text: str, seconds: float = 4.0) -> None:
            if hud is not None:
                hud.message(text, seconds)

        if self.closed:
            say(f"Attempt {self.attempt} is already saved. Reset tissue (r) to begin the next.")
            return
        records = app.resource(Records)
        if records.refuses:  # a replay: the attempt closes as it did when recorded, nothing is stored
            self.closed = True
            say(f"Not saved: {records.refuses}.")
            return
        s = app.resource(Settings)
        cls, who = s.get("class") or DEFAULT_CLASS, s.get("trainee") or DEFAULT_TRAINEE
        try:
            rid = records.save_attempt(cls, who, attempt_record(app.resource(PackResource).pack, v))
        except SavedLocally as e:  # safe on this computer; the records server gets it later
            self.closed = True
            say(f"Saved on this computer: {e}", 8.0)
        except (UserError, OSError) as e:  # a full disk or a vanished folder must not end the session
            self.errors.append(str(e))
            say(f"Not saved: {e}", 8.0)
            failed = app.get_resource(FailedSaves)
            if failed is not None:
                failed.messages.append(str(e))
        else:
            self.closed = True
            self.saved.append(rid)
            # a records server files the attempt under the signed-in account, not the typed names
            filed = records.filed_as(rid) if records.filed_as else None
            if filed:
                cls, who = filed[0], filed[1]
            say(f"Attempt {self.attempt} saved for {who} in class {cls}. Reset tissue (r) to begin the next.", 6.0)

    def __call__(self, app: App) -> None:
        st = self.st
        self.attempt_clock(app)
        per = {}
        for ent in st.layers:
            d = esper.component_for_entity(ent, Deformable)
            key = (d.body.version, int(np.count_nonzero(d.body.alive)))
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
        values.update(
            attempt=self.attempt,
            duration_s=self.elapsed,
            step_times=dict(self.step_times),
        )
        values["metrics"] = metric_values(app.resource(PackResource).pack, values)
        for ev in self.widgets.read() if self.widgets is not None else ():
            if ev.name == "save":
                self.save(app, values)
        values.update(saved=list(self.saved), save_errors=list(self.errors), unsaved=not self.closed)
        app.resource(Assessment).values = values
