"""The pyglet window adapter: the pack's layout in a resizable window, fed by the mouse and keyboard.

Only this module (and the GL adapters) import pyglet. Device events become the same input events
scripts use (`chainsim.components.input_events`), stamped with the App's simulated time and queued in PendingInput,
so a window session can be recorded (`--record`) and replayed headless. Each redraw (about 60 per
second where the machine keeps up) runs the whole fixed steps the wall-clock time since the previous
one holds, one App.update each (chainsim.game.ui.frameloop), and draws through
`chainsim.game.gl.render_system` into the window's framebuffer.

HiDPI: layouts, input events and widgets work in window units; the renderer draws at the
framebuffer's resolution (`RenderTarget.scale` = framebuffer pixels per window unit).

Keys: a widget's `key` (pyglet key names, lower case: "t", "left", "space", "f2"; digits "1".."9")
uses that widget (held arrow keys repeat); F1 opens the key page, F12 saves a screenshot
(chainsim-shot-FRAME.png in the current folder). Esc closes an open page (the sign-in page too:
attempts then go to anonymous until Sign in is pressed); with none open it quits, asking first when
the attempt is not saved, and in a study always, saying what is saved (so does the window's close
button). Packs with a `sign_in` button ask for class and name at
start (chainsim.game.ui.signin) unless --class and --trainee are given or a script is played.
`chainsim protocol --participant NAME` runs a study session in the window (chainsim.game.ui.study):
its questionnaires and trial pages take the keyboard while they are shown. `--input SCRIPT` plays a
script, `--exit-after S` closes after S simulated seconds, `--screenshot PNG` saves the last frame
on closing, `--record FILE` saves the session.
"""

from __future__ import annotations

import time
from pathlib import Path

import pyglet

import chainsim.game.gl.render_system as render
from chainsim.components.digest import world_digest
from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, MouseDrag, MouseMove, Resize, Scroll, Widget
from chainsim.components.resources import Assessment, PendingInput, Settings
from chainsim.game.app.compiling import KernelGate, needed_groups
from chainsim.game.app.headless import build_app
from chainsim.game.app.inputscript import load_script, write_recording
from chainsim.game.app.options import user_settings
from chainsim.game.gl import meshbuf
from chainsim.game.gl.context import window_context
from chainsim.game.records import remote
from chainsim.game.records.store import RecordStore
from chainsim.game.records.store import default_path as default_records_path
from chainsim.game.ui.frameloop import FixedStepper, FrameLog
from chainsim.game.ui.signin import SignInForm, remember, remembered, status_line
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.warmup import GEOMETRY, Compiler
from chainsim.systems.motion.input import InputLog
from chainsim.systems.view.cameras import ViewState

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


