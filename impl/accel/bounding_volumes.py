"""Per-object bounding volumes: spheres and boxes (thesis 1.3.3.1–2, 2.6.1).

Thesis 2.6.1: enclose each object (a scene shape: one sphere, or all the
triangles of one mesh) in a simple volume and test the volume first; only a
ray that hits it is tested against the object's primitives.  With n objects,
of which m have their volume hit, a ray costs

    n · B + m · I

(B the cost of a bounding-volume test, I of testing an object's primitives)
instead of n · I: a gain when the objects are complex (meshes) and B ≪ I,
none for a scene of single spheres, where the volume *is* the object.  The
volumes are not nested (that is the hierarchy of :mod:`impl.accel.bvh`), so
the cost stays linear in n.

* ``bv`` — axis-aligned boxes, tested by Kay–Kajiya slabs (thesis 1.3.3.2);
* ``bv-sphere`` — bounding spheres (thesis 1.3.3.1): the box centre and the
  largest distance from it to the object (vertices; sphere centre + radius),
  tested as "does the segment (tmin, t_best) come within the radius".

Objects are visited in shape order; a box or sphere entered beyond the
nearest hit found so far is skipped (its primitives cannot be nearer).

Layout in the ray configuration: ``node_lo``/``node_hi`` (O, 3) the boxes,
``acc_f`` (O·4,) the spheres (centre, radius), ``node_a`` (O + 1,) each
object's first entry of ``prim_idx``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..intersect import like
from .primitives import box_enter, closer, pad_of, prim_test, ulp_above

__all__ = ["build_objects", "bv_closest", "bv_any", "BOX", "SPHERE"]

BOX, SPHERE = 0, 1


def group_objects(prim_shape, n_prims):
    """Primitive ids grouped by object: ``(offsets (O + 1,), prim_idx (P,))``."""
    shape = np.asarray(prim_shape, dtype=np.int64)
    if shape.shape != (n_prims,):
        raise ValueError(f"accel: prim_shape must have one entry per primitive ({n_prims}), "
                         f"got shape {shape.shape}")
    order = np.argsort(shape, kind="stable").astype(np.int64)
    _, counts = np.unique(shape[order], return_counts=True)
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), order


def build_objects(lo, hi, sph_center, sph_radius, tri_v, prim_shape):
    """Per-object boxes ``(O, 3)`` ×2, spheres ``(O·4,)``, offsets and prim_idx."""
    n_s = len(sph_radius)
    offsets, idx = group_objects(prim_shape, len(lo))
    O = len(offsets) - 1
    blo = np.minimum.reduceat(lo[idx], offsets[:-1], axis=0)
    bhi = np.maximum.reduceat(hi[idx], offsets[:-1], axis=0)
    centre = 0.5 * (blo + bhi)
    c = np.asarray(sph_center, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(sph_radius, dtype=np.float64)
    v = np.asarray(tri_v, dtype=np.float64).reshape(-1, 3, 3)
    # Largest distance from the object's box centre to each primitive.
    obj = np.repeat(np.arange(O), np.diff(offsets))
    reach = np.empty(len(idx))
    is_s = idx < n_s
    ps = idx[is_s]
    reach[is_s] = np.linalg.norm(c[ps] - centre[obj[is_s]], axis=1) + np.abs(r[ps])
    pt = idx[~is_s] - n_s
    if len(pt):
        reach[~is_s] = np.linalg.norm(v[pt] - centre[obj[~is_s]][:, None, :], axis=2).max(axis=1)
    radius = np.maximum.reduceat(reach, offsets[:-1])
    radius += pad_of(blo.min(axis=0), bhi.max(axis=0), np.asarray(sph_radius).dtype)
    spheres = np.concatenate([centre, radius[:, None]], axis=1).reshape(-1)
    return np.ascontiguousarray(blo), np.ascontiguousarray(bhi), spheres, offsets, idx


@njit(inline="always", cache=True)
def _sphere_enter(sph, o, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Entry t (approximately; ≤ the t of any point inside) of the segment (tmin, tmax)
    into bounding sphere o, or inf: the segment's point nearest the centre."""
    cx, cy, cz, r = sph[4 * o], sph[4 * o + 1], sph[4 * o + 2], sph[4 * o + 3]
    fx, fy, fz = cx - ox, cy - oy, cz - oz
    s = (fx * dx + fy * dy + fz * dz) / (dx * dx + dy * dy + dz * dz)
    s = min(max(s, tmin), tmax)
    qx, qy, qz = ox + s * dx - cx, oy + s * dy - cy, oz + s * dz - cz
    if qx * qx + qy * qy + qz * qz > r * r:
        return math.inf
    return tmin


@njit(cache=True, error_model="numpy")
def bv_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, volumes_tested, prim_tests)``: n·B + m·I."""
    kind = R.acc_i[0]
    off, idx = R.node_a, R.prim_idx
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tmax, 0.0)
    fox, foy, foz, fdx, fdy, fdz = float(ox), float(oy), float(oz), float(dx), float(dy), float(dz)
    ix, iy, iz = 1.0 / fdx, 1.0 / fdy, 1.0 / fdz
    ftmin = float(tmin)
    n_obj = off.shape[0] - 1
    tests = 0
    for o in range(n_obj):
        fbest = float(best_t)
        if kind == BOX:
            te = box_enter(R.node_lo, R.node_hi, o, fox, foy, foz, ix, iy, iz, ftmin, fbest)
        else:
            te = _sphere_enter(R.acc_f, o, fox, foy, foz, fdx, fdy, fdz, ftmin, fbest)
        if te == math.inf:
            continue
        for k in range(off[o], off[o + 1]):
            p = idx[k]
            tests += 1
            t, b1, b2 = prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, ulp_above(best_t))
            if closer(t, p, best_t, best_p):
                best_t, best_p, bb1, bb2 = t, p, b1, b2
    return best_t, best_p, bb1, bb2, n_obj, tests


@njit(cache=True, error_model="numpy")
def bv_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax): ``(hit, volumes_tested, prim_tests)``."""
    kind = R.acc_i[0]
    off, idx = R.node_a, R.prim_idx
    fox, foy, foz, fdx, fdy, fdz = float(ox), float(oy), float(oz), float(dx), float(dy), float(dz)
    ix, iy, iz = 1.0 / fdx, 1.0 / fdy, 1.0 / fdz
    ftmin, ftmax = float(tmin), float(tmax)
    zero = like(tmax, 0.0)
    tests = 0
    for o in range(off.shape[0] - 1):
        if kind == BOX:
            te = box_enter(R.node_lo, R.node_hi, o, fox, foy, foz, ix, iy, iz, ftmin, ftmax)
        else:
            te = _sphere_enter(R.acc_f, o, fox, foy, foz, fdx, fdy, fdz, ftmin, ftmax)
        if te == math.inf:
            continue
        for k in range(off[o], off[o + 1]):
            tests += 1
            t, b1, b2 = prim_test(R, idx[k], ox, oy, oz, dx, dy, dz, tmin, tmax)
            if t > zero:
                return True, o + 1, tests
    return False, off.shape[0] - 1, tests
