"""Radiosity studies (thesis ch. 3): error against patch count and time,
and the form-factor hard cases.  Each study returns a list of flat row dicts.

========================  =====================================================
study                     what it measures
========================  =====================================================
``error_vs_patches``      own radiosity vs Mitsuba's 1024-spp full reference:
                          relMSE, MAE per scene × form factor × solver × patch
                          count, with form-factor, solve and view times (the
                          error-vs-patches and error-vs-time curves)
``mitsuba_ladder``        Mitsuba's own path tracer at spp 4 … 256 against the
                          same reference, timed in the same run
                          (:func:`gibench.ladder.mitsuba_ladder`)
``adjacent_patches``      two square patches sharing an edge: F from the centre
                          rule, k×k Gauss and graded rules, hemicube and Monte
                          Carlo against C-14 = 0.200044 (scale-free), and the
                          face-to-face sum as the faces are subdivided
``hemicube_aliasing``     a small square at distance d, off-axis, seen from a
                          point: hemicube F at res 8 … 256 against the exact
                          point-to-polygon value (relative error, and whether
                          the patch was missed altogether)
``thin_gap``              light leaking under a partition 0.02 above the floor
                          (suites/cornell/thin_gap.xml): the dark side's mean
                          radiance, own / Mitsuba, per patch count and method
``view_independence``     thesis 3.4's closing point: one solve, N views.
                          Radiosity's total time (form factors + solve once,
                          then one display per view) against N renders of
                          the own path tracer, per N
========================  =====================================================

Times are wall-clock on whatever machine runs the study; every row carries
the patch count, so the curves can be redrawn.  Compilation is kept out of
the times by one untimed warm-up render per study.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from core.provenance import REPO_ROOT

from . import StudyInfo, as_config, read_config, run_registered, table_titles

__all__ = ["STUDIES", "TABLES", "DEFAULT_CONFIG", "load_config", "run_studies", "error_vs_patches",
           "adjacent_patches", "hemicube_aliasing", "thin_gap", "view_independence", "camera_views"]

DEFAULT_CONFIG = REPO_ROOT / "suites" / "radiosity" / "studies.toml"
SUITES = REPO_ROOT / "suites"


def _algo():
    from .. import registry

    return registry.get("radiosity")


def _reference(scene_path, spp=1024, passes=8):
    from references.reference import get_reference

    return get_reference(scene_path, transport="full", spp=spp, passes=passes)


# ======================================================== error vs patches ===

def error_vs_patches(*, scenes, patch_counts, formfactors=("contour",), solvers=("gauss-seidel",),
                     displays=("gouraud",), spp=4, hemicube_res=64, mc_samples=256, max_bounces=-1,
                     reference_spp=1024) -> list[dict]:
    """Render each scene at each patch count, form-factor method, solver and display;
    compare with the full reference.  Times: form factors, solve and view, measured
    fresh (caches cleared) after one warm-up render."""
    from impl import radiosity
    from reports.metrics import mae, relmse

    algo = _algo()
    from core.loader import load_scene

    rows = []
    for scene_id in scenes:
        path = SUITES / scene_id
        scene = load_scene(path)
        ref = _reference(path, spp=reference_spp)
        warm = {"patches": 16, "spp": spp}
        for ff in formfactors:
            for solver in solvers:
                radiosity.clear_cache()
                algo.render(scene, algo.parse_params(dict(warm, formfactor=ff, solver=solver,
                                                          hemicube_res=8, mc_samples=16)))
        for n in patch_counts:
            for ff in formfactors:
                for solver in solvers:
                    for disp in displays:
                        radiosity.clear_cache()
                        params = algo.parse_params({"patches": n, "formfactor": ff, "solver": solver,
                                                    "display": disp, "spp": spp, "hemicube_res": hemicube_res,
                                                    "mc_samples": mc_samples, "max_bounces": max_bounces})
                        t0 = time.perf_counter()
                        res = algo.render(scene, params)
                        total = time.perf_counter() - t0
                        c = res.counters
                        rows.append({
                            "scene": scene_id, "patches": c["patches"], "target_patches": n,
                            "formfactor": ff, "solver": solver, "display": disp, "spp": spp,
                            "max_bounces": max_bounces,
                            "relmse": relmse(ref.image, res.image), "mae": mae(ref.image, res.image),
                            "formfactor_s": c["formfactor_s"], "solve_s": c["solve_s"], "view_s": c["view_s"],
                            "total_s": total, "iterations": c["solve_iterations"],
                            "residual": c["solve_residual"], "formfactor_rays": c["formfactor_rays"],
                        })
    return rows


# ======================================================== adjacent patches ===

def _squares(side, n):
    from impl.patches import FACE_PARALLELOGRAM, Polygon, mesh_polygons

    g, z = (0.5, 0.5, 0.5), (0.0, 0.0, 0.0)
    floor = Polygon(FACE_PARALLELOGRAM, np.zeros(3), np.array([side, 0, 0.0]), np.array([0, side, 0.0]), g, z)
    wall = Polygon(FACE_PARALLELOGRAM, np.zeros(3), np.array([0, 0, side]), np.array([side, 0, 0.0]), g, z)
    return mesh_polygons([floor, wall], patch_size=side / n + 1e-12)


def adjacent_patches(*, subdivisions=(1, 2, 4, 8), rules=None, hemicube_res=(64, 256),
                     mc_samples=100000, seed=1) -> list[dict]:
    """Perpendicular unit squares sharing an edge (Howell C-14, 0.200044 for any size).

    Per rule: the form factor of the two *corner* patches touching the shared
    edge (each 1/n wide: the singular pair, exact value C-14 again) and the
    face-to-face sum (1/A_floor) Σ A_i F_ij, exact C-14.
    """
    from impl.form_factors import form_factors

    exact = _c14()
    rules = rules or [("contour", {"points": 1}), ("contour", {"points": 4}), ("contour", {"points": 16}),
                      ("contour", {"points": 16, "graded": True})]
    rules = list(rules) + [("hemicube", {"hemicube_res": r, "points": 1}) for r in hemicube_res] \
        + [("montecarlo", {"mc_samples": mc_samples, "seed": seed})]
    rows = []
    for n in subdivisions:
        M = _squares(1.0, n)
        floor = M.patch_face == 0
        wall = ~floor
        # Corner pair: the floor patch and the wall patch at x ∈ [0, 1/n] along the shared edge.
        fi = int(np.flatnonzero(floor & (M.centre[:, 0] < 1.0 / n) & (M.centre[:, 1] < 1.0 / n))[0])
        wj = int(np.flatnonzero(wall & (M.centre[:, 0] < 1.0 / n) & (M.centre[:, 2] < 1.0 / n))[0])
        for method, kw in rules:
            if method != "contour":
                kw = dict(kw)
            ff = form_factors(M, method, vis_rays=0, **kw) if method == "contour" else form_factors(M, method, **kw)
            F = ff.F
            total = float((M.area[floor, None] * F[np.ix_(floor, wall)]).sum() / M.area[floor].sum())
            row = {"subdivisions": n, "patches_per_face": n * n, "method": method,
                   "rule": ", ".join(f"{k}={v}" for k, v in kw.items() if k != "seed"),
                   "F_corner_pair": float(F[fi, wj]), "corner_rel_err": float(F[fi, wj] / exact - 1.0),
                   "F_face_sum": total, "face_rel_err": total / exact - 1.0, "exact": exact,
                   "seconds": ff.seconds}
            if ff.halfwidth is not None:
                row["corner_ci99"] = float(ff.halfwidth[fi, wj])
            rows.append(row)
    return rows


def _c14(h=1.0, w=1.0, l=1.0):
    H, W = h / l, w / l
    s = math.sqrt(H * H + W * W)
    a = (1 + W * W) * (1 + H * H) / (1 + W * W + H * H)
    b = (W * W * (1 + W * W + H * H) / ((1 + W * W) * (W * W + H * H))) ** (W * W)
    c = (H * H * (1 + H * H + W * W) / ((1 + H * H) * (H * H + W * W))) ** (H * H)
    return (W * math.atan(1 / W) + H * math.atan(1 / H) - s * math.atan(1 / s) + 0.25 * math.log(a * b * c)) / (math.pi * W)


# ======================================================= hemicube aliasing ===

def hemicube_aliasing(*, resolutions=(8, 16, 32, 64, 128, 256), sizes=(0.02, 0.05, 0.1, 0.3),
                      distance=1.0, offsets=(0.0, 0.37, 1.3)) -> list[dict]:
    """A square of side ``size`` parallel to a receiver, at height ``distance`` and lateral
    offset ``offset``; the receiver is one patch whose centre is the hemicube's eye.
    Exact: the contour formula at that point."""
    from impl.form_factors import form_factors, point_form_factor
    from impl.patches import FACE_PARALLELOGRAM, Polygon, mesh_polygons

    g, z = (0.5, 0.5, 0.5), (0.0, 0.0, 0.0)
    rows = []
    for size in sizes:
        for off in offsets:
            # Receiver: 0.01-wide square centred at the origin, facing +z.
            rec = Polygon(FACE_PARALLELOGRAM, np.array([-0.005, -0.005, 0.0]), np.array([0.01, 0, 0.0]),
                          np.array([0, 0.01, 0.0]), g, z)
            lo = np.array([off - size / 2, -size / 2 + 0.013, distance])     # off the cell grid
            tgt = Polygon(FACE_PARALLELOGRAM, lo, np.array([0, size, 0.0]), np.array([size, 0, 0.0]), g, z)
            M = mesh_polygons([rec, tgt])
            exact = point_form_factor(M.centre[0], M.normal[0], M.poly[1])
            for res in resolutions:
                F = form_factors(M, "hemicube", hemicube_res=res, points=1).F[0, 1]
                rows.append({"size": size, "distance": distance, "offset": off, "res": res,
                             "size_in_cells": size / distance * res / 2.0,
                             "exact": exact, "hemicube": float(F), "rel_err": float(F / exact - 1.0),
                             "missed": bool(F == 0.0)})
    return rows


# ================================================================ thin gap ===

def _dark_side_mask(scene, x_split):
    """Pixels whose centre ray first hits a surface with x > x_split (the dark side)."""
    from impl.raycast import cast_primary

    depth, _ = cast_primary(scene)
    cam = scene.camera
    W, H = cam.film.width, cam.film.height
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    tx = cam.tan_half_fov_x
    d = np.stack(np.broadcast_arrays((1 - 2 * u)[None, :] * tx, (1 - 2 * v)[:, None] * tx / cam.film.aspect,
                                     np.ones((H, W))), axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d = d @ cam.to_world[:3, :3].T
    p = cam.origin + np.where(np.isfinite(depth), depth, 0.0)[..., None] * d
    return np.isfinite(depth) & (p[..., 0] > x_split)


def thin_gap(*, scene="cornell/thin_gap.xml", patch_counts=(64, 256, 1024, 4096),
             formfactors=("contour", "hemicube"), spp=4, x_split=0.07, reference_spp=1024) -> list[dict]:
    """Mean radiance of the dark side (beyond the partition) own vs Mitsuba: leak ratio."""
    from impl import radiosity
    from reports.metrics import relmse

    from core.loader import load_scene

    algo = _algo()
    path = SUITES / scene
    sc = load_scene(path)
    ref = _reference(path, spp=reference_spp)
    mask = _dark_side_mask(sc, x_split)
    ref_dark = float(ref.image[mask].mean())
    ref_lit = float(ref.image[~mask].mean())
    rows = []
    for n in patch_counts:
        for ff in formfactors:
            radiosity.clear_cache()
            res = algo.render(sc, algo.parse_params({"patches": n, "formfactor": ff, "spp": spp}))
            own_dark = float(res.image[mask].mean())
            rows.append({"scene": scene, "patches": res.counters["patches"], "formfactor": ff,
                         "dark_pixels": int(mask.sum()), "own_dark_mean": own_dark, "mitsuba_dark_mean": ref_dark,
                         "leak_ratio": own_dark / ref_dark if ref_dark > 0 else float("inf"),
                         "own_lit_mean": float(res.image[~mask].mean()), "mitsuba_lit_mean": ref_lit,
                         "relmse": relmse(ref.image, res.image),
                         "total_s": res.counters["formfactor_s"] + res.counters["solve_s"] + res.counters["view_s"]})
    return rows


def camera_views(scene, n: int, spread_deg: float):
    """``n`` copies of ``scene`` whose cameras turn about their own up axis by angles spread
    evenly over [−spread/2, spread/2] degrees (the same position, n different views)."""
    import dataclasses

    angles = np.linspace(-0.5, 0.5, n) * spread_deg if n > 1 else np.zeros(1)
    out = []
    for a in np.deg2rad(angles):
        rot = np.eye(4)
        rot[0, 0], rot[0, 2], rot[2, 0], rot[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
        cam = dataclasses.replace(scene.camera, to_world=scene.camera.to_world @ rot)
        out.append(dataclasses.replace(scene, camera=cam))
    return out


def view_independence(*, scene="cornell/cornell_box.xml", views=(1, 2, 4, 8, 16), spread_deg=30.0,
                      patches=256, formfactor="contour", display="gouraud", spp=4,
                      path_spp=16, path_max_depth=-1) -> list[dict]:
    """Rows per N in ``views``: radiosity's time for N views of one solution against N
    path-traced renders (own ``path``, ``path_spp`` samples per pixel, ``path_max_depth``).

    The max(views) views are rendered once by each method (after one untimed warm-up of
    each) and the totals for smaller N are the sums over the first N of them, so the rows
    share one measurement.  Radiosity: ``solve_s`` (meshing, form factors and solve, caches
    cleared) plus the display time of each view; the path tracer renders every view from
    scratch.  ``crossover`` is whether radiosity's total is the smaller.  The two methods
    are not at equal error (radiosity is biased, the path tracer noisy): times only.
    """
    from impl import radiosity as rad

    from .. import registry

    sc = _scene_path(scene)
    from core.loader import load_scene

    base = load_scene(sc)
    n_max = max(views)
    scenes = camera_views(base, n_max, spread_deg)
    ralgo = registry.get("radiosity")
    params = ralgo.parse_params({"patches": patches, "formfactor": formfactor, "display": display, "spp": spp})
    palgo = registry.get("path")
    pparams = palgo.parse_params({"spp": path_spp, "max_depth": path_max_depth})
    # Warm-up (compilation) of both, untimed.
    rad.clear_cache()
    ralgo.render(scenes[0], params, seed=0)
    palgo.render(scenes[0], pparams, seed=0)
    rad.clear_cache()
    t0 = time.perf_counter()
    sol = rad.solve_scene(base, params, seed=0)
    solve_s = time.perf_counter() - t0
    view_s = []
    for s in scenes:
        t0 = time.perf_counter()
        rad.display(s, sol, mode=display, spp=spp, seed=0)
        view_s.append(time.perf_counter() - t0)
    path_s = []
    for s in scenes:
        t0 = time.perf_counter()
        palgo.render(s, pparams, seed=0)
        path_s.append(time.perf_counter() - t0)
    rows = []
    for n in views:
        r_total = solve_s + sum(view_s[:n])
        p_total = sum(path_s[:n])
        rows.append({"scene": str(scene), "views": int(n), "patches": sol.mesh.n_patches,
                     "formfactor": formfactor, "path_spp": path_spp,
                     "solve_s": solve_s, "view_s_median": float(np.median(view_s[:n])),
                     "radiosity_total_s": r_total, "radiosity_per_view_s": r_total / n,
                     "path_total_s": p_total, "path_per_view_s": p_total / n,
                     "path_over_radiosity": p_total / r_total, "crossover": bool(r_total < p_total)})
    return rows


def _scene_path(scene):
    p = Path(scene)
    return p if p.is_absolute() else SUITES / p


# ================================================================ registry ===

STUDIES = {s.name: s for s in (
    StudyInfo("error_vs_patches", "Radiosity: error vs patch count and time",
              "Own radiosity (mesh, form factors, solve, Gouraud/flat display) against Mitsuba's 1024-spp "
              "path-traced reference: relMSE and mean absolute error per patch count, form-factor method and "
              "solver, with form-factor, solve and view times (caches cleared, warm-up excluded).",
              error_vs_patches),
    StudyInfo("adjacent_patches", "Radiosity: form factor of adjacent patches (shared edge)",
              "Perpendicular squares sharing an edge (Howell C-14 = 0.200044, independent of size): the corner "
              "pair's form factor and the face-to-face sum per rule (centre point, k×k Gauss, graded Gauss, "
              "hemicube at the centre, Monte Carlo) and subdivision.  The point rules miss the singular "
              "1/r² near the shared edge.", adjacent_patches),
    StudyInfo("hemicube_aliasing", "Radiosity: hemicube aliasing on small distant patches",
              "A small square (size 0.02 … 0.3 at distance 1, on and off axis) seen from a point: hemicube "
              "form factor at resolution 8 … 256 against the exact point-to-polygon value; 'missed' marks a "
              "patch that fell between cell centres.", hemicube_aliasing),
    StudyInfo("thin_gap", "Radiosity: light leaking through a thin gap",
              "A partition 0.02 above the floor splits a lit from a dark half; patches of floor and ceiling "
              "straddle it.  Mean radiance of the dark side, own / Mitsuba (leak ratio), per patch count.",
              thin_gap),
    StudyInfo("view_independence", "Radiosity: one solve, many views",
              "Radiosity's time for N views of one solution (form factors and solve once, then a display "
              "per view) against N renders of the own path tracer, per N (thesis 3.4: once the form "
              "factors are computed a new view needs only the shading).  Times only, not at equal error.",
              view_independence),
)}

TABLES = table_titles(STUDIES)
TABLES["error_vs_time"] = (
    "Radiosity and Mitsuba: error vs time",
    "relMSE against the 1024-spp full-transport reference vs wall time, for every radiosity "
    "configuration of the patch-count study (form factors + solve + one view) and Mitsuba's path tracer "
    "at its spp ladder, measured in the same run.")
TABLES["mitsuba_ladder"] = (
    "Mitsuba path tracer: error vs time",
    "Mitsuba's path tracer at spp 4 … 256 (fixed seeds other than the reference's) against its own 1024-spp "
    "reference, timed in the same run (median of repeats after a warm-up): the error-vs-time curve the "
    "radiosity rows are compared with.")


def load_config(path=None) -> dict:
    """The studies' parameters from a TOML file (default ``suites/radiosity/studies.toml``)."""
    return read_config(path, DEFAULT_CONFIG)


