"""The sample dimensions beyond the pixel position (impl/samplers.py: ``permute``,
``dim_1d``, ``dim_2d``; thesis 2.5.8): shuffled strata and padded Sobol.

* each stratified dimension covers its strata once per pixel, and the Sobol
  pairs are (0, m, 2)-nets;
* chi-square: every dimension's sample s is uniform over [0, 1)² (or [0, 1))
  across pixels, so the estimates they feed are unbiased; two dimensions of
  one sample are independent (their joint strata are uniform), with a
  negative control (a dimension paired with itself is rejected);
* the distributed tracer's pixel means with ``dimensions=stratified`` and
  ``sampler=sobol`` pass a Z-test against its independent-dimension render at
  1024 spp on the soft shadow and depth-of-field scenes (against Mitsuba in
  tests/test_distributed.py).

Seeds are fixed; α = 1e-3.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import njit
from scipy import stats

from impl import samplers as smp
from impl.rng import uniform_prefix

ALPHA = 1e-3
SEED = 7
ROOT = Path(__file__).resolve().parents[1]
LENS, LIGHT = 1, 1 << 16          # the tracer's dimension numbers of a lens and a light sample


@njit(cache=True)
def _perms(n, out):
    for a in range(out.shape[0]):
        for i in range(n):
            out[a, i] = smp.permute(i, n, uniform_prefix(SEED, a, 3))


@njit(cache=True)
def _draw_2d(mode, spp, dim, pixels, out):
    for p in range(pixels):
        for s in range(spp):
            out[p, s, 0], out[p, s, 1] = smp.dim_2d(mode, SEED, p, s, spp, dim)


@njit(cache=True)
def _draw_1d(mode, spp, dim, pixels, out):
    for p in range(pixels):
        for s in range(spp):
            out[p, s] = smp.dim_1d(mode, SEED, p, s, spp, dim)


def draw_2d(mode, spp, dim, pixels):
    out = np.zeros((pixels, spp, 2))
    _draw_2d(mode, spp, dim, pixels, out)
    return out


def draw_1d(mode, spp, dim, pixels):
    out = np.zeros((pixels, spp))
    _draw_1d(mode, spp, dim, pixels, out)
    return out


@pytest.mark.parametrize("n", (2, 3, 4, 9, 16, 36, 256))
def test_permute_is_a_permutation_placing_each_element_uniformly(n):
    out = np.zeros((20000, n), dtype=np.int64)
    _perms(n, out)
    assert (np.sort(out, axis=1) == np.arange(n)).all()
    for i in sorted({0, 1, n // 2, n - 1}):
        p = stats.chisquare(np.bincount(out[:, i], minlength=n)).pvalue
        assert p > ALPHA, f"n={n}: element {i} lands unevenly (p={p:.2e}, seed {SEED})"


@pytest.mark.parametrize("k", (2, 4, 8))
def test_stratified_dimensions_cover_their_strata_once_per_pixel(k):
    spp = k * k
    for dim in (LENS, LIGHT, 3):
        pts = draw_2d(smp.DIM_STRATIFIED, spp, dim, 50)
        assert pts.min() >= 0.0 and pts.max() < 1.0
        cells = (pts[..., 0] * k).astype(int) + k * (pts[..., 1] * k).astype(int)
        assert (np.sort(cells, axis=1) == np.arange(spp)).all()
        u = draw_1d(smp.DIM_STRATIFIED, spp, dim, 50)
        assert (np.sort((u * spp).astype(int), axis=1) == np.arange(spp)).all()
    # The strata are shuffled: sample s is not in stratum s in most pixels.
    pts = draw_2d(smp.DIM_STRATIFIED, spp, LENS, 50)
    cells = (pts[..., 0] * k).astype(int) + k * (pts[..., 1] * k).astype(int)
    assert (cells == np.arange(spp)).mean() < 0.5


@njit(cache=True)
def _draw_camera(n, pixels, out):
    for p in range(pixels):
        for s in range(n):
            for d in range(4):
                out[p, s, d] = smp.camera_sobol(SEED, p, s, d)


def draw_camera(n, pixels):
    out = np.zeros((pixels, n, 4))
    _draw_camera(n, pixels, out)
    return out


def _is_net(pts, m):
    """Whether every pixel's 2^m points (pixels, 2^m, 2) put one point in each
    elementary interval 2^j × 2^(m-j)."""
    n = 2 ** m
    for j in range(m + 1):
        cells = (pts[..., 0] * 2 ** j).astype(int) * 2 ** (m - j) + (pts[..., 1] * 2 ** (m - j)).astype(int)
        if not (np.sort(cells, axis=1) == np.arange(n)).all():
            return False
    return True


@pytest.mark.parametrize("m", (2, 4, 6))
def test_sobol_dimensions_are_nets_per_pixel(m):
    n = 2 ** m
    cam = draw_camera(n, 20)
    assert _is_net(cam[..., :2], m)                     # the film positions
    pat = np.zeros((n, 2))
    smp.sobol_pattern(n, SEED, 3, pat)
    assert np.array_equal(pat, cam[3, :, :2])
    for dim in (LENS, LIGHT):
        pts = draw_2d(smp.DIM_SOBOL, n, dim, 20)
        assert _is_net(pts, m), f"pair {dim}"
        u = draw_1d(smp.DIM_SOBOL, n, dim, 20)
        assert (np.sort((u * n).astype(int), axis=1) == np.arange(n)).all()


@pytest.mark.parametrize("mode", (smp.DIM_STRATIFIED, smp.DIM_SOBOL), ids=("stratified", "sobol"))
def test_every_sample_of_a_dimension_is_uniform(mode):
    """Chi-square over 8×8 bins (2-D) and 32 bins (1-D) of sample s across 20 000
    pixels: each sample is uniform over its dimension, whatever s."""
    spp = 16
    for dim in (LENS, LIGHT + 5):
        pts = draw_2d(mode, spp, dim, 20000)
        u = draw_1d(mode, spp, dim + 1, 20000)
        for s in (0, 5, 15):
            b = (pts[:, s, 0] * 8).astype(int) * 8 + (pts[:, s, 1] * 8).astype(int)
            p2 = stats.chisquare(np.bincount(b, minlength=64)).pvalue
            p1 = stats.chisquare(np.bincount((u[:, s] * 32).astype(int), minlength=32)).pvalue
            assert p2 > ALPHA and p1 > ALPHA, f"dim {dim}, sample {s}: p = {p2:.2e} / {p1:.2e}"


@pytest.mark.parametrize("mode", (smp.DIM_STRATIFIED, smp.DIM_SOBOL), ids=("stratified", "sobol"))
def test_two_dimensions_of_a_sample_are_independent(mode):
    """The 4×4 strata of a BSDF direction and of a light sample of the same pixel
    sample, across 20 000 pixels: their joint 16×16 table is uniform.  Negative
    control: a dimension paired with itself (the strata of an unshuffled pairing
    coincide) is rejected."""
    spp, k = 16, 4
    bsdf = draw_2d(mode, spp, 3, 20000)               # a BSDF direction
    light = draw_2d(mode, spp, LIGHT, 20000)

    def cell(p):
        return (p[..., 0] * k).astype(int) + k * (p[..., 1] * k).astype(int)

    for s in (0, 7):
        joint = cell(bsdf[:, s]) * spp + cell(light[:, s])
        p = stats.chisquare(np.bincount(joint, minlength=spp * spp)).pvalue
        assert p > ALPHA, f"sample {s}: BSDF and light strata are dependent (p={p:.2e})"
        same = cell(bsdf[:, s]) * spp + cell(bsdf[:, s])
        assert stats.chisquare(np.bincount(same, minlength=spp * spp)).pvalue < ALPHA
    # Within a pixel the two dimensions are uncorrelated too (mean correlation over pixels).
    r = [np.corrcoef(bsdf[i, :, 0], light[i, :, 0])[0, 1] for i in range(2000)]
    assert abs(np.mean(r)) < 4 * np.std(r) / np.sqrt(len(r))


def test_camera_sobol_lens_is_uniform_and_stratified_with_the_film_position():
    """The lens dimensions (2, 3) of the 4-D camera point: sample s uniform over the
    lens square across pixels (chi-square), each lens coordinate stratified in 1-D
    (one point per 1/n interval: Sobol's one-dimensional projections are (0, 1)-
    sequences), and the film-x × lens-x projection stratified in 4×4 cells at 16 points
    (as no independent pairing would be in every pixel)."""
    cam = draw_camera(16, 20000)
    for s in (0, 5, 15):
        b = (cam[:, s, 2] * 8).astype(int) * 8 + (cam[:, s, 3] * 8).astype(int)
        p = stats.chisquare(np.bincount(b, minlength=64)).pvalue
        assert p > ALPHA, f"sample {s}: lens point not uniform (p={p:.2e})"
    for d in range(4):
        assert (np.sort((cam[:200, :, d] * 16).astype(int), axis=1) == np.arange(16)).all()
    cells = (cam[:200, :, 0] * 4).astype(int) * 4 + (cam[:200, :, 2] * 4).astype(int)
    assert (np.sort(cells, axis=1) == np.arange(16)).all()


@njit(cache=True)
def _draw_lens(spp, pixels, out):
    for p in range(pixels):
        for s in range(spp):
            out[p, s, 0], out[p, s, 1] = smp.lens_stratified(SEED, p, s, spp, LENS)


@pytest.mark.parametrize("k", (2, 4, 8))
def test_stratified_lens_is_uniform_and_stratified_with_the_film_strata(k):
    """The lens of ``dimensions=stratified``: its k×k strata once each per pixel, and so
    the film-x × lens-x and film-y × lens-y strata (film stratum (s mod k, s div k));
    sample s uniform over the lens across 20 000 pixels (chi-square)."""
    spp = k * k
    lens = np.zeros((20000, spp, 2))
    _draw_lens(spp, 20000, lens)
    a = (lens[..., 0] * k).astype(int)
    b = (lens[..., 1] * k).astype(int)
    s = np.arange(spp)
    i, j = s % k, s // k
    assert (np.sort(a + k * b, axis=1) == s).all()
    assert (np.sort(i + k * a, axis=1) == s).all()
    assert (np.sort(j + k * b, axis=1) == s).all()
    for t in (0, spp // 2, spp - 1):
        cell = (lens[:, t, 0] * 8).astype(int) * 8 + (lens[:, t, 1] * 8).astype(int)
        p = stats.chisquare(np.bincount(cell, minlength=64)).pvalue
        assert p > ALPHA, f"k={k}, sample {t}: lens point not uniform (p={p:.2e})"


# --------------------------------------------------------- the tracer's means ---

SCENES = ("distributed/penumbra.xml", "distributed/dof.xml")


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_stratified_and_sobol_pixel_means_are_unbiased(scene):
    """Per-pixel Z-test of 256-spp renders (jittered pixels with stratified dimensions;
    Sobol) against the independent-dimension render at 1024 spp (32×24 pixels).
    Negative control: a 10 % exposure error fails.  (At 64 spp the depth-of-field
    scene at this size fails for the default sampler too at some seeds — fraction
    0.9965 at seed 4 — where a pixel's rarer features are seen by too few samples
    for its sample variance to be honest.)"""
    import dataclasses

    from core.loader import load_scene
    from gibench import registry
    from reports.metrics import z_test

    algo = registry.get("distributed")
    sc = load_scene(ROOT / "suites" / scene)
    film = dataclasses.replace(sc.camera.film, width=32, height=24)
    sc.camera = dataclasses.replace(sc.camera, film=film)
    ref = algo.render(sc, algo.parse_params({"spp": 1024, "light_samples": 1}), seed=11)
    for extra in ({"dimensions": "stratified"}, {"sampler": "sobol"}):
        own = algo.render(sc, algo.parse_params({"spp": 256, "light_samples": 1, **extra}), seed=3)
        z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
        print(f"{scene} {extra}: {z}")
        assert z.passed, f"{scene} {extra}: {z}"
        bad = z_test(ref.image, own.image * 1.1, reference_variance=ref.variance,
                     test_variance=own.variance)
        assert not bad.passed, f"{scene} {extra}: a 10% exposure error went unnoticed: {bad}"
