"""RecordStore: round trips, names, validation, default location, migrations, refused files.

Tests taking ``records_db`` run on an SQLite file and on a real PostgreSQL database (tests/records_db.py).
"""

from __future__ import annotations

import json
import sqlite3
from datetime import UTC
from pathlib import Path

import pytest

from chainsim.game.records.migrations import MIGRATIONS, SCHEMA_VERSION, V1_DDL
from chainsim.game.records.store import ENV_VAR, RecordStore, default_path
from chainsim.game.records.validate import AIDS
from chainsim.systems.engine.errors import UserError


def sample_attempt(i: int = 0, **over):
    a = {
        "pack": "prp",
        "created_at": f"2026-03-0{1 + i % 9}T09:15:00Z",
        "duration_s": 60.0 + i,
        "landmark_error_mm": 4.5 - 0.5 * i,
        "needle_error_mm": 12.0 - i,
        "target": "foramen_ovale_left",
        "skull_contacts": i,
        "path_length_mm": 55.5,
        "aids": {"tip_view": True, "reference_planes": i % 2 == 0},
        "step_times": {"landmarks": 20.0, "insert": 40.0 + i},
        "details": {"D1": 1.5, "d1": 0.25, "marks": [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]},
    }
    a.update(over)
    return a


@pytest.fixture
def store(records_db):
    with RecordStore(records_db) as s:
        yield s


def one_line_error(excinfo) -> str:
    msg = str(excinfo.value)
    assert msg and "\n" not in msg
    return msg


# -- round trip -------------------------------------------------------------------------------


def test_attempt_round_trip_keeps_every_field(store):
    a = sample_attempt(2, needle_error_mm=-1.25, details={"D2": 0.0, "nested": {"ok": True, "n": 3}})
    aid = store.save_attempt(" c1 ", " alice ", a)
    got = store.get_attempt(aid)
    assert got["id"] == aid
    assert got["class_name"] == "c1" and got["trainee"] == "alice"
    for key in (
        "pack",
        "created_at",
        "duration_s",
        "landmark_error_mm",
        "needle_error_mm",
        "target",
        "skull_contacts",
        "path_length_mm",
        "step_times",
        "details",
    ):
        assert got[key] == a[key], key
    # Aids left out were off; all five are always present.
    assert got["aids"] == {name: name in ("tip_view", "reference_planes") for name in AIDS}
    assert store.list_attempts() == [got]


def test_needle_error_none_means_no_contact(store):
    aid = store.save_attempt("c1", "alice", sample_attempt(needle_error_mm=None, target="none"))
    got = store.get_attempt(aid)
    assert got["needle_error_mm"] is None and got["target"] == "none"


def test_created_at_defaults_to_now_utc(store):
    a = sample_attempt()
    del a["created_at"]
    got = store.get_attempt(store.save_attempt("c1", "alice", a))
    from datetime import datetime

    stamp = datetime.fromisoformat(got["created_at"])
    assert stamp.utcoffset().total_seconds() == 0
    assert abs((datetime.now(UTC) - stamp).total_seconds()) < 3600


def test_numpy_numbers_are_accepted_as_plain_values(store):
    np = pytest.importorskip("numpy")
    a = sample_attempt(
        skull_contacts=np.int64(3), landmark_error_mm=np.float64(2.5), details={"pos": np.array([1.0, 2.0, 3.0])}
    )
    got = store.get_attempt(store.save_attempt("c1", "alice", a))
    assert got["skull_contacts"] == 3 and got["landmark_error_mm"] == 2.5
    assert got["details"]["pos"] == [1.0, 2.0, 3.0]


def test_list_filters_and_order(store):
    ids = {}
    for who, cls, day in (("bob", "c1", 3), ("alice", "c1", 2), ("alice", "c1", 1), ("alice", "c2", 5)):
        ids[(who, cls, day)] = store.save_attempt(cls, who, sample_attempt(day - 1))
    alice_c1 = store.list_attempts("c1", "alice")
    # Oldest first by created_at, not by insertion order.
    assert [a["id"] for a in alice_c1] == [ids[("alice", "c1", 1)], ids[("alice", "c1", 2)]]
    assert {a["class_name"] for a in store.list_attempts(trainee="alice")} == {"c1", "c2"}
    assert len(store.list_attempts("c1")) == 3
    assert len(store.list_attempts()) == 4


