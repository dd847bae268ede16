"""The tracer core shared by the ray tracers: tiles, ray batches, hit queries, accumulation.

A ray tracer renders the image tile by tile (``BATCH_TILE``² pixels, or
``TILE``² with eye-ray packets; one tile per parallel task).  For every
sample index ``s`` of the pixel grid the tile's eye rays form one *batch*,
stored as structure of arrays
(:class:`Batch`: a row per ray component, a column per ray), and go through
the same steps:

1. :func:`eye_batch` — pixel sample (:func:`impl.sampling.pixel_sample`),
   eye ray (:func:`impl.camera.eye_ray`), rounded to the intersection
   precision (:mod:`impl.rays`), and its closest hit (:func:`closest_batch`,
   or the packet traversal of :mod:`impl.accel.packets` with ``packets=true``);
2. the tracer's own step — shading, shadow rays (:func:`occluded_batch`),
   secondary rays — writing each ray's radiance into ``Batch.L`` and its
   ray counts into ``Batch.cnt``;
3. :func:`accumulate` — Welford mean and squared-deviation sums per pixel.

:func:`store` writes a tile's mean, variance of the mean and counters into
the :class:`Film`.  :func:`new_points` makes a batch not tied to a tile: the
shading points a tracer collects along its rays to light them together, or a
chunk of secondary rays.  :class:`Pending` holds a tile's secondary rays by depth
(a *wavefront*: ``whitted``'s reflection and transmission rays), so that they
too are traced a batch at a time: :func:`push_pending` queues a child ray one
level deeper, :func:`take_pending` moves up to a batch's worth of one level into
a batch for :func:`closest_batch`.  A tracer module is thus its transport step plus a
ten-line tile function and task loop (:func:`impl.kernel.run_tasks`; numba cannot
cache a kernel that takes or closes over another kernel, so the loop itself cannot
live here).

Hit queries over a batch.  By brute force with the stable ray–sphere form
(the default), :func:`closest_batch` and :func:`occluded_batch` run the
primitives in the outer loop and the rays in the inner one; the inner loop
has no branch (masks and selects), so LLVM vectorises it over the rays
(AVX2 ``ymm`` registers where the host has them; ``tests/test_tracer.py``
checks the machine code).  Without an early exit they test every primitive
for every ray: the branchy scalar loop that rejects most triangles after a
few operations costs about as much per ray on scenes of tens of triangles.
They compute exactly what :func:`impl.intersect.closest_hit_form` / ``any_hit_form`` compute for each
ray (same arithmetic, same tie rule: the first primitive of smallest ``t``),
so the image does not depend on the path taken.  Before the loops, a batch's rays are
bounded (:func:`_cull`: the frustum of rays from one origin or to one point, else the
box of the segments) and only the primitives inside the bound are tested, and of finite
segments (shadow rays) only the triangles whose plane crosses the box of the segments
(:func:`_plane_misses_box`: in a closed room, the walls a point's shadow ray does not
start on); a pinhole
camera's eye rays are bounded once per tile, for all its samples, by the frustum through
the corners of each of its pixel blocks, and through the wide BVH a block that keeps too
many primitives by those of its pairs of pixel rows (:func:`_tile_candidates`).
``accel=auto`` answers batch queries this way on small scenes even where its per-ray
queries use the wide BVH (:data:`impl.rays.AUTO_BATCH_PRIMS_PER_LANE`).  Through the wide BVH, a batch goes in
chunks of ``CHUNK`` rays: a chunk with a frustum gathers the primitives of the leaves the
frustum reaches (:func:`impl.accel.wide.wide_frustum_prims`) and, when at most
``CHUNK_CAP`` pass the frustum's own test, goes through the same brute-force loops; other
chunks go ray by ray through the tree.  The loops are functions of their own
taking every array as a separate argument: inlined with rows of one 2-D array as
outputs, LLVM left them scalar.  The same holds for the eye rays of a pinhole camera
(:func:`impl.sampling.jittered_film`, :func:`impl.sampling.sobol_film`,
:func:`impl.camera.pinhole_rays`) and the
Welford update (:func:`_welford`).  The algebraic and geometric
forms and every acceleration structure go to :func:`impl.accel.closest_rays` /
:func:`impl.accel.occluded_rays`: one call per batch that binds R's arrays
once and loops over the rays (the wide BVH's and the binary trees' traversals
inlined in that loop), with the answers of :func:`impl.rays.hit` /
:func:`impl.rays.occluded` ray for ray.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import overload

from core.algorithm import RenderResult

from .accel import WIDE, closest_rays, occluded_rays
from .accel.wide import wide_closest_rays, wide_frustum_prims, wide_occluded_rays
from .accel.packets import TILE, packet_hits
from .camera import SENSOR_PERSPECTIVE, SENSOR_THINLENS, eye_ray, eye_ray_lens, pinhole_rays
from .intersect import like
from .kernel import batch_kernel
from .rng import uniform_from, uniform_prefix
from .rays import PARAMS as RAY_PARAMS, RayConfig, ray_config
from .sampling import (PIXEL_JITTER, PIXEL_SOBOL, jittered_film, pixel_sample, sobol_film,
                       sobol_film_hashes, strata, variance_of_mean)
from .scene_arrays import scene_memo

#: The random dimensions of a thin lens's aperture sample (beyond any tracer's own).
DIM_LENS = 1 << 29

__all__ = ["TILE", "BATCH_TILE", "Film", "Batch", "Cull", "new_cull", "new_film", "film_counters",
           "film_result", "new_batch", "new_points", "first", "Pending", "packet_batch", "new_pending",
           "push_pending", "take_pending",
           "ray_config_cached", "eye_batch", "closest_batch", "occluded_batch",
           "brute_force", "culled", "accumulate",
           "store", "OX", "OY", "OZ", "DX", "DY", "DZ", "TMIN", "TMAX"]

#: Tile side without packets: a batch of up to BATCH_TILE² rays.  Every batch step has a
#: fixed cost besides its per-ray work: numba hands a named tuple to a compiled function
#: as its fields, each array as several machine words, so a call such as a tracer's
#: shading step (scene, ray configuration, model, batch) copies several hundred words
#: onto the stack; larger batches spread that over more rays.  The side is not a power
#: of two: the rows of a batch array are n·8 bytes apart, and with n a multiple of 512
#: (32×32 tiles) they all fall into one set of the L1 data cache, so a loop streaming
#: more rows than the cache's ways evicts its own data.
BATCH_TILE = 24

#: Rows of a ray batch (``Batch.ray``): origin, unit direction, valid range.
OX, OY, OZ, DX, DY, DZ, TMIN, TMAX = range(8)

#: Rows of a batch of shading points (``Batch.pts``; named by :mod:`impl.lighting`'s ``SP_*``).
POINT_ROWS = 21


class Film(NamedTuple):
    """A render's outputs, written tile by tile."""

    mean: np.ndarray            # (H, W, 3) pixel mean
    var: np.ndarray             # (H, W, 3) variance of the mean
    cnt: np.ndarray             # (H, W, C) int64 per-pixel ray counts of the tracer's C counters
    packet: np.ndarray          # (tiles, 2) packet nodes and tests per tile
    packets: bool               # trace eye rays as packets
    tile: int                   # tile side in pixels
    sampler: int                # pixel sampler code (impl.sampling.PIXEL_*)
    order: np.ndarray           # (tiles,) int64 tiles in the order the threads take them


class Cull(NamedTuple):
    """The scratch of a batch query's culling (:func:`closest_batch`, :func:`occluded_batch`),
    allocated once with its batch (:func:`new_cull`), so that the queries allocate nothing
    and run without numba's runtime: a query of a few rays, as at the end of a wavefront,
    otherwise spent more on allocating it and on counting references to the ray
    configuration's arrays than on its rays."""

    cand: np.ndarray            # (2 + w,) int64 candidate list: counts of spheres m and
                                # triangles k, then their indices (room for every primitive
                                # by brute force, CHUNK_CAP through the wide BVH)
    uv: np.ndarray              # (2, n) the frustum's projective coordinates of up to n rays
    bound: np.ndarray           # (_BOUND_WORDS,) the bound of a chunk (_bound)
    raw: np.ndarray             # (_SPLIT_RAW,) the wide BVH's leaf primitives ((0,) by brute force)


class Batch(NamedTuple):
    """One tile's rays of one sample index, structure of arrays, with the scratch arrays
    the steps reuse from sample to sample (no allocation inside the sample loop).  Column
    ``i`` is the pixel ``xy[:, i]`` (image index ``pixel[i]``): the tile's pixels in blocks
    of ``BLOCK`` × ``BLOCK``, the blocks in row order and each block's pixels in row order
    (:func:`new_batch`, :func:`pixel_block`), so that a run of columns — a block, a chunk
    of a batch query, the shadow rays of consecutive points — covers a compact patch of
    the image, whose rays a frustum bounds more tightly than a strip of rows."""

    x0: int
    y0: int
    nx: int
    n: int                      # rays in the batch (nx · ny)
    ray: np.ndarray             # (8, n) rows OX..TMAX, rounded to the intersection precision
    t: np.ndarray               # (n,) closest hit distance (float64)
    prim: np.ndarray            # (n,) closest primitive, -1 on a miss
    b: np.ndarray               # (2, n) barycentrics of a triangle hit
    L: np.ndarray               # (3, n) radiance of the sample, set by the tracer
    acc: np.ndarray             # (6, n) Welford running mean (rows 0-2) and deviation sums (3-5)
    cnt: np.ndarray             # (n, C) int64 ray counts, summed over the samples
    packet: np.ndarray          # (2,) this tile's packet counters
    aos: np.ndarray             # (n, 8) the rays in packet_hits' layout (packets only)
    aos_b: np.ndarray           # (n, 2)
    pixel: np.ndarray           # (n,) image index y·W + x of each column
    pts: np.ndarray             # (POINT_ROWS, n) shading points: p, g, n, v, ρ, s, map, light dims
                                # (impl.lighting SP_*)
    active: np.ndarray          # (n,) bool: the shading points to light
    sh: np.ndarray              # (8, n) a batch of shadow rays
    sh_w: np.ndarray            # (3, n) their radiance contributions
    sh_i: np.ndarray            # (n,) their columns
    blocked: np.ndarray         # (n,) bool: occluded_batch's answers
    q: np.ndarray               # (8, n) rays in the intersection precision
    qt: np.ndarray              # (3, n) t, b1, b2 in the intersection precision
    qp: np.ndarray              # (n,) int32 primitive (int32: the loops then vectorise in float32 too)
    film: np.ndarray            # (2, n) film positions (pixels) of the eye rays
    xy: np.ndarray              # (2, n) float64 pixel coordinates (x, y) of each column
    cand: np.ndarray            # (rows, 2 + w) int64 the eye-ray candidates of each pixel block,
                                # then of the blocks' runs of SPLIT_ROWS rows
                                # (:func:`_tile_candidates`, :func:`_cand_rows`): counts of
                                # spheres m and triangles k, then their indices; _UNKNOWN = not
                                # yet known, _PER_RAY = trace its rays one by one, _SPLIT = see
                                # the runs' lists; (1, 2) for batches not tied to a tile
    luv: np.ndarray             # (2, n) a light sample's two numbers per point (scratch of
                                # impl.lighting.direct_batch)
    fh: np.ndarray              # (2, n) uint64 the Sobol film hashes of each column
                                # (impl.sampling.sobol_film_hashes; (2, 0) unless the
                                # tile's pixels are Sobol-sampled)
    cull: Cull                  # the batch queries' culling scratch, for up to n rays


