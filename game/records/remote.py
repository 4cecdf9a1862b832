"""Saving attempts to a records server, with an offline queue in the local store.

``chainsim play PACK --records http://HOST:PORT`` files attempts on the programme's server
(``chainsim serve``) instead of the local file. Every attempt goes first into the ``outbox``
table of the local SQLite store, committed, with a fresh idempotency key; then it is sent. If the
server answers, the row is marked sent with the server's id; if it cannot be reached the row
waits and ``chainsim records sync`` (or the next start of the simulator) sends it. The server
stores a key once, so an attempt whose answer was lost and is sent again is not stored twice:
never lost, never sent twice.

Sign-in: ``chainsim records login URL NAME`` asks for the password and keeps the API token in the
local store (``server_logins``); $CHAINSIM_RECORDS_TOKEN overrides it (scripts, CI). A server with a
certificate of its own (self-signed, or signed by the programme's own authority) is trusted with
``--cafile PEM``: the authority's certificates are kept with the sign-in, and every later send, sync
and listing to that server verifies it against them (and only them).
"""

from __future__ import annotations

import json
import logging
import os
import ssl
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlencode, urlsplit

from chainsim.components.resources import Records, SavedLocally
from chainsim.game.records.store import NoDatabase, RecordStore
from chainsim.game.records.validate import clean_attempt, clean_name, to_json
from chainsim.systems.engine.errors import UserError

logger = logging.getLogger(__name__)

TOKEN_ENV = "CHAINSIM_RECORDS_TOKEN"
TIMEOUT_S = 5.0
#: a CA file larger than this is not a certificate bundle (the system's own bundle is about 200 KiB)
MAX_CA_BYTES = 1 << 20


class KeptOffline(SavedLocally):
    """The attempt is safe in the local queue but not on the server yet (message says why; ``why`` is
    that reason alone, e.g. "http://HOST:8000 is unreachable")."""

    def __init__(self, message: str, local_id: int, why: str = "") -> None:
        super().__init__(message)
        self.local_id = local_id
        self.why = why


class ServerError(Exception):
    """An HTTP answer from the server that is not success: ``status`` and its one-line message."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def server_url(text: str) -> str:
    """``http(s)://host[:port][/prefix]`` without a trailing slash, or one clear error."""
    parts = urlsplit(text.strip()) if isinstance(text, str) else None
    if parts is None or parts.scheme not in ("http", "https") or not parts.hostname:
        raise UserError(f"records server {text!r} must be an address like http://127.0.0.1:8000")
    if parts.query or parts.fragment or parts.username:
        raise UserError(f"records server {text!r}: give only scheme, host, port (and a path prefix)")
    return f"{parts.scheme}://{parts.netloc}{parts.path.rstrip('/')}"


def request(
    url: str,
    method: str = "GET",
    body: Any = None,
    token: str | None = None,
    headers: dict | None = None,
    timeout: float = TIMEOUT_S,
    context: ssl.SSLContext | None = None,
) -> Any:
    """One JSON request; returns the decoded answer, raises ServerError (HTTP) or OSError (network).

    ``context`` verifies an https server (``trust``); None trusts the system's authorities."""
    data = None if body is None else json.dumps(body, allow_nan=False).encode()
    req = urllib.request.Request(url, data=data, method=method)
    req.add_header("Accept", "application/json")
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    for k, v in (headers or {}).items():
        req.add_header(k, v)
    try:
        with urllib.request.urlopen(req, timeout=timeout, context=context) as resp:
            raw = resp.read()
    except urllib.error.HTTPError as exc:
        try:
            message = json.loads(exc.read(4096) or b"{}").get("error") or exc.reason
        except (ValueError, AttributeError):
            message = exc.reason
        raise ServerError(exc.code, str(message)) from None
    except urllib.error.URLError as exc:
        if isinstance(exc.reason, ssl.SSLCertVerificationError):
            raise OSError(
                f"cannot reach {url}: its certificate is not trusted ({exc.reason.verify_message}); for a server "
                "with its own certificate sign in with: chainsim records login --cafile CA.pem URL NAME"
            ) from None
        raise OSError(f"cannot reach {url}: {exc.reason}") from None
    return json.loads(raw) if raw else None


