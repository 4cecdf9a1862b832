"""A study's participant register and its allocation sequence (docs/validity.md, "From protocol to report").

Before their first trial a participant is entered in the study's register with the covariates a
methods reviewer asks for: the group (novice or expert), the year of training and the number of
procedures performed. Registering gives them the next ``slot`` of the study's one allocation
sequence: slot k takes row k of the protocol's counterbalanced design (a balanced Latin square over
each task's conditions, chainsim.game.study.protocol.latin_row), so consecutive participants take
consecutive rows and every row is used equally often.

The sequence lives in the records database that holds the register. Kept on the records server,
every site and machine filing to it draws from that one sequence; the slot is taken inside the
store's write transaction (SQLite's write lock, PostgreSQL's advisory lock) and ``UNIQUE (study,
slot)`` stands behind it, so two registrations at once never get the same slot. A register kept in
a machine's own file allocates for that machine only; the window says so and the trials record it.

Registering the same participant again with the same covariates answers the first entry (a resend);
with other covariates it is refused: a register entry is evidence and is not changed. The study's
design (its trials and their aids, chainsim.game.study.protocol.design) is filed with the register,
once, so the records server can check each uploaded trial against the participant's allocation; a
design other than the one filed is refused likewise.
"""

from __future__ import annotations

import json
from typing import Any
from urllib.parse import quote

from chainsim.game.records import remote, study_tables
from chainsim.game.records.backend import is_postgres
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_created_at, clean_name
from chainsim.game.study import protocol
from chainsim.game.study.validity_data import GROUPS
from chainsim.systems.engine.errors import UserError

DESIGN = protocol.DESIGN
#: the register's whole-number covariates and their largest values (as a CSV register takes them)
COUNTS = {"year_of_training": 80, "procedures_performed": 1_000_000}
FIELDS = ("code", "group", "year_of_training", "procedures_performed")


class AlreadyRegistered(UserError):
    """The participant is in the register with other covariates (HTTP 409)."""


def clean_entry(study: Any, body: Any) -> tuple[str, dict]:
    """(study, {code, group, year_of_training, procedures_performed}) checked; a one-line UserError
    naming what is wrong and what is expected otherwise."""
    study = clean_name("study", study)
    if not isinstance(body, dict):
        raise UserError(f"a registration must be an object with {', '.join(FIELDS)}")
    extra = sorted(set(body) - set(FIELDS) - {"class_name"})
    if extra:
        raise UserError(f"unknown field '{extra[0]}' in a registration; expected {', '.join(FIELDS)}")
    code = clean_name("participant", body.get("code"))
    group = body.get("group")
    if not isinstance(group, str) or group.strip().lower() not in GROUPS:
        raise UserError(f"group is {group!r}; expected {' or '.join(GROUPS)}")
    out: dict[str, str | int] = {"code": code, "group": group.strip().lower()}
    for key, top in COUNTS.items():
        v = body.get(key)
        if isinstance(v, str) and v.strip().isdigit():
            v = int(v.strip())
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= top:
            raise UserError(f"{key} is {v!r}; expected a whole number from 0 to {top}")
        out[key] = v
    return study, out


def _entry(row: Any) -> dict:
    d = {k: row[k] for k in row.keys()}
    d["group"] = d.pop("grp")
    return d


def register(store: RecordStore, study: Any, class_name: Any, body: Any, by: str) -> tuple[dict, bool]:
    """Enter a participant in ``study``'s register under ``class_name``: (entry with its slot, created).
    The slot is the next of the study's sequence, taken in the same write transaction as the entry."""
    study, entry = clean_entry(study, body)
    class_name = clean_name("class", class_name)
    with store.transaction() as conn:
        row = study_tables.participant(conn, study, entry["code"])
        if row is not None:
            old = _entry(row)
            if any(old[k] != entry[k] for k in FIELDS) or old["class_name"] != class_name:
                raise AlreadyRegistered(
                    f"participant {entry['code']!r} is already in the register of study {study!r} (class "
                    f"{old['class_name']}, group {old['group']}, year {old['year_of_training']}, "
                    f"{old['procedures_performed']} procedures); a register entry is not changed"
                )
            return old, False
        slot = study_tables.next_slot(conn, study)
        study_tables.insert_participant(
            conn,
            (
                study,
                class_name,
                entry["code"],
                entry["group"],
                entry["year_of_training"],
                entry["procedures_performed"],
                slot,
                by,
                clean_created_at(None),
            ),
        )
    found = lookup(store, study, entry["code"])
    assert found is not None  # written in the transaction just committed
    return found, True


def lookup(store: RecordStore, study: str, code: str) -> dict | None:
    """A participant's register entry, or None."""
    row = study_tables.read_participant(store, study, code)
    return None if row is None else _entry(row)


def entries(store: RecordStore, study: str, classes: list[str] | None = None) -> list[dict]:
    """The study's register in slot order (of ``classes`` only, when given)."""
    out = [_entry(r) for r in study_tables.participants(store, study)]
    return out if classes is None else [e for e in out if e["class_name"] in classes]


