"""Tests for reports.metrics, pinned by hand-computed and analytic cases."""

from __future__ import annotations

import dataclasses
import json

import colour
import numpy as np
import pytest
from scipy import stats
from skimage.metrics import structural_similarity

from core.imageio import ImageError
from reports import metrics as m
from reports.tonemap import tonemap_srgb


def srgb_decode(v):
    """Inverse sRGB OETF (IEC 61966-2-1), for display values above 0.04045."""
    return ((np.asarray(v, dtype=np.float64) + 0.055) / 1.055) ** 2.4


def gray(value, shape=(4, 4)):
    return np.full(shape + (3,), value, dtype=np.float64)


@pytest.fixture
def pair():
    rng = np.random.default_rng(7)
    ref = rng.uniform(0.05, 1.0, (32, 32, 3)).astype(np.float32)
    test = (ref * rng.uniform(0.8, 1.2, ref.shape)).astype(np.float32)
    return ref, test


# --- linear metrics -------------------------------------------------------

REF = np.array([[[0.0, 1.0, 2.0], [1.0, 1.0, 1.0]]])  # (1, 2, 3)
TEST = np.array([[[1.0, 1.0, 0.0], [1.0, 2.0, 1.0]]])  # diffs: 1, 0, -2, 0, 1, 0


def test_linear_metrics_hand_computed():
    assert m.mse(REF, TEST) == pytest.approx(6 / 6)
    assert m.rmse(REF, TEST) == pytest.approx(1.0)
    assert m.mae(REF, TEST) == pytest.approx(4 / 6)
    assert m.bias(REF, TEST) == pytest.approx(0.0)
    assert m.bias(REF, TEST + 0.5) == pytest.approx(0.5)
    assert m.bias(REF, REF - 0.25) == pytest.approx(-0.25)
    assert m.rmse(REF, TEST * 3) == pytest.approx(np.sqrt(np.mean((3 * TEST - REF) ** 2)))


def test_relmse_eps():
    # (1 / (0 + .01) + 0 + 4 / (4 + .01) + 0 + 1 / (1 + .01) + 0) / 6
    expected = (1 / 0.01 + 4 / 4.01 + 1 / 1.01) / 6
    assert m.relmse(REF, TEST) == pytest.approx(expected)
    assert m.relmse(REF, TEST, eps=1.0) == pytest.approx((1 / 1 + 4 / 5 + 1 / 2) / 6)
    with pytest.raises(ValueError):
        m.relmse(REF, TEST, eps=0.0)


def test_float32_input_computed_in_float64():
    a = np.full((2, 2, 3), 1e4, dtype=np.float32)
    b = a + np.float32(1.0)
    assert m.mse(a, b) == 1.0
    assert isinstance(m.mse(a, b), float)


