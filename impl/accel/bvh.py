"""Bounding-volume hierarchies built top-down: median split and binned SAH (thesis 2.6.1).

Thesis 2.6.1 (after Kay & Kajiya 1986 and Goldsmith & Salmon 1987): a tree of
bounding volumes over the primitives; a ray that misses a node's volume skips
its whole subtree, so a ray costs about log n volume tests plus the tests of
the few primitives in the leaves it reaches.  The probability that a ray
hitting a volume A also hits a volume B inside it is S(B)/S(A), the ratio of
surface areas (for uniformly distributed rays), so the expected cost of a
node split into children L and R is

    C = C_trav + S(L)/S(A) · N_L · C_isect + S(R)/S(A) · N_R · C_isect,

the surface-area heuristic (SAH; MacDonald & Booth 1990) the thesis's
probability argument leads to.  Two top-down builders:

* ``median`` — split at the object median of the centroids along the axis of
  largest centroid extent (Kay & Kajiya's "median cut"), leaves of ≤ 2.
* ``sah`` — binned SAH (Wald 2007): 16 bins per axis over the centroid
  bounds, the split of least C over all three axes; a node becomes a leaf of
  ≤ 4 primitives when that is cheaper than its best split.  O(n log n), two
  passes over a node's primitives: one bins them along the three axes at
  once, one partitions them and gathers both children's box and centroid
  bounds, so a node split off by SAH needs no bounds pass of its own, and
  no SAH split allocates.

Both emit the flat layout of :mod:`impl.accel.tree` (binary: ``node_b = -2``),
traversed nearest child first by :func:`impl.accel.tree.tree_closest`.

Leaves out: spatial splits (SBVH), refitting for animation, compressed
nodes.  The collapse to wide nodes is :mod:`impl.accel.wide`.  The incremental Goldsmith–Salmon build is in
:mod:`impl.accel.goldsmith_salmon`.

References: T. L. Kay, J. T. Kajiya, "Ray tracing complex scenes", SIGGRAPH
1986; J. D. MacDonald, K. S. Booth, "Heuristics for ray tracing using space
subdivision", *The Visual Computer* 6, 1990; I. Wald, "On fast construction
of SAH-based bounding volume hierarchies", IEEE RT 2007.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["build_bvh", "MEDIAN", "SAH"]

MEDIAN, SAH = 0, 1
N_BINS = 16
SAH_LEAF_MAX = 4
MEDIAN_LEAF_MAX = 2
#: Below this depth a degenerate SAH split falls back to the median split, so
#: the tree stays within the traversal stack.
MAX_SAH_DEPTH = 48
C_TRAV, C_ISECT = 1.0, 1.0


@njit(inline="always", cache=True)
def _area(lx, ly, lz, hx, hy, hz):
    ex, ey, ez = hx - lx, hy - ly, hz - lz
    if ex < 0.0 or ey < 0.0 or ez < 0.0:
        return 0.0
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit(cache=True)
def _median_split(idx, cen, s, e, cmin, cmax):
    """Sort idx[s:e] by the centroid coordinate of the widest axis, split in the middle."""
    axis = 0
    if cmax[1] - cmin[1] > cmax[axis] - cmin[axis]:
        axis = 1
    if cmax[2] - cmin[2] > cmax[axis] - cmin[axis]:
        axis = 2
    seg = idx[s:e].copy()
    keys = np.empty(e - s)
    for k in range(e - s):
        keys[k] = cen[seg[k], axis]
    order = np.argsort(keys, kind="mergesort")
    for k in range(e - s):
        idx[s + k] = seg[order[k]]
    return s + (e - s) // 2


@njit(inline="always", cache=True)
def _sah_split(idx, lo, hi, cen, s, e, cmin, cmax, area_parent, cnt, blo, bhi, right_area,
               right_cnt, ok, k_scale, side_lo, side_hi, side_cmin, side_cmax):
    """Binned SAH: ``(mid, cost)`` of the best split of idx[s:e] (partitioned in
    place), or ``(-1, inf)`` when no bin boundary separates the centroids.

    One pass bins the primitives along all three axes at once (each primitive's
    bounds read once); a second pass partitions them and gathers each side's box
    and centroid bounds into ``side_lo``/``side_hi``/``side_cmin``/``side_cmax``
    (row 0: left, row 1: right), so the children need no pass of their own.  The
    arrays after ``area_parent`` are work buffers the caller allocates once."""
    # Bin along every axis with a non-zero centroid extent.
    for axis in range(3):
        ext = cmax[axis] - cmin[axis]
        ok[axis] = ext > 0.0
        k_scale[axis] = N_BINS * (1.0 - 1e-9) / ext if ok[axis] else 0.0
        for b in range(N_BINS):
            cnt[axis, b] = 0
            for a in range(3):
                blo[axis, b, a] = np.inf
                bhi[axis, b, a] = -np.inf
    for k in range(s, e):
        p = idx[k]
        for axis in range(3):
            if not ok[axis]:
                continue
            b = int((cen[p, axis] - cmin[axis]) * k_scale[axis])
            b = min(max(b, 0), N_BINS - 1)
            cnt[axis, b] += 1
            for a in range(3):
                blo[axis, b, a] = min(blo[axis, b, a], lo[p, a])
                bhi[axis, b, a] = max(bhi[axis, b, a], hi[p, a])
    # The cost of every bin boundary, axis by axis.
    best_cost, best_axis, best_bin = np.inf, -1, -1
    for axis in range(3):
        if not ok[axis]:
            continue
        # Sweep from the right: area and count of bins b..N_BINS-1.
        rl0, rl1, rl2 = np.inf, np.inf, np.inf
        rh0, rh1, rh2 = -np.inf, -np.inf, -np.inf
        rc = 0
        for b in range(N_BINS - 1, 0, -1):
            rl0, rl1, rl2 = min(rl0, blo[axis, b, 0]), min(rl1, blo[axis, b, 1]), min(rl2, blo[axis, b, 2])
            rh0, rh1, rh2 = max(rh0, bhi[axis, b, 0]), max(rh1, bhi[axis, b, 1]), max(rh2, bhi[axis, b, 2])
            rc += cnt[axis, b]
            right_area[b] = _area(rl0, rl1, rl2, rh0, rh1, rh2)
            right_cnt[b] = rc
        # Sweep from the left: split between bin b-1 and bin b.
        ll0, ll1, ll2 = np.inf, np.inf, np.inf
        lh0, lh1, lh2 = -np.inf, -np.inf, -np.inf
        lc = 0
        for b in range(1, N_BINS):
            ll0, ll1, ll2 = min(ll0, blo[axis, b - 1, 0]), min(ll1, blo[axis, b - 1, 1]), min(ll2, blo[axis, b - 1, 2])
            lh0, lh1, lh2 = max(lh0, bhi[axis, b - 1, 0]), max(lh1, bhi[axis, b - 1, 1]), max(lh2, bhi[axis, b - 1, 2])
            lc += cnt[axis, b - 1]
            if lc == 0 or right_cnt[b] == 0:
                continue
            cost = C_TRAV + C_ISECT * (_area(ll0, ll1, ll2, lh0, lh1, lh2) * lc
                                       + right_area[b] * right_cnt[b]) / area_parent
            if cost < best_cost:
                best_cost, best_axis, best_bin = cost, axis, b
    if best_axis < 0:
        return -1, np.inf
    # Partition idx[s:e], centroids in bins < best_bin first, gathering each side's bounds.
    for side in range(2):
        for a in range(3):
            side_lo[side, a], side_hi[side, a] = np.inf, -np.inf
            side_cmin[side, a], side_cmax[side, a] = np.inf, -np.inf
    c0, ks = cmin[best_axis], k_scale[best_axis]
    i, j = s, e - 1
    while i <= j:
        p = idx[i]
        b = int((cen[p, best_axis] - c0) * ks)
        b = min(max(b, 0), N_BINS - 1)
        side = 0 if b < best_bin else 1
        for a in range(3):
            side_lo[side, a] = min(side_lo[side, a], lo[p, a])
            side_hi[side, a] = max(side_hi[side, a], hi[p, a])
            side_cmin[side, a] = min(side_cmin[side, a], cen[p, a])
            side_cmax[side, a] = max(side_cmax[side, a], cen[p, a])
        if side == 0:
            i += 1
        else:
            idx[i], idx[j] = idx[j], p
            j -= 1
    return i, best_cost


@njit(cache=True)
def _build(lo, hi, method):
    P = lo.shape[0]
    cen = 0.5 * (lo + hi)
    idx = np.arange(P)
    cap = max(2 * P - 1, 1)
    nlo = np.empty((cap, 3))
    nhi = np.empty((cap, 3))
    na = np.empty(cap, dtype=np.int64)
    nb = np.empty(cap, dtype=np.int64)
    # Work stack: node, primitive range, depth, and whether the node's box and
    # centroid bounds are known already (set by its parent's SAH partition).
    st_node = np.empty(256, dtype=np.int64)
    st_s = np.empty(256, dtype=np.int64)
    st_e = np.empty(256, dtype=np.int64)
    st_d = np.empty(256, dtype=np.int64)
    st_known = np.zeros(256, dtype=np.bool_)
    st_cmin = np.empty((256, 3))
    st_cmax = np.empty((256, 3))
    st_node[0], st_s[0], st_e[0], st_d[0] = 0, 0, P, 1
    sp = 1
    n_nodes = 1
    cmin = np.empty(3)
    cmax = np.empty(3)
    # The SAH split's work buffers, allocated once.
    cnt = np.empty((3, N_BINS), dtype=np.int64)
    blo = np.empty((3, N_BINS, 3))
    bhi = np.empty((3, N_BINS, 3))
    right_area = np.empty(N_BINS)
    right_cnt = np.empty(N_BINS, dtype=np.int64)
    ok = np.empty(3, dtype=np.bool_)
    k_scale = np.empty(3)
    side_lo = np.empty((2, 3))
    side_hi = np.empty((2, 3))
    side_cmin = np.empty((2, 3))
    side_cmax = np.empty((2, 3))
    max_depth = 1
    while sp > 0:
        sp -= 1
        node, s, e, depth = st_node[sp], st_s[sp], st_e[sp], st_d[sp]
        max_depth = max(max_depth, depth)
        if st_known[sp]:
            for a in range(3):
                cmin[a], cmax[a] = st_cmin[sp, a], st_cmax[sp, a]
        else:
            # The node's box and its centroid bounds.
            for a in range(3):
                nlo[node, a], nhi[node, a] = np.inf, -np.inf
                cmin[a], cmax[a] = np.inf, -np.inf
            for k in range(s, e):
                p = idx[k]
                for a in range(3):
                    nlo[node, a] = min(nlo[node, a], lo[p, a])
                    nhi[node, a] = max(nhi[node, a], hi[p, a])
                    cmin[a] = min(cmin[a], cen[p, a])
                    cmax[a] = max(cmax[a], cen[p, a])
        count = e - s
        mid = -1
        known = False                            # the children's bounds from the partition
        if method == MEDIAN:
            if count > MEDIAN_LEAF_MAX:
                mid = _median_split(idx, cen, s, e, cmin, cmax)
        elif count > 1:
            area = _area(nlo[node, 0], nlo[node, 1], nlo[node, 2],
                         nhi[node, 0], nhi[node, 1], nhi[node, 2])
            if depth < MAX_SAH_DEPTH and area > 0.0:
                mid, cost = _sah_split(idx, lo, hi, cen, s, e, cmin, cmax, area, cnt, blo, bhi,
                                       right_area, right_cnt, ok, k_scale,
                                       side_lo, side_hi, side_cmin, side_cmax)
                known = mid >= 0
                if count <= SAH_LEAF_MAX and cost >= C_ISECT * count:
                    mid = -1                     # the leaf is cheaper than any split
                elif mid < 0 and count > SAH_LEAF_MAX:
                    mid = _median_split(idx, cen, s, e, cmin, cmax)
            elif count > SAH_LEAF_MAX:
                mid = _median_split(idx, cen, s, e, cmin, cmax)
        if mid <= s or mid >= e:
            na[node], nb[node] = s, count             # leaf
            continue
        c = n_nodes
        n_nodes += 2
        na[node], nb[node] = c, -2
        if sp + 2 > st_node.shape[0]:
            raise RuntimeError("bvh build: work stack overflow")
        st_node[sp], st_s[sp], st_e[sp], st_d[sp] = c + 1, mid, e, depth + 1
        st_node[sp + 1], st_s[sp + 1], st_e[sp + 1], st_d[sp + 1] = c, s, mid, depth + 1
        st_known[sp], st_known[sp + 1] = known, known
        if known:
            for side in range(2):
                n_, k_ = c + side, sp + 1 - side
                for a in range(3):
                    nlo[n_, a], nhi[n_, a] = side_lo[side, a], side_hi[side, a]
                    st_cmin[k_, a], st_cmax[k_, a] = side_cmin[side, a], side_cmax[side, a]
        sp += 2
    return nlo[:n_nodes].copy(), nhi[:n_nodes].copy(), na[:n_nodes].copy(), nb[:n_nodes].copy(), idx, max_depth


def build_bvh(lo, hi, method: str):
    """A BVH over primitive bounds ``lo``/``hi`` (P, 3): the flat arrays
    ``(node_lo, node_hi, node_a, node_b, prim_idx)`` of :mod:`impl.accel.tree`.

    ``method``: ``"median"`` or ``"sah"``.  P must be ≥ 1.
    """
    codes = {"median": MEDIAN, "sah": SAH}
    if method not in codes:
        raise ValueError(f"build_bvh: unknown method {method!r} (valid: median, sah)")
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape or len(lo) == 0:
        raise ValueError(f"build_bvh: lo and hi must be (P>=1, 3), got {lo.shape} and {hi.shape}")
    nlo, nhi, na, nb, idx, depth = _build(lo, hi, codes[method])
    return nlo, nhi, na, nb, idx
