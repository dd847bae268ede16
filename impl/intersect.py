"""Ray–primitive intersection kernels and brute-force scene queries (thesis 1.3.3, 2.3).

What it computes
----------------
The parameter ``t`` of the nearest hit in ``(tmin, tmax)`` of a ray
``R(t) = o + t d`` (``d`` unit length, as the thesis requires in 2.3.1) with

========================  ====================================================
kernel                    primitive and method
========================  ====================================================
``ray_sphere_algebraic``  sphere, the quadratic of thesis 2.3.1 as written
``ray_sphere_geometric``  sphere, the geometric construction of thesis 2.3.2
``ray_sphere_stable``     sphere, the closest-approach discriminant and the
                          stable root (Haines et al. 2019) — ``ray_sphere``
``ray_plane``             plane ``A x + B y + C z + D = 0`` (thesis 2.3.5)
``ray_polygon``           planar polygon, crossing-number test (thesis 2.3.6)
``ray_triangle``          triangle, Möller & Trumbore (1997)
``ray_box``               axis-aligned box by slabs (thesis 1.3.3.2,
                          Kay & Kajiya 1986), NaN-safe
========================  ====================================================

Every kernel returns ``-1`` for ``t`` on a miss.  As in pbrt's
``BasicIntersect`` the kernels return only what decides the closest hit; the
caller computes the surface frame for the kept hit alone.

Precision
---------
Each kernel is one numba function compiled once per argument type: called
with ``float32`` scalars and arrays it computes in float32, with ``float64``
in float64.  Constants go through :func:`like` (a float64 literal such as
``2.0`` would silently promote float32 arithmetic to float64), and return
values have the arguments' type.  Pass every floating argument in the same
dtype; the batch wrappers (``ray_sphere_batch`` …) cast their inputs once.

Sources
-------
* Thesis sections 2.3.1–2.3.6 and 1.3.3.2 (after E. Haines, "Essential
  ray tracing algorithms", in A. Glassner (ed.), *An Introduction to Ray
  Tracing*, 1989).
* E. Haines, J. Günther, T. Akenine-Möller, "Precision improvements for
  ray/sphere intersection", *Ray Tracing Gems*, ch. 7, 2019.
* T. Möller, B. Trumbore, "Fast, minimum storage ray/triangle
  intersection", *JGT* 2(1), 1997.
* T. L. Kay, J. T. Kajiya, "Ray tracing complex scenes", SIGGRAPH 1986;
  A. Williams et al., "An efficient and robust ray–box intersection
  algorithm", *JGT* 10(1), 2005 (IEEE infinities for zero components).
* E. Haines, "Point in polygon strategies", *Graphics Gems IV*, 1994
  (crossing number with the half-open rule).

Leaves out: error bounds on ``t`` (pbrt's conservative intervals), ray
differentials, and acceleration structures (brute-force scene queries here,
cost n·I; thesis 2.6 comes separately).  Self-intersection handling for
secondary rays is in :mod:`impl.offset`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import overload
from numba.np.numpy_support import as_dtype

__all__ = [
    "like",
    "ray_sphere", "ray_sphere_algebraic", "ray_sphere_geometric", "ray_sphere_stable",
    "ray_plane", "polygon_plane", "ray_polygon", "ray_triangle", "ray_box", "ray_box_inv",
    "closest_hit", "any_hit", "ray_sphere_form", "closest_hit_form", "any_hit_form",
    "SPHERE_FORMS", "ray_sphere_batch", "ray_triangle_batch", "ray_box_batch",
]


# --------------------------------------------------------------- precision ---

def like(x, v):
    """``v`` converted to the floating type of ``x`` (float32 or float64).

    In numba kernels a float64 literal promotes float32 arithmetic, so every
    constant in the kernels below is written ``like(x, 2.0)``.
    """
    return type(x)(v)


@overload(like, inline="always")
def _like_overload(x, v):
    if isinstance(x, types.Float):
        cast = as_dtype(x).type

        def impl(x, v):
            return cast(v)
        return impl
    if isinstance(x, types.Array) and isinstance(x.dtype, types.Float):
        cast = as_dtype(x.dtype).type

        def impl_array(x, v):
            return cast(v)
        return impl_array
    return None


# ------------------------------------------------------------- ray–sphere ---

@njit(cache=True, error_model="numpy")
def ray_sphere_algebraic(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """Thesis 2.3.1: nearest t in (tmin, tmax) from the quadratic formula, or -1.

    Catastrophic cancellation: C = |o − c|² − r² and B² − 4AC subtract numbers
    of size |o − c|², so the discriminant carries an absolute error of about
    u·|o − c|² (u the unit roundoff) — relative to r² that is u·(|o − c|/r)²,
    which reaches 1 at |o − c| ≈ r/√u (4·10³ r in float32, 10⁸ r in float64).
    """
    # Substituting R(t) = o + t d into |X − c|² = r² gives A t² + B t + C = 0 with
    #   A = d·d,  B = 2 d·(o − c),  C = |o − c|² − r²,
    #   t = (−B ± √(B² − 4AC)) / 2A.
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    a = dx * dx + dy * dy + dz * dz
    b = like(a, 2.0) * (dx * fx + dy * fy + dz * fz)
    c = fx * fx + fy * fy + fz * fz - r * r
    disc = b * b - like(a, 4.0) * a * c
    if disc < like(a, 0.0):                   # negative radicand: no intersection
        return like(a, -1.0)
    sq = math.sqrt(disc)
    two_a = like(a, 2.0) * a
    t0 = (-b - sq) / two_a
    t1 = (-b + sq) / two_a
    # Both positive: the smaller; one negative (origin inside): the positive one.
    if t0 > tmin and t0 < tmax:
        return t0
    if t1 > tmin and t1 < tmax:
        return t1
    return like(a, -1.0)


@njit(cache=True, error_model="numpy")
def ray_sphere_geometric(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """Thesis 2.3.2: nearest t in (tmin, tmax) from the closest-approach construction, or -1.

    The squared distance D² = L_OC² − t_ca² of the centre from the line
    subtracts two numbers of size |o − c|²: the same cancellation as the
    algebraic form (thesis 2.3.3 shows the two are the same formula).
    """
    # OC = c − o, L²_OC = OC·OC; the origin is inside when L²_OC < r².
    ocx, ocy, ocz = cx - ox, cy - oy, cz - oz
    l2oc = ocx * ocx + ocy * ocy + ocz * ocz
    r2 = r * r
    inside = l2oc < r2
    # t_ca = OC·d: the ray parameter of the point closest to the centre.
    tca = ocx * dx + ocy * dy + ocz * dz
    if tca < like(r, 0.0) and not inside:     # pointing away from an outside sphere
        return like(r, -1.0)
    # D² = L²_OC − t_ca² (centre–line distance²), t²_hc = r² − D².
    d2 = l2oc - tca * tca
    thc2 = r2 - d2
    if thc2 < like(r, 0.0):                   # the line passes outside the sphere
        return like(r, -1.0)
    thc = math.sqrt(thc2)
    # t = t_ca ∓ t_hc
    t0 = tca - thc
    t1 = tca + thc
    if t0 > tmin and t0 < tmax:
        return t0
    if t1 > tmin and t1 < tmax:
        return t1
    return like(r, -1.0)


@njit(inline="always", cache=True, error_model="numpy")
def ray_sphere_stable(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """Haines et al. (RTG ch. 7, 2019): nearest t in (tmin, tmax), or -1.

    The discriminant is computed from the perpendicular part of o − c, whose
    error is about u·|o − c| in *length* rather than u·|o − c|² in squared
    length, and the two roots without subtracting nearly equal numbers.
    Requires |d| = 1.
    """
    # f = o − c; with |d| = 1 the quadratic is t² − 2bt + c = 0, b = −f·d, c = f·f − r².
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    b = -(fx * dx + fy * dy + fz * dz)            # −f·d: t of closest approach
    # Discriminant b² − c = r² − (f·f − (f·d)²) = r² − |f − (f·d)d|² (Pythagoras):
    # the squared distance from the centre to the line, from the perpendicular
    # vector f + b d itself instead of a difference of two squares.
    px, py, pz = fx + b * dx, fy + b * dy, fz + b * dz
    disc = r * r - (px * px + py * py + pz * pz)
    if disc < like(r, 0.0):
        return like(r, -1.0)
    # Roots b ± √disc: the one with the sign of b, q = b + sign(b)√disc, adds
    # numbers of one sign; the other comes from Vieta's t0·t1 = c, t0 = c/q.
    c = fx * fx + fy * fy + fz * fz - r * r
    q = b + math.copysign(math.sqrt(disc), b)
    if q == like(r, 0.0):
        return like(r, -1.0)
    t0, t1 = c / q, q
    if t0 > t1:
        t0, t1 = t1, t0
    if t0 > tmin and t0 < tmax:
        return t0
    if t1 > tmin and t1 < tmax:
        return t1
    return like(r, -1.0)


#: The scene kernels' ray–sphere test: the stable form.
ray_sphere = ray_sphere_stable

#: Names of the ray–sphere forms, in the order of the batch kernel's ``form`` code.
SPHERE_FORMS = ("algebraic", "geometric", "stable")


# -------------------------------------------------------- plane and polygon ---

@njit(cache=True, error_model="numpy")
def ray_plane(ox, oy, oz, dx, dy, dz, a, b, c, d, tmin, tmax):
    """Thesis 2.3.5: t in (tmin, tmax) where the ray meets the plane
    ``a x + b y + c z + d = 0`` (``(a, b, c)`` unit), or -1.

    Both sides count; the thesis's one-sided variant (v_d > 0: the normal
    points away from the ray) is the caller's test ``a dx + b dy + c dz > 0``.
    A ray parallel to the plane (v_d = 0, including a ray lying in it) misses.
    """
    # Substituting R(t) into the plane: P_n·(o + t d) + D = 0  ⇒  t = −(P_n·o + D) / (P_n·d).
    vd = a * dx + b * dy + c * dz
    if vd == like(a, 0.0):                    # parallel: no intersection (and no 0/0)
        return like(a, -1.0)
    t = -(a * ox + b * oy + c * oz + d) / vd
    if t > tmin and t < tmax:                 # an overflow to ±inf fails the test too
        return t
    return like(a, -1.0)


@njit(cache=True, error_model="numpy")
def polygon_plane(verts):
    """Plane ``(A, B, C, D)`` of a planar polygon ``verts`` (N, 3), unit normal by
    Newell's method (robust for concave and slightly non-planar polygons);
    the normal follows the right-hand rule of the vertex order."""
    n = verts.shape[0]
    nx = ny = nz = like(verts, 0.0)
    sx = sy = sz = like(verts, 0.0)
    for i in range(n):
        j = (i + 1) % n
        xi, yi, zi = verts[i, 0], verts[i, 1], verts[i, 2]
        xj, yj, zj = verts[j, 0], verts[j, 1], verts[j, 2]
        nx += (yi - yj) * (zi + zj)
        ny += (zi - zj) * (xi + xj)
        nz += (xi - xj) * (yi + yj)
        sx += xi
        sy += yi
        sz += zi
    # Normalise after scaling by the largest component: the squares of Newell's
    # sums (of size |v|²) would overflow float32 for vertices beyond ~1e9.
    m = max(abs(nx), abs(ny), abs(nz))
    nx, ny, nz = nx / m, ny / m, nz / m
    inv = like(verts, 1.0) / math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx * inv, ny * inv, nz * inv
    # D from the vertex centroid: −n·centroid.
    k = like(verts, 1.0) / like(verts, n)
    out = np.empty(4, dtype=verts.dtype)
    out[0], out[1], out[2] = nx, ny, nz
    out[3] = -(nx * sx + ny * sy + nz * sz) * k
    return out


@njit(cache=True, error_model="numpy")
def ray_polygon(ox, oy, oz, dx, dy, dz, verts, plane, tmin, tmax):
    """Thesis 2.3.6: t where the ray meets the polygon ``verts`` (N, 3) lying in
    ``plane`` (from :func:`polygon_plane`), or -1.  Convex or concave, not
    self-intersecting; the crossing number makes holes of self-overlaps.

    Boundary rule (half-open, Haines 1994): the test ray runs along +U; a
    vertex with V = 0 counts as above the ray, an edge crossing at U = 0 does
    not count.  Two polygons sharing an edge thus claim a point of it once.
    """
    t = ray_plane(ox, oy, oz, dx, dy, dz, plane[0], plane[1], plane[2], plane[3], tmin, tmax)
    if t < like(t, 0.0):
        return t
    # Project onto the coordinate plane that drops the normal's dominant axis:
    # the projection is then never degenerate and keeps inside/outside.
    ax, ay, az = abs(plane[0]), abs(plane[1]), abs(plane[2])
    if ax >= ay and ax >= az:
        iu, iv = 1, 2
        pu, pv = oy + t * dy, oz + t * dz
    elif ay >= az:
        iu, iv = 0, 2
        pu, pv = ox + t * dx, oz + t * dz
    else:
        iu, iv = 0, 1
        pu, pv = ox + t * dx, oy + t * dy
    # Jordan curve theorem: from the hit point (moved to the origin), count the
    # edges that cross the +U half-axis; odd means inside.
    n = verts.shape[0]
    zero = like(t, 0.0)
    inside = False
    ua, va = verts[n - 1, iu] - pu, verts[n - 1, iv] - pv
    for k in range(n):
        ub, vb = verts[k, iu] - pu, verts[k, iv] - pv
        if (va >= zero) != (vb >= zero):           # the edge straddles V = 0
            if ua > zero and ub > zero:             # wholly right of the origin: crosses
                inside = not inside
            elif ua > zero or ub > zero:            # U where the edge meets V = 0
                uc = ua - va * (ub - ua) / (vb - va)
                if uc > zero:
                    inside = not inside
        ua, va = ub, vb
    return t if inside else like(t, -1.0)


# ----------------------------------------------------------- ray–triangle ---

@njit(inline="always", cache=True, error_model="numpy")
def ray_triangle(ox, oy, oz, dx, dy, dz, v, tmin, tmax):
    """Möller–Trumbore: returns (t, b1, b2) with t = -1 on a miss; v is (3, 3).

    Edges and vertices count as inside (b1, b2 ≥ 0, b1 + b2 ≤ 1).  A ray in
    the triangle's plane (det = 0) misses.
    """
    # Solve o + t d = v0 + b1 e1 + b2 e2 by Cramer's rule with scalar triple
    # products: det = e1·(d × e2), b1 = s·(d × e2)/det, b2 = d·(s × e1)/det,
    # t = e2·(s × e1)/det, s = o − v0.
    zero = like(v, 0.0)
    one = like(v, 1.0)
    miss = like(v, -1.0)
    e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == zero:
        return miss, zero, zero
    inv = one / det
    sx, sy, sz = ox - v[0, 0], oy - v[0, 1], oz - v[0, 2]
    b1 = (sx * px + sy * py + sz * pz) * inv
    if b1 < zero or b1 > one:
        return miss, zero, zero
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    b2 = (dx * qx + dy * qy + dz * qz) * inv
    if b2 < zero or b1 + b2 > one:
        return miss, zero, zero
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t <= tmin or t >= tmax:
        return miss, zero, zero
    return t, b1, b2


# --------------------------------------------------------------- ray–box ---

@njit(inline="always", cache=True, error_model="numpy")
def _slab(o, inv, lo, hi, t0, t1):
    """Clip (t0, t1) by one slab lo ≤ x ≤ hi; NaN-safe, see :func:`ray_box_inv`."""
    if inv < like(inv, 0.0):                  # sign of 1/d, also for d = −0.0 (inv = −inf)
        lo, hi = hi, lo
    tn = (lo - o) * inv
    tf = (hi - o) * inv
    # A comparison with NaN is false, so a NaN bound leaves t0 / t1 unchanged.
    if tn > t0:
        t0 = tn
    if tf < t1:
        t1 = tf
    return t0, t1


@njit(cache=True, error_model="numpy")
def ray_box_inv(ox, oy, oz, ix, iy, iz, bmin, bmax, tmin, tmax):
    """Slabs with the reciprocal direction ``(ix, iy, iz) = 1/d`` precomputed
    (as a BVH traversal does): returns (t0, t1), the part of (tmin, tmax)
    inside the closed box, or (-1, -1) on a miss.

    With the origin inside the box, t0 = tmin.
    """
    # Thesis 1.3.3.2 (Kay & Kajiya): each pair of parallel planes bounds t to
    # [t_near, t_far]; the ray meets the box iff max t_near ≤ min t_far.
    # A zero direction component gives 1/d = ±inf (IEEE), so the slab's bounds
    # are −inf/+inf when the origin is strictly inside it (no constraint) and
    # both +inf or both −inf when outside (empty interval).  An origin exactly
    # on a slab plane gives (b − o)·inf = 0·inf = NaN, which the comparisons
    # in _slab ignore: a ray lying in a face plane counts as inside (closed box).
    t0, t1 = tmin, tmax
    t0, t1 = _slab(ox, ix, bmin[0], bmax[0], t0, t1)
    t0, t1 = _slab(oy, iy, bmin[1], bmax[1], t0, t1)
    t0, t1 = _slab(oz, iz, bmin[2], bmax[2], t0, t1)
    if t0 > t1:
        return like(tmin, -1.0), like(tmin, -1.0)
    return t0, t1


@njit(cache=True, error_model="numpy")
def ray_box(ox, oy, oz, dx, dy, dz, bmin, bmax, tmin, tmax):
    """Slabs (thesis 1.3.3.2): (t0, t1) ⊂ [tmin, tmax] inside the box [bmin, bmax], or (-1, -1)."""
    one = like(dx, 1.0)
    return ray_box_inv(ox, oy, oz, one / dx, one / dy, one / dz, bmin, bmax, tmin, tmax)


# ---------------------------------------------------------- scene queries ---

@njit(cache=True)
def closest_hit(ox, oy, oz, dx, dy, dz, tmin, tmax, sph_center, sph_radius, tri_v):
    """Closest hit over all primitives: (t, prim, b1, b2); prim = -1 on a miss.

    Primitives are numbered spheres first, then triangles.  Spheres use the
    stable form.
    """
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tri_v, 0.0)
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


@njit(inline="always", cache=True, error_model="numpy")
def ray_sphere_form(form, ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax):
    """The ray–sphere test of form code ``form`` (index into :data:`SPHERE_FORMS`:
    0 algebraic, 1 geometric, 2 stable)."""
    if form == 2:
        return ray_sphere_stable(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax)
    if form == 0:
        return ray_sphere_algebraic(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax)
    return ray_sphere_geometric(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, tmin, tmax)


@njit(cache=True)
def closest_hit_form(form, ox, oy, oz, dx, dy, dz, tmin, tmax, sph_center, sph_radius, tri_v):
    """:func:`closest_hit` with the ray–sphere form chosen by ``form`` (see
    :func:`ray_sphere_form`); the precision follows the arguments' dtype."""
    best_t, best_p = tmax, -1
    bb1 = bb2 = like(tri_v, 0.0)
    zero = like(tri_v, 0.0)
    ns = sph_radius.shape[0]
    for i in range(ns):
        t = ray_sphere_form(form, ox, oy, oz, dx, dy, dz, sph_center[i, 0], sph_center[i, 1],
                            sph_center[i, 2], sph_radius[i], tmin, best_t)
        if t > zero:
            best_t, best_p = t, i
    for j in range(tri_v.shape[0]):
        t, b1, b2 = ray_triangle(ox, oy, oz, dx, dy, dz, tri_v[j], tmin, best_t)
        if t > zero:
            best_t, best_p, bb1, bb2 = t, ns + j, b1, b2
    return best_t, best_p, bb1, bb2


