"""The pyglet window adapter: the pack's layout in a resizable window, fed by the mouse and keyboard.

Only this module (and the GL adapters) import pyglet. Device events become the same input events
scripts use (`chainsim.components.input_events`), stamped with the App's simulated time and queued in PendingInput,
so a window session can be recorded (`--record`) and replayed headless. Each redraw (about 60 per
second where the machine keeps up) runs the whole fixed steps the wall-clock time since the previous
one holds, one App.update each (chainsim.game.trainer.frameloop), and draws through
`chainsim.game.render.render_system` into the window's framebuffer.

HiDPI: layouts, input events and widgets work in window units; the renderer draws at the
framebuffer's resolution (`RenderTarget.scale` = framebuffer pixels per window unit).

Keys: a widget's `key` (pyglet key names, lower case: "t", "left", "space", "f2"; digits "1".."9")
uses that widget (held arrow keys repeat); F1 opens the key page, F12 saves a screenshot
(chainsim-shot-FRAME.png in the current folder). Esc closes an open page (the sign-in page too:
attempts then go to anonymous until Sign in is pressed); with none open it quits, asking first when
the attempt is not saved, and in a study always, saying what is saved (so does the window's close
button). Packs with a `sign_in` button ask for class and name at
start (chainsim.game.trainer.signin) unless --class and --trainee are given or a script is played.
`chainsim protocol --participant NAME` runs a study session in the window (chainsim.game.study.session):
its questionnaires and trial pages take the keyboard while they are shown. `--input SCRIPT` plays a
script, `--exit-after S` closes after S simulated seconds, `--screenshot PNG` saves the last frame
on closing, `--record FILE` saves the session.
"""

from __future__ import annotations

import functools
import importlib
import threading
import time
from pathlib import Path

import pyglet

import chainsim.game.render.render_system as render
from chainsim.components.digest import world_digest
from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, MouseDrag, MouseMove, Resize, Scroll
from chainsim.components.resources import Assessment, Settings
from chainsim.game.records import remote
from chainsim.game.records.store import RecordStore
from chainsim.game.records.store import default_path as default_records_path
from chainsim.game.render.context import window_context
from chainsim.game.trainer import plugins
from chainsim.game.trainer.frameloop import FrameLog
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script, write_recording
from chainsim.game.trainer.options import user_settings
from chainsim.game.trainer.seat import Seat
from chainsim.game.trainer.signin import SignInForm, remember, remembered, status_line
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.warmup import GEOMETRY, HAPTICS, Compiler
from chainsim.systems.motion.input import InputLog

QUIT_QUESTION = (
    "# Quit without saving?\n\nThis attempt is not saved. Press **Esc** again to quit, or any other key to "
    "go back and press **Save attempt** first.\n"
)


def key_name(symbol: int) -> str:
    """pyglet key symbol -> the name used in input events ('T' -> 't', '_1' -> '1', 'LEFT' -> 'left')."""

    name = pyglet.window.key.symbol_string(symbol).lower()
    if len(name) == 2 and name[0] == "_" and name[1].isdigit():
        name = name[1]
    return name


def _button(b) -> str:

    m = pyglet.window.mouse
    if b & m.LEFT:
        return "left"
    if b & m.RIGHT:
        return "right"
    return "middle"


SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast")
FULL_FPS = 60  # redraws a second
#: ... while the scene waits on its kernels (a first start): its picture stands still, and drawing it at
#: the full rate took about 0.8 of a core (software GL, two cores) from the processes compiling them
WAIT_FPS = 15


def _open_window(pyglet, w: int, h: int, caption: str):
    """A GL 3.3 core window; multisampled when the display offers it on a GPU. Software renderers
    (Mesa's llvmpipe) get no multisampling: it multiplies their rasterising time about five-fold
    (`chainsim bench render --pack prp`), which costs more than smooth edges are worth."""
    base = dict(major_version=3, minor_version=3, forward_compatible=True, double_buffer=True, depth_size=24)
    last: Exception | None = None
    w, h = fit_screen(pyglet, w, h)
    # pyglet's hidden shadow window already names the renderer: a software one skips the multisampled
    # window it would close again (a warm start's first picture waited on both)
    soft = any(name in (pyglet.gl.gl_info.get_renderer() or "").lower() for name in SOFTWARE_GL)
    for extra in ({},) if soft else (dict(sample_buffers=1, samples=4), {}):
        try:
            config = pyglet.gl.Config(**base, **extra)
            window = pyglet.window.Window(w, h, caption=caption, resizable=True, config=config)
        except Exception as e:  # no such config on this display: try a plainer one
            last = e
            continue
        renderer = (pyglet.gl.gl_info.get_renderer() or "").lower()
        if extra and any(name in renderer for name in SOFTWARE_GL):
            window.close()
            continue
        return window
    assert last is not None  # the last config tried, the plainest, either made a window or failed
    raise last


