"""Schema of the trainee-records database and its ordered migrations (thesis 3.3.4, 6.1.5).

The assessment tool of section 3.3.4 files each attempt under a class and a trainee name; the
metrics stored per attempt are those of 6.1.5 (the error E of the three marked points, the needle's
error from its tip to the target opening) plus the aids that were switched on, which is what the
with/without-feature comparison of 6.1.3-6.1.5 needs.

The schema version lives in ``PRAGMA user_version``. ``MIGRATIONS[i]`` takes a database from
version ``i`` to version ``i + 1``; each one runs inside the same transaction as the version bump,
so a database is never left half-migrated. Never edit a shipped step: append a new one.

The attempts table's fixed metric columns are the needle procedure's (the records' procedure,
chainsim.systems.procedures.RECORDS_PROCEDURE: the names come from its declared layout, the text of
every step is as shipped).
"""

from __future__ import annotations

from chainsim.systems.procedures import RECORDS_PROCEDURE, records_layout

#: the attempt whose metrics versions 1-5 keep as fixed columns (until version 13 moves them to rows)
LAYOUT = records_layout()

# Version 1: the first released layout. Kept verbatim so tests can build a genuine v1 file.
V1_DDL: tuple[str, ...] = (
    """
    CREATE TABLE classes (
        id   INTEGER PRIMARY KEY,
        name TEXT NOT NULL UNIQUE
    )
    """,
    """
    CREATE TABLE trainees (
        id       INTEGER PRIMARY KEY,
        class_id INTEGER NOT NULL REFERENCES classes(id) ON DELETE CASCADE,
        name     TEXT NOT NULL,
        UNIQUE (class_id, name)
    )
    """,
    f"""
    CREATE TABLE attempts (
        id                INTEGER PRIMARY KEY,
        trainee_id        INTEGER NOT NULL REFERENCES trainees(id) ON DELETE CASCADE,
        pack              TEXT NOT NULL,
        created_at        TEXT NOT NULL,
        duration_s        REAL NOT NULL,
        {LAYOUT.mark_error} REAL NOT NULL,
        {LAYOUT.target_error}   REAL,
        target            TEXT NOT NULL,
        skull_contacts    INTEGER NOT NULL,
        path_length_mm    REAL NOT NULL,
        aids              TEXT NOT NULL,
        step_times        TEXT NOT NULL
    )
    """,
)

# Version 2: free-form extra metrics (D1..D3, d1..d3, the marked positions) and an index for the
# per-trainee history queries that `list`, `export` and `plot` run.
V2_DDL: tuple[str, ...] = (
    "ALTER TABLE attempts ADD COLUMN details TEXT NOT NULL DEFAULT '{}'",
    "CREATE INDEX attempts_by_trainee ON attempts (trainee_id, created_at, id)",
)

# Version 3: redirections per attempt (times the needle was withdrawn to the skin and turned again);
# attempts saved before it keep their rows with 0.
V3_DDL: tuple[str, ...] = ("ALTER TABLE attempts ADD COLUMN redirections INTEGER NOT NULL DEFAULT 0",)

# Version 4: the records server (docs/records-server.md). Accounts with a role; a trainee
# account is one trainee row, a trainer account teaches classes. Web sessions and API tokens
# are kept as SHA-256 hashes of their secrets, expiry as Unix seconds. ``idem_key`` makes a
# resent attempt (the simulator's offline queue) land once. ``outbox`` is that queue, kept in
# the simulator's local file; ``server_logins`` the tokens it signed in with.
V4_DDL: tuple[str, ...] = (
    "ALTER TABLE attempts ADD COLUMN idem_key TEXT",
    "CREATE UNIQUE INDEX attempts_by_key ON attempts (idem_key)",
    """
    CREATE TABLE users (
        id            INTEGER PRIMARY KEY,
        name          TEXT NOT NULL UNIQUE,
        role          TEXT NOT NULL CHECK (role IN ('trainer', 'trainee')),
        password_hash TEXT NOT NULL,
        trainee_id    INTEGER UNIQUE REFERENCES trainees(id) ON DELETE SET NULL,
        created_at    TEXT NOT NULL
    )
    """,
    """
    CREATE TABLE trainer_classes (
        id       INTEGER PRIMARY KEY,
        user_id  INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        class_id INTEGER NOT NULL REFERENCES classes(id) ON DELETE CASCADE,
        UNIQUE (user_id, class_id)
    )
    """,
    """
    CREATE TABLE api_tokens (
        id         INTEGER PRIMARY KEY,
        user_id    INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        token_hash TEXT NOT NULL UNIQUE,
        label      TEXT NOT NULL,
        created_at REAL NOT NULL,
        expires_at REAL NOT NULL
    )
    """,
    """
    CREATE TABLE web_sessions (
        id           INTEGER PRIMARY KEY,
        user_id      INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        session_hash TEXT NOT NULL UNIQUE,
        csrf         TEXT NOT NULL,
        created_at   REAL NOT NULL,
        expires_at   REAL NOT NULL
    )
    """,
    """
    CREATE TABLE outbox (
        id         INTEGER PRIMARY KEY,
        server     TEXT NOT NULL,
        idem_key   TEXT NOT NULL UNIQUE,
        class_name TEXT NOT NULL,
        trainee    TEXT NOT NULL,
        attempt    TEXT NOT NULL,
        queued_at  TEXT NOT NULL,
        sent_at    TEXT,
        remote_id  INTEGER,
        last_error TEXT
    )
    """,
    """
    CREATE TABLE server_logins (
        id        INTEGER PRIMARY KEY,
        server    TEXT NOT NULL UNIQUE,
        user_name TEXT NOT NULL,
        role      TEXT NOT NULL,
        token     TEXT NOT NULL,
        saved_at  TEXT NOT NULL
    )
    """,
)

