"""Pixel sampling patterns for anti-aliasing (thesis 2.5.1–2.5.4).

Each pattern fills ``out[:n, 0:2]`` with sample positions (fx, fy) in pixel
units relative to the pixel's corner, [0, 1)² (scalar ``@njit`` functions; the
random numbers come from :func:`impl.rng.uniform` keyed by (seed, pixel,
sample, dimension), so every pixel's pattern is reproducible under ``prange``):

* :func:`uniform_pattern` — *supersampling* on a regular k×k grid of
  sub-pixel centres (2.5.1, 2.5.2 "uniform point sampling");
* :func:`random_pattern` — *stochastic* sampling: n independent uniform
  positions (2.5.1 "stochastic ray tracing");
* :func:`jitter_pattern` — a jittered regular grid (2.5.4): the centre of
  cell i, i.e. ``(i + ½) T`` with T = 1/k, displaced by ζ — *white-noise
  jitter* ζ ~ U[−γT, γT] (γ = ½ is the classic stratified sampling), or
  *Gaussian jitter* ζ ~ N(0, (σT)²) (the thesis's figure uses σ = T/6.5).
  A position leaving the pixel wraps around it (toroidally), so each pixel
  keeps its n samples;
* :func:`poisson_disk_pattern` — Poisson-disk sampling (2.5.3) by dart
  throwing (Cook 1986): uniform candidates are accepted when no accepted
  point lies within the minimum distance r (toroidal distance in the pixel,
  so the pattern tiles); r starts at ``POISSON_FILL`` × the hexagonal-packing
  distance √(2 / (√3 n)) and shrinks by 10 % after ``POISSON_TRIES``·n
  rejected darts in a row, so exactly n points are always placed.

The two adaptive schemes need radiance values while they decide where to
sample, so their drivers live in the tracer (:mod:`impl.distributed`); this
module holds their geometry and decision rules:

* *adaptive supersampling* (Whitted 1980, thesis 2.5.1): a square's four
  corners and centre are traced; if any of the five differs from their mean
  by more than ``threshold`` (in any RGB channel) and the depth limit allows,
  the square splits into four, re-using the corners and the centre and tracing
  the 4 edge midpoints and the 4 new centres (:func:`adaptive_children`).
  Each leaf square contributes its five samples with weight area/5
  (:func:`adaptive_disagree`);
* *statistical supersampling* (Lee, Redner, Uselton 1985, thesis 2.5.1):
  start with 4 stratified samples, then add uniform samples one at a time
  until the half-width ``z · s / √n`` of the confidence interval of the pixel
  mean is below ``tolerance`` in every channel, or the budget is spent
  (:func:`statistical_done`).  The sequential stopping rule has a small bias
  (it stops more readily after low-variance draws), measured in the
  convergence study rather than assumed away.

The other dimensions of a pixel sample (lens, shutter time, light point, BSDF
direction: thesis 2.5.8) draw from :func:`dim_1d` / :func:`dim_2d`, per
dimension ``dim`` of pixel sample ``s`` of ``spp``:

* :data:`DIM_STRATIFIED` — Cook's shuffled strata (Cook 1986, "Stochastic
  sampling in computer graphics", ACM TOG 5(1), §5; the idea of pbrt's
  stratified sampler): a 2-D dimension has its own k×k jittered strata
  (spp = k²), a 1-D dimension spp strata, one uniform point per stratum;
  sample s takes stratum π(s), π a pseudo-random permutation of the strata
  drawn per pixel and per dimension (:func:`permute`).  So every dimension's
  spp samples cover its strata once each, and the strata of one dimension
  are paired at random with those of the pixel and of every other dimension
  (no correlation between dimensions).  Each sample is uniform over its
  dimension (π(s) is uniform over the strata), so estimates stay unbiased.
  The lens is the exception (:func:`lens_stratified`): its strata follow the
  pixel strata's rows and columns, so that film-x × lens-x and film-y × lens-y
  are stratified too (an edge out of focus is a discontinuity along x + c·u
  and y + c·v, which a random pairing leaves unstratified);
* :data:`DIM_SOBOL` — padded Owen-scrambled Sobol points
  (:func:`impl.lowdiscrepancy.sample_2d` / ``sample_1d``), one scrambled
  (0, 2)-sequence per 2-D dimension and a scrambled van der Corput sequence
  per 1-D dimension, all seeded per pixel (``pixel_seed(pixel, ...)``) and
  decorrelated by their own index shuffles: the first 2^m samples of each
  2-D dimension are a (0, m, 2)-net.  This is the padded per-pixel form
  (Burley 2020 §4), not a sequence over the whole image (ZSobol).  The
  camera's four dimensions — film position and lens point — are instead one
  4-D Owen-scrambled Sobol point (:func:`camera_sobol`: dimensions 0–3 of
  :func:`impl.lowdiscrepancy.sobol_point`, one index shuffle): an edge out
  of focus is a discontinuity along a mix of film and lens coordinates,
  which strata of each pair apart (padding, shuffling) do not stratify.
"""

