"""Direct illumination shared by the ray-casting and ray-tracing algorithms.

The numba helpers the local-illumination model needs at a visible point, used
by ``raycast`` (thesis 1.3.3, 1.4) and by ``whitted`` at the leaves of its ray
tree (thesis 2.2: the shadow rays of a hit point):

* :func:`surface` — geometric and shading normals of the kept hit;
* :func:`diffuse_albedo` — the diffuse reflectance ρ at the hit, from the
  material's colour or its texture (Mitsuba's ``checkerboard`` or ``bitmap``,
  :mod:`impl.textures`);
* :func:`environment_radiance` — what a ray that escapes the scene sees: the
  radiance of a ``constant`` environment emitter or an ``envmap`` (0 without
  either), for the
  tracers' escaping rays;
* :func:`sample_emitter` — a uniform point on an area emitter, by area;
* the light samples of the Phong model (thesis 1.4.1–1.4.2), one helper per
  kind of light, each on plain scalars (and the emitter's arrays): a delta
  light (point, spot, directional, projector: :func:`delta_sample`; a spot's cone
  :func:`spot_falloff`, Mitsuba's, in the emitter's frame; the RGB factor of a
  projector's image or a spot's ``texture``, :func:`delta_filter`, applied by the
  callers), a uniform-by-area
  point of an area emitter (:func:`area_sample`), a cosine-weighted direction
  towards a ``constant`` environment emitter, or importance-sampled by an
  ``envmap``'s luminance (:func:`environment_sample`).
  Each gives the direction to the light and the radiance contribution that
  the shadow ray (:func:`shadow_towards`, :func:`shadow_along`, cast with a
  ray configuration :class:`impl.rays.RayConfig`: ray–sphere form,
  intersection precision, offset strategy) decides.  For the environment the
  diffuse estimator is L_env ρ V(ω) per sample (f cos / pdf = (ρ/π) cos /
  (cos/π) = ρ), the Phong highlight adds L_env k_s (R·V)^n π / cos;
* :func:`direct_light_rays` — the sum of every light sample at one point,
  shadow rays traced one at a time; :func:`direct_light` is the same with the
  fixed offset rule of :func:`impl.rays.legacy_config` (stable form, float64,
  origin moved SHADOW_EPSILON·(1 + max|p_i|) along the normal);
* :func:`direct_batch` — the same over a batch of shading points, each light
  sample's shadow rays traced together (:func:`impl.tracer.occluded_batch`),
  with the parameters in one :class:`LocalModel`;
* :func:`shadow_filter` — transmissive shadows (thesis 2.2: a shadow ray
  passes transparent objects, its light attenuated by their transmittance):
  the Fresnel transmittance of the smooth dielectric interfaces a blocked
  shadow segment crosses, 0 if it meets anything else.  Off unless the
  :class:`LocalModel` carries the dielectrics' indices (``shadow_eta``).

Both sums visit the samples in one order — delta lights, then
``light_samples`` per area emitter, then ``light_samples`` for the
environment — and draw sample j's two random numbers from dimensions
2 + 2j', j' = j minus the number of delta lights, so they give the same light
at the same point.  The loops over lights and points live in those two
functions and the per-sample helpers take scalars: a helper that took the
whole flattened scene per sample would copy its tuple of arrays (an atomic
reference-count update per array) at every call.

They take the flattened scene (:class:`impl.scene_arrays.SceneArrays`); the
single-point helpers return plain scalars, so a caller's kernel stays free of
allocation.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .envmap import envmap_draw, envmap_radiance
from .fresnel import fresnel_conductor, fresnel_dielectric
from .kernel import batch_kernel, by_reference, dereference
from .rays import RayConfig, hit, leave, leave_towards, legacy_config, occluded, refine, round_ray
from .phong import INV_PI, attenuation, phong_brdf_cos
from .lowdiscrepancy import pixel_seed, sample_2d
from .rng import uniform_from, uniform_prefix
from .projector import projector_weight
from .samplers import DIM_INDEPENDENT, dim_2d
from .scene_arrays import (LIGHT_DIRECTIONAL, LIGHT_PROJECTOR, LIGHT_SPOT, PTEX_ETA, PTEX_K,
                           PTEX_TRANSMITTANCE, TEX_BITMAP, TEX_CHECKERBOARD, SceneArrays, triangle_normal)
from .textures import bitmap, checkerboard
from .shading_frame import perturbed_normal, same_side, shadow_terminator
from .tracer import POINT_ROWS, brute_force, occluded_batch

__all__ = ["SHADOW_EPSILON", "surface", "surface_at", "sphere_surface",
           "diffuse_albedo", "sample_emitter", "direct_light",
           "direct_light_rays", "direct_light_dims", "spot_falloff", "delta_filter", "delta_sample",
           "area_sample", "environment_sample",
           "shadow_towards", "shadow_along", "direct_batch", "LocalModel", "local_model",
           "environment_radiance", "sample_cosine_hemisphere", "shadow_filter", "SHADOW_MODES",
           "mapped_normal", "mapped_normal_at", "map_weight", "point_map_weight", "store_point",
           "specular_tint", "param_rgb", "transmittance_tint", "textured_fresnel", "textured_params"]

#: Shadow-ray origins move off the surface by this much times (1 + |p|_max).
SHADOW_EPSILON = 1e-7

#: What a shadow ray does at a transparent object: stop (``opaque``) or pass it,
#: filtered by its Fresnel transmittance (``transmissive``, :func:`shadow_filter`).
SHADOW_MODES = ("opaque", "transmissive")

#: Interfaces a transmissive shadow segment may cross before it counts as blocked.
MAX_INTERFACES = 16


@njit(inline="always", cache=True)
def surface(prim, b1, b2, px, py, pz, ns, sph_center, sph_radius, tri_v, tri_n, tri_has_n, flip):
    """Geometric and shading normals of a hit (the costly part, only for the kept hit), a
    triangle's geometric normal computed from its vertices ``tri_v`` (for geometry that
    moves; :func:`surface_at` reads it from the scene's table)."""
    if prim < ns:
        gx, gy, gz, sx, sy, sz = sphere_surface(prim, px, py, pz, sph_center, sph_radius, flip)
    else:
        gx, gy, gz = triangle_normal(tri_v[prim - ns])
        gx, gy, gz, sx, sy, sz = _shading_normal(prim - ns, b1, b2, gx, gy, gz, tri_n, tri_has_n,
                                                 flip)
    return gx, gy, gz, sx, sy, sz        # one return path (see spot_falloff)


@njit(inline="always", cache=True)
def surface_at(A: SceneArrays, prim, b1, b2, px, py, pz, flip):
    """:func:`surface` of the scene ``A``, a triangle's geometric normal read from
    ``A.tri_ng`` (the same bits: :func:`impl.scene_arrays.flatten` computes the table with
    :func:`impl.scene_arrays.triangle_normal`)."""
    ns = A.sph_radius.shape[0]
    if prim < ns:
        gx, gy, gz, sx, sy, sz = sphere_surface(prim, px, py, pz, A.sph_center, A.sph_radius, flip)
    else:
        j = prim - ns
        gx, gy, gz, sx, sy, sz = _shading_normal(j, b1, b2, A.tri_ng[j, 0], A.tri_ng[j, 1],
                                                 A.tri_ng[j, 2], A.tri_n, A.tri_has_n, flip)
    return gx, gy, gz, sx, sy, sz


@njit(inline="always", cache=True)
def sphere_surface(prim, px, py, pz, sph_center, sph_radius, flip):
    """Normals (geometric = shading) of sphere ``prim`` at p: (p − c) / r, negated with ``flip``."""
    r = sph_radius[prim]
    gx = (px - sph_center[prim, 0]) / r
    gy = (py - sph_center[prim, 1]) / r
    gz = (pz - sph_center[prim, 2]) / r
    if flip:
        gx, gy, gz = -gx, -gy, -gz
    return gx, gy, gz, gx, gy, gz


@njit(inline="always", cache=True)
def _shading_normal(j, b1, b2, gx, gy, gz, tri_n, tri_has_n, flip):
    """Triangle j's normals at barycentrics (b1, b2) from its geometric normal g: the
    shading normal interpolated from its vertex normals where it has them, else g; both
    negated with ``flip``."""
    if tri_has_n[j]:
        sx, sy, sz = interpolated_normal(tri_n, j, b1, b2)
    else:
        sx, sy, sz = gx, gy, gz
    if flip:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    return gx, gy, gz, sx, sy, sz


@njit(inline="always", cache=True)
def interpolated_normal(tri_n, j, b1, b2):
    """Triangle j's unit shading normal at barycentrics (b1, b2): its vertex normals
    ``tri_n[j]`` weighted by (1 − b1 − b2, b1, b2), normalised (not negated)."""
    b0 = 1.0 - b1 - b2
    sx = b0 * tri_n[j, 0, 0] + b1 * tri_n[j, 1, 0] + b2 * tri_n[j, 2, 0]
    sy = b0 * tri_n[j, 0, 1] + b1 * tri_n[j, 1, 1] + b2 * tri_n[j, 2, 1]
    sz = b0 * tri_n[j, 0, 2] + b1 * tri_n[j, 1, 2] + b2 * tri_n[j, 2, 2]
    inv = 1.0 / math.sqrt(sx * sx + sy * sy + sz * sz)
    return sx * inv, sy * inv, sz * inv


@njit(inline="always", cache=True)
def sample_emitter(e, u1, u2, em_offset, em_tri, em_cdf, tri_v):
    """Uniform point on emitter ``e`` by area: (x, y, z, triangle index)."""
    lo, hi = em_offset[e], em_offset[e + 1] - 1
    # Binary search the area CDF with u1, then reuse the remainder of u1.
    a, b = lo, hi
    while a < b:
        mid = (a + b) // 2
        if em_cdf[mid] < u1:
            a = mid + 1
        else:
            b = mid
    prev = em_cdf[a - 1] if a > lo else 0.0
    width = em_cdf[a] - prev
    u1 = min(max((u1 - prev) / width, 0.0), 1.0) if width > 0.0 else 0.5
    v = tri_v[em_tri[a]]
    # Square to triangle: b0 = 1 − √u1, b1 = u2 √u1.
    su = math.sqrt(u1)
    w1, w2 = u2 * su, 1.0 - su
    w0 = 1.0 - w1 - w2
    x = w2 * v[0, 0] + w0 * v[1, 0] + w1 * v[2, 0]
    y = w2 * v[0, 1] + w0 * v[1, 1] + w1 * v[2, 1]
    z = w2 * v[0, 2] + w0 * v[1, 2] + w1 * v[2, 2]
    return x, y, z, em_tri[a]


