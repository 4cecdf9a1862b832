"""One trainee's trainer, run off screen in a process of its own and streamed as pictures (``/train/PACK``).

The records server starts this module as a child process per browser session
(``python -m chainsim.game.server.train_session``, see ``train_routes``). It is the desktop window
(``chainsim.game.trainer.window``) without a display: the same App built by ``build_app``, the same
layout, widgets, help pages and steps, drawn by the same render system into an EGL off-screen
framebuffer (``chainsim.game.render.context``) and paced by the wall clock in whole fixed steps
(``chainsim.game.trainer.frameloop.FixedStepper``), so a browser session replays exactly as a window
session does (thesis 3.3.1: delivery in a web browser; 3.3.4: the linked views and controller).

Protocol on the pipes (the parent is the only peer; it has validated every input already):

- stdin, one JSON object a line: ``{"t": "in", "ev": EVENT, "seq": N}`` an input event in the input
  scripts' vocabulary (``chainsim.components.input_events``) without its time, stamped here with the
  App's simulated time as the window stamps device events; ``{"t": "credit", "n": K}`` K more frames
  may be sent (the page asks for the next frame once it has drawn one, so a slow link never queues
  pictures), with ``"fresh": true`` when a page attached (the picture is sent even if unchanged);
  ``{"t": "reply", ...}`` the answer to a request below. End of input ends the session.
- stdout, records of ``kind`` (1 byte), length (4 bytes, big-endian), payload: ``F`` a frame (the parts
  of the picture that changed since the last frame sent, with the frame number and the last input
  ``seq`` the picture shows: ``chainsim.game.server.frame_tiles``), ``J`` a JSON object: ``ready``,
  ``save`` (the attempt with the recording and pack identity the records server scores it from, the
  same evidence ``chainsim play --records`` uploads), ``list`` (the trainee's saved attempts, for My
  attempts), ``error``.

A frame is encoded and sent only when the page has credit for one and the picture changed; a still
scene costs no bandwidth. Encoding runs on a thread of its own (Pillow lets go of the interpreter while
it encodes), so the App steps and draws the next picture meanwhile. The page's credit comes back when it
has drawn a frame: how long that takes above the quickest return seen is time frames spent queued on
the link or in the browser, and the session lowers the pictures' quality while it grows, raising it
again once it is gone; the credit window covers the link's round trip at the session's frame rate.

The session is ready as soon as its App is built: the scene's numba kernels compile (on a fresh install)
or load from numba's cache in child processes while the page already shows the scene, as at the window
(``chainsim.game.trainer.compiling.KernelWatch``): input that needs them waits and is given in order once
they are there, and the HUD says how far compiling has got.
"""

from __future__ import annotations

import json
import os
import queue
import struct
import sys
import threading
import time
from typing import Any

#: what a frame may be encoded as: Pillow's format name and the page's MIME type
FORMATS = {"jpeg": ("JPEG", "image/jpeg"), "webp": ("WEBP", "image/webp")}
DEFAULT_FORMAT = "jpeg"
DEFAULT_QUALITY = 70
#: the most pictures a second a session draws and sends (a window draws about 60; the stream is the cost)
DEFAULT_FPS = 40.0
#: frames the page may have in flight at once (sent, not yet drawn): at least MIN_CREDIT, and as many as
#: the quickest round trip seen takes at the session's frame rate, up to MAX_CREDIT
MIN_CREDIT, MAX_CREDIT = 2, 6
#: the quality falls by QUALITY_STEP (not under MIN_QUALITY) while frames wait longer than QUEUED_MS beyond
#: the quickest round trip, and climbs back while they wait under CLEAR_MS
MIN_QUALITY, QUALITY_STEP, QUEUED_MS, CLEAR_MS = 30, 10, 60.0, 25.0
SAVE_REPLY_S = 30.0
#: after this many loops without input or a changed picture, the picture is drawn every STILL_EVERY-th loop
STILL_FRAMES, STILL_EVERY = 15, 6


