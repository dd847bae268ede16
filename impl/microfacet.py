"""Microfacet distributions and the rough conductor / dielectric BSDFs built on them
(thesis 2.4.5.2, the Cook–Torrance specular term; 2.5.6 gloss and translucency).

The thesis writes the specular reflection of a rough surface, after Cook and
Torrance (R. L. Cook, K. E. Torrance, "A reflectance model for computer
graphics", ACM TOG 1(1), 1982, :doi:`10.1145/357290.357293`), as::

    I_sr = F/π · D G / ((N·L)(N·V))

with a facet distribution D in two forms, a geometric attenuation G (the
"V-cavity" G of Torrance–Sparrow) and the exact dielectric Fresnel term in
its (g, c) form.  Mitsuba 3 — the reference — evaluates the same model in the
normalised form of B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet
models for refraction through rough surfaces", EGSR 2007::

    f(wi, wo) = F(wi·m) D(m) G(wi, wo, m) / (4 |cos θ_i| |cos θ_o|),   m = h(wi, wo)

with Smith's shadowing–masking G.  This module has both, as scalar
``@njit(cache=True)`` functions.

Conventions (Mitsuba's)
-----------------------
* Every direction is a unit vector in the **local shading frame**: the
  macro-surface normal is +z, so ``cos θ = v_z``.  A vector is passed as
  three scalars ``(x, y, z)``.
* ``wi`` points *away* from the surface towards where the light goes to (the
  viewer, in radiance transport), ``wo`` away from the surface towards where it
  comes from; ``m`` is a microfacet normal with ``m_z > 0``.
* Roughness ``alpha`` is Mitsuba's ``alpha`` = the RMS slope, which is the
  ``m`` of the thesis's formulas; Mitsuba clamps it below at 1e-4
  (:func:`clamp_alpha`).  Anisotropic roughness: every function that depends on
  the distribution takes a trailing ``alpha_v`` (negative, the default: equal to
  ``alpha``); ``alpha`` is then Mitsuba's ``alpha_u``, the roughness along the
  local x axis (the shading frame's ``s``, the surface's ∂p/∂u), ``alpha_v``
  along y.
* ``gmodel``: :data:`G_SMITH` (0) or :data:`G_VCAVITY` (1).

Distributions
-------------
* :func:`beckmann_d` — Mitsuba's normalised Beckmann D,
  ``exp(−tan²θ_m / α²) / (π α² cos⁴θ_m)``, with ``∫ D(m) cos θ_m dω_m = 1``.
* :func:`cook_torrance_d` — the thesis's "more accurate" form
  ``exp(−(tan α / m)²) / (m² cos⁴ α)`` (α the angle between N and H).  It is
  π × :func:`beckmann_d` (the 1/π sits in the thesis's F/π prefactor).
* :func:`gaussian_d` — the thesis's fast form ``c e^{−(α/m)²}`` with a free
  constant c; :func:`gaussian_d_normalisation` gives the c that makes it a
  normalised distribution (∫ D cos dω = 1).  For small angles it approaches
  Beckmann with c = 1/(π m²).

Masking and shadowing
---------------------
* :func:`smith_g1` — Smith's G1 for Beckmann exactly as Mitsuba's
  ``MicrofacetDistribution::smith_g1``: the rational approximation
  ``(3.535a + 2.181a²)/(1 + 2.276a + 2.577a²)`` for ``a = 1/(α tan θ) < 1.6``
  (< 0.35 % relative error, Walter et al. 2007 eq. 27), 1 above, and 0 when
  ``v`` sees the back of the facet (``(v·m) v_z ≤ 0``).
* :func:`smith_g1_exact` — the exact Beckmann Smith G1 ``1 / (1 + Λ(a))``,
  ``Λ(a) = (erf(a) − 1)/2 + e^{−a²}/(2a√π)``; it is the G1 of the visible-normal
  distribution that :func:`sample_visible_normal` actually samples.
* :func:`smith_g` — the separable product G1(wi, m) G1(wo, m) (Mitsuba's ``G``).
* :func:`vcavity_g` — the thesis's ``G = min{1, γ (N·V), γ (N·L)}``,
  ``γ = 2 (N·H) / (V·H)`` (Torrance–Sparrow V-cavities), generalised to any m as
  ``min{1, 2 m_z |wi_z| / |wi·m|, 2 m_z |wo_z| / |wo·m|}`` with the same
  orientation rule as Smith's.

Sampling the microfacet normal
------------------------------
* :func:`sample_normal` / :func:`normal_pdf` — plain ``D(m) cos θ_m`` sampling
  (Mitsuba's ``sample_visible=false``).
* :func:`sample_visible_normal` / :func:`visible_normal_pdf` — the distribution
  of visible normals ``D_wi(m) = G1(wi, m) |wi·m| D(m) / cos θ_i`` (E. Heitz,
  E. d'Eon, "Importance sampling microfacet-based BSDFs using the distribution
  of visible normals", EGSR 2014), by the numerical inversion of W. Jakob, "An
  improved visible normal sampling routine for the Beckmann distribution"
  (2014) — Mitsuba's ``sample_visible_11``, three Newton steps on the erf-domain
  CDF.  Its pdf uses the rational G1, as Mitsuba's does; the exact density of
  the samples has the exact G1 (``exact=True``).

BSDFs
-----
:func:`conductor_eval` / :func:`conductor_pdf` / :func:`conductor_sample` and
:func:`dielectric_eval` / :func:`dielectric_pdf` / :func:`dielectric_sample`
are Mitsuba's ``roughconductor`` and ``roughdielectric`` (radiance transport;
``eval`` returns f·|cos θ_o|, ``sample`` returns the weight f·|cos θ_o| / pdf)
without the Fresnel factor of the conductor (it is per RGB channel: the
caller multiplies by :func:`impl.fresnel.fresnel_conductor` at ``cos_ih``)
and without ``specular_reflectance`` / ``specular_transmittance``.  Sampling
weights are ``eval / pdf`` of these same functions, which for Smith G with
visible normals equals Mitsuba's ``F · G1(wo, m)`` weight exactly (the rational
G1(wi, m) cancels).  Not reproduced: Mitsuba's roughdielectric with
``sample_visible=false`` samples with α scaled by ``1.2 − 0.2 √|cos θ_i|``
(Walter's trick) but weights the sample as if unscaled; here the unscaled D is
sampled and weighted consistently.

Roughness mixture
-----------------
Thesis 2.4.5.2: a surface with several degrees of roughness has
``D = Σ_k w_k D(m_k)``.  :func:`mixture_d` is that sum of Beckmann lobes
(``alphas`` (K,), ``weights`` (K,) summing to 1, so the mixture stays
normalised, ∫ D cos θ_m dω = 1); :func:`sample_mixture_normal` /
:func:`mixture_normal_pdf` draw m ∝ D(m) cos θ_m by picking lobe k with
probability w_k and sampling its D cos (the pdf is the whole mixture's, so any
lobe may have produced a given m).  :func:`mixture_arrays` checks and packs
the two arrays.

GGX
---
Every function above that depends on the distribution takes a trailing
``dist`` (:data:`BECKMANN`, the default, or :data:`GGX`): Mitsuba's GGX
(Trowbridge–Reitz) ``D(m) = 1 / (π α² cos⁴θ_m (1 + tan²θ_m / α²)²)``, its
exact Smith ``G1 = 2 / (1 + √(1 + α² tan²θ))``, ``D cos`` sampling
(``tan²θ_m = α² u1 / (1 − u1)``) and visible-normal sampling by Mitsuba's
``sample_visible_11`` for GGX (a concentric disk point projected onto the
hemisphere seen from wi; E. Heitz, "A simpler and exact sampling routine for
the GGX distribution of visible normals", 2017).  For GGX the pdf's G1 is exact.

Anisotropic roughness
---------------------
Mitsuba's ``MicrofacetDistribution`` with ``alpha_u`` ≠ ``alpha_v``
(``include/mitsuba/render/microfacet.h``): Beckmann
``D = exp(−((m_x/α_u)² + (m_y/α_v)²)/cos²θ_m) / (π α_u α_v cos⁴θ_m)``, GGX
``D = 1 / (π α_u α_v ((m_x/α_u)² + (m_y/α_v)² + m_z²)²)``, both still with
``∫ D cos θ_m dω = 1``; Smith G1 with ``α² tan²θ`` replaced by
``((α_u v_x)² + (α_v v_y)²) / v_z²``; visible normals by stretching wi to
``(α_u wi_x, α_v wi_y, wi_z)``, sampling the α = 1 slopes and scaling them back
by (α_u, α_v); ``D cos`` sampling (``sample_visible=false``) draws the azimuth
from ``tan φ = (α_v/α_u) tan 2π u2`` (quadrant kept) and the elevation with
``α² = 1 / (cos²φ/α_u² + sin²φ/α_v²)``.  The squared terms are written as
``α_u α_v (x² α_v/α_u + y² α_u/α_v)`` and the like, so that ``alpha_v = alpha``
gives the isotropic values bit for bit.
"""

