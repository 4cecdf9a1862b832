"""A real records server for the tests: `chainsim serve` in a subprocess over SQLite or PostgreSQL.

``site`` (one per backend per test session) is a server with a small programme in it: trainer
``tina`` teaches c1, trainer ``tom`` teaches c2; trainees ``alice`` and ``bob`` are in c1,
``carol`` in c2. Every account's password is ``PASSWORD`` and each has an API token in
``site.tokens``. Tests that need a server of their own (kill -9, restarts) use ``start_server``.

Uploads are real: ``upload()`` is what the simulator queues after a built-in scripted attempt with
Save pressed (its figures, its recording and the pack's identity), made once per test session.
The server answers 202 with an upload id and scores it by replay; ``save_scored`` sends one and
waits for the attempt the replay stored.

The prp pack these tests replay is a copy in a temporary folder, found through $CHAINSIM_PACK_PATH
by the simulator, the servers and the command lines alike: an edit made to ``assets/prp`` while the
tests run changes the built-in pack's hash, never the copy's, so an upload made at the start still
matches the server's pack at the end.
"""

from __future__ import annotations

import functools
import http.client
import json
import os
import shutil
import signal
import ssl
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import pytest

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / "assets" / "prp" / "scripts"
PASSWORD = "correct horse 42"
PEOPLE = (
    ("tina", "trainer", ["c1"]),
    ("tom", "trainer", ["c2"]),
    ("alice", "trainee", ["c1"]),
    ("bob", "trainee", ["c1"]),
    ("carol", "trainee", ["c2"]),
)

from records_db import free_port  # noqa: E402  (tests/records_db.py, loaded by tests/conftest.py)

#: the folder that holds the copy of the prp pack, once ``pack_copy`` made it
PACKS: list[Path] = []


@pytest.fixture(scope="session")
def pack_copy(tmp_path_factory):
    """The prp pack copied, once per session, to a folder of its own (see module doc)."""
    folder = tmp_path_factory.mktemp("packs")
    shutil.copytree(REPO / "assets" / "prp", folder / "prp", ignore=shutil.ignore_patterns("__pycache__", ".*"))
    PACKS[:] = [folder]
    return folder / "prp"


@pytest.fixture(autouse=True)
def serve_the_pack_copy(pack_copy, monkeypatch):
    """Each test here finds prp in the copy (the simulator, command lines, servers); tests elsewhere do not."""
    monkeypatch.setenv("CHAINSIM_PACK_PATH", str(pack_copy.parent))


def attempt(i: int = 0, **over) -> dict:
    a = {
        "pack": "prp",
        "created_at": f"2026-06-{1 + i % 28:02d}T10:00:00Z",
        "duration_s": 80.0 - 3 * i,
        "landmark_error_mm": 5.0 - 0.4 * i,
        "needle_error_mm": 9.0 - i,
        "target": "foramen_ovale_left" if i % 2 else "skull",
        "skull_contacts": max(0, 4 - i),
        "path_length_mm": 60.0 + i,
        "aids": {"tip_view": True},
        "step_times": {"landmarks": 30.0 - i, "insert": 50.0 - 2 * i},
        "details": {"D1": 0.5, "side": "left"},
    }
    a.update(over)
    return a


def save_through_simulator(url: str, local: str, script: str, trainee: str = "alice") -> None:
    """Make a built-in scripted attempt in the simulator with --records as a person at the window does
    (its picks and widget presses as clicks and drags at a person's pace, ``chainsim.game.trainer.windowform``)
    and click Save at its end."""
    from chainsim.components.resources import PendingInput  # noqa: PLC0415 - the simulator, loaded when used
    from chainsim.game.trainer import windowform  # noqa: PLC0415
    from chainsim.game.trainer.headless import build_app  # noqa: PLC0415
    from chainsim.game.trainer.inputscript import load_script  # noqa: PLC0415

    app = build_app("prp", settings={"db": local, "records": url, "class": "c1", "trainee": trainee})
    try:
        events = windowform.gestures(app, load_script(SCRIPTS / script))
        events += windowform.save_click(app, max(t for t, _ in events))
        app.resource(PendingInput).extend(events)
        app.run_steps(int((events[-1][0] + 1.0) * 120))
    finally:
        app.close()


