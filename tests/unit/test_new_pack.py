"""`chainsim new-pack --template empty|tissue|needle`: every template validates, runs headless, renders
a snapshot and does what its own step text says; bad names, titles and folders are refused."""

from __future__ import annotations

import numpy as np
import pytest

from chainsim.game.packs.scaffold import TEMPLATES, create

#: the window the templates' scripts are written for
W, H = 1280, 800
#: the middle of each template's main 3D view (window x, pixels)
MAIN_VIEW_X = {"empty": W // 2, "tissue": W // 4, "needle": int(W * 0.3)}


def make(tmp_path, template: str, cli) -> object:
    code, out, err = cli("new-pack", f"my-{template}", "--template", template, "--dir", tmp_path)
    assert code == 0, err
    assert "validates clean" in out
    return tmp_path / f"my-{template}"


@pytest.mark.parametrize("template", sorted(TEMPLATES))
def test_every_template_validates_and_runs_headless(tmp_path, cli, template):
    root = make(tmp_path, template, cli)
    assert (root / "pack.toml").is_file() and (root / "docs" / "readme.md").is_file()
    code, out, err = cli("validate", root)
    assert code == 0 and "ok" in out, err
    code, out, err = cli("run", root, "--headless", "--out", tmp_path / "o")
    assert code == 0, err
    assert (tmp_path / "o" / "summary.json").is_file()


@pytest.mark.parametrize("template", sorted(TEMPLATES))
def test_every_template_renders_a_snapshot(tmp_path, cli, template):
    from PIL import Image

    from chainsim.game.render.context import GLUnavailable, egl_context

    try:
        egl_context()
    except GLUnavailable as e:
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")
    root = make(tmp_path, template, cli)
    shot = tmp_path / "shot.png"
    code, out, err = cli("snapshot", root, "--scene", "main", "--out", shot)
    assert code == 0, err
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape == (H, W, 3)
    # the scene is drawn: the middle of the main view is not the plain background
    x = MAIN_VIEW_X[template]
    middle = img[H // 2 - 40 : H // 2 + 40, x - 40 : x + 40]
    assert (np.abs(middle - img[H - 5, 5]).sum(axis=2) > 30).mean() > 0.5


def test_empty_template_a_drag_turns_the_view_as_its_step_says(tmp_path, cli):
    from chainsim.systems.view.cameras import ViewState

    root = make(tmp_path, "empty", cli)
    from chainsim.components.resources import PendingInput
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script

    app = build_app(str(root))
    try:
        app.update(app.time.dt)
        cam = app.resource(ViewState).viewports[0].camera
        yaw0 = cam.yaw
        app.resource(PendingInput).extend(load_script(root / "scripts" / "look.toml"))
        for _ in range(40):
            app.update(app.time.dt)
        assert abs(cam.yaw - yaw0) > 5.0
    finally:
        app.close()
    assert "Drag to turn the view" in (root / "pack.toml").read_text()


def _tissue_lift(root, script: str, steps: int) -> float:
    """The largest upward move of any element of the tissue after the script (mm)."""
    import esper

    from chainsim.components.resources import PendingInput
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script
    from chainsim.systems.tissue.deformable import Deformable

    app = build_app(f"{root}/main", settings=None)
    try:
        with app.active():
            ((_, d0),) = esper.get_component(Deformable)
            rest = np.array(d0.body.positions, dtype=float)
        app.resource(PendingInput).extend(load_script(root / "scripts" / script))
        for _ in range(steps):
            app.update(app.time.dt)
        with app.active():
            ((_, d),) = esper.get_component(Deformable)
            return float((np.asarray(d.body.positions, float) - rest)[:, 2].max())
    finally:
        app.close()


def test_tissue_template_pull_button_and_mouse_drag_both_pull_as_its_step_says(tmp_path, cli):
    root = make(tmp_path, "tissue", cli)
    text = (root / "pack.toml").read_text()
    assert "Press Pull (p) to lift the top of the block, or drag the block in the middle view" in text
    assert _tissue_lift(root, "pull.toml", 240) > 15.0  # the Pull path lifts the top centre 20 mm
    assert _tissue_lift(root, "drag.toml", 120) > 5.0  # the drag in the middle view pulled the block up


def test_needle_template_correct_attempt_reaches_the_target_and_the_wrong_one_hits_bone(tmp_path, cli):
    from chainsim.game.trainer.headless import run_pack

    root = make(tmp_path, "needle", cli)
    text = (root / "pack.toml").read_text()
    assert 'requires = ["prp"]' in text and "prp:meshes/skull.ply" in text
    good = run_pack(str(root), script=str(root / "scripts" / "correct.toml"), save="test")["assessment"]
    assert good["target_reached"] is True and good["skull_contacts"] == 0
    assert good["landmark_error_mm"] < 0.01 and good["needle_error_mm"] < 0
    bad = run_pack(str(root), script=str(root / "scripts" / "bone.toml"), save="test")["assessment"]
    assert bad["target_reached"] is False and bad["skull_contacts"] >= 1 and bad["target"] == "skull"


def test_scaffold_refuses_bad_name_template_and_existing_folder(tmp_path, cli):
    code, _, err = cli("new-pack", "bad name", "--dir", tmp_path)
    assert code == 2 and "letters, digits" in err
    code, _, err = cli("new-pack", "ok", "--template", "nope", "--dir", tmp_path)
    assert code == 2 and "invalid choice" in err
    (tmp_path / "taken").mkdir()
    code, _, err = cli("new-pack", "taken", "--dir", tmp_path)
    assert code == 2 and "already exists" in err


@pytest.mark.parametrize("template", sorted(TEMPLATES))
def test_a_title_with_quotes_and_backslashes_still_makes_valid_toml(tmp_path, template):
    import tomllib

    from chainsim.game.packs import pack as packs

    root = create("qp", tmp_path, title='The "best" pack \\ v2', template=template)
    assert tomllib.loads((root / "pack.toml").read_text())["pack"]["title"] == 'The "best" pack \\ v2'
    assert packs.validate(root)[1] == []
    assert "__TITLE__" not in (root / "docs" / "readme.md").read_text()


def test_a_refused_title_leaves_no_folder_behind(tmp_path):
    from chainsim.systems.engine.errors import UserError

    with pytest.raises(UserError, match="title"):
        create("qp", tmp_path, title="bad\x1btitle")
    assert list(tmp_path.iterdir()) == []
