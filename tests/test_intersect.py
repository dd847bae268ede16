"""Intersection kernels (thesis 2.3, 1.3.3.2) and self-intersection offsets:
analytic cases in float32 and float64, float32 really computed in float32,
agreement of the three ray–sphere forms, and the brute-force scene queries
against a numpy reference."""

import math
import re

import numpy as np
import pytest
from numba import njit

import impl.intersect as I
import impl.offset as O

F32, F64 = np.float32, np.float64
DTYPES = [F32, F64]
SPHERES = {"algebraic": I.ray_sphere_algebraic, "geometric": I.ray_sphere_geometric,
           "stable": I.ray_sphere_stable}
INF = np.inf


def cast(F, *xs):
    return [F(x) for x in xs]


def sphere(form, F, o, d, c, r, tmin=0.0, tmax=INF):
    return SPHERES[form](*cast(F, *o, *d, *c, r, tmin, tmax))


def unit(*v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


# ----------------------------------------------------------------- precision ---

@pytest.mark.parametrize("form", list(SPHERES))
def test_kernels_return_the_argument_precision(form):
    for F in DTYPES:
        t = SPHERES[form](*cast(F, 0, 0, -5, 0, 0, 1, 0, 0, 0, 1, 0, INF))
        assert t == 4.0
    sigs = {str(s.return_type) for s in SPHERES[form].nopython_signatures}
    assert {"float32", "float64"} <= sigs


def _algebraic_emulated(F, o, d, c, r):
    """Thesis 2.3.1 with the kernel's operation order, in numpy scalars of type F."""
    ox, oy, oz, dx, dy, dz, cx, cy, cz, r = cast(F, *o, *d, *c, r)
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    a = dx * dx + dy * dy + dz * dz
    b = F(2.0) * (dx * fx + dy * fy + dz * fz)
    cc = fx * fx + fy * fy + fz * fz - r * r
    disc = b * b - F(4.0) * a * cc
    if disc < 0:
        return F(-1.0)
    sq = np.sqrt(disc)
    return (-b - sq) / (F(2.0) * a)


def _stable_emulated(F, o, d, c, r):
    """Haines et al.'s form with the kernel's operation order, in numpy scalars of type F."""
    ox, oy, oz, dx, dy, dz, cx, cy, cz, r = cast(F, *o, *d, *c, r)
    fx, fy, fz = ox - cx, oy - cy, oz - cz
    b = -(fx * dx + fy * dy + fz * dz)
    px, py, pz = fx + b * dx, fy + b * dy, fz + b * dz
    disc = r * r - (px * px + py * py + pz * pz)
    if disc < 0:
        return F(-1.0)
    cc = fx * fx + fy * fy + fz * fz - r * r
    q = b + np.copysign(np.sqrt(disc), b)
    return min(cc / q, q)


def test_float32_algebraic_loses_r_squared_at_distance_1e4():
    """C = |o − c|² − r² = 10⁸ − 1 rounds to 10⁸ in float32 (spacing 8 there), so
    the discriminant is 0 and the ray hits tangentially at t = 10⁴ instead of 9999."""
    o, d, c = (0, 0, 0), (0, 0, 1), (0, 0, 1e4)
    t32 = sphere("algebraic", F32, o, d, c, 1.0)
    t64 = sphere("algebraic", F64, o, d, c, 1.0)
    assert t64 == 9999.0
    assert t32 == 10000.0
    assert t32 == _algebraic_emulated(F32, o, d, c, 1.0)
    # The stable form keeps r² (its discriminant is r² − |f⊥|² = 1 − 0).
    assert sphere("stable", F32, o, d, c, 1.0) == 9999.0


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_float32_kernels_match_float32_emulation_bit_for_bit(seed):
    """On hard oblique inputs (sphere 10³ away) the float32 kernels equal a numpy
    float32 evaluation of the same operations exactly, and differ from float64."""
    rng = np.random.default_rng(seed)
    print(f"seed={seed}")
    diffs = 0
    for _ in range(50):
        w = unit(*rng.normal(size=3))
        c = tuple(1e3 * w + rng.normal(size=3) * 0.1)
        # Aim within the sphere's outline, at a random fraction of its radius.
        e = unit(*np.cross(w, rng.normal(size=3)))
        target = np.array(c) + e * 0.95 * rng.uniform()
        d = tuple(unit(*target))
        o = (0.0, 0.0, 0.0)
        for form, emulated in (("algebraic", _algebraic_emulated), ("stable", _stable_emulated)):
            t32 = SPHERES[form](*cast(F32, *o, *d, *c, 1.0, 0.0, INF))
            ref32 = emulated(F32, o, d, c, 1.0)
            assert np.float32(t32) == ref32 or (t32 == -1.0 and ref32 < 0), (form, t32, ref32)
            t64 = SPHERES[form](*cast(F64, *o, *d, *c, 1.0, 0.0, INF))
            assert t64 == emulated(F64, o, d, c, 1.0) or t64 == -1.0
            diffs += t32 != t64
    assert diffs > 0, "float32 and float64 never differ: the float32 path is not float32"


def _double_arithmetic(fn, args):
    """Float64 arithmetic instructions in the LLVM IR of a fresh (uncached) copy of
    ``fn``, outside the CPython wrapper (which boxes the result as a Python float)."""
    fresh = njit(error_model="numpy")(fn.py_func)
    fresh(*args)
    (sig,) = fresh.signatures
    ir = fresh.inspect_llvm(sig)
    bodies = [b for b in ir.split("\ndefine ")[1:] if "cpython" not in b.split("\n", 1)[0]
              and "cfunc" not in b.split("\n", 1)[0]]
    assert bodies, "no compiled function body found in the IR"
    return [line for b in bodies for line in b.split("\n")
            if re.search(r"\b(?:fadd|fsub|fmul|fdiv|fpext)\b.*\bdouble\b|llvm\.sqrt\.f64", line)]


@pytest.mark.parametrize("name", ["algebraic", "geometric", "stable", "plane", "polygon", "triangle",
                                  "box", "robust"])
def test_float32_kernels_have_no_float64_arithmetic(name):
    """No float64 add/mul/div/sqrt or float32→float64 promotion in the float32 code."""
    a = cast(F32, 0, 0, -5, 0, 0, 1)
    zero = F32(0)
    poly = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], F32)
    cases = {
        "algebraic": (I.ray_sphere_algebraic, a + cast(F32, 0, 0, 0, 1, 0, INF)),
        "geometric": (I.ray_sphere_geometric, a + cast(F32, 0, 0, 0, 1, 0, INF)),
        "stable": (I.ray_sphere_stable, a + cast(F32, 0, 0, 0, 1, 0, INF)),
        "plane": (I.ray_plane, a + cast(F32, 0, 0, 1, 0, 0, INF)),
        "polygon": (I.ray_polygon, a + [poly, I.polygon_plane(poly), zero, F32(INF)]),
        "triangle": (I.ray_triangle, a + [poly[:3].copy(), zero, F32(INF)]),
        "box": (I.ray_box, a + [-np.ones(3, F32), np.ones(3, F32), zero, F32(INF)]),
        "robust": (O.offset_ray, cast(F32, 1e3, -2e-3, 5, 0.6, 0.0, -0.8)),
    }
    fn, args = cases[name]
    assert _double_arithmetic(fn, args) == []


