"""The rest of the Mitsuba 3 vocabulary in the loader and the scene model:
focal lengths (against Mitsuba's sensor), serialized meshes (against Mitsuba's),
plastic, textured parameters, normal/bump maps, envmap and projector, and the
refusals (principled, media, features an algorithm does not model)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import SceneError, UnsupportedError
from core.loader import load_scene, sensor_fov

THIRDPARTY = Path(__file__).resolve().parent.parent / "suites" / "thirdparty"

SENSOR = """<scene version="3.0.0">
  <sensor type="perspective">
    {props}
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/></film>
  </sensor>
  {extra}
</scene>"""


def _write(tmp_path, text, name="s.xml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("props", [
    '<string name="focal_length" value="50mm"/>',
    '<string name="focal_length" value="28mm"/>',
    '<string name="focal_length" value="135"/>',
    '',                                                   # Mitsuba's default: 50mm
    '<float name="fov" value="40"/><string name="fov_axis" value="y"/>',
    '<float name="fov" value="40"/><string name="fov_axis" value="smaller"/>',
    '<float name="fov" value="60"/><string name="fov_axis" value="diagonal"/>',
])
@pytest.mark.parametrize("size", [(320, 240), (200, 400), (256, 256)])
def test_field_of_view_matches_mitsuba(mitsuba, tmp_path, props, size):
    """The camera's horizontal field of view is Mitsuba's x_fov for the same file."""
    mi = mitsuba
    w, h = size
    path = _write(tmp_path, SENSOR.format(props=props, w=w, h=h, extra=""))
    cam = load_scene(path).camera
    sensor = mi.load_file(str(path)).sensors()[0]
    x_fov = float(mi.traverse(sensor)["x_fov"][0])
    ours = float(np.rad2deg(2.0 * np.arctan(cam.tan_half_fov_x)))
    assert ours == pytest.approx(x_fov, rel=1e-5)
    props_dict = {}
    if "focal_length" in props:
        props_dict["focal_length"] = props.split('value="')[1].split('"')[0]
    elif "fov" in props:
        props_dict["fov"] = float(props.split('value="')[1].split('"')[0])
        props_dict["fov_axis"] = props.split('value="')[2].split('"')[0]
    assert sensor_fov(props_dict, w / h) == pytest.approx(x_fov, rel=1e-5)


def test_focal_length_and_fov_conflict(tmp_path):
    path = _write(tmp_path, SENSOR.format(props='<float name="fov" value="40"/>'
                                                '<string name="focal_length" value="50mm"/>',
                                          w=32, h=24, extra=""))
    with pytest.raises(SceneError, match=r"s\.xml:2: <sensor type=\"perspective\">: give either"):
        load_scene(path)
    path = _write(tmp_path, SENSOR.format(props='<string name="focal_length" value="35mm"/>'
                                                '<string name="fov_axis" value="y"/>',
                                          w=32, h=24, extra=""))
    with pytest.raises(SceneError, match="'fov_axis' is read only with 'fov'"):
        load_scene(path)
    with pytest.raises(Exception, match="unreferenced property"):
        import mitsuba as mi

        from references.mitsuba_env import load_mitsuba

        load_mitsuba().load_file(str(path))
    path = _write(tmp_path, SENSOR.format(props='<string name="focal_length" value="wide"/>',
                                          w=32, h=24, extra=""))
    with pytest.raises(SceneError, match="cannot parse the focal length"):
        load_scene(path)


@pytest.mark.parametrize("index", [0, 1, 2])
def test_serialized_matches_mitsuba(mitsuba, index):
    """Each shape of matpreview.serialized: Mitsuba's vertex and face counts and bounding box."""
    from core.meshes import load_serialized

    mi = mitsuba
    fn = THIRDPARTY / "common" / "meshes" / "matpreview.serialized"
    v, f, n, uv = load_serialized(fn, index)
    shape = mi.load_dict({"type": "serialized", "filename": str(fn), "shape_index": index})
    assert len(v) == shape.vertex_count() and len(f) == shape.face_count()
    bbox = shape.bbox()
    assert np.allclose(v.min(0), np.array(bbox.min, dtype=float), atol=1e-6)
    assert np.allclose(v.max(0), np.array(bbox.max, dtype=float), atol=1e-6)
    params = mi.traverse(shape)
    assert np.allclose(np.array(params["vertex_texcoords"], dtype=float).reshape(-1, 2), uv, atol=1e-6)
    with pytest.raises(Exception, match="shape_index 3 is out of range"):
        load_serialized(fn, 3)


