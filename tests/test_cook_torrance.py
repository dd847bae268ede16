"""Cook–Torrance diffuse + specular mixture, the roughness mixture D = Σ w_k D(m_k)
(thesis 2.4.5.2) and diffuse transmission (2.4.5.3), as scalar BSDF lobes
(impl.microfacet, impl.bsdf): normalisation, chi-square tests of every sampler
against its pdf, sampling weights = eval/pdf, furnaces, and negative controls
(the same checks reject a wrong pdf, unnormalised weights, and transmission
sent to the wrong side)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.errors import ParamError
from impl import bsdf
from impl import microfacet as mf
from test_microfacet import P_MIN, _chi2_pvalue, _dir, _hemisphere_quadrature

SEED = 20261201
N = 60_000
# Lobes no sharper than alpha = 0.2: the chi-square cells (24 in cos θ, 4×4 Gauss points
# each) integrate a sharper peak too coarsely (as in test_microfacet).
ALPHAS, WEIGHTS = mf.mixture_arrays([0.2, 0.6], [0.3, 0.7])


def _sphere_quadrature(f, n_theta=256, n_phi=128):
    """∫ f dω over the whole sphere: the hemisphere rule applied to f and to f mirrored."""
    return (_hemisphere_quadrature(f, n_theta, n_phi)
            + _hemisphere_quadrature(lambda x, y, z: f(x, y, -z), n_theta, n_phi))


def test_roughness_mixture_is_normalised_and_refuses_bad_weights():
    """∫ D cos θ_m dω = 1 for the mixture (each Beckmann lobe is, and Σ w = 1); weights that
    do not sum to 1 are refused — the negative control: with weights (0.6, 1.4) the same
    integral is 2, which the normalisation check rejects."""
    total = _hemisphere_quadrature(lambda x, y, z: mf.mixture_normal_pdf(ALPHAS, WEIGHTS, x, y, z), 384, 96)
    assert total == pytest.approx(1.0, abs=2e-3)
    bad_w = np.array([0.6, 1.4])
    bad = _hemisphere_quadrature(lambda x, y, z: mf.mixture_normal_pdf(ALPHAS, bad_w, x, y, z), 384, 96)
    assert bad != pytest.approx(1.0, abs=2e-3)
    with pytest.raises(ParamError, match="sum to 1"):
        mf.mixture_arrays([0.1, 0.5], [0.6, 1.4])
    with pytest.raises(ParamError, match="alpha must be finite and > 0"):
        mf.mixture_arrays([0.0, 0.5], [0.5, 0.5])
    # One lobe is Beckmann itself.
    one_a, one_w = mf.mixture_arrays([0.3], [1.0])
    m = np.array(_dir(0.4, 0.2))
    assert mf.mixture_d(one_a, one_w, *m) == mf.beckmann_d(0.3, *m)


def test_mixture_normal_sampling_matches_its_pdf():
    """Chi-square of m ~ Σ w_k D_k cos; negative control: the same samples against the pdf of
    the rough lobe alone (the weights ignored) are rejected."""
    rng = np.random.default_rng(SEED)
    u = rng.random((N, 3))
    out = np.array([mf.sample_mixture_normal(ALPHAS, WEIGHTS, a, b, c) for a, b, c in u])
    for r in out[:200]:
        assert r[3] == pytest.approx(mf.mixture_normal_pdf(ALPHAS, WEIGHTS, *r[:3]), rel=1e-12)
    pv = _chi2_pvalue(out[:, :3], lambda x, y, z: mf.mixture_normal_pdf(ALPHAS, WEIGHTS, x, y, z))
    assert pv > P_MIN, f"chi-square p = {pv:.2e} (seed {SEED})"
    wrong = _chi2_pvalue(out[:, :3], lambda x, y, z: mf.normal_pdf(0.6, x, y, z))
    assert wrong < 1e-6


CT = dict(kd=0.4, ks=0.6, eta=1.5)


def _ct_sample(wi, u, kd=CT["kd"], ks=CT["ks"], gmodel=mf.G_SMITH, rho=(0.8, 0.5, 0.2)):
    return np.array([bsdf.cook_torrance_sample(kd, ks, ALPHAS, WEIGHTS, gmodel, CT["eta"], *rho,
                                               *wi, a, b, c) for a, b, c in u])


@pytest.mark.parametrize("theta_i", [0.2, 1.1])
def test_cook_torrance_sample_matches_its_pdf_and_weights_are_eval_over_pdf(theta_i):
    wi = _dir(theta_i, 0.3)
    rng = np.random.default_rng(SEED)
    out = _ct_sample(wi, rng.random((N, 3)))
    ok = out[:, 6] > 0.0
    for r in out[ok][:300]:
        assert r[6] == pytest.approx(bsdf.cook_torrance_pdf(CT["kd"], CT["ks"], ALPHAS, WEIGHTS, *wi, *r[:3]),
                                     rel=1e-12)
        f = bsdf.cook_torrance_eval(CT["kd"], CT["ks"], ALPHAS, WEIGHTS, mf.G_SMITH, CT["eta"], 0.8, 0.5, 0.2,
                                    *wi, *r[:3])
        np.testing.assert_allclose(r[3:6], np.array(f) / r[6], rtol=1e-12)

    def pdf(x, y, z):
        return bsdf.cook_torrance_pdf(CT["kd"], CT["ks"], ALPHAS, WEIGHTS, *wi, x, y, z)

    pv = _chi2_pvalue(out[ok, :3], pdf, invalid=int((~ok).sum()))
    assert pv > P_MIN, f"chi-square p = {pv:.2e} (seed {SEED})"
    # Negative control: the pdf of the diffuse lobe alone (the specular choice forgotten).
    wrong = _chi2_pvalue(out[ok, :3], lambda x, y, z: max(z, 0.0) / math.pi, invalid=int((~ok).sum()))
    assert wrong < 1e-6


@pytest.mark.parametrize("gmodel", [mf.G_SMITH, mf.G_VCAVITY])
def test_cook_torrance_furnace(gmodel):
    """Energy: with ρ = 1 and k_d + k_s = 1 the albedo ∫ f cos dω is ≤ 1 at every angle,
    = k_d + k_s × (the specular lobe's albedo) (each lobe's integral by quadrature), and the
    sampling weights estimate it.  With k_d = 1 it is exactly 1 (the Lambertian furnace).
    Negative control: k_d = 1, k_s = 0.6 (the thesis's s + d = 1 broken) reflects more than
    it receives; :func:`impl.bsdf.check_cook_torrance` refuses such weights."""
    rng = np.random.default_rng(SEED + 1)
    for theta_i in (0.0, 0.7, 1.3):
        wi = _dir(theta_i, 0.1)

        def albedo(kd, ks):
            return _hemisphere_quadrature(
                lambda x, y, z: bsdf.cook_torrance_eval(kd, ks, ALPHAS, WEIGHTS, gmodel, CT["eta"], 1.0, 1.0,
                                                        1.0, *wi, x, y, z)[0], 384, 128)

        a = albedo(CT["kd"], CT["ks"])
        spec = albedo(0.0, 1.0)
        assert a == pytest.approx(CT["kd"] + CT["ks"] * spec, rel=1e-6)
        assert albedo(1.0, 0.0) == pytest.approx(1.0, abs=1e-4)
        assert a <= 1.0 and 0.0 < spec < 1.0
        w = _ct_sample(wi, rng.random((20_000, 3)), gmodel=gmodel, rho=(1.0, 1.0, 1.0))[:, 3]
        assert abs(w.mean() - a) < 4.5 * w.std() / math.sqrt(len(w)) + 1e-3, (theta_i, w.mean(), a)
        assert albedo(1.0, 0.6) > 1.0
    with pytest.raises(ParamError, match="k_d \\+ k_s <= 1"):
        bsdf.check_cook_torrance(1.0, 0.6)
    bsdf.check_cook_torrance(CT["kd"], CT["ks"])


def test_thesis_specular_term_is_cook_torrance_with_dielectric_fresnel():
    """k_d = 0, one roughness lobe, V-cavity G: the specular lobe is the thesis's
    I_sr = F/π · D_ct G / ((N·L)(N·V)) with D_ct = π D_Beckmann (2.4.5.2), times cos θ_o."""
    from impl.fresnel import fresnel_dielectric

    a, w = mf.mixture_arrays([0.35], [1.0])
    for ti, to, phi in ((0.3, 0.5, 2.0), (1.0, 0.2, 0.5), (0.7, 1.2, 3.0)):
        wi, wo = np.array(_dir(ti)), np.array(_dir(to, phi))
        h = (wi + wo) / np.linalg.norm(wi + wo)
        F = fresnel_dielectric(wi @ h, 1.5)[0]
        D = mf.cook_torrance_d(0.35, h[2])
        G = mf.vcavity_g(*wi, *wo, *h)
        thesis = F / math.pi * D * G / (wo[2] * wi[2]) / 4.0 * wo[2]   # Walter's 1/4 (test_microfacet)
        got = bsdf.cook_torrance_eval(0.0, 1.0, a, w, mf.G_VCAVITY, 1.5, 0.0, 0.0, 0.0, *wi, *wo)[0]
        assert got == pytest.approx(thesis, rel=1e-12)


RHO, TAU = (0.5, 0.3, 0.2), (0.4, 0.6, 0.1)


@pytest.mark.parametrize("theta_i", [0.4, 2.2])
def test_diffuse_transmission_sample_matches_its_pdf(theta_i):
    """From either side; the negative control puts the transmitted samples on the side of wi
    (a reflection in place of a transmission) and is rejected by the same test."""
    wi = _dir(theta_i, 0.5)
    rng = np.random.default_rng(SEED + 2)
    u = rng.random((N, 3))
    out = np.array([bsdf.diffuse_transmission_sample(*RHO, *TAU, *wi, a, b, c) for a, b, c in u])
    assert (out[:, 6] > 0).all()
    for r in out[:300]:
        assert r[6] == pytest.approx(bsdf.diffuse_transmission_pdf(*RHO, *TAU, *wi, *r[:3]), rel=1e-12)
        np.testing.assert_allclose(r[3:6], np.array(bsdf.diffuse_transmission_eval(*RHO, *TAU, *wi, *r[:3])) / r[6],
                                   rtol=1e-12)

    def pdf(x, y, z):
        return bsdf.diffuse_transmission_pdf(*RHO, *TAU, *wi, x, y, z)

    pv = _chi2_pvalue(out[:, :3], pdf, lower=-1.0, n_theta=48)
    assert pv > P_MIN, f"chi-square p = {pv:.2e} (seed {SEED})"
    folded = out[:, :3].copy()
    folded[:, 2] = np.sign(wi[2]) * np.abs(folded[:, 2])
    assert _chi2_pvalue(folded, pdf, lower=-1.0, n_theta=48) < 1e-6


def test_diffuse_transmission_furnace():
    """∫ f |cos| over the sphere = ρ + τ per channel (quadrature and sampling weights; with
    ρ + τ = 1 in every channel each sample's weight is exactly 1).  Negative control:
    transmission evaluated on the side of wi doubles the reflected light and the
    reflection/transmission split fails."""
    wi = _dir(0.6, 0.2)
    tot = [_sphere_quadrature(lambda x, y, z, c=c: bsdf.diffuse_transmission_eval(*RHO, *TAU, *wi, x, y, z)[c],
                              128, 32) for c in range(3)]
    np.testing.assert_allclose(tot, np.add(RHO, TAU), rtol=1e-6)
    up = [_hemisphere_quadrature(lambda x, y, z, c=c: bsdf.diffuse_transmission_eval(*RHO, *TAU, *wi, x, y, z)[c],
                                 128, 32) for c in range(3)]
    np.testing.assert_allclose(up, RHO, rtol=1e-6)
    rng = np.random.default_rng(SEED + 3)
    white_t = tuple(1.0 - r for r in RHO)
    w = np.array([bsdf.diffuse_transmission_sample(*RHO, *white_t, *wi, a, b, c)[3:6]
                  for a, b, c in rng.random((5000, 3))])
    w_mean = w.mean(axis=0)
    assert np.allclose(w_mean, 1.0, atol=0.03)          # a per-channel mean of ρ/p or τ/(1−p)

    def broken(x, y, z, c):
        f = bsdf.diffuse_transmission_eval(*RHO, *TAU, *wi, x, y, abs(z))[c]   # τ sent up
        return f if z > 0 else 0.0

    up_b = [_hemisphere_quadrature(lambda x, y, z, c=c: broken(x, y, z, c) + bsdf.diffuse_transmission_eval(
        *RHO, *TAU, *wi, x, y, z)[c], 128, 32) for c in range(3)]
    assert not np.allclose(up_b, RHO, rtol=1e-6)
