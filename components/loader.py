"""Spawning a pack's scene into an App: entities with their components, plus pack resources.

Components are built from the validated manifest tables; a component type may declare a `build`
hook (in its own module, in this codebase) that derives runtime state at spawn, e.g. a deformable
body's link graph from its mesh. Nothing from the pack is executed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import esper

from chainsim.components.app import App
from chainsim.components.core import Name
from chainsim.components.registry import COMPONENTS
from chainsim.components.resources import EntityIndex, PackResource


class Pack(Protocol):
    """What spawning needs of a loaded pack (chainsim.game.packs.pack.Pack is one): its validated
    manifest and its scenes."""

    manifest: dict[str, Any]

    def scene(self, name: str | None = None) -> tuple[str, dict[str, Any]]: ...


@dataclass(slots=True)
class SpawnContext:
    """What a component build hook may use."""

    app: App
    pack: Pack
    entity_name: str
    entity: int


def spawn_scene(app: App, pack: Pack, scene: str | None = None) -> EntityIndex:
    scene_name, spec = pack.scene(scene)
    app.insert_resource(PackResource(pack, scene_name, spec))
    wanted = spec.get("entities") or list(pack.manifest["entities"])
    index = EntityIndex()
    with app.active():
        for ename in wanted:
            tables = pack.manifest["entities"][ename]
            ent = esper.create_entity(Name(ename))
            index.by_name[ename] = ent
            built = []
            for cname, values in tables.items():
                schema = COMPONENTS[cname]
                assert schema.cls is not None  # @component registers every component schema with its class
                comp = schema.cls(**values)
                esper.add_component(ent, comp)
                if schema.build is not None:
                    built.append((schema.build, comp))
            for hook, comp in built:
                hook(comp, SpawnContext(app, pack, ename, ent))
    app.insert_resource(index)
    return index
