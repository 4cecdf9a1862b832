"""`chainsim serve`: run the records server (dashboard and JSON API) over a records database.

The server's web stack is the ``server`` extra: `chainsim serve --help` works without it, and
`chainsim serve` says in one line what to install (chainsim.game.server.require_web_stack)."""

from __future__ import annotations

import argparse
import ipaddress
import logging

from chainsim.game.records import remote
from chainsim.game.server import BASE_URL_ENV, require_web_stack
from chainsim.systems.engine.errors import UserError

NAME = "serve"
HELP = "run the records server: trainers' dashboard and JSON API over the records database"

_EPILOG = """\
database: --db PATH or postgresql://USER@HOST/DBNAME, else $CHAINSIM_DB, else the user data folder.
accounts: chainsim records user add --role trainer --class C NAME (see docs/records-server.md).
examples:
  chainsim serve --db programme.sqlite3 --port 8000
  chainsim serve --db postgresql://chainsim@db.example.org/records --host 0.0.0.0 --certfile c.pem --keyfile k.pem \\
      --base-url https://training.example.org
"""


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port must be a whole number, got {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 1-65535, got {value}")
    return value


def _proxy(text: str) -> str:
    try:
        if "/" not in text:
            return str(ipaddress.ip_address(text.strip()))
        return str(ipaddress.ip_network(text.strip(), strict=True))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected the proxy's IP address (such as 127.0.0.1) or network (such as 10.0.0.0/8), got {text[:64]!r}"
        ) from None


def _minutes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of minutes, got {text[:64]!r}") from None
    if not 0 < value <= 24 * 60:
        raise argparse.ArgumentTypeError(f"expected minutes above 0 and at most 1440 (a day), got {text[:64]!r}")
    return value


def add_parser(sub):
    p = sub.add_parser(
        NAME, help=HELP, description=HELP, epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--db", metavar="PATH|URL", help="records database: SQLite file or postgresql:// URL")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=_port, default=8000, help="port (default 8000)")
    p.add_argument("--certfile", metavar="PEM", help="TLS certificate: serve https (needed off this machine)")
    p.add_argument("--keyfile", metavar="PEM", help="TLS private key for --certfile")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR", help="more packs to score attempts of")
    p.add_argument(
        "--base-url",
        metavar="URL",
        help=f"the programme's public address, used in xAPI identities (default ${BASE_URL_ENV}, else the address "
        "the server listens on); never taken from a request",
    )
    p.add_argument(
        "--scorers", type=int, default=2, metavar="N", help="attempts replayed at once, one process each (default 2)"
    )
    p.add_argument(
        "--max-session-minutes",
        type=_minutes,
        default=45.0,
        metavar="M",
        help="the longest session a recording may hold (simulated minutes, default 45); a longer one is refused",
    )
    p.add_argument(
        "--uploads-per-minute",
        type=float,
        default=6.0,
        metavar="N",
        help="uploads an account may file a minute on average, 20 at once (default 6); past it: 429 and Retry-After",
    )
    p.add_argument(
        "--trust-proxy",
        action="append",
        default=[],
        type=_proxy,
        metavar="ADDR",
        help="a reverse proxy's IP address (or network): its X-Forwarded-For and X-Forwarded-Proto are believed; "
        "repeatable. Without it the client is the connection's own address",
    )
    p.add_argument(
        "--train-max-minutes",
        type=_minutes,
        metavar="M",
        help="the longest a browser training session (/train/PACK) runs, input or not "
        "(default $CHAINSIM_TRAIN_MAX_S seconds, else 120 minutes)",
    )
    return p


def run(args) -> int:
    require_web_stack()
    from chainsim.game.server.app import serve  # noqa: PLC0415 - the web stack, once it is known to be there

    if not 0.1 <= args.uploads_per_minute <= 10000:
        raise UserError(f"--uploads-per-minute: expected 0.1 to 10000, got {args.uploads_per_minute:g}")
    if bool(args.certfile) != bool(args.keyfile):
        raise UserError("--certfile and --keyfile go together")
    if args.base_url is not None:
        try:
            remote.server_url(args.base_url)
        except UserError:
            raise UserError(
                f"--base-url {args.base_url[:200]!r}: expected the programme's public address, such as "
                "https://training.example.org (scheme, host, optional port and path)"
            ) from None
    if args.host not in ("127.0.0.1", "localhost", "::1") and not args.certfile:
        logging.getLogger(__name__).warning(
            "listening on %s without TLS: passwords and cookies cross the network in clear; "
            "use --certfile/--keyfile or a TLS proxy in front",
            args.host,
        )
    level = logging.getLogger().getEffectiveLevel()
    serve(
        args.db,
        args.host,
        args.port,
        certfile=args.certfile,
        keyfile=args.keyfile,
        log_level="warning" if level >= logging.WARNING else "info",
        pack_paths=args.pack_path,
        scorers=args.scorers,
        max_session_s=args.max_session_minutes * 60.0,
        uploads_per_minute=args.uploads_per_minute,
        base_url=args.base_url,
        trust_proxy=args.trust_proxy,
        train_max_s=None if args.train_max_minutes is None else args.train_max_minutes * 60.0,
    )
    return 0
