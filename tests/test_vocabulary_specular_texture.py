"""A textured ``specular_reflectance`` on conductor, roughconductor and dielectric in the
path tracer and in Whitted and distributed ray tracing.

* ``suites/vocabulary/textured_specular.xml`` (a checkerboard on a smooth conductor, a
  bitmap on a smooth dielectric and on a GGX roughconductor) passes the per-pixel
  Z-test against Mitsuba's ``path`` (own 256 spp against 1024 spp × 8 passes), and the
  mean of each third of the image lies within 4 standard errors of Mitsuba's.
* ``textured_specular_whitted.xml`` (the right panel a smooth gold conductor) in
  ``whitted`` and ``distributed``, and ``textured_specular_glossy.xml`` (the right panel
  a Beckmann roughconductor) and ``textured_specular.xml`` itself (GGX) in
  ``distributed``, against the matched Mitsuba ``whitted``
  reference (own 64 spp for whitted, 256 for distributed, 16 light samples), per pixel
  and per third.
* Negative control: the textures replaced by their mean colours fail the Z-test.
* The other algorithms refuse it by name, spectral path and Hall's shading too.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from _regions import against_mitsuba, assert_passes_by_pixel_and_thirds, path_against_mitsuba

from core.errors import UnsupportedError
from core.loader import load_scene
from core.scene import texture_mean
from gibench import registry

VOC = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
SCENE = VOC / "textured_specular.xml"
#: (algorithm, scene) of the ray tracers' cases, against Mitsuba's whitted reference.
RAY_TRACED = [("whitted", VOC / "textured_specular_whitted.xml"),
              ("distributed", VOC / "textured_specular_whitted.xml"),
              ("distributed", VOC / "textured_specular_glossy.xml"),
              ("distributed", SCENE)]
#: Whitted's deterministic splits at 64 spp; distributed's sampled lobes at 256, where the
#: rough panel's rare bright samples (its reflection of the area light) are not too
#: few for the sample variance.
RAY_PARAMS = {"whitted": {"spp": 64, "light_samples": 16}, "distributed": {"spp": 256, "light_samples": 16}}


def _as_mean(m):
    """The specular_reflectance texture replaced by its mean colour (a constant)."""
    tex = m.textures.get("specular_reflectance")
    if tex is None:
        return m
    mean = texture_mean(tex)
    return dataclasses.replace(m, textures={}, params={**m.params, "specular_reflectance": mean.tolist()})


@pytest.mark.mitsuba
def test_scene_passes_the_ztest_against_mitsuba_path():
    """Per pixel and per third of the image, own ``path`` agrees with Mitsuba's ``path``;
    a 3 % exposure error moves some third's mean by more than 4 standard errors."""
    assert_passes_by_pixel_and_thirds("textured_specular", *path_against_mitsuba(SCENE))


@pytest.mark.mitsuba
def test_the_ztest_rejects_the_textures_replaced_by_their_means():
    ref, own, z = path_against_mitsuba(SCENE, materials=_as_mean)
    print(f"\ntextured_specular (_as_mean): {z}")
    assert not z.passed


@pytest.mark.mitsuba
@pytest.mark.parametrize("algo_name, scene_file", RAY_TRACED, ids=lambda v: getattr(v, "stem", v))
def test_ray_tracers_pass_the_ztest_against_mitsuba_whitted(algo_name, scene_file):
    """Per pixel and per third of the image, own ``whitted`` / ``distributed`` agree with
    the matched Mitsuba reference; a 3 % exposure error moves some third's mean by more
    than 4 standard errors."""
    assert_passes_by_pixel_and_thirds(f"{algo_name} {scene_file.stem}",
                                      *against_mitsuba(scene_file, algo_name, RAY_PARAMS[algo_name], "whitted"))


@pytest.mark.mitsuba
@pytest.mark.parametrize("algo_name, scene_file", RAY_TRACED, ids=lambda v: getattr(v, "stem", v))
def test_the_ray_tracers_ztest_rejects_the_textures_replaced_by_their_means(algo_name, scene_file):
    ref, own, z = against_mitsuba(scene_file, algo_name, RAY_PARAMS[algo_name], "whitted",
                                  materials=_as_mean)
    print(f"\n{algo_name} {scene_file.stem} (_as_mean): {z}")
    assert not z.passed


def test_other_algorithms_and_spectral_path_refuse_it_by_name():
    scene = load_scene(SCENE)
    feature = "textured specular reflectance"
    for algo_name in ("raycast", "zbuffer", "radiosity"):
        algo = registry.get(algo_name)
        with pytest.raises(UnsupportedError, match=f"uses '{feature}', which {algo_name} does not model"):
            algo.render(scene, algo.parse_params({}))
    algo = registry.get("distributed")
    with pytest.raises(UnsupportedError, match="shading=hall: .*specular_reflectance as one colour; "
                                               ".*textured_specular_glossy.xml is a texture"):
        algo.render(load_scene(VOC / "textured_specular_glossy.xml"),
                    algo.parse_params({"shading": "hall", "hall_ks": 1.0}))
    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match="textured specular_reflectance"):
        algo.render(dataclasses.replace(scene, environment=None), algo.parse_params({"spp": 1, "spectral": True}))
