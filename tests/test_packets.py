"""Eye-ray packets in the four ray tracers (``packets=true``, thesis 2.6): the must-hold
invariant is that tracing a tile's eye rays together changes nothing but the work —
the image, its variance and every counter are bit for bit those of single-ray
traversal of the *same* tree, on sphere and triangle scenes, spp > 1, in float64 (and
float32 for raycast, see PRECISION_CASES) — plus the refusals (no tree, per-pixel
sample counts, moving spheres).

Small films (21×19: tiles cut by both borders) keep the renders cheap; the
time goes into compiling the tile kernels once per precision.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene

SUITES = Path(__file__).resolve().parent.parent / "suites"
PACKET_COUNTERS = ("packet_nodes", "packet_tests")


def small(rel, width=21, height=19):
    sc = load_scene(SUITES / rel)
    return replace(sc, camera=replace(sc.camera, film=replace(sc.camera.film, width=width, height=height)))


# (tracer, scene, extra parameters): one sphere scene and one triangle scene per tracer.
CASES = [
    ("raycast", "spheres/spot_directional.xml", {"spp": 4}),
    ("raycast", "cornell/cornell_box.xml", {"spp": 4, "light_samples": 2}),
    ("whitted", "spheres/whitted_classic.xml", {"spp": 4, "light_samples": 2}),
    ("whitted", "cornell/cornell_mirror_glass.xml", {"spp": 4, "light_samples": 2}),
    ("path", "spheres/glass_sphere.xml", {"spp": 4, "max_depth": 6}),
    ("path", "cornell/cornell_box.xml", {"spp": 4, "max_depth": 4}),
    ("distributed", "spheres/rough_spheres.xml", {"spp": 4, "sampler": "jitter"}),
    ("distributed", "cornell/cornell_box.xml", {"spp": 5, "sampler": "poisson"}),
    ("distributed", "spheres/rough_spheres.xml", {"spp": 4, "sampler": "sobol"}),
    ("distributed", "cornell/cornell_box.xml", {"spp": 4, "dimensions": "stratified"}),
]


# float64 for every tracer; float32 for raycast only.  The precision-specific part of
# a packet — rounding the eye rays and the primitive tests (impl.accel.packets.packet_hits,
# packet_closest) — is shared by the four tile kernels, and each tracer's tile kernel in
# float32 is a separate numba compilation of 20–80 s on a cold cache (measured), which
# the CI budget cannot carry four times over.
PRECISION_CASES = [(*case, "float64") for case in CASES] + [
    (*case, "float32") for case in CASES if case[0] == "raycast"]


@pytest.mark.slow
@pytest.mark.parametrize("accel", ["bvh-sah", "bvh-wide"])
@pytest.mark.parametrize("tracer,scene,extra,precision", PRECISION_CASES,
                         ids=[f"{t}-{Path(s).stem}-{pr}" + "".join(f"-{v}" for k, v in e.items()
                                                                   if v in ("sobol", "stratified"))
                              for t, s, e, pr in PRECISION_CASES])
def test_packets_render_the_single_ray_image_bit_for_bit(tracer, scene, extra, precision, accel):
    """packets=true vs packets=false through the same BVH (binary or wide): identical
    image, variance and counters (the packet counters aside), and the packets did the
    eye rays' work."""
    algo = registry.get(tracer)
    sc = small(scene)
    p = {**extra, "precision": precision, "accel": accel}
    single = algo.render(sc, algo.parse_params(p), seed=7)
    packed = algo.render(sc, algo.parse_params({**p, "packets": True}), seed=7)
    assert single.image.max() > 0.0, f"{tracer} on {scene}: black image, the comparison would be empty"
    np.testing.assert_array_equal(packed.image, single.image, err_msg=f"{tracer} {scene} {precision}")
    np.testing.assert_array_equal(packed.variance, single.variance)
    assert single.variance is not None and single.variance.max() > 0.0   # spp > 1, noisy pixels
    for name in PACKET_COUNTERS:
        assert name not in single.counters, f"{name} reported without packets"
    assert {k: v for k, v in packed.counters.items() if k not in PACKET_COUNTERS} == single.counters
    W, H = sc.camera.film.width, sc.camera.film.height
    n_tiles = -(-W // 8) * -(-H // 8)
    spp = extra["spp"]
    # Every packet opens at least the root, and (the camera looks at the scene) tests primitives.
    assert packed.counters["packet_nodes"] >= n_tiles * (spp if tracer != "distributed" else 1)
    assert packed.counters["packet_tests"] > 0
    for name, v in single.aovs.items():
        np.testing.assert_array_equal(packed.aovs[name], v, err_msg=f"AOV {name}")


def test_auto_means_the_wide_bvh_with_packets_and_counts_match_primary_hits():
    """accel=auto with packets traces through bvh-wide whatever the scene size (the
    7-primitive scene below is brute force without packets), giving the image of
    packets=false with accel=bvh-wide; at spp = 1 the tracer's packets are exactly
    :func:`primary_hits`' pixel-centre packets, so their counters agree."""
    from impl.accel.packets import primary_hits
    from impl.rays import ray_config
    from impl.scene_arrays import flatten

    algo = registry.get("raycast")
    sc = small("spheres/spot_directional.xml")
    A = flatten(sc)
    assert ray_config(A, algo.parse_params({}), algorithm="raycast").accel == 0   # brute force
    auto = algo.render(sc, algo.parse_params({"packets": True}), seed=1)
    wide = algo.render(sc, algo.parse_params({"accel": "bvh-wide"}), seed=1)
    np.testing.assert_array_equal(auto.image, wide.image)
    R = ray_config(A, algo.parse_params({"accel": "bvh-wide"}), algorithm="raycast")
    depth, prim, counts = primary_hits(R, sc.camera, packets=True)
    assert (prim >= 0).any()
    assert auto.counters["packet_nodes"] == counts[0]
    assert auto.counters["packet_tests"] == counts[1]


@pytest.mark.parametrize("tracer", ["raycast", "whitted", "path", "distributed"])
@pytest.mark.parametrize("accel", ["none", "bv", "bv-sphere", "slabs", "grid"])
def test_packets_refuse_a_structure_that_is_not_a_tree(tracer, accel):
    algo = registry.get(tracer)
    sc = small("cornell/cornell_box.xml", 8, 8)
    with pytest.raises(ValueError, match=rf"packets=true needs a tree.*accel={accel}.*bvh-sah"):
        algo.render(sc, algo.parse_params({"packets": True, "accel": accel}))


@pytest.mark.parametrize("sampler", ["adaptive", "statistical"])
def test_distributed_packets_refuse_per_pixel_sample_counts(sampler):
    algo = registry.get("distributed")
    sc = small("cornell/cornell_box.xml", 8, 8)
    with pytest.raises(ValueError, match=rf"fixed-count sampler.*sampler={sampler}"):
        algo.render(sc, algo.parse_params({"packets": True, "sampler": sampler, "spp": 16}))


def test_distributed_packets_refuse_moving_spheres():
    algo = registry.get("distributed")
    sc = load_scene(SUITES / "distributed" / "motion" / "moving_sphere.xml")
    assert any(s.velocity is not None for s in sc.shapes)
    with pytest.raises(ValueError, match="moving spheres"):
        algo.render(sc, algo.parse_params({"packets": True}))