from __future__ import annotations

import math

from numba import njit

from core.errors import ParamError

from .fresnel import fresnel_dielectric

__all__ = ["G_SMITH", "G_VCAVITY", "BECKMANN", "GGX", "DISTRIBUTIONS", "ALPHA_MIN", "clamp_alpha",
           "erfinv", "erfinv_giles", "beckmann_d", "ggx_d", "microfacet_d", "cook_torrance_d", "gaussian_d", "gaussian_d_normalisation",
           "smith_g1", "smith_g1_exact", "smith_g", "vcavity_g", "masking",
           "sample_normal", "normal_pdf", "sample_visible_normal", "visible_normal_pdf",
           "conductor_eval", "conductor_pdf", "conductor_sample",
           "dielectric_eval", "dielectric_pdf", "dielectric_sample",
           "mixture_arrays", "mixture_d", "mixture_normal_pdf", "sample_mixture_normal"]

G_SMITH, G_VCAVITY = 0, 1
#: Microfacet distributions (the ``dist`` argument), by Mitsuba's ``distribution`` name.
BECKMANN, GGX = 0, 1
DISTRIBUTIONS = {"beckmann": BECKMANN, "ggx": GGX}
#: Mitsuba clamps the roughness below at 1e-4 (``MicrofacetDistribution::configure``).
ALPHA_MIN = 1e-4

