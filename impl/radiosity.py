"""Radiosity — registered as ``radiosity`` (thesis chapter 3).

What it computes
----------------
The rendering equation (thesis 3.2) restricted to Lambertian surfaces and
constant radiosity per patch becomes the linear system of 3.2.3,

    B_i = E_i + ρ_i Σ_j F_ij B_j ,

solved once for the whole scene (view-independent), then displayed from the
scene's camera.  The pipeline (thesis 3.3):

1. mesh every planar shape into patches (:mod:`impl.patches`; ``patch_size``
   or ``patches``); emitters get E = π L_e, every patch its diffuse ρ (RGB);
2. form factors (:mod:`impl.form_factors`): ``contour`` (hemisphere / Nusselt
   analog, 3.4.1, closed form × shadow-ray visibility), ``hemicube`` (3.4.2,
   ray-cast item buffers), ``hemicube-zbuffer`` (3.4.2, patches projected
   onto the five faces by the z-buffer rasteriser), ``point`` (the thesis's
   point approximation A_j cos cos / (π r²), for ablation) or ``montecarlo``
   (area-to-area ray shooting);
3. solve (:mod:`impl.radiosity_solvers`): ``jacobi``, ``gauss-seidel``,
   ``progressive`` refinement or the ``direct`` dense solve;
4. display: eye rays (pixel centres, or k×k jittered strata with a box filter
   as in ``raycast``) find the visible point; its radiance is B/π, with B
   constant per patch (``flat``) or interpolated from vertex radiosities
   (``gouraud``).  An emitter shows B/π = L_e + its reflected light, as
   Mitsuba's emitters do (the reflected part is tiny for a ceiling light).

Full diffuse interreflection: compared with Mitsuba's path tracer (``full``).
Mitsuba's ``max_depth`` cuts paths; ``max_bounces = max_depth − 1`` (Jacobi
for exactly that many bounces, the Neumann series) reproduces that cut, while
the default −1 solves the full system.

Caching: the mesh's form factors and the solution are cached within the
process, keyed by a hash of the patch geometry, reflectances and emission and
by the parameters that affect them; with ``reuse=true`` re-rendering with
another ``display`` or ``spp`` only redoes the view (off by default, so a
timed render is the whole method).  Counters report ``formfactor_s``,
``solve_s`` (as measured when first computed) and ``view_s`` separately, and
``solve_cached`` says whether this call reused them.

A ``constant`` environment emitter (uniform radiance L_env from every
direction) is an enclosing emitter: patch i receives π L_env times the
fraction V_i of its cosine-weighted hemisphere that escapes the scene, so its
emission becomes E_i + ρ_i π L_env V_i before the solve (V_i estimated with
``env_rays`` cosine-weighted rays from uniform points on the patch,
:func:`environment_fraction`); eye rays that escape show L_env.  The light it
brings after one or more bounces follows from the solve as any other.

Spheres are meshed into flat patches (``sphere_segments``, :mod:`impl.patches`).

Leaves out: non-diffuse and two-sided materials (refused with
``NotImplementedError`` naming the shape), textures (the mean reflectance),
delta lights (point/spot/directional, refused), adaptive subdivision and
discontinuity meshing, so shadows are as sharp as the patches are small and
coarse patches straddling a wall leak light (a study in
:mod:`gibench.studies.radiosity`).

Parameters
----------
============  ======  ============  ===========================================
name          type    default       meaning
============  ======  ============  ===========================================
formfactor    str     contour       contour | hemicube | hemicube-zbuffer | point | montecarlo
hemicube_res  int     64            hemicube top-face resolution (even)
ff_points     int     1             k: k×k quadrature points on patch i (1 = centre)
vis_rays      int     4             contour, point: shadow rays per pair (k²; 0 = none)
mc_samples    int     1024          montecarlo: rays per patch
patches       int     256           target patch count (when patch_size = 0)
patch_size    float   0             target patch edge length (overrides patches)
solver        str     gauss-seidel  jacobi | gauss-seidel | progressive | direct
tol           float   1e-8          relative residual to stop at
max_iter      int     10000         iteration cap (progressive: N shots each)
max_bounces   int     -1            ≥ 0: Neumann series of that many bounces
display       str     gouraud       flat | gouraud
spp           int     1             1 = pixel centre, k² = k×k jittered strata
ambient       bool    true          progressive: add the ambient term to the display
env_rays      int     256           constant environment: rays per patch for V_i
============  ======  ============  ===========================================

``sphere_segments`` (int, 12): segments around a sphere meshed into patches.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene
from core.errors import ParamError, UnsupportedError

from .camera import camera_params, eye_ray
from .form_factors import METHODS, FormFactors, _eps, form_factors
from .lighting import sample_cosine_hemisphere
from .rng import uniform
from .patches import PatchMesh, closest_face, locate, mesh_scene, vertex_radiosity
from .radiosity_solvers import SOLVERS, SolveResult, neumann, residual, solve
from .sampling import check_spp, pixel_sample, strata, variance_of_mean, welford_add

__all__ = ["render", "solve_scene", "display", "Solution", "clear_cache", "ALGORITHM",
           "DISPLAYS", "environment_fraction"]

DISPLAYS = ("flat", "gouraud")

#: Most recent form-factor matrices and solutions kept (each F is N² float64).
CACHE_SIZE = 4
_FF_CACHE: OrderedDict = OrderedDict()
_SOLVE_CACHE: OrderedDict = OrderedDict()

_FF_KEYS = ("formfactor", "hemicube_res", "ff_points", "vis_rays", "mc_samples")
_SOLVE_KEYS = ("solver", "tol", "max_iter", "max_bounces")


class Solution(NamedTuple):
    """A view-independent radiosity solution."""

    mesh: PatchMesh
    ff: FormFactors
    result: SolveResult
    B_display: np.ndarray       # B (+ the ambient term for progressive partial solutions)
    cached: bool

    def __repr__(self) -> str:
        return (f"Solution({self.mesh!r}, ff={self.ff.method} {self.ff.seconds:.3f} s, "
                f"{self.result!r}, cached={self.cached})")


def clear_cache() -> None:
    """Forget every cached form-factor matrix and solution."""
    _FF_CACHE.clear()
    _SOLVE_CACHE.clear()


def _remember(cache: OrderedDict, key, value):
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > CACHE_SIZE:
        cache.popitem(last=False)


def _check_lights(scene: Scene) -> None:
    if scene.lights:
        kinds = ", ".join(sorted({l.kind for l in scene.lights}))
        raise UnsupportedError(f"radiosity: the scene has delta lights ({kinds}); radiosity models "
                                  "area emitters on diffuse polygons only")


@njit(cache=True)
def _escape_fraction(M: PatchMesh, i, rays, seed, eps):
    """Fraction of ``rays`` cosine-weighted rays from uniform points of patch i that
    leave the scene (stratified directions when ``rays`` is a square)."""
    q = int(math.sqrt(rays) + 0.5)
    stratified = q * q == rays
    P = M.poly[i]
    nx, ny, nz = M.normal[i, 0], M.normal[i, 1], M.normal[i, 2]
    free = 0
    for k in range(rays):
        a = uniform(seed, i, k, 0)
        b = uniform(seed, i, k, 1)
        c = uniform(seed, i, k, 2)
        d = uniform(seed, i, k, 3)
        if stratified:
            c = (k % q + c) / q
            d = (k // q + d) / q
        if M.nverts[i] == 4:            # parallelogram: P0 + a (P1 − P0) + b (P3 − P0)
            w0, w1, w2, w3 = 1.0 - a - b, a, 0.0, b
        else:                           # triangle: square-to-triangle warp
            su = math.sqrt(a)
            w0, w1, w2, w3 = 1.0 - su, su * (1.0 - b), su * b, 0.0
        px = w0 * P[0, 0] + w1 * P[1, 0] + w2 * P[2, 0] + w3 * P[3, 0] + eps * nx
        py = w0 * P[0, 1] + w1 * P[1, 1] + w2 * P[2, 1] + w3 * P[3, 1] + eps * ny
        pz = w0 * P[0, 2] + w1 * P[1, 2] + w2 * P[2, 2] + w3 * P[3, 2] + eps * nz
        dx, dy, dz, cos_t = sample_cosine_hemisphere(c, d, nx, ny, nz)
        if closest_face(M, px, py, pz, dx, dy, dz, 0.0, np.inf)[1] < 0:
            free += 1
    return free / rays


@njit(parallel=True, cache=True)
def _escape_kernel(M: PatchMesh, rays, seed, eps, out):
    for c in prange(out.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        out[i] = _escape_fraction(M, i, rays, seed, eps)


def environment_fraction(M: PatchMesh, rays: int = 256, seed: int = 0) -> np.ndarray:
    """V_i: the cosine-weighted fraction of each patch's hemisphere that sees no
    surface (N,), i.e. its form factor to an enclosing environment."""
    if rays < 1:
        raise ParamError(f"radiosity: env_rays must be >= 1, got {rays}")
    out = np.zeros(M.n_patches)
    _escape_kernel(M, rays, seed, _eps(M), out)
    return out


def _with_environment(scene: Scene, M: PatchMesh, rays: int, seed: int) -> PatchMesh:
    """The mesh with E_i + ρ_i π L_env V_i as emission (unchanged without an environment)."""
    if getattr(scene, "environment", None) is None:
        return M
    L = np.asarray(scene.environment, dtype=np.float64)
    V = environment_fraction(M, rays, seed)
    return M._replace(emit=M.emit + M.rho * (math.pi * L)[None, :] * V[:, None])


def _check(params: dict) -> None:
    check_spp(params["spp"], "radiosity")
    if params["ff_points"] < 1:
        raise ParamError(f"radiosity: ff_points must be >= 1, got {params['ff_points']}")
    if params["patches"] < 0 or params["patch_size"] < 0:
        raise ParamError("radiosity: patches and patch_size must be >= 0")


def solve_scene(scene: Scene, params: dict, *, seed: int = 0, mesh: PatchMesh | None = None) -> Solution:
    """Mesh, form factors and solve (cached); ``params`` as parsed by the registry."""
    _check(params)
    M = mesh if mesh is not None else mesh_scene(scene, patch_size=params["patch_size"],
                                                 patches=params["patches"],
                                                 sphere_segments=params["sphere_segments"])
    _check_lights(scene)
    M = _with_environment(scene, M, params["env_rays"], seed)
    digest = M.digest()
    ff_key = (digest,) + tuple(params[k] for k in _FF_KEYS) + ((seed,) if params["formfactor"] == "montecarlo" else ())
    solve_key = ff_key + tuple(params[k] for k in _SOLVE_KEYS)
    if params["reuse"] and solve_key in _SOLVE_CACHE:
        sol = _SOLVE_CACHE[solve_key]
        return sol._replace(cached=True)
    ff = _FF_CACHE.get(ff_key) if params["reuse"] else None
    if ff is None:
        ff = form_factors(M, params["formfactor"], hemicube_res=params["hemicube_res"],
                          points=params["ff_points"], vis_rays=params["vis_rays"],
                          mc_samples=params["mc_samples"], seed=seed)
        _remember(_FF_CACHE, ff_key, ff)
    if params["max_bounces"] >= 0:
        t0 = time.perf_counter()
        B = neumann(ff.F, M.rho, M.emit, params["max_bounces"])
        dt = time.perf_counter() - t0
        r = residual(ff.F, M.rho, M.emit, B)
        res = SolveResult(B=B, ambient=np.zeros_like(B), iterations=params["max_bounces"], shots=0,
                          residuals=np.array([r]), times=np.array([dt]), seconds=dt, converged=False,
                          solver=f"neumann-{params['max_bounces']}")
    else:
        res = solve(ff.F, M.rho, M.emit, M.area, params["solver"], tol=params["tol"],
                    max_iter=params["max_iter"], source=f"formfactor={params['formfactor']}")
    B_disp = res.B + (res.ambient if params["ambient"] else 0.0)
    sol = Solution(mesh=M, ff=ff, result=res, B_display=B_disp, cached=False)
    _remember(_SOLVE_CACHE, solve_key, sol)
    return sol


# ---------------------------------------------------------------- display ---

@njit(cache=True)
def _shade(M: PatchMesh, B, V, gouraud, env, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Displayed radiance B/π of the first front-facing surface along an eye ray
    (``env``: the environment radiance an escaping ray sees)."""
    t, f = closest_face(M, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if f < 0:
        return env[0], env[1], env[2]
    if dx * M.face_n[f, 0] + dy * M.face_n[f, 1] + dz * M.face_n[f, 2] >= 0.0:
        return 0.0, 0.0, 0.0                       # back of a one-sided surface: black
    patch, v0, v1, v2, v3, w0, w1, w2, w3 = locate(M, f, ox + t * dx, oy + t * dy, oz + t * dz)
    inv_pi = 1.0 / math.pi
    if not gouraud:
        return B[patch, 0] * inv_pi, B[patch, 1] * inv_pi, B[patch, 2] * inv_pi
    r = (w0 * V[v0, 0] + w1 * V[v1, 0] + w2 * V[v2, 0] + w3 * V[v3, 0]) * inv_pi
    g = (w0 * V[v0, 1] + w1 * V[v1, 1] + w2 * V[v2, 1] + w3 * V[v3, 1]) * inv_pi
    b = (w0 * V[v0, 2] + w1 * V[v1, 2] + w2 * V[v2, 2] + w3 * V[v3, 2]) * inv_pi
    return r, g, b


@njit(cache=True)
def _pixel(cam, M: PatchMesh, B, V, gouraud, env, x, y, spp, seed):
    """Mean and variance of the mean of one pixel (a function of its own so that
    the accumulators are private to the thread running the pixel)."""
    pixel = y * int(cam[14]) + x
    k = strata(spp)
    m0 = m1 = m2 = 0.0
    q0 = q1 = q2 = 0.0
    for s in range(spp):
        fx, fy = pixel_sample(spp, k, s, seed, pixel)
        ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + fx, y + fy)
        r, g, b = _shade(M, B, V, gouraud, env, ox, oy, oz, dx, dy, dz, tmin, tmax)
        m0, m1, m2, q0, q1, q2 = welford_add(s, r, g, b, m0, m1, m2, q0, q1, q2)
    return (m0, m1, m2, variance_of_mean(q0, spp), variance_of_mean(q1, spp),
            variance_of_mean(q2, spp))


