"""Accounts of the records server: trainers and trainees, passwords, web sessions and API tokens.

The thesis tool (3.3.4, Fig. 3.11) files attempts under a class and a name and lets the trainer
review them; on a shared server that needs to know who is asking. A trainee account is one
trainee of one class (it sees and deletes only its own attempts); a trainer account teaches one
or more classes (it sees those classes' trainees and attempts).

Secrets: passwords are hashed with scrypt (hashlib, a memory-hard KDF) and a random salt. Web
session ids and API tokens are 256-bit random values; only their SHA-256 is stored, so a copy of
the database does not let anyone sign in. Everything lives in the records database (schema
version 3, ``chainsim.game.records.migrations``), on SQLite or PostgreSQL alike.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from chainsim.game.records.backend import inserted_id
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_name
from chainsim.systems.engine.errors import UserError

ROLES = ("trainer", "trainee")
PASSWORD_MIN, PASSWORD_MAX = 8, 1024
# scrypt cost: OWASP's Password Storage Cheat Sheet minimum (N=2^17, r=8, p=1): 128 MiB and a few
# tenths of a second per check on one core. hashlib's scrypt (OpenSSL) is the kept library; a hash of
# a lower cost (earlier versions used N=2^14) still verifies and is replaced at the next sign-in.
SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**17, 8, 1
SCRYPT_MAXMEM = 256 << 20  # hashlib refuses anything over 32 MiB unless told
# hashes computed at once: each holds 128 MiB, so a burst of sign-ins queues instead of exhausting memory
_HASHING = threading.BoundedSemaphore(2)
SESSION_TTL_S = 12 * 3600
TOKEN_TTL_S = 180 * 24 * 3600
TOKEN_PREFIX = "cst_"


@dataclass(frozen=True)
class User:
    """Who is asking: the account, its role and what it may see."""

    id: int
    name: str
    role: str
    classes: tuple[str, ...] = ()  # a trainer's classes; a trainee's one class
    trainee_id: int | None = None
    trainee: str | None = None  # a trainee account's name in the records
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def is_trainer(self) -> bool:
        return self.role == "trainer"

    def can_see(self, class_name: str, trainee: str) -> bool:
        """May this account read (and delete) an attempt filed under ``class_name``/``trainee``?"""
        if self.is_trainer:
            return class_name in self.classes
        return self.trainee_id is not None and (class_name, trainee) == (self.classes[0], self.trainee)

    def public(self) -> dict[str, Any]:
        return {"name": self.name, "role": self.role, "classes": list(self.classes), "trainee": self.trainee}


# -- passwords --------------------------------------------------------------------------------


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def check_password_rules(password: Any) -> str:
    if not isinstance(password, str):
        raise UserError("password must be text")
    if len(password) < PASSWORD_MIN:
        raise UserError(f"password is {len(password)} characters; at least {PASSWORD_MIN} needed")
    if len(password) > PASSWORD_MAX:
        raise UserError(f"password is {len(password)} characters; at most {PASSWORD_MAX} allowed")
    return password


def hash_password(password: str) -> str:
    """``scrypt$N$r$p$salt$hash`` (base64) for a password that passed ``check_password_rules``."""
    salt = secrets.token_bytes(16)
    with _HASHING:
        digest = hashlib.scrypt(
            password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, maxmem=SCRYPT_MAXMEM, dklen=32
        )
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, stored: str) -> bool:
    try:
        kind, n, r, p, salt, digest = stored.split("$")
        if kind != "scrypt":
            return False
        want = base64.b64decode(digest)
        if int(n) > SCRYPT_N or int(r) > SCRYPT_R or int(p) > SCRYPT_P:
            return False  # not a hash this server wrote: never spend more than its own cost on one
        with _HASHING:
            got = hashlib.scrypt(
                password.encode(),
                salt=base64.b64decode(salt),
                n=int(n),
                r=int(r),
                p=int(p),
                maxmem=SCRYPT_MAXMEM,
                dklen=len(want),
            )
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, want)


def needs_rehash(stored: str) -> bool:
    """True for a hash made at a lower cost than the current one (replaced at the next sign-in)."""
    parts = stored.split("$")
    return len(parts) != 6 or parts[0] != "scrypt" or parts[1:4] != [str(SCRYPT_N), str(SCRYPT_R), str(SCRYPT_P)]


@functools.cache
def _dummy_hash() -> str:
    """Checked against when the name is unknown, so a wrong name costs as long as a wrong password.
    Made at the first unknown name, not at import: every process that imports this module (the
    server, each command line) would otherwise pay a full hash before doing anything."""
    return hash_password("not a real password")


def _secret_hash(secret: str) -> str:
    return hashlib.sha256(secret.encode()).hexdigest()


# -- accounts ---------------------------------------------------------------------------------


def add_user(store: RecordStore, name: str, role: str, password: str, classes: list[str]) -> User:
    """Create an account. A trainee needs exactly one class (its trainee row is made or reused);
    a trainer teaches one or more classes (made if missing)."""
    name = clean_name("user", name)
    if role not in ROLES:
        raise UserError(f"role {role!r} is not one of {', '.join(ROLES)}")
    classes = list(dict.fromkeys(clean_name("class", c) for c in classes))
    if role == "trainee" and len(classes) != 1:
        raise UserError(f"a trainee belongs to exactly one class; got {len(classes)} (--class C)")
    if role == "trainer" and not classes:
        raise UserError("a trainer teaches at least one class (--class C, repeatable)")
    pw_hash = hash_password(check_password_rules(password))
    now = datetime.now(UTC).isoformat(timespec="seconds")
    with store.transaction() as conn:
        if conn.execute("SELECT 1 FROM users WHERE name = ?", (name,)).fetchone():
            raise UserError(f"user {name!r} already exists")
        class_ids = []
        for c in classes:
            row = conn.execute("SELECT id FROM classes WHERE name = ?", (c,)).fetchone()
            class_ids.append(row[0] if row else conn.execute("INSERT INTO classes (name) VALUES (?)", (c,)).lastrowid)
        trainee_id = None
        if role == "trainee":
            row = conn.execute(
                "SELECT id FROM trainees WHERE class_id = ? AND name = ?", (class_ids[0], name)
            ).fetchone()
            if row is not None:
                trainee_id = row[0]
                if conn.execute("SELECT 1 FROM users WHERE trainee_id = ?", (trainee_id,)).fetchone():
                    raise UserError(f"trainee {name!r} of class {classes[0]!r} already has an account")
            else:
                trainee_id = conn.execute(
                    "INSERT INTO trainees (class_id, name) VALUES (?, ?)", (class_ids[0], name)
                ).lastrowid
        user_id = inserted_id(
            conn.execute(
                "INSERT INTO users (name, role, password_hash, trainee_id, created_at) VALUES (?, ?, ?, ?, ?)",
                (name, role, pw_hash, trainee_id, now),
            )
        )
        if role == "trainer":
            for cid in class_ids:
                conn.execute("INSERT INTO trainer_classes (user_id, class_id) VALUES (?, ?)", (user_id, cid))
    user = load_user(store, user_id)
    assert user is not None  # the account was made just now
    return user


def remove_user(store: RecordStore, name: str) -> None:
    """Delete an account with its sessions and tokens; its attempts stay in the records."""
    name = clean_name("user", name)
    with store.transaction() as conn:
        if conn.execute("DELETE FROM users WHERE name = ?", (name,)).rowcount == 0:
            raise UserError(f"no user named {name!r}")


def set_password(store: RecordStore, name: str, password: str) -> None:
    """New password; every session and token of the account is revoked."""
    name = clean_name("user", name)
    pw_hash = hash_password(check_password_rules(password))
    with store.transaction() as conn:
        row = conn.execute("SELECT id FROM users WHERE name = ?", (name,)).fetchone()
        if row is None:
            raise UserError(f"no user named {name!r}")
        conn.execute("UPDATE users SET password_hash = ? WHERE id = ?", (pw_hash, row[0]))
        conn.execute("DELETE FROM web_sessions WHERE user_id = ?", (row[0],))
        conn.execute("DELETE FROM api_tokens WHERE user_id = ?", (row[0],))


def load_user(store: RecordStore, user_id: int) -> User | None:
    rows = store.query(
        """
        SELECT u.id, u.name, u.role, u.trainee_id, t.name AS trainee, c.name AS class_name
        FROM users u LEFT JOIN trainees t ON t.id = u.trainee_id LEFT JOIN classes c ON c.id = t.class_id
        WHERE u.id = ?
        """,
        (user_id,),
    )
    if not rows:
        return None
    r = rows[0]
    if r["role"] == "trainer":
        classes = tuple(
            x[0]
            for x in store.query(
                "SELECT c.name FROM trainer_classes tc JOIN classes c ON c.id = tc.class_id "
                "WHERE tc.user_id = ? ORDER BY c.name",
                (user_id,),
            )
        )
        return User(r["id"], r["name"], "trainer", classes)
    if r["trainee_id"] is None:  # its trainee row was deleted: the account sees nothing
        return User(r["id"], r["name"], "trainee", ())
    return User(r["id"], r["name"], "trainee", (r["class_name"],), r["trainee_id"], r["trainee"])


def list_users(store: RecordStore) -> list[User]:
    users = (load_user(store, r[0]) for r in store.query("SELECT id FROM users ORDER BY role, name"))
    return [u for u in users if u is not None]  # an account removed meanwhile is not listed


def check_login(store: RecordStore, name: Any, password: Any) -> User | None:
    """The account if ``password`` is right for ``name``, else None (same cost either way)."""
    if not isinstance(name, str) or not isinstance(password, str) or len(password) > PASSWORD_MAX:
        return None
    rows = store.query("SELECT id, password_hash FROM users WHERE name = ?", (name.strip(),)) if name.strip() else []
    if not rows:
        verify_password(password, _dummy_hash())
        return None
    if not verify_password(password, rows[0]["password_hash"]):
        return None
    if needs_rehash(rows[0]["password_hash"]):
        with store.transaction() as conn:
            conn.execute("UPDATE users SET password_hash = ? WHERE id = ?", (hash_password(password), rows[0]["id"]))
    return load_user(store, rows[0]["id"])


# -- API tokens -------------------------------------------------------------------------------


def issue_token(store: RecordStore, user: User, label: str = "api", ttl_s: float = TOKEN_TTL_S) -> tuple[str, float]:
    """A new API token for ``user``: (the token, shown once; its expiry in Unix seconds)."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    now = time.time()
    label = clean_name("token label", label)
    with store.transaction() as conn:
        conn.execute(
            "INSERT INTO api_tokens (user_id, token_hash, label, created_at, expires_at) VALUES (?, ?, ?, ?, ?)",
            (user.id, _secret_hash(token), label, now, now + ttl_s),
        )
    return token, now + ttl_s


