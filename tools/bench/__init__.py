"""ChainMail benchmarks: the thesis grids (6.2), full and local cascades, reordering, and their meshes."""
