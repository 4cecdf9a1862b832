"""Installed packs are found through the `chainsim.packs` entry points as files: nothing is imported.

A distribution is faked on a sys.path folder (dist-info with entry_points.txt and RECORD) whose
package and sub-package write a marker file when imported. Listing, validating and running the pack
must find it and leave no marker.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from .conftest import chainsim

PACK = """\
[pack]
name = "planted"
format = 1

[meshes.b]
primitive = "box"

[entities.b.mesh]
mesh = "b"
"""


def _site(tmp_path: Path, value: str, *, record: bool = True) -> tuple[Path, Path]:
    """A site folder with the distribution 'evilpacks' whose entry point value is `value`."""
    site = tmp_path / "site"
    marker = tmp_path / "imported"
    pkg = site / "evilpkg" / "packs" / "planted"
    pkg.mkdir(parents=True)
    code = f"open({str(marker)!r}, 'a').write(__name__ + '\\n')\n"
    for init in (site / "evilpkg", site / "evilpkg" / "packs", pkg):
        (init / "__init__.py").write_text(code)
    (pkg / "pack.toml").write_text(PACK)
    info = site / "evilpacks-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: evilpacks\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[chainsim.packs]\nplanted = {value}\n")
    if record:
        files = [p.relative_to(site).as_posix() for p in site.rglob("*") if p.is_file()]
        (info / "RECORD").write_text("".join(f"{f},,\n" for f in files))
    return site, marker


@pytest.mark.slow
@pytest.mark.parametrize(
    "value, record",
    [
        ("evilpkg.packs.planted", True),  # a dotted name: find_spec would import evilpkg and evilpkg.packs
        ("evilpkg.packs.planted:anything", True),  # an object reference
        ("evilpkg.packs.planted", False),  # no RECORD (editable installs): found on sys.path
    ],
)
def test_installed_pack_is_found_without_importing_anything(value, record, tmp_path):
    site, marker = _site(tmp_path, value, record=record)
    env = {"PYTHONPATH": str(site)}
    r = chainsim("packs", env=env)
    assert r.returncode == 0, r.stderr
    assert "planted" in r.stdout and "installed" in r.stdout
    r = chainsim("validate", "planted", env=env)
    assert r.returncode == 0, r.stderr
    r = chainsim("run", "planted", "--steps", "3", env=env)
    assert r.returncode == 0, r.stderr
    assert not marker.exists(), marker.read_text()


def test_entry_point_values_that_are_not_module_names_are_ignored(tmp_path):
    site, marker = _site(tmp_path, "../../etc")
    r = chainsim("packs", env={"PYTHONPATH": str(site)})
    assert r.returncode == 0 and "planted" not in r.stdout
    assert not marker.exists()


def test_a_deeply_nested_manifest_on_a_search_path_does_not_break_listing(tmp_path, cli, monkeypatch):
    bad = tmp_path / "deep"
    bad.mkdir()
    (bad / "pack.toml").write_text(textwrap.dedent('[pack]\nname = "x"\nformat = 1\ny = ' + "[" * 5000 + "]" * 5000))
    code, out, err = cli("packs", "--pack-path", tmp_path)
    assert code == 0 and "deep" in out  # listed by its folder name; `validate` says what is wrong
    code, out, err = cli("validate", bad)
    assert code == 2 and "nested more than" in err
