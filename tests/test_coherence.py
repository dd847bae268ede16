"""Scan-line coherence in the rasteriser (thesis 1.2.1): incremental span traversal covers
exactly the pixels the per-pixel edge functions cover, with the same depths and barycentrics
up to rounding, and does fewer operations; the span solver against brute force, with a
negative control (an off-by-one solver is caught)."""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench import registry
from impl.raster import (DEPTH_FIXED16, DEPTH_FLOAT32, DEPTH_NONE, TRAVERSAL_EDGE,
                         TRAVERSAL_INCREMENTAL, _span_limits, rasterize)

SUITES = Path(__file__).resolve().parent.parent / "suites"


def _brute(c, a, lo, hi):
    xs = [x for x in range(lo, hi + 1) if c + a * x > 0]
    return (xs[0], xs[-1]) if xs else None


def _solved(fn, c, a, lo, hi):
    xa, xb = fn(c, a, lo, hi)
    return (xa, xb) if xa <= xb else None


def test_span_limits_equal_brute_force_and_an_off_by_one_is_caught():
    rng = np.random.default_rng(5)
    print("seed 5")
    cases = [(int(c), int(a)) for c, a in zip(rng.integers(-5000, 5000, 3000), rng.integers(-600, 600, 3000))]
    cases += [(0, 256), (0, -256), (256, -256), (-256, 256), (512, -256), (5, 0), (0, 0), (-3, 0)]
    for c, a in cases:
        assert _solved(_span_limits, c, a, -20, 20) == _brute(c, a, -20, 20), (c, a)

    def off_by_one(c, a, lo, hi):          # 'x >= -c/a' instead of 'x > -c/a'
        if a > 0:
            return max(-((c) // a), lo), hi
        return _span_limits(c, a, lo, hi)

    assert any(_solved(off_by_one, c, a, -20, 20) != _brute(c, a, -20, 20) for c, a in cases)


@pytest.mark.parametrize("depth_mode", [DEPTH_FLOAT32, DEPTH_FIXED16, DEPTH_NONE])
def test_random_soups_rasterise_identically(depth_mode):
    rng = np.random.default_rng(11)
    print("seed 11")
    M = 300
    xy = rng.uniform(-5, 69, (M, 3, 2))
    xy[::3] = np.round(xy[::3] * 2) / 2            # many vertices and edges through pixel centres
    zc = rng.uniform(1.0, 10.0, (M, 3))
    out = {}
    for tr in (TRAVERSAL_EDGE, TRAVERSAL_INCREMENTAL):
        out[tr] = rasterize(xy, zc, 64, 48, depth_mode=depth_mode, near=0.5, far=20.0, traversal=tr)
    (ve, ce), (vi, ci) = out[TRAVERSAL_EDGE], out[TRAVERSAL_INCREMENTAL]
    assert ce["fragments"] == ci["fragments"]
    same = ve.id == vi.id
    assert same.mean() >= 0.999, f"{(~same).sum()} pixels differ"
    np.testing.assert_allclose(vi.invz[same], ve.invz[same], rtol=1e-9)
    np.testing.assert_allclose(vi.b[same], ve.b[same], atol=1e-8)
    # Incremental visits only covered pixels and evaluates no edge function per pixel.
    assert ci["pixels_visited"] == ci["fragments"] and ci["edge_evals"] == 0
    assert ce["pixels_visited"] > ce["fragments"] and ce["edge_evals"] >= ce["fragments"] * 3
    assert ci["interp_evals"] + ci["interp_steps"] == ci["fragments"]


@pytest.mark.parametrize("name", ["spheres/lit_sphere.xml", "cornell/cornell_point.xml",
                                  "spheres/coplanar.xml", "spheres/cyclic_overlap.xml"])
@pytest.mark.parametrize("algorithm", ["zbuffer", "depthsort"])
def test_incremental_traversal_renders_the_same_image(name, algorithm):
    algo = registry.get(algorithm)
    scene = load_scene(SUITES / name)
    res = {tr: algo.render(scene, algo.parse_params({"traversal": tr, "tessellation": 32, "shading": "gouraud"}),
                           seed=0) for tr in ("edge", "incremental")}
    e, i = res["edge"], res["incremental"]
    np.testing.assert_array_equal(i.aovs["shape_id"], e.aovs["shape_id"])
    np.testing.assert_allclose(i.image, e.image, rtol=1e-5, atol=1e-7)
    assert i.counters["pixels_visited"] < e.counters["pixels_visited"]
    print(algorithm, name, {k: (e.counters[k], i.counters[k]) for k in
                            ("fragments", "pixels_visited", "edge_evals", "span_solves", "interp_evals",
                             "interp_steps")})


def test_scan_coherence_study_counts_fewer_operations_for_the_same_image():
    from gibench.studies.shading import scan_coherence

    rows = scan_coherence(scenes=("cornell/cornell_point.xml",), tessellation=16, repeats=1)
    edge, inc = rows
    assert edge["traversal"] == "edge" and inc["traversal"] == "incremental"
    assert inc["identical"] and inc["fragments"] == edge["fragments"]
    assert inc["ops"] < edge["ops"] / 4 and inc["pixels_visited"] == inc["fragments"]


def test_frame_coherence_is_total_for_a_still_camera_and_partial_when_it_turns():
    """A camera that does not move reuses everything (negative control of the measure);
    turning 2° per frame keeps most but not all pixels' visible triangle."""
    from gibench.studies.shading import frame_coherence

    still = frame_coherence(frames=3, step_deg=0.0, tessellation=16)
    assert all(r["visible_same"] == 1.0 and r["survivors_same"] == 1.0 and r["vertices_reused"] == 1.0
               for r in still)
    moving = frame_coherence(frames=3, step_deg=2.0, tessellation=16)
    for r in moving:
        print(r)
        assert 0.3 < r["visible_same"] < 1.0
        assert abs(r["tess_share"] + r["geometry_share"] + r["raster_share"] + r["shading_share"] - 1) < 1e-9
