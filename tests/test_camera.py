"""Sensors (impl/camera.py, the loader's sensor parsing): the pinhole, the thin lens of
depth of field and the orthographic camera, against their definitions and Mitsuba."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import SceneError, load_scene
from impl.camera import SENSOR_ORTHOGRAPHIC, SENSOR_THINLENS, camera_params, eye_ray, eye_ray_lens

ROOT = Path(__file__).resolve().parents[1]
SUITES = ROOT / "suites"
DIST = registry.get("distributed")


def _variant(tmp_path, scene, name, *replacements):
    text = (SUITES / scene).read_text()
    for old, new in replacements:
        assert old in text, f"{old!r} not in {scene}"
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text)
    return p


def test_loader_reads_thinlens_and_orthographic(tmp_path):
    cam = load_scene(SUITES / "distributed/dof.xml").camera
    assert cam.kind == "thinlens" and cam.aperture_radius == 0.12 and cam.focus_distance == 5.5
    ortho = load_scene(SUITES / "distributed/orthographic.xml").camera
    assert ortho.kind == "orthographic"
    p = _variant(tmp_path, "distributed/dof.xml", "nofocus.xml",
                 ('<float name="focus_distance" value="5.5"/>', ''))
    assert load_scene(p).camera.focus_distance == 1e4            # Mitsuba's default: far_clip
    p = _variant(tmp_path, "distributed/dof.xml", "noaperture.xml",
                 ('<float name="aperture_radius" value="0.12"/>', ''))
    with pytest.raises(SceneError, match=r"noaperture.xml:\d+: .*thinlens sensor needs 'aperture_radius'"):
        load_scene(p)
    p = _variant(tmp_path, "distributed/orthographic.xml", "fov.xml",
                 ('<float name="near_clip" value="0.01"/>', '<float name="fov" value="30"/>'))
    with pytest.raises(SceneError, match="unsupported property 'fov' of sensor 'orthographic'"):
        load_scene(p)
    p = _variant(tmp_path, "distributed/penumbra.xml", "shutter.xml",
                 ('<float name="near_clip" value="0.01"/>',
                  '<float name="shutter_open" value="1"/><float name="shutter_close" value="0.5"/>'))
    with pytest.raises(SceneError, match=r"shutter_close \(0.5\) must not be before shutter_open"):
        load_scene(p)


def test_thin_lens_rays_converge_on_the_focal_plane_and_reduce_to_the_pinhole():
    cam_t = load_scene(SUITES / "distributed/dof.xml").camera
    c = camera_params(cam_t, lens=True)
    assert c[18] == SENSOR_THINLENS
    M = cam_t.to_world
    rng = np.random.default_rng(3)
    for px, py in ((0.5, 0.5), (31.2, 17.9), (63.9, 47.5)):
        pin = eye_ray(c, px, py)
        # The pinhole ray's point at camera depth focus_distance ...
        d_cam = M[:3, :3].T @ np.array(pin[3:6])
        focus = np.array(pin[:3]) + np.array(pin[3:6]) * (cam_t.focus_distance / d_cam[2])
        for u1, u2 in rng.random((20, 2)):
            o = np.array(eye_ray_lens(c, px, py, u1, u2))
            org, d = o[:3], o[3:6]
            lens_local = M[:3, :3].T @ (org - M[:3, 3])
            assert abs(lens_local[2]) < 1e-12 and np.hypot(*lens_local[:2]) <= 0.12 + 1e-12
            # ... lies on every lens ray of that film point.
            t = np.dot(focus - org, d)
            assert np.linalg.norm(org + t * d - focus) < 1e-9
            assert np.linalg.norm(d) == pytest.approx(1.0)
    # Zero aperture: the lens ray is the pinhole ray.
    c0 = c.copy()
    c0[19] = 0.0
    for u1, u2 in rng.random((5, 2)):
        assert np.allclose(eye_ray_lens(c0, 10.3, 20.7, u1, u2), eye_ray(c, 10.3, 20.7))


def test_orthographic_rays_are_parallel_and_span_the_scaled_view():
    cam = load_scene(SUITES / "distributed/orthographic.xml").camera
    c = camera_params(cam)
    assert c[18] == SENSOR_ORTHOGRAPHIC
    a = np.array(eye_ray(c, 0.0, 0.0))
    b = np.array(eye_ray(c, 64.0, 48.0))
    assert np.allclose(a[3:6], b[3:6])
    # to_world scale 2: the view is 2·[-1, 1] × 2·[-1/aspect, 1/aspect] = 4 × 3 units.
    assert np.linalg.norm(a[:3] - b[:3]) == pytest.approx(5.0)
    assert a[6] == 0.0 and a[7] == pytest.approx(cam.far_clip - cam.near_clip)


def test_pinhole_only_algorithms_refuse_a_thin_lens():
    whitted = registry.get("whitted")
    with pytest.raises(NotImplementedError, match="'thinlens' sensor .* only by the 'distributed'"):
        whitted.render(load_scene(SUITES / "distributed/dof.xml"), whitted.parse_params({}))


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", ["distributed/dof.xml", "distributed/orthographic.xml"])
def test_sensor_matches_mitsuba(scene):
    """Own distributed tracer (8×8 jitter, lens samples per pixel sample) vs Mitsuba direct
    with the same thinlens / orthographic sensor: Z-test, and a 10 % error must fail."""
    from references.reference import get_reference
    from reports.metrics import z_test

    ref = get_reference(SUITES / scene, transport="direct", spp=1024, passes=8)
    own = DIST.render(load_scene(SUITES / scene), DIST.parse_params({"spp": 64, "light_samples": 1}))
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    print(f"{scene}: {z}")
    assert z.passed, z
    zb = z_test(ref.image, own.image * 1.1, reference_variance=ref.variance, test_variance=own.variance)
    assert not zb.passed
