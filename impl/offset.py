"""Self-intersection of secondary rays: where a ray leaving a surface starts (thesis 2.3.4).

A shadow, reflected or refracted ray starts at a computed hit point ``p``
which lies off the true surface by its rounding error; tested against the
surface it starts on, it can find it again at a tiny ``t`` ("shadow acne",
thesis fig. 2.9).  The thesis names two remedies — flag the origin as on the
surface, or ignore hits below a minimum ``t`` — and this module offers four
strategies, all taking the hit point and the unit geometric normal ``n``
*facing the side the new ray leaves towards* (flip it for transmission or for
a light behind the surface):

=========  ===========================================  =====================
strategy   spawned ray                                   parameter
=========  ===========================================  =====================
tmin       origin p, hits below ``tmin = eps`` ignored   eps (absolute)
normal     origin p + eps·n, tmin = 0                    eps (absolute)
scaled     origin p + eps·(1 + max|p_i|)·n, tmin = 0     eps (relative; the
                                                         rule of
                                                         ``direct_light``)
robust     origin moved by integer ulps ∝ n, tmin = 0    none (Wächter &
                                                         Binder 2019)
=========  ===========================================  =====================

An absolute ``eps`` must exceed the hit point's error, which grows with the
distance from the world origin (about u·|p|, u the unit roundoff); too large
and shadow rays step over nearby occluders (light leaking at contacts).  The
robust offset scales with each coordinate's own magnitude instead — which has
the same limit far from the origin: 256 ulps of a float32 coordinate of 6·10⁴
is 1 unit, so there it steps over occluders closer than that (measured by the
``self_intersection`` study of :mod:`gibench.studies.intersection`).

Precision follows the argument types (float32 or float64), as in
:mod:`impl.intersect`.

References
----------
C. Wächter, N. Binder, "A fast and robust method for avoiding
self-intersection", *Ray Tracing Gems*, ch. 6, 2019.

Leaves out: the error-bound-driven offsets of pbrt-v3/v4 (which carry a
per-hit error interval ``pError`` through the intersection code).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic, overload
from numba.np.numpy_support import as_dtype

from .intersect import like

__all__ = [
    "STRATEGIES", "ORIGIN", "FLOAT_SCALE", "INT_SCALE",
    "float_as_int", "int_as_float", "offset_normal", "offset_scaled", "offset_ray", "spawn", "spawn_select",
]

#: Strategy names, in the order of :func:`spawn`'s ``strategy`` code.
STRATEGIES = ("tmin", "normal", "scaled", "robust")

# Wächter & Binder's constants, for float32 as in the paper and for float64.
#
# INT_SCALE — the offset in units in the last place per unit normal component.
#   The error of a computed hit point is a small multiple of ulp(p) in each
#   coordinate (a few roundings of numbers of that magnitude); the authors
#   chose 256 empirically to clear it.  Counted in ulps, this bound does not
#   depend on the format, so float64 keeps 256.
# FLOAT_SCALE — the absolute offset used near zero.  A coordinate near 0 has
#   tiny ulps while its error comes from larger operands (vertices and origins
#   of scene scale, ~1), so the relative offset would be too small; the paper
#   uses 1/65536 = 2⁻¹⁶ = 2⁷·ε₃₂ (ε₃₂ = 2⁻²³, the spacing of floats at 1):
#   128 float32 ulps of a unit-scale quantity.  For float64 the same 128 ulps
#   of 1 are 2⁷·ε₆₄ = 2⁻⁴⁵.
# ORIGIN — below this magnitude a coordinate counts as "near zero".  It is a
#   statement about the scene scale (the 1 above), not about the format, so
#   float64 keeps 1/32; at the switch the absolute offset is 16× the relative
#   one in both formats (2⁻¹⁶ vs 256·ulp₃₂(1/32) = 2⁻²⁰; 2⁻⁴⁵ vs 2⁻⁴⁹).
INT_SCALE = 256
ORIGIN = 1.0 / 32.0
FLOAT_SCALE = {"float32": 2.0 ** -16, "float64": 2.0 ** -45}


@intrinsic
def float_as_int(typingctx, x):
    """The bits of a float32 (float64) as an int32 (int64), like C++'s ``bit_cast``."""
    if isinstance(x, types.Float):
        ity = types.int32 if x.bitwidth == 32 else types.int64

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(ity))
        return ity(x), codegen
    return None


@intrinsic
def int_as_float(typingctx, i):
    """The float32 (float64) whose bits are the int32 (int64) ``i``."""
    if isinstance(i, types.Integer) and i.bitwidth in (32, 64):
        fty = types.float32 if i.bitwidth == 32 else types.float64

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(fty))
        return fty(i), codegen
    return None


def _float_scale(x):
    """FLOAT_SCALE of the float format of ``x`` (numba kernels only)."""
    return FLOAT_SCALE[np.dtype(type(x)).name]


@overload(_float_scale, inline="always")
def _float_scale_overload(x):
    if isinstance(x, types.Float):
        fs = as_dtype(x).type(FLOAT_SCALE[str(x)])

        def impl(x):
            return fs
        return impl
    return None