# Version 5: what the X-ray cost per attempt (single images, seconds of exposure, estimated entrance
# dose; thesis 3.2.3) - attempts saved before it keep their rows with 0 - and the study questionnaires
# of thesis 6.1.2/6.1.4 (a pre-session background form and a post-session rating form per session).
V5_DDL: tuple[str, ...] = (
    "ALTER TABLE attempts ADD COLUMN xray_shots INTEGER NOT NULL DEFAULT 0",
    "ALTER TABLE attempts ADD COLUMN exposure_s REAL NOT NULL DEFAULT 0",
    "ALTER TABLE attempts ADD COLUMN dose_mgy REAL NOT NULL DEFAULT 0",
    """
    CREATE TABLE questionnaires (
        id         INTEGER PRIMARY KEY,
        trainee_id INTEGER NOT NULL REFERENCES trainees(id) ON DELETE CASCADE,
        kind       TEXT NOT NULL,
        session    TEXT NOT NULL,
        created_at TEXT NOT NULL,
        answers    TEXT NOT NULL
    )
    """,
)

# Version 6: procedure-neutral metrics. Each attempt's metrics are rows (attempt, name, value) - a
# needle procedure stores the pack's own [metrics] here (docs/needle-procedures.md), so a new procedure
# needs no new column. Every value the fixed columns of versions 1-5 hold is copied in under the
# column's name, so attempts saved before keep all they had and read the same both ways. The fixed
# columns stay (the reports, the server and exports read them).
LEGACY_METRICS: tuple[str, ...] = tuple(c.name for c in LAYOUT.columns)
V6_DDL: tuple[str, ...] = (
    """
    CREATE TABLE attempt_metrics (
        id         INTEGER PRIMARY KEY,
        attempt_id INTEGER NOT NULL REFERENCES attempts(id) ON DELETE CASCADE,
        name       TEXT NOT NULL,
        value      REAL,
        UNIQUE (attempt_id, name)
    )
    """,
    *(
        f"INSERT INTO attempt_metrics (attempt_id, name, value) SELECT id, '{name}', {name} FROM attempts"
        for name in LEGACY_METRICS
    ),
)

