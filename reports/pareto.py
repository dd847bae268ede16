"""Speed against error: Pareto fronts, equal-error and equal-time ratios, efficiency.

Pure functions of (time, error) points; nothing here renders or knows about
algorithms.  Conventions: times in seconds, errors any non-negative metric
where lower is better (rel. MSE by default in the reports).  Comparisons
with a reference curve (Mitsuba's spp ladder) interpolate linearly in
log–log space between the curve's points, where Monte Carlo error falls as a
power of time (``error ~ c * t**-1`` for MSE-like metrics); outside the
curve's range the ratios are NaN unless ``extrapolate=True``, which extends
the expensive end segment of the curve's Pareto front as a power law (towards
more time and lower error only: nothing is cheaper than the first rung) (the reports do
so and mark such values with "~": a Mitsuba render longer than the ladder's
longest would follow that line only if its error keeps converging at the same
rate).

Efficiency of a configuration is ``1 / (error * time)`` (Veach's efficiency
of an estimator, with MSE as the error: constant for an unbiased estimator as
its sample count grows).

References
----------
.. [1] E. Veach, "Robust Monte Carlo Methods for Light Transport
   Simulation", PhD thesis, Stanford, 1997, §2.4 (efficiency = 1 / (variance x time)).
.. [2] V. Pareto, *Manuale di economia politica*, 1906 (the front of non-dominated points).
"""

from __future__ import annotations

import math

import numpy as np

from core.records import Record

__all__ = ["pareto_front", "loglog_interp", "time_at_error", "error_at_time",
           "equal_error_time_ratio", "equal_time_error_ratio", "efficiency", "noise_floor_relmse",
           "summarize_points", "points_from_records", "primary_records", "top_rung_race",
           "rung_race", "model_floors"]


def _points(times, errors):
    t = np.asarray(times, dtype=np.float64).ravel()
    e = np.asarray(errors, dtype=np.float64).ravel()
    if t.shape != e.shape:
        raise ValueError(f"times ({t.size}) and errors ({e.size}) differ in length")
    return t, e


def pareto_front(times, errors) -> np.ndarray:
    """Indices of the non-dominated points, ordered by increasing time.

    A point is dominated when another is no slower and no worse, and better in
    one of the two.  Non-finite points are never on the front; of exact
    duplicates the first is kept.
    """
    t, e = _points(times, errors)
    ok = np.isfinite(t) & np.isfinite(e)
    idx = np.flatnonzero(ok)
    order = idx[np.lexsort((e[idx], t[idx]))]          # by time, then error
    front, best = [], math.inf
    for i in order:
        if e[i] < best:
            front.append(int(i))
            best = e[i]
    return np.asarray(front, dtype=np.intp)


def loglog_interp(x, y, x0, *, extrapolate: bool = False):
    """``y(x0)`` by linear interpolation of ``log y`` against ``log x``.

    ``x`` must be positive and distinct; outside ``[min x, max x]`` the result
    is NaN, or with ``extrapolate`` the power law through the two nearest end
    points.
    """
    x, y = _points(x, y)
    if x.size == 0:
        return math.nan
    if np.any(x <= 0) or np.any(y <= 0):
        raise ValueError("log-log interpolation needs positive x and y")
    order = np.argsort(x)
    x, y = x[order], y[order]
    if np.any(np.diff(x) == 0):
        raise ValueError("log-log interpolation needs distinct x values")
    x0 = float(x0)
    if not x0 > 0:
        return math.nan
    if x[0] <= x0 <= x[-1]:
        return float(np.exp(np.interp(np.log(x0), np.log(x), np.log(y))))
    if not extrapolate or x.size < 2:
        return math.nan
    i, j = (0, 1) if x0 < x[0] else (-2, -1)
    slope = (np.log(y[j]) - np.log(y[i])) / (np.log(x[j]) - np.log(x[i]))
    return float(np.exp(np.log(y[i]) + slope * (np.log(x0) - np.log(x[i]))))


def _front(times, errors):
    t, e = _points(times, errors)
    f = pareto_front(t, e)
    f = f[(t[f] > 0) & (e[f] > 0)]
    return t[f], e[f]


