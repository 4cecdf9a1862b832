"""The JSON API of `chainsim serve` as a client sees it, on SQLite and PostgreSQL: upload (202, then
scored by replay), list, read, no deletes, idempotent resend, who may see what, and every kind of
bad request answered 4xx with the server still up and nothing written."""

from __future__ import annotations

import json
import secrets
import time
import uuid

import pytest
from conftest import PASSWORD, call, count_attempts, save_scored, send, settle, upload, wait_scored

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore


def count_uploads(db: str) -> int:
    with RecordStore(db) as store:
        return store.query("SELECT COUNT(*) FROM uploads")[0][0]


# -- the ordinary path --------------------------------------------------------------------------


def test_trainee_uploads_lists_and_reads_own_attempt_but_cannot_delete_it(site):
    body = upload()
    status, ack, hdrs = send(site, "alice", body)
    assert status == 202 and ack["status"] == "scoring", ack
    assert hdrs["Location"] == f"/api/uploads/{ack['upload']}"
    assert (ack["class_name"], ack["trainee"], ack["filed_by"]) == ("c1", "alice", "alice")  # filed under the account
    result = wait_scored(site, ack["upload"], site.tokens["alice"])
    assert result["status"] == "scored", result
    aid = result["attempt_id"]
    status, stored, _ = call(site, "GET", f"/api/attempts/{aid}", token=site.tokens["alice"])
    assert status == 200 and (stored["class_name"], stored["trainee"]) == ("c1", "alice")
    assert stored["target"] == body["target"] == "foramen_ovale_left" and stored["differences"] == []
    for key in ("landmark_error_mm", "needle_error_mm", "skull_contacts", "path_length_mm", "aids"):
        assert stored[key] == pytest.approx(body[key]), key
    status, listed, _ = call(site, "GET", "/api/attempts", token=site.tokens["alice"])
    assert status == 200 and aid in [a["id"] for a in listed["attempts"]]
    assert {(a["class_name"], a["trainee"]) for a in listed["attempts"]} == {("c1", "alice")}
    # attempts are records: the trainee's delete is refused and the attempt stays as it was
    status, answer, _ = call(site, "DELETE", f"/api/attempts/{aid}", token=site.tokens["alice"])
    assert status == 403 and "trainer" in answer["error"]
    assert call(site, "GET", f"/api/attempts/{aid}", token=site.tokens["alice"])[1] == stored
    # the trainer is told to retract instead
    status, answer, _ = call(site, "DELETE", f"/api/attempts/{aid}", token=site.tokens["tina"])
    assert status == 405 and "retract" in answer["error"]
    assert call(site, "GET", f"/api/attempts/{aid}", token=site.tokens["alice"])[0] == 200


def test_resend_with_same_key_is_stored_once(site):
    key = uuid.uuid4().hex
    before = count_uploads(site.db)
    first = send(site, "bob", upload(), key)
    again = send(site, "bob", upload(), key)
    assert (first[0], again[0]) == (202, 200)
    assert first[1]["upload"] == again[1]["upload"]
    assert count_uploads(site.db) == before + 1
    # The key belongs to bob's upload: alice reusing it learns nothing and writes nothing.
    stolen = send(site, "alice", upload(), key)
    assert stolen[0] == 409 and "upload" not in stolen[1]
    assert count_uploads(site.db) == before + 1
    # scored once: a resend after scoring answers with the same upload and its one attempt
    scored = wait_scored(site, first[1]["upload"], site.tokens["bob"])
    late = send(site, "bob", upload(), key)
    assert late[0] == 200 and (late[1]["upload"], late[1]["attempt_id"]) == (first[1]["upload"], scored["attempt_id"])
    with RecordStore(site.db) as store:
        assert store.query("SELECT COUNT(*) FROM attempts WHERE idem_key = ?", (key,))[0][0] == 1


