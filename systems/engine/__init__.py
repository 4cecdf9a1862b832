"""The deformation engine (`chainsim.systems.engine`): kernels, meshes, tetrahedralisation, reordering and bodies.

A library on its own: it imports numpy, numba, scipy and trimesh, never esper or the rest of chainsim.
"""
