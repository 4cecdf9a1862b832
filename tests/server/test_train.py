"""The trainer in a browser tab (/train/PACK, chainsim.game.server.train_routes and train_session).

As a trainee uses it: headless Chromium signs in, follows the link on their page, sees the trainer
drawn by the server, and drives it with the mouse and keys; the slow test makes the prp pack's whole
correct attempt with the clicks and drags of assets/prp/scripts/correct-mouse.toml and finds it in the
records under the trainee, witnessed (the server ran the session). The socket's rules are tested with a plain
WebSocket client carrying a signed-in trainee's cookie: who may open a session, messages refused with
a reason, the rate limit, the seats, the end of a session whose page went away or that reached its
longest length, and the back-off that holds an account back after refused input.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import re
import time

import pytest
from conftest import PASSWORD, call, populate, start_server
from test_browser import browser, sign_in  # noqa: F401 - the module's Chromium fixture
from test_tls import certificates  # noqa: F401 - the programme's authority and the server's certificate

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore
from chainsim.game.server.train_routes import RECHECK_S, BadMessage, Bucket, check_message

SIZE = (1280, 800)


# -- input messages (no server) -----------------------------------------------------------------


def test_device_events_pass_as_the_sessions_input_events():
    msg = check_message(
        '{"type": "mouse_button", "x": 10, "y": 20.5, "button": "left", "pressed": true, "seq": 3}', SIZE
    )
    assert msg == {
        "t": "in",
        "ev": {"kind": "mouse_button", "x": 10.0, "y": 20.5, "button": "left", "pressed": True},
        "seq": 3,
    }
    assert check_message('{"type": "key", "key": "f1", "pressed": false}', SIZE)["ev"]["key"] == "f1"
    assert check_message('{"type": "ack"}', SIZE) is None


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (b"\x00\x01", "JSON text, not binary"),
        ("not json", "not JSON"),
        ("[1, 2]", "JSON object"),
        ('{"type": "widget", "name": "save"}', "unknown input type 'widget'"),
        ('{"type": "pick", "entity": "skin", "point": [0, 0, 0]}', "unknown input type 'pick'"),
        ('{"type": "mouse_move", "x": 1}', "missing y"),
        ('{"type": "mouse_move", "x": 1, "y": 2, "z": 3}', "unknown field(s) z"),
        ('{"type": "mouse_move", "x": 1e9, "y": 2}', "'x' must be a number from 0 to 1280"),
        ('{"type": "mouse_move", "x": NaN, "y": 2}', "not JSON"),
        ('{"type": "mouse_move", "x": "1", "y": 2}', "'x' must be a number"),
        ('{"type": "scroll", "x": 1, "y": 2, "dy": 500}', "'dy' must be a number from -50 to 50"),
        ('{"type": "key", "key": "rm -rf", "pressed": true}', "unknown key name"),
        ('{"type": "key", "key": "a", "pressed": 1}', "'pressed' must be true or false"),
        ('{"type": "mouse_button", "x": 1, "y": 2, "button": "fourth", "pressed": true}', "'button' must be"),
        ('{"type": "key", "key": "a", "pressed": true, "seq": -1}', "'seq' must be a whole number"),
        ('{"type": "ack", "extra": 1}', "an ack has no other fields"),
        ('{"type": "mouse_move", "x": 1, "y": 2, "pad": "' + "x" * 600 + '"}', "over 512 bytes"),
    ],
)
def test_bad_messages_are_refused_naming_what_is_wrong(text, says):
    with pytest.raises(BadMessage, match=None) as info:
        check_message(text, SIZE)
    assert says in str(info.value)


def test_the_rate_limit_allows_a_burst_then_the_rate():
    now = [0.0]
    bucket = Bucket(rate=100.0, burst=10.0, clock=lambda: now[0])
    assert all(bucket.take() for _ in range(10))
    assert not bucket.take()
    now[0] += 0.05  # 5 more at 100 a second
    assert sum(bucket.take() for _ in range(10)) == 5


# -- the socket's rules, with a plain client ------------------------------------------------------


def cookie_for(db: str, name: str) -> str:
    with RecordStore(db) as store:
        user = accounts.check_login(store, name, PASSWORD)
        sid, _ = accounts.start_session(store, user)
    return sid


async def _talk(url: str, path: str, cookie: str | None, origin: str | None, send=(), ssl=None):
    """Open the socket, send ``send`` once the first picture came; (close code, reason, messages seen)."""
    import websockets

    headers = {"Cookie": f"chainsim_session={cookie}"} if cookie else {}
    seen = []
    async with websockets.connect(
        url.replace("http", "ws", 1) + path, additional_headers=headers, origin=origin, max_size=None, ssl=ssl
    ) as ws:
        try:
            while True:
                msg = await asyncio.wait_for(ws.recv(), 120)
                seen.append(json.loads(msg)["type"] if isinstance(msg, str) else "frame")
                if seen.count("frame") == 1 and not isinstance(msg, str):
                    for text in send:
                        await ws.send(text)
        except websockets.ConnectionClosed as exc:
            return exc.rcvd.code if exc.rcvd else None, exc.rcvd.reason if exc.rcvd else "", seen


def talk(server, name, path="/train/prp/ws", send=(), origin="self", ssl=None):
    cookie = None if name is None else cookie_for(server.db, name)
    origin = server.url if origin == "self" else origin
    return in_thread(_talk(server.url, path, cookie, origin, send, ssl))


def in_thread(coro):
    """Run ``coro`` on an event loop of its own thread: Playwright's sync API holds this thread's loop."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coro).result()