def fit_screen(pyglet, w: int, h: int) -> tuple[int, int]:
    """The window size asked for, made no larger than the display's screen (a 1024x768 screen gets a
    1024x768 window, not a 1280x800 one whose controller runs off its edge)."""
    try:
        screen = pyglet.display.get_display().get_default_screen()
        return max(min(w, int(screen.width)), 320), max(min(h, int(screen.height)), 240)
    except Exception:  # no screen to ask (some headless displays): the size asked for
        return w, h


def server_login(values: dict):
    """With --records URL and no token for that server yet: the sign-in form asks for the password and
    signs in through this (the token is kept in the local store, as `chainsim records login` does)."""
    server = values.get("records")
    if not server:
        return None
    with RecordStore(values.get("db") or None) as store:
        if remote.token_for(store, remote.server_url(server)):
            return None

    def login(name: str, password: str) -> None:
        with RecordStore(values.get("db") or None) as store:
            remote.login(store, server, name, password)

    return login


def run_window(args, session=None) -> int:
    """The window on `args.pack`. `session`, when given, is called with the App and returns a study
    session (chainsim.game.study.session) that takes the keyboard while it shows a form and is updated
    once per frame; the window closes when the session has finished."""
    # the kernels compile (or load from numba's cache) in child processes while the window opens and
    # the trainee signs in; input that needs them waits (chainsim.game.trainer.compiling)
    compiler = Compiler(first=[GEOMETRY])
    try:
        return _run_window(args, session, compiler)
    finally:
        compiler.stop()


def _run_window(args, session, compiler: Compiler) -> int:
    script = load_script(args.input) if getattr(args, "input", None) else None
    settings = user_settings(args)  # --db, --class, --trainee for procedures that save attempts
    app = build_app(args.pack, pack_paths=args.pack_path, headless=False, settings=settings)
    if getattr(args, "device", None):
        try:
            plugins.attach_device(app, args.device, realtime=True)  # the servo thread, at 1 kHz beside the frames
        except BaseException:
            app.close()
            raise
    window, ctx, width = _window_for(app, args.pack)
    target = _attach_renderer(app, window, ctx, width)
    ui = WindowSession(app, window, target, compiler, args=args, settings=settings, script=script)
    ui.begin(session)
    for name, handler in ui.handlers().items():  # as @window.event sets them
        window.set_handler(name, handler)
    try:
        pyglet.app.run(1 / FULL_FPS)
    finally:
        ui.frame_log.close()
        app.close()
    return ui.rc


def _window_for(app, pack: str):
    """(window, its moderngl context, its width asked for) for the pack's layout, or a UserError naming
    the command that works without a window (the App is closed then)."""
    w, h = (int(x) for x in app.resource(Settings).get("window_size", [1280, 800]))
    try:
        window = _open_window(pyglet, w, h, f"chainsim - {pack}")
    except Exception as e:
        app.close()
        raise UserError(
            f"cannot open a window on this display ({type(e).__name__}: {e}); "
            f"run headless instead: chainsim run {pack} --headless --steps 600 --out DIR"
        ) from None
    try:
        ctx = window_context()
    except Exception as e:
        window.close()
        app.close()
        raise UserError(
            f"this display has no OpenGL 3.3 ({type(e).__name__}: {e}); "
            f"render off screen instead: chainsim snapshot {pack} --out shot.png"
        ) from None
    return window, ctx, int(window.width)  # the screen may have asked for a smaller window (fit_screen)


