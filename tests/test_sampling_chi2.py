"""Chi-square tests of the path tracer's sampling routines against their pdfs.

Each ``sample`` routine draws N directions; the sphere of directions is
binned in (cos θ, φ) about a chosen axis, and the expected count of every
bin is N × the integral of the routine's own ``pdf`` function over the bin
(a midpoint rule on a sub-grid: dω = d(cos θ) dφ).  Bins expecting fewer than
5 samples are pooled (as Mitsuba's ``mitsuba.chi2.ChiSquareTest`` does), and
scipy's chi-square test must not reject at α = 1e-3.  Every test also feeds
a *wrong* pdf and checks that the test rejects it (the test has power).
Seeds are fixed.
"""

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from impl import bsdf, light_sampling
from impl.materials import MaterialArrays

N = 200_000
ALPHA = 1e-3
N_COS, N_PHI, SUB = 20, 40, 8


def _frame_axis(axis):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    s = np.cross(a, t)
    s /= np.linalg.norm(s)
    return s, np.cross(a, s), a


def _bin_directions(w, axis):
    s, t, a = _frame_axis(axis)
    z = np.clip(w @ a, -1, 1)
    phi = np.mod(np.arctan2(w @ t, w @ s), 2 * np.pi)
    iz = np.minimum(((z + 1) / 2 * N_COS).astype(int), N_COS - 1)
    ip = np.minimum((phi / (2 * np.pi) * N_PHI).astype(int), N_PHI - 1)
    return np.bincount(iz * N_PHI + ip, minlength=N_COS * N_PHI).astype(float)


def _integrate_pdf(pdf, axis, sub=SUB):
    """∫ pdf dω over every (cos θ, φ) bin, midpoint rule on sub×sub cells per bin."""
    s, t, a = _frame_axis(axis)
    SUB = sub
    nz, nphi = N_COS * SUB, N_PHI * SUB
    z = -1 + (np.arange(nz) + 0.5) * 2 / nz
    phi = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    Z, P = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - Z ** 2)
    w = (r * np.cos(P))[..., None] * s + (r * np.sin(P))[..., None] * t + Z[..., None] * a
    vals = pdf(w.reshape(-1, 3)).reshape(nz, nphi) * (2 / nz) * (2 * np.pi / nphi)
    return vals.reshape(N_COS, SUB, N_PHI, SUB).sum(axis=(1, 3)).reshape(-1)


def chi2_pvalue(samples, pdf, axis=(0, 0, 1), sub=SUB):
    """p-value of the chi-square test of direction samples (n, 3) against ``pdf(w) -> (n,)``."""
    obs = _bin_directions(samples, axis)
    exp = _integrate_pdf(pdf, axis, sub) * len(samples)
    # Pool the bins expecting < 5 samples into one (Mitsuba's chi2 does the same).
    small = exp < 5
    o = np.append(obs[~small], obs[small].sum())
    e = np.append(exp[~small], exp[small].sum())
    if e[-1] == 0:
        o, e = o[:-1], e[:-1]
    if obs[small].sum() > 0 and exp[small].sum() == 0:
        return 0.0                          # samples where the pdf says none can be
    e *= o.sum() / e.sum()                  # the pdf's integral is checked separately
    return stats.chisquare(o, e).pvalue


def _check(samples, pdf, wrong_pdf, axis=(0, 0, 1), integral=1.0, sub=SUB):
    total = _integrate_pdf(pdf, axis, sub).sum()
    assert total == pytest.approx(integral, abs=5e-3), f"pdf integrates to {total}"
    p = chi2_pvalue(samples, pdf, axis, sub)
    print(f"chi-square p = {p:.4g} (N = {len(samples)})")
    assert p > ALPHA
    p_bad = chi2_pvalue(samples, wrong_pdf, axis, sub)
    assert p_bad < ALPHA, f"a wrong pdf went unnoticed (p = {p_bad})"


# ------------------------------------------------------------- samplers ---

@njit
def _cosine_samples(n, seed):
    np.random.seed(seed)
    out = np.empty((n, 3))
    for i in range(n):
        out[i] = bsdf.sample_cosine_hemisphere(np.random.random(), np.random.random())
    return out


@njit
def _cosine_pdfs(z):
    out = np.empty(z.shape[0])
    for i in range(z.shape[0]):
        out[i] = bsdf.cosine_hemisphere_pdf(z[i])
    return out