def one_backend(site) -> None:
    """The input rules live in the server process, not the database: checked once, on SQLite."""
    if site.db.startswith("postgresql"):
        pytest.skip("the input rules do not touch the database; checked on SQLite")


def test_only_a_signed_in_trainee_opens_a_session_and_from_this_site_only(site):
    assert talk(site, None)[:2] == (4401, "not signed in; sign in and open the page again")
    code, reason, _ = talk(site, "tina")
    assert code == 4403 and "trainee accounts" in reason
    code, reason, _ = talk(site, "alice", origin="http://evil.example")
    assert (code, reason) == (4403, "opened from another site; refused")
    code, reason, _ = talk(site, "alice", path="/train/nosuchpack/ws")
    assert code == 4404 and "no pack named 'nosuchpack'" in reason
    # the page itself: a trainer is refused, a visitor is sent to sign in
    assert (
        call(site, "GET", "/train/prp", headers={"Cookie": f"chainsim_session={cookie_for(site.db, 'tom')}"})[0] == 403
    )


def test_a_bad_message_closes_the_session_with_its_reason(site):
    one_backend(site)
    code, reason, seen = talk(site, "carol", send=['{"type": "key", "key": "f1", "pressed": "yes"}'])
    assert (code, reason) == (4400, "key: 'pressed' must be true or false")
    assert seen[:3] == ["starting", "ready", "frame"]  # it had started and drawn


def test_a_flood_of_input_is_cut_off(site):
    one_backend(site)
    flood = ['{"type": "mouse_move", "x": 5, "y": 5}'] * 2000
    code, reason, _ = talk(site, "bob", send=flood)
    assert code == 4429 and "too many input messages" in reason
    # the account is held back a while (how long: test_refused_input_holds_the_account_back_...): waited
    # out here, so that bob's later sessions on this site start
    time.sleep(held_back(site, cookie_for(site.db, "bob")) + 0.5)


