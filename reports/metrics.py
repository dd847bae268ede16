"""Image metrics comparing a test render against a reference.

Every function takes the two images positionally as ``(reference, test)``:
``(H, W, 3)`` arrays of linear sRGB radiance, float32 or float64, of the same
shape.  Options are keyword-only and all arithmetic is done in float64.
Nothing here knows about algorithms or renderers.

Conventions
-----------
* ``mse``, ``rmse``, ``mae``, ``bias``, ``relmse``: linear radiance, averaged
  over all pixels and channels.
* ``psnr``, ``ssim``: display sRGB from :func:`reports.tonemap.tonemap_srgb`
  (``exposure * x`` clipped to [0, 1], sRGB OETF), data range 1.
* ``flip``: HDR-FLIP on the linear images (negative values clamped to 0).
* ``delta_e2000``: CIEDE2000 on CIELAB (D65) of the clipped *linear* sRGB.
* ``z_test``: per-entry two-sample Z-test with a Šidák-corrected level.

The single metrics do not check for NaN/Inf (NaN propagates into the linear
metrics, the display transform maps it to 0); :func:`compare` enforces the
finiteness policy and counts non-finite values.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import colour
import flip_evaluator
import numpy as np
from scipy.stats import norm
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from core.errors import ImageError
from core.imageio import check_finite
from reports.tonemap import tonemap_srgb

__all__ = [
    "mse",
    "rmse",
    "mae",
    "bias",
    "relmse",
    "psnr",
    "ssim",
    "flip",
    "flip_map",
    "delta_e2000",
    "nonfinite_counts",
    "noise_floor",
    "z_test",
    "ZTestResult",
    "mach_band",
    "compare",
]

_SRGB = colour.RGB_COLOURSPACES["sRGB"]
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB Y weights
# FLIP clamps the reference median luminance to float32 epsilon (2**-23) and
# terminates the whole process when the maximum luminance is below it.
_FLIP_MIN_LUMINANCE = 2.0**-22


def _pair(reference, test):
    """Both images as float64 arrays after checking they share an (H, W, 3) shape."""
    ref = np.asarray(reference, dtype=np.float64)
    tst = np.asarray(test, dtype=np.float64)
    if ref.shape != tst.shape:
        raise ImageError(f"reference shape {ref.shape} and test shape {tst.shape} differ")
    if ref.ndim != 3 or ref.shape[2] != 3:
        raise ImageError(f"reference and test must have shape (H, W, 3), got {ref.shape}")
    return ref, tst


def _variance(variance, shape, name):
    """``variance`` as float64 broadcast to ``shape``; rejects negative values."""
    v = np.asarray(variance, dtype=np.float64)
    try:
        v = np.broadcast_to(v, shape)
    except ValueError:
        raise ImageError(f"{name} shape {v.shape} does not match image shape {shape}") from None
    if np.any(v < 0):
        raise ImageError(f"{name} has negative values")
    return v


def mse(reference, test):
    """Mean squared error of linear radiance.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    float
        ``mean((test - reference)**2)`` over all pixels and channels.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).
    """
    ref, tst = _pair(reference, test)
    return float(np.mean((tst - ref) ** 2))


def rmse(reference, test):
    """Root mean squared error of linear radiance, ``sqrt(mse(reference, test))``.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    float
        Root mean squared error, in radiance units.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).
    """
    return float(np.sqrt(mse(reference, test)))


def mae(reference, test):
    """Mean absolute error of linear radiance.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    float
        ``mean(abs(test - reference))`` over all pixels and channels.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).
    """
    ref, tst = _pair(reference, test)
    return float(np.mean(np.abs(tst - ref)))


def bias(reference, test):
    """Mean signed difference of linear radiance, ``mean(test - reference)``.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    float
        Positive when the test image is brighter on average.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).
    """
    ref, tst = _pair(reference, test)
    return float(np.mean(tst - ref))


def relmse(reference, test, *, eps=1e-2):
    """Relative mean squared error of linear radiance.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.
    eps : float, optional
        Added to the squared reference in the denominator (default 0.01).

    Returns
    -------
    float
        ``mean((test - reference)**2 / (reference**2 + eps))`` over all
        pixels and channels.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3), or ``eps <= 0``.

    Notes
    -----
    The error is relative per entry, so bright and dark regions weigh alike;
    ``eps`` (default 1e-2, in squared radiance units) keeps nearly black
    pixels from dominating.  Quote ``eps`` with the value.

    References
    ----------
    .. [1] F. Rousselle, C. Knaus, M. Zwicker, "Adaptive Sampling and
       Reconstruction using Greedy Error Minimization", ACM TOG 30(6), 2011.
       :doi:`10.1145/2070781.2024193`
    """
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps}")
    ref, tst = _pair(reference, test)
    return float(np.mean((tst - ref) ** 2 / (ref**2 + eps)))


def mach_band(reference, test, *, mask, floor=1e-3):
    """Mach-band strength: excess curvature of log-luminance of ``test`` over ``reference``.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.  ``reference`` is the smooth image the
        test approximates (e.g. per-pixel shading of the exact surface).
    mask : ndarray of bool, shape (H, W)
        Pixels to average over (e.g. pixels on polygon edges, away from
        silhouettes).  Pixels in the outermost row and column are never used.
    floor : float, optional
        Luminance floor, as a fraction of the reference's maximum luminance,
        added before the logarithm (default 1e-3).

    Returns
    -------
    float
        ``mean over mask of max(|Δ²_x l_t − Δ²_x l_r|, |Δ²_y l_t − Δ²_y l_r|)``,
        with ``l = ln(Y + floor · max Y_ref)`` the log of Rec. 709 luminance and
        ``Δ²_x l = l[x+1] − 2 l[x] + l[x−1]`` the second difference along x
        (likewise y).  0 when the test bends exactly as the reference;
        ``nan`` if the mask selects no usable pixel.

    Raises
    ------
    ImageError
        If the images' shapes differ or are not (H, W, 3), or ``mask`` is not
        an (H, W) array.
    ValueError
        If ``floor <= 0``.

    Notes
    -----
    Thesis 1.5.3: the eye exaggerates a jump of the luminance *gradient*
    (lateral inhibition), so Gouraud shading, continuous in value but not in
    slope across polygon edges, shows bright and dark bands along them.  A
    jump of slope is a spike of the second difference.  The logarithm makes
    the measure a contrast (Weber–Fechner: equal ratios look equal), which is
    the perceptual weighting used here; it is not a full model of the
    contrast-sensitivity function (no spatial-frequency weighting).
    Subtracting the reference's curvature leaves what the shading technique
    adds: curvature of the true surface's shading is not a Mach band.

    References
    ----------
    .. [1] F. Ratliff, *Mach Bands: Quantitative Studies on Neural Networks
       in the Retina*, Holden-Day, 1965.
    """
    if not floor > 0:
        raise ValueError(f"floor must be positive, got {floor}")
    ref, tst = _pair(reference, test)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != ref.shape[:2]:
        raise ImageError(f"mask shape {mask.shape} does not match image shape {ref.shape[:2]}")
    y_ref = ref @ _LUMINANCE
    y_tst = tst @ _LUMINANCE
    off = floor * max(float(y_ref.max()), 1e-300)
    l_ref = np.log(np.maximum(y_ref, 0.0) + off)
    l_tst = np.log(np.maximum(y_tst, 0.0) + off)

    def second(l):
        dxx = np.zeros_like(l)
        dyy = np.zeros_like(l)
        dxx[:, 1:-1] = l[:, 2:] - 2.0 * l[:, 1:-1] + l[:, :-2]
        dyy[1:-1, :] = l[2:, :] - 2.0 * l[1:-1, :] + l[:-2, :]
        return dxx, dyy

    rx, ry = second(l_ref)
    tx, ty = second(l_tst)
    inner = mask.copy()
    inner[0, :] = inner[-1, :] = False
    inner[:, 0] = inner[:, -1] = False
    if not inner.any():
        return float("nan")
    excess = np.maximum(np.abs(tx - rx), np.abs(ty - ry))
    return float(excess[inner].mean())


def psnr(reference, test, *, exposure=1.0):
    """Peak signal-to-noise ratio, in dB, of the tone-mapped images.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.
    exposure : float, optional
        Multiplier applied before tone mapping.

    Returns
    -------
    float
        PSNR in dB; ``inf`` when the tone-mapped images are identical.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).

    Notes
    -----
    Computed by :func:`skimage.metrics.peak_signal_noise_ratio` with
    ``data_range=1`` on ``tonemap_srgb(image, exposure=exposure)``
    (``exposure * x`` clipped to [0, 1], sRGB OETF), i.e. on display values.
    """
    ref, tst = _pair(reference, test)
    a, b = tonemap_srgb(ref, exposure=exposure), tonemap_srgb(tst, exposure=exposure)
    if np.array_equal(a, b):
        return float("inf")
    return float(peak_signal_noise_ratio(a, b, data_range=1.0))


def ssim(reference, test, *, exposure=1.0):
    """Mean structural similarity (SSIM) of the tone-mapped images.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape, at least 3 x 3 pixels.
    exposure : float, optional
        Multiplier applied before tone mapping.

    Returns
    -------
    float
        Mean SSIM over pixels and channels; 1 for identical images.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3), or the image is smaller
        than 3 x 3 pixels.

    Notes
    -----
    Computed by :func:`skimage.metrics.structural_similarity` with
    ``channel_axis=-1``, ``data_range=1`` and scikit-image's default uniform
    window on ``tonemap_srgb(image, exposure=exposure)``.  The window is
    7 x 7, or for images smaller than 7 pixels in either direction the
    largest odd size ``<= min(H, W)``; images below 3 x 3 are refused.

    References
    ----------
    .. [1] Z. Wang, A. C. Bovik, H. R. Sheikh, E. P. Simoncelli, "Image
       quality assessment: from error visibility to structural similarity",
       IEEE TIP 13(4), 2004. :doi:`10.1109/TIP.2003.819861`
    """
    ref, tst = _pair(reference, test)
    size = min(ref.shape[:2])
    if size < 3:
        raise ValueError(f"ssim needs images of at least 3 x 3 pixels, got shape {ref.shape}")
    win_size = min(7, size if size % 2 else size - 1)
    a, b = tonemap_srgb(ref, exposure=exposure), tonemap_srgb(tst, exposure=exposure)
    return float(structural_similarity(a, b, channel_axis=-1, data_range=1.0, win_size=win_size))


def _flip(reference, test):
    """HDR-FLIP error map (H, W) float64 and its mean, via flip_evaluator."""
    ref, tst = (np.ascontiguousarray(np.maximum(a, 0.0), dtype=np.float32) for a in _pair(reference, test))
    if np.array_equal(ref, tst):
        return np.zeros(ref.shape[:2]), 0.0
    y_max = float(np.max(ref @ _LUMINANCE.astype(np.float32)))
    if not y_max >= _FLIP_MIN_LUMINANCE:
        raise ValueError(
            f"HDR-FLIP needs a reference with luminance above {_FLIP_MIN_LUMINANCE:.3g} "
            f"somewhere (maximum is {y_max:.3g})"
        )
    error_map, mean, _ = flip_evaluator.evaluate(ref, tst, "HDR", applyMagma=False)
    return np.asarray(error_map, dtype=np.float64)[..., 0], float(mean)


def flip(reference, test):
    """Mean HDR-FLIP error.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    float
        Mean HDR-FLIP error in [0, 1]; 0 for identical images.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3), or the reference is black
        (maximum luminance below 2**-22, where HDR-FLIP's exposure range is
        undefined and flip_evaluator would abort the process).

    Notes
    -----
    ``flip_evaluator.evaluate(reference, test, "HDR", applyMagma=False)``
    with the default viewing conditions (67 pixels per degree) and the
    exposure range FLIP derives from the reference.  HDR-FLIP needs
    nonnegative input, so negative values are clamped to 0 first.  Images
    that are equal after clamping give 0 without calling FLIP.

    References
    ----------
    .. [1] P. Andersson, J. Nilsson, T. Akenine-Möller, M. Oskarsson,
       K. Åström, M. D. Fairchild, "FLIP: A Difference Evaluator for
       Alternating Images", Proc. ACM CGIT 3(2), 2020. :doi:`10.1145/3406183`
    .. [2] P. Andersson, J. Nilsson, P. Shirley, T. Akenine-Möller,
       "Visualizing Errors in Rendered High Dynamic Range Images",
       Eurographics 2021 Short Papers. https://github.com/NVlabs/flip
    """
    return _flip(reference, test)[1]


def flip_map(reference, test):
    """Per-pixel HDR-FLIP error map.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.

    Returns
    -------
    ndarray, shape (H, W), float64
        HDR-FLIP error per pixel, in [0, 1].

    Raises
    ------
    ValueError
        As :func:`flip`.

    Notes
    -----
    Same convention as :func:`flip` (negative values clamped to 0).
    """
    return _flip(reference, test)[0]


def _lab(image, exposure):
    rgb = np.clip(image * float(exposure), 0.0, 1.0)
    xyz = colour.RGB_to_XYZ(rgb, _SRGB, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, _SRGB.whitepoint)


def delta_e2000(reference, test, *, exposure=1.0):
    """Mean CIEDE2000 colour difference.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.
    exposure : float, optional
        Multiplier applied before clipping.

    Returns
    -------
    float
        Mean ΔE00 over pixels; 0 for identical images.

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3).

    Notes
    -----
    ``exposure * x`` is clipped to [0, 1] and taken as *linear* sRGB (no
    transfer function is applied), converted to CIE XYZ and to CIELAB with
    the D65 white of sRGB (``colour.RGB_to_XYZ``, ``colour.XYZ_to_Lab``),
    and compared with ``colour.delta_E(..., method="CIE 2000")``.  A
    radiance of 1 maps to the white point (L* = 100).

    References
    ----------
    .. [1] G. Sharma, W. Wu, E. N. Dalal, "The CIEDE2000 color-difference
       formula: Implementation notes, supplementary test data, and
       mathematical observations", Color Res. Appl. 30(1), 2005.
       :doi:`10.1002/col.20070`
    """
    ref, tst = _pair(reference, test)
    de = colour.delta_E(_lab(ref, exposure), _lab(tst, exposure), method="CIE 2000")
    return float(np.mean(de))


def nonfinite_counts(image):
    """Count NaN and infinite values in ``image``.

    Parameters
    ----------
    image : array_like
        Any shape.

    Returns
    -------
    dict
        ``{"nan": int, "inf": int}``, counted per value (not per pixel).
    """
    a = np.asarray(image)
    return {"nan": int(np.count_nonzero(np.isnan(a))), "inf": int(np.count_nonzero(np.isinf(a)))}


def noise_floor(reference_variance):
    """Expected MSE contributed by the reference's own noise.

    Parameters
    ----------
    reference_variance : array_like, shape (H, W, 3)
        Per-pixel variance of the reference *mean* (sample variance divided
        by the sample count).

    Returns
    -------
    float
        ``mean(reference_variance)``.

    Raises
    ------
    ValueError
        If the variance has negative values.

    Notes
    -----
    For a reference that is an unbiased estimate of the truth with noise
    independent of the test image, ``E[MSE(test, ref)] = MSE(test, truth) +
    noise_floor``: MSE values near this floor cannot be resolved with this
    reference.
    """
    v = np.asarray(reference_variance, dtype=np.float64)
    return float(np.mean(_variance(v, v.shape, "reference_variance")))


@dataclass(frozen=True, eq=False, repr=False)
class ZTestResult:
    """Outcome of :func:`z_test`.

    Attributes
    ----------
    passed : bool
        ``fraction >= min_fraction``.
    fraction : float
        Fraction of entries (pixel-channels) with p-value above ``significance``.
    significance : float
        Šidák-corrected per-entry level ``1 - (1 - alpha)**(1 / n)``.
    n : int
        Number of tested entries, ``H * W * 3``.
    alpha : float
        Family-wise significance level.
    min_fraction : float
        Fraction of consistent entries needed to pass.
    p_values : ndarray, shape (H, W, 3)
        Two-sided p-value per entry (NaN where the data were non-finite).
    """

    passed: bool
    fraction: float
    significance: float
    n: int
    alpha: float
    min_fraction: float
    p_values: np.ndarray

    def to_dict(self):
        """All fields except ``p_values``, as plain Python values."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "p_values"}

    def __repr__(self):
        return (
            f"ZTestResult(passed={self.passed}, fraction={self.fraction:.6f}, "
            f"significance={self.significance:.3g}, n={self.n}, alpha={self.alpha}, "
            f"min_fraction={self.min_fraction})"
        )


