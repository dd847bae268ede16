"""The perturbed shading normal of Mitsuba 3's ``normalmap`` and ``bumpmap`` BSDF adapters.

What it computes
----------------
Both adapters evaluate, sample and take the pdf of the BSDF they wrap in a
shading frame whose normal n_p is perturbed (Mitsuba 3.9
``src/bsdfs/normalmap.cpp``, ``bumpmap.cpp``, ``normalmap_helpers.h``):

* surface parameterisation of a triangle with vertex uvs (Mitsuba's
  ``Mesh::compute_surface_interaction``): with dp0 = p1 − p0, dp1 = p2 − p0,
  duv0 = uv1 − uv0, duv1 = uv2 − uv0 and det = duv0.x duv1.y − duv0.y duv1.x,
  ∂p/∂u = (duv1.y dp0 − duv0.y dp1) / det and ∂p/∂v = (duv0.x dp1 − duv1.x dp0) / det
  (an orthonormal basis of the normal where det = 0).  Mitsuba's ``rectangle``
  is such a mesh, its uv the local [−1, 1]² mapped to [0, 1]²;
* ``normalmap``: the texture's RGB c gives n = 2c − 1 in the tangent frame
  (s, t, n_s) with s = ∂p/∂u made orthogonal to the shading normal n_s,
  t = n_s × s (Mitsuba's ``initialize_sh_frame``), so n_p ∝ n.x s + n.y t + n.z n_s;
* ``bumpmap``: the height h's gradient in uv, (h_u, h_v) = scale · ∇h (the
  bitmap luminance's bilinear gradient, :func:`impl.textures.bitmap_grad`),
  moves the tangents along n_s: ∂p/∂u' = ∂p/∂u + n_s (h_u − n_s · ∂p/∂u), likewise
  v, and n_p = normalize(∂p/∂u' × ∂p/∂v'), turned to the side of the geometric
  normal;
* ``flip_invalid_normals`` (default true): where the incident direction w_i lies
  below the perturbed horizon, (w_i · n_s)(w_i · n_p) ≤ 0, n_p's tangential part is
  negated (n_p ← 2 (n_p · n_s) n_s − n_p);
* light leaking: a direction w_o only scatters where it lies on the same side of the
  unperturbed shading normal as of n_p, (w_o · n_s)(w_o · n_p) > 0
  (:func:`same_side`); elsewhere eval, pdf and the sample's weight are 0.  The
  nested BSDF checks w_i and w_o against n_p itself;
* ``use_shadowing_function`` (default true): eval and the sample weight are
  multiplied by Estevez et al.'s shadowing term (:func:`shadow_terminator`,
  "A Microfacet-Based Shadowing Function to Solve the Bump Terminator Problem",
  Ray Tracing Gems 2019) G = 2 / (1 + √(1 + α² tan² θ_o)), α² = min(⅛ tan² θ_p, 1),
  θ_p and θ_o the angles of n_p and w_o to n_s; the pdf is the nested BSDF's.

A ``twosided`` material seen from behind: where the map is inside the
``twosided`` (``twosided(normalmap(bsdf))``), Mitsuba's ``twosided`` negates the
local z of w_i and w_o in the unperturbed frame, so the perturbation is computed
with the mirrored w_i on the front side and n_p is mirrored back through the
tangent plane; where the map wraps it (``normalmap(twosided(bsdf))``), the
``twosided`` negates them in the perturbed frame, so n_p is computed with w_i as
it is and the BSDF sees −n_p.

Where Mitsuba's normalisations divide by zero (a texel with 2c − 1 = 0, a
vanishing bumped cross product) n_p is the unperturbed s, and a tangent ∂p/∂u
along n_s is replaced by any tangent.

Only the normal matters to the isotropic BSDFs, so the tracers build their own
tangents around n_p.  An anisotropic BSDF under a ``normalmap`` takes Mitsuba
3.9.1's tangent of the perturbed frame: the unperturbed shading frame's tangent s
made orthogonal to n_p and normalised (:func:`perturbed_tangent`; in Mitsuba, e_x
of the local frame Gram–Schmidt-ed against the local n_p); mirrored or negated
with n_p on the back of a two-sided material, which leaves its axis (all an
anisotropic D sees) unchanged.  Under a ``bumpmap`` it takes 3.9.1's bump frame's
tangent (:func:`bump_tangent`), which Gram–Schmidts the world ∂p/∂u against the
perturbed normal in frame coordinates, mixing the two spaces.  Triangles only: the
loader gives spheres no uv.

The tangent frame of an anisotropic BSDF (:func:`tangent`): Mitsuba's
``SurfaceInteraction::initialize_sh_frame`` (3.9) takes s = ∂p/∂u made orthogonal to
the shading normal n and normalised (any tangent of n where ∂p/∂u vanishes), and
t = n × s.  ∂p/∂u of a triangle with uvs as above (:func:`tri_dpdu_dpdv`); of a
triangle without uvs p1 − p0 (Mitsuba's barycentric parameterisation); of a sphere
e_z × (p − c) (Mitsuba's ``sphere``: the azimuth about the sphere's local z axis,
here the world z axis: the scene model keeps no rotation of a sphere's to_world).

Per-ray helpers (``inline="always"``, scalars and a few arrays), called from
the batch kernels.
"""

