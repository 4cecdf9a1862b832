"""The demonstration procedure as the shell knows it: its one `Procedure`
(chainsim.systems.procedures.procedure). Light to import: its systems are imported when first called.
"""

from __future__ import annotations

from types import ModuleType

from chainsim.components.app import App
from chainsim.systems.procedures.procedure import Procedure


def _systems() -> ModuleType:
    from chainsim.systems.procedures.demo import procedure  # noqa: PLC0415 - the tissue's kernels on use

    return procedure


def _plugin(app: App) -> None:
    from chainsim.systems.procedures.demo.procedure import plugin  # noqa: PLC0415

    plugin(app)


PROCEDURE = Procedure(name="demo", plugin=_plugin, systems=_systems)
