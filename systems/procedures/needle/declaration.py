"""The needle procedure as the shell knows it: its one `Procedure` (chainsim.systems.procedures.procedure).

Light to import: its attempt layout and study (records), its manifest keys (manifest), its X-ray view
(carm) and its pack checks (checks) are plain data and numpy. Its systems, the replay reader, the
haptic servo and the benchmarks' run are imported when first called.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import esper

from chainsim.components.app import App
from chainsim.systems.procedures.needle import carm, checks, manifest, records
from chainsim.systems.procedures.procedure import Bench, ManifestKeys, Procedure, ReplayReader


def _systems() -> ModuleType:
    from chainsim.systems.procedures.needle import procedure  # noqa: PLC0415 - its kernels compile on use

    return procedure


def _plugin(app: App) -> None:
    from chainsim.systems.procedures.needle.procedure import plugin  # noqa: PLC0415

    plugin(app)


def _attempt_record(pack_name: str, values: dict) -> dict:
    from chainsim.systems.procedures.needle.assessment import attempt_record  # noqa: PLC0415

    return attempt_record(pack_name, values)


def _replay(app: App) -> ReplayReader:
    from chainsim.systems.procedures.needle.replay import reader  # noqa: PLC0415

    return reader(app)


def _haptics(app: App, spec: str, **kw: Any) -> Any:
    from chainsim.systems.procedures.needle.haptics import attach  # noqa: PLC0415

    return attach(app, spec, **kw)


def _insertion(root: Any, man: dict) -> tuple[list, float, float]:
    from chainsim.systems.procedures.needle.insertion import straight_insertion  # noqa: PLC0415

    return straight_insertion(root, man)


def _bodies(app: App) -> list:
    from chainsim.systems.procedures.needle.tissue import NeedleTissueScene  # noqa: PLC0415
    from chainsim.systems.tissue.deformable import Deformable  # noqa: PLC0415

    scene = app.resource(NeedleTissueScene)
    with app.active():
        return [esper.component_for_entity(b.entity, Deformable) for b in scene.bodies]


def _trace_rows(app: App) -> list:
    from chainsim.systems.procedures.needle.tissue import NeedleTrace  # noqa: PLC0415

    return app.resource(NeedleTrace).rows


def _pack_problems(man: dict) -> list[tuple[str, str]]:
    out = list(checks.problems(man))
    aids = man.get("needle_procedure", {}).get("aids", [])
    unknown = [a for a in aids if a not in records.AIDS]
    if unknown:
        out.append(
            (
                "needle_procedure.aids",
                f"'{unknown[0][:60]}' is not an aid the records store (aids: {', '.join(records.AIDS)})",
            )
        )
    return out


PROCEDURE = Procedure(
    name="needle",
    plugin=_plugin,
    systems=_systems,
    layout=records.LAYOUT,
    study=records.STUDY,
    attempt_record=_attempt_record,
    manifest=ManifestKeys(
        help=manifest.PROCEDURE_HELP,
        done_on_help=f"Needle procedure ({manifest.DONE_ON_HELP}; docs/needle-procedures.md): steps only move "
        "forward, and Next moves on one step.",
        step_fields=manifest.STEP_FIELDS,
        metric_fields=manifest.METRIC_FIELDS,
    ),
    viewport_kinds=("fluoro",),
    xray=carm.xray_image,
    pack_problems=_pack_problems,
    needs_steps=True,
    stored_targets=checks.hit_entities,
    replay=_replay,
    haptics=_haptics,
    bench=Bench(insertion=_insertion, bodies=_bodies, trace_rows=_trace_rows),
)
