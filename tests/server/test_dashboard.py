"""The dashboard over plain HTTP (no browser), on SQLite and PostgreSQL: sign-in with CSRF,
session cookies (missing, forged, expired), pages a trainer and a trainee may open, plots with the
class median, CSV and xAPI downloads, deletion forms and their CSRF checks, escaped names."""

from __future__ import annotations

import csv
import io
import re
import time
import urllib.parse

import pytest
from conftest import PASSWORD, PEOPLE, attempt, call, count_attempts, save_scored, upload

from chainsim.game.records.report import CSV_COLUMNS
from chainsim.game.records.store import RecordStore


class Browser:
    """Cookies and form posts by hand, as a browser without JavaScript sends them."""

    def __init__(self, site) -> None:
        self.site = site
        self.cookies: dict[str, str] = {}

    def _headers(self, extra=None) -> dict:
        h = dict(extra or {})
        if self.cookies:
            h["Cookie"] = "; ".join(f"{k}={v}" for k, v in self.cookies.items())
        return h

    def _keep(self, hdrs) -> None:
        for value in hdrs.get_all("set-cookie") or []:
            name, _, rest = value.partition("=")
            val = rest.split(";")[0]
            if val in ("", '""') or "max-age=0" in value.lower():
                self.cookies.pop(name, None)
            else:
                self.cookies[name] = val

    def get(self, path: str):
        status, body, hdrs = call(self.site, "GET", path, headers=self._headers())
        self._keep(hdrs)
        return status, body, hdrs

    def post(self, path: str, form: dict, headers=None):
        raw = urllib.parse.urlencode(form).encode()
        h = self._headers({"Content-Type": "application/x-www-form-urlencoded", **(headers or {})})
        status, body, hdrs = call(self.site, "POST", path, raw=raw, headers=h)
        self._keep(hdrs)
        return status, body, hdrs

    def sign_in(self, name: str, password: str = PASSWORD):
        status, page, _ = self.get("/login")
        assert status == 200
        return self.post("/login", {"name": name, "password": password, "csrf": csrf_of(page)})


def csrf_of(page: str) -> str:
    return re.search(r'name="csrf" value="([^"]+)"', page).group(1)


def trainee_id(site, name: str) -> int:
    with RecordStore(site.db) as store:
        return store.query("SELECT id FROM trainees WHERE name = ?", (name,))[0][0]


def save(site, who: str, a: dict):
    """An attempt stored as the server stores a scored upload: the pages are under test here, the
    scoring of uploads in test_scoring.py."""
    a = dict(a)
    class_name, trainee = a.pop("class_name", None), a.pop("trainee", None)
    if class_name is None:
        class_name, trainee = {name: classes[0] for name, _, classes in PEOPLE}[who], who
    with RecordStore(site.db) as store:
        return store.save_attempt(class_name, trainee, a)


def test_sign_in_pages_and_sign_out(site):
    b = Browser(site)
    assert b.get("/")[0] == 303  # not signed in: to the sign-in page
    status, _, hdrs = b.sign_in("tina")
    assert status == 303 and hdrs["Location"] == "/"
    cookie = [c for c in hdrs.get_all("set-cookie") if c.startswith("chainsim_session=")][0].lower()
    assert "httponly" in cookie and "samesite=lax" in cookie
    status, page, _ = b.get("/")
    assert status == 200 and ">c1</a>" in page and ">c2</a>" not in page
    status, page, _ = b.post("/logout", {"csrf": csrf_of(page)})
    assert status == 303 and b.get("/")[0] == 303


def test_wrong_password_and_missing_login_csrf(site):
    b = Browser(site)
    status, page, _ = b.sign_in("tina", "wrong password")
    assert status == 401 and "Name or password is wrong." in page
    fresh = Browser(site)  # never loaded the sign-in page: no CSRF cookie
    status, page, _ = fresh.post("/login", {"name": "tina", "password": PASSWORD, "csrf": "x" * 32})
    assert status == 403 and "chainsim_session" not in fresh.cookies


