"""Relaxation after a ChainMail cascade (thesis 5.2.5; Gibson's shrink-free variant, 4.2.3).

Each active element P is pulled toward the centroid of its neighbours' "ideal" positions
Q_i = P_i* + (rest[P] - rest[P_i]): where P would sit if the link to P_i kept its rest vector. The
centroid minimises the sum of squared distances to the Q_i, and because it uses rest offsets instead
of the bare neighbour positions it does not shrink the boundary; a rigidly moved mesh is already at
rest. (5.2.5 writes delta_i as the difference P - P_i and subtracts it; the sign that keeps a rigid
motion a fixed point is the one used here, Q_i = P_i* - (rest[P_i] - rest[P]).)

Every iteration is a Jacobi step: all active elements read the positions of the previous iteration and
write a separate buffer, so each element's update is independent and the result does not depend on
the number of threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .graph import Graph, fixed_mask


@njit(cache=True, parallel=True)
def _relax_kernel(rest, pos, indptr, indices, ealive, active, iterations, step, fixed, has_fixed):
    k = active.shape[0]
    dim = pos.shape[1]
    new = np.empty((k, dim), dtype=np.float64)
    for _ in range(iterations):
        for i in prange(k):
            e = active[i]
            cnt = 0
            for a in range(dim):
                new[i, a] = 0.0
            if not (has_fixed and fixed[e]):
                for j in range(indptr[e], indptr[e + 1]):
                    if not ealive[j]:
                        continue
                    nb = indices[j]
                    cnt += 1
                    for a in range(dim):
                        new[i, a] += np.float64(pos[nb, a]) + (np.float64(rest[e, a]) - np.float64(rest[nb, a]))
            for a in range(dim):
                p = np.float64(pos[e, a])
                if cnt > 0:
                    new[i, a] = p + step * (new[i, a] / cnt - p)
                else:
                    new[i, a] = p
        for i in prange(k):
            e = active[i]
            for a in range(dim):
                pos[e, a] = new[i, a]


def relax(rest, pos, graph: Graph, active, iterations, step=1.0, fixed=None) -> None:
    """Relax `active` elements in place for `iterations` Jacobi sweeps of size `step` (0 < step <= 1).

    rest, pos: (N, D) float64 or both float32. active: int64 ids (the cascade's moved elements minus the
    grabbed and fixed ones; the caller chooses). Elements with no live link stay put; fixed ones (bool
    (N,) mask) never move even if listed. Inactive neighbours are read but never written.
    """
    if not isinstance(pos, np.ndarray) or pos.ndim != 2 or pos.dtype not in (np.float32, np.float64):
        raise ValueError("pos must be a float32 or float64 array of shape (N, D)")
    if not isinstance(rest, np.ndarray) or rest.shape != pos.shape or rest.dtype != pos.dtype:
        raise ValueError(f"rest must match pos in shape and dtype, got {getattr(rest, 'shape', None)}")
    if not pos.flags.c_contiguous or not rest.flags.c_contiguous:
        raise ValueError("rest and pos must be C-contiguous")
    n = pos.shape[0]
    if graph.indptr.shape[0] != n + 1:
        raise ValueError(f"graph has {graph.indptr.shape[0] - 1} elements but pos has {n}")
    active = np.ascontiguousarray(np.atleast_1d(np.asarray(active)), dtype=np.int64)
    if active.ndim != 1:
        raise ValueError("active must be a 1-D array of element ids")
    if active.size and (active.min() < 0 or active.max() >= n):
        raise ValueError(f"active ids must lie in [0, {n})")
    if active.size > 1 and np.unique(active).size != active.size:
        raise ValueError("active ids must be distinct")
    iterations = int(iterations)
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    step = float(step)
    if not (0.0 < step <= 1.0):
        raise ValueError(f"step must lie in (0, 1], got {step}")
    fixed_arr, has_fixed = fixed_mask(fixed, n)
    if active.size == 0 or iterations == 0:
        return
    _relax_kernel(
        rest, pos, graph.indptr, graph.indices, graph.entry_alive, active, iterations, step, fixed_arr, has_fixed
    )
