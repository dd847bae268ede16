"""Error against time along Mitsuba's spp ladder (:mod:`references.ladder`).

The peer's error–time curve, measured in the same run as the own algorithms,
is what every equal-error and equal-time ratio is read from
(:mod:`reports.pareto`).  This module joins the two lower layers: Mitsuba's
timed renders and the metrics.

The peer's best: :func:`choose_sampler` renders the scene with each of
Mitsuba's samplers (:data:`references.ladder.SAMPLERS`) at one or more probe
sample counts and picks the most efficient (lowest rel. MSE x time, Veach's
efficiency) at the largest of them.  A sampler's advantage changes with the
sample count (strata and low-discrepancy points gain more as the count grows),
so the probe includes the ladder's top rung, where the equal-error race is
read: the ladder an own algorithm is measured against is Mitsuba's best on
that scene at that error level, not its ``independent`` default.  The probe's
renders use seeds apart from the ladder's, so the choice is not made on the
very images the ladder's error is then measured on.  The choice is cached per
reference key, transport, probe sample counts, candidates and Mitsuba version
(``references/cache/``), so a run with a warm cache pays only for the chosen
ladder.
"""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np

from core.provenance import REPO_ROOT

__all__ = ["ladder_points", "rung_metrics", "mitsuba_ladder", "choose_sampler", "probe_spps",
           "SAMPLER_CACHE", "PROBE_SPP", "PROBE_SEED_OFFSET"]

SAMPLER_CACHE = REPO_ROOT / "references" / "cache" / "ladder_samplers.json"
#: Sample count of the sampler probe below the top rung: a power of 4, rendered exactly
#: by every sampler.
PROBE_SPP = 16
#: The probe's seeds are ``LADDER_SEED + PROBE_SEED_OFFSET + k``, apart from the ladder's.
PROBE_SEED_OFFSET = 1000


def rung_metrics(reference, images, *, metrics=None, error_metric: str = "relmse") -> dict:
    """The error dictionary of a ladder rung's timed renders ``images`` against ``reference``.

    ``metrics(ref, img, var)`` computes the dictionary (default
    :func:`reports.metrics.compare` with the reference variance, so the Z-test
    is included) of the first image.  ``error_metric`` is then computed for
    every image: ``[error_metric]`` is their mean, ``[error_metric + "_seeds"]``
    the values and ``[error_metric + "_std"]`` their sample standard deviation.
    """
    from reports import metrics as mt

    m = (metrics(reference.image, images[0], reference.variance) if metrics is not None
         else mt.compare(reference.image, images[0], reference_variance=reference.variance,
                         allow_nonfinite=True))
    errs = [float(getattr(mt, error_metric)(reference.image, img)) for img in images]
    m[error_metric] = float(np.mean(errs))
    m[f"{error_metric}_seeds"] = errs
    m[f"{error_metric}_std"] = float(np.std(errs, ddof=1)) if len(errs) > 1 else math.nan
    return m


