"""Needle kinematics: rotation by concatenated quaternions, then insertion along the axis (thesis 3.3.4-3.3.5).

Stage: simulation (ORDER_KINEMATICS). Reads: Widget, WidgetRefused (a click on a locked dial) and Key
events, Needle, NeedleState, WidgetState, InputState. Writes: NeedleState, the Transforms of the needle
(tip) and its shaft, WidgetState (`disabled` and the dial/slider values it keeps in step); emits
RotationRefused, InsertRefused, NeedleAction and NeedleReset.

Controls (documented for trainees in the pack's how-to page):

    rotate_horizontal  dial, ABSOLUTE degrees turned about the vertical (+Z) axis since the needle was
                       placed; positive turns counter-clockwise seen from above. Right arrow raises
                       it, left lowers it (as the dial's "+" on the right and a drag to the right).
    rotate_vertical    dial, ABSOLUTE degrees of tilt about the needle's own horizontal axis (d x Z);
                       positive raises the tip. Up arrow raises it, down lowers it.
    insert             slider: ABSOLUTE depth in mm along the needle axis; as a button (no value) it
                       advances one step. Key i advances, key o withdraws one step.
                       Shift held with an arrow, i or o: a fine step (FINE of the normal one).
    withdraw           button: back one step (or by its value in mm)
    reset              needle back to landmark 1 and unlocked; value "all" (or shift held) also clears
                       the landmarks (the procedure system does that part)

A dial value is turned into the increment from the current angle, and that increment is applied as a
quaternion product (eq. 3.1 and the product formula of 3.3.5): horizontal rotations about world +Z,
vertical ones about the needle's current horizontal axis, so the tilt is kept when turning and the
heading is kept when tilting. Once the needle has been inserted (target depth > 0) rotation is locked,
as in the thesis, until the needle is withdrawn back to the skin (depth 0) - the dials then unlock
where they are, as a surgeon withdraws and redirects, and the next turn counts as a redirection -
or until a reset (which also zeroes the dials). The needle is hidden until landmark 1 places it.

A turn asked for while the needle is in (a key, a dial value, a click on the locked dial) is refused
and counted (`rotation_refused`, RotationRefused "locked"). A turn asked for after the needle was sent
back to the skin but before it got there (it withdraws at `withdraw_speed`) is not refused: the
trainee has withdrawn and is redirecting, as a clinician turns the needle while drawing it back, so
the turn is held (NeedleAction "turn_held") and made, in order, when the dials unlock at the skin;
sent in again first, the needle drops the held turns and says so (NeedleAction "turns_dropped").

Forward insertion reaches the requested depth within one step, or at the needle's `insert_speed` where
the pack sets one (the tissue's friction depends on speed); the collision system that runs next tests
the whole swept segment, so a jump of any length cannot pass through bone. Backward motion
(withdrawal, the bounce after touching bone) runs at `withdraw_speed` so it can be seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Transform
from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, Widget
from chainsim.components.resources import EntityIndex, InputState
from chainsim.components.stages import ORDER_KINEMATICS
from chainsim.components.view_events import WidgetRefused
from chainsim.systems.engine import quaternion as Q
from chainsim.systems.procedures.needle.components import Needle, NeedleState
from chainsim.systems.view.ui.widgets import WidgetState

Z = np.array([0.0, 0.0, 1.0])
ROTATION_WIDGETS = ("rotate_horizontal", "rotate_vertical")
KEY_ACTIONS = {
    "left": ("rotate_horizontal", -1.0),
    "right": ("rotate_horizontal", +1.0),
    "up": ("rotate_vertical", +1.0),
    "down": ("rotate_vertical", -1.0),
    "i": ("insert", +1.0),
    "o": ("withdraw", +1.0),
}
SHIFT_KEYS = {"lshift", "rshift", "shift"}
FINE = 0.25  # a shifted key moves a quarter of the normal step (0.25 degree, 0.5 mm)
KEY_ROWS = [
    ("`Right` / `Left` arrow", "horizontal turn up / down by the dial's step (1.0 degree)"),
    ("`Up` / `Down` arrow", "vertical tilt up / down (1.0 degree)"),
    ("`i` / `o`", "insert / withdraw the needle one step (2.0 mm)"),
    ("`Shift` + arrow, `i` or `o`", "a fine step: a quarter of the normal one"),
]


@dataclass(frozen=True, slots=True)
class RotationRefused:
    """A rotation command was refused (`reason`: "locked" once inserted, "not_placed" before landmark 1)."""

    widget: str
    reason: str


@dataclass(frozen=True, slots=True)
class InsertRefused:
    reason: str  # "not_placed", "in_target", "max_depth"


@dataclass(frozen=True, slots=True)
class NeedleAction:
    """A command the needle carried out: kind is a widget name; value the new angle or depth."""

    kind: str
    value: float


@dataclass(frozen=True, slots=True)
class NeedleReset:
    all: bool


# -- pose -----------------------------------------------------------------------------------------


def initial_direction(entry, aim_at=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Within the axial plane, toward the vertical axis through `aim_at` (the needle's manifest key; the
    frame origin by default): the needle starts level and aimed at that axis."""
    d = np.array([float(aim_at[0]) - float(entry[0]), float(aim_at[1]) - float(entry[1]), 0.0])
    n = float(np.linalg.norm(d))
    if n < 1e-9:
        return np.array([-math.copysign(1.0, float(entry[0]) or 1.0), 0.0, 0.0])
    return d / n


