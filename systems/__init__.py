"""The systems layer: one package per feature (tissue, view, motion) and one per procedure, plus the engine.

Each feature is a plugin in the manner of Bevy's: its package owns its components, events and systems,
and a `plugin(app)` installs what the spawned scene needs; the shell lists those functions, in the order
the App considers them (chainsim.game.trainer.plugins.CORE). FEATURE_MODULES names the modules whose
import registers the features' manifest tables, for the registry's loader (importing this package stays
light); procedures are the objects listed in chainsim.systems.procedures.PROCEDURES. The engine
(chainsim.systems.engine) is a library underneath everything: no ECS, no window, no GL.
"""

# the modules of the features' plugins (tests/unit/test_plugin_composition.py holds them equal to the
# modules of chainsim.game.trainer.plugins.CORE)
FEATURE_MODULES: tuple[str, ...] = (
    "chainsim.systems.motion.input",
    "chainsim.systems.view.cameras",
    "chainsim.systems.motion.scripted",
    "chainsim.systems.tissue.deformation",
)


def manifest_modules() -> list[str]:
    """The modules whose import registers every feature's and procedure's manifest tables."""
    from chainsim.systems.procedures import PROCEDURES  # noqa: PLC0415 - only the registry's loader asks

    return sorted(set(FEATURE_MODULES) | {p.systems().__name__ for p in PROCEDURES.values()})
