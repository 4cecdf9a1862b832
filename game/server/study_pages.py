"""The trainers' register page of a study on the records server: /studies/{study}.

The same register as /api/studies (chainsim.game.study.register), for a trainer signed in to the
dashboard: the participants of their classes in slot order with their covariates, a form that
enters the next one before their first trial and shows the slot (the row of the protocol's design)
they are given, and, once the study's design is filed, the browser trainer's link for its trials. A
bad entry is answered with the error page naming the field (4xx); nothing is saved.
It also holds the store work of a registration, which the JSON API (study_api) runs too.
"""

from __future__ import annotations

from urllib.parse import quote

from starlette.requests import Request
from starlette.responses import RedirectResponse, Response
from starlette.routing import Route

from chainsim.game.records.accounts import User
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_name
from chainsim.game.server.auth import HTTPError, check_csrf, read_form
from chainsim.game.server.dashboard import page_user, render
from chainsim.game.study import register
from chainsim.systems.engine.errors import UserError

# -- store work (storage worker threads), run by this page and by the JSON API (study_api) ------------


def trainer_only(user: User) -> None:
    if not user.is_trainer:
        raise HTTPError(403, "the study register is kept by trainers")


def register_as(store: RecordStore, user: User, study: str, body: object) -> tuple[dict, bool]:
    class_name = body.get("class_name") if isinstance(body, dict) else None
    try:
        class_name = clean_name("class", class_name)
    except UserError as exc:
        raise HTTPError(422, f"{exc} (class_name: the class the participant's trials are saved under)") from None
    if class_name not in user.classes:
        raise HTTPError(403, "you do not teach that class")
    try:
        return register.register(store, study, class_name, body, user.name)
    except register.AlreadyRegistered as exc:
        raise HTTPError(409, str(exc)) from None
    except UserError as exc:
        if type(exc) is not UserError:
            raise
        raise HTTPError(422, str(exc)) from None


async def study_page(request: Request) -> Response:
    user, csrf = await page_user(request)
    trainer_only(user)
    study = request.path_params["study"]
    rows = await request.app.state.storage.run(register.entries, study, list(user.classes))
    filed = await request.app.state.storage.run(register.design_of, study)
    added = request.query_params.get("added", "")
    note = next((f"{r['code']} registered: slot {r['slot']}." for r in rows if r["code"] == added), "")
    pack = filed["pack"] if filed else ""
    return render(
        "study.html", user=user, csrf=csrf, study=study, rows=rows, design=register.DESIGN, note=note, pack=pack
    )


async def study_register(request: Request) -> Response:
    user, csrf = await page_user(request)
    form = await read_form(request)
    check_csrf(request, form, csrf)
    trainer_only(user)
    body = {k: form.get(k, "") for k in ("class_name", *register.FIELDS)}
    study = request.path_params["study"]
    entry, _ = await request.app.state.storage.run(register_as, user, study, body)
    where = f"/studies/{quote(study, safe='')}?added={quote(entry['code'], safe='')}"
    return RedirectResponse(where, status_code=303)


routes = [
    Route("/studies/{study}", study_page, methods=["GET"]),
    Route("/studies/{study}", study_register, methods=["POST"]),
]