# ---------------------------------------------------------------- ray–sphere ---

@pytest.mark.parametrize("form", list(SPHERES))
@pytest.mark.parametrize("F", DTYPES)
def test_sphere_analytic_cases(form, F):
    c, r = (0.0, 0.0, 0.0), 1.0
    # Head-on from outside: t = 5 − 1.
    assert sphere(form, F, (0, 0, -5), (0, 0, 1), c, r) == 4.0
    # Miss: the line passes 1.5 from the centre.
    assert sphere(form, F, (1.5, 0, -5), (0, 0, 1), c, r) == -1.0
    # Tangent (discriminant exactly 0): one hit at t = 5.
    assert sphere(form, F, (1.0, 0, -5), (0, 0, 1), c, r) == 5.0
    # Origin inside: the exit at t = 1 (the thesis: take the positive root).
    assert sphere(form, F, (0, 0, 0), (0, 0, 1), c, r) == 1.0
    assert sphere(form, F, (0, 0, 0.5), (0, 0, -1), c, r) == 1.5
    # Sphere behind the origin.
    assert sphere(form, F, (0, 0, 5), (0, 0, 1), c, r) == -1.0
    # Range (tmin, tmax): clipped by tmax; tmin past the entry gives the exit.
    assert sphere(form, F, (0, 0, -5), (0, 0, 1), c, r, 0.0, 3.9) == -1.0
    assert sphere(form, F, (0, 0, -5), (0, 0, 1), c, r, 4.5, INF) == 6.0
    # An off-axis chord: o = (0.6, 0, −5) hits z = −0.8 at t = 4.2.
    t = sphere(form, F, (0.6, 0, -5), (0, 0, 1), c, r)
    assert t == pytest.approx(4.2, rel=4 * float(np.finfo(F).eps))
    # A shifted sphere, oblique ray: t from the closed form.
    d = unit(1, 2, 2)
    t = sphere(form, F, (1, 2, 3), tuple(d), (4, 8, 9), 2.0)
    assert t == pytest.approx(9.0 - 2.0, rel=16 * float(np.finfo(F).eps))


