"""Whitted ray tracing (impl.whitted): invariants of the ray tree, closed-form
total internal reflection, and agreement with the matched Mitsuba reference
``whitted`` (references/whitted_integrator.py) by a per-pixel Z-test."""

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from impl.raycast import cast_primary
from impl.whitted import trace
from _analytic import fresnel_inside

ROOT = Path(__file__).resolve().parent.parent
SUITES = ROOT / "suites"
WHITTED = registry.get("whitted")
RAYCAST = registry.get("raycast")
WHITTED_SCENES = ["spheres/mirror_sphere.xml", "spheres/glass_sphere.xml", "spheres/nested_glass.xml",
                  "spheres/whitted_classic.xml", "spheres/sphere_grid.xml",
                  "cornell/cornell_mirror_glass.xml", "spheres/mirror_env.xml"]


def render(path, seed=0, algo=WHITTED, **params):
    return algo.render(load_scene(path), algo.parse_params(params), seed=seed)


def variant(tmp_path, scene, name, *replacements):
    """A copy of a suite scene with text replacements (each must apply)."""
    text = (SUITES / scene).read_text()
    for old, new in replacements:
        assert old in text, f"{old!r} not in {scene}"
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text)
    return p


def remove_shape(text, shape_id):
    out, n = re.subn(rf'\s*<shape type="\w+" id="{shape_id}">.*?</shape>', "", text, flags=re.S)
    assert n == 1, shape_id
    return out


# ------------------------------------------------------------- registration ---

def test_registered_with_parameter_table():
    assert WHITTED.section.startswith("thesis 2.2, 2.2.1, 2.4.4, 2.4.5.5")
    names = [p.name for p in WHITTED.params]
    for name in ("spp", "max_depth", "hall_threshold", "light_samples", "ks", "c3", "shadows",
                 "intersect", "precision", "offset", "epsilon"):
        assert name in names
    table = WHITTED.param_table()
    assert "hall_threshold" in table and "max_depth" in table
    import impl.whitted as mod
    assert "Whitted" in mod.__doc__ and "1980" in mod.__doc__ and "Hall" in mod.__doc__


def test_invalid_parameters_are_refused():
    scene = SUITES / "spheres" / "mirror_sphere.xml"
    with pytest.raises(ValueError, match="square"):
        render(scene, spp=8)
    with pytest.raises(ValueError, match="max_depth must be >= 1"):
        render(scene, max_depth=0)
    with pytest.raises(ValueError, match="hall_threshold must be >= 0"):
        render(scene, hall_threshold=-1.0)
    with pytest.raises(registry.ParamError, match="unknown parameter 'depth'.*max_depth"):
        WHITTED.parse_params({"depth": 3})


def test_unmodelled_materials_are_refused_naming_shape_and_material(tmp_path):
    cases = [
        ('<bsdf type="conductor">\n            <string name="material" value="none"/>\n        </bsdf>',
         '<bsdf type="roughconductor"/>', NotImplementedError,
         "shape 'mirror' has a 'roughconductor' BSDF"),
        ('<string name="material" value="none"/>', '<string name="material" value="Gold"/>',
         ValueError, "shape 'mirror': unknown conductor material 'Gold'"),
        ('<string name="material" value="none"/>',
         '<string name="material" value="Cu"/><rgb name="eta" value="0.2, 0.9, 1.1"/>',
         ValueError, "both 'material'"),
    ]
    for i, (old, new, exc, msg) in enumerate(cases):
        p = variant(tmp_path, "spheres/mirror_sphere.xml", f"m{i}.xml", (old, new))
        with pytest.raises(exc, match=re.escape(msg)):
            render(p)
    p = variant(tmp_path, "spheres/glass_sphere.xml", "ior.xml",
                ('<float name="int_ior" value="1.5"/>', '<string name="int_ior" value="crown glass"/>'))
    with pytest.raises(ValueError, match="shape 'glass': int_ior: unknown index of refraction name "
                                         "'crown glass'.*bk7"):
        render(p)
    p = variant(tmp_path, "spheres/glass_sphere.xml", "twosided.xml",
                ('<bsdf type="dielectric">', '<bsdf type="twosided"><bsdf type="dielectric">'),
                ('</bsdf>\n    </shape>\n\n    <shape type="sphere" id="behind">',
                 '</bsdf></bsdf>\n    </shape>\n\n    <shape type="sphere" id="behind">'))
    with pytest.raises(NotImplementedError, match="shape 'glass': a two-sided dielectric"):
        render(p)