def test_classes_and_trainees(store):
    store.add_class("c3")
    assert store.add_trainee("c3", "carol") is False
    assert store.add_trainee("c9", "dave") is True  # class made on demand
    store.save_attempt("c1", "alice", sample_attempt())
    assert store.list_classes() == ["c1", "c3", "c9"]
    assert store.list_trainees("c3") == [{"class_name": "c3", "trainee": "carol", "attempts": 0}]
    assert [t["trainee"] for t in store.list_trainees()] == ["alice", "carol", "dave"]
    summary = {r["class_name"]: (r["trainees"], r["attempts"]) for r in store.class_summary()}
    assert summary == {"c1": (1, 1), "c3": (1, 0), "c9": (1, 0)}


def test_same_trainee_name_in_two_classes_is_two_trainees(store):
    store.save_attempt("c1", "alice", sample_attempt())
    store.save_attempt("c2", "alice", sample_attempt())
    assert [(t["class_name"], t["attempts"]) for t in store.list_trainees()] == [("c1", 1), ("c2", 1)]


def test_duplicate_names_are_refused(store):
    store.add_class("c1")
    with pytest.raises(UserError) as e:
        store.add_class(" c1")
    assert "already exists" in one_line_error(e)
    store.add_trainee("c1", "alice")
    with pytest.raises(UserError) as e:
        store.add_trainee("c1", "alice ")
    assert "already exists" in one_line_error(e)


def test_delete_attempt(store):
    keep = store.save_attempt("c1", "alice", sample_attempt(0))
    gone = store.save_attempt("c1", "alice", sample_attempt(1))
    store.delete_attempt(gone)
    assert [a["id"] for a in store.list_attempts()] == [keep]
    with pytest.raises(UserError) as e:
        store.delete_attempt(gone)
    assert f"no attempt with id {gone}" in one_line_error(e)
    with pytest.raises(UserError) as e:
        store.get_attempt(gone)
    assert str(gone) in one_line_error(e)


def test_unknown_filters_are_errors_not_empty_lists(store):
    store.save_attempt("c1", "alice", sample_attempt())
    with pytest.raises(UserError) as e:
        store.list_attempts("nope")
    assert "'nope'" in one_line_error(e) and "c1" in str(e.value)
    with pytest.raises(UserError) as e:
        store.list_attempts("c1", "zed")
    assert "'zed'" in one_line_error(e)
    with pytest.raises(UserError):
        store.list_trainees("nope")


def test_second_connection_sees_saves_and_closed_store_refuses(records_db):
    with RecordStore(records_db) as a, RecordStore(records_db) as b:
        aid = a.save_attempt("c1", "alice", sample_attempt())
        assert b.get_attempt(aid)["trainee"] == "alice"
    with pytest.raises(UserError):
        a.list_classes()


# -- validation -------------------------------------------------------------------------------

BAD_ATTEMPTS = [
    ({"duration_s": float("nan")}, "duration_s"),
    ({"landmark_error_mm": float("inf")}, "landmark_error_mm"),
    ({"landmark_error_mm": -0.1}, "landmark_error_mm"),
    ({"needle_error_mm": float("-inf")}, "needle_error_mm"),
    ({"path_length_mm": -1.0}, "path_length_mm"),
    ({"duration_s": "12"}, "duration_s"),
    ({"duration_s": True}, "duration_s"),
    ({"skull_contacts": -1}, "skull_contacts"),
    ({"skull_contacts": 1.5}, "skull_contacts"),
    ({"target": "Foramen Ovale"}, "target"),
    ({"target": ""}, "target"),
    ({"target": None}, "target"),
    ({"aids": {"xray": True}}, "xray"),
    ({"aids": {"tip_view": 1}}, "tip_view"),
    ({"aids": ["tip_view"]}, "aids"),
    ({"step_times": {"insert": -2.0}}, "step_times.insert"),
    ({"step_times": {"bad step": 1.0}}, "bad step"),
    ({"details": {"D1": float("nan")}}, "details.D1"),
    ({"details": {"pos": [1.0, float("inf")]}}, "details.pos[1]"),
    ({"details": {"obj": object()}}, "details.obj"),
    ({"created_at": "yesterday"}, "created_at"),
    ({"created_at": "2026-03-01T09:15:00+02:00"}, "UTC"),
    ({"created_at": "2026-03-01T09:15:00"}, "UTC"),
    ({"pack": "  "}, "pack"),
    ({"landmark_eror_mm": 1.0}, "landmark_eror_mm"),
]


