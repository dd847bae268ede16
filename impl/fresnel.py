"""Specular reflection and refraction at a smooth interface: the law of
reflection, Snell's law with total internal reflection, and the exact
unpolarised Fresnel reflectance of dielectrics and conductors (thesis 2.4.4).

Conventions (Mitsuba 3's, so that ``whitted`` can be checked against it):

* Normals point *outward*.  ``cos_theta_i`` is the cosine between the normal
  and the direction *towards* the viewer (``−I``); it is positive on the
  outside, where the medium is the exterior one.
* ``eta = n_int / n_ext`` is the relative index of the interface.  Seen from
  the side the light travels in, ``eta_it = n_t / n_i`` (``eta`` outside,
  ``1/eta`` inside) and ``eta_ti = 1 / eta_it``.
* A conductor's index is complex, ``eta + i k`` with ``k ≥ 0``.

Formulas
--------
Reflection (thesis 2.4.4): ``R = I − 2 (N·I) N``.

Snell's law ``n_i sin θ_i = n_t sin θ_t`` gives
``sin² θ_t = eta_ti² (1 − cos² θ_i)``; when that reaches 1 there is no
transmitted wave (total internal reflection).  Writing the transmitted
direction as ``T = α I + β N`` (the thesis's form) with ``α = eta_ti`` and
``β = eta_ti cos θ_i + cos θ_t`` (``cos θ_t`` signed: opposite to
``cos θ_i``, since T leaves on the other side) keeps T unit length.

Fresnel amplitudes for the s (perpendicular) and p (parallel) waves, with
``c_i = |cos θ_i|``, ``c_t = |cos θ_t|`` (Hecht, *Optics*, 4th ed., §4.6)::

    r_s = (c_i − eta_it c_t) / (c_i + eta_it c_t)
    r_p = (eta_it c_i − c_t) / (eta_it c_i + c_t)
    R   = (r_s² + r_p²) / 2                      (unpolarised light)

and the transmittances ``T_{s,p} = eta_it c_t / c_i · t_{s,p}²`` with
``t_s = 2 c_i / (c_i + eta_it c_t)``, ``t_p = 2 c_i / (eta_it c_i + c_t)``,
which satisfy ``R_{s,p} + T_{s,p} = 1`` (energy conservation, checked in the
tests rather than assumed).

For a conductor the relative index ``η = eta + i k`` is complex; with
``w = sqrt(η² − sin² θ_i)`` (principal root, ``w = η cos θ_t``)::

    r_s = (cos θ_i − w) / (cos θ_i + w)
    r_p = (η² cos θ_i − w) / (η² cos θ_i + w)
    R   = (|r_s|² + |r_p|²) / 2

Mitsuba's ``material="none"`` conductor is ``η = 0 + 1i``, for which R = 1.

All functions are scalar ``@njit`` kernels with no side effects.
"""

import math

from numba import njit
from core.errors import SceneError

__all__ = ["reflect", "fresnel_dielectric", "fresnel_dielectric_sp", "fresnel_dielectric_t_sp",
           "refract", "snell_refract", "fresnel_conductor", "IOR_TABLE", "lookup_ior"]

#: Named indices of refraction at ~589 nm, 0–20 °C (Hecht, *Optics*, 4th ed.),
#: the names Mitsuba 3's ``dielectric`` accepts for ``int_ior``/``ext_ior``.
IOR_TABLE = {
    "vacuum": 1.0,
    "helium": 1.000036,
    "hydrogen": 1.000132,
    "air": 1.000277,
    "carbon dioxide": 1.00045,
    "water": 1.3330,
    "acetone": 1.36,
    "ethanol": 1.361,
    "carbon tetrachloride": 1.461,
    "glycerol": 1.4729,
    "benzene": 1.501,
    "silicone oil": 1.52045,
    "bromine": 1.661,
    "water ice": 1.31,
    "fused quartz": 1.458,
    "pyrex": 1.470,
    "acrylic glass": 1.49,
    "polypropylene": 1.49,
    "bk7": 1.5046,
    "sodium chloride": 1.544,
    "amber": 1.55,
    "pet": 1.5750,
    "diamond": 2.419,
}


