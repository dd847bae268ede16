"""Sampler convergence study (thesis 2.5.1–2.5.4): error of every pixel
sampler of the ``distributed`` tracer against samples per pixel and time.

========================  =====================================================
study                     what it measures
========================  =====================================================
``convergence``           per scene × sampler × sample count (× seed): MSE over
                          all pixels and over *edge* pixels against the
                          tracer's own converged image, wall time of the
                          render, and the mean spp actually spent (adaptive
                          and statistical are swept over their threshold /
                          tolerance and plotted by that mean)
``convergence_slopes``    least-squares slope of log MSE against log spp (and
                          against log time) per scene × sampler × pixel set,
                          from the seed-averaged ``convergence`` rows
========================  =====================================================

The reference of each scene is the same tracer with the ``ref_sampler``
(white-noise jittered pixel positions by default; ``stratified`` also
stratifies the lens, time, light and BSDF dimensions) at ``ref_spp``
samples, averaged over ``ref_seeds`` seeds.  Its own MSE adds to every
measured one: with jittered pixels only it falls as 1/spp where the light or
lens dimension varies (the soft shadow, depth of field), about as fast as
the stratified samplers' 256-spp error, which would flatten their fitted
slopes; a ``stratified`` reference at 1024 spp keeps it far below.

Sampler names: the fixed patterns of :mod:`impl.samplers` (``uniform``,
``random``, ``jitter``, ``jitter-gaussian`` = Gaussian jitter, ``poisson``),
``stratified`` (jittered pixel positions and ``dimensions=stratified``: every
other 2-D dimension in shuffled k×k strata, thesis 2.5.8) and ``sobol``
(padded Owen-scrambled Sobol points for every dimension).  *Edge pixels* are
those whose reference sample variance (per-pixel variance of the mean × spp,
largest channel) exceeds ``edge_variance``: where the pixel integrand is not
constant — silhouettes, texture edges, shadow outlines.  Mitchell (1996,
"Consequences of stratified sampling in graphics", SIGGRAPH) shows that for
such pixels random sampling's MSE falls as N⁻¹ and jittered (stratified)
sampling's as N⁻¹·⁵; ``tests/test_samplers.py`` asserts both slopes.

Times are wall-clock renders on whatever machine runs the study (one untimed
warm-up render per study keeps compilation out).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from core.errors import SuiteError
from core.provenance import REPO_ROOT

from . import StudyInfo, as_config, read_config, run_registered, table_titles

__all__ = ["STUDIES", "TABLES", "DEFAULT_CONFIG", "load_config", "run_studies", "convergence",
           "fit_slopes", "reference_image"]

DEFAULT_CONFIG = REPO_ROOT / "suites" / "distributed" / "studies.toml"
SUITES = REPO_ROOT / "suites"


def _algo():
    from .. import registry

    return registry.get("distributed")


def _scene(path, size):
    from core.loader import load_scene

    scene = load_scene(path)
    if size is not None:
        w, h = int(size[0]), int(size[1])
        film = dataclasses.replace(scene.camera.film, width=w, height=h)
        scene.camera = dataclasses.replace(scene.camera, film=film)
    return scene


#: Tracer parameters of the sampler names that are not a ``sampler`` value alone.
SAMPLER_PARAMS = {
    "jitter": {"sampler": "jitter", "jitter": "white"},
    "jitter-gaussian": {"sampler": "jitter", "jitter": "gaussian"},
    "stratified": {"sampler": "jitter", "jitter": "white", "dimensions": "stratified"},
}


def _sampler_params(name: str) -> dict:
    return SAMPLER_PARAMS.get(name, {"sampler": name})


def reference_image(scene, *, spp: int = 1024, seeds: int = 4, base: dict | None = None,
                    sampler: str = "jitter"):
    """(image, per-pixel sample variance) of the tracer's own converged render: ``sampler``
    (a study sampler name) at ``spp``, mean over ``seeds`` seeds (seeds 1000, 1001, …)."""
    algo = _algo()
    p = algo.parse_params({**(base or {}), "spp": spp, **_sampler_params(sampler)})
    acc = np.zeros((scene.camera.film.height, scene.camera.film.width, 3))
    svar = np.zeros_like(acc)
    for s in range(seeds):
        res = algo.render(scene, p, seed=1000 + s)
        acc += res.image
        svar += res.variance * spp
    return acc / seeds, svar / seeds


def convergence(*, scenes, samplers=("uniform", "random", "jitter", "jitter-gaussian", "poisson"),
                spps=(4, 16, 64, 256), seeds=3, adaptive_thresholds=(0.2, 0.1, 0.05, 0.02, 0.01),
                adaptive_depth=3, adaptive_cap=145, statistical_tolerances=(0.1, 0.05, 0.02, 0.01, 0.005),
                statistical_cap=256, ref_spp=1024, ref_seeds=4, ref_sampler="jitter", edge_variance=1e-4,
                size=None, params=None) -> list[dict]:
    """Rows of MSE (all / edge pixels) and time per scene × sampler × spp × seed.

    ``scenes``: paths relative to ``suites/``; ``samplers``: names of the fixed
    patterns (``jitter-gaussian`` = ``sampler=jitter, jitter=gaussian``,
    ``stratified`` = jitter with ``dimensions=stratified``, ``sobol``); the
    adaptive and statistical samplers are run when their sweeps are non-empty.
    ``ref_sampler``: the reference's sampler name (:func:`reference_image`).
    ``size``: optional (width, height) replacing the films'.  ``params``:
    further tracer parameters for every render.
    """
    algo = _algo()
    base = dict(params or {})
    rows: list[dict] = []
    for rel in scenes:
        path = SUITES / rel
        scene = _scene(path, size)
        ref, svar = reference_image(scene, spp=ref_spp, seeds=ref_seeds, base=base, sampler=ref_sampler)
        edge = svar.max(axis=2) > edge_variance
        n_edge = int(edge.sum())
        if n_edge == 0:
            raise SuiteError(f"convergence: {rel} has no edge pixels (sample variance > {edge_variance})")
        # Warm-up (compilation) for every sampler code path, untimed.
        for smp in ("uniform", "adaptive", "statistical"):
            algo.render(scene, algo.parse_params({**base, "spp": 16, "sampler": smp}), seed=0)
        runs = []
        for name in samplers:
            extra = _sampler_params(name)
            for spp in spps:
                runs.append((name, spp, {**extra, "spp": spp}, "spp", spp))
        for thr in adaptive_thresholds:
            runs.append(("adaptive", adaptive_cap, {"sampler": "adaptive", "spp": adaptive_cap,
                                                    "threshold": thr, "adaptive_depth": adaptive_depth},
                         "threshold", thr))
        for tol in statistical_tolerances:
            runs.append(("statistical", statistical_cap, {"sampler": "statistical", "spp": statistical_cap,
                                                          "tolerance": tol}, "tolerance", tol))
        for name, spp, extra, knob, value in runs:
            p = algo.parse_params({**base, **extra})
            for seed in range(seeds):
                t0 = time.perf_counter()
                res = algo.render(scene, p, seed=seed)
                dt = time.perf_counter() - t0
                err = (res.image.astype(np.float64) - ref) ** 2
                rows.append({
                    "scene": rel, "sampler": name, "spp": spp, "knob": knob, "setting": value,
                    "seed": seed, "mean_spp": float(res.counters["mean_spp"]),
                    "edge_mean_spp": float(res.aovs["spp"][edge].mean()),
                    "mse": float(err.mean()), "mse_edge": float(err[edge].mean()),
                    "time_s": dt, "edge_pixels": n_edge, "pixels": int(edge.size),
                })
    return rows


def fit_slopes(rows: list[dict]) -> list[dict]:
    """Log–log least-squares slopes of the seed-averaged MSE against mean spp and time.

    One row per scene × sampler × pixel set (``all``/``edge``): ``slope_spp``
    (d log MSE / d log spp; for the edge set against the edge pixels' mean
    spp) and ``slope_time`` (against the seed-median render time), and the
    number of points fitted.
    """
    groups: dict = {}
    for r in rows:
        key = (r["scene"], r["sampler"], r["setting"])
        groups.setdefault(key, []).append(r)
    points: dict = {}
    for (scene, sampler, _v), rs in groups.items():
        d = points.setdefault((scene, sampler), [])
        d.append((float(np.mean([r["mean_spp"] for r in rs])),
                  float(np.mean([r["edge_mean_spp"] for r in rs])),
                  float(np.median([r["time_s"] for r in rs])),
                  float(np.mean([r["mse"] for r in rs])),
                  float(np.mean([r["mse_edge"] for r in rs]))))
    out = []
    for (scene, sampler), pts in points.items():
        a = np.array(sorted(pts))
        if len(a) < 2:
            continue
        for which, x_col, y_col in (("all", 0, 3), ("edge", 1, 4)):
            ok = (a[:, y_col] > 0) & (a[:, x_col] > 0)
            if ok.sum() < 2:
                continue
            slope_spp = float(np.polyfit(np.log(a[ok, x_col]), np.log(a[ok, y_col]), 1)[0])
            slope_time = float(np.polyfit(np.log(a[ok, 2]), np.log(a[ok, y_col]), 1)[0])
            out.append({"scene": scene, "sampler": sampler, "pixels": which, "slope_spp": slope_spp,
                        "slope_time": slope_time, "points": int(ok.sum()),
                        "spp_min": float(a[ok, x_col].min()), "spp_max": float(a[ok, x_col].max())})
    return out


STUDIES = {s.name: s for s in (
    StudyInfo("convergence", "Sampler convergence: MSE vs samples per pixel and time",
              "The distributed tracer's samplers (uniform grid, random, white-noise and Gaussian "
              "jitter, Poisson disk, Whitted adaptive, statistical; jitter with every other dimension "
              "in shuffled strata; padded Owen-scrambled Sobol) on edge-heavy scenes — a checkerboard "
              "to the horizon with sphere silhouettes under a directional light, a soft shadow, depth "
              "of field — against the tracer's own converged image (4 × 1024 spp): MSE over all "
              "pixels and over edge pixels, render time, mean spp actually spent.", convergence),
)}

TABLES = table_titles(STUDIES)
TABLES["convergence_slopes"] = (
    "Sampler convergence: fitted log-log slopes",
    "Least-squares slope of log MSE against log spp (and log time) per scene, sampler and pixel set; "
    "Mitchell 1996: random -1, jittered -1.5 on edge pixels where the pixel position is the "
    "only dimension that varies.")


def load_config(path=None) -> dict:
    """The studies' parameters from a TOML file (default ``suites/distributed/studies.toml``)."""
    return read_config(path, DEFAULT_CONFIG)


def run_studies(config=None, *, only=None, mitsuba: bool | None = None) -> dict[str, list[dict]]:
    """Run the studies named in ``config``; adds ``convergence_slopes`` from ``convergence``."""
    config = as_config(config, DEFAULT_CONFIG)
    out = run_registered(STUDIES, config, only=only)
    if "convergence" in out:
        out["convergence_slopes"] = fit_slopes(out["convergence"])
    return out