#: The parameters :func:`impl.rays.ray_config` reads (its parameter table).
_RAY_KEYS = tuple(p.name for p in RAY_PARAMS)


def ray_config_cached(scene, A, params: dict, *, algorithm: str) -> RayConfig:
    """:func:`impl.rays.ray_config` of the flattened scene ``A`` (that of ``scene``),
    built once per scene and ray parameters (:func:`impl.scene_arrays.scene_memo`): the
    acceleration structure is the costly part."""
    key = ("ray_config", id(A)) + tuple(params.get(k) for k in _RAY_KEYS)
    return scene_memo(scene, key, lambda: ray_config(A, params, algorithm=algorithm))


def new_film(W: int, H: int, counters: int, packets: bool, sampler: int = 0) -> Film:
    """The zeroed outputs of a W×H render with ``counters`` per-pixel counts, pixel
    samples placed by ``sampler`` (:func:`impl.sampling.pixel_sample`'s code).  Tiles are
    the packets' (``TILE``) with packets, else ``BATCH_TILE``."""
    ts = TILE if packets else BATCH_TILE
    tx, ty = (W + ts - 1) // ts, (H + ts - 1) // ts
    return Film(np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.zeros((H, W, counters), np.int64),
                np.zeros((tx * ty, 2), np.int64), bool(packets), ts, int(sampler), centre_out(tx, ty))


def centre_out(tx: int, ty: int) -> np.ndarray:
    """The tiles of a tx × ty grid (row-major numbers) by their centre's distance from the
    image centre, nearest first (ties in row-major order), as Mitsuba 3 hands out its
    image blocks in a spiral from the centre (``src/render/spiral.cpp``).  Threads take
    tiles in this order as each frees up (:func:`impl.kernel.run_tasks`): the subject of
    a view, and with it the costly tiles (secondary rays, many primitives), tends to sit
    near the centre, so the last tiles taken — which set how long the other threads
    wait — tend to be the cheap ones at the border."""
    x, y = np.meshgrid(np.arange(tx), np.arange(ty))
    d2 = (2 * x - (tx - 1)) ** 2 + (2 * y - (ty - 1)) ** 2
    return np.argsort(d2.ravel(), kind="stable").astype(np.int64)


def film_result(film: Film, spp: int, counters: dict, t0: float, t1: float, t2: float, *,
                aovs: dict | None = None) -> RenderResult:
    """The render's result from its film: float32 mean, the variance of the mean (none
    for one sample per pixel, which has no sample variance), ``counters`` and the
    wall-clock phases: ``setup_s`` (``t0`` to ``t1``: the fixed cost of flattening,
    configuration and allocation), ``trace_s`` (``t1`` to ``t2``, the kernel) and
    ``finish_s`` (from ``t2`` to now)."""
    image = film.mean.astype(np.float32)
    variance = film.var.astype(np.float32) if spp > 1 else None
    return RenderResult(image=image, variance=variance, counters=counters, aovs=aovs or {},
                        timings={"setup_s": t1 - t0, "trace_s": t2 - t1,
                                 "finish_s": time.perf_counter() - t2})


def film_counters(film: Film, names) -> dict:
    """The render's counters: the per-pixel counts summed, named by ``names``, plus the
    packet counters when packets were traced."""
    totals = film.cnt.reshape(-1, film.cnt.shape[2]).sum(axis=0)
    out = {name: int(v) for name, v in zip(names, totals)}
    if film.packets:
        out["packet_nodes"], out["packet_tests"] = (int(v) for v in film.packet.sum(axis=0))
    return out


