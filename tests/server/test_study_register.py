"""The study register on the records server (/api/studies, chainsim.game.server.study_api), on SQLite and
PostgreSQL: trainers register participants of their classes with their covariates and get the next slot
of the study's one sequence; two clients registering at once never get the same slot; trainees and other
classes' trainers are refused; a bad field is a 422 naming it."""

from __future__ import annotations

import threading
import uuid

from conftest import REPO, call


def person(code: str, **over) -> dict:
    return {
        "class_name": "c1",
        "code": code,
        "group": "novice",
        "year_of_training": 1,
        "procedures_performed": 0,
        **over,
    }


def test_a_trainer_registers_and_the_slots_follow_one_sequence(site):
    study = f"s-{uuid.uuid4().hex[:8]}"
    path = f"/api/studies/{study}/participants"
    tina = site.tokens["tina"]
    first = call(site, "POST", path, person("P1"), tina)
    second = call(site, "POST", path, person("P2", group="expert", year_of_training=6), tina)
    again = call(site, "POST", path, person("P1"), tina)
    assert (first[0], first[1]["slot"], second[0], second[1]["slot"]) == (201, 0, 201, 1)
    assert (again[0], again[1]["slot"]) == (200, 0)
    changed = call(site, "POST", path, person("P1", procedures_performed=9), tina)
    assert changed[0] == 409 and "already in the register" in changed[1]["error"]
    status, listed, _ = call(site, "GET", path, token=tina)
    assert status == 200
    assert [(p["code"], p["group"], p["year_of_training"], p["slot"]) for p in listed["participants"]] == [
        ("P1", "novice", 1, 0),
        ("P2", "expert", 6, 1),
    ]
    assert call(site, "GET", f"{path}/P2", token=tina)[1]["slot"] == 1
    assert call(site, "GET", f"{path}/nobody", token=tina)[0] == 404


def test_bad_fields_and_people_without_the_right_are_refused(site):
    path = f"/api/studies/s-{uuid.uuid4().hex[:8]}/participants"
    bad = call(site, "POST", path, person("P1", year_of_training="x"), site.tokens["tina"])
    assert bad[0] == 422 and "year_of_training is 'x'; expected a whole number" in bad[1]["error"]
    assert call(site, "POST", path, person("P1"), site.tokens["alice"])[0] == 403  # a trainee
    assert call(site, "POST", path, person("P1"), site.tokens["tom"])[0] == 403  # teaches c2, not c1
    assert call(site, "GET", path, token=site.tokens["alice"])[0] == 403
    assert call(site, "POST", path, person("P1"))[0] == 401
    assert call(site, "GET", path, token=site.tokens["tina"])[1]["participants"] == []


