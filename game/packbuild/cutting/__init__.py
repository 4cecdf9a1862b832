"""Builders of the cutting procedure's pack: its layered tissue meshes (make_cutting_pack)."""