def _attach_renderer(app, window, ctx, w: int) -> render.RenderTarget:
    """The renderer drawing into the window's framebuffer, at its resolution (HiDPI: `scale` framebuffer
    pixels per window unit)."""
    fw, fh = window.get_framebuffer_size()
    target = render.RenderTarget(ctx, ctx.screen, fw / max(w, 1), offscreen=False, size=(fw, fh))
    app.insert_resource(target)
    app.add_plugin(render.plugin)
    app.resource(render.Renderer).defer_shots = True  # the X-ray's cue first (FluoroRenderer.__init__)
    if not getattr(window.config, "sample_buffers", 0):
        # without multisampling (software GL) a view's image can be kept and copied while it is unchanged
        app.resource(render.Renderer).cache_views()
    return target


def _load_behind(modules) -> None:
    for name in modules:
        importlib.import_module(name)


@functools.cache
def _arrows() -> tuple[dict[int, str], dict[int, str]]:
    """(arrow key symbols, text-motion codes) -> "left", "right", "up", "down". Built on first use, not
    at import: loading pyglet.window (headless: EGL) leaves an off-screen moderngl context the process
    already draws with failing with GL_INVALID_OPERATION, and the study session imports this module
    beside one."""
    k = pyglet.window.key
    arrows = {k.LEFT: "left", k.RIGHT: "right", k.UP: "up", k.DOWN: "down"}
    motions = {k.MOTION_LEFT: "left", k.MOTION_RIGHT: "right", k.MOTION_UP: "up", k.MOTION_DOWN: "down"}
    return arrows, motions


