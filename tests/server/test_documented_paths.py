"""The paths the documentation shows, run as a user runs them against a real `chainsim serve`.

docs/records-server.md: sign in with `chainsim records login`, then `chainsim run PACK --headless
--input SCRIPT --records URL` saves the scripted attempt (the built-in scripts end with Save attempt).
A script of mouse events only is in the window's form: the server stores the figures its replay of
the recording computes. A script that picks
points and presses widgets (the cutting trainer's) is refused in one line.
"""

from __future__ import annotations

import os
import subprocess
import sys

from conftest import PASSWORD, REPO, call, wait_scored

from chainsim.game.records.store import RecordStore


def chainsim(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess:
    """The command line as a user runs it, in a process of its own."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(
        [sys.executable, "-m", "chainsim.game", *args],
        capture_output=True,
        text=True,
        env=env,
        input=stdin,
        timeout=300,
    )


def run_and_score(site, tmp_path, pack: str, script: str, scored: bool = True) -> dict:
    """Sign in as alice, run `chainsim run PACK --headless --input SCRIPT --records URL` as documented,
    and return the attempt the server stored once its replay scored the upload (the upload's state when
    ``scored`` is false)."""
    local = str(tmp_path / "local.sqlite3")
    r = chainsim("records", "--db", local, "login", site.url, "alice", "--password-stdin", stdin=PASSWORD + "\n")
    assert r.returncode == 0, r.stderr
    r = chainsim("run", pack, "--headless", "--input", script, "--records", site.url, "--db", local)
    assert r.returncode == 0, r.stderr
    with RecordStore(local) as store:
        sent = store.query("SELECT remote_id FROM outbox")
    assert len(sent) == 1, sent  # the script's Save made one upload, sent at once
    # the run says where the attempt went, under the signed-in account
    said = f"attempt sent to {site.url} as upload {sent[0][0]} (alice, class c1): the server scores it by replaying"
    assert [line.strip() for line in r.stdout.splitlines() if "attempt sent" in line] == [f"{said} the session"]
    token = site.tokens["alice"]
    result = wait_scored(site, sent[0][0], token)
    if not scored:
        return result
    assert result["status"] == "scored", result
    status, stored, _ = call(site, "GET", f"/api/attempts/{result['attempt_id']}", token=token)
    assert status == 200, stored
    return stored


def test_the_documented_needle_run_saves_an_attempt_the_server_scores(site, tmp_path):
    stored = run_and_score(site, tmp_path, "prp", str(REPO / "assets" / "prp" / "scripts" / "correct-mouse.toml"))
    assert stored["pack"] == "prp" and stored["trainee"] == "alice" and stored["filed_by"] == "alice"
    assert stored["target"] == "foramen_ovale_left" and stored["needle_error_mm"] < 1.0
    assert stored["differences"] == []  # the replay computed what the simulator showed
    # at the edge of a person's pace (six aimed clicks in a second), not beyond it
    assert stored["source"] == "replayed" and stored["flags"] == []


def test_a_scripted_attempt_that_picks_and_presses_widgets_is_refused_in_one_line(site, tmp_path):
    result = run_and_score(
        site, tmp_path, "cutting", str(REPO / "assets" / "cutting" / "scripts" / "cut-and-open.toml"), scored=False
    )
    assert result["status"] == "refused", result
    assert "event, which the window never records" in result["error"] and "\n" not in result["error"]
