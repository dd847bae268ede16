"""Texture lookups: Mitsuba's ``checkerboard`` and ``bitmap`` (a diffuse reflectance, a
normal or bump map, a projector's irradiance).

What it computes
----------------
The reflectance ρ(u, v) at a surface point's texture coordinates, after the
texture's 2D affine ``to_uv`` map (u', v') = to_uv · (u, v, 1):

* :func:`checkerboard` — ``color0`` where frac(u') > ½ and frac(v') > ½ agree,
  else ``color1`` (Mitsuba 3 ``src/textures/checkerboard.cpp``);
* :func:`bitmap` — an image in linear RGB, looked up as Mitsuba's ``bitmap``
  does (``src/textures/bitmap.cpp`` through ``dr::Texture``): texel (i, j)
  has its centre at ((i + ½)/w, (j + ½)/h), row j = 0 being the *first row of
  the file* (v is not flipped: on Mitsuba's ``rectangle``, whose v grows with
  local y, the file's top row lies at local y = −1); ``bilinear`` weights the
  four texels around (u' w − ½, v' h − ½), ``nearest`` takes the texel that
  contains (u' w, v' h); ``repeat`` / ``clamp`` / ``mirror`` wrap the integer
  texel indices.

The images arrive decoded (8-bit sRGB → linear with the exact sRGB curve, as
Mitsuba's ``raw = false`` does; float EXR as stored) by
:mod:`core.loader`, concatenated into one texel array
(:mod:`impl.scene_arrays`).

:func:`bitmap_grad` is the gradient in uv of a bitmap's luminance (Mitsuba's
``eval_1_grad``), which a ``bumpmap`` reads (:mod:`impl.shading_frame`), and
:func:`scalar_texture` a scalar texture's value at a triangle's point (Mitsuba's
``eval_1``), which :func:`scalar_param` reads for a material's mask opacity, blend
weight or roughness.

Leaves out: MIP-mapping and ray differentials (Mitsuba's bitmap does not
filter over the pixel footprint either), the ``raw`` flag's effect on spectral
upsampling (RGB only), alpha.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["WRAP_REPEAT", "WRAP_CLAMP", "WRAP_MIRROR", "FILTER_BILINEAR", "FILTER_NEAREST",
           "checkerboard", "bitmap", "bitmap_grad", "luminance", "scalar_param", "scalar_texture",
           "wrap_index"]

WRAP_REPEAT, WRAP_CLAMP, WRAP_MIRROR = 0, 1, 2
FILTER_BILINEAR, FILTER_NEAREST = 0, 1


@njit(inline="always", cache=True)
def checkerboard(u, v):
    """Whether (u, v) (after to_uv) lies on a ``color0`` square of Mitsuba's checkerboard."""
    return (u - math.floor(u) > 0.5) == (v - math.floor(v) > 0.5)


@njit(inline="always", cache=True)
def wrap_index(i, n, mode):
    """Integer texel index i wrapped into [0, n) by Mitsuba's wrap mode."""
    if mode == WRAP_CLAMP:
        return min(max(i, 0), n - 1)
    if mode == WRAP_MIRROR:
        period = 2 * n
        i = i % period
        if i < 0:
            i += period
        return i if i < n else period - 1 - i
    i = i % n
    return i + n if i < 0 else i


@njit(inline="always", cache=True)
def _bilinear_texels(offset, w, h, wrap, u, v):
    """The bilinear footprint of (u, v) on a w×h bitmap stored row-major from ``offset``
    (texel centres at half-integers, ``wrap`` at the borders): the fractions (f_x, f_y)
    and the rows of the four texels (00, 10, 01, 11; first index along x)."""
    x = u * w - 0.5
    y = v * h - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = wrap_index(int(x0), w, wrap)
    i1 = wrap_index(int(x0) + 1, w, wrap)
    j0 = wrap_index(int(y0), h, wrap)
    j1 = wrap_index(int(y0) + 1, h, wrap)
    return (fx, fy, offset + j0 * w + i0, offset + j0 * w + i1, offset + j1 * w + i0,
            offset + j1 * w + i1)


@njit(inline="always", cache=True)
def bitmap(data, offset, w, h, wrap, filt, u, v):
    """RGB of a bitmap stored row-major at ``data[offset : offset + w h]`` at (u, v)."""
    if filt == FILTER_NEAREST:
        i = wrap_index(int(math.floor(u * w)), w, wrap)
        j = wrap_index(int(math.floor(v * h)), h, wrap)
        k = offset + j * w + i
        return data[k, 0], data[k, 1], data[k, 2]
    fx, fy, k00, k10, k01, k11 = _bilinear_texels(offset, w, h, wrap, u, v)
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    r = w00 * data[k00, 0] + w10 * data[k10, 0] + w01 * data[k01, 0] + w11 * data[k11, 0]
    g = w00 * data[k00, 1] + w10 * data[k10, 1] + w01 * data[k01, 1] + w11 * data[k11, 1]
    b = w00 * data[k00, 2] + w10 * data[k10, 2] + w01 * data[k01, 2] + w11 * data[k11, 2]
    return r, g, b