from __future__ import annotations

import math

from numba import njit

import numpy as np

from .lowdiscrepancy import pixel_seed, sample_1d, sample_2d, sobol_point
from .rng import uniform, uniform_from, uniform_prefix

__all__ = ["uniform_pattern", "random_pattern", "jitter_pattern", "gaussian_jitter_pattern",
           "poisson_disk_pattern", "poisson_min_distance", "adaptive_disagree", "adaptive_children",
           "statistical_done", "normal_from_uniforms", "POISSON_FILL", "POISSON_TRIES",
           "PATTERN_STREAM", "permute", "dim_1d", "dim_2d", "sobol_pattern", "DIM_INDEPENDENT",
           "DIM_STRATIFIED", "DIM_SOBOL", "DIM_STREAM", "JITTER_STREAM", "camera_sobol", "lens_stratified"]

#: Dart throwing starts at this fraction of the hexagonal-packing distance.
POISSON_FILL = 0.75
#: Rejected darts in a row, per point, before the minimum distance shrinks by 10 %.
POISSON_TRIES = 30
#: Seed offset of the pattern's random stream (apart from every other stream of the tracer).
PATTERN_STREAM = 0x51ED2705

#: :func:`dim_1d` / :func:`dim_2d` modes (``DIM_INDEPENDENT``: the tracer's own hashed numbers).
DIM_INDEPENDENT, DIM_STRATIFIED, DIM_SOBOL = 0, 1, 2
#: Seed offsets of the strata permutations and of the jitter inside the strata.
DIM_STREAM = 0x3C6EF372
JITTER_STREAM = 0x1B873593
#: The second coordinate of :func:`impl.lowdiscrepancy.pixel_seed` for the Sobol dimensions.
_SOBOL_ROW = 0x7F4A7C15
_CAMERA_ROW = 0x2C1B3C6D


@njit(cache=True)
def uniform_pattern(k, out):
    """k×k sub-pixel centres ((i + ½)/k, (j + ½)/k); returns n = k²."""
    for j in range(k):
        for i in range(k):
            out[j * k + i, 0] = (i + 0.5) / k
            out[j * k + i, 1] = (j + 0.5) / k
    return k * k


@njit(cache=True)
def random_pattern(n, seed, pixel, out):
    """n independent uniform positions in the pixel; returns n."""
    for s in range(n):
        out[s, 0] = uniform(seed + PATTERN_STREAM, pixel, s, 0)
        out[s, 1] = uniform(seed + PATTERN_STREAM, pixel, s, 1)
    return n


@njit(inline="always", cache=True)
def _wrap(x):
    return x - math.floor(x)


@njit(cache=True)
def jitter_pattern(k, gamma, seed, pixel, out):
    """White-noise jittered k×k grid: (i + ½)T + ζ, ζ ~ U[−γT, γT], T = 1/k (wrapped); returns k²."""
    for j in range(k):
        for i in range(k):
            s = j * k + i
            zx = (2.0 * uniform(seed + PATTERN_STREAM, pixel, s, 0) - 1.0) * gamma
            zy = (2.0 * uniform(seed + PATTERN_STREAM, pixel, s, 1) - 1.0) * gamma
            out[s, 0] = _wrap((i + 0.5 + zx) / k)
            out[s, 1] = _wrap((j + 0.5 + zy) / k)
    return k * k