def test_plastic_textures_normalmap_in_the_model():
    scene = load_scene(THIRDPARTY / "docs" / "scenes" / "bsdf_normalmap_with.xml")
    mats = [m for m in scene.materials if m.kind == "roughplastic"]
    assert len(mats) == 1
    m = mats[0]
    assert m.shading["type"] == "normalmap" and m.shading["texture"]["type"] == "bitmap"
    assert set(m.textures) == {"diffuse_reflectance"}
    assert m.textures["diffuse_reflectance"]["data"].shape == (128, 128, 3)
    scene = load_scene(THIRDPARTY / "docs" / "scenes" / "bsdf_bumpmap_with.xml")
    m = [m for m in scene.materials if m.kind == "roughplastic"][0]
    assert m.shading["type"] == "bumpmap" and m.shading["scale"] == 0.02
    scene = load_scene(THIRDPARTY / "docs" / "scenes" / "bsdf_plastic_shiny.xml")
    m = [m for m in scene.materials if m.kind == "plastic"][0]
    assert m.params.get("int_ior") is not None
    scene = load_scene(THIRDPARTY / "docs" / "scenes" / "bsdf_roughconductor_textured_carbon.xml")
    m = [m for m in scene.materials if m.kind == "roughconductor"][0]
    assert set(m.textures) == {"alpha_u", "alpha_v"}


def test_envmap_and_projector_in_the_model():
    from core.imageio import read_exr

    scene = load_scene(THIRDPARTY / "docs" / "scenes" / "emitter_projector_textured.xml")
    env = scene.envmap
    assert env is not None and env.scale == 1.0
    ref = np.asarray(read_exr(THIRDPARTY / "common" / "textures" / "museum.exr"), dtype=np.float64)
    assert np.array_equal(env.data, ref[:, :, :3])
    (proj,) = [l for l in scene.lights if l.kind == "projector"]
    assert proj.scale == 85.8 and proj.texture["type"] == "bitmap"
    assert proj.fov_x == pytest.approx(32.0)       # fov along x (the default axis)


def test_one_environment_emitter(tmp_path):
    extra = ('<emitter type="constant"/><emitter type="envmap">'
             f'<string name="filename" value="{THIRDPARTY}/common/textures/museum.exr"/></emitter>')
    path = _write(tmp_path, SENSOR.format(props="", w=32, h=24, extra=extra))
    with pytest.raises(SceneError, match="only one environment emitter"):
        load_scene(path)


@pytest.mark.parametrize("extra, why", [
    ('<bsdf type="principled" id="p"/>', "not a model of the thesis"),
    ('<medium type="homogeneous" id="m"/>', "participating media are out of scope"),
    ('<shape type="sphere"><medium type="homogeneous" name="interior"/></shape>',
     "participating media are out of scope"),
])
def test_refused_by_name(tmp_path, extra, why):
    path = _write(tmp_path, SENSOR.format(props="", w=32, h=24, extra=extra))
    with pytest.raises(SceneError, match=why) as info:
        load_scene(path)
    assert "\n" not in str(info.value) and "s.xml:" in str(info.value)


@pytest.mark.parametrize("scene_file, feature", [
    ("docs/scenes/bsdf_plastic_default.xml", "plastic"),
    ("docs/scenes/bsdf_roughplastic_ggx.xml", "roughplastic"),
    ("docs/scenes/bsdf_diffuse_plain.xml", "envmap"),
    ("tests/scenes/projector/test_projector_constant_direct.xml", "projector"),
    ("docs/scenes/emitter_spot_texture.xml", "spot texture"),
    ("tests/scenes/bsdf_spheres/test_normalmap_path.xml", "normalmap"),
    ("docs/scenes/bsdf_roughconductor_textured_carbon.xml", "textured roughness"),
    ("docs/scenes/bsdf_roughconductor_anisotropic_aluminium.xml", "anisotropic roughness"),
])
@pytest.mark.parametrize("algorithm", ["raycast", "path", "whitted", "distributed", "radiosity",
                                       "zbuffer"])
