"""Attempts a programme can rely on: provenance, input a person made, bounded and fair scoring.

Against a real `chainsim serve` over SQLite and PostgreSQL, with uploads the real simulator made at
the window's pace (tests/server/conftest.py). The pack's own attempt sped up five times is stored
but flagged, audited and left for its trainer to accept; a script's events, a foreign step, a
recording that never saves and one longer than the server replays are refused with one line each;
a long recording stops at its Save; an account past its upload rate gets 429 with Retry-After; a
class that requires witnessed attempts refuses uploads from the window; and replay processes end
with the server whether it is stopped or killed.
"""

from __future__ import annotations

import math
import os
import signal
import time
from pathlib import Path

import pytest
from conftest import call, populate, save_scored, send, sign_in, start_server, upload, wait_scored

from chainsim.game.cli.main import main
from chainsim.game.records import provenance
from chainsim.game.records.store import RecordStore


@pytest.fixture
def server(records_db, tmp_path):
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log", args=("--max-session-minutes", "180"))
    sign_in(srv, "alice", "tina", "bob")
    yield srv
    srv.stop()


def with_recording(body: dict, change) -> dict:
    rec = provenance.decode_recording(body["recording"])
    change(rec)
    return {**body, "recording": provenance.encode_recording(rec)}


def sped_up(factor: float):
    def change(rec: dict) -> None:
        for e in rec["event"]:
            e["t"] = round(e["t"] / factor, 6)
        rec["steps"] = math.ceil(rec["event"][-1]["t"] / rec["dt"]) + 120

    return change


def test_an_honest_upload_is_replayed_unflagged_and_a_sped_up_one_is_flagged_until_accepted(server):
    honest = save_scored(server, "alice", upload())
    assert honest["source"] == "replayed" and honest["flags"] == [] and honest["target"] == "foramen_ovale_left"
    fast = save_scored(server, "alice", with_recording(upload(), sped_up(5.0)))
    assert fast["source"] == "replayed" and fast["accepted_by"] is None
    assert any("clicks on separate targets within one second" in f for f in fast["flags"]), fast["flags"]
    status, audit, _ = call(server, "GET", "/api/audit", token=server.tokens["tina"])
    assert any(r["action"] == "implausible" and r["attempt_id"] == fast["id"] for r in audit["audit"])
    # the trainee cannot accept their own; the trainer can, once, audited
    status, answer, _ = call(server, "POST", f"/api/attempts/{fast['id']}/accept", token=server.tokens["alice"])
    assert status == 403, answer
    status, accepted, _ = call(server, "POST", f"/api/attempts/{fast['id']}/accept", token=server.tokens["tina"])
    assert status == 200 and accepted["accepted_by"] == "tina", accepted
    status, again, _ = call(server, "POST", f"/api/attempts/{fast['id']}/accept", token=server.tokens["tina"])
    assert status == 422 and "already accepted" in again["error"]
    status, answer, _ = call(server, "POST", f"/api/attempts/{honest['id']}/accept", token=server.tokens["tina"])
    assert status == 422 and "not flagged" in answer["error"]
    status, audit, _ = call(server, "GET", "/api/audit", token=server.tokens["tina"])
    assert any(r["action"] == "accept" and r["attempt_id"] == fast["id"] for r in audit["audit"])


def test_recordings_not_made_at_the_window_or_not_saving_are_refused_in_one_line(server):
    good = upload()

    def scripted(rec):
        rec["event"] = [*rec["event"][:-3], {"t": rec["event"][-1]["t"], "kind": "widget", "name": "save"}]

    def no_save(rec):
        rec["event"] = rec["event"][:-3]  # the last click is the one on Save

    cases = {
        "a 'widget' event, which the window never records": scripted,
        "the recording's step is 0.01 s but the pack's is": lambda rec: rec.update(dt=0.01),
        "does not replay to a saved attempt": no_save,
    }
    sent = {}
    for expected, change in cases.items():
        status, ack, _ = send(server, "alice", with_recording(good, change))
        assert status == 202, ack
        sent[expected] = ack["upload"]
    for expected, uid in sent.items():
        result = wait_scored(server, uid, server.tokens["alice"], 240)
        assert result["status"] == "refused" and expected in result["error"], result
        assert "\n" not in result["error"]


