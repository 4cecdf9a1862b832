"""The tissue feature: the deformable component, its requests and reports, and the deformation system.

It talks to soft bodies only through the Body API of chainsim.systems.engine (thesis 4-5)."""
