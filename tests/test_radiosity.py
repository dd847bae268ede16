"""Radiosity (thesis ch. 3): solvers against the direct solve and the furnace,
the whole pipeline on a furnace scene, refusals, caching, and convergence to
Mitsuba's path tracer as the patches are refined."""

import sys
from pathlib import Path

import numpy as np
import pytest

import impl.radiosity as radiosity  # noqa: F401  (registers 'radiosity')
from gibench import registry
from core.loader import load_scene
from impl.form_factors import form_factors
from core.errors import ParamError
from impl.radiosity_solvers import SOLVERS, neumann, residual, solve, spectral_bounds

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_form_factors import closed_box  # noqa: E402

SUITES = Path(__file__).resolve().parent.parent / "suites"
RADIOSITY = registry.get("radiosity")
SEED = 7
ITERATIVE = [s for s in SOLVERS if s != "direct"]


def render(scene, **params):
    return RADIOSITY.render(scene, RADIOSITY.parse_params(params))


@pytest.fixture(scope="module")
def occluded_box():
    M = closed_box(4, block=True)
    F = form_factors(M, "hemicube", hemicube_res=32).F
    rng = np.random.default_rng(SEED)
    rho = rng.uniform(0.2, 0.9, (M.n_patches, 3))
    E = np.zeros((M.n_patches, 3))
    E[rng.choice(M.n_patches, 5, replace=False)] = rng.uniform(1, 10, (5, 3))
    return M, F, rho, E


@pytest.mark.parametrize("solver", ITERATIVE)
def test_iterative_solvers_reach_the_direct_solution(occluded_box, solver):
    M, F, rho, E = occluded_box
    ref = solve(F, rho, E, M.area, "direct")
    assert residual(F, rho, E, ref.B) < 1e-13
    res = solve(F, rho, E, M.area, solver, tol=1e-12)
    err = np.abs(res.B - ref.B).max() / np.abs(ref.B).max()
    print(f"seed {SEED}: {solver}: {res.iterations} iterations, residual {res.residuals[-1]:.2e}, "
          f"rel. error {err:.2e}, {res.seconds * 1e3:.2f} ms")
    assert res.converged and err < 1e-6
    assert len(res.residuals) == len(res.times) == res.iterations + 1
    assert np.all(np.diff(res.times) >= 0)


@pytest.mark.parametrize("rho", [0.5, 0.9, 0.99])
@pytest.mark.parametrize("solver", SOLVERS)
def test_white_furnace_box(rho, solver):
    """A closed box, uniform emission E and reflectance ρ: B = E / (1 − ρ) exactly
    (the contour form factors of an empty box close to 1e-15)."""
    M = closed_box(3)
    F = form_factors(M, "contour").F
    E = np.full((M.n_patches, 3), 2.0)
    R = np.full((M.n_patches, 3), rho)
    res = solve(F, R, E, M.area, solver, tol=1e-12, max_iter=20000)
    err = np.abs(res.B - 2.0 / (1.0 - rho)).max() / (2.0 / (1.0 - rho))
    print(f"furnace rho={rho}: {solver}: {res.iterations} iterations ({res.shots} shots), rel. error {err:.2e}")
    assert res.converged and err < 1e-6
    if solver != "direct":
        assert res.iterations < 20000


