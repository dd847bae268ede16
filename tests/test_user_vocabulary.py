"""More of the Mitsuba 3 vocabulary users' scene files bring.

* Loading: ``mask``, ``blendbsdf`` and ``thindielectric`` are read into the scene
  model (:attr:`core.scene.Material.opacity`, ``components``, the kind) and
  refused by name by every algorithm but ``path`` (which models them:
  ``tests/test_vocabulary_wrappers.py``), as a feature it does not model.
* Named conductors (``material="Au"``): the stored RGB table equals what the
  installed Mitsuba gives, and ``suites/vocabulary/named_conductors.xml`` passes
  the Z-test against Mitsuba's ``path``.
* GGX (``distribution="ggx"``) on roughconductor, roughdielectric and
  roughplastic in the path tracer: D normalised, D / G1 / visible-normal samples
  equal Mitsuba's, and ``suites/vocabulary/ggx.xml`` passes the Z-test against
  Mitsuba's ``path``.
* A ``thinlens`` sensor in the path tracer: ``suites/vocabulary/thinlens.xml``
  passes the Z-test against Mitsuba's ``path``.
* A plastic's textured ``diffuse_reflectance``: ``suites/vocabulary/textured_plastic.xml``
  passes the Z-test against Mitsuba's ``path``, and the same scene with the
  textures replaced by their means is rejected.
* A plastic's textured ``specular_reflectance`` (the coat only):
  ``suites/vocabulary/textured_plastic_specular.xml`` passes the Z-test against
  Mitsuba's ``path``; the textures replaced by their means are rejected; the
  lobe weight is Mitsuba's.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from _regions import thirds_z

from core.errors import GibenchError, SceneError, UnsupportedError
from core.loader import load_scene
from core.scene import scene_features
from gibench import registry

VOCAB = Path(__file__).resolve().parent.parent / "suites" / "vocabulary"
CONDUCTORS = VOCAB / "named_conductors.xml"
TEXTURED_PLASTIC = VOCAB / "textured_plastic.xml"
TEXTURED_COAT = VOCAB / "textured_plastic_specular.xml"
#: A thinlens sensor (aperture 0.12, focused at 5.5) over spheres at three depths.
DOF = VOCAB / "thinlens.xml"
GGX_SCENE = VOCAB / "ggx.xml"

_SCENE = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="40"/>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
    </sensor>
    <emitter type="point"><point name="position" value="0, 0, -1"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><translate z="4"/></transform>
        {bsdf}
    </shape>
</scene>
"""


def _write(tmp_path, bsdf: str, name: str = "s.xml") -> Path:
    p = tmp_path / name
    p.write_text(_SCENE.format(bsdf=bsdf))
    return p


# ------------------------------------------------------------------ loading ---

def test_mask_loads_with_its_opacity_and_is_refused_by_name_except_by_path(tmp_path):
    p = _write(tmp_path, '<bsdf type="mask"><float name="opacity" value="0.3"/>'
                         '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" '
                         'value="0.2, 0.4, 0.6"/></bsdf></bsdf></bsdf>')
    scene = load_scene(p)
    m = scene.materials[scene.shapes[0].material]
    assert (m.kind, m.twosided, m.opacity) == ("diffuse", True, {"type": "constant", "value": 0.3})
    assert m.reflectance == pytest.approx((0.2, 0.4, 0.6))
    assert "mask" in scene_features(scene)
    for name in ("raycast", "whitted", "distributed", "zbuffer", "radiosity"):
        algo = registry.get(name)
        with pytest.raises(UnsupportedError, match=f"{name}: shape 'rectangle' uses 'mask', which {name} "
                                                   "does not model"):
            algo.render(scene, algo.parse_params({}))
    default = load_scene(_write(tmp_path, '<bsdf type="mask"><bsdf type="diffuse"/></bsdf>', "d.xml"))
    assert default.materials[0].opacity == {"type": "constant", "value": 0.5}     # Mitsuba's default


