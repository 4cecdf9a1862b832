"""Password guesses are throttled per account and per address, on a server of its own (SQLite and PostgreSQL).

An attacker's 100 wrong passwords, then the right one, from one address: the right one is not let in
(429 with Retry-After), the guesses are answered without hashing a password, and the real user from
another address signs in once the account's short wait is over. The dashboard's form is throttled
the same way.
"""

from __future__ import annotations

import time

from conftest import PASSWORD, call, populate, start_server

from chainsim.game.server.throttle import ACCOUNT_FREE, ACCOUNT_MAX_WAIT_S, ADDRESS_FREE

ATTACKER, TRAINEE = "127.0.0.1", "127.0.0.2"


def test_password_guesses_are_throttled_without_locking_the_user_out(records_db, tmp_path):
    populate(records_db)
    server = start_server(records_db, tmp_path / "serve.log")
    try:
        answers = [
            call(server, "POST", "/api/login", {"name": "alice", "password": f"guess {i:03d}"}, source=ATTACKER)
            for i in range(100)
        ]
        statuses = [a[0] for a in answers]
        assert set(statuses) == {401, 429}
        assert statuses[:ACCOUNT_FREE] == [401] * ACCOUNT_FREE  # a few mistakes are free
        assert statuses.count(401) < 20  # most guesses were never checked
        throttled = next(a for a in answers if a[0] == 429)
        assert "too many failed sign-ins" in throttled[1]["error"] and int(throttled[2]["Retry-After"]) >= 1
        # the right password from the guessing address does not get in now
        status, answer, hdrs = call(
            server, "POST", "/api/login", {"name": "alice", "password": PASSWORD}, source=ATTACKER
        )
        assert status == 429 and "token" not in answer
        # the dashboard's sign-in form is throttled for that account too
        status, page, hdrs = call(server, "GET", "/login", source=ATTACKER)
        csrf = page.split('name="csrf" value="')[1].split('"')[0]
        cookie = hdrs["set-cookie"].split(";")[0]
        form = f"name=alice&password=nope-nope-nope&csrf={csrf}".encode()
        status, page, hdrs = call(
            server,
            "POST",
            "/login",
            raw=form,
            headers={"Content-Type": "application/x-www-form-urlencoded", "Cookie": cookie, "Origin": server.url},
            source=ATTACKER,
        )
        assert status == 429 and "Retry-After" in hdrs
        # the real user, elsewhere, waits at most the account's cap and then signs in
        status, answer, hdrs = call(
            server, "POST", "/api/login", {"name": "alice", "password": PASSWORD}, source=TRAINEE
        )
        if status == 429:
            wait = int(hdrs["Retry-After"])
            assert wait <= ACCOUNT_MAX_WAIT_S
            time.sleep(wait)
            status, answer, _ = call(
                server, "POST", "/api/login", {"name": "alice", "password": PASSWORD}, source=TRAINEE
            )
        assert status == 201 and answer["user"]["name"] == "alice"
        # another account from the trainee's address is not slowed by the attack on alice
        status, _, _ = call(server, "POST", "/api/login", {"name": "bob", "password": PASSWORD}, source=TRAINEE)
        assert status == 201
        assert server.alive()
    finally:
        server.stop()


# -- whose address a failure counts against -------------------------------------------------------


def forged_guesses(server, forwarded_for, count: int) -> list[int]:
    """``count`` wrong sign-ins from 127.0.0.1, each as a different made-up account (no account's own
    wait applies) and each with ``X-Forwarded-For: forwarded_for(i)``; their statuses."""
    return [
        call(
            server,
            "POST",
            "/api/login",
            {"name": f"nobody{i:03d}", "password": "a wrong password"},
            headers={"X-Forwarded-For": forwarded_for(i)},
            source=ATTACKER,
        )[0]
        for i in range(count)
    ]


def test_a_forged_forwarded_for_does_not_escape_the_address_count(tmp_path):
    """Without --trust-proxy the client is the connection's address: a guesser who writes a new
    X-Forwarded-For on every try is still slowed as 127.0.0.1 (the throttle lives in the server
    process, not the database: checked on SQLite)."""
    db = str(tmp_path / "forged.sqlite3")
    populate(db)
    server = start_server(db, tmp_path / "serve.log")
    try:
        statuses = forged_guesses(server, lambda i: f"10.{i // 250}.{i % 250}.7", ADDRESS_FREE + 2)
        assert statuses[:ADDRESS_FREE] == [401] * ADDRESS_FREE
        assert statuses[-1] == 429  # the address's 21st failure made it wait
    finally:
        server.stop()


def test_a_trusted_proxy_names_the_client(tmp_path):
    """With --trust-proxy 127.0.0.1 (the proxy's address) the client is the one the proxy forwards for:
    one client's failures slow that client, not another client behind the same proxy."""
    db = str(tmp_path / "proxied.sqlite3")
    populate(db)
    server = start_server(db, tmp_path / "serve.log", args=("--trust-proxy", "127.0.0.1"))
    try:
        statuses = forged_guesses(server, lambda i: "192.0.2.10", ADDRESS_FREE + 2)
        assert statuses[-1] == 429
        assert forged_guesses(server, lambda i: "192.0.2.11", 1) == [401]  # another client: counted apart
    finally:
        server.stop()


def test_trust_proxy_takes_an_address_only(cli):
    code, _, err = cli("serve", "--trust-proxy", "proxy.example.org")
    assert code == 2 and "Traceback" not in err
    assert "--trust-proxy: expected the proxy's IP address (such as 127.0.0.1) or network" in err
    assert "got 'proxy.example.org'" in err
