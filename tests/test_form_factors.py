"""Form factors (thesis 3.4) against closed forms, and their invariants.

Closed forms (Howell's catalogue): the point at height c on the normal through
the corner of an a×b rectangle (B-3 … the four-corner sum gives the centred
square), parallel directly opposed rectangles (C-11) and perpendicular
rectangles sharing an edge (C-14).  Each is computed here from its formula,
and the literals of the issue are checked against it first.
"""

import math

import numpy as np
import pytest

from impl.form_factors import Z99, form_factors, hemicube_table, point_form_factor
from impl.patches import FACE_PARALLELOGRAM, Polygon, mesh_polygons

SEED = 20240521
GREY, DARK = (0.5, 0.5, 0.5), (0.0, 0.0, 0.0)


# -------------------------------------------------------- closed forms ---

def corner_point_to_rectangle(a, b, c):
    """Point at height c above a corner of an a×b rectangle, parallel to it."""
    A, B = a / c, b / c
    return (A / math.sqrt(1 + A * A) * math.atan(B / math.sqrt(1 + A * A))
            + B / math.sqrt(1 + B * B) * math.atan(A / math.sqrt(1 + B * B))) / (2 * math.pi)


def howell_c11(a, b, c):
    """Parallel, directly opposed a×b rectangles at distance c."""
    X, Y = a / c, b / c
    x1, y1 = 1 + X * X, 1 + Y * Y
    return 2 / (math.pi * X * Y) * (
        math.log(math.sqrt(x1 * y1 / (1 + X * X + Y * Y)))
        + X * math.sqrt(y1) * math.atan(X / math.sqrt(y1))
        + Y * math.sqrt(x1) * math.atan(Y / math.sqrt(x1))
        - X * math.atan(X) - Y * math.atan(Y))


def howell_c14(h, w, l):
    """Perpendicular rectangles sharing an edge of length l: from the w×l one to the h×l one."""
    H, W = h / l, w / l
    s = math.sqrt(H * H + W * W)
    a = (1 + W * W) * (1 + H * H) / (1 + W * W + H * H)
    b = (W * W * (1 + W * W + H * H) / ((1 + W * W) * (W * W + H * H))) ** (W * W)
    c = (H * H * (1 + H * H + W * W) / ((1 + H * H) * (H * H + W * W))) ** (H * H)
    return (W * math.atan(1 / W) + H * math.atan(1 / H) - s * math.atan(1 / s)
            + 0.25 * math.log(a * b * c)) / (math.pi * W)


POINT_SQUARE = 4 * corner_point_to_rectangle(0.5, 0.5, 1.0)
C11 = howell_c11(1.0, 1.0, 1.0)
C14 = howell_c14(1.0, 1.0, 1.0)


def test_closed_forms_match_the_catalogue_values():
    assert abs(POINT_SQUARE - 0.239456) < 5e-7
    assert abs(C11 - 0.199825) < 5e-7
    assert abs(C14 - 0.200044) < 5e-7


def square(o, e1, e2):
    return Polygon(FACE_PARALLELOGRAM, np.array(o, float), np.array(e1, float), np.array(e2, float),
                   GREY, DARK)


def opposed_squares():
    # Bottom square faces +z, top square (z = 1) faces −z.
    return mesh_polygons([square([0, 0, 0], [1, 0, 0], [0, 1, 0]), square([0, 0, 1], [0, 1, 0], [1, 0, 0])])


def perpendicular_squares():
    # Floor z = 0 facing +z and wall y = 0 facing +y, sharing the edge x ∈ [0, 1].
    return mesh_polygons([square([0, 0, 0], [1, 0, 0], [0, 1, 0]), square([0, 0, 0], [0, 0, 1], [1, 0, 0])])


CASES = {"C-11": (opposed_squares, C11), "C-14": (perpendicular_squares, C14)}


# ---------------------------------------------------------- contour ---

