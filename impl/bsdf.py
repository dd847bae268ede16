"""BSDF sampling, evaluation and pdf for the path tracer (thesis 3.2.1: the BRDF ρ).

Each material kind has three scalar ``@njit`` functions in the *local shading
frame* (z = shading normal, ``wi`` towards the viewer, ``wo`` towards the
light), with Mitsuba 3's conventions so that ``path`` estimates what
Mitsuba's ``path`` integrator estimates:

* ``sample(wi, u) -> (wo, weight, pdf, delta, eta)``: ``weight`` is
  f(wi, wo)·|cos θ_o| / pdf (the throughput factor), ``eta`` the relative IOR
  crossed (1 unless transmitted);
* ``eval(wi, wo) -> f(wi, wo)·|cos θ_o|`` (0 for delta lobes);
* ``pdf(wi, wo)`` (solid angle; 0 for delta lobes).

Kinds
-----
``diffuse`` (Lambert): f = ρ/π, cosine-weighted hemisphere sampling
(Malley's method: a uniform disk point lifted to the hemisphere), pdf =
cos θ_o / π, weight = ρ.  One-sided: 0 when wi or wo is below the surface.

``conductor`` (smooth): the mirror direction, weight =
``specular_reflectance`` × the exact conductor Fresnel reflectance of
``eta + i k`` (:func:`impl.fresnel.fresnel_conductor`); one-sided.

``dielectric`` (smooth): reflection with probability F (exact unpolarised
Fresnel, :func:`impl.fresnel.fresnel_dielectric`), else refraction by Snell's
law; weights ``specular_reflectance`` and ``specular_transmittance`` ×
η_ti² (radiance scaling of Mitsuba's Radiance transport mode).  Two-sided by
construction (the normal points outward; cos θ_i < 0 is inside).

``roughconductor`` and ``roughdielectric`` (Beckmann or GGX, Smith G, visible-normal
sampling by default): Mitsuba's microfacet BSDFs of :mod:`impl.microfacet`
(Walter et al. 2007), with the conductor Fresnel term at the sampled
microfacet and ``specular_reflectance`` / ``specular_transmittance``; anisotropic
with α_u ≠ α_v (``alpha`` along the local x axis, ``alpha_v`` along y: the caller's
frame must then be the surface's tangent frame, :func:`impl.shading_frame.tangent`).

``thindielectric`` (Mitsuba's): a thin slab of dielectric, both sides alike;
reflection with probability R' = R + T²R/(1 − R²) = 2R/(1 + R) (R the
interface's Fresnel reflectance at |cos θ_i|, T = 1 − R: the multiple internal
reflections summed), else straight through (−wi, η 1); weights
``specular_reflectance`` / ``specular_transmittance``.  Delta.

``blendbsdf``: a row whose two components are rows of their own, a nested
blendbsdf's too (:func:`impl.materials.expand_components`); :func:`is_delta` when
all its leaves are, the mixture itself is resolved by the caller (:mod:`impl.path`).

``plastic`` and ``roughplastic``: Mitsuba's diffuse base under a dielectric
coat, the functions of :mod:`impl.plastic` (``nonlinear`` included); the
diffuse reflectance is the caller's ρ (the material's, as for ``diffuse``).
``plastic``'s specular lobe is a delta: a sample of it returns ``delta`` true
with its discrete probability as ``pdf``, while ``eval``/``pdf`` cover the
diffuse lobe (the material itself is not delta: it takes light samples).
Those functions take and return small arrays, so a plastic bounce allocates.

Thesis chapter 2 models without a Mitsuba plugin (scalar lobes, not yet a
material kind of :func:`bsdf_sample`; each an eval / pdf / sample triple in the
same conventions, checked by chi-square and furnace tests in
``tests/test_cook_torrance.py``):

* :func:`cook_torrance_eval` / :func:`cook_torrance_pdf` /
  :func:`cook_torrance_sample` — Cook & Torrance's (1982) mixture of a diffuse
  and a specular lobe, ``f = k_d ρ/π + k_s F(wi·h) D G / (4 cos θ_i cos θ_o)``
  with ``k_d + k_s ≤ 1`` (the thesis's s + d = 1), the exact dielectric Fresnel
  F of relative IOR η (2.4.5.2's (g, c) form), the roughness mixture D of
  :func:`impl.microfacet.mixture_d`, and G Smith or V-cavity.  Sampling picks
  the specular lobe with probability k_s / (k_d + k_s), else a cosine
  direction; the pdf is the mixture of both, so the weight eval/pdf is
  unbiased whichever lobe drew the sample.  One-sided.
* :func:`diffuse_transmission_eval` / :func:`diffuse_transmission_pdf` /
  :func:`diffuse_transmission_sample` — a Lambertian reflector and diffuse
  transmitter (the thesis's diffuse transparency, 2.4.5.3):
  ``f = ρ/π`` on the side of wi, ``τ/π`` on the other; ρ + τ ≤ 1 per channel
  conserves energy.  Sampling chooses the side with probability
  ρ̄/(ρ̄ + τ̄) (channel means), then a cosine direction on it.  Two-sided.

Material rows come from :func:`bsdf_arrays` (:func:`impl.materials.material_arrays`
and, for the plastics, :func:`impl.materials.plastic_arrays`, as one
:class:`BsdfArrays`); kind codes are :data:`impl.materials.KIND_CODES`.

Warps come as ``sample_*(u)`` / ``*_pdf`` pairs (:func:`sample_cosine_hemisphere`,
:func:`cosine_hemisphere_pdf`), each checked by a chi-square test
(``tests/test_sampling_chi2.py``).
"""

