"""The deformation engine (`chainsim.systems.engine`): kernels, meshes, tetrahedralisation, reordering and bodies.

A library on its own: it imports numpy, numba, scipy and trimesh, never esper or the rest of chainsim.
"""

from chainsim.systems.engine import threads

# before any kernel module: the OpenMP runtime reads its wait policy once, when numba first starts its
# threads, and every body, benchmark and tool reaches the kernels through this package
threads.apply()
