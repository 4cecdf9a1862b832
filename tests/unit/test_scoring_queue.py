"""The scoring queue on a real records database: trainees in turn, claims counted, cancels audited.

A trainee who floods the queue delays another trainee's upload by at most one replay; an upload
claimed twice without finishing is refused rather than tried for ever; a renewed claim is never
taken over while one that lapsed is; a cancelled upload stops its replay's claim at once; and
`chainsim records uploads` lists, cancels and refuses uploads in one line each, audited.
"""

from __future__ import annotations

import time

import pytest

from chainsim.game.cli.main import main
from chainsim.game.records.store import RecordStore
from chainsim.game.server import scoring

CHECKED = {
    "claimed": {"pack": "prp"},
    "recording": "eJw=",
    "identity": {"name": "prp", "version": "0.1.0", "hash": "0" * 64},
}


def queue(store: RecordStore, trainee: str, n: int = 1, cls: str = "c1") -> list[int]:
    return [scoring.enqueue(store, trainee, cls, trainee, CHECKED, None, "h")[0]["id"] for _ in range(n)]


def finish_refused(store: RecordStore, upload: dict, worker: str) -> None:
    scoring.finish(store, upload, worker, None, "test: done")


@pytest.fixture
def store(tmp_path):
    with RecordStore(str(tmp_path / "q.sqlite3")) as s:
        yield s


def test_one_trainees_flood_delays_anothers_upload_by_one_replay(store):
    flood = queue(store, "alice", 100)
    later = queue(store, "bob")[0]
    first = scoring.claim(store, "h|1|a|0", 300)
    assert first["id"] == flood[0]
    second = scoring.claim(store, "h|1|a|1", 300)  # the other scorer: bob has not been served yet
    assert second["id"] == later
    # with both served, turns alternate by who was served longest ago; each trainee's order is kept
    finish_refused(store, first, "h|1|a|0")
    finish_refused(store, second, "h|1|a|1")
    carol = queue(store, "carol")[0]
    order = []
    for _ in range(3):
        got = scoring.claim(store, "h|1|a|0", 300)
        order.append((got["trainee"], got["id"]))
        finish_refused(store, got, "h|1|a|0")
    assert order[0] == ("carol", carol) and order[1] == ("alice", flood[1]) and order[2] == ("alice", flood[2])


def test_an_upload_claimed_twice_without_finishing_is_refused(store):
    (uid,) = queue(store, "alice")
    assert scoring.claim(store, "h|1|a|0", 0.0)["id"] == uid  # lease 0: the claim lapses at once
    time.sleep(0.01)
    assert scoring.claim(store, "h|1|a|1", 0.0)["id"] == uid  # taken over once
    time.sleep(0.01)
    assert scoring.claim(store, "h|1|a|2", 0.0) is None
    row = scoring.get_upload(store, uid)
    assert row["state"] == "refused" and "started 2 times and never finished" in row["error"]
    assert any("scoring never finished" in a["detail"] for a in store.audit_entries(["c1"]))


def test_a_renewed_claim_is_kept_and_a_cancelled_one_lets_go(store):
    (uid,) = queue(store, "alice")
    up = scoring.claim(store, "h|1|a|0", 300)
    assert scoring.renew(store, uid, "h|1|a|0")
    assert scoring.claim(store, "h|1|a|1", 300) is None  # live: not taken over
    assert not scoring.renew(store, uid, "h|1|a|1")  # not the other worker's to renew
    scoring.end_upload(store, uid, "administrator x", "cancel", "sent twice")
    assert not scoring.renew(store, uid, "h|1|a|0")  # the replay stops at its next renewal
    assert scoring.finish(store, up, "h|1|a|0", None, "late") is None
    assert scoring.get_upload(store, uid)["error"] == "cancelled by administrator x: sent twice"


def test_records_uploads_lists_cancels_and_refuses_in_one_line_each(store, capsys):
    ids = queue(store, "alice", 2)
    db = str(store.path)
    assert main(["records", "--db", db, "uploads"]) == 0
    listing = capsys.readouterr().out
    assert all(f"{i} " in listing for i in ids) and "window" in listing
    assert main(["records", "--db", db, "uploads", "cancel", str(ids[0]), "--reason", "sent twice"]) == 0
    assert main(["records", "--db", db, "uploads", "refuse", str(ids[1]), "--reason", "not hers"]) == 0
    capsys.readouterr()
    assert main(["records", "--db", db, "uploads", "refuse", str(ids[1]), "--reason", "again"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already refused" in err[0]
    assert main(["records", "--db", db, "uploads", "cancel", "99999", "--reason", "x"]) == 2
    assert "no upload with id 99999" in capsys.readouterr().err
    assert main(["records", "--db", db, "uploads", "cancel", "abc", "--reason", "x"]) == 2
    actions = [(a["action"], a["detail"]) for a in store.audit_entries(["c1"])]
    assert ("cancel", f"upload {ids[0]}: sent twice") in actions and ("refuse", f"upload {ids[1]}: not hers") in actions
    assert main(["records", "--db", db, "uploads", "--state", "refused"]) == 0
    assert "cancelled by administrator" in capsys.readouterr().out


def test_a_class_that_requires_witnessed_attempts_refuses_window_uploads(store, capsys):
    assert main(["records", "--db", str(store.path), "witnessed", "c1"]) == 0
    with pytest.raises(Exception, match="takes only attempts made in the browser trainer"):
        queue(store, "alice")
    row, created = scoring.enqueue(store, "alice", "c1", "alice", CHECKED, None, "h", witnessed=True)
    assert created and row["witnessed"] == 1
    assert main(["records", "--db", str(store.path), "witnessed", "c1", "--off"]) == 0
    queue(store, "alice")


def test_a_recording_longer_than_the_server_replays_is_refused_before_any_step():
    from chainsim.game.packs import pack as packs
    from chainsim.game.records import provenance
    from chainsim.systems.engine.errors import UserError

    root, _ = packs.resolve("prp", [])
    rec = {
        "chainsim": "recording",
        "format": 1,
        "pack": "prp",
        "scene": "trainer",
        "dt": 1.0 / 120.0,
        "steps": 1_000_000,
        "settings": {},
        "digest": "0" * 64,
        "event": [{"t": 0.5, "kind": "key", "key": "i", "pressed": True}],
    }
    told = []
    with pytest.raises(UserError, match="a 138.9-minute session; this server replays sessions of up to 45 minutes"):
        scoring.replay_record(provenance.encode_recording(rec), str(root), [], {}, report=told.append)
    assert told == []  # refused before the replay's budget was even set
    rec["event"].append({"t": 1.0, "kind": "pick", "entity": "skin", "point": [0, 0, 0]})
    with pytest.raises(UserError, match="a 'pick' event, which the window never records"):
        scoring.replay_record(provenance.encode_recording(rec), str(root), [], {"max_session_s": 1e9})


def test_upload_rate_allows_a_burst_then_the_rate_per_account():
    from chainsim.game.server.auth import HTTPError
    from chainsim.game.server.upload_limit import UploadRate

    now = [0.0]
    rate = UploadRate(per_minute=6, burst=20, clock=lambda: now[0])
    for _ in range(20):
        rate.take(1)
    with pytest.raises(HTTPError) as refused:
        rate.take(1)
    assert refused.value.status == 429 and refused.value.headers["Retry-After"] == "10"
    rate.take(2)  # another account is not held up
    now[0] += 10.0  # one upload's worth of time
    rate.take(1)
    with pytest.raises(HTTPError):
        rate.take(1)
