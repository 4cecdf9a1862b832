"""The class at a glance, one procedure at a time, and a trainer's management of a class in the browser.

The thesis's trainer judges progress from saved results (3.3.4); a class page does it for every
trainee of a class at once: for one procedure (pack) - never two on one line or in one table - each
trainee's latest and best attempt, their success rate (attempts that met every benchmark and had
no critical error), a trend (whether their latest attempts pass more benchmarks than their earlier
ones) and whether they are below the benchmark now (their latest attempt failed). Verdicts come from
the pack's own [metrics] benchmarks (``chainsim.systems.procedures.verdicts``), labels and
units too, so nothing here names a procedure's words.

Tables sort and page on the server (links with ``sort``, ``dir`` and ``page``), so they work without
scripts. Plots: one per metric, every trainee's attempts faint, the class median over attempt
number bold, the benchmark as a horizontal line.

Class medians (here and on each trainee's plots, ``class_median``) are drawn only at the attempt
numbers where at least ``MEDIAN_MIN_TRAINEES`` trainees have a value: the median of fewer is one
classmate's figure, or the mean of two, so a trainee shown it would read a classmate's attempts.
Elsewhere the plot says so (``MEDIAN_WITHHELD``) instead of drawing it.

A refused page (403) names nothing the account may not see: not the class, not its trainees.

Management (trainers, for classes they teach; CSRF-checked forms; a refused form counts against
the trainer like a failed sign-in, so the site's throttle slows guessing): add a trainee account,
set a trainee's new password (their sessions and tokens end).
"""

from __future__ import annotations

import io
import statistics
from typing import Any, TypeGuard

from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from chainsim.game.records import accounts, listings
from chainsim.game.records.accounts import User
from chainsim.game.records.store import RecordStore, in_class_figures
from chainsim.game.server.auth import HTTPError
from chainsim.systems.procedures import verdicts as debrief

PAGE_SIZE = 25
SORTS = ("trainee", "attempts", "success", "latest", "best", "trend", "last")
#: trainees that must have a value at an attempt number before the class median there is shown
MEDIAN_MIN_TRAINEES = 5
#: what a plot says where it withholds the class median
MEDIAN_WITHHELD = f"class median shown from {MEDIAN_MIN_TRAINEES} trainees"


def values(a: dict) -> dict:
    """An attempt's metric values as the pack's benchmarks name them."""
    v = dict(a.get("metrics") or {})
    for k, x in a.items():  # the record's own fixed figures, where the pack's metrics share their names
        if isinstance(x, (int, float)) and not isinstance(x, bool) and k != "id":
            v.setdefault(k, x)
    return v


def judged(a: dict, specs: dict) -> dict:
    """The attempt with its verdict: passed (every benchmark met, no critical error), metrics passed."""
    rows = debrief.verdicts(specs, values(a)) if specs else []
    o = debrief.outcome(rows) if rows else {"passed": None}
    return {
        "id": a["id"],
        "created_at": a["created_at"],
        "passed": o.get("passed") if any(r["passed"] is not None for r in rows) else None,
        "met": sum(1 for r in rows if r["passed"]),
        "judged": sum(1 for r in rows if r["passed"] is not None),
        "rows": rows,
    }


