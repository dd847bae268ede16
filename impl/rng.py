"""Counter-based random numbers for the numba kernels.

``uniform(seed, a, b, c)`` hashes its integer coordinates (seed, pixel,
sample, dimension) with the SplitMix64 finaliser, so every pixel-sample draws
the same numbers whatever the thread schedule: renders are reproducible under
``prange``.
"""

import numpy as np
from numba import njit

_K1 = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_INV53 = 1.0 / 9007199254740992.0  # 2^-53


@njit(inline="always", cache=True)
def _mix(x):
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


@njit(inline="always", cache=True)
def uniform(seed, a, b, c):
    """A float64 in [0, 1) determined by four non-negative integers."""
    h = _mix(np.uint64(seed) * _K1 + np.uint64(a))
    h = _mix(h + np.uint64(b) * _K1)
    h = _mix(h + np.uint64(c) * _K1)
    return float(h >> np.uint64(11)) * _INV53
