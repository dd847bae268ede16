"""What every acceleration structure shares: primitive bounds and the primitive test.

An acceleration structure only decides *which* primitives a ray is tested
against (thesis 2.6: "ridurre il numero di test"); the test itself is the
brute-force one of :mod:`impl.intersect`, in the ray configuration's sphere
form and precision, so that an accelerated query returns the same closest hit
as brute force (same primitive id, same ``t``).

Conventions of every structure in :mod:`impl.accel`:

* Primitives are numbered as in :mod:`impl.scene_arrays`: spheres first, then
  triangles.
* Bounds (boxes, slabs, bounding spheres, grid cells) are float64 and padded
  by :func:`pad_of`: a hit point computed in float32 (or by the cancellation-
  prone algebraic sphere form) lies a few ulps off the exact surface, and the
  padding keeps it inside its primitive's bounds.
* Ties: brute force keeps the *first* primitive (lowest id) among hits at
  exactly the same ``t`` (its test needs ``t < best_t``).  The structures visit
  primitives in another order, so they test with ``tmax`` one ulp above
  ``best_t`` and keep a hit at equal ``t`` only if its id is lower
  (:func:`closer`): shared mesh edges then resolve as in brute force.
* Counters: each traversal returns the number of nodes (or cells, or bounding
  volumes) visited and of primitive tests with its hit, kept in two local
  integers (no memory traffic, no branch); the production path
  (:func:`impl.rays.hit`) drops them.  Their cost — two integer additions per
  node — was not measured apart.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from core.errors import ParamError

from ..intersect import like, ray_sphere_form, ray_triangle

__all__ = ["prim_bounds", "pad_of", "prim_test", "prim_test_arrays", "closer", "box_enter",
           "ulp_above"]

#: Relative padding of every bound, by precision (times the scene's largest
#: absolute coordinate + extent).  Float32 intersections carry errors of a few
#: hundred ulps of the coordinates in the worst (grazing) cases measured by the
#: equivalence test; float64 ones far less.
PAD_REL = {np.dtype(np.float32): 2e-5, np.dtype(np.float64): 1e-10}


def pad_of(lo, hi, dtype) -> float:
    """The absolute padding of the bounds of a scene with box [lo, hi]."""
    if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)):
        raise ParamError("accel: the scene has non-finite primitive coordinates")
    scale = float(max(np.max(np.abs(lo)), np.max(np.abs(hi)), np.max(hi - lo), 1e-30))
    return PAD_REL[np.dtype(dtype)] * scale


def prim_bounds(sph_center, sph_radius, tri_v):
    """Axis-aligned bounds ``(lo, hi)`` (P, 3) float64 of every primitive, padded
    (see :func:`pad_of`), from the primitives in their intersection precision."""
    c = np.asarray(sph_center, dtype=np.float64).reshape(-1, 3)
    r = np.abs(np.asarray(sph_radius, dtype=np.float64)).reshape(-1, 1)
    v = np.asarray(tri_v, dtype=np.float64).reshape(-1, 3, 3)
    lo = np.concatenate([c - r, v.min(axis=1)])
    hi = np.concatenate([c + r, v.max(axis=1)])
    if len(lo):
        pad = pad_of(lo.min(axis=0), hi.max(axis=0), np.asarray(sph_radius).dtype)
        lo -= pad
        hi += pad
    return np.ascontiguousarray(lo), np.ascontiguousarray(hi)


@intrinsic
def _next_up(typingctx, t):
    """``nextafter(t, +inf)`` of a float32 or float64 ``t`` from its IEEE 754 bits, inline
    (numba's ``np.nextafter`` calls a library function): a positive finite t
    has the next bit pattern, a negative t the previous one (-inf: the most
    negative finite number; the smallest negative subnormal: -0.0), ±0 the
    smallest positive subnormal; +inf and NaN are returned unchanged."""
    if not isinstance(t, types.Float):
        return None
    sig = t(t)

    def codegen(context, builder, sig, args):
        x = args[0]
        it = ir.IntType(sig.args[0].bitwidth)
        i = builder.bitcast(x, it)
        zero, inf = ir.Constant(x.type, 0.0), ir.Constant(x.type, math.inf)
        up = builder.bitcast(builder.add(i, ir.Constant(it, 1)), x.type)
        down = builder.bitcast(builder.sub(i, ir.Constant(it, 1)), x.type)
        tiny = builder.bitcast(ir.Constant(it, 1), x.type)
        cmp = builder.fcmp_ordered
        r = builder.select(cmp("<", x, zero), down, x)
        r = builder.select(cmp("==", x, zero), tiny, r)
        return builder.select(builder.and_(cmp(">", x, zero), cmp("<", x, inf)), up, r)

    return sig, codegen


@njit(inline="always", cache=True)
def ulp_above(t):
    """The next representable value above ``t`` in t's precision (a tie-inclusive tmax):
    ``np.nextafter(t, inf)``, computed inline (:func:`_next_up`)."""
    return _next_up(t)


@njit(inline="always", cache=True)
def closer(t, p, best_t, best_p):
    """Brute force's order: a hit at ``t`` of primitive ``p`` replaces ``(best_t, best_p)``
    when nearer, or at the same t with a lower primitive id."""
    return t > like(t, 0.0) and (t < best_t or (t == best_t and p < best_p))


@njit(inline="always", cache=True, error_model="numpy")
def prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Primitive ``p``'s hit ``(t, b1, b2)`` in R's form and precision (arguments in
    R's precision), ``t = -1`` on a miss — exactly the brute-force test."""
    return prim_test_arrays(R.form, R.sph_center, R.sph_radius, R.tri_v, p, ox, oy, oz, dx, dy,
                            dz, tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def prim_test_arrays(form, sc, sr, tv, p, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`prim_test` on the configuration's arrays, bound by the caller once per
    batch of rays (binding the whole configuration per ray increments and
    decrements the reference count of each of its arrays)."""
    ns = sr.shape[0]
    if p < ns:
        t = ray_sphere_form(form, ox, oy, oz, dx, dy, dz, sc[p, 0], sc[p, 1], sc[p, 2], sr[p],
                            tmin, tmax)
        return t, like(t, 0.0), like(t, 0.0)
    return ray_triangle(ox, oy, oz, dx, dy, dz, tv[p - ns], tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def _slab64(lo, hi, o, inv, t0, t1):
    """Clip (t0, t1) by the slab lo ≤ x ≤ hi; the near plane by the sign of 1/d
    (also for d = −0.0), so a NaN bound (0·inf) leaves t0 / t1 unchanged."""
    if inv < 0.0:
        lo, hi = hi, lo
    tn = (lo - o) * inv
    tf = (hi - o) * inv
    if tn > t0:
        t0 = tn
    if tf < t1:
        t1 = tf
    return t0, t1


@njit(inline="always", cache=True, error_model="numpy")
def box_enter(lo, hi, n, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """Kay–Kajiya slabs (thesis 1.3.3.2) of box ``n`` of the (N, 3) arrays lo/hi for a
    ray with reciprocal direction ``(ix, iy, iz)``, float64: the entry ``t`` of
    the part of [tmin, tmax] inside the closed box, or ``inf`` on a miss.

    Zero direction components give ±inf reciprocals; an origin on a slab plane
    then gives 0·inf = NaN, which the comparisons ignore (see
    :func:`impl.intersect.ray_box_inv`)."""
    t0, t1 = tmin, tmax
    t0, t1 = _slab64(lo[n, 0], hi[n, 0], ox, ix, t0, t1)
    t0, t1 = _slab64(lo[n, 1], hi[n, 1], oy, iy, t0, t1)
    t0, t1 = _slab64(lo[n, 2], hi[n, 2], oz, iz, t0, t1)
    if t0 > t1:
        return math.inf
    return t0
