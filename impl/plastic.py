"""Mitsuba 3's ``plastic`` and ``roughplastic`` BSDFs: a diffuse base under a
dielectric coat (thesis 3.2.1: a BRDF as the sum of a diffuse lobe and a
specular or glossy one; the physical cousin of Phong's model).

Pure numba functions of local directions (z = the shading normal; ``wi`` and
``wo`` both point away from the surface, Mitsuba's convention), ready for the
tracers to call.  ``eval`` returns the BSDF times cos θ_o (Mitsuba's ``eval``),
``sample`` returns ``(wo, pdf, weight = eval / pdf)``; the specular lobe of
``plastic`` is a delta, so its ``eval``/``pdf`` cover the diffuse lobe only and
``sample`` returns the delta with its discrete probability as ``pdf``.

The model (Mitsuba's ``src/bsdfs/plastic.cpp`` and ``roughplastic.cpp``,
after Weidlich and Wilkie 2007):

* diffuse: ρ / (1 − R) · (1 − F_i)(1 − F_o) / η² · cos θ_o / π with, for
  ``plastic``, F the dielectric Fresnel reflectance of the coat (η = int_ior /
  ext_ior) and R = the diffuse Fresnel reflectance of the inside
  (``fresnel_diffuse_reflectance(1/η)``, Mitsuba's polynomial fits); for
  ``roughplastic`` (1 − F) becomes the rough coat's transmittance T(cos θ)
  and R its internal diffuse reflectance (tables from :func:`rough_tables`).
  ``nonlinear=true`` replaces R by ρ·R (the colour shift of multiple
  internal bounces);
* specular: F_i · specular_reflectance along the mirror direction
  (``plastic``), or the microfacet reflection F D G / (4 cos θ_i) (``roughplastic``,
  Beckmann or GGX: :mod:`impl.microfacet`);
* lobe selection: specular with probability ∝ F_i · w (plastic) or
  (1 − T_i) · w (roughplastic), w = s̄ / (d̄ + s̄) from the mean specular and
  diffuse reflectances.

Limits: isotropic roughness (as Mitsuba's roughplastic); a caller that models
only Beckmann refuses ``ggx`` through :func:`plastic_params`'s ``distributions``.  The
rough tables are integrated here with Mitsuba's quadrature (64 cosines, 32²
Gauss-Legendre nodes over visible normals), in float64.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from core.errors import SceneError, UnsupportedError
from core.scene import texture_mean as scene_texture_mean

from .fresnel import fresnel_dielectric, lookup_ior
from .materials import texture_mean_value
from .microfacet import (BECKMANN, DISTRIBUTIONS, microfacet_d, normal_pdf, sample_normal,
                         sample_visible_normal, smith_g1)

__all__ = ["PlasticParams", "plastic_params", "fresnel_diffuse_reflectance", "rough_tables",
           "plastic_eval", "plastic_pdf", "plastic_sample", "roughplastic_eval", "roughplastic_pdf",
           "roughplastic_sample", "TABLE_RES"]

#: Cosines of the rough coat's transmittance table (Mitsuba's MI_ROUGH_TRANSMITTANCE_RES).
TABLE_RES = 64

_INV_PI = 1.0 / math.pi


class PlasticParams(NamedTuple):
    """One plastic material decoded with Mitsuba's defaults (RGB as float64 arrays)."""

    kind: str                   # 'plastic' or 'roughplastic'
    eta: float                  # int_ior / ext_ior
    diffuse: np.ndarray         # (3,) diffuse_reflectance
    specular: np.ndarray        # (3,) specular_reflectance (1 when absent)
    spec_weight: float          # s̄ / (d̄ + s̄)
    nonlinear: bool
    alpha: float                # roughness (roughplastic)
    visible: bool               # sample visible normals (roughplastic)
    fdr_int: float              # plastic: inner diffuse Fresnel reflectance
    ext_t: np.ndarray           # roughplastic: (TABLE_RES,) coat transmittance over cos θ
    int_r: float                # roughplastic: internal diffuse reflectance
    dist: int = BECKMANN        # roughplastic: microfacet distribution (impl.microfacet code)


@njit(cache=True)
def fresnel_diffuse_reflectance(eta):
    """Mitsuba's diffuse Fresnel reflectance: Egan-Hilgeman's fit for η < 1,
    d'Eon-Irving's for η ≥ 1."""
    inv = 1.0 / eta
    if eta < 1.0:
        return 0.0636 * inv + eta * (eta * -1.4399 + 0.7099) + 0.6681
    return 0.919317 + inv * (-3.4793 + inv * (6.75335 + inv * (-7.80989 + inv * (4.98554
                                                                              + inv * -1.36881))))


