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
shading points a tracer collects along its rays (``whitted``'s diffuse
leaves) to light them together.  A tracer module is thus its transport step plus a
ten-line tile function and ``prange`` loop (numba cannot cache a kernel that
takes or closes over another kernel, so the loop itself cannot live here).

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
so the image does not depend on the path taken.  The algebraic and geometric
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

import numba
import numpy as np
from numba import njit

from core.algorithm import RenderResult

from .accel import closest_rays, occluded_rays
from .accel.packets import TILE, packet_hits
from .camera import SENSOR_THINLENS, eye_ray, eye_ray_lens
from .intersect import like
from .kernel import batch_kernel
from .rng import uniform_from, uniform_prefix
from .rays import PARAMS as RAY_PARAMS, RayConfig, ray_config
from .sampling import pixel_sample, strata, variance_of_mean
from .scene_arrays import scene_memo

#: The random dimensions of a thin lens's aperture sample (beyond any tracer's own).
DIM_LENS = 1 << 29

__all__ = ["TILE", "BATCH_TILE", "Film", "Batch", "new_film", "film_counters", "film_result", "new_batch",
           "new_points",
           "ray_config_cached", "run_tiles", "eye_batch", "closest_batch", "occluded_batch", "accumulate",
           "store", "OX", "OY", "OZ", "DX", "DY", "DZ", "TMIN", "TMAX"]

#: Tile side without packets.
BATCH_TILE = 16

#: Rows of a ray batch (``Batch.ray``): origin, unit direction, valid range.
OX, OY, OZ, DX, DY, DZ, TMIN, TMAX = range(8)


class Film(NamedTuple):
    """A render's outputs, written tile by tile."""

    mean: np.ndarray            # (H, W, 3) pixel mean
    var: np.ndarray             # (H, W, 3) variance of the mean
    cnt: np.ndarray             # (H, W, C) int64 per-pixel ray counts of the tracer's C counters
    packet: np.ndarray          # (tiles, 2) packet nodes and tests per tile
    packets: bool               # trace eye rays as packets
    tile: int                   # tile side in pixels
    sampler: int                # pixel sampler code (impl.sampling.PIXEL_*)


