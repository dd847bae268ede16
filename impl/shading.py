"""Flat, Gouraud and Phong shading over the Phong model (thesis 1.4.2, 1.5).

The illumination model is the one ray casting evaluates (:mod:`impl.phong`
through :func:`impl.lighting.direct_light`, with the same parameters k_a,
I_a, k_s, n, c1..c3, the f_att clamp, area-light samples), **without shadow
rays**: local illumination only.  At a point p with geometric normal N_g,
shading normal N and view direction V = (eye − p)/|eye − p|, as
``impl.raycast._radiance`` after its hit:

    I = L_e [N·V > 0]  +  ρ ⊙ (I_a k_a + Σ_lights f_att I_p k_d' (N·L))  +  Σ f_att I_p k_s (R·V)^n

with k_d' = 1/π (k_d = ρ/π), a two-sided material's normals turned towards
V (decided by N_g), and nothing but L_e when N·V ≤ 0.  Writing it as
I = E + ρ ⊙ D + S (emission, diffuse weight, white specular) lets Gouraud
shading interpolate (E, D, S) and apply a per-pixel ρ (texture); for an
untextured material this is classic Gouraud shading of the colour.

=========  ===================================================  ================
mode       where the model is evaluated                          thesis
=========  ===================================================  ================
flat       once per polygon: at its centroid, face normal        1.5.1
gouraud    at the vertices (vertex normals, see                  1.5.2, 1.5.4
           :mod:`impl.tessellate`), (E, D, S) interpolated
phong      per pixel: position and normal interpolated, the      1.5.5
           normal renormalised
=========  ===================================================  ================

Interpolation is perspective-correct (:mod:`impl.raster`); the rasterisers
store a visibility buffer and shading resolves it per pixel in parallel.
Phong shading of a mesh therefore equals ray casting that mesh with shadows
off to rounding: the same point, interpolated normal and light samples
(area lights use the pixel's index and sample 0, as raycast at spp = 1).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .lighting import SHADOW_EPSILON, diffuse_albedo, direct_light, local_shading
from .rays import legacy_config
from .scene_arrays import SceneArrays

__all__ = ["SHADING_MODES", "FLAT", "GOURAUD", "PHONG", "PhongParams", "shade_point", "shade_terms",
           "face_colours", "vertex_terms", "resolve"]

FLAT, GOURAUD, PHONG = 0, 1, 2
SHADING_MODES = {"flat": FLAT, "gouraud": GOURAUD, "phong": PHONG}


def PhongParams(params: dict, seed: int = 0) -> np.ndarray:
    """Pack the Phong parameters of an algorithm's parameter dict into the float64
    vector the kernels read: (ka, ambient, ks, shininess, c1, c2, c3, fatt_clamp, light_samples, seed)."""
    return np.array([params["ka"], params["ambient"], params["ks"], params["shininess"], params["c1"],
                     params["c2"], params["c3"], float(params["fatt_clamp"]), params["light_samples"],
                     seed], dtype=np.float64)


@njit(cache=True)
def shade_point(px, py, pz, gx, gy, gz, sx, sy, sz, ex, ey, ez, shape, prim, b1, b2, A: SceneArrays,
                pp, pixel, sample):
    """Radiance from p towards the eye: ``impl.raycast._radiance`` after its hit, shadows off."""
    vx, vy, vz = ex - px, ey - py, ez - pz
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx * inv, vy * inv, vz * inv
    r, g, b, _n = local_shading(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, shape, prim, b1, b2, A,
                                legacy_config(A, SHADOW_EPSILON), pp[0], pp[1], pp[2], pp[3], pp[4],
                                pp[5], pp[6], pp[7] != 0.0, False, int(pp[8]), int(pp[9]), pixel, sample)
    return r, g, b


@njit(cache=True)
def shade_terms(px, py, pz, gx, gy, gz, sx, sy, sz, ex, ey, ez, shape, A: SceneArrays, pp, pixel, sample, out):
    """(E, D, S) of the model at p into ``out`` (9,): I = E + ρ ⊙ D + S."""
    for k in range(9):
        out[k] = 0.0
    vx, vy, vz = ex - px, ey - py, ez - pz
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx * inv, vy * inv, vz * inv
    cos_v = sx * vx + sy * vy + sz * vz
    if cos_v > 0.0:
        out[0] = A.shape_emit[shape, 0]
        out[1] = A.shape_emit[shape, 1]
        out[2] = A.shape_emit[shape, 2]
    mat = A.shape_material[shape]
    if A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
        cos_v = -cos_v
    if cos_v <= 0.0:
        return
    amb = pp[1] * pp[0]
    fclamp = pp[7] != 0.0
    # Diffuse weight: ρ = 1, k_s = 0.
    dr_, dg_, db_, _n = direct_light(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, 1.0, 1.0, 1.0,
                                     A, 0.0, pp[3], pp[4], pp[5], pp[6], fclamp, False,
                                     int(pp[8]), int(pp[9]), pixel, sample)
    out[3], out[4], out[5] = amb + dr_, amb + dg_, amb + db_
    if pp[2] > 0.0:                     # specular: ρ = 0
        sr, sg, sb, _n = direct_light(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, 0.0, 0.0, 0.0,
                                      A, pp[2], pp[3], pp[4], pp[5], pp[6], fclamp, False,
                                      int(pp[8]), int(pp[9]), pixel, sample)
        out[6], out[7], out[8] = sr, sg, sb


@njit(inline="always", cache=True)
def _face_normal(pos, tri, t, flip):
    a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
    e1x, e1y, e1z = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1], pos[b, 2] - pos[a, 2]
    e2x, e2y, e2z = pos[c, 0] - pos[a, 0], pos[c, 1] - pos[a, 1], pos[c, 2] - pos[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    if flip:
        inv = -inv
    return nx * inv, ny * inv, nz * inv


@njit(cache=True)
def _face_one(pos, tri, tri_shape, tri_prim, tri_flip, t, eye, A, pp, out):
    """Flat shading (1.5.1): the model once per polygon, at its centroid with the face normal."""
    a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
    third = 1.0 / 3.0
    px = (pos[a, 0] + pos[b, 0] + pos[c, 0]) * third
    py = (pos[a, 1] + pos[b, 1] + pos[c, 1]) * third
    pz = (pos[a, 2] + pos[b, 2] + pos[c, 2]) * third
    gx, gy, gz = _face_normal(pos, tri, t, tri_flip[t])
    r, g, bb = shade_point(px, py, pz, gx, gy, gz, gx, gy, gz, eye[0], eye[1], eye[2], tri_shape[t],
                           tri_prim[t], third, third, A, pp, t, 0)
    out[t, 0], out[t, 1], out[t, 2] = r, g, bb


@njit(cache=True)
def _vertex_one(pos, nrm, vshape, v, eye, A, pp, out):
    """Gouraud (1.5.4): the model at a vertex with its vertex normal (also the geometric one)."""
    nx, ny, nz = nrm[v, 0], nrm[v, 1], nrm[v, 2]
    shade_terms(pos[v, 0], pos[v, 1], pos[v, 2], nx, ny, nz, nx, ny, nz, eye[0], eye[1], eye[2],
                vshape[v], A, pp, v, 0, out[v])


def face_colours(soup, used_tri: np.ndarray, eye: np.ndarray, A: SceneArrays, pp: np.ndarray) -> np.ndarray:
    """Flat shading: (T, 3) colour per triangle (rows of unused triangles are 0)."""
    out = np.zeros((soup.n_triangles, 3))
    _stage_kernel(_FACES, soup.n_triangles, used_tri.astype(np.int64), *_no_pixels(), soup.pos, soup.nrm,
                  soup.tri, soup.tri_shape, soup.tri_prim, soup.tri_flip, _NO_V, _NO_FCOL, _NO_VTERM,
                  eye, A, pp, out)
    return out


def vertex_terms(soup, used_tri: np.ndarray, eye: np.ndarray, A: SceneArrays, pp: np.ndarray) -> np.ndarray:
    """Gouraud shading: (V, 9) terms (E, D, S) per vertex of the used triangles."""
    used_v = np.zeros(len(soup.pos), np.int64)
    used_v[soup.tri[used_tri.astype(bool)].ravel()] = 1
    vshape = np.zeros(len(soup.pos), np.int64)
    vshape[soup.tri.ravel()] = np.repeat(soup.tri_shape, 3)
    out = np.zeros((len(soup.pos), 9))
    _stage_kernel(_VERTICES, len(soup.pos), used_v, *_no_pixels(), soup.pos, soup.nrm, soup.tri,
                  soup.tri_shape, soup.tri_prim, soup.tri_flip, vshape, _NO_FCOL, _NO_VTERM, eye, A, pp,
                  out)
    return out


@njit(cache=True)
def _pixel(mode, t, b1, b2, scr_src, scr_bary, pos, nrm, tri, tri_shape, tri_prim, tri_flip,
           fcol, vterm, eye, A, pp, pixel):
    src = scr_src[t]
    b0 = 1.0 - b1 - b2
    # Barycentrics in the source triangle (clipped/split pieces carry their vertices').
    s0 = b0 * scr_bary[t, 0, 0] + b1 * scr_bary[t, 1, 0] + b2 * scr_bary[t, 2, 0]
    s1 = b0 * scr_bary[t, 0, 1] + b1 * scr_bary[t, 1, 1] + b2 * scr_bary[t, 2, 1]
    s2 = b0 * scr_bary[t, 0, 2] + b1 * scr_bary[t, 1, 2] + b2 * scr_bary[t, 2, 2]
    if mode == 0:
        return fcol[src, 0], fcol[src, 1], fcol[src, 2]
    i0, i1, i2 = tri[src, 0], tri[src, 1], tri[src, 2]
    shape = tri_shape[src]
    if mode == 1:
        mat = A.shape_material[shape]
        rr, rg, rb = diffuse_albedo(A, mat, tri_prim[src], s1, s2)
        out_r = s0 * (vterm[i0, 0] + rr * vterm[i0, 3] + vterm[i0, 6]) \
            + s1 * (vterm[i1, 0] + rr * vterm[i1, 3] + vterm[i1, 6]) \
            + s2 * (vterm[i2, 0] + rr * vterm[i2, 3] + vterm[i2, 6])
        out_g = s0 * (vterm[i0, 1] + rg * vterm[i0, 4] + vterm[i0, 7]) \
            + s1 * (vterm[i1, 1] + rg * vterm[i1, 4] + vterm[i1, 7]) \
            + s2 * (vterm[i2, 1] + rg * vterm[i2, 4] + vterm[i2, 7])
        out_b = s0 * (vterm[i0, 2] + rb * vterm[i0, 5] + vterm[i0, 8]) \
            + s1 * (vterm[i1, 2] + rb * vterm[i1, 5] + vterm[i1, 8]) \
            + s2 * (vterm[i2, 2] + rb * vterm[i2, 5] + vterm[i2, 8])
        return out_r, out_g, out_b
    px = s0 * pos[i0, 0] + s1 * pos[i1, 0] + s2 * pos[i2, 0]
    py = s0 * pos[i0, 1] + s1 * pos[i1, 1] + s2 * pos[i2, 1]
    pz = s0 * pos[i0, 2] + s1 * pos[i1, 2] + s2 * pos[i2, 2]
    nx = s0 * nrm[i0, 0] + s1 * nrm[i1, 0] + s2 * nrm[i2, 0]
    ny = s0 * nrm[i0, 1] + s1 * nrm[i1, 1] + s2 * nrm[i2, 1]
    nz = s0 * nrm[i0, 2] + s1 * nrm[i1, 2] + s2 * nrm[i2, 2]
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    gx, gy, gz = _face_normal(pos, tri, src, tri_flip[src])
    return shade_point(px, py, pz, gx, gy, gz, nx * inv, ny * inv, nz * inv, eye[0], eye[1], eye[2],
                       shape, tri_prim[src], s1, s2, A, pp, pixel, 0)


#: The stages of :func:`_stage_kernel`: the model at the used triangles (flat), at the
#: used vertices (Gouraud), then per pixel of the visibility buffer (every mode).
_FACES, _VERTICES, _PIXELS = 0, 1, 2
_NO_V = np.zeros(0, np.int64)
_NO_FCOL = np.zeros((1, 3))
_NO_VTERM = np.zeros((1, 9))


def _no_pixels():
    """The visibility-buffer arguments of a stage that does not read them."""
    return (np.int64(0), np.zeros((0, 0), np.int64), np.zeros((0, 0, 2)), np.zeros(0, np.int64),
            np.zeros((0, 3, 3)))


@njit(parallel=True, cache=True)
def _stage_kernel(stage, n, used, mode, vis_id, vis_b, scr_src, scr_bary, pos, nrm, tri, tri_shape,
                  tri_prim, tri_flip, vshape, fcol, vterm, eye, A: SceneArrays, pp, out):
    """One stage of shading, its ``n`` items in parallel into the rows of ``out``: flat
    colours of the used triangles ((T, 3)), Gouraud terms of the used vertices ((V, 9)),
    or the pixels of the visibility buffer ``vis_id`` (H, W) in shading ``mode`` ((H·W, 3)).

    One kernel for the three: each compiles the illumination model (and numba optimises a
    ``prange`` loop's module again with it linked in), so three kernels compiled it three
    times."""
    W = vis_id.shape[1]
    for c in prange(n):
        i = np.int64(c)                # one index type in both typings of the loop (impl.kernel)
        if stage == _FACES:
            if used[i]:
                _face_one(pos, tri, tri_shape, tri_prim, tri_flip, i, eye, A, pp, out)
        elif stage == _VERTICES:
            if used[i]:
                _vertex_one(pos, nrm, vshape, i, eye, A, pp, out)
        else:
            y, x = i // W, i % W
            t = vis_id[y, x]
            if t >= 0:
                r, g, b = _pixel(mode, t, vis_b[y, x, 0], vis_b[y, x, 1], scr_src, scr_bary, pos, nrm,
                                 tri, tri_shape, tri_prim, tri_flip, fcol, vterm, eye, A, pp, i)
                out[i, 0] = r
                out[i, 1] = g
                out[i, 2] = b


def resolve(mode: int, vis, scr, soup, eye: np.ndarray, A: SceneArrays, pp: np.ndarray) -> tuple[np.ndarray, dict]:
    """Shade a visibility buffer: (H, W, 3) float64 image and counters (model evaluations)."""
    used = np.zeros(soup.n_triangles, np.int64)
    used[scr.src] = 1
    fcol = np.zeros((1, 3))
    vterm = np.zeros((1, 9))
    evals = 0
    if mode == FLAT:
        fcol = face_colours(soup, used, eye, A, pp)
        evals = int(used.sum())
    elif mode == GOURAUD:
        vterm = vertex_terms(soup, used, eye, A, pp)
        evals = int(len(np.unique(soup.tri[used.astype(bool)])))
    else:
        evals = int((vis.id >= 0).sum())
    H, W = vis.id.shape
    image = np.zeros((H * W, 3))
    _stage_kernel(_PIXELS, H * W, _NO_V, np.int64(mode), vis.id, vis.b, scr.src, scr.bary, soup.pos,
                  soup.nrm, soup.tri, soup.tri_shape, soup.tri_prim, soup.tri_flip, _NO_V, fcol, vterm,
                  eye, A, pp, image)
    return image.reshape(H, W, 3), {"shading_evaluations": evals}
