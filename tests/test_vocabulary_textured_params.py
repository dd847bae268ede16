"""Textured parameters beyond the reflectances: a dielectric's ``specular_transmittance``
(smooth, rough and thin), a rough dielectric's ``specular_reflectance`` and a conductor's
``eta`` and ``k`` (smooth and rough), read at the hit as Mitsuba's BSDFs read them.

* ``suites/vocabulary/textured_params.xml`` (a checkerboard eta on a smooth conductor, a
  checkerboard transmittance on a thindielectric, a bitmap transmittance and a
  checkerboard reflectance on a roughdielectric) and ``textured_params_glossy.xml`` (a
  roughdielectric as before, a bitmap k on a Beckmann roughconductor) pass the per-pixel
  Z-test against Mitsuba's ``path`` (own 256 spp against 1024 spp × 8 passes), and each
  third's mean lies within 4 standard errors of Mitsuba's.
* ``textured_params_whitted.xml`` (a checkerboard eta and a bitmap k on smooth
  conductors, a checkerboard transmittance on a smooth dielectric) in ``whitted`` and
  ``distributed``, and ``textured_params_glossy.xml`` in ``distributed``, against the
  matched Mitsuba ``whitted`` reference, per pixel and per third.
* Negative control: each texture replaced by its mean colour fails the Z-test.
* The other algorithms refuse both features by name; spectral path, Hall's shading and
  whitted's transmissive shadow rays refuse them with their reason; a named conductor
  with a textured eta is a scene error, as in Mitsuba.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from _regions import against_mitsuba, assert_passes_by_pixel_and_thirds, path_against_mitsuba

from core.errors import SceneError, UnsupportedError
from core.loader import load_scene
from core.scene import texture_mean
from gibench import registry

VOC = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
PATH_SCENES = [VOC / "textured_params.xml", VOC / "textured_params_glossy.xml"]
#: (algorithm, scene) of the ray tracers' cases, against Mitsuba's whitted reference.
RAY_TRACED = [("whitted", VOC / "textured_params_whitted.xml"),
              ("distributed", VOC / "textured_params_whitted.xml"),
              ("distributed", VOC / "textured_params_glossy.xml")]
#: Whitted's deterministic splits at 64 spp; distributed's sampled lobes at 256 (the
#: rough panels' rare bright samples need them for the sample variance).
RAY_PARAMS = {"whitted": {"spp": 64, "light_samples": 16}, "distributed": {"spp": 256, "light_samples": 16}}
TEXTURED = ("eta", "k", "specular_transmittance", "specular_reflectance")


def _as_mean(m):
    """Every textured parameter of :data:`TEXTURED` replaced by its mean colour."""
    moved = {n: texture_mean(t).tolist() for n, t in m.textures.items() if n in TEXTURED}
    if not moved:
        return m
    rest = {n: t for n, t in m.textures.items() if n not in moved}
    return dataclasses.replace(m, textures=rest, params={**m.params, **moved})


def _id(v):
    return getattr(v, "stem", v)


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene_file", PATH_SCENES, ids=_id)
def test_path_passes_the_ztest_against_mitsuba_path(scene_file):
    """Per pixel and per third of the image, own ``path`` agrees with Mitsuba's ``path``;
    a 3 % exposure error moves some third's mean by more than 4 standard errors."""
    assert_passes_by_pixel_and_thirds(scene_file.stem, *path_against_mitsuba(scene_file))


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene_file", PATH_SCENES, ids=_id)
def test_the_path_ztest_rejects_the_textures_replaced_by_their_means(scene_file):
    ref, own, z = path_against_mitsuba(scene_file, materials=_as_mean)
    print(f"\n{scene_file.stem} (_as_mean): {z}")
    assert not z.passed


@pytest.mark.mitsuba
@pytest.mark.parametrize("algo_name, scene_file", RAY_TRACED, ids=_id)
def test_ray_tracers_pass_the_ztest_against_mitsuba_whitted(algo_name, scene_file):
    """Per pixel and per third of the image, own ``whitted`` / ``distributed`` agree with
    the matched Mitsuba reference; a 3 % exposure error moves some third's mean by more
    than 4 standard errors."""
    assert_passes_by_pixel_and_thirds(f"{algo_name} {scene_file.stem}",
                                      *against_mitsuba(scene_file, algo_name, RAY_PARAMS[algo_name], "whitted"))


@pytest.mark.mitsuba
@pytest.mark.parametrize("algo_name, scene_file", RAY_TRACED, ids=_id)
def test_the_ray_tracers_ztest_rejects_the_textures_replaced_by_their_means(algo_name, scene_file):
    ref, own, z = against_mitsuba(scene_file, algo_name, RAY_PARAMS[algo_name], "whitted",
                                  materials=_as_mean)
    print(f"\n{algo_name} {scene_file.stem} (_as_mean): {z}")
    assert not z.passed


@pytest.mark.parametrize("feature", ["textured specular transmittance", "textured conductor eta/k"])
def test_other_algorithms_refuse_them_by_name(feature):
    scene = load_scene(VOC / "textured_params_whitted.xml")
    for algo_name in ("raycast", "zbuffer", "depthsort", "radiosity"):
        algo = registry.get(algo_name)
        with pytest.raises(UnsupportedError, match=f"uses '(textured specular transmittance|textured "
                                                   f"conductor eta/k)', which {algo_name} does not model"):
            algo.render(scene, algo.parse_params({}))
        assert feature not in algo.models


@pytest.mark.parametrize("feature, why", [
    ("textured specular transmittance", "specular_transmittance as one colour; shape 'glass_panel'"),
    ("textured conductor eta/k", "Fresnel term from one eta \\+ ik; shape 'eta_panel'")])
def test_refused_with_their_reason_where_a_model_leaves_them_out(feature, why):
    """Hall's highlights (one colour, one index per surface), spectral path (RGB
    textures) and whitted's transmissive shadow rays (a constant transmittance)."""
    scene = load_scene(VOC / "textured_params_whitted.xml")
    keep = "specular_transmittance" if feature.endswith("transmittance") else "eta"
    scene = dataclasses.replace(scene, materials=[
        dataclasses.replace(m, textures={n: t for n, t in m.textures.items() if n == keep})
        for m in scene.materials])
    algo = registry.get("distributed")
    with pytest.raises(UnsupportedError, match="distributed: shading=hall: .*" + why):
        algo.render(scene, algo.parse_params({"shading": "hall", "hall_ks": 1.0}))
    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match="spectral=true does not model a"):
        algo.render(dataclasses.replace(scene, environment=None), algo.parse_params({"spp": 1, "spectral": True}))
    if keep == "specular_transmittance":
        algo = registry.get("whitted")
        with pytest.raises(UnsupportedError, match="whitted shadow_mode=transmissive: shape 'glass_panel'"):
            algo.render(scene, algo.parse_params({"shadow_mode": "transmissive"}))


def test_a_named_conductor_with_a_textured_eta_is_a_scene_error(tmp_path):
    text = (VOC / "textured_params_whitted.xml").read_text()
    text = text.replace('<rgb name="k" value="3.2, 2.6, 2.2"/>', '<string name="material" value="Au"/>')
    path = VOC / "textured_params_whitted.xml"
    out = tmp_path / path.name
    out.write_text(text)
    (tmp_path / "textures").symlink_to(VOC / "textures")
    scene = load_scene(out)
    algo = registry.get("whitted")
    with pytest.raises(SceneError, match="'material' \\('Au'\\) and a textured 'eta'"):
        algo.render(scene, algo.parse_params({}))
