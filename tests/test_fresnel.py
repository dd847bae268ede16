"""Reflection, Snell refraction and Fresnel reflectance (impl.fresnel) against
closed forms, energy conservation and Mitsuba's own ``mi.fresnel`` /
``mi.fresnel_conductor`` over sweeps of angles."""

import cmath
import math

import numpy as np
import pytest

from impl.fresnel import (IOR_TABLE, fresnel_conductor, fresnel_dielectric, fresnel_dielectric_sp,
                          fresnel_dielectric_t_sp, lookup_ior, reflect, refract, snell_refract)

ETAS = (1.5, 1.333, 2.419, 1.0 / 1.5, 1.0002)
COS = np.linspace(-1.0, 1.0, 401)


def _angle(cos_theta):
    return math.acos(min(1.0, abs(cos_theta)))


@pytest.mark.parametrize("eta", ETAS)
def test_normal_incidence_is_the_closed_form(eta):
    """F(θ=0) = ((n − 1)/(n + 1))², the same from either side of the interface."""
    expected = ((eta - 1.0) / (eta + 1.0)) ** 2
    for cos_i in (1.0, -1.0):
        F, cos_t, _, _ = fresnel_dielectric(cos_i, eta)
        assert F == pytest.approx(expected, rel=1e-12, abs=1e-16)
        assert cos_t == -cos_i              # straight through, on the other side


@pytest.mark.parametrize("eta", ETAS[:4])
def test_brewster_angle_has_no_p_reflection(eta):
    """tan θ_B = n_t / n_i: R_p = 0 while R_s > 0 (from outside and from inside)."""
    for cos_sign, rel in ((1.0, eta), (-1.0, 1.0 / eta)):
        theta_b = math.atan(rel)
        r_s, r_p, _, _, _ = fresnel_dielectric_sp(cos_sign * math.cos(theta_b), eta)
        assert r_p == pytest.approx(0.0, abs=1e-15)
        assert r_s > 1e-3
        # R_p is a minimum there: larger just off the Brewster angle.
        for d in (-1e-3, 1e-3):
            assert fresnel_dielectric_sp(cos_sign * math.cos(theta_b + d), eta)[1] > r_p


@pytest.mark.parametrize("eta", (1.5, 1.333, 2.419))
def test_total_internal_reflection_beyond_the_critical_angle(eta):
    """From inside (cos θ_i < 0), sin θ_c = 1/n: F = 1 above θ_c, F < 1 below, no NaN at θ_c."""
    theta_c = math.asin(1.0 / eta)
    for d in (1e-9, 1e-6, 1e-3, 0.3):
        F, cos_t, _, _ = fresnel_dielectric(-math.cos(theta_c + d), eta)
        assert F == 1.0 and cos_t == 0.0
        F, cos_t, _, _ = fresnel_dielectric(-math.cos(theta_c - d), eta)
        assert 0.0 < F < 1.0 and cos_t > 0.0
    # Exactly at the critical angle: finite, F = 1 or (rounding) just below it.
    for cos_i in (-math.cos(theta_c), -math.sqrt(1.0 - 1.0 / eta ** 2)):
        F, cos_t, eta_it, eta_ti = fresnel_dielectric(cos_i, eta)
        assert np.isfinite([F, cos_t, eta_it, eta_ti]).all()
        assert 0.99 <= F <= 1.0 and 0.0 <= cos_t < 1e-6
        # A ray inside (below the outward normal +z) travelling out at that angle.
        i = np.array([math.sqrt(1.0 - cos_i ** 2), 0.0, -cos_i])
        t = snell_refract(*i, 0.0, 0.0, 1.0, eta)
        assert np.isfinite(t[:3]).all()
        assert np.linalg.norm(t[:3]) == pytest.approx(1.0, abs=1e-9)
    # From outside there is never total internal reflection (F = 1 only at grazing incidence).
    assert all(fresnel_dielectric(c, eta)[0] < 1.0 for c in np.linspace(1e-6, 1, 101))


@pytest.mark.parametrize("eta", ETAS)
def test_energy_conservation_per_polarisation(eta):
    """R_s + T_s = 1 and R_p + T_p = 1 with T from the transmission amplitudes (not 1 − R)."""
    for c in COS:
        if c == 0.0:
            continue
        r_s, r_p, cos_t, _, _ = fresnel_dielectric_sp(c, eta)
        t_s, t_p = fresnel_dielectric_t_sp(c, eta)
        if cos_t == 0.0 and eta != 1.0:           # TIR: nothing is transmitted
            assert (r_s, r_p, t_s, t_p) == (1.0, 1.0, 0.0, 0.0)
            continue
        assert r_s + t_s == pytest.approx(1.0, abs=1e-12)
        assert r_p + t_p == pytest.approx(1.0, abs=1e-12)