@pytest.mark.parametrize("change,named", BAD_ATTEMPTS, ids=[n for _, n in BAD_ATTEMPTS])
def test_bad_attempt_fields_give_one_clear_line_and_save_nothing(store, change, named):
    with pytest.raises(UserError) as e:
        store.save_attempt("c1", "alice", sample_attempt(**change))
    assert named in one_line_error(e)
    assert store.list_attempts() == [] and store.list_classes() == []


def test_missing_required_field_is_named(store):
    a = sample_attempt()
    del a["target"]
    with pytest.raises(UserError) as e:
        store.save_attempt("c1", "alice", a)
    assert "'target'" in one_line_error(e)


@pytest.mark.parametrize(
    "name,why",
    [
        ("", "empty"),
        ("   ", "empty"),
        ("x" * 65, "65 characters"),
        ("bad\tname", "control"),
        ("bell\x07", "control"),
        (42, "text"),
    ],
)
def test_bad_names(store, name, why):
    with pytest.raises(UserError) as e:
        store.add_class(name)
    assert why in one_line_error(e)
    with pytest.raises(UserError) as e:
        store.save_attempt("c1", name, sample_attempt())
    assert "trainee" in one_line_error(e)
    assert store.list_classes() == []


def test_name_limits_accepted(store):
    store.add_trainee("x" * 64, "Ünïcode näme")
    assert store.list_trainees()[0]["trainee"] == "Ünïcode näme"


def test_pack_named_targets_accepted(store):
    for target in ("foramen_ovale_right", "skull", "mandible", "zygomatic_arch"):
        store.save_attempt("c1", "alice", sample_attempt(target=target))
    assert [a["target"] for a in store.list_attempts()][-1] == "zygomatic_arch"


# -- where the database lives -----------------------------------------------------------------


def test_default_path_uses_user_data_dir_and_creates_folders(tmp_path, monkeypatch):
    import platformdirs

    asked = []
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setattr(platformdirs, "user_data_dir", lambda app: asked.append(app) or str(tmp_path / "a" / "b"))
    with RecordStore() as s:
        s.add_class("c1")
    assert asked and asked[0] == "chainsim"
    assert (tmp_path / "a" / "b" / "records.sqlite3").is_file()


def test_env_var_overrides_default(tmp_path, monkeypatch):
    target = tmp_path / "deep" / "er" / "env.sqlite3"
    monkeypatch.setenv(ENV_VAR, str(target))
    assert default_path() == target
    with RecordStore() as s:
        s.add_class("c1")
    with RecordStore(target) as s:
        assert s.list_classes() == ["c1"]


def test_database_uses_wal(tmp_path):
    with RecordStore(tmp_path / "r.sqlite3"):
        pass
    assert not (tmp_path / "r.sqlite3").exists()  # made by the first write, not by opening
    with RecordStore(tmp_path / "r.sqlite3") as s:
        s.add_class("c1")
    conn = sqlite3.connect(tmp_path / "r.sqlite3")
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    conn.close()


# -- migrations -------------------------------------------------------------------------------


def make_v1(path: Path) -> None:
    conn = sqlite3.connect(path)
    for stmt in V1_DDL:
        conn.execute(stmt)
    conn.execute("INSERT INTO classes (name) VALUES ('c1')")
    conn.execute("INSERT INTO trainees (class_id, name) VALUES (1, 'alice')")
    for i in range(3):
        conn.execute(
            "INSERT INTO attempts (trainee_id, pack, created_at, duration_s, landmark_error_mm, "
            "needle_error_mm, target, skull_contacts, path_length_mm, aids, step_times) "
            "VALUES (1, 'prp', ?, ?, ?, ?, 'skull', ?, 50.0, ?, '{}')",
            (
                f"2025-01-0{i + 1}T10:00:00Z",
                30.0 + i,
                5.0 - i,
                None if i == 0 else 8.0 - i,
                i,
                json.dumps({name: False for name in AIDS}),
            ),
        )
    conn.execute("PRAGMA user_version = 1")
    conn.commit()
    conn.close()


