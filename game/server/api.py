"""The records server's JSON API under /api: sign in for a token, then create, list, read, delete.

    POST   /api/login              {"name", "password", "label"?} -> {"token", "expires_at", "user"}
    GET    /api/me                 the account behind the token
    GET    /api/attempts           ?class=C&trainee=T, the attempts the account may see
    POST   /api/attempts           an upload: the simulator's record, its recording and pack_identity;
                                   Idempotency-Key header -> 202 {"upload", "status": "scoring", "class_name",
                                   "trainee", "number" (the attempt's among the trainee's), ...}
    GET    /api/uploads/{id}       an upload's state: scoring, scored (with attempt_id) or refused (error)
    GET    /api/attempts/{id}      one attempt (403 when it is someone else's)
    POST   /api/attempts/{id}/retract  {"reason"}: a trainer retracts an attempt of their class (kept)
    POST   /api/attempts/{id}/accept   a trainer accepts a flagged attempt: it counts in the class figures
    DELETE /api/attempts/{id}      refused: attempts are records (a trainer retracts instead)
    GET    /api/audit              ?class=C, the audit log of a trainer's classes

An attempt is the record ``RecordStore`` keeps (``chainsim.game.records.validate.FIELDS``) with
the figures the server's replay computed (``chainsim.game.server.scoring``): the simulator's own
are kept beside them (``client_figures``) and ``differences`` lists where they disagree. A
trainee files attempts under their own class and name; a trainer may file for a trainee of a
class they teach by naming ``class_name`` and ``trainee``; the attempt records the account that
filed it and the server's time. A resent upload with the same Idempotency-Key answers 200 with
the first upload; the same key with another body is a 409. Each account files at most
``serve --uploads-per-minute`` new uploads a minute (``chainsim.game.server.upload_limit``; 429 with
Retry-After past it), and a class that requires witnessed attempts refuses uploads from the window (422).
"""

from __future__ import annotations

from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from chainsim.game.records import accounts
from chainsim.game.records.accounts import User
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_key, clean_name
from chainsim.game.server import scoring, throttle
from chainsim.game.server.auth import MAX_JSON_BYTES, HTTPError, api_user, read_json
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError

IDEMPOTENCY_HEADER = "idempotency-key"
#: an upload's body: the largest recording (base64 of at most MAX_RECORDING_BYTES) and the attempt's fields
UPLOAD_BODY_BYTES = limits.MAX_RECORDING_BYTES * 4 // 3 + MAX_JSON_BYTES


# -- store work (runs on a storage worker thread) ----------------------------------------------


def visible_attempts(store: RecordStore, user: User, class_name: str | None, trainee: str | None) -> list[dict]:
    try:
        class_name = None if class_name is None else clean_name("class", class_name)
        trainee = None if trainee is None else clean_name("trainee", trainee)
    except UserError as exc:
        raise HTTPError(400, str(exc)) from None
    if user.is_trainer:
        if class_name is not None and class_name not in user.classes:
            raise HTTPError(403, "you do not teach that class")
        classes = [class_name] if class_name is not None else list(user.classes)
        known = set(store.list_classes())
        out: list[dict] = []
        for c in classes:
            if c not in known:
                continue
            try:
                out += store.list_attempts(c, trainee)
            except UserError:  # that trainee is not in this class
                if class_name is not None:
                    raise HTTPError(404, f"no trainee named {trainee!r} in class {c!r}") from None
        return out
    if user.trainee_id is None:
        return []
    if (class_name or user.classes[0], trainee or user.trainee) != (user.classes[0], user.trainee):
        raise HTTPError(403, "a trainee sees only their own attempts")
    return store.list_attempts(user.classes[0], user.trainee)


def readable_attempt(store: RecordStore, user: User, attempt_id: int) -> dict:
    try:
        attempt = store.get_attempt(attempt_id)
    except UserError:
        raise HTTPError(404, f"no attempt with id {attempt_id}") from None
    if not user.can_see(attempt["class_name"], attempt["trainee"]):
        raise HTTPError(403, "that attempt is not yours to see")
    return attempt


def retract_attempt(store: RecordStore, user: User, attempt_id: int, reason: Any) -> dict:
    if not user.is_trainer:
        raise HTTPError(403, "attempts are kept; only a trainer of the class can retract one")
    readable_attempt(store, user, attempt_id)
    try:
        return store.retract_attempt(attempt_id, user.name, reason)
    except UserError as exc:
        if type(exc) is not UserError:
            raise
        raise HTTPError(422, str(exc)) from None