@njit(cache=True)
def any_hit_form(form, ox, oy, oz, dx, dy, dz, tmin, tmax, sph_center, sph_radius, tri_v):
    """:func:`any_hit` with the ray–sphere form chosen by ``form``."""
    zero = like(tri_v, 0.0)
    for i in range(sph_radius.shape[0]):
        if ray_sphere_form(form, ox, oy, oz, dx, dy, dz, sph_center[i, 0], sph_center[i, 1],
                           sph_center[i, 2], sph_radius[i], tmin, tmax) > zero:
            return True
    for j in range(tri_v.shape[0]):
        t, b1, b2 = ray_triangle(ox, oy, oz, dx, dy, dz, tri_v[j], tmin, tmax)
        if t > zero:
            return True
    return False


# ---------------------------------------------------------- batch kernels ---

@njit(cache=True, error_model="numpy")
def _sphere_batch_kernel(form, o, d, center, radius, tmin, tmax, out):
    cx, cy, cz = center[0], center[1], center[2]
    n = o.shape[0]
    # One loop per form so that the form test stays out of the inner loop.
    if form == 0:
        for i in range(n):
            out[i] = ray_sphere_algebraic(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                          cx, cy, cz, radius, tmin, tmax)
    elif form == 1:
        for i in range(n):
            out[i] = ray_sphere_geometric(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                          cx, cy, cz, radius, tmin, tmax)
    else:
        for i in range(n):
            out[i] = ray_sphere_stable(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                       cx, cy, cz, radius, tmin, tmax)