def test_contour_point_to_centred_square():
    square_at_1 = [[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]]
    f = point_form_factor([0, 0, 0], [0, 0, 1], square_at_1)
    assert abs(f - POINT_SQUARE) < 1e-6, f
    # Winding does not matter; a polygon below the tangent plane contributes nothing.
    assert abs(point_form_factor([0, 0, 0], [0, 0, 1], square_at_1[::-1]) - f) < 1e-15
    assert point_form_factor([0, 0, 0], [0, 0, -1], square_at_1) == 0.0
    # Half below the plane: clipped to exactly half (by symmetry, the square straddling z = 0 at y = 1).
    tilted = [[-0.5, 1.0, -0.5], [0.5, 1.0, -0.5], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5]]
    upper = [[-0.5, 1.0, 0.0], [0.5, 1.0, 0.0], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5]]
    assert abs(point_form_factor([0, 0, 0], [0, 0, 1], tilted)
               - point_form_factor([0, 0, 0], [0, 0, 1], upper)) < 1e-15


@pytest.mark.parametrize("case", CASES)
def test_contour_area_to_area_matches_howell(case):
    """The contour formula integrated over patch i by a 16×16 Gauss–Legendre rule: to 1e-6."""
    make, exact = CASES[case]
    ff = form_factors(make(), "contour", points=16, vis_rays=0)
    F = ff.F
    assert abs(F[0, 1] - exact) < 1e-6, (case, F[0, 1], exact)
    assert abs(F[1, 0] - exact) < 1e-6, (case, F[1, 0], exact)   # equal areas: F_12 = F_21
    assert F[0, 0] == 0.0 and F[1, 1] == 0.0


# --------------------------------------------------------- hemicube ---

def test_hemicube_table_sums_towards_one():
    raws = [hemicube_table(r)[2] for r in (10, 50, 300)]
    errs = [abs(r - 1.0) for r in raws]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-4, raws
    _, dF, _ = hemicube_table(300)
    assert abs(dF.sum() - 1.0) < 1e-12


@pytest.mark.parametrize("case", CASES)
def test_hemicube_res300_within_one_percent(case):
    """Hemicube at 300 cells per top edge, placed at 8×8 Gauss points of patch i."""
    make, exact = CASES[case]
    F = form_factors(make(), "hemicube", hemicube_res=300, points=8).F
    for f in (F[0, 1], F[1, 0]):
        assert abs(f - exact) / exact < 0.01, (case, f, exact)


def test_hemicube_point_to_centred_square():
    M = mesh_polygons([square([-0.5, -0.5, 0], [1, 0, 0], [0, 1, 0]),
                       square([-0.5, -0.5, 1], [0, 1, 0], [1, 0, 0])])
    # One point: the centre of the bottom square, 1 above the centred top one.
    F = form_factors(M, "hemicube", hemicube_res=300, points=1).F
    assert abs(F[0, 1] - POINT_SQUARE) / POINT_SQUARE < 0.01, F[0, 1]


# ------------------------------------------------------ Monte Carlo ---

@pytest.mark.parametrize("case", CASES)
def test_monte_carlo_within_its_confidence_interval(case):
    make, exact = CASES[case]
    ff = form_factors(make(), "montecarlo", mc_samples=100_000, seed=SEED)
    print(f"seed {SEED}: {case} F = {ff.F[0, 1]:.5f} ± {ff.halfwidth[0, 1]:.5f} (exact {exact:.6f})")
    for i, j in ((0, 1), (1, 0)):
        assert abs(ff.F[i, j] - exact) <= ff.halfwidth[i, j], (case, SEED, ff.F[i, j], ff.halfwidth[i, j])
    assert abs(ff.halfwidth[0, 1] - Z99 * math.sqrt(exact * (1 - exact) / 100_000)) < 1e-4


# ------------------------------------------ reciprocity and closure ---