class Batch(NamedTuple):
    """One tile's rays of one sample index, structure of arrays (column ``i`` = pixel ``i``
    of the tile, at ``(x0 + i % nx, y0 + i // nx)``), with the scratch arrays the steps
    reuse from sample to sample (no allocation inside the sample loop)."""

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
    pts: np.ndarray             # (15, n) shading points: p, g, s, v, ρ (impl.lighting SP_*)
    active: np.ndarray          # (n,) bool: the shading points to light
    sh: np.ndarray              # (8, n) a batch of shadow rays
    sh_w: np.ndarray            # (3, n) their radiance contributions
    sh_i: np.ndarray            # (n,) their columns
    blocked: np.ndarray         # (n,) bool: occluded_batch's answers
    q: np.ndarray               # (8, n) rays in the intersection precision
    qt: np.ndarray              # (3, n) t, b1, b2 in the intersection precision
    qp: np.ndarray              # (n,) int32 primitive (int32: the loops then vectorise in float32 too)


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
    the packets' (``TILE``) with packets, else ``BATCH_TILE`` (fewer, larger batches:
    each batch step has a fixed cost)."""
    ts = TILE if packets else BATCH_TILE
    tiles = ((W + ts - 1) // ts) * ((H + ts - 1) // ts)
    return Film(np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.zeros((H, W, counters), np.int64),
                np.zeros((tiles, 2), np.int64), bool(packets), ts, int(sampler))


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


def run_tiles(kernel, *args):
    """Call a tracer's tile kernel (a ``prange`` over the film's tiles) with one tile per
    scheduling chunk, so each thread takes the next tile when it finishes one.  numba's
    default hands each thread one equal block of tiles, and tiles differ in cost (a
    tile of sky traces no shadow or secondary rays), so one thread would idle while
    the other finishes its block."""
    with numba.parallel_chunksize(1):
        return kernel(*args)


@njit(cache=True)
def new_batch(film: Film, R: RayConfig, tile):
    """The batch of tile ``tile`` (of ``film.tile``-square tiles) with zeroed accumulators."""
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
    for i in range(n):
        pixel[i] = (y0 + i // nx) * W + x0 + i % nx
    return Batch(x0, y0, nx, n, np.empty((8, n)), np.empty(n), np.empty(n, np.int64),
                 np.empty((2, n)), np.zeros((3, n)), np.zeros((6, n)), np.zeros((n, C), np.int64),
                 film.packet[tile], np.empty((P, 8)), np.empty((P, 2)), pixel,
                 np.empty((15, n)), np.zeros(n, np.bool_), np.empty((8, n)), np.empty((3, n)),
                 np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty((8, n), F),
                 np.empty((3, n), F), np.empty(n, np.int32))


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
                 np.empty((15, n)), np.zeros(n, np.bool_), np.empty((8, n)), np.empty((3, n)),
                 np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty((8, n), F),
                 np.empty((3, n), F), np.empty(n, np.int32))


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
    lens = cam[18] == SENSOR_THINLENS     # a lens point (camera_params(..., lens=True) only)
    i = 0
    for y in range(T.y0, T.y0 + T.n // T.nx):
        for x in range(T.x0, T.x0 + T.nx):
            fx, fy = pixel_sample(spp, k, s, seed, T.pixel[i], sampler, x, y)
            if lens:
                h = uniform_prefix(seed, T.pixel[i], s)
                ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray_lens(
                    cam, x + fx, y + fy, uniform_from(h, DIM_LENS), uniform_from(h, DIM_LENS + 1))
            else:
                ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + fx, y + fy)
            ray[OX, i], ray[OY, i], ray[OZ, i] = float(like(g, ox)), float(like(g, oy)), float(like(g, oz))
            ray[DX, i], ray[DY, i], ray[DZ, i] = float(like(g, dx)), float(like(g, dy)), float(like(g, dz))
            ray[TMIN, i], ray[TMAX, i] = tmin, tmax
            i += 1
    if packets:
        for i in range(T.n):
            for c in range(8):
                T.aos[i, c] = ray[c, i]
        packet_hits(R, T.aos, T.n, T.t, T.prim, T.aos_b, T.packet)
        for i in range(T.n):
            T.b[0, i], T.b[1, i] = T.aos_b[i, 0], T.aos_b[i, 1]
    else:
        closest_batch(R, ray, T.n, T.t, T.prim, T.b, T.q, T.qt, T.qp)


@njit(cache=True, error_model="numpy", _nrt=True)
def closest_batch(R: RayConfig, ray, n, t, prim, b, q, qt, qp):
    """Closest hits of the first ``n`` rays of ``ray`` (8, ≥n) in R's form, precision and
    structure: ``t`` (float64), ``prim`` (-1 on a miss), ``b`` (2, n) barycentrics.
    ``q`` (8, ≥n), ``qt`` (3, ≥n) in R's precision and ``qp`` (≥n,) int32 are scratch."""
    if R.accel == 0 and R.form == 2:
        _closest_brute(R, ray, n, t, prim, b, q, qt, qp)
        return
    closest_rays(R, ray[OX, :n], ray[OY, :n], ray[OZ, :n], ray[DX, :n], ray[DY, :n], ray[DZ, :n],
                 ray[TMIN, :n], ray[TMAX, :n], t[:n], prim[:n], b[0, :n], b[1, :n])


@njit(cache=True, error_model="numpy", _nrt=True)
def occluded_batch(R: RayConfig, ray, n, blocked, q):
    """Whether anything lies on each of the first ``n`` rays of ``ray`` (8, ≥n) within
    (tmin, tmax), in R's form, precision and structure; ``q`` (8, ≥n) in R's precision
    is scratch."""
    if R.accel == 0 and R.form == 2:
        _occluded_brute(R, ray, n, blocked, q)
        return
    occluded_rays(R, ray[OX, :n], ray[OY, :n], ray[OZ, :n], ray[DX, :n], ray[DY, :n], ray[DZ, :n],
                  ray[TMIN, :n], ray[TMAX, :n], blocked[:n])


@njit(inline="always", cache=True, error_model="numpy")
def _in_precision(ray, n, q):
    """Copy the rays' rows into ``q`` (R's precision)."""
    for c in range(8):
        for i in range(n):
            q[c, i] = ray[c, i]


