"""`chainsim validate`: every broken fixture pack gives one precise line per problem, exit 2, no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import validate_pack

BROKEN = Path(__file__).parent / "broken"
ROOT = Path(__file__).resolve().parents[2]

# fixture -> the problems it must report: (line or None, key, words in the message)
EXPECTED = {
    "toml-syntax": [(5, "", "TOML syntax error")],
    "unknown-key": [(2, "pack.nmae", "did you mean 'name'")],
    "wrong-type": [(8, "entities.ball.transform.position", "expected array of 3 numbers")],
    "missing-mesh-file": [(6, "meshes.skull.path", "'meshes/skull.ply' not found")],
    "unreadable-mesh": [(6, "meshes.skull.path", "not a readable mesh")],
    "non-finite": [(7, "meshes.ball.radius", "must be finite"), (9, "entities.ball.transform.scale", "must be finite")],
    "path-escape": [
        (6, "meshes.secret.path", "escapes the pack folder"),
        (9, "docs.notes.path", "escapes the pack folder"),
    ],
    "mesh-too-big": [(6, "meshes.big.path", "over the")],
    "unknown-component": [(7, "entities.ball.transfrom", "did you mean 'transform'")],
    "bad-reference": [
        (6, "entities.ball.mesh.mesh", "no mesh named 'ghost'"),
        (7, "entities.ball.mesh.material", "no material named 'chrome'"),
        (9, "scenes.main.entities", "no entity named 'nobody'"),
        (10, "scenes.main.layout", "no layout named 'nowhere'"),
    ],
    "unsupported-format": [(3, "pack.format", "format 2 is not supported")],
    "bad-enum": [
        (6, "meshes.ball.primitive", "expected one of box"),
        (7, "meshes.ball.units", "expected one of mm, cm, m"),
    ],
    "bad-layout": [
        (9, "layouts.main.viewports.0.rect", "must be <= 1"),
        (7, "layouts.main.viewports.0.name", "duplicate viewport name"),
        (10, "layouts.main.viewports.0.attach", "no entity named 'needle'"),
        (7, "layouts.main.viewports.1.name", "duplicate viewport name"),
        (16, "layouts.main.viewports.1.far", "greater than 'near'"),
        (17, "layouts.main.widgets", "need a viewport of kind 'panel'"),
    ],
    "unknown-section": [(5, "meshs", "did you mean 'meshes'")],
    "missing-pack": [(None, "pack", "missing the [pack] table")],
    "bad-include": [(4, "pack.includes", "escapes the pack folder"), (2, "points.chin.position", "array of 3 numbers")],
    # what only starting a scene, or reading its script, finds: run would refuse these
    "bad-default-scene": [(4, "pack.default_scene", "no scene named 'nowhere'")],
    "bad-script-pick": [(11, "scenes.main.script", "'dot', which has no triangle mesh to pick on")],
    "bad-script-value": [(19, "scenes.main.script", "widget 'pull': expected \"x, y, z\"")],
}

#: fixtures that `run` refuses (words of its refusal) once it resolves the scene or reads the script:
#: validate must have reported them first
REFUSED_BY_RUN = {
    "bad-default-scene": "scene named 'nowhere'",
    "bad-script-pick": "has no triangle mesh to pick on",
    "bad-script-value": "widget 'pull': expected",
}


def test_every_fixture_has_expectations():
    assert sorted(p.name for p in BROKEN.iterdir() if p.is_dir()) == sorted(EXPECTED)
    assert len(EXPECTED) >= 10


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_broken_pack_reports_each_problem_precisely(name, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "0.01")
    pack, problems = validate_pack(BROKEN / name)  # what `chainsim validate` runs
    assert pack is None
    want = EXPECTED[name]
    assert len(problems) == len(want), [str(p) for p in problems]
    for (line, key, words), p in zip(want, problems):
        assert p.key == key
        assert words in p.message
        assert p.line == line, str(p)
        assert "\n" not in str(p)


@pytest.mark.parametrize("name", ["wrong-type", "bad-reference", "toml-syntax", "unreadable-mesh"])
def test_cli_prints_lines_and_exits_2_without_traceback(name):
    r = subprocess.run(
        [sys.executable, "-m", "game", "validate", str(BROKEN / name)], capture_output=True, text=True, cwd=ROOT
    )
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == len(EXPECTED[name]) + 1  # one per problem, then the count
    assert lines[0].startswith("pack.toml:")


@pytest.mark.parametrize("name", sorted(REFUSED_BY_RUN))
def test_what_run_refuses_validate_reports_first(name, cli):
    code, _, err = cli("validate", BROKEN / name)
    assert code == 2 and len(err.strip().splitlines()) == 2
    code, _, err = cli("run", BROKEN / name, "--headless", "--steps", "2")
    assert code == 2 and "Traceback" not in err
    assert REFUSED_BY_RUN[name] in err, err


def test_builtin_packs_validate_clean(cli):
    found = [f for f in packs.discover() if f.source == "builtin"]
    assert found, "no built-in packs"
    for f in found:
        code, out, err = cli("validate", f.path)
        assert code == 0, err
        assert "ok" in out


def test_unknown_pack_name_is_one_line(cli):
    code, out, err = cli("run", "no-such-pack", "--headless", "--steps", "1")
    assert code == 2
    assert "pack 'no-such-pack' not found" in err and err.count("\n") == 1


def test_user_pack_found_through_pack_path_and_env(tmp_path, cli, monkeypatch):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "pack.toml").write_text(
        '[pack]\nname = "mine"\nformat = 1\n[meshes.b]\nprimitive = "box"\n[entities.b.mesh]\nmesh = "b"\n'
    )
    code, out, _ = cli("packs", "--pack-path", tmp_path)
    assert code == 0 and "mine" in out and "pack-path" in out
    monkeypatch.setenv("CHAINSIM_PACK_PATH", str(tmp_path))
    code, out, _ = cli("packs")
    assert "mine" in out and "env" in out
    code, out, err = cli("run", "mine", "--headless", "--steps", "3")
    assert code == 0, err


def test_loading_a_pack_never_executes_code_from_it(tmp_path, cli):
    evil = tmp_path / "evil"
    evil.mkdir()
    marker = tmp_path / "pwned"
    (evil / "__init__.py").write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    (evil / "plugin.py").write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    (evil / "pack.toml").write_text('[pack]\nname = "evil"\nformat = 1\nprocedure = "plugin"\n')
    code, out, err = cli("validate", evil)
    assert code == 2 and "unknown procedure 'plugin'" in err
    cli("packs", "--pack-path", tmp_path)
    assert not marker.exists()


def test_docs_components_lists_every_registered_field(cli):
    from chainsim.components.registry import COMPONENTS, SECTIONS

    code, out, _ = cli("docs", "components")
    assert code == 0
    for schema in list(COMPONENTS.values()) + list(SECTIONS.values()):
        for f in schema.fields:
            assert f"`{f.name}`" in out, (schema.name, f.name)
    assert "### transform" in out and "### [meshes.NAME]" in out
