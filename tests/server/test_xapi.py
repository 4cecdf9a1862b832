"""`chainsim records export --format xapi`: xAPI 1.0.3 statements that follow the specification's
rules for the parts we write, stable ids, and posting to an LRS (a local HTTP endpoint that
checks the version header and basic auth as an LRS does)."""

from __future__ import annotations

import base64
import json
import re
import threading
import uuid
from datetime import datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import urlsplit

import pytest
from conftest import attempt

from chainsim.game.records import xapi
from chainsim.game.records.store import RecordStore

# ISO 8601 duration as xAPI 1.0.3 (Data 4.2.x) uses it
DURATION = re.compile(r"^P(?:\d+(?:\.\d+)?D)?(?:T(?:\d+H)?(?:\d+M)?(?:\d+(?:\.\d+)?S)?)?$")


def is_iri(text: str) -> bool:
    parts = urlsplit(text)
    return bool(parts.scheme) and bool(parts.netloc or parts.path)


def check_statement(s: dict) -> None:
    """The 1.0.3 requirements on the properties we set."""
    assert uuid.UUID(s["id"]).version == 5
    assert s["version"] == "1.0.3"
    actor = s["actor"]
    assert actor["objectType"] == "Agent"
    assert is_iri(actor["account"]["homePage"]) and actor["account"]["name"]
    assert set(actor) <= {"objectType", "name", "account"}  # exactly one inverse functional identifier
    assert is_iri(s["verb"]["id"]) and s["verb"]["display"]["en-US"]
    obj = s["object"]
    assert obj["objectType"] == "Activity" and is_iri(obj["id"]) and is_iri(obj["definition"]["type"])
    result = s["result"]
    assert isinstance(result["success"], bool) and result["completion"] is True
    assert DURATION.match(result["duration"]), result["duration"]
    assert all(is_iri(k) for k in result["extensions"])
    if "score" in result:
        assert isinstance(result["score"]["raw"], float)
    for group in s["context"]["contextActivities"]["grouping"]:
        assert is_iri(group["id"])
    assert datetime.fromisoformat(s["timestamp"]).utcoffset().total_seconds() == 0
    json.dumps(s, allow_nan=False)


@pytest.mark.parametrize("seconds,text", [(0, "PT0S"), (63.25, "PT1M3.25S"), (3600, "PT1H"), (3723.5, "PT1H2M3.5S")])
def test_iso_durations(seconds, text):
    assert xapi.iso_duration(seconds) == text
    assert DURATION.match(text)


def test_export_writes_valid_statements_with_every_metric(records_db, tmp_path, cli):
    with RecordStore(records_db) as store:
        ids = [store.save_attempt("c 1", "Zoë O'Neil", attempt(i)) for i in range(3)]
        store.save_attempt("c 1", "Zoë O'Neil", attempt(3, needle_error_mm=None, target="none"))
    out = tmp_path / "x.json"
    code, _, err = cli(
        "records",
        "--db",
        records_db,
        "export",
        "--format",
        "xapi",
        "--out",
        out,
        "--homepage",
        "https://training.example.org",
    )
    assert code == 0, err
    stmts = json.loads(out.read_text())
    assert len(stmts) == 4
    for s in stmts:
        check_statement(s)
    first = stmts[0]
    assert first["actor"]["account"] == {"homePage": "https://training.example.org", "name": "c 1/Zoë O'Neil"}
    assert first["object"]["id"] == "https://training.example.org/activities/procedure/prp"
    ext = first["result"]["extensions"]
    base = "https://training.example.org/xapi/extensions/"
    assert ext[base + "landmark_error_mm"] == attempt(0)["landmark_error_mm"]
    assert ext[base + "step_times"] == attempt(0)["step_times"]
    assert first["result"]["score"] == {"raw": attempt(0)["needle_error_mm"]}
    assert [s["result"]["success"] for s in stmts] == [False, True, False, False]  # skull / foramen / ... / none
    assert "score" not in stmts[3]["result"]  # no needle contact: no needle score
    # exporting again gives the same statement ids, so an LRS stores each attempt once
    code, _, _ = cli(
        "records",
        "--db",
        records_db,
        "export",
        "--format",
        "xapi",
        "--out",
        tmp_path / "y.json",
        "--homepage",
        "https://training.example.org",
    )
    assert [s["id"] for s in json.loads((tmp_path / "y.json").read_text())] == [s["id"] for s in stmts]
    assert len(set(s["id"] for s in stmts)) == 4 and ids


class LRS(BaseHTTPRequestHandler):
    received: list = []

    def do_POST(self):  # noqa: N802 - http.server's naming
        body = self.rfile.read(int(self.headers["Content-Length"]))
        auth = self.headers.get("Authorization", "")
        ok_auth = auth == "Basic " + base64.b64encode(b"key:secret").decode()
        if self.path != "/xapi/statements" or self.headers.get("X-Experience-API-Version") != "1.0.3" or not ok_auth:
            self.send_response(401 if not ok_auth else 400)
            self.end_headers()
            self.wfile.write(b'{"error": "refused"}')
            return
        stmts = json.loads(body)
        LRS.received.extend(stmts)
        out = json.dumps([s["id"] for s in stmts]).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(out)))
        self.end_headers()
        self.wfile.write(out)

    def log_message(self, *args):
        pass


def test_post_to_an_lrs(tmp_path, cli, monkeypatch):
    db = tmp_path / "r.sqlite3"
    with RecordStore(db) as store:
        store.save_attempt("c1", "alice", attempt(1))
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), LRS)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    lrs = f"http://127.0.0.1:{httpd.server_address[1]}/xapi"
    try:
        LRS.received.clear()
        monkeypatch.setenv("CHAINSIM_LRS_AUTH", "key:wrong")
        code, _, err = cli("records", "--db", db, "export", "--format", "xapi", "--lrs", lrs)
        assert code == 2 and "HTTP 401" in err and LRS.received == []
        monkeypatch.setenv("CHAINSIM_LRS_AUTH", "key:secret")
        code, _, err = cli("records", "--db", db, "export", "--format", "xapi", "--lrs", lrs)
        assert code == 0 and "posted 1 xAPI statement(s)" in err
        check_statement(LRS.received[0])
        code, _, err = cli("records", "--db", db, "export", "--format", "xapi", "--lrs", "http://127.0.0.1:9/x")
        assert code == 2 and "cannot reach LRS" in err
    finally:
        httpd.shutdown()


def test_export_flags(tmp_path, cli):
    db = tmp_path / "r.sqlite3"
    code, _, err = cli("records", "--db", db, "export", "--format", "xapi")
    assert code == 2 and "--out FILE" in err
    code, _, err = cli("records", "--db", db, "export")
    assert code == 2 and "--csv FILE" in err
    code, _, err = cli("records", "--db", db, "export", "--format", "xapi", "--out", tmp_path / "a", "--homepage", "x")
    assert code == 2 and "http(s) URL" in err