def closed_box(n=3, block=False):
    """Inward-facing unit box [0,1]³, each face n×n patches; optionally a block inside."""
    faces = [square([0, 0, 0], [1, 0, 0], [0, 1, 0]),      # z = 0, normal +z
             square([0, 0, 1], [0, 1, 0], [1, 0, 0]),      # z = 1, normal −z
             square([0, 0, 0], [0, 0, 1], [1, 0, 0]),      # y = 0, normal +y
             square([0, 1, 0], [1, 0, 0], [0, 0, 1]),      # y = 1, normal −y
             square([0, 0, 0], [0, 1, 0], [0, 0, 1]),      # x = 0, normal +x
             square([1, 0, 0], [0, 0, 1], [0, 1, 0])]      # x = 1, normal −x
    if block:   # outward-facing box [0.3, 0.6] × [0.35, 0.65] × [0, 0.5] standing on z = 0
        lo, hi = np.array([0.3, 0.35, 0.0]), np.array([0.6, 0.65, 0.5])
        d = hi - lo
        X, Y, Z = np.diag(d)
        faces += [square(lo + [0, 0, d[2]], X, Y),          # top, +z
                  square(lo, X, Z), square(lo + [0, d[1], 0], Z, X),     # −y, +y
                  square(lo, Z, Y), square(lo + [d[0], 0, 0], Y, Z)]     # −x, +x
    return mesh_polygons(faces, patch_size=1.0 / n + 1e-9)


def reciprocity_error(M, F):
    """max |A_i F_ij − A_j F_ji| / max(A_i F_ij, A_j F_ji) over pairs with a form factor > 1e-3."""
    AF = M.area[:, None] * F
    big = np.maximum(AF, AF.T)
    mask = big > 1e-3 * M.area.max()
    return float(np.max(np.abs(AF - AF.T)[mask] / big[mask]))


# Tolerances each method achieves on the 54-patch closed box (measured; see the report):
# the centre-point rules are exact in closure but not reciprocal (adjacent patches).
@pytest.mark.parametrize("method, kw, closure_tol, recip_tol", [
    ("contour", dict(points=1, vis_rays=4), 1e-12, 0.40),
    ("contour", dict(points=6, vis_rays=4), 1e-12, 0.01),
    ("hemicube", dict(points=1, hemicube_res=100), 1e-12, 0.40),
    ("hemicube", dict(points=4, hemicube_res=100), 1e-12, 0.05),
    ("montecarlo", dict(mc_samples=20000, seed=SEED), 1e-12, None),
])
def test_closure_and_reciprocity_in_a_closed_box(method, kw, closure_tol, recip_tol):
    M = closed_box(3)
    assert M.n_patches == 54
    ff = form_factors(M, method, **kw)
    F = ff.F
    rows = F.sum(axis=1)
    print(f"{method} {kw}: closure |ΣF − 1| max {np.abs(rows - 1).max():.3g}, "
          f"reciprocity max rel {reciprocity_error(M, F):.3g}")
    assert np.all(np.diag(F) == 0.0)
    assert np.abs(rows - 1.0).max() < closure_tol
    if recip_tol is not None:
        assert reciprocity_error(M, F) < recip_tol
    else:
        # Monte Carlo: A_i F_ij − A_j F_ji within the combined 99 % interval for ~99 % of
        # the pairs (97 % asserted: 1431 pairs, a binomial spread of ±0.7 %).
        AF, AH = M.area[:, None] * F, M.area[:, None] * ff.halfwidth
        iu = np.triu_indices(M.n_patches, 1)
        ok = (np.abs(AF - AF.T) <= np.hypot(AH, AH.T) + 1e-15)[iu]
        print(f"seed {SEED}: {ok.mean():.4f} of pairs reciprocal within the 99 % interval")
        assert ok.mean() >= 0.97, (SEED, ok.mean())