@pytest.mark.slow
def test_all_seats_taken_then_freed_when_the_page_has_gone(tmp_path, monkeypatch, browser):  # noqa: F811
    db = str(tmp_path / "seats.sqlite3")
    populate(db)
    monkeypatch.setenv("CHAINSIM_TRAIN_SEATS", "1")
    monkeypatch.setenv("CHAINSIM_TRAIN_GRACE_S", "1")
    server = start_server(db, tmp_path / "serve.log")
    try:
        context = browser.new_context(bypass_csp=True)
        page = context.new_page()
        sign_in(page, server, "alice")
        page.goto(server.url + "/train/prp")
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=120_000)
        # bob finds the one seat taken: a clear page, and the socket says so too
        bob = {"Cookie": f"chainsim_session={cookie_for(db, 'bob')}"}
        status, text, headers = call(server, "GET", "/train/prp", headers=bob)
        assert status == 503 and "All seats are taken" in text and headers["Retry-After"]
        assert talk(server, "bob")[:2] == (4503, "all 1 seats are taken; try again in a few minutes")
        # alice's second tab takes her session over (the picture as it stands); the first tab is told
        second = context.new_page()
        second.goto(server.url + "/train/prp")
        second.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=60_000)
        page.wait_for_function("window.trainStats.closed !== null", timeout=10_000)
        assert page.evaluate("() => window.trainStats.closed.code") == 4409
        context.close()  # alice's tab goes; her process is killed once the grace time has passed
        deadline = time.monotonic() + 30
        while call(server, "GET", "/train/prp", headers=bob)[0] != 200:
            assert time.monotonic() < deadline, "the seat was not freed"
            time.sleep(0.5)
        # bob trains, then signs out in another tab: his session ends at the next check of his sign-in
        context = browser.new_context(bypass_csp=True)
        page = context.new_page()
        sign_in(page, server, "bob")
        page.goto(server.url + "/train/prp")
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=120_000)
        other = context.new_page()
        other.goto(server.url + "/")
        other.click("header button[type=submit]")  # Sign out
        page.wait_for_function("window.trainStats.closed !== null", timeout=RECHECK_S * 1000 + 15_000)
        assert page.evaluate("() => [window.trainStats.closed.code, window.trainStats.closed.reason]") == [
            4401,
            "signed out; sign in and open the page again",
        ]
        context.close()
        # the log line follows the socket's close by a moment (the process is killed and reaped first)
        assert logged(server, "alice's session ended (page gone for 1 s)")
        assert logged(server, "bob's session ended (signed out)", within=30.0)
    finally:
        server.stop()


@pytest.mark.slow
def test_the_stream_runs_on_the_servers_tls(tmp_path, certificates):  # noqa: F811
    """Behind --certfile the socket is wss:// on the same listener and certificate; plain ws:// gets nothing."""
    import ssl

    db = str(tmp_path / "tls.sqlite3")
    populate(db)
    server = start_server(
        db, tmp_path / "serve.log", args=("--certfile", str(certificates / "server.pem"),
                                          "--keyfile", str(certificates / "server.key"))
    )  # fmt: skip
    try:
        trust = ssl.create_default_context(cafile=str(certificates / "ca.pem"))
        code, reason, seen = talk(server, "alice", send=['{"type": "key", "key": "nokey", "pressed": true}'], ssl=trust)
        assert seen[:3] == ["starting", "ready", "frame"]
        assert (code, reason) == (4400, "key: unknown key name 'nokey'")
        with pytest.raises(Exception):  # noqa: B017 - the TLS listener does not speak plain HTTP upgrades
            in_thread(_talk(server.url.replace("https", "http", 1), "/train/prp/ws", None, server.url))
    finally:
        server.stop()


# -- a session's longest length, and the back-off after refused input ----------------------------


@pytest.fixture(scope="module")
def short(tmp_path_factory, pack_copy):
    """A server of its own whose sessions last at most 4 s and whose first back-off is 2 s."""
    folder = tmp_path_factory.mktemp("short")
    db = str(folder / "short.sqlite3")
    populate(db)
    with pytest.MonkeyPatch.context() as env:
        env.setenv("CHAINSIM_TRAIN_MAX_S", "4")
        env.setenv("CHAINSIM_TRAIN_BACKOFF_S", "2")
        server = start_server(db, folder / "serve.log")
    yield server
    server.stop()