def accept_attempt(store: RecordStore, user: User, attempt_id: int) -> dict:
    if not user.is_trainer:
        raise HTTPError(403, "only a trainer of the class can accept a flagged attempt")
    readable_attempt(store, user, attempt_id)
    try:
        return store.accept_attempt(attempt_id, user.name)
    except UserError as exc:
        if type(exc) is not UserError:
            raise
        raise HTTPError(422, str(exc)) from None


def audit_entries(store: RecordStore, user: User, class_name: str | None) -> list[dict]:
    if not user.is_trainer:
        raise HTTPError(403, "the audit log is for trainers")
    if class_name is not None and class_name not in user.classes:
        raise HTTPError(403, "you do not teach that class")
    return store.audit_entries([class_name] if class_name is not None else list(user.classes))


def readable_upload(store: RecordStore, user: User, upload_id: int) -> dict:
    row = scoring.get_upload(store, upload_id)
    if row is None:
        raise HTTPError(404, f"no upload with id {upload_id}")
    if not user.can_see(row["class_name"], row["trainee"]) and row["filed_by"] != user.name:
        raise HTTPError(403, "that upload is not yours to see")
    return scoring.upload_view(row)


def known_upload(store: RecordStore, user: User, key: str, digest: str) -> dict | None:
    """The upload a resend with this Idempotency-Key already made; 409 when the key was used otherwise."""
    row = scoring.upload_for_key(store, key)
    if row is None:
        if store.attempt_id_for_key(key) is not None:  # an attempt saved before uploads were scored
            raise HTTPError(409, "this Idempotency-Key was already used; send the upload with a fresh key")
        return None
    if row["filed_by"] != user.name and not user.can_see(row["class_name"], row["trainee"]):
        raise HTTPError(409, "this Idempotency-Key was used for another trainee's attempt")
    if row["body_hash"] != digest:
        raise HTTPError(409, "this Idempotency-Key was used for a different attempt; send it with a fresh key")
    return row


def file_under(user: User, record: dict[str, Any]) -> tuple[str, str]:
    """(class, trainee) a new attempt goes under, taken out of ``record``; 403 if not allowed."""
    class_name = record.pop("class_name", None)
    trainee = record.pop("trainee", None)
    record.pop("id", None)  # a listed record sent back: the server gives the id
    if user.is_trainer:
        if class_name is None or trainee is None:
            raise HTTPError(422, "a trainer saving an attempt must name its class_name and trainee")
        try:
            class_name, trainee = clean_name("class", class_name), clean_name("trainee", trainee)
        except UserError as exc:
            raise HTTPError(422, str(exc)) from None
        if class_name not in user.classes:
            raise HTTPError(403, "you do not teach that class")
        return class_name, trainee
    if user.trainee_id is None or user.trainee is None:  # both are set together (accounts.load_user)
        raise HTTPError(403, "this trainee account has no trainee record; ask your trainer")
    own = (user.classes[0], user.trainee)
    if (class_name or own[0], trainee or own[1]) != own:
        raise HTTPError(403, "a trainee saves attempts only under their own class and name")
    return own


def queue_upload(
    store: RecordStore,
    user: User,
    class_name: str,
    trainee: str,
    checked: dict,
    key,
    digest: str,
    witnessed: bool = False,
):
    try:
        row, created = scoring.enqueue(store, user.name, class_name, trainee, checked, key, digest, witnessed=witnessed)
    except UserError as exc:
        if type(exc) is not UserError:
            raise
        raise HTTPError(422, str(exc)) from None
    if not created:  # two sends of one key raced; the first one's row answers both
        if row["body_hash"] != digest:
            raise HTTPError(409, "this Idempotency-Key was used for a different attempt; send it with a fresh key")
    return row, created


def acknowledgement(store: RecordStore, row: dict) -> dict:
    """What the server answers to an upload: its state, whom it files it under and the attempt's number."""
    return {**scoring.upload_view(row), "number": scoring.attempt_number(store, row)}


# -- routes -----------------------------------------------------------------------------------


def _attempt_id(request: Request) -> int:
    value = int(request.path_params["attempt_id"])
    if not 1 <= value < 2**63:  # ids are 64-bit in both databases
        raise HTTPError(404, f"no attempt with id {value}")
    return value


async def login(request: Request) -> Response:
    body = await read_json(request)
    if not isinstance(body, dict):
        raise HTTPError(422, "expected an object with name and password")
    label = body.get("label", "api")
    if not isinstance(label, str) or not label.strip() or len(label) > 64:
        raise HTTPError(422, "label must be 1-64 characters of text")
    key, address = throttle.guarded(request, body.get("name"))
    storage = request.app.state.storage
    user = await storage.run(accounts.check_login, body.get("name"), body.get("password"))
    if user is None:
        request.app.state.throttle.failed(key, address)
        raise HTTPError(401, "name or password is wrong")
    request.app.state.throttle.succeeded(key)
    token, expires = await storage.run(accounts.issue_token, user, label.strip())
    return JSONResponse({"token": token, "expires_at": expires, "user": user.public()}, status_code=201)


