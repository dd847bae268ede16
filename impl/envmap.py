"""Image-based lighting: Mitsuba 3's ``envmap`` emitter as pure numba functions.

An equirectangular (lat-long) RGB image gives the radiance arriving from every
direction.  :func:`envmap_tables` turns a :class:`core.scene.EnvMap` into an
:class:`EnvmapTables` bundle; the tracers call

* :func:`envmap_eval` — radiance seen along a world direction (a ray that
  leaves the scene);
* :func:`envmap_sample` — a direction drawn ∝ luminance · sin θ (importance
  sampling of the map, for next-event estimation) with its solid-angle pdf and
  radiance;
* :func:`envmap_pdf` — that density for a given direction (for MIS weights).

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

__all__ = ["EnvmapTables", "envmap_tables", "envmap_eval", "envmap_pdf", "envmap_sample", "LUMINANCE",
           "direction_to_uv", "uv_to_direction"]

#: Rec. 709 / sRGB luminance weights (Mitsuba's ``luminance``).
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])

#: Smallest sin θ in the pdf's Jacobian (float32 epsilon, as Mitsuba's ``dr::Epsilon``).
_SIN_EPS = 2.0 ** -24


class EnvmapTables(NamedTuple):
    image: np.ndarray        # (H, W, 3) radiance (the map × scale), linear RGB
    to_local: np.ndarray     # (3, 3) world -> map frame (to_world⁻¹, 3x3 part)
    to_world: np.ndarray     # (3, 3) map frame -> world
    grid: np.ndarray         # (H, W + 1) luminance · sin θ at the grid vertices
    cell_cdf: np.ndarray     # ((H - 1) * W,) cumulative cell integrals, last = 1
    norm: float              # integral of the bilinear grid over [0, 1]² (0: black map)


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
    norm = float(total / ((H - 1) * W))
    cdf = np.cumsum(cells.ravel()) / total if total > 0 else np.zeros(cells.size)
    if total > 0:
        cdf[-1] = 1.0
    return EnvmapTables(img, np.linalg.inv(m), m.copy(), grid, cdf, norm)


@njit(cache=True)
def direction_to_uv(x, y, z):
    """Map-frame unit direction -> (u, v) ∈ [0, 1)×[0, 1] (Mitsuba's ``direction_to_uv``)."""
    u = math.atan2(x, -z) / (2.0 * math.pi)
    u -= math.floor(u)
    return u, math.acos(max(-1.0, min(1.0, y))) / math.pi


@njit(cache=True)
def uv_to_direction(u, v):
    """(u, v) -> (x, y, z, sin θ) in the map frame (Mitsuba's ``uv_to_direction``)."""
    theta = v * math.pi
    phi = u * 2.0 * math.pi
    st = math.sin(theta)
    return math.sin(phi) * st, math.cos(theta), -math.cos(phi) * st, st


@njit(cache=True)
def _to_local(T, dx, dy, dz):
    M = T.to_local
    x = M[0, 0] * dx + M[0, 1] * dy + M[0, 2] * dz
    y = M[1, 0] * dx + M[1, 1] * dy + M[1, 2] * dz
    z = M[2, 0] * dx + M[2, 1] * dy + M[2, 2] * dz
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@njit(cache=True)
def _lookup(T, u, v):
    """Bilinear radiance at (u, v): texel-centred and periodic in u, align-corners in v."""
    img = T.image
    H, W = img.shape[0], img.shape[1]
    x = (u - math.floor(u)) * W - 0.5
    i0 = int(math.floor(x))
    fx = x - i0
    i0 %= W
    i1 = (i0 + 1) % W
    y = min(max(v, 0.0), 1.0) * (H - 1)
    j0 = min(int(y), H - 2)
    fy = y - j0
    out = np.empty(3)
    for c in range(3):
        a = img[j0, i0, c] * (1.0 - fx) + img[j0, i1, c] * fx
        b = img[j0 + 1, i0, c] * (1.0 - fx) + img[j0 + 1, i1, c] * fx
        out[c] = a * (1.0 - fy) + b * fy
    return out


@njit(cache=True)
def _grid_pdf(T, gu, gv):
    """Bilinear density of the warp grid at grid coordinates (gu, gv) ∈ [0, 1]²."""
    g = T.grid
    H, W1 = g.shape[0], g.shape[1]
    x = min(max(gu, 0.0), 1.0) * (W1 - 1)
    i = min(int(x), W1 - 2)
    fx = x - i
    y = min(max(gv, 0.0), 1.0) * (H - 1)
    j = min(int(y), H - 2)
    fy = y - j
    a = g[j, i] * (1.0 - fx) + g[j, i + 1] * fx
    b = g[j + 1, i] * (1.0 - fx) + g[j + 1, i + 1] * fx
    return (a * (1.0 - fy) + b * fy) / T.norm


@njit(cache=True)
def envmap_eval(T, dx, dy, dz):
    """Radiance (RGB array) arriving from world direction (dx, dy, dz) (pointing away
    from the scene, towards the environment)."""
    x, y, z = _to_local(T, dx, dy, dz)
    u, v = direction_to_uv(x, y, z)
    return _lookup(T, u, v)


@njit(cache=True)
def envmap_pdf(T, dx, dy, dz):
    """Solid-angle density of :func:`envmap_sample` for world direction (dx, dy, dz)."""
    if T.norm <= 0.0:
        return 0.0
    x, y, z = _to_local(T, dx, dy, dz)
    u, v = direction_to_uv(x, y, z)
    W = T.image.shape[1]
    gu = u - 0.5 / W
    gu -= math.floor(gu)
    inv_sin = 1.0 / math.sqrt(max(x * x + z * z, _SIN_EPS * _SIN_EPS))
    return _grid_pdf(T, gu, v) * inv_sin / (2.0 * math.pi * math.pi)


@njit(cache=True)
def _sample_linear(a, b, u):
    """t ∈ [0, 1] with density ∝ a (1 − t) + b t (inverse CDF)."""
    if abs(a - b) <= 1e-12 * (a + b):
        return u
    return (a - math.sqrt(max(0.0, (1.0 - u) * a * a + u * b * b))) / (a - b)


@njit(cache=True)
def envmap_sample(T, u1, u2):
    """``(dx, dy, dz, pdf, radiance)``: a world direction drawn ∝ luminance · sin θ
    (piecewise bilinear), its solid-angle pdf and the radiance from it (RGB array).
    A black map gives pdf 0."""
    rad = np.zeros(3)
    if T.norm <= 0.0:
        return 0.0, 0.0, 1.0, 0.0, rad
    g = T.grid
    H, W1 = g.shape[0], g.shape[1]
    W = W1 - 1
    # 1. a cell by its integral, u1 reused inside it
    k = np.searchsorted(T.cell_cdf, u1, side="right")
    k = min(k, T.cell_cdf.shape[0] - 1)
    lo = T.cell_cdf[k - 1] if k > 0 else 0.0
    width = T.cell_cdf[k] - lo
    r = (u1 - lo) / width if width > 0.0 else 0.5
    r = min(max(r, 0.0), 1.0)
    j, i = k // W, k % W
    v00, v10, v01, v11 = g[j, i], g[j, i + 1], g[j + 1, i], g[j + 1, i + 1]
    # 2. row offset from the linear marginal, column offset from the linear conditional
    t = _sample_linear(v00 + v10, v01 + v11, r)
    s = _sample_linear((1.0 - t) * v00 + t * v01, (1.0 - t) * v10 + t * v11, u2)
    gu, gv = (i + s) / W, (j + t) / (H - 1)
    u = gu + 0.5 / W
    x, y, z, st = uv_to_direction(u, gv)
    pdf = _grid_pdf(T, gu, gv) / (2.0 * math.pi * math.pi * max(st, _SIN_EPS))
    M = T.to_world
    dx = M[0, 0] * x + M[0, 1] * y + M[0, 2] * z
    dy = M[1, 0] * x + M[1, 1] * y + M[1, 2] * z
    dz = M[2, 0] * x + M[2, 1] * y + M[2, 2] * z
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / n, dy / n, dz / n, pdf, _lookup(T, u, gv)
