"""The matched Mitsuba reference of the Phong model (thesis 1.4.2): the Python BSDF
``phong`` against the formula, the transport name, and the Z-tests of raycast, zbuffer and
depthsort with ambient, specular and f_att on — each with negative controls (one term
dropped or changed) that must fail."""

import math
from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench import registry
from references.phong_reference import parse_phong_transport, phong_transport

SUITES = Path(__file__).resolve().parent.parent / "suites"
SCENE = SUITES / "phong/phong_spheres.xml"
#: The coefficients of suites/phong.toml's first configuration.
COEFFS = dict(ka=0.3, ambient=0.2, ks=0.5, shininess=20.0, c1=0.5, c2=0.2, c3=0.05)
OWN = {"raycast": dict(spp=16), "zbuffer": dict(spp=16, tessellation=128),
       "depthsort": dict(spp=16, tessellation=128)}


def test_transport_name_round_trip_and_refusals():
    name = phong_transport(dict(COEFFS, fatt_clamp=True, spp=16))
    assert name.startswith("phong(ka=0.3,ambient=0.2,ks=0.5,shininess=20.0,")
    assert parse_phong_transport(name) == dict(COEFFS, clamp=True)
    assert parse_phong_transport("phong") == parse_phong_transport(phong_transport({}))
    for bad in ("phong(kd=1)", "phong(ks=-1)", "phong(ks=x)", "phong(c1=0,c2=0,c3=0)",
                "phong(clamp=1)", "phongx"):
        with pytest.raises(ValueError):
            parse_phong_transport(bad)


@pytest.mark.mitsuba
@pytest.mark.parametrize("ks,n", [(0.0, 20.0), (0.5, 20.0), (0.8, 3.0)])
def test_bsdf_eval_is_the_phong_bracket(mitsuba, ks, n):
    """eval = ρ/π cosθ_l + k_s (R·V)^n on a sweep of light directions; 0 below the surface."""
    mi = mitsuba
    from references.phong_reference import register
    register(mi)
    rho = 0.6
    bsdf = mi.load_dict({"type": "phong", "reflectance": {"type": "rgb", "value": [rho] * 3},
                         "ks": ks, "shininess": n})
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    wi = np.array([0.3, -0.2, 0.9])
    wi /= np.linalg.norm(wi)
    si.wi = mi.Vector3f(*(float(c) for c in wi))
    ctx = mi.BSDFContext()
    for theta in np.linspace(0.05, math.pi - 0.05, 9):
        for phi in (0.0, 1.0, 2.5):
            wo = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
            got = np.array(bsdf.eval(ctx, si, mi.Vector3f(*(float(c) for c in wo)))).ravel()[0]
            r = np.array([-wo[0], -wo[1], wo[2]])
            spec = ks * max(r @ wi, 0.0) ** n
            want = rho / math.pi * wo[2] + spec if wo[2] > 0 else 0.0
            assert got == pytest.approx(want, rel=1e-5, abs=1e-7), (theta, phi)


def _own(name, **overrides):
    algo = registry.get(name)
    return algo.render(load_scene(SCENE), algo.parse_params(dict(COEFFS, **OWN[name], **overrides)),
                       seed=0)


def _ztest(ref, res):
    from reports.metrics import z_test
    return z_test(ref.image.astype(np.float64), res.image.astype(np.float64),
                  reference_variance=ref.variance, test_variance=res.variance)


@pytest.mark.mitsuba
@pytest.mark.parametrize("name", list(OWN))
def test_phong_model_matches_mitsuba_phong_reference_and_broken_variants_fail(name):
    """Ambient, highlight and f_att on: the own render passes the Z-test against the
    ``phong(...)`` reference; dropping the highlight, the ambient term, or replacing f_att by
    1/d² each fails it (the negative controls of suites/phong.toml)."""
    from references.reference import get_reference

    ref = get_reference(SCENE, transport=phong_transport(COEFFS), spp=1024, passes=8)
    z = _ztest(ref, _own(name))
    print(f"{name}: {z}")
    assert z.passed
    for broken in (dict(ks=0.0), dict(ka=0.0), dict(c1=0.0, c2=0.0, c3=1.0), dict(shininess=10.0)):
        zb = _ztest(ref, _own(name, **broken))
        print(f"{name} {broken}: fraction {zb.fraction:.4f}")
        assert not zb.passed, broken
