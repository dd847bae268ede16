"""A wide BVH: the binary SAH tree collapsed to nodes of WIDTH children (thesis 2.6.1).

The hierarchy is the one of :mod:`impl.accel.bvh` (binned SAH); only its
storage and traversal change.  Each wide node holds the boxes of up to
:data:`WIDTH` children structure-of-arrays, ``lo_x[W] lo_y[W] lo_z[W]
hi_x[W] hi_y[W] hi_z[W]`` (the layout of Embree's BVH4 nodes), so one ray
meets all the children in W-lane vector operations (:func:`_enter_all`): per
axis the near and far planes are picked once per ray from the sign of the
direction, so each plane costs one subtract and one multiply by the
precomputed reciprocal direction, with no per-child swap and no branch.
(Embree's ``box·rdir − org·rdir`` saves the subtract with a fused
multiply-subtract; ``(box − org)·rdir`` is kept here because it rounds
exactly as :func:`.primitives.box_enter`.)

Collapse (Wald, Benthin, Boulos 2008; Embree's BVH4 builder): starting
from a binary node's two children, the interior child of largest surface
area is replaced by its two children until the node has W children or
only leaves remain; a subtree of at most :data:`LEAF_MAX` primitives becomes
one leaf (a leaf's test of a few primitives is cheaper than the stack work
of opening them one node at a time).

Exactness.  The boxes are stored in float32, each coordinate rounded
outward (``lo`` down, ``hi`` up) from the padded float64 bounds of
:mod:`.primitives`, so every stored box contains its float64 box.  The slab
test reads them into float64 and computes exactly as
:func:`.primitives.box_enter` does (same NaN rule for zero direction
components): a ray enters every box the float64 tree would let it enter,
and the primitives it reaches are tested with the same arithmetic, in the
configured form and precision, with the same tie rule (:func:`.closer`).
So the closest hit (primitive id and ``t``) is brute force's.  The float64
arithmetic is a choice, not a necessity: with W = 4 (AVX2) or 8 (AVX-512)
lanes a float64 plane costs as many vector instructions as a float32 one,
and it needs no error bound on the origin's float32 rounding.

Leaves.  A leaf's primitives are stored again, structure of arrays, in groups
of :data:`LANES` (:func:`_leaf_groups`, in the configured precision): its
spheres (``cx cy cz r`` per lane), then its triangles (``v0``, ``e1 = v1 −
v0``, ``e2 = v2 − v0`` per lane).  A group is tested in one vector test: the
stable ray–sphere test (:func:`_sph_lanes`) or Möller–Trumbore
(:func:`_tri_lanes`), each the operations of the scalar test
(:func:`impl.intersect.ray_sphere_stable`, :func:`impl.intersect.ray_triangle`)
lane by lane, so each lane's hit is the scalar test's bit for bit; the lanes'
hits are then kept in the tie rule's order.  Spheres of the algebraic and
geometric forms (the thesis's ablation of the test) keep the scalar test.  All
of a group is tested against the nearest hit at the leaf's entry; a lane hit
that a smaller limit would have rejected is not nearer, so
:func:`.closer` drops it and the result is that of one-by-one tests.

Traversal (:func:`_trace`, one skeleton for both queries): nearest child
first (children sorted by entry ``t`` on the stack), popped entries entered
beyond the nearest hit skipped; shadow rays (:func:`wide_any`) push the
children in slot order and stop at the first hit in (tmin, tmax).  A node's
children's references sit in its record beside their boxes, so opening a node
reads one 128-byte record.  The per-ray code reads the arrays through raw data
pointers bound once per batch (:func:`wide_bind`): an array passed to an inlined
helper costs an atomic increment and decrement of its reference count per
call, which numba's reference-count pruning does not remove from a traversal
loop with several exits.

Entry points: :func:`wide_closest` / :func:`wide_any` (one ray, with
counters: what :func:`impl.accel.closest` dispatches to); over SoA ray
arrays, one after the other, :func:`wide_closest_rays` /
:func:`wide_occluded_rays` (the tracers' batches: the arrays bound once, the
traversal inlined into the loop), the same in parallel,
:func:`wide_closest_batch` / :func:`wide_occluded_batch`, and, for coherent rays,
:func:`wide_closest_packets` / :func:`wide_occluded_packets`: groups of
consecutive rays traversed as packets (Wald, Slusallek, Benthin, Wagner
2001) — each child box tested against the packet's active rays in one
vectorised loop, rays leaving the packet for single-ray traversal when
:data:`SWITCH` or fewer still enter a node (Embree's hybrid traversal).
Every entry point returns exactly the single-ray answer.  For a bundle of rays
bounded by a frustum, :func:`wide_frustum_prims` gathers the primitives of the
leaves the frustum reaches (the tracers then test the bundle against those alone:
:mod:`impl.tracer`).

Arrays (the :class:`impl.accel.Accel` fields; ``M`` wide nodes):

=========  =================  ===========================================
field      shape              meaning
=========  =================  ===========================================
node_lo/hi (1, 3) f64         the root's box
node_a     (M·W,) i64         slot ``n·W + k``: child node (interior) or
                              first entry of ``prim_idx`` (leaf)
node_b     (M·W,) i64         ``-1`` interior, ``c ≥ 0`` leaf of c
                              primitives (0: empty slot, empty box)
prim_idx   (P,) i64           the leaves' primitive ids
acc_f      (K,) f64           the node records, 8·W float32 words each:
                              the boxes ``[lo_x, lo_y, lo_z, hi_x, hi_y,
                              hi_z]×W``, the children's int32 references
                              ×W (node index, or ``-s - 1`` for the leaf
                              of slot s), W words of padding; stored two
                              words per float64 (read through
                              ``acc_f.view(np.float32)`` and
                              ``.view(np.int32)``), then the leaves'
                              sphere and triangle groups (G, 9, LANES)
                              in the configured precision
                              (:func:`wide_arrays`)
acc_i      (4+2·M·W+G·LANES,) ``W``, the groups' first word in that
           i64                precision, ``S = M·W`` slots, slot s's
                              sphere groups ``grp[2s]:grp[2s+1]`` and
                              triangle groups ``grp[2s+1]:grp[2s+2]``
                              (2S+1 entries), the lanes' primitive ids
                              (-1: padding)
=========  =================  ===========================================

Leaves out: compressed (quantised) boxes, vector tests of the algebraic and
geometric sphere forms, spatial splits, float32 box arithmetic, 8-lane float32
groups (the groups are 4 lanes in both precisions: 256-bit ymm arithmetic in
float64, 128-bit xmm in float32).

References: I. Wald, P. Slusallek, C. Benthin, M. Wagner, "Interactive
rendering with coherent ray tracing", CGF 20(3), 2001; I. Wald, C. Benthin, S. Boulos, "Getting rid of packets —
efficient SIMD single-ray traversal using multi-branching BVHs", IEEE RT
2008; H. Dammertz, J. Hanika, A. Keller, "Shallow bounding volume
hierarchies for fast SIMD ray tracing of incoherent rays", EGSR 2008;
I. Wald et al., "Embree: a kernel framework for efficient CPU ray
tracing", ACM TOG 33(4), 2014.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..intersect import like, ray_sphere_form
from ..kernel import batch_kernel, interleaved, task_stride
from .primitives import _slab64, box_enter, closer, prim_test_arrays as _prim, ulp_above
from .tree import STACK, _alloca_f64, _alloca_i64

__all__ = ["WIDTH", "SWITCH", "collapse", "wide_closest", "wide_any", "wide_depth",
           "wide_frustum_prims", "wide_closest_batch", "wide_occluded_batch", "wide_packet_closest",
           "wide_packet_occluded", "wide_closest_packets", "wide_occluded_packets"]

#: Children per node.
WIDTH = 4
#: A subtree of the binary tree with at most this many primitives becomes one
#: leaf (the builder keeps a subtree's primitives consecutive in ``prim_idx``).
LEAF_MAX = 4
_PLANES = 6 * WIDTH                 # float32 words of one node's boxes
#: float32 words of one node record: its boxes, its children's references
#: (int32, :func:`wide_arrays`) and padding to a multiple of 64 bytes.
_REC = 8 * WIDTH
#: Triangles per vector test of a leaf (:func:`_tri_lanes`).
LANES = 4
_TRI_WORDS = 9 * LANES              # words of one leaf group: v0, e1, e2 (SoA)


@njit(inline="always", cache=True)
def _area(lo, hi, c):
    ex, ey, ez = hi[c, 0] - lo[c, 0], hi[c, 1] - lo[c, 1], hi[c, 2] - lo[c, 2]
    return ex * ey + ey * ez + ez * ex


@njit(inline="always", cache=True)
def _down(x):
    """x rounded to float32 downward (the largest float32 <= x)."""
    y = np.float32(x)
    if float(y) > x:
        y = np.nextafter(y, np.float32(-np.inf))
    return y


@njit(inline="always", cache=True)
def _up(x):
    """x rounded to float32 upward (the smallest float32 >= x)."""
    y = np.float32(x)
    if float(y) < x:
        y = np.nextafter(y, np.float32(np.inf))
    return y


@njit(cache=True)
def _collapse(nlo, nhi, na, nb, W):
    """Wide nodes of the binary tree (node_b = -2 interior): ``(box (M, 6, W) float32
    rounded outward, slot_a (M·W,), slot_b (M·W,))``, depth-first."""
    n = nb.shape[0]
    cap = 1                                     # one wide node per binary interior node at most
    first = np.empty(n, dtype=np.int64)         # each subtree's primitives: prim_idx[first:first+cnt]
    cnt = np.empty(n, dtype=np.int64)
    leaf = np.empty(n, dtype=np.bool_)          # a wide leaf: a binary leaf, or few primitives
    for b in range(n - 1, -1, -1):              # children come after their parent
        if nb[b] >= 0:
            first[b], cnt[b] = na[b], nb[b]
            leaf[b] = True
        else:
            cap += 1
            first[b] = min(first[na[b]], first[na[b] + 1])
            cnt[b] = cnt[na[b]] + cnt[na[b] + 1]
            leaf[b] = cnt[b] <= LEAF_MAX
    box = np.empty((cap, 6, W), dtype=np.float32)
    sa = np.zeros(cap * W, dtype=np.int64)
    sb = np.zeros(cap * W, dtype=np.int64)
    st_bin = np.empty(cap, dtype=np.int64)
    st_wide = np.empty(cap, dtype=np.int64)
    cand = np.empty(W, dtype=np.int64)
    st_bin[0], st_wide[0] = 0, 0
    sp, m_nodes = 1, 1
    while sp > 0:
        sp -= 1
        b, w = st_bin[sp], st_wide[sp]
        box[w, :3, :] = np.inf                  # empty slots: an empty box
        box[w, 3:, :] = -np.inf
        if leaf[b]:                             # a leaf root (tiny scene)
            cand[0] = b
            m = 1
        else:
            cand[0], cand[1] = na[b], na[b] + 1
            m = 2
            while m < W:                        # open the largest interior child
                best, best_a = -1, -1.0
                for i in range(m):
                    c = cand[i]
                    if not leaf[c]:
                        a = _area(nlo, nhi, c)
                        if a > best_a:
                            best, best_a = i, a
                if best < 0:
                    break
                c = cand[best]
                cand[best] = na[c]
                cand[m] = na[c] + 1
                m += 1
        for k in range(m - 1, -1, -1):          # first child pushed last: visited next
            c = cand[k]
            for a in range(3):
                box[w, a, k] = _down(nlo[c, a])
                box[w, 3 + a, k] = _up(nhi[c, a])
            s = w * W + k
            if leaf[c]:
                sa[s], sb[s] = first[c], cnt[c]
            else:
                sa[s], sb[s] = m_nodes, -1
                st_bin[sp], st_wide[sp] = c, m_nodes
                sp += 1
                m_nodes += 1
    return box[:m_nodes].copy(), sa[:m_nodes * W].copy(), sb[:m_nodes * W].copy()


def collapse(nlo, nhi, na, nb, width: int = WIDTH):
    """The wide-BVH arrays ``(box32 (M, 6, W) float32, slot_a, slot_b)`` of a binary
    tree in the flat layout of :mod:`.tree` (children in pairs, ``node_b = -2``)."""
    if np.any((nb < 0) & (nb != -2)):
        raise ValueError("collapse: the tree is not binary")
    return _collapse(nlo, nhi, na, nb, int(width))


@njit(cache=True)
def _leaf_groups(slot_a, slot_b, idx, sph_center, sph_radius, tri_v, head):
    """The leaves' primitives in groups of :data:`LANES`, structure of arrays:
    ``(grp (2S+1,), buf, ids (G·LANES,))`` — slot s's spheres are groups
    ``grp[2s]:grp[2s+1]``, its triangles ``grp[2s+1]:grp[2s+2]`` (a slot's groups
    are consecutive, spheres first); ``buf`` (head + G·9·LANES,) in tri_v's
    precision holds ``head`` words left for the caller, then the groups (G, 9,
    LANES).  A triangle group's rows are v0x v0y v0z, e1 = v1 − v0, e2 = v2 − v0
    (as :func:`impl.intersect.ray_triangle` computes them), a sphere group's
    cx cy cz r and five rows of zeros; ``ids`` the lanes' primitive ids (spheres
    0…ns−1 first, then triangles; -1: padding).  Padding lanes miss: a zero
    triangle (det = 0), a sphere of centre NaN (every comparison of the test
    false)."""
    S = slot_a.shape[0]
    ns = sph_radius.shape[0]
    grp = np.zeros(2 * S + 1, dtype=np.int64)
    for s in range(S):
        cs = ct = 0
        if slot_b[s] > 0:
            for k in range(slot_a[s], slot_a[s] + slot_b[s]):
                if idx[k] < ns:
                    cs += 1
                else:
                    ct += 1
        grp[2 * s + 1] = grp[2 * s] + (cs + LANES - 1) // LANES
        grp[2 * s + 2] = grp[2 * s + 1] + (ct + LANES - 1) // LANES
    G = grp[2 * S]
    buf = np.empty(head + G * 9 * LANES, dtype=tri_v.dtype)
    data = buf[head:].reshape(G, 9, LANES)
    data[:] = 0.0
    ids = np.full(G * LANES, -1, dtype=np.int64)
    for s in range(S):
        if slot_b[s] <= 0:
            continue
        js = grp[2 * s] * LANES
        for g in range(grp[2 * s], grp[2 * s + 1]):
            data[g, 0:3, :] = np.nan
        jt = grp[2 * s + 1] * LANES
        for k in range(slot_a[s], slot_a[s] + slot_b[s]):
            p = idx[k]
            if p < ns:
                g, ln = js // LANES, js % LANES
                for a in range(3):
                    data[g, a, ln] = sph_center[p, a]
                data[g, 3, ln] = sph_radius[p]
                ids[js] = p
                js += 1
                continue
            g, ln = jt // LANES, jt % LANES
            v = tri_v[p - ns]
            for a in range(3):
                data[g, a, ln] = v[0, a]
                data[g, 3 + a, ln] = v[1, a] - v[0, a]
                data[g, 6 + a, ln] = v[2, a] - v[0, a]
            ids[jt] = p
            jt += 1
    return grp, buf, ids


def wide_arrays(box32, slot_a, slot_b, idx, sph_center, sph_radius, tri_v):
    """The ``(acc_f, acc_i)`` of a wide BVH: the node records followed by the leaves'
    sphere and triangle groups (:func:`_leaf_groups`) in the precision of
    ``sph_radius``, and ``[W, word offset of the groups in that precision, S slots,
    grp (2S+1), ids]``.  The records are written in place in front of the groups
    (no copy of either)."""
    F = np.asarray(sph_radius).dtype            # the kernels' precision (impl.rays.RayConfig)
    tri_v = np.ascontiguousarray(tri_v, dtype=F).reshape(-1, 3, 3)
    sph_center = np.ascontiguousarray(sph_center, dtype=F).reshape(-1, 3)
    sph_radius = np.ascontiguousarray(sph_radius, dtype=F)
    m, _, W = box32.shape
    if m * W >= 2 ** 31:
        raise ValueError(f"wide_arrays: {m * W} slots do not fit the int32 child references")
    words = m * 8 * W                           # float32 words of the node records
    off = words if F == np.float32 else words // 2
    grp, buf, ids = _leaf_groups(slot_a, slot_b, idx, sph_center, sph_radius, tri_v, off)
    rec = buf[:off].view(np.float32).reshape(m, 8, W)
    s = np.arange(m * W, dtype=np.int64)
    ref = np.where(slot_b < 0, slot_a, -s - 1).astype(np.int32).reshape(m, 1, W)
    rec[:, :6, :] = box32
    rec[:, 6:7, :] = ref.view(np.float32)
    rec[:, 7, :] = 0.0
    acc_f = buf.view(np.float64) if F == np.float32 else buf
    head = np.array([box32.shape[2], off, len(slot_a)], dtype=np.int64)
    return acc_f, np.concatenate([head, grp, ids])


@njit(cache=True)
def wide_depth(slot_a, slot_b, W):
    """Largest traversal stack the wide tree can need (children − 1 summed along a
    path, + 1, counting leaves as stack entries)."""
    m = slot_a.shape[0] // W
    need = np.zeros(m, dtype=np.int64)
    need[0] = 1
    max_s = 1
    for n in range(m):                       # children come after their parent
        k = 0
        for j in range(W):
            if slot_b[n * W + j] != 0:
                k += 1
        for j in range(W):
            s = n * W + j
            if slot_b[s] < 0:
                need[slot_a[s]] = need[n] + k - 1
            max_s = max(max_s, need[n] + k - 1)
    return max_s


@intrinsic
def _ptr(typingctx, a):
    """The data pointer of the contiguous array ``a`` (``CPointer`` of its dtype).

    The per-ray traversal reads the arrays through these pointers: a pointer is
    no reference-counted object, so passing it to the inlined helpers costs no
    atomic increment and decrement of a reference count per call, as passing an
    array does.  The caller keeps the arrays alive (they are fields of the
    configuration it holds)."""
    if not (isinstance(a, types.Array) and a.layout == "C"):
        return None
    sig = types.CPointer(a.dtype)(a)

    def codegen(context, builder, sig, args):
        return context.make_array(sig.args[0])(context, builder, args[0]).data

    return sig, codegen


def _data_ptr(context, builder, t, v):
    """An intrinsic argument's data pointer: an array's data, or the pointer itself."""
    if isinstance(t, types.Array):
        return context.make_array(t)(context, builder, v).data
    return v


@intrinsic
def _enter_all(typingctx, box, base, nx, ny, nz, fx, fy, fz, ox, oy, oz, ix, iy, iz, tmin, tmax, tn):
    """Slab test of one node's WIDTH children in WIDTH-lane vectors: ``tn[k]`` = entry t
    of child k's box within [tmin, tmax] (inf on a miss); returns the hit mask
    (bit k: child k entered).

    ``box`` is the float32 view of the node records (or its :func:`_ptr`), ``base``
    the node's first word, ``nx`` … ``fz`` the word offsets of the near / far plane
    of each axis (:func:`_planes`); ray and limits float64, ``tn`` a float64 array
    or pointer.  Per axis
    ``a = (near − o)·(1/d)``, ``t0 = a if a > t0 else t0`` (and ``t1`` alike with
    ``<``): the arithmetic and NaN rule of :func:`.primitives.box_enter`, lane by
    lane, on the boxes widened to float64 (exact).  Written as LLVM vector IR
    because numba leaves LLVM's SLP vectoriser off and a 4-trip loop is below
    the loop vectoriser's threshold."""
    sig = types.int64(box, base, nx, ny, nz, fx, fy, fz, ox, oy, oz, ix, iy, iz, tmin, tmax, tn)

    def codegen(context, builder, sig, args):
        args = [_data_ptr(context, builder, t, a) if isinstance(t, (types.Array, types.CPointer))
                else context.cast(builder, a, t, types.int64 if isinstance(t, types.Integer)
                                  else types.float64)
                for a, t in zip(args, sig.args)]
        (box_ptr, base, nx, ny, nz, fx, fy, fz, ox, oy, oz, ix, iy, iz, tmin, tmax, tn_ptr) = args
        f32v = ir.VectorType(ir.FloatType(), WIDTH)
        f64v = ir.VectorType(ir.DoubleType(), WIDTH)

        def splat(x):
            v = ir.Constant(f64v, ir.Undefined)
            for k in range(WIDTH):
                v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), k))
            return v

        def plane(off, o, inv):
            p = builder.gep(box_ptr, [builder.add(base, off)])
            v = builder.load(builder.bitcast(p, f32v.as_pointer()), align=4)
            return builder.fmul(builder.fsub(builder.fpext(v, f64v), o), inv)

        t0, t1 = splat(tmin), splat(tmax)
        for n, f, o, inv in ((nx, fx, ox, ix), (ny, fy, oy, iy), (nz, fz, oz, iz)):
            vo, vi = splat(o), splat(inv)
            a = plane(n, vo, vi)
            b = plane(f, vo, vi)
            t0 = builder.select(builder.fcmp_ordered(">", a, t0), a, t0)
            t1 = builder.select(builder.fcmp_ordered("<", b, t1), b, t1)
        hit = builder.fcmp_ordered("<=", t0, t1)
        inf = ir.Constant(f64v, [math.inf] * WIDTH)
        builder.store(builder.select(hit, t0, inf), builder.bitcast(tn_ptr, f64v.as_pointer()),
                      align=8)
        return builder.zext(builder.bitcast(hit, ir.IntType(WIDTH)), ir.IntType(64))

    return sig, codegen


