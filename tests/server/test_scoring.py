"""The server computes each result by replaying the attempt's recording (issue: results that can be trusted).

Uploads come from the real simulator (the prp pack, scripted input, Save pressed) through the
local outbox, to a real `chainsim serve` over SQLite and PostgreSQL. A queued upload edited to
claim a success after an attempt that hit the skull is stored with the replay's figures and
flagged; an unknown pack, another copy of a pack or an upload without its recording is refused and
stays queued with the reason (a recording that never saves is refused by the scorer:
test_provenance.py); a server killed with uploads waiting scores each of them once
after a restart; attempts cannot be deleted by a trainee, and a trainer's retraction is audited.
A trainer who updates a pack on a running server has uploads made with the new files scored
without a restart, and those made with the old files refused.
"""

from __future__ import annotations

import json
import shutil
import signal

import pytest
from conftest import PASSWORD, call, populate, save_through_simulator, sign_in, start_server, upload, wait_scored

from chainsim.game.packs import pack as packs
from chainsim.game.records import provenance, remote
from chainsim.game.records.store import RecordStore


def queue_offline(tmp_path, url: str, script: str, name: str = "local.sqlite3") -> str:
    """An attempt saved while the server is unknown to the simulator: it waits in the local outbox."""
    local = str(tmp_path / name)
    save_through_simulator("http://127.0.0.1:9", local, script)  # nothing listens on port 9
    with RecordStore(local) as store, store.transaction() as conn:
        conn.execute("UPDATE outbox SET server = ?", (url,))
    return local


@pytest.fixture
def server(records_db, tmp_path):
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log")
    sign_in(srv, "alice", "tina")
    yield srv
    srv.stop()


def test_forged_upload_is_stored_with_the_replays_figures_and_flagged(server, tmp_path):
    local = queue_offline(tmp_path, server.url, "skull-hit.toml")
    with RecordStore(local) as store:
        (row,) = store.query("SELECT id, attempt FROM outbox")
        body = json.loads(row["attempt"])
        assert body["target"] == "skull" and "recording" in body and body["pack_identity"]["name"] == "prp"
        # the trainee edits the queued upload: the foramen ovale, a perfect needle and perfect landmarks
        body.update(target="foramen_ovale_left", needle_error_mm=-2.0, landmark_error_mm=0.0, skull_contacts=0)
        with store.transaction() as conn:
            conn.execute("UPDATE outbox SET attempt = ? WHERE id = ?", (json.dumps(body), row["id"]))
        remote.login(store, server.url, "alice", PASSWORD)
        assert remote.sync(store)["sent"] == 1
        upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
    result = wait_scored(server, upload_id, server.tokens["alice"])
    assert result["status"] == "scored", result
    status, a, _ = call(server, "GET", f"/api/attempts/{result['attempt_id']}", token=server.tokens["tina"])
    assert status == 200
    assert a["target"] == "skull" and a["needle_error_mm"] > 5.0 and a["skull_contacts"] >= 1
    assert a["filed_by"] == "alice" and a["client_figures"]["target"] == "foramen_ovale_left"
    flagged = {d["field"] for d in a["differences"]}
    assert {"target", "needle_error_mm", "skull_contacts"} <= flagged
    # the trainer's page says so, and the audit log holds the flag
    status, log, _ = call(server, "GET", "/api/audit", token=server.tokens["tina"])
    assert any(e["action"] == "flag" and e["attempt_id"] == a["id"] for e in log["audit"])
    # the recording is kept with the attempt and replays as it was uploaded
    with RecordStore(server.db) as store:
        (kept,) = store.query("SELECT recording FROM attempt_recordings WHERE attempt_id = ?", (a["id"],))
        assert provenance.decode_recording(kept[0])["pack"] == "prp"


