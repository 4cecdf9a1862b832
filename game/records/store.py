"""Trainee records: the SQLite store behind the assessment tool of thesis 3.3.4 (Fig. 3.11).

The thesis tool files each attempt under a class and a user name, then lets the trainer view or
delete it later; the numbers kept are the 6.1.5 metrics. ``RecordStore`` is that store:

    with RecordStore() as store:                       # default file, or $CHAINSIM_DB
        store.save_attempt("c1", "alice", {...})       # class and trainee made on first save
        for row in store.list_attempts("c1", "alice"): ...

Names: classes and trainees are created on demand by ``save_attempt`` (the Save button takes
whatever class and user name are typed) and ``add_trainee`` creates its class when missing;
``add_class``/``add_trainee`` refuse a name that already exists, so a typo is noticed.

Safety: the database runs in WAL mode with ``synchronous=FULL`` and every write is a single
``BEGIN IMMEDIATE ... COMMIT``, so killing the process mid-save loses at most the attempt being
saved and never leaves part of one. A file that is not a records database is refused with one
line before anything is written to it: another program's SQLite file (any table, view, index or
trigger that is not ours) is never written into. A new database file is made by the first write,
not by opening (a command that fails first leaves nothing; reads until then see an empty store),
only in a folder that exists (the default location's folder excepted), and with a warning naming
the file, so a mistyped path is noticed; ``create=False`` refuses a path with no database at all.
Schema and migrations: ``chainsim.game.records.migrations``.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import platformdirs

from chainsim.components.resources import Records
from chainsim.game.records.backend import (
    Connection,
    PgConnection,
    db_errors,
    inserted_id,
    is_postgres,
    redact,
    schema_version,
    set_schema_version,
)
from chainsim.game.records.migrations import MIGRATIONS, OWN_TABLES, SCHEMA_VERSION
from chainsim.game.records.validate import (
    clean_attempt,
    clean_created_at,
    clean_key,
    clean_name,
    clean_questionnaire,
    to_json,
)
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import RECORDS_PROCEDURE, procedure_for
from chainsim.systems.procedures.procedure import AttemptLayout, Column

ENV_VAR = "CHAINSIM_DB"
DB_FILENAME = "records.sqlite3"
SQLITE_MAGIC = b"SQLite format 3\x00"
BUSY_TIMEOUT_MS = 5000
logger = logging.getLogger(__name__)


class NoDatabase(UserError):
    """Reading (``create=False``) a records database that does not exist: nothing was ever saved there."""


class WriteFailed(UserError):
    """The database refused a write (locked, gone, full); nothing changed and it may be retried."""


def default_path() -> Path:
    """$CHAINSIM_DB when set, else <user data dir>/chainsim/records.sqlite3."""
    env = os.environ.get(ENV_VAR, "").strip()
    if env:
        return Path(env).expanduser()

    return Path(platformdirs.user_data_dir("chainsim")) / DB_FILENAME


def _header(path: Path) -> bytes:
    try:
        with path.open("rb") as fh:
            return fh.read(len(SQLITE_MAGIC))
    except OSError as exc:
        raise UserError(f"cannot read records database {path}: {exc.strerror}") from None


def _check_file(path: Path) -> None:
    """Refuse, without writing, anything at ``path`` that cannot be a records database."""
    if path.is_dir():
        raise UserError(f"records database {path} is a directory; expected a .sqlite3 file")
    if not path.exists():
        return
    # Read-only look through SQLite first: opening read-write and switching to WAL would rewrite
    # the header of a file we are about to reject. The file is never opened with a plain handle
    # while it may be in use here: closing any descriptor of a file drops every POSIX lock this
    # process holds on it, those of live connections included, and another process could then
    # reset the WAL under them. The header is read only after SQLite refused the file, to say why.
    try:
        ro = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise UserError(f"cannot open records database {path}: {exc}") from None
    try:
        ok = ro.execute("PRAGMA quick_check").fetchone()[0]
        version = ro.execute("PRAGMA user_version").fetchone()[0]
        objects = ro.execute("SELECT type, name FROM sqlite_master WHERE name NOT LIKE 'sqlite_%'").fetchall()
        columns = {
            name: {r[1] for r in ro.execute(f"PRAGMA table_info({name})")}
            for kind, name in objects
            if kind == "table" and name in OWN_TABLES and name.isidentifier()
        }
    except sqlite3.DatabaseError as exc:
        ro.close()
        if _header(path) not in (b"", SQLITE_MAGIC):
            raise UserError(f"{path} is not an SQLite database; expected a chainsim records file") from None
        if not (os.access(path, os.W_OK) and os.access(path.parent, os.W_OK | os.X_OK)):
            # a WAL database cannot be read without writing its shared-memory file beside it
            raise UserError(f"records database {path} is read-only for this user ({exc})") from None
        raise UserError(f"records database {path} is damaged or not a database ({exc})") from None
    finally:
        ro.close()
    if ok != "ok":
        raise UserError(f"records database {path} is damaged (integrity check: {ok})")
    if version > SCHEMA_VERSION:
        raise UserError(
            f"records database {path} has schema version {version}; this chainsim reads up to {SCHEMA_VERSION}"
        )
    own = _own_schema()
    strange = sorted(name for kind, name in objects if (kind, name) not in own["objects"])
    if strange or any(not cols <= own["columns"][name] for name, cols in columns.items()):
        what = f"{strange[0]!r}" if strange else "tables with other columns"
        raise UserError(
            f"{path} is an SQLite database of something else ({what}); expected a chainsim records file "
            "(another program's database is never written into)"
        )
    missing = {"classes", "trainees", "attempts"} - {name for kind, name in objects if kind == "table"}
    if version >= 1 and missing:  # the first migration made these three
        raise UserError(f"records database {path} lacks table(s) {', '.join(sorted(missing))}; it is damaged")


_OWN: dict = {}


def _own_schema() -> dict:
    """Tables, indexes and columns a records database may hold: those the migrations create, at any
    version (a later step may drop a column an earlier file still has)."""
    if not _OWN:
        mem = sqlite3.connect(":memory:")
        objects: set = set()
        columns: dict[str, set] = {}
        try:
            for step in MIGRATIONS:
                for statement in step:
                    mem.execute(statement)
                now = set(mem.execute("SELECT type, name FROM sqlite_master WHERE name NOT LIKE 'sqlite_%'"))
                objects |= now
                for kind, name in now:
                    if kind == "table":
                        columns.setdefault(name, set()).update(r[1] for r in mem.execute(f"PRAGMA table_info({name})"))
            _OWN["objects"] = objects
            _OWN["columns"] = columns
        finally:
            mem.close()
    return _OWN


def migrate(conn: Connection) -> int:
    """Bring ``conn`` up to SCHEMA_VERSION, one transaction per step; returns the final version."""
    while True:
        conn.execute("BEGIN IMMEDIATE")
        try:
            version = schema_version(conn)
            if version >= SCHEMA_VERSION:
                conn.execute("COMMIT")
                return version
            for statement in MIGRATIONS[version]:
                conn.execute(statement)
            set_schema_version(conn, version + 1)
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise


def _row_to_attempt(row: sqlite3.Row, figures: dict[str, Any], metrics: dict[str, Any]) -> dict[str, Any]:
    """An attempt as the store gives it: its row, its procedure's figures by name (each figure in the
    place and type versions 1-12 read its fixed column in: the first three, the target, the rest; counts
    whole), then its metrics. An attempt of another procedure than the records' names it, after its pack."""
    raw = {key: row[key] for key in row.keys()}
    procedure = raw.pop("procedure_name")
    columns = attempt_layout(procedure).columns
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key == "pack" and procedure != RECORDS_PROCEDURE.name:
            out["procedure"] = procedure
            out[key] = value
        elif key == "target":
            out.update(_figures(columns[:3], figures))
            out[key] = value
            out.update(_figures(columns[3:], figures))
        else:
            out[key] = value
    for key in ("aids", "step_times", "details", "differences", "flags"):
        out[key] = json.loads(out[key])
    if out["client_figures"] is not None:
        out["client_figures"] = json.loads(out["client_figures"])
    out["metrics"] = metrics
    return out


