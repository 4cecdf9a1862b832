"""The records server as one ASGI app (Starlette), and ``serve`` to run it with uvicorn.

Routes come from ``api`` (JSON under /api) and ``views`` (the dashboard); static files from the
package's ``static`` folder. Every error leaves as one line: JSON ``{"error": ...}`` under /api,
a short page elsewhere; a database that cannot serve a request answers 503 (retry), never a
traceback. Every response gets headers that keep the pages to this origin (no scripts, styles or
images from elsewhere, no framing).
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Callable
from contextlib import asynccontextmanager
from typing import Any

from starlette.applications import Starlette
from starlette.datastructures import MutableHeaders
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import Mount
from starlette.staticfiles import StaticFiles

from chainsim.game.records import remote, xapi
from chainsim.game.server import BASE_URL_ENV, api, scoring, study_api, train_routes
from chainsim.game.server import dashboard as views
from chainsim.game.server import rating_pages as rating_routes
from chainsim.game.server import upload_limit as ratelimit
from chainsim.game.server.auth import HTTPError
from chainsim.game.server.store_threads import Storage, Unavailable
from chainsim.game.server.throttle import Throttle
from chainsim.systems.engine.errors import UserError

logger = logging.getLogger(__name__)

#: uploads read and checked at once (each holds its body, at most about 1 MB, while it is checked)
UPLOADS_AT_ONCE = 8


SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self'; style-src 'self'; script-src 'none'; "
        "frame-ancestors 'none'; form-action 'self'; base-uri 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
    "X-Frame-Options": "DENY",
}


def _error(request: Request, status: int, message: str, headers: dict[str, str] | None = None) -> Response:
    if request.url.path.startswith("/api/") or request.url.path == "/api":
        return JSONResponse({"error": message}, status_code=status, headers=headers)
    page = views.render("error.html", status, status=status, message=message)
    page.headers.update(headers or {})  # Retry-After on a 429 or 503 page too
    return page


async def _http_error(request: Request, exc: HTTPError) -> Response:
    return _error(request, exc.status, exc.message, exc.headers)


async def _starlette_error(request: Request, exc: HTTPException) -> Response:
    return _error(request, exc.status_code, exc.detail or "error", dict(exc.headers or {}))


async def _redirect(request: Request, exc: views.Redirect) -> Response:
    return RedirectResponse(exc.location, status_code=303)


async def _unavailable(request: Request, exc: Unavailable) -> Response:
    return _error(request, 503, f"records database busy or unreachable; try again ({exc})", {"Retry-After": "1"})


async def _user_error(request: Request, exc: UserError) -> Response:
    return _error(request, 422, str(exc))


def build_app(
    db: str | None,
    *,
    pack_paths: list[str] | tuple = (),
    scorers: int = scoring.DEFAULT_WORKERS,
    lease_s: float = scoring.DEFAULT_LEASE_S,
    base_url: str = xapi.DEFAULT_HOMEPAGE,
    train_max_s: float | None = None,
    max_session_s: float = scoring.DEFAULT_MAX_SESSION_S,
    uploads_per_minute: float = ratelimit.DEFAULT_PER_MINUTE,
) -> Starlette:
    """The app over the records database ``db`` (a path, a postgresql:// URL, or None: default file).

    ``scorers`` replays run at once (``chainsim.game.server.scoring``); packs are the built-in and
    installed ones plus ``pack_paths``. ``train_max_s``: the longest a browser training session runs
    (``serve --train-max-minutes``; None: $CHAINSIM_TRAIN_MAX_S, else ``train_routes``' default)."""
    storage = Storage(db)
    packs = scoring.ServerPacks(pack_paths)
    scorer = scoring.Scorer(db, packs, scorers, lease_s, max_session_s)

    @asynccontextmanager
    async def lifespan(app: Starlette):
        scorer.start()  # uploads a killed server left waiting are scored now
        yield
        scorer.stop()
        replays = getattr(app.state, "replays", None)
        if replays is not None:  # the attempt pages' replay process, started when first asked for
            replays.close()
        storage.close()

    # starlette calls each handler with its own exception class, which its handler type cannot say
    handlers: dict[Any, Callable[..., Any]] = {
        HTTPError: _http_error,
        HTTPException: _starlette_error,
        views.Redirect: _redirect,
        Unavailable: _unavailable,
        UserError: _user_error,
    }
    app = Starlette(
        routes=[
            *api.routes,
            *study_api.routes,
            *views.routes,
            *rating_routes.routes,
            Mount("/static", app=StaticFiles(packages=[("chainsim.game.server", "static")]), name="static"),
        ],
        exception_handlers=handlers,
        middleware=[Middleware(SecurityHeaders)],
        lifespan=lifespan,
    )
    app.state.storage = storage
    app.state.packs = packs
    app.state.scorer = scorer
    app.state.throttle = Throttle()
    app.state.upload_rate = ratelimit.UploadRate(uploads_per_minute)
    app.state.upload_slots = asyncio.Semaphore(UPLOADS_AT_ONCE)
    train_routes.install(app, max_s=train_max_s)  # /train/PACK: the trainer in a browser tab
    # the programme's address in xAPI identities: configured, never taken from a request's Host header
    app.state.base_url = remote.server_url(base_url)
    return app


class SecurityHeaders:
    """ASGI middleware adding SECURITY_HEADERS (and no-store outside /static) to every response."""

    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        static = scope.get("path", "").startswith("/static/")

        async def send_with_headers(message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for key, value in SECURITY_HEADERS.items():
                    headers.setdefault(key, value)
                if not static:
                    headers.setdefault("Cache-Control", "no-store")
                if scope.get("scheme") == "https":  # browsers keep to TLS for this host from now on
                    headers.setdefault("Strict-Transport-Security", "max-age=31536000")
            await send(message)

        await self.app(scope, receive, send_with_headers)


def serve(
    db: str | None,
    host: str = "127.0.0.1",
    port: int = 8000,
    *,
    certfile: str | None = None,
    keyfile: str | None = None,
    log_level: str = "info",
    pack_paths: list[str] | tuple = (),
    scorers: int = scoring.DEFAULT_WORKERS,
    base_url: str | None = None,
    trust_proxy: list[str] | tuple = (),
    train_max_s: float | None = None,
    max_session_s: float = scoring.DEFAULT_MAX_SESSION_S,
    uploads_per_minute: float = ratelimit.DEFAULT_PER_MINUTE,
) -> None:
    """Run the server until interrupted (uvicorn, one process; replays in ``scorers`` processes beside it).

    ``base_url`` (``serve --base-url``) is the programme's address in xAPI identities; without it
    $CHAINSIM_SERVER_URL, else the address the server listens on. ``trust_proxy`` (``serve
    --trust-proxy``): the addresses of proxies whose X-Forwarded-For and X-Forwarded-Proto are believed;
    without one the client is the socket's peer, whatever a request's headers say."""
    import uvicorn  # noqa: PLC0415 - only `chainsim serve` needs the server

    if base_url is not None:
        try:
            base_url = remote.server_url(base_url)
        except UserError as exc:
            raise UserError(f"--base-url: {exc}") from None
    else:
        base_url = os.environ.get(BASE_URL_ENV, "").strip() or f"{'https' if certfile else 'http'}://{host}:{port}"
        try:
            base_url = remote.server_url(base_url)
        except UserError as exc:
            raise UserError(f"${BASE_URL_ENV}: {exc}") from None
    app = build_app(
        db,
        pack_paths=pack_paths,
        scorers=scorers,
        base_url=base_url,
        train_max_s=train_max_s,
        max_session_s=max_session_s,
        uploads_per_minute=uploads_per_minute,
    )
    logger.info(
        "records server on %s://%s:%d, database %s",
        "https" if certfile else "http",
        host,
        port,
        app.state.storage.where,
    )
    uvicorn.run(
        app,
        host=host,
        port=port,
        log_level=log_level,
        ssl_certfile=certfile,
        ssl_keyfile=keyfile,
        access_log=False,
        # a proxy's headers only from the proxies named: anyone else could choose the address the
        # sign-in throttle counts against (chainsim.game.server.throttle)
        proxy_headers=bool(trust_proxy),
        forwarded_allow_ips=list(trust_proxy) or None,
    )