class _Group:
    """The code generation a leaf group's vector test shares (:func:`_tri_lanes`,
    :func:`_sph_lanes`; arguments ``data, base, ox, oy, oz, dx, dy, dz, tmin, tmax,
    out``): ``vt`` the vector of :data:`LANES` words of R's precision, ``ray`` the
    eight scalars (origin, direction, limits) cast to that precision and splatted,
    :meth:`row` the group's row r, :meth:`store` a vector into ``out`` (float64,
    exact), :meth:`mask` the int64 bit mask of a lane predicate."""

    def __init__(self, context, builder, sig, args):
        self.builder = builder
        self.F = F = sig.args[0].dtype
        self.vt = vt = ir.VectorType(context.get_value_type(F), LANES)
        self.dv = ir.VectorType(ir.DoubleType(), LANES)
        self.d_ptr = _data_ptr(context, builder, sig.args[0], args[0])
        self.o_ptr = _data_ptr(context, builder, sig.args[10], args[10])
        self.base = context.cast(builder, args[1], sig.args[1], types.int64)
        self.ray = []
        for a, t in zip(args[2:10], sig.args[2:10]):
            v = ir.Constant(vt, ir.Undefined)
            x = context.cast(builder, a, t, F)
            for k in range(LANES):
                v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), k))
            self.ray.append(v)

    def row(self, r):
        b = self.builder
        p = b.gep(self.d_ptr, [b.add(self.base, ir.Constant(ir.IntType(64), r * LANES))])
        return b.load(b.bitcast(p, self.vt.as_pointer()), align=self.F.bitwidth // 8)

    def store(self, k, v):
        """``out[k·LANES : (k+1)·LANES] = v``."""
        b = self.builder
        w = v if self.F == types.float64 else b.fpext(v, self.dv)
        p = b.gep(self.o_ptr, [ir.Constant(ir.IntType(64), k * LANES)])
        b.store(w, b.bitcast(p, self.dv.as_pointer()), align=8)

    def mask(self, hit):
        b = self.builder
        return b.zext(b.bitcast(hit, ir.IntType(LANES)), ir.IntType(64))


@intrinsic
def _tri_lanes(typingctx, data, base, ox, oy, oz, dx, dy, dz, tmin, tmax, out):
    """Möller–Trumbore for the :data:`LANES` triangles of one leaf group in one vector
    operation per step: ``data`` (R's precision) holds the group's rows ``v0x v0y v0z
    e1x e1y e1z e2x e2y e2z`` (:data:`LANES` words each) from word ``base``; the ray
    and limits are in R's precision.  Lane k's ``t``, ``b1``, ``b2`` go to ``out[k]``,
    ``out[LANES + k]``, ``out[2·LANES + k]`` (float64, exact); returns the mask of the
    lanes hit with ``t > 0``.

    The operations, their order and their precision are those of
    :func:`impl.intersect.ray_triangle` (``e1 = v1 − v0`` and ``e2`` precomputed in
    the same precision give the same values; no fused multiply-add), and a lane is
    a miss exactly when its early returns would fire (ordered comparisons), so a
    lane's hit is the scalar test's, bit for bit.  Padding lanes hold a degenerate
    triangle (det = 0: a miss)."""
    sig = types.int64(data, base, ox, oy, oz, dx, dy, dz, tmin, tmax, out)

    def codegen(context, builder, sig, args):
        G = _Group(context, builder, sig, args)
        vt, row = G.vt, G.row
        ox, oy, oz, dx, dy, dz, t_lo, t_hi = G.ray
        v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z = (row(r) for r in range(9))
        mul, sub, add = builder.fmul, builder.fsub, builder.fadd
        zero = ir.Constant(vt, [0.0] * LANES)
        one = ir.Constant(vt, [1.0] * LANES)

        def dot(ax, ay, az, bx, by, bz):
            return add(add(mul(ax, bx), mul(ay, by)), mul(az, bz))

        px, py, pz = (sub(mul(dy, e2z), mul(dz, e2y)), sub(mul(dz, e2x), mul(dx, e2z)),
                      sub(mul(dx, e2y), mul(dy, e2x)))
        det = dot(e1x, e1y, e1z, px, py, pz)
        inv = builder.fdiv(one, det)
        sx, sy, sz = sub(ox, v0x), sub(oy, v0y), sub(oz, v0z)
        b1 = mul(dot(sx, sy, sz, px, py, pz), inv)
        qx, qy, qz = (sub(mul(sy, e1z), mul(sz, e1y)), sub(mul(sz, e1x), mul(sx, e1z)),
                      sub(mul(sx, e1y), mul(sy, e1x)))
        b2 = mul(dot(dx, dy, dz, qx, qy, qz), inv)
        t = mul(dot(e2x, e2y, e2z, qx, qy, qz), inv)
        cmp = builder.fcmp_ordered
        miss = builder.or_(cmp("==", det, zero), cmp("<", b1, zero))
        miss = builder.or_(miss, cmp(">", b1, one))
        miss = builder.or_(miss, cmp("<", b2, zero))
        miss = builder.or_(miss, cmp(">", add(b1, b2), one))
        miss = builder.or_(miss, cmp("<=", t, t_lo))
        miss = builder.or_(miss, cmp(">=", t, t_hi))
        hit = builder.and_(builder.not_(miss), cmp(">", t, zero))
        for k, v in enumerate((t, b1, b2)):
            G.store(k, v)
        return G.mask(hit)

    return sig, codegen


@intrinsic
def _sph_lanes(typingctx, data, base, ox, oy, oz, dx, dy, dz, tmin, tmax, out):
    """The stable ray–sphere test (:func:`impl.intersect.ray_sphere_stable`) for the
    :data:`LANES` spheres of one leaf group in one vector operation per step:
    ``data`` (R's precision) holds the group's rows ``cx cy cz r`` (:data:`LANES`
    words each) from word ``base``; the ray (unit direction) and limits are in R's
    precision.  Lane k's ``t`` goes to ``out[k]`` (float64, exact); returns the
    mask of the lanes hit with ``t > 0``.

    The scalar test's operations in its order and precision (no fused multiply-add;
    ``sqrt`` and ``copysign`` exact as the scalar ones), its branches as selects:
    a lane misses where the scalar test returns −1 (ordered comparisons, so a NaN
    padding lane misses), and its ``t`` is the scalar test's bit for bit."""
    sig = types.int64(data, base, ox, oy, oz, dx, dy, dz, tmin, tmax, out)

    def codegen(context, builder, sig, args):
        G = _Group(context, builder, sig, args)
        vt, row = G.vt, G.row
        suffix = f"v{LANES}f{G.F.bitwidth}"
        sqrt = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vt, [vt]),
                                              f"llvm.sqrt.{suffix}")
        copysign = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vt, [vt, vt]),
                                                  f"llvm.copysign.{suffix}")
        ox, oy, oz, dx, dy, dz, t_lo, t_hi = G.ray
        cx, cy, cz, r = (row(k) for k in range(4))
        mul, sub, add, sel = builder.fmul, builder.fsub, builder.fadd, builder.select
        cmp = builder.fcmp_ordered
        zero = ir.Constant(vt, [0.0] * LANES)
        fx, fy, fz = sub(ox, cx), sub(oy, cy), sub(oz, cz)
        b = builder.fneg(add(add(mul(fx, dx), mul(fy, dy)), mul(fz, dz)))
        px, py, pz = add(fx, mul(b, dx)), add(fy, mul(b, dy)), add(fz, mul(b, dz))
        r2 = mul(r, r)
        disc = sub(r2, add(add(mul(px, px), mul(py, py)), mul(pz, pz)))
        c = sub(add(add(mul(fx, fx), mul(fy, fy)), mul(fz, fz)), r2)
        q = add(b, builder.call(copysign, [builder.call(sqrt, [disc]), b]))
        t0 = builder.fdiv(c, q)
        swap = cmp(">", t0, q)
        lo, hi = sel(swap, q, t0), sel(swap, t0, q)
        in_lo = builder.and_(cmp(">", lo, t_lo), cmp("<", lo, t_hi))
        in_hi = builder.and_(cmp(">", hi, t_lo), cmp("<", hi, t_hi))
        t = sel(in_lo, lo, sel(in_hi, hi, ir.Constant(vt, [-1.0] * LANES)))
        miss = builder.or_(cmp("<", disc, zero), cmp("==", q, zero))
        hit = builder.and_(builder.not_(miss), cmp(">", t, zero))
        G.store(0, t)
        return G.mask(hit)

    return sig, codegen


