"""Ray–primitive intersection kernels and brute-force scene queries (thesis 1.3.3, 2.3).

As in pbrt's ``BasicIntersect``, the hit kernels return only what decides the
closest hit — the parameter ``t`` and the primitive index — and the caller
computes the surface frame for the kept hit alone.

* Ray–sphere: the geometric form of thesis 2.3.2 with the numerically stable
  discriminant r² − |f − (f·d)d|² and root t = c/q (Haines et al., "Precision
  improvements for ray/sphere intersection", Ray Tracing Gems, ch. 7, 2019).
* Ray–triangle: Möller & Trumbore, "Fast, minimum storage ray/triangle
  intersection", JGT 2(1), 1997.

Scene queries here are brute force (every primitive, cost n·I); acceleration
structures (thesis 2.6) come separately.  Directions are unit length.
"""

import math

from numba import njit

__all__ = ["ray_sphere", "ray_triangle", "closest_hit", "any_hit"]


@njit(inline="always", cache=True)
def ray_sphere(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """Nearest t in (tmin, tmax) where the ray meets the sphere, or -1."""
    # f = o − c; with |d| = 1 the quadratic is t² + 2(f·d)t + (f·f − r²) = 0.
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    b = -(fx * dx + fy * dy + fz * dz)            # −f·d: t of closest approach
    # Distance² from the centre to the line, from the perpendicular part of f.
    px, py, pz = fx + b * dx, fy + b * dy, fz + b * dz
    disc = r * r - (px * px + py * py + pz * pz)
    if disc < 0.0:
        return -1.0
    c = fx * fx + fy * fy + fz * fz - r * r
    q = b + math.copysign(math.sqrt(disc), b)
    if q == 0.0:
        return -1.0
    t0, t1 = c / q, q
    if t0 > t1:
        t0, t1 = t1, t0
    if t0 > tmin and t0 < tmax:
        return t0
    if t1 > tmin and t1 < tmax:
        return t1
    return -1.0


@njit(inline="always", cache=True)
def ray_triangle(ox, oy, oz, dx, dy, dz, v, tmin, tmax):
    """Möller–Trumbore: returns (t, b1, b2) with t = -1 on a miss; v is (3, 3)."""
    e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return -1.0, 0.0, 0.0
    inv = 1.0 / det
    sx, sy, sz = ox - v[0, 0], oy - v[0, 1], oz - v[0, 2]
    b1 = (sx * px + sy * py + sz * pz) * inv
    if b1 < 0.0 or b1 > 1.0:
        return -1.0, 0.0, 0.0
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    b2 = (dx * qx + dy * qy + dz * qz) * inv
    if b2 < 0.0 or b1 + b2 > 1.0:
        return -1.0, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t <= tmin or t >= tmax:
        return -1.0, 0.0, 0.0
    return t, b1, b2


@njit(cache=True)
def closest_hit(ox, oy, oz, dx, dy, dz, tmin, tmax, sph_center, sph_radius, tri_v):
    """Closest hit over all primitives: (t, prim, b1, b2); prim = -1 on a miss.

    Primitives are numbered spheres first, then triangles.
    """
    best_t, best_p, bb1, bb2 = tmax, -1, 0.0, 0.0
    ns = sph_radius.shape[0]
    for i in range(ns):
        t = ray_sphere(ox, oy, oz, dx, dy, dz, sph_center[i, 0], sph_center[i, 1],
                       sph_center[i, 2], sph_radius[i], tmin, best_t)
        if t > 0.0:
            best_t, best_p = t, i
    for j in range(tri_v.shape[0]):
        t, b1, b2 = ray_triangle(ox, oy, oz, dx, dy, dz, tri_v[j], tmin, best_t)
        if t > 0.0:
            best_t, best_p, bb1, bb2 = t, ns + j, b1, b2
    return best_t, best_p, bb1, bb2


@njit(cache=True)
def any_hit(ox, oy, oz, dx, dy, dz, tmin, tmax, sph_center, sph_radius, tri_v):
    """True if any primitive lies on the ray within (tmin, tmax) (shadow rays)."""
    for i in range(sph_radius.shape[0]):
        if ray_sphere(ox, oy, oz, dx, dy, dz, sph_center[i, 0], sph_center[i, 1],
                      sph_center[i, 2], sph_radius[i], tmin, tmax) > 0.0:
            return True
    for j in range(tri_v.shape[0]):
        t, b1, b2 = ray_triangle(ox, oy, oz, dx, dy, dz, tri_v[j], tmin, tmax)
        if t > 0.0:
            return True
    return False