def test_trainer_sees_taught_classes_only_and_files_for_a_trainee(site):
    stored = save_scored(site, "tina", upload(class_name="c1", trainee="bob"))
    assert (stored["trainee"], stored["filed_by"]) == ("bob", "tina")
    carol = save_scored(site, "carol", upload())["id"]
    listed = call(site, "GET", "/api/attempts", token=site.tokens["tina"])[1]["attempts"]
    assert {a["class_name"] for a in listed} == {"c1"}
    assert call(site, "GET", f"/api/attempts/{carol}", token=site.tokens["tina"])[0] == 403
    assert call(site, "GET", f"/api/attempts/{carol}", token=site.tokens["tom"])[0] == 200
    assert call(site, "GET", "/api/attempts?class=c2", token=site.tokens["tina"])[0] == 403
    assert send(site, "tina", upload(class_name="c2", trainee="carol"))[0] == 403
    assert send(site, "tina", upload())[0] == 422  # a trainer must say whose attempt it is


# -- who may see what -----------------------------------------------------------------------------


def test_trainee_cannot_read_list_delete_or_file_another_trainees_attempts(site):
    bob_upload = send(site, "bob", upload())[1]["upload"]
    bobs = wait_scored(site, bob_upload, site.tokens["bob"])["attempt_id"]
    before = (count_attempts(site.db), count_uploads(site.db))
    alice = site.tokens["alice"]
    status, answer, _ = call(site, "GET", f"/api/attempts/{bobs}", token=alice)
    assert status == 403 and "not yours" in answer["error"]
    assert call(site, "GET", f"/api/uploads/{bob_upload}", token=alice)[0] == 403
    assert call(site, "DELETE", f"/api/attempts/{bobs}", token=alice)[0] == 403
    assert call(site, "POST", f"/api/attempts/{bobs}/retract", {"reason": "mine now"}, alice)[0] == 403
    assert call(site, "GET", "/api/attempts?trainee=bob", token=alice)[0] == 403
    assert call(site, "GET", "/api/attempts?class=c2", token=alice)[0] == 403
    assert send(site, "alice", upload(trainee="bob"))[0] == 403
    assert send(site, "alice", upload(class_name="c2"))[0] == 403
    assert (count_attempts(site.db), count_uploads(site.db)) == before
    assert call(site, "GET", f"/api/attempts/{bobs}", token=site.tokens["bob"])[0] == 200
    # a trainer of another class can neither delete nor retract it
    assert call(site, "DELETE", f"/api/attempts/{bobs}", token=site.tokens["tom"])[0] == 403
    assert call(site, "POST", f"/api/attempts/{bobs}/retract", {"reason": "x"}, site.tokens["tom"])[0] == 403
    assert (count_attempts(site.db), count_uploads(site.db)) == before
    assert call(site, "GET", f"/api/attempts/{bobs}", token=site.tokens["bob"])[1]["retracted_by"] is None


# -- credentials -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "header",
    [
        None,
        "Bearer",
        "Bearer ",
        "Basic YWxpY2U6c2VjcmV0",
        "Bearer cst_" + "A" * 43,  # well-formed, never issued
        "Bearer " + "x" * 5000,
        "Bearer cst_' OR '1'='1",
    ],
    ids=["missing", "empty", "blank", "basic", "forged", "huge", "injection"],
)
def test_missing_or_forged_token_is_401(site, header):
    before = count_attempts(site.db)
    headers = {"Authorization": header} if header else {}
    status, answer, hdrs = call(site, "GET", "/api/attempts", headers=headers)
    assert status == 401 and "error" in answer and "Bearer" in hdrs["WWW-Authenticate"]
    assert call(site, "POST", "/api/attempts", upload(), headers=headers)[0] == 401
    assert count_attempts(site.db) == before


