"""How a run is composed: the plugins are the functions themselves, and each feature registers its own manifest
tables."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from chainsim.components import registry
from chainsim.game.trainer import plugins
from chainsim.systems import FEATURE_MODULES, manifest_modules
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import PROCEDURES, procedure_for, procedure_of


def test_the_core_plugins_are_the_features_plugin_functions_and_their_modules_register_the_tables():
    assert all(p.__name__ == "plugin" and callable(p) for p in plugins.CORE)
    # the registry's loader imports exactly the core plugins' modules for the features' tables, in order
    assert tuple(p.__module__ for p in plugins.CORE) == FEATURE_MODULES


def test_every_feature_and_procedure_module_is_named_for_the_registry():
    names = manifest_modules()
    for name in FEATURE_MODULES:
        assert name in names
    for proc in PROCEDURES.values():
        assert proc.systems().__name__ in names
    for name in names:
        assert callable(importlib.import_module(name).plugin)


def test_a_pack_names_its_procedure_and_an_unknown_name_says_which_exist():
    assert procedure_for("prp") is procedure_for("needle")  # the needle procedure's former name still loads
    assert procedure_of({"pack": {"procedure": "cutting"}}).name == "cutting"
    assert procedure_of({"pack": {}}) is None
    with pytest.raises(UserError, match="unknown procedure 'sewing'; built-in procedures: cutting, demo, needle, prp"):
        procedure_for("sewing")


def test_importing_the_table_compiles_no_procedures_kernels():
    """`chainsim` starts without any procedure's systems: the table holds light declarations, and a
    procedure's systems (numba kernels, the tissue) are imported when a pack runs it."""
    systems = [f"chainsim.systems.procedures.{p}.procedure" for p in ("needle", "cutting", "demo")]
    heavy = [
        *systems,
        "chainsim.systems.procedures.needle.tissue",
        "chainsim.systems.procedures.needle.haptics",
        "numba",
    ]
    code = (
        "import sys; import chainsim.systems.procedures; import chainsim.game.packs.declarations; "
        f"print([m for m in {heavy!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip() == "[]"


def test_a_features_tables_come_from_its_own_package():
    registry.load_all(manifest_modules())
    owners = {name: schema.cls.__module__ for name, schema in registry.COMPONENTS.items()}
    # the deformable component is the tissue feature's, the needle the needle procedure's, the forceps the
    # cutting procedure's: none of them lives in the ECS kernel
    assert owners["deformable"].startswith("chainsim.systems.tissue.")
    assert owners["needle"].startswith("chainsim.systems.procedures.needle.")
    assert owners["forceps"].startswith("chainsim.systems.procedures.cutting.")
    kernel = {n for n, m in owners.items() if m.startswith("chainsim.components.")}
    assert "deformable" not in kernel and "transform" in kernel