@njit(cache=True)
def _table_integrals(alpha, eta, nodes, weights, dist):
    """(transmittance over TABLE_RES cosines with η, internal reflectance with 1/η)."""
    n = TABLE_RES
    trans = np.zeros(n)
    refl = np.zeros(n)
    for k in range(n):
        mu = max(1e-6, k / (n - 1))
        ix, iy, iz = math.sqrt(1.0 - mu * mu), 0.0, mu
        t_sum = 0.0
        r_sum = 0.0
        for a in range(len(nodes)):
            for b in range(len(nodes)):
                u1 = nodes[b] * 0.5 + 0.5       # meshgrid: x varies fastest
                u2 = nodes[a] * 0.5 + 0.5
                w = weights[a] * weights[b] * 0.25
                mx, my, mz, _ = sample_visible_normal(alpha, ix, iy, iz, u1, u2, dist)
                c = ix * mx + iy * my + iz * mz
                # transmission through the coat (η)
                f, cos_t, eta_it, eta_ti = fresnel_dielectric(c, eta)
                ox = eta_ti * -ix + (eta_ti * c + cos_t) * mx
                oy = eta_ti * -iy + (eta_ti * c + cos_t) * my
                oz = eta_ti * -iz + (eta_ti * c + cos_t) * mz
                if oz * iz < 0.0:
                    t_sum += smith_g1(alpha, ox, oy, oz, mx, my, mz, dist) * (1.0 - f) * w
                # reflection from inside (1/η)
                f2 = fresnel_dielectric(c, 1.0 / eta)[0]
                rx, ry, rz = 2.0 * c * mx - ix, 2.0 * c * my - iy, 2.0 * c * mz - iz
                if rz > 0.0 and iz > 0.0:
                    r_sum += smith_g1(alpha, rx, ry, rz, mx, my, mz, dist) * f2 * w
        trans[k] = t_sum
        refl[k] = r_sum * mu
    return trans, 2.0 * refl.mean()


def rough_tables(alpha: float, eta: float, dist: int = BECKMANN) -> tuple[np.ndarray, float]:
    """Mitsuba's roughplastic tables for ``alpha`` of distribution ``dist`` and ``eta``: the coat's
    transmittance at TABLE_RES evenly spaced cos θ ∈ [0, 1] and its internal diffuse
    reflectance 2 ⟨R(μ) μ⟩ (32² Gauss-Legendre nodes over visible normals for η > 1,
    128² otherwise; ``roughplastic.cpp``'s ``parameters_changed``)."""
    res_t = 32 if eta > 1.0 else 128
    nodes, weights = np.polynomial.legendre.leggauss(res_t)
    trans, _ = _table_integrals(alpha, eta, nodes, weights, dist)
    res_r = 32 if 1.0 / eta > 1.0 else 128
    nodes, weights = np.polynomial.legendre.leggauss(res_r)
    _, int_r = _table_integrals(alpha, eta, nodes, weights, dist)
    return trans, float(int_r)


def _rgb(p: dict, name: str, default: float, where: str) -> np.ndarray:
    a = np.asarray(p.get(name, default), dtype=np.float64).reshape(-1)
    if a.shape == (1,):
        a = np.repeat(a, 3)
    if a.shape != (3,):
        raise SceneError(f"{where}: '{name}' must be a float or rgb value")
    return a