def lookup_ior(value, *, what: str = "ior") -> float:
    """An index of refraction from a number or a name of :data:`IOR_TABLE` (case-insensitive).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones) or a negative value.
    """
    if isinstance(value, str):
        key = value.strip().lower()
        if key not in IOR_TABLE:
            raise SceneError(f"{what}: unknown index of refraction name '{value}' "
                             f"(known: {', '.join(IOR_TABLE)}; or give a number)")
        return IOR_TABLE[key]
    v = float(value)
    if not v >= 0.0:
        raise SceneError(f"{what}: index of refraction must be positive, got {value!r}")
    return v


@njit(inline="always", cache=True)
def reflect(ix, iy, iz, nx, ny, nz):
    """Mirror direction R = I − 2 (N·I) N of the incident direction I about the unit normal N."""
    d = 2.0 * (nx * ix + ny * iy + nz * iz)
    return ix - d * nx, iy - d * ny, iz - d * nz


@njit(cache=True)
def fresnel_dielectric_sp(cos_theta_i, eta):
    """(R_s, R_p, cos_theta_t, eta_it, eta_ti) of a dielectric interface.

    ``cos_theta_t`` is signed (opposite to ``cos_theta_i``) and 0 under total
    internal reflection, where R_s = R_p = 1.  ``eta == 1`` (index-matched)
    gives R_s = R_p = 0 exactly.
    """
    if cos_theta_i >= 0.0:
        eta_it = eta
    else:
        eta_it = 1.0 / eta
    eta_ti = 1.0 / eta_it
    c_i = abs(cos_theta_i)
    # Snell: sin²θ_t = eta_ti² sin²θ_i.
    sin2_t = eta_ti * eta_ti * max(0.0, 1.0 - c_i * c_i)
    if eta == 1.0:
        return 0.0, 0.0, -cos_theta_i, eta_it, eta_ti
    if sin2_t >= 1.0:                   # total internal reflection
        return 1.0, 1.0, 0.0, eta_it, eta_ti
    c_t = math.sqrt(1.0 - sin2_t)
    r_s = (c_i - eta_it * c_t) / (c_i + eta_it * c_t)
    r_p = (eta_it * c_i - c_t) / (eta_it * c_i + c_t)
    cos_t = -c_t if cos_theta_i >= 0.0 else c_t
    return r_s * r_s, r_p * r_p, cos_t, eta_it, eta_ti


@njit(cache=True)
def fresnel_dielectric_t_sp(cos_theta_i, eta):
    """(T_s, T_p): power transmittances from the transmission amplitudes (0 under TIR)."""
    if cos_theta_i >= 0.0:
        eta_it = eta
    else:
        eta_it = 1.0 / eta
    c_i = abs(cos_theta_i)
    sin2_t = max(0.0, 1.0 - c_i * c_i) / (eta_it * eta_it)
    if sin2_t >= 1.0 or c_i == 0.0:
        return 0.0, 0.0
    c_t = math.sqrt(1.0 - sin2_t)
    t_s = 2.0 * c_i / (c_i + eta_it * c_t)
    t_p = 2.0 * c_i / (eta_it * c_i + c_t)
    k = eta_it * c_t / c_i              # ratio of beam cross-sections × impedances
    return k * t_s * t_s, k * t_p * t_p


@njit(cache=True)
def fresnel_dielectric(cos_theta_i, eta):
    """Unpolarised reflectance: (F, cos_theta_t, eta_it, eta_ti), as Mitsuba's ``fresnel``.

    F = 1 and cos_theta_t = 0 under total internal reflection.
    """
    r_s, r_p, cos_t, eta_it, eta_ti = fresnel_dielectric_sp(cos_theta_i, eta)
    return 0.5 * (r_s + r_p), cos_t, eta_it, eta_ti