# -- sign-in ----------------------------------------------------------------------------------


def read_cafile(path: str | os.PathLike[str]) -> str:
    """The PEM text of ``--cafile``, checked to hold at least one certificate; UserError naming the problem."""
    what = "expected the PEM file of the authority that signed the server's certificate (or the certificate itself)"
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_CA_BYTES + 1)
    except FileNotFoundError:
        raise UserError(f"--cafile {path}: no such file; {what}") from None
    except IsADirectoryError:
        raise UserError(f"--cafile {path}: is a folder; {what}") from None
    except OSError as exc:
        raise UserError(f"--cafile {path}: cannot be read ({exc.strerror}); {what}") from None
    if len(raw) > MAX_CA_BYTES:
        raise UserError(f"--cafile {path}: larger than {MAX_CA_BYTES} bytes; {what}")
    try:
        pem = raw.decode("ascii")
        trust(pem)
    except (UnicodeDecodeError, ssl.SSLError, ValueError):
        raise UserError(f"--cafile {path}: holds no PEM certificate; {what}") from None
    return pem


def trust(ca_pem: str | None) -> ssl.SSLContext | None:
    """An SSL context that trusts only the certificates of ``ca_pem``; None (the system's) without it."""
    if not ca_pem:
        return None
    if "-----BEGIN CERTIFICATE-----" not in ca_pem:
        raise ValueError("no PEM certificate")
    return ssl.create_default_context(cadata=ca_pem)


def context_for(store: RecordStore, server: str) -> ssl.SSLContext | None:
    """How to verify ``server``: the authority kept at its sign-in (``--cafile``), else the system's."""
    rows = store.query("SELECT ca_pem FROM server_logins WHERE server = ?", (server,))
    try:
        return trust(rows[0][0] if rows else None)
    except (ssl.SSLError, ValueError):
        raise UserError(f"the authority kept for {server} is no longer readable; sign in again with --cafile") from None


def login(
    store: RecordStore, server: str, name: str, password: str, cafile: str | os.PathLike[str] | None = None
) -> dict:
    """Sign in to ``server`` and keep its token in ``store``; returns the account.

    ``cafile``: the PEM of the authority to trust for this server, kept with the sign-in for later sends
    and syncs. Without it a sign-in again keeps the authority an earlier one gave."""
    server = server_url(server)
    if cafile is not None:
        if not server.startswith("https://"):
            raise UserError(f"--cafile is for an https:// server; {server} is plain http, so nothing is verified")
        ca_pem = read_cafile(cafile)
    else:
        rows = store.query("SELECT ca_pem FROM server_logins WHERE server = ?", (server,))
        ca_pem = rows[0][0] if rows else None
    try:
        answer = request(
            f"{server}/api/login",
            "POST",
            {"name": name, "password": password, "label": "simulator"},
            context=trust(ca_pem),
        )
    except ServerError as exc:
        raise UserError(f"{server} refused the sign-in: {exc}") from None
    except OSError as exc:
        raise UserError(str(exc)) from None
    now = datetime.now(UTC).isoformat(timespec="seconds")
    with store.transaction() as conn:
        conn.execute("DELETE FROM server_logins WHERE server = ?", (server,))
        conn.execute(
            "INSERT INTO server_logins (server, user_name, role, token, saved_at, ca_pem) VALUES (?, ?, ?, ?, ?, ?)",
            (server, answer["user"]["name"], answer["user"]["role"], answer["token"], now, ca_pem),
        )
    return answer["user"]


def token_for(store: RecordStore, server: str) -> str | None:
    env = os.environ.get(TOKEN_ENV, "").strip()
    if env:
        return env
    rows = store.query("SELECT token FROM server_logins WHERE server = ?", (server,))
    return rows[0][0] if rows else None


