"""Jobs that build the shipped packs from source data, one folder per procedure: needle/ (the prp anatomy from
the shared BodyParts3D and HRA meshes, its display meshes and scripted attempts) and cutting/ (the layered
tissue meshes). They need a checkout (the source data, the assets folder they rewrite), so the wheel leaves
them out: run them from a checkout or an editable install, `python -m chainsim.game.packbuild.needle.prepare_prp`."""
