"""Uniform grid with 3D-DDA traversal and mailboxing (thesis 2.6.2, Fig. 2.34).

Thesis 2.6.2 (space subdivision): the scene's box is cut into equal voxels,
each listing the primitives whose (padded) bounding box overlaps it; a ray
visits only the voxels it pierces, front to back, by the 3D digital
differential analyser of Amanatides & Woo (1987): from the entry voxel, step
to the neighbour across whichever of the three next voxel planes the ray
reaches first (``t_next`` per axis, advanced by the plane spacing).

Two details make it exact and cheap:

* **Current voxel only.**  A primitive spanning several voxels can be hit
  *beyond* the voxel being examined while a nearer primitive waits in the
  next voxel (Fig. 2.34).  A hit is accepted only if its ``t`` lies within
  the current voxel (``t ≤ t_exit``); the traversal stops at the first voxel
  that yields an accepted hit.
* **Mailboxing** (Amanatides & Woo): a primitive met again in a later voxel
  is not tested again.  The mailbox is a 32-slot table per ray, hashed by
  primitive id, holding the primitive's hit ``(t, b1, b2)`` over the whole
  ray — so a hit rejected in one voxel (beyond its exit) is accepted, without
  a second test, in the voxel that contains it.  A slot collision only costs
  a repeated test.

Resolution: ``λ·P`` voxels in the proportions of the scene box (Cleary &
Wyvill; λ = ``density``, default :data:`DENSITY`), at most ``MAX_RES`` per axis.

Ablation knobs (thesis 2.6.2), fixed at build time and read by the traversal:

* ``density`` — the grid resolution (voxels per primitive): fewer voxels mean
  longer voxel lists (more tests per ray), more voxels more steps per ray and
  more references per primitive;
* ``mailbox`` — off: a primitive listed in several pierced voxels is tested
  again in each (the thesis's "object A" of Fig. 2.32); the hits do not change,
  only the tests per ray;
* ``current_voxel`` — off: the first voxel holding *any* hit ends the search,
  even a hit beyond that voxel's exit, so a nearer primitive listed only in the
  next voxel is missed (Fig. 2.34's object C): wrong hits.  This variant
  exists to show that failure; it is not a renderer's choice.

The any-hit query (shadow rays) needs no current-voxel rule: any hit in
(tmin, tmax) answers it wherever it lies.

Layout in the ray configuration: ``node_lo``/``node_hi`` (1, 3) the grid box,
``acc_f`` the voxel size (3,), ``acc_i`` (5,) the resolution (3) and the
mailbox and current-voxel flags (0/1), ``node_a`` (V + 1,) each voxel's first
entry of ``prim_idx``.

Leaves out: hierarchical or adaptive grids (the octree of
:mod:`impl.accel.octree` is the non-uniform subdivision), exact
triangle–voxel overlap (boxes only).

References: J. Amanatides, A. Woo, "A fast voxel traversal algorithm for ray
tracing", Eurographics 1987; J. G. Cleary, G. Wyvill, "Analysis of an
algorithm for fast ray tracing using uniform space subdivision",
*The Visual Computer* 4, 1988.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..intersect import like
from .primitives import box_enter, closer, prim_test, ulp_above

__all__ = ["build_grid", "grid_closest", "grid_any", "DENSITY", "MAX_RES"]

DENSITY = 4.0
MAX_RES = 256
MAILBOX = 32                                   # power of two


def grid_resolution(glo, ghi, n_prims, density=DENSITY):
    """Voxels per axis: ``density·n`` cells shaped like the box (flat boxes get one layer)."""
    ext = np.maximum(ghi - glo, 1e-12)
    side = (ext.prod() / max(density * n_prims, 1.0)) ** (1.0 / 3.0)
    res = np.clip(np.floor(ext / side), 1, MAX_RES).astype(np.int64)
    return res


@njit(cache=True)
def _fill(lo, hi, glo, cs, res):
    rx, ry, rz = res[0], res[1], res[2]
    counts = np.zeros(rx * ry * rz + 1, dtype=np.int64)
    P = lo.shape[0]
    rng = np.empty((P, 6), dtype=np.int64)
    for p in range(P):
        for a in range(3):
            i0 = int(math.floor((lo[p, a] - glo[a]) / cs[a]))
            i1 = int(math.floor((hi[p, a] - glo[a]) / cs[a]))
            rng[p, a] = min(max(i0, 0), res[a] - 1)
            rng[p, 3 + a] = min(max(i1, 0), res[a] - 1)
        for z in range(rng[p, 2], rng[p, 5] + 1):
            for y in range(rng[p, 1], rng[p, 4] + 1):
                for x in range(rng[p, 0], rng[p, 3] + 1):
                    counts[(z * ry + y) * rx + x + 1] += 1
    offsets = np.cumsum(counts)
    refs = np.empty(offsets[-1], dtype=np.int64)
    fill = offsets[:-1].copy()
    for p in range(P):
        for z in range(rng[p, 2], rng[p, 5] + 1):
            for y in range(rng[p, 1], rng[p, 4] + 1):
                for x in range(rng[p, 0], rng[p, 3] + 1):
                    c = (z * ry + y) * rx + x
                    refs[fill[c]] = p
                    fill[c] += 1
    return offsets, refs


def build_grid(lo, hi, *, density=DENSITY, mailbox=True, current_voxel=True):
    """A uniform grid over primitive bounds ``lo``/``hi`` (P, 3): ``(grid_lo (1, 3),
    grid_hi (1, 3), cell_size (3,), ints (5,), offsets (V + 1,), refs)``; ``ints`` is the
    resolution per axis followed by the ``mailbox`` and ``current_voxel`` flags."""
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape or len(lo) == 0:
        raise ValueError(f"build_grid: lo and hi must be (P>=1, 3), got {lo.shape} and {hi.shape}")
    if not density > 0:
        raise ValueError(f"build_grid: density must be > 0, got {density}")
    glo, ghi = lo.min(axis=0), hi.max(axis=0)
    res = grid_resolution(glo, ghi, len(lo), density)
    cs = np.maximum((ghi - glo) / res, 1e-300)
    offsets, refs = _fill(lo, hi, glo, cs, res)
    ints = np.concatenate([res, [int(bool(mailbox)), int(bool(current_voxel))]]).astype(np.int64)
    return glo[None, :].copy(), ghi[None, :].copy(), cs, ints, offsets, refs


@njit(inline="always", cache=True)
def _start(o, d, inv, t, glo, cs, res):
    """Voxel of the entry point o + t d (clamped), the step and the t of its next plane."""
    i = int(math.floor((o + t * d - glo) / cs))
    i = min(max(i, 0), res - 1)
    if d > 0.0:
        return i, 1, (glo + (i + 1) * cs - o) * inv
    if d < 0.0:
        return i, -1, (glo + i * cs - o) * inv
    return i, 0, math.inf


@njit(cache=True, error_model="numpy")
def grid_closest(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2, voxels_visited, prim_tests)`` by 3D-DDA, accepting a
    hit only within the current voxel (unless the configuration turns that rule off);
    arguments and t in R's precision."""
    glo, cs, res = R.node_lo[0], R.acc_f, R.acc_i
    use_mailbox, voxel_rule = res[3] != 0, res[4] != 0
    off, refs = R.node_a, R.prim_idx
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tmax, 0.0)
    zero = like(tmax, 0.0)
    fo = (float(ox), float(oy), float(oz))
    fd = (float(dx), float(dy), float(dz))
    ix, iy, iz = 1.0 / fd[0], 1.0 / fd[1], 1.0 / fd[2]
    ftmax = float(tmax)
    t_in = box_enter(R.node_lo, R.node_hi, 0, fo[0], fo[1], fo[2], ix, iy, iz, float(tmin), ftmax)
    if t_in == math.inf:
        return best_t, best_p, bb1, bb2, 0, 0
    x, sx, tx = _start(fo[0], fd[0], ix, t_in, glo[0], cs[0], res[0])
    y, sy, ty = _start(fo[1], fd[1], iy, t_in, glo[1], cs[1], res[1])
    z, sz, tz = _start(fo[2], fd[2], iz, t_in, glo[2], cs[2], res[2])
    mb_id = np.full(MAILBOX, -1, dtype=np.int64)
    mb = np.empty((MAILBOX, 3), dtype=R.sph_radius.dtype)
    t_far = ulp_above(tmax)
    voxels = tests = 0
    rx, ry = res[0], res[1]
    while True:
        voxels += 1
        t_exit = min(tx, ty, tz)
        c = (z * ry + y) * rx + x
        for k in range(off[c], off[c + 1]):
            p = refs[k]
            slot = p & (MAILBOX - 1)
            if use_mailbox and mb_id[slot] == p:       # mailbox: tested on an earlier voxel
                t, b1, b2 = mb[slot, 0], mb[slot, 1], mb[slot, 2]
            else:
                tests += 1
                t, b1, b2 = prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, t_far)
                mb_id[slot] = p
                mb[slot, 0], mb[slot, 1], mb[slot, 2] = t, b1, b2
            if t > zero and (float(t) <= t_exit or not voxel_rule) and closer(t, p, best_t, best_p):
                best_t, best_p, bb1, bb2 = t, p, b1, b2
        # Stop at the first voxel with an accepted hit, or where the ray ends.
        if best_p >= 0 or t_exit >= ftmax:
            break
        # Step to the neighbour across the nearest voxel plane.
        if tx <= ty and tx <= tz:
            x += sx
            if x < 0 or x >= rx:
                break
            tx = (glo[0] + (x + (sx > 0)) * cs[0] - fo[0]) * ix
        elif ty <= tz:
            y += sy
            if y < 0 or y >= ry:
                break
            ty = (glo[1] + (y + (sy > 0)) * cs[1] - fo[1]) * iy
        else:
            z += sz
            if z < 0 or z >= res[2]:
                break
            tz = (glo[2] + (z + (sz > 0)) * cs[2] - fo[2]) * iz
    return best_t, best_p, bb1, bb2, voxels, tests


