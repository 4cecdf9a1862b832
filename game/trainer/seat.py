"""A trainee's seat, whatever shows it: the one core the window and the browser trainer both drive.

Between a person's input and the App a seat follows the same rules wherever it is shown
(thesis 3.3.1: the trainer at the desk or in a web browser): input that needs the scene's kernels waits
while they compile and is then given in order (`compiling.KernelWatch`), a key tapped within one step is
held for a step (`keytiming`), the App advances in whole fixed steps by the wall clock
(`frameloop.FixedStepper`, so a session replays exactly), the GPU normals kernel is taken up once it is
compiled, and once the first picture is out the groups the scene waits on compile at normal priority.
The layout's Sign in button and the status line are read here too. The adapters add only what their
medium has: pyglet's events, pages that take the keyboard and the quit question at the window
(`chainsim.game.trainer.window`); the pipes and the pictures' encoding in a browser tab
(`chainsim.game.server.train_session`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, Widget
from chainsim.components.resources import PackResource, PendingInput
from chainsim.game.render import meshbuf
from chainsim.game.trainer.compiling import KernelWatch, needed_groups
from chainsim.game.trainer.frameloop import FixedStepper
from chainsim.game.trainer.keytiming import key_times
from chainsim.systems.engine.warmup import GEOMETRY, Compiler
from chainsim.systems.view.cameras import ViewState


class Seat:
    """The rules of one seat over one App (see the module). `target` is the render target the App's
    steps draw into (None: the adapter draws); `extra_groups` are kernel groups the seat itself needs
    from the first frame (a force-feedback device's servo); `log` takes the seat's lines."""

    def __init__(
        self,
        app,
        compiler: Compiler,
        *,
        log: Callable[[str], None],
        target=None,
        extra_groups: Sequence[str] = (),
        scripted: bool = False,
    ) -> None:
        self.app, self.compiler, self.log = app, compiler, log
        self.pending: PendingInput = app.resource(PendingInput)
        self.hud: HudState = app.resource(HudState)
        self.kernels = KernelWatch(
            compiler, [*needed_groups(app), *extra_groups], self.hud, self.pending, scripted=scripted, log=log
        )
        self.view_state: ViewState = app.resource(ViewState)
        self.stepper = FixedStepper(app, target)
        self.keys: dict[str, tuple[float, float]] = {}  # key -> (when its last press lands, when it is free)
        self.widget_events = app.events.reader(Widget)
        self.layout_names = {w["name"] for w in app.resource(PackResource).layout.get("widgets", [])}
        self.pictured = False
        # until the normals kernel is compiled the first uploads take numpy's normals (the same vectors)
        meshbuf.KERNEL_NORMALS = compiler.ready([GEOMETRY])

    @property
    def has_sign_in(self) -> bool:
        """Whether the layout has a Sign in button: only a trainer that saves attempts says who is signed in."""
        return "sign_in" in self.layout_names

    def waiting(self) -> bool:
        """Whether the scene still waits for kernels it needs (the seat then redraws less often)."""
        gate = self.kernels.gate
        return gate is not None and not gate.ready()

    def give(self, ev, t: float | None = None) -> None:
        """A person's input for the App at simulated time `t` (default: now), or held while the kernels it
        may need compile; a key's press and release land by the key-timing rule."""
        if not self.kernels.lets_through(ev, time.perf_counter(), self.view_state.hover):
            return  # held until the kernels are ready, then given in order (KernelWatch.update)
        now = self.app.time.sim_time if t is None else t
        if isinstance(ev, Key):
            for at in key_times(self.keys, ev.key, ev.pressed, now, self.app.time.dt):
                self.pending.push(at, ev)
            return
        self.pending.push(now, ev)

    def advance(self, wall_dt: float) -> int | None:
        """The App's whole steps for `wall_dt` wall seconds: how many ran, or None while input waits for
        kernels (the scene then stands still, and the adapter draws the same state again)."""
        self.kernels.update(self.app.time.sim_time, self.app.time.dt)
        if not meshbuf.KERNEL_NORMALS and self.compiler.ready([GEOMETRY]):
            meshbuf.KERNEL_NORMALS = True
        if not self.kernels.stepping():
            self.stepper.carry = 0.0
            return None
        return self.stepper.advance(wall_dt)

    def first_picture(self) -> float | None:
        """Call when a picture is out: the first time, the groups the scene waits on compile at normal
        priority from now on, and the seconds since the compiler started are returned (None later)."""
        if self.pictured:
            return None
        self.pictured = True
        gate = self.kernels.gate
        if gate is not None:
            self.compiler.hurry(gate.needed)
        return time.perf_counter() - self.compiler.started

    def sign_in_pressed(self) -> bool:
        """Whether the layout's Sign in button was pressed since the last call."""
        return any(ev.name == "sign_in" for ev in self.widget_events.read())