def test_expired_and_revoked_tokens_are_401(site):
    with RecordStore(site.db) as store:
        alice = next(u for u in accounts.list_users(store) if u.name == "alice")
        expired, _ = accounts.issue_token(store, alice, "test", ttl_s=-1.0)
        revoked, _ = accounts.issue_token(store, alice, "test")
    assert call(site, "GET", "/api/me", token=revoked)[0] == 200
    with RecordStore(site.db) as store:
        accounts.revoke_token(store, revoked)
    for token in (expired, revoked):
        status, answer, _ = call(site, "GET", "/api/me", token=token)
        assert status == 401 and "expired" in answer["error"]


def test_session_cookie_is_not_accepted_by_the_api(site):
    status, _, _ = call(site, "GET", "/api/attempts", headers={"Cookie": "chainsim_session=" + "a" * 43})
    assert status == 401


def test_login_answers_the_same_for_unknown_name_and_wrong_password(site):
    wrong = call(site, "POST", "/api/login", {"name": "alice", "password": "nope-nope-nope"})
    unknown = call(site, "POST", "/api/login", {"name": "mallory", "password": PASSWORD})
    huge = call(site, "POST", "/api/login", {"name": "x" * 10_000, "password": "y" * 10_000})
    typed = call(site, "POST", "/api/login", {"name": ["alice"], "password": {"a": 1}})
    for status, answer, _ in (wrong, unknown, huge, typed):
        assert status == 401 and answer == {"error": "name or password is wrong"}


# -- bad input: 4xx, server up, nothing written ---------------------------------------------------


BAD_BODIES = [
    ("malformed", b'{"pack": "prp", ', "application/json", 400),
    ("not utf-8", b'{"pack": "\xff\xfe"}', "application/json", 400),
    ("NaN literal", b'{"duration_s": NaN}', "application/json", 400),
    ("array", b"[1, 2, 3]", "application/json", 422),
    ("empty", b"", "application/json", 400),
    ("deep nesting", b"[" * 100_000 + b"]" * 100_000, "application/json", 400),
    ("oversized", b'{"details": {"x": "' + b"a" * (2 << 20) + b'"}}', "application/json", 413),
    ("form instead of JSON", b"pack=prp", "application/x-www-form-urlencoded", 415),
]


@pytest.mark.parametrize("what,raw,ctype,expected", BAD_BODIES, ids=[b[0] for b in BAD_BODIES])
def test_bad_bodies_are_4xx_and_write_nothing(site, what, raw, ctype, expected):
    before = (count_attempts(site.db), count_uploads(site.db))
    status, answer, _ = call(
        site, "POST", "/api/attempts", raw=raw, token=site.tokens["alice"], headers={"Content-Type": ctype}
    )
    assert status == expected, answer
    assert isinstance(answer, dict) and "\n" not in answer["error"]
    assert site.alive()
    assert (count_attempts(site.db), count_uploads(site.db)) == before


BAD_FIELDS = [
    ({"duration_s": -1.0}, "duration_s"),
    ({"landmark_error_mm": "3"}, "landmark_error_mm"),
    ({"target": "Robert'); DROP TABLE attempts;--"}, "target"),
    ({"pack": "p" * 10_000}, "10000 characters"),
    ({"aids": {"x_ray": True}}, "x_ray"),
    ({"step_times": {"insert": -2.0}}, "step_times.insert"),
    ({"details": "not an object"}, "details"),
    ({"unknown_field": 1}, "unknown_field"),
]


@pytest.mark.parametrize("change,named", BAD_FIELDS, ids=[n for _, n in BAD_FIELDS])
def test_bad_fields_are_422_naming_the_field(site, change, named):
    before = (count_attempts(site.db), count_uploads(site.db))
    status, answer, _ = send(site, "alice", upload(**change))
    assert status in (400, 422), answer
    assert named in answer["error"] and "\n" not in answer["error"]
    assert (count_attempts(site.db), count_uploads(site.db)) == before
    assert site.alive()


def nested(depth: int) -> dict:
    root: dict = {}
    inner = root
    for _ in range(depth - 1):
        inner["x"] = {}
        inner = inner["x"]
    return root