def apply_pose(app: App, ent: int, needle: Needle, st: NeedleState) -> None:
    """Write the tip Transform (origin at the tip, local +Z along insertion) and the shaft's."""
    tr = esper.try_component(ent, Transform)
    d = st.direction()
    tip = st.entry + st.depth * d
    if tr is not None:
        tr.position = tip.copy()
        tr.rotation = st.q.copy()
    if needle.shaft:
        index = app.get_resource(EntityIndex)
        sh = index.get(needle.shaft) if index is not None else None
        str_ = esper.try_component(sh, Transform) if sh is not None else None
        if str_ is not None:
            str_.position = tip - d * (0.5 * needle.length)
            str_.rotation = st.q.copy()


def show(app: App, ent: int, needle: Needle, visible: bool) -> None:
    """Show or hide the needle (tip and shaft): it is not drawn before landmark 1 places it."""

    index = app.get_resource(EntityIndex)
    ents = [ent] + ([index.get(needle.shaft)] if needle.shaft and index is not None else [])
    for e in ents:
        ref = esper.try_component(e, MeshRef) if e is not None else None
        if ref is not None:
            ref.visible = bool(visible)


def place(app: App, ent: int, needle: Needle, st: NeedleState, entry) -> None:
    """Put the tip at `entry` (landmark 1) pointing along `initial_direction`, unlocked, not inserted."""
    st.entry = np.asarray(entry, dtype=np.float64).copy()
    st.q0 = Q.look_rotation(initial_direction(st.entry, needle.aim_at), Z)
    reset(app, ent, needle, st)
    st.placed = True
    apply_pose(app, ent, needle, st)
    show(app, ent, needle, True)


def reset(app: App, ent: int, needle: Needle, st: NeedleState) -> None:
    st.q = st.q0.copy()
    st.yaw = st.pitch = 0.0
    st.depth = st.target_depth = st.prev_depth = 0.0
    st.locked = st.done = st.withdrawn = False
    st.held_turns = []
    st.contact = ""
    st.contact_point = np.full(3, np.nan)
    sync_widgets(app, st)
    if st.placed:
        apply_pose(app, ent, needle, st)


def park(app: App, ent: int, needle: Needle, st: NeedleState) -> None:
    """Back to where the pack placed the needle, before any landmark."""
    reset(app, ent, needle, st)
    st.placed = False
    new_attempt(st)
    tr = esper.try_component(ent, Transform)
    if tr is not None:
        tr.position = st.park_position.copy()
        tr.rotation = st.park_rotation.copy()
    show(app, ent, needle, False)


def new_attempt(st: NeedleState) -> None:
    """Zero what an attempt counts (a saved attempt is closed; the next one counts afresh)."""
    st.contacts = {}
    st.touches = {}
    st.rotation_refused = 0
    st.redirections = 0
    st.path_length = 0.0


def rotate_horizontal(st: NeedleState, delta_deg: float) -> None:
    st.q = Q.normalize(Q.mul(Q.from_axis_angle(Z, math.radians(delta_deg)), st.q))
    st.yaw += delta_deg


