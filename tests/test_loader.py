"""The scene loader: the suite scenes load in our loader and in Mitsuba, describe
the same geometry and camera (depth at pixel centres equals Mitsuba's aov
depth), and bad input gives a one-line error naming file, line and element."""

from pathlib import Path

import numpy as np
import pytest

from gibench import transforms as tf
from gibench.loader import SceneError, load_scene
from impl.raycast import cast_primary

SUITES = Path(__file__).resolve().parent.parent / "suites"
SCENES = sorted(SUITES.glob("*/*.xml"))
SCENE_IDS = [f"{p.parent.name}/{p.stem}" for p in SCENES]


def test_suite_has_the_promised_scenes():
    names = {f"{p.parent.name}/{p.stem}" for p in SCENES}
    assert {"cornell/cornell_box", "cornell/cornell_point", "spheres/lit_sphere",
            "spheres/spot_directional"} <= names


@pytest.mark.parametrize("path", SCENES, ids=SCENE_IDS)
def test_scene_loads(path):
    scene = load_scene(path)
    assert scene.shapes, "no shapes"
    assert scene.lights or scene.emitters, "no light"


# --------------------------------------------------------------- transforms ---

def test_transform_order_matches_mitsuba_python(mitsuba):
    """XML <scale/><rotate/><translate/> == Mitsuba's T().translate().rotate().scale()."""
    T = mitsuba.ScalarTransform4f
    expected = np.array(T().translate([0.335, -0.7, 0.38]).rotate([0, 1, 0], -17).scale(0.3).matrix)
    ours = tf.translate([0.335, -0.7, 0.38]) @ tf.rotate([0, 1, 0], -17) @ tf.scale(0.3)
    np.testing.assert_allclose(ours, expected, atol=1e-6)
    lk = np.array(T().look_at(origin=[1, 2, 3], target=[0, 0.5, -1], up=[0, 1, 0]).matrix)
    np.testing.assert_allclose(tf.look_at([1, 2, 3], [0, 0.5, -1], [0, 1, 0]), lk, atol=1e-6)


@pytest.mark.mitsuba
@pytest.mark.parametrize("path", SCENES, ids=SCENE_IDS)
def test_shapes_match_mitsuba_bounding_boxes(path, mitsuba):
    """Every shape's world-space bounding box agrees with the one Mitsuba builds."""
    ours = load_scene(path)
    mi_scene = mitsuba.load_file(str(path), optimize=False)  # no shape merging
    mi_boxes = {s.id(): s.bbox() for s in mi_scene.shapes()}
    assert len(mi_boxes) == len(ours.shapes)
    for shape in ours.shapes:
        box = mi_boxes[shape.name]
        if shape.kind == "sphere":
            lo, hi = shape.center - shape.radius, shape.center + shape.radius
        else:
            lo, hi = shape.vertices.min(0), shape.vertices.max(0)
        np.testing.assert_allclose(lo, np.array(box.min), atol=1e-5, err_msg=shape.name)
        np.testing.assert_allclose(hi, np.array(box.max), atol=1e-5, err_msg=shape.name)


@pytest.mark.mitsuba
@pytest.mark.parametrize("path", SCENES, ids=SCENE_IDS)
def test_depth_matches_mitsuba_aov(path, mitsuba):
    """Own eye-ray depth at pixel centres == Mitsuba's aov depth to 1e-4 relative.

    Mitsuba's perspective sensor starts rays on the near plane, so its depth is
    our distance minus near_clip / cos(angle to the optical axis).
    """
    from references.reference import render_depth

    scene = load_scene(path)
    ours, shape_id = cast_primary(scene)
    theirs = render_depth(path).astype(np.float64)
    cam = scene.camera
    W, H = cam.film.width, cam.film.height
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    tx = cam.tan_half_fov_x
    cx = (1 - 2 * u)[None, :] * tx
    cy = (1 - 2 * v)[:, None] * tx / cam.film.aspect
    cos = 1.0 / np.sqrt(cx ** 2 + cy ** 2 + 1.0)
    ours_mi = ours - cam.near_clip / cos
    hit_ours, hit_mi = np.isfinite(ours), theirs > 0
    # Hit/miss must agree except where a pixel centre grazes a silhouette.
    assert np.mean(hit_ours == hit_mi) > 0.999, f"hit masks differ on {np.sum(hit_ours != hit_mi)} pixels"
    both = hit_ours & hit_mi
    rel = np.abs(ours_mi[both] - theirs[both]) / theirs[both]
    # float32 in Mitsuba vs float64 here: compare the bulk to 1e-4 and allow a
    # few pixels at depth discontinuities (another surface hit by the other).
    assert np.mean(rel <= 1e-4) >= 0.999, f"max rel {rel.max():.3g}, {np.sum(rel > 1e-4)} pixels > 1e-4"


