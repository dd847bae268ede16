"""The thesis's 2.4.5 material models as materials of ``distributed``: Cook–Torrance with a
roughness mixture D (``gibench_cooktorrance``) and diffuse transmission
(``gibench_difftrans``), gibench-only BSDF types of the scene XML.  No Mitsuba plugin
computes them, so the reference is the white furnace: an orthographic camera looks straight
down at a large plane under a constant environment of radiance 1, so every pixel estimates
the directional albedo at normal incidence — for Cook–Torrance ∫ f cos dω by quadrature of
:func:`impl.bsdf.cook_torrance_eval`, for diffuse transmission ρ + τ in closed form (ρ
alone with a black floor under the plane)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from core.errors import SceneError, UnsupportedError
from core.loader import load_scene
from gibench import registry
from impl import bsdf, microfacet as mf

DIST = registry.get("distributed")
WHITTED = registry.get("whitted")

FURNACE = """<scene version="3.0.0">
    <sensor type="orthographic">
        <transform name="to_world"><scale value="2"/>
            <lookat origin="0, 1, 0" target="0, 0, 0" up="0, 0, -1"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
    <shape type="rectangle" id="plane">
        <transform name="to_world"><scale value="1000"/><rotate x="1" angle="-90"/></transform>
        {bsdf}
    </shape>
    {extra}
</scene>
"""
BLACK_FLOOR = """<shape type="rectangle" id="floor">
        <transform name="to_world"><scale value="1000"/><rotate x="1" angle="-90"/>
            <translate y="-1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>
    </shape>"""

RHO = (0.8, 0.5, 0.2)
KD, KS, ETA = 0.3, 0.6, 1.5
ALPHAS, WEIGHTS = (0.1, 0.4), (0.5, 0.5)


def ct_bsdf(kd=KD, ks=KS, alphas=ALPHAS, weights=WEIGHTS):
    return (f'<bsdf type="gibench_cooktorrance"><rgb name="reflectance" value="{", ".join(map(str, RHO))}"/>'
            f'<float name="kd" value="{kd}"/><float name="ks" value="{ks}"/>'
            f'<float name="int_ior" value="{ETA}"/>'
            f'<string name="alphas" value="{", ".join(map(str, alphas))}"/>'
            f'<string name="weights" value="{", ".join(map(str, weights))}"/></bsdf>')


def dt_bsdf(rho, tau):
    return (f'<bsdf type="gibench_difftrans"><rgb name="reflectance" value="{", ".join(map(str, rho))}"/>'
            f'<rgb name="transmittance" value="{", ".join(map(str, tau))}"/></bsdf>')


def scene(tmp_path, bsdf_xml, extra=""):
    p = tmp_path / "furnace.xml"
    p.write_text(FURNACE.format(bsdf=bsdf_xml, extra=extra))
    return load_scene(p)


def furnace(sc, spp=16):
    """Per channel: the mean over pixels and its standard error (pixels are independent
    estimates of one value)."""
    img = np.asarray(DIST.render(sc, DIST.parse_params({"spp": spp}), seed=3).image, np.float64)
    px = img.reshape(-1, 3)
    return px.mean(axis=0), px.std(axis=0, ddof=1) / math.sqrt(len(px))


def ct_albedo(kd=KD, ks=KS, alphas=ALPHAS, weights=WEIGHTS) -> np.ndarray:
    """∫ f cos θ_o dω at normal incidence by quadrature of cook_torrance_eval (isotropic:
    2π ∫ eval(θ) sin θ dθ), per channel."""
    a, w = mf.mixture_arrays(list(alphas), list(weights))
    out = []
    for c in range(3):
        rho = [0.0, 0.0, 0.0]
        rho[c] = RHO[c]

        def f(theta):
            return bsdf.cook_torrance_eval(kd, ks, a, w, mf.G_SMITH, ETA, *rho, 0.0, 0.0, 1.0,
                                           math.sin(theta), 0.0, math.cos(theta))[c] * math.sin(theta)
        pts = [min(alphas) * k for k in (0.5, 1, 2, 4)]
        out.append(2.0 * math.pi * quad(f, 0.0, 0.5 * math.pi, points=pts, limit=400, epsabs=1e-10)[0])
    return np.array(out)


LAMP = """<scene version="3.0.0">
    <sensor type="orthographic">
        <transform name="to_world"><scale value="0.001"/>
            <lookat origin="0, 1, 0" target="0, 0, 0" up="0, 0, -1"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle" id="lamp">
        <transform name="to_world"><rotate x="1" angle="90"/><translate y="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter>
        <bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>
    </shape>
    <shape type="rectangle" id="plane">
        <transform name="to_world"><scale value="1000"/><rotate x="1" angle="-90"/></transform>
        {bsdf}
    </shape>
