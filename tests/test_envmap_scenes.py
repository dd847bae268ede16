"""Mitsuba's ``envmap`` emitter in the tracers: scenes of ``suites/vocabulary/`` lit
by a lat-long map, Z-tested against Mitsuba rendering the same XML, and a constant map
against the ``constant`` emitter's stored reference.

``envmap.xml`` (a sky with a small, bright sun): the direct-light tracers sample the
map by its luminance (``impl.lighting.environment_sample``), so a direct reference matches
them on diffuse surfaces.  ``envmap_path.xml`` (a broad glow instead of the sun): the
path tracer reaches the environment by BSDF sampling only, which a small sun would
make heavy-tailed (a per-pixel sample variance that under-estimates the error).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.imageio import write_exr
from core.loader import load_scene
from gibench import registry

VOC = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
ENVMAP, ENVMAP_PATH, CONSTANT_ENV = VOC / "envmap.xml", VOC / "envmap_path.xml", VOC / "constant_env.xml"


def _ztest(path, algorithm, params, transport, seed=0):
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get(algorithm)
    ref = get_reference(path, transport=transport, spp=1024, passes=8)
    own = algo.render(load_scene(path), algo.parse_params(params), seed=seed)
    assert own.image.shape == ref.image.shape
    return ref, own, z_test(ref.image, own.image, reference_variance=ref.variance,
                            test_variance=own.variance)


@pytest.mark.mitsuba
@pytest.mark.parametrize("algorithm, params", [
    ("raycast", {"spp": 64, "light_samples": 16}),
    ("whitted", {"spp": 64, "light_samples": 16}),
    ("distributed", {"spp": 64, "light_samples": 4}),
])
def test_envmap_scene_passes_the_ztest_against_mitsuba_direct(algorithm, params):
    """Diffuse surfaces under the sky-and-sun map: each direct-light tracer against
    Mitsuba's ``direct`` integrator; a 3 % exposure error is rejected."""
    from reports.metrics import z_test

    ref, own, z = _ztest(ENVMAP, algorithm, params, "direct")
    print(f"\n{algorithm}: {z}")
    assert z.passed, z
    assert not z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                      test_variance=own.variance).passed


@pytest.mark.mitsuba
def test_envmap_scene_passes_the_ztest_against_mitsuba_path():
    """The glow map through the path tracer (full transport, sphere and ground
    interreflecting) against Mitsuba's ``path``; a 3 % exposure error is rejected.
    64 spp: with the map light-sampled and MIS-weighted as Mitsuba does (BSDF
    sampling alone needed 256 spp for the per-pixel test)."""
    from reports.metrics import z_test

    ref, own, z = _ztest(ENVMAP_PATH, "path", {"spp": 64}, "full")
    print(f"\npath: {z}")
    assert z.passed, z
    assert not z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                      test_variance=own.variance).passed


@pytest.fixture
def constant_map_scene(tmp_path):
    """constant_env.xml with its ``constant`` emitter replaced by an envmap of the same
    colour (a 16x8 EXR), rotated, so every lookup and sample of the map is exercised."""
    colour = (0.6, 0.7, 0.9)
    exr = write_exr(tmp_path / "flat.exr", np.broadcast_to(np.float32(colour), (8, 16, 3)).copy())
    text = CONSTANT_ENV.read_text()
    start, end = text.index('<emitter type="constant">'), text.index("</emitter>") + len("</emitter>")
    envmap = (f'<emitter type="envmap"><string name="filename" value="{exr}"/>'
              '<transform name="to_world"><rotate x="1" y="1" angle="40"/></transform></emitter>')
    p = tmp_path / "constant_map.xml"
    p.write_text(text[:start] + envmap + text[end:])
    return p


def test_constant_map_flattens_to_its_colour(constant_map_scene):
    from impl.lighting import environment_radiance
    from impl.scene_arrays import flatten

    A = flatten(load_scene(constant_map_scene))
    assert A.env_radiance.shape == (0, 3) and A.env_image.shape == (8, 16, 3)
    rng = np.random.default_rng(3)
    for d in rng.normal(size=(50, 3)):
        d /= np.linalg.norm(d)
        np.testing.assert_allclose(environment_radiance(A, *d), (0.6, 0.7, 0.9), rtol=1e-6)


@pytest.mark.mitsuba
def test_constant_map_matches_the_constant_emitters_reference(constant_map_scene):
    """A constant-colour map lights the scene as the ``constant`` emitter does: raycast's
    render of the envmap scene (light samples drawn by the map's luminance, not
    cosine-weighted) passes the Z-test against the stored Mitsuba reference of
    constant_env.xml."""
    from references.reference import get_reference
    from reports.metrics import z_test

    ref = get_reference(CONSTANT_ENV, transport="direct", spp=1024, passes=8)
    algo = registry.get("raycast")
    own = algo.render(load_scene(constant_map_scene),
                      algo.parse_params({"spp": 64, "light_samples": 16}), seed=1)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    print(f"\nraycast: {z}")
    assert z.passed, z


def test_constant_map_is_the_constant_emitter_in_the_path_tracer(constant_map_scene):
    """The path tracer light-samples a map (MIS with its escaped rays) and reaches a
    ``constant`` emitter by BSDF sampling only: two estimators of one image, which agree
    within their variances (per-pixel Z-test), while a 3 % exposure error is caught."""
    from reports.metrics import z_test

    algo = registry.get("path")
    params = algo.parse_params({"spp": 16, "max_depth": 3})
    a = algo.render(load_scene(constant_map_scene), params, seed=2)
    b = algo.render(load_scene(CONSTANT_ENV), params, seed=3)
    assert a.image.mean() > 0.1
    z = z_test(b.image, a.image, reference_variance=b.variance, test_variance=a.variance)
    assert z.passed, z
    assert not z_test(b.image, a.image * 1.03, reference_variance=b.variance,
                      test_variance=a.variance).passed


def test_radiosity_still_refuses_an_envmap():
    from core.errors import UnsupportedError

    algo = registry.get("radiosity")
    with pytest.raises(UnsupportedError, match=r"envmap emitter 'textures/sky.exr' uses 'envmap'"):
        algo.render(load_scene(ENVMAP), algo.parse_params({}))


def test_spectral_path_refuses_an_envmap():
    from core.errors import UnsupportedError

    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match=r"spectral=true.*envmap emitter 'textures/sky.exr'"):
        algo.render(load_scene(ENVMAP), algo.parse_params({"spectral": True, "spp": 1}))
