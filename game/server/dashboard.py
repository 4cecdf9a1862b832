"""The trainers' dashboard: sign in, classes, trainees, progress plots, one attempt, exports.

Plain HTML forms and links rendered on the server (Jinja2, autoescaped), one stylesheet served
from the package, plots as server-rendered SVG/PNG images: every page but one works without
JavaScript and nothing is loaded from another site. The attempt page adds its 3-D replay with this
site's own copy of three.js (``chainsim.game.server.replay3d``). A trainer sees the classes they
teach; a trainee lands on their own page and can open nothing else (403). Tables and plots hold one
procedure (pack) at a time.

    GET  /login, POST /login, POST /logout
    GET  /                                  a trainer's classes (a trainee: their own page)
    GET  /classes/{id}?pack=&sort=&dir=&page=   the class at a glance (chainsim.game.server.classpage)
    GET  /classes/{id}/plot/{pack}/{metric}.svg one metric for the class: trainees, median, benchmark
    POST /classes/{id}/trainees, /classes/{id}/password   a trainer adds a trainee, sets a password
    GET  /trainees/{id}?pack=&page=         one trainee's attempts of one pack, with verdicts
    GET  /trainees/{id}/plot/{pack}/{metric}.svg   (or .png) progress, class median, benchmark
    GET  /attempts/{id}                     one attempt in words and in 3-D: the verdict per metric
                                            against the pack's benchmark, the marked points' terms,
                                            step times, aids, details
    GET  /attempts/{id}/replay.json, /attempts/{id}/xray/{k}.png, /packs/{pack}/display.glb
    POST /attempts/{id}/retract             with a reason (audit log)
    POST /attempts/{id}/accept              a trainer accepts a flagged attempt (audit log)
    GET  /export/attempts.csv, /export/attempts.xapi.json   ?class=C&trainee=T
"""

from __future__ import annotations

import asyncio
import base64
import csv
import hashlib
import io
import json
from collections import Counter
from typing import Any

from jinja2 import Environment, PackageLoader, select_autoescape
from markupsafe import Markup
from starlette.requests import Request
from starlette.responses import HTMLResponse, RedirectResponse, Response
from starlette.routing import Route

from chainsim.game.records import accounts, listings, report, xapi
from chainsim.game.records.accounts import User
from chainsim.game.records.store import RecordStore, attempt_layout
from chainsim.game.server import classpage, plots, replay3d, scoring, throttle
from chainsim.game.server.api import (
    accept_attempt,
    audit_entries,
    readable_attempt,
    retract_attempt,
    visible_attempts,
)
from chainsim.game.server.auth import (
    LOGIN_CSRF_COOKIE,
    SESSION_COOKIE,
    HTTPError,
    check_csrf,
    new_login_csrf,
    page_or_api_user,
    read_form,
    session,
)
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import RECORDS_PROCEDURE, records_layout
from chainsim.systems.procedures import verdicts as debrief
from chainsim.systems.procedures.procedure import AttemptLayout

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

templates = Environment(loader=PackageLoader("chainsim.game.server", "templates"), autoescape=select_autoescape())
templates.globals["format_value"] = lambda v, units="": debrief.number(v, units) if isinstance(v, (int, float)) else v
templates.filters["tojson_pretty"] = lambda v: json.dumps(v, indent=2, sort_keys=True)


class Redirect(Exception):
    def __init__(self, location: str) -> None:
        super().__init__(location)
        self.location = location


def render(template: str, code: int = 200, /, **context: Any) -> HTMLResponse:
    return HTMLResponse(templates.get_template(template).render(**context), status_code=code)


def _secure(request: Request) -> bool:
    return request.url.scheme == "https"


async def page_user(request: Request) -> tuple[User, str]:
    found = await session(request)
    if found is None:
        raise Redirect("/login")
    return found


# -- store work (storage worker threads) --------------------------------------------------------


def class_list(store: RecordStore, user: User) -> list[dict]:
    if not user.classes:
        return []
    return listings.class_summaries(store, list(user.classes))


