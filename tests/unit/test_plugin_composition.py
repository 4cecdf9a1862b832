"""How a run is composed: a missing plugin is an error, and each feature registers its own manifest tables."""

from __future__ import annotations

import importlib

import pytest

from chainsim.components import registry
from chainsim.components.app import App
from chainsim.game.app import plugins
from chainsim.systems import FEATURES, manifest_modules
from chainsim.systems.procedures import PROCEDURES


def test_a_plugin_whose_module_is_missing_is_an_error_not_a_smaller_scene(monkeypatch):
    monkeypatch.setattr(plugins, "CORE", ["chainsim.systems.no_such_feature:plugin"])
    with pytest.raises(ModuleNotFoundError, match="no_such_feature"):
        plugins.install(App())


def test_every_feature_and_procedure_module_is_named_for_the_registry():
    names = manifest_modules()
    for ref in [*FEATURES, *PROCEDURES.values()]:
        assert ref.partition(":")[0] in names
    for name in names:
        assert callable(importlib.import_module(name).plugin)


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