def trend(scores: list[int]) -> str:
    """'better', 'worse' or 'steady': the latest attempts' benchmarks met against the earlier ones'."""
    if len(scores) < 2:
        return "-"
    half = max(1, len(scores) // 2)
    early, late = statistics.mean(scores[:half]), statistics.mean(scores[half:])
    return "better" if late > early + 0.25 else "worse" if late < early - 0.25 else "steady"


def class_median(series: list[list[Any]]) -> list[float | None]:
    """Per attempt number k (from 1), the median of the trainees' k-th values (``series``: one list per
    trainee, oldest first; a value that is not a number counts for nothing), or None where fewer
    than ``MEDIAN_MIN_TRAINEES`` trainees have one."""
    longest = max((len(ys) for ys in series), default=0)
    out: list[float | None] = []
    for k in range(longest):
        at_k = [float(ys[k]) for ys in series if len(ys) > k and _number(ys[k])]
        out.append(statistics.median(at_k) if len(at_k) >= MEDIAN_MIN_TRAINEES else None)
    return out


def _number(v: Any) -> TypeGuard[int | float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def class_row(store: RecordStore, user: User, class_id: int) -> dict:
    name = listings.name_of_class(store, class_id)
    if name is None:
        raise HTTPError(404, f"no class with id {class_id}")
    if not user.is_trainer or name not in user.classes:
        raise HTTPError(403, "you do not teach that class")  # its name is not the account's to learn
    return {"id": class_id, "name": name}


def overview(store: RecordStore, user: User, class_id: int, specs_for, query: dict) -> dict:
    """What the class page shows for one pack (``query['pack']``, else the class's first)."""
    cls = class_row(store, user, class_id)
    trainees = listings.class_trainees(store, class_id)
    everything = store.list_attempts(cls["name"])
    # retracted attempts, and those whose input is beyond a person's until a trainer accepts them, count for nothing
    attempts = [a for a in everything if in_class_figures(a)]
    waiting = [a for a in everything if not a["retracted_at"] and not in_class_figures(a)]
    packs = sorted({a["pack"] for a in attempts})
    pack = query.get("pack") if query.get("pack") in packs else (packs[0] if packs else "")
    specs = specs_for(pack) if pack else {}
    by_trainee: dict[str, list[dict]] = {}
    for a in attempts:
        if a["pack"] == pack:
            by_trainee.setdefault(a["trainee"], []).append(a)
    table = []
    for t in trainees:
        own = by_trainee.get(t["name"], [])
        js = [judged(a, specs) for a in own]
        latest = js[-1] if js else None
        best = max(js, key=lambda j: (j["passed"] is True, j["met"], j["id"])) if js else None
        passed = [j for j in js if j["passed"] is not None]
        table.append(
            {
                **t,
                "attempts": len(js),
                "latest": latest,
                "best": best,
                "success": (sum(1 for j in passed if j["passed"]) / len(passed)) if passed else None,
                "trend": trend([j["met"] for j in js]),
                "below": latest is not None and latest["passed"] is False,
                "last": own[-1]["created_at"] if own else "",
            }
        )
    sort = query.get("sort")
    sort = sort if isinstance(sort, str) and sort in SORTS else "trainee"
    desc = query.get("dir") == "desc"
    key = {
        "trainee": lambda r: (r["name"],),
        "attempts": lambda r: (r["attempts"],),
        "success": lambda r: (r["success"] is not None, r["success"] or 0.0),
        "latest": lambda r: (r["latest"] is not None, r["latest"]["met"] if r["latest"] else 0),
        "best": lambda r: (r["best"] is not None, r["best"]["met"] if r["best"] else 0),
        "trend": lambda r: ({"worse": 0, "steady": 1, "better": 2}.get(r["trend"], -1),),
        "last": lambda r: (r["last"],),
    }[sort]
    table.sort(key=key, reverse=desc)
    pages = max(1, -(-len(table) // PAGE_SIZE))
    try:
        page = min(max(1, int(query.get("page", 1))), pages)
    except ValueError:
        page = 1
    metric_names = [k for k, s in specs.items() if isinstance(s, dict)] if specs else []
    everyone = [values(a) for own in by_trainee.values() for a in own]
    shown_metrics = [m for m in metric_names if any(v.get(m) is not None for v in everyone)]
    return {
        **cls,
        "packs": packs,
        "pack": pack,
        "rows": table[(page - 1) * PAGE_SIZE : page * PAGE_SIZE],
        "count": len(table),
        "below": [r["name"] for r in table if r["below"]],
        # flagged attempts waiting for a trainer: listed on their trainees' pages, counted nowhere here
        "flagged": [{"id": a["id"], "trainee": a["trainee"]} for a in waiting],
        "page": page,
        "pages": pages,
        "sort": sort,
        "desc": desc,
        "metrics": [{"key": m, "label": specs[m].get("label", m.replace("_", " "))} for m in shown_metrics],
        "accounts": [t["account"] for t in trainees if t["account"]],
        # "below the benchmark" against provisional benchmarks is a guide: the page says so
        "basis_note": debrief.basis_note(debrief.verdicts(specs, {})) if specs else "",
    }


def metric_plot(store: RecordStore, user: User, class_id: int, pack: str, metric: str, specs: dict) -> bytes:
    """One metric of one pack for the whole class: each trainee's attempts (faint), the class median
    by attempt number, and the benchmark line (SVG)."""
    cls = class_row(store, user, class_id)
    if metric not in specs:
        raise HTTPError(404, f"pack {pack!r} has no metric {metric!r}")
    spec = specs[metric]
    by_trainee: dict[str, list[float]] = {}
    for a in store.list_attempts(cls["name"]):
        if not in_class_figures(a) or a["pack"] != pack:
            continue
        v = values(a).get(metric)
        if _number(v):
            by_trainee.setdefault(a["trainee"], []).append(float(v))
    # 4.8 x 3.2 in with 10-11 pt text: on a 390 px phone the image is drawn at about 3/4 size, its
    # text still about 10 px (at 6.4 in and 8 pt it was 5 px, unreadable)
    fig = Figure(figsize=(4.8, 3.2), dpi=100)
    FigureCanvasSVG(fig)
    ax = fig.subplots()
    ax.tick_params(labelsize=10)
    for ys in by_trainee.values():
        ax.plot(range(1, len(ys) + 1), ys, color="tab:blue", alpha=0.25, marker=".", linewidth=1)
    shown = [(k, y) for k, y in enumerate(class_median(list(by_trainee.values())), start=1) if y is not None]
    if shown:
        xs, ys = zip(*shown)
        ax.plot(xs, ys, color="tab:blue", linewidth=2.5, marker="o", label="class median")
    longest = max((len(ys) for ys in by_trainee.values()), default=0)
    if len(shown) < longest:  # some attempt numbers have too few trainees for a median
        ax.text(0.01, 0.98, MEDIAN_WITHHELD, transform=ax.transAxes, fontsize=10, va="top", color="0.35")
    units = spec.get("units", "")
    if isinstance(spec.get("benchmark"), (int, float)):
        better = "at most" if spec.get("lower_is_better", True) else "at least"
        bench = debrief.number(spec["benchmark"], units)
        ax.axhline(float(spec["benchmark"]), color="tab:red", linestyle="--", label=f"benchmark: {better} {bench}")
    ax.set_title(f"{cls['name']}: {spec.get('label', metric)} ({pack})", fontsize=11)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # attempts are whole numbers
    ax.set_xlabel("attempt", fontsize=11)
    ax.set_ylabel(f"{spec.get('label', metric)}" + (f" ({units})" if units else ""), fontsize=11)
    ax.grid(alpha=0.3)
    if shown or spec.get("benchmark") is not None:
        ax.legend(loc="best", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()


# -- management ----------------------------------------------------------------------------------


def add_trainee(store: RecordStore, user: User, class_id: int, name: Any, password: Any) -> str:
    cls = class_row(store, user, class_id)
    u = accounts.add_user(store, name if isinstance(name, str) else "", "trainee", password, [cls["name"]])
    return f"Trainee account {u.name!r} added to class {cls['name']}."


def reset_password(store: RecordStore, user: User, class_id: int, name: Any, password: Any) -> str:
    cls = class_row(store, user, class_id)
    account = listings.trainee_account(store, class_id, name if isinstance(name, str) else "")
    if account is None:
        raise HTTPError(404, f"class {cls['name']} has no trainee account {name!r}")
    accounts.set_password(store, account, password)
    return f"New password set for {account!r}; their sessions and tokens have ended."
