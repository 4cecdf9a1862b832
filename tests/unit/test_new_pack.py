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
