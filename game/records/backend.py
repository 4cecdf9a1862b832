"""Where a records database lives: an SQLite file, or a PostgreSQL database named by a URL.

``RecordStore`` is written against the part of ``sqlite3.Connection`` it uses (``execute`` with
``?`` parameters, rows readable by index and by column name, ``lastrowid``, ``rowcount``,
``in_transaction``). ``PgConnection`` offers that same part over psycopg 3, so the store, its
schema and its migrations are one text for both databases (thesis 3.3.4: one place where a
class's attempts are kept, whichever machine runs it). The differences are confined here:

- parameters: ``?`` becomes ``%s`` (bound on the client, so ``? IS NULL`` needs no type);
- ``BEGIN IMMEDIATE`` (SQLite: take the write lock now) is ``BEGIN`` plus a transaction-scoped
  advisory lock, so two saves that both create a class or trainee never race;
- DDL: ``INTEGER`` is ``BIGINT`` (SQLite integers are 64-bit), ``INTEGER PRIMARY KEY`` an
  identity column, ``REAL`` ``DOUBLE PRECISION`` (SQLite reals are doubles);
- an ``INSERT`` gets ``RETURNING id`` so ``lastrowid`` works (every table has an ``id``);
- the schema version, ``PRAGMA user_version`` in SQLite, is the one row of ``chainsim_schema``.
"""

from __future__ import annotations

import re
import sqlite3
from collections.abc import Iterator, Sequence
from typing import Any, Protocol, TypeGuard
from urllib.parse import urlsplit, urlunsplit

from chainsim.game.records.migrations import OWN_TABLES, SCHEMA_VERSION
from chainsim.systems.engine.errors import UserError

PG_SCHEMES = ("postgresql", "postgres")
VERSION_TABLE = "chainsim_schema"
# pg_advisory_xact_lock key shared by every chainsim writer of one database ("chainsim" in ASCII).
WRITE_LOCK_KEY = 0x636861696E73696D
CONNECT_TIMEOUT_S = 10


class Cursor(Protocol):
    """The part of ``sqlite3.Cursor`` the store reads (``PgCursor`` is the other)."""

    @property
    def lastrowid(self) -> int | None: ...

    @property
    def rowcount(self) -> int: ...

    def fetchone(self) -> Any: ...

    def fetchall(self) -> list[Any]: ...

    def __iter__(self) -> Iterator[Any]: ...


class Connection(Protocol):
    """The part of ``sqlite3.Connection`` the store uses: ``sqlite3.Connection`` or ``PgConnection``."""

    def execute(self, sql: str, params: Sequence[Any] = ..., /) -> Cursor: ...

    @property
    def in_transaction(self) -> bool: ...

    def close(self) -> None: ...


def inserted_id(cur: Cursor) -> int:
    """The id of the row an ``INSERT`` made (both backends set ``lastrowid`` after one)."""
    rid = cur.lastrowid
    if rid is None:
        raise RuntimeError("an INSERT left no row id")
    return rid


def is_postgres(spec: object) -> TypeGuard[str]:
    """True when ``spec`` is a postgresql:// (or postgres://) URL rather than a file path."""
    return isinstance(spec, str) and spec.split("://", 1)[0].lower() in PG_SCHEMES and "://" in spec