@njit(cache=True, error_model="numpy")
def _triangle_batch_kernel(o, d, v, tmin, tmax, t, b1, b2):
    for i in range(o.shape[0]):
        t[i], b1[i], b2[i] = ray_triangle(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                          v, tmin, tmax)


@njit(cache=True, error_model="numpy")
def _box_batch_kernel(o, d, bmin, bmax, tmin, tmax, t0, t1):
    for i in range(o.shape[0]):
        t0[i], t1[i] = ray_box(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                               bmin, bmax, tmin, tmax)


def _rays(origins, directions, dtype):
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    o = np.ascontiguousarray(origins, dtype=dtype)
    d = np.ascontiguousarray(directions, dtype=dtype)
    if o.ndim == 1:
        o = np.ascontiguousarray(np.broadcast_to(o, d.shape))
    if d.ndim != 2 or d.shape[1] != 3 or o.shape != d.shape:
        raise ValueError(f"origins and directions must be (N, 3) (origins may be (3,)); "
                         f"got {np.shape(origins)} and {np.shape(directions)}")
    return o, d, dtype.type


def ray_sphere_batch(origins, directions, center, radius, *, form="stable", dtype=np.float64,
                     tmin=0.0, tmax=np.inf):
    """Nearest hit t of N rays with one sphere (-1 on a miss), in precision ``dtype``.

    Parameters
    ----------
    origins : (N, 3) or (3,) array
    directions : (N, 3) array of unit vectors
    center : (3,) array
    radius : float
    form : {'algebraic', 'geometric', 'stable'}
    dtype : float32 or float64
        Every input is rounded to ``dtype`` once; the arithmetic is done in it.
    """
    if form not in SPHERE_FORMS:
        raise ValueError(f"unknown ray-sphere form {form!r} (valid: {', '.join(SPHERE_FORMS)})")
    o, d, F = _rays(origins, directions, dtype)
    out = np.empty(o.shape[0], dtype=F)
    c = np.asarray(center, dtype=F).reshape(3)
    _sphere_batch_kernel(SPHERE_FORMS.index(form), o, d, c, F(radius), F(tmin), F(tmax), out)
    return out