@functools.cache
def _queued(script: str) -> str:
    """The upload (JSON text) the simulator queues for a scripted attempt; nothing listens on port 9,
    so it stays in the local outbox, from where it is taken."""
    folder = tempfile.mkdtemp(prefix="chainsim-upload-")
    try:
        local = str(Path(folder) / "local.sqlite3")
        save_through_simulator("http://127.0.0.1:9", local, script)
        with RecordStore(local) as store:
            return store.query("SELECT attempt FROM outbox")[0][0]
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def upload(script: str = "correct.toml", **over) -> dict:
    """A real upload of the prp pack (figures, ``recording``, ``pack_identity``), fields in ``over`` changed."""
    body = json.loads(_queued(script))
    body.update(over)
    return body


def figures(script: str = "correct.toml", **over) -> dict:
    """The simulator's own record of a real upload, without its evidence: what the procedure saves."""
    body = upload(script, **over)
    del body["recording"], body["pack_identity"]
    return body


def evidence(script: str = "correct.toml") -> dict:
    """The recording and pack identity of a real upload: what ``RemoteRecords.save_attempt`` sends."""
    body = upload(script)
    return {"recording": body["recording"], "pack_identity": body["pack_identity"]}


@dataclass
class Server:
    url: str
    db: str
    proc: subprocess.Popen
    log: Path
    tokens: dict[str, str] = field(default_factory=dict)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def alive(self) -> bool:
        return self.proc.poll() is None and call(self, "GET", "/api/health")[0] == 200


def start_server(db: str, log: Path, port: int | None = None, args: tuple[str, ...] = ()) -> Server:
    """``chainsim serve`` over ``db`` on 127.0.0.1 (``args``: more options; https with --certfile), once it answers."""
    port = port or free_port()
    scheme = "https" if "--certfile" in args else "http"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if PACKS:  # a session's server starts before any test's environment is set
        env["CHAINSIM_PACK_PATH"] = str(PACKS[0])
    fh = log.open("ab")
    if not any(a.startswith("--uploads-per-minute") for a in args):  # tests upload far more than a person
        args = (*args, "--uploads-per-minute", "6000")
    proc = subprocess.Popen(
        [sys.executable, "-m", "chainsim.game", "serve", "--db", db, "--port", str(port), *args],
        stdout=fh,
        stderr=subprocess.STDOUT,
        env=env,
    )
    fh.close()
    server = Server(f"{scheme}://127.0.0.1:{port}", db, proc, log)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"chainsim serve exited {proc.returncode}: {log.read_text()}")
        try:
            if call(server, "GET", "/api/health")[0] == 200:
                return server
        except OSError:
            pass
        time.sleep(0.1)
    server.stop()
    raise RuntimeError(f"chainsim serve did not answer in 30 s: {log.read_text()}")


def call(
    server: Server,
    method: str,
    path: str,
    body=None,
    token: str | None = None,
    headers=None,
    raw=None,
    source: str | None = None,
):
    """(status, decoded JSON or text, headers) of one request; never raises on HTTP errors.

    A server may answer (413) before it has read a large body and close the connection: the client's
    send then fails with a broken pipe, and the answer already sent is read all the same. ``source``
    is the client's address (any of 127.0.0.0/8 reaches the server as another machine would).
    """
    data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
    hdrs = {}
    if data is not None and not any(k.lower() == "content-type" for k in (headers or {})):
        hdrs["Content-Type"] = "application/json"
    if token:
        hdrs["Authorization"] = f"Bearer {token}"
    hdrs.update(headers or {})
    url = urllib.parse.urlsplit(server.url)
    source_address = None if source is None else (source, 0)
    if url.scheme == "https":  # the tests' own server; what the simulator trusts is tested in test_tls.py
        conn = http.client.HTTPSConnection(
            url.hostname, url.port, timeout=30, source_address=source_address, context=ssl._create_unverified_context()
        )
    else:
        conn = http.client.HTTPConnection(url.hostname, url.port, timeout=30, source_address=source_address)
    try:
        try:
            conn.request(method, path, body=data, headers=hdrs)
        except (BrokenPipeError, ConnectionResetError):
            pass
        resp = conn.getresponse()
        status, text, rhdrs = resp.status, resp.read(), resp.headers
    finally:
        conn.close()
    try:
        decoded = json.loads(text) if text else None
    except ValueError:
        decoded = text.decode("utf-8", "replace")
    return status, decoded, rhdrs


