"""The Escobar functional's arithmetic in the optimiser's kernels (``optimize/kernels.py``)."""

from __future__ import annotations

import numba as nb
import numpy as np

from vmesh.geometry.optimize import kernels


@nb.njit(cache=False)
def _many(h):
    out = np.empty_like(h)
    for i in range(h.size):
        out[i] = kernels._inv_cbrt_sq(h[i])
    return out


def test_inverse_cube_root_squared_matches_libm_over_the_whole_range():
    """``h^(-2/3)`` without ``cbrt``: a few ulps from the library's value for every ``h`` the
    functional can see (``max(h, 1e-300)`` up to huge), exact powers of 8 included."""
    rng = np.random.default_rng(0)
    h = np.concatenate([10.0 ** rng.uniform(-300, 300, 200_000), 8.0 ** np.arange(-99, 100), [1e-300, 1.0, 0.5, 2.0, 3.0]])
    c = np.cbrt(h)
    ref = 1.0 / (c * c)  # (1 / cbrt(h * h), the kernels' former form, over- and underflows beyond 1e+-154)
    assert np.max(np.abs(_many(h) / ref - 1.0)) < 4e-15