@pytest.mark.parametrize("seed", [20240601])
def test_sphere_forms_agree_on_well_conditioned_rays(seed):
    """Random rays from 2–10 radii away, away from tangency: the three forms agree in float64."""
    rng = np.random.default_rng(seed)
    print(f"seed={seed}")
    n, checked = 2000, 0
    for _ in range(n):
        c = rng.uniform(-5, 5, 3)
        r = rng.uniform(0.5, 2.0)
        o = c + unit(*rng.normal(size=3)) * r * rng.uniform(0.2, 10.0)
        d = unit(*rng.normal(size=3))
        f = o - c
        perp = np.linalg.norm(f - (f @ d) * d)
        if abs(perp - r) < 1e-6 * r or abs(np.linalg.norm(f) - r) < 1e-6 * r:
            continue
        ts = [SPHERES[k](*o, *d, *c, r, 0.0, INF) for k in SPHERES]
        assert (ts[0] < 0) == (ts[1] < 0) == (ts[2] < 0), ts
        if ts[0] >= 0:
            np.testing.assert_allclose(ts, ts[2], rtol=1e-9, atol=1e-12)
        checked += 1
    assert checked > 0.9 * n


def test_sphere_batch_matches_scalar_kernels_and_checks_inputs():
    rng = np.random.default_rng(5)
    o = rng.normal(size=(64, 3)) * 3
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for F in DTYPES:
        for form in I.SPHERE_FORMS:
            t = I.ray_sphere_batch(o, d, (0.1, 0.2, 0.3), 1.5, form=form, dtype=F)
            assert t.dtype == F
            ref = [SPHERES[form](*cast(F, *o[i], *d[i], 0.1, 0.2, 0.3, 1.5, 0.0, INF)) for i in range(64)]
            np.testing.assert_array_equal(t, np.array(ref, dtype=F))
    with pytest.raises(ValueError, match="unknown ray-sphere form 'quadric'.*algebraic, geometric, stable"):
        I.ray_sphere_batch(o, d, (0, 0, 0), 1.0, form="quadric")
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        I.ray_sphere_batch(o[:, :2], d, (0, 0, 0), 1.0)
    with pytest.raises(ValueError, match="float32 or float64"):
        I.ray_sphere_batch(o, d, (0, 0, 0), 1.0, dtype=np.float16)


