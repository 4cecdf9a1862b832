BEGIN TRANSACTION;
CREATE TABLE api_tokens (
        id         INTEGER PRIMARY KEY,
        user_id    INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        token_hash TEXT NOT NULL UNIQUE,
        label      TEXT NOT NULL,
        created_at REAL NOT NULL,
        expires_at REAL NOT NULL
    );
CREATE TABLE attempt_metrics (
        id         INTEGER PRIMARY KEY,
        attempt_id INTEGER NOT NULL REFERENCES attempts(id) ON DELETE CASCADE,
        name       TEXT NOT NULL,
        value      REAL,
        UNIQUE (attempt_id, name)
    );
INSERT INTO "attempt_metrics" VALUES(1,1,'duration_s',61.5);
INSERT INTO "attempt_metrics" VALUES(2,1,'landmark_error_mm',4.25);
INSERT INTO "attempt_metrics" VALUES(3,1,'needle_error_mm',-0.75);
INSERT INTO "attempt_metrics" VALUES(4,1,'skull_contacts',2.0);
INSERT INTO "attempt_metrics" VALUES(5,1,'path_length_mm',55.5);
INSERT INTO "attempt_metrics" VALUES(6,1,'redirections',1.0);
INSERT INTO "attempt_metrics" VALUES(7,1,'xray_shots',3.0);
INSERT INTO "attempt_metrics" VALUES(8,1,'exposure_s',0.9);
INSERT INTO "attempt_metrics" VALUES(9,1,'dose_mgy',0.18);
INSERT INTO "attempt_metrics" VALUES(10,1,'first_contact_dist_mm',3.5);
INSERT INTO "attempt_metrics" VALUES(11,1,'peak_force_N',NULL);
INSERT INTO "attempt_metrics" VALUES(12,2,'duration_s',90.0);
INSERT INTO "attempt_metrics" VALUES(13,2,'landmark_error_mm',NULL);
INSERT INTO "attempt_metrics" VALUES(14,2,'needle_error_mm',NULL);
INSERT INTO "attempt_metrics" VALUES(15,2,'skull_contacts',0.0);
INSERT INTO "attempt_metrics" VALUES(16,2,'path_length_mm',12.0);
INSERT INTO "attempt_metrics" VALUES(17,2,'redirections',4.0);
INSERT INTO "attempt_metrics" VALUES(18,2,'xray_shots',0.0);
INSERT INTO "attempt_metrics" VALUES(19,2,'exposure_s',0.0);
INSERT INTO "attempt_metrics" VALUES(20,2,'dose_mgy',0.0);
INSERT INTO "attempt_metrics" VALUES(21,3,'duration_s',33.3);
INSERT INTO "attempt_metrics" VALUES(22,3,'landmark_error_mm',0.1);
INSERT INTO "attempt_metrics" VALUES(23,3,'needle_error_mm',2.2);
INSERT INTO "attempt_metrics" VALUES(24,3,'skull_contacts',5.0);
INSERT INTO "attempt_metrics" VALUES(25,3,'path_length_mm',70.25);
INSERT INTO "attempt_metrics" VALUES(26,3,'redirections',2.0);
INSERT INTO "attempt_metrics" VALUES(27,3,'xray_shots',0.0);
INSERT INTO "attempt_metrics" VALUES(28,3,'exposure_s',12.5);
INSERT INTO "attempt_metrics" VALUES(29,3,'dose_mgy',2.5);
CREATE TABLE attempt_recordings (
        id         INTEGER PRIMARY KEY,
        attempt_id INTEGER NOT NULL UNIQUE REFERENCES attempts(id) ON DELETE CASCADE,
        recording  TEXT NOT NULL
    );
