"""chainsim: the application shell (App, stages, packs, CLI, adapters)."""

__version__ = "0.1.0"
