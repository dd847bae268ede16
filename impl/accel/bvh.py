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
  ≤ 4 primitives when that is cheaper than its best split.  O(n log n): a
  10⁶-triangle build takes seconds (see the scaling study).

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


@njit(cache=True)
def _sah_split(idx, lo, hi, cen, s, e, cmin, cmax, area_parent):
    """Binned SAH: ``(mid, cost)`` of the best split of idx[s:e] (partitioned in
    place), or ``(-1, inf)`` when no bin boundary separates the centroids."""
    best_cost, best_axis, best_bin = np.inf, -1, -1
    cnt = np.zeros(N_BINS, dtype=np.int64)
    blo = np.empty((N_BINS, 3))
    bhi = np.empty((N_BINS, 3))
    right_area = np.empty(N_BINS)
    right_cnt = np.empty(N_BINS, dtype=np.int64)
    for axis in range(3):
        ext = cmax[axis] - cmin[axis]
        if not ext > 0.0:
            continue
        k_scale = N_BINS * (1.0 - 1e-9) / ext
        cnt[:] = 0
        blo[:, :] = np.inf
        bhi[:, :] = -np.inf
        for k in range(s, e):
            p = idx[k]
            b = int((cen[p, axis] - cmin[axis]) * k_scale)
            b = min(max(b, 0), N_BINS - 1)
            cnt[b] += 1
            for a in range(3):
                blo[b, a] = min(blo[b, a], lo[p, a])
                bhi[b, a] = max(bhi[b, a], hi[p, a])
        # Sweep from the right: area and count of bins b..N_BINS-1.
        rl = np.full(3, np.inf)
        rh = np.full(3, -np.inf)
        rc = 0
        for b in range(N_BINS - 1, 0, -1):
            for a in range(3):
                rl[a] = min(rl[a], blo[b, a])
                rh[a] = max(rh[a], bhi[b, a])
            rc += cnt[b]
            right_area[b] = _area(rl[0], rl[1], rl[2], rh[0], rh[1], rh[2])
            right_cnt[b] = rc
        # Sweep from the left: split between bin b-1 and bin b.
        ll = np.full(3, np.inf)
        lh = np.full(3, -np.inf)
        lc = 0
        for b in range(1, N_BINS):
            for a in range(3):
                ll[a] = min(ll[a], blo[b - 1, a])
                lh[a] = max(lh[a], bhi[b - 1, a])
            lc += cnt[b - 1]
            if lc == 0 or right_cnt[b] == 0:
                continue
            cost = C_TRAV + C_ISECT * (_area(ll[0], ll[1], ll[2], lh[0], lh[1], lh[2]) * lc
                                       + right_area[b] * right_cnt[b]) / area_parent
            if cost < best_cost:
                best_cost, best_axis, best_bin = cost, axis, b
    if best_axis < 0:
        return -1, np.inf
    # Partition idx[s:e]: centroids in bins < best_bin first.
    ext = cmax[best_axis] - cmin[best_axis]
    k_scale = N_BINS * (1.0 - 1e-9) / ext
    i, j = s, e - 1
    while i <= j:
        b = int((cen[idx[i], best_axis] - cmin[best_axis]) * k_scale)
        b = min(max(b, 0), N_BINS - 1)
        if b < best_bin:
            i += 1
        else:
            idx[i], idx[j] = idx[j], idx[i]
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
    st_node = np.empty(256, dtype=np.int64)
    st_s = np.empty(256, dtype=np.int64)
    st_e = np.empty(256, dtype=np.int64)
    st_d = np.empty(256, dtype=np.int64)
    st_node[0], st_s[0], st_e[0], st_d[0] = 0, 0, P, 1
    sp = 1
    n_nodes = 1
    cmin = np.empty(3)
    cmax = np.empty(3)
    max_depth = 1
    while sp > 0:
        sp -= 1
        node, s, e, depth = st_node[sp], st_s[sp], st_e[sp], st_d[sp]
        max_depth = max(max_depth, depth)
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
        if method == MEDIAN:
            if count > MEDIAN_LEAF_MAX:
                mid = _median_split(idx, cen, s, e, cmin, cmax)
        elif count > 1:
            area = _area(nlo[node, 0], nlo[node, 1], nlo[node, 2],
                         nhi[node, 0], nhi[node, 1], nhi[node, 2])
            if depth < MAX_SAH_DEPTH and area > 0.0:
                mid, cost = _sah_split(idx, lo, hi, cen, s, e, cmin, cmax, area)
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