def send(server: Server, who: str, body: dict, key: str | None = None, token: str | None = None):
    """POST one upload as ``who`` (or with ``token``); (status, answer, headers)."""
    headers = {"Idempotency-Key": key} if key else None
    return call(server, "POST", "/api/attempts", body, token or server.tokens[who], headers)


def wait_scored(server: Server, upload_id: int, token: str, timeout: float = 240.0) -> dict:
    """The upload's state once it is no longer "scoring" (scored or refused)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status, answer, _ = call(server, "GET", f"/api/uploads/{upload_id}", token=token)
        assert status == 200, answer
        if answer["status"] != "scoring":
            return answer
        time.sleep(0.2)
    raise AssertionError(f"upload {upload_id} not scored in {timeout} s")


def save_scored(server: Server, who: str, body: dict, key: str | None = None, token: str | None = None) -> dict:
    """Send an upload, wait for its scoring and return the attempt the server stored."""
    token = token or server.tokens[who]
    status, ack, _ = send(server, who, body, key, token)
    assert status in (200, 202), ack
    result = wait_scored(server, ack["upload"], token)
    assert result["status"] == "scored", result
    status, stored, _ = call(server, "GET", f"/api/attempts/{result['attempt_id']}", token=token)
    assert status == 200, stored
    return stored


_password_hash = functools.cache(functools.partial(accounts.hash_password, PASSWORD))


def populate(db: str) -> None:
    """The PEOPLE accounts in ``db``. They share one hash of PASSWORD (each hash costs a few tenths of a
    second by design, and dozens of servers are populated per run); sign-in checks it as any other."""
    with RecordStore(db) as store, mock.patch.object(accounts, "hash_password", lambda _password: _password_hash()):
        for name, role, classes in PEOPLE:
            accounts.add_user(store, name, role, PASSWORD, classes)


def sign_in(server: Server, *names: str) -> None:
    """API tokens for ``names`` in ``server.tokens``, issued in the store as ``/api/login`` issues them, for
    tests about something else than signing in (that is tested over HTTP by ``site`` and test_api.py)."""
    with RecordStore(server.db) as store:
        users = {u.name: u for u in accounts.list_users(store)}
        for name in names:
            server.tokens[name] = accounts.issue_token(store, users[name])[0]


@pytest.fixture(scope="session", params=("sqlite", "postgresql"))
def site(request, tmp_path_factory, pack_copy):
    """A running server with the PEOPLE accounts, one per backend for the whole session."""
    folder = tmp_path_factory.mktemp(f"site-{request.param}")
    if request.param == "sqlite":
        db = str(folder / "programme.sqlite3")
    else:
        db = request.getfixturevalue("postgres_server").new_database()
    populate(db)
    server = start_server(db, folder / "serve.log")
    for name, _, _ in PEOPLE:
        status, answer, _ = call(server, "POST", "/api/login", {"name": name, "password": PASSWORD})
        assert status == 201, answer
        server.tokens[name] = answer["token"]
    yield server
    server.stop()


def settle(db: str, timeout: float = 240.0) -> None:
    """Wait until no upload of ``db`` is still scoring: uploads an earlier test left are attempts by then,
    so a count taken now changes only by what the test itself sends."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with RecordStore(db) as store:
            if store.query("SELECT COUNT(*) FROM uploads WHERE state = 'scoring'")[0][0] == 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"uploads of {db} still scoring after {timeout} s")


def count_attempts(db: str) -> int:
    with RecordStore(db) as store:
        return len(store.list_attempts())