from __future__ import annotations

import math

from numba import njit

from typing import NamedTuple

import numpy as np

from core.scene import Scene

from . import microfacet as mf
from . import plastic as pl
from .fresnel import fresnel_conductor, fresnel_dielectric
from .materials import (MAT_BLEND, MAT_CONDUCTOR, MAT_DIELECTRIC, MAT_DIFFUSE, MAT_PLASTIC,
                        MAT_ROUGHCONDUCTOR, MAT_ROUGHDIELECTRIC, MAT_ROUGHPLASTIC, MAT_THINDIELECTRIC,
                        MaterialArrays, PlasticArrays, WrapperArrays, distribution_codes,
                        material_arrays, no_wrappers, plastic_arrays, wrapper_arrays)

__all__ = ["bsdf_arrays", "BsdfArrays", "with_plastic", "MODELLED", "frame", "to_local", "to_world",
           "sample_cosine_hemisphere", "sincos_octant", "cosine_hemisphere_pdf", "diffuse_eval", "diffuse_pdf",
           "bsdf_sample", "bsdf_eval", "bsdf_pdf", "bsdf_sample_at", "bsdf_eval_at", "bsdf_pdf_at", "is_delta",
           "is_dielectric", "cook_torrance_eval", "cook_torrance_pdf", "cook_torrance_sample",
           "diffuse_transmission_eval", "diffuse_transmission_pdf", "diffuse_transmission_sample",
           "check_cook_torrance"]

#: The Mitsuba BSDF plugins the path tracer models.
MODELLED = ("diffuse", "conductor", "dielectric", "roughconductor", "roughdielectric", "plastic",
            "roughplastic", "thindielectric", "blendbsdf")

INV_PI = 1.0 / math.pi


class BsdfArrays(NamedTuple):
    """:class:`impl.materials.MaterialArrays`'s rows and the plastic rows of
    :class:`impl.materials.PlasticArrays` (``pl_*``), one row per material."""

    spec_refl: np.ndarray
    spec_trans: np.ndarray
    cond_eta: np.ndarray
    cond_k: np.ndarray
    diel_eta: np.ndarray
    diel_int: np.ndarray
    diel_ext: np.ndarray
    kind: np.ndarray
    alpha: np.ndarray
    visible: np.ndarray
    pl_eta: np.ndarray          # (M,) int_ior / ext_ior of the coat
    pl_specular: np.ndarray     # (M, 3) specular_reflectance
    pl_spec_weight: np.ndarray  # (M,) specular lobe weight s̄ / (d̄ + s̄)
    pl_nonlinear: np.ndarray    # (M,) int
    pl_alpha: np.ndarray        # (M,) roughplastic: Beckmann roughness
    pl_visible: np.ndarray      # (M,) int: roughplastic samples visible normals
    pl_fdr_int: np.ndarray      # (M,) plastic: inner diffuse Fresnel reflectance
    pl_ext_t: np.ndarray        # (M, TABLE_RES) roughplastic: coat transmittance over cos θ
    pl_int_r: np.ndarray        # (M,) roughplastic: internal diffuse reflectance
    dist: np.ndarray            # (M,) int: microfacet distribution of the rough kinds (BECKMANN, GGX)
    opacity: np.ndarray         # (M,) the wrappers of impl.materials.WrapperArrays: mask opacity,
    comp: np.ndarray            # (M, 2) int blendbsdf components,
    blend_w: np.ndarray         # (M,) blend weight,
    ptex: np.ndarray            # (M, 4, 6) int their textures (slot 0 opacity, 1 weight, 2 alpha
                                # or alpha_u, 3 alpha_v),
    ptex_uv: np.ndarray         # (M, 4, 2, 3) to_uv maps,
    ptex_c: np.ndarray          # (M, 4, 2) checkerboard values,
    ptex_data: np.ndarray       # (K, 3) texels,
    alpha_v: np.ndarray         # (M,) roughness along the tangent t (= alpha when isotropic),
    aniso: np.ndarray           # (M,) int 1: anisotropic roughness (a blendbsdf: any leaf),
    leaf: np.ndarray            # (M, NL) int a blendbsdf's leaves, their blendbsdf ancestors
    leaf_node: np.ndarray       # (M, NL, D) int and the component taken at each
    leaf_branch: np.ndarray     # (M, NL, D) int (impl.materials.WrapperArrays)