CREATE TABLE attempts (
        id                INTEGER PRIMARY KEY,
        trainee_id        INTEGER NOT NULL REFERENCES trainees(id) ON DELETE CASCADE,
        pack              TEXT NOT NULL,
        created_at        TEXT NOT NULL,
        duration_s        REAL NOT NULL,
        landmark_error_mm REAL NOT NULL,
        needle_error_mm   REAL,
        target            TEXT NOT NULL,
        skull_contacts    INTEGER NOT NULL,
        path_length_mm    REAL NOT NULL,
        aids              TEXT NOT NULL,
        step_times        TEXT NOT NULL
    , details TEXT NOT NULL DEFAULT '{}', redirections INTEGER NOT NULL DEFAULT 0, idem_key TEXT, xray_shots INTEGER NOT NULL DEFAULT 0, exposure_s REAL NOT NULL DEFAULT 0, dose_mgy REAL NOT NULL DEFAULT 0, filed_by TEXT, client_created_at TEXT, pack_version TEXT, pack_hash TEXT, client_figures TEXT, differences TEXT NOT NULL DEFAULT '[]', retracted_at TEXT, retracted_by TEXT, retract_reason TEXT, source TEXT NOT NULL DEFAULT 'local', flags TEXT NOT NULL DEFAULT '[]', accepted_by TEXT, accepted_at TEXT);
INSERT INTO "attempts" VALUES(1,1,'prp','2026-03-01T09:15:00Z',61.5,4.25,-0.75,'foramen_ovale_left',2,55.5,'{"collision_signals":false,"landmark_planes":false,"reference_planes":true,"skin_transparent":false,"tip_view":true}','{"insert":41.5,"landmarks":20.0}','{"D1":1.5,"d1":0.25,"landmarks":[[1.0,2.0,3.0],null,[4.0,5.5,6.0]],"side":"left"}',1,NULL,3,0.9,0.18,NULL,NULL,NULL,NULL,NULL,'[]',NULL,NULL,NULL,'local','[]',NULL,NULL);
INSERT INTO "attempts" VALUES(2,1,'prp','2026-03-02T09:15:00Z',90.0,0.0,NULL,'skull',0,12.0,'{"collision_signals":false,"landmark_planes":false,"reference_planes":false,"skin_transparent":false,"tip_view":false}','{"insert":90.0}','{}',0,NULL,0,0.0,0.0,NULL,NULL,NULL,NULL,NULL,'[]',NULL,NULL,NULL,'local','[]',NULL,NULL);
INSERT INTO "attempts" VALUES(3,2,'needle_demo','2026-03-03T10:00:00Z',33.3,0.1,2.2,'foramen_ovale_right',5,70.25,'{"collision_signals":true,"landmark_planes":true,"reference_planes":true,"skin_transparent":true,"tip_view":true}','{}','{"side":"right"}',2,NULL,0,12.5,2.5,NULL,NULL,NULL,NULL,NULL,'[]',NULL,NULL,NULL,'local','[]',NULL,NULL);
CREATE TABLE audit_log (
        id         INTEGER PRIMARY KEY,
        at         TEXT NOT NULL,
        actor      TEXT NOT NULL,
        action     TEXT NOT NULL,
        attempt_id INTEGER,
        class_name TEXT NOT NULL,
        detail     TEXT NOT NULL
    );
CREATE TABLE classes (
        id   INTEGER PRIMARY KEY,
        name TEXT NOT NULL UNIQUE
    , require_witnessed INTEGER NOT NULL DEFAULT 0);
INSERT INTO "classes" VALUES(1,'c1',0);
INSERT INTO "classes" VALUES(2,'c2',0);
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
    );
CREATE TABLE questionnaires (
        id         INTEGER PRIMARY KEY,
        trainee_id INTEGER NOT NULL REFERENCES trainees(id) ON DELETE CASCADE,
        kind       TEXT NOT NULL,
        session    TEXT NOT NULL,
        created_at TEXT NOT NULL,
        answers    TEXT NOT NULL
    );