def file_design(store: RecordStore, study: Any, value: Any, by: str) -> tuple[dict, bool]:
    """Keep ``study``'s design (checked): (the design kept, filed now). The same design again is a resend;
    another is refused (AlreadyRegistered): trials already checked against the first must stay valid."""
    study = clean_name("study", study)
    value = protocol.clean_design(value, study)
    text = protocol.design_text(value)
    with store.transaction() as conn:
        filed = study_tables.design_text(conn, study)
        if filed is not None:
            if filed != text:
                raise AlreadyRegistered(
                    f"study {study!r} has another design on this server (its trials or aids differ from this "
                    "protocol's); a study's design is not changed: give the changed protocol a new file name"
                )
            return value, False
        study_tables.insert_design(conn, study, text, by, clean_created_at(None))
    return value, True


def design_of(store: RecordStore, study: str) -> dict | None:
    """The design filed for ``study``, or None."""
    text = study_tables.read_design_text(store, study)
    return None if text is None else json.loads(text)


def check_trial(store: RecordStore, class_name: str, trainee: str, claimed: dict) -> dict:
    """The ``details.protocol`` a records server keeps for an uploaded study trial: the trial its design
    and register give the participant at that place (chainsim.game.study.protocol.check_claim); a
    one-line UserError when the upload's trial, condition, practice flag, slot or aids are not that."""
    said = (claimed.get("details") or {}).get("protocol")
    said = said if isinstance(said, dict) else {}
    study, code = said.get("study"), said.get("participant")
    value = entry = None
    if isinstance(study, str) and isinstance(code, str):
        value, entry = design_of(store, study), lookup(store, study, code)
    kept = protocol.check_claim({**said, "aids": claimed.get("aids")}, value, entry, (class_name, trainee))
    try:
        attempts = store.list_attempts(class_name, trainee)
    except UserError:  # the trainee has no attempts yet
        attempts = []
    for a in attempts:
        p = (a.get("details") or {}).get("protocol") or {}
        if not a.get("retracted_at") and (p.get("study"), p.get("order")) == (study, kept["order"]):
            raise UserError(
                f"trial {kept['order']} of {code!r} in study {study!r} is already on this server (attempt "
                f"{a['id']}); a trial counts once: a trainer retracts it before it is made again"
            )
    return kept


# -- on a records server (the simulator's side) --------------------------------------------------


def _server_call(server: str, db, path: str, body: Any = None, missing_ok: bool = False) -> Any:
    with RecordStore(db) as local:
        token = remote.token_for(local, server)
        if token is None:
            raise UserError(f"not signed in to {server}: chainsim records login {server} NAME (a trainer)")
        context = remote.context_for(local, server)
    try:
        return remote.request(
            f"{server}{path}", "POST" if body is not None else "GET", body, token=token, context=context
        )
    except remote.ServerError as exc:
        if missing_ok and exc.status == 404:
            return None
        raise UserError(f"{server}: {exc}") from None
    except OSError as exc:
        raise UserError(
            f"{exc}; allocation from the study's sequence needs the records server (without --records the "
            "order comes from this machine's own register, and the trials record that)"
        ) from None


def register_on_server(server: str, db, study: str, class_name: str, body: dict) -> dict:
    """Register on the records server ``server`` (signed in as a trainer of ``class_name``)."""
    server = remote.server_url(server)
    return _server_call(
        server, db, f"/api/studies/{quote(study, safe='')}/participants", {**body, "class_name": class_name}
    )


def file_design_on_server(server: str, db, study: str, value: dict) -> dict:
    """File the study's design on the records server ``server`` (a resend of the same one is fine)."""
    server = remote.server_url(server)
    return _server_call(server, db, f"/api/studies/{quote(study, safe='')}/design", value)


def lookup_on_server(server: str, db, study: str, code: str) -> dict | None:
    """A participant's entry in the server's register, or None when they are not in it."""
    server = remote.server_url(server)
    path = f"/api/studies/{quote(study, safe='')}/participants/{quote(code, safe='')}"
    return _server_call(server, db, path, missing_ok=True)


# -- where a session's order comes from -----------------------------------------------------------

LOCAL_WARNING = (
    "condition order allocated from this machine's own register, not the records server's sequence: "
    "another machine may give the same order (run with --records URL to draw from the study's one sequence)"
)


def allocate(study: str, class_name: str, code: str, covariates: dict | None, server: str | None, db) -> dict:
    """A participant's allocation: their register entry's slot and covariates, the design, and who keeps the
    sequence (``by``; ``warning`` when it is only this machine's). ``covariates`` given: register first (a
    resend of the same entry is fine); None: they must be in the register already."""
    body = None if covariates is None else {"code": code, **covariates}
    shared = False
    if server:
        server = remote.server_url(server)
        if body is not None:
            entry: dict | None = register_on_server(server, db, study, class_name, body)
        else:
            entry = lookup_on_server(server, db, study, code)
        by, where = f"records server {server}", f" on {server}"
    else:
        with RecordStore(db) as store:
            entry = lookup(store, study, code) if body is None else register(store, study, class_name, body, "local")[0]
            # a PostgreSQL records database is one every machine can share: its sequence is the study's one
            shared = is_postgres(str(store.path))
            by, where = (f"records database {store.path}" if shared else "this machine"), f" in {store.path}"
    if entry is None:
        raise UserError(
            f"participant {code!r} is not in the register of study {study!r}{where}; enter them before their first "
            "trial: add --group novice|expert --year-of-training N --procedures-performed N"
        )
    out = {"by": by, "design": DESIGN, "slot": entry["slot"], **{k: entry[k] for k in FIELDS[1:]}}
    if not server and not shared:
        out["warning"] = LOCAL_WARNING
    return out
