"""impl.plastic against Mitsuba's own plastic / roughplastic BSDFs (eval, pdf) and
a chi-square test of each sampler against its pdf."""

from __future__ import annotations

import numpy as np
import pytest

from core.scene import Material
from impl.plastic import (plastic_eval, plastic_params, plastic_pdf, plastic_sample, roughplastic_eval,
                          roughplastic_pdf, roughplastic_sample)

CASES = [
    ("plastic", {"diffuse_reflectance": [0.8, 0.4, 0.2], "int_ior": 1.9}),
    ("plastic", {"diffuse_reflectance": [0.8, 0.4, 0.2], "nonlinear": True}),
    ("roughplastic", {"diffuse_reflectance": [0.8, 0.4, 0.2], "alpha": 0.3}),
    ("roughplastic", {"diffuse_reflectance": [0.3, 0.6, 0.9], "alpha": 0.1, "nonlinear": True,
                      "specular_reflectance": [0.5, 0.5, 0.5], "int_ior": 1.5}),
]


def _dirs(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _mi_dict(kind, params):
    d = {"type": kind}
    for k, v in params.items():
        d[k] = {"type": "rgb", "value": v} if isinstance(v, list) else v
    if kind == "roughplastic":
        d["distribution"] = "beckmann"
    return d


@pytest.mark.parametrize("kind, params", CASES)
def test_eval_pdf_match_mitsuba(mitsuba, kind, params):
    mi = mitsuba
    bsdf = mi.load_dict(_mi_dict(kind, params))
    P = plastic_params(Material(kind=kind, params=params))
    rng = np.random.default_rng(3)
    wi, wo = _dirs(rng, 200), _dirs(rng, 200)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*[wi[:, i].astype(np.float32) for i in range(3)])
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    ctx = mi.BSDFContext()
    v = mi.Vector3f(*[wo[:, i].astype(np.float32) for i in range(3)])
    ref = np.array(bsdf.eval(ctx, si, v), dtype=np.float64).reshape(3, -1).T
    ref_pdf = np.array(bsdf.pdf(ctx, si, v), dtype=np.float64)
    wi, wo = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    for k in range(len(wi)):
        if kind == "plastic":
            ours = plastic_eval(wi[k], wo[k], P.eta, P.diffuse, P.fdr_int, P.nonlinear)
            pdf = plastic_pdf(wi[k], wo[k], P.eta, P.spec_weight)
        else:
            ours = roughplastic_eval(wi[k], wo[k], P.eta, P.alpha, P.diffuse, P.specular, P.ext_t,
                                     P.int_r, P.nonlinear)
            pdf = roughplastic_pdf(wi[k], wo[k], P.alpha, P.visible, P.spec_weight, P.ext_t)
        assert ours == pytest.approx(ref[k], rel=2e-3, abs=1e-6), (k, wi[k], wo[k])
        assert pdf == pytest.approx(ref_pdf[k], rel=2e-3, abs=1e-6), (k, wi[k], wo[k])


@pytest.mark.parametrize("kind, params", CASES)
def test_sampler_matches_pdf_chi2(kind, params):
    """Histogram of sampled (cos θ, φ) against the integrated pdf (non-delta part),
    Pearson chi-square at significance 0.01 (cells with expected count < 5 pooled)."""
    from scipy.stats import chi2

    P = plastic_params(Material(kind=kind, params=params))
    wi = np.array([0.5, 0.1, np.sqrt(1 - 0.26)])
    rng = np.random.default_rng(11)
    n = 100_000
    nt, nph = 10, 20
    counts = np.zeros((nt, nph))
    u = rng.random((n, 3))
    delta = 0
    for k in range(n):
        if kind == "plastic":
            wo, pdf, w, is_delta = plastic_sample(wi, u[k, 0], u[k, 1], u[k, 2], P.eta, P.diffuse,
                                                   P.specular, P.spec_weight, P.fdr_int, P.nonlinear)
            if is_delta:
                delta += 1
                continue
        else:
            wo, pdf, w = roughplastic_sample(wi, u[k, 0], u[k, 1], u[k, 2], P.eta, P.alpha, P.visible,
                                             P.diffuse, P.specular, P.spec_weight, P.ext_t, P.int_r,
                                             P.nonlinear)
        if pdf <= 0.0:
            continue
        i = min(int(wo[2] * nt), nt - 1)
        j = min(int((np.arctan2(wo[1], wo[0]) + np.pi) / (2 * np.pi) * nph), nph - 1)
        counts[i, j] += 1
    # expected: integrate the pdf over each cell (midpoint rule on a fine grid)
    sub = 8
    expected = np.zeros((nt, nph))
    for i in range(nt):
        for j in range(nph):
            acc = 0.0
            for a in range(sub):
                for b in range(sub):
                    ct = (i + (a + 0.5) / sub) / nt
                    ph = -np.pi + 2 * np.pi * (j + (b + 0.5) / sub) / nph
                    st = np.sqrt(1 - ct * ct)
                    wo = np.array([st * np.cos(ph), st * np.sin(ph), ct])
                    acc += plastic_pdf(wi, wo, P.eta, P.spec_weight) if kind == "plastic" else \
                        roughplastic_pdf(wi, wo, P.alpha, P.visible, P.spec_weight, P.ext_t)
            expected[i, j] = acc / (sub * sub) * (1.0 / nt) * (2 * np.pi / nph) * n
    e, c = expected.ravel(), counts.ravel()
    order = np.argsort(e)
    e, c = e[order], c[order]
    small = e < 5
    e = np.concatenate([[e[small].sum()], e[~small]]) if small.any() else e
    c = np.concatenate([[c[small].sum()], c[~small]]) if small.any() else c
    stat = ((c - e) ** 2 / np.maximum(e, 1e-12)).sum()
    p = chi2.sf(stat, len(e) - 1)
    print(f"\n{kind} chi2={stat:.1f} dof={len(e) - 1} p={p:.3g} delta={delta}")
    # the expected counts include the delta lobe's share as missing mass
    assert abs(c.sum() - e.sum()) / n < 0.02
    assert p > 0.01


def test_plastic_arrays_rows_of_a_thirdparty_scene():
    """Rows of the table equal plastic_params for each plastic material of a scene
    (the diffuse texture's mean for a textured diffuse_reflectance), zeros elsewhere."""
    from pathlib import Path

    from core.loader import load_scene
    from impl.materials import plastic_arrays

    root = Path(__file__).resolve().parent.parent / "suites" / "thirdparty" / "docs" / "scenes"
    scene = load_scene(root / "bsdf_roughplastic_preserve.xml")
    A = plastic_arrays(scene)
    kinds = [m.kind for m in scene.materials]
    assert "roughplastic" in kinds
    for i, m in enumerate(scene.materials):
        if m.kind != "roughplastic":
            assert A.is_plastic[i] == 0
            continue
        P = plastic_params(m)
        assert A.is_plastic[i] == 2 and A.eta[i] == P.eta and A.int_r[i] == P.int_r
        assert np.array_equal(A.ext_t[i], P.ext_t)
        assert np.allclose(A.diffuse[i], m.reflectance)
    with pytest.raises(Exception, match="distribution 'ggx' is not modelled"):
        plastic_arrays(load_scene(root / "bsdf_roughplastic_ggx.xml"))