def test_a_replay_stops_at_the_save_however_long_the_recording_runs_on(server):
    # the same attempt with 120 simulated minutes after its Save
    tail = 120 * 60 * 120
    long_tail = with_recording(upload(), lambda rec: rec.update(steps=rec["steps"] + tail))
    stored = save_scored(server, "alice", long_tail)
    assert stored["target"] == "foramen_ovale_left"
    assert not any(d["field"] == "state at the Save" for d in stored["differences"])
    (line,) = [ln for ln in server.log.read_text().splitlines() if f"scored: attempt {stored['id']} " in ln]
    run, of = (int(w) for w in line.split("replayed ")[1].split(" steps")[0].split(" of the recording's "))
    assert of > tail and run < 3000, line


def test_an_account_past_its_upload_rate_waits_with_retry_after(records_db, tmp_path):
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log", args=("--uploads-per-minute", "1"))
    try:
        sign_in(srv, "alice", "bob")
        token = srv.tokens["alice"]
        bad = {**upload(), "pack": "nope", "pack_identity": {"name": "nope", "version": "1", "hash": "0" * 64}}
        statuses = [send(srv, "alice", bad, token=token)[0] for _ in range(20)]
        assert statuses == [422] * 20  # checked (and refused) within the burst of 20
        status, answer, headers = send(srv, "alice", bad, token=token)
        assert status == 429 and "too many uploads from this account" in answer["error"], answer
        assert 1 <= int(headers["Retry-After"]) <= 60
        assert send(srv, "bob", bad)[0] == 422  # another account is not held up
    finally:
        srv.stop()


def test_a_class_that_requires_witnessed_attempts_refuses_window_uploads(server):
    assert main(["records", "--db", server.db, "witnessed", "c1"]) == 0
    status, answer, _ = send(server, "alice", upload())
    assert status == 422 and "takes only attempts made in the browser trainer" in answer["error"], answer
    assert main(["records", "--db", server.db, "witnessed", "c1", "--off"]) == 0
    assert send(server, "alice", upload())[0] == 202


def children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(entry.name))
    return out


def running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def gone(pids: list[int], timeout: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout
    while any(running(p) for p in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_replay_processes_end_with_the_server(records_db, tmp_path, sig):
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log")
    try:
        sign_in(srv, "alice")

        def late_save(rec):  # a replay that runs a while: the Save comes after 30 more minutes of waiting
            rec["steps"] += 30 * 60 * 120
            for e in rec["event"][-3:]:
                e["t"] += 30 * 60

        body = with_recording(upload(), late_save)
        status, ack, _ = send(srv, "alice", body)
        assert status == 202
        deadline = time.monotonic() + 60
        while not children(srv.proc.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        replays = children(srv.proc.pid)
        assert replays, "no replay process started"
        time.sleep(2.0)
        srv.proc.send_signal(sig)
        srv.proc.wait(30)
        assert gone(replays), f"replay processes {replays} outlived the server ({sig.name})"
        with RecordStore(records_db) as store:
            (state,) = store.query("SELECT state FROM uploads WHERE id = ?", (ack["upload"],))[0]
        assert state == "scoring"  # taken up again by the next server
    finally:
        srv.stop()


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


@pytest.mark.slow
def test_forty_maximum_size_uploads_at_once_keep_the_servers_memory_bounded(records_db, tmp_path):
    import base64  # noqa: PLC0415
    import threading  # noqa: PLC0415

    from chainsim.systems.engine import limits  # noqa: PLC0415

    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log")
    try:
        sign_in(srv, "alice")
        token = srv.tokens["alice"]
        # the largest recording text an upload may carry (the scorer finds it is no recording and refuses it)
        text = base64.b64encode(os.urandom(limits.MAX_RECORDING_BYTES)).decode()
        body = {**upload(), "recording": text}
        assert send(srv, "alice", body, token=token)[0] == 202  # the first upload loads the pack's identity: once
        before = rss_mib(srv.proc.pid)
        peak, statuses, stop = [before], [], threading.Event()

        def watch():
            while not stop.is_set():
                peak.append(rss_mib(srv.proc.pid))
                time.sleep(0.05)

        def one():
            statuses.append(send(srv, "alice", body, token=token)[0])

        watcher = threading.Thread(target=watch)
        watcher.start()
        senders = [threading.Thread(target=one) for _ in range(40)]
        for t in senders:
            t.start()
        for t in senders:
            t.join()
        stop.set()
        watcher.join()
        grew = max(peak) - before
        print(f"server RSS {before:.0f} MiB before, peak {max(peak):.0f} MiB during 40 uploads of {len(text):,} chars")
        assert statuses == [202] * 40, statuses
        assert grew < 100, f"the server grew by {grew:.0f} MiB under 40 maximum-size uploads"
    finally:
        srv.stop()