async def _drive(url: str, cookie: str, within: float = 30.0):
    """A page that acks every picture and moves the mouse four times a second until the server closes
    the socket; (close code, reason, seconds from ready to the close), code None if it never did."""
    import websockets

    async with websockets.connect(
        url.replace("http", "ws", 1) + "/train/prp/ws",
        additional_headers={"Cookie": f"chainsim_session={cookie}"},
        origin=url,
        max_size=None,
    ) as ws:
        ready = None
        deadline = time.monotonic() + within + 120  # the start, then the session
        try:
            while time.monotonic() < deadline and (ready is None or time.monotonic() - ready < within):
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.25)
                except TimeoutError:
                    msg = None
                if isinstance(msg, str) and json.loads(msg)["type"] == "ready":
                    ready = time.monotonic()
                elif isinstance(msg, bytes):
                    await ws.send('{"type": "ack"}')
                if ready is not None:
                    await ws.send('{"type": "mouse_move", "x": 640, "y": 400}')
        except websockets.ConnectionClosed as exc:
            after = None if ready is None else time.monotonic() - ready
            return exc.rcvd.code if exc.rcvd else None, exc.rcvd.reason if exc.rcvd else "", after
    return None, "", None


def test_a_session_ends_at_its_longest_even_while_input_comes(short):
    code, reason, after = in_thread(_drive(short.url, cookie_for(short.db, "alice")))
    assert (code, reason) == (4410, "ended after 4 s, the longest a session runs here; reload to start a new one")
    assert 3.0 < after < 30.0
    assert logged(short, "alice's session ended (longest session, 4 s, reached)")


def logged(server, line: str, within: float = 10.0) -> bool:
    """Whether the server's log says ``line`` (the log follows the socket's close by a moment)."""
    deadline = time.monotonic() + within
    while line not in server.log.read_text():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


BAD = ['{"type": "key", "key": "f1", "pressed": "yes"}']


def held_back(server, cookie: str) -> float:
    """The wait a refused session start names; the start must be refused before anything started."""
    code, reason, seen = in_thread(_talk(server.url, "/train/prp/ws", cookie, server.url))
    assert (code, seen) == (4429, []), (code, reason, seen)
    said = re.fullmatch(r"the last session sent input the server refuses; start again in (\d+) s", reason)
    assert said, reason
    return float(said.group(1))


@pytest.mark.slow
def test_refused_input_holds_the_account_back_without_starting_a_process(short):
    cookie = cookie_for(short.db, "bob")

    def starts() -> int:
        return short.log.read_text().count("train: bob started prp")

    bad = in_thread(_talk(short.url, "/train/prp/ws", cookie, short.url, BAD))
    assert bad[:2] == (4400, "key: 'pressed' must be true or false")
    assert held_back(short, cookie) <= 2.0
    assert starts() == 1  # the refused start made no process
    time.sleep(2.1)
    assert in_thread(_talk(short.url, "/train/prp/ws", cookie, short.url, BAD))[0] == 4400
    assert 2.0 < held_back(short, cookie) <= 4.0  # doubled
    assert starts() == 2
    time.sleep(4.1)
    # a session that ends without breaking a rule (here: its longest length) forgets the back-off
    assert in_thread(_drive(short.url, cookie))[0] == 4410
    assert in_thread(_talk(short.url, "/train/prp/ws", cookie, short.url, BAD))[0] == 4400
    assert held_back(short, cookie) <= 2.0
    assert starts() == 4
    assert logged(short, "bob's session ended (bad input message: key: 'pressed' must be true or false; no new session")


# -- in Chromium, as a trainee does ---------------------------------------------------------------


def open_trainer(browser, site, who):  # noqa: F811
    context = browser.new_context(viewport={"width": 1400, "height": 1000}, bypass_csp=True)
    page = context.new_page()
    sign_in(page, site, who)
    page.click("a#train")
    assert page.url.endswith("/train/prp")
    try:
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=120_000)
    except Exception as exc:  # say what the page and the server said, not only that time ran out
        state = page.evaluate("() => (document.getElementById('train-state') || {}).textContent")
        tail = "\n".join(site.log.read_text(errors="replace").splitlines()[-40:])
        raise AssertionError(f"no picture in 120 s; the page says {state!r}; the server's log ends:\n{tail}") from exc
    return context, page