@njit(cache=True)
def new_batch(film: Film, R: RayConfig, tile, seed):
    """The batch of tile ``tile`` (of ``film.tile``-square tiles) with zeroed accumulators;
    with Sobol pixel samples, the pixels' scramble hashes of ``seed`` (once for all the
    tile's samples)."""
    H, W = film.mean.shape[0], film.mean.shape[1]
    ts = film.tile
    tx = (W + ts - 1) // ts
    x0, y0 = (tile % tx) * ts, (tile // tx) * ts
    nx, ny = min(ts, W - x0), min(ts, H - y0)
    n = nx * ny
    C = film.cnt.shape[2]
    P = n if film.packets else 0
    F = R.sph_radius.dtype
    pixel = np.empty(n, np.int64)
    xy = np.empty((2, n))
    i = 0
    for by in range(0, ny, BLOCK):              # the column order of Batch: see pixel_block()
        for bx in range(0, nx, BLOCK):
            for y in range(y0 + by, y0 + min(ny, by + BLOCK)):
                for x in range(x0 + bx, x0 + min(nx, bx + BLOCK)):
                    pixel[i] = y * W + x
                    xy[0, i], xy[1, i] = x, y
                    i += 1
    fh = np.empty((2, n if film.sampler == PIXEL_SOBOL else 0), np.uint64)
    if film.sampler == PIXEL_SOBOL:
        sobol_film_hashes(seed, xy[0], xy[1], fh[0], fh[1])
    return Batch(x0, y0, nx, n, np.empty((8, n)), np.empty(n), np.empty(n, np.int64),
                 np.empty((2, n)), np.zeros((3, n)), np.zeros((6, n)), np.zeros((n, C), np.int64),
                 film.packet[tile], np.empty((P, 8)), np.empty((P, 2)), pixel,
                 np.empty((POINT_ROWS, n)), np.zeros(n, np.bool_), np.empty((8, n)), np.empty((3, n)),
                 np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty((8, n), F),
                 np.empty((3, n), F), np.empty(n, np.int32), np.empty((2, n)), xy,
                 np.full((_cand_rows(R, nx, ny), 2 + _cand_width(R)), _UNKNOWN, np.int64),
                 np.empty((2, n)), fh, new_cull(R, n))


@njit(inline="always", cache=True)
def _cand_rows(R: RayConfig, nx, ny):
    """Rows of a tile's eye-ray candidate lists (``Batch.cand``): one per pixel block,
    and through the wide BVH one per run of ``SPLIT_ROWS`` rows of each block too
    (:func:`_tile_candidates`)."""
    nb = pixel_blocks(nx, ny)
    return nb if brute_force(R) else nb * (1 + _RUNS)


@njit(inline="always", cache=True)
def pixel_blocks(nx, ny):
    """How many pixel blocks (:func:`pixel_block`) an ``nx`` × ``ny`` tile has."""
    return ((nx + BLOCK - 1) // BLOCK) * ((ny + BLOCK - 1) // BLOCK)


@njit(inline="always", cache=True)
def pixel_block(nx, ny, g):
    """Pixel block ``g`` of an ``nx`` × ``ny`` tile in a batch's column order: its first
    column, its corner (x, y) relative to the tile's, its width and height.  The blocks go
    in row order, each a run of columns holding its pixels in row order; blocks in the
    tile's last block row or column are cut to the tile."""
    bxs = (nx + BLOCK - 1) // BLOCK
    q, p = g // bxs, g % bxs
    w, h = min(BLOCK, nx - p * BLOCK), min(BLOCK, ny - q * BLOCK)
    return q * BLOCK * nx + p * BLOCK * h, p * BLOCK, q * BLOCK, w, h


@njit(cache=True)
def new_points(n, R: RayConfig, counters=0):
    """A batch of ``n`` rays or shading points not tied to a tile (columns 0..n-1, none
    active, ``counters`` zeroed counts each): for the points a tracer collects along its
    rays and lights together with :func:`impl.lighting.direct_batch`, or a few rays of
    its own."""
    F = R.sph_radius.dtype
    return Batch(0, 0, n, n, np.empty((8, n)), np.empty(n), np.empty(n, np.int64),
                 np.empty((2, n)), np.zeros((3, n)), np.zeros((6, n)), np.zeros((n, counters), np.int64),
                 np.zeros(2, np.int64), np.empty((0, 8)), np.empty((0, 2)), np.zeros(n, np.int64),
                 np.empty((POINT_ROWS, n)), np.zeros(n, np.bool_), np.empty((8, n)), np.empty((3, n)),
                 np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty((8, n), F),
                 np.empty((3, n), F), np.empty(n, np.int32), np.empty((2, 0)), np.empty((2, 0)),
                 np.full((1, 2), _UNKNOWN, np.int64), np.empty((2, n)), np.empty((2, 0), np.uint64),
                 new_cull(R, n))


@njit(inline="always", cache=True)
def first(T: Batch, m):
    """The first ``m`` columns of batch ``T`` as a batch of its own (the same arrays, ``n`` =
    m): what the batch steps loop over when a chunk fills only part of a batch."""
    return Batch(T.x0, T.y0, T.nx, m, T.ray, T.t, T.prim, T.b, T.L, T.acc, T.cnt, T.packet, T.aos,
                 T.aos_b, T.pixel, T.pts, T.active, T.sh, T.sh_w, T.sh_i, T.blocked, T.q, T.qt, T.qp,
                 T.film, T.xy, T.cand, T.luv, T.fh, T.cull)


class Pending(NamedTuple):
    """Rays waiting to be traced, one block per depth (the wavefront of a tile's ray
    trees): block ``d`` holds ``count[d]`` rays of depth d in its first columns.

    A tracer drains the deepest non-empty block first, a batch of at most B rays at a
    time, and queues the children of that batch one block deeper; so a block receives
    the children of one batch only, at most (children per ray) × B rays, which is each
    block's capacity (:func:`new_pending`).  Memory: depths × capacity × 14 numbers."""

    ray: np.ndarray             # (D, 8, cap) rows OX..TMAX, rounded to the intersection precision
    w: np.ndarray               # (D, 4, cap) RGB weight of the branch and one number of the tracer's
    col: np.ndarray             # (D, cap) int64 column of the eye ray the branch belongs to
    kind: np.ndarray            # (D, cap) int64 the tracer's ray kind
    count: np.ndarray           # (D,) int64 rays queued per depth


@njit(cache=True)
def new_pending(depths, cap):
    """An empty :class:`Pending` of ``depths`` blocks of ``cap`` rays."""
    return Pending(np.empty((depths, 8, cap)), np.empty((depths, 4, cap)),
                   np.empty((depths, cap), np.int64), np.empty((depths, cap), np.int64),
                   np.zeros(depths, np.int64))


@njit(inline="always", cache=True)
def push_pending(Q: Pending, d, ox, oy, oz, dx, dy, dz, tmin, tmax, wr, wg, wb, extra, col, kind):
    """Queue a ray of depth ``d`` (already rounded to the intersection precision)."""
    k = Q.count[d]
    r, w = Q.ray[d], Q.w[d]
    r[OX, k], r[OY, k], r[OZ, k] = ox, oy, oz
    r[DX, k], r[DY, k], r[DZ, k] = dx, dy, dz
    r[TMIN, k], r[TMAX, k] = tmin, tmax
    w[0, k], w[1, k], w[2, k], w[3, k] = wr, wg, wb, extra
    Q.col[d, k] = col
    Q.kind[d, k] = kind
    Q.count[d] = k + 1


@njit(inline="always", cache=True)
def take_pending(Q: Pending, d, ray, w, col, kind, cap):
    """Move the last min(``count[d]``, ``cap``) queued rays of depth ``d`` into columns
    0, 1, … of ``ray`` (8, ≥cap), ``w`` (4, ≥cap), ``col`` and ``kind``; their number."""
    m = min(Q.count[d], cap)
    k0 = Q.count[d] - m
    r, qw = Q.ray[d], Q.w[d]
    for c in range(8):
        for i in range(m):
            ray[c, i] = r[c, k0 + i]
    for c in range(4):
        for i in range(m):
            w[c, i] = qw[c, k0 + i]
    for i in range(m):
        col[i] = Q.col[d, k0 + i]
        kind[i] = Q.kind[d, k0 + i]
    Q.count[d] = k0
    return m


@njit(inline="always", cache=True)
def packet_batch(R: RayConfig, T: Batch):
    """The closest hits of the batch's rays (``T.ray``, rounded to R's precision) traced
    as one packet (:func:`impl.accel.packets.packet_hits`, rays in ``T.aos``'s layout)
    into ``T.t``, ``T.prim``, ``T.b``; the packet's node and test counts into
    ``T.packet``."""
    for i in range(T.n):
        for c in range(8):
            T.aos[i, c] = T.ray[c, i]
    packet_hits(R, T.aos, T.n, T.t, T.prim, T.aos_b, T.packet)
    for i in range(T.n):
        T.b[0, i], T.b[1, i] = T.aos_b[i, 0], T.aos_b[i, 1]


@batch_kernel
def eye_batch(cam, R: RayConfig, T: Batch, s, spp, seed, packets, sampler):
    """Sample ``s`` of the tile's pixels: the eye rays (pixel centre for spp = 1, else
    the sample ``s`` of ``sampler``: jittered stratum or Sobol point,
    :func:`impl.sampling.pixel_sample`; through a lens point drawn from the random
    dimensions ``DIM_LENS``, ``DIM_LENS + 1`` for a ``thinlens`` sensor,
    :func:`impl.camera.eye_ray_lens`), rounded to R's precision, and their closest
    hits into ``T.t`` / ``T.prim`` / ``T.b``."""
    k = strata(spp)
    g = R.sph_radius
    ray = T.ray
    sensor = cam[18]
    n = T.n
    pinhole = sensor == SENSOR_PERSPECTIVE
    if pinhole and (spp == 1 or sampler == PIXEL_JITTER):     # every step a vector loop
        jittered_film(spp, k, s, seed, T.pixel[:n], T.xy[0, :n], T.xy[1, :n], T.film[0, :n],
                      T.film[1, :n])
    elif pinhole and sampler == PIXEL_SOBOL:
        sobol_film(s, T.fh[0, :n], T.fh[1, :n], T.xy[0, :n], T.xy[1, :n], T.film[0, :n],
                   T.film[1, :n])
    else:
        for i in range(n):
            x, y = np.int64(T.xy[0, i]), np.int64(T.xy[1, i])
            fx, fy = pixel_sample(spp, k, s, seed, T.pixel[i], sampler, x, y)
            if pinhole:                     # film position now, the rays below at once
                T.film[0, i], T.film[1, i] = x + fx, y + fy
            else:
                if sensor == SENSOR_THINLENS:   # a lens point (camera_params(..., lens=True))
                    h = uniform_prefix(seed, T.pixel[i], s)
                    ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray_lens(
                        cam, x + fx, y + fy, uniform_from(h, DIM_LENS), uniform_from(h, DIM_LENS + 1))
                else:
                    ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + fx, y + fy)
                ray[OX, i], ray[OY, i], ray[OZ, i] = (float(like(g, ox)), float(like(g, oy)),
                                                      float(like(g, oz)))
                ray[DX, i], ray[DY, i], ray[DZ, i] = (float(like(g, dx)), float(like(g, dy)),
                                                      float(like(g, dz)))
                ray[TMIN, i], ray[TMAX, i] = tmin, tmax
    if pinhole:
        pinhole_rays(cam, g, T.film[0, :n], T.film[1, :n], ray[OX, :n], ray[OY, :n], ray[OZ, :n],
                     ray[DX, :n], ray[DY, :n], ray[DZ, :n], ray[TMIN, :n], ray[TMAX, :n])
    if pinhole and not packets and culled(R) and n >= 4 and T.cand.shape[1] > 2:
        if T.cand[0, 0] == _UNKNOWN:
            _tile_candidates(cam, R, T)
        q = _query_rows(ray, n, T.q)
        ny = n // T.nx
        nb = pixel_blocks(T.nx, ny)
        for j in range(nb):                    # rays from one origin: the camera's
            c0, _, _, w, h = pixel_block(T.nx, ny, j)
            split = T.cand[j, 0] == _SPLIT     # then a span per run of SPLIT_ROWS rows
            step = w * SPLIT_ROWS if split else w * h
            for a in range(c0, c0 + w * h, step):
                _closest_span(R, ray, q, T.qt, T.qp, a, min(c0 + w * h, a + step),
                              T.cand[nb + j * _RUNS + (a - c0) // step if split else j], T.t,
                              T.prim, T.b, True)
    elif packets:
        packet_batch(R, T)
    else:
        closest_batch(R, ray, T.n, T.t, T.prim, T.b, T.q, T.qt, T.qp, T.cull)


@batch_kernel(error_model="numpy")
def _tile_candidates(cam, R: RayConfig, T: Batch):
    """The primitives the tile's eye rays can meet, into ``T.cand``, pixel block by
    block (:func:`pixel_block`), for every sample index at once: those inside the frustum
    of the four rays through the block's outer pixel corners (:func:`_rect_candidates`).
    By brute force the list is every primitive the frustum does not exclude; through the
    wide BVH, those of the leaves it reaches, or ``_PER_RAY`` when they are more than
    ``CHUNK_CAP``.  Such a block whose frustum reaches at most ``_SPLIT_RAW`` leaf
    primitives is culled again in runs of ``SPLIT_ROWS`` pixel rows (a block over a mesh
    of a few hundred triangles may keep 30, its runs some 15), each run's list in the rows
    of ``T.cand`` after the ``nb`` blocks' (run ``j`` of block ``g`` in row
    ``nb + g·_RUNS + j``), and the block marked ``_SPLIT``.  Called once per tile."""
    ny = T.n // T.nx
    nb = pixel_blocks(T.nx, ny)
    split = T.cand.shape[0] > nb
    for g in range(nb):
        _, bx, by, w, h = pixel_block(T.nx, ny, g)
        xa, ya = T.x0 + bx, T.y0 + by
        cand = T.cand[g]
        k = _rect_candidates(cam, R, T, xa, xa + w, ya, ya + h, cand, _SPLIT_RAW)
        if split and cand[0] == _PER_RAY and k >= 0:
            for j in range((h + SPLIT_ROWS - 1) // SPLIT_ROWS):
                y = ya + j * SPLIT_ROWS
                _rect_candidates(cam, R, T, xa, xa + w, y, min(ya + h, y + SPLIT_ROWS),
                                 T.cand[nb + g * _RUNS + j], _RAW_CAP)
            cand[0] = _SPLIT


@njit(inline="always", cache=True)
def _rect_candidates(cam, R: RayConfig, T: Batch, xa, xb, ya, yb, cand, cap):
    """The primitives the eye rays through the film rectangle [xa, xb] × [ya, yb] (pixels)
    can meet, into ``cand``: those inside the frustum of the rays through its four corners
    (:func:`_frustum_planes`).  A pinhole's rays share the camera's origin, and every film
    position of the rectangle lies between its corners, so every eye ray of every sample
    lies in that frustum (the projective map from the film to the frustum's (u, v) plane
    keeps the rectangle's image inside the box of its corners' images).  By brute force
    the list is every primitive the frustum does not exclude; through the wide BVH, those
    of the leaves it reaches (:func:`_wide_prims`, at most ``cap`` of them).  Returns how
    many primitives the leaves held (-1: more than ``cap``, or no frustum; 0 by brute
    force).  The corner rays go through the first four columns of the scratch arrays
    ``T.sh_w`` (film positions), ``T.sh`` (rays), ``T.q`` (in R's precision) and ``T.film``
    (the frustum's coordinates; the sample's film positions are used by then) and the
    batch queries' culling scratch ``T.cull`` (the bound and the tree's raw list): the
    tile has at least four pixels."""
    fx, fy, c = T.sh_w[0, :4], T.sh_w[1, :4], T.sh
    bound, raw = T.cull.bound, T.cull.raw
    fx[0], fy[0] = xa, ya
    fx[1], fy[1] = xb, ya
    fx[2], fy[2] = xa, yb
    fx[3], fy[3] = xb, yb
    pinhole_rays(cam, R.sph_radius, fx, fy, c[OX, :4], c[OY, :4], c[OZ, :4], c[DX, :4],
                 c[DY, :4], c[DZ, :4], c[TMIN, :4], c[TMAX, :4])
    _in_precision(c, 4, T.q)
    bound[0], bound[1], bound[2] = float(T.q[OX, 0]), float(T.q[OY, 0]), float(T.q[OZ, 0])
    bound[3], bound[16] = 0.0, math.inf          # no slack; eye rays reach any distance
    ok = _frustum_planes(T.q, 0, 4, False, T.film, bound)
    if brute_force(R):
        if ok:
            _frustum_prims(R, bound, cand)
        else:
            _keep_all(R, cand)
        return 0
    if ok:
        return _wide_prims(R, bound, raw, cand, cap)
    cand[0] = _PER_RAY
    return -1


@njit(inline="always", cache=True)
def brute_force(R: RayConfig):
    """Whether batch queries go through the brute-force loops (else through R's
    structure): a ray then costs a few vector operations per candidate primitive."""
    return (R.accel == 0 or R.batch_brute) and R.form == 2


@njit(inline="always", cache=True)
def culled(R: RayConfig):
    """Whether batch queries bound their rays and test the primitives inside the bound in
    the brute-force loops: by brute force (:func:`brute_force`), or through the wide BVH,
    chunk by chunk, where the bound holds few primitives (:func:`_wide_prims`)."""
    return brute_force(R) or (R.accel == WIDE and R.form == 2)


@batch_kernel(error_model="numpy")
def closest_batch(R: RayConfig, ray, n, t, prim, b, q, qt, qp, cull: Cull):
    """Closest hits of the first ``n`` rays of ``ray`` (8, ≥n) in R's form, precision and
    structure: ``t`` (float64), ``prim`` (-1 on a miss), ``b`` (2, n) barycentrics.
    ``q`` (8, ≥n), ``qt`` (3, ≥n) in R's precision, ``qp`` (≥n,) int32 and ``cull``
    (:func:`new_cull` of R and ≥n rays) are scratch.

    By brute force, the batch is bounded as a whole (:func:`_cull`); through the wide BVH,
    in chunks of ``CHUNK`` rays, each bounded and either tested against the primitives its
    bound reaches in the tree or traced ray by ray (:func:`_wide_cull`); other structures
    and forms trace ray by ray (:func:`impl.accel.closest_rays`, which keeps the runtime:
    the binary trees and the grid allocate their traversal stacks)."""
    if not culled(R) or n == 0:
        closest_rays(R, ray[OX, :n], ray[OY, :n], ray[OZ, :n], ray[DX, :n], ray[DY, :n], ray[DZ, :n],
                     ray[TMIN, :n], ray[TMAX, :n], t[:n], prim[:n], b[0, :n], b[1, :n])
        return
    _closest_chunks(R, ray, n, t, prim, b, q, qt, qp, cull.cand, cull.uv, cull.bound, cull.raw)


@batch_kernel(error_model="numpy")
def _closest_chunks(R: RayConfig, ray, n, t, prim, b, q, qt, qp, cand, uv, bound, raw):
    """The culled part of :func:`closest_batch`, with its scratch: a function without
    numba's runtime, so the views of every chunk cost no reference counting."""
    q = _query_rows(ray, n, q)
    step = _chunk(R, n)
    for c0 in range(0, n, step):
        c1 = min(n, c0 + step)
        _chunk_cull(R, q, c0, c1, cand, uv, bound, raw)
        _closest_span(R, ray, q, qt, qp, c0, c1, cand, t, prim, b)


@njit(inline="always", cache=True)
def _chunk(R: RayConfig, n):
    """Rays per bound of a batch of ``n``: the whole batch by brute force (a bound costs
    about as much as the primitives it culls), ``CHUNK`` through the wide BVH."""
    return n if brute_force(R) else CHUNK


@batch_kernel(error_model="numpy")
def _chunk_cull(R: RayConfig, q, c0, c1, cand, uv, bound, raw):
    """The candidates of rays ``c0:c1`` into ``cand``: :func:`_cull` by brute force,
    :func:`_wide_cull` through the wide BVH.  Called once per chunk, not inlined: the
    closest-hit and the shadow queries share one compile of it (numba's inlining copies
    a callee's IR into each caller, at a cost that grows with the callee's size)."""
    if brute_force(R):
        _cull(R, q, c0, c1, cand, uv, bound)
    else:
        _wide_cull(R, q, c0, c1, cand, uv, bound, raw)


@batch_kernel(error_model="numpy")
def occluded_batch(R: RayConfig, ray, n, blocked, q, cull: Cull):
    """Whether anything lies on each of the first ``n`` rays of ``ray`` (8, ≥n) within
    (tmin, tmax), in R's form, precision and structure; ``q`` (8, ≥n) in R's precision
    and ``cull`` (:func:`new_cull` of R and ≥n rays) are scratch.  Bounded and culled as
    :func:`closest_batch`."""
    if not culled(R) or n == 0:
        occluded_rays(R, ray[OX, :n], ray[OY, :n], ray[OZ, :n], ray[DX, :n], ray[DY, :n], ray[DZ, :n],
                      ray[TMIN, :n], ray[TMAX, :n], blocked[:n])
        return
    _occluded_chunks(R, ray, n, blocked, q, cull.cand, cull.uv, cull.bound, cull.raw)


@batch_kernel(error_model="numpy")
def _occluded_chunks(R: RayConfig, ray, n, blocked, q, cand, uv, bound, raw):
    """The culled part of :func:`occluded_batch` (see :func:`_closest_chunks`)."""
    q = _query_rows(ray, n, q)
    step = _chunk(R, n)
    for c0 in range(0, n, step):
        c1 = min(n, c0 + step)
        _chunk_cull(R, q, c0, c1, cand, uv, bound, raw)
        if cand[0] == _PER_RAY:              # only through the wide BVH
            wide_occluded_rays(R, ray[OX, c0:c1], ray[OY, c0:c1], ray[OZ, c0:c1], ray[DX, c0:c1],
                               ray[DY, c0:c1], ray[DZ, c0:c1], ray[TMIN, c0:c1],
                               ray[TMAX, c0:c1], blocked[c0:c1])
            continue
        m, k = cand[0], cand[1]
        _occluded_loops(R.sph_center, R.sph_radius, R.tri_v, cand[2:2 + m], cand[2 + m:2 + m + k],
                        q[OX, c0:c1], q[OY, c0:c1], q[OZ, c0:c1], q[DX, c0:c1], q[DY, c0:c1],
                        q[DZ, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], blocked[c0:c1])


@njit(cache=True)
def new_cull(R: RayConfig, n):
    """The :class:`Cull` scratch of batch queries of up to ``n`` rays in R, uninitialised
    (each chunk's culling fills it)."""
    return Cull(np.empty(2 + _cand_width(R), np.int64), np.empty((2, n)), np.empty(_BOUND_WORDS),
                np.empty(0 if brute_force(R) else _SPLIT_RAW, np.int64))


@njit(inline="always", cache=True)
def _cand_width(R: RayConfig):
    """Room for the ids of a candidate list: every primitive by brute force, at most
    ``CHUNK_CAP`` through the wide BVH."""
    P = R.sph_radius.shape[0] + R.tri_v.shape[0]
    return P if brute_force(R) else min(P, CHUNK_CAP)


@njit(inline="always", cache=True)
def _closest_span(R: RayConfig, ray, q, qt, bp, c0, c1, cand, t, prim, b, one_origin=False):
    """Closest hits of rays ``c0:c1``: by :func:`_closest_loops` of ``q`` (R's precision)
    over the candidates ``cand`` (``[m, k, m sphere ids, k triangle ids]``), the answers
    in ``t``, ``prim``, ``b`` (float64; in float32 through the scratch ``qt`` and ``bp``,
    :func:`_hit_rows`); or ray by ray through R's structure when
    ``cand`` says :data:`_PER_RAY`.  ``one_origin``: the rays share the origin of ray
    ``c0`` (a pinhole camera's eye rays), so :func:`_closest_loops_from` serves."""
    if cand[0] == _PER_RAY:              # only through the wide BVH
        wide_closest_rays(R, ray[OX, c0:c1], ray[OY, c0:c1], ray[OZ, c0:c1], ray[DX, c0:c1],
                          ray[DY, c0:c1], ray[DZ, c0:c1], ray[TMIN, c0:c1], ray[TMAX, c0:c1],
                          t[c0:c1], prim[c0:c1], b[0, c0:c1], b[1, c0:c1])
        return
    m, k = cand[0], cand[1]
    ht, hp, h1, h2 = _hit_rows(t, prim, b, qt, bp)
    if one_origin:
        _closest_loops_from(R.sph_center, R.sph_radius, R.tri_v, cand[2:2 + m], cand[2 + m:2 + m + k],
                            q[OX, c0], q[OY, c0], q[OZ, c0], q[DX, c0:c1], q[DY, c0:c1],
                            q[DZ, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], ht[c0:c1], hp[c0:c1],
                            h1[c0:c1], h2[c0:c1])
    else:
        _closest_loops(R.sph_center, R.sph_radius, R.tri_v, cand[2:2 + m], cand[2 + m:2 + m + k],
                       q[OX, c0:c1], q[OY, c0:c1], q[OZ, c0:c1], q[DX, c0:c1], q[DY, c0:c1],
                       q[DZ, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], ht[c0:c1], hp[c0:c1],
                       h1[c0:c1], h2[c0:c1])
    _hits_back(ht, hp, h1, h2, c0, c1, t, prim, b)


@njit(inline="always", cache=True, error_model="numpy")
def _in_precision(ray, n, q):
    """Copy the rays' rows into ``q`` (R's precision)."""
    for c in range(8):
        for i in range(n):
            q[c, i] = ray[c, i]


def _hit_rows(t, prim, b, qt, qp):
    """Where :func:`_closest_loops` writes its answers (t, primitive, b1, b2): the
    batch's own ``t``, ``prim``, ``b`` in float64 (no copy), else the scratch ``qt`` (3, ≥n)
    in R's precision and ``qp`` int32 (so the loops vectorise at the float32 width), which
    :func:`_hits_back` then copies.  Compiled code only."""
    raise NotImplementedError("_hit_rows runs in compiled code only")


@overload(_hit_rows, inline="always")
def _hit_rows_overload(t, prim, b, qt, qp):
    if qt.dtype == t.dtype:
        return lambda t, prim, b, qt, qp: (t, prim, b[0], b[1])
    return lambda t, prim, b, qt, qp: (qt[0], qp, qt[1], qt[2])


def _hits_back(best, bp, b1s, b2s, c0, c1, t, prim, b):
    """Copy the answers of rays ``c0:c1`` from :func:`_hit_rows`' scratch to ``t``,
    ``prim``, ``b`` (nothing when they were written there).  Compiled code only."""
    raise NotImplementedError("_hits_back runs in compiled code only")


@overload(_hits_back, inline="always")
def _hits_back_overload(best, bp, b1s, b2s, c0, c1, t, prim, b):
    if best.dtype == t.dtype and bp.dtype == prim.dtype:
        return lambda best, bp, b1s, b2s, c0, c1, t, prim, b: None

    def copy(best, bp, b1s, b2s, c0, c1, t, prim, b):
        for i in range(c0, c1):
            t[i] = float(best[i])
            prim[i] = bp[i]
            b[0, i] = float(b1s[i])
            b[1, i] = float(b2s[i])
    return copy


def _query_rows(ray, n, q):
    """The first ``n`` rays of ``ray`` (8, ≥n) in R's precision, the precision of ``q``
    (8, ≥n): ``ray`` itself when it has it (float64: no copy), else ``q`` filled by
    :func:`_in_precision`.  Compiled code only (an overload chosen by the types)."""
    raise NotImplementedError("_query_rows runs in compiled code only")


@overload(_query_rows, inline="always")
def _query_rows_overload(ray, n, q):
    if ray.dtype == q.dtype:
        return lambda ray, n, q: ray

    def copy(ray, n, q):
        _in_precision(ray, n, q)
        return q
    return copy


@njit(inline="always", cache=True, error_model="numpy")
def _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """:func:`impl.intersect.ray_sphere_stable` without branches: its t in (tmin, tmax)
    and whether there is one (same operations, selects instead of returns)."""
    fx, fy, fz, c = _sphere_origin(ox, oy, oz, cx, cy, cz, r)
    return _sphere_from(fx, fy, fz, c, dx, dy, dz, r, tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def _sphere_origin(ox, oy, oz, cx, cy, cz, r):
    """The terms of :func:`_sphere_t` that do not depend on the direction: f = o − c and
    |f|² − r²."""
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    return fx, fy, fz, fx * fx + fy * fy + fz * fz - r * r


@njit(inline="always", cache=True, error_model="numpy")
def _sphere_from(fx, fy, fz, c, dx, dy, dz, r, tmin, tmax):
    """:func:`_sphere_t` from its origin terms (:func:`_sphere_origin`)."""
    zero = like(r, 0.0)
    bq = -(fx * dx + fy * dy + fz * dz)
    px, py, pz = fx + bq * dx, fy + bq * dy, fz + bq * dz
    disc = r * r - (px * px + py * py + pz * pz)
    q = bq + math.copysign(math.sqrt(max(disc, zero)), bq)
    t0 = c / q
    lo = min(t0, q)
    hi = max(t0, q)
    ok0 = (lo > tmin) & (lo < tmax)
    ok1 = (hi > tmin) & (hi < tmax)
    tt = lo if ok0 else hi
    return tt, (disc >= zero) & (q != zero) & (ok0 | ok1) & (tt > zero)


@njit(inline="always", cache=True, error_model="numpy")
def _triangle_t(ox, oy, oz, dx, dy, dz, v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, tmin, tmax):
    """:func:`impl.intersect.ray_triangle` without branches: (t, b1, b2, hit)."""
    sx, sy, sz, qx, qy, qz, tq = _triangle_origin(ox, oy, oz, v0x, v0y, v0z, e1x, e1y, e1z, e2x,
                                                  e2y, e2z)
    return _triangle_from(sx, sy, sz, qx, qy, qz, tq, dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z,
                          tmin, tmax)


@njit(inline="always", cache=True, error_model="numpy")
def _triangle_origin(ox, oy, oz, v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z):
    """The terms of :func:`_triangle_t` that do not depend on the direction: s = o − v0,
    q = s × e1 and e2 · q."""
    sx, sy, sz = ox - v0x, oy - v0y, oz - v0z
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    return sx, sy, sz, qx, qy, qz, e2x * qx + e2y * qy + e2z * qz


@njit(inline="always", cache=True, error_model="numpy")
def _triangle_from(sx, sy, sz, qx, qy, qz, tq, dx, dy, dz, e1x, e1y, e1z, e2x, e2y, e2z, tmin, tmax):
    """:func:`_triangle_t` from its origin terms (:func:`_triangle_origin`): Möller–Trumbore's
    p = d × e2, det = e1 · p, b1 = (s · p)/det, b2 = (d · q)/det, t = (e2 · q)/det."""
    zero = like(e1x, 0.0)
    one = like(e1x, 1.0)
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    inv = one / det
    b1 = (sx * px + sy * py + sz * pz) * inv
    b2 = (dx * qx + dy * qy + dz * qz) * inv
    t = tq * inv
    ok = ((det != zero) & (b1 >= zero) & (b1 <= one) & (b2 >= zero) & (b1 + b2 <= one)
          & (t > tmin) & (t < tmax) & (t > zero))
    return t, b1, b2, ok


#: Side of a pixel block: a batch's columns hold a tile's pixels block by block
#: (:class:`Batch`), and a pinhole's eye rays are culled block by block
#: (:func:`_tile_candidates`); ``CHUNK`` is a block's worth of rays.
BLOCK = 8
#: Pixel rows per run of a split block (:func:`_tile_candidates`), and the runs per block.
SPLIT_ROWS = 2
_RUNS = (BLOCK + SPLIT_ROWS - 1) // SPLIT_ROWS
#: Rays per chunk of a batch query through the wide BVH, each chunk bounded on its own
#: (a batch's rays come in column order: a tile's pixel blocks, or its points' shadow
#: rays in that order).
CHUNK = 64
#: A chunk whose bound keeps more primitives than this goes ray by ray through the wide
#: BVH: the brute-force loops cost a few vector operations per ray and primitive, a
#: traversal some tens per ray.
CHUNK_CAP = 24
#: Room for the leaves' primitives a chunk's frustum reaches in the wide BVH, before the
#: frustum's own primitive test thins them.
_RAW_CAP = 2 * CHUNK_CAP
#: A pixel block whose frustum keeps more than ``CHUNK_CAP`` primitives is culled again in
#: runs of rows only when the frustum reaches at most this many leaf primitives (the runs
#: then tend to keep few each; a block over a dense mesh reaches more, and its runs would
#: go ray by ray too), so this is also the room of ``Cull.raw``.
_SPLIT_RAW = 4 * CHUNK_CAP
#: Words of a bound: apex, slack, four inward unit plane normals, reach (the frustum), then
#: the low and high corners of a box holding the segments (:func:`_pyramid_box`,
#: :func:`_shaft_box`).
_BOUND_WORDS = 23
#: Where the box of the segments starts in a bound.
_SEG = 17
#: Candidate-list states in its first word (else the number of spheres); ``_SPLIT``: a
#: pixel block whose runs of rows have lists of their own (:func:`_tile_candidates`).
_UNKNOWN, _PER_RAY, _SPLIT = -1, -3, -4
#: What bounds a set of rays (:func:`_bound`).
_NO_BOUND, _FRUSTUM, _BOX = 0, 1, 2

#: Relative padding of the culling bounds (the frustum's planes, the box): far above the
#: rounding of the bounds' arithmetic and of the float32 hit tests, so that no
#: primitive a ray's test could report is culled.
_CULL_PAD = 1e-5
#: Scenes of fewer primitives are not culled: the bounds cost about as much per ray
#: as the tests of a few primitives.
_CULL_MIN_PRIMS = 8
#: Batches of fewer rays are not culled: the bounds cost about 0.7 µs a batch (one
#: thread), the tests of some 30 rays against a Cornell box's 34 triangles.
_CULL_MIN_RAYS = 32


@njit(inline="always", cache=True)
def _cull(R: RayConfig, q, c0, c1, cand, uv, bound):
    """The spheres and triangles (in scene order) that may meet a segment o + t·d,
    tmin < t < tmax, of rays ``c0:c1`` of ``q`` (8, ≥c1), into ``cand``: a conservative
    culling, so the brute-force loops that follow return exactly what they return over
    every primitive.

    Rays from one origin (a pinhole camera's eye rays) and segments that end at one
    point (a light sample's shadow rays to a point or spot light) lie in a frustum from
    that apex (:func:`_bound`; the tile's frustum of Wald et al. 2001's packets and
    Reshetov et al. 2005's frustum culling).  A primitive wholly outside one of its
    planes is culled (:func:`_frustum_prims`).  Otherwise: the bounding box of the
    segments against each primitive's box (a shaft's box, Haines and Wallace 1994),
    e.g. an area light's shadow rays from one tile's points.  Without a bound
    (directions spread over a hemisphere or more, segments of unbounded length: a
    directional light's), every primitive is kept."""
    if c1 - c0 < _CULL_MIN_RAYS or R.sph_radius.shape[0] + R.tri_v.shape[0] < _CULL_MIN_PRIMS:
        _keep_all(R, cand)
        return
    kind = _bound(q, c0, c1, uv, bound)
    if kind == _FRUSTUM:
        _frustum_prims(R, bound, cand)
    elif kind == _BOX:
        _shaft_box(R, q, c0, c1, uv, bound, cand)
    else:
        _keep_all(R, cand)


@njit(inline="always", cache=True)
def _wide_cull(R: RayConfig, q, c0, c1, cand, uv, bound, raw):
    """:func:`_cull` through the wide BVH: the primitives of the leaves a chunk's frustum
    reaches, thinned by the frustum's primitive test (:func:`_wide_prims`); ``_PER_RAY``
    when the chunk is small, has no frustum, or its frustum holds more than
    ``CHUNK_CAP`` primitives."""
    if c1 - c0 < _CULL_MIN_RAYS or _bound(q, c0, c1, uv, bound) != _FRUSTUM:
        cand[0] = _PER_RAY
        return
    _wide_prims(R, bound, raw, cand, _RAW_CAP)


@njit(inline="always", cache=True)
def _wide_prims(R: RayConfig, bound, raw, cand, cap):
    """The primitives the frustum ``bound`` keeps among those of the wide BVH's leaves it
    reaches (:func:`impl.accel.wide.wide_frustum_prims`), in scene order, into ``cand``;
    ``_PER_RAY`` when the leaves hold more than ``cap`` primitives or the frustum keeps
    more than ``CHUNK_CAP``.  Returns how many the leaves held (-1: more than ``cap``)."""
    k = wide_frustum_prims(R, bound, _CULL_PAD, raw, cap)
    if k < 0:
        cand[0] = _PER_RAY
        return k
    ns = R.sph_radius.shape[0]
    kept = 0
    for i in range(k):                   # the frustum's own test, in place
        p = raw[i]
        if not (_sphere_outside(R, p, bound) if p < ns else _triangle_outside(R, p - ns, bound)):
            raw[kept] = p
            kept += 1
    if kept > cand.shape[0] - 2:
        cand[0] = _PER_RAY
        return k
    for i in range(1, kept):             # insertion sort: scene order, the loops' tie rule
        x = raw[i]
        j = i
        while j > 0 and raw[j - 1] > x:
            raw[j] = raw[j - 1]
            j -= 1
        raw[j] = x
    m = 0
    for i in range(kept):                # spheres first: their ids are below ns
        p = raw[i]
        cand[2 + i] = p if p < ns else p - ns
        m += p < ns
    cand[0], cand[1] = m, kept - m
    return k


@njit(inline="always", cache=True)
def _bound(q, c0, c1, uv, bound):
    """What bounds rays ``c0:c1`` of ``q``: ``_FRUSTUM`` (its apex, slack, planes, reach
    and box written to ``bound``: rays from one origin, or segments ending within a small
    slack of one point, their directions within acos(_FRUSTUM_MIN_COS) of the axis; the
    reach is how far from the apex a segment's point can lie — the largest tmax, or for
    segments ending near the apex, the largest distance of an origin plus the slack, as a
    point of a segment is no further from the apex than its two ends), ``_BOX``
    (finite segments otherwise, or a shared origin with too wide a fan) or
    ``_NO_BOUND`` (an unbounded segment)."""
    px, py, pz = float(q[OX, c0]), float(q[OY, c0]), float(q[OZ, c0])
    shared = True
    for i in range(c0, c1):
        if (q[OX, i] != q[OX, c0]) | (q[OY, i] != q[OY, c0]) | (q[OZ, i] != q[OZ, c0]):
            shared = False               # a shadow batch's second ray, as a rule
            break
    if shared:                           # apex: the origin; directions: the rays'
        bound[0], bound[1], bound[2], bound[3] = px, py, pz, 0.0
        reach = 0.0
        for i in range(c0, c1):          # a NaN tmax (a ray that meets nothing) is skipped
            t = float(q[TMAX, i])
            reach = t if t > reach else reach
        bound[16] = reach
        if _frustum_planes(q, c0, c1, False, uv, bound):
            return _FRUSTUM
        return _BOX
    # Segments ending within a small distance δ of one point A: each lies within δ
    # of the ray from A towards its origin, so the frustum from A padded by δ holds it.
    ex, ey, ez = _end(q, c0)
    s2, o2 = uv[0, :c1 - c0], uv[1, :c1 - c0]      # squared: no root per ray
    _spreads(q[OX, c0:c1], q[OY, c0:c1], q[OZ, c0:c1], q[DX, c0:c1], q[DY, c0:c1], q[DZ, c0:c1],
             q[TMAX, c0:c1], ex, ey, ez, s2, o2)
    lo_s, slack2 = _float_range(s2)
    lo_o, span2 = _float_range(o2)
    if not (lo_s >= 0.0 and slack2 < math.inf and lo_o >= 0.0 and span2 < math.inf):
        return _NO_BOUND                 # an unbounded segment (or overflow): no box either
    if slack2 <= _CONVERGE * _CONVERGE * span2:
        bound[0], bound[1], bound[2], bound[3] = ex, ey, ez, math.sqrt(slack2)
        bound[16] = math.sqrt(span2) + math.sqrt(slack2)
        if _frustum_planes(q, c0, c1, True, uv, bound):
            return _FRUSTUM
    return _BOX


#: Segments count as ending at one point when their ends lie within this fraction of the
#: batch's extent of each other (shadow rays to a point light end a relative 1e-9 short
#: of it; the frustum is padded by the actual spread, so this only chooses the bound).
_CONVERGE = 1e-3
#: The frustum is built only when every direction is within this cosine of the mean
#: direction (about 84°): wider bundles are bounded by their box.
_FRUSTUM_MIN_COS = 0.1


@njit(inline="always", cache=True)
def _plane_misses_box(V, j, bound):
    """Whether a box holding the segments (``bound[_SEG:]``) lies wholly on one side of
    triangle ``j``'s plane, more than the padding from it: then no segment crosses the
    plane, and none meets the triangle.  The shaft culling of Haines and Wallace 1994
    with the triangle's own plane: shadow rays from points of a closed room's walls to a
    light inside it never cross another wall's plane, nor those of the faces of a
    convex object that the point and the light both see.  The padding,
    ``_CULL_PAD``·(1 + the largest coordinate) along the unit normal, is absolute like
    the hit test's rounding.  A box unbounded along an axis (its centre or extent then
    NaN), or a degenerate triangle, culls nothing: a comparison with NaN is false."""
    v0x, v0y, v0z = float(V[j, 0, 0]), float(V[j, 0, 1]), float(V[j, 0, 2])
    e1x, e1y, e1z = float(V[j, 1, 0]) - v0x, float(V[j, 1, 1]) - v0y, float(V[j, 1, 2]) - v0z
    e2x, e2y, e2z = float(V[j, 2, 0]) - v0x, float(V[j, 2, 1]) - v0y, float(V[j, 2, 2]) - v0z
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    lx, ly, lz = bound[_SEG], bound[_SEG + 1], bound[_SEG + 2]
    hx, hy, hz = bound[_SEG + 3], bound[_SEG + 4], bound[_SEG + 5]
    cx, cy, cz = 0.5 * (lx + hx), 0.5 * (ly + hy), 0.5 * (lz + hz)
    dist = nx * (cx - v0x) + ny * (cy - v0y) + nz * (cz - v0z)
    spread = abs(nx) * (hx - cx) + abs(ny) * (hy - cy) + abs(nz) * (hz - cz)
    big = max(abs(lx), abs(ly), abs(lz), abs(hx), abs(hy), abs(hz),
              abs(v0x) + abs(e1x) + abs(e2x), abs(v0y) + abs(e1y) + abs(e2y),
              abs(v0z) + abs(e1z) + abs(e2z))
    pad = _CULL_PAD * (1.0 + big) * math.sqrt(nx * nx + ny * ny + nz * nz)
    return abs(dist) > spread + pad


@njit(inline="always", cache=True)
def _end(q, i):
    """The end o + tmax·d of ray i of ``q``, in the rays' precision (numba's ``float()`` of a
    float32 stays a float32)."""
    t = float(q[TMAX, i])
    return (float(q[OX, i]) + t * float(q[DX, i]), float(q[OY, i]) + t * float(q[DY, i]),
            float(q[OZ, i]) + t * float(q[DZ, i]))


@njit(inline="always", cache=True)
def _frustum_planes(q, c0, c1, towards_origins, uv, bound):
    """The frustum from the apex p = ``bound[0:3]`` holding the directions of rays
    ``c0:c1`` of ``q``: the rays' own (``towards_origins`` false) or those from p to the
    rays' origins.  The directions w, about an axis a (their sum's direction) with a frame
    (e1, e2, a), span [u0, u1] × [v0, v1] in u = w·e1 / w·a, v = w·e2 / w·a; the four
    planes u = u0, u = u1, v = v0, v = v1 through p bound a convex cone (in front of p)
    that holds every ray.  Any axis with w·a > 0 for every ray gives a cone holding them,
    so the sum may be taken in any order.  Writes the planes' inward unit normals to
    ``bound[4:16]``; ``uv`` (2, ≥c1−c0) float64 is scratch.  Returns whether it was
    built: not when some direction is more than acos(_FRUSTUM_MIN_COS) from the axis."""
    px, py, pz = bound[0], bound[1], bound[2]
    n = c1 - c0
    if towards_origins:
        wx, wy, wz, ox, oy, oz = q[OX, c0:c1], q[OY, c0:c1], q[OZ, c0:c1], px, py, pz
    else:
        wx, wy, wz, ox, oy, oz = q[DX, c0:c1], q[DY, c0:c1], q[DZ, c0:c1], 0.0, 0.0, 0.0
    ax, ay, az = _direction_sum(wx, wy, wz, ox, oy, oz)
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    if not norm > 0.0:
        return False
    ax, ay, az = ax / norm, ay / norm, az / norm
    # A frame about a (Duff et al. 2017).
    sign = 1.0 if az >= 0.0 else -1.0
    c = -1.0 / (sign + az)
    d = ax * ay * c
    e1x, e1y, e1z = 1.0 + sign * ax * ax * c, sign * d, -sign * ax
    e2x, e2y, e2z = d, sign + ay * ay * c, -ay
    u, v = uv[0, :n], uv[1, :n]
    wide = _frustum_uv(wx, wy, wz, ox, oy, oz, ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z,
                       _FRUSTUM_MIN_COS * _FRUSTUM_MIN_COS, u, v)
    if wide > 0:
        return False
    u0, u1 = _float_range(u)
    v0, v1 = _float_range(v)
    if not (u0 <= u1 and v0 <= v1):      # a NaN coordinate (from a non-finite ray)
        return False
    # Inward unit normals of the planes: e1 − u0 a, u1 a − e1, e2 − v0 a, v1 a − e2.
    bound[4], bound[5], bound[6] = _unit(e1x - u0 * ax, e1y - u0 * ay, e1z - u0 * az)
    bound[7], bound[8], bound[9] = _unit(u1 * ax - e1x, u1 * ay - e1y, u1 * az - e1z)
    bound[10], bound[11], bound[12] = _unit(e2x - v0 * ax, e2y - v0 * ay, e2z - v0 * az)
    bound[13], bound[14], bound[15] = _unit(v1 * ax - e2x, v1 * ay - e2y, v1 * az - e2z)
    _pyramid_box(px, py, pz, ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z, u0, u1, v0, v1, bound)
    return True


@njit(inline="always", cache=True)
def _pyramid_box(px, py, pz, ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z, u0, u1, v0, v1, bound):
    """A box holding every point the frustum ``bound`` bounds, into ``bound[_SEG:]``: the
    box of the apex p and the four points p + r (a + u e1 + v e2), (u, v) the corners of
    [u0, u1] × [v0, v1], r the reach, grown by the slack.  A point w = λ (a + u e1 + v e2)
    from p within the reach has λ ≤ r / |a + u e1 + v e2| ≤ r, so it lies in the pyramid
    of those five points.  O(1) per chunk where the box of the segments themselves costs a
    pass over the rays; unbounded (NaN or infinite) for rays of unbounded reach."""
    r, slack = bound[16], bound[3]
    lx = hx = px
    ly = hy = py
    lz = hz = pz
    for u in (u0, u1):
        for v in (v0, v1):
            x = px + r * (ax + u * e1x + v * e2x)
            y = py + r * (ay + u * e1y + v * e2y)
            z = pz + r * (az + u * e1z + v * e2z)
            lx, ly, lz, hx, hy, hz = min(lx, x), min(ly, y), min(lz, z), max(hx, x), max(hy, y), max(hz, z)
    bound[_SEG], bound[_SEG + 1], bound[_SEG + 2] = lx - slack, ly - slack, lz - slack
    bound[_SEG + 3], bound[_SEG + 4], bound[_SEG + 5] = hx + slack, hy + slack, hz + slack


@njit(inline="always", cache=True)
def _frustum_prims(R: RayConfig, bound, cand):
    """Every primitive the frustum ``bound`` keeps (:func:`_sphere_outside`,
    :func:`_triangle_outside`), in scene order, into ``cand``."""
    m = 0
    for s in range(R.sph_radius.shape[0]):
        if not _sphere_outside(R, s, bound):
            cand[2 + m] = s
            m += 1
    k = 0
    for j in range(R.tri_v.shape[0]):
        if not _triangle_outside(R, j, bound):
            cand[2 + m + k] = j
            k += 1
    cand[0], cand[1] = m, k


@njit(inline="always", cache=True)
def _sphere_outside(R: RayConfig, s, bound):
    """Whether sphere ``s`` lies wholly outside a plane of the frustum ``bound`` (its
    centre more than its radius and the padding outside) or beyond its reach."""
    C = R.sph_center
    x, y, z = float(C[s, 0]) - bound[0], float(C[s, 1]) - bound[1], float(C[s, 2]) - bound[2]
    r = float(R.sph_radius[s]) * (1.0 + _CULL_PAD)
    pad = bound[3] + r + _CULL_PAD * (1.0 + abs(x) + abs(y) + abs(z))
    out = x * x + y * y + z * z > (bound[16] + pad) * (bound[16] + pad)
    for j in range(4):
        out |= bound[4 + 3 * j] * x + bound[5 + 3 * j] * y + bound[6 + 3 * j] * z < -pad
    return out


@njit(inline="always", cache=True)
def _triangle_outside(R: RayConfig, j, bound):
    """Whether triangle ``j`` lies wholly outside a plane of the frustum ``bound`` — its
    three vertices each more than their padding (relative to the distance from the apex,
    bounded above by |x| + |y| + |z|, plus the slack) outside —, its bounding box
    beyond the frustum's reach, or its plane missing the box holding the segments
    (:func:`_plane_misses_box`; tested only for triangles the frustum keeps)."""
    V = R.tri_v
    px, py, pz, slack = bound[0], bound[1], bound[2], bound[3]
    x0, y0, z0 = float(V[j, 0, 0]) - px, float(V[j, 0, 1]) - py, float(V[j, 0, 2]) - pz
    x1, y1, z1 = float(V[j, 1, 0]) - px, float(V[j, 1, 1]) - py, float(V[j, 1, 2]) - pz
    x2, y2, z2 = float(V[j, 2, 0]) - px, float(V[j, 2, 1]) - py, float(V[j, 2, 2]) - pz
    p0 = slack + _CULL_PAD * (1.0 + abs(x0) + abs(y0) + abs(z0))
    p1 = slack + _CULL_PAD * (1.0 + abs(x1) + abs(y1) + abs(z1))
    p2 = slack + _CULL_PAD * (1.0 + abs(x2) + abs(y2) + abs(z2))
    gx = max(min(x0, x1, x2), 0.0) + max(-max(x0, x1, x2), 0.0)   # the box's gap from p
    gy = max(min(y0, y1, y2), 0.0) + max(-max(y0, y1, y2), 0.0)
    gz = max(min(z0, z1, z2), 0.0) + max(-max(z0, z1, z2), 0.0)
    far = bound[16] + max(p0, p1, p2)
    out = gx * gx + gy * gy + gz * gz > far * far
    for k in range(4):
        nx, ny, nz = bound[4 + 3 * k], bound[5 + 3 * k], bound[6 + 3 * k]
        a = nx * x0 + ny * y0 + nz * z0 + p0
        b = nx * x1 + ny * y1 + nz * z1 + p1
        c = nx * x2 + ny * y2 + nz * z2 + p2
        out |= max(a, b, c) < 0.0
    return out or _plane_misses_box(V, j, bound)


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "nsz"})
def _direction_sum(x, y, z, px, py, pz):
    """Σ_i (x_i − px, y_i − py, z_i − pz) in float64, summed in any order (reassociation
    allowed: LLVM vectorises the loop)."""
    sx = sy = sz = 0.0
    for i in range(x.shape[0]):
        sx += float(x[i]) - px
        sy += float(y[i]) - py
        sz += float(z[i]) - pz
    return sx, sy, sz


@njit(cache=True, error_model="numpy")
def _spreads(ox, oy, oz, dx, dy, dz, tmax, ex, ey, ez, s2, o2):
    """Squared distances from the point e of the segments' ends o + tmax·d (into ``s2``) and
    of their origins (into ``o2``): :func:`_end`'s operations (the ends in the rays'
    precision), the differences from e and their squares in float64; no branch, so LLVM
    vectorises the loop."""
    for i in range(ox.shape[0]):
        t = float(tmax[i])
        x = float(ox[i]) + t * float(dx[i]) - ex
        y = float(oy[i]) + t * float(dy[i]) - ey
        z = float(oz[i]) + t * float(dz[i]) - ez
        s2[i] = x * x + y * y + z * z
        x, y, z = float(ox[i]) - ex, float(oy[i]) - ey, float(oz[i]) - ez
        o2[i] = x * x + y * y + z * z


@njit(cache=True, error_model="numpy")
def _segment_ends(o, d, tmin, tmax, a, b):
    """One coordinate of the segments' two ends, o + tmin·d into ``a`` and o + tmax·d into
    ``b`` (float64 arrays; computed in the rays' precision, as :func:`_end`); no branch:
    LLVM vectorises the loop."""
    for i in range(o.shape[0]):
        a[i] = float(o[i]) + float(tmin[i]) * float(d[i])
        b[i] = float(o[i]) + float(tmax[i]) * float(d[i])


@njit(inline="always", cache=True)
def _axis_extent(o, d, tmin, tmax, a, b):
    """(min, max) along one axis of the segments' ends (:func:`_segment_ends` into the
    scratch ``a``, ``b``, then :func:`_float_range`); NaN if an end is not finite (then
    an extreme of its row is: ±inf, or a NaN of either sign)."""
    _segment_ends(o, d, tmin, tmax, a, b)
    lo_a, hi_a = _float_range(a)
    lo_b, hi_b = _float_range(b)
    if not (math.isfinite(lo_a) and math.isfinite(hi_a) and math.isfinite(lo_b)
            and math.isfinite(hi_b)):
        return math.nan, math.nan
    return min(lo_a, lo_b), max(hi_a, hi_b)


#: The magnitude bits of a float64.
_MAGNITUDE = np.int64(0x7FFFFFFFFFFFFFFF)


@njit(cache=True, error_model="numpy")
def _float_range(x):
    """(min, max) of the float64 array ``x`` (non-empty), as integer reductions: the bits b
    of a float64 map to the integer b ^ ((b >> 63) & 0x7fff...) in the floats' order (−0
    below +0), and LLVM vectorises integer min/max reductions but no floating-point one.
    A NaN lands beyond ±inf by its sign bit and comes back as the min or the max, so a
    caller detects it by comparing them."""
    lo = _MAGNITUDE
    hi = -_MAGNITUDE - 1
    for i in range(x.shape[0]):
        b = np.float64(x[i]).view(np.int64)
        k = b ^ ((b >> 63) & _MAGNITUDE)
        lo = min(lo, k)
        hi = max(hi, k)
    lo = lo ^ ((lo >> 63) & _MAGNITUDE)
    hi = hi ^ ((hi >> 63) & _MAGNITUDE)
    return np.int64(lo).view(np.float64), np.int64(hi).view(np.float64)


@njit(cache=True, error_model="numpy")
def _frustum_uv(x, y, z, px, py, pz, ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z, c2, u, v):
    """Projective coordinates u = w·e1 / w·a, v = w·e2 / w·a of the directions
    w = (x_i − px, y_i − py, z_i − pz) into ``u``, ``v``; returns how many directions lie
    behind a or wider than the cosine whose square is ``c2``.  No branch: LLVM
    vectorises the loop, divisions included."""
    wide = 0
    for i in range(x.shape[0]):
        wx, wy, wz = float(x[i]) - px, float(y[i]) - py, float(z[i]) - pz
        wa = wx * ax + wy * ay + wz * az
        ok = (wa > 0.0) & (wa * wa >= c2 * (wx * wx + wy * wy + wz * wz))
        wide += 0 if ok else 1
        inv = 1.0 / wa
        u[i] = (wx * e1x + wy * e1y + wz * e1z) * inv
        v[i] = (wx * e2x + wy * e2y + wz * e2z) * inv
    return wide


@njit(inline="always", cache=True)
def _unit(x, y, z):
    """(x, y, z) / |(x, y, z)|."""
    r = math.sqrt(x * x + y * y + z * z)
    return x / r, y / r, z / r


@njit(inline="always", cache=True)
def _shaft_box(R: RayConfig, q, c0, c1, uv, bound, cand):
    """Cull by the bounding box of segments ``c0:c1`` (every primitive kept when one is
    unbounded): a primitive whose box misses it, or a triangle whose plane it lies
    wholly on one side of (:func:`_plane_misses_box`; the box goes to ``bound[_SEG:]``).
    The box's extremes are taken axis by axis over the segments' two ends (written to
    the scratch ``uv`` by :func:`_segment_ends`) with :func:`_float_range`: a non-finite
    end makes an extreme non-finite."""
    C, g, V = R.sph_center, R.sph_radius, R.tri_v
    a, b = uv[0, :c1 - c0], uv[1, :c1 - c0]
    lo_x, hi_x = _axis_extent(q[OX, c0:c1], q[DX, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], a, b)
    lo_y, hi_y = _axis_extent(q[OY, c0:c1], q[DY, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], a, b)
    lo_z, hi_z = _axis_extent(q[OZ, c0:c1], q[DZ, c0:c1], q[TMIN, c0:c1], q[TMAX, c0:c1], a, b)
    if not (math.isfinite(lo_x) and math.isfinite(lo_y) and math.isfinite(lo_z)
            and math.isfinite(hi_x) and math.isfinite(hi_y) and math.isfinite(hi_z)):
        _keep_all(R, cand)               # an unbounded segment
        return
    bound[_SEG], bound[_SEG + 1], bound[_SEG + 2] = lo_x, lo_y, lo_z
    bound[_SEG + 3], bound[_SEG + 4], bound[_SEG + 5] = hi_x, hi_y, hi_z
    pad = _CULL_PAD * (1.0 + max(abs(lo_x), abs(lo_y), abs(lo_z), abs(hi_x), abs(hi_y), abs(hi_z)))
    lo_x, lo_y, lo_z = lo_x - pad, lo_y - pad, lo_z - pad
    hi_x, hi_y, hi_z = hi_x + pad, hi_y + pad, hi_z + pad
    m = 0
    for s in range(g.shape[0]):
        r = float(g[s])
        if (C[s, 0] + r >= lo_x and C[s, 0] - r <= hi_x and C[s, 1] + r >= lo_y
                and C[s, 1] - r <= hi_y and C[s, 2] + r >= lo_z and C[s, 2] - r <= hi_z):
            cand[2 + m] = s
            m += 1
    k = 0
    for j in range(V.shape[0]):
        if (max(V[j, 0, 0], V[j, 1, 0], V[j, 2, 0]) >= lo_x
                and min(V[j, 0, 0], V[j, 1, 0], V[j, 2, 0]) <= hi_x
                and max(V[j, 0, 1], V[j, 1, 1], V[j, 2, 1]) >= lo_y
                and min(V[j, 0, 1], V[j, 1, 1], V[j, 2, 1]) <= hi_y
                and max(V[j, 0, 2], V[j, 1, 2], V[j, 2, 2]) >= lo_z
                and min(V[j, 0, 2], V[j, 1, 2], V[j, 2, 2]) <= hi_z
                and not _plane_misses_box(V, j, bound)):
            cand[2 + m + k] = j
            k += 1
    cand[0], cand[1] = m, k


@njit(inline="always", cache=True)
def _keep_all(R: RayConfig, cand):
    """Every sphere and triangle as candidates: ``[S, T, 0, 1, …, S−1, 0, 1, …, T−1]``."""
    S, T = R.sph_radius.shape[0], R.tri_v.shape[0]
    for s in range(S):
        cand[2 + s] = s
    for j in range(T):
        cand[2 + S + j] = j
    cand[0], cand[1] = S, T


@njit(inline="always", cache=True)
def _no_hits(g, tmax, best, bp, b1s, b2s):
    """The answers of rays that meet nothing yet: ``best`` = tmax, ``bp`` = −1, barycentrics 0."""
    zero = like(g, 0.0)
    for i in range(best.shape[0]):
        best[i] = tmax[i]
        bp[i] = -1
        b1s[i] = zero
        b2s[i] = zero


@njit(inline="always", cache=True)
def _edges(V, j):
    """Triangle j's first vertex and edges e1 = v1 − v0, e2 = v2 − v0 (V's precision)."""
    v0x, v0y, v0z = V[j, 0, 0], V[j, 0, 1], V[j, 0, 2]
    return (v0x, v0y, v0z, V[j, 1, 0] - v0x, V[j, 1, 1] - v0y, V[j, 1, 2] - v0z,
            V[j, 2, 0] - v0x, V[j, 2, 1] - v0y, V[j, 2, 2] - v0z)


@batch_kernel(error_model="numpy", disjoint=True)
def _closest_loops(C, g, V, sph, tri, ox, oy, oz, dx, dy, dz, tmin, tmax, best, bp, b1s, b2s):
    """Closest hits of the rays (ox..tmax, one array per component) among spheres
    ``sph`` of (C, g) and triangles ``tri`` of V (index lists in scene order),
    primitive-outer / ray-inner: the inner loops have no branch, so LLVM vectorises them
    over the rays.  Writes the hit distance ``best``,
    primitive ``bp`` (-1 on a miss) and barycentrics ``b1s``, ``b2s``.

    A function of its own, every array a separate argument: inlined into its caller,
    where the outputs were rows of one 2-D array, LLVM kept the loops scalar (it
    could not separate the stores to the rows from the loads)."""
    n = ox.shape[0]
    _no_hits(g, tmax, best, bp, b1s, b2s)
    ns = g.shape[0]
    for s in sph:
        cx, cy, cz, r = C[s, 0], C[s, 1], C[s, 2], g[s]
        for i in range(n):
            tt, ok = _sphere_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], cx, cy, cz, r, tmin[i],
                               best[i])
            best[i] = tt if ok else best[i]
            bp[i] = s if ok else bp[i]
    for j in tri:
        v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z = _edges(V, j)
        pj = ns + j
        for i in range(n):
            tt, c1, c2, ok = _triangle_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], v0x, v0y, v0z,
                                         e1x, e1y, e1z, e2x, e2y, e2z, tmin[i], best[i])
            best[i] = tt if ok else best[i]
            bp[i] = pj if ok else bp[i]
            b1s[i] = c1 if ok else b1s[i]
            b2s[i] = c2 if ok else b2s[i]


