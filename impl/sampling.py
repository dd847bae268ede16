"""Pixel sampling shared by the ray-traced renderers (raycast, whitted, radiosity's view).

``spp = 1`` traces the pixel centre (the thesis's one ray per pixel, 1.3.3);
``spp = k²`` traces a k×k grid of jittered strata and averages it — a box
filter over the pixel, the same pixel integral a box-filtered Mitsuba
reference estimates.  The per-pixel variance of that mean comes from the
sample variance, accumulated with Welford's update (an over-estimate for
stratified samples, so Z-tests stay conservative).
"""

import math

from numba import njit

from core.errors import ParamError

from .rng import uniform

__all__ = ["check_spp", "strata", "pixel_sample", "welford_add", "variance_of_mean"]


def check_spp(spp: int, algorithm: str) -> int:
    """The side k of a k×k grid for ``spp`` = k², or a ValueError naming the algorithm."""
    k = int(round(math.sqrt(spp))) if spp >= 1 else 0
    if spp < 1 or k * k != spp:
        raise ParamError(f"{algorithm}: spp must be 1 (pixel centre) or a square k² (k×k strata), got {spp}")
    return k


@njit(inline="always", cache=True)
def strata(spp):
    return int(math.sqrt(spp) + 0.5)


@njit(inline="always", cache=True)
def pixel_sample(spp, k, s, seed, pixel):
    """Offset (fx, fy) in [0, 1)² of sample ``s`` inside the pixel: centre or jittered stratum."""
    if spp == 1:
        return 0.5, 0.5
    return (s % k + uniform(seed, pixel, s, 0)) / k, (s // k + uniform(seed, pixel, s, 1)) / k


@njit(inline="always", cache=True)
def welford_add(s, r, g, b, m0, m1, m2, q0, q1, q2):
    """Add sample number ``s`` (0-based) to running means m and squared-deviation sums q."""
    c = s + 1.0
    d0 = r - m0
    d1 = g - m1
    d2 = b - m2
    m0 += d0 / c
    m1 += d1 / c
    m2 += d2 / c
    return m0, m1, m2, q0 + d0 * (r - m0), q1 + d1 * (g - m1), q2 + d2 * (b - m2)


@njit(inline="always", cache=True)
def welford_row(acc, i, s, r, g, b):
    """:func:`welford_add` on row ``i`` of a (P, 6) array of running (m0, m1, m2, q0, q1, q2)."""
    (acc[i, 0], acc[i, 1], acc[i, 2], acc[i, 3], acc[i, 4],
     acc[i, 5]) = welford_add(s, r, g, b, acc[i, 0], acc[i, 1], acc[i, 2], acc[i, 3], acc[i, 4],
                              acc[i, 5])


@njit(inline="always", cache=True)
def variance_of_mean(q, spp):
    """Sample variance / spp from a squared-deviation sum; 0 for a single sample."""
    return q / (spp * (spp - 1.0)) if spp > 1 else 0.0