def test_cosine_hemisphere():
    w = _cosine_samples(N, 1)
    pdf = lambda w: _cosine_pdfs(np.ascontiguousarray(w[:, 2]))  # noqa: E731
    uniform = lambda w: np.where(w[:, 2] > 0, 1 / (2 * np.pi), 0.0)  # noqa: E731
    _check(w, pdf, uniform)


@njit
def _sincos(x):
    out = np.empty((2, x.shape[0]))
    for i in range(x.shape[0]):
        out[0, i], out[1, i] = bsdf.sincos_octant(x[i])
    return out


def test_sincos_polynomials_are_the_library_values_within_two_ulps():
    """The warp's polynomial sine and cosine on [−π/4, π/4] (no library call, so lanes
    vectorise): within 2 ulps of the C library's; a 1e-12 error would fail."""
    x = np.concatenate([np.linspace(-math.pi / 4, math.pi / 4, 200001), [0.0, -0.0, 1e-300, 5e-324]])
    s, c = _sincos(x)
    assert np.all(np.abs(s - np.sin(x)) <= 2 * np.spacing(np.abs(np.sin(x))))
    assert np.all(np.abs(c - np.cos(x)) <= 2 * np.spacing(np.cos(x)))
    assert np.abs(_sincos(np.array([math.pi / 4]))[1, 0] - math.sqrt(0.5)) < 1e-16


def test_concentric_warp_is_the_branching_maps_directions():
    """The branch-free concentric warp gives the Shirley–Chiu map's points (the angle's
    two wedge forms and the centre), the branching form with library calls computed
    here: the disk point to 1e-15, and the centre of the square at +z exactly."""
    rng = np.random.default_rng(3)
    for u1, u2 in list(rng.random((2000, 2))) + [(0.5, 0.5), (0.5, 0.0), (0.0, 0.5), (0.0, 0.0), (0.9, 0.9)]:
        a, b = 2 * u1 - 1, 2 * u2 - 1
        if a == 0 and b == 0:
            x, y = 0.0, 0.0
        elif abs(a) > abs(b):
            x, y = a * math.cos(math.pi / 4 * (b / a)), a * math.sin(math.pi / 4 * (b / a))
        else:
            phi = math.pi / 2 - math.pi / 4 * (a / b)
            x, y = b * math.cos(phi), b * math.sin(phi)
        wx, wy, wz = bsdf.sample_cosine_hemisphere(u1, u2)
        assert abs(wx - x) < 1e-15 and abs(wy - y) < 1e-15, (u1, u2)
        assert abs(wx * wx + wy * wy + wz * wz - 1.0) < 1e-15
    assert bsdf.sample_cosine_hemisphere(0.5, 0.5) == (0.0, 0.0, 1.0)


@njit
def _cone_samples(n, seed, c, r, p):
    np.random.seed(seed)
    out = np.empty((n, 4))
    for i in range(n):
        wx, wy, wz, yx, yy, yz, pdf = light_sampling.sample_sphere_cone(
            c[0], c[1], c[2], r, p[0], p[1], p[2], np.random.random(), np.random.random())
        out[i] = wx, wy, wz, (yx - c[0]) ** 2 + (yy - c[1]) ** 2 + (yz - c[2]) ** 2 - r * r
    return out


def test_sphere_light_cone_sampling():
    """Solid-angle sampling of a sphere light from outside: uniform over its cone,
    and every sampled point lies on the sphere."""
    # r/d = 0.6: the cone's edge cos α_max = 0.8 lies on a bin boundary, so the
    # midpoint rule integrates the discontinuous pdf exactly.
    c, r, p = np.array([0.3, -0.2, 2.0]), 1.2, np.array([0.3, -0.2, 0.0])
    s = _cone_samples(N, 2, c, r, p)
    assert np.max(np.abs(s[:, 3])) < 1e-9
    axis = c - p
    cos_max = math.sqrt(1 - (r / np.linalg.norm(axis)) ** 2)
    pdf_c = light_sampling.sphere_cone_pdf(*c, r, *p)

    def pdf(w):
        return np.where(w @ (axis / np.linalg.norm(axis)) >= cos_max, pdf_c, 0.0)

    def wrong(w):   # cos-weighted within the cone
        z = w @ (axis / np.linalg.norm(axis))
        return np.where(z >= cos_max, z, 0.0) / (np.pi * (1 - cos_max ** 2))

    _check(s[:, :3], pdf, wrong, axis=axis)


