"""Acceleration structures for the ray tracers' hit queries (thesis 1.2.4, 1.3.3.1–3, 2.6).

Thesis 2.6 names three ways to speed up ray tracing: fewer rays, faster
tests, and fewer tests per ray.  This package is the third: structures that
let a ray skip most primitives.  Every structure returns exactly the closest
hit of brute force (same primitive, same ``t``; see :mod:`.primitives`).

=============  ==========================================  ======================
``accel``      structure                                   module
=============  ==========================================  ======================
none           brute force, every primitive (n·I)          :mod:`impl.intersect`
bv             per-object bounding boxes (n·B + m·I)       :mod:`.bounding_volumes`
bv-sphere      per-object bounding spheres                 :mod:`.bounding_volumes`
slabs          per-object Kay–Kajiya slabs, k normals      :mod:`.slabs`
bvh-median     BVH, object-median split                    :mod:`.bvh`
bvh-sah        BVH, binned surface-area heuristic          :mod:`.bvh`
bvh-gs         BVH, Goldsmith–Salmon incremental insertion :mod:`.goldsmith_salmon`
bvh-wide       the SAH BVH collapsed to 4-wide nodes,      :mod:`.wide`
               float32 SoA child boxes
grid           uniform grid, 3D-DDA, mailboxing            :mod:`.grid`
octree         octree (non-uniform subdivision)            :mod:`.octree`
=============  ==========================================  ======================

:func:`build` makes the flat arrays a :class:`impl.rays.RayConfig` carries;
:func:`closest` / :func:`any_hit` dispatch on the traversal code
(:data:`KIND`) and return the counters (nodes or volumes or voxels visited,
primitive tests) with the hit.  :func:`trace_batch` runs a batch of rays in
parallel and keeps the counters — for the tests, benchmarks and the scaling
study; the ray tracers call :func:`impl.rays.hit`, which drops them.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from core.errors import ParamError

from ..intersect import any_hit_form, closest_hit_form, like as _cast
from .bounding_volumes import BOX, SPHERE, bv_any, bv_closest, build_objects
from .bvh import build_bvh
from .goldsmith_salmon import build_goldsmith_salmon
from .grid import DENSITY as GRID_DENSITY, build_grid, grid_any, grid_closest
from .octree import build_octree
from .primitives import prim_bounds
from .slabs import SLAB_COUNTS, build_slabs, slabs_any, slabs_closest
from .tree import (STACK, tree_any, tree_closest, tree_closest_rays, tree_depth,
                   tree_occluded_rays)
from .wide import (WIDTH, collapse, wide_any, wide_arrays, wide_closest, wide_closest_rays,
                   wide_depth, wide_occluded_rays)

__all__ = ["ACCELS", "KIND", "Accel", "build", "empty", "closest", "any_hit", "closest_rays",
           "occluded_rays", "trace_batch", "occluded_batch", "SLAB_COUNTS", "GRID_DENSITY",
           "memory_bytes"]

ACCELS = ("none", "bv", "bv-sphere", "slabs", "bvh-median", "bvh-sah", "bvh-gs", "grid", "octree",
          "bvh-wide")
#: Traversal codes.
NONE, BV, SLABS, TREE, GRID, WIDE = 0, 1, 2, 3, 4, 5
KIND = {"none": NONE, "bv": BV, "bv-sphere": BV, "slabs": SLABS, "bvh-median": TREE,
        "bvh-sah": TREE, "bvh-gs": TREE, "grid": GRID, "octree": TREE, "bvh-wide": WIDE}


class Accel(NamedTuple):
    """A structure's flat arrays (the fields :class:`impl.rays.RayConfig` carries)."""

    kind: int
    node_lo: np.ndarray     # (N, 3) or (O, k) float64
    node_hi: np.ndarray
    node_a: np.ndarray      # (N,) int64
    node_b: np.ndarray      # (N,) int64
    prim_idx: np.ndarray    # (M,) int64
    acc_f: np.ndarray       # (K,) float64
    acc_i: np.ndarray       # (K,) int64