from __future__ import annotations

import math

from numba import njit

from .textures import bitmap, bitmap_grad

__all__ = ["tri_dpdu_dpdv", "tangent", "perturbed_tangent", "bump_tangent", "perturbed_normal", "same_side",
           "shadow_terminator"]


@njit(inline="always", cache=True)
def _coordinate_system(nx, ny, nz):
    """Mitsuba's ``coordinate_system`` (Duff et al. 2017): two tangents of unit n."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx, b, sign + ny * ny * a, -ny)


@njit(inline="always", cache=True)
def tri_dpdu_dpdv(v, uv, gx, gy, gz):
    """(∂p/∂u, ∂p/∂v) of triangle vertices ``v`` (3, 3) with texture coordinates
    ``uv`` (3, 2), as Mitsuba's mesh; a degenerate uv map falls back on the
    coordinate system of the unit normal g."""
    d0x, d0y, d0z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    d1x, d1y, d1z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    a0, a1 = uv[1, 0] - uv[0, 0], uv[1, 1] - uv[0, 1]
    c0, c1 = uv[2, 0] - uv[0, 0], uv[2, 1] - uv[0, 1]
    det = a0 * c1 - a1 * c0
    if det == 0.0:
        return _coordinate_system(gx, gy, gz)
    inv = 1.0 / det
    return ((c1 * d0x - a1 * d1x) * inv, (c1 * d0y - a1 * d1y) * inv, (c1 * d0z - a1 * d1z) * inv,
            (a0 * d1x - c0 * d0x) * inv, (a0 * d1y - c0 * d0y) * inv, (a0 * d1z - c0 * d0z) * inv)


@njit(inline="always", cache=True)
def tangent(prim, ns, b1, b2, px, py, pz, sph_center, tri_v, tri_uv, tri_has_uv, gx, gy, gz, nx, ny, nz):
    """The unit tangent s of Mitsuba's shading frame at a hit on primitive ``prim``
    (spheres first, ``ns`` of them; triangles with vertices ``tri_v``, uvs ``tri_uv``
    where ``tri_has_uv``): ∂p/∂u made orthogonal to the unit shading normal n and
    normalised (module docstring); g the unit geometric normal (the fallback of a
    degenerate uv map)."""
    if prim < ns:
        dx, dy, dz = -(py - sph_center[prim, 1]), px - sph_center[prim, 0], 0.0
    else:
        j = prim - ns
        v = tri_v[j]
        if tri_has_uv[j]:
            dx, dy, dz, _a, _b, _c = tri_dpdu_dpdv(v, tri_uv[j], gx, gy, gz)
        else:
            dx, dy, dz = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    return perturbed_tangent(dx, dy, dz, nx, ny, nz)


@njit(inline="always", cache=True)
def perturbed_tangent(tx, ty, tz, nx, ny, nz):
    """Vector t made orthogonal to the unit normal n and normalised (Gram–Schmidt; any
    tangent of n where t lies along n): :func:`tangent` of ∂p/∂u, and the tangent of a
    normal map's perturbed frame from the unperturbed frame's tangent and the perturbed
    normal."""
    d = nx * tx + ny * ty + nz * tz
    ex, ey, ez = tx - d * nx, ty - d * ny, tz - d * nz
    le = math.sqrt(ex * ex + ey * ey + ez * ez)
    if le > 0.0:
        return ex / le, ey / le, ez / le
    ex, ey, ez, _a, _b, _c = _coordinate_system(nx, ny, nz)
    return ex, ey, ez


@njit(inline="always", cache=True)
def bump_tangent(v, uv, tex, back, gx, gy, gz, sx, sy, sz, nx, ny, nz):
    """The unit tangent of Mitsuba 3.9.1's ``bumpmap`` frame at a hit of a triangle
    (vertices ``v``, uvs ``uv``; ``tex`` the map's record of :func:`perturbed_normal`,
    whose entry 7 says whether the map wraps a ``twosided``), in world space: g the unit
    geometric normal, s the unit unperturbed shading normal on the front side, n the
    perturbed normal as the BSDF sees it (:func:`perturbed_normal`, mirrored or negated on
    the ``back`` of a two-sided material).

    ``BumpMap::frame`` computes the perturbed normal n_l in the coordinates of the
    unperturbed frame (e, e_t = s × e, s), e the tangent of :func:`tangent`, and then its
    tangent as ``normalize(dp_du − n_l (n_l · dp_du))`` with the *world* ∂p/∂u: that
    vector's three world components read as frame coordinates, made orthogonal to n_l
    and normalised, then taken to the world through the frame.  Where ∂p/∂u lies along a
    world axis other than the frame's e this turns the tangent (by 90° on a rectangle
    whose u runs along world y), which an anisotropic BSDF shows; reproduced as it is.
    On the back the tangent follows the normal (mirrored through the tangent plane where
    the map is inside the ``twosided``; as it is where the map wraps it, the normal then
    negated)."""
    dux, duy, duz, _a, _b, _c = tri_dpdu_dpdv(v, uv, gx, gy, gz)
    ex, ey, ez = perturbed_tangent(dux, duy, duz, sx, sy, sz)
    fx, fy, fz = sy * ez - sz * ey, sz * ex - sx * ez, sx * ey - sy * ex
    mirror = back and tex[7] == 0
    if mirror:                          # n_p on the front: mirrored back through the tangent plane
        d = 2.0 * (nx * sx + ny * sy + nz * sz)
        nx, ny, nz = nx - d * sx, ny - d * sy, nz - d * sz
    elif back:                          # negated by the twosided inside the map
        nx, ny, nz = -nx, -ny, -nz
    lx, ly, lz = nx * ex + ny * ey + nz * ez, nx * fx + ny * fy + nz * fz, nx * sx + ny * sy + nz * sz
    ax, ay, az = perturbed_tangent(dux, duy, duz, lx, ly, lz)
    tx, ty, tz = ax * ex + ay * fx + az * sx, ax * ey + ay * fy + az * sy, ax * ez + ay * fz + az * sz
    if mirror:
        d = 2.0 * (tx * sx + ty * sy + tz * sz)
        tx, ty, tz = tx - d * sx, ty - d * sy, tz - d * sz
    return tx, ty, tz


@njit(inline="always", cache=True)
def perturbed_normal(code, scale, tex, uvm, data, v, uv, b1, b2, gx, gy, gz, sx, sy, sz, wx, wy, wz,
                     back):
    """The unit perturbed shading normal n_p of a ``normalmap`` (``code`` 1) or
    ``bumpmap`` (2) at barycentrics (b1, b2) of a triangle (vertices ``v``, uvs
    ``uv``): ``tex`` the map's record (offset, width, height, wrap, filter,
    flip_invalid_normals, use_shadowing_function, wraps_twosided) into the texels ``data``, ``uvm``
    its 2×3 to_uv map, ``scale`` the bump scale; g and s the hit's unit geometric
    and shading normals (front side), w the unit direction towards the viewer;
    ``back``: a two-sided material seen from behind (n_p is mirrored, see the
    module docstring)."""
    mirror = back and tex[7] == 0
    if mirror:
        ws = wx * sx + wy * sy + wz * sz
        wx, wy, wz = wx - 2.0 * ws * sx, wy - 2.0 * ws * sy, wz - 2.0 * ws * sz
    b0 = 1.0 - b1 - b2
    u = b0 * uv[0, 0] + b1 * uv[1, 0] + b2 * uv[2, 0]
    t = b0 * uv[0, 1] + b1 * uv[1, 1] + b2 * uv[2, 1]
    uu = uvm[0, 0] * u + uvm[0, 1] * t + uvm[0, 2]
    vv = uvm[1, 0] * u + uvm[1, 1] * t + uvm[1, 2]
    pux, puy, puz, pvx, pvy, pvz = tri_dpdu_dpdv(v, uv, gx, gy, gz)
    if code == 1:
        r, g, b = bitmap(data, tex[0], tex[1], tex[2], tex[3], tex[4], uu, vv)
        cx, cy, cz = 2.0 * r - 1.0, 2.0 * g - 1.0, 2.0 * b - 1.0
        d = sx * pux + sy * puy + sz * puz
        ex, ey, ez = pux - d * sx, puy - d * sy, puz - d * sz
        le = math.sqrt(ex * ex + ey * ey + ez * ez)
        if le > 0.0:
            ex, ey, ez = ex / le, ey / le, ez / le
        else:                                       # ∂p/∂u along n_s: any tangent
            ex, ey, ez, _a, _b, _c = _coordinate_system(sx, sy, sz)
        fx, fy, fz = sy * ez - sz * ey, sz * ex - sx * ez, sx * ey - sy * ex
        nx = cx * ex + cy * fx + cz * sx
        ny = cx * ey + cy * fy + cz * sy
        nz = cx * ez + cy * fz + cz * sz
    else:
        hu, hv = bitmap_grad(data, tex[0], tex[1], tex[2], tex[3], tex[4], uvm[0, 0], uvm[0, 1],
                             uvm[1, 0], uvm[1, 1], uu, vv)
        hu, hv = scale * hu, scale * hv
        du = hu - (sx * pux + sy * puy + sz * puz)
        dv = hv - (sx * pvx + sy * pvy + sz * pvz)
        pux, puy, puz = pux + du * sx, puy + du * sy, puz + du * sz
        pvx, pvy, pvz = pvx + dv * sx, pvy + dv * sy, pvz + dv * sz
        nx, ny, nz = puy * pvz - puz * pvy, puz * pvx - pux * pvz, pux * pvy - puy * pvx
        if nx * gx + ny * gy + nz * gz < 0.0:
            nx, ny, nz = -nx, -ny, -nz
    if tex[5] != 0 and (wx * sx + wy * sy + wz * sz) * (wx * nx + wy * ny + wz * nz) <= 0.0:
        d = 2.0 * (nx * sx + ny * sy + nz * sz)
        nx, ny, nz = d * sx - nx, d * sy - ny, d * sz - nz
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln > 0.0:
        nx, ny, nz = nx / ln, ny / ln, nz / ln
    else:                                           # no direction (a texel 2c - 1 = 0): unperturbed
        nx, ny, nz = sx, sy, sz
    if mirror:
        d = 2.0 * (nx * sx + ny * sy + nz * sz)
        nx, ny, nz = nx - d * sx, ny - d * sy, nz - d * sz
    elif back:
        nx, ny, nz = -nx, -ny, -nz
    return nx, ny, nz


@njit(inline="always", cache=True)
def same_side(nx, ny, nz, sx, sy, sz, wx, wy, wz):
    """Whether w lies on the same side of the shading normal s as of the perturbed
    normal n (the adapters' test against light leaking)."""
    return (wx * sx + wy * sy + wz * sz) * (wx * nx + wy * ny + wz * nz) > 0.0


@njit(inline="always", cache=True)
def shadow_terminator(nx, ny, nz, sx, sy, sz, wx, wy, wz):
    """Estevez et al.'s shadowing term G(n_p, w_o) (see the module docstring); 1 where
    n_p = s, 0 where w_o is tangent to s."""
    c = nx * sx + ny * sy + nz * sz
    c2 = c * c
    if c2 >= 1.0:
        return 1.0
    alpha2 = 1.0 if c2 == 0.0 else min(0.125 * (1.0 - c2) / c2, 1.0)
    co = wx * sx + wy * sy + wz * sz
    co2 = co * co
    if co2 == 0.0:
        return 0.0
    tan2 = max(1.0 - co2, 0.0) / co2
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha2 * tan2))
