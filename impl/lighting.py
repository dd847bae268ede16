"""Direct illumination shared by the ray-casting and ray-tracing algorithms.

The numba helpers the local-illumination model needs at a visible point, used
by ``raycast`` (thesis 1.3.3, 1.4) and by ``whitted`` at the leaves of its ray
tree (thesis 2.2: the shadow rays of a hit point):

* :func:`surface` — geometric and shading normals of the kept hit;
* :func:`diffuse_albedo` — the diffuse reflectance ρ at the hit, from the
  material's colour or its texture (Mitsuba's ``checkerboard`` or ``bitmap``,
  :mod:`impl.textures`);
* :func:`environment_radiance` — what a ray that escapes the scene sees: the
  radiance of a ``constant`` environment emitter (0 without one), for the
  tracers' escaping rays;
* :func:`sample_emitter` — a uniform point on an area emitter, by area;
* :func:`direct_light_rays` — Phong-model light from every delta light and
  area emitter, each sample tested with a shadow ray cast with a ray
  configuration (:class:`impl.rays.RayConfig`: ray–sphere form, intersection
  precision, offset strategy); :func:`direct_light` is the same with the fixed
  rule of before (stable form, float64, origin moved SHADOW_EPSILON·(1 + max|p_i|)
  along the normal).  A ``constant`` environment emitter is sampled there too:
  ``light_samples`` cosine-weighted directions about the shading normal, each
  with a shadow ray to infinity; the estimator of the diffuse part is
  L_env ρ V(ω) per sample (f cos / pdf = (ρ/π) cos / (cos/π) = ρ), the Phong
  highlight adds L_env k_s (R·V)^n π / cos.

They take the flattened scene (:class:`impl.scene_arrays.SceneArrays`) and
return plain scalars, so a caller's pixel kernel stays free of allocation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .rays import RayConfig, legacy_config, leave, occluded
from .phong import attenuation, phong_brdf_cos
from .rng import uniform
from .scene_arrays import LIGHT_DIRECTIONAL, LIGHT_SPOT, TEX_BITMAP, TEX_CHECKERBOARD, SceneArrays
from .textures import bitmap, checkerboard

__all__ = ["SHADOW_EPSILON", "surface", "diffuse_albedo", "sample_emitter", "direct_light",
           "direct_light_rays", "environment_radiance", "sample_cosine_hemisphere"]

#: Shadow-ray origins move off the surface by this much times (1 + |p|_max).
SHADOW_EPSILON = 1e-7


@njit(inline="always", cache=True)
def surface(prim, b1, b2, px, py, pz, ns, sph_center, sph_radius, tri_v, tri_n, tri_has_n, flip):
    """Geometric and shading normals of a hit (the costly part, only for the kept hit)."""
    if prim < ns:
        r = sph_radius[prim]
        gx = (px - sph_center[prim, 0]) / r
        gy = (py - sph_center[prim, 1]) / r
        gz = (pz - sph_center[prim, 2]) / r
        sx, sy, sz = gx, gy, gz
    else:
        j = prim - ns
        v = tri_v[j]
        e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
        e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
        gx, gy, gz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
        gx, gy, gz = gx * inv, gy * inv, gz * inv
        if tri_has_n[j]:
            b0 = 1.0 - b1 - b2
            n = tri_n[j]
            sx = b0 * n[0, 0] + b1 * n[1, 0] + b2 * n[2, 0]
            sy = b0 * n[0, 1] + b1 * n[1, 1] + b2 * n[2, 1]
            sz = b0 * n[0, 2] + b1 * n[1, 2] + b2 * n[2, 2]
            inv = 1.0 / math.sqrt(sx * sx + sy * sy + sz * sz)
            sx, sy, sz = sx * inv, sy * inv, sz * inv
        else:
            sx, sy, sz = gx, gy, gz
    if flip:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    return gx, gy, gz, sx, sy, sz


@njit(cache=True)
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
def _blocked_towards(R, px, py, pz, gx, gy, gz, lx, ly, lz, yx, yy, yz, shrink):
    """Shadow ray from the surface point p (geometric normal g) to the point y, seen along
    the unit direction l: it leaves p on the side of l and is aimed from its offset origin."""
    side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
    ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
    hx, hy, hz, hd = _towards(ox, oy, oz, yx, yy, yz)
    return occluded(R, ox, oy, oz, hx, hy, hz, t0, hd * (1.0 - shrink))


@njit(inline="always", cache=True)
def _towards(ox, oy, oz, yx, yy, yz):
    """Unit direction from o to y and the distance |y − o| (direction 0 when y = o)."""
    hx, hy, hz = yx - ox, yy - oy, yz - oz
    hd = math.sqrt(hx * hx + hy * hy + hz * hz)
    if hd == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    return hx / hd, hy / hd, hz / hd, hd


@njit(cache=True)
def local_shading(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, shape, prim, b1, b2, A: SceneArrays,
                  R: RayConfig, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                  seed, pixel, sample):
    """Local illumination leaving a surface point towards the unit direction v (thesis 1.4.2):
    emitted L_e (front side only) + ambient I_a k_a ρ + the Phong direct light of every
    light; (r, g, b, shadow rays).  A one-sided point seen from behind gets nothing;
    a two-sided one is shaded on the side it is seen from."""
    r = g = b = 0.0
    cos_v = sx * vx + sy * vy + sz * vz
    if cos_v > 0.0:                     # emitted radiance L_e, front side only
        r += A.shape_emit[shape, 0]
        g += A.shape_emit[shape, 1]
        b += A.shape_emit[shape, 2]
    mat = A.shape_material[shape]
    if A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
        cos_v = -cos_v
    if cos_v <= 0.0:
        return r, g, b, 0
    rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
    amb = ambient * ka
    dr_, dg_, db_, nsh = direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz,
                                           rho_r, rho_g, rho_b, A, ks, shininess, c1, c2, c3,
                                           fclamp, shadows, light_samples, seed, pixel, sample, R)
    return r + amb * rho_r + dr_, g + amb * rho_g + dg_, b + amb * rho_b + db_, nsh


@njit(cache=True)
def direct_light(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
            A: SceneArrays, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
            seed, pixel, sample):
    """Phong-model direct light from every light at one point: (r, g, b, shadow rays).

    Shadow rays by the rule of before issue 3 (:func:`impl.rays.legacy_config`).
    """
    return direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                             A, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                             seed, pixel, sample, legacy_config(A, SHADOW_EPSILON))


@njit(cache=True)
def direct_light_rays(px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b,
                      A: SceneArrays, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                      seed, pixel, sample, R: RayConfig):
    """:func:`direct_light` with shadow rays cast by the ray configuration ``R``.

    A shadow ray leaves p on the side of the geometric normal that faces the
    light (:func:`impl.rays.leave`) and is aimed from its *offset origin* o at
    the light point y, ending at |y − o|·(1 − shrink).  (Aiming it along the
    direction from p, as the rule before did, shifts the segment sideways by
    the offset: where it meets an area emitter at a grazing angle it then hits
    the emitter itself before t_max — measured on ``mirror_sphere``, ~100
    pixels of ground wrongly in shadow with the 1e-7·(1 + max|p_i|) offset.)
    """
    r = g = b = 0.0
    nshadow = 0
    ns = A.sph_radius.shape[0]
    # Delta lights: point, spot, directional (thesis 1.4.1).
    for li in range(A.light_kind.shape[0]):
        kind = A.light_kind[li]
        if kind == LIGHT_DIRECTIONAL:
            lx, ly, lz = -A.light_dir[li, 0], -A.light_dir[li, 1], -A.light_dir[li, 2]
            dist = np.inf
            fatt = 1.0
            falloff = 1.0
        else:
            lx = A.light_pos[li, 0] - px
            ly = A.light_pos[li, 1] - py
            lz = A.light_pos[li, 2] - pz
            dist = math.sqrt(lx * lx + ly * ly + lz * lz)
            lx, ly, lz = lx / dist, ly / dist, lz / dist
            fatt = attenuation(dist, c1, c2, c3, fclamp)
            falloff = 1.0
            if kind == LIGHT_SPOT:
                # Mitsuba's spot: 1 inside beam_width, linear in angle to 0 at cutoff_angle.
                cos_t = -(lx * A.light_dir[li, 0] + ly * A.light_dir[li, 1] + lz * A.light_dir[li, 2])
                if cos_t <= A.light_cos_cutoff[li]:
                    continue
                if cos_t < A.light_cos_beam[li]:
                    falloff = (A.light_cutoff[li] - math.acos(min(cos_t, 1.0))) * A.light_inv_tw[li]
        kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
        if kd == 0.0 and spec == 0.0:
            continue
        if shadows:
            nshadow += 1
            if kind == LIGHT_DIRECTIONAL:
                side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
                ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
                if occluded(R, ox, oy, oz, lx, ly, lz, t0, np.inf):
                    continue
            elif _blocked_towards(R, px, py, pz, gx, gy, gz, lx, ly, lz, A.light_pos[li, 0],
                                  A.light_pos[li, 1], A.light_pos[li, 2], R.shrink_point):
                continue
        w = fatt * falloff
        r += w * A.light_rad[li, 0] * (kd * rho_r + spec)
        g += w * A.light_rad[li, 1] * (kd * rho_g + spec)
        b += w * A.light_rad[li, 2] * (kd * rho_b + spec)
    # Area lights (thesis 1.4.1): uniform area sampling, estimator L_e A cosθ_y f_att(d) · bracket.
    n_em = A.em_area.shape[0]
    if n_em > 0 and light_samples > 0:
        q = int(math.sqrt(light_samples) + 0.5)
        stratified = q * q == light_samples
        for e in range(n_em):
            sh = A.em_shape[e]
            flip = A.shape_flip[sh]
            er = eg = eb = 0.0
            for k in range(light_samples):
                dim = 2 + 2 * (e * light_samples + k)
                u1 = uniform(seed, pixel, sample, dim)
                u2 = uniform(seed, pixel, sample, dim + 1)
                if stratified:
                    u1 = (k % q + u1) / q
                    u2 = (k // q + u2) / q
                yx, yy, yz, tri = sample_emitter(e, u1, u2, A.em_offset, A.em_tri, A.em_cdf, A.tri_v)
                lx, ly, lz = yx - px, yy - py, yz - pz
                dist = math.sqrt(lx * lx + ly * ly + lz * lz)
                if dist == 0.0:
                    continue
                lx, ly, lz = lx / dist, ly / dist, lz / dist
                nyx, nyy, nyz, _a, _b, _c = surface(ns + tri, 0.0, 0.0, yx, yy, yz, ns, A.sph_center,
                                                     A.sph_radius, A.tri_v, A.tri_n, A.tri_has_n, flip)
                cos_y = -(nyx * lx + nyy * ly + nyz * lz)
                if cos_y <= 0.0:        # area emitters radiate from their front side only
                    continue
                kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
                if kd == 0.0 and spec == 0.0:
                    continue
                if shadows:
                    nshadow += 1
                    if _blocked_towards(R, px, py, pz, gx, gy, gz, lx, ly, lz, yx, yy, yz, R.shrink_area):
                        continue
                w = cos_y * attenuation(dist, c1, c2, c3, fclamp)
                er += w * (kd * rho_r + spec)
                eg += w * (kd * rho_g + spec)
                eb += w * (kd * rho_b + spec)
            scale = A.em_area[e] / light_samples
            r += scale * er * A.shape_emit[sh, 0]
            g += scale * eg * A.shape_emit[sh, 1]
            b += scale * eb * A.shape_emit[sh, 2]
    # Constant environment: cosine-weighted directions about the shading normal.
    if A.env_radiance.shape[0] > 0 and light_samples > 0:
        q = int(math.sqrt(light_samples) + 0.5)
        stratified = q * q == light_samples
        er = eg = eb = 0.0
        for k in range(light_samples):
            dim = 2 + 2 * (n_em * light_samples + k)
            u1 = uniform(seed, pixel, sample, dim)
            u2 = uniform(seed, pixel, sample, dim + 1)
            if stratified:
                u1 = (k % q + u1) / q
                u2 = (k // q + u2) / q
            lx, ly, lz, cos_l = sample_cosine_hemisphere(u1, u2, sx, sy, sz)
            if cos_l <= 0.0:
                continue
            kd, spec = phong_brdf_cos(sx, sy, sz, lx, ly, lz, vx, vy, vz, ks, shininess)
            if kd == 0.0 and spec == 0.0:
                continue
            if shadows:
                nshadow += 1
                side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
                ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
                if occluded(R, ox, oy, oz, lx, ly, lz, t0, np.inf):
                    continue
            w = math.pi / cos_l          # 1 / pdf, pdf = cos / π
            er += w * (kd * rho_r + spec)
            eg += w * (kd * rho_g + spec)
            eb += w * (kd * rho_b + spec)
        r += er * A.env_radiance[0, 0] / light_samples
        g += eg * A.env_radiance[0, 1] / light_samples
        b += eb * A.env_radiance[0, 2] / light_samples
    return r, g, b, nshadow


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
    environment emitter's, uniform in direction, or 0 without one."""
    if A.env_radiance.shape[0] == 0:
        return 0.0, 0.0, 0.0
    return A.env_radiance[0, 0], A.env_radiance[0, 1], A.env_radiance[0, 2]


@njit(cache=True)
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
