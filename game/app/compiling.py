"""The window while the kernels compile: which kernel groups a scene needs, input held until they are
ready, and the progress line on the HUD.

On a fresh install the numba kernels take minutes to compile (chainsim.systems.engine.warmup). The window
opens at once and they compile in child processes (`Compiler`) while the trainee signs in and reads
the help. Until the groups the scene needs are compiled (`needed_groups`: the normals and collision
kernels every scene draws and steps with, and the kernels of each soft body's own model), `KernelGate`
lets through what needs no kernel - the pointer moving, a resize, the sign-in form, F1 and the help
pages and their buttons - and holds everything else in order: the scene is not stepped while input
is held, the window keeps drawing and answering, and the HUD says that the input waits (how many
presses and clicks) and how far compiling has got. When the groups are ready the held input goes to
the scene with its own spacing in time, as if it had just been given, and the HUD says so; input
given after it waits behind it, so nothing overtakes what was held (a key's release its press).
Nothing given while compiling is dropped. Without a gate (`chainsim warmup` done, or a script
played) nothing changes.
"""

from __future__ import annotations

import esper

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseMove, Resize
from chainsim.components.resources import PackResource
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
            body = getattr(d, "body", None)
            # the body's own order, else the material's: the m key reaches ChainMail from every model
            order = getattr(body, "order", None) or d.order
            if every or d.model_used == "hybrid":
                names.append(HYBRID)
            chain = every or d.model_used == "chainmail" or getattr(body, "start", None) == "chainmail"
            if chain and order is not None:
                names.append(chainmail_group(order_name(order), str(d.dtype)))
            if every or d.model_used not in ("hybrid", "chainmail") or getattr(body, "sleep", 0.0):
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
        self.said = ""  # the HUD message this gate shows now
        self.open = compiler.ready(self.needed)

    def ready(self) -> bool:
        if not self.open and self.compiler.ready(self.needed):
            self.open = True
        return self.open

    def lets_through(self, ev, hud: HudState, hover: str) -> bool:
        """Whether `ev` may reach the App now."""
        if isinstance(ev, (MouseMove, Resize)):
            return True
        # once something waits, what follows waits behind it (a release after its press), also when the
        # kernels are ready but the held input has not been released yet (that happens once a frame)
        if self.held:
            return False
        if self.ready():
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
        out = [(now + round((w - w0) / dt) * dt, ev) for w, ev in self.held]
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