def test_blendbsdf_and_thindielectric_load_and_are_refused_by_name_except_by_path(tmp_path):
    scene = load_scene(_write(tmp_path, '<bsdf type="blendbsdf"><float name="weight" value="0.25"/>'
                                        '<bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf>'
                                        '<bsdf type="conductor"/></bsdf>'))
    m = scene.materials[0]
    assert m.kind == "blendbsdf" and [c.kind for c in m.components] == ["diffuse", "conductor"]
    assert m.params["weight"] == 0.25 and m.reflectance == pytest.approx((0.6, 0.6, 0.6))
    thin = load_scene(_write(tmp_path, '<bsdf type="thindielectric"><string name="int_ior" '
                                       'value="water"/></bsdf>', "t.xml"))
    assert thin.materials[0].kind == "thindielectric"
    for sc, feature in ((scene, "blendbsdf"), (thin, "thindielectric")):
        assert feature in scene_features(sc)
        with pytest.raises(UnsupportedError, match=f"uses '{feature}', which whitted does not model"):
            registry.get("whitted").render(sc, registry.get("whitted").parse_params({}))


@pytest.mark.parametrize("bsdf, why", [
    ('<bsdf type="mask"><float name="opacity" value="1.5"/><bsdf type="diffuse"/></bsdf>',
     "'opacity' must be in [0, 1]"),
    ('<bsdf type="mask"><float name="opacity" value="0.5"/></bsdf>',
     "mask needs exactly one nested bsdf"),
    ('<bsdf type="twosided"><bsdf type="mask"><bsdf type="diffuse"/></bsdf></bsdf>',
     "a mask bsdf must be the outermost bsdf"),
    ('<bsdf type="blendbsdf"><bsdf type="diffuse"/></bsdf>',
     "blendbsdf needs exactly two nested bsdfs, got 1"),
    ('<bsdf type="thindielectric"><float name="alpha" value="0.1"/></bsdf>',
     "unsupported property 'alpha' of bsdf 'thindielectric'"),
])
def test_malformed_wrappers_are_one_line_errors(tmp_path, bsdf, why):
    with pytest.raises(SceneError) as exc:
        load_scene(_write(tmp_path, bsdf))
    msg = str(exc.value)
    assert "\n" not in msg and why in msg, msg
    assert re.match(r"^\S+\.xml:\d+: <\w+( type=\"[^\"]*\")?>: .+", msg), msg


# ------------------------------------------------------- named conductors ---

def test_named_conductor_rows_and_unknown_names(tmp_path):
    from impl.materials import material_arrays, named_conductor

    eta, k = named_conductor("Au")
    assert eta.shape == k.shape == (3,) and eta[0] < eta[2] and k[0] > k[2]   # gold: red reflects
    scene = load_scene(CONDUCTORS)
    B = material_arrays(scene, algorithm="path", kinds=("diffuse", "conductor", "roughconductor"))
    by_name = {s.name: s.material for s in scene.shapes}
    assert np.array_equal(B.cond_eta[by_name["gold"]], eta)
    assert np.array_equal(B.cond_k[by_name["rough_copper"]], named_conductor("Cu")[1])
    with pytest.raises(SceneError, match="unknown conductor material 'gold'"):
        named_conductor("gold")
    bad = _write(tmp_path, '<bsdf type="conductor"><string name="material" value="Au"/>'
                           '<rgb name="k" value="2"/></bsdf>')
    with pytest.raises(GibenchError, match="both 'material' \\('Au'\\) and 'k'"):
        registry.get("path").render(load_scene(bad), registry.get("path").parse_params({"spp": 1}))


@pytest.mark.mitsuba
def test_named_conductor_table_is_mitsubas():
    """Every stored row equals what the installed Mitsuba's RGB conductor gives."""
    import json

    from impl.materials import CONDUCTOR_TABLE
    from references.conductor_table import conductor_names, mitsuba_rgb_ior
    from references.mitsuba_env import load_mitsuba

    mi = load_mitsuba()
    table = json.loads(CONDUCTOR_TABLE.read_text())
    assert sorted(table["materials"]) == conductor_names(mi)
    for name, row in table["materials"].items():
        eta, k = mitsuba_rgb_ior(mi, name)
        assert np.allclose(row["eta"], eta, rtol=1e-6, atol=1e-9), name
        assert np.allclose(row["k"], k, rtol=1e-6, atol=1e-9), name


# ---------------------------------------------------------------------- GGX ---