_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)
#: ``Frame3f::sincos_phi`` takes φ = 0 when sin²θ ≤ 4 ε (float32 ε = 2⁻²⁴); kept so that
#: visible-normal samples equal Mitsuba's for a wi within ~5e-4/α of the normal too.
_MI_SIN2_EPS = 4.0 * 2.0 ** -24


@njit(inline="always", cache=True)
def clamp_alpha(alpha):
    return max(alpha, ALPHA_MIN)


@njit(inline="always", cache=True)
def _alphas(alpha, alpha_v):
    """(α_u, α_v), clamped; ``alpha_v < 0``: isotropic, α_v = α_u."""
    a = clamp_alpha(alpha)
    return a, (a if alpha_v < 0.0 else clamp_alpha(alpha_v))


# ------------------------------------------------------------------ erfinv ---

@njit(cache=True)
def erfinv_giles(y):
    """Inverse error function on (−1, 1) (±inf at ±1), to about 1e-7 relative: M. Giles'
    single-precision approximation ("Approximating the erfinv function", GPU Computing
    Gems, 2011), the one Dr.Jit uses.  One logarithm (and a square root in the tails)."""
    if y <= -1.0:
        return -math.inf
    if y >= 1.0:
        return math.inf
    w = -math.log((1.0 - y) * (1.0 + y))
    if w < 5.0:
        w -= 2.5
        p = 2.81022636e-08
        p = 3.43273939e-07 + p * w
        p = -3.5233877e-06 + p * w
        p = -4.39150654e-06 + p * w
        p = 0.00021858087 + p * w
        p = -0.00125372503 + p * w
        p = -0.00417768164 + p * w
        p = 0.246640727 + p * w
        p = 1.50140941 + p * w
    else:
        w = math.sqrt(w) - 3.0
        p = -0.000200214257
        p = 0.000100950558 + p * w
        p = 0.00134934322 + p * w
        p = -0.00367342844 + p * w
        p = 0.00573950773 + p * w
        p = -0.0076224613 + p * w
        p = 0.00943887047 + p * w
        p = 1.00167406 + p * w
        p = 2.83297682 + p * w
    return p * y


@njit(cache=True)
def erfinv(y):
    """Inverse error function on (−1, 1) (±inf at ±1): :func:`erfinv_giles` refined by one
    Newton step on ``erf`` (quadratic convergence from its ~1e-7 relative error): within
    1e-11 of the root for |y| ≤ 1 − 10⁻⁶, the range the visible-normal sampler's clamped
    numbers reach; nearer ±1, where erf is flat to double precision, the root itself is
    ill-conditioned.
    """
    x = erfinv_giles(y)
    if math.isinf(x):
        return x
    # Newton on erf(x) − y: derivative 2/√π e^{−x²}.
    return x - (math.erf(x) - y) / (2.0 * _INV_SQRT_PI * math.exp(-x * x))


# ------------------------------------------------------------ distributions ---

@njit(cache=True)
def beckmann_d(alpha, mx, my, mz, alpha_v=-1.0):
    """Mitsuba's normalised Beckmann D(m) = exp(−tan²θ/α²) / (π α² cos⁴θ) (0 for m_z ≤ 0);
    anisotropic with ``alpha_v`` (module doc)."""
    a, b = _alphas(alpha, alpha_v)
    c2 = mz * mz
    if mz <= 0.0:
        return 0.0
    d = math.exp(-(mx * mx * (b / a) + my * my * (a / b)) / (a * b) / c2) / (math.pi * a * b * c2 * c2)
    return d if d * mz > 1e-20 else 0.0


@njit(cache=True)
def ggx_d(alpha, mx, my, mz, alpha_v=-1.0):
    """Mitsuba's GGX D(m) = 1 / (π α² cos⁴θ (1 + tan²θ/α²)²) (0 for m_z ≤ 0); anisotropic
    with ``alpha_v`` (module doc)."""
    a, b = _alphas(alpha, alpha_v)
    if mz <= 0.0:
        return 0.0
    c2 = mz * mz
    t = 1.0 + (mx * mx * (b / a) + my * my * (a / b)) / (a * b * c2)
    d = 1.0 / (math.pi * a * b * c2 * c2 * t * t)
    return d if d * mz > 1e-20 else 0.0


@njit(inline="always", cache=True)
def microfacet_d(dist, alpha, mx, my, mz, alpha_v=-1.0):
    """D(m) of distribution ``dist`` (:data:`BECKMANN` or :data:`GGX`)."""
    if dist == GGX:
        return ggx_d(alpha, mx, my, mz, alpha_v)
    return beckmann_d(alpha, mx, my, mz, alpha_v)


@njit(cache=True)
def cook_torrance_d(m, cos_alpha):
    """The thesis's accurate Cook–Torrance D(m, α) = exp(−(tan α / m)²) / (m² cos⁴ α).

    ``m`` is the RMS slope (Mitsuba's alpha), ``cos_alpha = N·H``.  Equal to
    π × :func:`beckmann_d`; normalised as ``∫ D cos α dω = π``.
    """
    if cos_alpha <= 0.0:
        return 0.0
    c2 = cos_alpha * cos_alpha
    tan2 = max(0.0, 1.0 - c2) / c2
    return math.exp(-tan2 / (m * m)) / (m * m * c2 * c2)


