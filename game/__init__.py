"""chainsim: the application shell (App, stages, packs, CLI, records, window and GL adapters)."""

from importlib.metadata import PackageNotFoundError, version

try:  # the version is written once, in pyproject.toml
    __version__ = version("chainsim")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "unknown (not installed)"
