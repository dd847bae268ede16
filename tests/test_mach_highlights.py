"""Mach bands (thesis 1.5.3) and highlights (1.5.5): the pure metric
:func:`reports.metrics.mach_band` on analytic ramps, and the shading studies
``mach_bands`` and ``highlights`` — each check with a negative control."""

import numpy as np
import pytest

from core.errors import ImageError
from gibench.studies.shading import highlights, mach_bands, polygon_edges
from reports.metrics import mach_band


def _ramp(values):
    """A (1-row-padded) image whose luminance varies along x as ``values``."""
    img = np.repeat(np.asarray(values, float)[None, :, None], 5, axis=0)
    return np.repeat(img, 3, axis=2)


def test_mach_band_is_zero_for_log_linear_ramps_and_spikes_at_a_slope_jump():
    x = np.arange(40)
    smooth = _ramp(np.exp(0.05 * x))
    kink = _ramp(np.exp(0.05 * x + 0.05 * np.maximum(x - 20, 0)))   # slope of ln Y jumps at x = 20
    mask = np.ones(smooth.shape[:2], bool)
    assert mach_band(smooth, smooth, mask=mask) == 0.0
    # A change of scale is no change of contrast (up to the luminance floor, 1e-3 of the maximum).
    assert mach_band(smooth, _ramp(3.0 * np.exp(0.05 * x)), mask=mask) < 1e-4
    at = np.zeros_like(mask)
    at[:, 20] = True
    # Negative control: the kink is found at its column, and only there.
    assert mach_band(smooth, kink, mask=at) == pytest.approx(0.05, rel=1e-2)
    off = mask.copy()
    off[:, 19:22] = False
    assert mach_band(smooth, kink, mask=off) < 1e-4


def test_mach_band_shape_contract():
    a = np.ones((4, 5, 3))
    with pytest.raises(ImageError):
        mach_band(a, np.ones((4, 6, 3)), mask=np.ones((4, 5), bool))
    with pytest.raises(ImageError):
        mach_band(a, a, mask=np.ones((5, 4), bool))
    with pytest.raises(ValueError):
        mach_band(a, a, mask=np.ones((4, 5), bool), floor=0.0)
    assert np.isnan(mach_band(a, a, mask=np.zeros((4, 5), bool)))


def test_polygon_edges_of_a_flat_image():
    img = np.zeros((6, 6, 3))
    img[:, 3:] = 1.0
    e = polygon_edges(img)
    assert e[:, 2:4].all() and not e[:, :2].any() and not e[:, 4:].any()


def _keeps_highlight(rows, mode, n):
    r = next(r for r in rows if r["mode"] == mode and r["tessellation"] == n)
    return r["peak_kept"] >= 0.95 and r["energy_kept"] >= 0.95


def test_phong_shading_keeps_highlights_gouraud_loses():
    """k_s = 0.5, n = 50 on the lit sphere: Phong shading keeps ≥ 95 % of the exact highlight's
    peak and energy from 16 segments on; Gouraud shading does not at 8, 16 or 32 (the
    negative control: the same check applied to Gouraud fails)."""
    rows = highlights(tessellations=(8, 16, 32))
    for r in rows:
        print(f"{r['mode']:8s} N={r['tessellation']:3d} peak {r['peak_kept']:.3f} energy {r['energy_kept']:.3f}")
    assert all(_keeps_highlight(rows, "phong", n) for n in (16, 32))
    assert not any(_keeps_highlight(rows, "gouraud", n) for n in (8, 16, 32))


def test_mach_bands_order_flat_gouraud_phong_and_sit_on_edges():
    """Diffuse lit sphere: at 32 and 64 segments the Mach-band strength on polygon edges orders
    flat > Gouraud > Phong; for flat and Gouraud it is larger on edges than off them, and it
    falls with tessellation."""
    rows = mach_bands(tessellations=(16, 32, 64))
    m = {(r["mode"], r["tessellation"]): r for r in rows}
    for r in rows:
        print(f"{r['mode']:8s} N={r['tessellation']:3d} edge {r['mach_edge']:.4f} off {r['mach_off_edge']:.4f}")
    for n in (32, 64):
        assert m["flat", n]["mach_edge"] > m["gouraud", n]["mach_edge"] > m["phong", n]["mach_edge"]
        for mode in ("flat", "gouraud"):
            assert m[mode, n]["mach_edge"] > 2.0 * m[mode, n]["mach_off_edge"]
    for mode in ("flat", "gouraud", "phong"):
        assert m[mode, 16]["mach_edge"] > m[mode, 32]["mach_edge"] > m[mode, 64]["mach_edge"]