@njit(cache=True)
def gaussian_d(c, m, angle):
    """The thesis's fast form D(m, c, α) = c · exp(−(α/m)²), α = angle(N, H) in radians."""
    return c * math.exp(-(angle / m) ** 2)


def gaussian_d_normalisation(m: float) -> float:
    """The constant c for which ``∫ c e^{−(α/m)²} cos α dω = 1`` over the hemisphere.

    By quadrature (scipy): ``1 / (2π ∫_0^{π/2} e^{−(θ/m)²} cos θ sin θ dθ)``.
    """
    from scipy.integrate import quad

    if not m > 0.0:
        raise ValueError(f"gaussian_d_normalisation: roughness m must be > 0, got {m}")
    val, _ = quad(lambda t: math.exp(-(t / m) ** 2) * math.cos(t) * math.sin(t), 0.0, math.pi / 2,
                  points=[min(m, math.pi / 2)], limit=200)
    return 1.0 / (2.0 * math.pi * val)


# ----------------------------------------------------- masking and shadowing ---

@njit(cache=True)
def smith_g1(alpha, vx, vy, vz, mx, my, mz, dist=BECKMANN, alpha_v=-1.0):
    """Smith's G1(v, m): for Beckmann Mitsuba's rational approximation, for GGX the exact
    2 / (1 + √(1 + α² tan²θ)) (see module doc; anisotropic: α² tan²θ =
    ((α_u v_x)² + (α_v v_y)²) / v_z²)."""
    a_, b_ = _alphas(alpha, alpha_v)
    if (vx * mx + vy * my + vz * mz) * vz <= 0.0:
        return 0.0                           # the back of the facet is not visible from v
    xy_alpha_2 = a_ * b_ * (vx * vx * (a_ / b_) + vy * vy * (b_ / a_))
    if xy_alpha_2 == 0.0:
        return 1.0
    if dist == GGX:
        return 2.0 / (1.0 + math.sqrt(1.0 + xy_alpha_2 / (vz * vz)))
    a = abs(vz) / math.sqrt(xy_alpha_2)      # 1 / (α tan θ)
    if a >= 1.6:
        return 1.0
    a2 = a * a
    return (3.535 * a + 2.181 * a2) / (1.0 + 2.276 * a + 2.577 * a2)


@njit(cache=True)
def smith_g1_exact(alpha, vx, vy, vz, mx, my, mz, alpha_v=-1.0):
    """Exact Smith G1 for Beckmann: 1 / (1 + Λ(a)), a = 1/(α tan θ) (same orientation rule;
    anisotropic as :func:`smith_g1`)."""
    a_, b_ = _alphas(alpha, alpha_v)
    if (vx * mx + vy * my + vz * mz) * vz <= 0.0:
        return 0.0
    xy = a_ * b_ * (vx * vx * (a_ / b_) + vy * vy * (b_ / a_))
    if xy == 0.0:
        return 1.0
    a = abs(vz) / math.sqrt(xy)
    lam = 0.5 * (math.erf(a) - 1.0) + math.exp(-a * a) / (2.0 * a * math.sqrt(math.pi))
    return 1.0 / (1.0 + lam)


@njit(cache=True)
def smith_g(alpha, ix, iy, iz, ox, oy, oz, mx, my, mz, dist=BECKMANN, alpha_v=-1.0):
    """Separable Smith G = G1(wi, m) G1(wo, m) (Mitsuba's ``MicrofacetDistribution::G``)."""
    return (smith_g1(alpha, ix, iy, iz, mx, my, mz, dist, alpha_v)
            * smith_g1(alpha, ox, oy, oz, mx, my, mz, dist, alpha_v))


@njit(cache=True)
def vcavity_g(ix, iy, iz, ox, oy, oz, mx, my, mz):
    """The thesis's V-cavity G = min{1, 2 m_z |wi_z|/|wi·m|, 2 m_z |wo_z|/|wo·m|}.

    For reflection with m = H this is Cook–Torrance's ``min{1, γ(N·V), γ(N·L)}``
    with ``γ = 2(N·H)/(V·H)``.  0 where a direction sees the back of the facet.
    """
    di = ix * mx + iy * my + iz * mz
    do = ox * mx + oy * my + oz * mz
    if di * iz <= 0.0 or do * oz <= 0.0 or mz <= 0.0:
        return 0.0
    return min(1.0, 2.0 * mz * abs(iz) / abs(di), 2.0 * mz * abs(oz) / abs(do))


@njit(inline="always", cache=True)
def masking(gmodel, alpha, ix, iy, iz, ox, oy, oz, mx, my, mz, dist=BECKMANN, alpha_v=-1.0):
    """G of the chosen model: :data:`G_SMITH` (of distribution ``dist``) or :data:`G_VCAVITY`."""
    if gmodel == G_VCAVITY:
        return vcavity_g(ix, iy, iz, ox, oy, oz, mx, my, mz)
    return smith_g(alpha, ix, iy, iz, ox, oy, oz, mx, my, mz, dist, alpha_v)


