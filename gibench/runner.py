"""Render an own algorithm with timing: one untimed warm-up (numba JIT
compile or cache load), then ``repeats`` timed renders; the median is quoted
and the warm-up's excess over it is reported as compile time.
"""

from __future__ import annotations

import statistics
import time

from core.scene import Scene

from .registry import Algorithm, RenderResult

__all__ = ["render_timed"]


def render_timed(algorithm: Algorithm, scene: Scene, params: dict, *, seed: int = 0,
                 repeats: int = 3) -> tuple[RenderResult, dict]:
    """Render ``repeats`` + 1 times; return the last result and the timing record.

    The renders are deterministic for a given seed, so the kept result equals
    every timed one.  Where the algorithm reports the phases of a render
    (``RenderResult.timings``: ``setup_s``, the fixed cost of flattening the scene
    and building the ray configuration, apart from ``trace_s``), their medians
    over the timed renders are recorded as ``own_setup_s``, ``own_trace_s``, ...
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    t0 = time.perf_counter()
    result = algorithm.render(scene, params, seed=seed)
    warmup = time.perf_counter() - t0
    times, phases = [], {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = algorithm.render(scene, params, seed=seed)
        times.append(time.perf_counter() - t0)
        for k, v in (result.timings or {}).items():
            phases.setdefault(k, []).append(float(v))
    median = statistics.median(times)
    timing = {"own_median_s": median, "own_times_s": times, "warmup_s": warmup,
              "compile_s": max(warmup - median, 0.0), "repeats": repeats}
    # The algorithm's own phases (fixed cost ``setup_s`` apart from ``trace_s``), medians.
    timing.update({f"own_{k}": statistics.median(v) for k, v in phases.items()})
    return result, timing


def warm_up(suite_paths, *, log=print, size: tuple[int, int] = (8, 6), jobs: int = 1,
            algorithms=None, precisions=None) -> list[dict]:
    """Compile (or load from numba's cache) every kernel the suites' cases use.

    Each distinct (scene, algorithm, parameters) of the suites renders once
    with its film shrunk to ``size`` pixels: numba compiles per argument type,
    not per image size, so this fills ``.numba_cache/`` for the full-size
    runs at a fraction of their cost.  Each algorithm's ``kernel_variants`` (parameter
    overrides that run kernels of their own, e.g. eye-ray packets) render once more per
    precision warmed, on the first case's scene that accepts them (a scene that refuses
    one is skipped silently; the next case is tried).  External algorithms (entry points,
    command renderers) are skipped: they compile nothing of gibench's.
    ``algorithms`` (names) restricts it to those, ``precisions`` to the cases whose
    ``precision`` parameter (None where the algorithm has none) is among them.  With
    ``jobs`` > 1 the (algorithm, precision) pairs go to ``jobs`` worker processes
    (:func:`_warm_tasks`, :func:`_warm_up_parallel`).
    Returns one row per render: scene, algorithm, seconds, error (and ``variant``, the
    overrides, for a variant's render).
    """
    if jobs > 1:
        return _warm_up_parallel(suite_paths, size, jobs, log)
    import dataclasses

    from core.errors import GibenchError
    from core.loader import load_scene

    from . import registry
    from .suite import load_suite

    rows, seen, pending = [], set(), {}

    def render(case, algo, params, variant=None) -> dict:
        t0 = time.perf_counter()
        error = None
        try:
            scene = load_scene(case.scene)
            film = dataclasses.replace(scene.camera.film, width=size[0], height=size[1])
            scene.camera = dataclasses.replace(scene.camera, film=film)
            algo.render(scene, params, seed=0)
        except (GibenchError, OSError) as exc:
            error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        row = {"scene": case.scene_id, "algorithm": algo.name, "seconds": time.perf_counter() - t0,
               "error": error}
        if variant is not None:
            row["variant"] = variant
        return row

    for path in suite_paths:
        suite = load_suite(path)
        for case in suite.cases:
            if registry.origin(case.algorithm)["source"] != "builtin":
                continue
            algo = registry.get(case.algorithm)
            if algorithms is not None and algo.name not in algorithms:
                continue
            params = algo.parse_params(case.params)
            if precisions is not None and params.get("precision") not in precisions:
                continue
            key = (str(case.scene), algo.name, repr(sorted(params.items())))
            if key in seen:
                continue
            seen.add(key)
            row = render(case, algo, params)
            rows.append(row)
            if log:
                log(f"  {case.scene_id}: {case.label}: {row['seconds']:.2f} s"
                    + (f" ({row['error']})" if row["error"] else ""))
            if row["error"]:
                continue
            todo = pending.setdefault((algo.name, params.get("precision")), list(algo.kernel_variants))
            for variant in list(todo):
                try:
                    vparams = algo.parse_params({**case.params, **variant})
                except GibenchError:
                    continue
                vrow = render(case, algo, vparams, variant)
                if vrow["error"]:
                    continue                    # not on this scene: tried again on the next case
                todo.remove(variant)
                rows.append(vrow)
                if log:
                    log(f"  {case.scene_id}: {case.label} + {_variant_label(variant)}: "
                        f"{vrow['seconds']:.2f} s")
    return rows


def _variant_label(variant: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in variant.items())


#: The built-in algorithms with the longest cold compiles (beyond the shared kernels of
#: :data:`_CORE`) first: the order in which :func:`_warm_up_parallel` hands out tasks.
_COMPILE_ORDER = ("path", "distributed", "zbuffer", "whitted", "radiosity")

#: The tile tracers' shared kernels (eye rays, batch closest-hit and shadow queries, the
#: batch light estimator) are most of the ray caster's kernels: at each precision raycast
#: warms first, and the tracers of :data:`_ON_CORE` at that precision wait for it, so that
#: they load those kernels from the cache instead of compiling them again at the same time
#: in another process.
_CORE = "raycast"
_ON_CORE = ("whitted", "distributed", "path")


def _warm_algorithm(suite_paths, size, name, precision) -> list[dict]:
    """:func:`warm_up` of one algorithm at one precision, silent (a worker process's task)."""
    return warm_up(suite_paths, log=None, size=size, algorithms={name}, precisions={precision})


def _warm_tasks(pairs) -> list[tuple[str, object, tuple | None]]:
    """The worker tasks of the (algorithm, precision) pairs ``pairs`` in the order they are
    handed out, each ``(algorithm, precision, after)``: ``after`` is the task that must
    finish first (the :data:`_CORE` task of the precision, for the :data:`_ON_CORE`
    tracers) or None.  Core tasks come first; of the others, those at a precision other
    than float64 (few cases, none sharing the float64 tasks' kernels), then
    :data:`_COMPILE_ORDER`."""
    rank = {a: i for i, a in enumerate(_COMPILE_ORDER)}
    out = []
    for name, prec in pairs:
        after = (_CORE, prec) if name in _ON_CORE and (_CORE, prec) in pairs else None
        out.append((name, prec, after))
    return sorted(out, key=lambda t: (t[0] != _CORE, t[1] in (None, "float64"),
                                      rank.get(t[0], len(rank)), t[0], str(t[1])))


def _warm_up_parallel(suite_paths, size, jobs, log) -> list[dict]:
    """:func:`warm_up` over ``jobs`` worker processes: each free process takes the first
    task of :func:`_warm_tasks` whose ``after`` task has finished."""
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    import multiprocessing

    from . import registry
    from .suite import load_suite

    pairs = set()
    for p in suite_paths:
        for c in load_suite(p).cases:
            if registry.origin(c.algorithm)["source"] == "builtin":
                algo = registry.get(c.algorithm)
                pairs.add((algo.name, algo.parse_params(c.params).get("precision")))
    queue, done, running, rows = _warm_tasks(pairs), set(), {}, []
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        while queue or running:
            while len(running) < jobs:
                ready = next((t for t in queue if t[2] is None or t[2] in done), None)
                if ready is None:
                    if not running:         # cannot happen: every "after" is a task
                        raise RuntimeError(f"warm-up tasks wait for tasks never run: {queue}")
                    break
                queue.remove(ready)
                running[pool.submit(_warm_algorithm, suite_paths, size, ready[0], ready[1])] = ready
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in finished:
                name, prec, _ = running.pop(f)
                done.add((name, prec))
                part = f.result()
                rows += part
                if log:
                    for r in part:
                        log(f"  {r['scene']}: {r['algorithm']}"
                            + (f" + {_variant_label(r['variant'])}" if "variant" in r else "")
                            + f": {r['seconds']:.2f} s" + (f" ({r['error']})" if r["error"] else ""))
    return rows