@njit(inline="always", cache=True)
def luminance(r, g, b):
    """Mitsuba's ``luminance`` of a linear sRGB colour (the Y row of sRGB → XYZ)."""
    return 0.212671 * r + 0.715160 * g + 0.072169 * b


@njit(inline="always", cache=True)
def bitmap_grad(data, offset, w, h, wrap, filt, m00, m01, m10, m11, u, v):
    """The uv gradient of a bitmap's luminance at (u', v') = to_uv · (u, v, 1), as
    Mitsuba's ``bitmap.eval_1_grad``: the bilinear interpolant's partial derivatives
    in texel units, (∂f/∂x, ∂f/∂y) = ((1 − f_y)(f10 − f00) + f_y (f11 − f01),
    (1 − f_x)(f01 − f00) + f_x (f11 − f10)), taken through the transpose of to_uv's
    2×2 block ``m`` and then scaled by the resolution (w, h) — Mitsuba's order, which
    equals the chain rule when to_uv is diagonal or w = h.  Zero for ``nearest``."""
    if filt == FILTER_NEAREST:
        return 0.0, 0.0
    fx, fy, k00, k10, k01, k11 = _bilinear_texels(offset, w, h, wrap, u, v)
    f00 = luminance(data[k00, 0], data[k00, 1], data[k00, 2])
    f10 = luminance(data[k10, 0], data[k10, 1], data[k10, 2])
    f01 = luminance(data[k01, 0], data[k01, 1], data[k01, 2])
    f11 = luminance(data[k11, 0], data[k11, 1], data[k11, 2])
    dfx = (1.0 - fy) * (f10 - f00) + fy * (f11 - f01)
    dfy = (1.0 - fx) * (f01 - f00) + fx * (f11 - f10)
    return w * (m00 * dfx + m10 * dfy), h * (m01 * dfx + m11 * dfy)


@njit(cache=True)
def scalar_texture(rec, m, c0, c1, data, t, b1, b2, clip):
    """A scalar texture at a triangle's point: ``rec`` its record (code 1 checkerboard of
    the values c0 / c1, 2 bitmap: first texel in ``data``, width, height, wrap, filter),
    ``m`` its to_uv map, ``t`` the triangle's vertex uvs, (b1, b2) the barycentrics.  Read
    as Mitsuba's ``eval_1`` (a bitmap: the luminance of the bilinear RGB; a checkerboard:
    c0 on the squares where its colour lookup gives color1, as Mitsuba), clipped to
    [0, 1] when ``clip``.  A plain call with a few arguments, not inlined: it runs only
    at points whose material has a texture there."""
    b0 = 1.0 - b1 - b2
    u = b0 * t[0, 0] + b1 * t[1, 0] + b2 * t[2, 0]
    v = b0 * t[0, 1] + b1 * t[1, 1] + b2 * t[2, 1]
    uu = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    vv = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    if rec[0] == 1:                  # checkerboard (impl.scene_arrays.TEX_CHECKERBOARD)
        # Mitsuba 3.9.1's checkerboard.eval_1 takes color0 where its colour eval takes
        # color1 (src/textures/checkerboard.cpp: the two tests are negations of each
        # other); a scalar checkerboard follows eval_1.
        x = c1 if checkerboard(uu, vv) else c0
    else:
        r, g, b = bitmap(data, rec[1], rec[2], rec[3], rec[4], rec[5], uu, vv)
        x = luminance(r, g, b)
    return min(max(x, 0.0), 1.0) if clip else x


@njit(inline="always", cache=True)
def scalar_param(T, mat, slot, value, ns, prim, tri_uv, b1, b2):
    """A scalar parameter of material ``mat`` at a hit (primitive ``prim``, barycentrics
    (b1, b2); ``ns`` spheres come first): slot 0 a mask's opacity, 1 a blend weight (both
    clipped to [0, 1], as Mitsuba), 2 a roughness (α_u), 3 α_v.  Its texture's value
    (:func:`scalar_texture`) on triangles, ``value`` (the constant, or the texture's mean
    on spheres) without a texture.  ``T`` holds the slots' textures as
    :class:`impl.materials.WrapperArrays` has them (``ptex``, ``ptex_uv``, ``ptex_c``,
    ``ptex_data``; path's BSDF arrays carry the same fields)."""
    if T.ptex[mat, slot, 0] == 0 or prim < ns:
        return value
    return scalar_texture(T.ptex[mat, slot], T.ptex_uv[mat, slot], T.ptex_c[mat, slot, 0],
                          T.ptex_c[mat, slot, 1], T.ptex_data, tri_uv[prim - ns], b1, b2, slot < 2)
