"""The records server's study register under /api/studies (chainsim.game.study.register): trainers only.

    POST /api/studies/{study}/participants         {"class_name", "code", "group", "year_of_training",
                                                    "procedures_performed"} -> 201 the entry with its
                                                    ``slot`` (200: the same registration again)
    GET  /api/studies/{study}/participants         the register, in slot order (the trainer's classes)
    GET  /api/studies/{study}/participants/{code}  one entry (404 when not registered)
    POST /api/studies/{study}/design               the study's trials and aids (``chainsim protocol`` sends
                                                    them) -> 201, 200 for the same design again, 409 for
                                                    another: uploaded trials are checked against it

The slot is the participant's place in the study's one allocation sequence, kept in this database, so
the simulator at every site takes its condition order from here (``chainsim protocol --records``).
A bad field is a 422 naming it; other covariates for a registered participant a 409.
"""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from chainsim.game.records.accounts import User
from chainsim.game.records.store import RecordStore
from chainsim.game.server import study_pages
from chainsim.game.server.auth import HTTPError, api_user, read_json
from chainsim.game.server.study_pages import register_as, trainer_only
from chainsim.game.study import register
from chainsim.systems.engine.errors import UserError


def _one(store: RecordStore, user: User, study: str, code: str) -> dict:
    entry = register.lookup(store, study, code)
    if entry is None or entry["class_name"] not in user.classes:
        raise HTTPError(404, f"no participant {code!r} in the register of study {study!r}")
    return entry


async def add_participant(request: Request) -> Response:
    user = await api_user(request)
    trainer_only(user)
    body = await read_json(request)
    storage = request.app.state.storage
    entry, created = await storage.run(register_as, user, request.path_params["study"], body)
    return JSONResponse(entry, status_code=201 if created else 200)


async def list_participants(request: Request) -> Response:
    user = await api_user(request)
    trainer_only(user)
    rows = await request.app.state.storage.run(register.entries, request.path_params["study"], list(user.classes))
    return JSONResponse({"study": request.path_params["study"], "design": register.DESIGN, "participants": rows})


async def get_participant(request: Request) -> Response:
    user = await api_user(request)
    trainer_only(user)
    p = request.path_params
    return JSONResponse(await request.app.state.storage.run(_one, user, p["study"], p["code"]))


def _file_design(store: RecordStore, user: User, study: str, body: object) -> tuple[dict, bool]:
    try:
        return register.file_design(store, study, body, user.name)
    except register.AlreadyRegistered as exc:
        raise HTTPError(409, str(exc)) from None
    except UserError as exc:
        raise HTTPError(422, str(exc)) from None


async def file_design(request: Request) -> Response:
    user = await api_user(request)
    trainer_only(user)
    body = await read_json(request)
    kept, created = await request.app.state.storage.run(_file_design, user, request.path_params["study"], body)
    return JSONResponse(kept, status_code=201 if created else 200)


routes = [
    Route("/api/studies/{study}/design", file_design, methods=["POST"]),
    Route("/api/studies/{study}/participants", add_participant, methods=["POST"]),
    Route("/api/studies/{study}/participants", list_participants, methods=["GET"]),
    Route("/api/studies/{study}/participants/{code}", get_participant, methods=["GET"]),
    *study_pages.routes,  # the trainers' page of the same register
]
