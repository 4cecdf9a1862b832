"""The trainer in a browser tab: ``/train/PACK`` and its WebSocket, one process per trainee.

    GET /train/{pack}      the page (signed-in trainees only): a canvas, the stream's state, a link back
    WS  /train/{pack}/ws   pictures out (binary), input in (JSON text), on the same origin and TLS

With ``?study=STUDY`` (on both) the seat runs that study's trials for the signed-in trainee, who must be
in its register (chainsim.game.study.register): the pages and the aids of each trial in the order of
their allocation, practice trials first, as ``chainsim protocol`` runs them at the window
(chainsim.game.study.session), each Save filed as a witnessed attempt with ``details.protocol``; a reload
continues after the last trial on this server.

The thesis wants the trainer delivered in a web browser with nothing to install (3.3.1). The server
runs the trainer for the trainee: ``chainsim.game.server.train_session`` in a child process per
trainee (the App, drawn off screen, pictures encoded as JPEG), and this module relays its pictures
to the page and the page's mouse, wheel and keyboard to it. Because the server simulates the
attempt, a Save files it through the same path as every upload (``api.file_under``,
``scoring.check_upload``, the scoring queue): under the signed-in trainee, with the session's
recording and the pack's identity, marked witnessed (the server ran it: stored as the session
computed it, whatever the class requires).

Sessions: one per trainee account (a second tab takes the session over; another account never
reaches it: sessions are keyed by the account of the session cookie). At most ``seats`` processes
run at once ($CHAINSIM_TRAIN_SEATS); past that the page says all seats are taken (503). A session
whose page went away is kept ``grace_s`` ($CHAINSIM_TRAIN_GRACE_S) for a reload to resume it (the
``ready`` message then says ``resumed`` and the session's age, and the page says so with a button to
start afresh: the socket opened with ``?fresh=1`` ends the old session first), then its process is
killed; one without input for ``idle_s`` ($CHAINSIM_TRAIN_IDLE_S) is ended, and every session ends
``max_s`` after it was ready (``serve --train-max-minutes``, $CHAINSIM_TRAIN_MAX_S), input or not: a
page that keeps sending input must not hold a seat for ever.

Input: each message is a JSON object of at most ``MAX_MESSAGE_BYTES``, one of the device events of
``chainsim.components.input_events`` (mouse_move, mouse_button, mouse_drag, scroll, key) with
coordinates inside the window, a known key name and an optional ``seq``, or ``{"type": "ack"}``
(a frame drawn: send the next). At most ``RATE`` messages a second (burst ``BURST``). Anything else
closes the socket with a 44xx code and a one-line reason naming what is wrong; nothing reaches the
App unchecked. Each such close also holds the account back: its next session may start only after a
back-off (``backoff_s``, $CHAINSIM_TRAIN_BACKOFF_S, doubling with every refused close up to
``BACKOFF_MAX_S``, forgotten after a session that ended without one), refused before a process is
started, so a script sending bad input cannot make the server start one process (some 440 MiB) per
message. The socket is refused from another site's page (Origin) like the dashboard's forms.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore
from chainsim.game.server import api, scoring
from chainsim.game.server import dashboard as views
from chainsim.game.server.auth import HTTPError, session
from chainsim.game.study import register
from chainsim.systems.engine.errors import UserError

logger = logging.getLogger(__name__)

SEATS_ENV, IDLE_ENV, GRACE_ENV = "CHAINSIM_TRAIN_SEATS", "CHAINSIM_TRAIN_IDLE_S", "CHAINSIM_TRAIN_GRACE_S"
MAX_ENV, BACKOFF_ENV = "CHAINSIM_TRAIN_MAX_S", "CHAINSIM_TRAIN_BACKOFF_S"
FORMAT_ENV, QUALITY_ENV = "CHAINSIM_TRAIN_FORMAT", "CHAINSIM_TRAIN_QUALITY"
#: sessions at once: each holds about one core while it draws (docs/records-server.md, cost per seat)
DEFAULT_SEATS = 2
DEFAULT_IDLE_S = 900.0
DEFAULT_GRACE_S = 60.0
#: the longest session: an afternoon's practice, then the seat goes to the next trainee
DEFAULT_MAX_S = 7200.0
#: the first wait after a refused input message; each further refusal doubles it, up to BACKOFF_MAX_S
DEFAULT_BACKOFF_S, BACKOFF_MAX_S = 5.0, 300.0
RECHECK_S = 30.0  # how often a running session's sign-in is checked again
START_TIMEOUT_S = 120.0  # a cold numba cache compiles the kernels once
MAX_MESSAGE_BYTES = 512
RATE, BURST = 240.0, 480.0
MAX_SCROLL = 50.0

#: the page's script, same origin only; pictures arrive over the socket and are drawn from blobs
PAGE_CSP = (
    "default-src 'self'; img-src 'self' blob:; style-src 'self'; script-src 'self'; connect-src 'self'; "
    "frame-ancestors 'none'; form-action 'self'; base-uri 'none'"
)

#: key names the page may send (pyglet's names, as widgets' ``key`` and the App's keys use them)
KEY_NAMES = frozenset(
    [chr(c) for c in range(ord("a"), ord("z") + 1)]
    + [str(d) for d in range(10)]
    + [f"f{k}" for k in range(1, 13)]
    + "left right up down space escape home end pageup pagedown return tab backspace delete insert".split()
    + "lshift rshift lctrl rctrl lalt ralt minus equal comma period slash semicolon apostrophe".split()
    + "bracketleft bracketright backslash grave".split()
)

#: message type -> (its fields besides type and seq, which are coordinates)
FIELDS = {
    "mouse_move": {"x", "y"},
    "mouse_button": {"x", "y", "button", "pressed"},
    "mouse_drag": {"x", "y", "dx", "dy", "button"},
    "scroll": {"x", "y", "dy"},
    "key": {"key", "pressed"},
}

# close codes (4000-4999 are the application's): the page shows the reason
BAD_MESSAGE, NOT_SIGNED_IN, FORBIDDEN, NO_PACK, TOO_FAST, IDLE, SEATS_TAKEN, TAKEN_OVER, ENDED = (
    4400,
    4401,
    4403,
    4404,
    4429,
    4408,
    4503,
    4409,
    4500,
)
#: the session reached its longest length; a session start refused while the account is held back
#: (429's "slow down", as for input sent too fast)
TOO_LONG, HELD_BACK = 4410, 4429


class BadMessage(Exception):
    """An input message the server refuses; its text is the close reason."""


def check_message(text: Any, size: tuple[int, int]) -> dict | None:
    """The checked input message as the session takes it (``{"t": "in", "ev", "seq"}``), ``None`` for an
    ack; BadMessage naming what is wrong otherwise."""
    if not isinstance(text, str):
        raise BadMessage("input messages are JSON text, not binary")
    if len(text.encode("utf-8")) > MAX_MESSAGE_BYTES:
        raise BadMessage(f"input message over {MAX_MESSAGE_BYTES} bytes")
    try:
        msg = json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError):
        raise BadMessage("input message is not JSON") from None
    if not isinstance(msg, dict):
        raise BadMessage("input message must be a JSON object with a 'type'")
    kind = msg.get("type")
    if kind == "ack":
        if set(msg) != {"type"}:
            raise BadMessage("an ack has no other fields")
        return None
    if kind not in FIELDS:
        raise BadMessage(f"unknown input type {str(kind)[:20]!r}; expected ack, {', '.join(FIELDS)}")
    extra = set(msg) - FIELDS[kind] - {"type", "seq"}
    missing = FIELDS[kind] - set(msg)
    if extra or missing:
        what = f"unknown field(s) {', '.join(sorted(extra))[:40]}" if extra else f"missing {', '.join(sorted(missing))}"
        raise BadMessage(f"{kind}: {what}")
    seq = msg.get("seq", 0)
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq < 2**31:
        raise BadMessage(f"{kind}: 'seq' must be a whole number from 0 to 2^31 - 1")
    w, h = size
    for name, lo, hi in (("x", 0, w), ("y", 0, h), ("dx", -w, w), ("dy", -h, h)):
        if name not in msg:
            continue
        if kind == "scroll" and name == "dy":
            lo, hi = -MAX_SCROLL, MAX_SCROLL
        v = msg[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise BadMessage(f"{kind}: '{name}' must be a number from {lo:g} to {hi:g}")
    if "button" in msg and msg["button"] not in ("left", "middle", "right"):
        raise BadMessage(f"{kind}: 'button' must be left, middle or right")
    if "pressed" in msg and not isinstance(msg["pressed"], bool):
        raise BadMessage(f"{kind}: 'pressed' must be true or false")
    if "key" in msg and msg["key"] not in KEY_NAMES:
        raise BadMessage(f"key: unknown key name {str(msg['key'])[:16]!r}")
    ev = {k: (float(v) if k in ("x", "y", "dx", "dy") else v) for k, v in msg.items() if k not in ("type", "seq")}
    return {"t": "in", "ev": {"kind": kind, **ev}, "seq": seq}


def _no_constant(name: str) -> Any:
    raise ValueError(name)


class Bucket:
    """Token bucket: ``RATE`` messages a second, ``BURST`` at once."""

    def __init__(self, rate: float = RATE, burst: float = BURST, clock=time.monotonic) -> None:
        self.rate, self.burst, self.clock = rate, burst, clock
        self.tokens, self.at = burst, clock()

    def take(self) -> bool:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


@dataclass
class Seat:
    """One trainee's running session: its process, the page attached to it (or None) and its clocks."""

    user: accounts.User
    pack: str
    proc: asyncio.subprocess.Process
    size: tuple[int, int] = (1280, 800)
    mime: str = "image/jpeg"
    socket: WebSocket | None = None
    last_input: float = field(default_factory=time.monotonic)
    detached_at: float | None = None
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    error: str = ""
    tasks: list = field(default_factory=list)
    frames: int = 0
    ready_at: float | None = None  # when the trainer was ready: its length counts from here
    refused: bool = False  # ended for a message broke the rules: no reset of the account's back-off
    resumed: bool = False  # this page took over a session that was running (a reload, another tab)
    study: str = ""  # the study whose trials the seat runs (``?study=``), or "" for free practice


