"""A blinded rating end to end, on SQLite and PostgreSQL: a trainer makes a rating set of scored attempts with
`chainsim rating create`, each rater opens their own secret link and sees coded attempts without the trainee's
name, class, dates, ids or the simulator's scores, marks them on the global rating form in the browser (bad marks
and forms from another site refused), and `chainsim rating report` gives the raters' agreement as the ICC the
statistics module computes from the stored marks, with each metric's correlation."""

from __future__ import annotations

import html
import json
import re

import numpy as np
import pytest
from conftest import call, save_scored, upload
from test_dashboard import Browser

from chainsim.game.cli.main import main
from chainsim.game.study import agreement
from chainsim.game.study.rating import FORM

SCRIPTS = ("correct.toml", "skull-hit.toml", "variant-1.toml", "variant-2.toml")


@pytest.fixture(scope="module")
def rated(site):
    """Four scored attempts of alice's (she is in class c1) with their recordings."""
    return [save_scored(site, "alice", upload(s)) for s in SCRIPTS]


def _links(out: str) -> dict[str, str]:
    return dict(re.findall(r"^  (\w+): \S+/rate/(\S+)$", out, re.M))


def _marks(total_per_item: int) -> dict[str, str]:
    return {key: str(total_per_item) for key, _label, _anchors in FORM}