@intrinsic
def _ptr_as(typingctx, a, g):
    """The data pointer of the contiguous array ``a`` (float64 words) as a pointer to
    the dtype of ``g``'s elements (no array is made: a function compiled without the
    runtime may not return a view)."""
    if not (isinstance(a, types.Array) and a.layout == "C" and isinstance(g, types.Array)):
        return None
    sig = types.CPointer(g.dtype)(a, g)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        return builder.bitcast(data, context.get_value_type(sig.return_type))

    return sig, codegen


@njit(inline="always", cache=True)
def _planes(ix, iy, iz):
    """Word offsets of the near and far planes of each axis in a node's boxes."""
    nx = 3 * WIDTH if ix < 0.0 else 0
    ny = (4 if iy < 0.0 else 1) * WIDTH
    nz = (5 if iz < 0.0 else 2) * WIDTH
    return nx, ny, nz, 3 * WIDTH - nx, 5 * WIDTH - ny, 7 * WIDTH - nz


@njit(inline="always", cache=True, error_model="numpy")
def _trace(T, ref0, t0, ox, oy, oz, dx, dy, dz, tmin, tmax, best_t, best_p, bb1, bb2, any_hit):
    """The traversal of both queries, from subtree ``ref0`` (a node, or ``-s - 1`` for
    the leaf of slot s) entered at ``t0``: ``(t, prim, b1, b2, nodes_visited,
    prim_tests)``.

    Closest hit (``any_hit`` False): from the hit so far ``(best_t, best_p, bb1,
    bb2)``, children pushed nearest first, entries beyond the nearest hit skipped,
    primitives tested with the tie-inclusive limit ``ulp_above(best_t)`` and kept
    by :func:`.primitives.closer`.  Any hit (``any_hit`` True, a constant the
    compiler folds): children in slot order, primitives tested within (tmin,
    tmax), stops at the first hit (prim ≥ 0 then says "hit").  ``T``: the tree as
    :func:`wide_bind` gives it; the ray in R's precision."""
    na, nb, idx, box, cref, tri, tri_off, grp, ids, form, sc, sr, ns = T
    nodes = tests = 0
    fox, foy, foz = float(ox), float(oy), float(oz)
    ix, iy, iz = 1.0 / float(dx), 1.0 / float(dy), 1.0 / float(dz)
    ftmin = float(tmin)
    nx, ny, nz, fx, fy, fz = _planes(ix, iy, iz)
    stack_n = _alloca_i64()
    stack_t = _alloca_f64()
    tn = _alloca_f64()
    stack_n[0], stack_t[0] = ref0, t0
    sp = 1
    zero = like(tmax, 0.0)
    while sp > 0:
        sp -= 1
        ref = stack_n[sp]
        if not any_hit and stack_t[sp] > float(best_t):  # entered beyond the nearest hit
            continue
        nodes += 1
        if ref < 0:
            s = -ref - 1
            lim = tmax if any_hit else ulp_above(best_t)
            if ns > 0 and form == 2:             # stable spheres: LANES at a time
                for g in range(grp[2 * s], grp[2 * s + 1]):
                    m = _sph_lanes(tri, tri_off + g * _TRI_WORDS, ox, oy, oz, dx, dy, dz, tmin,
                                   lim, tn)
                    for k in range(LANES):
                        tests += ids[g * LANES + k] >= 0
                        if m & (1 << k):
                            p = ids[g * LANES + k]
                            t = like(tmax, tn[k])
                            if any_hit:
                                return t, p, zero, zero, nodes, tests
                            if closer(t, p, best_t, best_p):
                                best_t, best_p, bb1, bb2 = t, p, zero, zero
            elif ns > 0:                         # the other forms: the scalar test
                for k in range(na[s], na[s] + nb[s]):
                    p = idx[k]
                    if p < ns:
                        tests += 1
                        t = ray_sphere_form(form, ox, oy, oz, dx, dy, dz, sc[3 * p],
                                            sc[3 * p + 1], sc[3 * p + 2], sr[p], tmin, lim)
                        if any_hit:
                            if t > zero:
                                return t, p, zero, zero, nodes, tests
                        elif closer(t, p, best_t, best_p):
                            best_t, best_p, bb1, bb2 = t, p, zero, zero
            for g in range(grp[2 * s + 1], grp[2 * s + 2]):  # triangles: LANES at a time
                m = _tri_lanes(tri, tri_off + g * _TRI_WORDS, ox, oy, oz, dx, dy, dz, tmin, lim, tn)
                for k in range(LANES):
                    tests += ids[g * LANES + k] >= 0
                    if m & (1 << k):
                        p = ids[g * LANES + k]
                        t = like(tmax, tn[k])
                        if any_hit:
                            return t, p, zero, zero, nodes, tests
                        if closer(t, p, best_t, best_p):
                            best_t, best_p = t, p
                            bb1, bb2 = like(tmax, tn[LANES + k]), like(tmax, tn[2 * LANES + k])
            continue
        # Interior: all W boxes in one vector test, then push the entered ones.
        base = ref * _REC
        mask = _enter_all(box, base, nx, ny, nz, fx, fy, fz, fox, foy, foz, ix, iy, iz,
                          ftmin, float(best_t), tn)
        sp0 = sp
        for k in range(WIDTH):
            if mask & (1 << k):
                tc = tn[k]
                c = cref[base + _PLANES + k]
                j = sp
                if not any_hit:                  # nearest on top
                    while j > sp0 and stack_t[j - 1] < tc:
                        stack_t[j] = stack_t[j - 1]
                        stack_n[j] = stack_n[j - 1]
                        j -= 1
                stack_t[j] = tc
                stack_n[j] = c
                sp += 1
    return best_t, best_p, bb1, bb2, nodes, tests


