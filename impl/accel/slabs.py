"""Kay–Kajiya slabs with a configurable set of plane normals (thesis 1.3.3.2, 2.6.1).

Kay and Kajiya (1986) bound each object by k pairs of parallel planes, the
*slabs* ``d_near ≤ n_j · x ≤ d_far`` for a fixed set of normals ``n_j``
shared by all objects.  A ray ``o + t d`` lies inside slab j for
``t ∈ [(d_near − n_j·o)/(n_j·d), (d_far − n_j·o)/(n_j·d)]`` (swapped when
``n_j·d < 0``); it meets the volume iff the intersection of the k intervals
is not empty.  ``n_j·o`` and ``1/(n_j·d)`` are computed once per ray, so a
volume costs 2k multiply-adds.  Three axis normals give the axis-aligned box;
Kay and Kajiya's seven add the four cube diagonals, which bound rotated and
round objects much more tightly (the parallelepipeds of their Fig. 2);
thirteen add the six face diagonals.

Here the slabs bound each object (per-object volumes, cost n·B + m·I as in
:mod:`impl.accel.bounding_volumes`); the hierarchy of Kay and Kajiya's paper
is the BVH of :mod:`impl.accel.bvh` (with 3 normals).

Parameter ``slab_normals`` = 3, 7 or 13.

Layout in the ray configuration: ``acc_f`` (3k,) the unit normals,
``node_lo``/``node_hi`` (O, k) ``d_near``/``d_far`` per object (padded),
``node_a`` (O + 1,) each object's first entry of ``prim_idx``.

Reference: T. L. Kay, J. T. Kajiya, "Ray tracing complex scenes",
SIGGRAPH 1986.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.errors import ParamError

from ..intersect import like
from .bounding_volumes import group_objects
from .primitives import _slab64, closer, pad_of, prim_test, ulp_above

__all__ = ["slab_normals", "build_slabs", "slabs_closest", "slabs_any", "SLAB_COUNTS"]

SLAB_COUNTS = (3, 7, 13)


def slab_normals(k: int) -> np.ndarray:
    """The k unit plane normals (k = 3 axes, 7 = + cube diagonals, 13 = + face diagonals)."""
    if k not in SLAB_COUNTS:
        raise ParamError(f"slabs: slab_normals must be one of {SLAB_COUNTS}, got {k}")
    axes = np.eye(3)
    cube = np.array([[1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]]) / math.sqrt(3.0)
    face = np.array([[1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1], [0, 1, 1], [0, 1, -1]]) / math.sqrt(2.0)
    return np.concatenate([axes, cube, face][: {3: 1, 7: 2, 13: 3}[k]])


def build_slabs(lo, hi, sph_center, sph_radius, tri_v, prim_shape, k: int):
    """Per-object slab extents ``(d_near (O, k), d_far (O, k))``, normals (3k,), offsets, prim_idx."""
    normals = slab_normals(k)
    n_s = len(sph_radius)
    offsets, idx = group_objects(prim_shape, len(lo))
    c = np.asarray(sph_center, dtype=np.float64).reshape(-1, 3)
    r = np.abs(np.asarray(sph_radius, dtype=np.float64))
    v = np.asarray(tri_v, dtype=np.float64).reshape(-1, 3, 3)
    # Extent of every primitive along every normal: n·c ± r, or min/max of n·v.
    pn = np.empty((len(idx), k))
    pf = np.empty((len(idx), k))
    if n_s:
        dc = c @ normals.T
        pn[:n_s], pf[:n_s] = dc - r[:, None], dc + r[:, None]
    if len(v):
        dv = v @ normals.T                               # (T, 3, k)
        pn[n_s:], pf[n_s:] = dv.min(axis=1), dv.max(axis=1)
    pad = pad_of(lo.min(axis=0), hi.max(axis=0), np.asarray(sph_radius).dtype)
    d_near = np.minimum.reduceat(pn[idx], offsets[:-1], axis=0) - pad
    d_far = np.maximum.reduceat(pf[idx], offsets[:-1], axis=0) + pad
    return (np.ascontiguousarray(d_near), np.ascontiguousarray(d_far),
            np.ascontiguousarray(normals.reshape(-1)), offsets, idx)


@njit(inline="always", cache=True)
def _ray_slab_terms(nrm, k, ox, oy, oz, dx, dy, dz):
    no = np.empty(k)
    inv = np.empty(k)
    for j in range(k):
        no[j] = nrm[3 * j] * ox + nrm[3 * j + 1] * oy + nrm[3 * j + 2] * oz
        inv[j] = 1.0 / (nrm[3 * j] * dx + nrm[3 * j + 1] * dy + nrm[3 * j + 2] * dz)
    return no, inv


@njit(inline="always", cache=True)
def _slabs_enter(dn, df, o, k, no, inv, tmin, tmax):
    t0, t1 = tmin, tmax
    for j in range(k):
        t0, t1 = _slab64(dn[o, j], df[o, j], no[j], inv[j], t0, t1)
        if t0 > t1:
            return math.inf
    return t0


@njit(cache=True, error_model="numpy")
def slabs_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, volumes_tested, prim_tests)``."""
    dn, df, off, idx = R.node_lo, R.node_hi, R.node_a, R.prim_idx
    k = dn.shape[1]
    no, inv = _ray_slab_terms(R.acc_f, k, float(ox), float(oy), float(oz),
                              float(dx), float(dy), float(dz))
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tmax, 0.0)
    ftmin = float(tmin)
    n_obj = off.shape[0] - 1
    tests = 0
    for o in range(n_obj):
        if _slabs_enter(dn, df, o, k, no, inv, ftmin, float(best_t)) == math.inf:
            continue
        for q in range(off[o], off[o + 1]):
            p = idx[q]
            tests += 1
            t, b1, b2 = prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, ulp_above(best_t))
            if closer(t, p, best_t, best_p):
                best_t, best_p, bb1, bb2 = t, p, b1, b2
    return best_t, best_p, bb1, bb2, n_obj, tests


@njit(cache=True, error_model="numpy")
def slabs_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax): ``(hit, volumes_tested, prim_tests)``."""
    dn, df, off, idx = R.node_lo, R.node_hi, R.node_a, R.prim_idx
    k = dn.shape[1]
    no, inv = _ray_slab_terms(R.acc_f, k, float(ox), float(oy), float(oz),
                              float(dx), float(dy), float(dz))
    ftmin, ftmax = float(tmin), float(tmax)
    zero = like(tmax, 0.0)
    tests = 0
    for o in range(off.shape[0] - 1):
        if _slabs_enter(dn, df, o, k, no, inv, ftmin, ftmax) == math.inf:
            continue
        for q in range(off[o], off[o + 1]):
            tests += 1
            t, b1, b2 = prim_test(R, idx[q], ox, oy, oz, dx, dy, dz, tmin, tmax)
            if t > zero:
                return True, o + 1, tests
    return False, off.shape[0] - 1, tests