def test_occluded_box_closure_per_method():
    """With a block inside, hemicube and Monte Carlo stay closed exactly (every ray hits
    something); the contour method's shadow-ray visibility (16 rays per pair) is an
    estimate: measured closure error max 0.105, mean 0.008; asserted 0.15 and 0.02.
    Floor patches (0.25 wide) reaching under the block see its inside (back faces,
    absorbed) from there: they are left out."""
    M = closed_box(4, block=True)
    c = M.centre
    covered = ((c[:, 2] == 0.0) & (np.abs(c[:, 0] - 0.45) < 0.15 + 0.125)
               & (np.abs(c[:, 1] - 0.5) < 0.15 + 0.125))
    assert covered.sum() == 4
    for method, kw, tol, tol_mean in (("hemicube", dict(hemicube_res=64), 1e-12, 1e-12),
                                      ("montecarlo", dict(mc_samples=2000, seed=SEED), 1e-12, 1e-12),
                                      ("contour", dict(vis_rays=16), 0.15, 0.02)):
        rows = form_factors(M, method, **kw).F.sum(axis=1)[~covered]
        print(f"{method}: closure error max {np.abs(rows - 1).max():.3g}, mean {np.abs(rows - 1).mean():.3g}")
        assert np.abs(rows - 1.0).max() < tol, method
        assert np.abs(rows - 1.0).mean() < tol_mean, method


# ------------------------------------------- z-buffer hemicube, point ---

@pytest.mark.parametrize("case", CASES)
def test_zbuffer_hemicube_matches_howell_and_the_ray_cast_hemicube(case):
    """Patches projected onto the hemicube faces by the rasteriser (100 cells per top edge,
    4×4 Gauss points): within 2 % of Howell's value and of the ray-cast hemicube on the same
    cells."""
    make, exact = CASES[case]
    Fz = form_factors(make(), "hemicube-zbuffer", hemicube_res=100, points=4).F
    Fr = form_factors(make(), "hemicube", hemicube_res=100, points=4).F
    print(f"{case}: zbuffer {Fz[0, 1]:.5f}, rays {Fr[0, 1]:.5f}, exact {exact:.6f}")
    for i, j in ((0, 1), (1, 0)):
        assert abs(Fz[i, j] - exact) / exact < 0.02
        assert abs(Fz[i, j] - Fr[i, j]) / Fr[i, j] < 0.02


def test_zbuffer_hemicube_closes_rows_with_occlusion():
    """With a block inside the box every cell of every hemicube sees some patch: rows sum to
    1 up to the cells lost to near-plane clipping (measured max 4.2e-4 at 64 cells); it
    agrees with the ray-cast hemicube pair by pair to 0.004 (mean 6e-5)."""
    M = closed_box(4, block=True)
    c = M.centre
    covered = ((c[:, 2] == 0.0) & (np.abs(c[:, 0] - 0.45) < 0.15 + 0.125)
               & (np.abs(c[:, 1] - 0.5) < 0.15 + 0.125))
    Fz = form_factors(M, "hemicube-zbuffer", hemicube_res=64).F
    Fr = form_factors(M, "hemicube", hemicube_res=64).F
    rows = Fz.sum(axis=1)[~covered]
    print(f"closure error max {np.abs(rows - 1).max():.3g}; vs rays max {np.abs(Fz - Fr).max():.3g}")
    assert np.abs(rows - 1.0).max() < 1e-3
    assert np.abs(Fz - Fr).max() < 0.01 and np.abs(Fz - Fr).mean() < 2e-4
    assert np.all(np.diag(Fz) == 0.0)


def test_point_approximation_far_and_near():
    """The thesis's point form factor A_j cosθ_i cosθ_j / (π r²): within 0.1 % of the exact
    value for small squares 10 apart (r ≫ √A), but 59 % high for the unit squares of C-11
    (r = √A): the ablation the approximation invites."""
    far = mesh_polygons([square([0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]),
                         square([0, 0, 10], [0, 0.2, 0], [0.2, 0, 0])])
    exact_far = howell_c11(0.2, 0.2, 10.0)
    Fp = form_factors(far, "point", vis_rays=0).F
    assert abs(Fp[0, 1] - exact_far) / exact_far < 1e-3
    near = form_factors(opposed_squares(), "point", vis_rays=0).F
    assert near[0, 1] == pytest.approx(1.0 / math.pi, rel=1e-5)     # A cos cos / (π r²), r = 1 (+ the ray offset)
    assert (near[0, 1] - C11) / C11 > 0.5