def role_for(store: RecordStore, server: str, token: str) -> str:
    """The role of the account behind ``token`` (kept at sign-in, else asked of the server)."""
    rows = store.query("SELECT role FROM server_logins WHERE server = ? AND token = ?", (server, token))
    if rows:
        return rows[0][0]
    return request(f"{server}/api/me", token=token, context=context_for(store, server))["role"]


# -- the queue --------------------------------------------------------------------------------


def enqueue(
    store: RecordStore, server: str, class_name: str, trainee: str, attempt: dict, evidence: dict | None = None
) -> int:
    """Validate the attempt and commit it to the outbox with its evidence; returns the outbox row id.

    ``evidence`` is what the server scores the attempt from: ``recording`` (compressed) and
    ``pack_identity`` (``chainsim.game.records.provenance``); the attempt's own figures go beside it
    and the server keeps them only to compare.
    """
    record = clean_attempt(attempt)  # a bad attempt is refused now, not after a round trip
    record.update(evidence or {})
    with store.transaction() as conn:
        return conn.execute(
            "INSERT INTO outbox (server, idem_key, class_name, trainee, attempt, queued_at) VALUES (?, ?, ?, ?, ?, ?)",
            (
                server,
                uuid.uuid4().hex,
                clean_name("class", class_name),
                clean_name("trainee", trainee),
                to_json(record),
                datetime.now(UTC).isoformat(timespec="seconds"),
            ),
        ).lastrowid


def outbox_attempts(store: RecordStore) -> list[str]:
    """The attempt (JSON text) of every outbox row, sent or not."""
    return [r[0] for r in store.query("SELECT attempt FROM outbox")]


def pending(store: RecordStore, server: str | None = None) -> list[Any]:
    return store.query(
        "SELECT id, server, idem_key, class_name, trainee, attempt FROM outbox "
        "WHERE sent_at IS NULL AND (? IS NULL OR server = ?) ORDER BY id",
        (server, server),
    )


def _send(store: RecordStore, row: Any, token: str) -> dict:
    """POST one outbox row; on acknowledgement mark it sent and return the server's answer.

    The server answers at once (202: ``upload``, the ``class_name`` and ``trainee`` it files under,
    the ``number`` the attempt will have among that trainee's) and scores the attempt afterwards by
    replaying its recording; ``GET /api/uploads/ID`` says when it is scored and the attempt's id."""
    body = json.loads(row["attempt"])
    # A trainee's attempts go under the signed-in account whatever the window's name fields say;
    # a trainer files for a trainee of their class by naming them.
    if role_for(store, row["server"], token) == "trainer":
        body["class_name"], body["trainee"] = row["class_name"], row["trainee"]
    answer = request(
        f"{row['server']}/api/attempts",
        "POST",
        body,
        token,
        {"Idempotency-Key": row["idem_key"]},
        context=context_for(store, row["server"]),
    )
    with store.transaction() as conn:
        conn.execute(
            "UPDATE outbox SET sent_at = ?, remote_id = ?, last_error = NULL WHERE id = ?",
            (datetime.now(UTC).isoformat(timespec="seconds"), int(answer["upload"]), row["id"]),
        )
    return answer


def _note_error(store: RecordStore, row_id: int, message: str) -> None:
    with store.transaction() as conn:
        conn.execute("UPDATE outbox SET last_error = ? WHERE id = ?", (message[:500], row_id))


