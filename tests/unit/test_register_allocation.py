"""A study's register and its one allocation sequence (chainsim.game.study.register), on SQLite and
PostgreSQL: slots in registration order, a resend answers the first entry, other covariates are
refused, bad fields are one line, and registrations at once from two connections never share a slot."""

from __future__ import annotations

import sqlite3
import threading

import pytest

from chainsim.game.records.migrations import MIGRATIONS, SCHEMA_VERSION
from chainsim.game.records.store import RecordStore
from chainsim.game.study import register
from chainsim.systems.engine.errors import UserError


def person(code: str, **over) -> dict:
    return {"code": code, "group": "novice", "year_of_training": 2, "procedures_performed": 5, **over}


def test_slots_follow_registration_and_a_resend_answers_the_first(records_db):
    with RecordStore(records_db) as store:
        slots = [register.register(store, "table61", "study", person(c), "tina")[0]["slot"] for c in "ABC"]
        again, created = register.register(store, "table61", "study", person("B"), "tina")
        other, _ = register.register(store, "another", "study", person("A"), "tina")
        assert slots == [0, 1, 2]
        assert (again["slot"], created) == (1, False)
        assert other["slot"] == 0  # each study has its own sequence
        with pytest.raises(register.AlreadyRegistered, match="already in the register"):
            register.register(store, "table61", "study", person("B", year_of_training=3), "tina")
        listed = register.entries(store, "table61")
        assert [(e["code"], e["group"], e["year_of_training"], e["procedures_performed"]) for e in listed] == [
            ("A", "novice", 2, 5),
            ("B", "novice", 2, 5),
            ("C", "novice", 2, 5),
        ]


@pytest.mark.parametrize(
    ("over", "says"),
    [
        ({"year_of_training": -1}, "year_of_training is -1; expected a whole number from 0 to 80"),
        ({"procedures_performed": "many"}, "procedures_performed is 'many'; expected a whole number"),
        ({"group": "senior"}, "group is 'senior'; expected novice or expert"),
        ({"code": ""}, "participant name is empty"),
        ({"age": 40}, "unknown field 'age'"),
    ],
)
def test_a_bad_field_is_one_line_and_nothing_is_saved(tmp_path, over, says):
    with RecordStore(tmp_path / "r.sqlite3") as store:
        with pytest.raises(UserError) as err:
            register.register(store, "table61", "study", {**person("A"), **over}, "tina")
        assert says in str(err.value) and "\n" not in str(err.value)
        assert register.entries(store, "table61") == []


def test_registrations_at_once_never_share_a_slot(records_db):
    """Two connections (two sites' requests) registering at the same time draw distinct, consecutive slots."""
    RecordStore(records_db).close()
    with RecordStore(records_db) as store:  # make the file (SQLite) before the threads open it
        register.register(store, "warm", "study", person("X"), "tina")
    got: dict[str, int] = {}
    errors: list[BaseException] = []
    start = threading.Barrier(2)

    def site(prefix: str) -> None:
        try:
            with RecordStore(records_db) as store:
                start.wait()
                for i in range(12):
                    entry, _ = register.register(store, "table61", "study", person(f"{prefix}{i}"), prefix)
                    got[entry["code"]] = entry["slot"]
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=site, args=(p,)) for p in ("north", "south")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors, errors
    assert sorted(got.values()) == list(range(24))


def test_a_version_10_database_opens_and_gains_the_register(tmp_path):
    path = tmp_path / "v10.sqlite3"
    conn = sqlite3.connect(path)
    for step in MIGRATIONS[:10]:
        for statement in step:
            conn.execute(statement)
    conn.execute("INSERT INTO classes (name) VALUES ('study')")
    conn.execute("PRAGMA user_version = 10")
    conn.commit()
    conn.close()
    with RecordStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert store.list_classes() == ["study"]
        assert register.register(store, "table61", "study", person("A"), "tina")[0]["slot"] == 0


def test_an_allocation_from_a_file_warns_and_one_from_a_shared_database_does_not(records_db):
    """Without a records server the order comes from the --db's register: an SQLite file is one machine's
    (warned), a PostgreSQL database is one every machine can share (its sequence is the study's)."""
    covariates = {"group": "expert", "year_of_training": 6, "procedures_performed": 80}
    got = register.allocate("table61", "study", "A", covariates, None, records_db)
    again = register.allocate("table61", "study", "A", None, None, records_db)
    assert got == again and got["slot"] == 0 and got["group"] == "expert"
    if records_db.startswith("postgresql://"):
        assert "warning" not in got and got["by"].startswith("records database postgresql://")
    else:
        assert "another machine may give the same order" in got["warning"] and got["by"] == "this machine"
    with pytest.raises(UserError, match="'B' is not in the register of study 'table61'"):
        register.allocate("table61", "study", "B", None, None, records_db)