@njit(parallel=True, cache=True)
def _display_kernel(cam, M: PatchMesh, B, V, gouraud, env, spp, seed, mean, var):
    W, H = int(cam[14]), int(cam[15])
    for c in prange(W * H):
        pixel = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        x = pixel % W
        y = pixel // W
        out = _pixel(cam, M, B, V, gouraud, env, x, y, spp, seed)
        mean[y, x, 0] = out[0]
        mean[y, x, 1] = out[1]
        mean[y, x, 2] = out[2]
        var[y, x, 0] = out[3]
        var[y, x, 1] = out[4]
        var[y, x, 2] = out[5]


def display(scene: Scene, sol: Solution, *, mode: str = "gouraud", spp: int = 1, seed: int = 0):
    """Image (H, W, 3), variance of the pixel mean (or None) and the view time."""
    if mode not in DISPLAYS:
        raise ParamError(f"radiosity: display must be one of {', '.join(DISPLAYS)}, got {mode!r}")
    t0 = time.perf_counter()
    M = sol.mesh
    B = np.ascontiguousarray(sol.B_display)
    V = vertex_radiosity(M, B) if mode == "gouraud" else np.zeros((1, 3))
    cam = camera_params(scene.camera)
    H, W = scene.camera.film.height, scene.camera.film.width
    mean = np.zeros((H, W, 3))
    var = np.zeros((H, W, 3))
    env = np.zeros(3) if getattr(scene, "environment", None) is None else \
        np.asarray(scene.environment, dtype=np.float64)
    _display_kernel(cam, M, B, V, mode == "gouraud", env, spp, seed, mean, var)
    return mean, (var if spp > 1 else None), time.perf_counter() - t0


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    t0 = time.perf_counter()
    sol = solve_scene(scene, params, seed=seed)
    t_solve_call = time.perf_counter() - t0
    mean, var, view_s = display(scene, sol, mode=params["display"], spp=params["spp"], seed=seed)
    res = sol.result
    r = res.residuals
    drop = (r[-1] / r[0]) ** (1.0 / max(res.iterations, 1)) if r[0] > 0 and r[-1] > 0 else 0.0
    decades = math.log10(r[0] / r[-1]) if r[0] > 0 and r[-1] > 0 else float("nan")
    H, W = mean.shape[:2]
    counters = {
        "patches": sol.mesh.n_patches,
        "formfactor_rays": sol.ff.rays,
        "camera_rays": int(W * H * params["spp"]),
        "formfactor_s": sol.ff.seconds,
        "solve_s": res.seconds,
        "view_s": view_s,
        "solve_call_s": t_solve_call,
        "solve_cached": sol.cached,
        "solve_iterations": res.iterations,
        "solve_shots": res.shots,
        "solve_residual": float(r[-1]),
        "residual_factor_per_iteration": float(drop),
        "residual_decades_per_s": float(decades / res.seconds) if res.seconds > 0 else float("nan"),
        "solve_converged": res.converged,
    }
    return RenderResult(image=mean.astype(np.float32),
                        variance=var.astype(np.float32) if var is not None else None,
                        counters=counters)