@njit(inline="always", cache=True)
def wide_bind(R):
    """R's wide BVH, bound once per batch of rays: ``(T, root, g)`` with ``T = (na, nb,
    idx, box, cref, tri, tri_off, grp, ids, form, sc, sr, ns)`` — data pointers
    (:func:`_ptr`) to the :class:`impl.accel.Accel` fields and their views (``box``
    the node records as float32, ``cref`` the same words as int32, ``tri`` the
    leaf groups in R's precision, ``sc`` the sphere centres row by row), the
    groups' first word, the sphere form and the number of spheres ``ns`` —, the
    root box ``root = (lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)`` and ``g`` a zero of
    R's precision.  Pointers and numbers are no reference-counted objects: the
    inlined per-ray helpers take them without the atomic reference counting that
    passing arrays (or the configuration) to them costs."""
    ai = R.acc_i
    S = ai[2]
    lo, hi = R.node_lo, R.node_hi
    sr = R.sph_radius
    T = (_ptr(R.node_a), _ptr(R.node_b), _ptr(R.prim_idx), _ptr(R.acc_f.view(np.float32)),
         _ptr(R.acc_f.view(np.int32)), _ptr_as(R.acc_f, sr), ai[1],
         _ptr(ai[3:4 + 2 * S]), _ptr(ai[4 + 2 * S:]), R.form, _ptr(R.sph_center), _ptr(sr),
         sr.shape[0])
    root = (float(lo[0, 0]), float(lo[0, 1]), float(lo[0, 2]), float(hi[0, 0]),
            float(hi[0, 1]), float(hi[0, 2]))
    return T, root, like(sr, 0.0)


