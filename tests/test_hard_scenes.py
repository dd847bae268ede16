"""Hard scenes of suites/hard/ for the Whitted ray tree (total internal reflection
around the critical angle, index-matched glass) checked against their analytic
expectations with single rays, and every suite image finite."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from gibench.suite import load_suite
from impl.whitted import trace
from _analytic import fresnel_inside

ROOT = Path(__file__).resolve().parent.parent
HARD = ROOT / "suites" / "hard"
WHITTED = registry.get("whitted")
THETA_C = math.asin(1 / 1.5)


def test_tir_slab_boundary_at_the_critical_angle():
    """tir_slab.xml: from the camera (inside the slab, at the origin) a ray at incidence
    θ on the top face leaves with 2.25 (1 − F(θ)) below θ_c and is trapped (black,
    every bounce a TIR) from θ_c on; in the rendered middle row the boundary is the
    image's centre line."""
    scene = load_scene(HARD / "tir_slab.xml")
    one = {"max_depth": 2, "hall_threshold": 0.0}
    for d in (1e-3, 1e-2, 0.2):
        theta = THETA_C - d
        rgb, c = trace(scene, [0, 0, 0], [math.sin(theta), math.cos(theta), 0], one)
        np.testing.assert_allclose(rgb, 2.25 * (1 - fresnel_inside(theta)), rtol=1e-9)
        assert c["tir"] == 0 and c["transmission_rays"] == 1
    for d in (0.0, 1e-9, 1e-3, 0.2):
        theta = THETA_C + d
        rgb, c = trace(scene, [0, 0, 0], [math.sin(theta), math.cos(theta), 0])
        assert np.all(rgb == 0.0) and c["transmission_rays"] == 0
        assert c["tir"] == WHITTED.parse_params({})["max_depth"]    # every ray of the chain
    img = WHITTED.render(scene, WHITTED.parse_params({"spp": 1})).image
    row = img[img.shape[0] // 2].max(-1)
    W = img.shape[1]
    lit = row > 0
    # One side lit, the other black, the switch at the centre line (±1 pixel).
    switch = np.flatnonzero(lit[:-1] != lit[1:])
    assert len(switch) == 1 and abs(switch[0] + 1 - W // 2) <= 1, row


def test_tir_sphere_boundary_at_the_critical_angle():
    """tir_sphere.xml: from s = (0, 0.9, 0) along (0, sin a, cos a) the incidence is
    sin θ = 0.9 cos a; below a_c = acos(1/1.35) every ray is trapped (TIR at every
    bounce), above it leaves with 2.25 (1 − F(θ)) towards the sky."""
    scene = load_scene(HARD / "tir_sphere.xml")
    a_c = math.acos(1 / (1.5 * 0.9))
    s = [0, 0.9, 0]
    for d in (1e-9, 1e-3, 0.1):
        a = a_c - d
        rgb, c = trace(scene, s, [0, math.sin(a), math.cos(a)])
        assert np.all(rgb == 0.0) and c["transmission_rays"] == 0 and c["tir"] >= 9
    for d in (0.05, 0.2, 0.4):
        a = a_c + d
        theta = math.asin(0.9 * math.cos(a))
        rgb, c = trace(scene, s, [0, math.sin(a), math.cos(a)], {"max_depth": 2, "hall_threshold": 0.0})
        np.testing.assert_allclose(rgb, 2.25 * (1 - fresnel_inside(theta)), rtol=1e-9)
        assert c["tir"] == 0
    rgb, c = trace(scene, s, [0, math.sin(a_c + 1e-9), math.cos(a_c + 1e-9)])
    assert c["tir"] == 0 and c["transmission_rays"] >= 1 and np.all(np.isfinite(rgb))


def test_index_matched_glass_scene_equals_the_scene_without_it(tmp_path):
    """glass_ior1.xml with shadows on: the light sits between the glass and the wall, so
    the image equals the scene without the glass sphere (F = 0, no bending, η² = 1)."""
    text = (HARD / "glass_ior1.xml").read_text()
    empty = tmp_path / "empty.xml"
    stripped, n = re.subn(r'\s*<shape type="sphere" id="glass">.*?</shape>', "", text, flags=re.S)
    assert n == 1
    empty.write_text(stripped)
    p = WHITTED.parse_params({"spp": 4})
    a = WHITTED.render(load_scene(HARD / "glass_ior1.xml"), p)
    b = WHITTED.render(load_scene(empty), p)
    assert a.counters["transmission_rays"] > 500 and a.counters["reflection_rays"] == 0
    np.testing.assert_allclose(a.image, b.image, rtol=1e-6, atol=1e-7)
    assert b.image.max() > 0.1


_NOTHING = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.25, 2"/></emitter>
</scene>
"""


@pytest.mark.parametrize("name", ["raycast", "whitted", "distributed", "path"])
def test_a_scene_without_shapes_shows_its_environment(tmp_path, name):
    """A sensor and a constant environment, no shape: every eye ray escapes, so each ray
    tracer's image is the environment's radiance at every pixel, in every precision and
    with every pixel sampler (the batch tracers' lanes read the primitive tables at
    clamped indices, which do not exist in a scene without primitives)."""
    path = tmp_path / "nothing.xml"
    path.write_text(_NOTHING)
    scene = load_scene(path)
    algo = registry.get(name)
    for params in ({"spp": 4}, {"spp": 4, "precision": "float32"}, {"spp": 1, "sampler": "sobol"}):
        if "sampler" in params and not any(p.name == "sampler" for p in algo.params):
            continue
        img = algo.render(scene, algo.parse_params(params), seed=1).image
        assert img.shape == (16, 24, 3)
        np.testing.assert_allclose(img, np.broadcast_to([0.5, 0.25, 2.0], img.shape), rtol=1e-6,
                                   err_msg=f"{name} {params}")


def _suite_cases():
    seen = {}
    for manifest in ("default.toml", "hard.toml"):
        for case in load_suite(ROOT / "suites" / manifest).cases:
            key = (str(case.scene), case.algorithm)
            seen.setdefault(key, case)
    return list(seen.values())


@pytest.mark.parametrize("case", _suite_cases(), ids=lambda c: f"{c.scene_id}-{c.algorithm}")
def test_every_suite_image_is_finite(case):
    """Every scene of suites/default.toml and suites/hard.toml, rendered by its group's
    algorithm (first configuration) at one sample per pixel, has no NaN or Inf."""
    algo = registry.get(case.algorithm)
    params = dict(case.params)
    if algo.spp_param:
        params[algo.spp_param] = 1
    r = algo.render(load_scene(case.scene), algo.parse_params(params), seed=0)
    assert np.all(np.isfinite(r.image)), f"{case.scene_id}: {np.sum(~np.isfinite(r.image))} non-finite"
    if r.variance is not None:
        assert np.all(np.isfinite(r.variance))
