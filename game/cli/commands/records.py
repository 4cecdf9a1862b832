"""`chainsim records`: view, export, plot and delete trainee records (thesis 3.3.4, Fig. 3.11).

The command-line face of the assessment tool: list classes and trainees, show or delete a saved
attempt, export a selection as CSV, or plot one trainee's progress. The store itself lives in
``chainsim.game.records.store``; this module only parses arguments and prints.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from chainsim.game.cli.commands import records_queue, records_server
from chainsim.game.records import report as report
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import printable
from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import records_layout

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

NAME = "records"
HELP = "view, export, plot or delete trainee records (classes, trainees, attempts)"
#: actions that look at what exists: on a path with no database they say so (a mistyped --db)
READ_ONLY = ("classes", "trainees", "list", "show", "plot", "delete", "uploads")

_EPILOG = """\
database: --db PATH or postgresql:// URL, else $CHAINSIM_DB, else the user data folder (records.sqlite3).
examples:
  chainsim records classes
  chainsim records list --class c1 --trainee alice
  chainsim records export --csv c1.csv --class c1
  chainsim records plot --class c1 --trainee alice --out alice.png
  chainsim records delete 12 --yes
  chainsim records export --format xapi --out c1.xapi.json --class c1
  chainsim records user add --role trainer --class c1 dr_jones
  chainsim records login http://127.0.0.1:8000 alice ; chainsim records sync