def raw_attempts(conn: sqlite3.Connection) -> list[dict]:
    """The attempts table's rows as an old chainsim stored them, by column."""
    cur = conn.execute("SELECT * FROM attempts ORDER BY id")
    return [dict(zip([c[0] for c in cur.description], row)) for row in cur]


def assert_fields_kept(store: RecordStore, before: list[dict]) -> None:
    """Every field each attempt had, read by name (the figures from their rows since version 13)."""
    for old in before:
        got = store.get_attempt(old["id"])
        for key, value in old.items():
            if key not in ("trainee_id", "idem_key"):  # the store keeps them, an attempt does not show them
                assert (json.dumps(got[key]) if key in ("aids", "step_times", "details") else got[key]) == value, key


def test_v1_database_is_migrated_in_place_with_rows_intact(tmp_path):
    path = tmp_path / "old.sqlite3"
    make_v1(path)
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION == 13
        rows = s.list_attempts()
        assert [r["created_at"] for r in rows] == [f"2025-01-0{i + 1}T10:00:00Z" for i in range(3)]
        assert [r["needle_error_mm"] for r in rows] == [None, 7.0, 6.0]
        assert [r["landmark_error_mm"] for r in rows] == [5.0, 4.0, 3.0]
        assert all(r["details"] == {} for r in rows)
        new = s.save_attempt("c1", "alice", sample_attempt())
        assert s.get_attempt(new)["details"]["D1"] == 1.5
    conn = sqlite3.connect(path)
    cols = [r[1] for r in conn.execute("PRAGMA table_info(attempts)")]
    indexes = [r[1] for r in conn.execute("PRAGMA index_list(attempts)")]
    assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    conn.close()
    assert "details" in cols and "attempts_by_trainee" in indexes


def test_v2_database_keeps_its_rows_and_gains_redirections(tmp_path):
    """Version 3 adds redirections per attempt; attempts saved by an older chainsim keep every field."""
    from chainsim.game.records.migrations import V2_DDL

    path = tmp_path / "v2.sqlite3"
    make_v1(path)
    conn = sqlite3.connect(path)
    for stmt in V2_DDL:
        conn.execute(stmt)
    conn.execute("UPDATE attempts SET details = '{\"D1\": 2.5}' WHERE id = 2")
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    before = raw_attempts(conn)
    conn.close()
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        rows = s.list_attempts()
        assert [r["redirections"] for r in rows] == [0, 0, 0]
        assert rows[1]["details"] == {"D1": 2.5}
        assert [r["duration_s"] for r in rows] == [30.0, 31.0, 32.0]
        new = s.save_attempt("c1", "alice", {**sample_attempt(), "redirections": 2})
        assert s.get_attempt(new)["redirections"] == 2
        assert_fields_kept(s, before)


def test_v4_database_keeps_its_rows_and_gains_xray_costs_and_questionnaires(tmp_path):
    """Version 5 adds the X-ray each attempt cost and the study questionnaires; rows saved before it keep
    every field and read as attempts without X-ray."""
    from chainsim.game.records.migrations import V2_DDL, V3_DDL, V4_DDL

    path = tmp_path / "v4.sqlite3"
    make_v1(path)
    conn = sqlite3.connect(path)
    for stmt in V2_DDL + V3_DDL + V4_DDL:
        conn.execute(stmt)
    conn.execute("UPDATE attempts SET redirections = 2 WHERE id = 3")
    conn.execute("PRAGMA user_version = 4")
    conn.commit()
    before = raw_attempts(conn)
    conn.close()
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION  # through versions 5, 6 and 7, and on to the newest
        rows = s.list_attempts()
        assert [(r["xray_shots"], r["exposure_s"], r["dose_mgy"]) for r in rows] == [(0, 0.0, 0.0)] * 3
        assert [r["redirections"] for r in rows] == [0, 0, 2]
        new = s.save_attempt("c1", "alice", {**sample_attempt(), "xray_shots": 4, "exposure_s": 3.2, "dose_mgy": 0.64})
        got = s.get_attempt(new)
        assert (got["xray_shots"], got["exposure_s"], got["dose_mgy"]) == (4, 3.2, 0.64)
        qid = s.save_questionnaire("c1", "alice", "post", "s1", {"local_viewer": 9, "remarks": "fine"})
        assert s.list_questionnaires("c1")[0]["id"] == qid
        assert s.list_questionnaires("c1")[0]["answers"] == {"local_viewer": 9, "remarks": "fine"}
        assert_fields_kept(s, before)


