"""Owen-scrambled Sobol (impl/lowdiscrepancy.py): the sequence, its nets, uniformity and
convergence rate."""

import math

import numpy as np
import pytest
from scipy import stats
from numba import njit
from scipy.stats import qmc

from impl import lowdiscrepancy as ld


def test_unscrambled_sequence_matches_scipy_in_gray_code_order():
    # scipy's unscrambled Sobol uses the same Joe-Kuo numbers in Gray-code order.
    n = 1024
    ref = qmc.Sobol(d=ld.MAX_DIMENSIONS, scramble=False).random(n)
    ours = np.array([[ld.sobol_uint(i ^ (i >> 1), d) for d in range(ld.MAX_DIMENSIONS)]
                     for i in range(n)], dtype=np.float64) / 2 ** 32
    np.testing.assert_array_equal(ours, ref)


def _elementary_interval_counts(pts: np.ndarray, m: int):
    """For each split j + (m - j) = m: the point counts of the 2**m intervals."""
    xi = np.floor(pts * 2 ** m).astype(np.int64)          # m-bit digits of each coordinate
    for j in range(m + 1):
        cell = (xi[:, 0] >> (m - j)) * (1 << (m - j)) + (xi[:, 1] >> j)
        yield j, np.bincount(cell, minlength=2 ** m)


@pytest.mark.parametrize("seed", [0, 1, 12345])
@pytest.mark.parametrize("pair", [0, 3])
def test_each_elementary_interval_holds_one_point(seed, pair):
    m = 8
    pts = ld.samples_2d(2 ** m, pair=pair, seed=seed)
    for j, counts in _elementary_interval_counts(pts, m):
        assert counts.min() == 1 and counts.max() == 1, (seed, pair, j)
    # An aligned later block is a net too; a misaligned one is not required to be.
    pts = ld.samples_2d(2 ** m, pair=pair, seed=seed, start=5 * 2 ** m)
    for j, counts in _elementary_interval_counts(pts, m):
        assert counts.max() == 1, (seed, pair, j)


def test_independent_points_are_not_nets():
    # Negative control of the interval test: uniform random points break it.
    pts = np.random.default_rng(3).random((256, 2))
    assert any(c.max() > 1 for _, c in _elementary_interval_counts(pts, 8))


def test_full_dimensional_points_are_a_net_in_dimensions_0_1():
    pts = ld.sobol_points(2 ** 7, 4, seed=9)
    for j, counts in _elementary_interval_counts(pts[:, :2], 7):
        assert counts.max() == 1, j
    assert np.all((pts >= 0) & (pts < 1))


def test_each_point_is_uniform_over_seeds_chi_square():
    # Owen scrambling makes every single point uniform on the square.
    n_seeds, bins = 6000, 8
    for index in (0, 1, 37):
        uv = np.array([ld.sample_2d(0, index, s) for s in range(n_seeds)])
        h, _, _ = np.histogram2d(uv[:, 0], uv[:, 1], bins=bins, range=[[0, 1], [0, 1]])
        p = stats.chisquare(h.ravel()).pvalue
        assert p > 1e-3, (index, p)


def test_pairs_and_seeds_are_decorrelated():
    a = ld.samples_2d(4096, pair=0, seed=5)
    b = ld.samples_2d(4096, pair=1, seed=5)
    c = ld.samples_2d(4096, pair=0, seed=6)
    for x, y in ((a[:, 0], b[:, 0]), (a[:, 1], b[:, 1]), (a[:, 0], c[:, 0])):
        assert abs(np.corrcoef(x, y)[0, 1]) < 0.06
    # 4D uniformity of (pair 0, pair 1): chi-square over 4**4 cells of a non-power-of-2 prefix.
    n = 3000
    q = np.floor(np.hstack([a[:n], b[:n]]) * 4).astype(int)
    cell = ((q[:, 0] * 4 + q[:, 1]) * 4 + q[:, 2]) * 4 + q[:, 3]
    assert stats.chisquare(np.bincount(cell, minlength=256)).pvalue > 1e-3


def _slope(ns, errs):
    return float(np.polyfit(np.log(ns), np.log(errs), 1)[0])


def _mse_curve(f, exact, sampler, ns, n_seeds):
    out = []
    for n in ns:
        est = np.array([f(sampler(n, s)).mean() for s in range(n_seeds)])
        out.append(np.mean((est - exact) ** 2))
    return np.array(out)


SMOOTH = (lambda p: np.exp(-(p[:, 0] ** 2 + p[:, 1] ** 2)), (math.sqrt(math.pi) / 2 * math.erf(1)) ** 2)
# The quarter disc of radius 0.9: a curved discontinuity (a soft shadow's edge, in one pixel).
DISC = (lambda p: (p[:, 0] ** 2 + p[:, 1] ** 2 < 0.81).astype(np.float64), math.pi * 0.81 / 4)


