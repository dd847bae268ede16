"""Ray casting with Phong local illumination: analytic radiance, invariants of
the Phong terms, and agreement with Mitsuba's direct integrator (Z-test)."""

from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from impl.raycast import cast_primary

SUITES = Path(__file__).resolve().parent.parent / "suites"
LIT_SPHERE = SUITES / "spheres" / "lit_sphere.xml"
RAYCAST = registry.get("raycast")


def render(path, seed=0, **params):
    return RAYCAST.render(load_scene(path), RAYCAST.parse_params(params), seed=seed)


def pixel_centre_rays(camera):
    """Eye rays through pixel centres, written out independently of impl.camera."""
    W, H = camera.film.width, camera.film.height
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    tx = camera.tan_half_fov_x
    d_cam = np.stack(np.broadcast_arrays((1 - 2 * u)[None, :] * tx,
                                         (1 - 2 * v)[:, None] * tx / camera.film.aspect,
                                         np.ones((H, W))), axis=-1)
    d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
    return camera.origin, d_cam @ camera.to_world[:3, :3].T


def test_lit_sphere_matches_analytic_radiance():
    """L = ρ/π · I · cosθ / d² at every pixel whose centre ray hits the sphere: ≤ 1e-4 relative."""
    scene = load_scene(LIT_SPHERE)
    sphere, light = scene.shapes[0], scene.lights[0]
    rho = np.array(scene.materials[sphere.material].reflectance)
    o, d = pixel_centre_rays(scene.camera)
    # Geometric ray–sphere (thesis 2.3.2), in float64 numpy.
    oc = sphere.center - o
    tca = d @ oc
    d2 = oc @ oc - tca ** 2
    hit = d2 <= sphere.radius ** 2
    t = tca - np.sqrt(np.maximum(sphere.radius ** 2 - d2, 0.0))
    p = o + t[..., None] * d
    n = (p - sphere.center) / sphere.radius
    to_light = light.position - p
    dist = np.linalg.norm(to_light, axis=-1)
    cos = np.maximum(np.einsum("hwc,hwc->hw", n, to_light / dist[..., None]), 0.0)
    analytic = rho / np.pi * light.radiant * (cos / dist ** 2)[..., None]

    _, shape_id = cast_primary(scene)
    mask = (shape_id == 0) & hit
    assert mask.sum() > 1000, "the sphere should cover many pixels"
    assert np.array_equal(shape_id == 0, hit), "pixel coverage of the sphere differs from the analytic one"
    image = render(LIT_SPHERE, spp=1).image.astype(np.float64)
    err = np.abs(image[mask] - analytic[mask])
    scale = np.maximum(analytic[mask], 1e-3 * analytic.max())   # no relative error of exact zeros
    assert (err / scale).max() <= 1e-4, f"max relative error {(err / scale).max():.3g}"
    # The unlit half is exactly black: nothing but the light contributes.
    assert np.all(image[mask & (cos == 0.0)] == 0.0)


def test_render_is_deterministic_and_counts_rays():
    a = render(LIT_SPHERE, spp=4, seed=3)
    b = render(LIT_SPHERE, spp=4, seed=3)
    c = render(LIT_SPHERE, spp=4, seed=4)
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.image, c.image)
    H, W = a.image.shape[:2]
    assert a.counters["camera_rays"] == W * H * 4
    # One point light: at most one shadow ray per camera ray, and at least one per lit hit.
    assert 0 < a.counters["shadow_rays"] <= a.counters["camera_rays"]
    assert a.variance is not None and np.all(a.variance >= 0)
    assert render(LIT_SPHERE, spp=1).variance is None


def test_phong_ambient_adds_exactly_ka_ia_rho():
    base = render(LIT_SPHERE, spp=1).image.astype(np.float64)
    amb = render(LIT_SPHERE, spp=1, ka=0.5, ambient=0.2).image.astype(np.float64)
    scene = load_scene(LIT_SPHERE)
    _, shape_id = cast_primary(scene)
    for sid, shape in enumerate(scene.shapes):
        rho = np.array(scene.materials[shape.material].reflectance)
        np.testing.assert_allclose(amb[shape_id == sid] - base[shape_id == sid],
                                   np.broadcast_to(0.1 * rho, (np.sum(shape_id == sid), 3)), atol=1e-6)
    assert np.all(amb[shape_id < 0] == 0.0)


def test_phong_specular_only_adds_light_and_peaks_at_mirror_direction():
    base = render(LIT_SPHERE, spp=1).image
    spec = render(LIT_SPHERE, spp=1, ks=0.5, shininess=50).image
    diff = (spec - base).mean(axis=-1)
    assert np.all(diff >= -1e-7)
    assert diff.max() > 0.01
    # A sharper lobe concentrates the highlight: fewer pixels above 10 % of the peak.
    sharp = (render(LIT_SPHERE, spp=1, ks=0.5, shininess=500).image - base).mean(axis=-1)
    assert np.sum(sharp > 0.1 * sharp.max()) < np.sum(diff > 0.1 * diff.max())