def time_at_error(times, errors, error: float, *, extrapolate: bool = False) -> float:
    """Time the curve ``(times, errors)`` needs to reach ``error`` (on its Pareto front,
    log–log interpolated; NaN outside its range unless ``extrapolate``)."""
    t, e = _front(times, errors)
    if t.size == 0 or not error > 0:
        return math.nan
    if t.size == 1:
        return float(t[0]) if error == e[0] else math.nan
    # Extrapolate only towards more time (lower error): fewer samples than the
    # cheapest ladder point is not a render the curve could make.
    return loglog_interp(e, t, error, extrapolate=extrapolate and error < e.min())


def error_at_time(times, errors, time: float, *, extrapolate: bool = False) -> float:
    """Error the curve reaches in ``time`` (Pareto front, log–log interpolation)."""
    t, e = _front(times, errors)
    if t.size == 0 or not time > 0:
        return math.nan
    if t.size == 1:
        return float(e[0]) if time == t[0] else math.nan
    return loglog_interp(t, e, time, extrapolate=extrapolate and time > t.max())


def equal_error_time_ratio(time: float, error: float, ref_times, ref_errors, *,
                           extrapolate: bool = False) -> float:
    """``time / t_ref(error)``: how much longer than the reference curve a configuration
    takes for the same error (< 1: faster than the reference)."""
    tr = time_at_error(ref_times, ref_errors, error, extrapolate=extrapolate)
    return float(time / tr) if tr and math.isfinite(tr) else math.nan


def equal_time_error_ratio(time: float, error: float, ref_times, ref_errors, *,
                           extrapolate: bool = False) -> float:
    """``error / e_ref(time)``: the error relative to the reference curve's at the same
    time (< 1: more accurate than the reference)."""
    er = error_at_time(ref_times, ref_errors, time, extrapolate=extrapolate)
    return float(error / er) if er and math.isfinite(er) else math.nan


def efficiency(error, time):
    """``1 / (error * time)``; inf for zero error or time, elementwise for arrays."""
    e = np.asarray(error, dtype=np.float64)
    t = np.asarray(time, dtype=np.float64)
    with np.errstate(divide="ignore"):
        out = 1.0 / (e * t)
    return float(out) if out.ndim == 0 else out


def noise_floor_relmse(reference, reference_variance, *, eps: float = 1e-2) -> float:
    """The relative-MSE floor of a noisy reference: ``mean(var / (ref**2 + eps))``.

    The relMSE analogue of :func:`reports.metrics.noise_floor` (same ``eps`` as
    :func:`reports.metrics.relmse`): relMSE values near it cannot be resolved
    with this reference.
    """
    ref = np.asarray(reference, dtype=np.float64)
    var = np.asarray(reference_variance, dtype=np.float64)
    if ref.shape != var.shape:
        raise ValueError(f"reference shape {ref.shape} and variance shape {var.shape} differ")
    return float(np.mean(var / (ref * ref + eps)))


