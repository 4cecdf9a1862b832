"""The window while the kernels compile: which kernel groups a scene needs, input held until they are
ready, and the progress line on the HUD.

On a fresh install the numba kernels take minutes to compile (chainsim.systems.engine.warmup). The window
opens at once and they compile in child processes (`Compiler`) while the trainee signs in and reads
the help. Until the groups the scene needs are compiled (`needed_groups`: the normals and collision
kernels every scene draws and steps with, and the kernels of each soft body's own model), `KernelGate`
lets through what needs no kernel - the pointer moving, a resize, the sign-in form, F1 and the help
pages and their buttons - and holds everything else in order (the pointer's moves too, once anything
is held): the scene is not stepped while input is held, the window keeps drawing and answering, and
the HUD says that the input waits (how many presses and clicks) and how far compiling has got. When
the groups are ready the held input goes to the scene with its own spacing in time, as if it had just
been given (a tap within one step held for a step: chainsim.game.trainer.keytiming), and the HUD says so;
input given after it waits behind it, so nothing overtakes what was held (a key's release its press).
Nothing given while compiling is dropped. Without a gate (`chainsim warmup` done, or a script
played) nothing changes.

`KernelWatch` is what a seat does with the gate each frame - the window's and a browser session's
(chainsim.game.server.train_session) alike: hold or pass each input, say on the HUD how far compiling
has got and when the scene is ready, and hand the held input to the App once it is.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import esper

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseMove, Resize
from chainsim.components.resources import PackResource, PendingInput
from chainsim.game.trainer.keytiming import key_times
from chainsim.systems.engine.chainmail_params import order_name
from chainsim.systems.engine.warmup import GEOMETRY, HYBRID, MODELS, MOVING, Compiler, chainmail_group
from chainsim.systems.tissue.deformable import Deformable

#: keys that open or move through pages (no kernel behind them)
PAGE_KEYS = {"f1", "f12"}
#: widgets whose clicks only open pages
PAGE_WIDGETS = {"help", "sign_in"}


def _switches_models(app) -> bool:
    """Whether the scene's layout has the model switch (the m key): then every model is in reach."""
    pack = app.get_resource(PackResource)
    widgets = pack.layout.get("widgets", []) if pack is not None else []
    return any(w.get("name") == "model" for w in widgets)


def needed_groups(app) -> list[str]:
    """The kernel groups the scene of `app` can call: normals, collision and the needle's force always;
    with soft bodies the normals of moving meshes and each body's own model's group (ChainMail's for its
    cascade order and precision, also under a hybrid body that starts with ChainMail); with the model
    switch in the layout every model's. The rest compile after, where nothing waits on them."""
    names = [GEOMETRY]
    every = _switches_models(app)
    with app.active():
        for _ent, d in esper.get_component(Deformable):
            body = d.body.model_body
            # the body's own order, else the material's: the m key reaches ChainMail from every model
            order = getattr(body, "order", None) or d.order
            if every or d.body.model_used == "hybrid":
                names.append(HYBRID)
            chain = every or d.body.model_used == "chainmail" or getattr(body, "start", None) == "chainmail"
            if chain and order is not None:
                names.append(chainmail_group(order_name(order), str(d.dtype)))
            sleeps = bool(getattr(body, "sleep", 0.0))
            if every or d.body.model_used not in ("hybrid", "chainmail") or sleeps:
                names.append(MODELS)
            # after the models' groups: the first two compile side by side, and a model's take longest
            names.append(MOVING)
    return list(dict.fromkeys(names))


