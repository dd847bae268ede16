"""Pixel reconstruction filters (thesis 2.5.4: "the value of each pixel is the sum of the
nearby sample values times their filter weights, normalised").

Two filters, matching Mitsuba 3's ``rfilter`` plugins so that an own render
estimates the very pixel value of its reference:

* ``box`` — Mitsuba's ``box``: radius ½, weight 1 inside the pixel; the pixel
  is the (weighted) mean of its own samples;
* ``gaussian`` — Mitsuba's ``gaussian`` (the ``hdrfilm`` default):
  ``stddev`` σ (default 0.5 px), cut off at radius 4σ and shifted to reach 0
  there: ``g(x) = max(0, e^{−x²/(2σ²)} − e^{−(4σ)²/(2σ²)})``, separable,
  ``w(dx, dy) = g(dx) g(dy)``.  (Mitsuba's CPU variants evaluate the same
  function through a degree-9 Remez fit of exp(−x/2) that also reaches 0 at
  the radius; the two differ by < 1e-6.)

Reconstruction is a normalised weighted sum, as Mitsuba's film develops it::

    I(x, y) = Σ_s w(p_s − c_xy) a_s L_s / Σ_s w(p_s − c_xy) a_s

over the samples s within the filter radius of the pixel centre c_xy (from
neighbouring pixels too), ``a_s`` a per-sample weight (1, or a leaf's area
share in adaptive supersampling).  Splatting each sample into the pixels it
reaches and gathering each pixel's samples from its neighbours compute the
same sums; :func:`reconstruct` gathers, so that parallel pixels never write
to the same place.

Variance of the pixel mean (for the Z-test): the delta-method variance of the
ratio estimator, ``Σ v_s² (L_s − I)² / (Σ v_s)²`` with v_s = w a_s, times
n_eff/(n_eff − 1) where n_eff = (Σ v)² / Σ v² (for equal weights this is the
usual s²/n).  For stratified or regular patterns it over-estimates the
variance, which keeps Z-tests conservative.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from core.scene import Film

__all__ = ["FILTER_BOX", "FILTER_GAUSSIAN", "film_filter", "filter_radius", "filter_weight",
           "gaussian_1d", "reconstruct", "S_X", "S_Y", "S_W", "S_R", "S_G", "S_B"]

FILTER_BOX, FILTER_GAUSSIAN = 0, 1
#: Columns of a sample record: film position (pixels), weight a_s, radiance.
S_X, S_Y, S_W, S_R, S_G, S_B = range(6)


def film_filter(film: Film, override: str = "film") -> tuple[int, float]:
    """``(code, stddev)`` of the film's ``rfilter``, or of ``override`` (``box``/``gaussian``).

    Raises ``ValueError`` for an unknown filter name or a non-positive stddev.
    """
    name = film.rfilter if override == "film" else override
    if name == "box":
        return FILTER_BOX, 0.0
    if name == "gaussian":
        stddev = float(film.rfilter_params.get("stddev", 0.5))
        if not stddev > 0.0:
            raise ValueError(f"filters: gaussian rfilter stddev must be > 0, got {stddev}")
        return FILTER_GAUSSIAN, stddev
    raise ValueError(f"filters: unknown reconstruction filter '{name}' (box, gaussian)")


@njit(inline="always", cache=True)
def filter_radius(kind, stddev):
    return 0.5 if kind == FILTER_BOX else 4.0 * stddev


@njit(inline="always", cache=True)
def gaussian_1d(x, stddev):
    """Mitsuba's shifted Gaussian: max(0, exp(−x²/2σ²) − exp(−(4σ)²/2σ²))."""
    a = -0.5 / (stddev * stddev)
    r = 4.0 * stddev
    return max(0.0, math.exp(a * x * x) - math.exp(a * r * r))


@njit(inline="always", cache=True)
def filter_weight(kind, stddev, dx, dy):
    """Weight of a sample at offset (dx, dy) pixels from a pixel centre."""
    if kind == FILTER_BOX:
        return 1.0 if (-0.5 <= dx < 0.5 and -0.5 <= dy < 0.5) else 0.0
    return gaussian_1d(dx, stddev) * gaussian_1d(dy, stddev)


