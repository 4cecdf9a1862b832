"""The step's changed-rows pass against numpy on random positions (NaN and inf included), float32 and float64."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.systems.engine.kernels.rows import changed_rows

values = st.floats(allow_nan=True, allow_infinity=True, width=32)


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from([np.float32, np.float64]),
    st.integers(0, 40),
    st.sampled_from([2, 3]),
    st.data(),
)
def test_changed_rows_equals_numpy(dtype, n, d, data):
    before = data.draw(arrays(dtype, (n, d), elements=values))
    after = before.copy()
    mask = data.draw(arrays(np.bool_, (n, d)))
    after[mask] = data.draw(arrays(dtype, (n, d), elements=values))[mask]
    moved, finite = changed_rows(after, before)
    assert np.array_equal(moved, np.flatnonzero(np.any(after != before, axis=1)))
    assert finite == bool(np.all(np.isfinite(after)))