def plastic_params(material, *, where: str = "plastic",
                   distributions: tuple[str, ...] = ("beckmann",)) -> PlasticParams:
    """Decode a :class:`core.scene.Material` of kind ``plastic``/``roughplastic``
    with Mitsuba's defaults (int_ior polypropylene, ext_ior air, diffuse 0.5,
    alpha 0.1, beckmann, sample_visible true, nonlinear false); ``distributions``:
    those the caller models (a roughplastic with another is refused).  A textured
    reflectance enters as its mean colour (``diffuse``, ``specular``) and the lobe
    weight takes its scalar mean as Mitsuba's ``Texture::mean``
    (:func:`impl.materials.texture_mean_value`);
    the per-point values are the caller's lookups (:mod:`impl.textures`)."""
    p = material.params
    if material.kind not in ("plastic", "roughplastic"):
        raise ValueError(f"plastic_params: not a plastic material ({material.kind})")
    n_int = lookup_ior(p.get("int_ior", "polypropylene"), what=f"{where}: int_ior")
    n_ext = lookup_ior(p.get("ext_ior", "air"), what=f"{where}: ext_ior")
    if material.kind == "roughplastic" and n_int == n_ext:
        raise SceneError(f"{where}: roughplastic needs int_ior != ext_ior (as Mitsuba requires)")
    eta = n_int / n_ext
    # A textured diffuse_reflectance: the texture's mean (the loader's ``reflectance``),
    # which is also what Mitsuba's lobe weight uses (``Texture::mean``).
    diffuse = _rgb(p, "diffuse_reflectance", 0.5, where) if "diffuse_reflectance" in p else \
        np.asarray(material.reflectance, dtype=np.float64)
    specular = _rgb(p, "specular_reflectance", 1.0, where)
    d_mean = float(diffuse.mean())
    s_mean = float(specular.mean()) if "specular_reflectance" in p else 1.0
    textures = getattr(material, "textures", None) or {}
    if "diffuse_reflectance" in textures:
        d_mean = texture_mean_value(textures["diffuse_reflectance"])
    if "specular_reflectance" in textures:
        tex = textures["specular_reflectance"]
        specular = np.asarray(scene_texture_mean(tex), dtype=np.float64)
        s_mean = texture_mean_value(tex)
    alpha, visible = 0.0, True
    ext_t, int_r = np.zeros(TABLE_RES), 0.0
    if material.kind == "roughplastic":
        dist = str(p.get("distribution", "beckmann")).lower()
        if dist not in DISTRIBUTIONS:
            raise SceneError(f"{where}: invalid distribution '{dist}' (Mitsuba accepts 'beckmann' or 'ggx')")
        if dist not in distributions:
            raise UnsupportedError(f"{where}: roughplastic distribution '{dist}' is not modelled; "
                                   f"only {' and '.join(repr(d) for d in distributions)}")
        alpha = float(p.get("alpha", 0.1))
        visible = bool(p.get("sample_visible", True))
        code = DISTRIBUTIONS[dist]
        ext_t, int_r = rough_tables(alpha, eta, code)
    else:
        code = BECKMANN
    return PlasticParams(material.kind, eta, diffuse, specular, s_mean / (d_mean + s_mean),
                         bool(p.get("nonlinear", False)), alpha, visible,
                         float(fresnel_diffuse_reflectance(1.0 / eta)), ext_t, int_r, code)


# ------------------------------------------------------------- plastic ---

@njit(cache=True)
def _diffuse_scale(rho, r, nonlinear):
    return rho / (1.0 - (rho * r if nonlinear else r))


@njit(cache=True)
def plastic_eval(wi, wo, eta, diffuse, fdr_int, nonlinear):
    """Diffuse lobe of ``plastic`` times cos θ_o (RGB); the delta lobe is not evaluable."""
    out = np.zeros(3)
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return out
    f_i = fresnel_dielectric(wi[2], eta)[0]
    f_o = fresnel_dielectric(wo[2], eta)[0]
    k = wo[2] * _INV_PI * (1.0 - f_i) * (1.0 - f_o) / (eta * eta)
    for c in range(3):
        out[c] = _diffuse_scale(diffuse[c], fdr_int, nonlinear) * k
    return out