def with_plastic(M: MaterialArrays, P: PlasticArrays | None = None,
                 dist: np.ndarray | None = None, W: WrapperArrays | None = None) -> BsdfArrays:
    """``M``'s rows with ``P``'s plastic rows (none: rows of zeros, no plastic material),
    the distribution codes ``dist`` (none: Beckmann everywhere) and the wrapper rows
    ``W`` (none: no mask, no blendbsdf, isotropic roughness)."""
    n = M.kind.shape[0]
    if P is None:
        P = PlasticArrays(np.zeros(n, dtype=np.int64), np.ones(n), np.zeros((n, 3)), np.zeros((n, 3)),
                          np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n),
                          np.ones(n, dtype=np.int64), np.zeros(n), np.zeros((n, pl.TABLE_RES)),
                          np.zeros(n))
    if dist is None:
        dist = np.zeros(n, dtype=np.int64)
    if W is None:
        W = no_wrappers(n, M.alpha)
    return BsdfArrays(*M, P.eta, P.specular, P.spec_weight, P.nonlinear, P.alpha, P.visible,
                      P.fdr_int, P.ext_t, P.int_r, np.asarray(dist, dtype=np.int64), *W)


def bsdf_arrays(scene: Scene, *, algorithm: str = "path") -> BsdfArrays:
    """:func:`impl.materials.material_arrays` for every BSDF this module models, with
    the plastic rows of :func:`impl.materials.plastic_arrays`.

    Raises
    ------
    NotImplementedError
        A BSDF kind not modelled, naming the shape (and see ``material_arrays``).
    """
    M = material_arrays(scene, algorithm=algorithm, model="the path tracer", kinds=MODELLED,
                        distributions=tuple(mf.DISTRIBUTIONS), anisotropic=True)
    return with_plastic(M, plastic_arrays(scene, algorithm=algorithm, distributions=tuple(mf.DISTRIBUTIONS)),
                        distribution_codes(scene), wrapper_arrays(scene, algorithm=algorithm, bump_tangent=True))


# ------------------------------------------------------------------ frames ---