class Trainer:
    """The sessions of one server (``app.state.trainer``): seats, processes, relaying, saving."""

    def __init__(
        self,
        seats: int,
        idle_s: float,
        grace_s: float,
        fmt: str = "jpeg",
        quality: int = 70,
        max_s: float = DEFAULT_MAX_S,
        backoff_s: float = DEFAULT_BACKOFF_S,
    ) -> None:
        self.seats = seats
        self.idle_s = idle_s
        self.grace_s = grace_s
        self.fmt = fmt
        self.quality = quality
        self.max_s = max_s
        self.backoff_s = backoff_s
        self.running: dict[int, Seat] = {}  # account id -> its session
        self.held: dict[int, tuple[float, float]] = {}  # account id -> (no start before, the next wait)
        self.lock = asyncio.Lock()

    def hold_back(self, seat: Seat) -> float:
        """The session broke a rule of the input: its account may start no session for a while (doubling
        with each refusal). The wait, in seconds."""
        seat.refused = True
        _, wait = self.held.get(seat.user.id, (0.0, self.backoff_s))
        self.held[seat.user.id] = (time.monotonic() + wait, min(2.0 * wait, max(BACKOFF_MAX_S, self.backoff_s)))
        return wait

    def held_back_s(self, user: accounts.User) -> float:
        """Seconds before this account may start a session again (0: now)."""
        until, _ = self.held.get(user.id, (0.0, 0.0))
        return max(0.0, until - time.monotonic())

    def full_for(self, user: accounts.User) -> bool:
        return user.id not in self.running and len(self.running) >= self.seats

    async def start(self, app, user: accounts.User, pack: str, info: dict, study: dict | None = None) -> Seat:
        cfg = {
            "study": study,
            "root": info["root"],
            "pack_paths": app.state.packs.pack_paths,
            "class": user.classes[0],
            "trainee": user.trainee,
            "format": self.fmt,
            "quality": self.quality,
        }
        env = dict(os.environ, PYGLET_HEADLESS="true")
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "chainsim.game.server.train_session",
            json.dumps(cfg),
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            env=env,
            limit=1 << 24,
        )
        seat = Seat(user, pack, proc, study=(study or {}).get("study", ""))
        self.running[user.id] = seat
        seat.tasks.append(asyncio.create_task(self._pump(app, seat)))
        seat.tasks.append(asyncio.create_task(self._watch(seat)))
        logger.info(
            "train: %s started %s (pid %d, %d of %d seats)", user.name, pack, proc.pid, len(self.running), self.seats
        )
        return seat

    async def end(self, seat: Seat, why: str) -> None:
        """Kill the session's process and free its seat; a session that ended without breaking a rule
        clears its account's back-off."""
        if self.running.get(seat.user.id) is seat:
            del self.running[seat.user.id]
        if not seat.refused:
            self.held.pop(seat.user.id, None)
        if seat.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                seat.proc.kill()
            await seat.proc.wait()
        logger.info("train: %s's session ended (%s)", seat.user.name, why)
        for task in seat.tasks:
            if task is not asyncio.current_task():
                task.cancel()

    async def send_child(self, seat: Seat, msg: dict) -> None:
        if seat.proc.stdin is None or seat.proc.returncode is not None:
            return
        seat.proc.stdin.write(json.dumps(msg).encode() + b"\n")
        with contextlib.suppress(ConnectionError):
            await seat.proc.stdin.drain()

    async def _pump(self, app, seat: Seat) -> None:
        """The child's output: pictures to the page attached, requests served, until it exits."""
        out = seat.proc.stdout
        assert out is not None
        try:
            while True:
                head = await out.readexactly(5)
                payload = await out.readexactly(int.from_bytes(head[1:], "big"))
                if head[:1] == b"F":
                    ws = seat.socket
                    seat.frames += 1
                    if ws is not None:
                        try:
                            await ws.send_bytes(payload)
                        except (WebSocketDisconnect, RuntimeError, OSError):
                            pass
                    continue
                msg = json.loads(payload)
                kind = msg.get("t")
                if kind == "ready":
                    seat.ready_at = time.monotonic()
                    seat.size = (int(msg["size"][0]), int(msg["size"][1]))
                    seat.mime = msg.get("format", seat.mime)
                    seat.ready.set()
                elif kind == "error":
                    seat.error = str(msg.get("message", "the trainer stopped"))
                elif kind == "save":
                    reply = await self._save(app, seat, msg)
                    await self.send_child(seat, {"t": "reply", **reply})
                elif kind == "list":
                    reply = await self._list(app, seat)
                    await self.send_child(seat, {"t": "reply", **reply})
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            if not seat.error and not seat.ready.is_set():
                seat.error = "the trainer stopped before it was ready"
            seat.ready.set()
            if self.running.get(seat.user.id) is seat:
                ws = seat.socket
                if ws is not None:
                    with contextlib.suppress(Exception):
                        await ws.close(ENDED, (seat.error or "the trainer stopped")[:120])
                await self.end(seat, seat.error or "process ended")

    async def _save(self, app, seat: Seat, msg: dict) -> dict:
        """A Save in the session: the upload path of ``POST /api/attempts`` for the signed-in trainee."""
        body = dict(msg.get("record") or {})
        body["recording"], body["pack_identity"] = msg.get("recording"), msg.get("pack_identity")
        storage = app.state.storage
        try:
            digest = scoring.body_hash(body)
            class_name, trainee = api.file_under(seat.user, body)
            checked = await run_in_threadpool(scoring.check_upload, app.state.packs, body)
            # the server ran this session: the attempt is witnessed, whatever the class requires
            row, created = await storage.run(
                api.queue_upload, seat.user, class_name, trainee, checked, None, digest, True
            )
            if created:
                app.state.scorer.wake()
            answer = await storage.run(api.acknowledgement, row)
        except HTTPError as exc:
            return {"ok": False, "error": exc.message}
        except UserError as exc:
            return {"ok": False, "error": f"the records server refused the attempt: {exc}"}
        except Exception as exc:  # the database gone: the trainee sees one line, the log the rest
            logger.warning("train: saving %s's attempt failed", seat.user.name, exc_info=True)
            return {"ok": False, "error": f"the records server could not save the attempt ({type(exc).__name__})"}
        logger.info("train: %s saved an attempt (upload %s)", seat.user.name, answer["upload"])
        return {"ok": True, **{k: answer[k] for k in ("upload", "class_name", "trainee", "number")}}

    async def _list(self, app, seat: Seat) -> dict:
        try:
            rows = await app.state.storage.run(api.visible_attempts, seat.user, None, None)
        except Exception as exc:
            return {"ok": False, "error": f"the records server could not list the attempts ({type(exc).__name__})"}
        return {"ok": True, "attempts": json.loads(json.dumps(rows, default=str))}

    async def _watch(self, seat: Seat) -> None:
        """End a session whose page is gone for ``grace_s``, that had no input for ``idle_s``, that ran
        ``max_s`` since it was ready (input or not), or whose sign-in ended (signed out, password
        changed, expired: checked every ``RECHECK_S``)."""
        checked = time.monotonic()
        while True:
            await asyncio.sleep(1.0)
            now = time.monotonic()
            ws = seat.socket
            if ws is not None and now - checked > RECHECK_S:
                checked = now
                try:
                    found = await session(ws)
                except Exception:  # the database busy: the next check decides
                    found = seat.user, ""
                if found is None or found[0].id != seat.user.id:
                    seat.socket = None
                    with contextlib.suppress(Exception):
                        await ws.close(NOT_SIGNED_IN, "signed out; sign in and open the page again")
                    await self.end(seat, "signed out")
                    return
            if seat.socket is None and seat.detached_at is not None and now - seat.detached_at > self.grace_s:
                await self.end(seat, f"page gone for {self.grace_s:g} s")
                return
            if seat.ready_at is not None and now - seat.ready_at > self.max_s:
                ws, seat.socket = seat.socket, None
                if ws is not None:
                    with contextlib.suppress(Exception):
                        await ws.close(
                            TOO_LONG,
                            f"ended after {_duration(self.max_s)}, the longest a session runs here; "
                            "reload to start a new one",
                        )
                await self.end(seat, f"longest session, {_duration(self.max_s)}, reached")
                return
            if seat.socket is not None and now - seat.last_input > self.idle_s:
                ws, seat.socket = seat.socket, None
                with contextlib.suppress(Exception):
                    await ws.close(
                        IDLE, f"ended after {self.idle_s / 60:g} minutes without input; reload to start again"
                    )
                await self.end(seat, "idle")
                return


