"""Coherent ray packets traversed as one through a BVH (thesis 2.6, third strategy).

Thesis 2.6 lists, beside faster tests and fewer tests, tracing *several
rays together*.  Neighbouring eye rays are coherent: they visit nearly the
same nodes.  A packet of the rays of a k×k pixel tile descends the tree
together: a node is opened when its box is entered by *any* active ray of the
packet (before that ray's nearest hit so far); the node's data is fetched
once for the whole packet, and at a leaf only the rays that entered its box
are tested.  Children are visited in the order of their entry along the
packet's first active ray.  Each ray's answer is exactly its single-ray
answer (same primitive tests, same tie rule as :mod:`.tree`); the gain is in
memory traffic and loop overhead, the loss in boxes tested for rays that do
not need them (incoherent packets).

Through a binary tree (:func:`packet_closest`) the packet's rays are looped
over one by one at each node.  Through the wide BVH (``accel=bvh-wide``,
:func:`.wide.wide_packet_closest`) the rays are structure-of-arrays and each
child box is tested against all active rays in one vectorised loop, with the
packet's active mask; from a node entered by few rays they continue one by
one (Embree's switch to single rays).

Scope: primary (eye) rays.  :func:`primary_hits` gives the depth / primitive
buffers of a camera, by packets or one ray at a time through the same tree.
The four ray tracers (``raycast``, ``whitted``, ``distributed``, ``path``)
take the parameter ``packets=true`` (:data:`impl.rays.PARAMS`): their render
kernel then runs over :data:`TILE`×:data:`TILE` pixel tiles, and for each
sample index the tile's eye rays — the very rays the per-pixel kernel traces —
form one packet (:func:`packet_hits`); each pixel's sample then continues
from that precomputed first hit (the tracers' radiance functions take it as
``pre_t, pre_prim, pre_b1, pre_b2``, with ``pre_prim =`` :data:`NOT_TRACED`
meaning "trace it yourself").  Secondary and shadow rays stay single-ray
(:func:`impl.rays.hit` / ``occluded``): after the first bounce they are
incoherent, and packets of them are out of scope.

Reference: I. Wald, P. Slusallek, C. Benthin, M. Wagner, "Interactive
rendering with coherent ray tracing", *Computer Graphics Forum* 20(3), 2001.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from core.errors import ParamError

from ..camera import eye_ray
from ..intersect import like
from ..sampling import pixel_sample
from .primitives import box_enter, closer, prim_test, ulp_above
from .tree import STACK, tree_closest
from .wide import wide_closest, wide_packet_closest
from . import WIDE as _WIDE

__all__ = ["packet_closest", "packet_hits", "packet_buffers", "tile_eye_packet", "primary_hits", "tile_rect",
           "tile_count", "TILE", "NOT_TRACED"]

TILE = 8
#: ``pre_prim`` of a tracer's radiance function when no first hit is given.  Callers
#: pass it as ``np.int64(NOT_TRACED)``: a bare ``-2`` is typed ``Literal[int]`` and
#: would compile the radiance function a second time (two signatures, one per
#: kernel), doubling the tile kernel's compile time.
NOT_TRACED = -2


@njit(cache=True, error_model="numpy")
def packet_closest(R, o, inv, d, tmin, best_t, best_p, bb, counts):
    """Closest hits of the packet's rays (o, d (P, 3) in R's precision; inv = 1/d in
    float64), updating best_t / best_p / bb (P,) / (P, 2) in place; counts[0] += nodes
    opened, counts[1] += primitive tests."""
    lo, hi, na, nb, idx = R.node_lo, R.node_hi, R.node_a, R.node_b, R.prim_idx
    P = o.shape[0]
    entered = np.empty((STACK, P), dtype=np.bool_)     # per stack entry: which rays entered
    stack_n = np.empty(STACK, dtype=np.int64)
    any_in = False
    for i in range(P):
        entered[0, i] = box_enter(lo, hi, 0, float(o[i, 0]), float(o[i, 1]), float(o[i, 2]),
                                  inv[i, 0], inv[i, 1], inv[i, 2], float(tmin[i]),
                                  float(best_t[i])) != math.inf
        any_in = any_in or entered[0, i]
    if not any_in:
        return
    stack_n[0] = 0
    sp = 1
    te = np.empty(8)                                   # entry t of the children being pushed
    cm = np.empty(P, dtype=np.bool_)                   # a child's entered-mask
    while sp > 0:
        sp -= 1
        n = stack_n[sp]
        mask = entered[sp].copy()
        counts[0] += 1
        b = nb[n]
        if b >= 0:
            for k in range(na[n], na[n] + b):
                p = idx[k]
                for i in range(P):
                    if not mask[i]:
                        continue
                    counts[1] += 1
                    t, b1, b2 = prim_test(R, p, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                          tmin[i], ulp_above(best_t[i]))
                    if closer(t, p, best_t[i], best_p[i]):
                        best_t[i], best_p[i], bb[i, 0], bb[i, 1] = t, p, float(b1), float(b2)
            continue
        # Interior: each child's entered-mask over the packet; push the entered ones,
        # the nearest (along the first ray that enters it) on top.
        k_children = -b
        sp0 = sp
        for ci in range(k_children):
            c = na[n] + ci
            first_t = math.inf
            hit_any = False
            for i in range(P):
                e = False
                if mask[i]:
                    tc = box_enter(lo, hi, c, float(o[i, 0]), float(o[i, 1]), float(o[i, 2]),
                                   inv[i, 0], inv[i, 1], inv[i, 2], float(tmin[i]), float(best_t[i]))
                    if tc != math.inf:
                        e = True
                        if not hit_any:
                            first_t = tc
                        hit_any = True
                cm[i] = e
            if hit_any:
                # Insert at slot j of [sp0, sp]: larger entry t deeper, nearest on top.
                j = sp
                while j > sp0 and te[j - 1 - sp0] < first_t:
                    stack_n[j] = stack_n[j - 1]
                    entered[j, :] = entered[j - 1, :]
                    te[j - sp0] = te[j - 1 - sp0]
                    j -= 1
                stack_n[j] = c
                entered[j, :] = cm
                te[j - sp0] = first_t
                sp += 1
    return


@njit(cache=True, error_model="numpy", _nrt=True)
def packet_hits(R, rays, n, hit_t, hit_p, hit_b, counts):
    """Closest hits of the eye rays ``rays[:n]`` = (ox, oy, oz, dx, dy, dz, tmin, tmax)
    (float64, as the camera gives them) traced as one packet through R's tree.

    Each ray is rounded to R's precision exactly as :func:`impl.rays.round_ray`
    and :func:`impl.rays.hit` round it, so ``hit_t[i], hit_p[i], hit_b[i, 0],
    hit_b[i, 1]`` are bit for bit what ``hit`` returns for it (float64 t and
    barycentrics, prim = -1 on a miss).  ``counts[0] +=`` nodes opened by the
    packet, ``counts[1] +=`` primitive tests.
    """
    g = R.sph_radius
    if R.accel == _WIDE:
        _wide_packet_hits(R, rays, n, hit_t, hit_p, hit_b, counts)
        return
    o = np.empty((n, 3), dtype=g.dtype)
    d = np.empty((n, 3), dtype=g.dtype)
    inv = np.empty((n, 3))
    tmin = np.empty(n, dtype=g.dtype)
    best_t = np.empty(n, dtype=g.dtype)
    best_p = np.full(n, -1, dtype=np.int64)
    bb = np.zeros((n, 2))
    for i in range(n):
        for a in range(3):
            # round_ray, then hit's like(): rounding twice to R's precision is rounding once
            o[i, a] = like(g, float(like(g, rays[i, a])))
            d[i, a] = like(g, float(like(g, rays[i, 3 + a])))
            inv[i, a] = 1.0 / float(d[i, a])
        tmin[i] = like(g, rays[i, 6])
        best_t[i] = like(g, rays[i, 7])
    packet_closest(R, o, inv, d, tmin, best_t, best_p, bb, counts)
    for i in range(n):
        hit_t[i] = float(best_t[i])
        hit_p[i] = best_p[i]
        hit_b[i, 0] = bb[i, 0]
        hit_b[i, 1] = bb[i, 1]


@njit(cache=True, error_model="numpy")
def _wide_packet_hits(R, rays, n, hit_t, hit_p, hit_b, counts):
    """:func:`packet_hits` through a wide BVH (:func:`.wide.wide_packet_closest`, rays SoA)."""
    g = R.sph_radius
    r = np.empty((7, n), dtype=g.dtype)
    best_t = np.empty(n, dtype=g.dtype)
    best_p = np.full(n, -1, dtype=np.int64)
    b1 = np.zeros(n, dtype=g.dtype)
    b2 = np.zeros(n, dtype=g.dtype)
    for i in range(n):
        for a in range(7):
            r[a, i] = like(g, float(like(g, rays[i, a])))
        best_t[i] = like(g, rays[i, 7])
    wide_packet_closest(R, r[0], r[1], r[2], r[3], r[4], r[5], r[6], best_t, best_p, b1, b2, counts)
    for i in range(n):
        hit_t[i] = float(best_t[i])
        hit_p[i] = best_p[i]
        hit_b[i, 0] = float(b1[i])
        hit_b[i, 1] = float(b2[i])


@njit(inline="always", cache=True)
def packet_buffers(P):
    """The arrays of a packet of up to ``P`` rays for :func:`packet_hits`:
    ``(rays (P, 8), hit_t (P,), hit_p (P,) int64, hit_b (P, 2))``."""
    return np.empty((P, 8)), np.empty(P), np.empty(P, dtype=np.int64), np.empty((P, 2))


@njit(cache=True, error_model="numpy")
def tile_eye_packet(R, cam, x0, nx, y0, P, spp, k, s, seed, rays, hit_t, hit_p, hit_b, counts):
    """Sample ``s`` of a tile's ``P`` pixels (pixel ``i`` at ``(x0 + i % nx, y0 + i // nx)``):
    the eye rays the per-pixel kernels of ``raycast``, ``whitted`` and ``path`` trace
    (``pixel_sample(spp, k, s, seed, pixel)`` through :func:`impl.camera.eye_ray`) into
    ``rays[:P]``, and their closest hits, traced as one packet (:func:`packet_hits`),
    into ``hit_t`` / ``hit_p`` / ``hit_b``."""
    W = int(cam[14])
    for i in range(P):
        x, y = x0 + i % nx, y0 + i // nx
        fx, fy = pixel_sample(spp, k, s, seed, y * W + x)
        ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + fx, y + fy)
        rays[i, 0], rays[i, 1], rays[i, 2] = ox, oy, oz
        rays[i, 3], rays[i, 4], rays[i, 5] = dx, dy, dz
        rays[i, 6], rays[i, 7] = tmin, tmax
    packet_hits(R, rays, P, hit_t, hit_p, hit_b, counts)


@njit(inline="always", cache=True)
def tile_count(W, H):
    """Number of TILE×TILE tiles covering a W×H image (row-major, cut at the border)."""
    return ((W + TILE - 1) // TILE) * ((H + TILE - 1) // TILE)


@njit(inline="always", cache=True)
def tile_rect(k, W, H):
    """Tile ``k``'s first pixel and size: ``(x0, y0, nx, ny)``; its pixel ``i`` (0 ≤ i <
    nx·ny) is ``(x0 + i % nx, y0 + i // nx)``."""
    tx = (W + TILE - 1) // TILE
    x0 = (k % tx) * TILE
    y0 = (k // tx) * TILE
    return x0, y0, min(TILE, W - x0), min(TILE, H - y0)


@njit(cache=True, error_model="numpy")
def _tile(R, cam, tile, W, H, packets, depth, prim, counts):
    """Tile ``tile``'s pixel-centre eye rays: by :func:`packet_hits`, or one by one through
    :func:`tree_closest` rounded as ``packet_hits`` rounds them."""
    x0, y0, nx, ny = tile_rect(tile, W, H)
    P = nx * ny
    rays, hit_t, hit_p, hit_b = packet_buffers(P)
    for i in range(P):
        ox, oy, oz, dx, dy, dz, t0, t1, _ = eye_ray(cam, x0 + i % nx + 0.5, y0 + i // nx + 0.5)
        rays[i, 0], rays[i, 1], rays[i, 2] = ox, oy, oz
        rays[i, 3], rays[i, 4], rays[i, 5] = dx, dy, dz
        rays[i, 6], rays[i, 7] = t0, t1
    if packets:
        packet_hits(R, rays, P, hit_t, hit_p, hit_b, counts)
    else:
        g = R.sph_radius
        for i in range(P):
            ox, oy, oz = like(g, rays[i, 0]), like(g, rays[i, 1]), like(g, rays[i, 2])
            dx, dy, dz = like(g, rays[i, 3]), like(g, rays[i, 4]), like(g, rays[i, 5])
            t0, t1 = like(g, rays[i, 6]), like(g, rays[i, 7])
            if R.accel == _WIDE:
                t, p, b1, b2, nodes, tests = wide_closest(R, ox, oy, oz, dx, dy, dz, t0, t1)
            else:
                t, p, b1, b2, nodes, tests = tree_closest(R, ox, oy, oz, dx, dy, dz, t0, t1)
            hit_t[i], hit_p[i] = float(t), p
            counts[0] += nodes
            counts[1] += tests
    for i in range(P):
        px = (y0 + i // nx) * W + x0 + i % nx
        prim[px] = hit_p[i]
        depth[px] = hit_t[i] if hit_p[i] >= 0 else math.inf


@njit(parallel=True, cache=True)
def _primary_kernel(R, cam, W, H, packets, depth, prim, counts):
    for tile in prange(tile_count(W, H)):
        _tile(R, cam, tile, W, H, packets, depth, prim, counts[tile])


def primary_hits(R, camera, *, packets: bool):
    """Eye-ray closest hits through R's tree (``accel=bvh-*`` or ``octree``) for every
    pixel centre, in 8×8 tiles: ``(depth (H, W), prim (H, W), counts)`` with counts
    = (nodes opened, primitive tests) summed over the image — by packets of a tile's
    64 rays traversed together, or ray by ray."""
    from ..camera import camera_params
    from . import TREE, WIDE

    if R.accel not in (TREE, WIDE):
        raise ParamError("primary_hits: packets need a tree structure (accel=bvh-median, bvh-sah, "
                         f"bvh-gs, octree or bvh-wide); this configuration has traversal code {R.accel}")
    W, H = camera.film.width, camera.film.height
    depth = np.empty(W * H)
    prim = np.empty(W * H, dtype=np.int64)
    counts = np.zeros((tile_count(W, H), 2), dtype=np.int64)
    _primary_kernel(R, camera_params(camera), W, H, bool(packets), depth, prim, counts)
    return depth.reshape(H, W), prim.reshape(H, W), counts.sum(axis=0)