def redact(url: str) -> str:
    """The URL without its password, for messages and logs."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    host = parts.hostname or ""
    if parts.port:
        host = f"{host}:{parts.port}"
    user = parts.username or ""
    return urlunsplit((parts.scheme, f"{user}:***@{host}", parts.path, parts.query, parts.fragment))


def db_errors() -> tuple[type[BaseException], ...]:
    """Exception classes that mean "the database refused or failed", for both backends."""
    try:
        import psycopg  # noqa: PLC0415 - optional: only a PostgreSQL store needs it
    except ImportError:
        return (sqlite3.Error,)
    return (sqlite3.Error, psycopg.Error)


def schema_version(conn: Any) -> int:
    if isinstance(conn, PgConnection):
        return conn.user_version()
    return conn.execute("PRAGMA user_version").fetchone()[0]


def set_schema_version(conn: Any, version: int) -> None:
    if isinstance(conn, PgConnection):
        conn.set_user_version(version)
    else:
        conn.execute(f"PRAGMA user_version = {int(version)}")


class Row(tuple):
    """A result row readable as ``row[0]`` and ``row["name"]``, like ``sqlite3.Row``."""

    _names: tuple[str, ...] = ()

    def __new__(cls, names: tuple[str, ...], values: Sequence[Any]) -> Row:
        row = super().__new__(cls, values)
        row._names = names
        return row

    def keys(self) -> list[str]:
        return list(self._names)

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, str):
            try:
                return tuple.__getitem__(self, self._names.index(key))
            except ValueError:
                raise IndexError(f"no column named {key!r}") from None
        return tuple.__getitem__(self, key)


def _row_factory(cursor: Any):
    names = tuple(col.name for col in cursor.description or ())
    return lambda values: Row(names, values)


_QUOTED_OR_MARK = re.compile(r"'(?:[^']|'')*'|\?|%")


def _placeholders(sql: str) -> str:
    """``?`` -> ``%s`` and ``%`` -> ``%%`` outside quoted literals."""

    def swap(m: re.Match[str]) -> str:
        tok = m.group(0)
        return "%s" if tok == "?" else "%%" if tok == "%" else tok

    return _QUOTED_OR_MARK.sub(swap, sql)


def _ddl(sql: str) -> str:
    sql = re.sub(r"\bINTEGER PRIMARY KEY\b", "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY", sql)
    sql = re.sub(r"\bINTEGER\b", "BIGINT", sql)
    return re.sub(r"\bREAL\b", "DOUBLE PRECISION", sql)


_DDL_START = re.compile(r"\s*(CREATE|ALTER|DROP)\b", re.IGNORECASE)
_INSERT_START = re.compile(r"\s*INSERT\b", re.IGNORECASE)


class PgCursor:
    """What ``PgConnection.execute`` returns: fetchone/fetchall/iteration, lastrowid, rowcount."""

    def __init__(self, cur: Any, lastrowid: int | None = None) -> None:
        self._cur = cur
        self.lastrowid = lastrowid
        self.rowcount = cur.rowcount

    def fetchone(self) -> Row | None:
        return self._cur.fetchone() if self._cur.description else None

    def fetchall(self) -> list[Row]:
        return self._cur.fetchall() if self._cur.description else []

    def __iter__(self) -> Iterator[Row]:
        return iter(self.fetchall())


class PgConnection:
    """A PostgreSQL database behind the ``sqlite3.Connection`` subset RecordStore uses."""

    def __init__(self, url: str) -> None:
        try:
            import psycopg  # noqa: PLC0415 - optional: only a PostgreSQL store needs it
        except ImportError:
            raise UserError(
                "PostgreSQL records need psycopg 3, which is not installed: pip install 'chainsim[server]'; "
                "or use an SQLite file"
            ) from None
        self._psycopg = psycopg
        self.url = url
        try:
            # autocommit: the store issues BEGIN/COMMIT itself, exactly as it does on SQLite.
            # ClientCursor binds on the client, as sqlite3 does, so untyped NULL parameters work.
            self._conn = psycopg.connect(
                url,
                autocommit=True,
                cursor_factory=psycopg.ClientCursor,
                row_factory=_row_factory,
                connect_timeout=CONNECT_TIMEOUT_S,
            )
        except psycopg.Error as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UserError(f"cannot connect to records database {redact(url)}: {first}") from None
        try:
            self._prepare()
        except BaseException:
            self._conn.close()
            raise

    def _prepare(self) -> None:
        """Create the version table in an empty database; refuse a database of something else."""
        self.execute("BEGIN IMMEDIATE")
        try:
            tables = {
                r[0]
                for r in self.execute(
                    "SELECT table_name FROM information_schema.tables WHERE table_schema = current_schema()"
                )
            }
            if VERSION_TABLE not in tables:
                foreign = tables - OWN_TABLES
                if foreign:
                    raise UserError(
                        f"PostgreSQL database {redact(self.url)} holds other tables ({sorted(foreign)[0]!r}); "
                        "expected an empty database or a chainsim records database"
                    )
                cur = self._conn.cursor()
                cur.execute(f"CREATE TABLE {VERSION_TABLE} (version BIGINT NOT NULL)")
                cur.execute(f"INSERT INTO {VERSION_TABLE} (version) VALUES (0)")
            version = self.user_version()
            if version > SCHEMA_VERSION:
                raise UserError(
                    f"records database {redact(self.url)} has schema version {version}; "
                    f"this chainsim reads up to {SCHEMA_VERSION}"
                )
            self.execute("COMMIT")
        except BaseException:
            self.execute("ROLLBACK")
            raise

    # -- the sqlite3.Connection subset ----------------------------------------------------

    def execute(self, sql: str, params: Sequence[Any] = ()) -> PgCursor:
        cur = self._conn.cursor()
        if sql.strip().upper() == "BEGIN IMMEDIATE":
            cur.execute("BEGIN")
            cur.execute("SELECT pg_advisory_xact_lock(%s)", (WRITE_LOCK_KEY,))
            return PgCursor(cur)
        if _DDL_START.match(sql):
            sql = _ddl(sql)
        returning = bool(_INSERT_START.match(sql)) and "RETURNING" not in sql.upper()
        if returning:
            sql = sql.rstrip().rstrip(";") + " RETURNING id"
        cur.execute(_placeholders(sql), tuple(params))
        if returning:
            row = cur.fetchone()
            return PgCursor(cur, None if row is None else row[0])
        return PgCursor(cur)

    @property
    def in_transaction(self) -> bool:
        return self._conn.info.transaction_status != self._psycopg.pq.TransactionStatus.IDLE

    def close(self) -> None:
        self._conn.close()

    def user_version(self) -> int:
        row = self.execute(f"SELECT version FROM {VERSION_TABLE}").fetchone()
        return 0 if row is None else int(row[0])

    def set_user_version(self, version: int) -> None:
        self.execute(f"UPDATE {VERSION_TABLE} SET version = ?", (int(version),))
