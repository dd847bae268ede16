"""The speed studies the thesis discusses, as report tables: ray–sphere cost per form
(2.3.3, ``sphere_form_cost``) and z-buffer vs depth sort as the triangle count grows (1.3,
``visibility_growth``).  Their timings are reported, never asserted; the tests check what
the tables claim besides time — the timed kernels' hits and images are right — and that
those correctness columns fail for a broken variant."""

import numpy as np

from core.loader import load_scene
from gibench.studies import intersection, shading
from impl import depth_sort, zbuffer
from impl.intersect import SPHERE_FORMS, ray_sphere_batch
from impl.tessellate import sphere_triangle_count


def test_sphere_form_cost_rows_and_their_hits():
    rows = intersection.sphere_form_cost(rays=1 << 14, repeats=2)
    assert {(r["form"], r["precision"]) for r in rows} == {(f, p) for f in SPHERE_FORMS
                                                           for p in ("float32", "float64")}
    assert all(r["hits_agree"] for r in rows)
    assert all(r["median_s"] > 0 and r["min_s"] <= r["median_s"] <= r["max_s"] for r in rows)
    assert all(r["vs_algebraic"] == 1.0 for r in rows if r["form"] == "algebraic")


def test_the_hit_check_rejects_a_wrong_sphere_and_wrong_distances():
    o, d = intersection._cost_rays(1 << 14, 1)
    t = ray_sphere_batch(o, d, np.zeros(3), 1.0, form="geometric")
    assert intersection.sphere_hits_agree(t, o, d, 1.0)
    assert not intersection.sphere_hits_agree(ray_sphere_batch(o, d, np.zeros(3), 1.01, form="geometric"),
                                              o, d, 1.0)
    assert not intersection.sphere_hits_agree(np.where(t >= 0, t * (1 + 1e-6), t), o, d, 1.0)


def test_visibility_growth_rows_and_agreement():
    rows = shading.visibility_growth(segments=(4, 12), repeats=1)
    assert [(r["algorithm"], r["segments"]) for r in rows] == [
        ("zbuffer", 4), ("depthsort", 4), ("zbuffer", 12), ("depthsort", 12)]
    assert all(r["triangles"] == sphere_triangle_count(r["segments"]) + 2 for r in rows)
    assert all(r["agree"] == 1.0 for r in rows)


def test_the_agreement_measure_sees_a_different_visible_surface():
    """Depth sort of a coarser mesh than the z-buffer's: the silhouette and shading differ."""
    sc = load_scene(shading.SUITES / "spheres/lit_sphere.xml")
    a = zbuffer.ALGORITHM.render(sc, zbuffer.ALGORITHM.parse_params({"tessellation": 12}), seed=0).image
    b = depth_sort.ALGORITHM.render(sc, depth_sort.ALGORITHM.parse_params({"tessellation": 4}), seed=0).image
    assert shading.image_agreement(a, a) == 1.0
    assert shading.image_agreement(a, b) < 0.99