@pytest.mark.parametrize("solver", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("tol", [1e-6, 1e-9, 1e-12, 3e-13])
def test_converged_flag_is_the_returned_iterates_residual(solver, tol):
    """One residual decides: ``converged`` is exactly ``residual(B) <= tol`` for the B
    returned, for any tolerance (none of it hinges on which side of tol rounding falls)."""
    M = closed_box(3)
    F = form_factors(M, "contour").F
    E = np.full((M.n_patches, 3), 2.0)
    R = np.full((M.n_patches, 3), 0.99)
    res = solve(F, R, E, M.area, solver, tol=tol, max_iter=20000)
    assert res.residuals[-1] == residual(F, R, E, res.B)
    assert res.converged == (residual(F, R, E, res.B) <= tol)
    capped = solve(F, R, E, M.area, solver, tol=tol, max_iter=3)
    assert capped.residuals[-1] == residual(F, R, E, capped.B) and not capped.converged


def test_progressive_ambient_term_improves_partial_solutions():
    M = closed_box(3)
    F = form_factors(M, "contour").F
    E = np.zeros((M.n_patches, 3))
    E[0] = 10.0
    R = np.full((M.n_patches, 3), 0.8)
    exact = solve(F, R, E, M.area, "direct").B
    part = solve(F, R, E, M.area, "progressive", tol=1e-12, max_iter=1)
    assert not part.converged
    e_plain = np.abs(part.B - exact).mean()
    e_amb = np.abs(part.B + part.ambient - exact).mean()
    print(f"after {part.shots} shots: mean error {e_plain:.3g} without, {e_amb:.3g} with the ambient term")
    assert e_amb < 0.5 * e_plain


FURNACE_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="80"/>
        <transform name="to_world"><lookat origin="0.2, 0.1, 0.5" target="-0.3, -0.2, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film>
    </sensor>
    <shape type="cube">
        <boolean name="flip_normals" value="true"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="{rho}, {rho}, {rho}"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="1, 0.5, 0.25"/></emitter>
    </shape>
</scene>"""


@pytest.mark.parametrize("display", ["flat", "gouraud"])
def test_furnace_scene_displays_le_over_one_minus_rho(tmp_path, display):
    """Inside a closed emitting box every pixel shows B/π = L_e / (1 − ρ)."""
    p = tmp_path / "furnace.xml"
    p.write_text(FURNACE_XML.format(rho=0.75))
    img = render(load_scene(p), display=display, patches=100, solver="gauss-seidel", tol=1e-12).image
    expected = np.array([1.0, 0.5, 0.25]) / 0.25
    assert np.abs(img - expected).max() / expected.max() < 1e-5


FURNACE_SPHERE = """    <shape type="sphere">
        <point name="center" value="-0.2, -0.3, -0.4"/>
        <float name="radius" value="0.35"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="{rho}, {rho}, {rho}"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="1, 0.5, 0.25"/></emitter>
    </shape>
</scene>"""


@pytest.mark.parametrize("formfactor", ["hemicube", "hemicube-zbuffer"])
def test_sphere_is_meshed_into_patches_and_the_furnace_holds(tmp_path, formfactor):
    """A sphere inside the closed emitting box, both with ρ = 0.75 and the same L_e, meshed into
    patches (12 segments): hemicube form factors close every row exactly, so every pixel —
    box and sphere — shows L_e / (1 − ρ).  Negative control: the point approximation does
    not close its rows (here Σ_j ρ F_ij > 1 for neighbouring patches, so the iteration
    diverges): the solve refuses it with one line naming the spectral radius and the
    patches, so the furnace check cannot pass with it."""
    p = tmp_path / "furnace_sphere.xml"
    p.write_text(FURNACE_XML.format(rho=0.75).replace("</scene>", FURNACE_SPHERE.format(rho=0.75)))
    scene = load_scene(p)
    expected = np.array([1.0, 0.5, 0.25]) / 0.25
    res = render(scene, display="flat", patches=100, formfactor=formfactor, hemicube_res=32,
                 solver="gauss-seidel", tol=1e-12)
    assert res.counters["patches"] >= 2 * 12 * 5             # the sphere's 120 triangles at least
    assert np.abs(res.image - expected).max() / expected.max() < 1e-5
    with pytest.raises(ParamError, match=r"formfactor=point.*spectral radius of ρF .* >= 1\.\d+.*patches"):
        render(scene, display="flat", patches=100, formfactor="point", vis_rays=4)


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_divergent_system_is_refused_with_its_cause(solver):
    """Row sums of ρF above 1 with spectral radius λ > 1: the Neumann series grows without
    bound (what the iterative solvers would have returned: inf), and every solver refuses
    the system with one line naming λ's lower bound, the channel and the offending patches.
    A matrix with a row sum above 1 but λ < 1 is accepted and solved (the check is on λ,
    not on the row sums alone)."""
    F = np.array([[0.0, 0.9, 0.6], [0.7, 0.0, 0.6], [0.4, 0.4, 0.0]])
    rho = np.full((3, 3), 0.9)
    rho[:, 2] = 0.5                                     # blue: rows of ρF 0.75, 0.65, 0.4: no complaint
    E = np.ones((3, 3))
    lam = max(abs(np.linalg.eigvals(rho[:, 0, None] * F)))
    assert lam > 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        assert not np.isfinite(neumann(F, rho, E, 20000)).all()
    with pytest.raises(ParamError) as err:
        solve(F, rho, E, np.ones(3), solver)
    msg = str(err.value)
    assert "\n" not in msg and "channel R" in msg and "2 of 3 patches (0, 1;" in msg
    lo = float(msg.split(">= ")[1].split(" ")[0])
    assert 1.0 <= lo <= lam
    ok = np.array([[0.0, 1.8, 0.0], [0.05, 0.0, 0.0], [0.0, 0.0, 0.0]])   # λ(ρF) = 0.9·0.3
    res = solve(ok, rho, E, np.ones(3), solver, tol=1e-12)
    exact = np.stack([np.linalg.solve(np.eye(3) - rho[:, c, None] * ok, E[:, c]) for c in range(3)], 1)
    assert res.converged and np.allclose(res.B, exact, rtol=1e-9)


def test_spectral_bounds_bracket_the_spectral_radius():
    rng = np.random.default_rng(SEED)
    for n in (2, 5, 40):
        A = rng.uniform(0, 2.0 / n, (n, n)) * (rng.uniform(size=(n, n)) < 0.7)
        lam = max(abs(np.linalg.eigvals(A)))
        lo, hi = spectral_bounds(A, rtol=1e-9, iterations=2000)
        assert lo <= lam * (1 + 1e-12) and hi >= lam * (1 - 1e-12)


def test_refuses_non_diffuse(tmp_path):
    p = tmp_path / "metal.xml"
    p.write_text(FURNACE_XML.format(rho=0.5).replace(
        '<bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>', '<bsdf type="conductor"/>'))
    with pytest.raises(NotImplementedError, match="'conductor' BSDF"):
        render(load_scene(p))
    with pytest.raises(ValueError, match="square"):
        render(load_scene(SUITES / "cornell" / "cornell_box.xml"), spp=3)


def test_solution_is_cached_and_view_independent():
    scene = load_scene(SUITES / "cornell" / "cornell_box.xml")
    radiosity.clear_cache()
    a = render(scene, patches=64, display="flat")
    b = render(scene, patches=64, display="gouraud", spp=4, reuse=True)
    assert not a.counters["solve_cached"] and b.counters["solve_cached"]
    fresh = render(scene, patches=64, display="gouraud", spp=4)      # reuse is off by default
    assert not fresh.counters["solve_cached"]
    assert a.counters["solve_s"] == b.counters["solve_s"]
    for key in ("formfactor_s", "solve_s", "view_s", "solve_iterations", "solve_residual",
                "residual_decades_per_s", "patches"):
        assert key in a.counters
    assert a.counters["solve_converged"] and a.counters["solve_residual"] <= 1e-8
    c = render(scene, patches=64, display="flat", solver="jacobi", reuse=True)
    assert not c.counters["solve_cached"]
    np.testing.assert_allclose(c.image, a.image, rtol=1e-5, atol=1e-6)


# ------------------------------------------------ against Mitsuba references ---

@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", ["cornell/cornell_box.xml", "cornell/diffuse_room.xml"])
def test_error_falls_with_patch_refinement_against_mitsuba_full(scene):
    from references.reference import get_reference
    from reports.metrics import mae, relmse

    ref = get_reference(SUITES / scene, transport="full", spp=1024, passes=8)
    sc = load_scene(SUITES / scene)
    rows = []
    for n in (64, 256, 1024):
        img = render(sc, patches=n, spp=4).image
        rows.append((n, relmse(ref.image, img), mae(ref.image, img)))
    print(scene, rows)
    rel = [r[1] for r in rows]
    abs_ = [r[2] for r in rows]
    assert rel[0] > rel[1] > rel[2] and abs_[0] > abs_[1] > abs_[2], rows
    assert rel[2] < 0.5 * rel[0]


def test_views_of_one_solution_equal_full_renders_per_view():
    """View independence (thesis 3.4): displaying each of 3 views from one solution gives the
    image a full render (mesh, form factors, solve, display) of that view gives.  Negative
    control: a solution of the scene with other reflectances does not."""
    import dataclasses

    from gibench.studies.radiosity import camera_views, view_independence

    base = load_scene(SUITES / "cornell" / "cornell_box.xml")
    params = RADIOSITY.parse_params({"patches": 64, "display": "gouraud"})
    sol = radiosity.solve_scene(base, params)
    views = camera_views(base, 3, 30.0)
    assert not np.allclose(views[0].camera.to_world, views[2].camera.to_world)
    for view in views:
        shared, _, _ = radiosity.display(view, sol, mode="gouraud")
        radiosity.clear_cache()
        fresh = RADIOSITY.render(view, params).image
        np.testing.assert_allclose(shared, fresh, rtol=1e-5, atol=1e-7)
    grey = dataclasses.replace(base, materials=[dataclasses.replace(m, reflectance=(0.3, 0.3, 0.3))
                                                for m in base.materials])
    other = radiosity.solve_scene(grey, params)
    wrong, _, _ = radiosity.display(views[1], other, mode="gouraud")
    assert not np.allclose(wrong, RADIOSITY.render(views[1], params).image, rtol=1e-3)
    rows = view_independence(views=(1, 2), patches=32, spp=1, path_spp=1)
    assert [r["views"] for r in rows] == [1, 2]
    assert rows[1]["radiosity_total_s"] >= rows[0]["radiosity_total_s"] and rows[0]["solve_s"] > 0