@njit(inline="always", cache=True)
def frame(nx, ny, nz):
    """An orthonormal basis (s, t) completing the unit normal n (Duff et al. 2017, branchless)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


@njit(inline="always", cache=True)
def to_local(sx, sy, sz, tx, ty, tz, nx, ny, nz, vx, vy, vz):
    return (sx * vx + sy * vy + sz * vz, tx * vx + ty * vy + tz * vz, nx * vx + ny * vy + nz * vz)


@njit(inline="always", cache=True)
def to_world(sx, sy, sz, tx, ty, tz, nx, ny, nz, lx, ly, lz):
    return (sx * lx + tx * ly + nx * lz, sy * lx + ty * ly + ny * lz, sz * lx + tz * ly + nz * lz)


# ------------------------------------------------------------------- warps ---

# Minimax polynomials of sin and cos on [-pi/4, pi/4], the coefficients of Sun's fdlibm
# (k_sin.c, k_cos.c, 1993): sin x = x + x^3 (S1 + z S2 + ... + z^5 S6), cos x = 1 - z/2 +
# z^2 (C1 + ... + z^5 C6), z = x^2.
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@njit(inline="always", cache=True)
def sincos_octant(x):
    """(sin x, cos x) for |x| <= pi/4 by polynomials (no library call, so a loop over
    lanes that calls it vectorises; numba's pip build has no vector ``sin``/``cos``).
    Within 2 ulps of ``math.sin``/``math.cos`` on that interval
    (``tests/test_sampling_chi2.py``); not range-reduced, so meaningless beyond it."""
    z = x * x
    s = x + x * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - (0.5 * z - z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6))))))
    return s, c


@njit(inline="always", cache=True)
def sample_cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +z (Malley: concentric disk point lifted to the hemisphere).

    The Shirley–Chiu concentric map of [0,1)² to the disk, written with selects and
    :func:`sincos_octant` instead of branches and library calls: its angle is
    (π/4)·(b/a) in the wedges |a| > |b| and π/2 − (π/4)·(a/b) in the others, whose cosine
    and sine are the sine and cosine of (π/4)·(a/b); the centre maps to +z."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    wide = abs(a) > abs(b)
    r = a if wide else b
    centre = (a == 0.0) & (b == 0.0)                # r = 0 there only
    s, c = sincos_octant((math.pi / 4.0) * ((b if wide else a) / (1.0 if centre else r)))
    x = r * (c if wide else s)
    y = r * (s if wide else c)
    return x, y, math.sqrt(max(0.0, 1.0 - x * x - y * y))


@njit(inline="always", cache=True)
def cosine_hemisphere_pdf(z):
    """pdf (solid angle) of :func:`sample_cosine_hemisphere`: cos θ / π above the surface."""
    return z * INV_PI if z > 0.0 else 0.0


# ------------------------------------------------------------------- BSDFs ---

@njit(inline="always", cache=True)
def diffuse_eval(rho_r, rho_g, rho_b, wiz, woz):
    """The Lambertian f·cos θ_o = ρ cos θ_o / π (RGB) with both directions above the
    surface, else 0; selects, no branch (a loop over lanes calling it vectorises)."""
    c = woz * INV_PI
    up = (wiz > 0.0) & (woz > 0.0)
    return rho_r * c if up else 0.0, rho_g * c if up else 0.0, rho_b * c if up else 0.0


@njit(inline="always", cache=True)
def diffuse_pdf(wiz, woz):
    """Solid-angle pdf of the Lambertian lobe's cosine-weighted sample producing wo (0
    with wi below the surface)."""
    return cosine_hemisphere_pdf(woz) if wiz > 0.0 else 0.0


@njit(inline="always", cache=True)
def is_delta(B: MaterialArrays, mat):
    """Whether every lobe of ``mat`` is a delta (no light samples); a blendbsdf is when
    all its leaves are."""
    if B.kind[mat] == MAT_BLEND:
        for c in B.leaf[mat]:
            if c < 0:
                break
            k = B.kind[c]
            if not (k == MAT_CONDUCTOR or k == MAT_DIELECTRIC or k == MAT_THINDIELECTRIC):
                return False
        return True
    k = B.kind[mat]
    return k == MAT_CONDUCTOR or k == MAT_DIELECTRIC or k == MAT_THINDIELECTRIC


@njit(inline="always", cache=True)
def is_dielectric(B: MaterialArrays, mat):
    """Whether ``mat`` has two sides of its own (dielectrics: the normal tells inside from
    outside; a thin dielectric is symmetric)."""
    k = B.kind[mat]
    return k == MAT_DIELECTRIC or k == MAT_ROUGHDIELECTRIC or k == MAT_THINDIELECTRIC


@njit(inline="always", cache=True)
def _conductor_fresnel(B: MaterialArrays, mat, cos_i):
    return (fresnel_conductor(cos_i, B.cond_eta[mat, 0], B.cond_k[mat, 0]) * B.spec_refl[mat, 0],
            fresnel_conductor(cos_i, B.cond_eta[mat, 1], B.cond_k[mat, 1]) * B.spec_refl[mat, 1],
            fresnel_conductor(cos_i, B.cond_eta[mat, 2], B.cond_k[mat, 2]) * B.spec_refl[mat, 2])


# The plastic lobes (:mod:`impl.plastic`) work on small arrays, which need numba's
# runtime: they sit in their own functions (runtime on, called only at plastic hits),
# so that the dispatchers below can be inlined into the path tracer's batch kernel,
# which runs without the runtime (:mod:`impl.kernel`).  The dispatchers are inlined
# because a call of a separate function passes every array of ``B`` by value.

@njit(cache=True, _nrt=True)
def _plastic_sample(B: MaterialArrays, mat, k, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, wix, wiy, wiz, u0, u1,
                    u2):
    """:func:`bsdf_sample` of a plastic or roughplastic material."""
    wi = np.array((wix, wiy, wiz))
    rho = np.array((rho_r, rho_g, rho_b))
    spec = np.array((sp_r, sp_g, sp_b))
    if k == MAT_PLASTIC:
        wo, pdf, w, delta = pl.plastic_sample(wi, u0, u1, u2, B.pl_eta[mat], rho, spec,
                                              B.pl_spec_weight[mat], B.pl_fdr_int[mat],
                                              B.pl_nonlinear[mat] != 0)
    else:
        wo, pdf, w = pl.roughplastic_sample(wi, u0, u1, u2, B.pl_eta[mat], B.pl_alpha[mat],
                                            B.pl_visible[mat] != 0, rho, spec,
                                            B.pl_spec_weight[mat], B.pl_ext_t[mat],
                                            B.pl_int_r[mat], B.pl_nonlinear[mat] != 0, B.dist[mat])
        delta = False
    if not pdf > 0.0:
        return wo[0], wo[1], wo[2], 0.0, 0.0, 0.0, 0.0, False, 1.0
    return wo[0], wo[1], wo[2], w[0], w[1], w[2], pdf, delta, 1.0


@njit(cache=True, _nrt=True)
def _plastic_eval(B: MaterialArrays, mat, k, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, wix, wiy, wiz, wox, woy,
                  woz):
    """:func:`bsdf_eval` of a plastic or roughplastic material."""
    wi = np.array((wix, wiy, wiz))
    wo = np.array((wox, woy, woz))
    rho = np.array((rho_r, rho_g, rho_b))
    if k == MAT_PLASTIC:
        f = pl.plastic_eval(wi, wo, B.pl_eta[mat], rho, B.pl_fdr_int[mat], B.pl_nonlinear[mat] != 0)
    else:
        f = pl.roughplastic_eval(wi, wo, B.pl_eta[mat], B.pl_alpha[mat], rho, np.array((sp_r, sp_g, sp_b)),
                                 B.pl_ext_t[mat], B.pl_int_r[mat], B.pl_nonlinear[mat] != 0,
                                 B.dist[mat])
    return f[0], f[1], f[2]


@njit(cache=True, _nrt=True)
def _plastic_pdf(B: MaterialArrays, mat, k, wix, wiy, wiz, wox, woy, woz):
    """:func:`bsdf_pdf` of a plastic or roughplastic material."""
    wi = np.array((wix, wiy, wiz))
    wo = np.array((wox, woy, woz))
    if k == MAT_PLASTIC:
        return pl.plastic_pdf(wi, wo, B.pl_eta[mat], B.pl_spec_weight[mat])
    return pl.roughplastic_pdf(wi, wo, B.pl_alpha[mat], B.pl_visible[mat] != 0, B.pl_spec_weight[mat],
                               B.pl_ext_t[mat], B.dist[mat])


@njit(inline="always", cache=True)
def bsdf_sample(B: MaterialArrays, mat, rho_r, rho_g, rho_b, eta_scale, wix, wiy, wiz, u0, u1, u2):
    """:func:`bsdf_sample_at` with the material's own roughness ``B.alpha[mat]``, ``B.alpha_v[mat]``
    and a plastic's own ``specular_reflectance`` ``B.pl_specular[mat]``."""
    s = B.pl_specular[mat]
    return bsdf_sample_at(B, mat, B.alpha[mat], B.alpha_v[mat], rho_r, rho_g, rho_b, s[0], s[1], s[2],
                          eta_scale, wix, wiy, wiz, u0, u1, u2)


