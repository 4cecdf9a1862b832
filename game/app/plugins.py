"""Which plugins a run gets. Core plugins always; the rest only when the scene needs them.

A plugin is `build(app)`; it inspects the spawned world and adds systems only for what some
entity requires (an all-rigid scene gets no deformation system). Procedures named by a pack's
`pack.procedure` are built-in plugins, referenced by name: packs never carry code.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from chainsim.systems.procedures import PROCEDURES

# always considered, in this order; each decides for itself whether the scene needs it
CORE: list[str] = [
    "chainsim.systems.input:plugin",
    "chainsim.systems.view:plugin",
    "chainsim.systems.motion:plugin",
    "chainsim.systems.deformation:plugin",
]

RENDER: list[str] = ["chainsim.game.gl.render_system:plugin"]


def _resolve(ref: str) -> Callable | None:
    mod, _, fn = ref.partition(":")
    try:
        module = importlib.import_module(mod)
    except ModuleNotFoundError as e:
        if e.name == mod:  # the capability is not part of this build
            return None
        raise
    return getattr(module, fn)


def event_check(procedure: str) -> Callable | None:
    """The procedure's check of one scripted event (a `check_event(ev)` in its plugin's module, raising
    UserError for a value it would refuse mid-run), or None when it reads every event as it comes."""
    if not procedure:
        return None
    module = importlib.import_module(PROCEDURES[procedure].partition(":")[0])
    return getattr(module, "check_event", None)


def install(app, procedure: str = "", render: bool = False) -> list[str]:
    """Build the plugins for a spawned scene; returns the names of those installed."""
    refs = list(CORE)
    if procedure:
        refs.append(PROCEDURES[procedure])
    if render:
        refs.extend(RENDER)
    done = []
    for ref in refs:
        build = _resolve(ref)
        if build is not None:
            build(app)
            done.append(ref)
    return done