@njit(inline="always", cache=True)
def _towards(ox, oy, oz, yx, yy, yz):
    """Unit direction from o to y and the distance |y − o| (direction 0 when y = o)."""
    hx, hy, hz = yx - ox, yy - oy, yz - oz
    hd = math.sqrt(hx * hx + hy * hy + hz * hz)
    if hd == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    inv = 1.0 / hd
    return hx * inv, hy * inv, hz * inv, hd


@njit(cache=True)
def local_shading(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, shape, prim, b1, b2, A: SceneArrays,
                  R: RayConfig, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                  seed, pixel, sample):
    """Local illumination leaving a surface point towards the unit direction v (thesis 1.4.2):
    emitted L_e (front side only) + ambient I_a k_a ρ + the Phong direct light of every
    light; (r, g, b, shadow rays).  A one-sided point seen from behind gets nothing;
    a two-sided one is shaded on the side it is seen from.  Under a normal or bump map
    (a triangle ``prim`` with uvs, barycentrics b1, b2) the bracket is taken about the
    perturbed normal and each light weighted as Mitsuba's adapters weight it
    (:func:`mapped_normal`, :func:`map_weight`), as ray casting shades its hits."""
    r = g = b = 0.0
    if sx * vx + sy * vy + sz * vz > 0.0:       # emitted radiance L_e, front side only
        r += A.shape_emit[shape, 0]
        g += A.shape_emit[shape, 1]
        b += A.shape_emit[shape, 2]
    mat = A.shape_material[shape]
    back = A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0
    nx, ny, nz, code = mapped_normal(A, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, back)
    if back:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    if nx * vx + ny * vy + nz * vz <= 0.0:      # the BSDF sees the viewer below n
        return r, g, b, 0
    rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
    amb = ambient * ka
    dr_, dg_, db_, nsh = direct_light_dims(px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz,
                                           rho_r, rho_g, rho_b, A, ks, shininess, c1, c2, c3,
                                           fclamp, shadows, light_samples, seed, pixel, sample, R,
                                           (DIM_INDEPENDENT, 0, 0), (sx, sy, sz, code))
    return r + amb * rho_r + dr_, g + amb * rho_g + dg_, b + amb * rho_b + db_, nsh


@njit(cache=True)
def direct_light(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
            A: SceneArrays, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
            seed, pixel, sample):
    """Phong-model direct light from every light at one point: (r, g, b, shadow rays),
    shadow rays by the fixed offset rule of :func:`impl.rays.legacy_config`."""
    return direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                             A, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                             seed, pixel, sample, legacy_config(A, SHADOW_EPSILON))


@njit(inline="always", cache=True)
def direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                      A: SceneArrays, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                      seed, pixel, sample, R: RayConfig):
    """:func:`direct_light` with shadow rays cast by the ray configuration ``R``: the
    sum of every light sample whose shadow ray is unoccluded (all of them with
    ``shadows`` false); (r, g, b, shadow rays)."""
    return direct_light_dims(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                             A, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples, seed,
                             pixel, sample, R, (DIM_INDEPENDENT, 0, 0), (sx, sy, sz, MAP_NONE))


@njit(inline="always", cache=True)
def direct_light_dims(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                      A: SceneArrays, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                      seed, pixel, sample, R: RayConfig, dims, mapped):
    """:func:`direct_light_rays` with the light samples' numbers of pixel sample
    ``sample`` drawn as ``dims = (dmode, dspp, ddim)`` says: light sample j is dimension
    ``ddim + j`` of ``dspp`` samples in mode ``dmode`` (:func:`light_uv_dims`; with
    ``DIM_INDEPENDENT`` the hashed :func:`light_uv` of ``sample``), and every light
    sample weighted by :func:`map_weight` with ``mapped = (s0x, s0y, s0z, code)``: under
    a normal or bump map (``code`` not ``MAP_NONE``) s is the perturbed normal the Phong
    bracket is taken about and s0 the unperturbed shading normal.  ``A`` and ``R`` may be
    the flattened scene and the ray configuration or references to them
    (:func:`impl.kernel.by_reference`; the light loop gets both by reference).  (Tuples:
    a call of an inlined function with more than 30 arguments compiles to a star-args
    call, which numba cannot inline.)"""
    # Every argument that a caller may pass as a literal (``False``, ``0``) goes through
    # its type (bool(), np.int64(), float()): numba compiles a function once per literal
    # value it is called with, and _direct_light_rays is a large function.
    dmode, dspp, ddim = dims
    s0x, s0y, s0z, code = mapped
    return _direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                              by_reference(A), ks, shininess, c1, c2, c3, fclamp, bool(shadows),
                              np.int64(light_samples), np.int64(seed), np.int64(pixel),
                              np.int64(sample), by_reference(R), np.int64(dmode), np.int64(dspp),
                              np.int64(ddim), float(s0x), float(s0y), float(s0z), float(code))


@batch_kernel
def _direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                       scene, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                       seed, pixel, sample, rays, dmode, dspp, ddim, s0x, s0y, s0z, code):
    """The body of :func:`direct_light_dims` (opaque shadows); ``scene`` and ``rays`` the
    flattened scene and the ray configuration by reference.  Compiled without numba's
    runtime whoever calls it first (its callers include runtime-on functions, the
    z-buffer's shading): with the runtime, reading them back would count a reference to
    each of their arrays at every call."""
    A, R = dereference(scene), dereference(rays)
    r = g = b = 0.0
    nshadow = 0
    for li in range(A.light_kind.shape[0]):
        kind = A.light_kind[li]
        ok, lx, ly, lz, w, kd, spec = delta_sample(
            kind, A.light_pos[li, 0], A.light_pos[li, 1], A.light_pos[li, 2], A.light_dir[li, 0],
            A.light_dir[li, 1], A.light_dir[li, 2], A.light_local, li, A.light_cos_cutoff[li],
            A.light_cos_beam[li], A.light_cutoff[li], A.light_inv_tw[li], px, py, pz, sx, sy, sz,
            vx, vy, vz, ks, shininess, c1, c2, c3, fclamp)
        if not ok:
            continue
        tr, tg, tb = delta_filter(A, li, kind, px, py, pz, lx, ly, lz)
        f = map_weight(sx, sy, sz, s0x, s0y, s0z, code, lx, ly, lz)
        if (tr == 0.0 and tg == 0.0 and tb == 0.0) or f == 0.0:
            continue
        cr = w * tr * A.light_rad[li, 0] * (kd * rho_r + spec) * f
        cg = w * tg * A.light_rad[li, 1] * (kd * rho_g + spec) * f
        cb = w * tb * A.light_rad[li, 2] * (kd * rho_b + spec) * f
        if shadows:
            nshadow += 1
            if kind == LIGHT_DIRECTIONAL:
                ox, oy, oz, dx, dy, dz, t0, t1 = shadow_along(R, px, py, pz, gx, gy, gz, lx, ly, lz)
            else:
                ox, oy, oz, dx, dy, dz, t0, t1 = shadow_towards(
                    R, px, py, pz, gx, gy, gz, lx, ly, lz, A.light_pos[li, 0], A.light_pos[li, 1],
                    A.light_pos[li, 2], R.shrink_point)
            if occluded(R, ox, oy, oz, dx, dy, dz, t0, t1):
                continue
        r += cr
        g += cg
        b += cb
    if light_samples <= 0:
        return r, g, b, nshadow
    q = int(math.sqrt(light_samples) + 0.5)
    stratified = q * q == light_samples
    n_em = A.em_area.shape[0]
    for e in range(n_em):
        sh = A.em_shape[e]
        flip = A.shape_flip[sh]
        scale = A.em_area[e] / light_samples
        er, eg, eb = A.shape_emit[sh, 0], A.shape_emit[sh, 1], A.shape_emit[sh, 2]
        for k in range(light_samples):
            u1, u2 = light_uv_dims(seed, pixel, sample, e * light_samples + k, k, q, stratified, dmode,
                                   dspp, ddim)
            ok, lx, ly, lz, yx, yy, yz, cr, cg, cb = area_sample(
                A, e, u1, u2, flip, scale, er, eg, eb, px, py, pz, sx, sy, sz, vx, vy, vz, rho_r,
                rho_g, rho_b, ks, shininess, c1, c2, c3, fclamp)
            f = map_weight(sx, sy, sz, s0x, s0y, s0z, code, lx, ly, lz) if ok else 0.0
            if f == 0.0:
                continue
            cr, cg, cb = cr * f, cg * f, cb * f
            if shadows:
                nshadow += 1
                ox, oy, oz, dx, dy, dz, t0, t1 = shadow_towards(R, px, py, pz, gx, gy, gz, lx, ly,
                                                                lz, yx, yy, yz, R.shrink_area)
                if occluded(R, ox, oy, oz, dx, dy, dz, t0, t1):
                    continue
            r += cr
            g += cg
            b += cb
    if A.env_radiance.shape[0] + A.env_image.shape[0] > 0:
        er = eg = eb = 0.0
        if A.env_radiance.shape[0] > 0:
            er, eg, eb = A.env_radiance[0, 0], A.env_radiance[0, 1], A.env_radiance[0, 2]
        img, frame, epdf, ecdf = A.env_image, A.env_frame, A.env_pdf, A.env_cdf
        for k in range(light_samples):
            u1, u2 = light_uv_dims(seed, pixel, sample, n_em * light_samples + k, k, q, stratified,
                                   dmode, dspp, ddim)
            ok, lx, ly, lz, cr, cg, cb = environment_sample(
                u1, u2, er, eg, eb, img, frame, epdf, ecdf, light_samples, sx, sy, sz, vx, vy, vz,
                rho_r, rho_g, rho_b, ks, shininess)
            f = map_weight(sx, sy, sz, s0x, s0y, s0z, code, lx, ly, lz) if ok else 0.0
            if f == 0.0:
                continue
            cr, cg, cb = cr * f, cg * f, cb * f
            if shadows:
                nshadow += 1
                ox, oy, oz, dx, dy, dz, t0, t1 = shadow_along(R, px, py, pz, gx, gy, gz, lx, ly, lz)
                if occluded(R, ox, oy, oz, dx, dy, dz, t0, t1):
                    continue
            r += cr
            g += cg
            b += cb
    return r, g, b, nshadow


