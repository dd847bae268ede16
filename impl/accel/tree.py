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

Memory layout of the traversal (issue 7).  The arrays above stay as the
builders emit them (:mod:`impl.accel.packets` reads them); the two
traversal kernels read a packed copy, :func:`pack_tree`, in ``acc_f``:

* one 32-byte record per node — its box as float32 rounded *outward* (lo
  down, hi up, so the box still contains its float64 box and no hit is
  lost), then two int32: ``a`` (first child's record / first entry of
  ``prim_idx``) and ``b`` (as ``node_b``);
* siblings adjacent and every sibling group starting at an even record,
  so the two children of a binary node — both boxes the traversal tests
  when it opens the node — share one 64-byte cache line (the buffer is
  64-byte aligned);
* groups in depth-first order: the group of a node's children follows the
  group holding the node's first sibling, so a descent reads forward.

A node visit used to read ``node_a``/``node_b`` of the node and two rows
of ``node_lo`` and ``node_hi`` per child: 3–4 cache lines in four arrays;
it now reads one line, the node's own record having been read with its
siblings' when its parent was opened (pbrt-v4's ``LinearBVHNode`` and
Embree's wide nodes make the same trade; the float32 boxes with outward
rounding are Embree's).  The box test itself is float64 as before; a box
grows by at most one float32 ulp per side, which can only add node visits,
never change a hit.  Measured on 256×192 camera rays through the SAH BVH of
the sphere fields: see ``gibench.studies_accel`` and the issue-7 notes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import carray, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..intersect import like
from .primitives import _slab64, closer, prim_test, ulp_above

__all__ = ["tree_closest", "tree_any", "STACK", "tree_depth", "pack_tree", "REC_WORDS"]

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
    """A traversal stack of STACK int64 on the native stack: the traversal kernels
    run once per ray, and two heap allocations per ray made the BVH queries of
    benchmarks/bench_accel.py 1.1–1.4× slower (measured on the shared 2-core VM).
    Only for functions that are *not* inlined into a loop (the space lives
    until the function returns)."""
    return carray(_alloca_i64(), STACK)


@njit(inline="always", cache=True)
def stack_f64():
    return carray(_alloca_f64(), STACK)


#: 32-bit words per packed node record: lo (3 × f32), hi (3 × f32), a, b (int32).
REC_WORDS = 8
_ALIGN = 128