def rotate_vertical(st: NeedleState, delta_deg: float, max_pitch: float) -> float:
    """Tilt about the needle's horizontal axis, clamped to +-max_pitch; returns the tilt applied."""
    new = min(max(st.pitch + delta_deg, -max_pitch), max_pitch)
    delta = new - st.pitch
    if delta == 0.0:
        return 0.0
    d = st.direction()
    h = np.cross(d, Z)
    h /= np.linalg.norm(h)
    st.q = Q.normalize(Q.mul(Q.from_axis_angle(h, math.radians(delta)), st.q))
    st.pitch = new
    return delta


def _shift(app: App) -> bool:
    return bool(app.resource(InputState).keys & SHIFT_KEYS)


def _widgets(app: App):

    return app.get_resource(WidgetState)


def sync_widgets(app: App, st: NeedleState, needle: Needle | None = None) -> None:
    """Mirror the needle's pose and lock state on the controller's dials (also after a collision). With
    the `needle`, dials stay usable while it withdraws to the skin: their turns wait for it there."""
    ws = _widgets(app)
    if ws is None:
        return
    for name, v in (("rotate_horizontal", st.yaw), ("rotate_vertical", st.pitch), ("insert", st.target_depth)):
        if name in ws.specs:
            ws.set(name, v)
    if st.locked and not (needle is not None and withdrawing(needle, st)):
        ws.disable(*ROTATION_WIDGETS)
    else:
        ws.enable(*ROTATION_WIDGETS)


def withdrawing(needle: Needle, st: NeedleState) -> bool:
    """Locked, but sent back to the skin where the dials will unlock (the slider at 0, withdraw pressed
    back to 0, or a spring-back from bone near the skin): the needle is still on its way there."""
    return st.locked and st.target_depth <= 0.0 and needle.unlock_at_skin


def turn(app: App, ent, needle: Needle, st: NeedleState, name: str, value, increment: bool) -> None:
    """Turn the unlocked needle: by `value` degrees (`increment`) or to the dial angle `value`."""
    current = st.yaw if name == "rotate_horizontal" else st.pitch
    if increment:
        delta = float(value)
    elif isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        delta = float(value) - current
    else:
        return
    if delta == 0.0:
        return
    if st.withdrawn:  # turned after coming back to the skin: a redirection
        st.withdrawn = False
        st.redirections += 1
    if name == "rotate_horizontal":
        if needle.max_yaw > 0.0:
            delta = min(max(st.yaw + delta, -needle.max_yaw), needle.max_yaw) - st.yaw
            if delta == 0.0:
                return
        rotate_horizontal(st, delta)
    else:
        rotate_vertical(st, delta, needle.max_pitch)
    apply_pose(app, ent, needle, st)
    sync_widgets(app, st, needle)
    app.events.emit(NeedleAction(name, st.yaw if name == "rotate_horizontal" else st.pitch))


# -- the system -------------------------------------------------------------------------------------