# ------------------------------------------------------ sampling the normal ---

@njit(cache=True)
def sample_normal(alpha, u1, u2, dist=BECKMANN, alpha_v=-1.0):
    """m ~ D(m) cos θ_m: ``(mx, my, mz, pdf)`` (Mitsuba, ``sample_visible=false``).

    Inverting the CDF of tan²θ_m: Beckmann ``cos θ_m = 1/√(1 − α² ln(1 − u1))``,
    pdf ``(1 − u1) / (π α² cos³θ_m)`` = D(m) cos θ_m; GGX ``tan²θ_m = α² u1 / (1 − u1)``,
    pdf D(m) cos θ_m; ``φ = 2π u2``.  Anisotropic (α_v ≠ α_u): :func:`_sample_normal_aniso`.
    """
    a, b = _alphas(alpha, alpha_v)
    if b != a:
        return _sample_normal_aniso(a, b, u1, u2, dist)
    phi = 2.0 * math.pi * u2
    if dist == GGX:
        cos_t = 1.0 / math.sqrt(1.0 + a * a * u1 / (1.0 - u1))
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        mx, my = math.cos(phi) * sin_t, math.sin(phi) * sin_t
        return mx, my, cos_t, ggx_d(alpha, mx, my, cos_t) * cos_t
    cos_t = 1.0 / math.sqrt(1.0 - a * a * math.log(1.0 - u1))
    c2 = cos_t * cos_t
    pdf = (1.0 - u1) / (math.pi * a * a * max(c2 * cos_t, 1e-20))
    sin_t = math.sqrt(max(0.0, 1.0 - c2))
    return math.cos(phi) * sin_t, math.sin(phi) * sin_t, cos_t, pdf


@njit(cache=True)
def _sample_normal_aniso(a, b, u1, u2, dist):
    """:func:`sample_normal` for α_u = a ≠ α_v = b, as Mitsuba's ``sample`` with
    ``sample_visible=false``: φ from tan φ = (b/a) tan 2π u2 in the quadrant of 2π u2,
    then the elevation with α² = 1 / (cos²φ/a² + sin²φ/b²); pdf D(m) cos θ_m."""
    tmp = (b / a) * math.tan(2.0 * math.pi * u2)
    cos_phi = 1.0 / math.sqrt(tmp * tmp + 1.0)
    cos_phi = math.copysign(cos_phi, abs(u2 - 0.5) - 0.25)
    sin_phi = cos_phi * tmp
    alpha_2 = 1.0 / ((cos_phi / a) ** 2 + (sin_phi / b) ** 2)
    if dist == GGX:
        cos_t = 1.0 / math.sqrt(1.0 + alpha_2 * u1 / (1.0 - u1))
    else:
        cos_t = 1.0 / math.sqrt(1.0 - alpha_2 * math.log(1.0 - u1))
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    mx, my = cos_phi * sin_t, sin_phi * sin_t
    return mx, my, cos_t, microfacet_d(dist, a, mx, my, cos_t, b) * cos_t


@njit(cache=True)
def normal_pdf(alpha, mx, my, mz, dist=BECKMANN, alpha_v=-1.0):
    """Density D(m) cos θ_m of :func:`sample_normal` (solid angle of m)."""
    return microfacet_d(dist, alpha, mx, my, mz, alpha_v) * mz


@njit(cache=True)
def _visible_slopes_ggx(cos_theta_i, u1, u2):
    """Mitsuba's ``sample_visible_11`` for GGX: slopes of a visible normal, α = 1 (a
    concentric disk point, squeezed towards the side wi sees, lifted to the hemisphere)."""
    px, py = _concentric(u1, u2)
    s = 0.5 * (1.0 + cos_theta_i)
    py = (1.0 - s) * math.sqrt(max(0.0, 1.0 - px * px)) + s * py
    z = math.sqrt(max(0.0, 1.0 - px * px - py * py))
    sin_theta_i = math.sqrt(max(0.0, 1.0 - cos_theta_i * cos_theta_i))
    norm = 1.0 / (sin_theta_i * py + cos_theta_i * z)
    return (cos_theta_i * py - sin_theta_i * z) * norm, px * norm


@njit(inline="always", cache=True)
def _concentric(u1, u2):
    """Shirley–Chiu concentric map of [0, 1)² onto the unit disk."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r, phi = a, (math.pi / 4.0) * (b / a)
    else:
        r, phi = b, math.pi / 2.0 - (math.pi / 4.0) * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


@njit(cache=True)
def _visible_slopes(cos_theta_i, u1, u2):
    """Mitsuba's ``sample_visible_11`` for Beckmann: slopes of a visible normal, α = 1."""
    sin_theta_i = math.sqrt(max(0.0, 1.0 - cos_theta_i * cos_theta_i))
    tan_theta_i = sin_theta_i / cos_theta_i
    cot_theta_i = 1.0 / tan_theta_i if tan_theta_i > 0.0 else math.inf
    maxval = math.erf(cot_theta_i)
    u1 = max(min(u1, 1.0 - 1e-6), 1e-6)
    u2 = max(min(u2, 1.0 - 1e-6), 1e-6)
    x = maxval - (maxval + 1.0) * math.erf(math.sqrt(-math.log(u1)))
    tail = tan_theta_i * math.exp(-cot_theta_i * cot_theta_i) if tan_theta_i > 0.0 else 0.0
    u1 *= 1.0 + maxval + _INV_SQRT_PI * tail
    # Giles' approximation of erfinv throughout, as Dr.Jit's: the slopes solve the
    # inversion with it, and stand ~1e-7 (relative) from the exact ones, a sample
    # density ~1e-7 from the pdf; the refinement on erf (:func:`erfinv`) would double the
    # sampler's transcendental calls.
    for _ in range(3):
        slope = erfinv_giles(x)
        value = 1.0 + x + _INV_SQRT_PI * tan_theta_i * math.exp(-slope * slope) - u1
        derivative = 1.0 - slope * tan_theta_i
        x -= value / derivative
    return erfinv_giles(x), erfinv_giles(2.0 * u2 - 1.0)


