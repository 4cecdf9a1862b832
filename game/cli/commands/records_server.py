"""The server-side actions of `chainsim records`: accounts, sign-in to a server, sync, xAPI export.

    records user add --role trainer|trainee --class C NAME   (password asked, or --password-stdin)
    records user list | token NAME [--days N] | passwd NAME | remove NAME --yes
    records login URL NAME [--cafile PEM]   sign the simulator in to a records server (keeps the token,
                                    and the authority to trust for a server with its own certificate)
    records sync [--server URL]     send attempts waiting in the local queue
    records export --format xapi --out FILE [--lrs URL]   xAPI 1.0.3 statements

``records.py`` builds the parser of the other actions and hands these to ``run``.
"""

from __future__ import annotations

import argparse
import getpass
import os
import sys
from pathlib import Path

from chainsim.game.records import accounts, remote, report, xapi
from chainsim.systems.engine.errors import UserError

ACTIONS = ("user", "login", "sync")
LRS_AUTH_ENV = "CHAINSIM_LRS_AUTH"


def add_actions(action) -> None:
    """Add the parsers of ACTIONS through records.py's ``action(name, help)``."""
    u = action("user", "accounts of the records server (trainers and trainees)")
    users = u.add_subparsers(dest="user_action", metavar="USER_ACTION", required=True)
    a = users.add_parser("add", help="create an account", description="create an account")
    a.add_argument("--role", choices=("trainer", "trainee"), required=True)
    a.add_argument(
        "--class",
        dest="classes",
        action="append",
        default=[],
        metavar="C",
        help="a trainee's class (one), or a class a trainer teaches (repeat for more)",
    )
    a.add_argument("--password-stdin", action="store_true", help="read the password from the first line of stdin")
    a.add_argument("name", help="account name (1-64 characters; a trainee's name in the records)")
    users.add_parser("list", help="accounts with role and classes")
    a = users.add_parser("token", help="issue an API token for an account (printed once)")
    a.add_argument("name")
    a.add_argument("--days", type=float, default=180.0, help="valid for this many days (default 180)")
    a = users.add_parser("passwd", help="set a new password (signs the account out everywhere)")
    a.add_argument("name")
    a.add_argument("--password-stdin", action="store_true", help="read the password from the first line of stdin")
    a = users.add_parser("remove", help="delete an account (its attempts stay)")
    a.add_argument("name")
    a.add_argument("--yes", action="store_true", help="really delete")

    a = action("login", "sign the simulator in to a records server; the token is kept in the local store")
    a.add_argument("server", metavar="URL", help="records server, e.g. http://127.0.0.1:8000")
    a.add_argument("name", help="your account name")
    a.add_argument("--password-stdin", action="store_true", help="read the password from the first line of stdin")
    a.add_argument(
        "--cafile",
        metavar="PEM",
        help="an https server with its own certificate: the PEM of the authority that signed it (or the "
        "certificate itself), trusted for this server from now on; kept for later sends and syncs",
    )

    a = action("sync", "send attempts waiting in the local queue to their records server")
    a.add_argument("--server", metavar="URL", help="only this server")


def add_export_options(export: argparse.ArgumentParser) -> None:
    export.add_argument("--format", choices=("csv", "xapi"), default=None, help="csv (default) or xapi statements")
    export.add_argument("--out", type=Path, metavar="FILE", help="output file (--csv FILE is the same for csv)")
    export.add_argument("--homepage", default=None, metavar="URL", help="xAPI: the programme's home page for accounts")
    export.add_argument(
        "--lrs", metavar="URL", help=f"xAPI: also POST the statements to this LRS (auth: ${LRS_AUTH_ENV})"
    )


def _password(args, confirm: bool = True) -> str:
    if args.password_stdin:
        line = sys.stdin.readline()
        if not line:
            raise UserError("--password-stdin: stdin is empty; expected the password on its first line")
        return line.rstrip("\r\n")
    if not sys.stdin.isatty():
        raise UserError("no terminal to ask the password on; pipe it with --password-stdin")
    first = getpass.getpass("password: ")
    if confirm and getpass.getpass("again: ") != first:
        raise UserError("the two passwords differ; nothing changed")
    return first


def run(args, store) -> int:
    act = args.action
    if act == "user":
        sub = args.user_action
        if sub == "add":
            user = accounts.add_user(store, args.name, args.role, _password(args), args.classes)
            print(f"added {user.role} {user.name!r} ({', '.join(user.classes)})", file=sys.stderr)
        elif sub == "list":
            rows = [[u.name, u.role, ", ".join(u.classes)] for u in accounts.list_users(store)]
            print(report.table(["name", "role", "classes"], rows))
        elif sub == "token":
            if not 0 < args.days <= 3650:
                raise UserError(f"--days must be in (0, 3650], got {args.days}")
            user = next((u for u in accounts.list_users(store) if u.name == args.name.strip()), None)
            if user is None:
                raise UserError(f"no user named {args.name.strip()!r}")
            token, _ = accounts.issue_token(store, user, "cli", args.days * 86400)
            print(token)
        elif sub == "passwd":
            accounts.set_password(store, args.name, _password(args))
            print(f"new password for {args.name.strip()!r}; its sessions and tokens are revoked", file=sys.stderr)
        elif sub == "remove":
            if not args.yes:
                raise UserError(f"would remove user {args.name.strip()!r}; re-run with --yes")
            accounts.remove_user(store, args.name)
            print(f"removed user {args.name.strip()!r}", file=sys.stderr)
        return 0
    if act == "login":
        if args.cafile is not None:  # a wrong file is said before the password is asked
            remote.read_cafile(args.cafile)
        user = remote.login(store, args.server, args.name, _password(args, confirm=False), args.cafile)
        print(f"signed in to {remote.server_url(args.server)} as {user['name']} ({user['role']})", file=sys.stderr)
        return 0
    if act == "sync":
        result = remote.sync(store, args.server)
        for line in result["problems"]:
            print(line, file=sys.stderr)
        print(f"sent {result['sent']} attempt(s); {result['waiting']} waiting")
        return 0 if not result["problems"] else 1
    raise UserError(f"unknown records action {act!r}")


def export_xapi(args, rows) -> None:
    stmts = xapi.statements(rows, args.homepage or xapi.DEFAULT_HOMEPAGE)
    if args.out is None and args.lrs is None:
        raise UserError("--format xapi needs --out FILE, --lrs URL or both")
    if args.out is not None:
        report.atomic_write(args.out, lambda fh: fh.write(xapi.dumps(stmts)), binary=False)
        print(f"wrote {len(stmts)} xAPI statement(s) to {args.out}", file=sys.stderr)
    if args.lrs is not None:
        taken = xapi.post_statements(stmts, args.lrs, os.environ.get(LRS_AUTH_ENV) or None)
        print(f"posted {taken} xAPI statement(s) to {args.lrs}", file=sys.stderr)
