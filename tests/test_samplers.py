"""Pixel samplers and reconstruction filters (impl/samplers.py, impl/filters.py) and the
convergence rates of random and jittered sampling (gibench/studies_sampling.py).

The slope test: on ``suites/distributed/silhouettes.xml`` (three sphere
silhouettes and hard shadows under a directional light, 32×24 px) the MSE of
the edge pixels against the tracer's own converged image, averaged over 3
seeds at 4, 16, 64, 256 spp, must fall with a fitted log–log slope of
−1 ± 0.15 for random sampling and −1.5 ± 0.15 for jittered sampling
(Mitchell 1996).  Measured: −1.04 and −1.49 (and −1.04 / −1.44 at 64×48).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from impl import filters as flt
from impl import samplers as smp

SLOPE_TOL = 0.15


def test_uniform_pattern_is_the_subpixel_centre_grid():
    out = np.zeros((16, 2))
    assert smp.uniform_pattern(4, out) == 16
    xs = sorted(set(np.round(out[:, 0], 12)))
    assert xs == pytest.approx([0.125, 0.375, 0.625, 0.875])
    assert sorted(set(np.round(out[:, 1], 12))) == pytest.approx(xs)


def test_random_pattern_is_uniform_in_the_pixel():
    from scipy import stats

    pts = np.concatenate([_pattern(smp.random_pattern, 16, p) for p in range(500)])
    assert pts.min() >= 0.0 and pts.max() < 1.0
    for c in range(2):
        assert stats.kstest(pts[:, c], "uniform").pvalue > 1e-3


def _pattern(fn, n, pixel, *args):
    out = np.zeros((n, 2))
    fn(n, 7, pixel, out) if not args else fn(*args, 7, pixel, out)
    return out


@pytest.mark.parametrize("gamma", (0.5, 0.25, 0.0))
def test_white_noise_jitter_stays_within_gamma_of_the_cell_centres(gamma):
    k = 4
    for pixel in range(50):
        out = np.zeros((k * k, 2))
        assert smp.jitter_pattern(k, gamma, 7, pixel, out) == k * k
        for s in range(k * k):
            i, j = s % k, s // k
            for c, idx in ((0, i), (1, j)):
                centre = (idx + 0.5) / k
                d = (out[s, c] - centre + 0.5) % 1.0 - 0.5     # toroidal offset
                assert abs(d) <= gamma / k + 1e-12
    if gamma == 0.5:     # the classic stratified pattern: one sample per stratum
        cells = {(int(x * k), int(y * k)) for x, y in out}
        assert len(cells) == k * k


def test_gaussian_jitter_has_the_requested_spread():
    k, sigma = 4, 1.0 / 6.5
    offs = []
    for pixel in range(400):
        out = np.zeros((k * k, 2))
        smp.gaussian_jitter_pattern(k, sigma, 7, pixel, out)
        for s in range(k * k):
            i = s % k
            offs.append(((out[s, 0] - (i + 0.5) / k + 0.5) % 1.0 - 0.5) * k)   # in units of T
    offs = np.array(offs)
    assert abs(offs.mean()) < 0.01
    assert offs.std() == pytest.approx(sigma, rel=0.03)


@pytest.mark.parametrize("n", (4, 16, 64))
def test_poisson_disk_keeps_its_minimum_distance(n):
    for pixel in range(20):
        out = np.zeros((n, 2))
        placed, r = smp.poisson_disk_pattern(n, 7, pixel, out)
        assert placed == n
        assert r >= 0.5 * smp.poisson_min_distance(n)     # at most a few 10 % shrinks
        d = np.abs(out[:, None, :] - out[None, :, :])
        d = np.minimum(d, 1.0 - d)
        dist = np.sqrt((d ** 2).sum(-1)) + np.eye(n) * 9
        assert dist.min() >= r * (1 - 1e-12)
    # Poisson-disk points are more evenly spread than random ones: larger nearest-neighbour distance.
    rnd = _pattern(smp.random_pattern, n, 3)
    d = np.abs(rnd[:, None] - rnd[None])
    d = np.minimum(d, 1 - d)
    assert (np.sqrt((d ** 2).sum(-1)) + np.eye(n) * 9).min() < r


def test_adaptive_and_statistical_rules():
    vals = np.zeros((5, 3))
    idx = np.arange(5)
    assert not smp.adaptive_disagree(vals, idx, 0.01)
    vals[3, 1] = 0.1
    assert smp.adaptive_disagree(vals, idx, 0.01) and not smp.adaptive_disagree(vals, idx, 0.1)
    pts = np.zeros((8, 2))
    smp.adaptive_children(0.0, 0.0, 1.0, pts)
    assert pts.tolist() == [[0.5, 0.0], [0.0, 0.5], [1.0, 0.5], [0.5, 1.0],
                            [0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]]
    assert not smp.statistical_done(3, 0.0, 0.0, 0.0, 1.96, 0.01)      # never before 4 samples
    assert smp.statistical_done(4, 0.0, 0.0, 0.0, 1.96, 0.01)
    # s² = 0.3/3 = 0.1, half-width 1.96·√(0.1/4) = 0.31
    assert not smp.statistical_done(4, 0.3, 0.0, 0.0, 1.96, 0.3)
    assert smp.statistical_done(4, 0.3, 0.0, 0.0, 1.96, 0.32)


# ------------------------------------------------------------------ filters ---

def test_gaussian_filter_is_mitsubas():
    # exp(-x²/2σ²) shifted to reach 0 at the radius 4σ, separable.
    s = 0.5
    assert flt.filter_radius(flt.FILTER_GAUSSIAN, s) == 2.0
    assert flt.gaussian_1d(2.0, s) == 0.0 and flt.gaussian_1d(2.5, s) == 0.0
    for x in (0.0, 0.3, 1.1):
        want = math.exp(-x * x / (2 * s * s)) - math.exp(-8.0)
        assert flt.gaussian_1d(x, s) == pytest.approx(want, rel=1e-12)
    assert flt.filter_weight(flt.FILTER_GAUSSIAN, s, 0.3, -0.7) == pytest.approx(
        flt.gaussian_1d(0.3, s) * flt.gaussian_1d(0.7, s))
    assert flt.filter_weight(flt.FILTER_BOX, 0.0, 0.49, -0.5) == 1.0
    assert flt.filter_weight(flt.FILTER_BOX, 0.0, 0.5, 0.0) == 0.0


def test_reconstruct_normalises_and_gives_the_variance_of_the_mean():
    rng = np.random.default_rng(1)
    W, H, n = 5, 4, 64
    recs = np.zeros((W * H, n, 6))
    for p in range(W * H):
        recs[p, :, 0] = p % W + rng.random(n)
        recs[p, :, 1] = p // W + rng.random(n)
        recs[p, :, 2] = 1.0
        recs[p, :, 3:] = 0.7                      # constant radiance
    counts = np.full(W * H, n)
    for kind, s in ((flt.FILTER_BOX, 0.0), (flt.FILTER_GAUSSIAN, 0.5)):
        mean, var = flt.reconstruct(recs, counts, W, H, kind, s)
        assert np.allclose(mean, 0.7) and np.allclose(var, 0.0, atol=1e-20)
    # Box, equal weights: the mean and s²/n of each pixel's own samples.
    recs[:, :, 3:] = rng.random((W * H, n, 3))
    mean, var = flt.reconstruct(recs, counts, W, H, flt.FILTER_BOX, 0.0)
    assert np.allclose(mean.reshape(-1, 3), recs[:, :, 3:].mean(1))
    assert np.allclose(var.reshape(-1, 3), recs[:, :, 3:].var(1, ddof=1) / n)
    with pytest.raises(ValueError, match=r"samples must be \(W\*H, cap, 6\)"):
        flt.reconstruct(recs[:5], counts, W, H, flt.FILTER_BOX, 0.0)


def test_film_filter_reads_the_scene_and_refuses_unknown_ones():
    from core.scene import Film

    assert flt.film_filter(Film(rfilter="gaussian", rfilter_params={"stddev": 0.3})) == (flt.FILTER_GAUSSIAN, 0.3)
    assert flt.film_filter(Film(rfilter="gaussian"), "box") == (flt.FILTER_BOX, 0.0)
    with pytest.raises(ValueError, match="unknown reconstruction filter 'tent'"):
        flt.film_filter(Film(), "tent")
    with pytest.raises(ValueError, match="stddev must be > 0"):
        flt.film_filter(Film(rfilter="gaussian", rfilter_params={"stddev": 0.0}))


# --------------------------------------------------------- convergence rates ---

@pytest.mark.slow
def test_random_and_jittered_mse_slopes_on_edge_pixels():
    from gibench.studies.sampling import convergence, fit_slopes

    rows = convergence(scenes=["distributed/silhouettes.xml"], samplers=("random", "jitter"),
                       spps=(4, 16, 64, 256), seeds=3, adaptive_thresholds=(),
                       statistical_tolerances=(), ref_spp=1024, ref_seeds=2, size=(32, 24))
    assert 0 < rows[0]["edge_pixels"] < rows[0]["pixels"]
    slopes = {(r["sampler"], r["pixels"]): r["slope_spp"] for r in fit_slopes(rows)}
    print({k: round(v, 3) for k, v in slopes.items()})
    assert slopes[("random", "edge")] == pytest.approx(-1.0, abs=SLOPE_TOL)
    assert slopes[("jitter", "edge")] == pytest.approx(-1.5, abs=SLOPE_TOL)
    # At equal spp jittered sampling beats random sampling from 16 spp on.
    by = {(r["sampler"], r["spp"], r["seed"]): r["mse_edge"] for r in rows}
    for spp in (16, 64, 256):
        assert sum(by[("jitter", spp, s)] for s in range(3)) < sum(by[("random", spp, s)] for s in range(3))


# Slopes of the samplers that stratify every dimension (thesis 2.5.8): on the soft
# shadow and depth of field the pixel position is not the only dimension that varies,
# so jittering it alone leaves the slope near -1; shuffled strata and Sobol points in
# the light and lens dimensions steepen it.  Measured at 32x24, 3 seeds (edge pixels):
# penumbra random -1.03, jitter -1.05, stratified -1.31, sobol -1.21; dof -1.00, -1.05,
# -1.16, -1.23.  Each seed's own fit spreads by 0.03 (stratified) to 0.055 (sobol, dof)
# standard deviation, so the 3-seed fit by about 0.02-0.03: the ceilings below leave
# 3-10 of those (sobol on the penumbra is the closest, 0.06 from its ceiling).  Jitter
# alone does not reach them (it must not: the test would not tell stratified
# dimensions from jittered pixels).  The reference's own error counts: with 2 reference
# seeds instead of 4 the dof slopes flattened to -1.12 (stratified) and -1.19 (sobol).
STEEP = {"penumbra": -1.15, "dof": -1.10}


@pytest.mark.slow
def test_stratified_and_sobol_dimensions_steepen_soft_shadow_and_dof_slopes():
    from gibench.studies.sampling import convergence, fit_slopes

    rows = convergence(scenes=["distributed/penumbra.xml", "distributed/dof.xml"],
                       samplers=("random", "jitter", "stratified", "sobol"), spps=(4, 16, 64, 256),
                       seeds=3, adaptive_thresholds=(), statistical_tolerances=(), ref_spp=1024,
                       ref_seeds=4, ref_sampler="stratified", size=(32, 24),
                       params={"light_samples": 1})
    slopes = {(r["scene"].split("/")[-1][:-4], r["sampler"]): r["slope_spp"]
              for r in fit_slopes(rows) if r["pixels"] == "edge"}
    print({k: round(v, 3) for k, v in slopes.items()})
    for scene, ceiling in STEEP.items():
        assert slopes[(scene, "random")] == pytest.approx(-1.0, abs=SLOPE_TOL), scene
        assert slopes[(scene, "jitter")] > ceiling, scene
        for sampler in ("stratified", "sobol"):
            assert slopes[(scene, sampler)] <= ceiling, (scene, sampler)
        # At 64 and 256 spp both beat jittered pixels alone at equal spp (3 seeds summed).
        by = {(r["sampler"], r["spp"], r["seed"]): r["mse_edge"] for r in rows
              if r["scene"].endswith(scene + ".xml")}
        for spp in (64, 256):
            jit = sum(by[("jitter", spp, s)] for s in range(3))
            for sampler in ("stratified", "sobol"):
                assert sum(by[(sampler, spp, s)] for s in range(3)) < jit, (scene, sampler, spp)