def empty() -> Accel:
    """No structure (brute force)."""
    z2 = np.empty((0, 3))
    zi = np.empty(0, dtype=np.int64)
    return Accel(NONE, z2, z2.copy(), zi, zi.copy(), zi.copy(), np.empty(0), zi.copy())


def memory_bytes(acc: Accel) -> int:
    """Bytes of the structure's arrays."""
    return int(sum(a.nbytes for a in acc[1:]))


def build(name: str, sph_center, sph_radius, tri_v, prim_shape=None, *, slab_normals: int = 7,
          grid_density: float | None = None, grid_mailbox: bool = True,
          grid_current_voxel: bool = True) -> Accel:
    """Build structure ``name`` (one of :data:`ACCELS`) over the primitives as the ray
    configuration holds them (its precision); ``prim_shape`` (P,) groups them into
    objects for ``bv``, ``bv-sphere`` and ``slabs`` (default: one object each).
    ``grid_*``: the uniform grid's resolution (voxels per primitive; None = its
    default), mailboxing and current-voxel rule (:mod:`.grid`)."""
    if name not in ACCELS:
        raise ParamError(f"accel: unknown structure {name!r} (valid: {', '.join(ACCELS)})")
    n = len(sph_radius) + len(tri_v)
    if name == "none" or n == 0:
        return empty()
    lo, hi = prim_bounds(sph_center, sph_radius, tri_v)
    if prim_shape is None:
        prim_shape = np.arange(n)
    zi = np.empty(0, dtype=np.int64)
    if name in ("bv", "bv-sphere"):
        blo, bhi, spheres, offsets, idx = build_objects(lo, hi, sph_center, sph_radius, tri_v,
                                                        prim_shape)
        return Accel(BV, blo, bhi, offsets, zi, idx, spheres,
                     np.array([BOX if name == "bv" else SPHERE], dtype=np.int64))
    if name == "slabs":
        dn, df, normals, offsets, idx = build_slabs(lo, hi, sph_center, sph_radius, tri_v,
                                                    prim_shape, int(slab_normals))
        return Accel(SLABS, dn, df, offsets, zi, idx, normals, zi)
    if name == "grid":
        kw = {} if grid_density is None else {"density": grid_density}
        glo, ghi, cs, res, offsets, refs = build_grid(lo, hi, mailbox=grid_mailbox,
                                                      current_voxel=grid_current_voxel, **kw)
        return Accel(GRID, glo, ghi, offsets, zi, refs, cs, res)
    if name == "bvh-wide":
        nlo, nhi, na, nb, idx = build_bvh(lo, hi, "sah")
        box32, slot_a, slot_b = collapse(nlo, nhi, na, nb, WIDTH)
        need = wide_depth(slot_a, slot_b, WIDTH)
        if need > STACK:
            raise RuntimeError(f"accel {name}: the tree needs a traversal stack of {need} "
                               f"(> {STACK}); the scene is too degenerate for it")
        acc_f, acc_i = wide_arrays(box32, slot_a, slot_b, idx, sph_center, sph_radius, tri_v)
        return Accel(WIDE, nlo[:1].copy(), nhi[:1].copy(), slot_a, slot_b, idx, acc_f, acc_i)
    if name == "bvh-median":
        arrays = build_bvh(lo, hi, "median")
    elif name == "bvh-sah":
        arrays = build_bvh(lo, hi, "sah")
    elif name == "bvh-gs":
        arrays = build_goldsmith_salmon(lo, hi)
    else:
        arrays = build_octree(lo, hi)
    _, need = tree_depth(arrays[2], arrays[3])
    if need > STACK:
        raise RuntimeError(f"accel {name}: the tree needs a traversal stack of {need} "
                           f"(> {STACK}); the scene is too degenerate for it")
    nlo, nhi, na, nb, idx = arrays
    return Accel(TREE, nlo, nhi, na, nb, idx, np.empty(0), zi)


