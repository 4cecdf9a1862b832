"""The mental-block pack: a second needle procedure written only in data on the prp pack's head.

What a modder relies on: the pack holds no Python and no copy of prp's meshes, validates, its correct
script reaches the mental foramen headless, its wrong script meets the mandible and springs back,
and both attempts are saved and listed by `chainsim records`.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from chainsim.game.trainer.inputscript import load_script

ROOT = Path(__file__).resolve().parents[2]
PACK = ROOT / "assets" / "mental-block"


def _run(cli, tmp_path, script: str, *extra):
    out = tmp_path / script
    code, _, err = cli(
        "run", str(PACK), "--headless", "--input", PACK / "scripts" / f"{script}.toml", "--out", out, *extra
    )
    assert code == 0, err
    return json.loads((out / "summary.json").read_text())["assessment"]


def test_pack_is_data_only_and_borrows_prp_meshes():
    assert not list(PACK.rglob("*.py"))
    manifest = tomllib.loads((PACK / "pack.toml").read_text())
    assert manifest["pack"]["requires"] == ["prp"]
    files = [m["path"] for m in manifest["meshes"].values() if "path" in m]
    # its anatomy is prp's; its own files are the tissue volumes the pack builder made from that anatomy
    own = sorted(p for p in files if not p.startswith("prp:meshes/"))
    assert own == ["meshes/tissue_left.vtu", "meshes/tissue_right.vtu"]
    assert sorted(p.name for p in (PACK / "meshes").iterdir()) == [
        "skin_around_tissue.ply",
        "tissue_left.vtu",
        "tissue_right.vtu",
    ]


def test_validates(cli):
    code, out, err = cli("validate", PACK)
    assert code == 0, err + out
    assert "ok" in out


def test_correct_attempt_reaches_the_mental_foramen(cli, tmp_path):
    a = _run(cli, tmp_path, "correct")
    assert a["target_reached"] is True
    assert a["target"] == "mental_foramen_left"
    assert a["side"] == "left"
    assert a["bone_contacts"] == 0
    assert a["needle_error_mm"] <= 0.5  # at the opening: within its 2 mm radius
    assert a["landmark_error_mm"] < 0.5  # the script clicks the ideal points


def test_wrong_attempt_hits_the_mandible_and_springs_back(cli, tmp_path):
    a = _run(cli, tmp_path, "bone")
    assert a["target_reached"] is False
    assert a["target"] == "mandible"
    assert a["bone_contacts"] >= 1
    assert a["needle_error_mm"] > 2.0  # below the foramen, outside its radius


def test_runs_without_input(cli, tmp_path):
    code, _, err = cli("run", str(PACK), "--headless", "--steps", "240", "--out", tmp_path / "smoke")
    assert code == 0, err


def _saving(tmp_path, name: str) -> Path:
    """The pack's script with Save pressed after its last event."""
    src = PACK / "scripts" / f"{name}.toml"
    last = max(t for t, _ in load_script(src))
    path = tmp_path / f"{name}-saved.toml"
    path.write_text(src.read_text() + f'\n[[event]]\nt = {last + 0.3}\nkind = "widget"\nname = "save"\n')
    return path


def test_both_attempts_show_in_records(cli, tmp_path):
    db = tmp_path / "r.sqlite3"
    for name in ("correct", "bone"):
        code, _, err = cli(
            "run", str(PACK), "--headless", "--input", _saving(tmp_path, name), "--out", tmp_path / name,
            "--db", db, "--class", "c1", "--trainee", "ann",
        )  # fmt: skip
        assert code == 0, err
    code, out, err = cli("records", "--db", db, "list")
    assert code == 0, err
    rows = [line for line in out.splitlines()[2:] if line.strip()]  # below the header and its rule
    assert len(rows) == 2 and all("mental-block" in r for r in rows)
    shown = {}
    for n in (1, 2):
        code, out, err = cli("records", "--db", db, "show", str(n))
        assert code == 0, err
        shown[n] = dict(line.split(None, 1) for line in out.splitlines() if line.strip())
    targets = sorted(f["target"].strip() for f in shown.values())
    assert targets == ["mandible", "mental_foramen_left"]
    # the pack's own [metrics] are stored per attempt under their names
    metrics = {f["target"].strip(): json.loads(f["metrics"]) for f in shown.values()}
    assert metrics["mandible"]["bone_contacts"] >= 1
    assert metrics["mental_foramen_left"]["bone_contacts"] == pytest.approx(0.0)
    assert metrics["mental_foramen_left"]["needle_error_mm"] <= 0.5
    # and a trainer's CSV export carries them too, one JSON cell per attempt
    code, _, err = cli("records", "--db", db, "export", "--csv", tmp_path / "all.csv")
    assert code == 0, err
    import csv

    with (tmp_path / "all.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    by_target = {r["target"]: json.loads(r["metrics"]) for r in rows}
    assert by_target["mandible"]["bone_contacts"] >= 1 and "needle_error_mm" in by_target["mental_foramen_left"]