# ----------------------------------------------------------- plane, polygon ---

@pytest.mark.parametrize("F", DTYPES)
def test_plane_analytic_cases(F):
    def plane(o, d, n, dist, tmin=0.0, tmax=INF):
        return I.ray_plane(*cast(F, *o, *d, *n, dist, tmin, tmax))
    # z = 2 written as 0x + 0y + 1z − 2 = 0.
    assert plane((0, 0, 0), (0, 0, 1), (0, 0, 1), -2) == 2.0
    assert plane((0, 0, 5), (0, 0, -1), (0, 0, 1), -2) == 3.0       # from the other side
    assert plane((0, 0, 5), (0, 0, 1), (0, 0, 1), -2) == -1.0       # plane behind
    assert plane((0, 0, 0), (1, 0, 0), (0, 0, 1), -2) == -1.0       # parallel
    assert plane((0, 0, 2), (1, 0, 0), (0, 0, 1), -2) == -1.0       # in the plane: no 0/0
    assert plane((0, 0, 0), (0, 0, 1), (0, 0, 1), -2, 0.0, 1.5) == -1.0
    d = unit(0, 3, 4)
    assert plane((0, 0, 0), tuple(d), (0, 0, 1), -2) == pytest.approx(2.5, rel=4 * float(np.finfo(F).eps))


def _poly_hit(F, verts, o, d):
    v = np.asarray(verts, dtype=F)
    return I.ray_polygon(*cast(F, *o, *d), v, I.polygon_plane(v), F(0), F(INF))


@pytest.mark.parametrize("F", DTYPES)
def test_polygon_convex_and_concave(F):
    square = [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]]
    down = (0, 0, -1)
    assert _poly_hit(F, square, (1, 1, 3), down) == 2.0
    assert _poly_hit(F, square, (3, 1, 3), down) == -1.0
    assert _poly_hit(F, square[::-1], (1, 1, 3), down) == 2.0        # orientation does not matter
    # A concave "U": the notch x ∈ (1, 2), y > 1 is outside, the arms inside.
    u_shape = [[0, 0, 0], [3, 0, 0], [3, 3, 0], [2, 3, 0], [2, 1, 0], [1, 1, 0], [1, 3, 0], [0, 3, 0]]
    assert _poly_hit(F, u_shape, (1.5, 2, 5), down) == -1.0          # in the notch
    assert _poly_hit(F, u_shape, (0.5, 2, 5), down) == 5.0           # left arm
    assert _poly_hit(F, u_shape, (2.5, 2, 5), down) == 5.0           # right arm
    assert _poly_hit(F, u_shape, (1.5, 0.5, 5), down) == 5.0         # base
    # The test ray along +U passes exactly through vertices (v = 1 and v = 3 rows):
    # the half-open rule counts each crossing once.
    assert _poly_hit(F, u_shape, (0.5, 1, 5), down) == 5.0
    assert _poly_hit(F, u_shape, (1.5, 1, 5), down) == 5.0           # on the notch's bottom edge
    # A diamond with the hit point level with its side vertices.
    diamond = [[0, -1, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0]]
    assert _poly_hit(F, diamond, (0, 0, 1), down) == 1.0
    assert _poly_hit(F, diamond, (-0.9, 0, 1), down) == 1.0
    assert _poly_hit(F, diamond, (1.1, 0, 1), down) == -1.0
    assert _poly_hit(F, diamond, (-1.1, 0, 1), down) == -1.0