def trainee_detail(store: RecordStore, user: User, trainee_id: int, specs_for=None, query: dict | None = None) -> dict:
    """One trainee's attempts of one procedure (``query['pack']``, else their newest attempt's): each with its
    verdict against the pack's benchmarks, their latest and best, success rate and trend, a page of the
    list (newest first), and the pack's metrics to plot. Packs never share a table or a plot."""
    query = query or {}
    found = listings.trainee_by_id(store, trainee_id)
    if found is None:
        raise HTTPError(404, f"no trainee with id {trainee_id}")
    t = found
    if not user.can_see(t["class_name"], t["name"]):
        raise HTTPError(403, "these attempts are not yours to see")
    every = store.list_attempts(t["class_name"], t["name"])
    t["packs"] = sorted({a["pack"] for a in every})
    newest = every[-1]["pack"] if every else ""
    t["pack"] = query.get("pack") if query.get("pack") in t["packs"] else newest
    specs = specs_for(t["pack"]) if specs_for and t["pack"] else {}
    own = [a for a in every if a["pack"] == t["pack"]]
    for k, a in enumerate(own, start=1):
        a["number"] = k
        a["judged"] = classpage.judged(a, specs)
    kept = [a["judged"] for a in own if not a["retracted_at"]]
    passed = [j for j in kept if j["passed"] is not None]
    t["summary"] = {
        "latest": kept[-1] if kept else None,
        "best": max(kept, key=lambda j: (j["passed"] is True, j["met"], j["id"])) if kept else None,
        "success": (sum(1 for j in passed if j["passed"]) / len(passed)) if passed else None,
        "trend": classpage.trend([j["met"] for j in kept]),
        "count": len(kept),
    }
    newest_first = own[::-1]
    t["pages"] = max(1, -(-len(newest_first) // classpage.PAGE_SIZE))
    try:
        t["page"] = min(max(1, int(query.get("page", 1))), t["pages"])
    except ValueError:
        t["page"] = 1
    t["attempts"] = newest_first[(t["page"] - 1) * classpage.PAGE_SIZE : t["page"] * classpage.PAGE_SIZE]
    live = [a for a in own if not a["retracted_at"]]
    if specs:
        names = [m for m in specs if any(classpage.values(a).get(m) is not None for a in live)]
        t["metrics"] = {m: specs[m].get("label") or m for m in names}
    else:  # a pack the server does not have: the records' numeric fields
        t["metrics"] = {m: plots.label(m) for m in plots.metrics(live)}
    t["columns"] = list(t["metrics"])[:4]  # the table shows a few; the attempt page shows every one
    t["units"] = {m: (specs.get(m) or {}).get("units", "") for m in t["metrics"]}
    t["basis_note"] = debrief.basis_note(debrief.verdicts(specs, {})) if specs else ""
    t["waiting"] = scoring.waiting_uploads(store, [t["class_name"]], t["name"])
    return t


def trainee_plot(
    store: RecordStore, user: User, trainee_id: int, metric: str, fmt: str, pack: str, specs: dict
) -> bytes:
    t = trainee_detail(store, user, trainee_id, lambda _: specs, {"pack": pack})
    if metric not in t["metrics"]:
        raise HTTPError(404, f"no metric {metric!r} in these attempts; known: {', '.join(t['metrics']) or 'none'}")
    by_trainee: dict[str, list[dict]] = {}
    for a in store.list_attempts(t["class_name"]):  # oldest first within each trainee
        if not a["retracted_at"] and a["pack"] == t["pack"]:
            by_trainee.setdefault(a["trainee"], []).append(classpage.values(a))
    # only where enough trainees have a k-th value: the median of fewer is a classmate's figure
    median = classpage.class_median([[v.get(metric) for v in rows] for rows in by_trainee.values()])
    spec = specs.get(metric) or {}
    units = spec.get("units", "")
    words = t["metrics"][metric]
    bench = None
    if isinstance(spec.get("benchmark"), (int, float)):
        better = "at most" if spec.get("lower_is_better", True) else "at least"
        bench = (float(spec["benchmark"]), f"benchmark: {better} {debrief.number(spec['benchmark'], units)}")
    title = f"{t['name']} ({t['class_name']}), {t['pack']}: {words}"
    if None in median:
        title += f"\n{classpage.MEDIAN_WITHHELD}"
    own = by_trainee.get(t["name"], [])  # every attempt of the pack, not only the page's
    ylabel = f"{words} ({units})" if units else words
    return plots.render(own, median, metric, title, fmt, ylabel=ylabel, benchmark=bench)


def attempt_detail(store: RecordStore, user: User, attempt_id: int) -> dict:
    a = readable_attempt(store, user, attempt_id)
    return {"attempt": a, "trainee_id": listings.id_of_trainee(store, a["class_name"], a["trainee"])}


# -- routes -----------------------------------------------------------------------------------


def _int_param(request: Request, name: str) -> int:
    value = int(request.path_params[name])
    if not 1 <= value < 2**63:
        raise HTTPError(404, f"no such {name.split('_')[0]}")
    return value


async def login_page(request: Request) -> Response:
    if await session(request) is not None:
        return RedirectResponse("/", status_code=303)
    token = new_login_csrf()
    resp = render("login.html", csrf=token, error=None, name="")
    resp.set_cookie(LOGIN_CSRF_COOKIE, token, httponly=True, samesite="strict", secure=_secure(request))
    return resp


async def login_submit(request: Request) -> Response:
    form = await read_form(request)
    cookie = request.cookies.get(LOGIN_CSRF_COOKIE)
    if not cookie:
        raise HTTPError(403, "sign-in form expired or forged (no CSRF cookie); reload the sign-in page")
    check_csrf(request, form, cookie)
    key, address = throttle.guarded(request, form.get("name", ""))
    storage = request.app.state.storage
    user = await storage.run(accounts.check_login, form.get("name", ""), form.get("password", ""))
    if user is None:
        request.app.state.throttle.failed(key, address)
        token = new_login_csrf()
        resp = render("login.html", 401, csrf=token, error="Name or password is wrong.", name=form.get("name", "")[:64])
        resp.set_cookie(LOGIN_CSRF_COOKIE, token, httponly=True, samesite="strict", secure=_secure(request))
        return resp
    request.app.state.throttle.succeeded(key)
    sid, _ = await storage.run(accounts.start_session, user)
    resp = RedirectResponse("/", status_code=303)
    resp.set_cookie(
        SESSION_COOKIE,
        sid,
        max_age=accounts.SESSION_TTL_S,
        httponly=True,
        samesite="lax",
        secure=_secure(request),
    )
    resp.delete_cookie(LOGIN_CSRF_COOKIE)
    return resp


async def logout(request: Request) -> Response:
    user, csrf = await page_user(request)
    check_csrf(request, await read_form(request), csrf)
    await request.app.state.storage.run(accounts.end_session, request.cookies[SESSION_COOKIE])
    resp = RedirectResponse("/login", status_code=303)
    resp.delete_cookie(SESSION_COOKIE)
    return resp


async def home(request: Request) -> Response:
    user, csrf = await page_user(request)
    storage = request.app.state.storage
    if not user.is_trainer:
        if user.trainee_id is None:
            raise HTTPError(403, "this trainee account has no trainee record; ask your trainer")
        return RedirectResponse(f"/trainees/{user.trainee_id}", status_code=303)
    classes = await storage.run(class_list, user)
    return render("home.html", user=user, csrf=csrf, classes=classes)


async def class_page(request: Request) -> Response:
    user, csrf = await page_user(request)
    packs = getattr(request.app.state, "packs", None)
    q = dict(request.query_params)
    cls = await request.app.state.storage.run(
        classpage.overview, user, _int_param(request, "class_id"), lambda name: metric_specs(packs, name), q
    )
    notes = {"added": "Trainee account added.", "password": "New password set; their sessions and tokens have ended."}
    return render("class.html", user=user, csrf=csrf, cls=cls, note=notes.get(q.get("done", ""), ""))


async def class_plot(request: Request) -> Response:
    user, _ = await page_user(request)
    pack, metric = request.path_params["pack"], request.path_params["image"]
    if not metric.endswith(".svg"):
        raise HTTPError(404, f"class plots are .svg, got {metric!r}")
    specs = await asyncio.to_thread(metric_specs, getattr(request.app.state, "packs", None), pack)
    data = await request.app.state.storage.run(
        classpage.metric_plot, user, _int_param(request, "class_id"), pack, metric[:-4], specs
    )
    return Response(data, media_type="image/svg+xml", headers={"Cache-Control": "private, no-store"})


async def _manage(request: Request, action, done: str) -> Response:
    """A trainer's form on the class page: CSRF-checked; a refused one counts like a failed sign-in."""
    user, csrf = await page_user(request)
    form = await read_form(request)
    check_csrf(request, form, csrf)
    if not user.is_trainer:
        raise HTTPError(403, "only trainers manage classes")
    key, address = throttle.guarded(request, user.name)
    class_id = _int_param(request, "class_id")
    try:
        await request.app.state.storage.run(action, user, class_id, form.get("name", ""), form.get("password", ""))
    except (HTTPError, UserError):
        request.app.state.throttle.failed(key, address)
        raise
    return RedirectResponse(f"/classes/{class_id}?done={done}", status_code=303)


async def class_add_trainee(request: Request) -> Response:
    return await _manage(request, classpage.add_trainee, "added")


async def class_reset_password(request: Request) -> Response:
    return await _manage(request, classpage.reset_password, "password")


async def trainee_page(request: Request) -> Response:
    user, csrf = await page_user(request)
    packs = getattr(request.app.state, "packs", None)
    t = await request.app.state.storage.run(
        trainee_detail,
        user,
        _int_param(request, "trainee_id"),
        lambda name: metric_specs(packs, name),
        dict(request.query_params),
    )
    return render("trainee.html", user=user, csrf=csrf, t=t, labels=t["metrics"])


async def plot_image(request: Request) -> Response:
    user, _ = await page_user(request)
    metric, _, fmt = request.path_params["image"].rpartition(".")
    if fmt not in plots.FORMATS or not metric:
        raise HTTPError(404, f"plots are .svg or .png, got {request.path_params['image']!r}")
    pack = request.path_params.get("pack", "")
    specs = await asyncio.to_thread(metric_specs, getattr(request.app.state, "packs", None), pack) if pack else {}
    data = await request.app.state.storage.run(
        trainee_plot, user, _int_param(request, "trainee_id"), metric, fmt, pack, specs
    )
    return Response(data, media_type=plots.FORMATS[fmt], headers={"Cache-Control": "private, no-store"})


_SPECS: dict[str, tuple] = {}  # pack root -> (its pack.toml's modification time, [metrics] section)


def metric_specs(packs, name: str) -> dict:
    """The [metrics] section (labels, units, benchmarks) of pack `name` as the server has it; {} when
    the server has no such pack (the page then names the metrics without verdicts)."""
    from pathlib import Path  # noqa: PLC0415

    from chainsim.game.packs import pack as packlib  # noqa: PLC0415 - loaded when an attempt page needs it

    info = packs.info(name) if packs is not None else None
    if info is None:
        return {}
    root = Path(info["root"])
    stamp = (root / "pack.toml").stat().st_mtime_ns
    hit = _SPECS.get(str(root))
    if hit is None or hit[0] != stamp:
        hit = _SPECS[str(root)] = (stamp, dict(packlib.load(root, packs.pack_paths).section("metrics")))
    return hit[1]


#: an attempt's fields said in words on its page: field -> (words, units); the procedure's own fields
#: as it words them (a pack's [metrics] labels and units come first, `metric_specs`)
FIELD_WORDS = {"pack": ("Procedure", ""), "created_at": ("Saved", ""), **LAYOUT.field_words}


def layout_of(a: dict) -> AttemptLayout:
    """The attempt layout of a stored attempt's procedure (an attempt that names none is the records'
    own procedure's): its figures, words and marks as that procedure declares them."""
    return attempt_layout(a.get("procedure", RECORDS_PROCEDURE.name))


def said(key: str, value, field_words: dict[str, tuple[str, str]] | None = None) -> tuple[str, str]:
    """(words, value in words) for one field of an attempt: numbers rounded with units, points as
    x, y, z in mm, lists and tables summarised, never raw JSON. `field_words`: the attempt's procedure's
    (default: the records' own procedure's)."""
    words, units = (field_words or FIELD_WORDS).get(key, (key.replace("_", " ").capitalize(), ""))
    if not units:
        for suffix, u in (("_mm", "mm"), ("_s", "s"), ("_deg", "deg"), ("_mgy", "mGy")):
            if key.endswith(suffix):
                units = u
    if value is None:
        return words, "-"
    if isinstance(value, bool):
        return words, "yes" if value else "no"
    if isinstance(value, (int, float)):
        return words, debrief.number(value, units)
    if isinstance(value, list) and len(value) == 3 and all(isinstance(c, (int, float)) for c in value):
        return words, ", ".join(f"{c:.1f}" for c in value) + " mm (x, y, z)"
    if isinstance(value, list):
        return words, f"{len(value)} items"
    if isinstance(value, dict):
        return words, "; ".join(f"{k.replace('_', ' ')} {said(k, v, field_words)[1]}" for k, v in value.items())
    return words, str(value).replace("_", " ")


def attempt_view(a: dict, specs: dict) -> dict:
    """What the attempt page shows: the verdict, one row per metric, the marked points' terms and the rest."""
    lay = layout_of(a)  # the attempt's procedure words its own figures (a cutting attempt's cut length ...)
    fw = {"pack": ("Procedure", ""), "created_at": ("Saved", ""), **lay.field_words}
    values = dict(a.get("metrics") or {})
    shown = ("duration_s", "path_length_mm", "redirections") if lay is LAYOUT else tuple(c.name for c in lay.columns)
    for k in (lay.mark_error, lay.target_error, *shown):
        if k:
            values.setdefault(k, a.get(k))
    if not specs:  # a pack the server does not have: its stored metrics, named, without verdicts
        specs = {k: {"label": said(k, None, fw)[0], "units": said(k, None, fw)[1] or ""} for k in values}
        for k in specs:
            specs[k]["units"] = fw.get(k, ("", ""))[1]
    rows = debrief.verdicts(specs, values)
    d = dict(a.get("details") or {})
    placed = (d.get(lay.marks) or []) if lay.marks else []
    ideal = (d.get(lay.ideal_marks) or []) if lay.ideal_marks else []
    marks = []
    for k, p in enumerate(placed, start=1):
        marks.append(
            {
                "k": k,
                "placed": said("p", p)[1] if p else "not placed",
                "ideal": said("p", ideal[k - 1])[1] if k - 1 < len(ideal) and ideal[k - 1] else "-",
                "D": debrief.number(d.get(f"D{k}"), "mm"),
                "d": debrief.number(d.get(f"d{k}"), "mm"),
            }
        )
    skip = {lay.marks, lay.ideal_marks, "needle_path", "ideal_path", "verdict", "contacts", "protocol"}
    # shown under "Force through the device" and as the pack's device metrics, not again as raw details
    skip |= {"force_profile", "reported_by_device", "device_peak_force_N", "puncture_force_N", "bone_contact_s"}
    skip |= {k for k in d if k[:1] in "Dd" and k[1:].isdigit() or k.startswith("Dist")}
    facts = [said(k, a.get(k), fw) for k in ("pack", "created_at", "target") if k in a]
    facts += [said(k, v, fw) for k, v in d.items() if k not in skip]
    facts += lay.contact_facts(d)  # bone contacts counted; the target reached is no contact
    if d.get("needle_path"):
        facts.append(("Needle path stored", f"{len(d['needle_path'])} points"))
    return {
        "rows": rows,
        "outcome": debrief.outcome(rows),
        "verdict": debrief.verdict_line(debrief.outcome(rows)) if any(r["passed"] is not None for r in rows) else "",
        "marks": marks,
        "marks_heading": lay.marks_heading,
        "marks_column": lay.marks_column,
        "marks_note": Markup(lay.marks_note),  # the procedure's own text, with its subscripts
        "facts": facts,
        "force": _force_view(d),
        "basis_note": debrief.basis_note(rows),
        "saved_basis": saved_basis(d.get("verdict"), rows),
    }


def saved_basis(verdict: Any, rows: list[dict]) -> str:
    """What the attempt's stored verdict rested on (details.verdict.benchmarks), and which of those
    benchmarks the pack has changed since; '' for an attempt saved before verdicts kept them."""
    saved = verdict.get("benchmarks") if isinstance(verdict, dict) else None
    if not isinstance(saved, dict):
        return ""
    saved = {k: b for k, b in saved.items() if isinstance(b, dict)}
    if not saved:
        return ""
    bases = Counter(str(b.get("basis") or "provisional") for b in saved.values())
    text = f"When it was saved, this attempt was judged against {len(saved)} benchmarks: " + ", ".join(
        f"{n} {basis}" for basis, n in sorted(bases.items())
    )
    now = {r["name"]: r for r in rows}
    changed = []
    for name, b in saved.items():
        r = now.get(name, {"label": name, "units": "", "benchmark": None, "basis": ""})
        if (r["benchmark"], r["basis"]) != (b.get("benchmark"), b.get("basis")):
            then = b.get("benchmark") if isinstance(b.get("benchmark"), (int, float)) else None
            changed.append(f"{r['label']} (then {debrief.number(then, r['units'])}, {b.get('basis') or '-'})")
    if changed:
        text += ". The pack's benchmarks have changed since; the verdicts above use today's: " + "; ".join(changed)
    return text + "."


def _force_view(d: dict) -> dict | None:
    """What the page says of the forces felt through a device (None: made without one)."""
    profile = d.get("force_profile")
    if not d.get("device") or not isinstance(profile, list) or not profile:
        return None
    reported = d.get("reported_by_device") or []
    return {
        "device": str(d["device"]),
        "points": len(profile),
        "reported": bool(reported),
        "alt": (
            f"{len(profile)} points; peak "
            f"{debrief.number(d.get('device_peak_force_N'), 'N')}, at the first puncture "
            f"{debrief.number(d.get('puncture_force_N'), 'N')}, {debrief.number(d.get('bone_contact_s'), 's')} on bone"
        ),
    }


#: the attempt page's import map (three.js's modules import "three"); inline, so allowed by its hash
IMPORT_MAP = '{"imports": {"three": "/static/vendor/three/three.module.js"}}'
_MAP_HASH = base64.b64encode(hashlib.sha256(IMPORT_MAP.encode()).digest()).decode()
#: the site's policy, with this site's scripts and the import map allowed (the 3-D replay)
REPLAY_CSP = (
    f"default-src 'self'; img-src 'self'; style-src 'self'; script-src 'self' 'sha256-{_MAP_HASH}'; "
    "connect-src 'self'; frame-ancestors 'none'; form-action 'self'; base-uri 'none'"
)


async def attempt_page(request: Request) -> Response:
    user, csrf = await page_user(request)
    d = await request.app.state.storage.run(attempt_detail, user, _int_param(request, "attempt_id"))
    a = d["attempt"]
    specs = await request.app.state.storage.run(
        lambda *_: metric_specs(getattr(request.app.state, "packs", None), a.get("pack", ""))
    )
    view = attempt_view(a, specs)
    page = render("attempt.html", user=user, csrf=csrf, a=a, trainee_id=d["trainee_id"], v=view, import_map=IMPORT_MAP)
    page.headers["Content-Security-Policy"] = REPLAY_CSP
    return page


# -- the attempt in 3-D (chainsim.game.server.replay3d) ------------------------------------------


def stored_recording(store: RecordStore, attempt_id: int) -> str:
    """The attempt's stored recording; 404 when it has none."""
    recording = store.recording(attempt_id)
    if recording is None:
        raise HTTPError(404, f"attempt {attempt_id} has no recording (only attempts the server scored can be replayed)")
    return recording


def attempt_recording(store: RecordStore, user: User, attempt_id: int) -> tuple[dict, str]:
    """The attempt (if this account may read it) and its stored recording; 404 when it has none."""
    a = readable_attempt(store, user, attempt_id)
    return a, stored_recording(store, attempt_id)


def attempt_geometry(a: dict) -> dict:
    """The attempt's own geometry the 3-D page draws beside the replay: the marked points and their ideal
    places, the needle's path and the ideal one (under their stored names)."""
    d = a.get("details") or {}
    return {
        LAYOUT.marks: d.get(LAYOUT.marks) or [],
        LAYOUT.ideal_marks: d.get(LAYOUT.ideal_marks) or [],
        "ideal_path": d.get("ideal_path"),
        "needle_path": d.get("needle_path") or [],
    }


def pack_info(request: Request, name: str, pack_hash: str | None = None) -> dict:
    info = request.app.state.packs.info(name)
    if info is None:
        raise HTTPError(404, f"this server has no pack {name!r}, so the attempt cannot be replayed")
    if pack_hash and info["identity"]["hash"] != pack_hash:
        raise HTTPError(409, f"pack {name!r} changed since this attempt was scored; its replay would differ")
    return info


def replays(request: Request) -> replay3d.Replays:
    state = request.app.state
    if getattr(state, "replays", None) is None:
        state.replays = replay3d.Replays()
    return state.replays


def pack_paths(request: Request) -> list[str]:
    return list(request.app.state.packs.pack_paths)


def _cached(request: Request, etag: str, max_age: int) -> dict[str, str] | None:
    """Cache headers for a response whose bytes depend only on `etag`; None when the browser's copy is current."""
    headers = {"ETag": f'"{etag}"', "Cache-Control": f"private, max-age={max_age}"}
    return None if request.headers.get("if-none-match", "").strip() == headers["ETag"] else headers


async def _track(request: Request) -> tuple[dict, dict, str]:
    user, _ = await page_user(request)
    attempt_id = _int_param(request, "attempt_id")
    a, recording = await request.app.state.storage.run(attempt_recording, user, attempt_id)
    info = await asyncio.to_thread(pack_info, request, a["pack"], a.get("pack_hash"))
    key = replay3d.track_key(recording, info["identity"]["hash"])
    # a replay takes seconds: on a thread of its own, not one of the database's workers
    track = await asyncio.to_thread(replays(request).track, key, recording, info["root"], pack_paths(request))
    return a, track, key


async def attempt_replay(request: Request) -> Response:
    """The attempt's replay track (JSON): the needle over time, contacts, X-ray image addresses, and
    the stored marked points and paths the page draws beside it (under their stored names)."""
    a, track, key = await _track(request)
    headers = _cached(request, key, 3600)
    if headers is None:
        return Response(status_code=304, headers={"ETag": f'"{key}"'})
    body = replay3d.public_track(track, a["id"])
    body.update({"pack": a["pack"], "mesh": f"/packs/{a['pack']}/display.glb", **attempt_geometry(a)})
    return Response(json.dumps(body), media_type="application/json", headers=headers)


def xray_image(track: dict, name: str, whose: str) -> tuple[int, bytes]:
    """(k, PNG bytes) of the track's X-ray image named "k.png" (1-based); 404 naming how many there are."""
    k = int(name[:-4]) if name.endswith(".png") and name[:-4].isdigit() else 0
    if not 1 <= k <= len(track["images"]):
        raise HTTPError(404, f"{whose} has {len(track['images'])} X-ray images; no image {name!r}")
    return k, track["images"][k - 1]["png"]


async def attempt_xray(request: Request) -> Response:
    a, track, key = await _track(request)
    k, png = xray_image(track, request.path_params["image"], f"attempt {a['id']}")
    headers = _cached(request, f"{key}-{k}", 3600)
    if headers is None:
        return Response(status_code=304)
    return Response(png, media_type="image/png", headers=headers)


#: the force profile's plots: image name -> what the force is drawn against
FORCE_PLOTS = {"force-depth.svg": "depth", "force-time.svg": "time"}


def force_plot(store: RecordStore, user: User, attempt_id: int, against: str) -> bytes:
    """The force profile of an attempt made with a force-feedback device (404 for one made without)."""
    a = readable_attempt(store, user, attempt_id)
    profile = (a.get("details") or {}).get("force_profile")
    if not isinstance(profile, list) or not profile:
        raise HTTPError(404, f"attempt {attempt_id} was made without a force-feedback device: no force profile")
    title = f"Attempt {attempt_id}: force against {'depth' if against == 'depth' else 'time'}"
    return plots.force_profile(profile, title, against)


async def attempt_force(request: Request) -> Response:
    user, _csrf = await page_user(request)
    against = FORCE_PLOTS.get(request.path_params["image"])
    if against is None:
        raise HTTPError(404, f"the force plots are {' and '.join(FORCE_PLOTS)}, got {request.path_params['image']!r}")
    data = await request.app.state.storage.run(force_plot, user, _int_param(request, "attempt_id"), against)
    return Response(data, media_type="image/svg+xml", headers={"Cache-Control": "private, no-store"})


async def pack_mesh(request: Request) -> Response:
    """The pack's anatomy as binary glTF, cached by the pack's version (its hash)."""
    await page_user(request)
    info = await asyncio.to_thread(pack_info, request, request.path_params["pack"])
    etag = info["identity"]["hash"][:32]
    headers = _cached(request, etag, 86400)
    if headers is None:
        return Response(status_code=304, headers={"ETag": f'"{etag}"'})
    data = await asyncio.to_thread(replays(request).glb, etag, info["root"], pack_paths(request))
    return Response(data, media_type="model/gltf-binary", headers=headers)


async def attempt_retract(request: Request) -> Response:
    user, csrf = await page_user(request)
    form = await read_form(request)
    check_csrf(request, form, csrf)
    attempt_id = _int_param(request, "attempt_id")
    await request.app.state.storage.run(retract_attempt, user, attempt_id, form.get("reason", ""))
    return RedirectResponse(f"/attempts/{attempt_id}", status_code=303)


async def attempt_accept(request: Request) -> Response:
    user, csrf = await page_user(request)
    form = await read_form(request)
    check_csrf(request, form, csrf)
    attempt_id = _int_param(request, "attempt_id")
    await request.app.state.storage.run(accept_attempt, user, attempt_id)
    return RedirectResponse(f"/attempts/{attempt_id}", status_code=303)


async def audit_page(request: Request) -> Response:
    user, csrf = await page_user(request)
    rows = await request.app.state.storage.run(audit_entries, user, None)
    return render("audit.html", user=user, csrf=csrf, rows=rows)


async def _export_rows(request: Request) -> list[dict]:
    user = await page_or_api_user(request)
    if user is None:
        raise Redirect("/login")
    q = request.query_params
    return await request.app.state.storage.run(visible_attempts, user, q.get("class"), q.get("trainee"))


async def export_csv(request: Request) -> Response:
    rows = await _export_rows(request)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(report.CSV_COLUMNS)
    w.writerows(report.csv_rows(rows))
    return Response(
        buf.getvalue(),
        media_type="text/csv; charset=utf-8",
        headers={"Content-Disposition": 'attachment; filename="attempts.csv"'},
    )


async def export_xapi(request: Request) -> Response:
    rows = await _export_rows(request)
    home = request.app.state.base_url  # configured: a Host header must not choose whose identities these are
    return Response(
        xapi.dumps(xapi.statements(rows, home)),
        media_type="application/json",
        headers={"Content-Disposition": 'attachment; filename="attempts.xapi.json"'},
    )


routes = [
    Route("/login", login_page, methods=["GET"]),
    Route("/login", login_submit, methods=["POST"]),
    Route("/logout", logout, methods=["POST"]),
    Route("/", home, methods=["GET"]),
    Route("/classes/{class_id:int}", class_page, methods=["GET"]),
    Route("/classes/{class_id:int}/plot/{pack}/{image}", class_plot, methods=["GET"]),
    Route("/classes/{class_id:int}/trainees", class_add_trainee, methods=["POST"]),
    Route("/classes/{class_id:int}/password", class_reset_password, methods=["POST"]),
    Route("/trainees/{trainee_id:int}", trainee_page, methods=["GET"]),
    Route("/trainees/{trainee_id:int}/plot/{image}", plot_image, methods=["GET"]),
    Route("/trainees/{trainee_id:int}/plot/{pack}/{image}", plot_image, methods=["GET"]),
    Route("/attempts/{attempt_id:int}", attempt_page, methods=["GET"]),
    Route("/attempts/{attempt_id:int}/retract", attempt_retract, methods=["POST"]),
    Route("/attempts/{attempt_id:int}/accept", attempt_accept, methods=["POST"]),
    Route("/attempts/{attempt_id:int}/replay.json", attempt_replay, methods=["GET"]),
    Route("/attempts/{attempt_id:int}/xray/{image}", attempt_xray, methods=["GET"]),
    Route("/attempts/{attempt_id:int}/plot/{image}", attempt_force, methods=["GET"]),
    Route("/packs/{pack}/display.glb", pack_mesh, methods=["GET"]),
    Route("/audit", audit_page, methods=["GET"]),
    Route("/export/attempts.csv", export_csv, methods=["GET"]),
    Route("/export/attempts.xapi.json", export_xapi, methods=["GET"]),
]