def z_test(
    reference,
    test,
    *,
    reference_variance,
    test_variance=None,
    alpha=0.01,
    min_fraction=0.9975,
    rtol=1e-3,
    atol=1e-6,
):
    """Per-entry Z-test that two noisy images have the same expectation.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape.
    reference_variance : array_like, broadcastable to (H, W, 3)
        Variance of the reference *mean* (sample variance / sample count).
    test_variance : array_like, optional
        Variance of the test mean; ``None`` treats the test as exact.
    alpha : float, optional
        Family-wise significance level, in (0, 1).
    min_fraction : float, optional
        Fraction of entries that must be consistent for the test to pass.
    rtol, atol : float, optional
        Variance floor ``(rtol * |reference|)**2 + atol**2``.

    Returns
    -------
    ZTestResult

    Raises
    ------
    ValueError
        If the shapes differ or are not (H, W, 3), a variance does not
        broadcast to the image shape or is negative, or ``alpha`` or
        ``min_fraction`` is out of range.

    Notes
    -----
    For every pixel and channel ("entry"),
    ``z = |test - reference| / sqrt(var_ref + var_test)`` and the two-sided
    p-value is ``2 * (1 - Phi(z))``.  An entry is consistent when its
    p-value exceeds the Šidák-corrected level
    ``1 - (1 - alpha)**(1 / n)`` with ``n = H * W * 3`` entries (Mitsuba's
    test uses the same per-entry comparison but ``n = H * W``); the test
    passes when at least ``min_fraction`` of the entries are consistent.
    Under the null hypothesis with independent Gaussian errors, the chance
    that any entry is inconsistent is exactly ``alpha``.

    The combined variance is floored at ``(rtol * |reference|)**2 + atol**2``:
    zero-variance pixels (background, directly seen emitters) would
    otherwise reject differences as small as float32 or EXR half-float
    rounding (relative 5e-4).  The floor makes the test tolerate relative
    differences of a few ``rtol`` there, and only there.  Non-finite values
    give a NaN p-value and count as inconsistent.

    References
    ----------
    .. [1] Mitsuba 3, ``src/render/tests/test_renders.py`` (``z_test`` and
       the Šidák correction in ``test_render``).
       https://github.com/mitsuba-renderer/mitsuba3
    .. [2] Z. Šidák, "Rectangular Confidence Regions for the Means of
       Multivariate Normal Distributions", JASA 62(318), 1967.
       :doi:`10.1080/01621459.1967.10482935`
    """
    ref, tst = _pair(reference, test)
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    var = _variance(reference_variance, ref.shape, "reference_variance")
    if test_variance is not None:
        var = var + _variance(test_variance, ref.shape, "test_variance")
    var = np.maximum(var, (rtol * np.abs(ref)) ** 2 + atol**2)
    z = np.abs(tst - ref) / np.sqrt(var)
    p = np.where(np.isfinite(var), 2.0 * norm.sf(z), np.nan)
    n = ref.size
    significance = float(-np.expm1(np.log1p(-alpha) / n))
    fraction = float(np.count_nonzero(p > significance) / n)
    return ZTestResult(
        passed=bool(fraction >= min_fraction),
        fraction=fraction,
        significance=significance,
        n=int(n),
        alpha=float(alpha),
        min_fraction=float(min_fraction),
        p_values=p,
    )


