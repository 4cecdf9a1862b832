"""Password hashes of the records server's accounts: OWASP's scrypt cost, and older hashes upgraded."""

from __future__ import annotations

import base64
import hashlib
import secrets

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore

PASSWORD = "correct horse 42"


def old_hash(password: str) -> str:
    """A hash as earlier versions wrote it (scrypt N=2^14, below OWASP's minimum)."""
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=2**14, r=8, p=1, dklen=32)
    return f"scrypt${2**14}$8$1${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def test_new_hashes_use_owasps_scrypt_cost(tmp_path):
    with RecordStore(tmp_path / "r.sqlite3") as store:
        accounts.add_user(store, "alice", "trainee", PASSWORD, ["c1"])
        stored = store.query("SELECT password_hash FROM users")[0][0]
    kind, n, r, p, _, _ = stored.split("$")
    assert kind == "scrypt" and int(n) >= 2**17 and int(r) >= 8 and int(p) >= 1
    assert accounts.verify_password(PASSWORD, stored) and not accounts.verify_password("wrong password", stored)


def test_an_older_hash_still_signs_in_and_is_replaced(tmp_path):
    with RecordStore(tmp_path / "r.sqlite3") as store:
        accounts.add_user(store, "alice", "trainee", "another password", ["c1"])
        with store.transaction() as conn:
            conn.execute("UPDATE users SET password_hash = ?", (old_hash(PASSWORD),))
        assert accounts.check_login(store, "alice", "wrong password") is None
        assert store.query("SELECT password_hash FROM users")[0][0].startswith(f"scrypt${2**14}$")
        assert accounts.check_login(store, "alice", PASSWORD).name == "alice"
        upgraded = store.query("SELECT password_hash FROM users")[0][0]
        assert upgraded.startswith(f"scrypt${accounts.SCRYPT_N}$") and not accounts.needs_rehash(upgraded)
        assert accounts.check_login(store, "alice", PASSWORD).name == "alice"


def test_a_hash_costlier_than_the_servers_is_refused_unchecked():
    salt = base64.b64encode(b"s" * 16).decode()
    assert not accounts.verify_password(PASSWORD, f"scrypt${2**30}$8$1${salt}${salt}")
