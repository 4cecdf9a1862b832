"""A study run in the browser trainer (/train/PACK?study=STUDY, chainsim.game.server.train_routes.study_seat).

A trainee registered in a study opens the seat with the study: its pages come before each trial, each
trial has the aids of the trainee's allocation, practice first, and every Save is filed as a witnessed
attempt whose details.protocol the server checked against its register. Driven over the seat's socket
with a signed-in trainee's cookie, as test_train.py drives seats; checked on SQLite (the seat's rules do
not depend on the database; the register's are tested on both in test_study_trials.py)."""

from __future__ import annotations

import asyncio
import json
import time
import uuid

import pytest
from conftest import SCRIPTS, call
from test_browser import browser, sign_in  # noqa: F401 - the module's Chromium fixture
from test_train import cookie_for, in_thread

PROTOCOL = {
    "pack": "prp",
    "practice": 1,
    "trials": [
        {
            "name": "loc-planes",
            "task": "location",
            "condition": "reference_planes",
            "repeat": 1,
            "aids": {"reference_planes": True},
        },
        {"name": "loc-none", "task": "location", "condition": "without_clues", "repeat": 1, "aids": {}},
    ],
}


def window_messages(events) -> list[tuple[float, dict]]:
    """(seconds after the previous one, socket message) for window events (as the page sends them)."""
    out, last = [], events[0][0]
    for t, ev in events:
        msg = {"type": ev.kind, "x": ev.x, "y": ev.y}
        if ev.kind == "mouse_button":
            msg.update(button=ev.button, pressed=ev.pressed)
        out.append((t - last, msg))
        last = t
    return out


def trial_clicks() -> list[tuple[float, dict]]:
    """A location trial at the window: the correct script's three points clicked, then Save."""
    from chainsim.components.input_events import PickPoint
    from chainsim.game.trainer import windowform
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script

    picks = [(0.2 * k, e) for k, (_, e) in enumerate(load_script(SCRIPTS / "correct.toml")) if isinstance(e, PickPoint)]
    app = build_app("prp")
    try:
        events = windowform.gestures(app, picks[:3], close_page=False)
        events += windowform.save_click(app, max(t for t, _ in events))
    finally:
        app.close()
    return window_messages(events)


async def _run(url: str, path: str, cookie: str, trials: int, clicks, filed) -> list[str]:
    """Open the seat, then per trial: Enter on its page, the clicks, a wait until `filed()` (the attempts
    the server has from this session) counts the trial's Save: a loaded machine files it late, and the
    next trial's Enter must not come first."""
    import websockets

    seen: list[str] = []
    async with websockets.connect(
        url.replace("http", "ws", 1) + path,
        additional_headers={"Cookie": f"chainsim_session={cookie}"},
        origin=url,
        max_size=None,
    ) as ws:

        async def read() -> None:
            async for msg in ws:
                seen.append(json.loads(msg)["type"] if isinstance(msg, str) else "frame")
                if not isinstance(msg, str):
                    await ws.send('{"type": "ack"}')

        reader = asyncio.create_task(read())
        while "frame" not in seen:
            assert not reader.done(), seen
            await asyncio.sleep(0.2)
        for k in range(trials):
            for pressed in (True, False):
                await ws.send(json.dumps({"type": "key", "key": "return", "pressed": pressed}))
            await asyncio.sleep(1.0)  # the trial's aids set, a fresh attempt
            for delay, msg in clicks:
                await asyncio.sleep(delay * 1.5)
                await ws.send(json.dumps(msg))
            deadline = time.monotonic() + 180
            while await asyncio.to_thread(filed) < k + 1:
                assert time.monotonic() < deadline, f"trial {k + 1}'s Save was not filed in 180 s"
                await asyncio.sleep(0.5)
        reader.cancel()
    return seen


@pytest.mark.slow
def test_a_registered_trainee_runs_the_studys_trials_in_the_browser(site):
    if site.db.startswith("postgresql"):
        pytest.skip("the seat runs the same on both databases; the register's checks are tested on both")
    study = f"s{uuid.uuid4().hex[:8]}"
    tina = site.tokens["tina"]
    assert call(site, "POST", f"/api/studies/{study}/design", PROTOCOL, tina)[0] == 201
    entry = {"class_name": "c1", "code": "alice", "group": "expert", "year_of_training": 5, "procedures_performed": 40}
    assert call(site, "POST", f"/api/studies/{study}/participants", entry, tina)[0] == 201
    cookie = cookie_for(site.db, "alice")
    # the page names the study; a study the trainee is not registered in is refused with the reason
    status, page, _ = call(site, "GET", f"/train/prp?study={study}", headers={"Cookie": f"chainsim_session={cookie}"})
    assert status == 200 and f"Study <b>{study}</b>" in page and f"ws?study={study}" in page
    status, page, _ = call(site, "GET", "/train/prp?study=nosuch", headers={"Cookie": f"chainsim_session={cookie}"})
    assert status == 404 and "has no design on this server" in page

    def attempts() -> list[dict]:
        rows = call(site, "GET", "/api/attempts", token=site.tokens["alice"])[1]["attempts"]
        return [a for a in rows if (a["details"].get("protocol") or {}).get("study") == study]

    seen = in_thread(_run(site.url, f"/train/prp/ws?study={study}", cookie, 3, trial_clicks(), lambda: len(attempts())))
    assert "ready" in seen
    mine = attempts()
    mine.sort(key=lambda a: a["details"]["protocol"]["order"])
    protos = [a["details"]["protocol"] for a in mine]
    # slot 0: practice first, then the conditions in the first row of the design, each with its aids
    assert [(p["order"], p["trial"], p["practice"]) for p in protos] == [
        (1, "loc-planes", True),
        (2, "loc-planes", False),
        (3, "loc-none", False),
    ]
    assert [a["aids"]["reference_planes"] for a in mine] == [True, True, False]
    assert all(a["source"] == "witnessed" and p["group"] == "expert" for a, p in zip(mine, protos, strict=True))


def test_the_study_link_opens_the_seat_with_the_study_in_chromium(browser, site):  # noqa: F811
    """The link a trainer hands out, opened in the browser: the page names the study, and its socket carries
    it (the seat starts with the study's first page)."""
    if site.db.startswith("postgresql"):
        pytest.skip("the page and the socket do not touch the database; checked on SQLite")
    study = f"s{uuid.uuid4().hex[:8]}"
    tina = site.tokens["tina"]
    assert call(site, "POST", f"/api/studies/{study}/design", PROTOCOL, tina)[0] == 201
    entry = {"class_name": "c1", "code": "bob", "group": "novice", "year_of_training": 1, "procedures_performed": 0}
    assert call(site, "POST", f"/api/studies/{study}/participants", entry, tina)[0] == 201
    context = browser.new_context(viewport={"width": 1400, "height": 1000}, bypass_csp=True)
    page = context.new_page()
    sockets: list[str] = []
    page.on("websocket", lambda ws: sockets.append(ws.url))
    try:
        sign_in(page, site, "bob")
        page.goto(f"{site.url}/train/prp?study={study}")
        assert f"Study {study}" in page.inner_text("main")
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=120_000)
        assert sockets and sockets[-1].endswith(f"/train/prp/ws?study={study}")
    finally:
        context.close()