def _figures(columns: Sequence[Column], figures: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for c in columns:
        v = figures.get(c.name)
        out[c.name] = None if v is None else int(v) if c.whole else v
    return out


def attempt_layout(procedure: str) -> AttemptLayout:
    """The attempt layout of a stored attempt's procedure (one without a layout keeps no figures)."""
    return procedure_for(procedure).layout or AttemptLayout(columns=())


_ATTEMPT_SELECT = """
    SELECT a.id, c.name AS class_name, t.name AS trainee, a.pack, a.created_at,
           a.target, a.procedure_name, a.aids, a.step_times, a.details,
           a.filed_by, a.client_created_at, a.pack_version, a.pack_hash, a.client_figures, a.differences,
           a.retracted_at, a.retracted_by, a.retract_reason, a.source, a.flags, a.accepted_by, a.accepted_at
    FROM attempts a JOIN trainees t ON t.id = a.trainee_id JOIN classes c ON c.id = t.class_id
"""


def check_target(path: str | os.PathLike[str] | None) -> Path | str | None:
    """Check, without creating or writing anything, that attempts can be saved at ``path``.

    An existing file must be a records database we may write; a new one needs an existing, writable
    folder (a mistyped folder is an error, not a new database somewhere unexpected).
    """
    # a PostgreSQL server answers for itself when connected to
    if is_postgres(path):
        return path
    if path is None and is_postgres(os.environ.get(ENV_VAR, "").strip()):
        return None
    p = _path(path)
    folder = p.parent
    if p.is_file() and not os.access(p, os.W_OK):
        raise UserError(f"records database {p} is read-only; nothing could be saved")
    if not p.exists() and path is not None and not folder.is_dir():
        raise UserError(f"records database {p}: folder {folder} does not exist (is the path mistyped?)")
    if folder.is_dir() and not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"records database {p}: folder {folder} is not writable; nothing could be saved")
    _check_file(p)
    return p