def summarize_points(own: list[dict], mitsuba: list[dict]) -> dict:
    """Rows for the speed-vs-error table.

    ``own`` and ``mitsuba`` are lists of ``{"label", "time", "error"}``.
    Each own row gets ``efficiency``, ``pareto`` (on the own front),
    ``equal_error_time_ratio`` and ``equal_time_error_ratio`` against the
    Mitsuba curve, interpolated inside it and extrapolated as a power law
    outside (flags ``equal_error_extrapolated`` / ``equal_time_extrapolated``);
    ``best`` holds the smallest of each ratio over the own configurations and
    which configuration gives it.  A configuration with more error than
    Mitsuba's cheapest rung has no equal-error ratio; its
    ``equal_error_lower_bound`` is its time over that rung's (the ratio is at
    least that).
    """
    mt = [p["time"] for p in mitsuba]
    me = [p["error"] for p in mitsuba]
    t = [p["time"] for p in own]
    e = [p["error"] for p in own]
    front = set(pareto_front(t, e).tolist()) if own else set()
    rows = []
    for i, p in enumerate(own):
        ee = equal_error_time_ratio(p["time"], p["error"], mt, me)
        ee_x = math.isnan(ee)
        if ee_x:
            ee = equal_error_time_ratio(p["time"], p["error"], mt, me, extrapolate=True)
        et = equal_time_error_ratio(p["time"], p["error"], mt, me)
        et_x = math.isnan(et)
        if et_x:
            et = equal_time_error_ratio(p["time"], p["error"], mt, me, extrapolate=True)
        bound = math.nan
        if math.isnan(ee) and mt:
            # Worse than Mitsuba's cheapest rung: Mitsuba reaches a lower error in its
            # cheapest time, so the ratio is at least own time / that time.
            k = int(np.argmin(mt))
            if p["error"] > me[k] and mt[k] > 0:
                bound = p["time"] / mt[k]
        rows.append(dict(p, efficiency=efficiency(p["error"], p["time"]), pareto=i in front,
                         equal_error_lower_bound=bound,
                         equal_error_time_ratio=ee, equal_error_extrapolated=ee_x and not math.isnan(ee),
                         equal_time_error_ratio=et, equal_time_extrapolated=et_x and not math.isnan(et)))
    mrows = [dict(p, efficiency=efficiency(p["error"], p["time"])) for p in mitsuba]
    best = None
    ee = [r for r in rows if math.isfinite(r["equal_error_time_ratio"])]
    et = [r for r in rows if math.isfinite(r["equal_time_error_ratio"])]
    if ee or et:
        b1 = min(ee, key=lambda r: r["equal_error_time_ratio"]) if ee else None
        b2 = min(et, key=lambda r: r["equal_time_error_ratio"]) if et else None
        best = {"equal_error_time_ratio": b1["equal_error_time_ratio"] if b1 else math.nan,
                "equal_error_label": b1["label"] if b1 else "—",
                "equal_error_extrapolated": bool(b1 and b1["equal_error_extrapolated"]),
                "equal_time_error_ratio": b2["equal_time_error_ratio"] if b2 else math.nan,
                "equal_time_label": b2["label"] if b2 else "—",
                "equal_time_extrapolated": bool(b2 and b2["equal_time_extrapolated"])}
    return {"rows": rows, "mitsuba_rows": mrows, "best": best}


def _num(x):
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else None


def _case_key(r: Record) -> tuple:
    import json

    return (r.scene, r.transport, r.algorithm, r.label,
            json.dumps(r.params, sort_keys=True, default=str))


def primary_records(records: list[Record]) -> list[Record]:
    """The records without the extra seeds: of the ``case`` records of one
    configuration (scene, transport, algorithm, label, params) only the lowest
    seed is kept (the timed and judged one); other kinds pass unchanged."""
    first: dict = {}
    for r in records:
        if r.kind == "case":
            k = _case_key(r)
            if k not in first or r.seed < first[k].seed:
                first[k] = r
    keep = {id(r) for r in first.values()}
    return [r for r in records if r.kind != "case" or id(r) in keep]