def _duration(seconds: float) -> str:
    """``90 minutes``, or ``4 s`` for a length under a minute (the short ones tests set)."""
    return f"{seconds / 60:g} minutes" if seconds >= 60 else f"{seconds:g} s"


def _env_number(name: str, default: float, kind=float, lo: float = 0.0):
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = kind(raw)
    except ValueError:
        raise UserError(f"${name} must be a number, got {raw!r}") from None
    if not lo <= value < 1e7:
        raise UserError(f"${name} must be from {lo:g} up, got {raw!r}")
    return value


def trainer_from_env(max_s: float | None = None) -> Trainer:
    """The sessions' settings from the environment ($CHAINSIM_TRAIN_*); ``max_s`` (``serve
    --train-max-minutes``), when given, over $CHAINSIM_TRAIN_MAX_S."""
    fmt = os.environ.get(FORMAT_ENV, "").strip().lower() or "jpeg"
    if fmt not in ("jpeg", "webp"):
        raise UserError(f"${FORMAT_ENV} must be jpeg or webp, got {fmt!r}")
    quality = _env_number(QUALITY_ENV, 70, int, 1)
    if quality > 100:
        raise UserError(f"${QUALITY_ENV} must be from 1 to 100, got {quality}")
    return Trainer(
        seats=_env_number(SEATS_ENV, DEFAULT_SEATS, int, 1),
        idle_s=_env_number(IDLE_ENV, DEFAULT_IDLE_S, float, 1.0),
        grace_s=_env_number(GRACE_ENV, DEFAULT_GRACE_S, float, 0.0),
        fmt=fmt,
        quality=quality,
        max_s=max_s if max_s is not None else _env_number(MAX_ENV, DEFAULT_MAX_S, float, 1.0),
        backoff_s=_env_number(BACKOFF_ENV, DEFAULT_BACKOFF_S, float, 0.1),
    )