class WindowSession:
    """One window session: turns the window's events into the App's input events, keeps who has the
    keyboard (a quit question, a study page, the sign-in form, else the controller), and runs the App
    once per redraw."""

    def __init__(self, app, window, target, compiler: Compiler, *, args, settings: dict, script) -> None:
        self.app, self.window, self.target, self.compiler = app, window, target, compiler
        self.args, self.settings = args, settings
        self.rc = 0
        self.last: float | None = None  # wall-clock time of the previous redraw
        self.closing = False
        self.confirm = False  # a quit question is shown
        self.behind = ""  # the page the quit question covers
        self.swallow_text = False  # the key that answered the question types nothing
        self.slow = False  # redrawing at WAIT_FPS
        # the rules every seat follows (held input while compiling, key timing, fixed steps); a
        # force-feedback device's servo runs from the first frame: its kernels first too
        self.seat = Seat(
            app,
            compiler,
            log=lambda s: print(s, flush=True),
            target=target,
            extra_groups=[HAPTICS] if getattr(args, "device", None) else [],
            scripted=bool(script),
        )
        self.pending, self.hud = self.seat.pending, self.seat.hud
        if script:
            self.pending.extend(script)
        self.scripted = bool(script)
        self.values = app.resource(Settings).values
        self.records_path = Path(self.values["db"]).expanduser() if self.values.get("db") else default_records_path()
        if self.seat.has_sign_in:  # only a trainer that saves attempts says who is signed in and where
            self.hud.status = status_line(self.values, self.records_path)
        self.form: SignInForm | None = None
        self.study = None
        self.frame_log = FrameLog(getattr(args, "frame_times", None))

    def begin(self, session) -> None:
        """Start the study session, or ask who is training unless --class and --trainee said so (or a
        script is played)."""
        self.study = session(self.app) if session is not None else None
        if self.study is not None:
            self.study.start()
        elif (
            self.seat.has_sign_in
            and not self.scripted
            and (not (self.values.get("class") and self.values.get("trainee")) or server_login(self.values) is not None)
        ):
            self.open_sign_in()

    def handlers(self) -> dict:
        """The window's event handlers, by event name (pyglet holds bound methods weakly: keep this object)."""
        names = (
            "on_mouse_motion on_mouse_press on_mouse_release on_mouse_drag on_mouse_scroll on_text "
            "on_key_press on_text_motion on_key_release on_resize on_draw on_close"
        )
        return {name: getattr(self, name) for name in names.split()}

    # --- sign-in, sending, leaving

    def open_sign_in(self) -> None:
        given = {k: self.values.get(k) or remembered().get(k, "") for k in ("class", "trainee")}
        self.form = SignInForm(given, self.records_path, login=server_login(self.values))
        self.hud.notice = self.form.markdown()

    def form_changed(self) -> None:
        f = self.form
        if f is None:  # called only while the sign-in page is open
            return
        if f.done:
            self.values["class"], self.values["trainee"] = f.values["class"], f.values["trainee"]
            self.settings["class"], self.settings["trainee"] = f.values["class"], f.values["trainee"]
            remember(f.values)
            self.hud.status = status_line(self.values, self.records_path)
            self.hud.message(f"Signed in as {f.values['trainee']}, class {f.values['class']}.")
            self.hud.notice = ""
            self.form = None
        else:
            self.hud.notice = f.markdown()

    def now(self) -> float:
        return self.app.time.sim_time

    def send(self, ev, t: float | None = None) -> None:
        """Queue a device event for the App, or hold it while the kernels it may need compile (Seat.give)."""
        self.seat.give(ev, t)

    def finish(self) -> None:
        """Save what was asked for, then close (once)."""
        if self.closing:
            return
        self.closing = True
        try:
            self._save_on_close()
        finally:
            # close outside the event dispatch that called us; GL objects go before their context
            def close(_dt):
                self.app.close()
                self.window.close()
                pyglet.app.exit()

            pyglet.clock.schedule_once(close, 0.0)

    def _save_on_close(self) -> None:
        """--screenshot and --record."""
        app, args = self.app, self.args
        if getattr(args, "screenshot", None):
            path = render.screenshot(app, args.screenshot)
            print(f"screenshot: {path}")
        if getattr(args, "record", None):
            log = app.get_resource(InputLog)
            write_recording(
                args.record,
                pack=args.pack,
                scene=app.resource(render.PackResource).scene,
                dt=app.time.dt,
                steps=app.time.tick,
                events=log.items if log else [],
                digest=world_digest(app),
                settings=self.settings or None,
            )
            print(f"recording: {args.record}")

    def unsaved(self) -> bool:
        return bool(self.app.resource(Assessment).values.get("unsaved"))

    def ask_or_quit(self) -> None:
        """Quit, unless something would be lost: then ask (Esc again quits, any other key goes back)."""
        if self.study is not None:
            question = self.study.end_question(self.unsaved())
        else:
            question = QUIT_QUESTION if self.unsaved() else None
        if question is None:
            self.finish()
            return
        self.confirm = True
        self.behind = self.hud.notice  # the page the question covers comes back when the trainee says no
        self.hud.notice = question

    # --- the mouse

    def on_mouse_motion(self, x, y, dx, dy):
        self.send(MouseMove(float(x), float(y)))

    def on_mouse_press(self, x, y, button, modifiers):
        self.send(MouseButton(float(x), float(y), _button(button), True))

    def on_mouse_release(self, x, y, button, modifiers):
        self.send(MouseButton(float(x), float(y), _button(button), False))

    def on_mouse_drag(self, x, y, dx, dy, buttons, modifiers):
        self.send(MouseDrag(float(x), float(y), float(dx), float(dy), _button(buttons)))

    def on_mouse_scroll(self, x, y, scroll_x, scroll_y):
        self.send(Scroll(float(x), float(y), float(scroll_y)))

    # --- the keyboard

    def _page_has_keys(self) -> bool:
        """A study page or the sign-in form takes the keyboard."""
        return self.form is not None or (self.study is not None and self.study.form is not None)

    def on_text(self, text):
        swallow, self.swallow_text = self.swallow_text, False
        if swallow or self.confirm:
            return pyglet.event.EVENT_HANDLED  # the key that answered the question types nothing
        if self.study is not None and self.study.form is not None:
            self.study.text(text)
            return pyglet.event.EVENT_HANDLED
        if self.form is not None:
            self.form.text(text)
            self.form_changed()
            return pyglet.event.EVENT_HANDLED

    def on_key_press(self, symbol, modifiers):
        keys = pyglet.window.key
        if self.confirm and symbol != keys.F12:  # a screenshot leaves the question open
            self._answer_question(symbol)
        elif self.study is not None and self.study.form is not None and symbol != keys.F12:
            # a questionnaire or a study page: the keys are its own (F12 still takes a screenshot)
            if symbol == keys.ESCAPE:
                self.ask_or_quit()  # ending early keeps what was saved, and says so first
            else:
                self.study.key(key_name(symbol))
        elif self.form is not None and symbol != keys.F12:
            # typing a name: no key reaches the controller (F12 still takes a screenshot)
            self._sign_in_key(symbol)
        elif symbol == keys.ESCAPE:
            if self.hud.doc_open:
                self.pending.push(self.now(), Key("escape", True))  # closes the page (the view system)
            else:
                self.ask_or_quit()
        elif symbol == keys.F12:
            path = render.screenshot(self.app, f"chainsim-shot-{self.app.time.frame:06d}.png")
            self.app.resource(HudState).message(f"saved {path}", 3.0)
        elif symbol not in _arrows()[0]:  # arrows arrive through on_text_motion, with key repeat
            self.send(Key(key_name(symbol), True))
        return pyglet.event.EVENT_HANDLED

    def _answer_question(self, symbol) -> None:
        """Esc quits; any other key goes back to the page the question covered."""
        self.confirm = False
        self.hud.notice, self.behind = self.behind, ""
        if symbol == pyglet.window.key.ESCAPE:
            self.finish()
        else:
            self.swallow_text = True

    def _sign_in_key(self, symbol) -> None:
        if symbol == pyglet.window.key.ESCAPE:
            # Esc closes the page, as everywhere; attempts go to anonymous until Sign in is pressed
            self.form = None
            self.hud.notice = ""
            if not self.values.get("trainee"):
                self.hud.message("Not signed in: attempts are saved as anonymous. Press Sign in to sign in.", 8.0)
        elif self.form is not None:  # it is: the key came here because the page is open
            self.form.key(key_name(symbol))
            self.form_changed()

    def on_text_motion(self, motion):
        # held arrow keys repeat, so a dial on an arrow key keeps turning while it is held; not while a
        # form or study page has the keyboard (it took the arrow in on_key_press)
        if self._page_has_keys():
            return pyglet.event.EVENT_HANDLED
        motions = _arrows()[1]
        if motion in motions:
            self.send(Key(motions[motion], True))

    def on_key_release(self, symbol, modifiers):
        if symbol not in (pyglet.window.key.ESCAPE, pyglet.window.key.F12):
            # a key pressed and released within one frame (a quick Shift+R) is held for one step, so the
            # step that sees R also sees Shift down (key_times, in send)
            self.send(Key(key_name(symbol), False))

    # --- the window

    def on_resize(self, width, height):
        fbw, fbh = self.window.get_framebuffer_size()
        self.target.size = (int(fbw), int(fbh))
        self.target.scale = fbw / max(int(width), 1)
        self.send(Resize(max(int(width), 1), max(int(height), 1)))
        return pyglet.event.EVENT_HANDLED

    def _pace(self, waiting: bool) -> None:
        """Redraw at WAIT_FPS while the scene's kernels compile and at FULL_FPS once they are ready."""
        loop = pyglet.app.event_loop
        if waiting == self.slow or not loop.is_running:
            return
        self.slow = waiting
        pyglet.clock.unschedule(loop._redraw_windows)
        pyglet.clock.schedule_interval(loop._redraw_windows, 1.0 / (WAIT_FPS if waiting else FULL_FPS))

    def on_draw(self):
        t = time.perf_counter()  # wall clock paces the window only; the App runs on simulated time
        dt = 0.0 if self.last is None else t - self.last
        self.last = t
        if self.closing:
            return
        # a step draws into the window; with none (input waits for kernels, or no whole step yet) the
        # window shows the same state again
        if not self.seat.advance(dt):
            render.draw(self.app)
        self._pace(self.seat.waiting())
        self.frame_log.add(t, dt, time.perf_counter() - t)
        since = self.seat.first_picture()
        if since is not None:  # chainsim bench startup times a start by these lines
            print(f"window: first picture {since:.1f} s after start", flush=True)
            # what the first picture did not need, loaded behind it: the nearest-point search of a
            # pick (trimesh) and the X-ray image's blur (scipy)
            threading.Thread(target=_load_behind, args=(("trimesh", "scipy.ndimage"),), daemon=True).start()
            if self.seat.kernels.gate is None:
                print("kernels: the scene's ready at the first picture (compiled before)", flush=True)
        if self.seat.sign_in_pressed() and self.form is None and self.study is None:
            self.open_sign_in()
        if self.study is not None:
            self.study.update()
            if self.study.finished:
                self.finish()
        if self.args.exit_after is not None and self.app.time.sim_time >= self.args.exit_after:
            self.finish()

    def on_close(self):
        # the window's close button asks as Esc does; a second close (or Esc) while asked quits
        if self.confirm:
            self.finish()
        else:
            self.ask_or_quit()
        return pyglet.event.EVENT_HANDLED
