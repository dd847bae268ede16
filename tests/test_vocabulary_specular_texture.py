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

import numpy as np
import pytest
from _regions import thirds_z

from core.errors import UnsupportedError
from core.loader import load_scene
from gibench import registry

SCENE = Path(__file__).resolve().parent.parent / "suites" / "vocabulary" / "textured_specular.xml"


def _as_mean(m):
    """The specular_reflectance texture replaced by its mean colour (a constant)."""
    tex = m.textures.get("specular_reflectance")
    if tex is None:
        return m
    mean = (np.asarray(tex["data"]).reshape(-1, 3).mean(axis=0) if tex["type"] == "bitmap"
            else 0.5 * (np.asarray(tex["color0"]) + np.asarray(tex["color1"])))
    return dataclasses.replace(m, textures={}, params={**m.params, "specular_reflectance": mean.tolist()})


def _render_and_test(change=None):
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get("path")
    ref = get_reference(SCENE, transport="full", spp=1024, passes=8)
    scene = load_scene(SCENE)
    if change is not None:
        scene = dataclasses.replace(scene, materials=[change(m) for m in scene.materials])
    own = algo.render(scene, algo.parse_params({"spp": 256}), seed=0)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    return ref, own, z


@pytest.mark.mitsuba
def test_scene_passes_the_ztest_against_mitsuba_path():
    """Per pixel and per third of the image, own ``path`` agrees with Mitsuba's ``path``;
    a 3 % exposure error moves some third's mean by more than 4 standard errors."""
    ref, own, z = _render_and_test()
    zt = thirds_z(ref, own.image, own.variance).astype(np.float64)
    z3 = thirds_z(ref, own.image * 1.03, own.variance).astype(np.float64)
    print(f"\ntextured_specular: {z}\nz of the thirds' means {np.round(zt, 2).tolist()}; with a 3 % "
          f"exposure error {np.round(z3, 1).tolist()}")
    assert z.passed, z
    assert np.all(np.abs(zt) < 4.0)
    assert np.abs(z3).max() > 4.0


@pytest.mark.mitsuba
def test_the_ztest_rejects_the_textures_replaced_by_their_means():
    ref, own, z = _render_and_test(_as_mean)
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