@pytest.mark.parametrize("name, integrand, bound", [("smooth", SMOOTH, -2.3), ("disc", DISC, -1.2)])
def test_convergence_slope_is_steeper_than_monte_carlo(name, integrand, bound):
    # MSE of the mean over n points, n = 2**4 .. 2**12, 48 scrambles each.  Independent
    # points give slope -1; Owen-scrambled nets -3 (smooth) and -1.5 (discontinuity).
    f, exact = integrand
    ns = 2 ** np.arange(4, 13)
    mse = _mse_curve(f, exact, lambda n, s: ld.samples_2d(int(n), pair=1, seed=s), ns, 48)
    slope = _slope(ns, mse)
    rng = np.random.default_rng(11)
    mc = _mse_curve(f, exact, lambda n, s: rng.random((int(n), 2)), ns, 48)
    mc_slope = _slope(ns, mc)
    print(f"{name}: Sobol MSE slope {slope:.2f}, independent {mc_slope:.2f}")
    assert slope < bound
    assert -1.3 < mc_slope < -0.7          # control: the test can tell the two apart


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="start"):
        ld.samples_2d(10, start=2 ** 32)
    with pytest.raises(ValueError, match="ndim"):
        ld.sobol_points(4, ld.MAX_DIMENSIONS + 1)
    with pytest.raises(ValueError, match="ndim"):
        ld.generator_matrices(0)


def test_dimension_0_and_1_shortcuts_equal_the_matrix_product():
    """``sobol_point`` and the padded samples compute Sobol dimension 0 as the bit
    reversal of the (scrambled) index and dimension 1 from byte tables: the same values
    as the generator-matrix product over the index's 32 bits, for any 32-bit index."""

    @njit
    def reverse32(i):                 # an intrinsic: callable from compiled code only
        return ld._reverse32(i)

    rng = np.random.default_rng(7)
    for i in list(range(64)) + [int(x) for x in rng.integers(0, 2**32, 2000, dtype=np.uint64)]:
        i = np.uint64(i)
        assert reverse32(i) == ld._sobol(ld._V, i, 0)
        assert ld._sobol1(i) == ld._sobol(ld._V, i, 1)


# ------------------------------------------------- seeded (per-dimension) samples ---

@njit(cache=False)
def _seeded_points_into(n, seed, d0, out):
    for i in range(n):
        out[i, 0], out[i, 1] = ld.sample_2d_seeded(i, ld.dimension_seed(seed, d0),
                                                   ld.dimension_seed(seed, d0 + 1),
                                                   ld.dimension_seed(seed, d0 + 2))
        out[i, 2] = ld.sample_1d_seeded(i, ld.dimension_seed(seed, d0 + 3),
                                        ld.dimension_seed(seed, d0 + 4))
        out[i, 3] = ld.sample_1d_seeded(i, ld.dimension_seed(seed, d0 + 5),
                                        ld.dimension_seed(seed, d0 + 6))


def _seeded_points(n, seed, d0):
    """Points 0..n-1 of one vertex's numbers as path's kernel draws them: a 2-D pair from
    dimension seeds d0..d0+2 and two 1-D numbers from d0+3..d0+6, shape (n, 4)."""
    out = np.empty((n, 4))
    _seeded_points_into(n, np.uint64(seed), d0, out)
    return out


def test_lowbias32_in_32_bit_lanes_is_the_masked_64_bit_hash():
    @njit
    def both(x):
        return ld._lowbias32(x), ld._mix32(x)

    rng = np.random.default_rng(5)
    for x in [0, 1, 2**32 - 1, 2**32, 2**64 - 1] + [int(v) for v in rng.integers(0, 2**63, 3000)]:
        a, b = both(np.uint64(x))
        assert a == b, x


@pytest.mark.parametrize("seed", [0, 77, 2**63 + 12345])
@pytest.mark.parametrize("d0", [0, 12, 60])
def test_seeded_pairs_are_nets_and_seeded_1d_points_are_stratified(seed, d0):
    m = 8
    pts = _seeded_points(2 ** m, seed, d0)
    for j, counts in _elementary_interval_counts(pts[:, :2], m):
        assert counts.min() == 1 and counts.max() == 1, (seed, d0, j)
    for col in (2, 3):
        for k in range(1, m + 1):       # one point per stratum of width 2^-k, in each block
            strata = np.floor(pts[:2 ** k, col] * 2 ** k).astype(np.int64)
            assert np.array_equal(np.sort(strata), np.arange(2 ** k)), (seed, d0, col, k)


def test_seeded_points_are_uniform_over_seeds_and_their_dimensions_decorrelated():
    # Each point is uniform over seeds (chi-square of 16 bins per number) ...
    n_seeds = 4000
    rng = np.random.default_rng(17)
    seeds = rng.integers(0, 2**63, n_seeds)
    for index in (0, 5):
        vals = np.array([_seeded_points(index + 1, s, 24)[index] for s in seeds])
        for col in range(4):
            h = np.bincount(np.floor(vals[:, col] * 16).astype(int), minlength=16)
            assert stats.chisquare(h).pvalue > 1e-3, (index, col)
    # ... and within one pixel's 4096 samples no number tracks another: not the pair's
    # two coordinates against the 1-D numbers, nor two vertices' (d0 apart) numbers.
    a, b = _seeded_points(4096, 99, 0), _seeded_points(4096, 99, 12)
    cols = np.hstack([a, b])
    r = np.corrcoef(cols.T)
    off = r[~np.eye(8, dtype=bool)]
    assert np.abs(off).max() < 0.06, np.abs(off).max()
    # The control: two 1-D numbers sharing the index shuffle (value scrambles apart) are
    # correlated (their top bits agree or disagree at every index), which the test sees.
    @njit
    def shared_shuffle(n, out):
        for i in range(n):
            out[i, 0] = ld.sample_1d_seeded(i, 1234567, 89)
            out[i, 1] = ld.sample_1d_seeded(i, 1234567, 4242)

    sh = np.empty((4096, 2))
    shared_shuffle(4096, sh)
    assert abs(np.corrcoef(sh.T)[0, 1]) > 0.3