@njit(cache=True)
def sample_visible_normal(alpha, ix, iy, iz, u1, u2, dist=BECKMANN, alpha_v=-1.0):
    """m ~ the visible normals seen from wi (``iz > 0``): ``(mx, my, mz, pdf)``.

    Heitz–d'Eon 2014 with Jakob's Beckmann inversion, as Mitsuba's
    ``MicrofacetDistribution::sample`` (``sample_visible=true``): stretch wi by
    α, sample the α = 1 slopes, rotate to wi's azimuth, scale by α, and
    m = normalise(−slope_x, −slope_y, 1).  ``pdf`` is Mitsuba's
    :func:`visible_normal_pdf` (rational G1).  Anisotropic: the stretch and the
    scaling by (α_u, α_v).
    """
    a, b = _alphas(alpha, alpha_v)
    sx, sy, sz = a * ix, b * iy, iz
    inv = 1.0 / math.sqrt(sx * sx + sy * sy + sz * sz)
    sx *= inv
    sy *= inv
    sz *= inv
    sin2_t = sx * sx + sy * sy
    sin_t = math.sqrt(sin2_t)
    if sin2_t <= _MI_SIN2_EPS:           # Mitsuba's Frame3f::sincos_phi: azimuth 0 near the pole
        cos_phi, sin_phi = 1.0, 0.0
    else:
        cos_phi = max(-1.0, min(1.0, sx / sin_t))
        sin_phi = max(-1.0, min(1.0, sy / sin_t))
    if dist == GGX:
        s1, s2 = _visible_slopes_ggx(sz, u1, u2)
    else:
        s1, s2 = _visible_slopes(sz, u1, u2)
    px = (cos_phi * s1 - sin_phi * s2) * a
    py = (sin_phi * s1 + cos_phi * s2) * b
    n = 1.0 / math.sqrt(px * px + py * py + 1.0)
    mx, my, mz = -px * n, -py * n, n
    return mx, my, mz, visible_normal_pdf(alpha, ix, iy, iz, mx, my, mz, False, dist, alpha_v)


@njit(cache=True)
def visible_normal_pdf(alpha, ix, iy, iz, mx, my, mz, exact, dist=BECKMANN, alpha_v=-1.0):
    """D_wi(m) = D(m) G1(wi, m) |wi·m| / cos θ_i; Beckmann's G1 rational (Mitsuba) or
    ``exact``; GGX's G1 is exact either way."""
    if iz <= 0.0:
        return 0.0
    g1 = smith_g1_exact(alpha, ix, iy, iz, mx, my, mz, alpha_v) if exact and dist == BECKMANN else \
        smith_g1(alpha, ix, iy, iz, mx, my, mz, dist, alpha_v)
    return microfacet_d(dist, alpha, mx, my, mz, alpha_v) * g1 * abs(ix * mx + iy * my + iz * mz) / iz


@njit(inline="always", cache=True)
def _m_pdf(alpha, visible, ix, iy, iz, mx, my, mz, dist, alpha_v):
    if visible:
        return visible_normal_pdf(alpha, ix, iy, iz, mx, my, mz, False, dist, alpha_v)
    return normal_pdf(alpha, mx, my, mz, dist, alpha_v)


@njit(inline="always", cache=True)
def _sample_m(alpha, visible, ix, iy, iz, u1, u2, dist, alpha_v):
    if visible:
        return sample_visible_normal(alpha, ix, iy, iz, u1, u2, dist, alpha_v)
    return sample_normal(alpha, u1, u2, dist, alpha_v)


# ------------------------------------------------------- rough conductor ---

@njit(cache=True)
def conductor_eval(alpha, gmodel, ix, iy, iz, ox, oy, oz, dist=BECKMANN, alpha_v=-1.0):
    """``roughconductor`` f·cos θ_o without Fresnel: ``(D G / (4 cos θ_i), cos_ih)``.

    0 unless both directions are above the surface (one-sided, as Mitsuba).
    ``cos_ih = wi·h`` is the cosine at which the caller evaluates the
    conductor Fresnel term.
    """
    if iz <= 0.0 or oz <= 0.0:
        return 0.0, 1.0
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    n = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx *= n
    hy *= n
    hz *= n
    d = microfacet_d(dist, alpha, hx, hy, hz, alpha_v)
    if d == 0.0:
        return 0.0, 1.0
    g = masking(gmodel, alpha, ix, iy, iz, ox, oy, oz, hx, hy, hz, dist, alpha_v)
    return d * g / (4.0 * iz), ix * hx + iy * hy + iz * hz