@pytest.mark.parametrize("alpha", [0.05, 0.3, 0.8])
def test_ggx_d_is_normalised_and_g1_is_its_smith_term(alpha):
    """∫ D(m) cos θ_m dω = 1, and the visible-normal density ∫ D_wi(m) dω = 1 (which
    holds only with the distribution's own Smith G1), by quadrature."""
    from scipy.integrate import dblquad

    import impl.microfacet as mf

    def d_cos(t, p):
        m = (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))
        return mf.ggx_d(alpha, *m) * m[2] * math.sin(t)

    def visible(t, p, wi):
        m = (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))
        return mf.visible_normal_pdf(alpha, *wi, *m, False, mf.GGX) * math.sin(t)

    pts = min(0.999, 4 * alpha)
    val = sum(dblquad(d_cos, 0, 2 * math.pi, a, b, epsabs=1e-7)[0]
              for a, b in ((0, math.atan(pts)), (math.atan(pts), math.pi / 2)))
    assert val == pytest.approx(1.0, abs=2e-3)
    wi = (math.sin(1.0), 0.0, math.cos(1.0))
    val = sum(dblquad(lambda t, p: visible(t, p, wi), 0, 2 * math.pi, a, b, epsabs=1e-7)[0]
              for a, b in ((0, math.atan(pts)), (math.atan(pts), math.pi / 2)))
    assert val == pytest.approx(1.0, abs=2e-3)


@pytest.mark.mitsuba
def test_ggx_matches_mitsuba(mitsuba):
    """D, G1 and the visible-normal samples and pdf of GGX equal Mitsuba's
    ``MicrofacetDistribution(GGX)`` (float32 rounding aside)."""
    import impl.microfacet as mf

    mi = mitsuba
    rng = np.random.default_rng(3)
    for alpha in (0.05, 0.3, 0.8):
        dist = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
        th = rng.uniform(0.0, 1.5, 256)
        ph = rng.uniform(0.0, 2 * math.pi, 256)
        wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
        u = rng.uniform(0.0, 1.0, (2, 256))
        m, pdf = dist.sample(mi.Vector3f(*wi), mi.Point2f(*u))
        m = np.array([np.array(m.x), np.array(m.y), np.array(m.z)])
        ours = np.array([mf.sample_visible_normal(alpha, *wi[:, k], *u[:, k], mf.GGX) for k in range(256)])
        assert np.median(np.abs(ours[:, :3] - m.T)) < 1e-5
        assert np.max(np.abs(ours[:, :3] - m.T)) < 2e-3
        assert np.allclose(ours[:, 3], np.array(pdf), rtol=2e-3)
        d = np.array(dist.eval(mi.Vector3f(*m)))
        g1 = np.array(dist.smith_g1(mi.Vector3f(*wi), mi.Vector3f(*m)))
        ours_d = np.array([mf.ggx_d(alpha, *m[:, k]) for k in range(256)])
        ours_g = np.array([mf.smith_g1(alpha, *wi[:, k], *m[:, k], mf.GGX) for k in range(256)])
        assert np.allclose(ours_d, d, rtol=1e-4, atol=1e-6)
        assert np.allclose(ours_g, g1, rtol=1e-4, atol=1e-6)


# ------------------------------------------------------------ Z-tests ---

def _ztest(scene_path: Path, *, spp: int = 256, image=None, seed: int = 0):
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get("path")
    ref = get_reference(scene_path, transport="full", spp=1024, passes=8)
    own = algo.render(load_scene(scene_path), algo.parse_params({"spp": spp}), seed=seed)
    z = z_test(ref.image, own.image if image is None else image(own.image),
               reference_variance=ref.variance, test_variance=own.variance)
    return ref, own, z


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene_path", [CONDUCTORS, TEXTURED_PLASTIC, TEXTURED_COAT, GGX_SCENE, DOF],
                         ids=lambda p: p.stem)