@njit(inline="always", cache=True)
def bsdf_eval(B: MaterialArrays, mat, rho_r, rho_g, rho_b, eta_scale, wix, wiy, wiz, wox, woy, woz):
    """:func:`bsdf_eval_at` with the material's own roughness ``B.alpha[mat]``, ``B.alpha_v[mat]``
    and a plastic's own ``specular_reflectance`` ``B.pl_specular[mat]``."""
    s = B.pl_specular[mat]
    return bsdf_eval_at(B, mat, B.alpha[mat], B.alpha_v[mat], rho_r, rho_g, rho_b, s[0], s[1], s[2],
                        eta_scale, wix, wiy, wiz, wox, woy, woz)


@njit(inline="always", cache=True)
def bsdf_pdf(B: MaterialArrays, mat, eta_scale, wix, wiy, wiz, wox, woy, woz):
    """:func:`bsdf_pdf_at` with the material's own roughness ``B.alpha[mat]``, ``B.alpha_v[mat]``."""
    return bsdf_pdf_at(B, mat, B.alpha[mat], B.alpha_v[mat], eta_scale, wix, wiy, wiz, wox, woy, woz)


@njit(inline="always", cache=True)
def bsdf_sample_at(B: MaterialArrays, mat, alpha, alpha_v, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, eta_scale,
                   wix, wiy, wiz, u0, u1, u2):
    """Sample wo for material ``mat`` (diffuse albedo ρ given, textures resolved by the caller).

    ``eta_scale`` multiplies a dielectric's relative index (dispersion: the
    ratio n(λ)/n of the hero wavelength; 1 otherwise).  Returns
    ``(wox, woy, woz, w_r, w_g, w_b, pdf, delta, eta)`` with ``eta`` the
    relative index η_t/η_i crossed (1 unless transmitted, Mitsuba's
    ``bs.eta``); a zero weight ends the path.  ``alpha`` and ``alpha_v`` are the
    roughness α_u, α_v of a roughconductor / roughdielectric at this point
    (``B.alpha[mat]`` and ``B.alpha_v[mat]``, or their textures' values; equal when
    isotropic).  ``sp_r``, ``sp_g``, ``sp_b`` are a plastic's ``specular_reflectance``
    at this point (``B.pl_specular[mat]`` or its texture's value), which weights its
    specular coat (Mitsuba's plastics multiply that lobe by the texture's ``eval``);
    other kinds ignore them.
    """
    k = B.kind[mat]
    if k == MAT_DIFFUSE:
        if wiz <= 0.0:
            return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, 1.0
        x, y, z = sample_cosine_hemisphere(u1, u2)
        return x, y, z, rho_r, rho_g, rho_b, cosine_hemisphere_pdf(z), False, 1.0
    if k == MAT_PLASTIC or k == MAT_ROUGHPLASTIC:
        return _plastic_sample(B, mat, k, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, wix, wiy, wiz, u0, u1, u2)
    if k == MAT_CONDUCTOR:
        if wiz <= 0.0:
            return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, True, 1.0
        fr, fg, fb = _conductor_fresnel(B, mat, wiz)
        return -wix, -wiy, wiz, fr, fg, fb, 1.0, True, 1.0
    if k == MAT_ROUGHCONDUCTOR:
        ox, oy, oz, w, pdf, cos_ih = mf.conductor_sample(mf.clamp_alpha(alpha), mf.G_SMITH,
                                                         B.visible[mat], wix, wiy, wiz, u1, u2, B.dist[mat],
                                                         alpha_v)
        if w <= 0.0 or pdf <= 0.0:
            return ox, oy, oz, 0.0, 0.0, 0.0, 0.0, False, 1.0
        fr, fg, fb = _conductor_fresnel(B, mat, cos_ih)
        return ox, oy, oz, w * fr, w * fg, w * fb, pdf, False, 1.0
    eta = B.diel_eta[mat] * eta_scale
    if k == MAT_THINDIELECTRIC:
        # Mitsuba's thindielectric: R' = R + T²R / (1 − R²) = 2R / (1 + R) of the interface's
        # Fresnel R at |cos θ_i| (both sides alike), reflection with probability R', else
        # the ray goes straight through (−wi, a null event); weights the specular colours.
        F, _, _, _ = fresnel_dielectric(abs(wiz), eta)
        r = 2.0 * F / (1.0 + F)
        if u0 <= r:
            return (-wix, -wiy, wiz, B.spec_refl[mat, 0], B.spec_refl[mat, 1], B.spec_refl[mat, 2],
                    r, True, 1.0)
        return (-wix, -wiy, -wiz, B.spec_trans[mat, 0], B.spec_trans[mat, 1], B.spec_trans[mat, 2],
                1.0 - r, True, 1.0)
    if k == MAT_ROUGHDIELECTRIC:
        ox, oy, oz, w, pdf, refl, eti = mf.dielectric_sample(mf.clamp_alpha(alpha), mf.G_SMITH,
                                                             B.visible[mat], eta, wix, wiy, wiz,
                                                             u0, u1, u2, B.dist[mat], alpha_v)
        if w <= 0.0 or pdf <= 0.0:
            return ox, oy, oz, 0.0, 0.0, 0.0, 0.0, False, 1.0
        if refl:
            return (ox, oy, oz, w * B.spec_refl[mat, 0], w * B.spec_refl[mat, 1],
                    w * B.spec_refl[mat, 2], pdf, False, 1.0)
        return (ox, oy, oz, w * B.spec_trans[mat, 0], w * B.spec_trans[mat, 1],
                w * B.spec_trans[mat, 2], pdf, False, 1.0 / eti)
    # Smooth dielectric: pick the reflected lobe with probability F.
    F, cos_t, eta_it, eta_ti = fresnel_dielectric(wiz, eta)
    if u0 < F:
        return (-wix, -wiy, wiz, B.spec_refl[mat, 0], B.spec_refl[mat, 1], B.spec_refl[mat, 2],
                F, True, 1.0)
    # T = −η_ti wi + (η_ti cos θ_i + cos θ_t) n with n = +z, i.e. (−η_ti wi_xy, cos θ_t).
    s = eta_ti * eta_ti
    return (-eta_ti * wix, -eta_ti * wiy, cos_t, s * B.spec_trans[mat, 0],
            s * B.spec_trans[mat, 1], s * B.spec_trans[mat, 2], 1.0 - F, True, eta_it)