def picture(page) -> list[int]:
    """A coarse sample of the canvas's pixels (what the trainee sees)."""
    return page.evaluate(
        """() => { const c = document.getElementById('train-screen');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; const out = [];
        for (let i = 0; i < d.length; i += 4 * 997) out.push(d[i], d[i + 1], d[i + 2]); return out; }"""
    )


def test_a_trainee_sees_the_trainer_and_drives_it_with_keys(browser, site):  # noqa: F811
    context, page = open_trainer(browser, site, "alice")
    try:
        first = picture(page)
        assert len(set(first)) > 20  # drawn: views, panel and text, not a blank canvas
        box = page.locator("#train-screen").bounding_box()
        assert (round(box["width"]), round(box["height"])) == (1280, 800)  # pixel for pixel
        shown = page.evaluate("() => window.trainStats.frames")
        page.locator("#train-screen").press("Escape")  # closes the help page over the surgeon's view
        page.wait_for_function(f"window.trainStats.frames > {shown}", timeout=30_000)
        time.sleep(0.5)
        assert picture(page) != first
        assert page.evaluate("() => window.trainStats.latencies.length") >= 1
    finally:
        context.close()


#: the dials' keys (the prp controller's help): the normal step is 1 degree, with Shift a quarter
DIAL_KEYS = {"rotate_horizontal": ("ArrowRight", "ArrowLeft"), "rotate_vertical": ("ArrowUp", "ArrowDown")}


def dial_presses(name: str, value: float) -> list[str]:
    """Key presses turning dial ``name`` from 0 to ``value`` (within an eighth of a degree)."""
    up, down = DIAL_KEYS[name]
    key = up if value > 0 else down
    whole = int(abs(value))
    quarters = round((abs(value) - whole) / 0.25)
    return [key] * whole + [f"Shift+{key}"] * quarters


@pytest.mark.slow
def test_a_whole_correct_attempt_in_the_browser_is_saved_under_the_trainee(browser, site):  # noqa: F811
    """The prp correct attempt as a trainee makes it in the page: the help page closed, the landmarks
    clicked on the face, the dials turned with the arrow keys to the correct script's angles, the
    X-ray and insertion controls clicked, Self assessment and Save clicked (the clicks of
    correct-mouse.toml, whose dial drags carry fractions of a pixel no pointer makes)."""
    from conftest import SCRIPTS

    from chainsim.components.input_events import Widget
    from chainsim.game.trainer.inputscript import load_script

    dials = [
        (ev.name, ev.value) for _, ev in load_script(SCRIPTS / "correct.toml") if getattr(ev, "name", "") in DIAL_KEYS
    ]
    events = load_script(SCRIPTS / "correct-mouse.toml")
    assert not any(isinstance(ev, Widget) for _, ev in events)
    before = {a["id"] for a in call(site, "GET", "/api/attempts", token=site.tokens["bob"])[1]["attempts"]}
    context, page = open_trainer(browser, site, "bob")
    try:
        box = page.locator("#train-screen").bounding_box()
        W, H = 1280, 800
        assert (round(box["width"]), round(box["height"])) == (W, H)
        mouse, keyboard = page.mouse, page.keyboard
        last_t, i = 0.0, 0
        while i < len(events):
            t, ev = events[i]
            time.sleep(max(0.0, t - last_t) * 1.5)  # the script's pace, with room for a slow machine
            last_t = t
            x, y = box["x"] + ev.x, box["y"] + (H - ev.y)
            if ev.kind == "mouse_button" and ev.pressed and events[i + 1][1].kind == "mouse_drag":
                name, value = dials.pop(0)  # a dial's drag: turned by its keys instead
                for key in dial_presses(name, value):
                    keyboard.press(key)
                    time.sleep(0.05)
                i += 3  # the press, the drag, the release
                continue
            if ev.kind == "mouse_move":
                mouse.move(x, y)
            elif ev.kind == "mouse_button":
                (mouse.down if ev.pressed else mouse.up)(button=ev.button)
            else:
                raise AssertionError(f"unexpected event {ev}")
            i += 1
        assert dials == []
        deadline = time.monotonic() + 240
        while True:  # the script ends with Self assessment and Save: the server stores it, witnessed
            rows = call(site, "GET", "/api/attempts", token=site.tokens["bob"])[1]["attempts"]
            new = [a for a in rows if a["id"] not in before]
            if new:
                break
            assert time.monotonic() < deadline, "no attempt stored"
            time.sleep(1.0)
    finally:
        context.close()
    (attempt,) = new
    assert (attempt["class_name"], attempt["trainee"], attempt["pack"]) == ("c1", "bob", "prp")
    assert attempt["target"].startswith("foramen_ovale")
    status, full, _ = call(site, "GET", f"/api/attempts/{attempt['id']}", token=site.tokens["bob"])
    assert status == 200 and full["differences"] == []
    # the server ran this session: the attempt is witnessed, and its pace is not judged
    assert full["source"] == "witnessed" and full["flags"] == []


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("--sessions", "0"), "--sessions must be from 1 to 32, got 0"),
        (("--seconds", "1"), "--seconds must be from 2 to 600, got 1"),
        (("--quality", "101"), "--quality must be from 1 to 100, got 101"),
        (("--rtt-ms", "-5"), "--rtt-ms must be from 0 to 2000, got -5"),
        (("--json", "/no/such/folder/figures.json"), "--json /no/such/folder/figures.json: folder /no/such/folder"),
    ],
)
def test_bench_train_refuses_bad_sizes_in_one_line(cli, args, says):
    code, out, err = cli("bench", "train", *args)
    assert code == 2
    assert says in err and "Traceback" not in err