def test_honest_upload_is_not_flagged_and_the_server_keeps_time(server, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        remote.login(store, server.url, "alice", PASSWORD)
    save_through_simulator(server.url, local, "correct.toml")
    with RecordStore(local) as store:
        (row,) = store.query("SELECT remote_id, attempt, last_error FROM outbox")
        assert row["last_error"] is None
    result = wait_scored(server, row["remote_id"], server.tokens["alice"])
    status, a, _ = call(server, "GET", f"/api/attempts/{result['attempt_id']}", token=server.tokens["alice"])
    assert a["target"] == "foramen_ovale_left" and a["differences"] == []
    assert a["created_at"] == result["received_at"]  # the server's clock; the client's is kept beside it
    assert a["client_created_at"] == json.loads(row["attempt"])["created_at"]


def test_unknown_pack_or_copy_or_no_recording_is_refused_and_stays_queued(server, tmp_path):
    local = queue_offline(tmp_path, server.url, "skull-hit.toml")
    with RecordStore(local) as store:
        (row,) = store.query("SELECT id, attempt FROM outbox")
        good = json.loads(row["attempt"])
        remote.login(store, server.url, "alice", PASSWORD)
        cases = {
            "not on this server": {**good, "pack_identity": {**good["pack_identity"], "name": "nope"}, "pack": "nope"},
            "another copy": {**good, "pack_identity": {**good["pack_identity"], "hash": "0" * 64}},
        }
        cases["must carry its recording"] = {k: v for k, v in good.items() if k != "recording"}
        for expected, body in cases.items():
            with store.transaction() as conn:
                conn.execute(
                    "UPDATE outbox SET attempt = ?, last_error = NULL WHERE id = ?", (json.dumps(body), row["id"])
                )
            result = remote.sync(store)
            assert result["sent"] == 0 and result["waiting"] == 1, result
            assert "HTTP 422" in result["problems"][0] and "kept in the queue" in result["problems"][0]
            assert expected in store.query("SELECT last_error FROM outbox")[0][0]


@pytest.mark.slow
def test_killed_server_scores_every_waiting_upload_once_after_restart(records_db, tmp_path):
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log")
    sign_in(srv, "alice")
    token = srv.tokens["alice"]
    local = queue_offline(tmp_path, srv.url, "skull-hit.toml")
    with RecordStore(local) as store:
        body = json.loads(store.query("SELECT attempt FROM outbox")[0][0])
    ids = []
    for i in range(6):
        status, ack, _ = call(srv, "POST", "/api/attempts", body, token, {"Idempotency-Key": f"kill-key-{i}"})
        assert status == 202 and ack["status"] == "scoring", ack
        ids.append(ack["upload"])
    # a resend is answered with the first upload; the same key with another body is a conflict
    status, again, _ = call(srv, "POST", "/api/attempts", body, token, {"Idempotency-Key": "kill-key-0"})
    assert status == 200 and again["upload"] == ids[0]
    other = {**body, "duration_s": 1.0}
    status, _, _ = call(srv, "POST", "/api/attempts", other, token, {"Idempotency-Key": "kill-key-0"})
    assert status == 409
    srv.stop(signal.SIGKILL)
    srv = start_server(records_db, tmp_path / "serve2.log", int(srv.url.rsplit(":", 1)[1]))
    try:
        results = [wait_scored(srv, i, token, 240) for i in ids]
        assert all(r["status"] == "scored" for r in results), results
        with RecordStore(records_db) as store:
            attempts = store.list_attempts("c1", "alice")
        assert sorted(a["id"] for a in attempts) == sorted(r["attempt_id"] for r in results)
        assert len(attempts) == len(ids)
    finally:
        srv.stop()


def test_trainee_cannot_delete_trainer_retracts_with_a_reason(server, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        remote.login(store, server.url, "alice", PASSWORD)
    save_through_simulator(server.url, local, "skull-hit.toml")
    with RecordStore(local) as store:
        upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
    aid = wait_scored(server, upload_id, server.tokens["alice"])["attempt_id"]
    status, answer, _ = call(server, "DELETE", f"/api/attempts/{aid}", token=server.tokens["alice"])
    assert status == 403 and "trainer" in answer["error"]
    status, answer, _ = call(server, "POST", f"/api/attempts/{aid}/retract", {}, server.tokens["tina"])
    assert status == 422 and "reason" in answer["error"]
    status, a, _ = call(
        server, "POST", f"/api/attempts/{aid}/retract", {"reason": "wrong trainee"}, server.tokens["tina"]
    )
    assert status == 200 and a["retracted_by"] == "tina" and a["retract_reason"] == "wrong trainee"
    status, log, _ = call(server, "GET", "/api/audit", token=server.tokens["tina"])
    assert [(e["action"], e["actor"], e["detail"]) for e in log["audit"] if e["attempt_id"] == aid][-1] == (
        "retract",
        "tina",
        "wrong trainee",
    )
    status, _, _ = call(server, "GET", "/api/audit", token=server.tokens["alice"])
    assert status == 403


@pytest.mark.slow
def test_a_pack_updated_on_a_running_server_scores_uploads_made_with_its_new_files(records_db, tmp_path, pack_copy):
    folder = tmp_path / "packs"
    shutil.copytree(pack_copy, folder / "prp")  # this server's own copy, which the trainer updates
    populate(records_db)
    srv = start_server(records_db, tmp_path / "serve.log", args=("--pack-path", str(folder)))
    try:
        sign_in(srv, "alice")
        token = srv.tokens["alice"]
        old = upload("correct.toml")
        status, ack, _ = call(srv, "POST", "/api/attempts", old, token, {"Idempotency-Key": "before-update"})
        assert status == 202, ack
        assert wait_scored(srv, ack["upload"], token)["status"] == "scored"

        # the trainer updates the pack in place; the simulator, with the same update, sends its new identity
        manifest = folder / "prp" / "pack.toml"
        manifest.write_text(manifest.read_text() + "\n# updated by the trainer\n")
        new = {**old, "pack_identity": provenance.pack_identity(packs.load(folder / "prp"))}
        assert new["pack_identity"]["hash"] != old["pack_identity"]["hash"]
        status, ack, _ = call(srv, "POST", "/api/attempts", new, token, {"Idempotency-Key": "after-update"})
        assert status == 202, ack
        result = wait_scored(srv, ack["upload"], token)
        assert result["status"] == "scored", result
        status, a, _ = call(srv, "GET", f"/api/attempts/{result['attempt_id']}", token=token)
        assert a["pack_hash"] == new["pack_identity"]["hash"] and a["target"] == "foramen_ovale_left"

        # an upload made with the old files is now another copy of the pack: refused, naming why
        status, answer, _ = call(srv, "POST", "/api/attempts", old, token, {"Idempotency-Key": "old-files"})
        assert status == 422 and "is not the server's" in answer["error"], answer
    finally:
        srv.stop()
