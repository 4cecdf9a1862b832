"""numba kernels: pure functions on flat arrays, no ECS imports."""