</scene>
"""


def lamp_radiance(kd=KD, ks=KS, alphas=ALPHAS, weights=WEIGHTS, nodes=64, pieces=16) -> np.ndarray:
    """Radiance leaving the plane's centre straight up when only the square lamp
    [−1, 1]² at height 2 (radiance 1) lights it: ∫ f cos θ_o dω over the lamp =
    ∫∫ f cos θ_o · cos θ_e / d² dA, cos θ_e = 2/d, by a product Gauss–Legendre rule
    (``pieces`` intervals of ``nodes`` points per axis).  The orthographic view spans
    0.002 units, so every pixel sees the lamp under the same directions to ~1e-3."""
    a, w = mf.mixture_arrays(list(alphas), list(weights))
    x, wx = np.polynomial.legendre.leggauss(nodes)
    edges = np.linspace(-1.0, 1.0, pieces + 1)
    u = np.concatenate([0.5 * (e1 - e0) * x + 0.5 * (e0 + e1) for e0, e1 in zip(edges[:-1], edges[1:])])
    wu = np.concatenate([0.5 * (e1 - e0) * wx for e0, e1 in zip(edges[:-1], edges[1:])])
    total = np.zeros(3)
    for i in range(len(u)):
        for j in range(len(u)):
            d = math.sqrt(u[i] ** 2 + 4.0 + u[j] ** 2)
            f = bsdf.cook_torrance_eval(kd, ks, a, w, mf.G_SMITH, ETA, *RHO, 0.0, 0.0, 1.0,
                                        u[i] / d, u[j] / d, 2.0 / d)
            total += np.array(f) * (2.0 / d) / (d * d) * wu[i] * wu[j]
    return total


def within(mean, se, expected, z=4.0) -> bool:
    return bool(np.all(np.abs(mean - expected) <= z * se + 1e-6))


def test_cook_torrance_mixture_passes_the_furnace_and_the_check_rejects_other_models(tmp_path):
    expected = ct_albedo()
    mean, se = furnace(scene(tmp_path, ct_bsdf()))
    print("Cook-Torrance furnace", mean, "+-", se, "expected", expected)
    assert within(mean, se, expected)
    # The check has power: the albedos of the models a broken material would compute.
    # (At normal incidence the albedo hardly depends on the roughness: the mixture's
    # shape is the lamp test's.)
    for wrong in (ct_albedo(kd=0.0), expected + KD * (1.0 - np.array(RHO)), expected * 1.02):
        assert not within(mean, se, wrong)


def test_cook_torrance_mixture_under_a_lamp_matches_quadrature_and_one_lobe_does_not(tmp_path):
    """A square lamp above the plane collects the lobe within ~27° of the normal: the
    mixture's wide lobe (α = 0.4) puts part of its light outside, the narrow one (0.1)
    almost none, so the mixture and a single lobe give different radiances."""
    p = tmp_path / "lamp.xml"
    expected = lamp_radiance()
    one_lobe = lamp_radiance(alphas=(0.1,), weights=(1.0,))
    results = {}
    for name, weights in (("mixture", WEIGHTS), ("one lobe", (1.0, 0.0))):
        p.write_text(LAMP.format(bsdf=ct_bsdf(weights=weights)))
        results[name] = furnace(load_scene(p), spp=64)
    print("lamp: expected", expected, "one lobe", one_lobe, results)
    mean, se = results["mixture"]
    assert within(mean, se, expected) and not within(mean, se, one_lobe)
    # The rendered broken variant (the second lobe dropped) fails the mixture's check.
    mean, se = results["one lobe"]
    assert within(mean, se, one_lobe) and not within(mean, se, expected)


def test_diffuse_transmission_passes_the_furnace_with_and_without_a_black_floor(tmp_path):
    rho, tau = np.array([0.5, 0.3, 0.1]), np.array([0.3, 0.4, 0.2])
    mean, se = furnace(scene(tmp_path, dt_bsdf(rho, tau)))
    print("difftrans, open below", mean, "+-", se)
    assert within(mean, se, rho + tau)
    mean, se = furnace(scene(tmp_path, dt_bsdf(rho, tau), BLACK_FLOOR))
    print("difftrans, black floor", mean, "+-", se)
    assert within(mean, se, rho)
    # Negative control: transmission folded back to the viewer's side would give ρ + τ here,
    # a lobe that ignored τ would give ρ in the open furnace; both are rejected.
    assert not within(mean, se, rho + tau)
    m_open, se_open = furnace(scene(tmp_path, dt_bsdf(rho, tau)))
    assert not within(m_open, se_open, rho)


def test_bad_material_parameters_are_refused_with_their_values(tmp_path):
    with pytest.raises(SceneError, match=r"kd \+ ks <= 1.*kd=0.6 \+ ks=0.6"):
        DIST.render(scene(tmp_path, ct_bsdf(kd=0.6, ks=0.6)), DIST.parse_params({"spp": 1}))
    with pytest.raises(SceneError, match="weights must be >= 0 and sum to 1"):
        DIST.render(scene(tmp_path, ct_bsdf(weights=(0.5, 0.7))), DIST.parse_params({"spp": 1}))
    with pytest.raises(SceneError, match="reflectance \\+ transmittance <= 1"):
        DIST.render(scene(tmp_path, dt_bsdf((0.6, 0.5, 0.5), (0.6, 0.1, 0.1))), DIST.parse_params({"spp": 1}))
    with pytest.raises(UnsupportedError, match="gibench_cooktorrance"):
        WHITTED.render(scene(tmp_path, ct_bsdf()), WHITTED.parse_params({}))