@pytest.mark.parametrize(
    "fn", [m.mse, m.rmse, m.mae, m.bias, m.relmse, m.psnr, m.ssim, m.flip, m.flip_map, m.delta_e2000]
)
def test_shape_mismatch_names_both_shapes(fn):
    with pytest.raises(ValueError) as info:
        fn(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    msg = str(info.value)
    assert "(4, 4, 3)" in msg and "(4, 5, 3)" in msg
    assert "reference" in msg and "test" in msg


def test_not_rgb_raises():
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        m.mse(np.zeros((4, 4)), np.zeros((4, 4)))


# --- display metrics ------------------------------------------------------

def test_psnr_identical_is_inf(pair):
    ref, _ = pair
    assert m.psnr(ref, ref) == float("inf")
    # Values above 1 clip to the same display value.
    assert m.psnr(gray(2.0), gray(3.0)) == float("inf")


def test_psnr_constant_display_offset():
    # Display values 0.5 vs 0.6: MSE 0.01 -> 10 log10(1 / 0.01) = 20 dB.
    ref, test = gray(srgb_decode(0.5)), gray(srgb_decode(0.6))
    assert m.psnr(ref, test) == pytest.approx(20.0, abs=1e-6)
    # Exposure 2 on half the radiance gives the same display images.
    assert m.psnr(ref / 2, test / 2, exposure=2.0) == pytest.approx(20.0, abs=1e-6)


def test_ssim_identical_and_noisy(pair):
    ref, test = pair
    assert m.ssim(ref, ref) == pytest.approx(1.0)
    assert m.ssim(ref, test) < 0.99


def test_ssim_small_images():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0, 1, (8, 8, 3))
    test = np.clip(ref + rng.normal(0, 0.1, ref.shape), 0, None)
    assert 0 < m.ssim(ref, test) < 1
    # 6 x 9 uses the largest odd window <= 6, i.e. 5.
    a, b = ref[:6, :8], test[:6, :8]
    expected = structural_similarity(
        tonemap_srgb(a), tonemap_srgb(b), channel_axis=-1, data_range=1.0, win_size=5
    )
    assert m.ssim(a, b) == pytest.approx(expected)
    assert m.ssim(ref[:3, :3], ref[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="3 x 3"):
        m.ssim(ref[:2], test[:2])


# --- FLIP -----------------------------------------------------------------

def test_flip_identical_and_changed(pair):
    ref, test = pair
    assert m.flip(ref, ref) == 0.0
    assert m.flip(ref, test) > 0.01
    assert m.flip(ref, test * 4) > m.flip(ref, test)


def test_flip_map(pair):
    ref, test = pair
    fmap = m.flip_map(ref, test)
    assert fmap.shape == (32, 32) and fmap.dtype == np.float64
    assert np.all((fmap >= 0) & (fmap <= 1))
    assert float(fmap.mean()) == pytest.approx(m.flip(ref, test), rel=1e-5)
    assert not m.flip_map(ref, ref).any()


def test_flip_clamps_negatives(pair):
    ref, test = pair
    neg = test.copy()
    neg[:4] = -1.0
    clamped = np.maximum(neg, 0.0)
    assert m.flip(ref, neg) == m.flip(ref, clamped)
    assert m.flip(ref, -ref) == m.flip(ref, np.zeros_like(ref))


def test_flip_black_reference_raises_instead_of_aborting():
    black = np.zeros((8, 8, 3))
    assert m.flip(black, black) == 0.0
    with pytest.raises(ValueError, match="HDR-FLIP"):
        m.flip(black, black + 0.1)


# --- CIEDE2000 --------------------------------------------------------------

def test_delta_e2000_identical_is_zero(pair):
    ref, _ = pair
    assert m.delta_e2000(ref, ref) == 0.0


def test_delta_e2000_neutral_grays_analytic():
    # Linear gray Y maps to L* = 116 Y^(1/3) - 16, a* = b* = 0; for neutral
    # colours CIEDE2000 reduces to |dL*| / S_L.
    y1, y2 = 0.18, 0.25
    l1, l2 = 116 * np.cbrt(y1) - 16, 116 * np.cbrt(y2) - 16
    lbar = (l1 + l2) / 2
    s_l = 1 + 0.015 * (lbar - 50) ** 2 / np.sqrt(20 + (lbar - 50) ** 2)
    expected = abs(l2 - l1) / s_l
    assert m.delta_e2000(gray(y1), gray(y2)) == pytest.approx(expected, abs=1e-6)
    # Exposure scales radiance before clipping; values above 1 clip to white.
    assert m.delta_e2000(gray(y1 / 4), gray(y2 / 4), exposure=4.0) == pytest.approx(expected, abs=1e-6)
    assert m.delta_e2000(gray(1.0), gray(5.0)) == 0.0


def test_delta_e2000_matches_colour_on_one_pair():
    ref_rgb, test_rgb = np.array([0.6, 0.2, 0.05]), np.array([0.5, 0.25, 0.1])
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    lab = [colour.XYZ_to_Lab(colour.RGB_to_XYZ(c, srgb), srgb.whitepoint) for c in (ref_rgb, test_rgb)]
    expected = float(colour.delta_E(lab[0], lab[1], method="CIE 2000"))
    got = m.delta_e2000(np.tile(ref_rgb, (3, 3, 1)), np.tile(test_rgb, (3, 3, 1)))
    assert got == pytest.approx(expected)
    assert 5 < got < 30


# --- counts and noise floor -------------------------------------------------

def test_nonfinite_counts():
    a = np.zeros((2, 2, 3))
    a[0, 0, 0] = np.nan
    a[1, 1] = [np.inf, -np.inf, np.nan]
    assert m.nonfinite_counts(a) == {"nan": 2, "inf": 2}
    assert m.nonfinite_counts(np.ones((2, 2, 3))) == {"nan": 0, "inf": 0}


def test_noise_floor_adds_to_mse():
    rng = np.random.default_rng(11)
    truth = rng.uniform(0.1, 1.0, (64, 64, 3))
    variance = rng.uniform(1e-4, 4e-4, truth.shape)
    ref = truth + rng.normal(0.0, np.sqrt(variance))
    test = truth + rng.normal(0.0, 0.02, truth.shape)
    floor = m.noise_floor(variance)
    assert floor == pytest.approx(variance.mean())
    assert m.mse(ref, test) == pytest.approx(m.mse(truth, test) + floor, rel=0.02)
    with pytest.raises(ValueError, match="negative"):
        m.noise_floor(-variance)


# --- Z-test -------------------------------------------------------------------

def noisy_pair(seed, shape=(32, 32), var_ref=1e-4, var_test=2e-4):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.2, 1.0, shape + (3,))
    ref = truth + rng.normal(0.0, np.sqrt(var_ref), truth.shape)
    test = truth + rng.normal(0.0, np.sqrt(var_test), truth.shape)
    return ref, test, np.full(truth.shape, var_ref), np.full(truth.shape, var_test)