# -- routes -----------------------------------------------------------------------------------


def _trainee(user: accounts.User) -> None:
    if user.is_trainer:
        raise HTTPError(403, "the trainer in the browser is for trainee accounts; sign in as a trainee")
    if user.trainee_id is None:
        raise HTTPError(403, "this trainee account has no trainee record; ask your trainer")


def _pack_info(request, name: str) -> dict:
    info = None
    if len(name) <= 64 and name.replace("-", "").replace("_", "").isalnum():
        info = request.app.state.packs.info(name)
    if info is None:
        raise HTTPError(404, f"no pack named {name[:64]!r} on this server")
    return info


def study_seat(store: RecordStore, user: accounts.User, study: str, pack: str) -> dict:
    """What a seat needs to run ``study``'s trials for the signed-in trainee: the study's design, their
    allocation in its register and their trials already on this server; HTTPError when they cannot."""
    value = register.design_of(store, study)
    if value is None:
        raise HTTPError(404, f"study {study[:64]!r} has no design on this server; ask your trainer")
    if value["pack"] != pack:
        raise HTTPError(404, f"study {study!r} runs pack {value['pack']!r}, not {pack!r}")
    if user.trainee is None:  # a trainee account without its trainee (train_page checked it already: _trainee)
        raise HTTPError(403, "this trainee account has no trainee record; ask your trainer")
    entry = register.lookup(store, study, user.trainee)
    if entry is None or entry["class_name"] != user.classes[0]:
        raise HTTPError(403, f"{user.trainee} is not in the register of study {study!r}; ask your trainer")
    try:
        attempts = store.list_attempts(user.classes[0], user.trainee)
    except UserError:  # no attempts yet
        attempts = []
    done = []
    for a in attempts:
        trial = (a.get("details") or {}).get("protocol") or {}
        if trial.get("study") == study and not a.get("retracted_at"):
            done.append({"id": a["id"], "details": {"protocol": trial}})
    allocation = {"by": "records server", "design": register.DESIGN}
    allocation.update({k: entry[k] for k in ("slot", "group", "year_of_training", "procedures_performed")})
    return {"study": study, "design": value, "allocation": allocation, "attempts": done}