@pytest.mark.parametrize("F", DTYPES)
def test_polygon_in_any_plane_drops_the_dominant_axis(F):
    # The same unit square in the planes x = 1, y = 1 and a tilted one.
    sq_x = [[1, 0, 0], [1, 1, 0], [1, 1, 1], [1, 0, 1]]
    assert _poly_hit(F, sq_x, (3, 0.5, 0.5), (-1, 0, 0)) == 2.0
    assert _poly_hit(F, sq_x, (3, 1.5, 0.5), (-1, 0, 0)) == -1.0
    sq_y = [[0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]]
    assert _poly_hit(F, sq_y, (0.5, -2, 0.5), (0, 1, 0)) == 3.0
    tilted = [[0, 0, 0], [1, 0, 1], [1, 1, 1], [0, 1, 0]]             # the plane z = x
    t = _poly_hit(F, tilted, (0.5, 0.5, 5), (0, 0, -1))
    assert t == pytest.approx(4.5, rel=4 * float(np.finfo(F).eps))
    assert _poly_hit(F, tilted, (1.5, 0.5, 5), (0, 0, -1)) == -1.0
    plane = I.polygon_plane(np.array(tilted, F))
    np.testing.assert_allclose(np.abs(plane[:3]), [math.sqrt(0.5), 0, math.sqrt(0.5)], rtol=1e-6)


def test_polygons_sharing_an_edge_claim_its_points_once():
    """Two triangles splitting a square: points on the diagonal, on the outer
    edges' shared vertex rows, hit exactly one of them."""
    a = [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    b = [[0, 0, 0], [1, 1, 0], [0, 1, 0]]
    for F in DTYPES:
        for x in (0.25, 0.5, 0.75):
            hits = [_poly_hit(F, p, (x, x, 1), (0, 0, -1)) > 0 for p in (a, b)]
            assert sum(hits) == 1, (F, x, hits)


# ---------------------------------------------------------------- triangle ---

@pytest.mark.parametrize("F", DTYPES)
def test_triangle_analytic_cases(F):
    v = np.array([[0, 0, 2], [2, 0, 2], [0, 2, 2]], dtype=F)

    def tri(o, d, tmin=0.0, tmax=INF):
        return I.ray_triangle(*cast(F, *o, *d), v, F(tmin), F(tmax))
    t, b1, b2 = tri((0.5, 0.5, 0), (0, 0, 1))
    assert (t, b1, b2) == (2.0, 0.25, 0.25)
    # Edges and vertices count as inside (b ≥ 0, b1 + b2 ≤ 1).
    assert tri((1, 1, 0), (0, 0, 1))[0] == 2.0            # on the hypotenuse: b1 + b2 = 1
    assert tri((1, 0, 0), (0, 0, 1))[0] == 2.0            # on the edge b2 = 0
    assert tri((0, 0, 0), (0, 0, 1))[0] == 2.0            # vertex v0
    assert tri((2, 0, 0), (0, 0, 1))[1:] == (1.0, 0.0)    # vertex v1
    # Just outside each edge.
    eps = 1e-3
    assert tri((1 + eps, 1 + eps, 0), (0, 0, 1))[0] == -1.0
    assert tri((1, -eps, 0), (0, 0, 1))[0] == -1.0
    assert tri((-eps, 1, 0), (0, 0, 1))[0] == -1.0
    # From behind (both sides count), behind the origin, parallel, clipped.
    assert tri((0.5, 0.5, 4), (0, 0, -1))[0] == 2.0
    assert tri((0.5, 0.5, 4), (0, 0, 1))[0] == -1.0
    assert tri((0.5, 0.5, 2), (1, 0, 0))[0] == -1.0       # in the plane: det = 0
    assert tri((0.5, 0.5, 0), (0, 0, 1), 0.0, 1.5)[0] == -1.0
    assert all(isinstance(x, float) for x in tri((0.5, 0.5, 0), (0, 0, 1)))


def test_triangle_batch_matches_scalar():
    rng = np.random.default_rng(8)
    o = rng.uniform(-1, 1, (100, 3)) + [0, 0, -3]
    d = np.tile([0.0, 0.0, 1.0], (100, 1))
    v = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float)
    for F in DTYPES:
        t, b1, b2 = I.ray_triangle_batch(o, d, v, dtype=F)
        assert t.dtype == F
        for i in range(100):
            assert (t[i], b1[i], b2[i]) == I.ray_triangle(*cast(F, *o[i], *d[i]), v.astype(F), F(0), F(INF))