@njit(inline="always", cache=True)
def _weight(kind, stddev, dx, dy):
    """Filter weight in the gather: a box pixel takes all of its own samples (reach 0), so
    samples on its closing edges (adaptive corners) count too."""
    if kind == FILTER_BOX:
        return 1.0
    return filter_weight(kind, stddev, dx, dy)


@njit(cache=True)
def _gather(samples, counts, W, H, x, y, kind, stddev):
    """Normalised weighted mean and its variance (per channel) at pixel (x, y)."""
    rad = filter_radius(kind, stddev)
    reach = int(math.ceil(rad - 0.5)) if kind == FILTER_GAUSSIAN else 0
    cx, cy = x + 0.5, y + 0.5
    sw = sw2 = 0.0
    m0 = m1 = m2 = 0.0
    for yy in range(max(0, y - reach), min(H, y + reach + 1)):
        for xx in range(max(0, x - reach), min(W, x + reach + 1)):
            p = yy * W + xx
            for s in range(counts[p]):
                v = samples[p, s, S_W] * _weight(kind, stddev, samples[p, s, S_X] - cx,
                                                 samples[p, s, S_Y] - cy)
                if v == 0.0:
                    continue
                sw += v
                sw2 += v * v
                m0 += v * samples[p, s, S_R]
                m1 += v * samples[p, s, S_G]
                m2 += v * samples[p, s, S_B]
    if sw == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    m0 /= sw
    m1 /= sw
    m2 /= sw
    # Delta-method variance of the ratio estimator, with the small-sample correction.
    q0 = q1 = q2 = 0.0
    for yy in range(max(0, y - reach), min(H, y + reach + 1)):
        for xx in range(max(0, x - reach), min(W, x + reach + 1)):
            p = yy * W + xx
            for s in range(counts[p]):
                v = samples[p, s, S_W] * _weight(kind, stddev, samples[p, s, S_X] - cx,
                                                 samples[p, s, S_Y] - cy)
                if v == 0.0:
                    continue
                v2 = v * v
                q0 += v2 * (samples[p, s, S_R] - m0) ** 2
                q1 += v2 * (samples[p, s, S_G] - m1) ** 2
                q2 += v2 * (samples[p, s, S_B] - m2) ** 2
    n_eff = sw * sw / sw2
    corr = n_eff / (n_eff - 1.0) if n_eff > 1.0 + 1e-9 else 0.0
    k = corr / (sw * sw)
    return m0, m1, m2, q0 * k, q1 * k, q2 * k


@njit(parallel=True, cache=True)
def _reconstruct_kernel(samples, counts, W, H, kind, stddev, mean, var):
    for c in prange(W * H):
        pixel = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        x, y = pixel % W, pixel // W
        m0, m1, m2, v0, v1, v2 = _gather(samples, counts, W, H, x, y, kind, stddev)
        mean[y, x, 0] = m0
        mean[y, x, 1] = m1
        mean[y, x, 2] = m2
        var[y, x, 0] = v0
        var[y, x, 1] = v1
        var[y, x, 2] = v2


def reconstruct(samples: np.ndarray, counts: np.ndarray, width: int, height: int, kind: int,
                stddev: float) -> tuple[np.ndarray, np.ndarray]:
    """Film image and per-pixel variance of the mean from per-pixel sample records.

    Parameters
    ----------
    samples
        (W·H, cap, 6) float64: per pixel (row-major), its sample records
        ``(x, y, a, r, g, b)`` with (x, y) in film pixels.
    counts
        (W·H,) int: how many records of each pixel are valid.
    kind, stddev
        :data:`FILTER_BOX` or :data:`FILTER_GAUSSIAN` and its σ (pixels).
    """
    if samples.ndim != 3 or samples.shape[0] != width * height or samples.shape[2] != 6:
        raise ValueError(f"filters.reconstruct: samples must be (W*H, cap, 6) = ({width * height}, cap, 6), "
                         f"got {samples.shape}")
    mean = np.zeros((height, width, 3))
    var = np.zeros((height, width, 3))
    _reconstruct_kernel(samples, counts, width, height, kind, float(stddev), mean, var)
    return mean, var