async def train_page(request: Request) -> Response:
    user, csrf = await views.page_user(request)
    _trainee(user)
    pack = request.path_params["pack"]
    await run_in_threadpool(_pack_info, request, pack)
    study = request.query_params.get("study", "")
    if study:  # refused here, with the page's reason, rather than by the socket
        await request.app.state.storage.run(study_seat, user, study, pack)
    trainer: Trainer = request.app.state.trainer
    if trainer.full_for(user):
        page = views.render("train_full.html", 503, user=user, csrf=csrf, pack=pack, seats=trainer.seats)
        page.headers["Retry-After"] = "60"
        return page
    page = views.render("train.html", user=user, csrf=csrf, pack=pack, study=study)
    page.headers["Content-Security-Policy"] = PAGE_CSP
    return page


def _same_origin(ws: WebSocket) -> bool:
    origin = ws.headers.get("origin")
    if not origin:
        return False  # a browser always says; a page elsewhere must not borrow the cookie
    scheme, _, rest = origin.partition("://")
    return rest == ws.headers.get("host", "") and scheme in ("http", "https")


async def train_socket(ws: WebSocket) -> None:
    await ws.accept()
    admitted = await _admit(ws)
    if admitted is None:
        return
    trainer: Trainer = ws.app.state.trainer
    seat = await _claim(ws, trainer, *admitted)
    if seat is None or not await _started(ws, trainer, seat):
        return
    await _relay(ws, trainer, seat)