@njit(inline="always", cache=True)
def normal_from_uniforms(u1, u2):
    """A standard normal deviate (Box–Muller) from two uniforms in [0, 1)."""
    return math.sqrt(-2.0 * math.log(1.0 - u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def gaussian_jitter_pattern(k, sigma, seed, pixel, out):
    """Gaussian-jittered k×k grid: (i + ½)T + ζ, ζ ~ N(0, (σT)²), T = 1/k (wrapped); returns k²."""
    for j in range(k):
        for i in range(k):
            s = j * k + i
            zx = sigma * normal_from_uniforms(uniform(seed + PATTERN_STREAM, pixel, s, 0),
                                              uniform(seed + PATTERN_STREAM, pixel, s, 1))
            zy = sigma * normal_from_uniforms(uniform(seed + PATTERN_STREAM, pixel, s, 2),
                                              uniform(seed + PATTERN_STREAM, pixel, s, 3))
            out[s, 0] = _wrap((i + 0.5 + zx) / k)
            out[s, 1] = _wrap((j + 0.5 + zy) / k)
    return k * k


@njit(inline="always", cache=True)
def poisson_min_distance(n):
    """Starting minimum distance: POISSON_FILL × the hexagonal-packing distance of n points."""
    return POISSON_FILL * math.sqrt(2.0 / (math.sqrt(3.0) * n))


@njit(cache=True)
def poisson_disk_pattern(n, seed, pixel, out):
    """n Poisson-disk positions by dart throwing (toroidal distance); returns (n, final r)."""
    r = poisson_min_distance(n)
    placed = 0
    dart = 0
    misses = 0
    while placed < n:
        x = uniform(seed + PATTERN_STREAM, pixel, dart, 0)
        y = uniform(seed + PATTERN_STREAM, pixel, dart, 1)
        dart += 1
        ok = True
        r2 = r * r
        for q in range(placed):
            dx = abs(x - out[q, 0])
            dy = abs(y - out[q, 1])
            dx = min(dx, 1.0 - dx)
            dy = min(dy, 1.0 - dy)
            if dx * dx + dy * dy < r2:
                ok = False
                break
        if ok:
            out[placed, 0] = x
            out[placed, 1] = y
            placed += 1
            misses = 0
        else:
            misses += 1
            if misses >= POISSON_TRIES * n:
                r *= 0.9
                misses = 0
    return n, r


@njit(cache=True)
def adaptive_disagree(vals, idx, threshold):
    """Whether the five samples ``vals[idx[0..4]]`` (RGB rows) differ from their mean by > threshold."""
    for c in range(3):
        m = 0.0
        for q in range(5):
            m += vals[idx[q], c]
        m /= 5.0
        for q in range(5):
            if abs(vals[idx[q], c] - m) > threshold:
                return True
    return False


@njit(cache=True)
def adaptive_children(x0, y0, size, pts):
    """The 8 new positions of a split square: 4 edge midpoints, then 4 quadrant centres.

    The square has corner (x0, y0) and side ``size``; its corners are
    c00, c10, c01, c11 and its centre C.  Writes ``pts[0:8]`` in the order
    bottom (mid of c00–c10), left (c00–c01), right (c10–c11), top (c01–c11),
    then the centres of quadrants 00, 10, 01, 11.
    """
    h = 0.5 * size
    q = 0.25 * size
    pts[0, 0], pts[0, 1] = x0 + h, y0
    pts[1, 0], pts[1, 1] = x0, y0 + h
    pts[2, 0], pts[2, 1] = x0 + size, y0 + h
    pts[3, 0], pts[3, 1] = x0 + h, y0 + size
    pts[4, 0], pts[4, 1] = x0 + q, y0 + q
    pts[5, 0], pts[5, 1] = x0 + h + q, y0 + q
    pts[6, 0], pts[6, 1] = x0 + q, y0 + h + q
    pts[7, 0], pts[7, 1] = x0 + h + q, y0 + h + q


@njit(cache=True)
def statistical_done(n, q0, q1, q2, z, tolerance):
    """Whether n ≥ 4 samples with squared-deviation sums q give z·s/√n < tolerance in every channel."""
    if n < 4:
        return False
    qmax = max(q0, q1, q2)
    s2 = qmax / (n - 1.0)
    return z * math.sqrt(s2 / n) < tolerance


# ------------------------------------------------------- sample dimensions ---

@njit(cache=True)
def permute(i, n, key):
    """Element ``i`` (0 ≤ i < n) of a pseudo-random permutation of 0..n−1 chosen by the
    64-bit ``key``.

    A four-round balanced Feistel network on 2h-bit integers (2^2h ≥ n), each
    round ``(L, R) → (R, L xor F(key, round, R))`` with F the low h bits of
    :func:`impl.rng.uniform_prefix` (a bijection whatever F is; Luby & Rackoff
    1988), restricted to [0, n) by cycle walking (re-applied until it lands below
    n: a bijection of [0, 4^h) restricted this way is a bijection of [0, n); at
    most four steps on average), then rotated by r = key mod n.  The rotation
    makes each element land on every place with probability 1/n over keys,
    exactly, whatever the network's quality on tiny domains (where its
    permutations are far from uniform over all n! ones: pairs of elements are
    not equally likely to land on every pair of places).
    """
    if n <= 1:
        return 0
    h = 1
    while (1 << (2 * h)) < n:
        h += 1
    hmask = np.uint64((1 << h) - 1)
    sh = np.uint64(h)
    x = np.uint64(i)
    nn = np.uint64(n)
    while True:
        left = x >> sh
        right = x & hmask
        for r in range(4):
            f = uniform_prefix(key, r, right) & hmask
            left, right = right, left ^ f
        x = (left << sh) | right
        if x < nn:
            break
    return int((x + np.uint64(key) % nn) % nn)


@njit(inline="always", cache=True)
def _stratum_jitter(seed, pixel, s, spp, dim):
    """The jitter (u, v) in [0, 1)² of 2-D dimension ``dim`` of pixel sample ``s`` and
    the grid size k = round(√spp) of the stratified modes."""
    h = uniform_prefix(seed + JITTER_STREAM, pixel, s)
    return uniform_from(h, 2 * dim), uniform_from(h, 2 * dim + 1), int(math.sqrt(spp) + 0.5)


@njit(cache=True)
def dim_2d(mode, seed, pixel, s, spp, dim):
    """(u, v) in [0, 1)² of 2-D dimension ``dim`` of pixel sample ``s`` (of ``spp``).

    :data:`DIM_STRATIFIED`: stratum π(s) of the k×k grid (spp = k², π the pixel's
    and dimension's :func:`permute`), jittered uniformly in it; a sample beyond k²
    (spp not a square) is uniform.  :data:`DIM_SOBOL`: padded Owen-scrambled Sobol
    point s of pair ``dim``, scrambled per pixel.
    """
    if mode == DIM_SOBOL:
        return sample_2d(dim, s, pixel_seed(pixel, _SOBOL_ROW, seed))
    ju, jv, k = _stratum_jitter(seed, pixel, s, spp, dim)
    if s >= k * k:
        return ju, jv
    c = permute(s, k * k, uniform_prefix(seed + DIM_STREAM, pixel, 2 * dim))
    return (c % k + ju) / k, (c // k + jv) / k


@njit(cache=True)
def lens_stratified(seed, pixel, s, spp, dim):
    """(u, v) of the lens (dimension ``dim``) of pixel sample ``s`` in
    :data:`DIM_STRATIFIED` mode, spp = k².

    Pixel sample s lies in film stratum (i, j) = (s mod k, s div k) (the jittered
    and uniform patterns' order); its lens stratum is (P(j), Q(i)), P and Q
    permutations of 0..k−1 drawn per pixel (:func:`permute`), jittered uniformly
    in it.  (i, j) → (P(j), Q(i)) is a bijection, so the lens strata are covered
    once each, and so are the k×k strata of film-x × lens-x (pairs (i, P(j))) and
    of film-y × lens-y; film-x and lens-y are dependent (Q(i)), which the blur of
    a thin lens, coupling x with u and y with v, does not see.  Each point is
    uniform over the lens (P(j) and Q(i) are independent and uniform).  A sample
    beyond k² (spp not a square) is uniform.
    """
    ju, jv, k = _stratum_jitter(seed, pixel, s, spp, dim)
    if s >= k * k:
        return ju, jv
    key = uniform_prefix(seed + DIM_STREAM, pixel, 2 * dim)
    a = permute(s // k, k, key)
    b = permute(s % k, k, uniform_prefix(key, 1, 2))
    return (a + ju) / k, (b + jv) / k


@njit(cache=True)
def dim_1d(mode, seed, pixel, s, spp, dim):
    """u in [0, 1) of 1-D dimension ``dim`` of pixel sample ``s`` (of ``spp``):
    stratum π(s) of spp equal strata, jittered (:data:`DIM_STRATIFIED`), or the
    padded scrambled van der Corput point s (:data:`DIM_SOBOL`)."""
    if mode == DIM_SOBOL:
        return sample_1d(dim, s, pixel_seed(pixel, _SOBOL_ROW, seed))
    c = permute(s, spp, uniform_prefix(seed + DIM_STREAM, pixel, 2 * dim + 1))
    return (c + uniform(seed + JITTER_STREAM + 1, pixel, s, dim)) / spp


@njit(cache=True)
def camera_sobol(seed, pixel, s, d):
    """Dimension ``d`` (0, 1: film position; 2, 3: lens point) of the pixel's
    Owen-scrambled 4-D Sobol point ``s`` (:func:`impl.lowdiscrepancy.sobol_point`
    seeded per pixel).  Dimensions 0 and 1 are a (0, 2)-sequence: the first 2^m
    points are a (0, m, 2)-net of the pixel."""
    return sobol_point(s, d, pixel_seed(pixel, _CAMERA_ROW, seed))


@njit(cache=True)
def sobol_pattern(n, seed, pixel, out):
    """The pixel positions of :data:`DIM_SOBOL`: dimensions 0 and 1 of
    :func:`camera_sobol`; returns n."""
    for s in range(n):
        out[s, 0] = camera_sobol(seed, pixel, s, 0)
        out[s, 1] = camera_sobol(seed, pixel, s, 1)
    return n