@njit(cache=True)
def conductor_pdf(alpha, visible, ix, iy, iz, ox, oy, oz, dist=BECKMANN, alpha_v=-1.0):
    """Solid-angle density of wo from :func:`conductor_sample`."""
    if iz <= 0.0 or oz <= 0.0:
        return 0.0
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    n = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx *= n
    hy *= n
    hz *= n
    do = ox * hx + oy * hy + oz * hz
    if (ix * hx + iy * hy + iz * hz) <= 0.0 or do <= 0.0:
        return 0.0
    return _m_pdf(alpha, visible, ix, iy, iz, hx, hy, hz, dist, alpha_v) / (4.0 * do)


@njit(cache=True)
def conductor_sample(alpha, gmodel, visible, ix, iy, iz, u1, u2, dist=BECKMANN, alpha_v=-1.0):
    """Sample wo: ``(ox, oy, oz, weight, pdf, cos_ih)``; weight = f cos θ_o / pdf without F.

    weight = 0 (and pdf 0) for an invalid sample (wo below the surface).
    """
    if iz <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 1.0
    mx, my, mz, pm = _sample_m(alpha, visible, ix, iy, iz, u1, u2, dist, alpha_v)
    dim = ix * mx + iy * my + iz * mz
    ox, oy, oz = 2.0 * dim * mx - ix, 2.0 * dim * my - iy, 2.0 * dim * mz - iz
    if pm == 0.0 or oz <= 0.0 or dim <= 0.0:
        return ox, oy, oz, 0.0, 0.0, dim
    pdf = pm / (4.0 * dim)
    val, _ = conductor_eval(alpha, gmodel, ix, iy, iz, ox, oy, oz, dist, alpha_v)
    return ox, oy, oz, val / pdf, pdf, dim


# ------------------------------------------------------ rough dielectric ---

@njit(cache=True)
def _dielectric_half(eta, ix, iy, iz, ox, oy, oz):
    """Generalised half vector (pointing to +z), ``reflect`` flag and the side's eta."""
    reflect = iz * oz > 0.0
    e = eta if iz > 0.0 else 1.0 / eta
    s = 1.0 if reflect else e
    hx, hy, hz = ix + ox * s, iy + oy * s, iz + oz * s
    n = math.sqrt(hx * hx + hy * hy + hz * hz)
    if n == 0.0:
        return 0.0, 0.0, 1.0, reflect, e, False
    if hz < 0.0:
        n = -n
    return hx / n, hy / n, hz / n, reflect, e, True


@njit(cache=True)
def dielectric_eval(alpha, gmodel, eta, ix, iy, iz, ox, oy, oz, dist=BECKMANN, alpha_v=-1.0):
    """``roughdielectric`` f·|cos θ_o| (radiance transport), without specular_reflectance/transmittance.

    ``eta = int_ior / ext_ior``.  Returns ``(value, reflect)``.  Reflection:
    ``F D G / (4 |cos θ_i|)``; transmission:
    ``(1/η)² (1 − F) D G η² |wi·m| |wo·m| / (|cos θ_i| (wi·m + η wo·m)²)`` with
    η the relative index seen from wi's side (Walter et al. 2007 eq. 21, plus
    Mitsuba's radiance scaling).
    """
    if iz == 0.0:
        return 0.0, True
    mx, my, mz, reflect, e, ok = _dielectric_half(eta, ix, iy, iz, ox, oy, oz)
    if not ok:
        return 0.0, reflect
    dim = ix * mx + iy * my + iz * mz
    dom = ox * mx + oy * my + oz * mz
    d = microfacet_d(dist, alpha, mx, my, mz, alpha_v)
    F, _, _, _ = fresnel_dielectric(dim, eta)
    g = masking(gmodel, alpha, ix, iy, iz, ox, oy, oz, mx, my, mz, dist, alpha_v)
    if reflect:
        return F * d * g / (4.0 * abs(iz)), True
    denom = dim + e * dom
    if denom == 0.0:
        return 0.0, False
    # Walter's η² · (1/η)² radiance scaling = 1.
    return abs((1.0 - F) * d * g * dim * dom / (iz * denom * denom)), False


@njit(cache=True)
def dielectric_pdf(alpha, visible, eta, ix, iy, iz, ox, oy, oz, dist=BECKMANN, alpha_v=-1.0):
    """Solid-angle density of wo from :func:`dielectric_sample` (lobe chosen with prob. F)."""
    if iz == 0.0:
        return 0.0
    mx, my, mz, reflect, e, ok = _dielectric_half(eta, ix, iy, iz, ox, oy, oz)
    if not ok:
        return 0.0
    dim = ix * mx + iy * my + iz * mz
    dom = ox * mx + oy * my + oz * mz
    if dim * iz <= 0.0 or dom * oz <= 0.0:
        return 0.0
    if reflect:
        jac = 1.0 / (4.0 * dom)
    else:
        den = dim + e * dom
        jac = e * e * dom / (den * den)
    sgn = 1.0 if iz > 0.0 else -1.0
    pm = _m_pdf(alpha, visible, sgn * ix, sgn * iy, sgn * iz, mx, my, mz, dist, alpha_v)
    F, _, _, _ = fresnel_dielectric(dim, eta)
    return pm * (F if reflect else 1.0 - F) * abs(jac)