def run_studies(config=None, *, only=None, mitsuba: bool | None = None) -> dict[str, list[dict]]:
    """Run the studies named in ``config`` (as :func:`gibench.studies.run_studies`);
    ``mitsuba_ladder`` comes from :func:`gibench.ladder.mitsuba_ladder`."""
    config = as_config(config, DEFAULT_CONFIG)
    out = run_registered(STUDIES, config, only=only)
    lad = dict(config.get("mitsuba_ladder", {}))
    enabled = lad.pop("enabled", False) if mitsuba is None else mitsuba
    if enabled and (only is None or "mitsuba_ladder" in only):
        from ..ladder import mitsuba_ladder

        out["mitsuba_ladder"] = mitsuba_ladder(**lad)
    if "error_vs_patches" in out and "mitsuba_ladder" in out:
        out["error_vs_time"] = error_vs_time(out["error_vs_patches"], out["mitsuba_ladder"])
    return out


def error_vs_time(own_rows: list[dict], mitsuba_rows: list[dict]) -> list[dict]:
    """Own radiosity configurations and Mitsuba's spp ladder as one table of
    (scene, method, time, error), so both curves share the report's axes."""
    rows = [{"scene": r["scene"], "method": f"radiosity {r['formfactor']} {r['display']}",
             "setting": f"{r['patches']} patches", "time_s": r["total_s"], "relmse": r["relmse"]}
            for r in own_rows]
    rows += [{"scene": r["scene"], "method": r["renderer"], "setting": f"{r['spp']} spp",
              "time_s": r["median_s"], "relmse": r["relmse"]} for r in mitsuba_rows]
    return rows