def test_index_matched_interface_is_invisible():
    for c in COS:
        F, cos_t, eta_it, eta_ti = fresnel_dielectric(c, 1.0)
        assert F == 0.0 and cos_t == -c and eta_it == eta_ti == 1.0


@pytest.mark.parametrize("eta", ETAS[:4])
def test_snell_law_and_reflection_directions(eta):
    """n_i sin θ_i = n_t sin θ_t, unit length, in the plane of incidence; R mirrors I."""
    rng = np.random.default_rng(7)
    print("seed 7")
    n = np.array([0.3, -0.5, 0.8])
    n /= np.linalg.norm(n)
    for _ in range(200):
        i = rng.normal(size=3)
        i /= np.linalg.norm(i)
        cos_i = -float(n @ i)
        r = np.array(reflect(*i, *n))
        assert np.linalg.norm(r) == pytest.approx(1.0, abs=1e-12)
        assert float(n @ r) == pytest.approx(cos_i, abs=1e-12)            # θ_r = θ_i
        assert np.cross(n, i) @ r == pytest.approx(0.0, abs=1e-12)       # coplanar
        t = np.array(snell_refract(*i, *n, eta)[:3])
        tir = snell_refract(*i, *n, eta)[3]
        assert np.linalg.norm(t) == pytest.approx(1.0, abs=1e-12)
        if tir:
            np.testing.assert_allclose(t, r, atol=1e-12)
            continue
        n_i, n_t = (1.0, eta) if cos_i > 0 else (eta, 1.0)
        sin_i = np.linalg.norm(np.cross(n, i))
        sin_t = np.linalg.norm(np.cross(n, t))
        assert n_i * sin_i == pytest.approx(n_t * sin_t, abs=1e-12)
        assert (n @ t) * (n @ i) > 0 or cos_i == 0       # continues to the other side
        F, cos_t, _, eta_ti = fresnel_dielectric(cos_i, eta)
        np.testing.assert_allclose(refract(*i, *n, cos_i, cos_t, eta_ti), t, atol=1e-15)


@pytest.mark.parametrize("eta, k", [(0.2, 3.0), (1.5, 0.0), (0.27, 2.78), (2.9, 3.1), (0.143, 3.983)])
def test_conductor_closed_forms(eta, k):
    """Normal incidence ((n−1)² + k²)/((n+1)² + k²); k = 0 is the dielectric; grazing → 1."""
    normal = ((eta - 1) ** 2 + k ** 2) / ((eta + 1) ** 2 + k ** 2)
    assert fresnel_conductor(1.0, eta, k) == pytest.approx(normal, rel=1e-12)
    assert fresnel_conductor(0.0, eta, k) == pytest.approx(1.0, abs=1e-12)
    if k == 0.0:
        for c in np.linspace(0.01, 1.0, 50):
            assert fresnel_conductor(c, eta, 0.0) == pytest.approx(fresnel_dielectric(c, eta)[0], rel=1e-10)


def test_ideal_mirror_shortcut_is_the_formulas_value():
    """Mitsuba's material="none" (0 + 1i) returns 1 without the arithmetic; the formula
    itself gives exactly 1 there at every angle (the compiled function's Python source,
    run without the shortcut), so the shortcut changes no bit."""
    import inspect
    import textwrap

    import impl.fresnel as fresnel_module
    src = textwrap.dedent(inspect.getsource(fresnel_conductor.py_func))
    src = src[src.index("def "):].replace("if eta == 0.0 and k == 1.0:", "if False:")
    ns = dict(vars(fresnel_module))
    exec(src, ns)
    formula = ns["fresnel_conductor"]
    for c in np.concatenate([np.linspace(-1.0, 1.0, 2001), [1e-300, 1e-20, -1e-20]]):
        assert fresnel_conductor(c, 0.0, 1.0) == 1.0 == formula(c, 0.0, 1.0), c


def _conductor_complex(c, eta, k):
    """The complex amplitudes of the module's docstring, in Python's complex arithmetic."""
    c = min(abs(c), 1.0)
    n2 = complex(eta, k) ** 2
    w = cmath.sqrt(n2 - (1.0 - c * c))
    if c + w == 0.0 or n2 * c + w == 0.0:
        return 1.0
    return 0.5 * (abs((c - w) / (c + w)) ** 2 + abs((n2 * c - w) / (n2 * c + w)) ** 2)