def _add_ulps(p, k):
    """The float whose bits are those of ``p`` plus the integer ``k`` (numba kernels only)."""
    raise NotImplementedError("_add_ulps is for numba kernels only")


@overload(_add_ulps, inline="always")
def _add_ulps_overload(p, k):
    if isinstance(p, types.Float):
        ity = np.int32 if p.bitwidth == 32 else np.int64

        def impl(p, k):
            # Integer arithmetic promotes to int64: cast back to the float's width.
            return int_as_float(ity(float_as_int(p) + k))
        return impl
    return None


@njit(inline="always", cache=True)
def _offset_component(p, n):
    # Near zero: absolute offset FLOAT_SCALE·n.
    if abs(p) < like(p, ORIGIN):
        return p + _float_scale(p) * n
    # Elsewhere: move p by of_i = ⌊256·n⌋ ulps (truncated toward zero, as the
    # paper's int conversion) in the direction of n.  Floats of one sign are
    # ordered like their bit patterns read as integers, by magnitude: adding
    # to the bits of a positive p moves it up, subtracting from the bits of a
    # negative p moves it towards zero, i.e. also up.
    of_i = int(like(p, INT_SCALE) * n)
    if p < like(p, 0.0):
        of_i = -of_i
    return _add_ulps(p, of_i)


@njit(cache=True)
def offset_ray(px, py, pz, nx, ny, nz):
    """Wächter & Binder (RTG ch. 6): the origin of a ray leaving the surface at
    p towards the side of the unit normal n, moved off the surface by an integer
    number of ulps of each coordinate proportional to n.  Use it with tmin = 0.
    """
    return _offset_component(px, nx), _offset_component(py, ny), _offset_component(pz, nz)


@njit(inline="always", cache=True)
def offset_normal(px, py, pz, nx, ny, nz, eps):
    """Origin p + eps·n (a fixed offset along the normal); use it with tmin = 0."""
    return px + eps * nx, py + eps * ny, pz + eps * nz


@njit(inline="always", cache=True)
def offset_scaled(px, py, pz, nx, ny, nz, eps):
    """Origin p + eps·(1 + max|p_i|)·n: an offset relative to the magnitude of p
    (so that it stays above the rounding error, about u·|p|, far from the
    origin), as ``impl.lighting.direct_light`` does with ``SHADOW_EPSILON``; use it with tmin = 0."""
    m = max(abs(px), abs(py), abs(pz))
    return offset_normal(px, py, pz, nx, ny, nz, eps * (like(px, 1.0) + m))


@njit(cache=True)
def spawn(strategy, px, py, pz, nx, ny, nz, eps):
    """Origin and tmin of a ray leaving p on the side of n: ``(ox, oy, oz, tmin)``.

    ``strategy`` is an index into :data:`STRATEGIES`: 0 = tmin (origin p,
    tmin = eps), 1 = normal (origin p + eps·n, tmin = 0), 2 = scaled (origin
    p + eps·(1 + max|p_i|)·n, tmin = 0), 3 = robust (the Wächter–Binder
    offset, eps ignored, tmin = 0).  ``n`` must face the side the ray leaves to.
    """
    zero = like(px, 0.0)
    if strategy == 0:
        return px, py, pz, eps
    if strategy == 1:
        ox, oy, oz = offset_normal(px, py, pz, nx, ny, nz, eps)
        return ox, oy, oz, zero
    if strategy == 2:
        ox, oy, oz = offset_scaled(px, py, pz, nx, ny, nz, eps)
        return ox, oy, oz, zero
    ox, oy, oz = offset_ray(px, py, pz, nx, ny, nz)
    return ox, oy, oz, zero



@njit(inline="always", cache=True)
def spawn_select(strategy, px, py, pz, nx, ny, nz, eps):
    """:func:`spawn` without branches, for loops that LLVM vectorises over rays: every
    strategy's origin computed with the same operations as there, the one of
    ``strategy`` selected (so the result has the same bits)."""
    zero = like(px, 0.0)
    rx, ry, rz = _offset_select(px, nx), _offset_select(py, ny), _offset_select(pz, nz)
    ax, ay, az = offset_normal(px, py, pz, nx, ny, nz, eps)
    bx, by, bz = offset_scaled(px, py, pz, nx, ny, nz, eps)
    robust, normal, scaled = strategy == 3, strategy == 1, strategy == 2
    ox = rx if robust else (ax if normal else (bx if scaled else px))
    oy = ry if robust else (ay if normal else (by if scaled else py))
    oz = rz if robust else (az if normal else (bz if scaled else pz))
    return ox, oy, oz, (eps if strategy == 0 else zero)


@njit(inline="always", cache=True)
def _offset_select(p, n):
    """:func:`_offset_component` with selects instead of branches (same operations)."""
    near = p + _float_scale(p) * n
    of_i = int(like(p, INT_SCALE) * n)
    of_i = -of_i if p < like(p, 0.0) else of_i
    far = _add_ulps(p, of_i)
    return near if abs(p) < like(p, ORIGIN) else far
