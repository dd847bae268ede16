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
  high spp on the soft shadow and depth-of-field scenes (against Mitsuba in
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


@pytest.mark.parametrize("m", (2, 4, 6))
def test_sobol_dimensions_are_nets_per_pixel(m):
    n = 2 ** m
    for dim in (0, LENS, LIGHT):
        pts = draw_2d(smp.DIM_SOBOL, n, dim, 20)
        for j in range(m + 1):          # elementary intervals 2^j × 2^(m-j)
            cells = (pts[..., 0] * 2 ** j).astype(int) * 2 ** (m - j) + (pts[..., 1] * 2 ** (m - j)).astype(int)
            assert (np.sort(cells, axis=1) == np.arange(n)).all(), f"pair {dim}, 2^{j} x 2^{m - j}"
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
    """The 4×4 strata of the lens and of a light sample of the same pixel sample,
    across 20 000 pixels: their joint 16×16 table is uniform.  Negative control: the
    lens paired with itself (the strata of an unshuffled pairing coincide) is rejected."""
    spp, k = 16, 4
    lens = draw_2d(mode, spp, LENS, 20000)
    light = draw_2d(mode, spp, LIGHT, 20000)

    def cell(p):
        return (p[..., 0] * k).astype(int) + k * (p[..., 1] * k).astype(int)

    for s in (0, 7):
        joint = cell(lens[:, s]) * spp + cell(light[:, s])
        p = stats.chisquare(np.bincount(joint, minlength=spp * spp)).pvalue
        assert p > ALPHA, f"sample {s}: lens and light strata are dependent (p={p:.2e})"
        same = cell(lens[:, s]) * spp + cell(lens[:, s])
        assert stats.chisquare(np.bincount(same, minlength=spp * spp)).pvalue < ALPHA
    # Within a pixel the two dimensions are uncorrelated too (mean correlation over pixels).
    r = [np.corrcoef(lens[i, :, 0], light[i, :, 0])[0, 1] for i in range(2000)]
    assert abs(np.mean(r)) < 4 * np.std(r) / np.sqrt(len(r))


# --------------------------------------------------------- the tracer's means ---

SCENES = ("distributed/penumbra.xml", "distributed/dof.xml")


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_stratified_and_sobol_pixel_means_are_unbiased(scene):
    """Per-pixel Z-test of 64-spp renders (jittered pixels with stratified dimensions;
    Sobol) against the independent-dimension render at 1024 spp (32×24 pixels).
    Negative control: a 10 % exposure error fails."""
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
        own = algo.render(sc, algo.parse_params({"spp": 64, "light_samples": 1, **extra}), seed=3)
        z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
        print(f"{scene} {extra}: {z}")
        assert z.passed, f"{scene} {extra}: {z}"
        bad = z_test(ref.image, own.image * 1.1, reference_variance=ref.variance,
                     test_variance=own.variance)
        assert not bad.passed, f"{scene} {extra}: a 10% exposure error went unnoticed: {bad}"