def test_attenuation_clamp_only_limits_near_lights():
    """f_att = min(1/(c1 + c2 d + c3 d²), 1): with all lights farther than 1 the clamp changes nothing."""
    a = render(LIT_SPHERE, spp=1).image
    b = render(LIT_SPHERE, spp=1, fatt_clamp=True).image
    np.testing.assert_array_equal(a, b)
    c = render(LIT_SPHERE, spp=1, c1=1.0, c3=0.0, fatt_clamp=True).image   # f_att = 1
    assert c.max() > a.max()


def test_shadows_off_only_adds_light():
    a = render(LIT_SPHERE, spp=1).image
    b = render(LIT_SPHERE, spp=1, shadows=False).image
    assert np.all(b >= a - 1e-7) and np.sum(b > a + 1e-4) > 100   # the plane's shadow is lit


def test_invalid_parameters_are_refused():
    with pytest.raises(registry.ParamError, match="unknown parameter 'spp2'.*valid: spp"):
        RAYCAST.parse_params({"spp2": 4})
    with pytest.raises(registry.ParamError, match="expects int"):
        RAYCAST.parse_params({"spp": "many"})
    with pytest.raises(ValueError, match="square"):
        render(LIT_SPHERE, spp=5)
    with pytest.raises(registry.ParamError, match="unknown algorithm 'raytrace'.*raycast"):
        registry.get("raytrace")


def test_non_diffuse_material_is_refused_not_rendered_black(tmp_path):
    text = LIT_SPHERE.read_text().replace(
        '<bsdf type="diffuse">\n            <rgb name="reflectance" value="0.8, 0.45, 0.2"/>\n        </bsdf>',
        '<bsdf type="conductor"/>')
    assert "conductor" in text
    p = tmp_path / "mirror.xml"
    p.write_text(text)
    with pytest.raises(NotImplementedError, match="raycast: shape 'sphere' has a 'conductor' BSDF"):
        render(p)


# ------------------------------------------------ against Mitsuba references ---

def _reference(path, transport):
    from references.reference import get_reference

    return get_reference(path, transport=transport, spp=1024, passes=8)


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", ["spheres/lit_sphere.xml", "spheres/spot_directional.xml",
                                   "spheres/meshes.xml", "cornell/cornell_point.xml",
                                   "cornell/cornell_box.xml"])
def test_ztest_passes_against_mitsuba_direct(scene):
    from reports.metrics import z_test

    ref = _reference(SUITES / scene, "direct")
    own = render(SUITES / scene, spp=16, light_samples=16)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    assert z.passed, f"{scene}: {z}"
    # The test has power: a 3 % error in exposure is detected.
    z_bad = z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                   test_variance=own.variance)
    assert not z_bad.passed, f"{scene}: a 3% exposure error went unnoticed: {z_bad}"


@pytest.mark.mitsuba
def test_direct_only_is_darker_than_full_transport_in_the_cornell_box():
    """Against the full reference, the error is model error: indirect light is missing,
    so the mean signed difference is negative, far beyond the reference noise."""
    from reports.metrics import bias, noise_floor

    path = SUITES / "cornell" / "cornell_box.xml"
    ref = _reference(path, "full")
    own = render(path, spp=16, light_samples=16)
    b = bias(ref.image, own.image)
    # Standard error of a mean over n independent entries: sqrt(mean variance / n).
    stderr = np.sqrt(noise_floor(ref.variance) / ref.image.size)
    assert b < -10 * stderr, (b, stderr)


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", ["spheres/lit_sphere.xml", "cornell/cornell_box.xml"])
def test_sobol_pixel_samples_estimate_the_same_image(scene):
    """Owen-scrambled Sobol pixel samples (``sampler=sobol``) estimate the pixel integral
    Mitsuba's ``direct`` computes: Z-test passes, and a 3 % exposure error is still
    caught; the image differs from the jittered one (the sampler is really used)."""
    from reports.metrics import z_test

    ref = _reference(SUITES / scene, "direct")
    own = render(SUITES / scene, spp=16, light_samples=16, sampler="sobol")
    jit = render(SUITES / scene, spp=16, light_samples=16)
    assert not np.array_equal(own.image, jit.image)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    assert z.passed, f"{scene}: {z}"
    z_bad = z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                   test_variance=own.variance)
    assert not z_bad.passed, f"{scene}: a 3% exposure error went unnoticed: {z_bad}"


@pytest.mark.mitsuba
def test_sobol_light_samples_are_stratified_over_the_pixel():
    """With ``sampler=sobol`` the area light's samples of a pixel's pixel samples are one
    Sobol net (:func:`impl.lighting.light_uv_sobol`), not independent draws per pixel
    sample: at 64 spp and one light sample the soft shadows on the Cornell box's floor
    (the image's lower half) are closer to Mitsuba's ``direct`` than with hashed light
    numbers (mean squared error over two seeds each)."""
    path = SUITES / "cornell" / "cornell_box.xml"
    ref = _reference(path, "direct")
    H = ref.image.shape[0]

    def err(**params):
        e = [np.mean((render(path, seed=s, spp=64, light_samples=1, **params).image - ref.image)[H // 2:] ** 2)
             for s in (1, 2)]
        return float(np.mean(e))

    sobol, hashed = err(sampler="sobol"), err()
    assert sobol < 0.6 * hashed, (sobol, hashed)