class Channel:
    """The pipes to the parent: framed records out (one writer lock), JSON lines in (a reader thread)."""

    def __init__(self, out, inp) -> None:
        self.out = out
        self.lock = threading.Lock()
        self.inputs: queue.Queue = queue.Queue()
        self.replies: queue.Queue = queue.Queue()
        self.closed = threading.Event()
        self.credit = 0  # the parent gives credit once the page is told the picture's size
        self.fresh = False
        self._credit_lock = threading.Lock()
        self.window = MIN_CREDIT  # the credit the page may hold (see MIN_CREDIT)
        self.period = 1.0 / DEFAULT_FPS
        self._sent: list[float] = []  # when each frame not yet drawn by the page was sent
        self.base_ms = float("inf")  # the quickest send-to-drawn time seen (the link's round trip)
        self.queued_ms = 0.0  # how much longer than that frames take now (smoothed)
        threading.Thread(target=self._read, args=(inp,), daemon=True, name="train-input").start()

    def _read(self, inp) -> None:
        try:
            for line in inp:
                msg = json.loads(line)
                kind = msg.get("t")
                if kind == "in":
                    self.inputs.put(msg)
                elif kind == "credit":
                    self._credited(int(msg.get("n", 1)), bool(msg.get("fresh")))
                elif kind == "reply":
                    self.replies.put(msg)
        finally:
            self.closed.set()
            self.replies.put(None)

    def _credited(self, n: int, fresh: bool) -> None:
        with self._credit_lock:
            if fresh:  # a page (re)attached: it needs the picture even if unchanged; nothing is in flight
                self.fresh, self._sent = True, []
            now = time.perf_counter()
            for _ in range(min(n, len(self._sent))):
                took = 1e3 * (now - self._sent.pop(0))
                self.base_ms = min(self.base_ms, took)
                self.queued_ms = 0.8 * self.queued_ms + 0.2 * (took - self.base_ms)
            if self.base_ms < float("inf"):
                self.window = max(MIN_CREDIT, min(MAX_CREDIT, 1 + int(self.base_ms / 1e3 / self.period + 0.999)))
            # the page hands back one credit per frame drawn; what may be in flight is the window
            self.credit = max(self.window - len(self._sent), 0)

    def take_credit(self) -> bool:
        with self._credit_lock:
            if self.credit <= 0:
                return False
            self.credit -= 1
            self._sent.append(time.perf_counter())
            return True

    def send(self, kind: bytes, payload: bytes) -> None:
        with self.lock:
            self.out.write(kind + struct.pack(">I", len(payload)) + payload)
            self.out.flush()

    def send_json(self, obj: dict) -> None:
        self.send(b"J", json.dumps(obj, allow_nan=False, default=str).encode())

    def ask(self, obj: dict, timeout: float = SAVE_REPLY_S) -> dict:
        """Send a request and wait for the parent's reply (requests come one at a time: the App's thread)."""
        self.send_json(obj)
        try:
            reply = self.replies.get(timeout=timeout)
        except queue.Empty:
            reply = None
        if reply is None:
            from chainsim.systems.engine.errors import UserError  # noqa: PLC0415

            raise UserError("the records server did not answer; the attempt is not saved")
        return reply