def sync(store: RecordStore, server: str | None = None) -> dict[str, Any]:
    """Send every waiting attempt (of ``server``, or all). Returns counts and one line per problem.

    Stops sending to a server at the first network failure or refused token (the rest wait);
    an attempt the server refuses (4xx) stays in the queue with the reason, never dropped.
    """
    sent, problems, skipped = 0, [], set()
    for row in pending(store, None if server is None else server_url(server)):
        srv = row["server"]
        if srv in skipped:
            continue
        token = token_for(store, srv)
        if token is None:
            skipped.add(srv)
            problems.append(f"{srv}: not signed in; run: chainsim records login {srv} NAME")
            continue
        try:
            _send(store, row, token)
            sent += 1
        except OSError as exc:
            skipped.add(srv)
            problems.append(f"{srv}: unreachable ({exc}); attempts kept for the next sync")
        except ServerError as exc:
            _note_error(store, row["id"], f"HTTP {exc.status}: {exc}")
            if exc.status == 401:
                skipped.add(srv)
                problems.append(f"{srv}: sign-in expired or refused ({exc}); run: chainsim records login {srv} NAME")
            elif exc.status >= 500 or exc.status == 429:  # busy, or this account's uploads are rate-limited
                skipped.add(srv)
                problems.append(f"{srv}: server error {exc.status} ({exc}); attempts kept for the next sync")
            else:
                problems.append(f"{srv}: attempt {row['id']} refused (HTTP {exc.status}: {exc}); kept in the queue")
    left = len(pending(store, None if server is None else server_url(server)))
    return {"sent": sent, "waiting": left, "problems": problems}


# -- what the simulator uses ------------------------------------------------------------------


class RemoteRecords:
    """``save_attempt``/``list_attempts`` like ``RecordStore``, on a records server via the outbox."""

    def __init__(self, server: str, local_db: str | os.PathLike[str] | None = None) -> None:
        self.server = server_url(server)
        self.local = RecordStore(local_db)
        self.where = f"records server {self.server}"
        #: the server's acknowledgement of the last save: whom it files the attempt under, its number
        self.acknowledged: dict[str, Any] | None = None

    def __enter__(self) -> RemoteRecords:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.local.close()

    def save_attempt(self, class_name: str, trainee: str, attempt: dict[str, Any], evidence: dict | None = None) -> int:
        """The server's upload id of the attempt; KeptOffline when it waits in the local queue.

        The server acknowledges at once and scores the attempt by replaying ``evidence["recording"]``."""
        local_id = enqueue(self.local, self.server, class_name, trainee, attempt, evidence)
        token = token_for(self.local, self.server)
        why = None
        if token is None:
            why = f"not signed in to {self.server} (chainsim records login {self.server} NAME)"
        else:
            row = next(r for r in pending(self.local, self.server) if r["id"] == local_id)
            try:
                self.acknowledged = _send(self.local, row, token)
            except OSError:
                why = f"{self.server} is unreachable"
            except ServerError as exc:
                _note_error(self.local, local_id, f"HTTP {exc.status}: {exc}")
                if exc.status < 500 and exc.status not in (401, 429):
                    raise UserError(f"{self.server} refused the attempt: {exc} (kept in the local queue)") from None
                why = f"{self.server} answered {exc.status} ({exc})"
            else:
                self._flush_quietly()
                return int(self.acknowledged["upload"])
        raise KeptOffline(
            f"{why}; attempt kept on this computer and sent by `chainsim records sync` or the next start",
            local_id,
            why,
        )

    def _flush_quietly(self) -> None:
        """The server answered: send what earlier saves left in the queue too."""
        try:
            sync(self.local, self.server)
        except UserError as exc:
            logger.warning("records sync: %s", exc)

    def list_attempts(self, class_name: str | None = None, trainee: str | None = None) -> list[dict[str, Any]]:
        token = token_for(self.local, self.server)
        if token is None:
            raise UserError(f"not signed in to {self.server}: chainsim records login {self.server} NAME")
        try:
            if role_for(self.local, self.server, token) != "trainer":
                class_name = trainee = None  # a trainee account lists its own attempts, whatever the names typed
            query = {k: v for k, v in (("class", class_name), ("trainee", trainee)) if v is not None}
            url = f"{self.server}/api/attempts" + (f"?{urlencode(query)}" if query else "")
            return request(url, token=token, context=context_for(self.local, self.server))["attempts"]
        except ServerError as exc:
            raise UserError(f"{self.server}: {exc}") from None
        except OSError as exc:
            raise UserError(str(exc)) from None


