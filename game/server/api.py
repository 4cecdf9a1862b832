"""The records server's JSON API under /api: sign in for a token, then create, list, read, delete.

    POST   /api/login              {"name", "password", "label"?} -> {"token", "expires_at", "user"}
    GET    /api/me                 the account behind the token
    GET    /api/attempts           ?class=C&trainee=T, the attempts the account may see
    POST   /api/attempts           an attempt record (the store's fields); Idempotency-Key header
    GET    /api/attempts/{id}      one attempt (403 when it is someone else's)
    DELETE /api/attempts/{id}      delete one attempt (same rule)

An attempt is the record ``RecordStore`` keeps (``chainsim.game.records.validate.FIELDS``),
so fields added to the record pass through unchanged. A trainee files attempts under their own
class and name; a trainer may file for a trainee of a class they teach by naming ``class_name``
and ``trainee``. A resent attempt with the same Idempotency-Key answers 200 with the first id.
"""

from __future__ import annotations

from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from chainsim.engine.errors import UserError
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_name
from chainsim.game.server import accounts
from chainsim.game.server.accounts import User
from chainsim.game.server.auth import HTTPError, api_user, read_json

IDEMPOTENCY_HEADER = "idempotency-key"


# -- store work (runs on a storage worker thread) ----------------------------------------------


def visible_attempts(store: RecordStore, user: User, class_name: str | None, trainee: str | None) -> list[dict]:
    try:
        class_name = None if class_name is None else clean_name("class", class_name)
        trainee = None if trainee is None else clean_name("trainee", trainee)
    except UserError as exc:
        raise HTTPError(400, str(exc)) from None
    if user.is_trainer:
        if class_name is not None and class_name not in user.classes:
            raise HTTPError(403, f"you do not teach class {class_name!r}")
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
        raise HTTPError(403, f"attempt {attempt_id} is not yours to see")
    return attempt


def delete_attempt(store: RecordStore, user: User, attempt_id: int) -> dict:
    attempt = readable_attempt(store, user, attempt_id)
    store.delete_attempt(attempt_id)
    return attempt


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
            raise HTTPError(403, f"you do not teach class {class_name!r}")
        return class_name, trainee
    if user.trainee_id is None:
        raise HTTPError(403, "this trainee account has no trainee record; ask your trainer")
    own = (user.classes[0], user.trainee)
    if (class_name or own[0], trainee or own[1]) != own:
        raise HTTPError(403, "a trainee saves attempts only under their own class and name")
    return own


def save_attempt(store: RecordStore, user: User, class_name: str, trainee: str, record: dict, key: str | None):
    """(id, created?) of the attempt; a known key returns the first save's id."""
    try:
        if key is not None:
            existing = store.attempt_id_for_key(key)
            if existing is not None:
                first = store.get_attempt(existing)
                if not user.can_see(first["class_name"], first["trainee"]):
                    raise HTTPError(409, "this Idempotency-Key was used for another trainee's attempt")
                return first, False
        aid = store.save_attempt(class_name, trainee, record, key=key)
        return store.get_attempt(aid), True
    except HTTPError:
        raise
    except UserError as exc:
        if type(exc) is not UserError:  # WriteFailed and the like: the storage layer answers 503
            raise
        raise HTTPError(422, str(exc)) from None


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
    storage = request.app.state.storage
    user = await storage.run(accounts.check_login, body.get("name"), body.get("password"))
    if user is None:
        raise HTTPError(401, "name or password is wrong")
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
    body = await read_json(request)
    if not isinstance(body, dict):
        raise HTTPError(422, f"an attempt must be a JSON object of fields, got {type(body).__name__}")
    key = request.headers.get(IDEMPOTENCY_HEADER)
    class_name, trainee = file_under(user, body)
    attempt, created = await request.app.state.storage.run(save_attempt, user, class_name, trainee, body, key)
    return JSONResponse(
        {"id": attempt["id"], "attempt": attempt},
        status_code=201 if created else 200,
        headers={"Location": f"/api/attempts/{attempt['id']}"},
    )


async def get_attempt(request: Request) -> Response:
    user = await api_user(request)
    attempt = await request.app.state.storage.run(readable_attempt, user, _attempt_id(request))
    return JSONResponse(attempt)


async def remove_attempt(request: Request) -> Response:
    user = await api_user(request)
    await request.app.state.storage.run(delete_attempt, user, _attempt_id(request))
    return Response(status_code=204)


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
]
