"""Transmissive shadows of whitted (thesis 2.2: shadow rays pass transparent objects,
attenuated by their transmittance; ``shadow_mode=transmissive``): the closed form of a
shadow ray through the centre of a glass sphere, and the model error of both shadow
modes against full transport (Mitsuba ``path``) on a glass sphere over a floor."""

from pathlib import Path

import numpy as np
import pytest

from core.errors import ParamError
from core.loader import load_scene
from gibench import registry
from impl.whitted import trace

SUITES = Path(__file__).resolve().parent.parent / "suites"
GLASS_SHADOW = SUITES / "thesis" / "glass_shadow.xml"
WHITTED = registry.get("whitted")

#: A point light straight above a glass sphere (index $ior) above a diffuse floor.
AXIS_SCENE = """<scene version="3.0.0">
    <default name="ior" value="1.5"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="3, 0.5, 0" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <emitter type="point">
        <point name="position" value="0, 5, 0"/>
        <rgb name="intensity" value="25, 25, 25"/>
    </emitter>
    <shape type="sphere">
        <point name="center" value="0, 1.2, 0"/>
        <float name="radius" value="0.7"/>
        <bsdf type="dielectric"><float name="int_ior" value="$ior"/><float name="ext_ior" value="1"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
    </shape>
</scene>
"""


def _floor_radiance(tmp_path, mode, ior="1.5"):
    """whitted's radiance of the floor point under the sphere's centre, seen along a ray
    that misses the sphere (from (3, 0.5, 0))."""
    p = tmp_path / "axis.xml"
    p.write_text(AXIS_SCENE)
    rgb, counters = trace(load_scene(p, defines={"ior": ior}), [3.0, 0.5, 0.0], [-3.0, -0.5, 0.0],
                          {"shadow_mode": mode, "light_samples": 0})
    assert counters["diffuse_hits"] == 1 and counters["shadow_rays"] == 1
    return rgb


def test_a_shadow_ray_through_the_centre_of_a_glass_sphere_keeps_two_fresnel_transmittances(tmp_path):
    """At normal incidence both interfaces transmit 1 − F0, F0 = ((n − 1)/(n + 1))² (0.04 for
    n = 1.5): the floor under the sphere gets ρ/π · I/d² · (1 − F0)², d = 5, ρ = 0.5, I = 25.
    Opaque shadows give 0 there; the check rejects the variants a wrong filter would give
    (one interface: (1 − F0); the η² radiance scaling kept: (1 − F0)² η² or η⁻²)."""
    unshadowed = 0.5 / np.pi * 25.0 / 25.0
    for n in (1.5, 2.0):
        f0 = ((n - 1.0) / (n + 1.0)) ** 2
        expected = unshadowed * (1.0 - f0) ** 2
        got = _floor_radiance(tmp_path, "transmissive", ior=str(n))
        assert np.allclose(got, expected, rtol=1e-9, atol=0.0), (n, got, expected)
        for wrong in (unshadowed * (1.0 - f0), expected * n * n, expected / (n * n), unshadowed):
            assert not np.allclose(got, wrong, rtol=1e-3, atol=0.0)
    assert np.all(_floor_radiance(tmp_path, "opaque") == 0.0)
    # Index-matched glass (n = 1) is invisible to shadow rays: the full unshadowed light.
    assert np.allclose(_floor_radiance(tmp_path, "transmissive", ior="1.0"), unshadowed, rtol=1e-9)


def test_shadow_mode_is_checked_and_opaque_by_default():
    assert WHITTED.parse_params({})["shadow_mode"] == "opaque"
    with pytest.raises(ParamError, match="shadow_mode"):
        WHITTED.parse_params({"shadow_mode": "glass"})


def shadow_region_errors(ref: np.ndarray, opaque: np.ndarray, transmissive: np.ndarray) -> dict:
    """Per mode, on the pixels the glass shadows (black with opaque shadows, lit with
    transmissive ones): the mean radiance over the reference's (energy ratio), the mean
    absolute error; over the whole image the relMSE."""
    from reports.metrics import relmse

    mask = (opaque.mean(-1) == 0.0) & (transmissive.mean(-1) > 0.0)
    out = {"pixels": int(mask.sum())}
    for name, img in (("opaque", opaque), ("transmissive", transmissive)):
        out[name] = {"energy_ratio": float(img[mask].mean() / ref[mask].mean()),
                     "mae_shadow": float(np.abs(img - ref)[mask].mean()),
                     "relmse": float(relmse(img, ref))}
    return out


#: The shadow region's energy must be within this factor of full transport's.
ENERGY_BAND = (0.4, 1.6)


@pytest.mark.mitsuba
def test_transmissive_shadows_carry_the_light_through_the_glass_that_opaque_ones_lose():
    """Model error against full transport (Mitsuba path, 1024 spp): in the glass's shadow
    the transmissive mode keeps a share of path's light within ENERGY_BAND (measured 0.57:
    the straight segment does not focus the light into the caustic), the opaque mode (the
    negative control) keeps none; over the image the transmissive relMSE is below the
    opaque one."""
    from references.reference import get_reference

    scene = load_scene(GLASS_SHADOW)
    ref = np.asarray(get_reference(GLASS_SHADOW, transport="full", spp=1024, passes=8).image, np.float64)
    imgs = {m: np.asarray(WHITTED.render(scene, WHITTED.parse_params({"spp": 16, "shadow_mode": m}),
                                         seed=0).image, np.float64)
            for m in ("opaque", "transmissive")}
    e = shadow_region_errors(ref, imgs["opaque"], imgs["transmissive"])
    print(e)
    assert e["pixels"] > 100
    assert ENERGY_BAND[0] < e["transmissive"]["energy_ratio"] < ENERGY_BAND[1]
    assert not ENERGY_BAND[0] < e["opaque"]["energy_ratio"] < ENERGY_BAND[1]
    assert e["transmissive"]["relmse"] < e["opaque"]["relmse"]