@njit(inline="always", cache=True)
def refract(ix, iy, iz, nx, ny, nz, cos_theta_i, cos_theta_t, eta_ti):
    """Transmitted direction T = eta_ti I + (eta_ti cos θ_i + cos θ_t) N (signed cosines).

    ``I`` is the incident direction (towards the surface), ``N`` the outward
    normal and ``cos_theta_i = −N·I``; ``cos_theta_t`` and ``eta_ti`` come
    from :func:`fresnel_dielectric`.
    """
    b = eta_ti * cos_theta_i + cos_theta_t
    return eta_ti * ix + b * nx, eta_ti * iy + b * ny, eta_ti * iz + b * nz


@njit(cache=True)
def snell_refract(ix, iy, iz, nx, ny, nz, eta):
    """Snell's law for unit I and outward unit N of an interface of relative index ``eta``.

    Returns ``(tx, ty, tz, tir)``: the transmitted unit direction and False,
    or the mirror direction and True under total internal reflection.
    """
    cos_i = -(nx * ix + ny * iy + nz * iz)
    _, cos_t, _, eta_ti = fresnel_dielectric(cos_i, eta)
    sin2_t = eta_ti * eta_ti * max(0.0, 1.0 - cos_i * cos_i)
    if eta != 1.0 and sin2_t >= 1.0:
        rx, ry, rz = reflect(ix, iy, iz, nx, ny, nz)
        return rx, ry, rz, True
    tx, ty, tz = refract(ix, iy, iz, nx, ny, nz, cos_i, cos_t, eta_ti)
    return tx, ty, tz, False


@njit(cache=True, inline="always")
def fresnel_conductor(cos_theta_i, eta, k):
    """Unpolarised reflectance of a conductor of complex relative index eta + i k.

    The complex amplitudes above, squared in real arithmetic (Born & Wolf,
    *Principles of Optics*, §14.2; the form of S. Lagarde, "Memo on Fresnel
    equations", 2013): with ``s² = 1 − c²``, ``t = eta² − k² − s²``,
    ``a² + b² = |w|² = sqrt(t² + 4 eta² k²)`` and ``a = Re w = sqrt((a² + b² + t) / 2)``
    (for t < 0 computed as ``|eta k| / b`` with ``b = sqrt((a² + b² − t) / 2)``, which
    does not cancel)::

        R_s = (a² + b² + c² − 2ac) / (a² + b² + c² + 2ac)
        R_p = R_s (c²(a² + b²) + s⁴ − 2ac s²) / (c²(a² + b²) + s⁴ + 2ac s²)
        R   = (R_s + R_p) / 2

    The denominators vanish only where the complex form's do: at grazing incidence on
    an index-matched interface (1 + 0i; R_s = 1, the complex form's value) and, for the
    second, at normal incidence with the degenerate index 0 + 0i (R_p = R_s).  Grazing
    incidence, total internal reflection (k = 0, a = 0) and Mitsuba's
    ``material="none"`` (0 + 1i) otherwise need no special case: all give 1.  Real
    square roots and divisions only, where the complex form takes a complex root, two
    complex divisions and three moduli (``hypot``).  Mitsuba's default ``material="none"``
    (an ideal mirror) returns that 1 without the arithmetic."""
    if eta == 0.0 and k == 1.0:
        return 1.0
    c = min(abs(cos_theta_i), 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    ab2 = math.sqrt(t * t + 4.0 * eta * eta * k * k)
    if t >= 0.0:                        # a = Re w, without cancellation: a b = eta k
        a = math.sqrt(0.5 * (ab2 + t))
    else:
        a = abs(eta * k) / math.sqrt(0.5 * (ab2 - t))
    u = ab2 + c2
    v = 2.0 * a * c
    r_s = (u - v) / (u + v) if u + v > 0.0 else 1.0
    p = ab2 * c2 + s2 * s2
    q = v * s2
    d = p + q
    return 0.5 * r_s * (1.0 + ((p - q) / d if d > 0.0 else 1.0))