@njit(inline="always", cache=True)
def bsdf_eval_at(B: MaterialArrays, mat, alpha, alpha_v, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, eta_scale,
                 wix, wiy, wiz, wox, woy, woz):
    """f(wi, wo)·|cos θ_o| (RGB) of the non-delta lobes; 0 for delta BSDFs (``alpha``,
    ``alpha_v``, ``sp_r``, ``sp_g``, ``sp_b`` as for :func:`bsdf_sample_at`)."""
    k = B.kind[mat]
    if k == MAT_DIFFUSE:
        return diffuse_eval(rho_r, rho_g, rho_b, wiz, woz)
    if k == MAT_PLASTIC or k == MAT_ROUGHPLASTIC:
        return _plastic_eval(B, mat, k, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, wix, wiy, wiz, wox, woy, woz)
    if k == MAT_ROUGHCONDUCTOR:
        v, cos_ih = mf.conductor_eval(mf.clamp_alpha(alpha), mf.G_SMITH, wix, wiy, wiz,
                                      wox, woy, woz, B.dist[mat], alpha_v)
        if v <= 0.0:
            return 0.0, 0.0, 0.0
        fr, fg, fb = _conductor_fresnel(B, mat, cos_ih)
        return v * fr, v * fg, v * fb
    if k == MAT_ROUGHDIELECTRIC:
        v, refl = mf.dielectric_eval(mf.clamp_alpha(alpha), mf.G_SMITH,
                                     B.diel_eta[mat] * eta_scale, wix, wiy, wiz, wox, woy, woz, B.dist[mat],
                                     alpha_v)
        if refl:
            return v * B.spec_refl[mat, 0], v * B.spec_refl[mat, 1], v * B.spec_refl[mat, 2]
        return v * B.spec_trans[mat, 0], v * B.spec_trans[mat, 1], v * B.spec_trans[mat, 2]
    return 0.0, 0.0, 0.0


