"""A force-feedback device on the needle: the servo loop attached to a running needle procedure.

`attach(app, spec)` (`chainsim play/run PACK --device NAME`) starts a servo loop
(chainsim.systems.engine.haptics.servo) and adds two systems:

- input stage, before the input system: the needle's depth is the tool's, the servo's needle coupled to
  the hand. Once the needle is placed, a changed depth is given to the needle procedure as the insert
  slider's value (Widget "insert"), so the kinematics, the collision test, the tissue and the recording
  take it as they take the slider (a replay needs no device). At the wall the depth asked for is
  WALL_REACH past it, so the simulation's swept test meets the bone it stands on. In "lockstep" (a
  headless run) the servo first runs the ticks up to the simulated time; in the window it runs on its
  own thread and this reads its latest tick.
- simulation stage, after the tissue: the servo's model is refreshed from what the simulation knows
  (the crossings of the needle's line, the holes, the wall along the line: `line_model`), and the
  servo's force at the depth this step took is paired with the simulation's axial force there.

The device drives the depth. A port's stylus also turns the needle while it may turn (placed, out of the
tissue: `aim_needle`); in tissue the servo holds the hand on the needle's line (port.Lateral). The
landmarks and buttons stay the mouse's and the keyboard's; so do the dials, with the simulated device.
The forces of every tick go to the run's haptic_trace.csv; `haptic_values` gives the attempt's
force metrics (peak force, force at the first puncture, time held against bone) to the assessment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput, RunOutputs
from chainsim.components.stages import ORDER_INPUT
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.haptics import model as M
from chainsim.systems.engine.haptics import port as P
from chainsim.systems.engine.haptics import simdevice as D
from chainsim.systems.engine.haptics.servo import Servo
from chainsim.systems.engine.needle_force import punch_stiffness
from chainsim.systems.procedures.needle.collision import NeedleObstacles
from chainsim.systems.procedures.needle.components import Needle, NeedleState
from chainsim.systems.procedures.needle.handles import NeedleHandles
from chainsim.systems.procedures.needle.manifest import NeedleScene
from chainsim.systems.procedures.needle.tissue import ORDER_NEEDLE_TISSUE, NeedleTissue, NeedleTissueScene

#: how far past the wall the simulation is asked to go while the servo holds the needle there (mm)
WALL_REACH = 0.5
#: the simulated device's trajectory without a file: in to this depth at 10 mm/s, held, out
SIM_DEPTH = 30.0
TRACE_HEADER = "time_s,ref_mm,hand_mm,tool_mm,force_N,passed,events,wall"


#: the force profile keeps a point every this many ticks (and every tick with an event)
PROFILE_EVERY = 20
#: at most this many points of it are stored with an attempt
PROFILE_POINTS = 400


@dataclass(slots=True)
class AttemptForces:
    """What the device felt this attempt, gathered tick by tick as the servo logs them."""

    seen: int = 0  # ticks gathered so far
    peak: float = 0.0  # largest force resisting insertion, N
    at_puncture: float | None = None  # the force the tick before the first puncture, N
    wall_ticks: int = 0  # ticks held at the wall (bone or target)
    last_force: float = 0.0
    profile: list = field(default_factory=list)  # (time s, tool depth mm, force N, events)

    def gather(self, rows: np.ndarray, dt: float) -> None:
        if not len(rows):
            return
        f = rows[:, D.L_FORCE]
        self.peak = max(self.peak, float(f.max()))
        self.wall_ticks += int(rows[:, D.L_WALL].sum())
        ev = rows[:, D.L_EVENT].astype(np.int64)
        hits = np.nonzero(ev & M.EV_PUNCTURE)[0]
        if self.at_puncture is None and len(hits):
            k = int(hits[0])
            self.at_puncture = float(f[k - 1]) if k else self.last_force
        keep = (rows[:, D.L_TICK].astype(np.int64) % PROFILE_EVERY == 0) | (ev != 0)
        self.profile.extend(
            (round(r[D.L_TICK] * dt, 3), round(r[D.L_TOOL], 3), round(r[D.L_FORCE], 4), int(r[D.L_EVENT]))
            for r in rows[keep]
        )
        self.last_force = float(f[-1])
        self.seen = int(rows[-1, D.L_TICK]) + 1


@dataclass(slots=True)
class HapticLink:
    """Resource: the servo attached to this App and what the systems keep between steps."""

    servo: Servo
    device: str
    gen: int = 0
    key: tuple = ()
    wall: float = np.inf
    read: tuple = (0, 0.0, 0.0)  # (tick, force N, tool depth mm) the last step took
    errors: list = field(default_factory=list)  # (servo N, simulation N, moved) at the same depth
    last_depth: float = 0.0  # the needle's depth at the end of the previous step
    attempt_tick: int = 0  # the first tick of the current attempt
    figures: AttemptForces = field(default_factory=lambda: AttemptForces())
    aim: P.Aim | None = None  # a port's stylus turns the needle while it may turn (`aim_needle`)
    aim_from: tuple | None = None  # the dials' (yaw, pitch) when the stylus's turn started counting
    aim_left: tuple = ()  # the dials as this system left them: changed since, the keys or mouse turned them


def attach(app: App, spec: str, realtime: bool = False, mode: str = "kernel", traj=None) -> HapticLink:
    """Attach the device `spec` ("sim", "sim:FILE" or a driver's name) to the App's needle. `realtime`:
    the servo runs on its own thread at 1 kHz (the window, benchmarks); else in lockstep with the App.
    `traj`: the simulated device's trajectory (depth per tick), instead of a file's or the default."""
    if app.get_resource(NeedleHandles) is None:
        raise UserError(f"--device {spec}: only a needle procedure takes a device")
    name, arg = P.parse(spec)
    cfg = M.new_cfg()
    if name == P.SIM:
        try:
            if traj is None:
                traj = D.load(arg) if arg else D.scripted(D.insertion(SIM_DEPTH))
        except ValueError as e:
            raise UserError(f"--device {spec}: {e}") from None
        servo = Servo(cfg, traj, D.new_hand(float(traj[0]), free=False), mode=mode if realtime else "lockstep")
    else:
        P.require(name)
        if not realtime:
            raise UserError(f"--device {name}: a real device runs in the window (chainsim play), not headless")
        dev = P.open_device(spec)
        cfg[M.C_FMAX] = min(cfg[M.C_FMAX], dev.max_force_N)
        servo = Servo(cfg, np.zeros(1), D.new_hand(0.0), mode="python", port=dev)
    link = HapticLink(servo, spec)
    if servo.port is not None:
        link.aim = P.Aim(servo.port.axis, getattr(servo.port, "up", np.array([0.0, 1.0, 0.0])))
    app.insert_resource(link)
    app.add_system("input", haptic_input, order=ORDER_INPUT - 1, name="haptics_input")
    app.add_system("simulation", haptic_refresh, order=ORDER_NEEDLE_TISSUE + 1, name="haptics_refresh")
    outputs = app.get_resource(RunOutputs)
    if outputs is not None:
        outputs.files["haptic_trace.csv"] = lambda: trace_csv(servo)
    app.on_close(servo.stop)
    servo.start()
    return link


def _needle(app: App) -> tuple[int, Needle, NeedleState]:
    ent = app.resource(NeedleHandles).needle
    return ent, esper.component_for_entity(ent, Needle), esper.component_for_entity(ent, NeedleState)


def _push_now(app: App, ev) -> None:
    """Queue `ev` for this step, ahead of input queued for later (PendingInput keeps time order)."""
    pending: PendingInput = app.resource(PendingInput)
    now, i = app.time.sim_time, pending.cursor
    while i < len(pending.items) and pending.items[i][0] <= now + 1e-12:
        i += 1
    pending.items.insert(i, (now, ev))


def haptic_input(app: App) -> None:
    """The needle's depth from the servo's tool (module docstring)."""
    link: HapticLink = app.resource(HapticLink)
    servo = link.servo
    if servo.mode == "lockstep":
        servo.advance(int(round(app.time.sim_time / servo.cfg[M.C_DT])))
    row = servo.latest()
    link.read = (servo.ticks, float(row[D.L_FORCE]), float(row[D.L_TOOL]))
    link.figures.gather(servo.rows(max(link.figures.seen, link.attempt_tick)), float(servo.cfg[M.C_DT]))
    _ent, needle, st = _needle(app)
    if link.aim is not None:
        aim_needle(app, link, st)
    if not st.placed:
        return
    depth = float(row[D.L_TOOL]) + (WALL_REACH if row[D.L_WALL] else 0.0)
    depth = round(min(max(depth, 0.0), needle.max_depth), 4)
    if abs(depth - st.target_depth) < 1e-9 or (st.done and depth > st.depth):
        return
    _push_now(app, Widget("insert", depth))


def aim_needle(app: App, link: HapticLink, st: NeedleState) -> None:
    """The stylus's turn since the needle could last turn, given to the dials (as their absolute values,
    so a recording replays without the device). Only while the needle may turn: placed, out of the
    tissue and the clutch let go. In tissue the needle keeps its line (the servo holds the hand on it,
    port.Lateral) and turning the stylus asks for nothing, so no turn is refused or counted. Turned by
    the keys or the mouse meanwhile, or stopped at a dial's limit, the dials start from there again."""
    sample, aim = link.servo.sample, link.aim
    if aim is None or sample is None or not st.placed or st.locked or sample.buttons & 1:
        link.aim_from = None
        return
    now = (float(st.yaw), float(st.pitch))
    if link.aim_from is None or max(abs(a - b) for a, b in zip(now, link.aim_left, strict=True)) > 1e-6:
        aim.start(sample.orientation)
        link.aim_from = link.aim_left = now
        return
    turned = aim.turned(sample.orientation)
    left = list(now)
    for k, name in enumerate(("rotate_horizontal", "rotate_vertical")):
        want = round(link.aim_from[k] + turned[k], 3)
        if abs(want - now[k]) >= P.AIM_DEADBAND_DEG:
            _push_now(app, Widget(name, want))
            left[k] = want
    link.aim_left = tuple(left)


