"""What the records server must not give away, on SQLite and PostgreSQL: a classmate's figures through
a class median of too few trainees, and a class's name through a refused (403) page.

Class FEW has five trainees: f4 made three prp attempts (needle errors 5, 700 and 800 mm), the others
one each (needle errors 1-4 mm). The class median at attempt 1 is of five trainees and is drawn; at
attempts 2 and 3 only f4 has a value, so a median there would be f4's own attempts: the plots say
"class median shown from 5 trainees" instead, and f0's plot never reaches f4's hundreds.
"""

from __future__ import annotations

import re
import urllib.parse

import pytest
from conftest import PASSWORD, attempt, call

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore
from chainsim.game.server.classpage import MEDIAN_MIN_TRAINEES, MEDIAN_WITHHELD

CLASS, TRAINER, VIEWER = "few", "fay", "f0"
F4_NEEDLE = (5.0, 700.0, 800.0)


@pytest.fixture(scope="module")
def few(site):
    """Class CLASS: f0 (an account) to f4, taught by TRAINER; f4 alone has attempts 2 and 3."""
    with RecordStore(site.db) as store:
        if not store.query("SELECT 1 FROM users WHERE name = ?", (TRAINER,)):
            accounts.add_user(store, TRAINER, "trainer", PASSWORD, [CLASS])
            accounts.add_user(store, VIEWER, "trainee", PASSWORD, [CLASS])
            for k in range(4):
                store.save_attempt(CLASS, f"f{k}", attempt(k, needle_error_mm=float(k + 1)))
            for k, v in enumerate(F4_NEEDLE):
                store.save_attempt(CLASS, "f4", attempt(k, needle_error_mm=v))
    return site


def ids(site) -> dict[str, int]:
    with RecordStore(site.db) as store:
        cls = store.query("SELECT id FROM classes WHERE name = ?", (CLASS,))[0][0]
        trainees = dict(store.query("SELECT name, id FROM trainees WHERE class_id = ?", (cls,)))
    return {"class": cls, **trainees}


def signed_in(site, name: str) -> tuple[dict, str]:
    """(headers carrying a fresh session cookie of ``name``, the session's CSRF token)."""
    with RecordStore(site.db) as store:
        sid, csrf = accounts.start_session(store, accounts.check_login(store, name, PASSWORD))
    return {"Cookie": f"chainsim_session={sid}"}, csrf


def numbers_drawn(svg: str) -> list[float]:
    """The numbers written on an SVG plot (its tick labels: matplotlib keeps each text as a comment)."""
    out = []
    for text in re.findall(r"<!-- ([^<>]*?) -->", svg):
        text = text.replace("\u2212", "-")
        if re.fullmatch(r"-?\d+(\.\d+)?", text):
            out.append(float(text))
    return out


def test_a_trainee_never_sees_a_median_of_fewer_than_five_classmates(few):
    site, at = few, ids(few)
    headers, _ = signed_in(site, VIEWER)
    status, svg, _ = call(site, "GET", f"/trainees/{at[VIEWER]}/plot/prp/needle_error_mm.svg", headers=headers)
    assert status == 200, svg
    assert "<!-- class median -->" in svg  # attempt 1: five trainees, drawn
    assert MEDIAN_WITHHELD in svg and MEDIAN_MIN_TRAINEES == 5
    drawn = numbers_drawn(svg)
    assert drawn and max(drawn) < min(F4_NEEDLE[1:]), drawn  # f4's 700 and 800 mm appear nowhere


def test_the_trainers_plots_hold_the_same_minimum(few):
    site, at = few, ids(few)
    headers, _ = signed_in(site, TRAINER)
    status, svg, _ = call(site, "GET", f"/classes/{at['class']}/plot/prp/needle_error_mm.svg", headers=headers)
    assert status == 200, svg
    assert "<!-- class median -->" in svg and MEDIAN_WITHHELD in svg
    # the trainer's view of a trainee's plot: the median of attempt 1 only
    status, svg, _ = call(site, "GET", f"/trainees/{at['f4']}/plot/prp/needle_error_mm.svg", headers=headers)
    assert status == 200 and MEDIAN_WITHHELD in svg


def refusal(page: str) -> str:
    """The one line a 403 page says."""
    return re.search(r'<p class="error">(.*?)</p>', page, re.S).group(1)


def test_refused_pages_name_no_class(few):
    site, at = few, ids(few)
    for who in ("tom", "alice"):  # another class's trainer, another class's trainee
        headers, csrf = signed_in(site, who)
        for path in (f"/classes/{at['class']}", f"/classes/{at['class']}/plot/prp/needle_error_mm.svg"):
            status, page, _ = call(site, "GET", path, headers=headers)
            assert status == 403, (who, path, page)
            assert CLASS not in refusal(page), (who, path)
    headers, csrf = signed_in(site, "tom")
    for form_path in ("trainees", "password"):
        form = urllib.parse.urlencode({"csrf": csrf, "name": "f1", "password": "a new password 1"}).encode()
        status, page, _ = call(
            site,
            "POST",
            f"/classes/{at['class']}/{form_path}",
            raw=form,
            headers={**headers, "Content-Type": "application/x-www-form-urlencoded", "Origin": site.url},
        )
        assert status == 403, page
        line = refusal(page)
        assert CLASS not in line and "f1" not in line, line
