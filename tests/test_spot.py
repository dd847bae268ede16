"""The spot light of every own algorithm (:func:`impl.lighting.spot_falloff`, shared by
raycast, whitted, distributed and path) against Mitsuba 3's ``spot``
(``src/emitters/spot.cpp``): the cone profile as a closed form — 1 within
``beam_width``, linear in angle to 0 at ``cutoff_angle``, both in degrees, the beam
3/4 of the cutoff by default — evaluated in the emitter's own frame (the inverse of
its to_world applied to the direction), so that a non-uniformly scaled to_world
stretches the cone as Mitsuba's does; then Mitsuba's plugin itself and Z-tests of
renders.  The third-party spot scene's Z-test at 256 spp closes the file, with
Mitsuba's own ``path`` failing the same test at 64 spp."""

import dataclasses
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench import registry
from impl.lighting import spot_falloff
from impl.scene_arrays import flatten

ROOT = Path(__file__).resolve().parent.parent
SUITES = ROOT / "suites"
SCALED = SUITES / "spheres" / "spot_scaled.xml"
THIRDPARTY_SPOT = SUITES / "thirdparty" / "docs" / "scenes" / "emitter_spot_no_texture.xml"

SPOT_SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film>
    </sensor>
    <emitter type="spot">
        <transform name="to_world">{scale}<lookat origin="0.2, 3, -0.1" target="0, 0, 0" up="0, 0, 1"/></transform>
        <rgb name="intensity" value="1"/>{cone}
    </emitter>
    <shape type="sphere"/>
</scene>
"""


def _spot(tmp_path, scale="", cone=""):
    """The flattened scene of one spot (to_world = lookat after ``scale``) and that to_world."""
    path = tmp_path / "spot.xml"
    path.write_text(SPOT_SCENE.format(scale=scale, cone=cone))
    scene = load_scene(path)
    return flatten(scene), scene.lights[0].to_world


def _profile(theta_deg, cutoff_deg, beam_deg):
    """Mitsuba's spot profile as a closed form of the angle θ to the axis."""
    if theta_deg >= cutoff_deg:
        return 0.0
    if theta_deg <= beam_deg:
        return 1.0
    return (cutoff_deg - theta_deg) / (cutoff_deg - beam_deg)


def _falloff(A, w):
    return spot_falloff(w[0], w[1], w[2], A.light_local, 0, A.light_cos_cutoff[0],
                        A.light_cos_beam[0], A.light_cutoff[0], A.light_inv_tw[0])


def _direction(to_world, theta_deg, phi_deg):
    """The world direction of the emitter-frame direction at angle θ to +z, azimuth φ."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    local = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    w = to_world[:3, :3] @ local
    return w / np.linalg.norm(w)


ANGLES = [0.0, 5.0, 11.5, 12.5, 15.0, 18.0, 21.5, 24.5, 25.5, 40.0, 120.0]


def test_defaults_are_mitsubas(tmp_path):
    """cutoff_angle 20 degrees and beam_width 3/4 of it when not given, degrees to radians."""
    A, _ = _spot(tmp_path)
    assert A.light_cutoff[0] == pytest.approx(math.radians(20.0), rel=1e-12)
    assert A.light_cos_beam[0] == pytest.approx(math.cos(math.radians(15.0)), rel=1e-12)
    A, _ = _spot(tmp_path, cone='<float name="cutoff_angle" value="40"/>')
    assert A.light_cos_beam[0] == pytest.approx(math.cos(math.radians(30.0)), rel=1e-12)


@pytest.mark.parametrize("phi", [0.0, 70.0, 200.0])
def test_falloff_is_the_linear_ramp_in_angle(tmp_path, phi):
    """Orthonormal to_world: the profile at angles inside the beam, on the ramp and outside
    the cone is the closed form, to 1e-12 (angles 0.5 degrees from the two boundaries,
    so no comparison hinges on rounding)."""
    A, m = _spot(tmp_path, cone='<float name="cutoff_angle" value="25"/><float name="beam_width" value="12"/>')
    for theta in ANGLES:
        got = _falloff(A, _direction(m, theta, phi))
        assert got == pytest.approx(_profile(theta, 25.0, 12.0), abs=1e-12), theta
    # Negative control: a ramp linear in cos θ (a common alternative) differs on the ramp.
    cos_ramp = (math.cos(math.radians(18.0)) - math.cos(math.radians(25.0))) / (
        math.cos(math.radians(12.0)) - math.cos(math.radians(25.0)))
    assert abs(cos_ramp - _profile(18.0, 25.0, 12.0)) > 1e-2


def test_falloff_is_evaluated_in_the_emitters_scaled_frame(tmp_path):
    """to_world = lookat · scale(2.5, 1, 1): the profile is the closed form of the angle in
    the emitter's frame, where the cone is round; in the world the cone is 2.5 times wider
    along the frame's x axis, so the profile of the world angle is a different function."""
    A, m = _spot(tmp_path, scale='<scale x="2.5"/>',
                 cone='<float name="cutoff_angle" value="25"/><float name="beam_width" value="12"/>')
    axis = m[:3, :3] @ [0.0, 0.0, 1.0]
    axis /= np.linalg.norm(axis)
    differs = 0
    for phi in (0.0, 90.0, 45.0, 180.0):
        for theta in ANGLES[:-1]:
            w = _direction(m, theta, phi)
            got = _falloff(A, w)
            assert got == pytest.approx(_profile(theta, 25.0, 12.0), abs=1e-12), (theta, phi)
            world = math.degrees(math.acos(min(1.0, float(w @ axis))))
            differs += abs(_profile(world, 25.0, 12.0) - got) > 1e-3
    assert differs >= 10                    # the world-space cone would be wrong here