ALGORITHM = Algorithm(
    name="radiosity",
    summary="Radiosity: patches, form factors (contour / hemicube / Monte Carlo), iterative solvers, "
            "flat or Gouraud display (full diffuse interreflection)",
    section="thesis 3.2.3-3.4",
    transport="full",
    params=(
        Param("formfactor", str, "contour", "form-factor method", choices=METHODS),
        Param("hemicube_res", int, 64, "hemicube top-face resolution (even)"),
        Param("ff_points", int, 1, "k: k×k quadrature points on the emitting patch (1 = centre)"),
        Param("vis_rays", int, 4, "contour, point: shadow rays per patch pair (square; 0 = no occlusion test)"),
        Param("mc_samples", int, 1024, "montecarlo: rays shot per patch"),
        Param("patches", int, 256, "target patch count (used when patch_size = 0)"),
        Param("patch_size", float, 0.0, "target patch edge length (0 = use patches)"),
        Param("sphere_segments", int, 12, "segments around a sphere meshed into patches (UV sphere)"),
        Param("solver", str, "gauss-seidel", "linear solver", choices=SOLVERS),
        Param("tol", float, 1e-8, "relative residual to stop at"),
        Param("max_iter", int, 10000, "iteration cap (progressive: N shots per iteration)"),
        Param("max_bounces", int, -1, ">= 0: Neumann series with this many bounces (Mitsuba max_depth - 1)"),
        Param("display", str, "gouraud", "radiosity display", choices=DISPLAYS),
        Param("spp", int, 1, "pixel samples: 1 = pixel centre, k² = k×k jittered strata (box filter)"),
        Param("ambient", bool, True, "progressive: add the ambient term to the displayed radiosity"),
        Param("env_rays", int, 256, "constant environment: cosine-weighted rays per patch for the "
                                    "fraction of its hemisphere that sees the environment"),
        Param("reuse", bool, False, "reuse this process's cached form factors and solution (a view-only "
                                    "re-render); off, every render is timed from meshing to pixels"),
    ),
    render=render,
)
