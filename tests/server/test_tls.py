"""A records server with a certificate of its own: the simulator signs in with ``--cafile`` and keeps trusting it.

The programme's authority signs the server's certificate (both made here with openssl). Without
``--cafile`` the sign-in is refused with one line that says how to trust the server; with it the
sign-in works, the authority is kept with the token, and a later ``records sync`` sends a queued
attempt over TLS without being told again. A missing file, a file that is no certificate and an
http address each get one line and exit 2.
"""

from __future__ import annotations

import io
import shutil
import subprocess
import sys

import pytest
from conftest import PASSWORD, populate, start_server, upload, wait_scored

from chainsim.game.records import remote
from chainsim.game.records.store import RecordStore


def openssl(*args: str, cwd) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture(scope="module")
def certificates(tmp_path_factory):
    """``ca.pem`` (the programme's authority) and ``server.pem``/``server.key`` for 127.0.0.1, signed by it."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed")
    d = tmp_path_factory.mktemp("tls")
    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=Programme CA",
            "-keyout", "ca.key", "-out", "ca.pem", cwd=d)  # fmt: skip
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1",
            "-keyout", "server.key", "-out", "server.csr", cwd=d)  # fmt: skip
    (d / "san.ext").write_text("subjectAltName = IP:127.0.0.1\n")
    openssl("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-days", "2", "-extfile", "san.ext", "-out", "server.pem", cwd=d)  # fmt: skip
    return d


def login(cli, monkeypatch, local, url, *extra):
    """(exit code, stdout, stderr) of ``records login``; stderr without the note of a new local database."""
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\n"))
    code, out, err = cli("records", "--db", local, "login", url, "alice", "--password-stdin", *extra)
    return code, out, "".join(line for line in err.splitlines(True) if "created a new records database" not in line)


@pytest.mark.slow
def test_sign_in_with_cafile_is_kept_for_later_syncs(records_db, tmp_path, certificates, cli, monkeypatch):
    populate(records_db)
    tls = ("--certfile", str(certificates / "server.pem"), "--keyfile", str(certificates / "server.key"))
    server = start_server(records_db, tmp_path / "serve.log", args=tls)
    local = str(tmp_path / "local.sqlite3")
    try:
        code, _, err = login(cli, monkeypatch, local, server.url)
        assert code == 2 and "not trusted" in err and "--cafile" in err and len(err.strip().splitlines()) == 1, err

        code, _, err = login(cli, monkeypatch, local, server.url, "--cafile", str(certificates / "ca.pem"))
        assert code == 0 and "signed in" in err, err
        with RecordStore(local) as store:
            kept = store.query("SELECT ca_pem FROM server_logins WHERE server = ?", (server.url,))[0][0]
            assert kept == (certificates / "ca.pem").read_text()
            body = upload()
            evidence = {"recording": body.pop("recording"), "pack_identity": body.pop("pack_identity")}
            remote.enqueue(store, server.url, "c1", "alice", body, evidence)

        # a later sync trusts the kept authority without being told again
        code, out, err = cli("records", "--db", local, "sync")
        assert code == 0 and "sent 1 attempt(s); 0 waiting" in out, (out, err)
        with RecordStore(local) as store:
            upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
            token = remote.token_for(store, server.url)
        assert wait_scored(server, upload_id, token)["status"] == "scored"
    finally:
        server.stop()


def test_bad_cafile_is_one_line(tmp_path, certificates, cli, monkeypatch):
    local = str(tmp_path / "local.sqlite3")
    notes = tmp_path / "notes.txt"
    notes.write_text("not a certificate\n")
    cases = [
        ("https://127.0.0.1:9", str(tmp_path / "missing.pem"), "no such file"),
        ("https://127.0.0.1:9", str(notes), "holds no PEM certificate"),
        ("https://127.0.0.1:9", str(tmp_path), "is a folder"),
        ("http://127.0.0.1:9", str(certificates / "ca.pem"), "is for an https:// server"),
    ]
    for url, cafile, message in cases:
        code, _, err = login(cli, monkeypatch, local, url, "--cafile", cafile)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