def compare(
    reference,
    test,
    *,
    reference_variance=None,
    test_variance=None,
    exposure=1.0,
    allow_nonfinite=False,
):
    """Every metric of this module in one JSON-ready dictionary.

    Parameters
    ----------
    reference, test : ndarray, shape (H, W, 3)
        Linear radiance, same shape; the reference must be finite.
    reference_variance, test_variance : array_like, optional
        Variances of the means, for :func:`noise_floor` and :func:`z_test`.
    exposure : float, optional
        Exposure for the display metrics (psnr, ssim, delta_e2000).
    allow_nonfinite : bool, optional
        Accept NaN/Inf in the test image (counted, then replaced by 0).

    Returns
    -------
    dict
        Keys ``mse, rmse, relmse, mae, bias, psnr, ssim, flip, delta_e2000``
        (floats; ``psnr`` may be ``inf``), ``nan_count, inf_count`` (ints,
        of the test image), ``noise_floor`` (float or ``None`` without
        ``reference_variance``), ``ztest`` (``ZTestResult.to_dict()`` or
        ``None``) and ``conventions`` (dict of strings and numbers).

    Raises
    ------
    core.imageio.ImageError
        If the reference holds NaN/Inf, or the test image does and
        ``allow_nonfinite`` is False; the one-line message gives the counts.
    ValueError
        As the single metrics (shape mismatch, image too small for SSIM,
        black reference for FLIP, bad variances).

    Notes
    -----
    With ``allow_nonfinite=True`` non-finite test values are replaced by 0
    before every metric, so they count as black pixels (and almost always
    as inconsistent entries in the Z-test).
    """
    ref, tst = _pair(reference, test)
    check_finite(ref, name="reference")
    counts = nonfinite_counts(tst)
    if not allow_nonfinite:
        check_finite(tst, name="test image")
    tst = np.where(np.isfinite(tst), tst, 0.0)
    eps = 1e-2
    ztest = None
    if reference_variance is not None:
        ztest = z_test(ref, tst, reference_variance=reference_variance, test_variance=test_variance).to_dict()
    return {
        "mse": mse(ref, tst),
        "rmse": rmse(ref, tst),
        "relmse": relmse(ref, tst, eps=eps),
        "mae": mae(ref, tst),
        "bias": bias(ref, tst),
        "psnr": psnr(ref, tst, exposure=exposure),
        "ssim": ssim(ref, tst, exposure=exposure),
        "flip": flip(ref, tst),
        "delta_e2000": delta_e2000(ref, tst, exposure=exposure),
        "nan_count": counts["nan"],
        "inf_count": counts["inf"],
        "noise_floor": None if reference_variance is None else noise_floor(reference_variance),
        "ztest": ztest,
        "conventions": {
            "relmse": f"mean((test-ref)^2 / (ref^2 + eps)), eps={eps}",
            "exposure": float(exposure),
            "tonemap": "exposure*x clipped to [0, 1], sRGB OETF (psnr, ssim; data_range=1)",
            "flip": "HDR-FLIP mean, negatives clamped to 0",
            "delta_e2000": "CIEDE2000, D65, clipped linear sRGB (exposure*x)",
            "ztest": "per-entry Z-test, Sidak level over N=H*W*3 entries, alpha=0.01, min_fraction=0.9975",
        },
    }
