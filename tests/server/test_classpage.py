"""The class page and a trainer's management of a class, in headless Chromium, on both databases.

A class of 30 trainees with prp attempts (some passing, some not) and a few mental-block attempts:
the class page shows one procedure at a time (a mental-block attempt never in the prp table or its
plots), who is below the benchmark, sorts and pages its table, draws one plot per metric with the
benchmark line and the class median, and fits 1280 px and 390 px windows without sideways scrolling.
The trainer adds a trainee account and resets its password in the browser; the trainee signs in
with it and sees their own page the same way; a forged form (no CSRF token) is refused.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from conftest import PASSWORD, attempt
from test_attempt3d import browser, sign_in, wait_until  # noqa: F401 - the fixture, shared

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore

CLASS = "big"
TRAINER = "tess"


def shot(page, name: str) -> None:
    folder = os.environ.get("CHAINSIM_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / name), full_page=True)


#: a prp attempt's metrics that meet every benchmark of the pack (near its correct scripted attempt's)
GOOD = {
    "landmark_error_mm": 0.5,
    "needle_error_mm": -1.0,
    "skull_contacts": 0.0,
    "path_length_mm": 70.0,
    "duration_s": 60.0,
    "rotation_refused": 0.0,
    "redirections": 0.0,
    "first_contact_dist_mm": 1.5,
    "xray_shots": 3.0,
    "exposure_s": 0.9,
    "dose_mgy": 0.18,
}


def good(i: int) -> dict:
    top = {k: GOOD[k] for k in ("landmark_error_mm", "needle_error_mm", "path_length_mm", "duration_s")}
    return attempt(
        i % 10,
        created_at=f"2026-07-01T{10 + i // 60:02d}:{i % 60:02d}:00Z",
        target="foramen_ovale_left",
        metrics=dict(GOOD),
        skull_contacts=0,
        **top,
    )


def bad(i: int, **over) -> dict:
    """The same with two bone contacts too many: below the benchmark, not critical."""
    m = dict(GOOD, skull_contacts=2.0, duration_s=100.0 + i)
    return attempt(
        i % 10,
        created_at=f"2026-07-01T{10 + i // 60:02d}:{i % 60:02d}:00Z",
        metrics=m,
        skull_contacts=2,
        duration_s=100.0 + i,
        needle_error_mm=-1.0,
        landmark_error_mm=0.5,
        **over,
    )


@pytest.fixture(scope="module")
def big_class(site):
    """30 trainees in class CLASS taught by TRAINER; t00..t29; even ones pass their latest prp attempt."""
    with RecordStore(site.db) as store:
        if not store.query("SELECT 1 FROM users WHERE name = ?", (TRAINER,)):
            accounts.add_user(store, TRAINER, "trainer", PASSWORD, [CLASS])
            for k in range(30):
                name = f"t{k:02d}"
                store.save_attempt(CLASS, name, bad(2 * k))  # a failing first attempt
                store.save_attempt(CLASS, name, good(2 * k + 1) if k % 2 == 0 else bad(2 * k + 1))
            store.save_attempt(CLASS, "t01", bad(70, pack="mental-block"))
    return site


def class_url(page, site) -> str:
    page.goto(site.url + "/")
    return page.locator(f"a:text-is('{CLASS}')").get_attribute("href")


@pytest.mark.slow
def test_class_page_one_procedure_sorted_paged_and_fits(browser, big_class):  # noqa: F811
    site = big_class
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    try:
        sign_in(page, site, TRAINER)
        url = site.url + class_url(page, site)
        page.goto(url + "?pack=prp")
        tabs = page.locator("nav.tabs a").all_inner_texts()
        assert tabs == ["mental-block", "prp"]
        below = page.locator("#below").inner_text()
        odd = [f"t{k:02d}" for k in range(1, 30, 2)]
        assert all(n in below for n in odd) and "t00" not in below
        rows = page.locator("#class-table tbody tr")
        assert rows.count() == 25
        # t01's mental-block attempt is not one of its prp attempts
        assert rows.filter(has_text="t01").locator("td").nth(1).inner_text() == "2"  # the first page of 30
        assert page.locator("nav.pager a").count() == 2
        # sorting by success rate, best first, puts a passing trainee first
        page.click("#class-table thead a:text-is('success')")
        page.click("#class-table thead a:text-is('success')")
        assert "dir=desc" in page.url
        first = page.locator("#class-table tbody tr").first.inner_text()
        assert "50 %" in first, first
        # the plots: one per metric of prp, each with the benchmark and the class median, no mental-block point
        imgs = page.locator(".plots img")
        assert imgs.count() >= 4
        wait_until(page, "[...document.querySelectorAll('.plots img')].every(i => i.complete && i.naturalWidth > 0)")
        svg = page.request.get(site.url + imgs.first.get_attribute("src")).text()
        assert "class median" in svg and "benchmark" in svg
        assert page.evaluate("document.scrollingElement.scrollWidth <= innerWidth")
        shot(page, "class-1280.png")
        page.set_viewport_size({"width": 390, "height": 844})
        page.goto(url + "?pack=prp")
        assert page.evaluate("document.scrollingElement.scrollWidth <= innerWidth")
        shot(page, "class-390.png")
        # mental-block on its own
        page.goto(url + "?pack=mental-block")
        assert page.locator("#class-table tbody tr").count() == 25
        assert "t01" in page.locator("#class-table").inner_text()
    finally:
        page.close()


@pytest.mark.slow
def test_trainer_adds_a_trainee_and_resets_a_password(browser, big_class):  # noqa: F811
    site = big_class
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    try:
        sign_in(page, site, TRAINER)
        url = site.url + class_url(page, site)
        page.goto(url)
        page.fill("#add-trainee input[name=name]", "newbie")
        page.fill("#add-trainee input[name=password]", "first password 1")
        page.click("#add-trainee button")
        assert "added" in page.locator("p.done").inner_text()
        # the same name again is one line, not a traceback
        page.fill("#add-trainee input[name=name]", "newbie")
        page.fill("#add-trainee input[name=password]", "first password 1")
        page.click("#add-trainee button")
        assert "already exists" in page.locator("p.error").inner_text()
        page.goto(url)
        page.select_option("#reset-password select", "newbie")
        page.fill("#reset-password input[name=password]", "second password 2")
        page.click("#reset-password button")
        assert "New password" in page.locator("p.done").inner_text()
        # a form without the CSRF token is refused
        forged = page.request.post(url + "/trainees", form={"name": "intruder", "password": "whatever 123"})
        assert forged.status == 403
        with RecordStore(site.db) as store:
            assert not store.query("SELECT 1 FROM users WHERE name = 'intruder'")
        # the trainee signs in with the new password and sees their own page
        trainee = browser.new_page(viewport={"width": 390, "height": 844})
        try:
            trainee.goto(site.url + "/login")
            trainee.fill("input[name=name]", "newbie")
            trainee.fill("input[name=password]", "second password 2")
            trainee.click("button[type=submit]")
            trainee.wait_for_load_state()
            assert re.search(r"/trainees/\d+$", trainee.url)
            assert "No attempts saved yet" in trainee.content()
            assert trainee.goto(url).status == 403  # the class page is the trainer's
        finally:
            trainee.close()
        # a trainee's page per procedure, as the trainer sees it
        page.goto(url + "?pack=prp")
        page.click("#class-table a:text-is('t02')")
        assert page.locator("nav.tabs a").all_inner_texts() == ["prp"]
        assert "50 %" in page.locator("#summary").inner_text()
        assert page.evaluate("document.scrollingElement.scrollWidth <= innerWidth")
        wait_until(page, "[...document.querySelectorAll('.plots img')].every(i => i.complete && i.naturalWidth > 0)")
        shot(page, "trainee-1280.png")
        # retract t02's passing attempt with a reason: it stays listed, marked, and leaves the figures
        trainee_url = page.url
        page.click("#attempts tbody tr:first-child td:first-child a")
        page.fill("form.danger input[name=reason]", "ran the wrong scenario")
        page.click("form.danger button")
        assert "ran the wrong scenario" in page.locator("#retracted").inner_text()
        page.goto(trainee_url)
        assert "retracted" in page.locator("#attempts").inner_text()
        assert "0 %" in page.locator("#summary").inner_text()
        page.goto(site.url + "/audit")
        assert "ran the wrong scenario" in page.locator("#audit").inner_text()
        page.goto(url + "?pack=prp")
        assert "t02" in page.locator("#below").inner_text()
    finally:
        page.close()