# --------------------------------------------------------------------- box ---

@pytest.mark.parametrize("F", DTYPES)
def test_box_slabs(F):
    lo, hi = np.array([-1, -1, -1], F), np.array([1, 2, 3], F)

    def box(o, d, tmin=0.0, tmax=INF):
        return I.ray_box(*cast(F, *o), *(F(x) for x in d), lo, hi, F(tmin), F(tmax))
    assert box((-5, 0, 0), (1, 0, 0)) == (4.0, 6.0)                  # axis-parallel, zero y, z
    assert box((5, 0, 0), (-1, 0, 0)) == (4.0, 6.0)
    assert box((-5, 5, 0), (1, 0, 0)) == (-1.0, -1.0)                # outside the y slab
    assert box((0, 0, 0), (0, 0, 1)) == (0.0, 3.0)                   # origin inside: t0 = tmin
    assert box((0, 0, 0), (0, 0, 1), 0.5, 2.0) == (0.5, 2.0)
    assert box((-5, 0, 0), (-1, 0, 0)) == (-1.0, -1.0)               # box behind
    # Zero components of both signs: 1/(−0.0) = −inf.
    assert box((-5, 0, 0), (1, -0.0, -0.0)) == (4.0, 6.0)
    assert box((-5, 5, 0), (1, -0.0, 0)) == (-1.0, -1.0)
    # Rays lying in a face plane (o_y = 2 = hi_y, d_y = 0: 0·inf = NaN) count as inside.
    assert box((-5, 2, 0), (1, 0, 0)) == (4.0, 6.0)
    assert box((-5, -1, 3), (1, 0, 0)) == (4.0, 6.0)                 # along an edge
    assert box((-1, -1, -5), (0, 0, 1)) == (4.0, 8.0)                # along another edge
    # Diagonal ray through a corner region.
    d = unit(1, 1, 1)
    t0, t1 = box((-2, -2, -2), tuple(d))
    assert t0 == pytest.approx(math.sqrt(3), rel=4 * float(np.finfo(F).eps))
    assert t1 == pytest.approx(3 * math.sqrt(3), rel=4 * float(np.finfo(F).eps))
    # A miss that passes a corner.
    assert box((-2, 3, 0), tuple(unit(1, 1, 0))) == (-1.0, -1.0)
    assert not any(math.isnan(x) for x in box((-5, 2, 0), (1, 0, 0)))


