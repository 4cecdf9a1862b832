"""Which rows of a positions array a step changed, and whether all are finite, in one pass.

Every body's step reports the elements it moved and refuses non-finite positions (bodies.base.Body.step);
done with numpy that is four passes over the whole body and temporaries of its size, which a body that
solves only near the tool (hybrid sleeping) would pay for every frame."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def changed_rows(after, before):
    """(indices of the rows where `after` differs from `before`, whether every value of `after` is finite)."""
    n, d = after.shape
    out = np.empty(n, dtype=np.int64)
    m = 0
    finite = True
    for i in range(n):
        changed = False
        for c in range(d):
            a = after[i, c]
            if a != before[i, c]:
                changed = True
            if not np.isfinite(a):
                finite = False
        if changed:
            out[m] = i
            m += 1
    return out[:m].copy(), finite