@njit(inline="always", cache=True, error_model="numpy")
def _root_enter(root, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """:func:`.primitives.box_enter` of the root box ``(lo_x, lo_y, lo_z, hi_x, hi_y,
    hi_z)``."""
    lx, ly, lz, hx, hy, hz = root
    t0, t1 = tmin, tmax
    t0, t1 = _slab64(lx, hx, ox, ix, t0, t1)
    t0, t1 = _slab64(ly, hy, oy, iy, t0, t1)
    t0, t1 = _slab64(lz, hz, oz, iz, t0, t1)
    if t0 > t1:
        return math.inf
    return t0


@njit(inline="always", cache=True, error_model="numpy")
def wide_query(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit):
    """One ray from the root (root box test, then :func:`_trace`)."""
    zero = like(tmax, 0.0)
    t_root = _root_enter(root, float(ox), float(oy), float(oz), 1.0 / float(dx),
                         1.0 / float(dy), 1.0 / float(dz), float(tmin), float(tmax))
    if t_root == math.inf:
        return tmax, -1, zero, zero, 1, 0
    return _trace(T, 0, t_root, ox, oy, oz, dx, dy, dz, tmin, tmax, tmax, -1, zero, zero,
                  any_hit)


@njit(inline="always", cache=True, error_model="numpy")
def _walk(R, ref0, t0, ox, oy, oz, dx, dy, dz, tmin, best_t, best_p, bb1, bb2):
    """Closest-hit traversal of the subtree ``ref0`` entered at ``t0`` from the hit so
    far (the packets' single-ray continuation): see :func:`_trace`."""
    T, _, _ = wide_bind(R)
    return _trace(T, ref0, t0, ox, oy, oz, dx, dy, dz, tmin, best_t, best_t, best_p, bb1, bb2,
                  False)


@njit(inline="always", cache=True, error_model="numpy")
def _any_from(R, ref0, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any-hit traversal of the subtree ``ref0``: ``(hit, nodes_visited, prim_tests)``."""
    T, _, _ = wide_bind(R)
    zero = like(tmax, 0.0)
    _, p, _, _, nodes, tests = _trace(T, ref0, -math.inf, ox, oy, oz, dx, dy, dz, tmin, tmax,
                                      tmax, -1, zero, zero, True)
    return p >= 0, nodes, tests


@batch_kernel(error_model="numpy")
def wide_closest_bound(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`wide_closest` of the tree ``(T, root)`` that :func:`wide_bind` gives: the
    arguments are data pointers and numbers, so a per-ray call from a batch kernel
    copies no array (what :func:`impl.rays.hit` calls); ``(t, prim, b1, b2)``."""
    t, p, b1, b2, _, _ = wide_query(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax, False)
    return t, p, b1, b2


@batch_kernel(error_model="numpy")
def wide_any_bound(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`wide_any` of the bound tree (as :func:`wide_closest_bound`): hit or not."""
    _, p, _, _, _, _ = wide_query(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax, True)
    return p >= 0


@batch_kernel(error_model="numpy")
def wide_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, nodes_visited, prim_tests)``; arguments and t in
    R's precision, prim = -1 on a miss (nodes: wide nodes and leaves opened).
    Compiled without numba's runtime (it allocates nothing: :mod:`impl.kernel`), so
    a per-ray call (:func:`impl.rays.hit` in a tracer's bounce loop) costs no
    reference counting of R's arrays."""
    T, root, _ = wide_bind(R)
    return wide_query(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax, False)


@batch_kernel(error_model="numpy")
def wide_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax): ``(hit, nodes_visited, prim_tests)``; without the
    runtime, as :func:`wide_closest`."""
    T, root, _ = wide_bind(R)
    _, p, _, _, nodes, tests = wide_query(T, root, ox, oy, oz, dx, dy, dz, tmin, tmax, True)
    return p >= 0, nodes, tests


@batch_kernel(error_model="numpy")
def wide_frustum_prims(R, bound, pad_rel, out, cap):
    """The primitives of every leaf whose box may meet the frustum ``bound`` (float64:
    apex p, slack δ, the four inward unit plane normals through p, the reach r, as
    :func:`impl.tracer._bound` gives them) into ``out``; their count, or -1 when there
    are more than ``cap``.

    A depth-first walk that opens every child box neither wholly outside one plane nor
    further than r from p: a box lies outside the plane with normal n when its corner
    furthest along n does, and beyond the reach when its nearest point is further than r,
    by more than δ + ``pad_rel``·(1 + the box's largest L1 distance from p) — no less than the
    padding of any point of the box, so a primitive kept by the frustum's own
    primitive test (:func:`impl.tracer._frustum_prims`) is always in a kept leaf (a
    box holds its primitives: :mod:`.primitives` pads them, ``wide_arrays`` rounds
    outward).  The leaves' primitives come in tree order, unsorted, each once."""
    box = R.acc_f.view(np.float32)
    cref = R.acc_f.view(np.int32)
    na, nb, idx = R.node_a, R.node_b, R.prim_idx
    px, py, pz, slack, reach = bound[0], bound[1], bound[2], bound[3], bound[16]
    stack = _alloca_i64()
    stack[0] = 0
    sp = 1
    k = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        base = node * _REC
        for c in range(WIDTH):
            s = node * WIDTH + c
            if nb[s] == 0:                       # empty slot
                continue
            lx = float(box[base + c]) - px
            ly = float(box[base + WIDTH + c]) - py
            lz = float(box[base + 2 * WIDTH + c]) - pz
            hx = float(box[base + 3 * WIDTH + c]) - px
            hy = float(box[base + 4 * WIDTH + c]) - py
            hz = float(box[base + 5 * WIDTH + c]) - pz
            pad = slack + pad_rel * (1.0 + max(abs(lx), abs(hx)) + max(abs(ly), abs(hy))
                                     + max(abs(lz), abs(hz)))
            gx = max(lx, 0.0) + max(-hx, 0.0)   # the box's gap from p along each axis
            gy = max(ly, 0.0) + max(-hy, 0.0)
            gz = max(lz, 0.0) + max(-hz, 0.0)
            out_of = gx * gx + gy * gy + gz * gz > (reach + pad) * (reach + pad)
            for j in range(4):
                nx, ny, nz = bound[4 + 3 * j], bound[5 + 3 * j], bound[6 + 3 * j]
                far = max(nx * lx, nx * hx) + max(ny * ly, ny * hy) + max(nz * lz, nz * hz)
                out_of |= far + pad < 0.0
            if out_of:
                continue
            ref = cref[base + _PLANES + c]
            if ref >= 0:
                stack[sp] = ref
                sp += 1
                continue
            if k + nb[s] > cap:
                return -1
            for e in range(na[s], na[s] + nb[s]):
                out[k] = idx[e]
                k += 1
    return k


# ------------------------------------------------------------------ batches ---
# A batch binds the configuration's arrays once and runs the traversal inlined
# in its loop over the rays.

@batch_kernel(error_model="numpy")
def wide_closest_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2):
    """Closest hits of the N rays given as float64 arrays (N,), one after the other
    (the tracers' batches, inside their own parallel loop): each ray rounded to R's
    precision as :func:`impl.rays.hit` rounds it; ``out_t`` (tmax on a miss),
    ``out_b1``, ``out_b2`` float64 (N,), ``out_prim`` int64 (N,) (-1 on a miss)."""
    T, root, g = wide_bind(R)
    for i in range(ox.shape[0]):
        t, p, b1, b2, _, _ = wide_query(T, root, like(g, ox[i]), like(g, oy[i]), like(g, oz[i]),
                                    like(g, dx[i]), like(g, dy[i]), like(g, dz[i]),
                                    like(g, tmin[i]), like(g, tmax[i]), False)
        out_t[i], out_prim[i], out_b1[i], out_b2[i] = float(t), p, float(b1), float(b2)


@batch_kernel(error_model="numpy")
def wide_occluded_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit):
    """Any-hit of the N rays (float64 arrays (N,)) within (tmin[i], tmax[i]), one after
    the other: ``out_hit`` bool (N,)."""
    T, root, g = wide_bind(R)
    for i in range(ox.shape[0]):
        _, p, _, _, _, _ = wide_query(T, root, like(g, ox[i]), like(g, oy[i]), like(g, oz[i]),
                                  like(g, dx[i]), like(g, dy[i]), like(g, dz[i]),
                                  like(g, tmin[i]), like(g, tmax[i]), True)
        out_hit[i] = p >= 0


#: Rays per parallel task of the batch entry points.
CHUNK = 256


@njit(parallel=True, cache=True, error_model="numpy")
def wide_closest_batch(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2):
    """:func:`wide_closest_rays` in parallel (chunks of :data:`CHUNK` rays)."""
    n = ox.shape[0]
    chunks = (n + CHUNK - 1) // CHUNK
    stride = task_stride(chunks)
    for it in prange(chunks):
        c = interleaved(it, chunks, stride)
        a, e = c * CHUNK, min(n, (c + 1) * CHUNK)
        wide_closest_rays(R, ox[a:e], oy[a:e], oz[a:e], dx[a:e], dy[a:e], dz[a:e], tmin[a:e],
                          tmax[a:e], out_t[a:e], out_prim[a:e], out_b1[a:e], out_b2[a:e])


@njit(parallel=True, cache=True, error_model="numpy")
def wide_occluded_batch(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit):
    """:func:`wide_occluded_rays` in parallel (chunks of :data:`CHUNK` rays)."""
    n = ox.shape[0]
    chunks = (n + CHUNK - 1) // CHUNK
    stride = task_stride(chunks)
    for it in prange(chunks):
        c = interleaved(it, chunks, stride)
        a, e = c * CHUNK, min(n, (c + 1) * CHUNK)
        wide_occluded_rays(R, ox[a:e], oy[a:e], oz[a:e], dx[a:e], dy[a:e], dz[a:e], tmin[a:e],
                           tmax[a:e], out_hit[a:e])


# ------------------------------------------------------------------ packets ---
#: A packet's rays continue one by one (:func:`_walk`) from a node that this many
#: or fewer of them enter (Embree's switch threshold of its hybrid traversal).
SWITCH = 4


@njit(cache=True, error_model="numpy")
def _packet_setup(R, ox, oy, oz, dx, dy, dz, tmin, tmax, fo, inv, ft0, fbest, entered):
    """Float64 origins, reciprocal directions and limits of the packet's rays; row 0 of
    ``entered`` = which rays enter the root box.  Returns how many do."""
    n_in = 0
    for i in range(ox.shape[0]):
        fo[0, i], fo[1, i], fo[2, i] = float(ox[i]), float(oy[i]), float(oz[i])
        inv[0, i], inv[1, i], inv[2, i] = 1.0 / float(dx[i]), 1.0 / float(dy[i]), 1.0 / float(dz[i])
        ft0[i], fbest[i] = float(tmin[i]), float(tmax[i])
        e = box_enter(R.node_lo, R.node_hi, 0, fo[0, i], fo[1, i], fo[2, i],
                      inv[0, i], inv[1, i], inv[2, i], ft0[i], fbest[i]) != math.inf
        entered[0, i] = e
        n_in += e
    return n_in


@njit(inline="always", cache=True, error_model="numpy")
def _packet_child(box, base, k, fo, inv, ft0, fbest, act, cm, te):
    """Child ``k`` of the node at word ``base`` against the packet's active rays, one
    vectorised loop over the rays: ``cm[i]`` = ray i is active and enters the box,
    ``te[i]`` its entry t (the arithmetic of :func:`.primitives.box_enter`); returns
    how many enter."""
    lx, ly, lz = float(box[base + k]), float(box[base + WIDTH + k]), float(box[base + 2 * WIDTH + k])
    hx = float(box[base + 3 * WIDTH + k])
    hy = float(box[base + 4 * WIDTH + k])
    hz = float(box[base + 5 * WIDTH + k])
    cnt = 0
    for i in range(act.shape[0]):
        t0, t1 = ft0[i], fbest[i]
        v = inv[0, i]
        a = ((hx if v < 0.0 else lx) - fo[0, i]) * v
        b = ((lx if v < 0.0 else hx) - fo[0, i]) * v
        t0 = a if a > t0 else t0
        t1 = b if b < t1 else t1
        v = inv[1, i]
        a = ((hy if v < 0.0 else ly) - fo[1, i]) * v
        b = ((ly if v < 0.0 else hy) - fo[1, i]) * v
        t0 = a if a > t0 else t0
        t1 = b if b < t1 else t1
        v = inv[2, i]
        a = ((hz if v < 0.0 else lz) - fo[2, i]) * v
        b = ((lz if v < 0.0 else hz) - fo[2, i]) * v
        t0 = a if a > t0 else t0
        t1 = b if b < t1 else t1
        h = np.uint8(t0 <= t1) & act[i]
        cm[i] = h
        te[i] = t0
        cnt += h
    return cnt


@njit(cache=True, error_model="numpy")
def wide_packet_closest(R, ox, oy, oz, dx, dy, dz, tmin, best_t, best_p, bb1, bb2, counts):
    """Closest hits of a packet of P rays traversed together (Wald et al. 2001) through
    R's wide BVH.

    Rays: SoA arrays (P,) in R's precision; ``best_t`` holds each ray's tmax on
    entry.  ``best_t``, ``best_p`` (int64, -1 on entry), ``bb1``, ``bb2`` (R's
    precision) are updated in place to exactly each ray's single-ray answer
    (:func:`wide_closest`).  A node carries the mask of the packet's rays that
    entered it; its children are tested against the active rays in one
    vectorised loop each, and pushed nearest first (by the entry t of their
    first active ray).  From a node entered by :data:`SWITCH` or fewer rays they
    continue one by one.  ``counts[0] +=`` nodes opened (packet and single-ray),
    ``counts[1] +=`` primitive tests."""
    P = ox.shape[0]
    na, nb, idx = R.node_a, R.node_b, R.prim_idx
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    box = R.acc_f.view(np.float32)
    fo = np.empty((3, P))
    inv = np.empty((3, P))
    ft0 = np.empty(P)
    fbest = np.empty(P)
    entered = np.empty((STACK, P), dtype=np.uint8)
    stack_n = np.empty(STACK, dtype=np.int64)
    stack_t = np.empty(STACK)
    act = np.empty(P, dtype=np.uint8)
    cm = np.empty(P, dtype=np.uint8)
    te = np.empty(P)
    if _packet_setup(R, ox, oy, oz, dx, dy, dz, tmin, best_t, fo, inv, ft0, fbest, entered) == 0:
        return
    stack_n[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        ref = stack_n[sp]
        n_act = 0
        for i in range(P):                  # a copy: the children's masks go to this slot
            act[i] = entered[sp, i]
            n_act += act[i]
        if n_act == 0:
            continue
        if n_act <= SWITCH:
            for i in range(P):
                if act[i]:
                    t, p, b1, b2, nd, ts = _walk(R, ref, -math.inf, ox[i], oy[i], oz[i], dx[i], dy[i],
                                                 dz[i], tmin[i], best_t[i], best_p[i], bb1[i], bb2[i])
                    best_t[i], best_p[i], bb1[i], bb2[i] = t, p, b1, b2
                    fbest[i] = float(t)
                    counts[0] += nd
                    counts[1] += ts
            continue
        counts[0] += 1
        if ref < 0:
            s = -ref - 1
            for k in range(na[s], na[s] + nb[s]):
                p = idx[k]
                for i in range(P):
                    if act[i]:
                        counts[1] += 1
                        t, b1, b2 = _prim(form, sc, sr, tv, p, ox[i], oy[i], oz[i], dx[i], dy[i],
                                          dz[i], tmin[i], ulp_above(best_t[i]))
                        if closer(t, p, best_t[i], best_p[i]):
                            best_t[i], best_p[i], bb1[i], bb2[i] = t, p, b1, b2
                            fbest[i] = float(t)
            continue
        base = ref * _REC
        sp0 = sp
        for k in range(WIDTH):
            s = ref * WIDTH + k
            if nb[s] == 0:
                continue
            if _packet_child(box, base, k, fo, inv, ft0, fbest, act, cm, te) == 0:
                continue
            first = 0
            while not cm[first]:
                first += 1
            tc = te[first]
            # Insert at slot j of [sp0, sp]: farther entries deeper, the nearest on top.
            j = sp
            while j > sp0 and stack_t[j - 1] < tc:
                stack_t[j] = stack_t[j - 1]
                stack_n[j] = stack_n[j - 1]
                entered[j, :] = entered[j - 1, :]
                j -= 1
            stack_t[j] = tc
            stack_n[j] = na[s] if nb[s] < 0 else -s - 1
            entered[j, :] = cm
            sp += 1


@njit(cache=True, error_model="numpy")
def wide_packet_occluded(R, ox, oy, oz, dx, dy, dz, tmin, tmax, hit, counts):
    """Any-hit of a packet of P rays (SoA (P,) in R's precision) within (tmin[i],
    tmax[i]), traversed together: ``hit`` (P,) bool set in place, exactly each ray's
    :func:`wide_any` answer.  A ray leaves the packet at its first hit; from a
    node entered by :data:`SWITCH` or fewer live rays they continue one by one."""
    P = ox.shape[0]
    na, nb, idx = R.node_a, R.node_b, R.prim_idx
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    box = R.acc_f.view(np.float32)
    fo = np.empty((3, P))
    inv = np.empty((3, P))
    ft0 = np.empty(P)
    fend = np.empty(P)
    entered = np.empty((STACK, P), dtype=np.uint8)
    stack_n = np.empty(STACK, dtype=np.int64)
    live = np.ones(P, dtype=np.uint8)
    act = np.empty(P, dtype=np.uint8)
    cm = np.empty(P, dtype=np.uint8)
    te = np.empty(P)
    for i in range(P):
        hit[i] = False
    if _packet_setup(R, ox, oy, oz, dx, dy, dz, tmin, tmax, fo, inv, ft0, fend, entered) == 0:
        return
    stack_n[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        ref = stack_n[sp]
        n_act = 0
        for i in range(P):                  # a copy: the children's masks go to this slot
            act[i] = entered[sp, i] & live[i]
            n_act += act[i]
        if n_act == 0:
            continue
        if n_act <= SWITCH:
            for i in range(P):
                if act[i]:
                    h, nd, ts = _any_from(R, ref, ox[i], oy[i], oz[i], dx[i], dy[i], dz[i],
                                          tmin[i], tmax[i])
                    counts[0] += nd
                    counts[1] += ts
                    if h:
                        hit[i] = True
                        live[i] = 0
            continue
        counts[0] += 1
        zero = like(tmax[0], 0.0)
        if ref < 0:
            s = -ref - 1
            for k in range(na[s], na[s] + nb[s]):
                for i in range(P):
                    if act[i] and live[i]:
                        counts[1] += 1
                        t, b1, b2 = _prim(form, sc, sr, tv, idx[k], ox[i], oy[i], oz[i], dx[i],
                                          dy[i], dz[i], tmin[i], tmax[i])
                        if t > zero:
                            hit[i] = True
                            live[i] = 0
            continue
        base = ref * _REC
        for k in range(WIDTH):
            s = ref * WIDTH + k
            if nb[s] == 0:
                continue
            if _packet_child(box, base, k, fo, inv, ft0, fend, act, cm, te) > 0:
                stack_n[sp] = na[s] if nb[s] < 0 else -s - 1
                entered[sp, :] = cm
                sp += 1


@njit(parallel=True, cache=True, error_model="numpy")
def wide_closest_packets(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2,
                         packet):
    """:func:`wide_closest_batch` for coherent rays: consecutive groups of ``packet``
    rays (e.g. the eye rays of a pixel tile) traced as packets
    (:func:`wide_packet_closest`), the groups in parallel; same outputs, bit for bit."""
    g = R.sph_radius
    n = ox.shape[0]
    for q in prange((n + packet - 1) // packet):
        i0 = q * packet
        P = min(packet, n - i0)
        o = np.empty((7, P), dtype=g.dtype)
        best_t = np.empty(P, dtype=g.dtype)
        best_p = np.full(P, -1, dtype=np.int64)
        b1 = np.zeros(P, dtype=g.dtype)
        b2 = np.zeros(P, dtype=g.dtype)
        counts = np.zeros(2, dtype=np.int64)
        for i in range(P):
            o[0, i], o[1, i], o[2, i] = like(g, ox[i0 + i]), like(g, oy[i0 + i]), like(g, oz[i0 + i])
            o[3, i], o[4, i], o[5, i] = like(g, dx[i0 + i]), like(g, dy[i0 + i]), like(g, dz[i0 + i])
            o[6, i] = like(g, tmin[i0 + i])
            best_t[i] = like(g, tmax[i0 + i])
        wide_packet_closest(R, o[0], o[1], o[2], o[3], o[4], o[5], o[6], best_t, best_p, b1, b2,
                            counts)
        for i in range(P):
            out_t[i0 + i], out_prim[i0 + i] = float(best_t[i]), best_p[i]
            out_b1[i0 + i], out_b2[i0 + i] = float(b1[i]), float(b2[i])


@njit(parallel=True, cache=True, error_model="numpy")
def wide_occluded_packets(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit, packet):
    """:func:`wide_occluded_batch` for coherent rays (e.g. a tile's shadow rays to one
    point light): groups of ``packet`` consecutive rays traced as packets
    (:func:`wide_packet_occluded`), in parallel; same answers."""
    g = R.sph_radius
    n = ox.shape[0]
    for q in prange((n + packet - 1) // packet):
        i0 = q * packet
        P = min(packet, n - i0)
        o = np.empty((8, P), dtype=g.dtype)
        h = np.empty(P, dtype=np.bool_)
        counts = np.zeros(2, dtype=np.int64)
        for i in range(P):
            o[0, i], o[1, i], o[2, i] = like(g, ox[i0 + i]), like(g, oy[i0 + i]), like(g, oz[i0 + i])
            o[3, i], o[4, i], o[5, i] = like(g, dx[i0 + i]), like(g, dy[i0 + i]), like(g, dz[i0 + i])
            o[6, i], o[7, i] = like(g, tmin[i0 + i]), like(g, tmax[i0 + i])
        wide_packet_occluded(R, o[0], o[1], o[2], o[3], o[4], o[5], o[6], o[7], h, counts)
        for i in range(P):
            out_hit[i0 + i] = h[i]
