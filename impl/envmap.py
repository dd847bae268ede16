"""Image-based lighting: Mitsuba 3's ``envmap`` emitter as pure numba functions.

An equirectangular (lat-long) RGB image gives the radiance arriving from every
direction.  :func:`envmap_tables` turns a :class:`core.scene.EnvMap` into four
arrays (an :class:`EnvmapTables`; :func:`impl.scene_arrays.flatten` puts the same
four in the flattened scene), and the kernels take those arrays and scalars
(inlined, allocation-free):

* :func:`envmap_radiance` — radiance (r, g, b) seen along a world direction (a
  ray that leaves the scene);
* :func:`envmap_draw` — a direction drawn ∝ luminance · sin θ (importance
  sampling of the map, for next-event estimation) with its solid-angle pdf and
  radiance;
* :func:`envmap_direction_pdf` — that density for a given direction (for MIS
  weights).

:func:`envmap_eval`, :func:`envmap_sample` and :func:`envmap_pdf` are the same
on an :class:`EnvmapTables` (radiance as an RGB array), for tests and tools.

Parameterisation (Mitsuba's ``envmap.cpp``): a world direction d is taken to
the map's frame, d' = to_world⁻¹ d (normalised), and
u = atan2(d'_x, −d'_z) / 2π (wrapped to [0, 1)), v = acos(d'_y) / π; +y is up,
row 0 the top.  Lookups are bilinear, texel-centred and periodic in u,
"align-corners" in v (row j at v = j / (H − 1)), times ``scale``.

Sampling: the luminance (Rec. 709 weights, Mitsuba's ``luminance``) times
sin θ_j at the (W + 1) × H grid vertices (column W repeats column 0; vertex
column x sits at u = (x + ½) / W, the texel centres) defines a piecewise-
bilinear density over (u, v), as Mitsuba's ``Hierarchical2D`` warp; a cell is
chosen by its integral and a point inside it by inverting the bilinear
marginal and conditional (linear) densities.  The solid-angle pdf is
p(u, v) / (2π² sin θ).  The same density as Mitsuba's, drawn by a different
mapping of the random numbers.

Limits: RGB only (no spectral upsampling); ``mis_compensation`` is not
modelled (it changes only the sampling density, not the image's expectation).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["EnvmapTables", "envmap_tables", "envmap_radiance", "envmap_draw", "envmap_direction_pdf",
           "envmap_eval", "envmap_pdf", "envmap_sample", "LUMINANCE", "direction_to_uv", "uv_to_direction"]

#: Rec. 709 / sRGB luminance weights (Mitsuba's ``luminance``).
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])

#: Smallest sin θ in the pdf's Jacobian (float32 epsilon, as Mitsuba's ``dr::Epsilon``).
_SIN_EPS = 2.0 ** -24


class EnvmapTables(NamedTuple):
    """The arrays of one map; the flattened scene carries the same four
    (:mod:`impl.scene_arrays`: ``env_image``, ``env_frame``, ``env_pdf``, ``env_cdf``)."""

    image: np.ndarray        # (H, W, 3) radiance (the map × scale), linear RGB
    frame: np.ndarray        # (2, 3, 3) world -> map frame (to_world⁻¹, 3x3 part), map -> world
    pdf: np.ndarray          # (H, W + 1) density over [0, 1]² of the grid vertices (0: black map)
    cdf: np.ndarray          # ((H - 1) * W,) cumulative cell integrals, last = 1 (all 0: black map)


def envmap_tables(envmap) -> EnvmapTables:
    """The sampling tables of a :class:`core.scene.EnvMap` (see the module docstring)."""
    img = np.ascontiguousarray(np.asarray(envmap.data, dtype=np.float64)[:, :, :3] * float(envmap.scale))
    H, W = img.shape[:2]
    if H < 2 or W < 1:
        raise ValueError(f"envmap_tables: the map must have at least 2 rows, got {W}x{H}")
    m = np.asarray(envmap.to_world, dtype=np.float64)[:3, :3]
    lum = img @ LUMINANCE
    grid = np.empty((H, W + 1))
    grid[:, :W] = lum
    grid[:, W] = lum[:, 0]
    grid *= np.sin(np.arange(H) * (np.pi / (H - 1)))[:, None]
    grid = np.maximum(grid, 0.0)
    cells = 0.25 * (grid[:-1, :-1] + grid[:-1, 1:] + grid[1:, :-1] + grid[1:, 1:])
    total = cells.sum()
    if total > 0:
        norm = total / ((H - 1) * W)        # integral of the bilinear grid over [0, 1]²
        cdf = np.cumsum(cells.ravel()) / total
        cdf[-1] = 1.0
        pdf = grid / norm
    else:
        cdf, pdf = np.zeros(cells.size), np.zeros_like(grid)
    return EnvmapTables(img, np.ascontiguousarray(np.stack([np.linalg.inv(m), m])), pdf, cdf)


@njit(inline="always", cache=True)
def direction_to_uv(x, y, z):
    """Map-frame unit direction -> (u, v) ∈ [0, 1)×[0, 1] (Mitsuba's ``direction_to_uv``)."""
    u = math.atan2(x, -z) / (2.0 * math.pi)
    u -= math.floor(u)
    return u, math.acos(max(-1.0, min(1.0, y))) / math.pi


@njit(inline="always", cache=True)
def uv_to_direction(u, v):
    """(u, v) -> (x, y, z, sin θ) in the map frame (Mitsuba's ``uv_to_direction``)."""
    theta = v * math.pi
    phi = u * 2.0 * math.pi
    st = math.sin(theta)
    return math.sin(phi) * st, math.cos(theta), -math.cos(phi) * st, st


@njit(inline="always", cache=True)
def _apply(frame, k, dx, dy, dz):
    """frame[k] · d, normalised."""
    M = frame[k]
    x = M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz
    y = M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz
    z = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@njit(inline="always", cache=True)
def _lookup(img, u, v):
    """Bilinear radiance (r, g, b) at (u, v): texel-centred and periodic in u, align-corners in v."""
    H, W = img.shape[0], img.shape[1]
    x = (u - math.floor(u)) * W - 0.5
    i0 = int(math.floor(x))
    fx = x - i0
    i0 %= W
    i1 = (i0 + 1) % W
    y = min(max(v, 0.0), 1.0) * (H - 1)
    j0 = min(int(y), H - 2)
    fy = y - j0
    w00, w01 = (1.0 - fx) * (1.0 - fy), fx * (1.0 - fy)
    w10, w11 = (1.0 - fx) * fy, fx * fy
    a, b = img[j0], img[j0 + 1]
    return (w00 * a[i0, 0] + w01 * a[i1, 0] + w10 * b[i0, 0] + w11 * b[i1, 0],
            w00 * a[i0, 1] + w01 * a[i1, 1] + w10 * b[i0, 1] + w11 * b[i1, 1],
            w00 * a[i0, 2] + w01 * a[i1, 2] + w10 * b[i0, 2] + w11 * b[i1, 2])


@njit(inline="always", cache=True)
def _grid_pdf(g, gu, gv):
    """Bilinear density of the warp grid at grid coordinates (gu, gv) ∈ [0, 1]²."""
    H, W1 = g.shape[0], g.shape[1]
    x = min(max(gu, 0.0), 1.0) * (W1 - 1)
    i = min(int(x), W1 - 2)
    fx = x - i
    y = min(max(gv, 0.0), 1.0) * (H - 1)
    j = min(int(y), H - 2)
    fy = y - j
    a = g[j, i] * (1.0 - fx) + g[j, i + 1] * fx
    b = g[j + 1, i] * (1.0 - fx) + g[j + 1, i + 1] * fx
    return a * (1.0 - fy) + b * fy


@njit(inline="always", cache=True)
def envmap_radiance(image, frame, dx, dy, dz):
    """Radiance (r, g, b) arriving from world direction (dx, dy, dz) (pointing away
    from the scene, towards the environment), from a map's ``image`` and ``frame``."""
    x, y, z = _apply(frame, 0, dx, dy, dz)
    u, v = direction_to_uv(x, y, z)
    return _lookup(image, u, v)


@njit(inline="always", cache=True)
def envmap_direction_pdf(image, frame, pdf, dx, dy, dz):
    """Solid-angle density of :func:`envmap_draw` for world direction (dx, dy, dz)."""
    x, y, z = _apply(frame, 0, dx, dy, dz)
    u, v = direction_to_uv(x, y, z)
    W = image.shape[1]
    gu = u - 0.5 / W
    gu -= math.floor(gu)
    inv_sin = 1.0 / math.sqrt(max(x * x + z * z, _SIN_EPS * _SIN_EPS))
    return _grid_pdf(pdf, gu, v) * inv_sin / (2.0 * math.pi * math.pi)


@njit(inline="always", cache=True)
def _sample_linear(a, b, u):
    """t ∈ [0, 1] with density ∝ a (1 − t) + b t (inverse CDF)."""
    if abs(a - b) <= 1e-12 * (a + b):
        return u
    return (a - math.sqrt(max(0.0, (1.0 - u) * a * a + u * b * b))) / (a - b)


@njit(inline="always", cache=True)
def envmap_draw(image, frame, pdf, cdf, u1, u2):
    """``(dx, dy, dz, pdf, r, g, b)``: a world direction drawn ∝ luminance · sin θ
    (piecewise bilinear) from a map's arrays, its solid-angle pdf and the radiance
    (r, g, b) from it.  A black map gives pdf 0."""
    n = cdf.shape[0]
    if n == 0 or cdf[n - 1] <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0
    H, W1 = pdf.shape[0], pdf.shape[1]
    W = W1 - 1
    # 1. a cell by its integral (binary search), u1 reused inside it
    a, b = 0, n - 1
    while a < b:
        mid = (a + b) // 2
        if cdf[mid] <= u1:
            a = mid + 1
        else:
            b = mid
    k = a
    lo = cdf[k - 1] if k > 0 else 0.0
    width = cdf[k] - lo
    r = (u1 - lo) / width if width > 0.0 else 0.5
    r = min(max(r, 0.0), 1.0)
    j, i = k // W, k % W
    v00, v10, v01, v11 = pdf[j, i], pdf[j, i + 1], pdf[j + 1, i], pdf[j + 1, i + 1]
    # 2. row offset from the linear marginal, column offset from the linear conditional
    t = _sample_linear(v00 + v10, v01 + v11, r)
    s = _sample_linear((1.0 - t) * v00 + t * v01, (1.0 - t) * v10 + t * v11, u2)
    gu, gv = (i + s) / W, (j + t) / (H - 1)
    u = gu + 0.5 / W
    x, y, z, st = uv_to_direction(u, gv)
    p = _grid_pdf(pdf, gu, gv) / (2.0 * math.pi * math.pi * max(st, _SIN_EPS))
    dx, dy, dz = _apply(frame, 1, x, y, z)
    cr, cg, cb = _lookup(image, u, gv)
    return dx, dy, dz, p, cr, cg, cb


@njit(cache=True)
def envmap_eval(T, dx, dy, dz):
    """:func:`envmap_radiance` of an :class:`EnvmapTables`, as an RGB array."""
    r, g, b = envmap_radiance(T.image, T.frame, dx, dy, dz)
    out = np.empty(3)
    out[0], out[1], out[2] = r, g, b
    return out


@njit(cache=True)
def envmap_pdf(T, dx, dy, dz):
    """:func:`envmap_direction_pdf` of an :class:`EnvmapTables`."""
    return envmap_direction_pdf(T.image, T.frame, T.pdf, dx, dy, dz)


@njit(cache=True)
def envmap_sample(T, u1, u2):
    """:func:`envmap_draw` of an :class:`EnvmapTables`: ``(dx, dy, dz, pdf, radiance)``
    with the radiance as an RGB array."""
    dx, dy, dz, p, r, g, b = envmap_draw(T.image, T.frame, T.pdf, T.cdf, u1, u2)
    out = np.empty(3)
    out[0], out[1], out[2] = r, g, b
    return dx, dy, dz, p, out
