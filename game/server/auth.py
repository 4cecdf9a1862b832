"""Who a request comes from, and the checks every route shares: tokens, cookies, CSRF, body limits.

- API requests carry ``Authorization: Bearer <token>`` (tokens from ``POST /api/login`` or
  ``chainsim records user token``); cookies are never accepted there, so the API needs no CSRF.
- Dashboard requests carry the ``chainsim_session`` cookie (HttpOnly, SameSite=Lax, Secure over
  TLS). Every form that changes something carries the session's CSRF token, and a cross-site
  ``Origin`` is refused as well. The sign-in form, which has no session yet, uses a double-submit
  cookie for the same purpose.
- Bodies are read with a hard size limit, whatever Content-Length claims.
"""

from __future__ import annotations

import hmac
import json
import secrets
from typing import Any
from urllib.parse import parse_qs, urlsplit

from starlette.requests import HTTPConnection, Request

from chainsim.game.records import accounts
from chainsim.game.records.accounts import User

SESSION_COOKIE = "chainsim_session"
LOGIN_CSRF_COOKIE = "chainsim_login_csrf"
MAX_JSON_BYTES = 1 << 20  # an attempt with its details and a few X-ray shots' metadata
MAX_FORM_BYTES = 64 << 10
#: objects and lists inside objects and lists; an attempt's details nest 3 or 4 deep. Deeper bodies are
#: refused before any code walks them recursively (that would end in a RecursionError, a 500).
MAX_JSON_DEPTH = 32


class HTTPError(Exception):
    """Ends a request with ``status`` and a one-line ``message`` (JSON for /api, a page otherwise)."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers or {}


async def read_body(request: Request, limit: int) -> bytes:
    """The request body, or 413 as soon as it passes ``limit`` bytes."""
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            if int(declared) > limit:
                raise HTTPError(413, f"request body is {int(declared)} bytes; at most {limit} accepted")
        except ValueError:
            raise HTTPError(400, "Content-Length is not a number") from None
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise HTTPError(413, f"request body is over {limit} bytes; at most {limit} accepted")
        chunks.append(chunk)
    return b"".join(chunks)


async def read_json(request: Request, limit: int = MAX_JSON_BYTES) -> Any:
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise HTTPError(415, f"expected Content-Type application/json, got {ctype or 'none'}")
    body = await read_body(request, limit)
    try:
        value = json.loads(body.decode("utf-8"), parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise HTTPError(400, f"request body is not valid JSON ({_short(exc)})") from None
    except RecursionError:
        raise HTTPError(400, f"request body nests too deeply; at most {MAX_JSON_DEPTH} levels accepted") from None
    where = too_deep(value, MAX_JSON_DEPTH)
    if where is not None:
        raise HTTPError(
            422, f"{where} nests more than {MAX_JSON_DEPTH} levels of objects or lists; at most {MAX_JSON_DEPTH}"
        )
    return value


def too_deep(value: Any, limit: int) -> str | None:
    """What in ``value`` nests deeper than ``limit`` (``field 'details'``, or ``request body``), else None.

    Walked with a stack, not recursion, so any depth the JSON parser accepted is measured safely."""
    stack: list[tuple[Any, int, Any]] = [(value, 1, None)]  # (item, its depth, the top-level field it is in)
    while stack:
        item, depth, top = stack.pop()
        if isinstance(item, dict):
            children = item.items()
        elif isinstance(item, list):
            children = enumerate(item)
        else:
            continue
        if depth > limit:
            return "request body" if top is None else f"field {top!r}"
        for key, child in children:
            stack.append((child, depth + 1, key if item is value and isinstance(value, dict) else top))
    return None


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _short(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text[:120]


async def read_form(request: Request) -> dict[str, str]:
    """An ``application/x-www-form-urlencoded`` form (what the dashboard's forms send)."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/x-www-form-urlencoded":
        raise HTTPError(415, "expected a form (application/x-www-form-urlencoded)")
    body = await read_body(request, MAX_FORM_BYTES)
    try:
        fields = parse_qs(body.decode("utf-8"), keep_blank_values=True, max_num_fields=20, strict_parsing=False)
    except (UnicodeDecodeError, ValueError) as exc:
        raise HTTPError(400, f"form is malformed ({_short(exc)})") from None
    return {k: v[0] for k, v in fields.items()}


def bearer_token(request: Request) -> str | None:
    value = request.headers.get("authorization", "")
    scheme, _, token = value.partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


async def api_user(request: Request) -> User:
    """The account behind the request's bearer token, or 401."""
    token = bearer_token(request)
    if token is None:
        raise HTTPError(401, "sign in first: send Authorization: Bearer <token>", {"WWW-Authenticate": "Bearer"})
    user = await request.app.state.storage.run(accounts.user_for_token, token)
    if user is None:
        raise HTTPError(
            401,
            "token is unknown, revoked or expired; sign in again",
            {"WWW-Authenticate": 'Bearer error="invalid_token"'},
        )
    return user


async def session(request: HTTPConnection) -> tuple[User, str] | None:
    """(account, CSRF token) of the request's session cookie, or None."""
    sid = request.cookies.get(SESSION_COOKIE)
    if not sid:
        return None
    return await request.app.state.storage.run(accounts.session_user, sid)


async def page_or_api_user(request: Request) -> User | None:
    """For read-only downloads: a bearer token if one is sent, else the session cookie."""
    if bearer_token(request) is not None:
        return await api_user(request)
    found = await session(request)
    return None if found is None else found[0]


def same_origin(request: Request) -> bool:
    """False when the browser says the form came from another site."""
    origin = request.headers.get("origin")
    if origin is None or origin == "null":
        return origin is None
    parts = urlsplit(origin)
    return parts.netloc == request.headers.get("host", "") and parts.scheme in ("http", "https")


def check_csrf(request: Request, form: dict[str, str], expected: str) -> None:
    if not same_origin(request):
        raise HTTPError(403, "form sent from another site; refused")
    sent = form.get("csrf", "")
    if not sent or not hmac.compare_digest(sent.encode(), expected.encode()):
        raise HTTPError(403, "form expired or forged (CSRF check failed); reload the page and try again")


def new_login_csrf() -> str:
    return secrets.token_urlsafe(24)
