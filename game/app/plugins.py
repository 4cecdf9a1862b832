"""Which plugins a run gets. Core plugins always; the rest only when the scene needs them.

A plugin is `build(app)`; it inspects the spawned world and adds systems only for what some
entity requires (an all-rigid scene gets no deformation system). Procedures named by a pack's
`pack.procedure` are built-in plugins, referenced by name: packs never carry code.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from chainsim.systems import FEATURES
from chainsim.systems.procedures import PROCEDURES

CORE: list[str] = FEATURES

RENDER: list[str] = ["chainsim.game.gl.render_system:plugin"]


def _resolve(ref: str) -> Callable:
    # a plugin that is named but missing is an error: a scene must never run with a feature quietly absent
    mod, _, fn = ref.partition(":")
    return getattr(importlib.import_module(mod), fn)


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
        _resolve(ref)(app)
        done.append(ref)
    return done