CREATE TABLE raters (
        id         INTEGER PRIMARY KEY,
        set_id     INTEGER NOT NULL REFERENCES rating_sets(id) ON DELETE CASCADE,
        name       TEXT NOT NULL,
        token_hash TEXT NOT NULL UNIQUE,
        UNIQUE (set_id, name)
    );
CREATE TABLE rating_items (
        id         INTEGER PRIMARY KEY,
        set_id     INTEGER NOT NULL REFERENCES rating_sets(id) ON DELETE CASCADE,
        code       TEXT NOT NULL UNIQUE,
        attempt_id INTEGER NOT NULL REFERENCES attempts(id) ON DELETE CASCADE,
        UNIQUE (set_id, attempt_id)
    );
CREATE TABLE rating_sets (
        id         INTEGER PRIMARY KEY,
        name       TEXT NOT NULL UNIQUE,
        created_by TEXT NOT NULL,
        created_at TEXT NOT NULL,
        form       TEXT NOT NULL
    );
CREATE TABLE ratings (
        id       INTEGER PRIMARY KEY,
        item_id  INTEGER NOT NULL REFERENCES rating_items(id) ON DELETE CASCADE,
        rater_id INTEGER NOT NULL REFERENCES raters(id) ON DELETE CASCADE,
        scores   TEXT NOT NULL,
        total    REAL NOT NULL,
        rated_at TEXT NOT NULL,
        UNIQUE (item_id, rater_id)
    );
CREATE TABLE server_logins (
        id        INTEGER PRIMARY KEY,
        server    TEXT NOT NULL UNIQUE,
        user_name TEXT NOT NULL,
        role      TEXT NOT NULL,
        token     TEXT NOT NULL,
        saved_at  TEXT NOT NULL
    , ca_pem TEXT);
CREATE TABLE study_designs (
        id        INTEGER PRIMARY KEY,
        study     TEXT NOT NULL UNIQUE,
        design    TEXT NOT NULL,
        filed_by  TEXT NOT NULL,
        filed_at  TEXT NOT NULL
    );
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
    );
CREATE TABLE trainees (
        id       INTEGER PRIMARY KEY,
        class_id INTEGER NOT NULL REFERENCES classes(id) ON DELETE CASCADE,
        name     TEXT NOT NULL,
        UNIQUE (class_id, name)
    );
INSERT INTO "trainees" VALUES(1,1,'alice');
INSERT INTO "trainees" VALUES(2,2,'bob');
CREATE TABLE trainer_classes (
        id       INTEGER PRIMARY KEY,
        user_id  INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        class_id INTEGER NOT NULL REFERENCES classes(id) ON DELETE CASCADE,
        UNIQUE (user_id, class_id)
    );
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
    , witnessed INTEGER NOT NULL DEFAULT 0);
CREATE TABLE users (
        id            INTEGER PRIMARY KEY,
        name          TEXT NOT NULL UNIQUE,
        role          TEXT NOT NULL CHECK (role IN ('trainer', 'trainee')),
        password_hash TEXT NOT NULL,
        trainee_id    INTEGER UNIQUE REFERENCES trainees(id) ON DELETE SET NULL,
        created_at    TEXT NOT NULL
    );
CREATE TABLE web_sessions (
        id           INTEGER PRIMARY KEY,
        user_id      INTEGER NOT NULL REFERENCES users(id) ON DELETE CASCADE,
        session_hash TEXT NOT NULL UNIQUE,
        csrf         TEXT NOT NULL,
        created_at   REAL NOT NULL,
        expires_at   REAL NOT NULL
    );
CREATE INDEX attempts_by_trainee ON attempts (trainee_id, created_at, id);
CREATE UNIQUE INDEX attempts_by_key ON attempts (idem_key);
CREATE INDEX uploads_by_state ON uploads (state, id);
CREATE INDEX uploads_by_trainee ON uploads (class_name, trainee, state, id);
COMMIT;
PRAGMA user_version = 12;