class Encoder:
    """Encodes and sends one frame at a time on a thread of its own (the module docstring): the changed
    parts of each picture against the last one sent, at a quality that follows the link."""

    def __init__(self, channel: Channel, fmt: str, quality: int) -> None:
        self.channel, self.fmt = channel, fmt
        self.best = self.quality = int(quality)
        self.last = None  # the last picture sent (rows top first), or None: the next is sent whole
        self.idle = threading.Event()
        self.idle.set()
        self.jobs: queue.Queue = queue.Queue()
        threading.Thread(target=self._run, daemon=True, name="train-encode").start()

    def submit(self, number: int, seq: int, picture) -> None:
        self.idle.clear()
        self.jobs.put((number, seq, picture))

    def close(self) -> None:
        self.jobs.put(None)

    def _adapt(self) -> None:
        queued = self.channel.queued_ms
        if queued > QUEUED_MS:
            self.quality = max(MIN_QUALITY, self.quality - QUALITY_STEP)
        elif queued < CLEAR_MS:
            self.quality = min(self.best, self.quality + QUALITY_STEP // 2)

    def _run(self) -> None:
        from chainsim.game.server.frame_tiles import changed_runs, pack_frame  # noqa: PLC0415

        while True:
            job = self.jobs.get()
            if job is None:
                return
            number, seq, picture = job
            try:
                self._adapt()
                runs = changed_runs(self.last, picture)
                self.channel.send(b"F", pack_frame(number, seq, picture, runs, self.fmt, self.quality))
                self.last = picture
            except (OSError, ValueError):  # the parent is gone: the App's loop ends on the closed input
                pass
            finally:
                self.idle.set()


def server_records(channel: Channel, app, pack, settings: dict):
    """Records that file each save through the records server's parent process, with the session's
    recording and the pack's identity (``chainsim.game.trainer.headless.attempt_evidence``): the server
    checks and queues it as it does every upload, and scores it by replaying the recording."""
    from chainsim.components.resources import Records  # noqa: PLC0415
    from chainsim.game.records.validate import clean_attempt, to_json  # noqa: PLC0415
    from chainsim.game.trainer.headless import attempt_evidence  # noqa: PLC0415
    from chainsim.systems.engine.errors import UserError  # noqa: PLC0415

    filed: dict[int, tuple[str, str, int | None]] = {}

    def save_attempt(class_name: str, trainee: str, record: dict) -> int:
        evidence = attempt_evidence(app, pack, settings)
        # checked and made JSON here, as the simulator's outbox does before it uploads
        record = json.loads(to_json(clean_attempt(record)))
        reply = channel.ask({"t": "save", "record": record, **evidence})
        if not reply.get("ok"):
            raise UserError(str(reply.get("error") or "the records server refused the attempt"))
        upload = int(reply["upload"])
        filed[upload] = (reply.get("class_name", class_name), reply.get("trainee", trainee), reply.get("number"))
        return upload

    def list_attempts(class_name: str, trainee: str) -> list[dict]:
        reply = channel.ask({"t": "list"})
        if not reply.get("ok"):
            raise UserError(str(reply.get("error") or "the records server did not list the attempts"))
        return list(reply.get("attempts") or [])

    return Records(save_attempt, list_attempts, "records server", filed_as=filed.get)


def study_session(app, cfg: dict):
    """The study session of ``cfg["study"]`` on the App, started: the trials of the trainee's allocation
    with their aids, practice first (chainsim.game.study.session, as at the window, without the questionnaires),
    each Save filed through the server with ``details.protocol``."""
    from pathlib import Path  # noqa: PLC0415

    from chainsim.game.study.session import StudySession  # noqa: PLC0415

    spec = cfg["study"]
    proto = {**spec["design"], "path": Path(f"{spec['study']}.toml"), "title": ""}
    session = StudySession(
        app, proto, cfg["trainee"], cfg["class"], None, allocation=spec["allocation"], served=spec["attempts"]
    )
    session.start()
    return session


class Session:
    """The App of one trainee drawn off screen: input in, pictures out (see the module docstring)."""

    def __init__(self, cfg: dict, channel: Channel) -> None:
        import chainsim.game.render.render_system as render  # noqa: PLC0415 - imported in the session process only
        from chainsim.components.resources import Settings  # noqa: PLC0415
        from chainsim.game.packs import pack as packs  # noqa: PLC0415
        from chainsim.game.render.context import egl_context, offscreen_framebuffer  # noqa: PLC0415
        from chainsim.game.trainer.compiling import needed_groups  # noqa: PLC0415
        from chainsim.game.trainer.headless import app_for_pack  # noqa: PLC0415
        from chainsim.game.trainer.seat import Seat  # noqa: PLC0415
        from chainsim.systems.engine.warmup import GEOMETRY, Compiler  # noqa: PLC0415

        self.render = render
        self.channel = channel
        self.fmt = cfg.get("format", DEFAULT_FORMAT)
        self.quality = int(cfg.get("quality", DEFAULT_QUALITY))
        self.period = 1.0 / float(cfg.get("fps", DEFAULT_FPS))
        channel.period = self.period
        self.encoder = Encoder(channel, self.fmt, self.quality)
        self.settings = {"class": cfg["class"], "trainee": cfg["trainee"]}
        pack = packs.load(cfg["root"], cfg.get("pack_paths", []))
        # the window's App (headless=False: the window's settings), saving through the records server
        app = app_for_pack(pack, None, settings=self.settings, headless=False, save="")
        self.app = app
        app.insert_resource(server_records(channel, app, pack, self.settings))
        w, h = (int(x) for x in app.resource(Settings).get("window_size", [1280, 800]))
        self.size = (w, h)
        ctx = egl_context()
        # one sample: multisampling multiplies a software rasteriser's time (see game/trainer/window.py)
        app.insert_resource(render.RenderTarget(ctx, offscreen_framebuffer(ctx, (w, h)), 1.0, samples=1))
        app.add_plugin(render.plugin)
        app.resource(render.Renderer).cache_views()  # most frames repeat most views
        # as at the window: the picture comes at once and the scene's kernels compile (or load from
        # numba's cache) in child processes meanwhile; input that needs them waits, and the HUD says so
        self.compiler = Compiler(first=[GEOMETRY], groups=needed_groups(app))
        self.seat = Seat(app, self.compiler, log=self._log)
        self.hud = self.seat.hud
        values = app.resource(Settings).values
        self.who = f"Signed in: {values.get('trainee')}, class {values.get('class')}. Records: this server"
        if self.seat.has_sign_in:
            self.hud.status = self.who
        # a study's trials (``cfg["study"]``, from train_routes.study_seat): its pages take the keys they show
        self.study = study_session(app, cfg) if cfg.get("study") else None
        self.last_seq = 0
        self.frame_no = 0
        self.last_raw: bytes | None = None
        self.still = 0  # loops since the input or picture last changed

    @staticmethod
    def _log(line: str) -> None:
        print(f"train session: {line}", file=sys.stderr, flush=True)  # the records server's log

    def apply(self, msg: dict) -> None:
        """One input from the page, as the window turns a device event into an App event."""
        from chainsim.components.input_events import Key, event_from_dict  # noqa: PLC0415

        ev = event_from_dict(dict(msg["ev"]), "input")
        self.last_seq = max(self.last_seq, int(msg.get("seq") or 0))
        if isinstance(ev, Key) and self.study is not None and self.study.form is not None:
            if ev.pressed:  # a study page (what comes next, the last page) takes Enter, as at the window
                self.study.key(ev.key)
            return
        if isinstance(ev, Key) and ev.key == "escape" and ev.pressed and not self.hud.doc_open:
            self.hud.message("Close the tab to leave; press Save attempt first to keep this attempt.", 6.0)
            return
        self.seat.give(ev)  # as the window gives a device event: held while kernels compile, keys timed

    def frame(self):
        """Draw now; the picture (H, W, 3 uint8, rows top first), or None when it is the one sent last."""
        import numpy as np  # noqa: PLC0415

        render = self.render
        render.draw(self.app)
        target = self.app.resource(render.RenderTarget)
        raw = target.fbo.read(components=3, alignment=1)
        if raw == self.last_raw:
            return None
        self.last_raw = raw
        w, h = target.fbo.size
        return np.ascontiguousarray(np.frombuffer(raw, np.uint8).reshape(h, w, 3)[::-1])  # GL: bottom row first

    def run(self) -> None:
        channel = self.channel
        channel.send_json({"t": "ready", "size": list(self.size), "format": FORMATS[self.fmt][1]})
        last = due = time.perf_counter()
        while not channel.closed.is_set():
            start = time.perf_counter()
            had_input = False
            while True:
                try:
                    self.apply(channel.inputs.get_nowait())
                except queue.Empty:
                    break
                had_input = True
            self.step(start - last)
            last = start
            if self.study is not None:
                self.study.update()
            if self.seat.sign_in_pressed():  # the page's sign-in is the records server's: say who is signed in
                self.hud.message(self.who.replace("Signed in:", "You are signed in as"), 6.0)
            # a still scene is looked at a few times a second only; input brings back the full rate
            self.still = 0 if had_input else self.still + 1
            encoder = self.encoder
            if channel.fresh and encoder.idle.is_set():
                channel.fresh, self.last_raw, self.still, encoder.last = False, None, 0, None
            # a picture is drawn only when the encoder can take it: the steps go on meanwhile
            ready = encoder.idle.is_set() and channel.credit > 0
            if ready and (self.still < STILL_FRAMES or self.still % STILL_EVERY == 0):
                picture = self.frame()
                if picture is not None:
                    self.still = 0
                    if channel.take_credit():
                        self.frame_no += 1
                        encoder.submit(self.frame_no, self.last_seq, picture)
                        self._first_picture()
            # a fixed cadence (each loop due a period after the last was due), so the wake-up's own delay
            # does not lower the rate; a loop that overran starts the next at once and the cadence anew
            due = max(due + self.period, time.perf_counter() - self.period)
            spare = due - time.perf_counter()
            if spare > 0:
                channel.closed.wait(spare)

    def step(self, dt: float) -> None:
        """The App's steps for `dt` wall seconds, unless input waits for kernels (the scene then stands)."""
        self.seat.advance(dt)

    def _first_picture(self) -> None:
        """Once the first picture is on its way: the groups the scene waits on compile at normal priority."""
        since = self.seat.first_picture()
        if since is not None:
            self._log(f"first picture {since:.1f} s after the compiler started")

    def close(self) -> None:
        self.compiler.stop()
        self.encoder.close()
        self.app.close()


def main(argv: list[str] | None = None) -> int:
    """``python -m chainsim.game.server.train_session CONFIG_JSON``: run one session on the pipes."""
    argv = sys.argv[1:] if argv is None else argv
    cfg: dict[str, Any] = json.loads(argv[0])
    os.environ.setdefault("PYGLET_HEADLESS", "true")
    # the protocol owns stdout: anything the App prints goes to stderr (the server's log)
    out = os.fdopen(os.dup(1), "wb", buffering=0)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    channel = Channel(out, sys.stdin.buffer)
    try:
        session = Session(cfg, channel)
    except Exception as exc:  # a pack that does not start: one line for the page
        channel.send_json({"t": "error", "message": f"the trainer did not start: {type(exc).__name__}: {exc}"})
        return 2
    try:
        session.run()
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
