"""ECS systems, one module per system; numba kernels live in chainsim.engine.kernels."""
