"""`chainsim new-pack`: the scaffold validates, runs headless, and refuses bad names and existing folders."""

from __future__ import annotations


def test_scaffold_validates_and_runs(tmp_path, cli):
    code, out, err = cli("new-pack", "my-proc", "--dir", tmp_path)
    assert code == 0, err
    root = tmp_path / "my-proc"
    assert (root / "pack.toml").is_file() and (root / "docs" / "readme.md").is_file()
    code, out, err = cli("run", root, "--headless", "--steps", "30", "--out", tmp_path / "o")
    assert code == 0, err
    assert (tmp_path / "o" / "summary.json").is_file()


def test_scaffold_refuses_bad_name_and_existing_folder(tmp_path, cli):
    code, _, err = cli("new-pack", "bad name", "--dir", tmp_path)
    assert code == 2 and "letters, digits" in err
    (tmp_path / "taken").mkdir()
    code, _, err = cli("new-pack", "taken", "--dir", tmp_path)
    assert code == 2 and "already exists" in err


def test_a_title_with_quotes_and_backslashes_still_makes_valid_toml(tmp_path):
    import tomllib

    from chainsim.game.packs import pack as packs
    from chainsim.game.packs.scaffold import create

    root = create("qp", tmp_path, title='The "best" pack \\ v2')
    assert tomllib.loads((root / "pack.toml").read_text())["pack"]["title"] == 'The "best" pack \\ v2'
    assert packs.validate(root)[1] == []


def test_a_refused_title_leaves_no_folder_behind(tmp_path):
    import pytest

    from chainsim.engine.errors import UserError
    from chainsim.game.packs.scaffold import create

    with pytest.raises(UserError, match="title"):
        create("qp", tmp_path, title="bad\x1btitle")
    assert list(tmp_path.iterdir()) == []


def test_the_scaffold_body_can_be_pulled_as_its_step_says(tmp_path):
    from chainsim.game.packs import pack as packs
    from chainsim.game.packs.scaffold import create

    pack = packs.load(create("qp", tmp_path))
    assert pack.manifest["entities"]["body"]["deformable"]["drag"] is True
    assert "pull" in pack.section("steps")[0]["instruction"]