# --------------------------------------------------------------- bad input ---

def _write(tmp_path, text, name="scene.xml"):
    p = tmp_path / name
    p.write_text(text)
    return p


MINIMAL = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="40"/>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
    </sensor>
    {body}
</scene>
"""


def test_malformed_xml_names_file_and_line(tmp_path):
    p = _write(tmp_path, MINIMAL.format(body='<shape type="sphere">\n<float name="radius" value="1">\n</shape>'))
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and "malformed XML" in msg
    assert ":7:" in msg or ":8:" in msg


def test_unknown_plugin_type_names_element_file_and_line(tmp_path):
    p = _write(tmp_path, MINIMAL.format(body='<shape type="disk"/>'))
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = str(e.value)
    assert "\n" not in msg
    assert f"{p}:5:" in msg and '<shape type="disk">' in msg and "supported" in msg


def test_unsupported_property_is_not_silently_ignored(tmp_path):
    p = _write(tmp_path, MINIMAL.format(body='<shape type="sphere"><float name="radiuss" value="1"/></shape>'))
    with pytest.raises(SceneError, match="unsupported property 'radiuss'"):
        load_scene(p)


def test_missing_mesh_file_names_the_file(tmp_path):
    p = _write(tmp_path, MINIMAL.format(body='<shape type="obj"><string name="filename" value="nope.obj"/></shape>'))
    with pytest.raises(SceneError) as e:
        load_scene(p)
    assert "nope.obj" in str(e.value) and "not found" in str(e.value) and f"{p}:5:" in str(e.value)


def test_missing_scene_file():
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene("/nonexistent/scene.xml")


def test_defaults_are_substituted_and_undefined_ones_refused(tmp_path):
    body = '<default name="r" value="2.5"/><shape type="sphere"><float name="radius" value="$r"/></shape>'
    scene = load_scene(_write(tmp_path, MINIMAL.format(body=body)))
    assert scene.shapes[0].radius == 2.5
    bad = '<shape type="sphere"><float name="radius" value="$r"/></shape>'
    with pytest.raises(SceneError, match=r"'\$r' has no <default>"):
        load_scene(_write(tmp_path, MINIMAL.format(body=bad), "bad.xml"))


def test_non_uniform_sphere_scale_refused(tmp_path):
    body = '<shape type="sphere"><transform name="to_world"><scale value="1, 2, 1"/></transform></shape>'
    with pytest.raises(SceneError, match="uniform scale"):
        load_scene(_write(tmp_path, MINIMAL.format(body=body)))


def test_inline_bsdfs_stay_with_their_shapes():
    """Regression: materials were cached by id() of lxml proxies, which Python
    reuses once a proxy is freed, so the ground plane of lit_sphere.xml took the
    sphere's albedo in about 1 load in 12.  Fifty loads make a recurrence likely."""
    for _ in range(50):
        scene = load_scene(SUITES / "spheres" / "lit_sphere.xml")
        sphere, ground = scene.shapes
        assert scene.materials[sphere.material].reflectance == (0.8, 0.45, 0.2)
        assert scene.materials[ground.material].reflectance == (0.5, 0.5, 0.5)
