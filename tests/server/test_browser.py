"""The dashboard in a real browser: the distribution's Chromium, headless, driven by Playwright.

A trainer signs in, opens a class, a trainee's progress plots (the images load and are drawn by
the server), and downloads the CSV export; a trainee signs in and gets 403 on another trainee's
attempt. Playwright only drives /usr/bin/chromium; it never downloads a browser. Without Chromium
the test is skipped on a developer's machine and fails in CI, where .ci/run installs it.
"""

from __future__ import annotations

import csv
import io
import os
import re
import shutil

import pytest
from conftest import PASSWORD, save_scored, send, upload, wait_scored
from records_db import missing

from chainsim.tools.bench.train import CHROMIUM, CHROMIUM_ARGS

# the flags the bench starts Chromium with (a closed network: no background connections)
ARGS = ["--headless", *CHROMIUM_ARGS]


def chromium(args=ARGS):
    """The distribution's Chromium started headless through Playwright (a generator for fixtures)."""
    if not (os.path.exists(CHROMIUM) and shutil.which(CHROMIUM)):
        missing("Chromium (/usr/bin/chromium)", "apt-get install -y chromium chromium-driver")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        missing("playwright (Python package)", "pip install -e '.[test]'")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=args, headless=True)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def sign_in(page, site, name: str) -> None:
    page.goto(site.url + "/")
    assert page.url.endswith("/login")
    page.fill("input[name=name]", name)
    page.fill("input[name=password]", PASSWORD)
    page.click("button[type=submit]")


@pytest.mark.slow
def test_trainer_signs_in_opens_progress_plot_and_exports_csv(browser, site, tmp_path):
    sent = [send(site, "alice", upload(("correct.toml", "skull-hit.toml")[i % 2])) for i in range(4)]
    sent.append(send(site, "bob", upload("skull-hit.toml")))
    assert [status for status, _, _ in sent] == [202] * 5
    for (_, ack, _), who in zip(sent, ["alice"] * 4 + ["bob"], strict=True):
        assert wait_scored(site, ack["upload"], site.tokens[who])["status"] == "scored"
    context = browser.new_context(accept_downloads=True)
    page = context.new_page()
    try:
        sign_in(page, site, "tina")
        assert page.locator("text=Your classes").is_visible()
        page.click("a:text-is('c1')")
        page.click("a:text-is('alice')")
        assert page.locator("h1").inner_text().startswith("alice")
        imgs = page.locator("img")
        assert imgs.count() >= 4
        # every plot image arrived and decoded: drawn by the server, not left broken
        page.wait_for_load_state("networkidle")
        widths = page.eval_on_selector_all("img", "els => els.map(e => e.complete ? e.naturalWidth : 0)")
        assert all(w > 0 for w in widths), widths
        src = imgs.first.get_attribute("src")
        response = page.goto(site.url + src)
        assert response.status == 200 and response.headers["content-type"].startswith("image/svg+xml")
        assert b"class median" in response.body()
        page.go_back()
        with page.expect_download() as info:
            page.click("#export-csv")
        target = tmp_path / "alice.csv"
        info.value.save_as(target)
        rows = list(csv.DictReader(io.StringIO(target.read_text())))
        assert len(rows) >= 4 and {r["trainee"] for r in rows} == {"alice"}
        assert {r["class_name"] for r in rows} == {"c1"}
    finally:
        context.close()


def test_trainee_gets_403_on_another_trainees_attempt(browser, site):
    bobs = save_scored(site, "bob", upload())["id"]
    context = browser.new_context()
    page = context.new_page()
    try:
        sign_in(page, site, "alice")
        assert re.search(r"/trainees/\d+$", page.url)
        response = page.goto(f"{site.url}/attempts/{bobs}")
        assert response.status == 403
        assert "not yours" in page.content()
    finally:
        context.close()


@pytest.mark.slow
def test_class_and_progress_plots_stay_readable_on_a_phone(browser, site):
    """At 390 px wide (a phone held upright) the class page's and a trainee's plots stack one under another
    and are drawn at three quarters of their size or more: their 10-11 pt text stays about 10 px high."""
    save_scored(site, "alice", upload("correct.toml"))
    page = browser.new_page(viewport={"width": 390, "height": 844})
    try:
        sign_in(page, site, "tina")
        page.click("a:text-is('c1')")
        for where in ("class", "trainee"):
            page.wait_for_load_state("networkidle")
            sizes = page.eval_on_selector_all(
                "img",
                "els => els.map(e => [e.naturalWidth, e.getBoundingClientRect().width, e.offsetLeft])",
            )
            plots = [s for s in sizes if s[0] > 300]
            assert plots, f"no plot drawn on the {where} page"
            assert all(shown >= 0.75 * natural for natural, shown, _ in plots), (where, plots)
            assert len({round(left) for _, _, left in plots}) == 1  # one column: stacked, not side by side
            if where == "class":
                page.click("a:text-is('alice')")
    finally:
        page.close()
