"""The Phong local illumination model (thesis 1.4.2, eqs. of 1.4.2.3–1.4.2.5).

For one light seen from a surface point, per RGB channel::

    I = I_a k_a ρ  +  f_att · I_p · [ k_d (N·L) + k_s (R·V)^n ]

with N the shading normal, L the unit direction to the light, V the unit
direction to the viewer and R = 2(N·L)N − L the mirror direction of L.

Conventions that make the model physically comparable:

* ``k_d = ρ/π`` — the Lambertian BRDF of Mitsuba's ``diffuse`` — and ``I_p``
  is the light's radiant intensity (W/sr) or irradiance (directional), so with
  ``k_a = k_s = 0`` and f_att = 1/d² the model *is* the direct radiance
  ρ/π · I · cosθ / d² and can be compared with Mitsuba's ``direct`` integrator.
* ``f_att = 1 / (c1 + c2 d + c3 d²)``; the thesis clamps it to ≤ 1
  (``clamp=True``), which is not physical for d < 1 and is off by default.
* The ambient term is ``I_a k_a ρ`` (k_a as a fraction of the diffuse colour)
  and is added once per visible point, not per light.
* Like Mitsuba's one-sided BSDFs, a point seen from behind (V·N ≤ 0) or lit
  from behind (L·N ≤ 0) receives no diffuse or specular light.
"""

import math

from numba import njit

from core.algorithm import Param

__all__ = ["attenuation", "phong_brdf_cos", "PHONG_PARAMS"]

#: The model's coefficients as algorithm parameters (they are not scene content).
_NON_NEGATIVE = (lambda v: v >= 0.0, ">= 0")

PHONG_PARAMS = (
    Param("ka", float, 0.0, "ambient coefficient k_a (times the diffuse colour)", valid=_NON_NEGATIVE),
    Param("ambient", float, 0.0, "ambient intensity I_a", valid=_NON_NEGATIVE),
    Param("ks", float, 0.0, "specular coefficient k_s", valid=_NON_NEGATIVE),
    Param("shininess", float, 32.0, "Phong exponent n", valid=_NON_NEGATIVE),
    Param("c1", float, 0.0, "f_att constant term", valid=_NON_NEGATIVE),
    Param("c2", float, 0.0, "f_att linear term", valid=_NON_NEGATIVE),
    Param("c3", float, 1.0, "f_att quadratic term", valid=_NON_NEGATIVE),
    Param("fatt_clamp", bool, False, "clamp f_att to 1 (thesis 1.4.2.3)"),
)

INV_PI = 1.0 / math.pi


@njit(inline="always", cache=True)
def attenuation(d, c1, c2, c3, clamp):
    """f_att = 1 / (c1 + c2 d + c3 d²), optionally clamped to 1 (thesis 1.4.2.3); +inf
    when the denominator is 0 (c1 = c2 = c3 = 0: the image is then refused as
    non-finite instead of the kernel raising a division by zero)."""
    den = c1 + c2 * d + c3 * d * d
    f = 1.0 / den if den > 0.0 else math.inf
    if clamp and f > 1.0:
        f = 1.0
    return f


@njit(inline="always", cache=True)
def phong_brdf_cos(nx, ny, nz, lx, ly, lz, vx, vy, vz, ks, shininess):
    """(k_d-weight, specular) of the Phong bracket for unit N, L, V.

    Returns ``(cos_l / π, k_s (R·V)^n)``: the caller multiplies the first by ρ
    and adds the second (white highlight) before scaling by f_att · I_p.
    Both are 0 when L or V is below the surface.
    """
    cos_l = nx * lx + ny * ly + nz * lz
    cos_v = nx * vx + ny * vy + nz * vz
    if cos_l <= 0.0 or cos_v <= 0.0:
        return 0.0, 0.0
    spec = 0.0
    if ks > 0.0:
        rx, ry, rz = 2.0 * cos_l * nx - lx, 2.0 * cos_l * ny - ly, 2.0 * cos_l * nz - lz
        rv = rx * vx + ry * vy + rz * vz
        if rv > 0.0:
            spec = ks * rv ** shininess
    return cos_l * INV_PI, spec