async def _admit(ws: WebSocket) -> tuple[accounts.User, str, dict] | None:
    """(account, pack, pack info) of a socket from this site, a signed-in trainee and a pack the server
    has; None once the socket is closed saying why not."""
    if not _same_origin(ws):
        await ws.close(FORBIDDEN, "opened from another site; refused")
        return None
    found = await session(ws)  # the dashboard's session cookie: HttpOnly, never seen by the script
    if found is None:
        await ws.close(NOT_SIGNED_IN, "not signed in; sign in and open the page again")
        return None
    user = found[0]
    try:
        _trainee(user)
        pack = ws.path_params["pack"]
        info = await run_in_threadpool(_pack_info, ws, pack)
    except HTTPError as exc:
        await ws.close(NO_PACK if exc.status == 404 else FORBIDDEN, exc.message[:120])
        return None
    return user, pack, info


async def _claim(ws: WebSocket, trainer: Trainer, user: accounts.User, pack: str, info: dict) -> Seat | None:
    """The trainee's running session (this page takes it over from another tab), else a new one when
    the account is not held back and a seat is free; None once the socket is closed saying why not."""
    async with trainer.lock:  # one start at a time: two pages at once never pass the seat count together
        wait = trainer.held_back_s(user)
        if wait > 0:  # refused before any process starts: that is what the back-off saves
            await ws.close(
                HELD_BACK, f"the last session sent input the server refuses; start again in {math.ceil(wait)} s"
            )
            return None
        seat = trainer.running.get(user.id)
        study = ws.query_params.get("study", "")
        if seat is not None and (seat.pack, seat.study) != (pack, study):
            await trainer.end(seat, "the trainee opened another pack or study")
            seat = None
        if seat is not None and ws.query_params.get("fresh") == "1":  # the page's "Start afresh"
            await trainer.end(seat, "the trainee started afresh")
            seat = None
        if seat is not None:
            seat.resumed = True  # the page says so, with a way to start afresh
        if seat is None:
            if trainer.full_for(user):
                await ws.close(SEATS_TAKEN, f"all {trainer.seats} seats are taken; try again in a few minutes")
                return None
            try:
                spec = await ws.app.state.storage.run(study_seat, user, study, pack) if study else None
            except HTTPError as exc:
                await ws.close(FORBIDDEN, exc.message[:120])
                return None
            seat = await trainer.start(ws.app, user, pack, info, spec)
        elif seat.socket is not None:  # the same trainee in a second tab: this one takes the session over
            old, seat.socket = seat.socket, None
            with contextlib.suppress(Exception):
                await old.close(TAKEN_OVER, "this session was opened in another tab")
        seat.socket, seat.detached_at = ws, None
    return seat