# --------------------------------------------------------------- invariants ---

@pytest.mark.parametrize("scene, params", [
    ("spheres/lit_sphere.xml", {"spp": 4}),
    ("spheres/spot_directional.xml", {"spp": 1}),
    ("cornell/cornell_box.xml", {"spp": 4, "light_samples": 4}),
])
def test_diffuse_only_scene_renders_identically_to_raycast(scene, params):
    """Without delta surfaces the ray tree is the eye ray alone: whitted == raycast, bit for bit."""
    a = render(SUITES / scene, seed=5, **params)
    b = render(SUITES / scene, seed=5, algo=RAYCAST, **params)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.counters["shadow_rays"] == b.counters["shadow_rays"]
    assert a.counters["reflection_rays"] == a.counters["transmission_rays"] == 0


def test_checkerboard_scene_without_its_glass_renders_identically_to_raycast(tmp_path):
    text = remove_shape((SUITES / "spheres" / "glass_sphere.xml").read_text(), "glass")
    p = tmp_path / "checker.xml"
    p.write_text(text)
    a, b = render(p, spp=4), render(p, spp=4, algo=RAYCAST)
    np.testing.assert_array_equal(a.image, b.image)
    # Both colours of the checkerboard (albedo 0.8 and 0.1) appear on the ground.
    bottom = a.image[-10:, :, 0]
    assert bottom.max() > 4 * np.percentile(bottom, 5) > 0


def test_index_matched_glass_vanishes(tmp_path):
    """A dielectric with int_ior = ext_ior reflects nothing and bends nothing: with shadow
    rays off (glass would still block them) the image equals the scene without it."""
    glass = variant(tmp_path, "spheres/glass_sphere.xml", "ior1.xml",
                    ('<float name="int_ior" value="1.5"/>', '<float name="int_ior" value="1.0"/>'))
    empty = tmp_path / "empty.xml"
    empty.write_text(remove_shape(glass.read_text(), "glass"))
    a = render(glass, shadows=False)
    b = render(empty, shadows=False)
    assert a.counters["transmission_rays"] > 1000 and a.counters["reflection_rays"] == 0
    np.testing.assert_allclose(a.image, b.image, rtol=1e-6, atol=1e-7)