def test_scene_passes_the_ztest_against_mitsuba_path(scene_path):
    """Per pixel (Z-test) and per third of the image (the mean of each third, |z| < 4):
    own ``path`` agrees with Mitsuba's ``path`` on the same XML; a 3 % exposure error
    makes some third's mean fail (|z| > 4)."""
    ref, own, z = _ztest(scene_path)
    print(f"\n{scene_path.name}: {z}")
    assert z.passed, z
    zt = thirds_z(ref, own.image, own.variance).astype(np.float64)
    z3 = thirds_z(ref, own.image * 1.03, own.variance).astype(np.float64)
    print(f"z of the thirds' means {np.round(zt, 2).tolist()}; with a 3 % exposure error "
          f"{np.round(z3, 1).tolist()}")
    assert np.all(np.abs(zt) < 4.0)
    assert np.abs(z3).max() > 4.0


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene_path", [TEXTURED_PLASTIC, TEXTURED_COAT], ids=lambda p: p.stem)
def test_the_ztest_sees_the_plastic_textures_replaced_by_their_means(scene_path):
    """The textured plastics rendered with each texture replaced by its mean colour
    (what an algorithm ignoring the texture would draw) fail the Z-test."""
    from references.reference import get_reference
    from reports.metrics import z_test
    import dataclasses

    from core.scene import texture_mean

    algo = registry.get("path")
    ref = get_reference(scene_path, transport="full", spp=1024, passes=8)
    scene = load_scene(scene_path)
    def as_means(m):     # a diffuse texture's mean is the material's reflectance already
        params = dict(m.params)
        params.update({name: [float(v) for v in texture_mean(tex)] for name, tex in m.textures.items()
                       if name != "diffuse_reflectance"})
        return dataclasses.replace(m, textures={}, params=params)

    flat = dataclasses.replace(scene, materials=[as_means(m) for m in scene.materials])
    own = algo.render(flat, algo.parse_params({"spp": 256}), seed=0)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    print(f"\n{scene_path.name}, textures as means: {z}")
    assert not z.passed


def test_a_plastic_specular_texture_is_named_and_refused_by_the_tracers_without_plastics():
    """A plastic's textured ``specular_reflectance`` is the feature "textured specular
    reflectance" (not an unmodelled "textured parameter"); the tracers that do not
    model plastics refuse the scene by the plastic's name."""
    scene = load_scene(TEXTURED_COAT)
    features = scene_features(scene)
    assert "textured parameter" not in features
    assert features["textured specular reflectance"].startswith("shape 'ground'")
    for name in ("raycast", "whitted", "distributed"):
        algo = registry.get(name)
        with pytest.raises(UnsupportedError, match=f"{name}: shape '(ground|wall)' uses 'plastic|{name}: "
                                                   f"shape '(ground|wall)' uses 'roughplastic"):
            algo.render(scene, algo.parse_params({}))


@pytest.mark.mitsuba
def test_the_plastic_lobe_weights_of_textured_reflectances_are_mitsubas(mitsuba):
    """The specular lobe's sampling weight s̄ / (d̄ + s̄) of plastics whose reflectances
    are textures equals the ``specular_sampling_weight`` Mitsuba prints for the same
    BSDFs (``Texture::mean``: a bitmap's mean luminance, a checkerboard's mean of its
    colours' channel means)."""
    from impl.materials import plastic_arrays
    from references.reference import load_scene as mitsuba_load, prepare_scene_xml

    for path in (TEXTURED_PLASTIC, TEXTURED_COAT):
        scene = load_scene(path)
        ours = plastic_arrays(scene, distributions=("beckmann", "ggx"))
        xml, _, _ = prepare_scene_xml(path, transport="full", spp_per_pass=1)
        theirs = {}
        for shape in mitsuba_load(mitsuba, path, xml).shapes():
            text = str(shape.bsdf())
            m = re.search(r"specular_sampling_weight = \[?([0-9.eE+-]+)", text)
            if m:
                theirs[shape.id()] = float(m.group(1))
        assert set(theirs) == {"ground", "wall"}
        for shape in scene.shapes:
            if shape.name in theirs:
                assert ours.spec_weight[shape.material] == pytest.approx(theirs[shape.name], rel=1e-5), \
                    (path.name, shape.name)


@pytest.mark.mitsuba
def test_reference_overrides_a_sensor_declared_in_an_included_file(mitsuba):
    """A documentation scene whose sensor and integrator sit in an included file: the
    reference's overrides reach them (in the expanded scene) and Mitsuba loads it,
    its textures and meshes found through the file's <path>."""
    from references.reference import load_scene as mitsuba_load, prepare_scene_xml

    path = VOCAB.parent / "thirdparty" / "docs" / "scenes" / "bsdf_plastic_preserve.xml"
    xml, integrator, overrides = prepare_scene_xml(path, transport="full", spp_per_pass=3)
    assert integrator == {"type": "path", "max_depth": -1}
    assert overrides["sensor[0]"]["sampler"]["to"]["sample_count"] == 3
    assert overrides["sensor[0]"]["rfilter"]["to"] == {"type": "box"}
    scene = mitsuba_load(mitsuba, path, xml)
    assert scene.sensors()[0].sampler().sample_count() == 3
    assert len(scene.shapes()) == len(load_scene(path).shapes)
