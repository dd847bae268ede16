"""Normal maps, bump maps, projectors and a spot's texture against Mitsuba 3.

* :func:`impl.textures.bitmap_grad` is the derivative of the bilinear luminance
  (finite differences), and 0 for ``nearest``;
* ``suites/vocabulary/normalmap.xml`` and ``bumpmap.xml`` (``path``),
  ``maps_direct.xml`` (``raycast``: both maps over diffuse surfaces),
  ``maps_whitted.xml`` (``whitted`` and ``distributed``: a normal-mapped mirror and
  a bump-mapped glass sheet), ``maps_distributed.xml`` (``distributed``: a
  normal-mapped rough gold wall and a bump-mapped rough glass sheet), and
  ``projector.xml`` and ``spot_texture_direct.xml`` (``path``, ``raycast``,
  ``whitted``, ``distributed``) pass the per-pixel Z-test against Mitsuba on the
  same XML, and each image's thirds agree in the mean;
* negative controls, each of which must fail the Z-test: the normal map ignored,
  the normal map with its tangent t negated (the green channel inverted), the
  panels seen from behind with the normal map's order around ``twosided``
  swapped, the bump map ignored, the bump map with its scale negated (in
  ``distributed`` too), the rough wall's normal map ignored, the projector's image
  and the spot's texture mirrored left to right, the spot's texture ignored;
* the algorithms that do not model a part refuse it by name.
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

VOCAB = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
NORMALMAP, BUMPMAP, PROJECTOR, SPOT, MAPS_DIRECT, MAPS_WHITTED, MAPS_DISTRIBUTED = (
    VOCAB / f"{n}.xml" for n in ("normalmap", "bumpmap", "projector", "spot_texture_direct", "maps_direct",
                                 "maps_whitted", "maps_distributed"))


# ------------------------------------------------------------ the gradient ---

@pytest.mark.parametrize("wrap", [0, 1, 2], ids=["repeat", "clamp", "mirror"])
def test_bitmap_grad_is_the_derivative_of_the_bilinear_luminance(wrap):
    from impl.textures import FILTER_BILINEAR, FILTER_NEAREST, bitmap, bitmap_grad, luminance

    rng = np.random.default_rng(4)
    w, h = 7, 5
    data = rng.uniform(0.0, 1.0, size=(w * h + 3, 3))
    off = 3
    m = np.array([[2.0, 0.0], [0.0, 0.5]])       # a diagonal to_uv: Mitsuba's order is the chain rule
    eps = 1e-6
    for u, v in rng.uniform(-0.3, 1.3, size=(50, 2)):
        uu, vv = m[0, 0] * u, m[1, 1] * v

        def lum(a, b):
            return luminance(*bitmap(data, off, w, h, wrap, FILTER_BILINEAR, a, b))

        fd_u = m[0, 0] * (lum(uu + m[0, 0] * eps, vv) - lum(uu - m[0, 0] * eps, vv)) / (2 * m[0, 0] * eps)
        fd_v = m[1, 1] * (lum(uu, vv + m[1, 1] * eps) - lum(uu, vv - m[1, 1] * eps)) / (2 * m[1, 1] * eps)
        gu, gv = bitmap_grad(data, off, w, h, wrap, FILTER_BILINEAR, m[0, 0], m[0, 1], m[1, 0], m[1, 1],
                             uu, vv)
        assert gu == pytest.approx(fd_u, rel=1e-4, abs=1e-5)
        assert gv == pytest.approx(fd_v, rel=1e-4, abs=1e-5)
    assert bitmap_grad(data, off, w, h, wrap, FILTER_NEAREST, 1.0, 0.0, 0.0, 1.0, 0.3, 0.6) == (0.0, 0.0)


# ------------------------------------------------------------ Z-tests ---

_TRANSPORT = {"path": "full", "raycast": "direct", "whitted": "whitted", "distributed": "whitted"}


def _render(algorithm: str, scene_path: Path, scene=None, spp: int = 256):
    from references.reference import get_reference

    algo = registry.get(algorithm)
    ref = get_reference(scene_path, transport=_TRANSPORT[algorithm], spp=1024, passes=8)
    scene = load_scene(scene_path) if scene is None else scene
    params = {"spp": spp}
    if algorithm in ("raycast", "whitted", "distributed"):
        params["light_samples"] = 1
    if algorithm == "path" and "max_depth" in scene.integrator:
        params["max_depth"] = scene.integrator["max_depth"]     # what the reference renders
    own = algo.render(scene, algo.parse_params(params), seed=0)
    return ref, own


def _z(ref, own):
    from reports.metrics import z_test

    return z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)


@pytest.mark.mitsuba
@pytest.mark.parametrize("algorithm, scene_path", [("path", NORMALMAP), ("path", BUMPMAP),
                                                   ("raycast", MAPS_DIRECT), ("whitted", MAPS_WHITTED),
                                                   ("distributed", MAPS_WHITTED),
                                                   ("distributed", MAPS_DISTRIBUTED),
                                                   ("path", PROJECTOR), ("raycast", PROJECTOR),
                                                   ("whitted", PROJECTOR), ("distributed", PROJECTOR),
                                                   ("path", SPOT), ("raycast", SPOT), ("whitted", SPOT),
                                                   ("distributed", SPOT)],
                         ids=["path-normalmap", "path-bumpmap", "raycast-maps", "whitted-maps",
                              "distributed-maps-whitted", "distributed-maps-glossy",
                              "path-projector", "raycast-projector", "whitted-projector",
                              "distributed-projector", "path-spot", "raycast-spot", "whitted-spot",
                              "distributed-spot"])
def test_scene_passes_the_ztest_against_mitsuba(algorithm, scene_path):
    """Per pixel (Z-test) and per third of the image (|z| < 4 for each third's mean):
    the own tracer agrees with Mitsuba's matching integrator on the same XML; a 3 %
    exposure error makes some third's mean fail."""
    ref, own = _render(algorithm, scene_path)
    z = _z(ref, own)
    print(f"\n{algorithm} {scene_path.name}: {z}")
    assert z.passed, z
    zt = thirds_z(ref, own.image, own.variance).astype(np.float64)
    z3 = thirds_z(ref, own.image * 1.03, own.variance).astype(np.float64)
    print(f"z of the thirds' means {np.round(zt, 2).tolist()}; with a 3 % exposure error "
          f"{np.round(z3, 1).tolist()}")
    assert np.all(np.abs(zt) < 4.0)
    assert np.abs(z3).max() > 4.0


def _with_shading(scene, change):
    """``scene`` with every material's ``shading`` passed through ``change``."""
    return dataclasses.replace(scene, materials=[
        dataclasses.replace(m, shading=change(m.shading)) if m.shading else m for m in scene.materials])


def _green_inverted(shading):
    tex = dict(shading["texture"])
    data = tex["data"].copy()
    data[:, :, 1] = 1.0 - data[:, :, 1]
    tex["data"] = data
    return {**shading, "texture": tex}


def _bump_scale_negated(shading):
    return {**shading, "scale": -shading["scale"]} if shading["type"] == "bumpmap" else shading


def _only_bumpmap(shading):
    """The normal maps dropped (on ``maps_whitted.xml``: the mirror's among them)."""
    return shading if shading["type"] == "bumpmap" else None


def _order_swapped(scene):
    """Each two-sided normal map's order around ``twosided`` swapped: the panels seen
    from behind take the other mirror."""
    return dataclasses.replace(scene, materials=[
        dataclasses.replace(m, shading={**m.shading, "wraps_twosided": not m.shading.get("wraps_twosided")})
        if m.shading and m.twosided else m for m in scene.materials])


def _mirrored_slide(scene):
    lights = []
    for light in scene.lights:
        if light.texture is not None:
            tex = {**light.texture, "data": light.texture["data"][:, ::-1].copy()}
            light = dataclasses.replace(light, texture=tex)
        lights.append(light)
    return dataclasses.replace(scene, lights=lights)


def _untextured(scene):
    return dataclasses.replace(scene, lights=[dataclasses.replace(light, texture=None)
                                              if light.kind == "spot" else light for light in scene.lights])


@pytest.mark.mitsuba
@pytest.mark.parametrize("algorithm, scene_path, wrong", [
    ("path", NORMALMAP, lambda s: _with_shading(s, lambda sh: None)),
    ("path", NORMALMAP, lambda s: _with_shading(s, _green_inverted)),
    ("path", NORMALMAP, _order_swapped),
    ("path", BUMPMAP, lambda s: _with_shading(s, lambda sh: None)),
    ("path", BUMPMAP, lambda s: _with_shading(s, lambda sh: {**sh, "scale": -sh["scale"]})),
    ("raycast", MAPS_DIRECT, lambda s: _with_shading(s, _green_inverted)),
    ("raycast", MAPS_DIRECT, _order_swapped),
    ("raycast", MAPS_DIRECT, lambda s: _with_shading(s, _bump_scale_negated)),
    ("whitted", MAPS_WHITTED, lambda s: _with_shading(s, _only_bumpmap)),
    ("whitted", MAPS_WHITTED, lambda s: _with_shading(s, _bump_scale_negated)),
    ("distributed", MAPS_DISTRIBUTED, lambda s: _with_shading(s, _only_bumpmap)),
    ("distributed", MAPS_DISTRIBUTED, lambda s: _with_shading(s, _bump_scale_negated)),
    ("path", PROJECTOR, _mirrored_slide),
    ("raycast", PROJECTOR, _mirrored_slide),
    ("raycast", SPOT, _mirrored_slide),
    ("whitted", SPOT, _untextured),
    ("distributed", PROJECTOR, _mirrored_slide),
    ("distributed", SPOT, _untextured),
], ids=["normalmap-ignored", "normalmap-tangent-negated", "normalmap-twosided-order-swapped",
        "bumpmap-ignored", "bumpmap-scale-negated", "raycast-normalmap-tangent-negated",
        "raycast-twosided-order-swapped", "raycast-bumpmap-scale-negated", "whitted-mirror-map-ignored",
        "whitted-glass-bumpmap-scale-negated", "distributed-normalmaps-ignored",
        "distributed-rough-glass-bumpmap-scale-negated",
        "path-projector-mirrored", "raycast-projector-mirrored", "raycast-spot-mirrored",
        "whitted-spot-untextured", "distributed-projector-mirrored", "distributed-spot-untextured"])
def test_the_ztest_rejects_a_wrong_rendering(algorithm, scene_path, wrong):
    """Each deliberately wrong rendering of the scene fails the Z-test."""
    ref, own = _render(algorithm, scene_path, scene=wrong(load_scene(scene_path)))
    z = _z(ref, own)
    print(f"\n{algorithm} {scene_path.name}, wrong: {z}")
    assert not z.passed, z


# ------------------------------------------------------------ refusals ---

@pytest.mark.parametrize("algorithm, scene_path, feature", [
    ("radiosity", MAPS_DIRECT, "normalmap"), ("radiosity", PROJECTOR, "projector")])
def test_algorithms_refuse_what_they_do_not_model_by_name(algorithm, scene_path, feature):
    algo = registry.get(algorithm)
    with pytest.raises(UnsupportedError, match=f"uses '{feature}', which {algorithm} does not model"):
        algo.render(load_scene(scene_path), algo.parse_params({}), seed=0)


@pytest.mark.parametrize("algorithm", ["zbuffer", "depthsort"])
@pytest.mark.parametrize("shading, where", [("flat", "once per polygon"), ("gouraud", "at the vertices")])
def test_rasterisers_refuse_maps_without_per_pixel_shading(algorithm, shading, where):
    """The rasterisers take normal and bump maps per pixel (shading=phong); flat and
    Gouraud shading, which evaluate the model elsewhere, refuse them by name."""
    algo = registry.get(algorithm)
    with pytest.raises(UnsupportedError, match=f"{algorithm}: shape '.*' uses 'normalmap', which "
                                               f"shading={shading} cannot show \\(it evaluates the model "
                                               f"{where}, not per pixel\\); use shading=phong"):
        algo.render(load_scene(MAPS_DIRECT), algo.parse_params({"shading": shading}), seed=0)


@pytest.mark.parametrize("scene_path, kind", [(PROJECTOR, "projector"), (SPOT, "spot")])
def test_halls_shading_refuses_a_lights_image_by_name(scene_path, kind):
    """distributed models a projector's image and a spot's texture at diffuse hits, but
    Hall's light-source terms at specular ones leave them out: shading=hall refuses the
    scene, naming the emitter, before anything is rendered."""
    algo = registry.get("distributed")
    with pytest.raises(UnsupportedError, match=f"shading=hall: .*{kind} emitter.* has an image") as info:
        algo.render(load_scene(scene_path), algo.parse_params({"shading": "hall"}), seed=0)
    assert "\n" not in str(info.value)


def test_spectral_path_refuses_the_projector():
    algo = registry.get("path")
    with pytest.raises(UnsupportedError, match="spectral=true does not model the projector"):
        algo.render(load_scene(PROJECTOR), algo.parse_params({"spectral": True, "spp": 1}), seed=0)


def test_map_order_around_twosided_is_recorded(tmp_path):
    """``normalmap(twosided(bsdf))`` and ``twosided(normalmap(bsdf))`` differ seen from
    behind (Mitsuba's twosided mirrors in the perturbed or in the true frame): the
    loader records which one the file wrote."""
    tex = ('<texture name="normalmap" type="bitmap"><boolean name="raw" value="true"/>'
           f'<string name="filename" value="{VOCAB / "textures" / "bumps_normal.png"}"/></texture>')
    outer = f'<bsdf type="normalmap">{tex}<bsdf type="twosided"><bsdf type="diffuse"/></bsdf></bsdf>'
    inner = f'<bsdf type="twosided"><bsdf type="normalmap">{tex}<bsdf type="diffuse"/></bsdf></bsdf>'
    found = []
    for name, bsdf in (("outer.xml", outer), ("inner.xml", inner)):
        p = tmp_path / name
        p.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                     '<integer name="width" value="8"/><integer name="height" value="6"/></film></sensor>'
                     '<shape type="rectangle">' + bsdf + '</shape></scene>')
        m = load_scene(p).materials[0]
        assert m.twosided and m.shading["type"] == "normalmap"
        found.append(m.shading.get("wraps_twosided", False))
    assert found == [True, False]


def test_a_vanishing_map_normal_leaves_the_shading_normal():
    """A normal-map texel of 0.5 (2c − 1 = 0) has no direction: the shading normal
    stays, where Mitsuba's normalisation would give NaN; a tilted texel tilts it."""
    from impl.shading_frame import perturbed_normal

    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    uvm = np.eye(3)[:2].copy()
    tex = np.array([0, 1, 1, 0, 1, 1, 1, 0], dtype=np.int64)       # 1x1, nearest, flip, shadowing
    args = (uvm, None, v, uv, 0.2, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.6, 0.8, False)
    grey = np.full((1, 3), 0.5)
    assert perturbed_normal(1, 1.0, tex, args[0], grey, *args[2:]) == (0.0, 0.0, 1.0)
    tilted = np.array([[0.5 + 0.5 * 0.6, 0.5, 0.5 + 0.5 * 0.8]])   # n = (0.6, 0, 0.8) along ∂p/∂u = +x
    n = perturbed_normal(1, 1.0, tex, args[0], tilted, *args[2:])
    assert np.allclose(n, (0.6, 0.0, 0.8))
