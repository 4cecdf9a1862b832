"""`chainsim rating`: a blinded rating of attempts by raters in the browser, and its agreement report.

    chainsim rating create --db DB --name SET --attempts 3,4,5 (or --study NAME) --rater A --rater B
        makes the set (each attempt under a random code) and prints each rater's secret link on the
        records server (--base-url, default $CHAINSIM_SERVER_URL): the link opens that rater's coded
        attempts, each replayed in 3-D beside the global rating form, without names, class, dates or
        the simulator's scores (chainsim.game.study.rating, chainsim.game.server.rating_pages);
    chainsim rating report --db DB --name SET --pack PACK --out DIR
        the raters' agreement (ICC with its 95 % interval) and each metric's correlation with their
        scores: agreement.md, ratings.csv, ratings.png (chainsim.game.study.rating_report).

docs/validity.md, "Blinded rating", walks through it.
"""

from __future__ import annotations

import argparse
import math
import os

from chainsim.game.common.outputs import prepare_output_dir
from chainsim.game.records.backend import is_postgres, redact
from chainsim.game.records.store import RecordStore
from chainsim.game.study import rating, rating_report
from chainsim.systems.engine.errors import UserError

NAME = "rating"
HELP = "a blinded rating of attempts by raters in the browser, and the raters' agreement"
BASE_URL_ENV = "CHAINSIM_SERVER_URL"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    acts = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    c = acts.add_parser("create", help="make a rating set and print each rater's secret link")
    c.add_argument("--db", metavar="PATH|URL", help="the records server's database")
    c.add_argument("--name", required=True, help="the rating set's name")
    which = c.add_mutually_exclusive_group(required=True)
    which.add_argument("--attempts", metavar="IDS", help="attempt ids, comma-separated")
    which.add_argument("--study", metavar="NAME", help="every scored attempt of this study (details.protocol.study)")
    c.add_argument("--rater", action="append", required=True, metavar="NAME", help="a rater (give two or more)")
    c.add_argument("--base-url", metavar="URL", help=f"the records server's address (default ${BASE_URL_ENV})")
    r = acts.add_parser("report", help="the raters' agreement and each metric against their scores")
    r.add_argument("--db", metavar="PATH|URL", help="the records server's database")
    r.add_argument("--name", required=True, help="the rating set's name")
    r.add_argument("--pack", required=True, help="the pack whose [metrics] are compared with the ratings")
    r.add_argument("--out", required=True, metavar="DIR", help="folder for agreement.md, ratings.csv, ratings.png")
    r.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def _ids(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UserError(f"--attempts {text!r}: expected attempt ids separated by commas, e.g. 3,4,5") from None


def _study_attempts(store: RecordStore, study: str) -> list[int]:
    ids = [
        int(a["id"])
        for a in store.list_attempts()
        if ((a.get("details") or {}).get("protocol") or {}).get("study") == study
        and not ((a.get("details") or {}).get("protocol") or {}).get("practice")
    ]
    if not ids:
        raise UserError(f"--study {study!r}: no scored attempt of that study in this database")
    return ids


def _create(args, store: RecordStore) -> int:
    base = (args.base_url or os.environ.get(BASE_URL_ENV) or "").rstrip("/")
    if not base:
        raise UserError(f"--base-url: the records server's address is needed for the links (or set ${BASE_URL_ENV})")
    ids = _ids(args.attempts) if args.attempts else _study_attempts(store, args.study)
    tokens = rating.create_set(store, args.name, ids, args.rater, created_by=os.environ.get("USER", "cli"))
    print(f"rating set {args.name!r}: {len(set(ids))} attempts under codes, {len(tokens)} raters; each link once:")
    for who, token in tokens.items():
        print(f"  {who}: {base}/rate/{token}")
    return 0


def _report(args, store: RecordStore) -> int:
    from chainsim.game.cli.commands.study_report import pack_metrics  # noqa: PLC0415 - loads the pack checker

    _pack, specs = pack_metrics(args.pack, args.pack_path)
    where = redact(args.db) if is_postgres(args.db) else str(store.path)
    study = rating_report.analyse(store, args.name, specs, source=f"records database {where}, rating set {args.name}")
    out = prepare_output_dir(args.out, "--out")
    md = rating_report.write(study, out)
    a = study.agreement
    if a is not None:
        print(
            f"ICC(A,1) {a.single:.2f} (95 % {a.single_ci[0]:.2f} to {a.single_ci[1]:.2f}); "
            f"ICC(A,{a.k}) {a.average:.2f}; {a.n} attempts, {a.k} raters"
        )
        if not math.isfinite(a.average):
            print(rating_report.NO_AVERAGE)
    for c in study.correlations:
        rho = "-" if c["rho"] is None else f"{c['rho']:.2f}"
        print(f"{c['label']}: rho {rho} over {c['n']} attempts")
    print(f"report: {md}")
    return 0


def run(args: argparse.Namespace) -> int:
    with RecordStore(args.db, create=False) as store:
        return _create(args, store) if args.action == "create" else _report(args, store)
