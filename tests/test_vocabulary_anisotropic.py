"""Anisotropic roughness and a spot's texture in the path tracer.

* ``suites/vocabulary/anisotropic.xml`` (constant ``alpha_u`` ≠ ``alpha_v``: Beckmann
  and GGX, roughconductor and roughdielectric, visible-normal sampling on and off, on a
  rectangle, an OBJ without uvs and spheres), ``anisotropic_textured.xml`` (bitmap and
  checkerboard ``alpha_u`` / ``alpha_v``) and ``spot_texture.xml`` (a spot whose beam
  is a bitmap) pass the per-pixel Z-test against Mitsuba's ``path`` (own 256 spp
  against 1024 spp × 8 passes), and the mean of each third of the image lies within 4
  standard errors of Mitsuba's.
* Negative controls fail the Z-test: the roughness along the tangent and the bitangent
  swapped (the tangent turned by 90°), the anisotropic roughness replaced by an
  isotropic one (√(α_u α_v)), the spot's texture ignored or mirrored in u.
* ``anisotropic_normalmap.xml`` (anisotropic rough conductors under a normal map, seen
  from the front and, inside and outside ``twosided``, from behind) passes in path and
  distributed: the tangent of Mitsuba's perturbed frame (the unperturbed tangent made
  orthogonal to the perturbed normal); α_u and α_v swapped fail.
* ``anisotropic_bumpmap.xml`` (the same under a bump map, on rectangles whose u runs
  along world y) passes in path: the tangent of Mitsuba 3.9.1's bump frame (the world
  ∂p/∂u's components read as frame coordinates, made orthogonal to the perturbed
  normal: here along the frame's bitangent); α_u and α_v swapped, which is what the
  normal map's tangent would give there, fail.
* The algorithms that do not model them refuse them by name (raycast and whitted
  model a spot's texture: tests/test_shading_maps.py); a lone ``alpha_u`` is refused with its
  file and line, as Mitsuba refuses it; distributed refuses anisotropic roughness
  under a bump map by name.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from _regions import against_mitsuba, assert_passes_by_pixel_and_thirds, path_against_mitsuba

from core.errors import SceneError, UnsupportedError
from core.loader import load_scene
from gibench import registry

VOCAB = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
SCENES = {name: VOCAB / f"{name}.xml"
          for name in ("anisotropic", "anisotropic_textured", "anisotropic_normalmap", "anisotropic_bumpmap",
                       "spot_texture")}


def _swap_uv(m):
    """alpha_u and alpha_v exchanged (values and textures)."""
    if m.kind not in ("roughconductor", "roughdielectric"):
        return m
    ren = {"alpha_u": "alpha_v", "alpha_v": "alpha_u"}
    return dataclasses.replace(m, params={ren.get(k, k): v for k, v in m.params.items()},
                               textures={ren.get(k, k): v for k, v in m.textures.items()})


def _isotropic(m):
    """Constant alpha_u / alpha_v replaced by one alpha = √(α_u α_v)."""
    p = m.params
    if m.kind not in ("roughconductor", "roughdielectric") or "alpha_u" not in p:
        return m
    q = {k: v for k, v in p.items() if k not in ("alpha_u", "alpha_v")}
    return dataclasses.replace(m, params={**q, "alpha": math.sqrt(p["alpha_u"] * p["alpha_v"])})


def _spot_plain(light):
    return dataclasses.replace(light, texture=None)


def _spot_mirrored(light):
    if light.texture is None:
        return light
    to_uv = np.asarray(light.texture["to_uv"], dtype=np.float64) @ np.array(
        [[-1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return dataclasses.replace(light, texture={**light.texture, "to_uv": to_uv})


#: Per scene, the mis-modellings the Z-test must reject (materials or lights changed).
WRONG = {"anisotropic": [("materials", _swap_uv), ("materials", _isotropic)],
         "anisotropic_textured": [("materials", _swap_uv)],
         "anisotropic_normalmap": [("materials", _swap_uv)],
         "anisotropic_bumpmap": [("materials", _swap_uv)],
         "spot_texture": [("lights", _spot_plain), ("lights", _spot_mirrored)]}


@pytest.mark.mitsuba
@pytest.mark.parametrize("name", list(SCENES))
def test_scene_passes_the_ztest_against_mitsuba_path(name):
    """Per pixel and per third of the image, own ``path`` agrees with Mitsuba's ``path``;
    a 3 % exposure error moves some third's mean by more than 4 standard errors."""
    assert_passes_by_pixel_and_thirds(name, *path_against_mitsuba(SCENES[name]))


@pytest.mark.mitsuba
@pytest.mark.parametrize("name,k", [(n, k) for n, changes in WRONG.items() for k in range(len(changes))])
def test_the_ztest_rejects_the_feature_mis_modelled(name, k):
    """alpha_u and alpha_v swapped, anisotropy replaced by an isotropic alpha, the spot's
    texture ignored or mirrored: the Z-test fails."""
    field, fn = WRONG[name][k]
    _, _, z = path_against_mitsuba(SCENES[name], **{field: fn})
    print(f"\n{name} ({WRONG[name][k][1].__name__}): {z}")
    assert not z.passed


@pytest.mark.parametrize("name, feature, others", [
    ("anisotropic", "anisotropic roughness", ("raycast", "whitted", "zbuffer", "radiosity")),
    ("anisotropic_textured", "anisotropic roughness", ("raycast", "whitted", "zbuffer", "radiosity")),
    ("spot_texture", "spot texture", ("zbuffer", "radiosity"))])
def test_other_algorithms_refuse_them_by_name(name, feature, others):
    scene = load_scene(SCENES[name])
    for algo_name in others:
        algo = registry.get(algo_name)
        with pytest.raises(UnsupportedError, match=f"uses '{feature}', which {algo_name} does not model"):
            algo.render(scene, algo.parse_params({}))