@njit(inline="always", cache=True, error_model="numpy")
def _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """:func:`impl.intersect.ray_sphere_stable` without branches: its t in (tmin, tmax)
    and whether there is one (same operations, selects instead of returns)."""
    zero = like(r, 0.0)
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    bq = -(fx * dx + fy * dy + fz * dz)
    px, py, pz = fx + bq * dx, fy + bq * dy, fz + bq * dz
    disc = r * r - (px * px + py * py + pz * pz)
    c = fx * fx + fy * fy + fz * fz - r * r
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
    zero = like(e1x, 0.0)
    one = like(e1x, 1.0)
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    inv = one / det
    sx, sy, sz = ox - v0x, oy - v0y, oz - v0z
    b1 = (sx * px + sy * py + sz * pz) * inv
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    b2 = (dx * qx + dy * qy + dz * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    ok = ((det != zero) & (b1 >= zero) & (b1 <= one) & (b2 >= zero) & (b1 + b2 <= one)
          & (t > tmin) & (t < tmax) & (t > zero))
    return t, b1, b2, ok


@njit(inline="always", cache=True, error_model="numpy")
def _closest_brute(R: RayConfig, ray, n, t, prim, b, q, qt, bp):
    """Brute-force closest hits, primitive-outer / ray-inner (the inner loops vectorise)."""
    _in_precision(ray, n, q)
    g = R.sph_radius
    best, b1s, b2s = qt[0], qt[1], qt[2]
    zero = like(g, 0.0)
    for i in range(n):
        best[i] = q[TMAX, i]
        bp[i] = -1
        b1s[i] = zero
        b2s[i] = zero
    ox, oy, oz, dx, dy, dz, tmin = q[OX], q[OY], q[OZ], q[DX], q[DY], q[DZ], q[TMIN]
    ns = g.shape[0]
    C = R.sph_center
    for s in range(ns):
        cx, cy, cz, r = C[s, 0], C[s, 1], C[s, 2], g[s]
        for i in range(n):
            tt, ok = _sphere_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], cx, cy, cz, r, tmin[i],
                               best[i])
            best[i] = tt if ok else best[i]
            bp[i] = s if ok else bp[i]
    V = R.tri_v
    for j in range(V.shape[0]):
        v0x, v0y, v0z = V[j, 0, 0], V[j, 0, 1], V[j, 0, 2]
        e1x, e1y, e1z = V[j, 1, 0] - v0x, V[j, 1, 1] - v0y, V[j, 1, 2] - v0z
        e2x, e2y, e2z = V[j, 2, 0] - v0x, V[j, 2, 1] - v0y, V[j, 2, 2] - v0z
        pj = ns + j
        for i in range(n):
            tt, c1, c2, ok = _triangle_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], v0x, v0y, v0z,
                                         e1x, e1y, e1z, e2x, e2y, e2z, tmin[i], best[i])
            best[i] = tt if ok else best[i]
            bp[i] = pj if ok else bp[i]
            b1s[i] = c1 if ok else b1s[i]
            b2s[i] = c2 if ok else b2s[i]
    for i in range(n):
        t[i] = float(best[i])
        prim[i] = bp[i]
        b[0, i] = float(b1s[i])
        b[1, i] = float(b2s[i])


@njit(inline="always", cache=True, error_model="numpy")
def _occluded_brute(R: RayConfig, ray, n, hitm, q):
    """Brute-force any-hit, primitive-outer / ray-inner (the inner loops vectorise)."""
    _in_precision(ray, n, q)
    g = R.sph_radius
    for i in range(n):
        hitm[i] = False
    ox, oy, oz, dx, dy, dz, tmin, tmax = q[OX], q[OY], q[OZ], q[DX], q[DY], q[DZ], q[TMIN], q[TMAX]
    C = R.sph_center
    for s in range(g.shape[0]):
        cx, cy, cz, r = C[s, 0], C[s, 1], C[s, 2], g[s]
        for i in range(n):
            _, ok = _sphere_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], cx, cy, cz, r, tmin[i],
                              tmax[i])
            hitm[i] = hitm[i] | ok
    V = R.tri_v
    for j in range(V.shape[0]):
        v0x, v0y, v0z = V[j, 0, 0], V[j, 0, 1], V[j, 0, 2]
        e1x, e1y, e1z = V[j, 1, 0] - v0x, V[j, 1, 1] - v0y, V[j, 1, 2] - v0z
        e2x, e2y, e2z = V[j, 2, 0] - v0x, V[j, 2, 1] - v0y, V[j, 2, 2] - v0z
        for i in range(n):
            _, _, _, ok = _triangle_t(ox[i], oy[i], oz[i], dx[i], dy[i], dz[i], v0x, v0y, v0z,
                                      e1x, e1y, e1z, e2x, e2y, e2z, tmin[i], tmax[i])
            hitm[i] = hitm[i] | ok


@njit(inline="always", cache=True)
def accumulate(T: Batch, s):
    """Add sample ``s`` (0-based; radiance ``T.L``) to every pixel's Welford state."""
    c = s + 1.0
    for k in range(3):
        for i in range(T.n):
            x = T.L[k, i]
            d = x - T.acc[k, i]
            T.acc[k, i] += d / c
            T.acc[3 + k, i] += d * (x - T.acc[k, i])


@njit(cache=True)
def store(T: Batch, film: Film, spp):
    """Write the tile's mean, variance of the mean and counts into the film."""
    for i in range(T.n):
        x, y = T.x0 + i % T.nx, T.y0 + i // T.nx
        for k in range(3):
            film.mean[y, x, k] = T.acc[k, i]
            film.var[y, x, k] = variance_of_mean(T.acc[3 + k, i], spp)
        for c in range(T.cnt.shape[1]):
            film.cnt[y, x, c] = T.cnt[i, c]