@njit(inline="always", cache=True)
def bsdf_pdf_at(B: MaterialArrays, mat, alpha, alpha_v, eta_scale, wix, wiy, wiz, wox, woy, woz):
    """Solid-angle pdf of :func:`bsdf_sample_at` producing wo (0 for delta lobes)."""
    k = B.kind[mat]
    if k == MAT_DIFFUSE:
        return diffuse_pdf(wiz, woz)
    if k == MAT_PLASTIC or k == MAT_ROUGHPLASTIC:
        return _plastic_pdf(B, mat, k, wix, wiy, wiz, wox, woy, woz)
    if k == MAT_ROUGHCONDUCTOR:
        return mf.conductor_pdf(mf.clamp_alpha(alpha), B.visible[mat], wix, wiy, wiz,
                                wox, woy, woz, B.dist[mat], alpha_v)
    if k == MAT_ROUGHDIELECTRIC:
        return mf.dielectric_pdf(mf.clamp_alpha(alpha), B.visible[mat],
                                 B.diel_eta[mat] * eta_scale, wix, wiy, wiz, wox, woy, woz, B.dist[mat],
                                 alpha_v)
    return 0.0


# ----------------------------------------- Cook–Torrance diffuse + specular ---

def check_cook_torrance(kd: float, ks: float) -> None:
    """Refuse lobe weights that create energy: k_d, k_s ≥ 0 and k_d + k_s ≤ 1 (the
    thesis's s + d = 1; with ρ ≤ 1 the albedo then stays ≤ 1).  Raises ParamError."""
    from core.errors import ParamError

    if not (kd >= 0.0 and ks >= 0.0 and kd + ks <= 1.0 + 1e-12):
        raise ParamError(f"cook-torrance: need k_d, k_s >= 0 and k_d + k_s <= 1, got k_d={kd}, k_s={ks}")


@njit(cache=True)
def _ct_half(ix, iy, iz, ox, oy, oz):
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx / n, hy / n, hz / n


@njit(cache=True)
def cook_torrance_eval(kd, ks, alphas, weights, gmodel, eta, rho_r, rho_g, rho_b, ix, iy, iz, ox, oy, oz):
    """f·cos θ_o (r, g, b) of ``k_d ρ/π + k_s F D G / (4 cos θ_i cos θ_o)``; 0 below the surface."""
    if iz <= 0.0 or oz <= 0.0:
        return 0.0, 0.0, 0.0
    diff = kd * oz * INV_PI
    spec = 0.0
    if ks > 0.0:
        hx, hy, hz = _ct_half(ix, iy, iz, ox, oy, oz)
        d = mf.mixture_d(alphas, weights, hx, hy, hz)
        if d > 0.0:
            g = mf.masking(gmodel, alphas[0], ix, iy, iz, ox, oy, oz, hx, hy, hz) if gmodel == mf.G_VCAVITY \
                else _mixture_smith_g(alphas, weights, ix, iy, iz, ox, oy, oz, hx, hy, hz)
            F, _, _, _ = fresnel_dielectric(ix * hx + iy * hy + iz * hz, eta)
            spec = ks * F * d * g / (4.0 * iz)
    return diff * rho_r + spec, diff * rho_g + spec, diff * rho_b + spec


@njit(inline="always", cache=True)
def _mixture_smith_g(alphas, weights, ix, iy, iz, ox, oy, oz, hx, hy, hz):
    """Smith G of a roughness mixture, taken per lobe and weighted by each lobe's share
    of D at h (each lobe is its own microsurface: D G = Σ_k w_k D_k G_k)."""
    num = den = 0.0
    for k in range(alphas.shape[0]):
        if weights[k] > 0.0:
            dk = weights[k] * mf.beckmann_d(alphas[k], hx, hy, hz)
            num += dk * mf.smith_g(alphas[k], ix, iy, iz, ox, oy, oz, hx, hy, hz)
            den += dk
    return num / den if den > 0.0 else 0.0


