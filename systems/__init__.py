"""The systems layer: one package per feature (tissue, view, motion) and one per procedure, plus the engine.

Each feature is a plugin in the manner of Bevy's: its package owns its components, events and systems,
and a `plugin(app)` installs what the spawned scene needs. FEATURES lists them in the order the App
considers them; procedures are listed by name in chainsim.systems.procedures.PROCEDURES. The engine
(chainsim.systems.engine) is a library underneath everything: no ECS, no window, no GL.
"""

from chainsim.systems.procedures import PROCEDURES

# always considered, in this order; each decides for itself whether the scene needs it
FEATURES: list[str] = [
    "chainsim.systems.motion.input:plugin",
    "chainsim.systems.view.cameras:plugin",
    "chainsim.systems.motion.scripted:plugin",
    "chainsim.systems.tissue.deformation:plugin",
]


def manifest_modules() -> list[str]:
    """The modules whose import registers every feature's and procedure's manifest tables."""
    return sorted({ref.partition(":")[0] for ref in [*FEATURES, *PROCEDURES.values()]})