def points_from_records(records: list[Record], *, metric: str = "relmse") -> dict:
    """Group result records (kinds ``case`` and ``ladder``) into speed-vs-error point sets
    ``{(scene, transport): {"own": [...], "mitsuba": [...], "noise_floor": x, "sampler": s}}``.

    Own points are the configurations (label, algorithm, ``model_error``): the
    records of one configuration with different seeds are one point whose
    error is the mean of ``metrics[metric]`` over the seeds (``errors`` the
    values, ``spread`` their sample standard deviation, ``seeds`` how many)
    and whose time is the lowest seed's own median (the one timed with the
    suite's repeats; ``times`` its timed renders, ``min_s`` / ``max_s`` their
    range, ``timing_group`` and ``interleaved`` how they were timed,
    ``run_id``).  Mitsuba points are the ladder records (error: the mean
    over the ladder's seeds when ``metrics[metric + "_seeds"]`` is present);
    ``sampler`` is the ladder's Mitsuba sampler.  The noise floor is the
    record's ``metrics["noise_floor_" + metric]`` (relmse) or
    ``metrics["noise_floor"]`` (mse).  Only scene/transport pairs with a
    Mitsuba ladder are returned.
    """
    groups: dict = {}
    own: dict = {}
    for r in records:
        kind = r.kind
        if kind not in ("case", "ladder") or r.error:
            continue
        m, t = r.metrics, r.time
        err, tm = _num(m.get(metric)), _num(t.get("own_median_s"))
        if err is None or tm is None or not (math.isfinite(err) and math.isfinite(tm)):
            continue
        g = groups.setdefault((r.scene, r.transport),
                              {"own": [], "mitsuba": [], "noise_floor": None, "sampler": None})
        if kind == "ladder":
            errs = [x for x in (m.get(f"{metric}_seeds") or []) if _num(x) is not None]
            pt = {"label": str(r.label), "algorithm": r.algorithm, "time": tm, "error": err,
                  "model_error": False, "spp": r.ladder_spp, "errors": errs or [err],
                  **_timing_fields(r),
                  "seeds": max(len(errs), 1),
                  "spread": float(np.std(errs, ddof=1)) if len(errs) > 1 else math.nan,
                  "sampler": r.params.get("sampler", "independent")}
            g["mitsuba"].append(pt)
            g["sampler"] = pt["sampler"]
        else:
            own.setdefault(_case_key(r), []).append((r.seed, err, tm, r))
        floor = _num(m.get(f"noise_floor_{metric}")) if metric != "mse" else _num(m.get("noise_floor"))
        if floor is not None:
            g["noise_floor"] = floor
    for key, runs in own.items():
        runs.sort(key=lambda x: x[0])
        errs = [e for _, e, _, _ in runs]
        r0 = runs[0][3]
        groups[key[:2]]["own"].append(
            {"label": str(r0.label), "algorithm": r0.algorithm, "time": runs[0][2],
             **_timing_fields(r0),
             "error": float(np.mean(errs)), "errors": errs, "seeds": len(errs),
             "spread": float(np.std(errs, ddof=1)) if len(errs) > 1 else math.nan,
             "model_error": bool(r0.model_error), "params": dict(r0.params)})
    for g in groups.values():
        g["mitsuba"].sort(key=lambda p: p.get("spp") or 0)
    return {k: v for k, v in groups.items() if v["mitsuba"]}


def _timing_fields(r: Record) -> dict:
    """A record's timed renders and how they were timed (:func:`points_from_records`)."""
    t = r.time or {}
    times = [float(x) for x in (t.get("own_times_s") or []) if _num(x) is not None]
    tm = _num(t.get("own_median_s"))
    return {"times": times, "min_s": _num(t.get("own_min_s")) or (min(times) if times else tm),
            "max_s": _num(t.get("own_max_s")) or (max(times) if times else tm),
            "timing_group": t.get("timing_group") or None, "interleaved": bool(t.get("interleaved")),
            "run_id": r.run_id}


def _own_time_at(own: list[dict], times: list[float], error: float, extrapolate: bool):
    """The time the own front ``(times, own errors)`` needs for ``error``: interpolated,
    else (``extrapolate``) the power-law extension, else the fastest own point at or
    below the error.  Returns ``(time, extrapolated)``."""
    e = [p["error"] for p in own]
    inside = time_at_error(times, e, error)
    if math.isfinite(inside):
        return inside, False
    ot = time_at_error(times, e, error, extrapolate=extrapolate)
    if math.isfinite(ot):
        return ot, True
    below = [t for t, p in zip(times, own) if p["error"] <= error]
    return (min(below), False) if below else (math.nan, False)


