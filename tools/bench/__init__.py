"""Every benchmark, one module per `chainsim bench NAME`: the engine's (the thesis grids of 6.2, full and local
cascades, the tissue models, sleeping, drag) and the shell's (render, docs, window, startup, records, train,
replay, haptics, needle, per-pack frame costs)."""