# Version 7: results the server computes (docs/records-server.md). An upload is a row of ``uploads``
# (the server's scoring queue: acknowledged at once, scored by a worker that replays its recording);
# the attempt it becomes carries who filed it, the server's time (the client's clock kept beside it),
# the pack's identity, the client's own figures and where they differ from the replay's. A trainer
# retracts an attempt with a reason instead of deleting it; ``audit_log`` keeps who did what, when.
# Attempts saved before keep their rows, filed by nobody and not flagged.
V7_DDL: tuple[str, ...] = (
    "ALTER TABLE attempts ADD COLUMN filed_by TEXT",
    "ALTER TABLE attempts ADD COLUMN client_created_at TEXT",
    "ALTER TABLE attempts ADD COLUMN pack_version TEXT",
    "ALTER TABLE attempts ADD COLUMN pack_hash TEXT",
    "ALTER TABLE attempts ADD COLUMN client_figures TEXT",
    "ALTER TABLE attempts ADD COLUMN differences TEXT NOT NULL DEFAULT '[]'",
    "ALTER TABLE attempts ADD COLUMN retracted_at TEXT",
    "ALTER TABLE attempts ADD COLUMN retracted_by TEXT",
    "ALTER TABLE attempts ADD COLUMN retract_reason TEXT",
    """
    CREATE TABLE uploads (
        id           INTEGER PRIMARY KEY,
        idem_key     TEXT UNIQUE,
        body_hash    TEXT NOT NULL,
        filed_by     TEXT NOT NULL,
        class_name   TEXT NOT NULL,
        trainee      TEXT NOT NULL,
        received_at  TEXT NOT NULL,
        pack         TEXT NOT NULL,
        pack_version TEXT NOT NULL,
        pack_hash    TEXT NOT NULL,
        claimed      TEXT NOT NULL,
        recording    TEXT NOT NULL,
        state        TEXT NOT NULL CHECK (state IN ('scoring', 'scored', 'refused')),
        claimed_by   TEXT,
        claimed_at   REAL,
        tries        INTEGER NOT NULL DEFAULT 0,
        attempt_id   INTEGER REFERENCES attempts(id) ON DELETE SET NULL,
        error        TEXT,
        scored_at    TEXT
    )
    """,
    "CREATE INDEX uploads_by_state ON uploads (state, id)",
    """
    CREATE TABLE attempt_recordings (
        id         INTEGER PRIMARY KEY,
        attempt_id INTEGER NOT NULL UNIQUE REFERENCES attempts(id) ON DELETE CASCADE,
        recording  TEXT NOT NULL
    )
    """,
    """
    CREATE TABLE audit_log (
        id         INTEGER PRIMARY KEY,
        at         TEXT NOT NULL,
        actor      TEXT NOT NULL,
        action     TEXT NOT NULL,
        attempt_id INTEGER,
        class_name TEXT NOT NULL,
        detail     TEXT NOT NULL
    )
    """,
)

# Version 8: the certificate authority a simulator trusts for a records server with its own certificate
# (``chainsim records login --cafile``), kept as PEM text with the sign-in so later sends and syncs
# verify the server against it; sign-ins saved before trust the system's authorities, as they did.
V8_DDL: tuple[str, ...] = ("ALTER TABLE server_logins ADD COLUMN ca_pem TEXT",)

# Version 9: where an attempt came from and whether its input is a person's (docs/records-server.md,
# "Provenance"). ``source`` is ``local`` (saved to a local file), ``replayed`` (uploaded from the
# window, scored by replaying its recording) or ``witnessed`` (made in the browser trainer: the server
# ran it); attempts a server stored before keep ``replayed``. ``flags`` lists why a replayed attempt's
# input is beyond what a person can do (docs/limits.md); a flagged attempt counts in no class figure
# until a trainer accepts it (``accepted_by``/``accepted_at``). A class may require witnessed attempts.
# ``uploads.witnessed`` marks the browser trainer's saves; ``uploads.sim_s`` is the recording's
# simulated time once the scorer has read it.
V9_DDL: tuple[str, ...] = (
    "ALTER TABLE attempts ADD COLUMN source TEXT NOT NULL DEFAULT 'local'",
    "UPDATE attempts SET source = 'replayed' WHERE filed_by IS NOT NULL",
    "ALTER TABLE attempts ADD COLUMN flags TEXT NOT NULL DEFAULT '[]'",
    "ALTER TABLE attempts ADD COLUMN accepted_by TEXT",
    "ALTER TABLE attempts ADD COLUMN accepted_at TEXT",
    "ALTER TABLE uploads ADD COLUMN witnessed INTEGER NOT NULL DEFAULT 0",
    "CREATE INDEX uploads_by_trainee ON uploads (class_name, trainee, state, id)",
    "ALTER TABLE classes ADD COLUMN require_witnessed INTEGER NOT NULL DEFAULT 0",
)

# Version 10: blinded rating (docs/validity.md, "Blinded rating"). A rating set is a list of attempts
# shown to raters under random codes, without names, dates or class; each rater has a secret link (its
# hash kept here), not an account, so a rater can open nothing else. ``form`` is the global rating form's
# items (JSON) as the set was made with, ``scores`` a rater's marks per item (JSON).
V10_DDL: tuple[str, ...] = (
    """
    CREATE TABLE rating_sets (
        id         INTEGER PRIMARY KEY,
        name       TEXT NOT NULL UNIQUE,
        created_by TEXT NOT NULL,
        created_at TEXT NOT NULL,
        form       TEXT NOT NULL
    )
    """,
    """
    CREATE TABLE rating_items (
        id         INTEGER PRIMARY KEY,
        set_id     INTEGER NOT NULL REFERENCES rating_sets(id) ON DELETE CASCADE,
        code       TEXT NOT NULL UNIQUE,
        attempt_id INTEGER NOT NULL REFERENCES attempts(id) ON DELETE CASCADE,
        UNIQUE (set_id, attempt_id)
    )
    """,
    """
    CREATE TABLE raters (
        id         INTEGER PRIMARY KEY,
        set_id     INTEGER NOT NULL REFERENCES rating_sets(id) ON DELETE CASCADE,
        name       TEXT NOT NULL,
        token_hash TEXT NOT NULL UNIQUE,
        UNIQUE (set_id, name)
    )
    """,
    """
    CREATE TABLE ratings (
        id       INTEGER PRIMARY KEY,
        item_id  INTEGER NOT NULL REFERENCES rating_items(id) ON DELETE CASCADE,
        rater_id INTEGER NOT NULL REFERENCES raters(id) ON DELETE CASCADE,
        scores   TEXT NOT NULL,
        total    REAL NOT NULL,
        rated_at TEXT NOT NULL,
        UNIQUE (item_id, rater_id)
    )
    """,
)