@pytest.mark.parametrize(
    "field,value,needle",
    [
        ("xray_shots", -1, "'xray_shots' is -1"),
        ("xray_shots", 1.5, "'xray_shots' must be a whole number"),
        ("exposure_s", float("nan"), "'exposure_s' is nan"),
        ("dose_mgy", -0.1, "'dose_mgy' is -0.1"),
    ],
)
def test_bad_xray_fields_are_refused_with_one_line(tmp_path, field, value, needle):
    with RecordStore(tmp_path / "r.sqlite3") as s:
        with pytest.raises(UserError, match=needle):
            s.save_attempt("c1", "alice", {**sample_attempt(), field: value})
        assert s.list_classes() == []


def test_questionnaires_refuse_bad_kinds_and_answers(tmp_path):
    with RecordStore(tmp_path / "r.sqlite3") as s:
        with pytest.raises(UserError, match="questionnaire kind is 'during'"):
            s.save_questionnaire("c1", "alice", "during", "s1", {})
        with pytest.raises(UserError, match="answer 'q1' holds list"):
            s.save_questionnaire("c1", "alice", "pre", "s1", {"q1": [1, 2]})
        with pytest.raises(UserError, match="'answers.q1' is inf"):
            s.save_questionnaire("c1", "alice", "pre", "s1", {"q1": float("inf")})
        with pytest.raises(UserError, match="answer 'q1' must be printable text"):
            s.save_questionnaire("c1", "alice", "pre", "s1", {"q1": "ok\x1b[2J"})
        assert s.list_classes() == []


def test_reopening_current_database_is_a_no_op(tmp_path):
    path = tmp_path / "r.sqlite3"
    with RecordStore(path) as s:
        aid = s.save_attempt("c1", "alice", sample_attempt())
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        assert s.get_attempt(aid)["trainee"] == "alice"


def test_failed_migration_leaves_database_at_old_version(tmp_path, monkeypatch):
    import chainsim.game.records.store as records

    path = tmp_path / "old.sqlite3"
    make_v1(path)
    broken = (records.MIGRATIONS[0], ("ALTER TABLE attempts ADD COLUMN details TEXT", "THIS IS NOT SQL"))
    monkeypatch.setattr(records, "MIGRATIONS", broken)
    with pytest.raises(UserError):
        RecordStore(path)
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == 1
    assert "details" not in [r[1] for r in conn.execute("PRAGMA table_info(attempts)")]
    assert conn.execute("SELECT COUNT(*) FROM attempts").fetchone()[0] == 3
    conn.close()


# -- files that are not ours ------------------------------------------------------------------


def assert_refused_untouched(path: Path, expect: str) -> None:
    before = path.read_bytes()
    with pytest.raises(UserError) as e:
        RecordStore(path)
    assert expect in one_line_error(e) and str(path) in str(e.value)
    assert path.read_bytes() == before
    assert not Path(f"{path}-wal").exists()


def test_text_file_is_refused_untouched(tmp_path):
    path = tmp_path / "notes.sqlite3"
    path.write_text("these are my notes, not a database\n" * 50)
    assert_refused_untouched(path, "not an SQLite database")