def _rectangle_scene():
    from core.scene import Camera, Material, Scene, Shape

    v = np.array([[-1.0, -0.5, 0], [1.0, -0.5, 0], [1.0, 0.5, 0], [-1.0, 0.5, 0]])
    v = v @ np.array([[1, 0, 0], [0, 0.8, 0.6], [0, -0.6, 0.8]]).T + [0.2, 0.1, 0.5]
    f = np.array([[0, 1, 2], [0, 2, 3]])
    # Emitting towards −z (towards the origin): flip the winding's normal.
    shape = Shape(kind="mesh", material=0, name="light", source="rectangle", vertices=v, faces=f,
                  flip_normals=True, emitter_radiance=np.ones(3))
    return Scene(path=None, camera=Camera(to_world=np.eye(4)), shapes=[shape],
                 materials=[Material()], lights=[])


@njit
def _light_samples(n, seed, A, L, p):
    np.random.seed(seed)
    out = np.empty((n, 4))
    for i in range(n):
        wx, wy, wz, d, yx, yy, yz, er, eg, eb, pdf, delta, _ = light_sampling.sample_light(
            A, L, p[0], p[1], p[2], np.random.random(), np.random.random(), np.random.random())
        out[i] = wx, wy, wz, er
    return out


def _ray_rectangle(A, p, w):
    """Distance and |cos| at which rays from p hit the (two-triangle) emitter, or inf."""
    t_best = np.full(len(w), np.inf)
    cos_best = np.zeros(len(w))
    for tri in A.tri_v:
        e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n)
        h = np.cross(w, e2)
        det = h @ e1
        s = p - tri[0]
        u = (h @ s) / det
        q = np.cross(s, e1)
        v = (w @ q) / det
        t = (q @ e2) / det
        ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t_best = np.where(ok, t, t_best)
        cos_best = np.where(ok, np.abs(w @ n), cos_best)
    return t_best, cos_best


def test_rectangle_light_sampling():
    """Area sampling of a rectangle emitter (two triangles) seen from a point: the
    directions follow emitter_pdf = d² / (A cos θ_y), which integrates to one."""
    A, L = light_sampling.flatten_with_lights(_rectangle_scene())
    p = np.array([0.0, 0.0, 0.0])
    s = _light_samples(N, 3, A, L, p)
    assert np.all(s[:, 3] > 0)                 # the emitter faces p: every sample counts
    axis = A.tri_v.reshape(-1, 3).mean(axis=0) - p

    def pdf(w):     # emitter_pdf's d² / (A cos θ_y) / n_lights, vectorised
        t, c = _ray_rectangle(A, p, w)
        hit = np.isfinite(t)
        return np.where(hit, np.where(hit, t, 0.0) ** 2 / (A.em_area[0] * np.maximum(c, 1e-300))
                        / L.n_lights, 0.0)

    # ... which is what emitter_pdf returns at the emitter's points:
    t, c = _ray_rectangle(A, p, s[:100, :3])
    assert np.all(np.isfinite(t))
    np.testing.assert_allclose([light_sampling.emitter_pdf(A, L, 0, *p, ti, ci) for ti, ci in zip(t, c)],
                               pdf(s[:100, :3]), rtol=1e-12)

    def wrong(w):   # area sampling's pdf without the cosine
        t, c = _ray_rectangle(A, p, w)
        return np.where(np.isfinite(t), np.minimum(t, 1e9) ** 2 / A.em_area[0], 0.0)

    # The rectangle's edges cut bins along curves: a finer midpoint grid.
    _check(s[:, :3], pdf, wrong, axis=axis, integral=1.0, sub=24)


# ------------------------------------------------------ rough BSDFs ---

def _rough_materials(kind, alpha, eta=1.5, dist=0, alpha_v=None, visible=1):
    """One rough material's rows; ``alpha_v``: anisotropic, α_u = ``alpha``."""
    from impl.materials import MAT_ROUGHCONDUCTOR, MAT_ROUGHDIELECTRIC

    code = {"roughconductor": MAT_ROUGHCONDUCTOR, "roughdielectric": MAT_ROUGHDIELECTRIC}[kind]
    o = np.ones((1, 3))
    B = bsdf.with_plastic(MaterialArrays(o, o, np.zeros((1, 3)), o.copy(), np.array([eta]),
                                         np.array([eta]), np.ones(1), np.array([code]),
                                         np.array([alpha]), np.full(1, visible, np.int64)),
                          dist=np.array([dist]))
    if alpha_v is not None:
        B = B._replace(alpha_v=np.array([float(alpha_v)]), aniso=np.ones(1, np.int64))
    return B