@pytest.mark.parametrize("depth", [40, 500, 900])
def test_deeply_nested_details_are_422_naming_the_field(site, depth):
    before = (count_attempts(site.db), count_uploads(site.db))
    status, answer, _ = send(site, "alice", upload(details=nested(depth)))
    assert status == 422, answer
    assert "'details'" in answer["error"] and "at most 32" in answer["error"] and "\n" not in answer["error"]
    assert site.alive()
    assert (count_attempts(site.db), count_uploads(site.db)) == before
    # an ordinary nesting is kept
    ok = send(site, "alice", upload(details={"shots": [{"angle": {"a": [1, 2]}}]}))
    assert ok[0] == 202, ok[1]


def test_injection_shaped_and_huge_names(site):
    nasty = "x'); DROP TABLE attempts;--"
    stored = save_scored(site, "tina", upload(class_name="c1", trainee=nasty))
    assert stored["trainee"] == nasty  # stored as text, nothing run
    q = "?trainee=" + urllib_quote(nasty)
    listed = call(site, "GET", "/api/attempts" + q, token=site.tokens["tina"])[1]["attempts"]
    assert [a["trainee"] for a in listed] == [nasty]
    settle(site.db)  # an earlier test's upload scored meanwhile would change the count
    before = (count_attempts(site.db), count_uploads(site.db))
    assert send(site, "tina", upload(class_name="c1", trainee="n" * 10_000))[0] == 422
    assert call(site, "GET", "/api/attempts?class=" + "c" * 10_000, token=site.tokens["tina"])[0] == 400
    assert call(site, "GET", "/api/attempts/" + "9" * 40, token=site.tokens["tina"])[0] == 404
    assert call(site, "GET", "/api/attempts/-1", token=site.tokens["tina"])[0] == 404
    assert send(site, "alice", upload(), key="k" * 10_000)[0] == 400
    assert send(site, "alice", upload(), key="bad key!")[0] == 400
    assert (count_attempts(site.db), count_uploads(site.db)) == before
    assert site.alive()


def urllib_quote(text: str) -> str:
    from urllib.parse import quote

    return quote(text, safe="")


def test_errors_are_json_and_pages_carry_security_headers(site):
    status, answer, hdrs = call(site, "GET", "/api/nothing-here")
    assert status == 404 and isinstance(answer, dict)
    status, _, hdrs = call(site, "GET", "/login")
    csp = hdrs["Content-Security-Policy"]
    assert status == 200 and "default-src 'self'" in csp and "frame-ancestors 'none'" in csp
    assert hdrs["X-Content-Type-Options"] == "nosniff"


@pytest.mark.slow
def test_many_concurrent_uploads_all_land_and_are_scored_once(site):
    from concurrent.futures import ThreadPoolExecutor

    settle(site.db)  # an earlier test's upload scored meanwhile would count as one of these
    before = (count_attempts(site.db), count_uploads(site.db))
    keys = [secrets.token_hex(8) for _ in range(40)]
    body = upload("skull-hit.toml")

    def send_as_a_client_does(key: str):
        # past the account's burst the server answers 429 with Retry-After, and a client (the simulator's
        # outbox) sends again then, under the same key: 40 at once outrun 20 at 100 a second on a fast run
        for _ in range(30):
            answer = send(site, "carol", body, key)
            if answer[0] != 429:
                return answer
            time.sleep(float(answer[2]["Retry-After"]))
        return answer

    with ThreadPoolExecutor(8) as pool:
        acks = list(pool.map(send_as_a_client_does, keys))
    assert all(r[0] == 202 for r in acks), [r for r in acks if r[0] != 202][:1]
    assert len({r[1]["upload"] for r in acks}) == 40
    assert count_uploads(site.db) == before[1] + 40
    scored = [wait_scored(site, r[1]["upload"], site.tokens["carol"]) for r in acks]
    assert all(r["status"] == "scored" for r in scored)
    assert len({r["attempt_id"] for r in scored}) == 40
    assert count_attempts(site.db) == before[0] + 40
    assert json.dumps(scored[0])  # what came back is plain JSON