@pytest.mark.mitsuba
def test_falloff_matches_mitsubas_spot_plugin(mitsuba):
    """Mitsuba's ``spot`` of ``spheres/spot_scaled.xml`` (a non-uniformly scaled to_world):
    its ``sample_direction`` weight times d² / intensity at 4000 points around the cone,
    against :func:`spot_falloff` of the loaded scene, to 2e-4 (float32)."""
    mi = mitsuba
    scene = load_scene(SCALED)
    A = flatten(scene)
    light = scene.lights[0]
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.uniform(-5.0, 5.0, 4000), rng.uniform(-0.5, 1.0, 4000),
                         rng.uniform(-3.0, 3.0, 4000)])
    ms = mi.load_file(str(SCALED))
    emitters = ms.emitters()
    assert len(emitters) == 1
    it = mi.Interaction3f()
    it.p = mi.Point3f(*[p[:, k].astype(np.float32) for k in range(3)])
    _, weight = emitters[0].sample_direction(it, mi.Point2f(0.5, 0.5))
    d2 = np.sum((p - light.position) ** 2, axis=1)
    theirs = np.array(weight, dtype=np.float64).reshape(3, -1)[0] * d2 / light.radiant[0]
    ours = np.array([_falloff(A, q - light.position) for q in p])
    assert 0.2 < np.mean(ours > 0.0) < 0.8 and np.any((ours > 0.05) & (ours < 0.95))
    assert np.max(np.abs(ours - theirs)) < 2e-4


def _ztest(ref, res):
    from reports.metrics import z_test

    return z_test(ref.image, res.image, reference_variance=ref.variance,
                  test_variance=res.variance)


@pytest.mark.mitsuba
@pytest.mark.parametrize("algorithm,params", [("raycast", {"spp": 64}),
                                              ("path", {"spp": 64, "max_depth": 2})])
def test_scaled_spot_ztest_against_mitsuba_direct(algorithm, params):
    """``spheres/spot_scaled.xml``: raycast and path (direct light) pass the Z-test against
    Mitsuba's ``direct``; the same scene with the spot's cone taken round in the world
    (its to_world dropped, the axis kept) fails it."""
    from references.reference import get_reference

    alg = registry.get(algorithm)
    ref = get_reference(SCALED, transport="direct", spp=1024, passes=8)
    scene = load_scene(SCALED)
    z = _ztest(ref, alg.render(scene, alg.parse_params(params), seed=5))
    print(f"{algorithm}: {z}")
    assert z.passed, z
    round_cone = dataclasses.replace(scene, lights=[dataclasses.replace(light, to_world=None)
                                                    for light in scene.lights])
    z = _ztest(ref, alg.render(round_cone, alg.parse_params(params), seed=5))
    print(f"{algorithm}, cone round in the world: {z}")
    assert not z.passed and z.fraction < 0.9


def _reduced_spot_scene(tmp_path) -> Path:
    """``emitter_spot_no_texture.xml`` as ``examples/thirdparty_reduced.py`` writes it
    (expanded, film sides divided by 8: 85 x 64)."""
    spec = importlib.util.spec_from_file_location("thirdparty_reduced",
                                                  ROOT / "examples" / "thirdparty_reduced.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "emitter_spot_no_texture.xml"
    out.write_text(module.reduced(THIRDPARTY_SPOT, 8, {"spp": "64"}))
    return out


@pytest.mark.mitsuba
@pytest.mark.slow
def test_thirdparty_spot_scene_passes_and_64_spp_is_below_the_tests_reach(tmp_path):
    """The reduced third-party spot scene (two coloured spots, a constant environment, a
    sphere on a checkerboard plane; 85 x 64) against Mitsuba's ``path`` (1024 spp x 8
    passes): own path at 256 spp passes the per-pixel Z-test.  At 64 spp the light the
    spots' lit regions send into the unlit plane arrives through a few samples per pixel
    (a sample mean and variance of rare events), so the test rejects unbiased
    estimators: Mitsuba's own ``path`` at 64 spp fails it against its own reference."""
    from references.reference import get_reference

    scene_path = _reduced_spot_scene(tmp_path)
    store = tmp_path / "store"
    ref = get_reference(scene_path, transport="full", spp=1024, passes=8, store=store)
    alg = registry.get("path")
    res = alg.render(load_scene(scene_path), alg.parse_params({"spp": 256}), seed=11)
    z = _ztest(ref, res)
    print(f"own path, 256 spp: {z}")
    assert z.passed, z
    theirs = get_reference(scene_path, transport="full", spp=64, passes=64, seed=1000, store=store)
    z = _ztest(ref, theirs)
    print(f"Mitsuba path, 64 spp: {z}")
    assert not z.passed, z