class KernelGate:
    """Holds the window's input until the scene's kernel groups are compiled (see the module docstring)."""

    def __init__(self, compiler: Compiler, needed: list[str], scripted: bool = False):
        self.compiler = compiler
        self.scripted = scripted
        self.needed = list(needed)
        self.held: list[tuple[float, object]] = []  # (wall seconds, event)
        self.last: tuple[float, float] | None = None  # the last released event's (wall, simulated) times
        self.said = ""  # the HUD message this gate shows now
        self.open = compiler.ready(self.needed)

    def ready(self) -> bool:
        if not self.open and self.compiler.ready(self.needed):
            self.open = True
        return self.open

    def lets_through(self, ev, hud: HudState, hover: str) -> bool:
        """Whether `ev` may reach the App now."""
        if isinstance(ev, Resize):
            return True
        # once something waits, what follows waits behind it (a release after its press), also when the
        # kernels are ready but the held input has not been released yet (that happens once a frame);
        # the pointer's moves too: a held click lands where the pointer was when it was given
        if self.held:
            return False
        if isinstance(ev, MouseMove) or self.ready():
            return True
        if hud.doc_open or hud.notice:
            return True  # a page or question has the input; its box keeps clicks from the scene
        if isinstance(ev, Key):
            return ev.key in PAGE_KEYS
        return hover in PAGE_WIDGETS or hover.startswith("docs:")

    def hold(self, wall: float, ev) -> None:
        self.held.append((wall, ev))

    def presses(self, events=None) -> int:
        """Key presses and button presses among `events` (default: the held ones)."""
        return sum(bool(getattr(ev, "pressed", False)) for _w, ev in (self.held if events is None else events))

    def stepping(self) -> bool:
        """Whether the scene may step this frame: not while input waits for kernels, nor, when a script
        plays (`scripted`), before they are ready."""
        return self.ready() or not (self.held or self.scripted)

    def release(self, now: float, dt: float) -> list[tuple[float, object]]:
        """The held input (once ready), stamped from simulated time `now` on with its own spacing in whole steps."""
        if not self.ready() or not self.held:
            return []
        w0 = self.held[0][0]
        if self.last is not None:  # input held behind a replay keeps its distance to the replay's last event
            now = max(now, self.last[1] + round((w0 - self.last[0]) / dt) * dt)
        keys: dict[str, tuple[float, float]] = {}
        out = []
        for w, ev in self.held:
            t = now + round((w - w0) / dt) * dt
            # a tap given within one step is held for a step, taps of one key a step apart each
            times = key_times(keys, ev.key, ev.pressed, t, dt) if isinstance(ev, Key) else (t,)
            out += [(at, ev) for at in times]
        self.last = (self.held[-1][0], max(at for at, _ in out))
        self.held = []
        return out

    def text(self) -> str:
        """The HUD's progress line ('' once everything is compiled)."""
        if self.ready():
            return ""  # the other models go on compiling unseen: nothing waits on them
        c = self.compiler
        have = set(c.done)
        done = sum(n in have for n in self.needed)
        lead = f"Your input waits ({self.presses()} presses and clicks): " if self.held else ""
        return (
            f"{lead}preparing the soft-tissue engine (first start only): {done} of {len(self.needed)} kernel "
            f"groups compiled. Sign in and read the help (F1) meanwhile."
        )

    def show(self, hud: HudState) -> None:
        """Put the progress line on the HUD (replacing the last one this gate put there)."""
        text = self.text()
        if text == self.said:
            return
        hud.messages = [(t, s) for t, s in hud.messages if t != self.said]
        if text:
            hud.messages.append((text, None))
        self.said = text


class KernelWatch:
    """One seat's input and HUD while the scene's kernel groups compile (the module docstring).

    `log` gets the lines `chainsim bench startup` times a start by; `on_ready(group)` is told once per
    needed group as it becomes ready (the window switches its normals to the kernel's)."""

    def __init__(
        self,
        compiler: Compiler,
        needed: list[str],
        hud: HudState,
        pending: PendingInput,
        *,
        scripted: bool = False,
        log: Callable[[str], None] = print,
    ) -> None:
        compiler.prefer(needed)
        self.compiler, self.hud, self.pending, self.log = compiler, hud, pending, log
        self.gate = None if compiler.ready(needed) else KernelGate(compiler, needed, scripted=scripted)
        self.said_ready = self.said_all = False
        self.replaying = False  # held input released into the App and not all due yet
        self.said_released = False

    def _replaying(self) -> bool:
        self.replaying = self.replaying and not self.pending.exhausted
        return self.replaying

    def lets_through(self, ev, wall: float, hover: str = "") -> bool:
        """Whether `ev` may go to the App now; when not, it is held in order with `wall`, the seat's clock
        when it was given (its spacing in time is kept when it is released). While released input is
        still being given to the scene, what comes meanwhile is held behind it: stamped now, it would
        wait behind the replay and then arrive all at once, without its own spacing."""
        gate = self.gate
        if gate is None:
            return True
        if not isinstance(ev, Resize) and self._replaying():
            gate.hold(wall, ev)
            return False
        if gate.lets_through(ev, self.hud, hover):
            return True
        gate.hold(wall, ev)
        return False

    def stepping(self) -> bool:
        """Whether the scene may step this frame (not while input waits for its kernels)."""
        return self.gate is None or self.gate.stepping()

    def update(self, now: float, dt: float) -> None:
        """Once a frame: say when the scene and then everything is ready, show the gate's line, and give
        the App the held input once its kernels are there (stamped from simulated time `now`)."""
        gate, compiler = self.gate, self.compiler
        if gate is not None and not self.said_ready and gate.ready():
            self.said_ready = True
            self.log(f"kernels: the scene's ready {time.perf_counter() - compiler.started:.1f} s after start")
            if not gate.held:  # with input held, the "Ready: the N presses ..." line below says it
                self.hud.message("Ready: the soft-tissue engine is prepared; the scene takes your input.", 8.0)
        if not self.said_all and compiler.ready():  # also without a gate: loaded from the cache
            self.said_all = True
            self.log(f"kernels: all compiled {compiler.seconds:.1f} s after start")
        if gate is None:
            return
        gate.show(self.hud)
        if self._replaying():
            return  # what came meanwhile follows once the replay is given (lets_through)
        released = gate.release(now, dt)
        for t_ev, ev in released:
            self.pending.push(t_ev, ev)
        self.replaying = bool(released)
        if released and not self.said_released:  # said, so a trainee who pressed on knows where it went
            self.said_released = True
            n = gate.presses(released)
            self.hud.message(f"Ready: the {n} presses and clicks given while preparing are applied now, in order.", 8.0)
