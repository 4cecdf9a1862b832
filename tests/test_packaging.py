"""Packaging: every code folder is importable under `chainsim` through pyproject's package mapping, and the
wheel carries what users run: everything but the pack builders (game/packbuild/), which need a checkout."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())

#: packages a checkout has and the wheel leaves out (.ci/run checks the built wheel holds none of them)
CHECKOUT_ONLY = "chainsim.game.packbuild"


def _checkout_only(package: str) -> bool:
    return package == CHECKOUT_ONLY or package.startswith(CHECKOUT_ONLY + ".")


def _folder_of(package: str, mapping: dict[str, str]) -> Path:
    """The folder a dotted package name maps to (longest mapped prefix wins)."""
    parts = package.split(".")
    for k in range(len(parts), 0, -1):
        head = ".".join(parts[:k])
        if head in mapping:
            return REPO / mapping[head] / Path(*parts[k:])
    raise AssertionError(f"{package} has no package-dir mapping")


def test_every_package_folder_is_listed_and_every_listed_package_exists():
    setup = PYPROJECT["tool"]["setuptools"]
    mapping, listed = setup["package-dir"], set(setup["packages"])
    for pkg in listed:
        assert (_folder_of(pkg, mapping) / "__init__.py").is_file(), f"{pkg} is listed but has no __init__.py"
    # every folder with an __init__.py under a mapped root is listed
    for pkg, folder in mapping.items():
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / folder)
            name = ".".join([pkg, *rel.parts]) if rel.parts else pkg
            owner = max(
                (p for p in mapping if (REPO / mapping[p]) in [init.parent, *init.parent.parents]),
                key=lambda p: len(mapping[p]),
            )
            if owner != pkg:
                continue
            if _checkout_only(name):
                assert name not in listed, f"{name} builds packs from a checkout's data: not for the wheel"
            else:
                assert name in listed, f"{init.parent.relative_to(REPO)} is a package but {name} is not in pyproject"


def test_the_pack_builders_stay_out_of_the_wheel_and_run_from_a_checkout():
    import importlib

    listed = PYPROJECT["tool"]["setuptools"]["packages"]
    assert not [p for p in listed if _checkout_only(p)]
    builders = sorted((REPO / "game" / "packbuild").rglob("*.py"))
    assert len(builders) > 10
    # one builder per procedure folder, importable from this checkout (the editable install maps chainsim.game)
    for sub in ("needle", "cutting"):
        assert (REPO / "game" / "packbuild" / sub / "__init__.py").is_file()
    for mod in ("needle.prepare_prp", "needle.make_prp_scripts", "cutting.make_cutting_pack"):
        assert callable(importlib.import_module(f"{CHECKOUT_ONLY}.{mod}").main)
    # nothing the wheel ships imports them
    shipped = [f for root in ("components", "systems", "tools", "game") for f in (REPO / root).rglob("*.py")]
    users = [
        f.relative_to(REPO).as_posix()
        for f in shipped
        if "packbuild" not in f.relative_to(REPO).parts
        and re.search(r"^\s*(from|import) chainsim\.game\.packbuild", f.read_text(), re.M)
    ]
    assert not users, f"shipped modules import the pack builders: {users}"


def test_the_folder_tree_is_the_import_tree():
    """Only the top-level folders are mapped, each to chainsim.<folder>: below them a module's dotted name
    is its path, so a reader (and any tool that reads paths) sees the house the code imports."""
    mapping = PYPROJECT["tool"]["setuptools"]["package-dir"]
    for pkg, folder in mapping.items():
        assert "/" not in folder and pkg == f"chainsim.{folder}", f"{pkg} is mapped to {folder}"
    for pkg in PYPROJECT["tool"]["setuptools"]["packages"]:
        folder = _folder_of(pkg, mapping).relative_to(REPO)
        assert "chainsim." + ".".join(folder.parts) == pkg


def test_version_is_written_once():
    import chainsim.game

    assert PYPROJECT["project"]["version"] == chainsim.game.__version__
    numbered = re.compile(r"__version__\s*=\s*[\"']\d")
    hits = [p for p in REPO.glob("[gsct]*/**/*.py") if numbered.search(p.read_text())]
    assert not hits, f"a second version string in {hits}"


def test_licence_expression_covers_the_shipped_data():
    project = PYPROJECT["project"]
    assert "MIT" in project["license"] and "CC-BY-4.0" in project["license"] and "CC-BY-SA" in project["license"]
    for f in project["license-files"]:
        assert (REPO / f).is_file(), f


def test_architecture_doc_names_every_package_folder():
    doc = (REPO / "docs" / "architecture.md").read_text()
    setup = PYPROJECT["tool"]["setuptools"]
    for pkg in setup["packages"]:
        folder = _folder_of(pkg, setup["package-dir"]).relative_to(REPO)
        leaf = folder.name + "/"
        assert f"{folder.as_posix()}/" in doc or f"`{leaf}" in doc or leaf in doc, f"docs/architecture.md: {folder}"