def _wall(app: App, needle: Needle, st: NeedleState) -> float:
    """Depth along the needle's line of the first target or blocking obstacle (inf: none within reach)."""
    scene: NeedleScene = app.resource(NeedleScene)
    warn = {e for r in scene.roles.values() if r.kind == "obstacle" and r.on_contact == "warn" for e in r.entities}
    target = scene.target(scene.side_of(st.entry))
    reach = st.entry + needle.max_depth * st.direction()
    _name, t, _tri = app.resource(NeedleObstacles).first_hit(st.entry, reach, skip=warn - set(target.entities))
    return float(t * needle.max_depth) if np.isfinite(t) else np.inf


def line_model(scene: NeedleTissueScene | None, nt: NeedleTissue | None, placed: bool, wall: float, gen: int):
    """The servo's model of the needle's line from the simulation's state (chainsim.systems.engine.haptics.model)."""
    m = M.new_model()
    m[M.M_GEN], m[M.M_PLACED], m[M.M_WALL] = gen, float(placed), wall
    if scene is None or nt is None:
        return m
    L, rows = scene.layers, []
    for i, c in enumerate(nt.crossings[: M.MAXC]):
        j = c.layer_in
        hole = i < nt.punctured or any(
            b == c.body and layer == j and float(np.linalg.norm(p - c.point)) <= scene.hole_radius
            for b, p, layer in nt.holes
        )
        k = punch_stiffness(float(L.E[j]), float(L.nu[j]), scene.contact_radius)
        rows.append(
            (c.depth, c.room, k, L.puncture[j], L.cutting[j], L.static[j], L.dyn[j], L.visc[j], float(hole))
        )  # fmt: skip
    M.set_crossings(m, rows)
    m[M.M_PSIM] = nt.punctured
    return m