def _path(path: str | os.PathLike[str] | None) -> Path:
    if path is None:
        return default_path()
    text = os.fspath(path)
    if not text.strip() or "\x00" in text:
        raise UserError(f"records database path {text!r} is not usable")
    return Path(text).expanduser()


class RecordStore:
    """Classes, trainees and their attempts in one SQLite file (see module docstring)."""

    def __init__(self, path: str | os.PathLike[str] | None = None, *, create: bool = True) -> None:
        if path is None and is_postgres(os.environ.get(ENV_VAR, "").strip()):
            path = os.environ[ENV_VAR].strip()
        self.path: Path | str  # the SQLite file, or the PostgreSQL URL without its password
        self._conn: Connection | None
        if is_postgres(path):
            # A PostgreSQL URL (chainsim.game.records.backend): same schema, same migrations.
            self.path = redact(path)
            self._conn = PgConnection(path)
            try:
                migrate(self._conn)
            except db_errors() as exc:
                self._conn.close()
                raise UserError(f"cannot use records database {self.path}: {exc}") from None
            except BaseException:
                self._conn.close()
                raise
            return
        self.path = self._file = _path(path)
        _check_file(self._file)
        created = not self._file.exists()
        if created and not create:
            raise NoDatabase(f"no records database at {self._file} (nothing has been saved there)")
        if created:
            if path is None:  # the default location: its folder is ours to make
                try:
                    self._file.parent.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise UserError(f"cannot create folder for records database {self._file}: {exc.strerror}") from None
            elif not self._file.parent.is_dir():
                raise UserError(
                    f"records database {self._file}: folder {self._file.parent} does not exist (is the path mistyped?)"
                )
            # The file is made by the first write, not now: a command that fails before writing leaves
            # nothing behind, and reads until then see an empty store (an in-memory one).
            self._conn = None
            self._memory: sqlite3.Connection | None = None
            self._unmade = True
            return
        self._unmade = False
        self._conn = self._open_file()

    def _open_file(self) -> sqlite3.Connection:
        """Connect to the SQLite file (made if missing), in WAL mode, migrated to SCHEMA_VERSION."""
        if not self._file.exists():
            # attempts and password hashes are private: the file (and, after it, SQLite's -wal and
            # -shm files, which copy its mode) is readable by its owner only
            try:
                os.close(os.open(self._file, os.O_CREAT | os.O_WRONLY, 0o600))
            except OSError as exc:
                raise UserError(f"cannot create records database {self._file}: {exc.strerror}") from None
        try:
            # isolation_level=None: we issue BEGIN/COMMIT ourselves so each save is exactly one
            # transaction and DDL is not auto-committed behind our back.
            conn = sqlite3.connect(self._file, isolation_level=None, timeout=BUSY_TIMEOUT_MS / 1000)
        except sqlite3.Error as exc:
            raise UserError(f"cannot open records database {self._file}: {exc}") from None
        try:
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA foreign_keys = ON")
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise UserError(f"records database {self._file} cannot use WAL journaling (got {mode})")
            conn.execute("PRAGMA synchronous = FULL")
            migrate(conn)
        except sqlite3.Error as exc:
            conn.close()
            raise UserError(f"cannot use records database {self._file}: {exc}") from None
        except BaseException:
            conn.close()
            raise
        return conn

    # -- plumbing -------------------------------------------------------------------------

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        conn, self._conn = getattr(self, "_conn", None), None
        memory, self._memory = getattr(self, "_memory", None), None
        self._unmade = False
        for c in (conn, memory):
            if c is not None:
                c.close()

    @property
    def schema_version(self) -> int:
        return schema_version(self._db)

    @property
    def _db(self) -> Connection:
        if self._conn is None:
            if getattr(self, "_unmade", False) and self._file.exists():  # another store made it meanwhile
                self._conn = self._open_file()
                self._unmade = False
                return self._conn
            if getattr(self, "_unmade", False):  # not made yet: reads see an empty store
                if self._memory is None:
                    self._memory = sqlite3.connect(":memory:", isolation_level=None)
                    self._memory.row_factory = sqlite3.Row
                    migrate(self._memory)
                return self._memory
            raise UserError("records store is closed")
        return self._conn

    @contextmanager
    def _write(self) -> Iterator[Connection]:
        """One write transaction; rolled back whole on any error. The first one makes a new file."""
        if self._conn is None and getattr(self, "_unmade", False):
            self._conn = self._open_file()
            self._unmade = False
            logger.warning("created a new records database at %s", self.path)
        conn = self._db
        # IMMEDIATE takes the write lock up front so a concurrent writer waits instead of failing
        # half-way through.
        try:
            conn.execute("BEGIN IMMEDIATE")
            yield conn
            conn.execute("COMMIT")
        except BaseException as exc:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            if isinstance(exc, db_errors()):
                raise WriteFailed(f"records database {self.path}: write failed, nothing changed ({exc})") from None
            raise

    def _class_id(self, conn: Connection, name: str) -> int | None:
        row = conn.execute("SELECT id FROM classes WHERE name = ?", (name,)).fetchone()
        return None if row is None else row[0]

    def _trainee_id(self, conn: Connection, class_id: int, name: str) -> int | None:
        row = conn.execute("SELECT id FROM trainees WHERE class_id = ? AND name = ?", (class_id, name)).fetchone()
        return None if row is None else row[0]

    def _require_class(self, name: str) -> int:
        class_id = self._class_id(self._db, name)
        if class_id is None:
            known = ", ".join(self.list_classes()) or "none yet"
            raise UserError(f"no class named {name!r} (classes: {known})")
        return class_id

    def _require_trainee(self, class_name: str | None, name: str) -> list[int]:
        rows = self._db.execute(
            "SELECT t.id FROM trainees t JOIN classes c ON c.id = t.class_id "
            "WHERE t.name = ? AND (? IS NULL OR c.name = ?)",
            (name, class_name, class_name),
        ).fetchall()
        if not rows:
            where = f" in class {class_name!r}" if class_name is not None else ""
            raise UserError(f"no trainee named {name!r}{where}")
        return [r[0] for r in rows]

    # -- classes and trainees ---------------------------------------------------------------

    def add_class(self, name: str) -> None:
        """Create a class; a name already in use is an error."""
        name = clean_name("class", name)
        with self._write() as conn:
            if self._class_id(conn, name) is not None:
                raise UserError(f"class {name!r} already exists")
            conn.execute("INSERT INTO classes (name) VALUES (?)", (name,))

    def add_trainee(self, class_name: str, name: str) -> bool:
        """Add a trainee to a class, creating the class if needed; returns True if it did."""
        class_name = clean_name("class", class_name)
        name = clean_name("trainee", name)
        with self._write() as conn:
            class_id = self._class_id(conn, class_name)
            created = class_id is None
            if class_id is None:
                class_id = inserted_id(conn.execute("INSERT INTO classes (name) VALUES (?)", (class_name,)))
            elif self._trainee_id(conn, class_id, name) is not None:
                raise UserError(f"trainee {name!r} already exists in class {class_name!r}")
            conn.execute("INSERT INTO trainees (class_id, name) VALUES (?, ?)", (class_id, name))
        return created

    def list_classes(self) -> list[str]:
        return [r[0] for r in self._db.execute("SELECT name FROM classes ORDER BY name")]

    def class_summary(self) -> list[dict[str, Any]]:
        """Per class: name, number of trainees, number of attempts."""
        rows = self._db.execute(
            """
            SELECT c.name AS class_name, COUNT(DISTINCT t.id) AS trainees, COUNT(a.id) AS attempts
            FROM classes c LEFT JOIN trainees t ON t.class_id = c.id
                 LEFT JOIN attempts a ON a.trainee_id = t.id
            GROUP BY c.id ORDER BY c.name
            """
        )
        return [dict(r) for r in rows]

    def list_trainees(self, class_name: str | None = None) -> list[dict[str, Any]]:
        """Trainees (optionally of one class) as dicts: class_name, trainee, attempts."""
        if class_name is not None:
            class_name = clean_name("class", class_name)
            self._require_class(class_name)
        rows = self._db.execute(
            """
            SELECT c.name AS class_name, t.name AS trainee, COUNT(a.id) AS attempts
            FROM trainees t JOIN classes c ON c.id = t.class_id
                 LEFT JOIN attempts a ON a.trainee_id = t.id
            WHERE ? IS NULL OR c.name = ?
            GROUP BY t.id, c.name ORDER BY c.name, t.name
            """,
            (class_name, class_name),
        )
        return [dict(r) for r in rows]

    # -- attempts ---------------------------------------------------------------------------

    def save_attempt(
        self,
        class_name: str,
        trainee: str,
        attempt: dict[str, Any],
        *,
        key: str | None = None,
        recording: str | None = None,
    ) -> int:
        """Validate and store one attempt in one transaction; returns its id.

        The class and trainee are created if missing, in the same transaction, so an interrupted
        save leaves no empty trainee behind either. ``key`` (an idempotency key, see
        ``attempt_id_for_key``) makes a resend return the first save's id instead of a copy. ``recording``
        (``provenance.encode_recording`` text) is kept with the attempt, as a records server keeps an upload's.
        """
        class_name = clean_name("class", class_name)
        trainee = clean_name("trainee", trainee)
        a = clean_attempt(attempt)
        key = None if key is None else clean_key(key)
        with self._write() as conn:
            if key is not None:
                row = conn.execute("SELECT id FROM attempts WHERE idem_key = ?", (key,)).fetchone()
                if row is not None:
                    return row[0]
            prov = None if recording is None else {"recording": recording}
            return self.insert_attempt(conn, class_name, trainee, a, key=key, provenance=prov)

    def insert_attempt(
        self,
        conn: Connection,
        class_name: str,
        trainee: str,
        a: dict[str, Any],
        *,
        key: str | None = None,
        provenance: dict[str, Any] | None = None,
    ) -> int:
        """Insert one cleaned attempt (``clean_attempt``) inside the caller's transaction; returns its id.

        ``provenance`` (the records server's scoring) fills who filed it, the client's clock, the pack's
        version and hash, the client's own figures, where they differ from the replay's, the recording,
        ``source`` (``replayed`` or ``witnessed``; ``local`` without provenance) and ``flags`` (why its input
        is beyond a person's, ``chainsim.game.records.plausible``).
        """
        prov = provenance or {}
        procedure = a.get("procedure", RECORDS_PROCEDURE.name)
        figures = [c.name for c in attempt_layout(procedure).columns]
        class_id = self._class_id(conn, class_name)
        if class_id is None:
            class_id = inserted_id(conn.execute("INSERT INTO classes (name) VALUES (?)", (class_name,)))
        trainee_id = self._trainee_id(conn, class_id, trainee)
        if trainee_id is None:
            trainee_id = inserted_id(
                conn.execute("INSERT INTO trainees (class_id, name) VALUES (?, ?)", (class_id, trainee))
            )
        cur = conn.execute(
            """
            INSERT INTO attempts (trainee_id, pack, created_at, target, procedure_name, aids, step_times,
                details, idem_key, filed_by, client_created_at, pack_version, pack_hash, client_figures,
                differences, source, flags)
            VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)
            """,
            (
                trainee_id,
                a["pack"],
                a["created_at"],
                a["target"],
                procedure,
                to_json(a["aids"]),
                to_json(a["step_times"]),
                to_json(a["details"]),
                key,
                prov.get("filed_by"),
                prov.get("client_created_at"),
                prov.get("pack_version"),
                prov.get("pack_hash"),
                None if prov.get("client_figures") is None else to_json(prov["client_figures"]),
                to_json(prov.get("differences") or []),
                prov.get("source", "local"),
                to_json(prov.get("flags") or []),
            ),
        )
        rid = inserted_id(cur)
        # the figures of the procedure's layout, then the procedure-neutral metrics: those figures too
        # (as version 6 keeps them), then the pack's own
        for name in figures:
            conn.execute(
                "INSERT INTO attempt_figures (attempt_id, name, value) VALUES (?, ?, ?)",
                (rid, name, None if a[name] is None else float(a[name])),
            )
        metrics = {name: a[name] for name in figures}
        metrics.update(a["metrics"])
        for name, value in metrics.items():
            conn.execute(
                "INSERT INTO attempt_metrics (attempt_id, name, value) VALUES (?, ?, ?)",
                (rid, name, None if value is None else float(value)),
            )
        if prov.get("recording") is not None:
            conn.execute(
                "INSERT INTO attempt_recordings (attempt_id, recording) VALUES (?, ?)", (rid, prov["recording"])
            )
        return rid

    def _attempts(self, rows: list[sqlite3.Row]) -> list[dict[str, Any]]:
        """Each attempt of `rows`, with its figures and `metrics`, its rows of the metrics table by name
        (in the order stored)."""
        figures = self._by_attempt("attempt_figures", [r["id"] for r in rows])
        metrics = self._by_attempt("attempt_metrics", [r["id"] for r in rows])
        return [_row_to_attempt(r, figures[r["id"]], metrics[r["id"]]) for r in rows]

    def _by_attempt(self, table: str, ids: list[int]) -> dict[int, dict[str, Any]]:
        by_id: dict[int, dict[str, Any]] = {i: {} for i in ids}
        for start in range(0, len(ids), 500):
            chunk = ids[start : start + 500]
            marks = ", ".join("?" for _ in chunk)
            for m in self._db.execute(
                f"SELECT attempt_id, name, value FROM {table} WHERE attempt_id IN ({marks}) ORDER BY id",
                tuple(chunk),
            ):
                by_id[m["attempt_id"]][m["name"]] = m["value"]
        return by_id

    def list_attempts(self, class_name: str | None = None, trainee: str | None = None) -> list[dict[str, Any]]:
        """Attempts, oldest first, optionally filtered; naming an unknown class/trainee is an error."""
        if class_name is not None:
            class_name = clean_name("class", class_name)
            self._require_class(class_name)
        if trainee is not None:
            trainee = clean_name("trainee", trainee)
            self._require_trainee(class_name, trainee)
        rows = self._db.execute(
            _ATTEMPT_SELECT
            + """
            WHERE (? IS NULL OR c.name = ?) AND (? IS NULL OR t.name = ?)
            ORDER BY c.name, t.name, a.created_at, a.id
            """,
            (class_name, class_name, trainee, trainee),
        )
        return self._attempts(list(rows))

    def get_attempt(self, attempt_id: int) -> dict[str, Any]:
        attempt_id = _attempt_id(attempt_id)
        row = self._db.execute(_ATTEMPT_SELECT + " WHERE a.id = ?", (attempt_id,)).fetchone()
        if row is None:
            raise UserError(f"no attempt with id {attempt_id}")
        return self._attempts([row])[0]

    def delete_attempt(self, attempt_id: int) -> None:
        attempt_id = _attempt_id(attempt_id)
        with self._write() as conn:
            if conn.execute("DELETE FROM attempts WHERE id = ?", (attempt_id,)).rowcount == 0:
                raise UserError(f"no attempt with id {attempt_id}")

    def retract_attempt(self, attempt_id: int, actor: str, reason: str) -> dict[str, Any]:
        """Mark an attempt retracted (kept, shown as such) with who, when and why; one audit row."""
        attempt_id = _attempt_id(attempt_id)
        reason = reason.strip() if isinstance(reason, str) else ""
        if not reason or len(reason) > 500:
            raise UserError("a retraction needs a reason of 1-500 characters")
        now = clean_created_at(None)
        with self._write() as conn:
            row = conn.execute(_ATTEMPT_SELECT + " WHERE a.id = ?", (attempt_id,)).fetchone()
            if row is None:
                raise UserError(f"no attempt with id {attempt_id}")
            if row["retracted_at"] is not None:
                raise UserError(f"attempt {attempt_id} was already retracted")
            conn.execute(
                "UPDATE attempts SET retracted_at = ?, retracted_by = ?, retract_reason = ? WHERE id = ?",
                (now, actor, reason, attempt_id),
            )
            self.audit(conn, actor, "retract", row["class_name"], reason, attempt_id)
        return self.get_attempt(attempt_id)

    def accept_attempt(self, attempt_id: int, actor: str) -> dict[str, Any]:
        """A trainer accepts a flagged attempt: from now on it counts in the class figures; one audit row."""
        attempt_id = _attempt_id(attempt_id)
        with self._write() as conn:
            row = conn.execute(_ATTEMPT_SELECT + " WHERE a.id = ?", (attempt_id,)).fetchone()
            if row is None:
                raise UserError(f"no attempt with id {attempt_id}")
            if json.loads(row["flags"]) == []:
                raise UserError(f"attempt {attempt_id} is not flagged; there is nothing to accept")
            if row["accepted_at"] is not None:
                raise UserError(f"attempt {attempt_id} was already accepted by {row['accepted_by']}")
            conn.execute(
                "UPDATE attempts SET accepted_by = ?, accepted_at = ? WHERE id = ?",
                (actor, clean_created_at(None), attempt_id),
            )
            self.audit(conn, actor, "accept", row["class_name"], "flagged input accepted as a person's", attempt_id)
        return self.get_attempt(attempt_id)

    def require_witnessed(self, class_name: str, required: bool | None = None) -> bool:
        """Whether ``class_name`` takes only witnessed attempts (browser trainer); set it when ``required``
        is given (the class is made if missing). An unknown class requires nothing."""
        class_name = clean_name("class", class_name)
        if required is None:
            row = self._db.execute("SELECT require_witnessed FROM classes WHERE name = ?", (class_name,)).fetchone()
            return bool(row and row[0])
        with self._write() as conn:
            if self._class_id(conn, class_name) is None:
                conn.execute("INSERT INTO classes (name) VALUES (?)", (class_name,))
            conn.execute("UPDATE classes SET require_witnessed = ? WHERE name = ?", (1 if required else 0, class_name))
        return bool(required)

    def audit(self, conn: Connection, actor: str, action: str, class_name: str, detail: str, attempt_id=None) -> None:
        """One row of the audit log, inside the caller's transaction."""
        conn.execute(
            "INSERT INTO audit_log (at, actor, action, attempt_id, class_name, detail) VALUES (?, ?, ?, ?, ?, ?)",
            (clean_created_at(None), actor, action, attempt_id, class_name, detail),
        )

    def audit_entries(self, classes: list[str]) -> list[dict[str, Any]]:
        """The audit log of the given classes, oldest first."""
        if not classes:
            return []
        marks = ", ".join("?" for _ in classes)
        rows = self._db.execute(
            "SELECT id, at, actor, action, attempt_id, class_name, detail FROM audit_log "
            f"WHERE class_name IN ({marks}) ORDER BY id",
            tuple(classes),
        )
        return [{k: r[k] for k in r.keys()} for r in rows]

    def save_questionnaire(self, class_name: str, trainee: str, kind: str, session: str, answers: dict) -> int:
        """Store a study questionnaire ('pre' or 'post') of one session; the trainee is created if missing."""
        class_name = clean_name("class", class_name)
        trainee = clean_name("trainee", trainee)
        kind, session, answers = clean_questionnaire(kind, session, answers)
        with self._write() as conn:
            class_id = self._class_id(conn, class_name)
            if class_id is None:
                class_id = inserted_id(conn.execute("INSERT INTO classes (name) VALUES (?)", (class_name,)))
            trainee_id = self._trainee_id(conn, class_id, trainee)
            if trainee_id is None:
                trainee_id = inserted_id(
                    conn.execute("INSERT INTO trainees (class_id, name) VALUES (?, ?)", (class_id, trainee))
                )
            cur = conn.execute(
                "INSERT INTO questionnaires (trainee_id, kind, session, created_at, answers) VALUES (?, ?, ?, ?, ?)",
                (trainee_id, kind, session, clean_created_at(None), to_json(answers)),
            )
            return inserted_id(cur)

    def list_questionnaires(self, class_name: str | None = None) -> list[dict[str, Any]]:
        """Questionnaires, oldest first, optionally of one class."""
        if class_name is not None:
            class_name = clean_name("class", class_name)
            self._require_class(class_name)
        rows = self._db.execute(
            """
            SELECT q.id, c.name AS class_name, t.name AS trainee, q.kind, q.session, q.created_at, q.answers
            FROM questionnaires q JOIN trainees t ON t.id = q.trainee_id JOIN classes c ON c.id = t.class_id
            WHERE (? IS NULL OR c.name = ?)
            ORDER BY q.created_at, q.id
            """,
            (class_name, class_name),
        )
        out = []
        for r in rows:
            d = {k: r[k] for k in r.keys()}
            d["answers"] = json.loads(d["answers"])
            out.append(d)
        return out

    def recording(self, attempt_id: int) -> str | None:
        """The recording kept with an attempt (``provenance.encode_recording`` text), or None."""
        found = list(self._db.execute("SELECT recording FROM attempt_recordings WHERE attempt_id = ?", (attempt_id,)))
        return found[0][0] if found else None

    def attempt_id_for_key(self, key: str) -> int | None:
        """The attempt saved with idempotency key ``key``, or None if none was."""
        row = self._db.execute("SELECT id FROM attempts WHERE idem_key = ?", (clean_key(key),)).fetchone()
        return None if row is None else row[0]

    # -- for modules that keep their own tables in this database (server accounts, outbox) --

    def transaction(self):
        """Context manager: one write transaction on the store's connection (see ``_write``)."""
        return self._write()

    def query(self, sql: str, params: tuple = ()) -> list[Any]:
        """Rows of one read statement (``?`` parameters), readable by index and column name."""
        return list(self._db.execute(sql, params))