@njit(cache=True)
def plastic_pdf(wi, wo, eta, spec_weight):
    """Solid-angle density of the diffuse lobe of :func:`plastic_sample`."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return 0.0
    f_i = fresnel_dielectric(wi[2], eta)[0]
    ps = f_i * spec_weight
    pd = (1.0 - f_i) * (1.0 - spec_weight)
    return wo[2] * _INV_PI * pd / (ps + pd)


@njit(cache=True)
def plastic_sample(wi, u1, u2, u3, eta, diffuse, specular, spec_weight, fdr_int, nonlinear):
    """``(wo, pdf, weight, is_delta)``: the mirror direction with probability ∝ F_i w
    (``pdf`` its discrete probability, ``weight`` F_i s / pdf), else a cosine-weighted
    direction (``weight`` = eval / pdf)."""
    wo = np.zeros(3)
    weight = np.zeros(3)
    if wi[2] <= 0.0:
        return wo, 0.0, weight, False
    f_i = fresnel_dielectric(wi[2], eta)[0]
    ps = f_i * spec_weight
    pd = (1.0 - f_i) * (1.0 - spec_weight)
    ps = ps / (ps + pd)
    if u1 < ps:
        wo[0], wo[1], wo[2] = -wi[0], -wi[1], wi[2]
        for c in range(3):
            weight[c] = f_i * specular[c] / ps
        return wo, ps, weight, True
    r = math.sqrt(u2)
    phi = 2.0 * math.pi * u3
    wo[0], wo[1], wo[2] = r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u2))
    pdf = wo[2] * _INV_PI * (1.0 - ps)
    if pdf <= 0.0:
        return wo, 0.0, weight, False
    f_o = fresnel_dielectric(wo[2], eta)[0]
    k = (1.0 - f_i) * (1.0 - f_o) / (eta * eta) / (1.0 - ps)
    for c in range(3):
        weight[c] = _diffuse_scale(diffuse[c], fdr_int, nonlinear) * k
    return wo, pdf, weight, False


# -------------------------------------------------------- roughplastic ---

@njit(cache=True)
def _lerp_table(table, x):
    n = table.shape[0]
    x *= n - 1
    i = min(int(x), n - 2)
    return table[i] + (table[i + 1] - table[i]) * (x - i)


@njit(cache=True)
def roughplastic_eval(wi, wo, eta, alpha, diffuse, specular, ext_t, int_r, nonlinear, dist=BECKMANN):
    """``roughplastic`` BSDF times cos θ_o (RGB): microfacet reflection off the coat
    (distribution ``dist``) plus the diffuse base seen through it."""
    out = np.zeros(3)
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return out
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    d = microfacet_d(dist, alpha, hx, hy, hz)
    f = fresnel_dielectric(wi[0] * hx + wi[1] * hy + wi[2] * hz, eta)[0]
    g = smith_g1(alpha, wi[0], wi[1], wi[2], hx, hy, hz, dist) * \
        smith_g1(alpha, wo[0], wo[1], wo[2], hx, hy, hz, dist)
    spec = f * d * g / (4.0 * wi[2])
    t_i = _lerp_table(ext_t, wi[2])
    t_o = _lerp_table(ext_t, wo[2])
    k = _INV_PI * wo[2] * t_i * t_o / (eta * eta)
    for c in range(3):
        out[c] = spec * specular[c] + _diffuse_scale(diffuse[c], int_r, nonlinear) * k
    return out


@njit(cache=True)
def roughplastic_pdf(wi, wo, alpha, visible, spec_weight, ext_t, dist=BECKMANN):
    """Solid-angle density of :func:`roughplastic_sample`."""
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return 0.0
    t_i = _lerp_table(ext_t, wi[2])
    ps = (1.0 - t_i) * spec_weight
    pd = t_i * (1.0 - spec_weight)
    ps = ps / (ps + pd)
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    inv = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    if visible:
        spec = microfacet_d(dist, alpha, hx, hy, hz) * \
            smith_g1(alpha, wi[0], wi[1], wi[2], hx, hy, hz, dist) / (4.0 * wi[2])
    else:
        spec = normal_pdf(alpha, hx, hy, hz, dist) / (4.0 * (wo[0] * hx + wo[1] * hy + wo[2] * hz))
    return spec * ps + (1.0 - ps) * wo[2] * _INV_PI


@njit(cache=True)
def roughplastic_sample(wi, u1, u2, u3, eta, alpha, visible, diffuse, specular, spec_weight,
                        ext_t, int_r, nonlinear, dist=BECKMANN):
    """``(wo, pdf, weight = eval / pdf)``: a microfacet reflection with probability
    ∝ (1 − T_i) w, else a cosine-weighted direction; ``pdf`` is the mixture's."""
    wo = np.zeros(3)
    if wi[2] <= 0.0:
        return wo, 0.0, np.zeros(3)
    t_i = _lerp_table(ext_t, wi[2])
    ps = (1.0 - t_i) * spec_weight
    pd = t_i * (1.0 - spec_weight)
    ps = ps / (ps + pd)
    if u1 < ps:
        if visible:
            mx, my, mz, _ = sample_visible_normal(alpha, wi[0], wi[1], wi[2], u2, u3, dist)
        else:
            mx, my, mz, _ = sample_normal(alpha, u2, u3, dist)
        c = 2.0 * (wi[0] * mx + wi[1] * my + wi[2] * mz)
        wo[0], wo[1], wo[2] = c * mx - wi[0], c * my - wi[1], c * mz - wi[2]
    else:
        r = math.sqrt(u2)
        phi = 2.0 * math.pi * u3
        wo[0], wo[1], wo[2] = r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u2))
    pdf = roughplastic_pdf(wi, wo, alpha, visible, spec_weight, ext_t, dist)
    if not pdf > 0.0:
        return wo, 0.0, np.zeros(3)
    return wo, pdf, roughplastic_eval(wi, wo, eta, alpha, diffuse, specular, ext_t, int_r, nonlinear,
                                      dist) / pdf