def test_forged_and_expired_session_cookies(site):
    b = Browser(site)
    b.cookies["chainsim_session"] = "forged-" + "a" * 40
    assert b.get("/")[0] == 303 and b.get(f"/trainees/{trainee_id(site, 'alice')}")[0] == 303
    b = Browser(site)
    b.sign_in("tina")
    assert b.get("/")[0] == 200
    with RecordStore(site.db) as store, store.transaction() as conn:
        conn.execute("UPDATE web_sessions SET expires_at = ?", (time.time() - 1,))
    assert b.get("/")[0] == 303
    assert b.get("/export/attempts.csv?class=c1")[0] == 303


def test_trainer_opens_trainee_progress_plots_with_class_median(site):
    for i in range(3):
        save(site, "alice", attempt(i))
        save(site, "bob", attempt(i + 3))
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get("/")
    class_link = re.search(r'href="(/classes/\d+)">c1<', page).group(1)
    status, page, _ = b.get(class_link)
    assert status == 200 and ">alice</a>" in page and ">bob</a>" in page
    # who is below prp's benchmarks is a guide: they are provisional, and the page says so
    note = re.search(r'id="provisional">([^<]*)<', page).group(1)
    assert note.startswith("Provisional: every benchmark here rests on no study and no programme data")
    alice = trainee_id(site, "alice")
    status, page, _ = b.get(f"/trainees/{alice}")
    assert status == 200
    assert re.search(r'id="provisional">Provisional: every benchmark here rests on no study', page)
    plots = re.findall(r'<img src="([^"]+\.svg)"', page)
    names = {p.rsplit("/", 1)[1] for p in plots}
    # one plot per numeric field of the record
    assert {"duration_s.svg", "landmark_error_mm.svg", "needle_error_mm.svg", "skull_contacts.svg"} <= names
    status, svg, hdrs = b.get(plots[0])
    assert status == 200 and hdrs["Content-Type"].startswith("image/svg+xml")
    assert "<svg" in svg and "class median" in svg and "this trainee" in svg
    status, png, hdrs = b.get(plots[0].replace(".svg", ".png"))
    assert status == 200 and hdrs["Content-Type"] == "image/png"
    assert b.get(f"/trainees/{alice}/plot/no_such_metric.svg")[0] == 404
    assert b.get(f"/trainees/{alice}/plot/duration_s.gif")[0] == 404


def test_trainee_sees_only_own_pages(site):
    save(site, "alice", attempt(1))
    bob_attempt = save(site, "bob", attempt(2))
    b = Browser(site)
    b.sign_in("alice")
    status, _, hdrs = b.get("/")
    assert status == 303 and hdrs["Location"] == f"/trainees/{trainee_id(site, 'alice')}"
    assert b.get(f"/trainees/{trainee_id(site, 'alice')}")[0] == 200
    status, page, _ = b.get(f"/attempts/{bob_attempt}")
    assert status == 403 and "not yours" in page
    assert b.get(f"/trainees/{trainee_id(site, 'bob')}")[0] == 403
    assert b.get(f"/trainees/{trainee_id(site, 'bob')}/plot/duration_s.svg")[0] == 403
    assert b.get("/classes/1")[0] in (403, 404)
    status, text, _ = b.get("/export/attempts.csv")
    rows = list(csv.DictReader(io.StringIO(text)))
    assert rows and {r["trainee"] for r in rows} == {"alice"}
    assert b.get("/export/attempts.csv?trainee=bob")[0] == 403