@pytest.mark.parametrize("eta", [0.0, 1e-8, 0.05, 0.27, 1.0, 1.0001, 1.5, 2.9, 1e3])
def test_conductor_real_form_equals_the_complex_amplitudes(eta):
    """The real-arithmetic reflectance equals |r_s|² and |r_p|² of the complex
    amplitudes to rounding, over cos θ_i ∈ [−1, 1] and k from 0 to 10³ — including a
    tiny eta under a large k, where a = sqrt((a² + b² + t)/2) cancels to 0 (an error of
    2e-8 at eta = 1e-8, k = 1) unless it is taken as |eta k| / b."""
    for k in (0.0, 1e-9, 1e-6, 0.1, 1.0, 3.1, 1e3):
        for c in np.linspace(-1.0, 1.0, 401):
            ref = _conductor_complex(float(c), eta, k)
            got = fresnel_conductor(float(c), eta, k)
            assert got == pytest.approx(ref, rel=1e-12, abs=1e-15), (eta, k, c)


def test_conductor_material_none_is_a_perfect_mirror():
    """Mitsuba's material="none" is eta = 0, k = 1: R = 1 at every angle."""
    for c in np.linspace(0.0, 1.0, 101):
        assert fresnel_conductor(c, 0.0, 1.0) == pytest.approx(1.0, abs=1e-14)


def test_named_iors():
    assert lookup_ior("BK7") == 1.5046 and lookup_ior("air") == 1.000277 and lookup_ior(1.33) == 1.33
    with pytest.raises(ValueError, match="unknown index of refraction name 'unobtainium'.*bk7"):
        lookup_ior("unobtainium")
    with pytest.raises(ValueError, match="must be positive"):
        lookup_ior(-1.0)


# ------------------------------------------------------------ against Mitsuba ---

@pytest.mark.mitsuba
@pytest.mark.parametrize("eta", ETAS[:4])
def test_dielectric_fresnel_matches_mitsuba(eta, mitsuba):
    """(F, cos θ_t, η_it, η_ti) equal Mitsuba's mi.fresnel over cos θ_i ∈ [−1, 1].

    Mitsuba computes in float32; an interface with eta ≈ 1 (not swept here)
    has its critical angle where F changes so fast that float32 rounding of
    cos θ_i alone moves F by 1e-2.
    """
    import drjit as dr

    mi = mitsuba
    ours = np.array([fresnel_dielectric(c, eta) for c in COS])
    if dr.is_jit_v(mi.Float):
        theirs = np.stack([np.array(x, dtype=np.float64).reshape(-1) * np.ones(len(COS))
                           for x in mi.fresnel(mi.Float(COS), mi.Float(eta))], axis=1)
    else:
        theirs = np.array([[float(x) for x in mi.fresnel(float(c), eta)] for c in COS])
    np.testing.assert_allclose(ours, theirs, atol=2e-5, rtol=1e-5)


@pytest.mark.mitsuba
@pytest.mark.parametrize("eta, k", [(0.2, 3.0), (1.5, 0.0), (0.0, 1.0), (0.27, 2.78), (2.9, 3.1)])
def test_conductor_fresnel_matches_mitsuba(eta, k, mitsuba):
    import drjit as dr

    mi = mitsuba
    cos = np.linspace(0.0, 1.0, 201)
    ours = np.array([fresnel_conductor(c, eta, k) for c in cos])
    complex_t = getattr(dr, mi.variant().split("_")[0]).ad.Complex2f if dr.is_jit_v(mi.Float) \
        else dr.scalar.Complex2f
    if dr.is_jit_v(mi.Float):
        theirs = np.array(mi.fresnel_conductor(mi.Float(cos), complex_t(mi.Float(eta), mi.Float(k))))
    else:
        theirs = np.array([mi.fresnel_conductor(float(c), complex_t(eta, k)) for c in cos])
    np.testing.assert_allclose(ours, theirs, atol=2e-6)


@pytest.mark.mitsuba
def test_ior_table_matches_mitsubas_named_iors(mitsuba):
    """Every name of IOR_TABLE gives Mitsuba's dielectric the same eta (relative to vacuum)."""
    mi = mitsuba
    for name, value in IOR_TABLE.items():
        bsdf = mi.load_dict({"type": "dielectric", "int_ior": name, "ext_ior": "vacuum"})
        eta = mi.traverse(bsdf)["eta"]
        assert float(eta) == pytest.approx(value, rel=1e-6), name