def test_raters_see_coded_attempts_only_mark_them_and_the_report_gives_their_agreement(site, rated, capsys, tmp_path):
    ids = ",".join(str(a["id"]) for a in rated)
    name = "panel"  # each backend's site has its own database
    assert main(["rating", "create", "--db", site.db, "--name", name, "--attempts", ids,
                 "--rater", "rita", "--rater", "rolf", "--base-url", "http://records.example"]) == 0  # fmt: skip
    links = _links(capsys.readouterr().out)
    assert set(links) == {"rita", "rolf"}
    rita, rolf = Browser(site), Browser(site)
    status, page, _ = rita.get(f"/rate/{links['rita']}")
    assert status == 200 and "0 of 4 attempts rated" in page
    codes = re.findall(rf'href="/rate/{re.escape(links["rita"])}/(R[0-9A-F]{{8}})"', page)
    assert len(codes) == 4
    # blinded: no trainee, class, date, attempt id, metric or verdict anywhere the rater can open
    status, page, _ = rita.get(f"/rate/{links['rita']}/{codes[0]}")
    assert status == 200 and 'id="rating-form"' in page
    status, track, _ = rita.get(f"/rate/{links['rita']}/{codes[0]}/replay.json")
    assert status == 200, track
    # the rater's own link is a random token that may hold any two letters ("c1" among them): left out
    seen = (page + json.dumps(track)).replace(links["rita"], "")
    for secret in ("alice", "c1", "2026-", "Needle error", "PASS", "FAIL", "/attempts/"):
        assert secret not in seen
    assert track["frames"] and all(im["url"].startswith(f"/rate/{links['rita']}/{codes[0]}/") for im in track["images"])
    assert rita.get(f"/rate/{links['rita']}/{codes[0]}/display.glb")[0] == 200
    for im in track["images"][:1]:  # the X-ray images the trainee took, under the code's address
        status, _, hdrs = rita.get(im["url"])
        assert status == 200 and hdrs["Content-Type"] == "image/png"
    status, text, _ = rita.get(f"/rate/{links['rita']}/{codes[0]}/xray/99.png")
    assert status == 404 and f"this attempt has {len(track['images'])} X-ray images" in text
    # the link is the credential: an unknown one, or a code of no set of this rater's, opens nothing
    assert rita.get("/rate/not-a-link")[0] == 404
    assert rita.get(f"/rate/{links['rita']}/RFFFFFFFF")[0] == 404
    assert call(site, "GET", f"/attempts/{rated[0]['id']}")[0] in (303, 401)  # the rater has no account
    # a form with an item unmarked, or a mark outside 1-5, is refused in one line and nothing is stored
    bad = {**_marks(3), "overall": "7"}
    status, page, _ = rita.post(f"/rate/{links['rita']}/{codes[0]}", bad)
    assert status == 400 and "Overall performance: mark it from 1 to 5, got '7'" in html.unescape(page)
    assert rita.post(f"/rate/{links['rita']}/{codes[0]}", _marks(3), {"Origin": "http://evil.example"})[0] == 403
    assert "0 of 4 attempts rated" in rita.get(f"/rate/{links['rita']}")[1]
    # each rater marks every attempt; rolf's marks follow rita's, one lower on the last
    by_code = {}
    for k, code in enumerate(codes):
        status, _, hdrs = rita.post(f"/rate/{links['rita']}/{code}", _marks(1 + k))
        assert status == 303 and hdrs["Location"] == f"/rate/{links['rita']}"
        by_code[code] = (5 * (1 + k), 5 * max(1, k))
        assert rolf.post(f"/rate/{links['rolf']}/{code}", _marks(max(1, k)))[0] == 303
    status, page, _ = rita.get(f"/rate/{links['rita']}")
    assert "4 of 4 attempts rated" in page and f"{by_code[codes[2]][0]} of 25" in page
    # the report: the ICC of the stored marks, as the statistics module gives it
    out = tmp_path / "report"
    assert main(["rating", "report", "--db", site.db, "--name", name, "--pack", "prp", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    want = agreement.icc(np.array([by_code[c] for c in sorted(by_code)], dtype=float))
    assert f"ICC(A,1) {want.single:.2f} (95 % {want.single_ci[0]:.2f} to {want.single_ci[1]:.2f})" in printed
    md = (out / "agreement.md").read_text()
    assert "| one rater, ICC(A,1) |" in md and "Needle error" in md and (out / "ratings.png").stat().st_size > 5000
    rows = (out / "ratings.csv").read_text().splitlines()
    assert rows[0].startswith("code,attempt_id,rater:rita,rater:rolf,mean") and len(rows) == 5


def test_a_rating_set_refuses_bad_requests_in_one_line(site, rated, capsys):
    ids = ",".join(str(a["id"]) for a in rated[:2])
    args = ["rating", "create", "--db", site.db, "--base-url", "http://x"]
    assert main([*args, "--name", "solo", "--attempts", ids, "--rater", "rita"]) == 2
    assert "at least two raters" in capsys.readouterr().err
    assert main([*args, "--name", "few", "--attempts", str(rated[0]["id"]), "--rater", "a", "--rater", "b"]) == 2
    assert "at least two attempts" in capsys.readouterr().err
    assert (
        main([*args, "--name", "gone", "--attempts", f"{rated[0]['id']},999999", "--rater", "a", "--rater", "b"]) == 2
    )
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "no attempt with id 999999" in err
    assert main(["rating", "report", "--db", site.db, "--name", "nope", "--pack", "prp", "--out", "/tmp/x"]) == 2
    assert "no rating set named 'nope'" in capsys.readouterr().err


@pytest.mark.slow
def test_a_rater_marks_an_attempt_in_a_real_browser(site, rated, capsys):
    """The distribution's Chromium: the rater's link, the replay drawn, the form marked by clicks, saved."""
    from test_browser import chromium

    ids = ",".join(str(a["id"]) for a in rated[:3])
    assert main(["rating", "create", "--db", site.db, "--name", "browser-panel", "--attempts", ids,
                 "--rater", "rita", "--rater", "rolf", "--base-url", site.url]) == 0  # fmt: skip
    link = _links(capsys.readouterr().out)["rita"]
    for browser in chromium():
        page = browser.new_page(viewport={"width": 1024, "height": 768})
        page.goto(f"{site.url}/rate/{link}")
        assert page.locator("#progress").inner_text() == "0 of 3 attempts rated."
        page.click("table#items a >> nth=0")
        page.locator("#replay-status:has-text('Replayed')").wait_for(timeout=60_000)  # the page's CSP allows no eval
        assert "alice" not in page.content()
        for key, _label, _anchors in FORM:
            page.check(f"input[name={key}][value='4']")
        page.click("button[type=submit]")
        page.wait_for_url(f"{site.url}/rate/{link}")
        assert page.locator("#progress").inner_text() == "1 of 3 attempts rated."
        assert page.locator("text=20 of 25").count() == 1