@njit(cache=True, error_model="numpy")
def grid_any(R, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Any hit in (tmin, tmax) by 3D-DDA: ``(hit, voxels_visited, prim_tests)``; the
    mailbox (when on) skips primitives already found to miss."""
    glo, cs, res = R.node_lo[0], R.acc_f, R.acc_i
    use_mailbox = res[3] != 0
    off, refs = R.node_a, R.prim_idx
    zero = like(tmax, 0.0)
    fo = (float(ox), float(oy), float(oz))
    fd = (float(dx), float(dy), float(dz))
    ix, iy, iz = 1.0 / fd[0], 1.0 / fd[1], 1.0 / fd[2]
    ftmax = float(tmax)
    t_in = box_enter(R.node_lo, R.node_hi, 0, fo[0], fo[1], fo[2], ix, iy, iz, float(tmin), ftmax)
    if t_in == math.inf:
        return False, 0, 0
    x, sx, tx = _start(fo[0], fd[0], ix, t_in, glo[0], cs[0], res[0])
    y, sy, ty = _start(fo[1], fd[1], iy, t_in, glo[1], cs[1], res[1])
    z, sz, tz = _start(fo[2], fd[2], iz, t_in, glo[2], cs[2], res[2])
    mb_id = np.full(MAILBOX, -1, dtype=np.int64)
    voxels = tests = 0
    rx, ry = res[0], res[1]
    while True:
        voxels += 1
        t_exit = min(tx, ty, tz)
        c = (z * ry + y) * rx + x
        for k in range(off[c], off[c + 1]):
            p = refs[k]
            slot = p & (MAILBOX - 1)
            if use_mailbox and mb_id[slot] == p:
                continue
            tests += 1
            t, b1, b2 = prim_test(R, p, ox, oy, oz, dx, dy, dz, tmin, tmax)
            if t > zero:
                return True, voxels, tests
            mb_id[slot] = p
        if t_exit >= ftmax:
            break
        if tx <= ty and tx <= tz:
            x += sx
            if x < 0 or x >= rx:
                break
            tx = (glo[0] + (x + (sx > 0)) * cs[0] - fo[0]) * ix
        elif ty <= tz:
            y += sy
            if y < 0 or y >= ry:
                break
            ty = (glo[1] + (y + (sy > 0)) * cs[1] - fo[1]) * iy
        else:
            z += sz
            if z < 0 or z >= res[2]:
                break
            tz = (glo[2] + (z + (sz > 0)) * cs[2] - fo[2]) * iz
    return False, voxels, tests