async def _started(ws: WebSocket, trainer: Trainer, seat: Seat) -> bool:
    """Tell the page the trainer is starting, then ready (its picture's size); False when it did not
    start or the page went away meanwhile."""
    try:
        await ws.send_json({"type": "starting"})
        try:
            await asyncio.wait_for(seat.ready.wait(), START_TIMEOUT_S)
        except TimeoutError:
            seat.error = f"the trainer did not start in {START_TIMEOUT_S:g} s"
        if seat.error:
            await ws.close(ENDED, seat.error[:120])
            await trainer.end(seat, seat.error)
            return False
        seat.last_input = time.monotonic()
        age = 0.0 if seat.ready_at is None else time.monotonic() - seat.ready_at
        await ws.send_json(
            {"type": "ready", "width": seat.size[0], "height": seat.size[1], "format": seat.mime}
            | ({"resumed": True, "age_s": round(age)} if seat.resumed else {})
        )
    except WebSocketDisconnect:  # the page went away while the trainer started: a reload may come back
        if seat.socket is ws:
            seat.socket, seat.detached_at = None, time.monotonic()
        return False
    return True


async def _relay(ws: WebSocket, trainer: Trainer, seat: Seat) -> None:
    """The page's input to the session, checked, until the page goes or breaks a rule (which ends the
    session at once, its seat too, and holds the account back)."""
    await trainer.send_child(seat, {"t": "credit", "n": 2, "fresh": True})
    bucket = Bucket()
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            if not bucket.take():
                wait = trainer.hold_back(seat)
                await ws.close(TOO_FAST, f"too many input messages: at most {RATE:g} a second")
                await trainer.end(seat, f"too many input messages; no new session for {wait:g} s")
                break
            try:
                checked = check_message(message.get("text", message.get("bytes")), seat.size)
            except BadMessage as exc:
                wait = trainer.hold_back(seat)
                await ws.close(BAD_MESSAGE, str(exc)[:120])
                await trainer.end(seat, f"bad input message: {exc}; no new session for {wait:g} s")
                break
            if checked is None:
                await trainer.send_child(seat, {"t": "credit", "n": 1})
            else:
                seat.last_input = time.monotonic()
                await trainer.send_child(seat, checked)
    except WebSocketDisconnect:
        pass
    finally:
        if seat.socket is ws:
            seat.socket, seat.detached_at = None, time.monotonic()


def install(app, max_s: float | None = None) -> None:
    """Add the trainer's page and socket to the records server ``app`` (called by ``app.build_app``;
    ``max_s``: the longest session, else $CHAINSIM_TRAIN_MAX_S)."""
    app.state.trainer = trainer_from_env(max_s)
    app.router.routes[:0] = [
        Route("/train/{pack}", train_page, methods=["GET"]),
        WebSocketRoute("/train/{pack}/ws", train_socket),
    ]
    # the sessions' processes end with the server: each ends when its input pipe closes
