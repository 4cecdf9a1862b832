"""Which plugins a run gets. Core plugins always; the rest only when the scene needs them.

A plugin is `build(app)`; it inspects the spawned world and adds systems only for what some
entity requires (an all-rigid scene gets no deformation system). The plugins are the functions
themselves, imported here, so the type checker and the import contracts follow every one (a missing
one fails at import, never as a quietly smaller scene). Procedures named by a pack's `pack.procedure`
are built-in plugins, the table's objects: packs never carry code.
"""

from __future__ import annotations

from collections.abc import Callable

from chainsim.components.app import App
from chainsim.components.resources import PackResource
from chainsim.systems.engine.errors import UserError
from chainsim.systems.motion import input as motion_input
from chainsim.systems.motion import scripted
from chainsim.systems.procedures import procedure_for, procedure_of
from chainsim.systems.tissue import deformation
from chainsim.systems.view import cameras

Plugin = Callable[[App], None]

#: always considered, in this order; each decides for itself whether the scene needs it
CORE: tuple[Plugin, ...] = (motion_input.plugin, cameras.plugin, scripted.plugin, deformation.plugin)


def render_plugin(app: App) -> None:
    """The render system (moderngl), imported only by a run that draws."""
    from chainsim.game.render.render_system import plugin  # noqa: PLC0415 - GL only where a run draws

    plugin(app)


def _name(plugin: Plugin) -> str:
    return f"{plugin.__module__}:{plugin.__name__}"


def event_check(procedure: str) -> Callable | None:
    """The procedure's check of one scripted event (its declared `check_event(ev)`, raising UserError for
    a value it would refuse mid-run), or None when it reads every event as it comes."""
    return procedure_for(procedure).check_event if procedure else None


def install(app, procedure: str = "", render: bool = False) -> list[str]:
    """Build the plugins for a spawned scene; returns the names of those installed (a procedure's by
    its name in the table)."""
    done = []
    for plugin in CORE:
        plugin(app)
        done.append(_name(plugin))
    if procedure:
        procedure_for(procedure).plugin(app)
        done.append(f"procedure:{procedure}")
    if render:
        render_plugin(app)
        done.append("chainsim.game.render.render_system:plugin")
    return done


def attach_device(app, spec: str, **kw):
    """Attach the force-feedback device `spec` to the instrument of the pack's procedure (its declared
    `haptics`; keywords as it takes them); a procedure without a haptic instrument takes no device."""
    pres = app.get_resource(PackResource)
    proc = procedure_of(pres.pack.manifest) if pres is not None else None
    if proc is None or proc.haptics is None:
        raise UserError(f"--device {spec}: only a needle procedure takes a device")
    return proc.haptics(app, spec, **kw)
