"""impl.envmap: Mitsuba's envmap emitter (eval and pdf against Mitsuba's own on
random directions), the sampler against its pdf (chi-square), and a constant map
as the constant emitter."""

from __future__ import annotations

import numpy as np
import pytest

from core.imageio import write_exr
from core.scene import EnvMap
from impl.envmap import envmap_eval, envmap_pdf, envmap_sample, envmap_tables


def _rotation():
    from core import transforms as tf

    return tf.rotate(np.array([0.3, 1.0, 0.2]), 37.0)


def _map(seed=5, w=16, h=8):
    rng = np.random.default_rng(seed)
    img = rng.uniform(0.05, 2.0, size=(h, w, 3))
    img[2, 5] = [30.0, 20.0, 10.0]          # a bright texel, as a sun
    return img


def _dirs(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_eval_and_pdf_match_mitsuba(mitsuba, tmp_path):
    mi = mitsuba
    img = _map()
    path = write_exr(tmp_path / "env.exr", img.astype(np.float32))
    m = _rotation()
    env = EnvMap(data=img.astype(np.float32).astype(np.float64), scale=1.7, to_world=m)
    T = envmap_tables(env)
    emitter = mi.load_dict({"type": "envmap", "filename": str(path), "scale": 1.7,
                            "to_world": mi.ScalarTransform4f(m.tolist())})
    rng = np.random.default_rng(1)
    d = _dirs(rng, 500)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*[(-d[:, i]).astype(np.float32) for i in range(3)])
    ref = np.array(emitter.eval(si), dtype=np.float64).reshape(3, -1).T
    ours = np.array([envmap_eval(T, *di) for di in d])
    assert np.allclose(ours, ref, rtol=2e-3, atol=1e-5), np.abs(ours - ref).max()
    it = mi.Interaction3f()
    ds = mi.DirectionSample3f()
    ds.d = mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)])
    ref_pdf = np.array(emitter.pdf_direction(it, ds), dtype=np.float64)
    pdf = np.array([envmap_pdf(T, *di) for di in d])
    assert np.allclose(pdf, ref_pdf, rtol=2e-3, atol=1e-6), np.abs(pdf - ref_pdf).max()


def test_sample_matches_pdf_chi2():
    """Sampled directions binned in the map's (cos θ, φ) frame against the pdf
    integrated over each bin; Pearson chi-square at significance 0.01."""
    from scipy.stats import chi2

    m = _rotation()
    T = envmap_tables(EnvMap(data=_map(), scale=1.0, to_world=m))
    rng = np.random.default_rng(2)
    n, nt, nph = 200_000, 16, 32
    counts = np.zeros((nt, nph))
    u = rng.random((n, 2))
    for k in range(n):
        dx, dy, dz, pdf, rad = envmap_sample(T, u[k, 0], u[k, 1])
        assert pdf > 0.0
        x, y, z = np.linalg.solve(m[:3, :3], [dx, dy, dz])
        i = min(int((y + 1) / 2 * nt), nt - 1)
        j = min(int((np.arctan2(x, -z) + np.pi) / (2 * np.pi) * nph), nph - 1)
        counts[i, j] += 1
        if k < 200:     # the pdf and radiance the sampler returns are those of the direction
            assert pdf == pytest.approx(envmap_pdf(T, dx, dy, dz), rel=1e-6)
            assert np.allclose(rad, envmap_eval(T, dx, dy, dz), rtol=1e-6)
    sub = 6
    expected = np.zeros((nt, nph))
    for i in range(nt):
        for j in range(nph):
            acc = 0.0
            for a in range(sub):
                for b in range(sub):
                    y = -1 + 2 * (i + (a + 0.5) / sub) / nt
                    ph = -np.pi + 2 * np.pi * (j + (b + 0.5) / sub) / nph
                    s = np.sqrt(1 - y * y)
                    local = np.array([np.sin(ph) * s, y, -np.cos(ph) * s])
                    acc += envmap_pdf(T, *(m[:3, :3] @ local))
            expected[i, j] = acc / sub ** 2 * (2.0 / nt) * (2 * np.pi / nph) * n
    e, c = expected.ravel(), counts.ravel()
    keep = e >= 5
    e2 = np.concatenate([[e[~keep].sum()], e[keep]]) if (~keep).any() else e
    c2 = np.concatenate([[c[~keep].sum()], c[keep]]) if (~keep).any() else c
    stat = ((c2 - e2) ** 2 / e2).sum()
    p = chi2.sf(stat, len(e2) - 1)
    print(f"\nenvmap chi2={stat:.1f} dof={len(e2) - 1} p={p:.3g}")
    assert abs(e.sum() - n) / n < 5e-3          # the pdf integrates to 1
    assert p > 0.01


def test_constant_map_is_the_constant_emitter():
    """A constant map returns the constant radiance in every direction, and
    importance-sampled irradiance ∫ L cos θ dω equals the constant emitter's π L."""
    L = np.array([0.7, 1.3, 2.0])
    T = envmap_tables(EnvMap(data=np.broadcast_to(L, (32, 64, 3)).copy(), scale=1.0,
                             to_world=_rotation()))
    rng = np.random.default_rng(4)
    for d in _dirs(rng, 100):
        assert np.allclose(envmap_eval(T, *d), L, rtol=1e-12)
    n = 200_000
    u = rng.random((n, 2))
    est = np.zeros((n, 3))
    for k in range(n):
        dx, dy, dz, pdf, rad = envmap_sample(T, u[k, 0], u[k, 1])
        est[k] = rad * max(0.0, dz) / pdf
    mean, err = est.mean(axis=0), est.std(axis=0) / np.sqrt(n)
    print(f"\nE = {mean} +- {err}, pi L = {np.pi * L}")
    assert np.all(np.abs(mean - np.pi * L) < 4 * err)


def test_black_map_has_no_samples():
    T = envmap_tables(EnvMap(data=np.zeros((4, 8, 3))))
    assert envmap_sample(T, 0.3, 0.7)[3] == 0.0
    assert envmap_pdf(T, 0.0, 1.0, 0.0) == 0.0
