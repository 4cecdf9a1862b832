"""Blinded rating: attempts shown to raters under random codes, scored on a global rating form.

A validity study's simulator metrics are checked against experts' judgement of the same attempts. The
judgement is worth something only when the raters cannot tell whose attempt they see: a rating set
lists attempts under random codes, and each rater opens them through a secret link of their own (no
account: the link opens that rater's list and nothing else), on a page with the attempt replayed in
3-D and the form, without the trainee's name, class, dates, the simulator's metrics or verdict. Each
rater sees the attempts in their own order (drawn from the link), so order effects do not line up
between raters.

The form (`FORM`) is a global rating scale in the manner of OSATS (Martin et al. 1997), five items
each marked 1 to 5 with words at 1, 3 and 5; the score of a rating is the sum (5 to 25). A set keeps the
form it was made with. `ratings_table` gives one row per coded attempt with each rater's score, which
the agreement statistics (chainsim.game.study.agreement) read.
"""

from __future__ import annotations

import hashlib
import json
import random
import re
import secrets
from dataclasses import dataclass
from typing import Any

from chainsim.game.records import rating_tables
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_created_at
from chainsim.systems.engine.errors import UserError

#: the global rating form: (key, the item, what 1, 3 and 5 mean)
FORM: tuple[tuple[str, str, tuple[str, str, str]], ...] = (
    ("planning", "Planning and preparation", (
        "No plan: entry and direction found by trial", "Plan made, corrected once or twice",
        "Entry and direction planned before the needle goes in")),
    ("aiming", "Aiming and direction", (
        "Direction changed repeatedly, far off the path", "Near the path with some correction",
        "On the path throughout")),
    ("economy", "Economy of motion", (
        "Many needless moves and withdrawals", "Efficient with some needless moves",
        "Every move purposeful")),
    ("tissue", "Respect for tissue", (
        "Repeated punctures, force on bone", "Some needless punctures or contacts",
        "One clean path, no needless contact")),
    ("overall", "Overall performance", (
        "Could not perform it unsupervised", "Competent with supervision", "Competent to perform it alone")),
)  # fmt: skip
MARKS = (1, 5)
#: a rating set's name, and a rater's: letters, digits, space, . _ -
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9 ._-]{0,63}")


@dataclass(frozen=True, slots=True)
class Rater:
    id: int
    name: str
    set_id: int
    set_name: str
    form: tuple


def _name(what: str, value: Any) -> str:
    if not isinstance(value, str) or not NAME_RE.fullmatch(value.strip()):
        raise UserError(f"{what} {value!r}: expected 1-64 letters, digits, spaces, '.', '_' or '-'")
    return value.strip()


def _token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def create_set(
    store: RecordStore, name: str, attempt_ids: list[int], raters: list[str], created_by: str
) -> dict[str, str]:
    """Make the rating set `name` of these attempts for these raters; returns each rater's secret token
    (shown once: only its hash is kept). UserError naming what is wrong (an unknown attempt, a name used)."""
    name = _name("rating set", name)
    names = [_name("rater", r) for r in raters]
    if len(names) < 2 or len(set(names)) != len(names):
        raise UserError(f"a rating set needs at least two raters, each named once; got {', '.join(names) or 'none'}")
    ids = sorted({int(a) for a in attempt_ids})
    if len(ids) < 2:
        raise UserError("a rating set needs at least two attempts: agreement is measured across attempts")
    tokens = {r: secrets.token_urlsafe(24) for r in names}
    with store.transaction() as conn:
        if rating_tables.set_exists(conn, name):
            raise UserError(f"a rating set named {name!r} exists already; choose another name")
        for a in ids:
            if not rating_tables.attempt_exists(conn, a):
                raise UserError(f"no attempt with id {a}")
            if not rating_tables.has_recording(conn, a):
                raise UserError(f"attempt {a} has no recording, so it cannot be replayed to raters")
        set_id = rating_tables.insert_set(conn, name, created_by, clean_created_at(None), json.dumps(FORM))
        for a in ids:
            code = "R" + secrets.token_hex(4).upper()  # random: the code says nothing of the attempt
            rating_tables.insert_item(conn, set_id, code, a)
        for r in names:
            rating_tables.insert_rater(conn, set_id, r, _token_hash(tokens[r]))
    return tokens


def rater_for(store: RecordStore, token: str) -> Rater | None:
    """The rater whose secret link holds `token` (None: no such link)."""
    r = rating_tables.rater_by_token_hash(store, _token_hash(str(token)))
    if r is None:
        return None
    return Rater(int(r[0]), str(r[1]), int(r[2]), str(r[3]), tuple(tuple(i) for i in json.loads(r[4])))


def items_for(store: RecordStore, rater: Rater) -> list[dict]:
    """The rater's coded attempts in the rater's own order: code, whether rated, the score given."""
    rows = rating_tables.rater_items(store, rater.id, rater.set_id)
    items = [{"code": str(c), "rated": t is not None, "total": t} for c, t in rows]
    random.Random(f"{rater.set_id}:{rater.id}").shuffle(items)  # each rater's own order, the same each visit
    return items


def attempt_of(store: RecordStore, rater: Rater, code: str) -> int | None:
    """The attempt behind `code` in the rater's set (None: not one of theirs)."""
    return rating_tables.item_attempt(store, rater.set_id, str(code))


def clean_scores(form: tuple, given: dict) -> dict[str, int]:
    """Every item of `form` marked with a whole number within MARKS; UserError naming the first that is not."""
    out = {}
    for key, label, _anchors in form:
        raw = given.get(key)
        try:
            mark = int(str(raw).strip())
        except (TypeError, ValueError):
            raise UserError(f"{label}: mark it from {MARKS[0]} to {MARKS[1]}") from None
        if not MARKS[0] <= mark <= MARKS[1] or str(raw).strip() != str(mark):
            raise UserError(f"{label}: mark it from {MARKS[0]} to {MARKS[1]}, got {raw!r}")
        out[key] = mark
    return out


def save_rating(store: RecordStore, rater: Rater, code: str, given: dict) -> int:
    """Store the rater's marks for `code` (a second Save replaces the first); returns the score."""
    scores = clean_scores(rater.form, given)
    total = sum(scores.values())
    with store.transaction() as conn:
        item = rating_tables.item_id(conn, rater.set_id, code)
        if item is None:
            raise UserError(f"no attempt {code!r} in this rating set")
        rating_tables.replace_rating(conn, item, rater.id, json.dumps(scores), float(total), clean_created_at(None))
    return total


def ratings_table(store: RecordStore, name: str) -> dict:
    """The set's raters and one row per coded attempt: ``{"raters": [...], "rows": [{"code", "attempt_id",
    "scores": {rater: score or None}}]}``; UserError for a set that does not exist."""
    set_id = rating_tables.set_id_named(store, name)
    if set_id is None:
        known = rating_tables.set_names(store)
        raise UserError(f"no rating set named {name!r}; known: {', '.join(known) or 'none'}")
    raters = rating_tables.set_raters(store, set_id)
    rows = []
    for item_id, code, attempt_id in rating_tables.set_items(store, set_id):
        given = rating_tables.item_totals(store, item_id)
        rows.append({"code": code, "attempt_id": int(attempt_id), "scores": {n: given.get(i) for i, n in raters}})
    return {"raters": [n for _, n in raters], "rows": rows}