def test_half_reflectance_mirror_halves_reflected_radiance(tmp_path):
    """specular_reflectance 0.5 halves every pixel seen in the mirror and nothing else."""
    half = variant(tmp_path, "spheres/mirror_sphere.xml", "half.xml",
                   ('<string name="material" value="none"/>',
                    '<string name="material" value="none"/>\n'
                    '            <float name="specular_reflectance" value="0.5"/>'))
    full = render(SUITES / "spheres" / "mirror_sphere.xml")
    halved = render(half)
    _, shape_id = cast_primary(load_scene(half))
    mirror = shape_id == [s.name for s in load_scene(half).shapes].index("mirror")
    assert mirror.sum() > 1000 and full.image[mirror].max() > 1.0     # the area light's image
    np.testing.assert_allclose(halved.image[mirror], 0.5 * full.image[mirror], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(halved.image[~mirror], full.image[~mirror])


def _radiance_bound(scene):
    """Largest radiance any ray can carry in a scene of diffuse planes lit by point lights:
    max ρ/π · I / d² over the planes (d: light–plane distance), times η² inside glass."""
    bound = 0.0
    for shape in scene.shapes:
        m = scene.materials[shape.material]
        if m.kind != "diffuse":
            continue
        v = shape.vertices
        n = np.cross(v[1] - v[0], v[2] - v[0])
        n /= np.linalg.norm(n)
        rho = max(max(m.texture["color0"]), max(m.texture["color1"])) if m.texture else max(m.reflectance)
        for light in scene.lights:
            assert light.kind == "point"
            d = abs(n @ (light.position - v[0]))
            bound = max(bound, rho / np.pi * max(light.radiant) / d ** 2)
    eta = max(float(m.params.get("int_ior", 1.0)) for m in scene.materials if m.kind == "dielectric")
    return bound * eta ** 2


def test_hall_threshold_cuts_branches_within_its_bound():
    """Hall's criterion: a positive threshold cuts branches (counted) and changes each pixel
    by at most (summed weight of the cut branches) × (largest radiance a ray can carry)."""
    path = SUITES / "spheres" / "nested_glass.xml"
    exact = render(path, hall_threshold=0.0)
    cut = render(path, hall_threshold=1e-3)
    assert exact.counters["hall_cuts"] == 0 and cut.counters["hall_cuts"] > 1000
    rays = ("reflection_rays", "transmission_rays")
    assert sum(cut.counters[k] for k in rays) < sum(exact.counters[k] for k in rays)
    diff = exact.image.astype(np.float64) - cut.image
    assert diff.max() > 0.0                                  # it changes the image ...
    assert diff.min() >= -1e-7                               # ... only by removing light ...
    bound = cut.aovs["hall_cut_weight"][..., None] * _radiance_bound(load_scene(path))
    assert np.all(diff <= bound + 1e-7)                      # ... and no more than the bound


def test_max_depth_one_is_ray_casting_and_deeper_trees_only_add_light():
    path = SUITES / "spheres" / "mirror_sphere.xml"
    deep = render(path)
    flat = render(path, max_depth=1)
    _, shape_id = cast_primary(load_scene(path))
    mirror = shape_id == [s.name for s in load_scene(path).shapes].index("mirror")
    assert np.all(flat.image[mirror] == 0.0)                 # a mirror needs a second ray
    np.testing.assert_array_equal(flat.image[~mirror], deep.image[~mirror])
    assert flat.counters["reflection_rays"] == 0 and flat.counters["depth_cuts"] == mirror.sum()
    # Point light only: more depth adds non-negative branch contributions.
    path = SUITES / "spheres" / "nested_glass.xml"
    prev = None
    for d in range(1, 7):
        r = render(path, max_depth=d, hall_threshold=0.0)
        hist = r.counters["tree_depth_histogram"]
        assert len(hist) == d + 1 and sum(hist) == r.counters["eye_rays"] and hist[d] > 0
        if prev is not None:
            assert np.all(r.image >= prev - 1e-7)
            assert r.image.sum() > prev.sum()
        prev = r.image


# --------------------------------------------------- total internal reflection ---

TIR_SCENE = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="40"/>
        <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film>
    </sensor>
    {glass}
    <shape type="rectangle" id="sky">
        <transform name="to_world"><scale value="100"/><rotate x="1" angle="{rot}"/>
            <translate {where}/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    </shape>
</scene>"""
GLASS = '<bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1"/></bsdf>'
SLAB = (f'<shape type="cube" id="slab"><transform name="to_world"><scale x="30" y="0.2" z="30"/>'
        f'</transform>{GLASS}</shape>')
SPHERE = f'<shape type="sphere" id="ball"><float name="radius" value="1"/>{GLASS}</shape>'


@pytest.mark.parametrize("shape", ["slab", "sphere"])
def test_total_internal_reflection_around_the_critical_angle(shape, tmp_path):
    """A ray inside glass meets the surface at θ: below θ_c it leaves with radiance
    L_e (1 − F) η² (radiance scaling); above θ_c it is totally reflected (radiance 0
    with max_depth 2); at θ_c exactly nothing is NaN."""
    if shape == "slab":
        text = TIR_SCENE.format(glass=SLAB, rot=90, where='y="3"')   # emitter above, facing down
    else:
        text = TIR_SCENE.format(glass=SPHERE, rot=0, where='z="3"').replace(
            '<rotate x="1" angle="0"/>', '<rotate y="1" angle="180"/>')  # in front (+z), facing -z
    p = tmp_path / f"{shape}.xml"
    p.write_text(text)
    scene = load_scene(p)
    theta_c = math.asin(1 / 1.5)

    def ray(theta):
        if shape == "slab":                      # from the slab's centre towards its top face
            return [0, 0, 0], [math.sin(theta), math.cos(theta), 0]
        b = math.sin(theta)                      # impact parameter b = R sin θ
        return [0, b, -0.5], [0, 0, 1]

    # (Just below θ_c the ray leaves almost tangentially and flies past the emitter.)
    for d in (1e-3, 1e-2, 0.2):
        rgb, c = trace(scene, *ray(theta_c - d), {"max_depth": 2, "hall_threshold": 0.0})
        expected = 2.25 * (1 - fresnel_inside(theta_c - d))
        np.testing.assert_allclose(rgb, expected, rtol=1e-9)
        assert c["tir"] == 0 and c["transmission_rays"] == 1 and c["reflection_rays"] == 1
    for d in (1e-12, 1e-9, 1e-6):
        rgb, c = trace(scene, *ray(theta_c + d), {"max_depth": 1, "hall_threshold": 0.0})
        assert np.all(rgb == 0.0) and c["tir"] == 1 and c["depth_cuts"] == 1
    # Further bounces: each hit point carries rounding error and the ray leaves it offset
    # (robust: 256 ulps), which moves the next incidence angle by ~1e-14, so those are
    # checked well away from θ_c.
    for d in (1e-4, 1e-3, 0.2):
        rgb, c = trace(scene, *ray(theta_c + d), {"max_depth": 2, "hall_threshold": 0.0})
        # Both hits (the eye ray's and its reflection's) are total internal reflections.
        assert np.all(rgb == 0.0) and c["tir"] == 2 and c["transmission_rays"] == 0
        # Deeper: each bounce in a slab or a sphere meets the surface at the same angle.
        rgb, c = trace(scene, *ray(theta_c + d), {"max_depth": 6, "hall_threshold": 0.0})
        assert c["tir"] == 6 and c["transmission_rays"] == 0 and c["depth_cuts"] == 1
    for theta in (theta_c, math.asin(1 / 1.5 * (1 - 1e-16))):
        rgb, c = trace(scene, *ray(theta), {"max_depth": 4, "hall_threshold": 0.0})
        assert np.all(np.isfinite(rgb)) and np.all(rgb >= 0.0)


def test_ior_mismatches_are_counted(tmp_path):
    """The inner sphere's ext_ior must be the outer glass's int_ior; a wrong one is counted."""
    good = render(SUITES / "spheres" / "nested_glass.xml")
    assert good.counters["ior_mismatches"] == 0
    bad = variant(tmp_path, "spheres/nested_glass.xml", "bad.xml",
                  ('<float name="ext_ior" value="1.5"/>', '<float name="ext_ior" value="1.0"/>'))
    assert render(bad).counters["ior_mismatches"] > 100


@pytest.mark.parametrize("scene", WHITTED_SCENES + ["spheres/lit_sphere.xml", "spheres/meshes.xml"])
def test_no_nan_or_inf_and_consistent_counters(scene):
    r = render(SUITES / scene, spp=4, light_samples=4)
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0.0)
    assert np.all(np.isfinite(r.variance)) and np.all(r.variance >= 0.0)
    H, W = r.image.shape[:2]
    c = r.counters
    assert c["eye_rays"] == W * H * 4 == sum(c["tree_depth_histogram"])
    assert np.all(np.isfinite(r.aovs["hall_cut_weight"]))


# ------------------------------------------------ against the Mitsuba reference ---

def _reference(path):
    from references.reference import get_reference

    return get_reference(path, transport="whitted", spp=1024, passes=8)


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", WHITTED_SCENES)
def test_ztest_passes_against_mitsuba_whitted(scene):
    """Own whitted (6×6 strata, default parameters) vs the matched Mitsuba reference.

    At 4×4 strata two scenes fall just short (0.9970 and 0.9972 of the entries
    consistent, 0.9975 needed): where a mirror's or a glass's silhouette
    crosses a pixel, a sliver of it can reflect something bright that none
    of the 16 samples hits, so their sample variance is 0 and the Z-test
    trusts them too much.  36 samples resolve the slivers.
    """
    from reports.metrics import z_test

    ref = _reference(SUITES / scene)
    own = render(SUITES / scene, spp=36)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    print(f"{scene}: {z}")
    assert z.passed, f"{scene}: {z}"
    z_bad = z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                   test_variance=own.variance)
    assert not z_bad.passed, f"{scene}: a 3% exposure error went unnoticed: {z_bad}"


@pytest.mark.mitsuba
def test_reference_transport_overrides(tmp_path):
    from references.reference import (TRANSPORTS, WHITTED_LOBE_CHOICE, WHITTED_MAX_DEPTH,
                                      prepare_scene_xml, reference_key)

    path = SUITES / "spheres" / "glass_sphere.xml"
    assert "whitted" in TRANSPORTS
    xml, used, overrides = prepare_scene_xml(path, transport="whitted", spp_per_pass=4)
    assert used["type"] == "whitted" and used["max_depth"] == WHITTED_MAX_DEPTH
    assert used["lobe_choice"] == WHITTED_LOBE_CHOICE and len(used["source_sha256"]) == 64
    assert '<integrator type="whitted">' in xml and overrides["integrator"]["from"]["type"] == "path"
    assert WHITTED.parse_params({})["max_depth"] == WHITTED_MAX_DEPTH
    keys = {t: reference_key(path, transport=t) for t in TRANSPORTS}
    assert len(set(keys.values())) == len(TRANSPORTS)


@pytest.mark.mitsuba
def test_reference_lobe_choices_agree(mitsuba):
    """Uniform lobe choice and Mitsuba's Fresnel-proportional bsdf.sample estimate the
    same image (their means over the glass agree to a fraction of a percent)."""
    from references.reference import load_scene as mi_load, prepare_scene_xml

    path = SUITES / "spheres" / "glass_sphere.xml"
    means = {}
    for choice in ("uniform", "fresnel"):
        xml, _, _ = prepare_scene_xml(path, transport="whitted", spp_per_pass=256, seed=3)
        xml = xml.replace('name="lobe_choice" value="uniform"', f'name="lobe_choice" value="{choice}"')
        img = np.array(mitsuba.render(mi_load(mitsuba, path, xml), spp=256, seed=3))[..., :3]
        means[choice] = img[20:100, 40:120].mean()
    assert means["uniform"] == pytest.approx(means["fresnel"], rel=5e-3)


@pytest.mark.mitsuba
def test_reference_integrator_runs_in_scalar_rgb(tmp_path):
    """The Python integrator also runs in scalar_rgb (tiny film; a child process picks the variant)."""
    small = tmp_path / "small.xml"
    small.write_text((SUITES / "spheres" / "glass_sphere.xml").read_text()
                     .replace('value="160"', 'value="24"').replace('value="120"', 'value="18"'))
    code = f"""
import numpy as np
from references.mitsuba_env import load_mitsuba
from references.reference import load_scene, prepare_scene_xml
mi = load_mitsuba()
assert mi.variant() == "scalar_rgb", mi.variant()
xml, _, _ = prepare_scene_xml({str(small)!r}, transport="whitted", spp_per_pass=16)
img = np.array(mi.render(load_scene(mi, {str(small)!r}, xml), spp=16))[..., :3]
assert np.isfinite(img).all()
print("MEAN", float(img.mean()))
"""
    import os

    env = dict(os.environ, GIBENCH_MITSUBA_VARIANT="scalar_rgb")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    mean = float(out.stdout.split("MEAN")[1])
    own = render(small, spp=16).image.mean()
    assert mean == pytest.approx(own, rel=0.05)


# ------------------------------------- ray configuration: form, precision, offset ---
# Issue 3: `intersect`, `precision`, `offset`, `epsilon` (impl.rays).  Numbers in
# the comments were measured at spp = 1 when these tests were written.

@pytest.mark.parametrize("name, value", [
    ("intersect", "algebraic"), ("intersect", "geometric"), ("intersect", "stable"),
    ("precision", "float32"), ("precision", "float64"),
    ("offset", "epsilon"), ("offset", "normal"), ("offset", "robust"),
])
def test_every_ray_configuration_value_renders_finite(name, value):
    r = render(SUITES / "spheres" / "nested_glass.xml", **{name: value})
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0.0)
    assert r.counters["transmission_rays"] > 1000


def test_ray_configuration_parameters_are_documented_and_checked():
    names = [p.name for p in WHITTED.params]
    for name in ("intersect", "precision", "offset", "epsilon"):
        assert name in names and name in RAYCAST.parse_params({})
    p = WHITTED.parse_params({})
    assert (p["intersect"], p["precision"], p["offset"]) == ("stable", "float64", "robust")
    with pytest.raises(registry.ParamError, match="algebraic, geometric, stable"):
        WHITTED.parse_params({"intersect": "quadratic"})
    with pytest.raises(ValueError, match="epsilon"):
        render(SUITES / "spheres" / "lit_sphere.xml", offset="epsilon", epsilon=-1.0)
    import impl.whitted as mod
    for word in ("intersect", "precision", "float64", "Wächter", "2.3.4"):
        assert word in mod.__doc__


def _rel_diff(a, b):
    """Per-pixel largest channel difference relative to the pixel's largest channel."""
    return np.abs(a - b).max(-1) / np.maximum(np.maximum(a.max(-1), b.max(-1)), 1e-3)


def test_forms_and_precisions_agree_on_a_suite_scene():
    """On whitted_classic (spheres of radius ~1 a few units from the eye) the three
    ray-sphere forms give the same image in float64 (measured: max relative
    difference 0) and nearly the same in float32 (measured: 0.10 % of the pixels
    differ by more than 1e-3, 0.005 % by more than 1e-2: silhouettes and shadow
    edges moved by float32 rounding)."""
    path = SUITES / "spheres" / "whitted_classic.xml"
    ref = render(path).image
    for form in ("algebraic", "geometric", "stable"):
        d64 = _rel_diff(render(path, intersect=form).image, ref)
        assert d64.max() < 1e-6, form
        d32 = _rel_diff(render(path, intersect=form, precision="float32").image, ref)
        assert (d32 > 1e-3).mean() < 0.005 and (d32 > 1e-2).mean() < 0.001, form
        assert (d32 > 0).any()                  # float32 really is used


LIT = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="{x}, {y1}, {z5}" target="{x}, {y08}, {z}" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="48"/>
      <rfilter type="box"/></film></sensor>
  <emitter type="point"><point name="position" x="{x3}" y="{y5}" z="{z3}"/><rgb name="intensity" value="40"/></emitter>
  <shape type="sphere"><point name="center" x="{x}" y="{y1}" z="{z}"/><float name="radius" value="1"/>
    <bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/>
    <translate x="{x}" y="{y}" z="{z}"/></transform><bsdf type="diffuse"/></shape>
</scene>"""


def _lit_scene(tmp_path, T):
    """A unit diffuse sphere on a ground square, a point light; everything moved by (T, T, T)."""
    p = tmp_path / f"lit_{T:g}.xml"
    p.write_text(LIT.format(x=T, y=T, z=T, y1=T + 1, z5=T + 5, y08=T + 0.8, x3=T + 3, y5=T + 5,
                            z3=T + 3))
    return p


def test_shadow_acne_with_zero_epsilon_and_not_with_robust_offset(tmp_path):
    """offset=epsilon with epsilon=0 lets shadow rays find their own surface again
    (thesis fig. 2.9): measured 176 of 3072 pixels darker than half the robust
    render's in float64, 324 in float32.  The robust offset has no acne: it
    equals a render with a 1e-4 normal offset (this scene has no contact closer
    than that) in both precisions."""
    scene = _lit_scene(tmp_path, 0.0)
    robust = render(scene).image
    for prec, at_least in (("float64", 100), ("float32", 200)):
        acne = render(scene, offset="epsilon", epsilon=0.0, precision=prec).image
        darker = acne.sum(-1) < 0.5 * robust.sum(-1)
        print(prec, "acne pixels", int(darker.sum()), "of", darker.size)
        assert darker.sum() >= at_least and np.all(acne <= robust + 1e-6)
        clean = render(scene, offset="normal", epsilon=1e-4, precision=prec).image
        assert (_rel_diff(render(scene, precision=prec).image, clean) > 1e-3).sum() == 0


def test_far_from_the_origin(tmp_path):
    """The lit scene moved by 1e5 along every axis: float64 renders it as at the origin
    (a float64 ulp of 1e5 is 1.5e-11); float32 (ulp 0.0078) moves hit points by ~1e-2
    and changes many pixels (measured 894 of 3072 by more than 1e-3), yet nothing
    is lost and nothing is NaN; epsilon = 0 gives acne there too."""
    near = render(_lit_scene(tmp_path, 0.0)).image
    far_path = _lit_scene(tmp_path, 1e5)
    far = render(far_path).image
    assert (_rel_diff(far, near) > 1e-3).mean() < 0.002
    far32 = render(far_path, precision="float32").image
    assert np.isfinite(far32).all() and (_rel_diff(far32, near) > 1e-3).mean() > 0.1
    # Translation alone does not make the algebraic form lose the sphere: o − c stays small.
    np.testing.assert_array_equal(render(far_path, precision="float32", intersect="algebraic").image
                                  > 0, far32 > 0)
    acne = render(far_path, precision="float32", offset="epsilon", epsilon=0.0).image
    assert (acne.sum(-1) < 0.5 * near.sum(-1)).sum() > 200


DISTANT = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="{fov}"/><float name="far_clip" value="1e9"/>
    <transform name="to_world"><lookat origin="{t}, {t}, {t}" target="{t}, {t}, {tz}" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
      <rfilter type="box"/></film></sensor>
  <emitter type="directional"><vector name="direction" value="0, 0, 1"/><rgb name="irradiance" value="1"/></emitter>
  <shape type="sphere"><point name="center" x="{t}" y="{t}" z="{tz}"/><float name="radius" value="1"/>
    <bsdf type="diffuse"/></shape>
</scene>"""


@pytest.mark.parametrize("T", [0.0, 1e5])
def test_distant_sphere_algebraic_float32_loses_it_stable_keeps_it(tmp_path, T):
    """A unit sphere 1e4 away (|o − c|/r = 1e4 > 1/√u₃₂ ≈ 4e3, thesis 2.3.3), scene at
    the origin or moved by 1e5: in float32 the algebraic discriminant is rounding
    noise (measured: 0 of 1024 pixels hit), the geometric one hits everywhere
    (D² = L² − t_ca² cancels to ≤ 0: 1024 of 1024), the stable form keeps the
    silhouette of float64 (360 pixels)."""
    p = tmp_path / "distant.xml"
    p.write_text(DISTANT.format(t=T, tz=T + 1e4, fov=2 * math.degrees(math.atan(1.5e-4))))
    hit = {(prec, form): render(p, precision=prec, intersect=form).image.max(-1) > 0
           for prec in ("float32", "float64") for form in ("algebraic", "geometric", "stable")}
    disc = hit["float64", "stable"]
    assert 300 < disc.sum() < 420
    for form in ("algebraic", "geometric"):
        np.testing.assert_array_equal(hit["float64", form], disc)
    np.testing.assert_array_equal(hit["float32", "stable"], disc)
    assert hit["float32", "algebraic"].sum() == 0
    assert hit["float32", "geometric"].sum() == disc.size


def test_ray_exactly_at_the_critical_angle(tmp_path):
    """Inside glass at θ_c = asin(1/1.5) (and one ulp either side) nothing is NaN and the
    reflected branch carries weight 1 within rounding: the depth-cut weight of a
    max_depth 1 tree is F + (1 − F)·η²·[F < 1], which is 1 at and above θ_c."""
    p = tmp_path / "slab.xml"
    p.write_text(TIR_SCENE.format(glass=SLAB, rot=90, where='y="3"'))
    scene = load_scene(p)
    theta_c = math.asin(1 / 1.5)
    for theta in (theta_c, np.nextafter(theta_c, 2.0), np.nextafter(theta_c, 0.0)):
        d = [math.sin(theta), math.cos(theta), 0.0]
        rgb, c = trace(scene, [0, 0, 0], d, {"max_depth": 1, "hall_threshold": 0.0})
        assert np.all(np.isfinite(rgb)) and np.isfinite(c["depth_cut_weight"])
        if theta >= theta_c:
            assert c["tir"] == 1
            assert c["depth_cut_weight"] == pytest.approx(1.0, abs=1e-12)
        rgb, c = trace(scene, [0, 0, 0], d, {"max_depth": 4, "hall_threshold": 0.0})
        assert np.all(np.isfinite(rgb)) and np.all(rgb >= 0.0)
