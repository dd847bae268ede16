"""Scan conversion of screen triangles (thesis 1.1 "rasterizzazione", 1.3.1, 1.3.2).

Coverage
--------
Edge functions on vertices snapped to 1/2^:data:`SUBPIXEL_BITS` pixel, in
int64, evaluated at pixel centres (i + ½, j + ½) — exactly the points the
eye rays of :mod:`impl.camera` pass through.  With the triangle wound so that
its signed area is positive, a sample is inside when every edge function is
> 0, or = 0 on a *top* or *left* edge (the top-left fill rule of Direct3D /
OpenGL, Pineda 1988): with y pointing down, an edge a→b is a top edge when
it is horizontal with the inside below (dy = 0, dx > 0) and a left edge when
the inside is to its right (dy < 0).  Integer edge functions of a shared edge
are exact negatives of each other, so a pixel centre on an edge shared by two
triangles is covered exactly once, and one on a vertex shared by a fan
exactly once.

Interpolation
-------------
Screen-space barycentrics λ come from the *unsnapped* float64 vertices (the
snap decides coverage only, so interpolated values do not carry its 1/512
pixel error); perspective-correct barycentrics are b_i = (λ_i / z_i) / Σ λ_j / z_j,
and 1/z = Σ λ_j / z_j is affine in screen space (camera-space z of each
vertex).

Depth buffer (thesis 1.3.1)
---------------------------
The stored depth is the window depth z_w = f/(f − n) · (1 − n/z) ∈ [0, 1]
(affine in 1/z, as a GPU's), kept as float32 (``DEPTH_FLOAT32``) or rounded
to a 24- or 16-bit fixed-point integer; a fragment passes when its value is
*strictly* less than the stored one (so of two fragments that quantise to
the same value the first drawn stays).  ``DEPTH_NONE`` draws every fragment
in order (the painter's algorithm of depth sort).

Traversal: per-pixel edge functions or scan-line coherence (thesis 1.2.1)
-----------------------------------------------------------------------
``TRAVERSAL_EDGE`` (default) visits every pixel of a triangle's bounding box
and evaluates the edge functions there, then the barycentrics and 1/z of each
covered pixel from scratch.  ``TRAVERSAL_INCREMENTAL`` uses the coherence of
a scan line: each integer edge function is affine in the pixel column,
w(x) = c + a·x, so on row y the columns where w + bias > 0 form one interval
found by one integer division per edge; the three intervals' intersection
is the span, every pixel of it is covered and none outside it is visited
(no per-pixel edge test).  Along the span λ0, λ1 and 1/z are affine in x:
they are evaluated once at the span's first pixel and then advanced by one
addition each per pixel.  Coverage is the same integer computation, so the
covered pixels are identical; λ and 1/z differ from the direct evaluation by
rounding accumulated over at most one span (≤ W additions), so a depth
comparison that is a tie to the last bits may go the other way.

Operation counters (per traversal, summed over bands): ``pixels_visited``
(pixels the traversal looks at), ``edge_evals`` (full edge-function
evaluations: 2 multiplications, 5 additions each), ``span_solves`` (per-row
interval solves: one division each), ``interp_evals`` (full evaluations of
λ0, λ1, λ2 and 1/z: 9 multiplications, 14 additions), ``interp_steps``
(incremental advances of λ0, λ1, 1/z: 3 additions).

The frame is cut into horizontal bands rasterised in parallel (``prange``);
each band draws all triangles in the given order, so the result is the same
as one serial pass.  Output is a visibility buffer: per pixel the index of
the winning screen triangle, its perspective-correct barycentrics and 1/z;
shading reads it afterwards (:mod:`impl.shading`) — the colour equals
forward shading of the last fragment that passed.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from core.errors import ParamError

__all__ = ["SUBPIXEL_BITS", "TRAVERSALS", "TRAVERSAL_EDGE", "TRAVERSAL_INCREMENTAL", "OP_COUNTERS", "DEPTH_MODES", "DEPTH_FLOAT32", "DEPTH_FIXED24", "DEPTH_FIXED16", "DEPTH_NONE",
           "VisibilityBuffer", "rasterize", "coverage"]

SUBPIXEL_BITS = 8
_ONE = 1 << SUBPIXEL_BITS
_HALF = _ONE >> 1

DEPTH_FLOAT32, DEPTH_FIXED24, DEPTH_FIXED16, DEPTH_NONE = 0, 1, 2, 3
DEPTH_MODES = {"float32": DEPTH_FLOAT32, "fixed24": DEPTH_FIXED24, "fixed16": DEPTH_FIXED16}

TRAVERSAL_EDGE, TRAVERSAL_INCREMENTAL = 0, 1
TRAVERSALS = {"edge": TRAVERSAL_EDGE, "incremental": TRAVERSAL_INCREMENTAL}
#: Operation counters of :func:`rasterize` (see the module docstring), in the kernel's column order.
OP_COUNTERS = ("pixels_visited", "edge_evals", "span_solves", "interp_evals", "interp_steps")

#: Bands the frame is cut into for parallel rasterisation.
N_BANDS = 16


@njit(parallel=True, cache=True)
def _setup_kernel(xy, W, H, ix, iy, bbox):
    """Snap vertices, wind counter-clockwise (positive area), integer pixel bounding box (extent)."""
    for t in prange(xy.shape[0]):
        X0 = np.int64(np.floor(xy[t, 0, 0] * _ONE + 0.5))
        Y0 = np.int64(np.floor(xy[t, 0, 1] * _ONE + 0.5))
        X1 = np.int64(np.floor(xy[t, 1, 0] * _ONE + 0.5))
        Y1 = np.int64(np.floor(xy[t, 1, 1] * _ONE + 0.5))
        X2 = np.int64(np.floor(xy[t, 2, 0] * _ONE + 0.5))
        Y2 = np.int64(np.floor(xy[t, 2, 1] * _ONE + 0.5))
        area = (X1 - X0) * (Y2 - Y0) - (Y1 - Y0) * (X2 - X0)
        if area < 0:
            X1, Y1, X2, Y2 = X2, Y2, X1, Y1
        ix[t, 0], ix[t, 1], ix[t, 2] = X0, X1, X2
        iy[t, 0], iy[t, 1], iy[t, 2] = Y0, Y1, Y2
        if area == 0:
            bbox[t, 0], bbox[t, 1], bbox[t, 2], bbox[t, 3] = 0, -1, 0, -1
            continue
        # Pixel i's centre is at i·ONE + HALF: the range of i with a centre in [min, max].
        xmin = -((-(min(X0, X1, X2) - _HALF)) // _ONE)
        xmax = (max(X0, X1, X2) - _HALF) // _ONE
        ymin = -((-(min(Y0, Y1, Y2) - _HALF)) // _ONE)
        ymax = (max(Y0, Y1, Y2) - _HALF) // _ONE
        bbox[t, 0] = max(xmin, 0)
        bbox[t, 1] = min(xmax, W - 1)
        bbox[t, 2] = max(ymin, 0)
        bbox[t, 3] = min(ymax, H - 1)


@njit(inline="always", cache=True)
def _bias(ax, ay, bx, by):
    """1 if the edge a→b is a top or left edge (samples on it are inside), else 0."""
    dx, dy = bx - ax, by - ay
    return 1 if (dy < 0 or (dy == 0 and dx > 0)) else 0


@njit(inline="always", cache=True)
def _span_limits(c, a, x_lo, x_hi):
    """Columns x in [x_lo, x_hi] with c + a·x > 0 (integers): the interval (lo, hi), empty if lo > hi."""
    if a > 0:            # x > −c / a
        lo = (-c) // a + 1
        return max(lo, x_lo), x_hi
    if a < 0:            # x < c / (−a)
        m = -a
        hi = c // m - 1 if c % m == 0 else c // m
        return x_lo, min(hi, x_hi)
    if c > 0:
        return x_lo, x_hi
    return x_hi + 1, x_hi


@njit(inline="always", cache=True)
def _write(t, x, y, l0, l1, l2, iz1, iz2, invz, depth_mode, zscale, near, levels, vis_id, vis_b, vis_invz, zbuf):
    """Depth test and visibility-buffer write of one fragment; True when it passed."""
    if depth_mode != DEPTH_NONE:
        zw = zscale * (1.0 - near * invz)
        if depth_mode == DEPTH_FLOAT32:
            q = float(np.float32(zw))
        else:
            q = np.floor(min(max(zw, 0.0), 1.0) * levels + 0.5)
        if not q < zbuf[y, x]:
            return False
        zbuf[y, x] = q
    vis_id[y, x] = t
    vis_b[y, x, 0] = l1 * iz1 / invz
    vis_b[y, x, 1] = l2 * iz2 / invz
    vis_invz[y, x] = invz
    return True


@njit(cache=True)
def _band(y0, y1, order, xy, zc, ix, iy, bbox, depth_mode, near, far, vis_id, vis_b, vis_invz, zbuf,
          traversal, ops):
    """Rasterise every triangle of ``order`` into rows [y0, y1); (fragments, depth tests passed).
    ``ops`` (5,) accumulates the operation counters of :data:`OP_COUNTERS`."""
    frags = 0
    passed = 0
    visited = 0
    edge_evals = 0
    span_solves = 0
    interp_evals = 0
    interp_steps = 0
    zscale = far / (far - near)
    levels = 0.0
    if depth_mode == DEPTH_FIXED24:
        levels = float((1 << 24) - 1)
    elif depth_mode == DEPTH_FIXED16:
        levels = float((1 << 16) - 1)
    for k in range(order.shape[0]):
        t = order[k]
        ya = max(bbox[t, 2], y0)
        yb = min(bbox[t, 3], y1 - 1)
        if ya > yb:
            continue
        X0, X1, X2 = ix[t, 0], ix[t, 1], ix[t, 2]
        Y0, Y1, Y2 = iy[t, 0], iy[t, 1], iy[t, 2]
        b0 = _bias(X1, Y1, X2, Y2)       # edge 1→2, opposite vertex 0
        b1 = _bias(X2, Y2, X0, Y0)
        b2 = _bias(X0, Y0, X1, Y1)
        # Float edge functions (unsnapped, original vertex order) for interpolation.
        fx0, fy0 = xy[t, 0, 0], xy[t, 0, 1]
        fx1, fy1 = xy[t, 1, 0], xy[t, 1, 1]
        fx2, fy2 = xy[t, 2, 0], xy[t, 2, 1]
        farea = (fx1 - fx0) * (fy2 - fy0) - (fy1 - fy0) * (fx2 - fx0)
        if farea == 0.0:
            continue
        inv_area = 1.0 / farea
        iz0, iz1, iz2 = 1.0 / zc[t, 0], 1.0 / zc[t, 1], 1.0 / zc[t, 2]
        if traversal == TRAVERSAL_INCREMENTAL:
            # Per-pixel steps along x of λ0, λ1 (affine in px) and 1/z.
            dl0 = -(fy2 - fy1) * inv_area
            dl1 = -(fy0 - fy2) * inv_area
            dinvz = dl0 * iz0 + dl1 * iz1 - (dl0 + dl1) * iz2
            for y in range(ya, yb + 1):
                PY = y * _ONE + _HALF
                py = y + 0.5
                # w_e(x) = c_e + a_e·x with PX = x·ONE + HALF; the covered columns solve c + bias + a·x > 0.
                xa, xb = _span_limits((X2 - X1) * (PY - Y1) - (Y2 - Y1) * (_HALF - X1) + b0,
                                      -(Y2 - Y1) * _ONE, bbox[t, 0], bbox[t, 1])
                xa, xb = _span_limits((X0 - X2) * (PY - Y2) - (Y0 - Y2) * (_HALF - X2) + b1,
                                      -(Y0 - Y2) * _ONE, xa, xb)
                xa, xb = _span_limits((X1 - X0) * (PY - Y0) - (Y1 - Y0) * (_HALF - X0) + b2,
                                      -(Y1 - Y0) * _ONE, xa, xb)
                span_solves += 3
                if xa > xb:
                    continue
                px = xa + 0.5
                l0 = ((fx2 - fx1) * (py - fy1) - (fy2 - fy1) * (px - fx1)) * inv_area
                l1 = ((fx0 - fx2) * (py - fy2) - (fy0 - fy2) * (px - fx2)) * inv_area
                invz = l0 * iz0 + l1 * iz1 + (1.0 - l0 - l1) * iz2
                interp_evals += 1
                for x in range(xa, xb + 1):
                    if x > xa:
                        l0 += dl0
                        l1 += dl1
                        invz += dinvz
                        interp_steps += 1
                    frags += 1
                    if _write(t, x, y, l0, l1, 1.0 - l0 - l1, iz1, iz2, invz, depth_mode, zscale, near,
                              levels, vis_id, vis_b, vis_invz, zbuf):
                        passed += 1
                visited += xb - xa + 1
            continue
        for y in range(ya, yb + 1):
            PY = y * _ONE + _HALF
            py = y + 0.5
            visited += bbox[t, 1] - bbox[t, 0] + 1
            for x in range(bbox[t, 0], bbox[t, 1] + 1):
                PX = x * _ONE + _HALF
                edge_evals += 1
                w0 = (X2 - X1) * (PY - Y1) - (Y2 - Y1) * (PX - X1)
                if w0 + b0 <= 0:
                    continue
                edge_evals += 1
                w1 = (X0 - X2) * (PY - Y2) - (Y0 - Y2) * (PX - X2)
                if w1 + b1 <= 0:
                    continue
                edge_evals += 1
                w2 = (X1 - X0) * (PY - Y0) - (Y1 - Y0) * (PX - X0)
                if w2 + b2 <= 0:
                    continue
                frags += 1
                px = x + 0.5
                l0 = ((fx2 - fx1) * (py - fy1) - (fy2 - fy1) * (px - fx1)) * inv_area
                l1 = ((fx0 - fx2) * (py - fy2) - (fy0 - fy2) * (px - fx2)) * inv_area
                l2 = 1.0 - l0 - l1
                invz = l0 * iz0 + l1 * iz1 + l2 * iz2
                interp_evals += 1
                if _write(t, x, y, l0, l1, l2, iz1, iz2, invz, depth_mode, zscale, near, levels,
                          vis_id, vis_b, vis_invz, zbuf):
                    passed += 1
    ops[0] += visited
    ops[1] += edge_evals
    ops[2] += span_solves
    ops[3] += interp_evals
    ops[4] += interp_steps
    return frags, passed


@njit(parallel=True, cache=True)
def _raster_kernel(order, xy, zc, ix, iy, bbox, depth_mode, near, far, vis_id, vis_b, vis_invz, zbuf, counts,
                   traversal):
    H = vis_id.shape[0]
    nb = counts.shape[0]
    for band in prange(nb):
        y0 = band * H // nb
        y1 = (band + 1) * H // nb
        f, p = _band(y0, y1, order, xy, zc, ix, iy, bbox, depth_mode, near, far, vis_id, vis_b, vis_invz, zbuf,
                     traversal, counts[band, 2:])
        counts[band, 0] = f
        counts[band, 1] = p


class VisibilityBuffer:
    """Per pixel: screen-triangle index (-1: background), perspective-correct
    barycentrics (b1, b2) in it, 1/z (camera-space), and the depth buffer."""

    def __init__(self, width: int, height: int):
        self.id = np.full((height, width), -1, np.int64)
        self.b = np.zeros((height, width, 2))
        self.invz = np.zeros((height, width))
        self.zbuf = np.full((height, width), np.inf)

    def __repr__(self) -> str:
        h, w = self.id.shape
        return f"VisibilityBuffer({w}x{h}, covered={int((self.id >= 0).sum())})"


def rasterize(xy: np.ndarray, zc: np.ndarray, width: int, height: int, *, depth_mode: int,
              near: float, far: float, order: np.ndarray | None = None,
              traversal: int = TRAVERSAL_EDGE) -> tuple[VisibilityBuffer, dict]:
    """Scan-convert screen triangles ``xy`` (M, 3, 2) with camera-space depths ``zc`` (M, 3).

    ``order``: drawing order (default 0..M-1).  ``traversal``: ``TRAVERSAL_EDGE``
    (per-pixel edge functions) or ``TRAVERSAL_INCREMENTAL`` (scan-line spans and
    incremental interpolation).  Returns the visibility buffer and counters
    ``fragments`` (covered samples), ``depth_passed`` (samples written) and the
    operation counters :data:`OP_COUNTERS`.
    """
    M = xy.shape[0]
    xy = np.ascontiguousarray(xy, np.float64)
    zc = np.ascontiguousarray(zc, np.float64)
    order = np.arange(M, dtype=np.int64) if order is None else np.ascontiguousarray(order, np.int64)
    ix = np.empty((M, 3), np.int64)
    iy = np.empty((M, 3), np.int64)
    bbox = np.empty((M, 4), np.int64)
    _setup_kernel(xy, width, height, ix, iy, bbox)
    vb = VisibilityBuffer(width, height)
    if traversal not in (TRAVERSAL_EDGE, TRAVERSAL_INCREMENTAL):
        raise ParamError(f"rasterize: traversal must be one of {sorted(TRAVERSALS.values())}, got {traversal!r}")
    counts = np.zeros((min(N_BANDS, max(height, 1)), 2 + len(OP_COUNTERS)), np.int64)
    _raster_kernel(order, xy, zc, ix, iy, bbox, depth_mode, float(near), float(far),
                   vb.id, vb.b, vb.invz, vb.zbuf, counts, int(traversal))
    out = {"fragments": int(counts[:, 0].sum()), "depth_passed": int(counts[:, 1].sum())}
    out.update({name: int(counts[:, 2 + i].sum()) for i, name in enumerate(OP_COUNTERS)})
    return vb, out


@njit(cache=True)
def _coverage_kernel(ix, iy, bbox, cov):
    for t in range(ix.shape[0]):
        X0, X1, X2 = ix[t, 0], ix[t, 1], ix[t, 2]
        Y0, Y1, Y2 = iy[t, 0], iy[t, 1], iy[t, 2]
        b0 = _bias(X1, Y1, X2, Y2)
        b1 = _bias(X2, Y2, X0, Y0)
        b2 = _bias(X0, Y0, X1, Y1)
        for y in range(bbox[t, 2], bbox[t, 3] + 1):
            PY = y * _ONE + _HALF
            for x in range(bbox[t, 0], bbox[t, 1] + 1):
                PX = x * _ONE + _HALF
                if ((X2 - X1) * (PY - Y1) - (Y2 - Y1) * (PX - X1) + b0 > 0
                        and (X0 - X2) * (PY - Y2) - (Y0 - Y2) * (PX - X2) + b1 > 0
                        and (X1 - X0) * (PY - Y0) - (Y1 - Y0) * (PX - X0) + b2 > 0):
                    cov[y, x] += 1


def coverage(xy: np.ndarray, width: int, height: int) -> np.ndarray:
    """Additive coverage buffer: how many triangles of ``xy`` (M, 3, 2) cover each pixel centre."""
    xy = np.ascontiguousarray(xy, np.float64)
    M = xy.shape[0]
    ix = np.empty((M, 3), np.int64)
    iy = np.empty((M, 3), np.int64)
    bbox = np.empty((M, 4), np.int64)
    _setup_kernel(xy, width, height, ix, iy, bbox)
    cov = np.zeros((height, width), np.int64)
    _coverage_kernel(ix, iy, bbox, cov)
    return cov