def test_corrupted_database_is_refused_untouched(tmp_path):
    path = tmp_path / "r.sqlite3"
    with RecordStore(path) as s:
        for i in range(40):
            s.save_attempt("c1", f"t{i}", sample_attempt(i % 5, details={"pad": "x" * 1500}))
    # Move everything into the main file (and drop the WAL) so the damage below is all there is.
    conn = sqlite3.connect(path)
    conn.execute("PRAGMA journal_mode = DELETE")
    conn.close()
    data = bytearray(path.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    for p in range(1, len(data) // page):
        data[p * page : p * page + 12] = b"\xa5" * 12  # wreck each b-tree page header
    path.write_bytes(bytes(data))
    assert_refused_untouched(path, "damaged")


def test_other_sqlite_database_is_refused_untouched(tmp_path):
    path = tmp_path / "other.db"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE invoices (id INTEGER PRIMARY KEY, amount REAL)")
    conn.commit()
    conn.close()
    assert_refused_untouched(path, "something else")


def test_newer_schema_is_refused_untouched(tmp_path):
    path = tmp_path / "future.sqlite3"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE classes (id INTEGER PRIMARY KEY, name TEXT)")
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    conn.commit()
    conn.close()
    assert_refused_untouched(path, "schema version")


def test_directory_is_refused(tmp_path):
    with pytest.raises(UserError) as e:
        RecordStore(tmp_path)
    assert "directory" in one_line_error(e)


def test_empty_file_becomes_a_database(tmp_path):
    path = tmp_path / "empty.sqlite3"
    path.touch()
    with RecordStore(path) as s:
        s.add_class("c1")
        assert s.list_classes() == ["c1"]
    assert path.stat().st_size > 0


def test_v5_rhizotomy_rows_migrate_to_the_metrics_table_and_lose_nothing(tmp_path):
    """Version 6 adds the procedure-neutral metrics table: every fixed-column value of an attempt saved
    before it is there under the column's name, and every column still reads as it did."""
    from chainsim.game.records.migrations import LEGACY_METRICS, MIGRATIONS

    path = tmp_path / "v5.sqlite3"
    make_v1(path)
    conn = sqlite3.connect(path)
    for step in MIGRATIONS[1:5]:
        for stmt in step:
            conn.execute(stmt)
    conn.execute(
        "UPDATE attempts SET redirections = id, xray_shots = 2 * id, exposure_s = 0.3 * id, dose_mgy = 0.06 * id, "
        "details = ?",
        (json.dumps({"side": "left", "D1": 1.5, "landmarks": [[1.0, 2.0, 3.0]]}),),
    )
    conn.execute("PRAGMA user_version = 5")
    conn.commit()
    before = [
        dict(zip([c[0] for c in cur.description], row))
        for cur in [conn.execute("SELECT * FROM attempts")]
        for row in cur
    ]
    conn.close()
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        rows = s.list_attempts()
        assert len(rows) == len(before) == 3
        for old, new in zip(before, rows):
            for key in ("created_at", "pack", "target", *LEGACY_METRICS):
                assert new[key] == old[key], key
            assert new["details"] == json.loads(old["details"]) and new["aids"] == json.loads(old["aids"])
            assert new["metrics"] == {
                name: (None if old[name] is None else float(old[name])) for name in LEGACY_METRICS
            }
        # a new attempt keeps its procedure's own metrics beside the fixed ones, with no new column
        rid = s.save_attempt("c1", "alice", dict(sample_attempt(), metrics={"first_contact_dist_mm": 3.5, "x": None}))
        got = s.get_attempt(rid)["metrics"]
        assert got["first_contact_dist_mm"] == 3.5 and got["x"] is None and got["landmark_error_mm"] == 4.5
        s.delete_attempt(rid)
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT COUNT(*) FROM attempt_metrics WHERE attempt_id = ?", (rid,)).fetchone()[0] == 0
    assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    conn.close()


def test_metrics_that_are_not_numbers_are_refused(tmp_path):
    with RecordStore(tmp_path / "m.sqlite3") as s:
        with pytest.raises(UserError, match="metric"):
            s.save_attempt("c1", "alice", dict(sample_attempt(), metrics={"bad name": 1.0}))
        with pytest.raises(UserError, match="metric"):
            s.save_attempt("c1", "alice", dict(sample_attempt(), metrics={"x": float("nan")}))


def test_v7_sign_ins_are_kept_and_trust_the_systems_authorities_after_migration(tmp_path):
    path = tmp_path / "simulator.sqlite3"
    conn = sqlite3.connect(path)
    for step in MIGRATIONS[:7]:
        for stmt in step:
            conn.execute(stmt)
    conn.execute(
        "INSERT INTO server_logins (server, user_name, role, token, saved_at) "
        "VALUES ('https://records.example.org', 'alice', 'trainee', 'tok', '2026-01-01T00:00:00+00:00')"
    )
    conn.execute("PRAGMA user_version = 7")
    conn.commit()
    conn.close()
    with RecordStore(path) as s:
        assert s.schema_version == SCHEMA_VERSION
        rows = s.query("SELECT server, user_name, token, ca_pem FROM server_logins")
        assert [tuple(r) for r in rows] == [("https://records.example.org", "alice", "tok", None)]
