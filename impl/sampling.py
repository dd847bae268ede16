"""Pixel sampling shared by the ray-traced renderers (raycast, whitted, radiosity's view).

``spp = 1`` traces the pixel centre (the thesis's one ray per pixel, 1.3.3);
``spp = k²`` averages ``spp`` samples over the pixel — a box filter over the
pixel, the same pixel integral a box-filtered Mitsuba reference estimates —
placed by one of two samplers (:func:`pixel_sample`'s ``sampler`` code):

* :data:`PIXEL_JITTER` (the default): a k×k grid of jittered strata, one
  uniform point per stratum (thesis 2.5.3);
* :data:`PIXEL_SOBOL`: the first ``spp`` points of an Owen-scrambled Sobol
  (0, 2)-sequence (:func:`impl.lowdiscrepancy.sample_2d`, dimension pair 0),
  scrambled per pixel by :func:`impl.lowdiscrepancy.pixel_seed`.  When ``spp``
  is a power of two they form a (0, m, 2)-net: one point in every elementary
  interval of area 1/spp (k×k strata and every other aspect ratio), and the
  scrambling makes each point uniform on the pixel, so the estimate stays
  unbiased (Owen 1995; Burley 2020).

The per-pixel variance of that mean comes from the sample variance,
accumulated with Welford's update (an over-estimate for stratified and
low-discrepancy samples, so Z-tests stay conservative).
"""

import math

import numpy as np
from numba import njit

from core.algorithm import Param

from core.errors import ParamError

from .lowdiscrepancy import pair_hashes, pixel_seed, sample_2d, sample_2d_hashed
from .rng import uniform_from, uniform_prefix

__all__ = ["check_spp", "strata", "pixel_sample", "jittered_film", "sobol_film_hashes", "sobol_film",
           "welford_add", "variance_of_mean", "PIXEL_JITTER", "PIXEL_SOBOL", "PIXEL_SAMPLERS",
           "SAMPLER_PARAM", "sampler_code"]

#: :func:`pixel_sample` sampler codes, and their names (index = code).
PIXEL_JITTER = 0
PIXEL_SOBOL = 1
PIXEL_SAMPLERS = ("jitter", "sobol")
#: The Sobol dimension pair of the pixel position (other pairs are free for lens, time, light).
PIXEL_PAIR = 0

#: The tracers' ``sampler`` parameter: where a pixel's samples go (:func:`pixel_sample`).
SAMPLER_PARAM = Param("sampler", str, "jitter",
                      "pixel samples: jitter (k×k jittered strata) | sobol (Owen-scrambled Sobol "
                      "points, a (0, m, 2)-net per pixel when spp is a power of two)",
                      choices=PIXEL_SAMPLERS)


def sampler_code(params: dict) -> int:
    """The :func:`pixel_sample` code of parsed parameters' ``sampler`` (jitter without one)."""
    return PIXEL_SAMPLERS.index(params.get("sampler", "jitter"))


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
def pixel_sample(spp, k, s, seed, pixel, sampler=PIXEL_JITTER, x=0, y=0):
    """Offset (fx, fy) in [0, 1)² of sample ``s`` (0 .. spp-1) inside the pixel.

    ``spp = 1``: the pixel centre, whatever the sampler.  :data:`PIXEL_JITTER`:
    a uniform point in stratum ``s`` of the k×k grid (``k`` = :func:`strata`),
    drawn from ``(seed, pixel, s)``.  :data:`PIXEL_SOBOL`: Owen-scrambled Sobol
    point ``s`` of the pixel ``(x, y)`` (its column and row: the scramble seed is
    ``pixel_seed(x, y, seed)``; ``k`` and ``pixel`` are unused).
    """
    if spp == 1:
        return 0.5, 0.5
    if sampler == PIXEL_SOBOL:
        return sample_2d(PIXEL_PAIR, s, pixel_seed(x, y, seed))
    h = uniform_prefix(seed, pixel, s)
    return (s % k + uniform_from(h, 0)) / k, (s // k + uniform_from(h, 1)) / k


@njit(cache=True, _nrt=False)
def jittered_film(spp, k, s, seed, pixel, x, y, fx, fy):
    """Film positions (pixels) of sample ``s`` of :data:`PIXEL_JITTER` for every pixel i of
    a batch: ``x[i] + offset``, ``y[i] + offset`` with :func:`pixel_sample`'s offset
    (same arithmetic, same bits) — the pixel's integer coordinates ``x``, ``y`` (float64)
    and index ``pixel`` (int64).  Every array a separate argument and no branch in the
    loop: LLVM vectorises the hashing and the divisions over the pixels.  Where k is a
    power of two, 1/k is exact and a product by it rounds as the quotient does (both are
    the exact value scaled by a power of two), so that loop multiplies: a packed division
    costs several times a product."""
    if spp == 1:
        for i in range(pixel.shape[0]):
            fx[i] = x[i] + 0.5
            fy[i] = y[i] + 0.5
        return
    sx, sy = s % k, s // k
    if k & (k - 1) == 0:
        r = 1.0 / k
        for i in range(pixel.shape[0]):
            h = uniform_prefix(seed, pixel[i], s)
            fx[i] = x[i] + (sx + uniform_from(h, 0)) * r
            fy[i] = y[i] + (sy + uniform_from(h, 1)) * r
        return
    for i in range(pixel.shape[0]):
        h = uniform_prefix(seed, pixel[i], s)
        fx[i] = x[i] + (sx + uniform_from(h, 0)) / k
        fy[i] = y[i] + (sy + uniform_from(h, 1)) / k


@njit(cache=True, _nrt=False)
def sobol_film_hashes(seed, x, y, h, h2):
    """The scramble hashes of every pixel i of a batch (integer coordinates ``x``, ``y``,
    float64) for :func:`sobol_film`: :func:`impl.lowdiscrepancy.pair_hashes` of the pixel
    pair and ``pixel_seed(x, y, seed)`` into ``h[i]``, ``h2[i]`` (uint64).  They do not
    depend on the sample index: a tile computes them once for all its samples."""
    for i in range(x.shape[0]):
        h[i], h2[i] = pair_hashes(PIXEL_PAIR, pixel_seed(np.int64(x[i]), np.int64(y[i]), seed))


@njit(cache=True, _nrt=False)
def sobol_film(s, h, h2, x, y, fx, fy):
    """Film positions (pixels) of sample ``s`` of :data:`PIXEL_SOBOL` for every pixel i of a
    batch: ``x[i] + u``, ``y[i] + v`` with :func:`pixel_sample`'s (u, v) for spp > 1 (same
    arithmetic, same bits) — the pixel's integer coordinates ``x``, ``y`` (float64) and its
    hashes ``h``, ``h2`` (:func:`sobol_film_hashes`).  The index shuffle and value
    scrambles are 32-bit integer arithmetic, bit reversals and byte-table lookups without
    branches: LLVM vectorises them over the pixels."""
    for i in range(x.shape[0]):
        u, v = sample_2d_hashed(s, h[i], h2[i])
        fx[i] = x[i] + u
        fy[i] = y[i] + v


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