def rung_race(own: list[dict], mitsuba: list[dict], *, spp=None, extrapolate: bool = True) -> dict | None:
    """Whether the own configurations reach the error of Mitsuba's ladder rung ``spp``
    (default: the most expensive rung) faster than Mitsuba does.

    ``spp``, ``error``, ``time`` and ``sampler`` of the rung; ``own_time`` the time the
    own Pareto front (all own points, log–log interpolated, extrapolated as a power
    law beyond its lowest-error end when ``extrapolate``) needs for that error, from
    the points' median times; ``ratio = own_time / time`` (< 1: the own side is
    faster); ``extrapolated`` whether the front had to be extended; ``label`` the own
    configuration nearest that error.

    The spread: when every own point and the rung were timed in the same interleaved
    rounds (one ``timing_group``, ``times`` of equal length), ``ratio_rounds`` holds
    the ratio of each round (own times and Mitsuba's time of that round, measured
    under the same load), ``ratio_min`` / ``ratio_max`` their range and ``spread``
    is ``"paired"``; otherwise the range uses the fastest own times against Mitsuba's
    slowest and the reverse (``spread = "min-max"``).  ``same_run``: all points from
    one run; ``interleaved``: all timed in interleaved rounds.  None without points
    or without the rung.
    """
    if not own or not mitsuba:
        return None
    if spp is None:
        rung = max(mitsuba, key=lambda p: (p.get("spp") or 0, p["time"]))
    else:
        rung = next((p for p in mitsuba if p.get("spp") == spp), None)
        if rung is None:
            return None
    err = rung["error"]
    ot, ext = _own_time_at(own, [p["time"] for p in own], err, extrapolate)
    near = min(own, key=lambda p: abs(math.log(max(p["error"], 1e-300) / err)))
    ratio = ot / rung["time"] if math.isfinite(ot) and rung["time"] > 0 else math.nan
    pts = own + [rung]
    groups = {p.get("timing_group") for p in pts}
    n = {len(p.get("times") or []) for p in pts}
    rounds, kind = [], None
    if len(groups) == 1 and None not in groups and len(n) == 1 and n != {0}:
        for k in range(n.pop()):
            tk, _ = _own_time_at(own, [p["times"][k] for p in own], err, extrapolate)
            if math.isfinite(tk) and rung["times"][k] > 0:
                rounds.append(tk / rung["times"][k])
        kind = "paired" if rounds else None
    lo = hi = math.nan
    if rounds:
        lo, hi = min(rounds), max(rounds)
    elif math.isfinite(ratio):
        fast, _ = _own_time_at(own, [p.get("min_s") or p["time"] for p in own], err, extrapolate)
        slow, _ = _own_time_at(own, [p.get("max_s") or p["time"] for p in own], err, extrapolate)
        mmax, mmin = rung.get("max_s") or rung["time"], rung.get("min_s") or rung["time"]
        if math.isfinite(fast) and math.isfinite(slow) and mmin > 0:
            lo, hi, kind = fast / mmax, slow / mmin, "min-max"
    return {"spp": rung.get("spp"), "sampler": rung.get("sampler"), "error": err,
            "time": rung["time"], "own_time": ot, "ratio": ratio, "extrapolated": bool(ext),
            "label": near["label"], "ratio_rounds": rounds, "ratio_min": lo, "ratio_max": hi,
            "spread": kind, "same_run": len({p.get("run_id") for p in pts}) == 1,
            "interleaved": all(p.get("interleaved") for p in pts)}


def top_rung_race(own: list[dict], mitsuba: list[dict], *, extrapolate: bool = True) -> dict | None:
    """:func:`rung_race` at Mitsuba's most expensive ladder rung."""
    return rung_race(own, mitsuba, extrapolate=extrapolate)


def model_floors(own: list[dict]) -> dict:
    """Per algorithm of the own points (``algorithm``, ``label``, ``error``, ``time``):
    the error at its most converged setting (the most expensive point) as an upper
    bound of its model-error floor, and ``drop`` = that error / the error of the
    next cheaper point of the same algorithm (close to 1 when more samples no
    longer help: the floor is reached; NaN with one point).
    ``{algorithm: {"floor", "label", "drop", "time"}}``."""
    out = {}
    by: dict = {}
    for p in own:
        by.setdefault(p["algorithm"], []).append(p)
    for algo, pts in by.items():
        pts = sorted(pts, key=lambda p: p["time"])
        last = pts[-1]
        drop = last["error"] / pts[-2]["error"] if len(pts) > 1 and pts[-2]["error"] > 0 else math.nan
        out[algo] = {"floor": last["error"], "label": last["label"], "drop": drop, "time": last["time"]}
    return out
