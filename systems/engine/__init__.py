"""The deformation engine (`chainsim.systems.engine`): kernels, meshes, tetrahedralisation, reordering and bodies.

A library on its own: it imports numpy, numba, scipy and trimesh, never esper or the rest of chainsim.
The names a researcher starts from are here (loaded when first used, so importing the package stays
light): ``make_body`` (any model by name, chainsim.systems.engine.bodies.factory) and ``tet_grid`` (a
block of tetrahedra, chainsim.systems.engine.meshgen)::

    from chainsim.systems.engine import make_body, tet_grid
"""

from typing import Any

from chainsim.systems.engine import threads

# before any kernel module: the OpenMP runtime reads its wait policy once, when numba first starts its
# threads, and every body, benchmark and tool reaches the kernels through this package
threads.apply()

__all__ = ["make_body", "tet_grid"]


def __getattr__(name: str) -> Any:
    if name == "make_body":
        from chainsim.systems.engine.bodies.factory import make_body  # noqa: PLC0415 - loaded on first use

        return make_body
    if name == "tet_grid":
        from chainsim.systems.engine.meshgen import tet_grid  # noqa: PLC0415

        return tet_grid
    raise AttributeError(f"module 'chainsim.systems.engine' has no attribute {name!r}")
