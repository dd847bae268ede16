"""Counter-based random numbers for the numba kernels.

``uniform(seed, a, b, c)`` hashes its integer coordinates (seed, pixel,
sample, dimension) with the SplitMix64 finaliser, so every pixel-sample draws
the same numbers whatever the thread schedule: renders are reproducible under
``prange``.  The hash runs left to right, so a kernel drawing many dimensions of
one (seed, pixel, sample) hashes their common prefix once (:func:`uniform_prefix`,
:func:`uniform_from`).
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
def uniform_prefix(seed, a, b):
    """The hash state of (seed, a, b) that :func:`uniform` continues for every
    dimension c: hoisted out of a loop over dimensions, each number then costs one
    mix instead of three (:func:`uniform_from`)."""
    h = _mix(np.uint64(seed) * _K1 + np.uint64(a))
    return _mix(h + np.uint64(b) * _K1)


@njit(inline="always", cache=True)
def uniform_from(h, c):
    """``uniform(seed, a, b, c)`` from ``h = uniform_prefix(seed, a, b)``: the same number."""
    return float(_mix(h + np.uint64(c) * _K1) >> np.uint64(11)) * _INV53


@njit(inline="always", cache=True)
def uniform(seed, a, b, c):
    """A float64 in [0, 1) determined by four non-negative integers."""
    return uniform_from(uniform_prefix(seed, a, b), c)
