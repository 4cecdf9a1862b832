"""Builders of the needle procedure's packs: the prp anatomy (prepare_prp and its prp_* parts), its lighter
display meshes (prp_display) and its scripted attempts (make_prp_scripts, make_prp_mouse_script)."""
