"""The pyglet window adapter: feeds device events into the App and runs it at the display rate.

Only this module (and the GL adapters) import pyglet. Device events become the same input events
scripts use, stamped with the App's simulated time, so a window session can be recorded and
replayed headless.
"""

from __future__ import annotations

import sys

from game.errors import UserError


def run_window(args) -> int:
    try:
        import pyglet
    except Exception as e:  # pragma: no cover - pyglet is a dependency
        raise UserError(f"cannot start the window system ({e})") from None
    from game.headless import build_app
    from game.input_events import Key, MouseButton, MouseDrag, MouseMove, Resize, Scroll
    from game.resources import PendingInput

    app = build_app(args.pack, pack_paths=args.pack_path, headless=False)
    w, h = (int(x) for x in app.resource(__import__("game.resources", fromlist=["Settings"]).Settings).get("window_size", [1280, 800]))
    try:
        window = pyglet.window.Window(w, h, caption=f"chainsim - {args.pack}", resizable=True)
    except Exception as e:
        app.close()
        raise UserError(f"cannot open a window on this display ({type(e).__name__}: {e}); "
                        f"run headless instead: chainsim run {args.pack} --headless --steps 600 --out DIR") from None
    pending: PendingInput = app.resource(PendingInput)

    def now() -> float:
        return app.time.sim_time

    @window.event
    def on_mouse_motion(x, y, dx, dy):
        pending.push(now(), MouseMove(float(x), float(y)))

    @window.event
    def on_mouse_press(x, y, button, modifiers):
        pending.push(now(), MouseButton(float(x), float(y), _button(button), True))

    @window.event
    def on_mouse_release(x, y, button, modifiers):
        pending.push(now(), MouseButton(float(x), float(y), _button(button), False))

    @window.event
    def on_mouse_drag(x, y, dx, dy, buttons, modifiers):
        pending.push(now(), MouseDrag(float(x), float(y), float(dx), float(dy), _button(buttons)))

    @window.event
    def on_mouse_scroll(x, y, scroll_x, scroll_y):
        pending.push(now(), Scroll(float(x), float(y), float(scroll_y)))

    @window.event
    def on_key_press(symbol, modifiers):
        if symbol == pyglet.window.key.ESCAPE:
            window.close()
            return pyglet.event.EVENT_HANDLED
        pending.push(now(), Key(pyglet.window.key.symbol_string(symbol).lower(), True))

    @window.event
    def on_key_release(symbol, modifiers):
        pending.push(now(), Key(pyglet.window.key.symbol_string(symbol).lower(), False))

    @window.event
    def on_resize(width, height):
        pending.push(now(), Resize(int(width), int(height)))

    def tick(dt):
        app.update(min(dt, 0.1))
        if args.exit_after is not None and app.time.sim_time >= args.exit_after:
            window.close()

    pyglet.clock.schedule_interval(tick, 1 / 60)
    try:
        pyglet.app.run()
    finally:
        app.close()
    return 0


def _button(b) -> str:
    import pyglet

    m = pyglet.window.mouse
    if b & m.LEFT:
        return "left"
    if b & m.RIGHT:
        return "right"
    return "middle"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(1)
