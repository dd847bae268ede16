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
    every timed one.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    t0 = time.perf_counter()
    result = algorithm.render(scene, params, seed=seed)
    warmup = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = algorithm.render(scene, params, seed=seed)
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    return result, {"own_median_s": median, "own_times_s": times, "warmup_s": warmup,
                    "compile_s": max(warmup - median, 0.0), "repeats": repeats}