async def _ready(url: str, path: str, cookie: str) -> dict:
    """Open the socket, take its first picture and close the page: the session's ``ready`` message."""
    import websockets

    async with websockets.connect(
        url.replace("http", "ws", 1) + path, additional_headers={"Cookie": f"chainsim_session={cookie}"},
        origin=url, max_size=None,
    ) as ws:  # fmt: skip
        ready = None
        while True:
            msg = await asyncio.wait_for(ws.recv(), 120)
            if isinstance(msg, str) and json.loads(msg)["type"] == "ready":
                ready = json.loads(msg)
            elif isinstance(msg, bytes) and ready is not None:
                return ready


@pytest.fixture(scope="module")
def own(tmp_path_factory, pack_copy):
    """A server of its own, its seats free of the sessions other tests leave within their grace time."""
    folder = tmp_path_factory.mktemp("own")
    db = str(folder / "own.sqlite3")
    populate(db)
    server = start_server(db, folder / "serve.log")
    yield server
    server.stop()


def test_a_reload_says_it_resumed_the_session_and_a_fresh_start_ends_it(own):
    cookie = cookie_for(own.db, "carol")
    first = in_thread(_ready(own.url, "/train/prp/ws", cookie))
    assert "resumed" not in first
    again = in_thread(_ready(own.url, "/train/prp/ws", cookie))  # the page reloaded within the grace time
    assert again["resumed"] is True and again["age_s"] >= 0
    fresh = in_thread(_ready(own.url, "/train/prp/ws?fresh=1", cookie))  # "Start a new session"
    assert "resumed" not in fresh
    assert logged(own, "carol's session ended (the trainee started afresh)")


@pytest.mark.slow
def test_a_reload_in_the_browser_says_it_resumed_and_offers_a_new_session(browser, own):  # noqa: F811
    context, page = open_trainer(browser, own, "bob")
    try:
        assert page.locator("#train-state").inner_text().startswith("Trainer ready")
        assert page.locator("#train-fresh").is_hidden()
        page.reload()
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=120_000)
        said = page.locator("#train-state").inner_text()
        assert said.startswith("Resumed your session from ") and "goes on where you left it" in said
        page.click("#train-fresh")  # a new session: the old one ends, its attempt in progress unsaved
        page.wait_for_function(
            "document.getElementById('train-state').textContent.startsWith('Trainer ready')", timeout=120_000
        )
        assert page.locator("#train-fresh").is_hidden()
        assert logged(own, "bob's session ended (the trainee started afresh)")
    finally:
        context.close()