"""


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        NAME,
        help=HELP,
        description=HELP,
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    db_help = "records database file (default: $CHAINSIM_DB or user data folder)"
    p.add_argument("--db", metavar="PATH", help=db_help)
    # Also accepted after the action (`records list --db x`); SUPPRESS keeps an earlier --db.
    db_after = argparse.ArgumentParser(add_help=False)
    db_after.add_argument("--db", metavar="PATH", default=argparse.SUPPRESS, help=db_help)
    acts = p.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, help: str) -> argparse.ArgumentParser:
        return acts.add_parser(name, help=help, description=help, parents=[db_after])

    action("classes", "list classes with trainee and attempt counts")

    a = action("trainees", "list trainees with attempt counts")
    a.add_argument("--class", dest="class_name", metavar="C", help="only this class")

    a = action("list", "table of attempts, oldest first")
    a.add_argument("--class", dest="class_name", metavar="C", help="only this class")
    a.add_argument("--trainee", metavar="T", help="only this trainee")

    a = action("show", "every field of one attempt")
    a.add_argument("id", type=_positive_id, help="attempt id (from `list`)")

    a = action("export", "write attempts to a CSV file or as xAPI statements (atomically)")
    a.add_argument("--csv", type=Path, metavar="FILE", help="output CSV file")
    a.add_argument("--class", dest="class_name", metavar="C", help="only this class")
    a.add_argument("--trainee", metavar="T", help="only this trainee")
    records_server.add_export_options(a)
    records_server.add_actions(action)
    records_queue.add_actions(action)

    a = action("delete", "delete one attempt (needs --yes)")
    a.add_argument("id", type=_positive_id, help="attempt id (from `list`)")
    a.add_argument("--yes", action="store_true", help="really delete; without it only show what would go")

    a = action("add-class", "create a class (and the database, if new)")
    a.add_argument("name", help=f"class name (1-{limits.MAX_NAME_LENGTH} characters)")

    a = action("add-trainee", "add a trainee to a class (created if missing)")
    a.add_argument("class_name", metavar="CLASS", help="class name")
    a.add_argument("name", help=f"trainee name (1-{limits.MAX_NAME_LENGTH} characters)")

    a = action("plot", "PNG of one trainee's errors (marked points, needle) and X-rays over attempts")
    a.add_argument("--class", dest="class_name", metavar="C", required=True, help="class name")
    a.add_argument("--trainee", metavar="T", required=True, help="trainee name")
    a.add_argument("--out", required=True, type=Path, metavar="FILE.png", help="output PNG file")
    return p


_positive_id = argtypes.count(1, limits.MAX_ATTEMPT_ID)
#: the fixed fields `list` shows (the needle procedure's; the dose is left to `show` and the exports)
_LISTED = LAYOUT.columns[:8]


def _summary(a: dict) -> str:
    errors = []
    for c in LAYOUT.columns[1:3]:  # the two errors of 6.1.5, in mm; the needle's is None when it touched nothing
        errors.append(f"{c.short.removesuffix('_mm')} " + ("-" if a.get(c.name) is None else f"{a[c.name]:.2f} mm"))
    return (
        f"attempt {a['id']}: {printable(a['class_name'])}/{printable(a['trainee'])} {printable(a['pack'])} "
        f"{printable(a['created_at'])} {', '.join(errors)}, target {a['target']}"
    )


def _attempts_table(rows) -> str:
    """`records list`: one line per attempt, the listed metrics around its target."""
    return report.table(
        [
            "id",
            "created_at",
            "class",
            "trainee",
            "pack",
            *(c.short for c in _LISTED[:3]),
            "target",
            *(c.short for c in _LISTED[3:]),
        ],
        [
            [
                a["id"],
                a["created_at"],
                a["class_name"],
                a["trainee"],
                a["pack"],
                *(a.get(c.name) for c in _LISTED[:3]),  # an attempt of another procedure has none of them
                a["target"],
                *(a.get(c.name) for c in _LISTED[3:]),
            ]
            for a in rows
        ],
    )


def _show(a: dict) -> None:
    """`records show`: every field of one attempt, one a line."""
    width = max(len(k) for k in a)
    for key, value in a.items():
        text = json.dumps(value, sort_keys=True) if isinstance(value, dict) else ("-" if value is None else value)
        print(f"{key.ljust(width)}  {printable(str(text))}")


def _export(args, store) -> None:
    """`records export`: the attempts as CSV (--csv / --out) or as xAPI statements (--format xapi)."""
    fmt = args.format or "csv"
    if fmt == "csv" and (args.csv or args.out) is None:
        raise UserError("export needs --csv FILE (or --format xapi --out FILE)")
    if fmt == "xapi" and args.csv is not None:
        raise UserError("--csv writes CSV; with --format xapi use --out FILE")
    rows = store.list_attempts(args.class_name, args.trainee)
    if fmt == "xapi":
        records_server.export_xapi(args, rows)
    else:
        report.export_csv(rows, args.csv or args.out)
        print(f"wrote {len(rows)} attempt(s) to {args.csv or args.out}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:

    with RecordStore(args.db, create=args.action not in READ_ONLY) as store:
        act = args.action
        if act in records_server.ACTIONS:
            return records_server.run(args, store)
        if act in records_queue.ACTIONS:
            return records_queue.run(args, store)
        if act == "classes":
            rows = store.class_summary()
            print(
                report.table(
                    ["class", "trainees", "attempts"], [[r["class_name"], r["trainees"], r["attempts"]] for r in rows]
                )
            )
        elif act == "trainees":
            rows = store.list_trainees(args.class_name)
            print(
                report.table(
                    ["class", "trainee", "attempts"], [[r["class_name"], r["trainee"], r["attempts"]] for r in rows]
                )
            )
        elif act == "list":
            print(_attempts_table(store.list_attempts(args.class_name, args.trainee)))
        elif act == "show":
            _show(store.get_attempt(args.id))
        elif act == "export":
            _export(args, store)
        elif act == "delete":
            a = store.get_attempt(args.id)
            if not args.yes:
                raise UserError(f"would delete {_summary(a)}; re-run with --yes to delete it")
            store.delete_attempt(args.id)
            print(f"deleted {_summary(a)}", file=sys.stderr)
        elif act == "add-class":
            store.add_class(args.name)
            print(f"added class {args.name.strip()!r}", file=sys.stderr)
        elif act == "add-trainee":
            created = store.add_trainee(args.class_name, args.name)
            note = " (new class)" if created else ""
            print(f"added trainee {args.name.strip()!r} to class {args.class_name.strip()!r}{note}", file=sys.stderr)
        elif act == "plot":
            rows = store.list_attempts(args.class_name, args.trainee)
            title = f"{args.trainee.strip()} ({args.class_name.strip()})"
            report.plot_progress(rows, args.out, title)
            print(f"wrote progress plot of {len(rows)} attempt(s) to {args.out}", file=sys.stderr)
        else:  # argparse guarantees one of the above
            raise UserError(f"unknown records action {act!r}")
    return 0