def test_z_test_unbiased_noise_passes():
    seed = 1
    ref, test, vr, vt = noisy_pair(seed)
    result = m.z_test(ref, test, reference_variance=vr, test_variance=vt)
    print(f"seed={seed}: {result!r}")
    assert result.passed
    assert result.fraction == 1.0
    assert result.n == 32 * 32 * 3
    assert result.significance == pytest.approx(1 - (1 - 0.01) ** (1 / result.n))
    assert result.p_values.shape == ref.shape


def test_z_test_detects_five_sigma_bias_on_five_percent_of_pixels():
    seed = 2
    ref, test, vr, vt = noisy_pair(seed)
    mask = np.random.default_rng(seed).random(ref.shape[:2]) < 0.05
    test[mask] += 5 * np.sqrt(vr[mask] + vt[mask])
    result = m.z_test(ref, test, reference_variance=vr, test_variance=vt)
    print(f"seed={seed}: biased pixels={mask.sum()}, {result!r}")
    assert not result.passed
    assert result.fraction < 0.99
    # Unbiased entries stay consistent: all failures are in the biased pixels.
    assert np.all(result.p_values[~mask] > result.significance)


def test_z_test_p_values_uniform_under_null():
    ref, test, vr, vt = noisy_pair(3, shape=(64, 64))
    p = m.z_test(ref, test, reference_variance=vr, test_variance=vt).p_values
    assert stats.kstest(p.ravel(), "uniform").pvalue > 1e-3


def test_z_test_false_rejection_rate_matches_alpha():
    # With min_fraction=1 a run fails iff any entry is below the Šidák level,
    # which under the null happens with probability exactly alpha.
    alpha, trials = 0.2, 300
    failures = strict_failures = 0
    for seed in range(trials):
        ref, test, vr, vt = noisy_pair(1000 + seed, shape=(16, 16))
        failures += not m.z_test(ref, test, reference_variance=vr, test_variance=vt, alpha=alpha, min_fraction=1.0).passed
        strict_failures += not m.z_test(ref, test, reference_variance=vr, test_variance=vt).passed
    print(f"alpha={alpha}: {failures}/{trials} runs rejected; default settings: {strict_failures}")
    assert stats.binomtest(failures, trials, alpha).pvalue > 1e-3
    assert strict_failures == 0  # alpha=0.01 with 0.25 % tolerance: ~never


def test_z_test_variance_floor():
    rng = np.random.default_rng(5)
    ref = rng.uniform(0.0, 10.0, (16, 16, 3))
    zero = np.zeros_like(ref)
    assert m.z_test(ref, ref.copy(), reference_variance=zero).passed
    # Float32 and half-float rounding is within the floor ...
    assert m.z_test(ref, ref.astype(np.float32), reference_variance=zero).fraction == 1.0
    assert m.z_test(ref, ref.astype(np.float16), reference_variance=zero).fraction == 1.0
    # ... a real difference is not.
    result = m.z_test(ref, ref * 1.01 + 1e-3, reference_variance=zero)
    assert not result.passed and result.fraction < 0.01


