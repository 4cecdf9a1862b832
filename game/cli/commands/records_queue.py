"""The scoring queue and provenance rules of `chainsim records`, run on the server's database.

    records uploads [--state waiting|refused|all]    the uploads the server has not scored
    records uploads cancel ID --reason TEXT         withdraw one (sent by mistake); audited
    records uploads refuse ID --reason TEXT         refuse one (not a person's attempt); audited
    records witnessed CLASS [--off]                 the class takes only attempts made in the browser
                                                    trainer, which the server witnesses (or no longer)

``records.py`` builds the parser of the other actions and hands these to ``run``.
"""

from __future__ import annotations

import argparse
import getpass
import sys

from chainsim.game.records import report
from chainsim.game.records.store import RecordStore
from chainsim.game.server import scoring
from chainsim.systems.engine import limits

ACTIONS = ("uploads", "witnessed")


def _upload_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an upload id (a whole number), got {text[:40]!r}") from None
    if not 1 <= value <= limits.MAX_ATTEMPT_ID:
        raise argparse.ArgumentTypeError(f"expected an upload id from 1 to {limits.MAX_ATTEMPT_ID}, got {value}")
    return value


def add_actions(action) -> None:
    """Add the parsers of ACTIONS through records.py's ``action(name, help)``."""
    u = action("uploads", "the server's scoring queue: list, cancel or refuse uploads not scored yet")
    u.add_argument("--state", choices=("waiting", "refused", "all"), default="waiting", help="which (default waiting)")
    ups = u.add_subparsers(dest="uploads_action", metavar="UPLOADS_ACTION")
    for name, what in (("cancel", "withdraw an upload (sent by mistake)"), ("refuse", "refuse an upload")):
        a = ups.add_parser(name, help=what, description=what)
        a.add_argument("id", type=_upload_id, help="upload id (from `records uploads`)")
        a.add_argument("--reason", required=True, help="why, in 1-500 characters (kept in the audit log)")
    a = action("witnessed", "require witnessed attempts (made in the browser trainer) in a class, or no longer")
    a.add_argument("class_name", metavar="CLASS", help="class name")
    a.add_argument("--off", action="store_true", help="accept attempts uploaded from the window again")


def _actor() -> str:
    try:
        return f"administrator {getpass.getuser()}"
    except (KeyError, OSError):
        return "administrator"


def run(args: argparse.Namespace, store: RecordStore) -> int:
    if args.action == "witnessed":
        on = store.require_witnessed(args.class_name, not args.off)
        with store.transaction() as conn:
            detail = "required" if on else "no longer required"
            store.audit(conn, _actor(), "witnessed", args.class_name.strip(), detail)
        state = "takes only witnessed attempts" if on else "accepts attempts uploaded from the window"
        print(f"class {args.class_name.strip()!r} {state}", file=sys.stderr)
        return 0
    how = getattr(args, "uploads_action", None)
    if how is not None:
        row = scoring.end_upload(store, args.id, _actor(), how, args.reason)
        print(f"upload {row['id']} ({row['class_name']}/{row['trainee']}): {row['error']}", file=sys.stderr)
        return 0
    rows = scoring.list_queue(store, args.state)
    print(
        report.table(
            ["id", "class", "trainee", "received", "pack", "state", "tries", "from", "note"],
            [
                [
                    r["id"],
                    r["class_name"],
                    r["trainee"],
                    r["received_at"],
                    r["pack"],
                    "scoring now" if r["state"] == "scoring" and r["claimed_by"] else r["state"],
                    r["tries"],
                    "browser" if r["witnessed"] else "window",
                    (r["error"] or "")[:60],
                ]
                for r in rows
            ],
        )
    )
    if not rows:
        print(f"no {args.state if args.state != 'all' else ''} uploads".replace("  ", " "), file=sys.stderr)
    return 0
