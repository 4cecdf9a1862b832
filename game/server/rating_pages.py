"""The raters' pages of a blinded rating (chainsim.game.study.rating): each rater's secret link opens their
list of coded attempts, each attempt replayed in 3-D with the global rating form, and nothing else.

    GET  /rate/{token}                           the rater's attempts, in their own order, rated or not
    GET  /rate/{token}/{code}                    one attempt: the 3-D replay and the form
    POST /rate/{token}/{code}                    the marks (same origin only); back to the list
    GET  /rate/{token}/{code}/replay.json        the replay track, without the trainee, class, dates or ids
    GET  /rate/{token}/{code}/xray/{k}.png       the X-ray images the trainee took
    GET  /rate/{token}/{code}/display.glb        the pack's anatomy

Blinding: the pages and the track carry the code only: no name, class, date, attempt id, metric or
verdict (the raters' judgement is compared with the metrics afterwards, so it must not see them). The
link is the credential (its hash is stored); an unknown link or a code not in the rater's set is 404.
"""

from __future__ import annotations

import asyncio
import json

from starlette.requests import Request
from starlette.responses import RedirectResponse, Response
from starlette.routing import Route

from chainsim.game.server import dashboard as views
from chainsim.game.server import replay3d
from chainsim.game.server.auth import HTTPError, read_form, same_origin
from chainsim.game.study import rating
from chainsim.systems.engine.errors import UserError

#: what of the replay track a rater sees: the needle over time, contacts, the images, the procedure's
#: marked and ideal points (the attempt's own geometry); never who, when or the attempt's id
TRACK_KEYS = ("duration_s", "frames", "contacts", "reached", "needle_length_mm")


async def _rater(request: Request) -> rating.Rater:
    r = await request.app.state.storage.run(lambda store, *_: rating.rater_for(store, request.path_params["token"]))
    if r is None:
        raise HTTPError(404, "this rating link is not known here; ask for your link again")
    return r


async def _attempt(request: Request, r: rating.Rater) -> int:
    code = request.path_params["code"]
    aid = await request.app.state.storage.run(lambda store, *_: rating.attempt_of(store, r, code))
    if aid is None:
        raise HTTPError(404, f"no attempt {code!r} in your rating set")
    return aid


async def rate_list(request: Request) -> Response:
    r = await _rater(request)
    items = await request.app.state.storage.run(lambda store, *_: rating.items_for(store, r))
    done = sum(1 for i in items if i["rated"])
    return views.render("rate_list.html", user=None, r=r, items=items, done=done, token=request.path_params["token"])


async def rate_attempt(request: Request, error: str = "", given: dict | None = None) -> Response:
    r = await _rater(request)
    await _attempt(request, r)
    token, code = request.path_params["token"], request.path_params["code"]
    page = views.render(
        "rate_attempt.html",
        400 if error else 200,
        user=None,
        r=r,
        code=code,
        token=token,
        form=r.form,
        marks=range(rating.MARKS[0], rating.MARKS[1] + 1),
        error=error,
        given=given or {},
        import_map=views.IMPORT_MAP,
    )
    page.headers["Content-Security-Policy"] = views.REPLAY_CSP
    return page


async def rate_submit(request: Request) -> Response:
    if not same_origin(request):
        raise HTTPError(403, "a rating is accepted from this server's own page only")
    r = await _rater(request)
    await _attempt(request, r)
    given = await read_form(request)
    code = request.path_params["code"]
    try:
        await request.app.state.storage.run(lambda store, *_: rating.save_rating(store, r, code, given))
    except UserError as e:
        return await rate_attempt(request, error=str(e), given=given)
    return RedirectResponse(f"/rate/{request.path_params['token']}", status_code=303)


async def _track(request: Request) -> tuple[dict, str, dict]:
    r = await _rater(request)
    aid = await _attempt(request, r)
    a, recording = await request.app.state.storage.run(
        lambda store, *_: (store.get_attempt(aid), views.stored_recording(store, aid))
    )
    info = await asyncio.to_thread(views.pack_info, request, a["pack"], a.get("pack_hash"))
    key = replay3d.track_key(recording, info["identity"]["hash"])
    track = await asyncio.to_thread(
        views.replays(request).track, key, recording, info["root"], views.pack_paths(request)
    )
    return track, key, a


async def rate_replay(request: Request) -> Response:
    track, key, a = await _track(request)
    base = f"/rate/{request.path_params['token']}/{request.path_params['code']}"
    body = {k: track[k] for k in TRACK_KEYS if k in track}
    body["images"] = [
        {**{k: v for k, v in im.items() if k != "png"}, "url": f"{base}/xray/{n + 1}.png"}
        for n, im in enumerate(track["images"])
    ]
    body["mesh"] = f"{base}/display.glb"
    body.update(views.attempt_geometry(a))
    return Response(json.dumps(body), media_type="application/json", headers={"Cache-Control": "private, no-store"})


async def rate_xray(request: Request) -> Response:
    track, _key, _a = await _track(request)
    _k, png = views.xray_image(track, request.path_params["image"], "this attempt")
    return Response(png, media_type="image/png", headers={"Cache-Control": "private"})


async def rate_mesh(request: Request) -> Response:
    r = await _rater(request)
    aid = await _attempt(request, r)
    a = await request.app.state.storage.run(lambda store, *_: store.get_attempt(aid))
    info = await asyncio.to_thread(views.pack_info, request, a["pack"])
    etag = info["identity"]["hash"][:32]
    data = await asyncio.to_thread(views.replays(request).glb, etag, info["root"], views.pack_paths(request))
    return Response(data, media_type="model/gltf-binary", headers={"Cache-Control": "private, max-age=86400"})


routes = [
    Route("/rate/{token}", rate_list, methods=["GET"]),
    Route("/rate/{token}/{code}", rate_attempt, methods=["GET"]),
    Route("/rate/{token}/{code}", rate_submit, methods=["POST"]),
    Route("/rate/{token}/{code}/replay.json", rate_replay, methods=["GET"]),
    Route("/rate/{token}/{code}/xray/{image}", rate_xray, methods=["GET"]),
    Route("/rate/{token}/{code}/display.glb", rate_mesh, methods=["GET"]),
]
