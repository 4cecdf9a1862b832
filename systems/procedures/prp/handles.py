"""What the rhizotomy systems share: the entity ids they act on and the HUD they write to."""

from __future__ import annotations

from chainsim.components.hud import HudState


def hud(app):
    """The HUD resource (the view plugin's); one is made when running without it."""
    h = app.get_resource(HudState)
    if h is None:
        h = app.insert_resource(HudState())
    return h


class PrpHandles:
    """Entity ids the procedure systems use (resource)."""

    def __init__(self, needle: int, procedure: int, markers: list, planes: list, labels: list):
        self.needle = needle
        self.procedure = procedure
        self.markers = markers
        self.planes = planes
        self.labels = labels  # the markers' label texts, shown once a landmark is placed