@njit(inline="always", cache=True, error_model="numpy")
def rec_enter(f, r, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """:func:`impl.accel.primitives.box_enter` of packed record ``r`` (``f`` the records
    viewed as float32): the float64 slab test of its float32 box."""
    k = REC_WORDS * r
    t0, t1 = tmin, tmax
    t0, t1 = _slab64(f[k], f[k + 3], ox, ix, t0, t1)
    t0, t1 = _slab64(f[k + 1], f[k + 4], oy, iy, t0, t1)
    t0, t1 = _slab64(f[k + 2], f[k + 5], oz, iz, t0, t1)
    if t0 > t1:
        return math.inf
    return t0


@njit(cache=True)
def _record_order(node_a, node_b):
    """Record index of every node: depth-first, siblings adjacent, each sibling group
    at an even record (root at 0, record 1 padding).  ``(rec_of, n_records)``."""
    n = node_a.shape[0]
    rec_of = np.full(n, -1, dtype=np.int64)
    rec_of[0] = 0
    pos = 1
    stack = np.empty(n + 1, dtype=np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if node_b[node] >= 0:
            continue
        k = -node_b[node]
        pos += pos & 1                      # even start: a binary group fills one cache line
        for i in range(k):
            rec_of[node_a[node] + i] = pos + i
        pos += k
        for i in range(k - 1, -1, -1):      # first child popped first: its group comes next
            stack[sp] = node_a[node] + i
            sp += 1
    return rec_of, pos + (pos & 1)


@njit(cache=True)
def _fill_records(node_lo, node_hi, node_a, node_b, rec_of, f, w):
    m = f.shape[0] // REC_WORDS
    for r in range(m):                      # padding records: empty box, empty leaf
        for a in range(3):
            f[REC_WORDS * r + a] = np.inf
            f[REC_WORDS * r + 3 + a] = -np.inf
        w[REC_WORDS * r + 6] = 0
        w[REC_WORDS * r + 7] = 0
    down, up = np.float32(-np.inf), np.float32(np.inf)
    for i in range(node_a.shape[0]):
        r = rec_of[i]
        for a in range(3):
            f[REC_WORDS * r + a] = node_lo[i, a]
            f[REC_WORDS * r + 3 + a] = node_hi[i, a]
        w[REC_WORDS * r + 6] = rec_of[node_a[i]] if node_b[i] < 0 else node_a[i]
        w[REC_WORDS * r + 7] = node_b[i]


def pack_tree(node_lo, node_hi, node_a, node_b, n_prim_refs: int) -> np.ndarray:
    """The packed node records of a flattened tree (see the module docstring) as a
    64-byte-aligned float64 array (the type of ``RayConfig.acc_f``)."""
    n = len(node_a)
    rec_of, m = _record_order(np.ascontiguousarray(node_a, dtype=np.int64),
                              np.ascontiguousarray(node_b, dtype=np.int64))
    if n == 0 or np.any(rec_of < 0):
        raise ValueError(f"pack_tree: {int(np.sum(rec_of < 0))} of {n} nodes are not reachable "
                         "from the root (node_a/node_b do not describe a tree)")
    if m >= 2 ** 31 // REC_WORDS or n_prim_refs >= 2 ** 31:
        raise ValueError(f"pack_tree: {n} nodes / {n_prim_refs} primitive references exceed "
                         "the int32 offsets of the packed records")
    words = m * REC_WORDS
    raw = np.empty(words + _ALIGN // 8, dtype=np.float64)
    skip = (-raw.ctypes.data % _ALIGN) // 8
    buf = raw[skip:skip + words]
    _fill_records(np.ascontiguousarray(node_lo, dtype=np.float64),
                  np.ascontiguousarray(node_hi, dtype=np.float64),
                  node_a, node_b, rec_of, buf, buf.view(np.int64))
    return buf


@njit(cache=True, error_model="numpy")
def tree_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, nodes_visited, prim_tests)``; arguments and
    t in R's precision, prim = -1 on a miss."""
    f, w, idx = R.acc_f, R.acc_f.view(np.int64), R.prim_idx
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tmax, 0.0)
    nodes = tests = 0
    fox, foy, foz = float(ox), float(oy), float(oz)
    ix, iy, iz = 1.0 / float(dx), 1.0 / float(dy), 1.0 / float(dz)
    ftmin = float(tmin)
    t_root = rec_enter(f, 0, fox, foy, foz, ix, iy, iz, ftmin, float(tmax))
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
        a, b = np.int64(w[REC_WORDS * n + 6]), np.int64(w[REC_WORDS * n + 7])
        if b >= 0:
            # Leaf: the brute-force test of each primitive, tie-inclusive tmax.
            for k in range(a, a + b):
                p = idx[k]
                tests += 1
                t, b1, b2 = prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, ulp_above(best_t))
                if closer(t, p, best_t, best_p):
                    best_t, best_p, bb1, bb2 = t, p, b1, b2
        else:
            # Interior: push the children hit before best_t, nearest on top.
            fbest = float(best_t)
            sp0 = sp
            for c in range(a, a - b):
                tc = rec_enter(f, c, fox, foy, foz, ix, iy, iz, ftmin, fbest)
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
    f, w, idx = R.acc_f, R.acc_f.view(np.int64), R.prim_idx
    nodes = tests = 0
    fox, foy, foz = float(ox), float(oy), float(oz)
    ix, iy, iz = 1.0 / float(dx), 1.0 / float(dy), 1.0 / float(dz)
    ftmin, ftmax = float(tmin), float(tmax)
    if rec_enter(f, 0, fox, foy, foz, ix, iy, iz, ftmin, ftmax) == math.inf:
        return False, 1, 0
    stack_n = stack_i64()
    stack_n[0] = 0
    sp = 1
    zero = like(tmax, 0.0)
    while sp > 0:
        sp -= 1
        n = stack_n[sp]
        nodes += 1
        a, b = np.int64(w[REC_WORDS * n + 6]), np.int64(w[REC_WORDS * n + 7])
        if b >= 0:
            for k in range(a, a + b):
                tests += 1
                t, b1, b2 = prim_test(R, idx[k], ox, oy, oz, dx, dy, dz, tmin, tmax)
                if t > zero:
                    return True, nodes, tests
        else:
            for c in range(a, a - b):
                if rec_enter(f, c, fox, foy, foz, ix, iy, iz, ftmin, ftmax) != math.inf:
                    stack_n[sp] = c
                    sp += 1
    return False, nodes, tests


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