def timed_build(name, *args, **kw):
    """``(accel, seconds)`` — the build's wall time (numba compile excluded only if warm)."""
    t0 = time.perf_counter()
    acc = build(name, *args, **kw)
    return acc, time.perf_counter() - t0


@njit(cache=True, _nrt=True)
def closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit through R's structure: ``(t, prim, b1, b2, nodes, tests)`` in R's
    precision (arguments too); ``R.accel`` must not be ``NONE``."""
    k = R.accel
    if k == WIDE:
        return wide_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == TREE:
        return tree_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == GRID:
        return grid_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == BV:
        return bv_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    return slabs_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(cache=True, _nrt=True)
def any_hit(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax) through R's structure: ``(hit, nodes, tests)``."""
    k = R.accel
    if k == WIDE:
        return wide_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == TREE:
        return tree_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == GRID:
        return grid_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if k == BV:
        return bv_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    return slabs_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(cache=True, error_model="numpy", _nrt=True)
def closest_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2):
    """Closest hits of the N rays given as float64 arrays (N,), one after the other, in
    R's form, precision and structure (what :func:`impl.rays.hit` returns for each):
    ``out_t`` (tmax on a miss), ``out_b1``, ``out_b2`` float64 (N,), ``out_prim``
    int64 (N,) (-1 on a miss).  The wide BVH and the binary trees run batch loops
    that bind R's arrays once; brute force binds them too; the grid, bounding
    volumes and slabs go ray by ray through :func:`closest`."""
    k = R.accel
    if k == WIDE:
        wide_closest_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2)
        return
    if k == TREE:
        tree_closest_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_t, out_prim, out_b1, out_b2)
        return
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    g = sr
    for i in range(ox.shape[0]):
        a = (_cast(g, ox[i]), _cast(g, oy[i]), _cast(g, oz[i]), _cast(g, dx[i]), _cast(g, dy[i]),
             _cast(g, dz[i]), _cast(g, tmin[i]), _cast(g, tmax[i]))
        if k == NONE:
            t, p, b1, b2 = closest_hit_form(form, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7],
                                            sc, sr, tv)
        else:
            t, p, b1, b2, _, _ = closest(R, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7])
        out_t[i], out_prim[i], out_b1[i], out_b2[i] = float(t), p, float(b1), float(b2)


@njit(cache=True, error_model="numpy", _nrt=True)
def occluded_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit):
    """Any-hit of the N rays (float64 arrays (N,)) within (tmin[i], tmax[i]), one after
    the other, in R's form, precision and structure (:func:`impl.rays.occluded` of
    each): ``out_hit`` bool (N,).  Dispatch as :func:`closest_rays`."""
    k = R.accel
    if k == WIDE:
        wide_occluded_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit)
        return
    if k == TREE:
        tree_occluded_rays(R, ox, oy, oz, dx, dy, dz, tmin, tmax, out_hit)
        return
    form, sc, sr, tv = R.form, R.sph_center, R.sph_radius, R.tri_v
    g = sr
    for i in range(ox.shape[0]):
        a = (_cast(g, ox[i]), _cast(g, oy[i]), _cast(g, oz[i]), _cast(g, dx[i]), _cast(g, dy[i]),
             _cast(g, dz[i]), _cast(g, tmin[i]), _cast(g, tmax[i]))
        if k == NONE:
            out_hit[i] = any_hit_form(form, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7],
                                      sc, sr, tv)
        else:
            out_hit[i] = any_hit(R, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7])[0]


@njit(cache=True)
def _brute_counts(R):
    return R.sph_radius.shape[0] + R.tri_v.shape[0]


