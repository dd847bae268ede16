"""Bounding-volume hierarchy by incremental insertion (Goldsmith & Salmon 1987; thesis 2.6.1).

Goldsmith and Salmon build the hierarchy one object at a time: each new
object descends from the root along the path where adding it increases the
expected cost least — the cost of a node being its surface area, the
probability S(B)/S(A) of thesis 2.6.1 that a ray hitting the parent also
hits it — and is finally paired with the node where it stops.  Here the
binary form of that greedy descent: at node N with children L and R, with
the object's box b,

* pairing b with N here (a new parent of N and b) costs S(N ∪ b);
* descending into child C costs the growth of N, S(N ∪ b) − S(N), plus
  S(C ∪ b) − S(C) (and S(C ∪ b) when C is a leaf, for the new parent there);

the cheaper choice wins, and the boxes on the path are refitted.  Objects are
inserted in a fixed pseudo-random order (seed 0): Goldsmith and Salmon
report that sorted input orders (as scene files often are) build poor trees.

The tree is then flattened to the layout of :mod:`impl.accel.tree` (leaves of
one primitive) and traversed like the top-down BVHs of :mod:`impl.accel.bvh`.

Leaves out: the original's n-ary nodes and its choice among several
insertion orders by estimated cost.

Reference: J. Goldsmith, J. Salmon, "Automatic creation of object hierarchies
for ray tracing", *IEEE CG&A* 7(5), 1987.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["build_goldsmith_salmon"]


@njit(inline="always", cache=True)
def _area_union(blo, bhi, n, plo, phi):
    ex = max(bhi[n, 0], phi[0]) - min(blo[n, 0], plo[0])
    ey = max(bhi[n, 1], phi[1]) - min(blo[n, 1], plo[1])
    ez = max(bhi[n, 2], phi[2]) - min(blo[n, 2], plo[2])
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit(inline="always", cache=True)
def _area(blo, bhi, n):
    ex, ey, ez = bhi[n, 0] - blo[n, 0], bhi[n, 1] - blo[n, 1], bhi[n, 2] - blo[n, 2]
    return 2.0 * (ex * ey + ey * ez + ez * ex)


@njit(cache=True)
def _insert_all(lo, hi, order):
    P = lo.shape[0]
    cap = 2 * P
    blo = np.empty((cap, 3))
    bhi = np.empty((cap, 3))
    left = np.full(cap, -1, dtype=np.int64)
    right = np.full(cap, -1, dtype=np.int64)
    parent = np.full(cap, -1, dtype=np.int64)
    prim = np.full(cap, -1, dtype=np.int64)
    blo[0], bhi[0], prim[0] = lo[order[0]], hi[order[0]], order[0]
    root, n = 0, 1
    for k in range(1, P):
        p = order[k]
        plo, phi = lo[p], hi[p]
        # Greedy descent by least surface-area increase.
        node = root
        while prim[node] < 0:
            here = _area_union(blo, bhi, node, plo, phi)
            grow = here - _area(blo, bhi, node)
            best_c, best_cost = -1, here
            for c in (left[node], right[node]):
                cu = _area_union(blo, bhi, c, plo, phi)
                cost = grow + cu - _area(blo, bhi, c)
                if prim[c] >= 0:
                    cost += cu
                if cost < best_cost:
                    best_c, best_cost = c, cost
            if best_c < 0:
                break
            node = best_c
        # New leaf for p and a new parent of (node, leaf) in node's place.
        leaf, inner = n, n + 1
        n += 2
        blo[leaf], bhi[leaf], prim[leaf] = plo, phi, p
        up = parent[node]
        left[inner], right[inner], parent[inner] = node, leaf, up
        parent[node] = inner
        parent[leaf] = inner
        for a in range(3):
            blo[inner, a] = min(blo[node, a], plo[a])
            bhi[inner, a] = max(bhi[node, a], phi[a])
        if up < 0:
            root = inner
        elif left[up] == node:
            left[up] = inner
        else:
            right[up] = inner
        # Refit the ancestors.
        while up >= 0:
            for a in range(3):
                blo[up, a] = min(blo[up, a], plo[a])
                bhi[up, a] = max(bhi[up, a], phi[a])
            up = parent[up]
    return blo[:n], bhi[:n], left[:n], right[:n], prim[:n], root


@njit(cache=True)
def _flatten(blo, bhi, left, right, prim, root):
    """Breadth-first renumbering: the two children of a node get consecutive slots."""
    n = blo.shape[0]
    n_leaves = 0
    for i in range(n):
        if prim[i] >= 0:
            n_leaves += 1
    nlo = np.empty((n, 3))
    nhi = np.empty((n, 3))
    na = np.empty(n, dtype=np.int64)
    nb = np.empty(n, dtype=np.int64)
    idx = np.empty(n_leaves, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)       # old ids in new order
    queue[0] = root
    head, tail, leaf_k = 0, 1, 0
    while head < tail:
        old = queue[head]
        nlo[head], nhi[head] = blo[old], bhi[old]
        if prim[old] >= 0:
            na[head], nb[head] = leaf_k, 1
            idx[leaf_k] = prim[old]
            leaf_k += 1
        else:
            na[head], nb[head] = tail, -2
            queue[tail], queue[tail + 1] = left[old], right[old]
            tail += 2
        head += 1
    return nlo, nhi, na, nb, idx


def build_goldsmith_salmon(lo, hi, *, seed: int = 0):
    """The Goldsmith–Salmon BVH over primitive bounds ``lo``/``hi`` (P, 3) as the
    flat arrays ``(node_lo, node_hi, node_a, node_b, prim_idx)``."""
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape or len(lo) == 0:
        raise ValueError(f"build_goldsmith_salmon: lo and hi must be (P>=1, 3), "
                         f"got {lo.shape} and {hi.shape}")
    order = np.random.default_rng(seed).permutation(len(lo)).astype(np.int64)
    return _flatten(*_insert_all(lo, hi, order))