@njit(cache=True)
def dielectric_sample(alpha, gmodel, visible, eta, ix, iy, iz, u0, u1, u2, dist=BECKMANN, alpha_v=-1.0):
    """Sample wo: ``(ox, oy, oz, weight, pdf, reflect, eta_ti)``.

    As Mitsuba's ``roughdielectric::sample``: a microfacet normal from the
    side of wi (wi flipped to +z), the reflected lobe with probability
    F(wi·m), else the refracted one; weight = f|cos θ_o|/pdf (without
    specular_reflectance/transmittance).  ``eta_ti`` is the η_i/η_t of a
    transmission (1 for a reflection).  weight = pdf = 0 for an invalid sample.
    """
    if iz == 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, True, 1.0
    sgn = 1.0 if iz > 0.0 else -1.0
    mx, my, mz, pm = _sample_m(alpha, visible, sgn * ix, sgn * iy, sgn * iz, u1, u2, dist, alpha_v)
    dim = ix * mx + iy * my + iz * mz
    F, cos_t, eta_it, eta_ti = fresnel_dielectric(dim, eta)
    if pm == 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, True, 1.0
    if u0 <= F:
        ox, oy, oz = 2.0 * dim * mx - ix, 2.0 * dim * my - iy, 2.0 * dim * mz - iz
        reflect = True
        eti = 1.0
    else:
        b = dim * eta_ti + cos_t
        ox, oy, oz = mx * b - ix * eta_ti, my * b - iy * eta_ti, mz * b - iz * eta_ti
        reflect = False
        eti = eta_ti
    # A sample on the wrong side of the macro-surface for its lobe is invalid.
    if (iz * oz > 0.0) != reflect:
        return ox, oy, oz, 0.0, 0.0, reflect, eti
    val, _ = dielectric_eval(alpha, gmodel, eta, ix, iy, iz, ox, oy, oz, dist, alpha_v)
    pdf = dielectric_pdf(alpha, visible, eta, ix, iy, iz, ox, oy, oz, dist, alpha_v)
    if pdf <= 0.0 or val <= 0.0:
        return ox, oy, oz, 0.0, 0.0, reflect, eti
    return ox, oy, oz, val / pdf, pdf, reflect, eti


# ---------------------------------------------------- roughness mixture ---

def mixture_arrays(alphas, weights) -> tuple:
    """``(alphas, weights)`` as float64 arrays for :func:`mixture_d`: K ≥ 1 lobes,
    every α > 0 and finite, weights ≥ 0 summing to 1 (to 1e-9; a mixture whose weights
    sum to more would reflect more light than it receives).  Raises ParamError."""
    import numpy as np

    a = np.atleast_1d(np.asarray(alphas, dtype=np.float64))
    w = np.atleast_1d(np.asarray(weights, dtype=np.float64))
    if a.ndim != 1 or a.shape != w.shape or len(a) == 0:
        raise ParamError(f"roughness mixture: alphas and weights must be two 1-D lists of the same "
                         f"length >= 1, got {a.shape} and {w.shape}")
    if not (np.all(np.isfinite(a)) and np.all(a > 0.0)):
        raise ParamError(f"roughness mixture: every alpha must be finite and > 0, got {a.tolist()}")
    if not (np.all(np.isfinite(w)) and np.all(w >= 0.0) and abs(w.sum() - 1.0) <= 1e-9):
        raise ParamError(f"roughness mixture: weights must be >= 0 and sum to 1, got {w.tolist()} "
                         f"(sum {w.sum():.6g})")
    return a, w


@njit(cache=True)
def mixture_d(alphas, weights, mx, my, mz):
    """Thesis 2.4.5.2's ``D = Σ_k w_k D(m_k)`` with Beckmann lobes of roughness ``alphas``."""
    d = 0.0
    for k in range(alphas.shape[0]):
        if weights[k] > 0.0:
            d += weights[k] * beckmann_d(alphas[k], mx, my, mz)
    return d


@njit(cache=True)
def mixture_normal_pdf(alphas, weights, mx, my, mz):
    """Density of :func:`sample_mixture_normal`: ``D(m) cos θ_m`` of the mixture."""
    if mz <= 0.0:
        return 0.0
    return mixture_d(alphas, weights, mx, my, mz) * mz


@njit(cache=True)
def sample_mixture_normal(alphas, weights, u0, u1, u2):
    """m ∝ D(m) cos θ_m of the mixture: lobe k with probability w_k (by ``u0``), then
    :func:`sample_normal` of that lobe.  ``(mx, my, mz, pdf)``, pdf the mixture's."""
    K = alphas.shape[0]
    k = K - 1
    c = 0.0
    for j in range(K):
        c += weights[j]
        if u0 < c:
            k = j
            break
    mx, my, mz, _ = sample_normal(alphas[k], u1, u2)
    return mx, my, mz, mixture_normal_pdf(alphas, weights, mx, my, mz)