def remote_records(
    server: str,
    db: str | os.PathLike[str] | None = None,
    evidence: Callable[[], dict] | None = None,
    said: list[str] | None = None,
) -> Records:
    """The Records resource on a records server, queueing in the local store ``db`` (see module doc).

    ``evidence()`` gives, at each save, the recording and pack identity the server scores from. A
    trainee cannot delete an attempt on a server (a trainer retracts it), so there is no delete here.
    ``filed_as(upload)`` is what the server said it files a save under: the signed-in trainee's class and
    name (not the names typed in the window) and the attempt's number among theirs once it is scored.
    ``said`` gets one line per save saying where the attempt went (`chainsim run` prints them).
    """
    server = server_url(server)
    filed: dict[int, tuple[str, str, int | None]] = {}

    def save_attempt(class_name: str, trainee: str, record: dict) -> int:
        with RemoteRecords(server, db) as rr:
            try:
                upload = rr.save_attempt(class_name, trainee, record, None if evidence is None else evidence())
            except KeptOffline as exc:
                if said is not None:
                    said.append(f"attempt kept on this computer: {exc.why}; sent by `chainsim records sync`")
                raise
            ack = rr.acknowledged or {}
            filed[upload] = (ack.get("class_name", class_name), ack.get("trainee", trainee), ack.get("number"))
            if said is not None:
                cls, who, _ = filed[upload]
                said.append(
                    f"attempt sent to {server} as upload {upload} ({who}, class {cls}): the server scores it by "
                    "replaying the session"
                )
            return upload

    def list_attempts(class_name: str, trainee: str) -> list[dict]:
        with RemoteRecords(server, db) as rr:
            return rr.list_attempts(class_name, trainee)

    return Records(save_attempt, list_attempts, f"records server {server}", filed_as=filed.get)


def sync_quietly(server: str, db: str | os.PathLike[str] | None = None) -> None:
    """Send what earlier sessions left in the queue for ``server``; problems are logged, not raised."""
    try:
        with RecordStore(db, create=False) as store:  # no database: nothing was ever queued
            result = sync(store, server_url(server))
    except NoDatabase:
        return
    except UserError as exc:
        logger.warning("records: %s", exc)
        return
    if result["sent"]:
        logger.info("sent %d queued attempt(s) to %s", result["sent"], server)
    for line in result["problems"]:
        logger.warning("records: %s", line)


def kept_and_filed(
    server: str, db: str | os.PathLike[str] | None, evidence: Callable[[], dict], said: Callable[[str], None]
) -> Records:
    """The Records of a study session with a records server: each trial is saved in the local store ``db``
    with its recording, as without a server, and filed on ``server`` through the outbox with the same
    recording (the server checks it against its register and scores it by replaying it). A server that
    cannot be reached leaves the trial in the queue (``chainsim records sync`` sends it); one that
    refuses it says why. ``said`` gets one line per trial saying where it went."""
    server = server_url(server)

    def save_attempt(class_name: str, trainee: str, record: dict) -> int:
        sent = evidence()
        with RecordStore(db) as store:
            local_id = store.save_attempt(class_name, trainee, record, recording=sent["recording"])
        try:
            with RemoteRecords(server, db) as rr:
                upload = rr.save_attempt(class_name, trainee, record, sent)
            said(f"trial saved here and sent to {server} as upload {upload}")
        except KeptOffline as exc:
            said(f"trial saved here; for {server} it waits in the queue ({exc.why}): chainsim records sync sends it")
        except UserError as exc:
            said(f"trial saved here; {exc}")
        return local_id

    def list_attempts(class_name: str, trainee: str) -> list[dict]:
        with RecordStore(db, create=False) as store:
            return store.list_attempts(class_name, trainee)

    return Records(save_attempt, list_attempts, f"this computer and records server {server}")