async def me(request: Request) -> Response:
    user = await api_user(request)
    return JSONResponse(user.public())


async def list_attempts(request: Request) -> Response:
    user = await api_user(request)
    q = request.query_params
    rows = await request.app.state.storage.run(visible_attempts, user, q.get("class"), q.get("trainee"))
    return JSONResponse({"attempts": rows})


async def create_attempt(request: Request) -> Response:
    user = await api_user(request)
    # a few uploads are read and checked at once, the rest wait their turn: the server's memory is bounded
    # by this many bodies at the size limit, however many arrive together
    async with request.app.state.upload_slots:
        return await _create_attempt(request, user)


async def _create_attempt(request: Request, user: User) -> Response:
    body = await read_json(request, UPLOAD_BODY_BYTES)
    if not isinstance(body, dict):
        raise HTTPError(422, f"an attempt must be a JSON object of fields, got {type(body).__name__}")
    key = request.headers.get(IDEMPOTENCY_HEADER)
    if key is not None:
        try:
            key = clean_key(key)
        except UserError as exc:
            raise HTTPError(400, str(exc)) from None
    digest = scoring.body_hash(body)
    storage = request.app.state.storage
    row = None if key is None else await storage.run(known_upload, user, key, digest)
    created = False
    if row is None:
        request.app.state.upload_rate.take(user.id)  # a resend of a known upload costs nothing
        class_name, trainee = file_under(user, body)
        try:
            # the pack's identity (hashed once per server) and the recording are checked off the event loop
            checked = await run_in_threadpool(scoring.check_upload, request.app.state.packs, body)
        except UserError as exc:
            raise HTTPError(422, str(exc)) from None
        row, created = await storage.run(queue_upload, user, class_name, trainee, checked, key, digest)
        if created:
            request.app.state.scorer.wake()
    # the simulator names the account and the attempt's number in its save message from this answer
    answer = await storage.run(acknowledgement, row)
    return JSONResponse(
        answer,
        status_code=202 if created else 200,
        headers={"Location": f"/api/uploads/{row['id']}"},
    )


async def get_upload(request: Request) -> Response:
    user = await api_user(request)
    value = int(request.path_params["upload_id"])
    if not 1 <= value < 2**63:
        raise HTTPError(404, f"no upload with id {value}")
    return JSONResponse(await request.app.state.storage.run(readable_upload, user, value))


async def retract(request: Request) -> Response:
    user = await api_user(request)
    body = await read_json(request)
    reason = body.get("reason") if isinstance(body, dict) else None
    attempt = await request.app.state.storage.run(retract_attempt, user, _attempt_id(request), reason)
    return JSONResponse(attempt)


async def accept(request: Request) -> Response:
    user = await api_user(request)
    attempt = await request.app.state.storage.run(accept_attempt, user, _attempt_id(request))
    return JSONResponse(attempt)


async def audit(request: Request) -> Response:
    user = await api_user(request)
    rows = await request.app.state.storage.run(audit_entries, user, request.query_params.get("class"))
    return JSONResponse({"audit": rows})


async def get_attempt(request: Request) -> Response:
    user = await api_user(request)
    attempt = await request.app.state.storage.run(readable_attempt, user, _attempt_id(request))
    return JSONResponse(attempt)


async def remove_attempt(request: Request) -> Response:
    user = await api_user(request)
    await request.app.state.storage.run(readable_attempt, user, _attempt_id(request))
    if user.is_trainer:
        raise HTTPError(405, "attempts are kept; retract it with POST /api/attempts/ID/retract and a reason")
    raise HTTPError(403, "attempts are kept; only a trainer of the class can retract one")


async def health(request: Request) -> Response:
    return JSONResponse({"ok": True})


routes = [
    Route("/api/health", health, methods=["GET"]),
    Route("/api/login", login, methods=["POST"]),
    Route("/api/me", me, methods=["GET"]),
    Route("/api/attempts", list_attempts, methods=["GET"]),
    Route("/api/attempts", create_attempt, methods=["POST"]),
    Route("/api/attempts/{attempt_id:int}", get_attempt, methods=["GET"]),
    Route("/api/attempts/{attempt_id:int}", remove_attempt, methods=["DELETE"]),
    Route("/api/attempts/{attempt_id:int}/retract", retract, methods=["POST"]),
    Route("/api/attempts/{attempt_id:int}/accept", accept, methods=["POST"]),
    Route("/api/uploads/{upload_id:int}", get_upload, methods=["GET"]),
    Route("/api/audit", audit, methods=["GET"]),
]