def haptic_refresh(app: App) -> None:
    """Refresh the servo's model from this step's simulation; pair the two forces at the same depth."""
    link: HapticLink = app.resource(HapticLink)
    ent, needle, st = _needle(app)
    nt = esper.try_component(ent, NeedleTissue)
    key = (st.placed, tuple(np.round(st.entry, 9)), tuple(np.round(st.q, 12)), nt.pose if nt is not None else ())
    if key != link.key:
        if st.placed and not (link.key and link.key[0]):
            link.attempt_tick = link.servo.ticks  # placed: an attempt begins, its forces counted afresh
            link.figures = AttemptForces(seen=link.attempt_tick)
        link.gen, link.key = link.gen + 1, key
        link.wall = _wall(app, needle, st) if st.placed else np.inf
    scene = app.get_resource(NeedleTissueScene)
    link.servo.refresh(line_model(scene, nt, st.placed, link.wall, link.gen))
    _tick, force, tool = link.read
    if nt is not None and nt.contact and st.placed and abs(st.depth - tool) < 1e-3 and tool < link.wall:
        # moved: the simulation's needle slid this step (its friction is then the sliding one, as the servo's)
        band = scene.stick_band if scene is not None else 0.0
        moved = abs(st.depth - link.last_depth) > band * app.time.dt
        link.errors.append((force, float(nt.axial), moved))
    link.last_depth = float(st.depth)


def haptic_values(app: App) -> dict:
    """The attempt's force figures from the device (nothing without one): the largest force the hand felt
    resisting the insertion, the force when the first boundary gave, seconds held against bone (or the
    target), and the force profile (time s, depth mm, force N, events) thinned to PROFILE_POINTS."""
    link = app.get_resource(HapticLink)
    if link is None:
        return {}
    fig = link.figures
    step = max(1, -(-len(fig.profile) // PROFILE_POINTS))
    profile = [p for i, p in enumerate(fig.profile) if i % step == 0 or p[3]]
    return {
        "device": link.device,
        "device_peak_force_N": fig.peak,
        "puncture_force_N": fig.at_puncture,
        "bone_contact_s": fig.wall_ticks * float(link.servo.cfg[M.C_DT]),
        "force_profile": [list(p) for p in profile],
    }


def trace_csv(servo: Servo) -> str:
    """Every logged tick: time, the trajectory's depth (simulated device), hand, tool, force and events."""
    rows = servo.rows()
    dt = servo.cfg[M.C_DT]
    lines = [TRACE_HEADER]
    for r in rows:
        lines.append(
            f"{r[D.L_TICK] * dt:.3f},{r[D.L_REF]:.4f},{r[D.L_HAND]:.4f},{r[D.L_TOOL]:.4f},{r[D.L_FORCE]:.5f},"
            f"{int(r[D.L_PASSED])},{int(r[D.L_EVENT])},{int(r[D.L_WALL])}"
        )
    return "\n".join(lines) + "\n"
