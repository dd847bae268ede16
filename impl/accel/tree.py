"""Traversal of a flattened tree of axis-aligned boxes (thesis 2.6.1, Fig. 2.33).

Every hierarchy of :mod:`impl.accel` — the BVHs (median, SAH, Goldsmith–Salmon)
and the octree — is flattened into the same arrays, so one pair of kernels
traverses them all:

==========  ===========  ==============================================
array       shape        meaning
==========  ===========  ==============================================
node_lo/hi  (N, 3) f64   the node's box (padded, see primitives.py)
node_a      (N,) i64     first child (interior) / first entry of
                         ``prim_idx`` (leaf)
node_b      (N,) i64     ``-k``: interior with k consecutive children;
                         ``k >= 0``: leaf with k primitives
prim_idx    (M,) i64     the leaves' primitive ids
==========  ===========  ==============================================

Node 0 is the root.  The closest-hit traversal visits the children of a
node nearest box first (entry ``t`` of the slab test, thesis 1.3.3.2) and
skips a node whose box is entered beyond the nearest hit found so far, so
a leaf far behind a hit is never opened — the early termination that gives a
hierarchy its logarithmic cost (Kay & Kajiya 1986, their heap of candidate
nodes is this sorted stack).  The any-hit (shadow) traversal stops at the
first hit in (tmin, tmax), in any order.

Layout: the builders emit the nodes depth-first with siblings consecutive
(a node's children are allocated when it is split, and the first child is
split next), so a descent reads forward through the arrays.  The wide
collapse of the SAH tree, with float32 structure-of-arrays child boxes, is
:mod:`impl.accel.wide`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import carray, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..intersect import like
from .primitives import box_enter, closer, prim_test_arrays, ulp_above

__all__ = ["tree_closest", "tree_any", "tree_closest_rays", "tree_occluded_rays", "STACK",
           "tree_depth"]

#: Traversal stack entries: a binary tree of depth D needs D + 1, an octree
#: 7 per level; :func:`impl.accel.build` refuses a tree that needs more.
STACK = 160


@intrinsic
def _alloca_i64(typingctx):
    """STACK int64 on the native stack of the calling function (no heap allocation per ray)."""
    def codegen(context, builder, sig, args):
        return cgutils.alloca_once(builder, context.get_value_type(types.int64), size=STACK)
    return types.CPointer(types.int64)(), codegen


@intrinsic
def _alloca_f64(typingctx):
    def codegen(context, builder, sig, args):
        return cgutils.alloca_once(builder, context.get_value_type(types.float64), size=STACK)
    return types.CPointer(types.float64)(), codegen


@njit(inline="always", cache=True)
def stack_i64():
    """A traversal stack of STACK int64 on the native stack (no heap allocation per
    ray).  The space is allocated once in the entry block of the function it ends
    up in and lives until that function returns."""
    return carray(_alloca_i64(), STACK)


@njit(inline="always", cache=True)
def stack_f64():
    return carray(_alloca_f64(), STACK)


@njit(cache=True, error_model="numpy")
def tree_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, nodes_visited, prim_tests)``; arguments and
    t in R's precision, prim = -1 on a miss."""
    return _closest(R.node_lo, R.node_hi, R.node_a, R.node_b, R.prim_idx, R.form, R.sph_center,
                    R.sph_radius, R.tri_v, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def _closest(lo, hi, na, nb, idx, form, sc, sr, tv, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`tree_closest` on the configuration's arrays."""
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tmax, 0.0)
    nodes = tests = 0
    fox, foy, foz = float(ox), float(oy), float(oz)
    ix, iy, iz = 1.0 / float(dx), 1.0 / float(dy), 1.0 / float(dz)
    ftmin = float(tmin)
    t_root = box_enter(lo, hi, 0, fox, foy, foz, ix, iy, iz, ftmin, float(tmax))
    if t_root == math.inf:
        return best_t, best_p, bb1, bb2, 1, 0
    stack_n = stack_i64()
    stack_t = stack_f64()
    stack_n[0], stack_t[0] = 0, t_root
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack_n[sp]
        if stack_t[sp] > float(best_t):          # entered beyond the nearest hit: skip
            continue
        nodes += 1
        b = nb[n]
        if b >= 0:
            # Leaf: the brute-force test of each primitive, tie-inclusive tmax.
            for k in range(na[n], na[n] + b):
                p = idx[k]
                tests += 1
                t, b1, b2 = prim_test_arrays(form, sc, sr, tv, p, ox, oy, oz, dx, dy, dz, tmin,
                                             ulp_above(best_t))
                if closer(t, p, best_t, best_p):
                    best_t, best_p, bb1, bb2 = t, p, b1, b2
        else:
            # Interior: push the children hit before best_t, nearest on top.
            fbest = float(best_t)
            sp0 = sp
            for c in range(na[n], na[n] - b):
                tc = box_enter(lo, hi, c, fox, foy, foz, ix, iy, iz, ftmin, fbest)
                if tc != math.inf:
                    j = sp
                    while j > sp0 and stack_t[j - 1] < tc:
                        stack_t[j] = stack_t[j - 1]
                        stack_n[j] = stack_n[j - 1]
                        j -= 1
                    stack_t[j] = tc
                    stack_n[j] = c
                    sp += 1
    return best_t, best_p, bb1, bb2, nodes, tests


@njit(cache=True, error_model="numpy")
def tree_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax): ``(hit, nodes_visited, prim_tests)``."""
    return _any(R.node_lo, R.node_hi, R.node_a, R.node_b, R.prim_idx, R.form, R.sph_center,
                R.sph_radius, R.tri_v, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def _any(lo, hi, na, nb, idx, form, sc, sr, tv, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`tree_any` on the configuration's arrays."""
    nodes = tests = 0
    fox, foy, foz = float(ox), float(oy), float(oz)
    ix, iy, iz = 1.0 / float(dx), 1.0 / float(dy), 1.0 / float(dz)
    ftmin, ftmax = float(tmin), float(tmax)
    if box_enter(lo, hi, 0, fox, foy, foz, ix, iy, iz, ftmin, ftmax) == math.inf:
        return False, 1, 0
    stack_n = stack_i64()
    stack_n[0] = 0
    sp = 1
    zero = like(tmax, 0.0)
    while sp > 0:
        sp -= 1
        n = stack_n[sp]
        nodes += 1
        b = nb[n]
        if b >= 0:
            for k in range(na[n], na[n] + b):
                tests += 1
                t, b1, b2 = prim_test_arrays(form, sc, sr, tv, idx[k], ox, oy, oz, dx, dy, dz,
                                             tmin, tmax)
                if t > zero:
                    return True, nodes, tests
        else:
            for c in range(na[n], na[n] - b):
                if box_enter(lo, hi, c, fox, foy, foz, ix, iy, iz, ftmin, ftmax) != math.inf:
                    stack_n[sp] = c
                    sp += 1
    return False, nodes, tests