# Version 11: study registers (docs/validity.md, "From protocol to report"). A participant is entered
# in a study's register before their first trial, with the covariates a methods reviewer asks for (group,
# year of training, procedures performed); ``slot`` is their place in the study's one allocation sequence
# (the row of the protocol's counterbalanced design they take), given in registration order and unique
# per study, so every site and machine filing to this database draws from the same sequence. ``grp``:
# ``group`` is an SQL keyword.
V11_DDL: tuple[str, ...] = (
    """
    CREATE TABLE study_participants (
        id                   INTEGER PRIMARY KEY,
        study                TEXT NOT NULL,
        class_name           TEXT NOT NULL,
        code                 TEXT NOT NULL,
        grp                  TEXT NOT NULL,
        year_of_training     INTEGER NOT NULL,
        procedures_performed INTEGER NOT NULL,
        slot                 INTEGER NOT NULL,
        registered_by        TEXT NOT NULL,
        registered_at        TEXT NOT NULL,
        UNIQUE (study, code),
        UNIQUE (study, slot)
    )
    """,
)

# Version 12: study designs. A study's trials and their aids (chainsim.game.study.protocol.design),
# filed before its trials are uploaded, so the records server checks each trial against the trial the
# participant's slot gives that place of their session. Kept as filed: a design is not changed.
V12_DDL: tuple[str, ...] = (
    """
    CREATE TABLE study_designs (
        id        INTEGER PRIMARY KEY,
        study     TEXT NOT NULL UNIQUE,
        design    TEXT NOT NULL,
        filed_by  TEXT NOT NULL,
        filed_at  TEXT NOT NULL
    )
    """,
)

# Version 13: procedure-neutral attempts. An attempt names its procedure (``procedure_name``; every
# attempt saved before is the records' procedure's, the needle procedure), and the figures every attempt
# of a procedure has (its declared layout's columns: versions 1-5's fixed columns) move to rows
# (attempt, name, value) of ``attempt_figures``, read by name through that procedure's layout; the fixed
# columns are dropped, so a procedure's attempt needs no column of its own. Figures are kept apart from
# ``attempt_metrics`` (the pack's own [metrics], version 6): a pack's metric may share a figure's name
# and hold another value (a needle pack that scores no marked points has no such metric; its figure is 0).
V13_DDL: tuple[str, ...] = (
    f"ALTER TABLE attempts ADD COLUMN procedure_name TEXT NOT NULL DEFAULT '{RECORDS_PROCEDURE.name}'",
    """
    CREATE TABLE attempt_figures (
        id         INTEGER PRIMARY KEY,
        attempt_id INTEGER NOT NULL REFERENCES attempts(id) ON DELETE CASCADE,
        name       TEXT NOT NULL,
        value      REAL,
        UNIQUE (attempt_id, name)
    )
    """,
    *(
        f"INSERT INTO attempt_figures (attempt_id, name, value) SELECT id, '{name}', {name} FROM attempts"
        for name in LEGACY_METRICS
    ),
    *(f"ALTER TABLE attempts DROP COLUMN {name}" for name in LEGACY_METRICS),
)

MIGRATIONS: tuple[tuple[str, ...], ...] = (
    V1_DDL,
    V2_DDL,
    V3_DDL,
    V4_DDL,
    V5_DDL,
    V6_DDL,
    V7_DDL,
    V8_DDL,
    V9_DDL,
    V10_DDL,
    V11_DDL,
    V12_DDL,
    V13_DDL,
)
SCHEMA_VERSION = len(MIGRATIONS)

# Tables a records database owns; a version-0 file holding anything else is not ours.
OWN_TABLES = frozenset(
    {
        "classes",
        "trainees",
        "attempts",
        "users",
        "trainer_classes",
        "api_tokens",
        "web_sessions",
        "outbox",
        "server_logins",
        "questionnaires",
        "attempt_metrics",
        "attempt_figures",
        "uploads",
        "attempt_recordings",
        "audit_log",
        "rating_sets",
        "rating_items",
        "raters",
        "study_participants",
        "study_designs",
        "ratings",
    }
)