def in_class_figures(attempt: dict[str, Any]) -> bool:
    """Whether an attempt counts in its class's figures (medians, plots, summaries): not retracted, and its
    input a person's or accepted as such by a trainer (docs/records-server.md, "Provenance")."""
    return not attempt.get("retracted_at") and (not attempt.get("flags") or bool(attempt.get("accepted_by")))


def _attempt_id(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= limits.MAX_ATTEMPT_ID:
        shown = repr(value) if len(repr(value)) < 30 else f"a {len(repr(value))}-digit number"
        raise UserError(f"attempt id must be a whole number from 1 to {limits.MAX_ATTEMPT_ID}, got {shown}")
    return value


def local_records(db: str | os.PathLike[str] | None = None, recording: Callable[[], str] | None = None) -> Records:
    """The Records resource over a local SQLite store; each call opens and closes the database.
    ``recording()`` gives, at each save, the session's recording to keep with the attempt (a study's
    trials keep theirs on every machine, not only on those that upload)."""

    def save_attempt(class_name: str, trainee: str, record: dict) -> int:
        kept = None if recording is None else recording()
        with RecordStore(db) as store:
            return store.save_attempt(class_name, trainee, record, recording=kept)

    def list_attempts(class_name: str, trainee: str) -> list[dict]:
        with RecordStore(db, create=False) as store:  # looking never creates a database
            return store.list_attempts(class_name, trainee)

    def delete_attempt(class_name: str, trainee: str, attempt_id: int) -> None:
        with RecordStore(db, create=False) as store:
            a = store.get_attempt(attempt_id)
            if (a["class_name"], a["trainee"]) != (class_name, trainee):
                raise UserError(f"attempt {attempt_id} is not yours")
            store.delete_attempt(attempt_id)

    where = redact(db) if is_postgres(db) else str(Path(db).expanduser() if db else default_path())
    return Records(save_attempt=save_attempt, list_attempts=list_attempts, where=where, delete_attempt=delete_attempt)