def test_csv_and_xapi_downloads(site):
    aid = save(site, "carol", attempt(4))
    b = Browser(site)
    b.sign_in("tom")
    status, text, hdrs = b.get("/export/attempts.csv?class=c2&trainee=carol")
    assert status == 200 and "attachment" in hdrs["Content-Disposition"]
    rows = list(csv.reader(io.StringIO(text)))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert str(aid) in [r[0] for r in rows[1:]]
    status, stmts, _ = b.get("/export/attempts.xapi.json?class=c2")
    assert status == 200 and all(s["actor"]["account"]["homePage"] == site.url for s in stmts)
    assert any(s["result"]["extensions"][f"{site.url}/xapi/extensions/duration_s"] == 68.0 for s in stmts)
    # identities come from the server's configured address, never from the request's Host header
    forged = b._headers({"Host": "evil.example:80"})
    status, stmts, _ = call(site, "GET", "/export/attempts.xapi.json?class=c2", headers=forged)
    assert status == 200 and stmts and all(s["actor"]["account"]["homePage"] == site.url for s in stmts)
    assert "evil.example" not in str(stmts)
    # the same downloads with an API token (scripts)
    assert call(site, "GET", "/export/attempts.csv?class=c2", token=site.tokens["tom"])[0] == 200
    assert call(site, "GET", "/export/attempts.csv?class=c1", token=site.tokens["tom"])[0] == 403


def test_retract_form_needs_the_session_csrf_token_and_same_origin(site):
    aid = save(site, "bob", attempt(5))
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{aid}")
    assert status == 200 and "Retract this attempt" in page and "Delete" not in page
    token = csrf_of(page)
    form = {"reason": "filed twice"}

    def retracted() -> bool:
        with RecordStore(site.db) as store:
            return store.get_attempt(aid)["retracted_at"] is not None

    assert b.post(f"/attempts/{aid}/retract", form)[0] == 403
    assert b.post(f"/attempts/{aid}/retract", {**form, "csrf": "forged" + token[6:]})[0] == 403
    assert b.post(f"/attempts/{aid}/retract", {**form, "csrf": token}, {"Origin": "http://evil.example"})[0] == 403
    # another account's CSRF token does not work on this session
    other = Browser(site)
    other.sign_in("tom")
    other_token = csrf_of(other.get("/")[1])
    assert b.post(f"/attempts/{aid}/retract", {**form, "csrf": other_token})[0] == 403
    assert not retracted()
    before = count_attempts(site.db)
    status, _, hdrs = b.post(f"/attempts/{aid}/retract", {**form, "csrf": token})
    assert status == 303 and hdrs["Location"] == f"/attempts/{aid}"
    assert retracted() and count_attempts(site.db) == before  # kept, marked
    page = b.get(f"/attempts/{aid}")[1]
    assert "Retracted by tina" in page and "filed twice" in page
    assert "filed twice" in b.get("/audit")[1]


def test_trainee_cannot_retract_anothers_attempt_by_form(site):
    aid = save(site, "bob", attempt(6))
    b = Browser(site)
    b.sign_in("alice")
    token = csrf_of(b.get(f"/trainees/{trainee_id(site, 'alice')}")[1])
    before = count_attempts(site.db)
    assert b.post(f"/attempts/{aid}/retract", {"csrf": token, "reason": "not mine"})[0] == 403
    assert count_attempts(site.db) == before


@pytest.mark.parametrize("name", ["<script>alert(1)</script>", '" onmouseover="x', "a&b'c"])
def test_names_are_escaped_in_pages(site, name):
    aid = save(site, "tina", dict(attempt(1), class_name="c1", trainee=name))
    b = Browser(site)
    b.sign_in("tina")
    class_page = b.get(re.search(r'href="(/classes/\d+)">c1<', b.get("/")[1]).group(1))[1]
    detail = b.get(f"/attempts/{aid}")[1]
    for page in (class_page, detail):
        assert name not in page
    assert "&lt;script&gt;" in class_page or "&#34;" in class_page or "&amp;" in class_page


