"""A textured ``specular_reflectance`` on conductor, roughconductor and dielectric in the
path tracer.

* ``suites/vocabulary/textured_specular.xml`` (a checkerboard on a smooth conductor, a
  bitmap on a smooth dielectric and on a GGX roughconductor) passes the per-pixel
  Z-test against Mitsuba's ``path`` (own 256 spp against 1024 spp × 8 passes), and the
  mean of each third of the image lies within 4 standard errors of Mitsuba's.
* Negative control: the textures replaced by their mean colours fail the Z-test.
* The other algorithms refuse it by name, spectral path too.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from _regions import assert_passes_by_pixel_and_thirds, path_against_mitsuba

from core.errors import UnsupportedError
from core.loader import load_scene
from core.scene import texture_mean
from gibench import registry

SCENE = Path(__file__).resolve().parent.parent / "suites" / "vocabulary" / "textured_specular.xml"


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


def test_other_algorithms_and_spectral_path_refuse_it_by_name():
    scene = load_scene(SCENE)
    feature = "textured specular reflectance"
    for algo_name in ("raycast", "whitted", "distributed", "zbuffer", "radiosity"):
        algo = registry.get(algo_name)
        with pytest.raises(UnsupportedError, match=f"uses '{feature}', which {algo_name} does not model"):
            algo.render(scene, algo.parse_params({}))
    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match="textured specular_reflectance"):
        algo.render(dataclasses.replace(scene, environment=None), algo.parse_params({"spp": 1, "spectral": True}))
