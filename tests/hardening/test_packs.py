"""Broken packs: `validate` names every problem in one line each, and fails exactly when `run` fails.

Each case is a small pack (BASE_PACK edited, plus files) that a careless or hostile author could
write. For each: the validator reports words naming the problem, `chainsim validate` exits 2 with
no traceback, and `chainsim run` refuses it too (validate fails iff run fails, here and for the
fixtures of tests/packs/broken). Good variants must pass both.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from chainsim.game.trainer.headless import validate_pack

from .badfiles import npz_arrays, ply_declaring, vtu_bomb
from .conftest import BASE_PACK, assert_one_line_error, chainsim, write_pack

BROKEN_FIXTURES = Path(__file__).resolve().parents[1] / "packs" / "broken"

DEEP_ARRAY = "[" * 5000 + "]" * 5000
DEEP_TABLE = "{a = " * 100 + "1" + "}" * 100
DOTTED = ".".join(["k"] * 100)
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


def _sub(old: str, new: str) -> str:
    assert old in BASE_PACK, old
    return BASE_PACK.replace(old, new)


def _mesh_pack(extra_mesh: str) -> str:
    """BASE_PACK whose body uses a mesh file instead of the grid."""
    return (
        BASE_PACK.replace('mesh = "sheet"', 'mesh = "file"')
        .replace("[materials.soft]", f'[meshes.file]\npath = "meshes/m.obj"\n{extra_mesh}\n[materials.soft]')
        .replace("element = 12", "element = 1")
        .replace("path = [0.0, 0.0, 5.0]", "path = [0.0, 0.0, 0.5]")
    )


# id -> (pack.toml, {file: content}, words the problem report must contain)
CASES: dict[str, tuple[str, dict, tuple[str, ...]]] = {
    # counts without a bound hang `run`
    "material-relax-2**63-1": (
        _sub("relax = 2", "relax = 9223372036854775807"),
        {},
        ("materials.soft.relax", "<= 1000"),
    ),
    "deformable-relax-huge": (
        _sub("fixed = [0]", "fixed = [0]\nrelax = 4611686018427387904"),
        {},
        ("deformable.relax", "<= 1000"),
    ),
    "deformable-depth-huge": (_sub("fixed = [0]", "fixed = [0]\ndepth = 1099511627776"), {}, ("depth", "<= 64")),
    "settings-steps-huge": (BASE_PACK + "[settings]\nsteps = 9223372036854775807\n", {}, ("settings.steps", "<=")),
    # whole numbers that overflow
    "fixed-10**23": (_sub("fixed = [0]", "fixed = [100000000000000000000000]"), {}, ("deformable.fixed", "64-bit")),
    "format-10**30": (_sub("format = 1", "format = 1000000000000000000000000000000"), {}, ("pack.format", "64-bit")),
    # accepted by validate, refused later by run (before this work)
    "fixed-out-of-range": (_sub("fixed = [0]", "fixed = [999]"), {}, ("deformable.fixed", "0..24")),
    "fixed-negative": (_sub("fixed = [0]", "fixed = [-3]"), {}, ("deformable.fixed", ">= 0")),
    "alpha-min-5-inline": (_sub("fixed = [0]", "fixed = [0]\nalpha_min = 5.0"), {}, ("alpha_min", "[0, 1]")),
    "alpha-min-5-material": (_sub("alpha_min = 0.8", "alpha_min = 5.0"), {}, ("materials.soft.alpha_min", "<= 1")),
    "alpha-max-inline-below-1": (_sub("fixed = [0]", "fixed = [0]\nalpha_max = 0.5"), {}, ("alpha_max", ">= 1")),
    "pull-element-out-of-range": (_sub("element = 12", "element = 4000"), {}, ("pull.element", "0..24")),
    "pull-path-not-triples": (
        _sub("path = [0.0, 0.0, 5.0]", "path = [1.0, 2.0, 3.0, 4.0]"),
        {},
        ("pull.path", "triples"),
    ),
    "motion-waypoints-not-triples": (
        BASE_PACK + '[entities.box.mesh]\nmesh = "sheet"\n[entities.box.scripted_motion]\nwaypoints = [1.0, 2.0]\n',
        {},
        ("scripted_motion.waypoints", "triples"),
    ),
    "fixed-box-five-numbers": (
        _sub("fixed = [0]", "fixed_box = [0.0, 0.0, 0.0, 1.0, 1.0]"),
        {},
        ("fixed_box", "xmin"),
    ),
    "deformable-without-mesh": (
        BASE_PACK + "[entities.ghost.deformable]\nfixed = []\n",
        {},
        ("ghost", "needs a mesh"),
    ),
    "volume-source-on-surface": (_sub("fixed = [0]", 'fixed = [0]\nsource = "volume"'), {}, ("source", "tetrahedra")),
    "grid-resolution-1e9": (
        _sub("resolution = [4.0, 4.0, 1.0]", "resolution = [1e9, 1e9, 1.0]"),
        {},
        ("resolution", "<= 4096"),
    ),
    "grid-resolution-over-vertex-limit": (
        _sub("resolution = [4.0, 4.0, 1.0]", "resolution = [4096.0, 4096.0, 1.0]"),
        {},
        ("meshes.sheet.resolution", "vertices", "limit"),
    ),
    "sphere-resolution-over-vertex-limit": (
        BASE_PACK + '[meshes.ball]\nprimitive = "sphere"\nresolution = [4000.0, 4000.0, 1.0]\n',
        {},
        ("meshes.ball.resolution", "vertices"),
    ),
    "tet-block-10**9-vertices": (
        BASE_PACK + '[meshes.block]\nprimitive = "tet_block"\nresolution = [1000.0, 1000.0, 1000.0]\n',
        {},
        ("meshes.block.resolution", "vertices"),
    ),
    # out-of-range settings and views
    "window-size-negative": (BASE_PACK + "[settings]\nwindow_size = [-5.0, 0.0]\n", {}, ("window_size", ">= 1")),
    "window-size-huge": (BASE_PACK + "[settings]\nwindow_size = [1e9, 800.0]\n", {}, ("window_size", "<= 16384")),
    "dt-zero": (BASE_PACK + "[settings]\ndt = 0.0\n", {}, ("settings.dt", ">= 1e-05")),
    "dt-1e300": (BASE_PACK + "[settings]\ndt = 1e300\n", {}, ("settings.dt", "<= 0.1")),
    "dt-text": (BASE_PACK + '[settings]\ndt = "fast"\n', {}, ("settings.dt", "expected number")),
    "viewport-distance-zero": (
        BASE_PACK
        + '[layouts.main]\nviewports = [{name = "v", kind = "orbit", rect = [0.0, 0.0, 1.0, 1.0], distance = 0.0}]\n'
        + '[scenes.main]\nlayout = "main"\n',
        {},
        ("distance", ">= 0.001"),
    ),
    "widget-min-above-max": (
        BASE_PACK
        + '[layouts.main]\nviewports = [{name = "p", kind = "panel", rect = [0.0, 0.0, 1.0, 1.0]}]\n'
        + 'widgets = [{name = "d", kind = "dial", min = 5.0, max = 1.0}]\n',
        {},
        ("widgets.0.max", ">= 'min'"),
    ),
    # coordinates that overflow to inf/NaN downstream
    "position-1e308": (
        BASE_PACK + "[entities.body.transform]\nposition = [1e308, 0.0, 0.0]\n",
        {},
        ("position", "1e+06"),
    ),
    "scale-1e300": (BASE_PACK + "[entities.body.transform]\nscale = 1e300\n", {}, ("scale", "1e+06")),
    "point-1e300": (BASE_PACK + "[points.chin]\nposition = [0.0, 1e300, 0.0]\n", {}, ("points.chin.position", "1e+06")),
    "extents-1e300": (_sub("extents = [20.0, 20.0, 0.0]", "extents = [1e300, 20.0, 0.0]"), {}, ("extents", "1e+06")),
    "waypoint-1e308": (_sub("path = [0.0, 0.0, 5.0]", "path = [0.0, 0.0, 1e308]"), {}, ("pull.path", "1e+06")),
    "pull-speed-inf": (_sub("speed = 50.0", "speed = inf"), {}, ("pull.speed", "finite")),
    "obj-nan-vertex": (
        _mesh_pack(""),
        {"meshes/m.obj": "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n"},
        ("m.obj", "non-finite"),
    ),
    "obj-1e309-vertex": (_mesh_pack(""), {"meshes/m.obj": "v 0 0 0\nv 1 0 0\nv 1e309 1 0\nf 1 2 3\n"}, ("non-finite",)),
    "obj-1e308-vertex": (_mesh_pack(""), {"meshes/m.obj": "v 0 0 0\nv 1e308 0 0\nv 0 1 0\nf 1 2 3\n"}, ("1e+06",)),
    "obj-in-metres-too-far": (
        _mesh_pack('units = "m"'),
        {"meshes/m.obj": "v 0 0 0\nv 5000 0 0\nv 0 1 0\nf 1 2 3\n"},
        ("within +-1e+06 mm", "5e+06"),
    ),
    "obj-face-out-of-range": (_mesh_pack(""), {"meshes/m.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"}, ("m.obj",)),
    "ply-declaring-10**12-vertices": (
        _mesh_pack("").replace("m.obj", "m.ply"),
        {},
        ("m.ply", "declares 1,000,000,000,000 vertices"),
    ),
    # paths
    "nul-in-mesh-path": (
        _mesh_pack("").replace("meshes/m.obj", "meshes/m\\u0000.obj"),
        {"meshes/m.obj": TRI},
        ("control character",),
    ),
    "newline-in-docs-path": (
        BASE_PACK + '[docs.d]\ntitle = "d"\npath = "a\\nb.md"\n',
        {},
        ("docs.d.path", "control character"),
    ),
    "include-with-nul": (
        _sub("format = 1", 'format = 1\nincludes = ["x\\u0000.toml"]'),
        {},
        ("pack.includes", "control"),
    ),
    "include-missing": (
        _sub("format = 1", 'format = 1\nincludes = ["{side}anatomy.toml"]'),
        {},
        ("pack.includes", "'{side}anatomy.toml'", "not found"),
    ),
    # nesting and size
    "5000-deep-array": (BASE_PACK + f"[metrics.m]\nlabel = {DEEP_ARRAY}\n", {}, ("nested more than 32",)),
    "100-deep-inline-table": (BASE_PACK + f"[metrics.m]\nlabel = {DEEP_TABLE}\n", {}, ("nested more than 32",)),
    "100-deep-dotted-key": (BASE_PACK + f"[metrics.m]\n{DOTTED} = 1\n", {}, ("nested more than 32",)),
    "manifest-over-4mb": (BASE_PACK + "#" + "x" * (4 * 1024 * 1024) + "\n", {}, ("byte limit",)),
    "manifest-not-utf8": (None, {"pack.toml": b'[pack]\nname = "\xff\xfe"\n'}, ("not utf-8",)),
    "description-30000-chars": (_sub("format = 1", f'format = 1\ndescription = "{"d" * 30000}"'), {}, ("20000",)),
    "entity-name-200-chars": (
        BASE_PACK + f'[entities.{"e" * 200}.mesh]\nmesh = "sheet"\n',
        {},
        ("over the 128",),
    ),
    # procedures whose needs only show when the scene starts
    "prp-without-anatomy": (_sub("format = 1", 'format = 1\nprocedure = "prp"'), {}, ("needle procedure needs",)),
    "cutting-without-tools": (
        _sub("format = 1", 'format = 1\nprocedure = "cutting"'),
        {},
        ("cutting procedure needs",),
    ),
    # a scene's own script
    "scene-script-deep-json": (
        BASE_PACK + '[scenes.main]\nscript = "s.json"\n',
        {"s.json": "[" * 100000 + "]" * 100000},
        ("scenes.main.script", "nested more than 32"),
    ),
    "scene-script-time-10**400": (
        BASE_PACK + '[scenes.main]\nscript = "s.json"\n',
        {"s.json": json.dumps({"format": 1, "event": [{"t": 0}]}).replace('"t": 0', '"t": 1' + "0" * 400)},
        ("scenes.main.script", "64-bit"),
    ),
    "scene-script-picks-unknown-entity": (
        BASE_PACK + '[scenes.main]\nscript = "s.toml"\n',
        {"s.toml": 'format = 1\n[[event]]\nt = 0.0\nkind = "pick"\nentity = "nobody"\npoint = [0.0, 0.0, 0.0]\n'},
        ("scenes.main.script", "'nobody'"),
    ),
}

GOOD = {
    "base": BASE_PACK,
    "relax-at-the-limit": _sub("relax = 2", "relax = 1000"),
    "negative-e-notation-coordinates": _sub("path = [0.0, 0.0, 5.0]", "path = [-1e1, 0.0, 5.0]"),
    "coordinates-at-the-limit": BASE_PACK + "[points.far]\nposition = [1e6, -1e6, 0.0]\n",
}


def _make(tmp_path: Path, case: str) -> Path:
    manifest, files, _ = CASES[case]
    folder = tmp_path / case
    files = dict(files)
    if case == "ply-declaring-10**12-vertices":
        (folder / "meshes").mkdir(parents=True)
        ply_declaring(folder / "meshes" / "m.ply", 10**12)
    if manifest is None:
        folder.mkdir(parents=True, exist_ok=True)
        for rel, content in files.items():
            (folder / rel).write_bytes(content if isinstance(content, bytes) else content.encode())
        return folder
    return write_pack(folder, manifest, files)


def test_every_issue_example_is_in_the_table():
    assert len(CASES) >= 50


@pytest.mark.parametrize("case", sorted(CASES))
def test_validate_names_the_problem_and_run_refuses_it_too(case, tmp_path, cli):
    folder = _make(tmp_path, case)
    words = CASES[case][2]
    pack, problems = validate_pack(folder)
    assert pack is None and problems, case
    text = "\n".join(str(p) for p in problems)
    for w in words:
        assert w.lower() in text.lower(), (w, text)
    assert all("\n" not in str(p) for p in problems)
    code, out, err = cli("validate", folder)
    assert_one_line_error(code, err)
    assert err.strip().splitlines()[-1].endswith(str(folder))  # "N problems in FOLDER"
    code, out, err = cli("run", folder, "--steps", "2")
    assert_one_line_error(code, err)


@pytest.mark.parametrize("case", sorted(GOOD))
def test_good_variants_validate_and_run(case, tmp_path, cli):
    folder = write_pack(tmp_path / case, GOOD[case])
    code, out, err = cli("validate", folder)
    assert code == 0, err
    code, out, err = cli("run", folder, "--steps", "30")
    assert code == 0, err


@pytest.mark.parametrize("name", sorted(p.name for p in BROKEN_FIXTURES.iterdir()))
def test_validate_fails_iff_run_fails_for_the_broken_fixtures(name, cli, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "0.01")
    folder = BROKEN_FIXTURES / name
    v_code, _, v_err = cli("validate", folder)
    r_code, _, r_err = cli("run", folder, "--steps", "2")
    assert (v_code == 0) == (r_code == 0), (v_err, r_err)
    assert v_code == 2 and r_code == 2


def test_every_scene_of_a_pack_that_validates_runs(tmp_path, cli):
    """The other direction over a pack with several scenes: validate passes, so each scene runs."""
    folder = write_pack(
        tmp_path / "two",
        BASE_PACK + '[scenes.a]\nentities = ["body"]\n[scenes.b]\nentities = ["body"]\n',
    )
    assert cli("validate", folder)[0] == 0
    for scene in ("a", "b"):
        code, _, err = cli("run", f"hard/{scene}", "--pack-path", tmp_path, "--steps", "5")
        assert code == 0, err


@pytest.mark.parametrize(
    "case", ["material-relax-2**63-1", "deformable-relax-huge", "settings-steps-huge", "tet-block-10**9-vertices"]
)
def test_counts_that_used_to_hang_are_refused_quickly(case, tmp_path):
    folder = _make(tmp_path, case)
    for cmd in ("validate", "run"):
        r = chainsim(cmd, folder, timeout=60)
        assert_one_line_error(r.returncode, r.stderr)


def test_mesh_decompression_bomb_in_a_pack_is_refused_by_declared_size(tmp_path, cli, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "1")
    folder = write_pack(
        tmp_path / "bomb",
        BASE_PACK + '[meshes.vol]\npath = "meshes/v.vtu"\n',
    )
    (folder / "meshes").mkdir()
    vtu_bomb(folder / "meshes" / "v.vtu", 32 * 2**20, points=4)
    assert (folder / "meshes" / "v.vtu").stat().st_size < 64 * 1024  # small file, big data
    code, out, err = cli("validate", folder)
    assert_one_line_error(code, err, "meshes.vol.path", "mesh limit")


@pytest.mark.parametrize("value", ["abc", "nan", "inf", "-1", "0", "1e9"])
def test_mesh_limit_variable_must_be_a_usable_number(value, tmp_path, cli, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", value)
    folder = write_pack(tmp_path / "p", _mesh_pack(""), {"meshes/m.obj": TRI})
    for args in (("validate", folder), ("run", folder, "--steps", "1")):
        code, out, err = cli(*args)
        assert_one_line_error(code, err, "CHAINSIM_MAX_MESH_MB", "expected a number")


def test_npz_is_not_a_pack_mesh_type(tmp_path, cli):
    folder = write_pack(tmp_path / "p", _mesh_pack("").replace("m.obj", "m.npz"))
    (folder / "meshes").mkdir()
    npz_arrays(folder / "meshes" / "m.npz", positions=[[0.0]])
    code, out, err = cli("validate", folder)
    assert_one_line_error(code, err, "unsupported mesh type")


def test_a_preset_with_an_unbounded_count_is_refused(tmp_path, monkeypatch):
    from chainsim.game.packs import model

    presets = tmp_path / "materials.toml"
    presets.write_text("[runaway]\nalpha_min = 0.9\nalpha_max = 1.1\nbeta = 0.05\nrelax_iterations = 1099511627776\n")
    monkeypatch.setattr(model, "PRESET_FILE", presets)
    folder = write_pack(tmp_path / "p", _sub("relax = 2", 'preset = "runaway"').replace("alpha_min = 0.8\n", ""))
    pack, problems = validate_pack(folder)
    assert pack is None
    assert any(
        "materials.soft.preset" in str(p) and "relax_iterations" in str(p) and "<= 1000" in str(p) for p in problems
    )


def test_a_stiff_xpbd_body_under_its_substep_rule_is_said_in_one_line(tmp_path):
    # E = 1e12 with 2 substeps given: honoured, and the user reads why it may go wrong, not a Python warning
    stiff = _sub("fixed = [0]\n", 'fixed = [0]\nmodel = "xpbd"\nE = 1e12\nsubsteps = 2\n')
    r = chainsim("run", write_pack(tmp_path / "p", stiff), "--steps", "3", "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "substeps" in line]
    assert said == [
        "xpbd: 5 mm elements at E = 1e+12 Pa need 105410 substeps per 8.33 ms step (a wave crosses 0.5 of an "
        "element per substep); 2 given, so the body may come out too soft or invert under a hard pull"
    ], r.stderr
    assert ".py" not in r.stderr and "Warning" not in r.stderr
