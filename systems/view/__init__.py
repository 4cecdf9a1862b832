"""The view feature: cameras, picking on the (deformed) meshes, and the control panel's widgets."""
