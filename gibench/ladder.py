"""Error against time along Mitsuba's spp ladder (:mod:`references.ladder`).

The peer's error–time curve, measured in the same run as the own algorithms,
is what every equal-error and equal-time ratio is read from
(:mod:`reports.pareto`).  This module joins the two lower layers: Mitsuba's
timed renders and the metrics.

The peer's best: :func:`choose_sampler` renders the scene once at a probe spp
with each of Mitsuba's samplers (:data:`references.ladder.SAMPLERS`) and picks
the most efficient (lowest rel. MSE x time, Veach's efficiency), so the ladder
an own algorithm is measured against is Mitsuba's best on that scene, not its
``independent`` default.  The choice is cached per reference key, transport,
probe spp, candidates and Mitsuba version (``references/cache/``), so a run
with a warm cache pays only for the chosen ladder.
"""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np

from core.provenance import REPO_ROOT

__all__ = ["ladder_points", "mitsuba_ladder", "choose_sampler", "SAMPLER_CACHE", "PROBE_SPP"]

SAMPLER_CACHE = REPO_ROOT / "references" / "cache" / "ladder_samplers.json"
#: Sample count of the sampler probe: a power of 4, rendered exactly by every sampler.
PROBE_SPP = 16


def ladder_points(scene_path, *, transport: str, spps=(1, 4, 16, 64), reference, repeats: int = 3,
                  defines: dict | None = None, metrics=None, sampler: str = "independent",
                  error_metric: str = "relmse") -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps`` with ``sampler``:
    time and error against ``reference`` (a :class:`references.reference.Reference`).

    ``metrics(ref, img, var)`` computes the error dictionary (default
    :func:`reports.metrics.compare` with the reference variance, so the Z-test
    is included) of the first timed render.  ``error_metric`` is then computed
    for every timed render (``repeats`` distinct seeds): ``metrics[error_metric]``
    is their mean, ``metrics[error_metric + "_seeds"]`` the values and
    ``metrics[error_metric + "_std"]`` their sample standard deviation.
    Returns one dict per spp: ``spp``, ``median_s``, ``times_s``, ``metrics``,
    ``variant``, ``mitsuba``, ``sampler``.
    """
    from references.ladder import render_ladder
    from reports import metrics as mt

    out = []
    for rung in render_ladder(scene_path, transport=transport, spps=spps, repeats=repeats,
                              defines=defines, sampler=sampler):
        images = rung.pop("images")
        rung.pop("image")
        m = (metrics(reference.image, images[0], reference.variance) if metrics is not None
             else mt.compare(reference.image, images[0], reference_variance=reference.variance,
                             allow_nonfinite=True))
        errs = [float(getattr(mt, error_metric)(reference.image, img)) for img in images]
        m[error_metric] = float(np.mean(errs))
        m[f"{error_metric}_seeds"] = errs
        m[f"{error_metric}_std"] = float(np.std(errs, ddof=1)) if len(errs) > 1 else math.nan
        rung["metrics"] = m
        out.append(rung)
    return out


def _cache_key(reference, transport, probe_spp, candidates, defines) -> str:
    from references.mitsuba_env import load_mitsuba

    mi = load_mitsuba()
    payload = {"reference": reference.key, "transport": transport, "probe_spp": int(probe_spp),
               "candidates": list(candidates), "mitsuba": mi.__version__, "variant": mi.variant(),
               "defines": dict(sorted((defines or {}).items()))}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]


def choose_sampler(scene_path, *, transport: str, reference, candidates=None,
                   probe_spp: int = PROBE_SPP, defines: dict | None = None,
                   cache=SAMPLER_CACHE) -> dict:
    """Mitsuba's most efficient sampler on a scene: each of ``candidates`` renders
    ``probe_spp`` samples (one warm-up, one timed render); the one with the
    smallest ``relmse x time`` against ``reference`` wins.

    Returns ``{"sampler", "probe_spp", "candidates": {name: {"relmse",
    "median_s", "efficiency"}}, "cached"}``; with ``cache`` (a JSON file, None
    for none) a measured choice is stored and reused.
    """
    from references.ladder import SAMPLERS, render_ladder
    from reports.metrics import relmse

    candidates = tuple(candidates or SAMPLERS)
    for c in candidates:
        if c not in SAMPLERS:
            raise ValueError(f"ladder sampler must be one of {', '.join(SAMPLERS)}, got {c!r}")
    if len(candidates) == 1:
        return {"sampler": candidates[0], "probe_spp": None, "candidates": {}, "cached": False}
    key = _cache_key(reference, transport, probe_spp, candidates, defines)
    store = {}
    if cache is not None and cache.is_file():
        try:
            store = json.loads(cache.read_text())
        except (OSError, ValueError):
            store = {}
        if isinstance(store.get(key), dict) and store[key].get("sampler") in candidates:
            return dict(store[key], cached=True)
    table = {}
    for name in candidates:
        rung = render_ladder(scene_path, transport=transport, spps=(probe_spp,), repeats=1,
                             defines=defines, sampler=name)[0]
        err = float(relmse(reference.image, rung["image"]))
        eff = 1.0 / (err * rung["median_s"]) if err > 0 and rung["median_s"] > 0 else math.inf
        table[name] = {"relmse": err, "median_s": rung["median_s"], "efficiency": eff}
    best = max(table, key=lambda n: table[n]["efficiency"])
    choice = {"sampler": best, "probe_spp": int(probe_spp), "candidates": table,
              "scene": str(scene_path), "transport": transport}
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        store[key] = choice
        tmp = cache.with_suffix(".tmp")
        tmp.write_text(json.dumps(store, indent=1, sort_keys=True))
        tmp.replace(cache)
    return dict(choice, cached=False)


def mitsuba_ladder(*, scenes=("cornell/cornell_box.xml",), spps=(4, 16, 64, 256), repeats=3,
                   reference_spp=1024, passes=8) -> list[dict]:
    """Mitsuba's ``path`` at each spp against the stored full reference of each scene
    (a path under ``suites/``): rows (scene, spp, relmse, mae, median_s, variant)."""
    from references.ladder import render_ladder
    from references.reference import get_reference
    from reports.metrics import mae, relmse

    rows = []
    for scene_id in scenes:
        path = REPO_ROOT / "suites" / scene_id
        ref = get_reference(path, transport="full", spp=reference_spp, passes=passes)
        for rung in render_ladder(path, transport="full", spps=spps, repeats=repeats):
            rows.append({"scene": scene_id, "renderer": "mitsuba path", "spp": rung["spp"],
                         "relmse": relmse(ref.image, rung["image"]), "mae": mae(ref.image, rung["image"]),
                         "median_s": rung["median_s"], "variant": rung["variant"],
                         "mitsuba": rung["mitsuba"]})
    return rows