@batch_kernel(error_model="numpy", disjoint=True)
def _closest_loops_from(C, g, V, sph, tri, ox, oy, oz, dx, dy, dz, tmin, tmax, best, bp, b1s, b2s):
    """:func:`_closest_loops` for rays from one origin (``ox``, ``oy``, ``oz`` scalars in R's
    precision; a pinhole camera's eye rays): the terms of a test that depend on the
    origin and the primitive alone (:func:`_sphere_origin`, :func:`_triangle_origin`)
    are computed once per primitive instead of once per ray and primitive.  The same
    operations on the same values: the answers are :func:`_closest_loops`' bit for bit."""
    n = dx.shape[0]
    _no_hits(g, tmax, best, bp, b1s, b2s)
    ns = g.shape[0]
    for s in sph:
        r = g[s]
        fx, fy, fz, c = _sphere_origin(ox, oy, oz, C[s, 0], C[s, 1], C[s, 2], r)
        for i in range(n):
            tt, ok = _sphere_from(fx, fy, fz, c, dx[i], dy[i], dz[i], r, tmin[i], best[i])
            best[i] = tt if ok else best[i]
            bp[i] = s if ok else bp[i]
    for j in tri:
        v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z = _edges(V, j)
        sx, sy, sz, qx, qy, qz, tq = _triangle_origin(ox, oy, oz, v0x, v0y, v0z, e1x, e1y, e1z,
                                                      e2x, e2y, e2z)
        pj = ns + j
        for i in range(n):
            tt, c1, c2, ok = _triangle_from(sx, sy, sz, qx, qy, qz, tq, dx[i], dy[i], dz[i], e1x,
                                            e1y, e1z, e2x, e2y, e2z, tmin[i], best[i])
            best[i] = tt if ok else best[i]
            bp[i] = pj if ok else bp[i]
            b1s[i] = c1 if ok else b1s[i]
            b2s[i] = c2 if ok else b2s[i]