@njit(inline="always", cache=True)
def light_uv(seed, pixel, sample, j, k, q, stratified):
    """The two random numbers of area/environment light sample ``j`` (sample ``k`` of its
    light): dimensions 2 + 2j and 3 + 2j of :func:`impl.rng.uniform`, moved into stratum
    k of a q×q grid when the light's sample count is the square q²."""
    dim = 2 + 2 * j
    h = uniform_prefix(seed, pixel, sample)
    u1 = uniform_from(h, dim)
    u2 = uniform_from(h, dim + 1)
    if stratified:
        u1 = (k % q + u1) / q
        u2 = (k // q + u2) / q
    return u1, u2


@njit(inline="always", cache=True)
def light_uv_dims(seed, pixel, sample, j, k, q, stratified, dmode, dspp, ddim):
    """:func:`light_uv`, or with ``dmode`` not ``DIM_INDEPENDENT`` dimension ``ddim + j``
    of pixel sample ``sample`` of ``dspp`` (:func:`impl.samplers.dim_2d`: shuffled
    strata or padded Sobol over the pixel's samples)."""
    if dmode != DIM_INDEPENDENT:
        return dim_2d(dmode, seed, pixel, sample, dspp, ddim + j)
    return light_uv(seed, pixel, sample, j, k, q, stratified)


@njit(inline="always", cache=True)
def light_uv_sobol(seed, pixel, sample, light, k, light_samples):
    """The two numbers of light sample ``k`` of light ``light`` (its index among the area
    emitters, the environment after them) at pixel sample ``sample``: point
    ``sample · light_samples + k`` of an Owen-scrambled Sobol (0, 2)-sequence
    (:func:`impl.lowdiscrepancy.sample_2d`, dimension pair ``1 + light``; the pixel
    position is pair 0) scrambled per pixel.  The points of a pixel's first
    ``spp · light_samples`` samples then form a (0, m, 2)-net when that count is a power
    of two: stratified over the pixel's samples, not only within one (Owen 1997 for
    the nets; pbrt-v4's padded Sobol sampler for pairing dimensions by independent
    scrambles).  Each point stays uniform, so the estimate stays unbiased."""
    return sample_2d(1 + light, sample * light_samples + k, pixel_seed(pixel, 0, seed))


@njit(cache=True, _nrt=False)
def light_uv_sobol_lanes(seed, pixel, sample, light, k, light_samples, u, v):
    """:func:`light_uv_sobol` of every point i (pixel ``pixel[i]``, pixel sample
    ``sample[i]``) into ``u[i]``, ``v[i]``: the same bits, in one loop without branches,
    which LLVM vectorises where the target has packed 64-bit multiplies (AVX-512DQ)."""
    for i in range(pixel.shape[0]):
        u[i], v[i] = light_uv_sobol(seed, pixel[i], sample[i], light, k, light_samples)


@njit(inline="always", cache=True)
def spot_texture(wx, wy, wz, local, li, tan_cutoff, tex, uvm, data):
    """The RGB factor of spot ``li``'s ``texture`` towards the world direction w (from
    the light to the lit point; any length), as Mitsuba 3's ``spot``
    (``src/emitters/spot.cpp``, ``direction_to_uv``): w in the light's frame
    (``local[li]``, as :func:`spot_falloff`) gives uv = (½ + ½ x / (z tan cutoff),
    ½ + ½ y / (z tan cutoff)), then the texture's to_uv ``uvm`` and its bitmap record
    ``tex`` (offset, width, height, wrap, filter) into ``data``.  Only meaningful
    inside the cone (z > 0), where the callers apply it."""
    ax = local[li, 0, 0] * wx + local[li, 0, 1] * wy + local[li, 0, 2] * wz
    ay = local[li, 1, 0] * wx + local[li, 1, 1] * wy + local[li, 1, 2] * wz
    az = local[li, 2, 0] * wx + local[li, 2, 1] * wy + local[li, 2, 2] * wz
    u = 0.5 + 0.5 * ax / (az * tan_cutoff)
    v = 0.5 + 0.5 * ay / (az * tan_cutoff)
    uu = uvm[0, 0] * u + uvm[0, 1] * v + uvm[0, 2]
    vv = uvm[1, 0] * u + uvm[1, 1] * v + uvm[1, 2]
    return bitmap(data, tex[0], tex[1], tex[2], tex[3], tex[4], uu, vv)


@njit(inline="always", cache=True)
def spot_falloff(wx, wy, wz, local, li, cos_cutoff, cos_beam, cutoff, inv_tw):
    """The cone profile of spot light ``li`` towards the world direction w (from the
    light to the lit point; any length), in [0, 1], as Mitsuba 3's ``spot``
    (``src/emitters/spot.cpp``, ``falloff_curve``): w is taken into the light's frame
    by ``local[li]`` (the inverse of its to_world's 3×3, so a non-uniform scale or a
    shear shapes the cone as Mitsuba's) and normalised; with θ its angle to +z the
    profile is 0 unless cos θ > cos(cutoff), then 1 where cos θ ≥ cos(beam width)
    and (cutoff − θ) / (cutoff − beam width) (linear in angle, radians; ``inv_tw`` =
    1 / (cutoff − beam width)) below.  One return path: a helper with several can keep
    numba from pruning the reference counts of its caller's arrays."""
    ax = local[li, 0, 0] * wx + local[li, 0, 1] * wy + local[li, 0, 2] * wz
    ay = local[li, 1, 0] * wx + local[li, 1, 1] * wy + local[li, 1, 2] * wz
    az = local[li, 2, 0] * wx + local[li, 2, 1] * wy + local[li, 2, 2] * wz
    cos_t = az / math.sqrt(ax * ax + ay * ay + az * az)
    f = 0.0
    if cos_t > cos_cutoff:
        f = 1.0
        if cos_t < cos_beam:
            f = cone_edge(cos_t, cutoff, inv_tw)
    return f


@njit(inline="always", cache=True)
def cone_edge(cos_t, cutoff, inv_tw):
    """A spot's profile between its beam width and its cutoff angle (:func:`spot_falloff`):
    (cutoff − θ) / (cutoff − beam width), θ = acos(cos_t), ``inv_tw`` = 1 / (cutoff − beam width)."""
    return (cutoff - math.acos(min(cos_t, 1.0))) * inv_tw


@njit(inline="always", cache=True)
def delta_filter(A: SceneArrays, li, kind, px, py, pz, lx, ly, lz):
    """The RGB factor of delta light ``li``'s image at p, l the unit direction from p
    to the light: a projector's irradiance image (:func:`impl.projector.projector_weight`,
    which holds the d² the attenuation's 1/d² cancels), a spot's ``texture``
    (:func:`spot_texture`; meaningful inside the cone, where the callers apply it),
    else (1, 1, 1).  One return path, as :func:`spot_falloff`."""
    tr = tg = tb = 1.0
    if kind == LIGHT_PROJECTOR:
        tr, tg, tb = projector_weight(A.light_local, li, A.light_pos[li, 0], A.light_pos[li, 1],
                                      A.light_pos[li, 2], A.light_dir[li, 0], A.light_dir[li, 1],
                                      A.light_dir[li, 2], A.light_proj[li], A.light_tex[li],
                                      A.light_tex_uv[li], A.tex_data, px, py, pz, lx, ly, lz)
    elif kind == LIGHT_SPOT and A.light_tex[li, 1] > 0:
        tr, tg, tb = spot_texture(-lx, -ly, -lz, A.light_local, li, math.tan(A.light_cutoff[li]),
                                  A.light_tex[li], A.light_tex_uv[li], A.tex_data)
    return tr, tg, tb


@njit(inline="always", cache=True)
def delta_sample(kind, lpx, lpy, lpz, ldx, ldy, ldz, local, li, cos_cutoff, cos_beam, cutoff,
                 inv_tw, px, py, pz, sx, sy, sz, vx, vy, vz, ks, shininess, c1, c2, c3, fclamp):
    """A delta light (thesis 1.4.1) at a surface point p (shading normal s, towards the
    viewer v), Phong model (1.4.2): ``(lit, l, w, kd, spec)``, l the unit direction to
    the light; the light of radiant intensity I reflected by diffuse reflectance ρ is
    w I (kd ρ + spec).  Point and spot lights sit at ``lp``, attenuated
    by f_att(d); a directional light shines along ``ld``.  A spot (light ``li``) is
    weighted by :func:`spot_falloff` (``local`` and the cone parameters as there).  A
    projector is a point light here, and a spot's texture is left out: the callers
    multiply by their image's RGB factor (:func:`delta_filter`).  ``lit`` is false
    where the light adds nothing (outside the cone, or the bracket is 0)."""
    z = 0.0
    if kind == LIGHT_DIRECTIONAL:
        lx, ly, lz = -ldx, -ldy, -ldz
        w = 1.0
    else:
        lx, ly, lz = lpx - px, lpy - py, lpz - pz
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        inv = 1.0 / dist
        lx, ly, lz = lx * inv, ly * inv, lz * inv
        w = attenuation(dist, c1, c2, c3, fclamp)
        if kind == LIGHT_SPOT:
            f = spot_falloff(-lx, -ly, -lz, local, li, cos_cutoff, cos_beam, cutoff, inv_tw)
            if f == 0.0:
                return False, z, z, z, z, z, z
            w *= f
    kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
    if kd == 0.0 and spec == 0.0:
        return False, z, z, z, z, z, z
    return True, lx, ly, lz, w, kd, spec


@njit(inline="always", cache=True)
def area_sample(A: SceneArrays, e, u1, u2, flip, scale, er, eg, eb, px, py, pz, sx, sy, sz, vx, vy,
                vz, rho_r, rho_g, rho_b, ks, shininess, c1, c2, c3, fclamp):
    """One uniform-by-area sample y of area emitter ``e`` (radiance ``(er, eg, eb)``,
    ``scale`` = its area / the sample count N) lit towards p (thesis 1.4.1):
    ``(lit, l, y, contribution)`` with the estimator L_e A cos θ_y f_att(d) · bracket / N.
    Area emitters radiate from their front side only (``flip``: the shape's normals are
    flipped); the emitter triangle's unit normal is read from ``A.tri_ng`` (the bits
    :func:`surface` computes from the vertices)."""
    z = 0.0
    yx, yy, yz, tri = sample_emitter(e, u1, u2, A.em_offset, A.em_tri, A.em_cdf, A.tri_v)
    lx, ly, lz = yx - px, yy - py, yz - pz
    dist = math.sqrt(lx * lx + ly * ly + lz * lz)
    if dist == 0.0:
        return False, z, z, z, z, z, z, z, z, z
    lx, ly, lz = lx / dist, ly / dist, lz / dist
    nx, ny, nz = A.tri_ng[tri, 0], A.tri_ng[tri, 1], A.tri_ng[tri, 2]
    if flip:
        nx, ny, nz = -nx, -ny, -nz
    cos_y = -(nx * lx + ny * ly + nz * lz)
    if cos_y <= 0.0:
        return False, z, z, z, z, z, z, z, z, z
    kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
    if kd == 0.0 and spec == 0.0:
        return False, z, z, z, z, z, z, z, z, z
    w = cos_y * attenuation(dist, c1, c2, c3, fclamp) * scale
    return (True, lx, ly, lz, yx, yy, yz, w * (kd * rho_r + spec) * er,
            w * (kd * rho_g + spec) * eg, w * (kd * rho_b + spec) * eb)


@njit(inline="always", cache=True)
def environment_sample(u1, u2, er, eg, eb, image, frame, pdf, cdf, n, sx, sy, sz, vx, vy, vz, rho_r,
                       rho_g, rho_b, ks, shininess):
    """One of ``n`` cosine-weighted directions l about the shading normal towards a
    constant environment of radiance ``(er, eg, eb)``: ``(lit, l, contribution)``
    with the estimator L_env · bracket · π / (cos θ n); with an envmap (``image``
    has rows; its ``frame``, ``pdf``, ``cdf`` of :mod:`impl.envmap`) a direction
    drawn by the map's luminance, estimator L(l) · bracket / (pdf(l) n)."""
    z = 0.0
    if image.shape[0] > 0:
        lx, ly, lz, p, er, eg, eb = envmap_draw(image, frame, pdf, cdf, u1, u2)
        inv_pdf = 1.0 / p if p > 0.0 else 0.0
    else:
        lx, ly, lz, cos_l = sample_cosine_hemisphere(u1, u2, sx, sy, sz)
        inv_pdf = math.pi / cos_l if cos_l > 0.0 else 0.0
    if inv_pdf == 0.0:
        return False, z, z, z, z, z, z
    kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
    if kd == 0.0 and spec == 0.0:
        return False, z, z, z, z, z, z
    w = inv_pdf / n                  # 1 / (pdf n); constant: pdf = cos / π
    return (True, lx, ly, lz, w * (kd * rho_r + spec) * er, w * (kd * rho_g + spec) * eg,
            w * (kd * rho_b + spec) * eb)


@njit(inline="always", cache=True)
def shadow_towards(R, px, py, pz, gx, gy, gz, lx, ly, lz, yx, yy, yz, shrink):
    """Shadow ray from the surface point p (geometric normal g) to the point y, seen along
    the unit direction l: it leaves p on the side of l and is aimed from its offset origin
    at y, ending at |y − o|·(1 − shrink).  (Aimed along l from p instead, the segment
    shifts sideways by the offset and can meet a grazing area emitter before t_max.)"""
    side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
    ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
    hx, hy, hz, hd = _towards(ox, oy, oz, yx, yy, yz)
    return ox, oy, oz, hx, hy, hz, t0, hd * (1.0 - shrink)


@njit(inline="always", cache=True)
def shadow_along(R, px, py, pz, gx, gy, gz, lx, ly, lz):
    """Shadow ray from p towards infinity along the unit direction l."""
    side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
    ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
    return ox, oy, oz, lx, ly, lz, t0, np.inf


@njit(cache=True)
def shadow_filter(R, ox, oy, oz, dx, dy, dz, t0, t1, seta, strans, prim_shape, shape_material,
                  sph_center, sph_radius, tri_v, tri_n, tri_has_n, shape_flip):
    """Transmittance (r, g, b) of the shadow segment o + t d, t0 < t < t1, when shadow
    rays pass transparent objects (thesis 2.2): the product, over the surfaces the
    segment meets in order, of (1 − F(N·(−d))) × ``specular_transmittance`` at a smooth
    dielectric (``seta[mat]`` = its int_ior/ext_ior > 0, F the unpolarised Fresnel
    reflectance, :func:`impl.fresnel.fresnel_dielectric`); 0 at any other surface, under
    total internal reflection, or after ``MAX_INTERFACES`` interfaces.

    Whitted's approximation, not light transport: the segment goes straight through
    (refraction does not bend it, so no caustic is formed and the shadow of a glass
    sphere is a disc of light dimmed by two Fresnel factors), and the η² radiance
    scaling is left out (it cancels between entering and leaving a closed object).
    Each crossing continues from the hit, offset to the far side by R's strategy.
    """
    ns = sph_radius.shape[0]
    tr = tg = tb = 1.0
    for _ in range(MAX_INTERFACES):
        ox, oy, oz, dx, dy, dz = round_ray(R, ox, oy, oz, dx, dy, dz)
        t, prim, b1, b2 = hit(R, ox, oy, oz, dx, dy, dz, t0, t1)
        if prim < 0:
            return tr, tg, tb
        shape = prim_shape[prim]
        mat = shape_material[shape]
        eta = seta[mat]
        if eta <= 0.0:
            return 0.0, 0.0, 0.0
        px, py, pz = refine(R, prim, b1, b2, ox + t * dx, oy + t * dy, oz + t * dz)
        gx, gy, gz, sx, sy, sz = surface(prim, b1, b2, px, py, pz, ns, sph_center, sph_radius,
                                         tri_v, tri_n, tri_has_n, shape_flip[shape])
        F, cos_t, _eit, _eti = fresnel_dielectric(-(sx * dx + sy * dy + sz * dz), eta)
        tr *= (1.0 - F) * strans[mat, 0]
        tg *= (1.0 - F) * strans[mat, 1]
        tb *= (1.0 - F) * strans[mat, 2]
        if tr <= 0.0 and tg <= 0.0 and tb <= 0.0:
            return 0.0, 0.0, 0.0
        side = 1.0 if gx * dx + gy * dy + gz * dz >= 0.0 else -1.0
        qx, qy, qz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
        t1 -= (qx - ox) * dx + (qy - oy) * dy + (qz - oz) * dz
        ox, oy, oz = qx, qy, qz
    return 0.0, 0.0, 0.0


class LocalModel(NamedTuple):
    """The local-illumination parameters (thesis 1.4.2) as one kernel argument."""

    ka: float                   # ambient coefficient k_a
    ambient: float              # ambient intensity I_a
    ks: float                   # specular coefficient k_s
    shininess: float            # Phong exponent n
    c1: float                   # f_att = 1 / (c1 + c2 d + c3 d²)
    c2: float
    c3: float
    fclamp: bool                # clamp f_att to 1
    shadows: bool               # cast shadow rays
    light_samples: int          # samples per area emitter / environment
    shadow_eta: np.ndarray      # (M,) transmissive shadows: a smooth dielectric's int_ior/ext_ior,
                                # 0 for an opaque material; empty (0,): shadow rays stop at anything
    shadow_trans: np.ndarray    # (M, 3) its specular_transmittance
    sobol: bool                 # light samples from Owen-scrambled Sobol points (light_uv_sobol)
    dims: int                   # otherwise: DIM_INDEPENDENT, hashed numbers (light_uv); another
                                # mode of impl.samplers: a point's light sample j is 2-D
                                # dimension SP_DDIM + j of its pixel sample of SP_DSPP
                                # (light_uv_dims; distributed's numbers)


def local_model(params: dict, materials=None) -> LocalModel:
    """The :class:`LocalModel` of an algorithm's parsed parameters.  With
    ``params["shadow_mode"] == "transmissive"``, ``materials`` (the scene's
    :class:`impl.materials.MaterialArrays`) gives the dielectrics shadow rays pass."""
    eta, trans = np.zeros(0), np.zeros((0, 3))
    if params.get("shadow_mode", "opaque") == "transmissive":
        from .materials import MAT_DIELECTRIC
        dielectric = materials.kind == MAT_DIELECTRIC
        eta = np.where(dielectric, materials.diel_eta, 0.0).astype(np.float64)
        trans = np.ascontiguousarray(materials.spec_trans, dtype=np.float64)
    return LocalModel(float(params["ka"]), float(params["ambient"]), float(params["ks"]),
                      float(params["shininess"]), float(params["c1"]), float(params["c2"]),
                      float(params["c3"]), bool(params["fatt_clamp"]), bool(params["shadows"]),
                      int(params["light_samples"]), eta, trans, params.get("sampler") == "sobol",
                      DIM_INDEPENDENT)


#: Rows of a batch of shading points (:func:`direct_batch`): the point p, its geometric
#: normal g (to the side it is lit from), the normal n the BSDF is evaluated about, the
#: direction v to the viewer, the diffuse reflectance ρ, and for a point under a normal
#: or bump map the unperturbed shading normal s and the map's code (:func:`mapped_normal`);
#: with ``LocalModel.dims`` the pixel sample count and first light dimension of the point's
#: light samples (:func:`light_uv_dims`; exact integers in float64).
SP_P, SP_G, SP_S, SP_V, SP_RHO, SP_N0, SP_MAP, SP_DSPP, SP_DDIM = 0, 3, 6, 9, 12, 15, 18, 19, 20
assert SP_DDIM + 1 == POINT_ROWS

#: ``SP_MAP`` codes: no map (n = s); a map (light leaks cut); a map with Mitsuba's
#: shadowing function (Estevez et al.'s term as well).
MAP_NONE, MAP_PLAIN, MAP_SHADOWED = 0.0, 1.0, 2.0


@njit(inline="always", cache=True)
def mapped_normal(A: SceneArrays, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, back):
    """``(n, code)``: the normal a BSDF of material ``mat`` is evaluated about at a hit of
    primitive ``prim`` (barycentrics b1, b2; g, s its unit geometric and shading normals on
    the front side, v the unit direction to the viewer; ``back``: a two-sided material seen
    from behind), and its ``SP_MAP`` code.  Under a ``normalmap`` or ``bumpmap`` on a
    triangle, n is the perturbed normal n_p of :func:`impl.shading_frame.perturbed_normal`
    (on the back side as there); elsewhere s, or −s on the back.  Spheres carry no uv and
    keep s, as in ``path``."""
    return mapped_normal_at(A, A.tri_v, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, back)


@njit(inline="always", cache=True)
def mapped_normal_at(A: SceneArrays, tri_v, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz,
                     back):
    """:func:`mapped_normal` with the triangles' vertices ``tri_v`` (T, 3, 3) in place of
    the scene's own (a moving mesh's at the sample's time)."""
    shade = A.mat_shade[mat]
    ns = A.sph_radius.shape[0]
    if shade == 0 or prim < ns:
        if back:
            return -sx, -sy, -sz, MAP_NONE
        return sx, sy, sz, MAP_NONE
    nx, ny, nz = _perturbed_normal(shade, A.mat_shade_scale[mat], A.mat_shade_tex[mat],
                                   A.mat_shade_uv[mat], A.tex_data, tri_v[prim - ns],
                                   A.tri_uv[prim - ns], b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz,
                                   back)
    return nx, ny, nz, MAP_SHADOWED if A.mat_shade_tex[mat, 6] != 0 else MAP_PLAIN


@njit(cache=True)
def _perturbed_normal(code, scale, tex, uvm, data, v, uv, b1, b2, gx, gy, gz, sx, sy, sz, wx, wy, wz,
                      back):
    """:func:`impl.shading_frame.perturbed_normal` compiled once and called, not inlined
    into every specialisation of the shading kernels: its texture lookups are a large
    piece of code that only points under a map run."""
    return perturbed_normal(code, scale, tex, uvm, data, v, uv, b1, b2, gx, gy, gz, sx, sy, sz, wx, wy,
                            wz, back)


@njit(inline="always", cache=True)
def map_weight(nx, ny, nz, sx, sy, sz, code, wx, wy, wz):
    """The factor a normal or bump map (Mitsuba's adapters) puts on light scattered into
    the unit direction w at a point of perturbed normal n and unperturbed shading normal s
    (``code`` as ``SP_MAP``): 1 without a map; 0 where w lies on opposite sides of s and n
    (:func:`impl.shading_frame.same_side`: the adapters' cut against light leaking); with
    the shadowing function Estevez et al.'s term
    (:func:`impl.shading_frame.shadow_terminator`); else 1.  The nested BSDF's own tests
    of w against n are the caller's (the Phong bracket about n)."""
    if code == MAP_NONE:
        return 1.0
    return _mapped_weight(nx, ny, nz, sx, sy, sz, code, wx, wy, wz)


@njit(cache=True)
def _mapped_weight(nx, ny, nz, sx, sy, sz, code, wx, wy, wz):
    """:func:`map_weight` under a map, compiled once and called rather than inlined at
    every light sample's site (only points under a map run it)."""
    if not same_side(nx, ny, nz, sx, sy, sz, wx, wy, wz):
        return 0.0
    if code == MAP_SHADOWED:
        return shadow_terminator(nx, ny, nz, sx, sy, sz, wx, wy, wz)
    return 1.0


@njit(inline="always", cache=True)
def point_map_weight(P, i, wx, wy, wz):
    """:func:`map_weight` of shading point i of the point rows ``P`` (``SP_*``)."""
    return map_weight(P[SP_S, i], P[SP_S + 1, i], P[SP_S + 2, i], P[SP_N0, i], P[SP_N0 + 1, i],
                      P[SP_N0 + 2, i], P[SP_MAP, i], wx, wy, wz)


@njit(inline="always", cache=True)
def store_point(P, i, px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz, rho_r, rho_g, rho_b, sx, sy, sz,
                code):
    """Write shading point i into the point rows ``P`` (``SP_*``); s only under a map (the
    readers of ``SP_N0`` look at ``SP_MAP`` first)."""
    P[SP_P, i], P[SP_P + 1, i], P[SP_P + 2, i] = px, py, pz
    P[SP_G, i], P[SP_G + 1, i], P[SP_G + 2, i] = gx, gy, gz
    P[SP_S, i], P[SP_S + 1, i], P[SP_S + 2, i] = nx, ny, nz
    P[SP_V, i], P[SP_V + 1, i], P[SP_V + 2, i] = vx, vy, vz
    P[SP_RHO, i], P[SP_RHO + 1, i], P[SP_RHO + 2, i] = rho_r, rho_g, rho_b
    P[SP_MAP, i] = code
    if code != MAP_NONE:
        P[SP_N0, i], P[SP_N0 + 1, i], P[SP_N0 + 2, i] = sx, sy, sz


@batch_kernel
def direct_batch(A: SceneArrays, R: RayConfig, M: LocalModel, T, sample, seed, nshadow):
    """:func:`direct_light_rays` over a batch of shading points (an
    :class:`impl.tracer.Batch` ``T``), light sample by light sample: each sample's
    shadow rays (of the points where it has one) are traced together by
    :func:`impl.tracer.occluded_batch`.  Without ``M.sobol``: the same samples, in the
    same order, and the same light as :func:`direct_light_rays` at every point.

    Reads the points ``T.pts`` (rows ``SP_*``) where ``T.active``,
    point i's random numbers those of pixel ``T.pixel[i]`` and pixel sample
    ``sample[i]`` (hashed and stratified within the pixel sample, :func:`light_uv`; with
    ``M.sobol`` Sobol points over the pixel's samples, :func:`light_uv_sobol`; with
    ``M.dims`` the point's own dimensions, :func:`_point_uv`); adds
    their light to ``T.L`` and their shadow rays to ``nshadow`` (n,).  The Phong bracket
    is taken about the row ``SP_S``; at a point under a normal or bump map every light
    sample is also weighted by :func:`map_weight`.

    A point, directional or untextured spot light without a specular term and with
    opaque shadows is computed a point per vector lane (:func:`_delta_light_lanes`); the
    other lights, the area emitters and the environment point by point.
    """
    P, L, active, pixel, luv = T.pts, T.L, T.active, T.pixel, T.luv
    sh, sh_w, sh_i = T.sh, T.sh_w, T.sh_i
    ks, shininess, c1, c2, c3, fclamp = M.ks, M.shininess, M.c1, M.c2, M.c3, M.fclamp
    shadows, light_samples, sobol = M.shadows, M.light_samples, M.sobol
    seta, strans = M.shadow_eta, M.shadow_trans
    local = A.light_local
    for li in range(A.light_kind.shape[0]):
        kind = A.light_kind[li]
        if kind != LIGHT_PROJECTOR and not (kind == LIGHT_SPOT and A.light_tex[li, 1] > 0) \
                and ks == 0.0 and seta.shape[0] == 0:
            _delta_light_lanes(A, R, M, T, li, nshadow)
            continue
        lpx, lpy, lpz = A.light_pos[li, 0], A.light_pos[li, 1], A.light_pos[li, 2]
        ldx, ldy, ldz = A.light_dir[li, 0], A.light_dir[li, 1], A.light_dir[li, 2]
        rr, rg, rb = A.light_rad[li, 0], A.light_rad[li, 1], A.light_rad[li, 2]
        cc, cb_, cut, itw = (A.light_cos_cutoff[li], A.light_cos_beam[li], A.light_cutoff[li],
                             A.light_inv_tw[li])
        m = 0
        for i in range(T.n):
            if not active[i]:
                continue
            ok, lx, ly, lz, w, kd, spec = delta_sample(
                kind, lpx, lpy, lpz, ldx, ldy, ldz, local, li, cc, cb_, cut, itw, P[0, i], P[1, i],
                P[2, i], P[6, i], P[7, i], P[8, i], P[9, i], P[10, i], P[11, i], ks, shininess, c1,
                c2, c3, fclamp)
            if not ok:
                continue
            tr, tg, tb = delta_filter(A, li, kind, P[0, i], P[1, i], P[2, i], lx, ly, lz)
            f = point_map_weight(P, i, lx, ly, lz)
            if (tr == 0.0 and tg == 0.0 and tb == 0.0) or f == 0.0:
                continue
            cr = w * tr * rr * (kd * P[12, i] + spec) * f
            cg = w * tg * rg * (kd * P[13, i] + spec) * f
            cb = w * tb * rb * (kd * P[14, i] + spec) * f
            if not shadows:
                L[0, i] += cr
                L[1, i] += cg
                L[2, i] += cb
                continue
            if kind == LIGHT_DIRECTIONAL:
                ray = shadow_along(R, P[0, i], P[1, i], P[2, i], P[3, i], P[4, i], P[5, i], lx, ly, lz)
            else:
                ray = shadow_towards(R, P[0, i], P[1, i], P[2, i], P[3, i], P[4, i], P[5, i], lx,
                                     ly, lz, lpx, lpy, lpz, R.shrink_point)
            m = _queue_shadow(sh, sh_w, sh_i, m, i, ray, cr, cg, cb)
        _light_unoccluded(R, T, m, nshadow, A, seta, strans)
    if light_samples <= 0:
        return
    q = int(math.sqrt(light_samples) + 0.5)
    stratified = q * q == light_samples
    n_em = A.em_area.shape[0]
    lanes = n_em > 0 and ks == 0.0 and seta.shape[0] == 0
    if lanes:                            # lanes leave map weights to the point-by-point loop
        for i in range(T.n):
            if active[i] and P[SP_MAP, i] != MAP_NONE:
                lanes = False
                break
    for e in range(n_em):
        esh = A.em_shape[e]
        flip = A.shape_flip[esh]
        scale = A.em_area[e] / light_samples
        er, eg, eb = A.shape_emit[esh, 0], A.shape_emit[esh, 1], A.shape_emit[esh, 2]
        for k in range(light_samples):
            if sobol:
                light_uv_sobol_lanes(seed, pixel[:T.n], sample[:T.n], e, k, light_samples,
                                     luv[0, :T.n], luv[1, :T.n])
            if lanes:
                _area_light_lanes(A, R, M, T, e, k, q, stratified, flip, scale, er, eg, eb, sample, seed,
                                  nshadow)
                continue
            m = 0
            for i in range(T.n):
                if not active[i]:
                    continue
                u1, u2 = _point_uv(M, T, i, sample, seed, e * light_samples + k, k, q, stratified)
                ok, lx, ly, lz, yx, yy, yz, cr, cg, cb = area_sample(
                    A, e, u1, u2, flip, scale, er, eg, eb, P[0, i], P[1, i], P[2, i], P[6, i],
                    P[7, i], P[8, i], P[9, i], P[10, i], P[11, i], P[12, i], P[13, i], P[14, i], ks,
                    shininess, c1, c2, c3, fclamp)
                f = point_map_weight(P, i, lx, ly, lz) if ok else 0.0
                if f == 0.0:
                    continue
                cr, cg, cb = cr * f, cg * f, cb * f
                if not shadows:
                    L[0, i] += cr
                    L[1, i] += cg
                    L[2, i] += cb
                    continue
                ray = shadow_towards(R, P[0, i], P[1, i], P[2, i], P[3, i], P[4, i], P[5, i], lx,
                                     ly, lz, yx, yy, yz, R.shrink_area)
                m = _queue_shadow(sh, sh_w, sh_i, m, i, ray, cr, cg, cb)
            _light_unoccluded(R, T, m, nshadow, A, seta, strans)
    if A.env_radiance.shape[0] + A.env_image.shape[0] > 0:
        er = eg = eb = 0.0
        if A.env_radiance.shape[0] > 0:
            er, eg, eb = A.env_radiance[0, 0], A.env_radiance[0, 1], A.env_radiance[0, 2]
        img, frame, epdf, ecdf = A.env_image, A.env_frame, A.env_pdf, A.env_cdf
        for k in range(light_samples):
            if sobol:
                light_uv_sobol_lanes(seed, pixel[:T.n], sample[:T.n], n_em, k, light_samples,
                                     luv[0, :T.n], luv[1, :T.n])
            m = 0
            for i in range(T.n):
                if not active[i]:
                    continue
                u1, u2 = _point_uv(M, T, i, sample, seed, n_em * light_samples + k, k, q, stratified)
                ok, lx, ly, lz, cr, cg, cb = environment_sample(
                    u1, u2, er, eg, eb, img, frame, epdf, ecdf, light_samples, P[6, i], P[7, i], P[8, i], P[9, i],
                    P[10, i], P[11, i], P[12, i], P[13, i], P[14, i], ks, shininess)
                f = point_map_weight(P, i, lx, ly, lz) if ok else 0.0
                if f == 0.0:
                    continue
                cr, cg, cb = cr * f, cg * f, cb * f
                if not shadows:
                    L[0, i] += cr
                    L[1, i] += cg
                    L[2, i] += cb
                    continue
                ray = shadow_along(R, P[0, i], P[1, i], P[2, i], P[3, i], P[4, i], P[5, i], lx, ly, lz)
                m = _queue_shadow(sh, sh_w, sh_i, m, i, ray, cr, cg, cb)
            _light_unoccluded(R, T, m, nshadow, A, seta, strans)


@njit(inline="always", cache=True)
def _point_uv(M: LocalModel, T, i, sample, seed, j, k, q, stratified):
    """The two numbers of light sample ``j`` (sample ``k`` of its light) at shading point i
    of batch ``T``, pixel sample ``sample[i]``: with ``M.sobol`` those
    :func:`light_uv_sobol_lanes` left in ``T.luv``; with ``M.dims`` dimension
    ``SP_DDIM + j`` of the point's ``SP_DSPP`` samples (:func:`light_uv_dims`); else the
    hashed :func:`light_uv`."""
    if M.sobol:
        return T.luv[0, i], T.luv[1, i]
    if M.dims != DIM_INDEPENDENT:
        P = T.pts
        return dim_2d(M.dims, seed, T.pixel[i], sample[i], np.int64(P[SP_DSPP, i]),
                      np.int64(P[SP_DDIM, i]) + j)
    return light_uv(seed, T.pixel[i], sample[i], j, k, q, stratified)


#: A point's state for one delta light in :func:`_delta_light_lanes` (``Batch.sh_i``): no
#: light, lit (pending its shadow ray), or in a spot's transition band (its profile,
#: :func:`cone_edge`, left to a loop over those points: its ``acos`` does not vectorise).
_DARK, _LIT, _BAND = 0, 1, 2


@njit(inline="always", cache=True)
def _delta_light_lanes(A: SceneArrays, R: RayConfig, M: LocalModel, T, li, nshadow):
    """Delta light ``li`` (point, directional or untextured spot; no specular term, opaque
    shadows) at every active point of batch ``T``, a point per lane: the light sample, its
    contribution and its shadow ray computed by the branch-free :func:`_delta_lanes` into
    ``T.sh`` / ``T.sh_w`` (column i for point i; ``T.sh_i`` the state), then one
    :func:`impl.tracer.occluded_batch` over the lanes.  Lanes without light are given a lit
    lane's ray when queries are brute force (:func:`impl.tracer.brute_force`: a lane costs a
    few vector operations per candidate, and a copy keeps the culling bound), else the lit
    lanes are moved to the front.  The same samples, contributions and shadow rays as the
    scalar loop of :func:`direct_batch`, so the same image bit for bit."""
    n = T.n
    sh, w, flag, P, L = T.sh, T.sh_w, T.sh_i, T.pts, T.L
    kind = A.light_kind[li]
    loc = A.light_local[li]
    _delta_lanes(kind == LIGHT_DIRECTIONAL, kind == LIGHT_SPOT, A.light_pos[li, 0], A.light_pos[li, 1],
                 A.light_pos[li, 2], A.light_dir[li, 0], A.light_dir[li, 1], A.light_dir[li, 2],
                 loc[0, 0], loc[0, 1], loc[0, 2], loc[1, 0], loc[1, 1], loc[1, 2], loc[2, 0], loc[2, 1],
                 loc[2, 2], A.light_cos_cutoff[li], A.light_cos_beam[li], M.c1, M.c2, M.c3, M.fclamp,
                 A.light_rad[li, 0], A.light_rad[li, 1], A.light_rad[li, 2], R.strategy, R.eps,
                 R.shrink_point, R.sph_radius, T.active[:n], P[0, :n], P[1, :n], P[2, :n], P[3, :n],
                 P[4, :n], P[5, :n], P[6, :n], P[7, :n], P[8, :n], P[9, :n], P[10, :n], P[11, :n],
                 P[12, :n], P[13, :n], P[14, :n], sh[0, :n], sh[1, :n], sh[2, :n], sh[3, :n], sh[4, :n],
                 sh[5, :n], sh[6, :n], sh[7, :n], w[0, :n], w[1, :n], w[2, :n], flag[:n])
    lit, first, fix = _lit_lanes(flag[:n], P[SP_MAP, :n])
    if fix == 0:                         # no cone edge, no map: the lanes are final
        _trace_lit_lanes(A, R, M, T, lit, first, nshadow)
        return
    lit, first = 0, -1
    for i in range(n):
        if flag[i] == _BAND:             # the spot's cone edge: (attenuation, kd, cos θ) in w
            f = cone_edge(w[2, i], A.light_cutoff[li], A.light_inv_tw[li])
            flag[i] = _LIT if f != 0.0 else _DARK
            wt, kd = w[0, i] * f, w[1, i]
            w[0, i] = wt * A.light_rad[li, 0] * (kd * P[12, i])
            w[1, i] = wt * A.light_rad[li, 1] * (kd * P[13, i])
            w[2, i] = wt * A.light_rad[li, 2] * (kd * P[14, i])
        if flag[i] == _LIT and P[SP_MAP, i] != MAP_NONE:       # under a normal or bump map
            if kind == LIGHT_DIRECTIONAL:
                lx, ly, lz = -A.light_dir[li, 0], -A.light_dir[li, 1], -A.light_dir[li, 2]
            else:
                lx, ly, lz, _d = _towards(P[0, i], P[1, i], P[2, i], A.light_pos[li, 0],
                                          A.light_pos[li, 1], A.light_pos[li, 2])
            f = point_map_weight(P, i, lx, ly, lz)
            flag[i] = _LIT if f != 0.0 else _DARK
            w[0, i], w[1, i], w[2, i] = w[0, i] * f, w[1, i] * f, w[2, i] * f
        if flag[i] == _LIT:
            lit += 1
            first = i if first < 0 else first
    _trace_lit_lanes(A, R, M, T, lit, first, nshadow)


@batch_kernel(error_model="numpy")
def _lit_lanes(flag, code):
    """``(lit, first, fix)`` of a delta light's lanes (states ``flag``, the points' map codes
    ``code``): how many are ``_LIT``, the first of them (−1: none), and how many need the
    point-by-point step after :func:`_delta_lanes` (a ``_BAND`` lane, or a ``_LIT`` one
    under a normal or bump map).  Reductions without a branch: LLVM vectorises them."""
    n = flag.shape[0]
    lit = fix = 0
    first = n
    for i in range(n):
        f = flag[i]
        on = f == _LIT
        lit += on
        first = min(first, i if on else n)
        fix += (f == _BAND) | (on & (code[i] != MAP_NONE))
    return lit, (first if first < n else -1), fix


@njit(inline="always", cache=True)
def _trace_lit_lanes(A: SceneArrays, R: RayConfig, M: LocalModel, T, lit, first, nshadow):
    """Finish a light sample computed a point per lane (``T.sh_i`` the lanes' states,
    ``lit`` of them ``_LIT``, the first at ``first``; their shadow rays in ``T.sh``, their
    light in ``T.sh_w``): trace the lit lanes' shadow rays together and add the light of
    the unoccluded ones to ``T.L``.  Lanes without light are given a lit lane's ray when
    queries are brute force (:func:`impl.tracer.brute_force`: a lane costs a few vector
    operations per candidate, and a copy keeps the culling bound), else the lit lanes are
    moved to the front."""
    n = T.n
    sh, w, flag, L = T.sh, T.sh_w, T.sh_i, T.L
    if lit == 0:
        return
    if not M.shadows:
        _add_lit(flag[:n], T.blocked[:n], False, w[0, :n], w[1, :n], w[2, :n], L[0, :n], L[1, :n],
                 L[2, :n])
        return
    if brute_force(R):
        _copy_lane(flag[:n], first, sh[0, :n], sh[1, :n], sh[2, :n], sh[3, :n], sh[4, :n], sh[5, :n],
                   sh[6, :n], sh[7, :n])
        occluded_batch(R, sh, np.int64(n), T.blocked, T.q, T.cull)
        for i in range(n):
            nshadow[i] += flag[i] == _LIT
        _add_lit(flag[:n], T.blocked[:n], True, w[0, :n], w[1, :n], w[2, :n], L[0, :n], L[1, :n],
                 L[2, :n])
        return
    m = 0
    for i in range(n):                   # lit lanes to the front (m <= i: in place)
        if flag[i] == _LIT:
            for c in range(8):
                sh[c, m] = sh[c, i]
            w[0, m], w[1, m], w[2, m] = w[0, i], w[1, i], w[2, i]
            flag[m] = i
            m += 1
    _light_unoccluded(R, T, m, nshadow, A, M.shadow_eta, M.shadow_trans)


@njit(inline="always", cache=True)
def _area_light_lanes(A: SceneArrays, R: RayConfig, M: LocalModel, T, e, k, q, stratified, flip, scale,
                      er, eg, eb, sample, seed, nshadow):
    """Light sample k of area emitter ``e`` (no specular term, opaque shadows, no normal or
    bump map) at every active point of batch ``T``, a point per lane: each point's two
    numbers (:func:`_point_uv`), the emitter triangle they pick and the point on it
    (:func:`sample_emitter`'s search and arithmetic) point by point, then the contribution
    and the shadow ray by the branch-free :func:`_area_lanes`, and :func:`_trace_lit_lanes`.  The
    same samples, contributions and shadow rays as the scalar loop of :func:`direct_batch`,
    so the same image bit for bit."""
    n = T.n
    P, flag, sh, w = T.pts, T.sh_i, T.sh, T.sh_w
    lo, hi = A.em_offset[e], A.em_offset[e + 1] - 1
    cdf = A.em_cdf
    j = e * M.light_samples + k
    for i in range(n):
        if not T.active[i]:
            flag[i] = -1
            continue
        u1, u2 = _point_uv(M, T, i, sample, seed, j, k, q, stratified)
        a, b = lo, hi                    # sample_emitter's search and remainder
        while a < b:
            mid = (a + b) // 2
            if cdf[mid] < u1:
                a = mid + 1
            else:
                b = mid
        prev = cdf[a - 1] if a > lo else 0.0
        width = cdf[a] - prev
        u1 = min(max((u1 - prev) / width, 0.0), 1.0) if width > 0.0 else 0.5
        tri = A.em_tri[a]
        v = A.tri_v[tri]                 # sample_emitter's point on the triangle
        su = math.sqrt(u1)
        w1, w2 = u2 * su, 1.0 - su
        w0 = 1.0 - w1 - w2
        sh[3, i] = w2 * v[0, 0] + w0 * v[1, 0] + w1 * v[2, 0]
        sh[4, i] = w2 * v[0, 1] + w0 * v[1, 1] + w1 * v[2, 1]
        sh[5, i] = w2 * v[0, 2] + w0 * v[1, 2] + w1 * v[2, 2]
        w[0, i], w[1, i], w[2, i] = A.tri_ng[tri, 0], A.tri_ng[tri, 1], A.tri_ng[tri, 2]
        flag[i] = 0
    _area_lanes(flip, scale, er, eg, eb, M.c1, M.c2, M.c3, M.fclamp, R.strategy, R.eps, R.shrink_area,
                R.sph_radius, P[0, :n], P[1, :n], P[2, :n], P[3, :n], P[4, :n], P[5, :n], P[6, :n],
                P[7, :n], P[8, :n], P[9, :n], P[10, :n], P[11, :n], P[12, :n], P[13, :n], P[14, :n],
                sh[0, :n], sh[1, :n], sh[2, :n], sh[3, :n], sh[4, :n], sh[5, :n], sh[6, :n], sh[7, :n],
                w[0, :n], w[1, :n], w[2, :n], flag[:n])
    lit, first = 0, -1
    for i in range(n):
        if flag[i] == _LIT:
            lit += 1
            first = i if first < 0 else first
    _trace_lit_lanes(A, R, M, T, lit, first, nshadow)


@njit(inline="always", cache=True)
def _lane_diffuse(sx, sy, sz, vx, vy, vz, lx, ly, lz):
    """:func:`phong_brdf_cos`'s bracket with k_s = 0 at a lane: cos θ_l and cos θ_v about
    the shading normal s, and k_d's factor cos θ_l / π."""
    cos_l = sx * lx + sy * ly + sz * lz
    cos_v = sx * vx + sy * vy + sz * vz
    return cos_l, cos_v, cos_l * INV_PI


@njit(inline="always", cache=True)
def _lane_shadow_ray(strategy, g, eps, p_x, p_y, p_z, gx, gy, gz, lx, ly, lz, tx, ty, tz):
    """:func:`shadow_towards` at a lane, branch-free: the origin left from p on the side of
    l (geometric normal g), its ``tmin``, the unit direction from the origin to the target
    t and that distance (a zero direction and distance where the origin is t)."""
    o_x, o_y, o_z, t0 = leave_towards(strategy, g, eps, p_x, p_y, p_z, gx, gy, gz, lx, ly, lz)
    hx, hy, hz = tx - o_x, ty - o_y, tz - o_z
    hd = math.sqrt(hx * hx + hy * hy + hz * hz)
    away = hd != 0.0
    ih = 1.0 / hd
    return (o_x, o_y, o_z, t0, hx * ih if away else 0.0, hy * ih if away else 0.0,
            hz * ih if away else 0.0, hd if away else 0.0)


@batch_kernel(error_model="numpy", disjoint=True)
def _area_lanes(flip, scale, er, eg, eb, c1, c2, c3, fclamp, strategy, eps, shrink, g, px, py, pz, gx, gy,
                gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b, ox, oy, oz, dx, dy, dz, tmin, tmax, wr, wg,
                wb, flag):
    """An area emitter's light sample at every point i (a lane).  On entry ``dx``/``dy``/``dz``
    hold the point y the sample picked on the emitter, ``wr``/``wg``/``wb`` the unit normal
    of its triangle, and ``flag`` is 0 for a point to light, −1 otherwise (a lane reads
    its own column of these before it writes it, so the loop carries no dependence); on
    exit the contribution of :func:`area_sample` with k_s = 0 is in ``wr``/``wg``/``wb``,
    the shadow ray of :func:`shadow_towards` in ``ox``..``tmax`` and the state (``_DARK``,
    ``_LIT``) in ``flag`` — the same operations as those functions, selects for their
    branches, so LLVM vectorises the loop.  ``g`` is an array of the intersection
    precision.  (The point on the triangle is taken before: indexed loads of the
    triangle's vertices keep LLVM from vectorising.)"""
    sgn = -1.0 if flip else 1.0
    for i in range(px.shape[0]):
        live = flag[i] >= 0
        yx, yy, yz = dx[i], dy[i], dz[i]
        p_x, p_y, p_z = px[i], py[i], pz[i]
        lx, ly, lz = yx - p_x, yy - p_y, yz - p_z
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        lx, ly, lz = lx / dist, ly / dist, lz / dist
        cos_y = -(sgn * wr[i] * lx + sgn * wg[i] * ly + sgn * wb[i] * lz)
        cos_l, cos_v, kd = _lane_diffuse(sx[i], sy[i], sz[i], vx[i], vy[i], vz[i], lx, ly, lz)
        lit = live & (dist != 0.0) & (cos_y > 0.0) & (cos_l > 0.0) & (cos_v > 0.0) & (kd != 0.0)
        flag[i] = _LIT if lit else _DARK
        wt = cos_y * attenuation(dist, c1, c2, c3, fclamp) * scale
        wr[i] = wt * (kd * rho_r[i]) * er
        wg[i] = wt * (kd * rho_g[i]) * eg
        wb[i] = wt * (kd * rho_b[i]) * eb
        # the shadow ray leaves p on the side of l, aimed from its origin at y
        ox[i], oy[i], oz[i], tmin[i], dx[i], dy[i], dz[i], hd = _lane_shadow_ray(
            strategy, g, eps, p_x, p_y, p_z, gx[i], gy[i], gz[i], lx, ly, lz, yx, yy, yz)
        tmax[i] = hd * (1.0 - shrink)


@batch_kernel(error_model="numpy", disjoint=True)
def _delta_lanes(directional, spot, lpx, lpy, lpz, ldx, ldy, ldz, m00, m01, m02, m10, m11, m12, m20,
                 m21, m22, cos_cutoff, cos_beam, c1, c2, c3, fclamp, ir, ig, ib, strategy, eps, shrink, g,
                 active, px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                 ox, oy, oz, dx, dy, dz, tmin, tmax, wr, wg, wb, flag):
    """A delta light at every point i (a lane): :func:`delta_sample` with k_s = 0 (the
    Phong bracket's diffuse term), the contribution w I kd ρ into ``wr``/``wg``/``wb``, the
    shadow ray of :func:`shadow_towards` (:func:`shadow_along` for a directional light)
    into ``ox``..``tmax`` and the state (``_DARK``, ``_LIT``, ``_BAND``) into ``flag`` —
    the same operations as those functions, selects for their branches, so LLVM
    vectorises the loop.  A ``_BAND`` point's profile is not applied here: ``wr``, ``wg``,
    ``wb`` hold its attenuation, kd and cos θ, for :func:`cone_edge` and the contribution
    after it.  ``m`` is the spot's world-to-local map, ``g`` an array of the
    intersection precision (the origin's offset is computed in it, :func:`impl.rays.leave`).

    One loop per kind of light, its kind a constant in it: a select computes both of its
    sides, so a loop for every kind would take the spot's square root and division (its
    cos θ) at a point light's lanes, and the distance's at a directional light's."""
    def lane(directional, spot, i):
        p_x, p_y, p_z = px[i], py[i], pz[i]
        lx, ly, lz = lpx - p_x, lpy - p_y, lpz - p_z
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        inv = 1.0 / dist
        lx, ly, lz = lx * inv, ly * inv, lz * inv
        wt = attenuation(dist, c1, c2, c3, fclamp)
        lx = -ldx if directional else lx
        ly = -ldy if directional else ly
        lz = -ldz if directional else lz
        wt = 1.0 if directional else wt
        inside, band, cos_t = True, False, 1.0
        if spot:        # spot_falloff: in the cone (beyond its beam: the band, its profile left to cone_edge)
            ax = m00 * -lx + m01 * -ly + m02 * -lz
            ay = m10 * -lx + m11 * -ly + m12 * -lz
            az = m20 * -lx + m21 * -ly + m22 * -lz
            cos_t = az / math.sqrt(ax * ax + ay * ay + az * az)
            inside = cos_t > cos_cutoff
            band = inside & (cos_t < cos_beam)
        cos_l, cos_v, kd = _lane_diffuse(sx[i], sy[i], sz[i], vx[i], vy[i], vz[i], lx, ly, lz)
        lit = active[i] & inside & (cos_l > 0.0) & (cos_v > 0.0) & (kd != 0.0)
        flag[i] = (_BAND if band else _LIT) if lit else _DARK
        wr[i] = wt if band else wt * ir * (kd * rho_r[i])
        wg[i] = kd if band else wt * ig * (kd * rho_g[i])
        wb[i] = cos_t if band else wt * ib * (kd * rho_b[i])
        # the shadow ray leaves p on the side of l (along l for a directional light)
        ox[i], oy[i], oz[i], tmin[i], hx, hy, hz, hd = _lane_shadow_ray(
            strategy, g, eps, p_x, p_y, p_z, gx[i], gy[i], gz[i], lx, ly, lz, lpx, lpy, lpz)
        dx[i] = lx if directional else hx
        dy[i] = ly if directional else hy
        dz[i] = lz if directional else hz
        tmax[i] = math.inf if directional else hd * (1.0 - shrink)

    if spot:
        for i in range(px.shape[0]):
            lane(False, True, i)
    elif directional:
        for i in range(px.shape[0]):
            lane(True, False, i)
    else:
        for i in range(px.shape[0]):
            lane(False, False, i)


@batch_kernel(error_model="numpy", disjoint=True)
def _copy_lane(flag, k, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Give every lane not ``_LIT`` the ray of lane ``k`` (a lit one)."""
    a, b, c, d, e, f, t0, t1 = ox[k], oy[k], oz[k], dx[k], dy[k], dz[k], tmin[k], tmax[k]
    for i in range(flag.shape[0]):
        keep = flag[i] == _LIT
        ox[i] = ox[i] if keep else a
        oy[i] = oy[i] if keep else b
        oz[i] = oz[i] if keep else c
        dx[i] = dx[i] if keep else d
        dy[i] = dy[i] if keep else e
        dz[i] = dz[i] if keep else f
        tmin[i] = tmin[i] if keep else t0
        tmax[i] = tmax[i] if keep else t1


@batch_kernel(error_model="numpy", disjoint=True)
def _add_lit(flag, blocked, shadows, wr, wg, wb, Lr, Lg, Lb):
    """L += w at the ``_LIT`` lanes, with ``shadows`` only where ``blocked`` is false."""
    for i in range(flag.shape[0]):
        add = (flag[i] == _LIT) & (not (shadows & blocked[i]))
        Lr[i] = Lr[i] + wr[i] if add else Lr[i]
        Lg[i] = Lg[i] + wg[i] if add else Lg[i]
        Lb[i] = Lb[i] + wb[i] if add else Lb[i]


@njit(inline="always", cache=True)
def _queue_shadow(sh, sh_w, sh_i, m, i, ray, cr, cg, cb):
    """Put point i's shadow ray (origin, direction, t range) and the light it decides in
    column m of a batch's shadow queue (``Batch.sh``, ``sh_w``, ``sh_i``); the queue's
    new length."""
    sh[0, m], sh[1, m], sh[2, m], sh[3, m] = ray[0], ray[1], ray[2], ray[3]
    sh[4, m], sh[5, m], sh[6, m], sh[7, m] = ray[4], ray[5], ray[6], ray[7]
    sh_w[0, m], sh_w[1, m], sh_w[2, m] = cr, cg, cb
    sh_i[m] = i
    return m + 1


@njit(inline="always", cache=True)
def _light_unoccluded(R: RayConfig, T, m, nshadow, A: SceneArrays, seta, strans):
    """Trace the m queued shadow rays together; add the light of the unoccluded ones
    (and, with transmissive shadows, of the blocked ones × :func:`shadow_filter`)."""
    if m == 0:
        return
    occluded_batch(R, T.sh, np.int64(m), T.blocked, T.q, T.cull)     # not a literal 0: one compile
    for k in range(m):
        i = T.sh_i[k]
        nshadow[i] += 1
        if not T.blocked[k]:
            T.L[0, i] += T.sh_w[0, k]
            T.L[1, i] += T.sh_w[1, k]
            T.L[2, i] += T.sh_w[2, k]
    if seta.shape[0] == 0:
        return
    sh = T.sh
    prim_shape, shape_material, sph_center, sph_radius = (A.prim_shape, A.shape_material,
                                                          A.sph_center, A.sph_radius)
    tri_v, tri_n, tri_has_n, shape_flip = A.tri_v, A.tri_n, A.tri_has_n, A.shape_flip
    for k in range(m):
        if T.blocked[k]:
            i = T.sh_i[k]
            fr, fg, fb = shadow_filter(R, sh[0, k], sh[1, k], sh[2, k], sh[3, k], sh[4, k],
                                       sh[5, k], sh[6, k], sh[7, k], seta, strans, prim_shape,
                                       shape_material, sph_center, sph_radius, tri_v, tri_n,
                                       tri_has_n, shape_flip)
            T.L[0, i] += T.sh_w[0, k] * fr
            T.L[1, i] += T.sh_w[1, k] * fg
            T.L[2, i] += T.sh_w[2, k] * fb


@njit(inline="always", cache=True)
def sample_cosine_hemisphere(u1, u2, nx, ny, nz):
    """Cosine-weighted direction about the unit normal n (Malley: a uniform point on
    the unit disk lifted to the hemisphere): (x, y, z, cos θ); pdf = cos θ / π."""
    rad = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    a, c = rad * math.cos(phi), rad * math.sin(phi)
    cz = math.sqrt(max(0.0, 1.0 - u1))
    # Orthonormal basis (Duff et al. 2017).
    sign = 1.0 if nz >= 0.0 else -1.0
    p = -1.0 / (sign + nz)
    q = nx * ny * p
    tx, ty, tz = 1.0 + sign * nx * nx * p, sign * q, -sign * nx
    bx, by, bz = q, sign + ny * ny * p, -ny
    return (a * tx + c * bx + cz * nx, a * ty + c * by + cz * ny, a * tz + c * bz + cz * nz, cz)


@njit(inline="always", cache=True)
def environment_radiance(A: SceneArrays, dx, dy, dz):
    """Radiance seen by a ray leaving the scene along (dx, dy, dz): a ``constant``
    environment emitter's, uniform in direction, an ``envmap``'s (:mod:`impl.envmap`),
    or 0 without one."""
    if A.env_image.shape[0] > 0:
        return envmap_radiance(A.env_image, A.env_frame, dx, dy, dz)
    if A.env_radiance.shape[0] == 0:
        return 0.0, 0.0, 0.0
    return A.env_radiance[0, 0], A.env_radiance[0, 1], A.env_radiance[0, 2]


@njit(inline="always", cache=True)
def diffuse_albedo(A: SceneArrays, mat, prim, b1, b2):
    """Diffuse reflectance ρ (r, g, b) of material ``mat`` at a hit (primitive, barycentrics).

    A textured reflectance is looked up at (u', v') = to_uv · (u, v, 1), (u, v)
    interpolated from the triangle's vertex uvs (:mod:`impl.textures`:
    Mitsuba's ``checkerboard`` and ``bitmap``).  Primitives without texture
    coordinates get the material's mean colour (the loader refuses textures on
    such shapes).
    """
    ns = A.sph_radius.shape[0]
    code = A.mat_tex[mat]
    if code != 0 and prim >= ns and A.tri_has_uv[prim - ns]:
        t = A.tri_uv[prim - ns]
        b0 = 1.0 - b1 - b2
        u = b0 * t[0, 0] + b1 * t[1, 0] + b2 * t[2, 0]
        v = b0 * t[0, 1] + b1 * t[1, 1] + b2 * t[2, 1]
        m = A.mat_tex_uv[mat]
        uu = m[0, 0] * u + m[0, 1] * v + m[0, 2]
        vv = m[1, 0] * u + m[1, 1] * v + m[1, 2]
        if code == TEX_CHECKERBOARD:
            if checkerboard(uu, vv):
                return A.mat_tex_c0[mat, 0], A.mat_tex_c0[mat, 1], A.mat_tex_c0[mat, 2]
            return A.mat_tex_c1[mat, 0], A.mat_tex_c1[mat, 1], A.mat_tex_c1[mat, 2]
        if code == TEX_BITMAP:
            return bitmap(A.tex_data, A.mat_tex_offset[mat], A.mat_tex_size[mat, 0],
                          A.mat_tex_size[mat, 1], A.mat_tex_wrap[mat], A.mat_tex_filter[mat], uu, vv)
    return A.mat_rho[mat, 0], A.mat_rho[mat, 1], A.mat_rho[mat, 2]


@njit(inline="always", cache=True)
def specular_tint(A: SceneArrays, mat, prim, b1, b2):
    """The factor (r, g, b) a conductor's, rough conductor's or smooth dielectric's
    reflected light takes at a hit: its textured ``specular_reflectance`` there, which
    :func:`impl.materials.with_specular_textures` moved to the material's texture slot
    (Mitsuba multiplies the reflected light by the texture's ``eval``), else 1 — the
    constant ``specular_reflectance`` is the caller's per-material factor.  Such BSDFs
    have no diffuse texture of their own, so a texture code on them is always the moved
    one.  The lookup is a plain call (:func:`_albedo_at`): it runs only at textured
    materials, and one compiled copy serves every call site."""
    if A.mat_tex[mat] == 0:
        return 1.0, 1.0, 1.0
    return _albedo_at(A, mat, prim, b1, b2)


@njit(cache=True)
def _albedo_at(A: SceneArrays, mat, prim, b1, b2):
    """:func:`diffuse_albedo`, compiled once and called."""
    return diffuse_albedo(A, mat, prim, b1, b2)


@njit(cache=True)
def param_rgb(A: SceneArrays, mat, slot, prim, b1, b2):
    """RGB parameter texture ``slot`` (``PTEX_*`` of :mod:`impl.scene_arrays`) of
    material ``mat`` at a hit: a checkerboard's or bitmap's value at (u', v') = to_uv ·
    (u, v, 1), as :func:`diffuse_albedo` looks it up, or the slot's constant.  A
    primitive without uvs (the loader refuses textures on those) gets the texture's
    mean.  A plain call, not inlined: it runs only at textured materials, and one copy
    of the bitmap lookup serves every caller (inlined, each call site of the tracers
    would compile its own)."""
    code = A.mat_ptex[mat, slot, 0]
    c = A.mat_ptex_c[mat, slot]
    ns = A.sph_radius.shape[0]
    if code == 0:
        return c[0, 0], c[0, 1], c[0, 2]
    if prim < ns or not A.tri_has_uv[prim - ns]:
        if code == TEX_CHECKERBOARD:
            return 0.5 * (c[0, 0] + c[1, 0]), 0.5 * (c[0, 1] + c[1, 1]), 0.5 * (c[0, 2] + c[1, 2])
        return c[0, 0], c[0, 1], c[0, 2]
    t = A.tri_uv[prim - ns]
    b0 = 1.0 - b1 - b2
    u = b0 * t[0, 0] + b1 * t[1, 0] + b2 * t[2, 0]
    v = b0 * t[0, 1] + b1 * t[1, 1] + b2 * t[2, 1]
    m = A.mat_ptex_uv[mat, slot]
    uu = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    vv = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    if code == TEX_CHECKERBOARD:
        k = 0 if checkerboard(uu, vv) else 1
        return c[k, 0], c[k, 1], c[k, 2]
    r = A.mat_ptex[mat, slot]
    return bitmap(A.tex_data, r[1], r[2], r[3], r[4], r[5], uu, vv)


@njit(inline="always", cache=True)
def transmittance_tint(A: SceneArrays, mat, prim, b1, b2):
    """The factor (r, g, b) a dielectric's transmitted light takes at a hit: its textured
    ``specular_transmittance`` there (Mitsuba multiplies the transmitted light by the
    texture's ``eval``), else 1 — a constant one is the caller's per-material factor."""
    if A.mat_ptex[mat, PTEX_TRANSMITTANCE, 0] == 0:
        return 1.0, 1.0, 1.0
    return param_rgb(A, mat, PTEX_TRANSMITTANCE, prim, b1, b2)


@njit(inline="always", cache=True)
def textured_fresnel(A: SceneArrays, mat, prim, b1, b2, cos_i):
    """The conductor Fresnel reflectance (r, g, b) at cos_i of a conductor's or rough
    conductor's textured ``eta`` + i ``k`` at a hit (Mitsuba reads both textures there),
    else 1: such a material's own row holds 0 + 1i, whose Fresnel term is 1
    (:func:`impl.materials.material_arrays`), so the caller multiplies by this factor;
    for a rough conductor cos_i is taken to the microfacet normal, as Mitsuba's."""
    if A.mat_ptex[mat, PTEX_ETA, 0] == 0 and A.mat_ptex[mat, PTEX_K, 0] == 0:
        return 1.0, 1.0, 1.0
    return _fresnel_at(A, mat, prim, b1, b2, cos_i)


@njit(cache=True)
def _fresnel_at(A: SceneArrays, mat, prim, b1, b2, cos_i):
    """:func:`textured_fresnel` of a textured conductor, a plain call (as
    :func:`param_rgb`)."""
    er, eg, eb = param_rgb(A, mat, PTEX_ETA, prim, b1, b2)
    kr, kg, kb = param_rgb(A, mat, PTEX_K, prim, b1, b2)
    return fresnel_conductor(cos_i, er, kr), fresnel_conductor(cos_i, eg, kg), fresnel_conductor(cos_i, eb, kb)


@njit(inline="always", cache=True)
def textured_params(A: SceneArrays, mat):
    """Whether material ``mat`` reads a parameter texture other than its diffuse one at a
    hit (:func:`transmittance_tint`, :func:`textured_fresnel`)."""
    return (A.mat_ptex[mat, 0, 0] != 0) | (A.mat_ptex[mat, 1, 0] != 0) | (A.mat_ptex[mat, 2, 0] != 0)