def test_box_batch_matches_scalar_and_inv_form():
    rng = np.random.default_rng(9)
    o = rng.uniform(-3, 3, (200, 3))
    d = rng.normal(size=(200, 3))
    d[::7, 0] = 0.0
    d[::11, 1] = -0.0
    lo, hi = np.array([-1.0, -0.5, -2.0]), np.array([1.0, 0.5, 2.0])
    for F in DTYPES:
        t0, t1 = I.ray_box_batch(o, d, lo, hi, dtype=F)
        assert t0.dtype == F
        for i in range(200):
            ref = I.ray_box(*cast(F, *o[i], *d[i]), lo.astype(F), hi.astype(F), F(0), F(INF))
            assert (t0[i], t1[i]) == ref
        with np.errstate(divide="ignore"):
            inv = (1.0 / d.astype(F)).astype(F)
        i = 7
        assert I.ray_box_inv(*cast(F, *o[i]), *inv[i], lo.astype(F), hi.astype(F), F(0), F(INF)) == (t0[i], t1[i])
    # Reference: a ray hits the box iff its slab intervals overlap (float64, no zero components).
    keep = np.all(d != 0.0, axis=1)
    with np.errstate(divide="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    near = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
    far = np.maximum(ta, tb).min(axis=1)
    t0, _ = I.ray_box_batch(o, d, lo, hi)
    np.testing.assert_array_equal((t0 >= 0)[keep], (near <= far)[keep])


# ----------------------------------------------------------- scene queries ---

def _numpy_closest(o, d, centers, radii, tris):
    """Reference closest hit in float64 numpy: (t, prim) for one ray."""
    best, prim = np.inf, -1
    for i, (c, r) in enumerate(zip(centers, radii)):
        f = o - c
        b = -f @ d
        disc = r * r - np.sum((f + b * d) ** 2)
        if disc >= 0:
            for t in (b - math.sqrt(disc), b + math.sqrt(disc)):
                if 0 < t < best:
                    best, prim = t, i
                    break
    for j, v in enumerate(tris):
        m = np.column_stack([-d, v[1] - v[0], v[2] - v[0]])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        t, b1, b2 = np.linalg.solve(m, o - v[0])
        if b1 >= 0 and b2 >= 0 and b1 + b2 <= 1 and 0 < t < best:
            best, prim = t, len(radii) + j
    return best, prim


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_closest_hit_matches_numpy_reference_on_random_scenes(seed):
    rng = np.random.default_rng(seed)
    print(f"seed={seed}")
    centers = rng.uniform(-4, 4, (6, 3))
    radii = rng.uniform(0.3, 1.2, 6)
    tris = rng.uniform(-4, 4, (10, 3, 3))
    agree = 0
    for _ in range(400):
        o = rng.uniform(-8, 8, 3)
        d = unit(*(rng.uniform(-3, 3, 3) - o))
        t, prim, b1, b2 = I.closest_hit(*o, *d, 0.0, INF, centers, radii, tris)
        t_ref, prim_ref = _numpy_closest(o, d, centers, radii, tris)
        assert prim == prim_ref, (o, d, t, t_ref)
        if prim >= 0:
            assert t == pytest.approx(t_ref, rel=1e-9)
            agree += 1
        assert I.any_hit(*o, *d, 0.0, INF, centers, radii, tris) == (prim >= 0)
        if prim >= 0:
            assert not I.any_hit(*o, *d, 0.0, t * (1 - 1e-9), centers, radii, tris) or \
                _numpy_closest(o, d, centers, radii, tris)[0] < t
    assert agree > 50


def test_closest_hit_in_float32():
    centers = np.array([[0, 0, 5]], F32)
    radii = np.array([1.0], F32)
    tris = np.array([[[-1, -1, 2], [1, -1, 2], [0, 1, 2]]], F32)
    t, prim, b1, b2 = I.closest_hit(*cast(F32, 0, 0, 0, 0, 0, 1, 0, INF), centers, radii, tris)
    assert (t, prim) == (2.0, 1)
    t, prim, _, _ = I.closest_hit(*cast(F32, 0, 0, 3, 0, 0, 1, 0, INF), centers, radii, tris)
    assert (t, prim) == (1.0, 0)


# ------------------------------------------------------------------ offsets ---

def test_robust_offset_moves_by_256_ulps_along_the_normal():
    # float32: 1 + 256 ulps(1) = 1 + 2⁸·2⁻²³; moving down from 1 the ulps are half as large.
    ox, oy, oz = O.offset_ray(*cast(F32, 1.0, -1.0, 4.0, 1.0, 1.0, -1.0))
    assert ox == np.float32(1 + 2.0 ** -15)
    assert oy == np.float32(-1 + 2.0 ** -16)        # p < 0, n > 0: towards zero, i.e. up
    assert oz == np.float32(4 - 256 * 2.0 ** -22)   # below 4 the spacing is 2⁻²²
    # Components of n below 1/256 give no integer offset.
    assert O.offset_ray(*cast(F32, 3.0, 3.0, 3.0, 0.003, 0.0, 0.0))[0] == 3.0
    # float64: the same 256 ulps of its own format.
    ox, oy, oz = O.offset_ray(*cast(F64, 1.0, -1.0, 4.0, 1.0, 1.0, -1.0))
    assert ox == 1 + 256 * 2.0 ** -52
    assert oy == -1 + 256 * 2.0 ** -53
    assert oz == 4 - 256 * 2.0 ** -51


def test_robust_offset_near_the_origin_is_absolute():
    # |p| < 1/32: p + FLOAT_SCALE·n, 2⁻¹⁶ in float32 and 2⁻⁴⁵ in float64.
    o32 = O.offset_ray(*cast(F32, 0.0, 0.01, -0.02, 0.6, 0.0, -0.8))
    assert o32[0] == np.float32(0.6 * 2.0 ** -16)
    assert o32[1] == np.float32(0.01)
    assert o32[2] == np.float32(np.float32(-0.02) + np.float32(-0.8) * np.float32(2.0 ** -16))
    o64 = O.offset_ray(0.0, 0.01, -0.02, 0.6, 0.0, -0.8)
    assert o64[0] == 0.6 * 2.0 ** -45
    assert o64[2] == -0.02 - 0.8 * 2.0 ** -45
    assert O.FLOAT_SCALE == {"float32": 2.0 ** -16, "float64": 2.0 ** -45}
    assert {str(s.return_type) for s in O.offset_ray.nopython_signatures} >= \
        {"UniTuple(float32 x 3)", "UniTuple(float64 x 3)"}


def test_spawn_strategies():
    p = cast(F32, 1.0, 2.0, 3.0)
    n = cast(F32, 0.0, 0.0, 1.0)
    e = F32(0.25)
    assert O.spawn(0, *p, *n, e) == (1.0, 2.0, 3.0, 0.25)
    assert O.spawn(1, *p, *n, e) == (1.0, 2.0, 3.25, 0.0)
    assert O.spawn(2, *p, *n, e) == (1.0, 2.0, 4.0, 0.0)            # 0.25·(1 + 3)
    assert O.spawn(3, *p, *n, e) == (1.0, 2.0, np.float32(3 + 256 * 2.0 ** -22), 0.0)
    assert O.STRATEGIES == ("tmin", "normal", "scaled", "robust")


@pytest.mark.parametrize("F", DTYPES)
@pytest.mark.parametrize("shift", [1.0, 1e3, 1e5])
def test_robust_offset_prevents_self_hits_on_a_far_sphere(F, shift):
    """Points computed on a sphere far from the origin, offset by Wächter–Binder:
    rays leaving on the outer side (n·l > 0) never hit the sphere again, while
    without an offset some do (seed 4)."""
    rng = np.random.default_rng(4)
    c = (np.array([0.3, -0.7, 0.5]) * shift).astype(F)
    r = F(1.0)
    self_hits_raw = self_hits = 0
    for _ in range(300):
        # Hit point of a ray from outside, computed in precision F.
        o = (c.astype(np.float64) + unit(*rng.normal(size=3)) * 5.0).astype(F)
        target = c.astype(np.float64) + unit(*rng.normal(size=3)) * 0.7
        d = unit(*(target - o)).astype(F)
        t = I.ray_sphere_stable(*o, *d, *c, r, F(0), F(INF))
        assert t > 0
        p = o + t * d
        n = (p - c) / r
        l_dir = unit(*(n.astype(np.float64) + rng.normal(size=3) * 0.8)).astype(F)
        if float(l_dir @ n) <= 0.05:
            continue
        self_hits_raw += I.ray_sphere_stable(*p, *l_dir, *c, r, F(0), F(INF)) > 0
        q = O.offset_ray(*p, *n)
        self_hits += I.ray_sphere_stable(*q, *l_dir, *c, r, F(0), F(INF)) > 0
    assert self_hits == 0
    assert self_hits_raw > 0