class NeedleSystem:
    def __init__(self, app: App):
        self.widgets = app.events.reader(Widget)
        self.refused = app.events.reader(WidgetRefused)
        self.keys = app.events.reader(Key)

    def commands(self, app: App):
        """(name, value, from_key) in event order; keys become increments."""
        out = []
        for ev in self.widgets.read():
            out.append((ev.name, ev.value, False))
        for ev in self.refused.read():  # a click on a locked dial: a turn asked for, with no angle
            if ev.name in ROTATION_WIDGETS:
                out.append((ev.name, None, False))
        for ev in self.keys.read():
            if ev.pressed and ev.key in KEY_ACTIONS:
                name, sign = KEY_ACTIONS[ev.key]
                out.append((name, sign, True))
        return out

    def rotate(self, app: App, ent, needle, st, name, value, from_key) -> None:
        """A turn asked for: made, held until the needle is back at the skin, or refused (and counted)."""
        if not st.placed:
            app.events.emit(RotationRefused(name, "not_placed"))
            return
        if from_key:  # a key turns by a step from where the dial is; held, it keeps that increment
            value = float(value) * needle.rotate_step * (FINE if _shift(app) else 1.0)
        if withdrawing(needle, st):
            # sent back to the skin and still on its way: the turn is the redirection asked for, made
            # when the dials unlock there - the time the withdrawal takes is the simulator's, not a
            # refusal of the trainee's technique
            if value is not None:
                st.held_turns.append((name, value, from_key))
            app.events.emit(NeedleAction("turn_held", float(len(st.held_turns))))
            return
        if st.locked:
            st.rotation_refused += 1
            app.events.emit(RotationRefused(name, "locked"))
            return
        turn(app, ent, needle, st, name, value, from_key)

    def insert(self, app: App, ent, needle, st, name, value, from_key) -> None:
        if not st.placed:
            app.events.emit(InsertRefused("not_placed"))
            return
        key_step = needle.insert_step * (FINE if from_key and _shift(app) else 1.0)
        if name == "withdraw":
            step = key_step if (from_key or value is None or isinstance(value, (bool, str))) else abs(float(value))
            want = st.target_depth - step
        elif from_key or value is None or isinstance(value, (bool, str)):
            want = st.target_depth + key_step
        else:
            want = float(value)
        if st.done and want > st.depth:
            app.events.emit(InsertRefused("in_target"))
            return
        if want > needle.max_depth:
            app.events.emit(InsertRefused("max_depth"))
        st.target_depth = min(max(want, 0.0), needle.max_depth)
        if st.target_depth > 0.0 and not st.locked and needle.lock_on_insert:
            st.locked = True  # thesis 3.3.4: no rotation once the insertion has begun
        if st.target_depth > 0.0 and st.held_turns:
            # sent in again before it reached the skin: the turns that waited for the skin are not made
            app.events.emit(NeedleAction("turns_dropped", float(len(st.held_turns))))
            st.held_turns = []
        sync_widgets(app, st, needle)
        app.events.emit(NeedleAction(name, st.target_depth))

    def __call__(self, app: App) -> None:
        cmds = self.commands(app)
        for ent, (needle, st) in esper.get_components(Needle, NeedleState):
            for name, value, from_key in cmds:
                if name in ROTATION_WIDGETS:
                    self.rotate(app, ent, needle, st, name, value, from_key)
                elif name in ("insert", "withdraw"):
                    self.insert(app, ent, needle, st, name, value, from_key)
                elif name == "reset":
                    keys = app.resource(InputState).keys
                    everything = value == "all" or bool(keys & SHIFT_KEYS)
                    if everything:
                        park(app, ent, needle, st)
                    else:
                        reset(app, ent, needle, st)
                    app.events.emit(NeedleReset(everything))
            self.move(app, ent, needle, st)

    def move(self, app: App, ent, needle, st) -> None:
        st.prev_depth = st.depth
        if not st.placed:
            return
        if st.target_depth > st.depth:
            # immediate (0), or at the needle's insertion speed: forces that depend on speed need one
            step = needle.insert_speed * app.time.dt if needle.insert_speed > 0 else np.inf
            st.depth = min(st.target_depth, st.depth + step)
        elif st.target_depth < st.depth:
            st.depth = max(st.target_depth, st.depth - needle.withdraw_speed * app.time.dt)
        if st.depth != st.prev_depth:
            st.path_length += abs(st.depth - st.prev_depth)
            apply_pose(app, ent, needle, st)
        if st.locked and st.depth <= 0.0 and st.target_depth <= 0.0 and needle.unlock_at_skin:
            # back at the skin: the dials unlock where they are (withdraw and redirect)
            st.locked = st.done = False
            st.withdrawn = True
            sync_widgets(app, st, needle)
            app.events.emit(NeedleAction("withdrawn", 0.0))
            held, st.held_turns = st.held_turns, []
            for name, value, increment in held:  # the turns asked for on the way back, in order
                turn(app, ent, needle, st, name, value, increment)


def init_state(app: App) -> None:
    """Give every needle its runtime state, remembering where the pack parked it."""
    with app.active():
        for ent, _needle in esper.get_component(Needle):
            if esper.has_component(ent, NeedleState):
                continue
            st = NeedleState()
            tr = esper.try_component(ent, Transform)
            if tr is not None:
                st.park_position = tr.position.copy()
                st.park_rotation = tr.rotation.copy()
            esper.add_component(ent, st)


def plugin(app: App) -> None:

    init_state(app)
    with app.active():
        for ent, needle in esper.get_component(Needle):
            show(app, ent, needle, False)
    h = app.get_resource(HudState)
    if h is not None:
        h.key_rows[:0] = KEY_ROWS
    app.add_system("simulation", NeedleSystem(app), order=ORDER_KINEMATICS, name="needle")