def ray_triangle_batch(origins, directions, v, *, dtype=np.float64, tmin=0.0, tmax=np.inf):
    """Möller–Trumbore for N rays against one triangle ``v`` (3, 3): (t, b1, b2) arrays."""
    o, d, F = _rays(origins, directions, dtype)
    v = np.ascontiguousarray(v, dtype=F)
    if v.shape != (3, 3):
        raise ValueError(f"v must be (3, 3) (one vertex a row), got {v.shape}")
    t, b1, b2 = (np.empty(o.shape[0], dtype=F) for _ in range(3))
    _triangle_batch_kernel(o, d, v, F(tmin), F(tmax), t, b1, b2)
    return t, b1, b2


def ray_box_batch(origins, directions, bmin, bmax, *, dtype=np.float64, tmin=0.0, tmax=np.inf):
    """Slabs for N rays against one box: (t0, t1) arrays, -1 on a miss."""
    o, d, F = _rays(origins, directions, dtype)
    lo = np.asarray(bmin, dtype=F).reshape(3)
    hi = np.asarray(bmax, dtype=F).reshape(3)
    t0, t1 = np.empty(o.shape[0], dtype=F), np.empty(o.shape[0], dtype=F)
    _box_batch_kernel(o, d, lo, hi, F(tmin), F(tmax), t0, t1)
    return t0, t1