def ladder_points(scene_path, *, transport: str, spps=(1, 4, 16, 64), reference, repeats: int = 3,
                  defines: dict | None = None, metrics=None, sampler: str = "independent",
                  error_metric: str = "relmse") -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps`` with ``sampler``,
    rung after rung: time and error against ``reference`` (a
    :class:`references.reference.Reference`; errors by :func:`rung_metrics`).
    Returns one dict per spp: ``spp``, ``median_s``, ``times_s``, ``metrics``,
    ``variant``, ``mitsuba``, ``sampler``.
    """
    from references.ladder import render_ladder

    out = []
    for rung in render_ladder(scene_path, transport=transport, spps=spps, repeats=repeats,
                              defines=defines, sampler=sampler):
        images = rung.pop("images")
        rung.pop("image")
        rung["metrics"] = rung_metrics(reference, images, metrics=metrics, error_metric=error_metric)
        out.append(rung)
    return out


def probe_spps(ladder) -> tuple[int, ...]:
    """The probe sample counts for a ladder: :data:`PROBE_SPP` (or the top rung when
    that is smaller) and the top rung."""
    top = max(int(x) for x in ladder) if ladder else PROBE_SPP
    return tuple(sorted({min(PROBE_SPP, top), top}))


def _cache_key(reference, transport, probes, candidates, defines, repeats) -> str:
    from references.mitsuba_env import load_mitsuba

    mi = load_mitsuba()
    payload = {"reference": reference.key, "transport": transport,
               "probe_spps": [int(x) for x in probes], "probe_repeats": int(repeats),
               "candidates": list(candidates), "mitsuba": mi.__version__, "variant": mi.variant(),
               "defines": dict(sorted((defines or {}).items()))}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]


def _probe(scene_path, *, transport, reference, candidates, spp, repeats, defines) -> dict:
    """Each candidate at ``spp``: warmed up, then ``repeats`` rounds in which every
    candidate renders once (order rotated per round, so none is always first);
    ``{name: {"relmse" (mean over the rounds' seeds), "relmse_seeds", "median_s",
    "times_s", "spp" (rendered), "efficiency"}}``."""
    from references.ladder import LADDER_SEED, prepare_ladder
    from reports.metrics import relmse

    rungs = {n: prepare_ladder(scene_path, transport=transport, spps=(spp,), defines=defines,
                               sampler=n)[0] for n in candidates}
    names = list(candidates)
    errs: dict = {n: [] for n in names}
    times: dict = {n: [] for n in names}
    for k in range(repeats):
        for n in names[k % len(names):] + names[:k % len(names)]:
            img, dt = rungs[n].render(LADDER_SEED + PROBE_SEED_OFFSET + k)
            errs[n].append(float(relmse(reference.image, img)))
            times[n].append(dt)
    table = {}
    for n in names:
        err, t = float(np.mean(errs[n])), float(np.median(times[n]))
        eff = 1.0 / (err * t) if err > 0 and t > 0 else math.inf
        table[n] = {"relmse": err, "relmse_seeds": errs[n], "median_s": t, "times_s": times[n],
                    "spp": rungs[n].spp, "efficiency": eff}
    return table


def choose_sampler(scene_path, *, transport: str, reference, candidates=None,
                   probe_spp=PROBE_SPP, defines: dict | None = None,
                   cache=SAMPLER_CACHE, repeats: int = 8) -> dict:
    """Mitsuba's most efficient sampler on a scene at the error level compared.

    ``probe_spp``: one sample count or several (e.g. :func:`probe_spps` of the
    ladder: 16 and the top rung); at each, every candidate renders ``repeats``
    times after a warm-up (:func:`_probe`), and the one with the smallest
    ``relmse x time`` at the *largest* probe count wins (the top rung's error is
    the one the equal-error race is read at).  One render's relMSE can move 2–5×
    from seed to seed (a few pixels at a small bright feature's edge carry most
    of it), so a choice from one or two renders can fall on a lucky draw of a
    weaker sampler; hence several repeats.

    Returns ``{"sampler", "probe_spp" (the deciding count), "candidates"
    ({name: {"relmse", "median_s", "efficiency", ...}} at that count), "probes"
    ({str(spp): that table} for every count), "best_by_spp" ({str(spp): the most
    efficient there}), "cached"}``; with ``cache`` (a JSON file, None for none) a
    measured choice is stored and reused.
    """
    from references.ladder import SAMPLERS

    candidates = tuple(candidates or SAMPLERS)
    for c in candidates:
        if c not in SAMPLERS:
            raise ValueError(f"ladder sampler must be one of {', '.join(SAMPLERS)}, got {c!r}")
    spps = sorted({int(x) for x in (probe_spp if isinstance(probe_spp, (list, tuple)) else [probe_spp])})
    if not spps or spps[0] < 1 or repeats < 1:
        raise ValueError(f"probe spp and repeats must be positive, got {spps}, {repeats}")
    if len(candidates) == 1:
        return {"sampler": candidates[0], "probe_spp": None, "candidates": {}, "probes": {},
                "best_by_spp": {}, "cached": False}
    key = _cache_key(reference, transport, spps, candidates, defines, repeats)
    store = {}
    if cache is not None and cache.is_file():
        try:
            store = json.loads(cache.read_text())
        except (OSError, ValueError):
            store = {}
        if isinstance(store.get(key), dict) and store[key].get("sampler") in candidates:
            return dict(store[key], cached=True)
    probes = {str(spp): _probe(scene_path, transport=transport, reference=reference,
                               candidates=candidates, spp=spp, repeats=repeats, defines=defines)
              for spp in spps}
    best_by = {k: max(t, key=lambda n: t[n]["efficiency"]) for k, t in probes.items()}
    top = str(spps[-1])
    choice = {"sampler": best_by[top], "probe_spp": spps[-1], "candidates": probes[top],
              "probes": probes, "best_by_spp": best_by, "probe_repeats": int(repeats),
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
