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
    runs at a fraction of their cost.  External algorithms (entry points,
    command renderers) are skipped: they compile nothing of gibench's.
    ``algorithms`` (names) restricts it to those, ``precisions`` to the cases whose
    ``precision`` parameter (None where the algorithm has none) is among them.  With
    ``jobs`` > 1 the (algorithm, precision) pairs go to ``jobs`` worker processes as
    they free up, the tile tracers of one precision together and the longest compiles
    first (:func:`_warm_tasks`): numba compiles on one core and per argument type, so a
    float32 ray configuration compiles a tracer's kernels again, apart from its
    float64 ones (kernels shared across tasks compile in each process that needs them
    before they are cached; numba's cache writes are atomic).
    Returns one row per render: scene, algorithm, seconds, error.
    """
    if jobs > 1:
        return _warm_up_parallel(suite_paths, size, jobs, log)
    import dataclasses

    from core.errors import GibenchError
    from core.loader import load_scene

    from . import registry
    from .suite import load_suite

    rows, seen = [], set()
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
            t0 = time.perf_counter()
            error = None
            try:
                scene = load_scene(case.scene)
                film = dataclasses.replace(scene.camera.film, width=size[0], height=size[1])
                scene.camera = dataclasses.replace(scene.camera, film=film)
                algo.render(scene, params, seed=0)
            except (GibenchError, OSError) as exc:
                error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            dt = time.perf_counter() - t0
            rows.append({"scene": case.scene_id, "algorithm": algo.name, "seconds": dt, "error": error})
            if log:
                log(f"  {case.scene_id}: {case.label}: {dt:.2f} s" + (f" ({error})" if error else ""))
    return rows


#: The built-in algorithms with the largest kernels (longest cold compiles) first: the
#: order in which :func:`warm_up` hands its tasks to its worker processes.
_COMPILE_ORDER = ("path", "distributed", "whitted", "raycast", "radiosity")

#: Algorithms that share most of their kernels (the tile tracers' eye rays, batch queries
#: and light lanes): at one precision they warm up in one task, one after the other in one
#: process, so that the second loads the shared kernels from the cache the first filled
#: instead of compiling them at the same time in another process.
_SHARED_KERNELS = (("whitted", "raycast"),)


def _warm_algorithm(suite_paths, size, names, precision) -> list[dict]:
    """:func:`warm_up` of some algorithms at one precision, silent (a worker process's
    task), in the order of ``names``."""
    rows = []
    for name in names:
        rows += warm_up(suite_paths, log=None, size=size, algorithms={name}, precisions={precision})
    return rows


def _warm_tasks(pairs) -> list[tuple[tuple[str, ...], object]]:
    """The worker tasks of the (algorithm, precision) pairs ``pairs``: the algorithms of a
    :data:`_SHARED_KERNELS` group at one precision in one task, the others one each.
    Tasks at a precision other than float64 come first: the suites render the other
    algorithms in float64 too, so such a task's kernels share nothing with the other
    tasks' and compile longest; then :data:`_COMPILE_ORDER`."""
    rank = {a: i for i, a in enumerate(_COMPILE_ORDER)}
    group = {a: g for g in _SHARED_KERNELS for a in g}
    tasks = {}
    for name, prec in pairs:
        members = group.get(name, (name,))
        key = (members, prec)
        tasks.setdefault(key, set()).add(name)
    out = [(tuple(a for a in members if a in names), prec) for (members, prec), names in tasks.items()]
    return sorted(out, key=lambda t: (t[1] in (None, "float64"), min(rank.get(a, len(rank)) for a in t[0]),
                                      t[0], str(t[1])))


def _warm_up_parallel(suite_paths, size, jobs, log) -> list[dict]:
    """:func:`warm_up` over ``jobs`` worker processes, one task (:func:`_warm_tasks`) at a
    time each."""
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    from . import registry
    from .suite import load_suite

    pairs = set()
    for p in suite_paths:
        for c in load_suite(p).cases:
            if registry.origin(c.algorithm)["source"] == "builtin":
                algo = registry.get(c.algorithm)
                pairs.add((algo.name, algo.parse_params(c.params).get("precision")))
    tasks = _warm_tasks(pairs)
    rows = []
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(_warm_algorithm, suite_paths, size, names, prec) for names, prec in tasks]
        for f in futures:
            part = f.result()
            rows += part
            if log:
                for r in part:
                    log(f"  {r['scene']}: {r['algorithm']}: {r['seconds']:.2f} s"
                        + (f" ({r['error']})" if r["error"] else ""))
    return rows