@njit(parallel=True, cache=True)
def _trace_kernel(R, o, d, tmin, tmax, t, prim, b, counts):
    for c in prange(o.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        _trace_one(R, o, d, tmin, tmax, t, prim, b, counts, i)


@njit(cache=True)
def _trace_one(R, o, d, tmin, tmax, t, prim, b, counts, i):
    g = R.sph_radius
    ox, oy, oz = _cast(g, o[i, 0]), _cast(g, o[i, 1]), _cast(g, o[i, 2])
    dx, dy, dz = _cast(g, d[i, 0]), _cast(g, d[i, 1]), _cast(g, d[i, 2])
    lo, hi = _cast(g, tmin), _cast(g, tmax)
    if R.accel == NONE:
        tt, p, b1, b2 = _brute(R, ox, oy, oz, dx, dy, dz, lo, hi)
        nodes, tests = 0, _brute_counts(R)
    else:
        tt, p, b1, b2, nodes, tests = closest(R, ox, oy, oz, dx, dy, dz, lo, hi)
    t[i], prim[i], b[i, 0], b[i, 1] = float(tt), p, float(b1), float(b2)
    counts[i, 0], counts[i, 1] = nodes, tests


@njit(inline="always", cache=True)
def _brute(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    return closest_hit_form(R.form, ox, oy, oz, dx, dy, dz, tmin, tmax,
                            R.sph_center, R.sph_radius, R.tri_v)


@njit(parallel=True, cache=True)
def _occluded_kernel(R, o, d, tmin, tmax, out, counts):
    for c in prange(o.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        _occluded_one(R, o, d, tmin, tmax, out, counts, i)


@njit(cache=True)
def _occluded_one(R, o, d, tmin, tmax, out, counts, i):
    g = R.sph_radius
    ox, oy, oz = _cast(g, o[i, 0]), _cast(g, o[i, 1]), _cast(g, o[i, 2])
    dx, dy, dz = _cast(g, d[i, 0]), _cast(g, d[i, 1]), _cast(g, d[i, 2])
    lo, hi = _cast(g, tmin[i]), _cast(g, tmax[i])
    if R.accel == NONE:
        out[i] = any_hit_form(R.form, ox, oy, oz, dx, dy, dz, lo, hi,
                              R.sph_center, R.sph_radius, R.tri_v)
        counts[i, 0], counts[i, 1] = 0, _brute_counts(R)
    else:
        h, nodes, tests = any_hit(R, ox, oy, oz, dx, dy, dz, lo, hi)
        out[i] = h
        counts[i, 0], counts[i, 1] = nodes, tests


def _ray_arrays(origins, directions):
    o = np.ascontiguousarray(origins, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    if o.ndim == 1:
        o = np.ascontiguousarray(np.broadcast_to(o, d.shape))
    if d.ndim != 2 or d.shape[1] != 3 or o.shape != d.shape:
        raise ValueError(f"origins and directions must be (N, 3) (origins may be (3,)); "
                         f"got {np.shape(origins)} and {np.shape(directions)}")
    return o, d


def trace_batch(R, origins, directions, *, tmin=0.0, tmax=np.inf):
    """Closest hits of N rays through R (in parallel): ``t`` (N,) (``tmax`` on a
    miss), ``prim`` (N,) (-1), ``b`` (N, 2), ``counts`` (N, 2) (nodes, primitive tests)."""
    o, d = _ray_arrays(origins, directions)
    n = len(o)
    t, prim = np.empty(n), np.empty(n, dtype=np.int64)
    b, counts = np.empty((n, 2)), np.empty((n, 2), dtype=np.int64)
    _trace_kernel(R, o, d, float(tmin), float(tmax), t, prim, b, counts)
    return t, prim, b, counts


def occluded_batch(R, origins, directions, tmin, tmax):
    """Any-hit of N rays within (tmin[i], tmax[i]): ``hit`` (N,) bool, ``counts`` (N, 2)."""
    o, d = _ray_arrays(origins, directions)
    n = len(o)
    lo = np.ascontiguousarray(np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,)))
    hi = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,)))
    out = np.empty(n, dtype=np.bool_)
    counts = np.empty((n, 2), dtype=np.int64)
    _occluded_kernel(R, o, d, lo, hi, out, counts)
    return out, counts