def test_two_clients_registering_at_once_never_share_a_slot(site):
    path = f"/api/studies/s-{uuid.uuid4().hex[:8]}/participants"
    slots: list[int] = []
    statuses: list[int] = []
    start = threading.Barrier(2)

    def client(prefix: str) -> None:
        start.wait()
        for i in range(10):
            status, answer, _ = call(site, "POST", path, person(f"{prefix}{i}"), site.tokens["tina"])
            statuses.append(status)
            slots.append(answer["slot"])

    threads = [threading.Thread(target=client, args=(p,)) for p in ("a", "b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert statuses == [201] * 20
    assert sorted(slots) == list(range(20))


def test_two_machines_draw_from_the_servers_one_sequence(site, tmp_path, cli, monkeypatch):
    """`chainsim protocol --register --records URL` on two machines (two local databases): the slots and
    orders come from the server's sequence, not each machine's own, so they differ; no warning is given."""
    study = f"s{uuid.uuid4().hex[:8]}"
    proto = tmp_path / f"{study}.toml"
    text = (REPO / "assets" / "prp" / "protocols" / "table61.toml").read_text()
    proto.write_text(text.replace('pack = "prp"', 'pack = "prp"\npractice = 1', 1))
    monkeypatch.setenv("CHAINSIM_RECORDS_TOKEN", site.tokens["tina"])
    entry = ["--group", "expert", "--year-of-training", "4", "--procedures-performed", "30", "--class", "c1"]
    outs = []
    for machine, code in (("north", "P1"), ("south", "P2")):
        db = tmp_path / f"{machine}.sqlite3"
        rc, out, err = cli("protocol", proto, "--register", code, *entry, "--records", site.url, "--db", db)
        assert rc == 0, err
        assert "another machine" not in err
        outs.append(out)
    assert "slot 0" in outs[0] and "slot 1" in outs[1]
    assert outs[0].splitlines()[1] != outs[1].splitlines()[1]  # the next row of the design: another order
    status, listed, _ = call(site, "GET", f"/api/studies/{study}/participants", token=site.tokens["tina"])
    assert [(p["code"], p["year_of_training"], p["procedures_performed"]) for p in listed["participants"]] == [
        ("P1", 4, 30),
        ("P2", 4, 30),
    ]


def test_without_the_server_allocation_is_refused_in_one_line(tmp_path, cli, monkeypatch):
    monkeypatch.setenv("CHAINSIM_RECORDS_TOKEN", "anything")
    entry = ["--group", "novice", "--year-of-training", "1", "--procedures-performed", "0"]
    proto = REPO / "assets" / "prp" / "protocols" / "table61.toml"
    db = tmp_path / "local.sqlite3"
    rc, _, err = cli("protocol", proto, "--register", "P1", *entry, "--records", "http://127.0.0.1:9", "--db", db)
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "cannot reach" in err and "allocation from the study's sequence needs the records server" in err


def test_a_session_takes_its_order_from_the_servers_register(site, tmp_path, cli, monkeypatch):
    """`--participant CODE --records URL`: the window's session is given the slot the server allocated (no
    warning); a participant the server has not registered is refused before the window opens."""
    import chainsim.game.trainer.window as window
    from chainsim.game.trainer.headless import build_app

    study = f"s{uuid.uuid4().hex[:8]}"
    proto = tmp_path / f"{study}.toml"
    proto.write_text((REPO / "assets" / "prp" / "protocols" / "table61.toml").read_text())
    monkeypatch.setenv("CHAINSIM_RECORDS_TOKEN", site.tokens["tina"])
    path = f"/api/studies/{study}/participants"
    for code in ("P1", "P2"):
        assert call(site, "POST", path, person(code, class_name="c1"), site.tokens["tina"])[0] == 201
    sessions = []
    monkeypatch.setattr(window, "run_window", lambda args, session: sessions.append(session) or 0)
    db = tmp_path / "local.sqlite3"
    common = ["--records", site.url, "--db", db, "--class", "c1"]
    rc, _, err = cli("protocol", proto, "--participant", "P2", *common)
    assert rc == 0, err
    app = build_app("prp", settings={"db": str(db), "class": "c1", "trainee": "P2"})
    try:
        s = sessions[-1](app)
        s.start()
        assert s.allocation["slot"] == 1 and s.allocation["by"] == f"records server {site.url}"
        assert "Warning" not in s.notice
    finally:
        app.close()
    rc, _, err = cli("protocol", proto, "--participant", "P9", *common)
    assert rc == 2 and "'P9' is not in the register of study" in err and f"on {site.url}" in err


def test_the_register_page_enters_a_participant_and_shows_their_slot(site):
    """A trainer signed in to the dashboard registers on /studies/STUDY (CSRF-checked form); a bad count
    is a 422 naming it; a trainee may not open the page. Once the study's design is filed (the same one
    again is fine, another is a 409, a bad one a 422) the page gives the browser trainer's link."""
    from test_dashboard import Browser, csrf_of

    study = f"s{uuid.uuid4().hex[:8]}"
    b = Browser(site)
    assert b.sign_in("tina")[0] == 303
    status, page, _ = b.get(f"/studies/{study}")
    assert status == 200 and "No participant registered yet" in page
    assert "design (its trials and aids) is not filed yet" in page
    form = {"class_name": "c1", "code": "P1", "group": "expert", "year_of_training": "7", "procedures_performed": "120"}
    assert b.post(f"/studies/{study}", {**form, "csrf": "forged" * 6})[0] == 403
    status, _, hdrs = b.post(f"/studies/{study}", {**form, "csrf": csrf_of(page)})
    assert status == 303 and hdrs["location"] == f"/studies/{study}?added=P1"
    design = {"pack": "prp", "practice": 0, "trials": [{"name": "t", "task": "location", "condition": "c"}]}
    path = f"/api/studies/{study}/design"
    assert call(site, "POST", path, design, site.tokens["tina"])[0] == 201
    assert call(site, "POST", path, design, site.tokens["tina"])[0] == 200  # the same design again
    status, answer, _ = call(site, "POST", path, {**design, "practice": 1}, site.tokens["tina"])
    assert status == 409 and "has another design on this server" in answer["error"]
    bad = call(site, "POST", path, {**design, "trials": [{"task": "juggling"}]}, site.tokens["tina"])
    assert bad[0] == 422 and "'task' must be one of location, insertion" in bad[1]["error"]
    assert call(site, "POST", path, design, site.tokens["alice"])[0] == 403
    status, page, _ = b.get(hdrs["location"])
    assert "P1 registered: slot 0." in page and "<td>expert</td><td>7</td>" in page
    assert f'href="/train/prp?study={study}"' in page  # the browser trainer's link for the trials
    bad = {**form, "code": "P2", "year_of_training": "seven", "csrf": csrf_of(page)}
    status, page, _ = b.post(f"/studies/{study}", bad)
    assert status == 422 and "year_of_training is &#39;seven&#39;" in page
    trainee = Browser(site)
    trainee.sign_in("alice")
    assert trainee.get(f"/studies/{study}")[0] == 403