def test_attempt_page_says_the_needle_reached_the_foramen_and_counts_bone_contacts_only(site):
    # the correct attempt touches no bone and ends in the foramen, which the procedure books as a touch of
    # its target role: the page must not call that a contact
    stored = save_scored(site, "alice", upload("correct.toml"))
    assert stored["skull_contacts"] == 0 and stored["target"] == "foramen_ovale_left"
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{stored['id']}")
    assert status == 200
    facts = dict(re.findall(r"<tr><th>([^<]*)</th><td>([^<]*)</td></tr>", page))
    assert facts["Bone contacts, per bone"] == "skull 0"
    assert facts["Needle reached the foramen"] == "yes (not a contact: only bone contacts are counted)"
    assert "Contacts" not in facts and "foramen 1" not in page
    # the 3-D replay's track: no contact, the foramen reached where the attempt ended
    status, track, _ = b.get(f"/attempts/{stored['id']}/replay.json")
    assert status == 200, track
    assert track["contacts"] == []
    assert track["reached"]["role"] == "foramen_ovale_left" and track["reached"]["t"] <= track["duration_s"]


def test_attempt_page_says_each_metric_in_words_against_the_benchmark(site):
    a = attempt(
        3,
        needle_error_mm=6.721578213131352e-05,
        skull_contacts=4,
        metrics={"needle_error_mm": 6.721578213131352e-05, "skull_contacts": 4.0, "xray_shots": 2.0},
        details={"D1": 6.721578213131352e-05, "d1": 0.31, "side": "left", "landmarks": [[-46.43, 52.6, -38.15]]},
    )
    aid = save(site, "alice", a)
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{aid}")
    assert status == 200
    # the prp pack's benchmarks: more than 3 bone contacts is a critical error whatever the rest
    verdict = re.search(r'id="verdict">([^<]*)<', page).group(1)
    assert verdict.startswith("FAILED: critical error") and "more than 3 bone contacts" in verdict
    assert re.search(r"<td[^>]*>Bone contacts</td>\s*<td class=\"num\">4</td>", page)
    assert "\u2264 1" in page and "Advice: On bone, withdraw" in page
    # rounded with units, never raw floats, snake_case keys or JSON arrays
    assert "0.0 mm" in page and "6.72" not in page and "e-05" not in page
    assert "-46.4, 52.6, -38.1 mm (x, y, z)" in page or "-46.4, 52.6, -38.2 mm (x, y, z)" in page
    assert "skull_contacts" not in page and "[[" not in page and "needle_error_mm" not in page


def test_attempt_page_marks_provisional_benchmarks_and_says_what_the_saved_verdict_rested_on(site):
    saved_with = {
        "skull_contacts": {"benchmark": 1.0, "basis": "provisional", "source": "the pack's default"},
        "xray_shots": {"benchmark": 8.0, "basis": "programme", "source": "programme data: 9 novices / 9 experts"},
    }
    a = attempt(
        3,
        skull_contacts=0,
        metrics={"skull_contacts": 0.0, "xray_shots": 2.0},
        details={"verdict": {"passed": True, "met": 2, "judged": 2, "critical": [], "benchmarks": saved_with}},
    )
    aid = save(site, "alice", a)
    b = Browser(site)
    b.sign_in("tina")
    status, page, _ = b.get(f"/attempts/{aid}")
    assert status == 200
    # prp ships provisional benchmarks: marked beside each threshold, and what that means said once
    assert re.search(r"<td[^>]*>\u2264 1 <span class=\"provisional\">provisional</span></td>", page)
    note = re.search(r'id="provisional">([^<]*)<', page).group(1)
    assert note.startswith("Provisional: every benchmark here rests on no study and no programme data")
    sources = re.search(r'id="benchmark-sources">(.*?)</details>', page, re.S).group(1)
    assert "Landmark error: provisional - provisional: the scripted correct attempt" in sources
    assert "Shakur et al. 2015" in sources
    # the stored verdict's own benchmarks, and the one the pack has changed since
    kept = re.search(r'id="saved-benchmarks">([^<]*)<', page).group(1)
    assert kept.startswith(
        "When it was saved, this attempt was judged against 2 benchmarks: 1 programme, 1 provisional"
    )
    assert "changed since" in kept and "X-ray images (then 8, programme)" in kept
    assert "Bone contacts (then" not in kept
