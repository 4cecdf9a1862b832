"""The attempt page's 3-D replay in a real browser (headless Chromium, WebGL in software), on both databases.

A scripted prp attempt with three X-ray images is uploaded and scored by replay; the trainer opens
its page: the 3-D view draws (the canvas has pixels other than its background), moving the scrubber
moves the needle, every X-ray image the trainee took loads, and the meshes come back 304 when the
browser already has them. The page's own pixels are saved for a person to look at (``$CHAINSIM_SHOTS``).
"""

from __future__ import annotations

import io
import os
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import PASSWORD, attempt, save_scored, upload
from test_browser import ARGS as BROWSER_ARGS
from test_browser import chromium

from chainsim.game.records.store import RecordStore

# WebGL without a GPU: SwiftShader through ANGLE
ARGS = [*BROWSER_ARGS, "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
BACKGROUND = (0x1D, 0x23, 0x30)


@pytest.fixture(scope="module")
def browser():
    yield from chromium(ARGS)


def sign_in(page, site, name: str) -> None:
    page.goto(site.url + "/login")
    page.fill("input[name=name]", name)
    page.fill("input[name=password]", PASSWORD)
    page.click("button[type=submit]")
    page.wait_for_load_state()


def shot(page, name: str) -> None:
    folder = os.environ.get("CHAINSIM_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / name), full_page=True)


def wait_until(page, js: str, timeout_s: float = 30.0) -> None:
    """Poll a JavaScript expression from outside the page (the site's CSP forbids the page evaluating strings)."""
    end = time.monotonic() + timeout_s
    while not page.evaluate(js):
        assert time.monotonic() < end, f"never true: {js}"
        time.sleep(0.1)


def drawn_pixels(page) -> int:
    from PIL import Image  # noqa: PLC0415

    png = page.locator("#replay-canvas").screenshot()
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), int)
    return int((np.abs(rgb - np.array(BACKGROUND)).sum(axis=2) > 30).sum())


@pytest.mark.slow
def test_attempt_page_replays_the_attempt_in_3d(browser, site):
    stored = save_scored(site, "alice", upload("correct.toml"))
    assert stored["xray_shots"] == 3
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    try:
        sign_in(page, site, "tina")
        page.goto(f"{site.url}/attempts/{stored['id']}")
        page.wait_for_selector("#replay3d[data-ready='1']", timeout=120_000)
        assert page.locator("#replay-canvas").count() == 1
        assert drawn_pixels(page) > 5000, "the 3-D view drew nothing but its background"

        n = page.evaluate("window.chainsimReplay.frames")
        assert n > 10
        page.locator("#scrubber").fill("0")
        early = page.evaluate("window.chainsimReplay.state.tip")
        page.locator("#scrubber").fill(str(n - 1))
        late = page.evaluate("window.chainsimReplay.state.tip")
        assert late is not None, "at the attempt's end the needle is in the head"
        assert early is None or np.linalg.norm(np.subtract(late, early)) > 5.0, "the scrubber did not move the needle"
        assert page.evaluate("window.chainsimReplay.state.index") == n - 1
        # Play from the start runs the needle forward over the attempt's time (3.6 s); Pause holds it
        page.locator("#scrubber").fill("0")
        page.click("#play")
        wait_until(page, "window.chainsimReplay.state.index > 5")
        for _ in range(3):  # Pause; on a slow machine the replay may reach its end first, and a click replays it
            if page.locator("#play").inner_text() == "Play":
                break
            page.click("#play")
        assert page.locator("#play").inner_text() == "Play"
        held = page.evaluate("window.chainsimReplay.state.index")
        page.wait_for_timeout(500)
        assert page.evaluate("window.chainsimReplay.state.index") == held
        page.locator("#scrubber").fill(str(n - 1))

        imgs = page.locator("#xrays img")
        assert imgs.count() == stored["xray_shots"]
        wait_until(page, "[...document.querySelectorAll('#xrays img')].every(i => i.complete)")
        sizes = page.evaluate("[...document.querySelectorAll('#xrays img')].map(i => i.naturalWidth)")
        assert all(w >= 256 for w in sizes), sizes
        assert page.evaluate("document.scrollingElement.scrollWidth <= innerWidth")
        shot(page, f"attempt3d-{'postgresql' if site.db.startswith('postgres') else 'sqlite'}-1280.png")

        mesh = page.request.get(f"{site.url}/packs/prp/display.glb")
        assert mesh.status == 200 and mesh.body()[:4] == b"glTF"
        assert "max-age" in mesh.headers["cache-control"]
        again = page.request.get(f"{site.url}/packs/prp/display.glb", headers={"If-None-Match": mesh.headers["etag"]})
        assert again.status == 304

        page.set_viewport_size({"width": 390, "height": 844})
        page.wait_for_timeout(300)
        assert page.evaluate("document.scrollingElement.scrollWidth <= innerWidth")
        shot(page, f"attempt3d-{'postgresql' if site.db.startswith('postgres') else 'sqlite'}-390.png")
    finally:
        page.close()


@pytest.mark.slow
def test_an_attempt_without_recording_says_why_it_has_no_3d_view(browser, site):
    with RecordStore(site.db) as store:
        aid = store.save_attempt("c1", "bob", attempt(2))  # as a local simulator's import would have it
    page = browser.new_page()
    try:
        sign_in(page, site, "tina")
        page.goto(f"{site.url}/attempts/{aid}")
        wait_until(page, "document.getElementById('replay-status').textContent.startsWith('No 3-D replay')")
        assert "has no recording" in page.locator("#replay-status").inner_text()
        assert page.locator("#replay-canvas").count() == 0
        assert page.locator("#metrics").is_visible()  # the page in words is all there
    finally:
        page.close()


@pytest.mark.slow
def test_another_class_gets_no_replay(browser, site):
    stored = save_scored(site, "alice", upload("skull-hit.toml"))
    page = browser.new_page()
    try:
        sign_in(page, site, "tom")  # teaches c2, not alice's c1
        for path in (f"/attempts/{stored['id']}/replay.json", f"/attempts/{stored['id']}/xray/1.png"):
            assert page.request.get(site.url + path).status == 403
    finally:
        page.close()