def test_algorithms_refuse_unmodelled_features(scene_file, feature, algorithm):
    """Every algorithm refuses, by name and before rendering, a feature it does not model."""
    from gibench import registry

    from core.scene import scene_features

    algo = registry.get(algorithm)
    scene = load_scene(THIRDPARTY / scene_file)
    assert feature in scene_features(scene)
    if feature in algo.models:
        pytest.skip(f"{algorithm} models {feature}")
    with pytest.raises(UnsupportedError, match=f"^{algorithm}: .* uses '") as info:
        algo.render(scene, algo.parse_params({}), seed=0)
    assert "\n" not in str(info.value)
    named = str(info.value).split(" uses '")[1].split("'")[0]
    assert named in scene_features(scene) and named not in algo.models


VOCABULARY = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"


@pytest.mark.mitsuba
@pytest.mark.parametrize("name", ["focal_length", "instancing", "serialized"])
def test_vocabulary_scenes_pass_the_ztest_against_mitsuba_direct(name):
    """Scenes using focal_length, shapegroup/instance with referenced definitions and
    a quad OBJ, and serialized meshes: raycast (8x8 strata) agrees with Mitsuba's
    direct integrator by the Z-test, and the test detects a 3 % exposure error."""
    from gibench import registry
    from references.reference import get_reference
    from reports.metrics import z_test

    raycast = registry.get("raycast")
    path = VOCABULARY / f"{name}.xml"
    ref = get_reference(path, transport="direct", spp=1024, passes=8)
    own = raycast.render(load_scene(path), raycast.parse_params({"spp": 64, "light_samples": 16}),
                         seed=0)
    assert own.image.shape == ref.image.shape
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    assert z.passed, z
    assert not z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                      test_variance=own.variance).passed


@pytest.mark.parametrize("props, aspect_image", [
    ('<float name="fov" value="32"/>', None),
    ('<string name="focal_length" value="28mm"/>', None),
    ('<float name="fov" value="40"/><string name="fov_axis" value="y"/>', "bitmap"),
])
def test_projector_field_of_view_matches_mitsuba(mitsuba, tmp_path, props, aspect_image):
    """A projector's horizontal field of view is Mitsuba's (parse_fov with the
    irradiance texture's aspect, 1 for a constant)."""
    mi = mitsuba
    tex = ""
    if aspect_image:
        fn = THIRDPARTY / "common" / "textures" / "carrot.png"
        tex = (f'<texture type="bitmap" name="irradiance"><string name="filename" value="{fn}"/>'
               '</texture>')
    extra = f'<emitter type="projector" id="proj">{props}{tex}</emitter><shape type="sphere"/>'
    path = _write(tmp_path, SENSOR.format(props='<float name="fov" value="45"/>', w=32, h=24,
                                          extra=extra))
    (proj,) = load_scene(path).lights
    emitter = [e for e in mi.load_file(str(path)).emitters()][0]
    import re

    # Mitsuba's projector does not expose x_fov as a parameter; its to_string() prints it.
    x_fov = float(re.search(r"x_fov = ([-+0-9.eE]+)", str(emitter)).group(1))
    assert proj.fov_x == pytest.approx(x_fov, rel=1e-5)


def test_plastic_alone_is_refused_by_name(tmp_path):
    """A scene whose only new feature is a plastic sphere: each algorithm but path (which
    models it) names 'plastic'."""
    from gibench import registry

    extra = ('<emitter type="point"><point name="position" value="0, 0, -3"/></emitter>'
             '<shape type="sphere" id="ball"><point name="center" value="0, 0, 3"/>'
             '<bsdf type="plastic"/></shape>')
    scene = load_scene(_write(tmp_path, SENSOR.format(props='<float name="fov" value="45"/>', w=8,
                                                      h=6, extra=extra)))
    for name in ("raycast", "whitted", "distributed"):
        algo = registry.get(name)
        with pytest.raises(UnsupportedError) as info:
            algo.render(scene, algo.parse_params({}), seed=0)
        assert str(info.value) == f"{name}: shape 'ball' uses 'plastic', which {name} does not model"
