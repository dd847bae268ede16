"""Octree: non-uniform space subdivision (thesis 2.6.2; Glassner 1984).

Thesis 2.6.2: a uniform grid wastes voxels on empty space and overloads the
voxels of dense regions; an octree subdivides only where the primitives are.
The scene's box is cut into eight octants, recursively, while a cell holds
more than ``LEAF_MAX`` primitives (padded bounding boxes overlapping the cell)
and is shallower than ``MAX_DEPTH``, unless the split cannot separate them:
a cell whose children would together hold more than ``DUP_MAX`` times its
references (cells already smaller than the primitives, or many overlapping
boxes there), or whose fullest child would keep them all, stays a leaf.
Without that rule a finely tessellated mesh makes millions of tiny cells
wherever more than ``LEAF_MAX`` triangle boxes overlap.  Empty octants get
no node.

Traversal: the octree is flattened to the layout of :mod:`impl.accel.tree`
(up to eight children per node), each node's box tightened to its octant ∩
the boxes of its primitives, and traversed by the same nearest-first kernel
as the BVHs: children sorted by the entry ``t`` of their boxes, a node
entered beyond the nearest hit skipped.  A primitive lying in several cells
may be tested more than once (no mailbox), and a hit outside the current cell
is kept (any real hit is a valid candidate; cells entered beyond it are
pruned), so no nearer hit is missed.

Leaves out: Glassner's hashed cell lookup and neighbour-finding traversal
(point location by descending from the root for each cell); the SAH kd-tree.

Reference: A. S. Glassner, "Space subdivision for fast ray tracing",
*IEEE CG&A* 4(10), 1984.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .tree import STACK, tree_depth

__all__ = ["build_octree", "LEAF_MAX", "MAX_DEPTH"]

LEAF_MAX = 8
MAX_DEPTH = 16
DUP_MAX = 4


@njit(cache=True)
def _grow_f(a, n):
    if n <= a.shape[0]:
        return a
    b = np.empty((max(n, 2 * a.shape[0]), a.shape[1]))
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def _grow_i(a, n):
    if n <= a.shape[0]:
        return a
    b = np.empty(max(n, 2 * a.shape[0]), dtype=np.int64)
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def _build(lo, hi, leaf_max, max_depth):
    P = lo.shape[0]
    cap = 64
    nlo = np.empty((cap, 3))         # traversal box (tightened)
    nhi = np.empty((cap, 3))
    clo = np.empty((cap, 3))         # cell (octant) box
    chi = np.empty((cap, 3))
    na = np.empty(cap, dtype=np.int64)
    nb = np.empty(cap, dtype=np.int64)
    depth = np.empty(cap, dtype=np.int64)
    rs = np.empty(cap, dtype=np.int64)  # each pending node's segment of `work` (a LIFO stack)
    rc = np.empty(cap, dtype=np.int64)
    work = np.empty(max(2 * P, 16), dtype=np.int64)
    work[:P] = np.arange(P)
    w_top = P
    out = np.empty(max(P, 16), dtype=np.int64)
    n_out = 0
    # Root cell: the scene box.
    for a in range(3):
        clo[0, a] = lo[:, a].min()
        chi[0, a] = hi[:, a].max()
        nlo[0, a], nhi[0, a] = clo[0, a], chi[0, a]
    depth[0], rs[0], rc[0] = 1, 0, P
    n_nodes = 1
    stack = np.empty(1024, dtype=np.int64)
    stack[0] = 0
    sp = 1
    kid_cnt = np.zeros(8, dtype=np.int64)
    while sp > 0:
        sp -= 1
        node = stack[sp]
        s, cnt = rs[node], rc[node]
        split = cnt > leaf_max and depth[node] < max_depth
        if split:
            # Count the primitives of each octant (box overlap).
            mid = 0.5 * (clo[node] + chi[node])
            kid_cnt[:] = 0
            for k in range(s, s + cnt):
                p = work[k]
                for o in range(8):
                    ok = True
                    for a in range(3):
                        if (o >> a) & 1:
                            ok = ok and hi[p, a] >= mid[a]
                        else:
                            ok = ok and lo[p, a] <= mid[a]
                    if ok:
                        kid_cnt[o] += 1
            # A split that cannot separate the primitives (the children together would
            # hold more than DUP_MAX times the references: cells smaller than the
            # primitives, or many boxes overlapping there) makes a leaf instead.
            split = kid_cnt.sum() <= DUP_MAX * cnt and kid_cnt.max() < cnt
        if not split:
            out = _grow_i(out, n_out + cnt)
            out[n_out:n_out + cnt] = work[s:s + cnt]
            na[node], nb[node] = n_out, cnt
            n_out += cnt
            w_top = s                        # LIFO: this node's segment is the topmost
            continue
        n_kids = np.count_nonzero(kid_cnt)
        first = n_nodes
        need = n_nodes + n_kids
        if need > nlo.shape[0]:
            nlo, nhi = _grow_f(nlo, need), _grow_f(nhi, need)
            clo, chi = _grow_f(clo, need), _grow_f(chi, need)
            na, nb, depth = _grow_i(na, need), _grow_i(nb, need), _grow_i(depth, need)
            rs, rc = _grow_i(rs, need), _grow_i(rc, need)
        work = _grow_i(work, w_top + kid_cnt.sum())
        na[node], nb[node] = first, -n_kids
        mid = 0.5 * (clo[node] + chi[node])
        c = first
        for o in range(8):
            if kid_cnt[o] == 0:
                continue
            for a in range(3):
                if (o >> a) & 1:
                    clo[c, a], chi[c, a] = mid[a], chi[node, a]
                else:
                    clo[c, a], chi[c, a] = clo[node, a], mid[a]
                nlo[c, a], nhi[c, a] = np.inf, -np.inf
            rs[c] = w_top
            for k in range(s, s + cnt):
                p = work[k]
                ok = True
                for a in range(3):
                    if (o >> a) & 1:
                        ok = ok and hi[p, a] >= mid[a]
                    else:
                        ok = ok and lo[p, a] <= mid[a]
                if ok:
                    work[w_top] = p
                    w_top += 1
                    for a in range(3):
                        nlo[c, a] = min(nlo[c, a], lo[p, a])
                        nhi[c, a] = max(nhi[c, a], hi[p, a])
            rc[c] = w_top - rs[c]
            # Tighten to the octant ∩ the primitives' boxes.
            for a in range(3):
                nlo[c, a] = max(nlo[c, a], clo[c, a])
                nhi[c, a] = min(nhi[c, a], chi[c, a])
            depth[c] = depth[node] + 1
            if sp >= stack.shape[0]:
                stack = _grow_i(stack, sp + 1)
            stack[sp] = c
            sp += 1
            c += 1
        n_nodes = need
        # The parent's segment is dead: move the children's segments down onto it,
        # so that `work` holds only the segments of pending nodes.
        shift = w_top - (s + cnt)
        work[s:s + shift] = work[s + cnt:w_top].copy()
        for q in range(first, need):
            rs[q] -= cnt
        w_top = s + shift
    return (nlo[:n_nodes].copy(), nhi[:n_nodes].copy(), na[:n_nodes].copy(),
            nb[:n_nodes].copy(), out[:n_out].copy())


def build_octree(lo, hi, *, leaf_max=LEAF_MAX, max_depth=MAX_DEPTH):
    """An octree over primitive bounds ``lo``/``hi`` (P, 3), flattened to the arrays
    ``(node_lo, node_hi, node_a, node_b, prim_idx)`` of :mod:`impl.accel.tree`."""
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape or len(lo) == 0:
        raise ValueError(f"build_octree: lo and hi must be (P>=1, 3), got {lo.shape} and {hi.shape}")
    arrays = _build(lo, hi, leaf_max, max_depth)
    _, need = tree_depth(arrays[2], arrays[3])
    if need > STACK:
        raise RuntimeError(f"build_octree: traversal would need {need} stack entries (> {STACK})")
    return arrays
