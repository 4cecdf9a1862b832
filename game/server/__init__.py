"""The records server: trainee records of a whole programme on one server (thesis 3.3.4, Fig. 3.11).

``chainsim serve`` runs ``app.build_app`` with uvicorn over the records store (SQLite file or
PostgreSQL): request checks (``auth``, ``throttle``), the JSON API (``api``), the trainers' dashboard
(``dashboard``, ``classpage``, ``plots``, ``replay3d``, ``templates/``, ``static/``), scoring by replay
(``scoring``, ``replayer``, ``store_threads``, ``upload_limit``), the study's pages (``study_api``,
``study_pages``, ``rating_pages``) and the trainer in a browser tab (``train_routes``, ``train_session``,
``frame_tiles``). Accounts and the store are the records feature's (``chainsim.game.records``). The
simulator's side, saving to a server with an offline queue, is ``chainsim.game.records.remote``;
the load benchmark is ``chainsim.tools.bench.records``. docs/records-server.md describes it as a
user sees it.

The web stack is the ``server`` extra (``pip install 'chainsim[server]'``), not a dependency of the
simulator: this package's ``__init__`` and ``accounts`` import none of it, so `chainsim records user`
works without it, and a command that serves asks ``require_web_stack`` first.
"""

from __future__ import annotations

import importlib.util

from chainsim.systems.engine.errors import UserError

#: the programme's address for xAPI identities (default: the address the server listens on)
BASE_URL_ENV = "CHAINSIM_SERVER_URL"

#: the modules of the ``server`` extra (pyproject.toml) that serving imports
WEB_STACK = ("starlette", "uvicorn", "websockets", "jinja2")

#: what to install for them
INSTALL_HINT = "pip install 'chainsim[server]'"


def require_web_stack(needed_by: str | None = None) -> None:
    """Stop with one line naming the extra when the web stack is not installed (a UserError: exit 2,
    no traceback), before anything imports it; ``needed_by`` names a command that starts a server."""
    missing = [name for name in WEB_STACK if importlib.util.find_spec(name) is None]
    if missing:
        lead = f"{needed_by} runs the records server, whose" if needed_by else "the records server's"
        raise UserError(f"{lead} packages are not installed ({', '.join(missing)}): {INSTALL_HINT}")
