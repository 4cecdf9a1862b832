"""The cutting trainer as the shell knows it: its one `Procedure` (chainsim.systems.procedures.procedure).

Light to import: its attempt layout (records) is plain data; its systems, and its check of a scripted
event, are imported when first called.
"""

from __future__ import annotations

from types import ModuleType

from chainsim.components.app import App
from chainsim.systems.procedures.cutting import records
from chainsim.systems.procedures.procedure import ManifestKeys, Procedure


def _systems() -> ModuleType:
    from chainsim.systems.procedures.cutting import procedure  # noqa: PLC0415 - the tissue's kernels on use

    return procedure


def _plugin(app: App) -> None:
    from chainsim.systems.procedures.cutting.procedure import plugin  # noqa: PLC0415

    plugin(app)


def _check_event(ev: object) -> None:
    from chainsim.systems.procedures.cutting.procedure import check_event  # noqa: PLC0415

    check_event(ev)


PROCEDURE = Procedure(
    name="cutting",
    plugin=_plugin,
    systems=_systems,
    check_event=_check_event,
    layout=records.LAYOUT,
    manifest=ManifestKeys(
        done_on_help="Cutting procedure (carried:MM, cut:MM, opened:MM; docs/making-a-pack.md): any one completes "
        "the step, in whatever order the trainee works.",
    ),
)