@njit(cache=True, error_model="numpy")
def tree_closest_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2):
    """Closest hits of the N rays given as float64 arrays (N,), one after the other,
    the configuration's arrays bound once: each ray rounded to R's precision as
    :func:`impl.rays.hit` rounds it; ``out_t`` (tmax on a miss), ``out_b1``,
    ``out_b2`` float64 (N,), ``out_prim`` int64 (N,) (-1 on a miss)."""
    lo, hi, na, nb, idx = R.node_lo, R.node_hi, R.node_a, R.node_b, R.prim_idx
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    for i in range(ox.shape[0]):
        t, p, b1, b2, _, _ = _closest(lo, hi, na, nb, idx, form, sc, sr, tv, like(sr, ox[i]),
                                      like(sr, oy[i]), like(sr, oz[i]), like(sr, dx[i]),
                                      like(sr, dy[i]), like(sr, dz[i]), like(sr, tmin[i]),
                                      like(sr, tmax[i]))
        out_t[i], out_prim[i], out_b1[i], out_b2[i] = float(t), p, float(b1), float(b2)


@njit(cache=True, error_model="numpy")
def tree_occluded_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit):
    """Any-hit of the N rays (float64 arrays (N,)) within (tmin[i], tmax[i]), one after
    the other, the configuration's arrays bound once: ``out_hit`` bool (N,)."""
    lo, hi, na, nb, idx = R.node_lo, R.node_hi, R.node_a, R.node_b, R.prim_idx
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    for i in range(ox.shape[0]):
        h, _, _ = _any(lo, hi, na, nb, idx, form, sc, sr, tv, like(sr, ox[i]), like(sr, oy[i]),
                       like(sr, oz[i]), like(sr, dx[i]), like(sr, dy[i]), like(sr, dz[i]),
                       like(sr, tmin[i]), like(sr, tmax[i]))
        out_hit[i] = h


@njit(cache=True)
def tree_depth(node_a, node_b):
    """Depth of the flattened tree (root = 1) and the largest stack the traversal
    can need (``sum over a path of children − 1``, + 1)."""
    n = node_a.shape[0]
    depth = np.zeros(n, dtype=np.int64)
    need = np.zeros(n, dtype=np.int64)
    depth[0], need[0] = 1, 1
    max_d = max_s = 1
    for i in range(n):                      # children come after their parent
        if node_b[i] < 0:
            k = -node_b[i]
            for c in range(node_a[i], node_a[i] + k):
                depth[c] = depth[i] + 1
                need[c] = need[i] + k - 1
                max_d = max(max_d, depth[c])
                max_s = max(max_s, need[c])
    return max_d, max_s