@njit
def _bsdf_samples(n, seed, B, wi):
    np.random.seed(seed)
    out = np.empty((n, 4))
    for i in range(n):
        ox, oy, oz, wr, wg, wb, pdf, delta, eta = bsdf.bsdf_sample(
            B, 0, 0.5, 0.5, 0.5, 1.0, wi[0], wi[1], wi[2], np.random.random(), np.random.random(),
            np.random.random())
        out[i] = ox, oy, oz, wr
    return out


@njit
def _bsdf_pdfs(B, wi, w):
    out = np.empty(w.shape[0])
    for i in range(w.shape[0]):
        out[i] = bsdf.bsdf_pdf(B, 0, 1.0, wi[0], wi[1], wi[2], w[i, 0], w[i, 1], w[i, 2])
    return out


@pytest.mark.parametrize("kind,alpha,theta,dist", [("roughconductor", 0.3, 40.0, 0),
                                                   ("roughdielectric", 0.4, 30.0, 0),
                                                   ("roughdielectric", 0.25, 150.0, 0),
                                                   ("roughconductor", 0.3, 40.0, 1),
                                                   ("roughdielectric", 0.4, 30.0, 1),
                                                   ("roughdielectric", 0.25, 150.0, 1)],
                         ids=lambda v: {0: "beckmann", 1: "ggx"}.get(v) if isinstance(v, int) else None)
def test_rough_bsdf_sampling(kind, alpha, theta, dist):
    """The path tracer's rough-BSDF sampling (lobe choice, Beckmann or GGX visible
    normals, Fresnel) against its own pdf, for wi outside and (θ > 90°) inside the glass."""
    B = _rough_materials(kind, alpha, dist=dist)
    th = math.radians(theta)
    wi = np.array([math.sin(th), 0.0, math.cos(th)])
    s = _bsdf_samples(N, 4, B, wi)
    valid = s[:, 3] > 0
    w = s[valid, :3] / np.linalg.norm(s[valid, :3], axis=1, keepdims=True)

    def pdf(w):
        return _bsdf_pdfs(B, wi, w)

    def wrong(w):   # a 10% rougher distribution
        return _bsdf_pdfs(_rough_materials(kind, alpha * 1.1, dist=dist), wi, w)

    # Invalid samples (wo on the wrong side for its lobe) carry pdf mass no valid
    # direction has: the valid directions' pdf integrates to the valid fraction.
    _check(w, pdf, wrong, integral=valid.mean())


@pytest.mark.parametrize("kind,alphas,theta,dist,visible", [
    ("roughconductor", (0.1, 0.5), 40.0, 0, 1),
    ("roughconductor", (0.5, 0.08), 60.0, 1, 1),
    ("roughconductor", (0.1, 0.4), 30.0, 0, 0),
    ("roughdielectric", (0.5, 0.1), 30.0, 1, 1),
    ("roughdielectric", (0.1, 0.4), 150.0, 0, 1)],
    ids=["conductor-beckmann", "conductor-ggx", "conductor-beckmann-not-visible", "dielectric-ggx",
         "dielectric-beckmann-inside"])
def test_anisotropic_rough_bsdf_sampling(kind, alphas, theta, dist, visible):
    """Anisotropic roughness (α_u ≠ α_v): the path tracer's sampling against its own
    pdf, wi off both tangent axes, outside and inside the glass; the pdf with α_u and
    α_v swapped (the tangent turned by 90°) is rejected."""
    au, av = alphas
    B = _rough_materials(kind, au, dist=dist, alpha_v=av, visible=visible)
    th, ph = math.radians(theta), 0.6
    wi = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    s = _bsdf_samples(N, 5, B, wi)
    valid = s[:, 3] > 0
    w = s[valid, :3] / np.linalg.norm(s[valid, :3], axis=1, keepdims=True)

    def pdf(w):
        return _bsdf_pdfs(B, wi, w)

    def wrong(w):
        return _bsdf_pdfs(_rough_materials(kind, av, dist=dist, alpha_v=au, visible=visible), wi, w)

    _check(w, pdf, wrong, integral=valid.mean())