def user_for_token(store: RecordStore, token: Any) -> User | None:
    if not isinstance(token, str) or not token.startswith(TOKEN_PREFIX) or len(token) > 128:
        return None
    rows = store.query(
        "SELECT user_id FROM api_tokens WHERE token_hash = ? AND expires_at > ?", (_secret_hash(token), time.time())
    )
    return load_user(store, rows[0][0]) if rows else None


def revoke_token(store: RecordStore, token: str) -> None:
    with store.transaction() as conn:
        conn.execute("DELETE FROM api_tokens WHERE token_hash = ?", (_secret_hash(token),))


# -- web sessions -----------------------------------------------------------------------------


def start_session(store: RecordStore, user: User, ttl_s: float = SESSION_TTL_S) -> tuple[str, str]:
    """(session id for the cookie, CSRF token for the session's forms)."""
    sid, csrf = secrets.token_urlsafe(32), secrets.token_urlsafe(32)
    now = time.time()
    with store.transaction() as conn:
        # Expired sessions are dropped here rather than by a timer: the table stays small.
        conn.execute("DELETE FROM web_sessions WHERE expires_at <= ?", (now,))
        conn.execute(
            "INSERT INTO web_sessions (user_id, session_hash, csrf, created_at, expires_at) VALUES (?, ?, ?, ?, ?)",
            (user.id, _secret_hash(sid), csrf, now, now + ttl_s),
        )
    return sid, csrf


def session_user(store: RecordStore, sid: Any) -> tuple[User, str] | None:
    """(account, CSRF token) of a live session, or None."""
    if not isinstance(sid, str) or not sid or len(sid) > 128:
        return None
    rows = store.query(
        "SELECT user_id, csrf FROM web_sessions WHERE session_hash = ? AND expires_at > ?",
        (_secret_hash(sid), time.time()),
    )
    if not rows:
        return None
    user = load_user(store, rows[0]["user_id"])
    return None if user is None else (user, rows[0]["csrf"])


def end_session(store: RecordStore, sid: str) -> None:
    with store.transaction() as conn:
        conn.execute("DELETE FROM web_sessions WHERE session_hash = ?", (_secret_hash(sid),))
