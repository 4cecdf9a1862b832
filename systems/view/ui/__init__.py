"""Viewports, cameras and control-panel widgets without GL: the geometry the view system and the renderer share."""