@batch_kernel(error_model="numpy", disjoint=True)
def _occluded_loops(C, g, V, sph, tri, ox, oy, oz, dx, dy, dz, tmin, tmax, hitm):
    """Whether any sphere ``sph`` of (C, g) or triangle ``tri`` of V lies on each ray
    within (tmin, tmax), primitive-outer / ray-inner with branch-free inner loops
    (vectorised over the rays)."""
    n = ox.shape[0]
    for i in range(n):
        hitm[i] = False
    for s in sph:
        cx, cy, cz, r = C[s, 0], C[s, 1], C[s, 2], g[s]
        for i in range(n):
            _, ok = _sphere_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], cx, cy, cz, r, tmin[i],
                              tmax[i])
            hitm[i] = hitm[i] | ok
    for j in tri:
        v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z = _edges(V, j)
        for i in range(n):
            _, _, _, ok = _triangle_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], v0x, v0y, v0z,
                                      e1x, e1y, e1z, e2x, e2y, e2z, tmin[i], tmax[i])
            hitm[i] = hitm[i] | ok


@njit(inline="always", cache=True)
def accumulate(T: Batch, s):
    """Add sample ``s`` (0-based; radiance ``T.L``) to every pixel's Welford state."""
    A, L = T.acc, T.L
    _welford(s + 1.0, L[0], L[1], L[2], A[0], A[1], A[2], A[3], A[4], A[5])


@batch_kernel
def _welford(c, x0, x1, x2, m0, m1, m2, q0, q1, q2):
    """Welford's update with sample number ``c`` (1-based) of values x per column: the
    running means m and squared-deviation sums q, one array each (a loop LLVM
    vectorises, divisions included)."""
    for i in range(x0.shape[0]):
        d = x0[i] - m0[i]
        m0[i] += d / c
        q0[i] += d * (x0[i] - m0[i])
        d = x1[i] - m1[i]
        m1[i] += d / c
        q1[i] += d * (x1[i] - m1[i])
        d = x2[i] - m2[i]
        m2[i] += d / c
        q2[i] += d * (x2[i] - m2[i])


@njit(cache=True)
def store(T: Batch, film: Film, spp):
    """Write the tile's mean, variance of the mean and counts into the film."""
    for i in range(T.n):
        x, y = int(T.xy[0, i]), int(T.xy[1, i])
        for k in range(3):
            film.mean[y, x, k] = T.acc[k, i]
            film.var[y, x, k] = variance_of_mean(T.acc[3 + k, i], spp)
        for c in range(T.cnt.shape[1]):
            film.cnt[y, x, c] = T.cnt[i, c]
