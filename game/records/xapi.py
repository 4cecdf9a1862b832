"""xAPI 1.0.3 statements for saved attempts, so a learning record store (LRS) can take them.

One statement per attempt: the trainee (an account of the programme's home page) *completed*
the procedure (the pack, as an activity), with a result carrying success (the needle ended in
its target, not on bone or nowhere: thesis 3.3.4's green light), the duration, the needle error
of 6.1.5 as the raw score (millimetres beyond the target's radius: lower is better, negative is
inside) and every metric of the attempt record as a result extension. The class is the
statement's grouping activity. Statement ids are name-based UUIDs of (home page, attempt id),
so exporting or posting the same attempt twice gives the same statement, which an LRS keeps once.

``post_statements`` sends them to an LRS's ``/statements`` resource with HTTP basic auth.
"""

from __future__ import annotations

import base64
import json
import numbers
import urllib.error
import urllib.request
import uuid
from collections.abc import Sequence
from typing import Any
from urllib.parse import quote

from chainsim.game.records.validate import KNOWN_TARGETS
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import records_layout

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

XAPI_VERSION = "1.0.3"
DEFAULT_HOMEPAGE = "http://localhost/chainsim"
VERB_COMPLETED = {"id": "http://adlnet.gov/expapi/verbs/completed", "display": {"en-US": "completed"}}
ACTIVITY_SIMULATION = "http://adlnet.gov/expapi/activities/simulation"
ACTIVITY_COURSE = "http://adlnet.gov/expapi/activities/course"
_NAMESPACE = uuid.UUID("6f1c1a52-2f0e-5d7c-9a43-63686169736d")
# Fields of the record that are who/when/where, not measurements.
_NOT_METRICS = {
    "id",
    "procedure",
    "class_name",
    "trainee",
    "pack",
    "created_at",
    "target",
    "source",
    "flags",
    "accepted_by",
    "accepted_at",
}


def iso_duration(seconds: float) -> str:
    """ISO 8601 duration as xAPI wants it (``PT1M3.25S``), at most 0.01 s precision."""
    total = round(max(0.0, float(seconds)), 2)
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    out = "PT"
    if hours:
        out += f"{int(hours)}H"
    if minutes:
        out += f"{int(minutes)}M"
    if secs or out == "PT":
        out += f"{secs:.2f}".rstrip("0").rstrip(".") + "S"
    return out


def _base(homepage: str) -> str:
    home = homepage.rstrip("/")
    if not home.startswith(("http://", "https://")):
        raise UserError(f"xAPI home page {homepage!r} must be an http(s) URL, e.g. https://training.example.org")
    return home


def statement(attempt: dict[str, Any], homepage: str = DEFAULT_HOMEPAGE) -> dict[str, Any]:
    """The xAPI statement of one attempt record (as ``RecordStore.list_attempts`` returns it)."""
    home = _base(homepage)
    ext = f"{home}/xapi/extensions"
    metrics = {f"{ext}/{key}": value for key, value in attempt.items() if key not in _NOT_METRICS and value is not None}
    result: dict[str, Any] = {
        "success": attempt["target"] not in KNOWN_TARGETS,
        "completion": True,
        "duration": iso_duration(attempt["duration_s"]),
        "extensions": {**metrics, f"{ext}/target": attempt["target"]},
    }
    needle = attempt.get(LAYOUT.target_error)
    if isinstance(needle, numbers.Real):
        result["score"] = {"raw": float(needle)}
    return {
        "id": str(uuid.uuid5(_NAMESPACE, f"{home}|attempt|{attempt['id']}")),
        "actor": {
            "objectType": "Agent",
            "name": attempt["trainee"],
            "account": {"homePage": home, "name": f"{attempt['class_name']}/{attempt['trainee']}"},
        },
        "verb": VERB_COMPLETED,
        "object": {
            "objectType": "Activity",
            "id": f"{home}/activities/procedure/{quote(attempt['pack'], safe='')}",
            "definition": {"name": {"en-US": attempt["pack"]}, "type": ACTIVITY_SIMULATION},
        },
        "result": result,
        "context": {
            "platform": "chainsim",
            # where the attempt came from (docs/records-server.md, "Provenance"), and whether its input is
            # beyond a person's and not yet accepted by the trainer
            "extensions": {
                f"{ext}/source": attempt.get("source", "local"),
                f"{ext}/flagged": bool(attempt.get("flags")) and not attempt.get("accepted_by"),
            },
            "contextActivities": {
                "grouping": [
                    {
                        "objectType": "Activity",
                        "id": f"{home}/activities/class/{quote(attempt['class_name'], safe='')}",
                        "definition": {"name": {"en-US": attempt["class_name"]}, "type": ACTIVITY_COURSE},
                    }
                ]
            },
        },
        "timestamp": attempt["created_at"],
        "version": XAPI_VERSION,
    }


def statements(attempts: Sequence[dict[str, Any]], homepage: str = DEFAULT_HOMEPAGE) -> list[dict[str, Any]]:
    _base(homepage)  # a bad home page is an error even when there is nothing to export
    return [statement(a, homepage) for a in attempts]


def dumps(stmts: list[dict[str, Any]]) -> str:
    return json.dumps(stmts, indent=2, sort_keys=True, allow_nan=False) + "\n"


def post_statements(stmts: list[dict[str, Any]], lrs: str, auth: str | None = None, timeout: float = 30.0) -> int:
    """POST the statements to ``LRS/statements`` (one request); returns how many the LRS took.

    ``auth`` is ``user:password`` for HTTP basic auth, as LRSs issue it.
    """
    if not lrs.startswith(("http://", "https://")):
        raise UserError(f"LRS address {lrs!r} must be an http(s) URL ending before /statements")
    if not stmts:
        return 0
    url = lrs.rstrip("/") + "/statements"
    headers = {"Content-Type": "application/json", "X-Experience-API-Version": XAPI_VERSION}
    if auth:
        headers["Authorization"] = "Basic " + base64.b64encode(auth.encode()).decode("ascii")
    req = urllib.request.Request(url, data=json.dumps(stmts).encode(), headers=headers, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            body = resp.read()
    except urllib.error.HTTPError as exc:
        detail = exc.read(300).decode("utf-8", "replace").strip().splitlines()
        raise UserError(f"LRS {url} refused the statements: HTTP {exc.code} {detail[0] if detail else ''}") from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise UserError(f"cannot reach LRS {url}: {reason}") from None
    try:
        ids = json.loads(body or b"[]")
    except ValueError:
        ids = []
    return len(ids) if isinstance(ids, list) and ids else len(stmts)