@njit(cache=True)
def cook_torrance_pdf(kd, ks, alphas, weights, ix, iy, iz, ox, oy, oz):
    """Solid-angle density of :func:`cook_torrance_sample`."""
    if iz <= 0.0 or oz <= 0.0 or kd + ks <= 0.0:
        return 0.0
    p_spec = ks / (kd + ks)
    pdf = (1.0 - p_spec) * oz * INV_PI
    if p_spec > 0.0:
        hx, hy, hz = _ct_half(ix, iy, iz, ox, oy, oz)
        do = ox * hx + oy * hy + oz * hz
        if do > 0.0:
            pdf += p_spec * mf.mixture_normal_pdf(alphas, weights, hx, hy, hz) / (4.0 * do)
    return pdf


@njit(cache=True)
def cook_torrance_sample(kd, ks, alphas, weights, gmodel, eta, rho_r, rho_g, rho_b, ix, iy, iz,
                         u0, u1, u2):
    """Sample wo: ``(ox, oy, oz, w_r, w_g, w_b, pdf)``, weight = f cos θ_o / pdf.  ``u0``
    chooses the lobe and, rescaled, the roughness component; weight = pdf = 0 for an
    invalid sample (below the surface)."""
    if iz <= 0.0 or kd + ks <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0
    p_spec = ks / (kd + ks)
    if u0 < p_spec:
        mx, my, mz, pm = mf.sample_mixture_normal(alphas, weights, u0 / p_spec, u1, u2)
        dim = ix * mx + iy * my + iz * mz
        ox, oy, oz = 2.0 * dim * mx - ix, 2.0 * dim * my - iy, 2.0 * dim * mz - iz
        if pm == 0.0 or dim <= 0.0 or oz <= 0.0:
            return ox, oy, oz, 0.0, 0.0, 0.0, 0.0
    else:
        ox, oy, oz = sample_cosine_hemisphere(u1, u2)
    pdf = cook_torrance_pdf(kd, ks, alphas, weights, ix, iy, iz, ox, oy, oz)
    if pdf <= 0.0:
        return ox, oy, oz, 0.0, 0.0, 0.0, 0.0
    r, g, b = cook_torrance_eval(kd, ks, alphas, weights, gmodel, eta, rho_r, rho_g, rho_b,
                                 ix, iy, iz, ox, oy, oz)
    return ox, oy, oz, r / pdf, g / pdf, b / pdf, pdf


# ----------------------------------------------------- diffuse transmission ---

@njit(cache=True)
def diffuse_transmission_eval(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b, ix, iy, iz, ox, oy, oz):
    """f·|cos θ_o| (r, g, b): ρ/π on the side of wi, τ/π on the other (0 when either
    direction lies in the surface)."""
    if iz == 0.0 or oz == 0.0:
        return 0.0, 0.0, 0.0
    c = abs(oz) * INV_PI
    if iz * oz > 0.0:
        return rho_r * c, rho_g * c, rho_b * c
    return tau_r * c, tau_g * c, tau_b * c


@njit(inline="always", cache=True)
def _p_reflect(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b):
    r = rho_r + rho_g + rho_b
    t = tau_r + tau_g + tau_b
    return 0.5 if r + t <= 0.0 else r / (r + t)


@njit(cache=True)
def diffuse_transmission_pdf(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b, ix, iy, iz, ox, oy, oz):
    """Solid-angle density of :func:`diffuse_transmission_sample` over the sphere."""
    if iz == 0.0 or oz == 0.0:
        return 0.0
    p = _p_reflect(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b)
    return (p if iz * oz > 0.0 else 1.0 - p) * abs(oz) * INV_PI


@njit(cache=True)
def diffuse_transmission_sample(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b, ix, iy, iz, u0, u1, u2):
    """Sample wo: ``(ox, oy, oz, w_r, w_g, w_b, pdf)``: the side by ``u0`` (reflection with
    probability ρ̄/(ρ̄ + τ̄)), a cosine direction on it; weight ρ/p or τ/(1 − p)."""
    if iz == 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0
    p = _p_reflect(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b)
    ox, oy, oz = sample_cosine_hemisphere(u1, u2)
    side = 1.0 if iz > 0.0 else -1.0
    if u0 >= p:
        side = -side
    oz = side * oz
    pdf = diffuse_transmission_pdf(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b, ix, iy, iz, ox, oy, oz)
    if pdf <= 0.0:
        return ox, oy, oz, 0.0, 0.0, 0.0, 0.0
    r, g, b = diffuse_transmission_eval(rho_r, rho_g, rho_b, tau_r, tau_g, tau_b, ix, iy, iz, ox, oy, oz)
    return ox, oy, oz, r / pdf, g / pdf, b / pdf, pdf
