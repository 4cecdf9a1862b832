"""The shell's benchmarks, one module per `chainsim bench NAME` (render, docs, window, records, train) and the
per-pack frame costs of `chainsim study`; the engine's own benchmarks are in chainsim.tools.bench."""