#: Distributed ray tracing on the two anisotropic files, against Mitsuba's matched
#: ``whitted`` (glossy lobes followed by ``bsdf.sample``; the point light and the sky
#: reach the rough surfaces only along their sampled rays in both).
DISTRIBUTED_PARAMS = {"spp": 256, "light_samples": 16}


@pytest.mark.mitsuba
@pytest.mark.parametrize("name", ["anisotropic", "anisotropic_textured", "anisotropic_normalmap"])
def test_distributed_anisotropic_roughness_passes_the_ztest_against_mitsuba_whitted(name):
    """distributed samples a rough conductor's and a rough dielectric's direction with
    (α_u, α_v) in Mitsuba's shading frame (the tangent along ∂p/∂u), constant or read from
    a texture at the hit, and agrees with Mitsuba per pixel and per third of the image."""
    assert_passes_by_pixel_and_thirds(f"{name} (distributed)", *against_mitsuba(
        SCENES[name], "distributed", DISTRIBUTED_PARAMS, "whitted"))


@pytest.mark.mitsuba
@pytest.mark.parametrize("name,k", [("anisotropic", 0), ("anisotropic", 1), ("anisotropic_textured", 0),
                                    ("anisotropic_normalmap", 0)])
def test_distributed_ztest_rejects_the_anisotropy_mis_modelled(name, k):
    """The tangent turned by 90° (α_u and α_v swapped) or the anisotropy replaced by an
    isotropic α: distributed's image fails the Z-test."""
    field, fn = WRONG[name][k]
    _, _, z = against_mitsuba(SCENES[name], "distributed", DISTRIBUTED_PARAMS, "whitted", **{field: fn})
    print(f"\n{name} (distributed, {fn.__name__}): {z}")
    assert not z.passed


def test_distributed_refuses_anisotropic_roughness_on_moving_shapes(tmp_path):
    """A moving shape's shading frame at the sample's time is not modelled: refused by name."""
    text = SCENES["anisotropic"].read_text()
    p = tmp_path / "s.xml"
    gold = '<shape type="sphere" id="gold">'
    assert text.count(gold) == 1
    p.write_text(text.replace("meshes/quad_box.obj", str(VOCAB / "meshes" / "quad_box.obj"))
                 .replace(gold, gold + '<vector name="gibench_velocity" value="0.1, 0, 0"/>'))
    algo = registry.get("distributed")
    with pytest.raises(UnsupportedError, match="anisotropic roughness on a moving"):
        algo.render(load_scene(p), algo.parse_params({"spp": 1}))


def test_a_lone_alpha_u_is_refused_with_file_and_line(tmp_path):
    p = tmp_path / "s.xml"
    text = SCENES["anisotropic"].read_text().replace('<float name="alpha_v" value="0.35"/>', "")
    p.write_text(text.replace("meshes/quad_box.obj", str(VOCAB / "meshes" / "quad_box.obj")))
    line = next(i for i, s in enumerate(text.splitlines(), 1) if 'value="0.04"' in s) - 1
    with pytest.raises(SceneError, match=f"s.xml:{line}: .*'alpha_u' needs its partner"):
        load_scene(p)


def test_spectral_path_refuses_the_spot_texture():
    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match="spot's texture"):
        scene = dataclasses.replace(load_scene(SCENES["spot_texture"]), environment=None)
        algo.render(scene, algo.parse_params({"spp": 1, "spectral": True}))


def test_distributed_refuses_anisotropic_roughness_under_a_bump_map_by_name(tmp_path):
    """Mitsuba 3.9.1's bumpmap builds its frame's tangent from ∂p/∂u and a normal in
    local coordinates, which path reproduces (``anisotropic_bumpmap.xml`` above) and
    distributed does not: distributed refuses it with the material named, path renders."""
    text = (VOCAB / "bumpmap.xml").read_text()
    start = text.index('<bsdf type="roughplastic">')
    old = text[start:text.index('</bsdf>', start)]
    p = tmp_path / "s.xml"
    p.write_text(text.replace(old, '<bsdf type="roughconductor"><float name="alpha_u" value="0.05"/>'
                                   '<float name="alpha_v" value="0.3"/>')
                 .replace('value="textures/', f'value="{VOCAB}/textures/'))
    algo = registry.get("distributed")
    with pytest.raises(UnsupportedError, match="distributed: material .* anisotropic roughness under a "
                                               "bumpmap is not modelled"):
        algo.render(load_scene(p), algo.parse_params({"spp": 1}))
    algo = registry.get("path")
    assert np.isfinite(algo.render(load_scene(p), algo.parse_params({"spp": 1})).image).all()


@pytest.mark.parametrize("axis, refused", [("x", True), ("z", False)])
def test_an_anisotropic_sphere_turned_off_its_z_axis_is_refused(tmp_path, axis, refused):
    """The scene model keeps no sphere rotation; the tangent runs about world z, which is
    Mitsuba's only while to_world keeps the sphere's z axis (a turn about z is fine)."""
    text = SCENES["anisotropic"].read_text()
    old = '<float name="radius" value="0.55"/>'
    assert text.count(old) == 1
    p = tmp_path / "s.xml"
    p.write_text(text.replace(old, old + f'<transform name="to_world"><rotate {axis}="1" angle="30"/></transform>')
                 .replace("meshes/quad_box.obj", str(VOCAB / "meshes" / "quad_box.obj")))
    if refused:
        with pytest.raises(SceneError, match="s.xml:.*anisotropic roughness on a sphere whose to_world turns"):
            load_scene(p)
    else:
        assert len(load_scene(p).shapes) == len(load_scene(SCENES["anisotropic"]).shapes)