def test_z_test_nonfinite_entries_are_inconsistent():
    ref, test, vr, vt = noisy_pair(4, shape=(8, 8))
    test[0, 0, 0] = np.nan
    vt[1, 1, 1] = np.inf
    result = m.z_test(ref, test, reference_variance=vr, test_variance=vt, min_fraction=1.0)
    assert np.isnan(result.p_values[0, 0, 0]) and np.isnan(result.p_values[1, 1, 1])
    assert result.fraction == pytest.approx(1 - 2 / test.size)
    assert not result.passed


def test_z_test_argument_checks():
    a = np.ones((4, 4, 3))
    with pytest.raises(ValueError, match=r"\(4, 5, 3\)"):
        m.z_test(a, a, reference_variance=np.ones((4, 5, 3)))
    with pytest.raises(ValueError, match="negative"):
        m.z_test(a, a, reference_variance=-a)
    with pytest.raises(ValueError, match="alpha"):
        m.z_test(a, a, reference_variance=a, alpha=1.5)
    # A scalar or (H, W, 1) variance broadcasts.
    assert m.z_test(a, a, reference_variance=1e-3).passed
    assert m.z_test(a, a, reference_variance=np.ones((4, 4, 1))).passed


def test_z_test_result_record():
    a = np.ones((4, 4, 3))
    result = m.z_test(a, a, reference_variance=0.0)
    text = repr(result)
    assert text.startswith("ZTestResult(passed=True") and "array" not in text and "p_values" not in text
    d = result.to_dict()
    assert set(d) == {"passed", "fraction", "significance", "n", "alpha", "min_fraction"}
    assert json.loads(json.dumps(d)) == d
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.passed = False


# --- compare ------------------------------------------------------------------

KEYS = {
    "mse", "rmse", "relmse", "mae", "bias", "psnr", "ssim", "flip", "delta_e2000",
    "nan_count", "inf_count", "noise_floor", "ztest", "conventions",
}


def test_compare_without_variance(pair):
    ref, test = pair
    d = m.compare(ref, test)
    assert set(d) == KEYS
    assert d["noise_floor"] is None and d["ztest"] is None
    assert d["nan_count"] == 0 and d["inf_count"] == 0
    for key in KEYS - {"nan_count", "inf_count", "noise_floor", "ztest", "conventions"}:
        assert type(d[key]) is float, key
    assert d["mse"] == m.mse(ref, test) and d["flip"] == m.flip(ref, test)
    assert "eps=0.01" in d["conventions"]["relmse"]
    json.dumps(d)
    assert m.compare(ref, ref)["psnr"] == float("inf")


def test_compare_with_variance():
    ref, test, vr, vt = noisy_pair(6)
    d = m.compare(ref, test, reference_variance=vr, test_variance=vt, exposure=0.5)
    assert d["noise_floor"] == pytest.approx(1e-4)
    assert d["ztest"]["passed"] is True
    assert d["psnr"] == m.psnr(ref, test, exposure=0.5)
    assert d["conventions"]["exposure"] == 0.5
    json.dumps(d)


def test_compare_nonfinite_test_image(pair):
    ref, test = pair
    bad = test.copy()
    bad[1, 2, 0] = np.nan
    bad[3, 4] = np.inf
    with pytest.raises(ImageError, match="NaN") as info:
        m.compare(ref, bad)
    assert "test image" in str(info.value) and "\n" not in str(info.value)
    d = m.compare(ref, bad, allow_nonfinite=True)
    assert (d["nan_count"], d["inf_count"]) == (1, 3)
    fixed = np.where(np.isfinite(bad), bad, 0.0)
    assert d["mse"] == m.mse(ref, fixed) and d["ssim"] == m.ssim(ref, fixed)


def test_compare_nonfinite_reference_always_raises(pair):
    ref, test = pair
    ref = ref.copy()
    ref[0, 0, 0] = np.nan
    for allow in (False, True):
        with pytest.raises(ImageError, match="reference"):
            m.compare(ref, test, allow_nonfinite=allow)


def test_compare_shape_mismatch(pair):
    ref, test = pair
    with pytest.raises(ValueError, match=r"\(32, 32, 3\).*\(32, 16, 3\)"):
        m.compare(ref, test[:, :16])