def _open_window(pyglet, w: int, h: int, caption: str):
    """A GL 3.3 core window; multisampled when the display offers it on a GPU. Software renderers
    (Mesa's llvmpipe) get no multisampling: it multiplies their rasterising time about five-fold
    (`chainsim bench render --pack prp`), which costs more than smooth edges are worth."""
    base = dict(major_version=3, minor_version=3, forward_compatible=True, double_buffer=True, depth_size=24)
    last = None
    for extra in (dict(sample_buffers=1, samples=4), {}):
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
    raise last


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
    session (chainsim.game.ui.study) that takes the keyboard while it shows a form and is updated
    once per frame; the window closes when the session has finished."""
    # the kernels compile (or load from numba's cache) in child processes while the window opens and
    # the trainee signs in; input that needs them waits (chainsim.game.app.compiling)
    compiler = Compiler(first=[GEOMETRY])
    try:
        return _run_window(args, session, compiler)
    finally:
        compiler.stop()


def _run_window(args, session, compiler: Compiler) -> int:
    script = load_script(args.input) if getattr(args, "input", None) else None
    settings = user_settings(args)  # --db, --class, --trainee for procedures that save attempts
    app = build_app(args.pack, pack_paths=args.pack_path, headless=False, settings=settings)
    w, h = (int(x) for x in app.resource(Settings).get("window_size", [1280, 800]))
    try:
        window = _open_window(pyglet, w, h, f"chainsim - {args.pack}")
    except Exception as e:
        app.close()
        raise UserError(
            f"cannot open a window on this display ({type(e).__name__}: {e}); "
            f"run headless instead: chainsim run {args.pack} --headless --steps 600 --out DIR"
        ) from None
    try:
        ctx = window_context()
    except Exception as e:
        window.close()
        app.close()
        raise UserError(
            f"this display has no OpenGL 3.3 ({type(e).__name__}: {e}); "
            f"render off screen instead: chainsim snapshot {args.pack} --out shot.png"
        ) from None
    fw, fh = window.get_framebuffer_size()
    target = render.RenderTarget(ctx, ctx.screen, fw / max(w, 1), offscreen=False, size=(fw, fh))
    app.insert_resource(target)
    app.add_plugin(render.plugin)
    if not getattr(window.config, "sample_buffers", 0):
        # without multisampling (software GL) a view's image can be kept and copied while it is unchanged
        app.resource(render.Renderer).cache_views()
    pending: PendingInput = app.resource(PendingInput)
    needed = needed_groups(app)
    compiler.prefer(needed)
    gate = None if compiler.ready(needed) else KernelGate(compiler, needed, scripted=bool(script))
    # until the normals kernel is compiled the first uploads take numpy's normals (the same vectors)
    meshbuf.KERNEL_NORMALS = compiler.ready([GEOMETRY])
    view_state: ViewState = app.resource(ViewState)
    if script:
        pending.extend(script)
    state = {"last": None, "closing": False, "rc": 0, "confirm": False}
    hud: HudState = app.resource(HudState)
    values = app.resource(Settings).values
    records_path = Path(values["db"]).expanduser() if values.get("db") else default_records_path()
    widget_events = app.events.reader(Widget)
    layout_names = {w["name"] for w in app.resource(render.PackResource).layout.get("widgets", [])}
    if "sign_in" in layout_names:  # only a trainer that saves attempts says who is signed in and where
        hud.status = status_line(values, records_path)
    form: dict = {"open": None}

    def open_sign_in() -> None:
        given = {k: values.get(k) or remembered().get(k, "") for k in ("class", "trainee")}
        form["open"] = SignInForm(given, records_path, login=server_login(values))
        hud.notice = form["open"].markdown()

    def form_changed() -> None:
        f = form["open"]
        if f.done:
            values["class"], values["trainee"] = f.values["class"], f.values["trainee"]
            settings["class"], settings["trainee"] = f.values["class"], f.values["trainee"]
            remember(f.values)
            hud.status = status_line(values, records_path)
            hud.message(f"Signed in as {f.values['trainee']}, class {f.values['class']}.")
            hud.notice = ""
            form["open"] = None
        else:
            hud.notice = f.markdown()

    study = session(app) if session is not None else None
    if study is not None:
        study.start()
    # the trainer asks who is training, unless --class and --trainee said so (or a study names them)
    elif (
        "sign_in" in layout_names
        and not script
        and (not (values.get("class") and values.get("trainee")) or server_login(values) is not None)
    ):
        open_sign_in()

    def now() -> float:
        return app.time.sim_time

    def send(ev, t: float | None = None) -> None:
        """Queue a device event for the App, or hold it while the kernels it may need compile."""
        if gate is not None and not gate.lets_through(ev, hud, view_state.hover):
            gate.hold(time.perf_counter(), ev)
            return
        pending.push(now() if t is None else t, ev)

    def finish() -> None:
        """Save what was asked for, then close (once)."""
        if state["closing"]:
            return
        state["closing"] = True
        try:
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
                    settings=settings or None,
                )
                print(f"recording: {args.record}")
        finally:
            # close outside the event dispatch that called us; GL objects go before their context
            def close(_dt):
                app.close()
                window.close()
                pyglet.app.exit()

            pyglet.clock.schedule_once(close, 0.0)

    @window.event
    def on_mouse_motion(x, y, dx, dy):
        send(MouseMove(float(x), float(y)))

    @window.event
    def on_mouse_press(x, y, button, modifiers):
        send(MouseButton(float(x), float(y), _button(button), True))

    @window.event
    def on_mouse_release(x, y, button, modifiers):
        send(MouseButton(float(x), float(y), _button(button), False))

    @window.event
    def on_mouse_drag(x, y, dx, dy, buttons, modifiers):
        send(MouseDrag(float(x), float(y), float(dx), float(dy), _button(buttons)))

    @window.event
    def on_mouse_scroll(x, y, scroll_x, scroll_y):
        send(Scroll(float(x), float(y), float(scroll_y)))

    def unsaved() -> bool:
        return bool(app.resource(Assessment).values.get("unsaved"))

    def ask_or_quit() -> None:
        """Quit, unless something would be lost: then ask (Esc again quits, any other key goes back)."""
        question = study.end_question(unsaved()) if study is not None else (QUIT_QUESTION if unsaved() else None)
        if question is None:
            finish()
            return
        state["confirm"] = True
        state["behind"] = hud.notice  # the page the question covers comes back when the trainee says no
        hud.notice = question

    @window.event
    def on_text(text):
        if state.pop("swallow_text", False) or state["confirm"]:
            return pyglet.event.EVENT_HANDLED  # the key that answered the question types nothing
        if study is not None and study.form is not None:
            study.text(text)
            return pyglet.event.EVENT_HANDLED
        if form["open"] is not None:
            form["open"].text(text)
            form_changed()
            return pyglet.event.EVENT_HANDLED

    @window.event
    def on_key_press(symbol, modifiers):
        if state["confirm"] and symbol != pyglet.window.key.F12:  # a screenshot leaves the question open
            state["confirm"] = False
            hud.notice = state.pop("behind", "")
            if symbol == pyglet.window.key.ESCAPE:
                finish()
            else:
                state["swallow_text"] = True
            return pyglet.event.EVENT_HANDLED
        if study is not None and study.form is not None and symbol != pyglet.window.key.F12:
            # a questionnaire or a study page: the keys are its own (F12 still takes a screenshot)
            if symbol == pyglet.window.key.ESCAPE:
                ask_or_quit()  # ending early keeps what was saved, and says so first
            else:
                study.key(key_name(symbol))
            return pyglet.event.EVENT_HANDLED
        if form["open"] is not None and symbol != pyglet.window.key.F12:
            # typing a name: no key reaches the controller (F12 still takes a screenshot)
            if symbol == pyglet.window.key.ESCAPE:
                # Esc closes the page, as everywhere; attempts go to anonymous until Sign in is pressed
                form["open"] = None
                hud.notice = ""
                if not values.get("trainee"):
                    hud.message("Not signed in: attempts are saved as anonymous. Press Sign in to sign in.", 8.0)
            else:
                form["open"].key(key_name(symbol))
                form_changed()
            return pyglet.event.EVENT_HANDLED
        if symbol == pyglet.window.key.ESCAPE:
            if hud.doc_open:
                pending.push(now(), Key("escape", True))  # closes the page (the view system)
            else:
                ask_or_quit()
            return pyglet.event.EVENT_HANDLED
        if symbol == pyglet.window.key.F12:
            path = render.screenshot(app, f"chainsim-shot-{app.time.frame:06d}.png")
            app.resource(HudState).message(f"saved {path}", 3.0)
            return pyglet.event.EVENT_HANDLED
        if symbol in ARROWS:
            return pyglet.event.EVENT_HANDLED  # arrives through on_text_motion, with key repeat
        pressed_at[key_name(symbol)] = now()
        send(Key(key_name(symbol), True))
        return pyglet.event.EVENT_HANDLED

    # when a key goes down at simulated time t
    pressed_at: dict[str, float] = {}

    ARROWS = {
        pyglet.window.key.LEFT: "left",
        pyglet.window.key.RIGHT: "right",
        pyglet.window.key.UP: "up",
        pyglet.window.key.DOWN: "down",
    }
    MOTIONS = {
        pyglet.window.key.MOTION_LEFT: "left",
        pyglet.window.key.MOTION_RIGHT: "right",
        pyglet.window.key.MOTION_UP: "up",
        pyglet.window.key.MOTION_DOWN: "down",
    }

    @window.event
    def on_text_motion(motion):
        # held arrow keys repeat, so a dial on an arrow key keeps turning while it is held; not while a
        # form or study page has the keyboard (it took the arrow in on_key_press)
        if form["open"] is not None or (study is not None and study.form is not None):
            return pyglet.event.EVENT_HANDLED
        if motion in MOTIONS:
            send(Key(MOTIONS[motion], True))

    @window.event
    def on_key_release(symbol, modifiers):
        if symbol not in (pyglet.window.key.ESCAPE, pyglet.window.key.F12):
            name, t = key_name(symbol), now()
            # a key pressed and released within one frame (a quick Shift+R) is held for one step, so the
            # step that sees R also sees Shift down; otherwise both would be up before anything read them
            if pressed_at.pop(name, None) == t:
                t += app.time.dt
            send(Key(name, False), t)

    @window.event
    def on_resize(width, height):
        fbw, fbh = window.get_framebuffer_size()
        target.size = (int(fbw), int(fbh))
        target.scale = fbw / max(int(width), 1)
        send(Resize(max(int(width), 1), max(int(height), 1)))
        return pyglet.event.EVENT_HANDLED

    stepper = FixedStepper(app, target)

    frame_log = FrameLog(getattr(args, "frame_times", None))

    @window.event
    def on_draw():
        t = time.perf_counter()  # wall clock paces the window only; the App runs on simulated time
        dt = 0.0 if state["last"] is None else t - state["last"]
        state["last"] = t
        if state["closing"]:
            return
        if gate is not None:
            if not state.get("said_ready") and gate.ready():
                state["said_ready"] = True
                print(
                    f"kernels: the scene's ready {time.perf_counter() - compiler.started:.1f} s after start", flush=True
                )
            if not state.get("said_all") and compiler.ready():
                state["said_all"] = True
                print(f"kernels: all compiled {compiler.seconds:.1f} s after start", flush=True)
            gate.show(hud)
            if not meshbuf.KERNEL_NORMALS and compiler.ready([GEOMETRY]):
                meshbuf.KERNEL_NORMALS = True
            for t_ev, ev in gate.release(now(), app.time.dt):
                pending.push(t_ev, ev)
        if gate is not None and not gate.stepping():
            stepper.carry = 0.0
            render.draw(app)  # input waits for kernels: the scene stands still, the window still draws
        elif stepper.advance(dt) == 0:
            render.draw(app)  # no whole step yet: show the same state again
        frame_log.add(t, dt, time.perf_counter() - t)
        for ev in widget_events.read():
            if ev.name == "sign_in" and form["open"] is None and study is None:
                open_sign_in()
        if study is not None:
            study.update()
            if study.finished:
                finish()
        if args.exit_after is not None and app.time.sim_time >= args.exit_after:
            finish()

    @window.event
    def on_close():
        # the window's close button asks as Esc does; a second close (or Esc) while asked quits
        if state["confirm"]:
            finish()
        else:
            ask_or_quit()
        return pyglet.event.EVENT_HANDLED

    try:
        pyglet.app.run(1 / 60)
    finally:
        frame_log.close()
        app.close()
    return state["rc"]
