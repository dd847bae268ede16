"""Timing two sides under the same machine load: interleaved rounds.

On a shared machine the load changes from minute to minute, so timing all of
one side and then all of the other compares the two under different loads.
:func:`run_rounds` runs already warmed-up timed tasks of two sides (own
algorithms and Mitsuba) in ``repeats`` rounds; within a round the two sides
alternate (A B A B ..., the longer side's rest at the end), and every other
round runs in the reverse order (B A B A ...), so neither side is always the
first after a pause or the last before one.  Each task gets one time per
round: task ``i``'s ``k``-th time and task ``j``'s ``k``-th time were measured
seconds apart, so their ratio is a paired ratio under the same load
(:func:`paired_ratios`).

Before every timed task :func:`settle` waits until this process is idle:
both renderers leave worker threads busy after a render returns (Dr.Jit's
pool keeps spinning for tens of milliseconds, numba's OpenMP threads for a
few), and a render started then shares the two cores with them.  Measured in
one process: a raycast render of ``lit_sphere`` started right after a Mitsuba
render took about twice its time in a row of own renders; after the wait, the
same.

:func:`spread` is what the records keep of repeated timings: the minimum,
median and maximum.
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass
from typing import Callable

__all__ = ["Timed", "round_order", "run_rounds", "settle", "spread", "paired_ratios", "load_average"]

SIDES = ("own", "mitsuba")


@dataclass
class Timed:
    """A warmed-up timed task: ``run(k)`` does round ``k``'s work and returns its wall
    time in seconds (whatever it produces besides, it keeps itself)."""

    name: str
    side: str                       # "own" or "mitsuba"
    run: Callable[[int], float]

    def __post_init__(self):
        if self.side not in SIDES:
            raise ValueError(f"side must be one of {SIDES}, got {self.side!r}")


def round_order(tasks: list[Timed], k: int) -> list[int]:
    """Indices of ``tasks`` in the order of round ``k``: own and Mitsuba tasks alternate
    (each side in its given order, the longer side's rest at the end), starting with
    the own side in even rounds; odd rounds run the even order reversed."""
    a = [i for i, t in enumerate(tasks) if t.side == "own"]
    b = [i for i, t in enumerate(tasks) if t.side == "mitsuba"]
    order = []
    for j in range(max(len(a), len(b))):
        order += ([a[j]] if j < len(a) else []) + ([b[j]] if j < len(b) else [])
    return order[::-1] if k % 2 else order


def settle(window: float = 0.01, busy: float = 0.1, limit: float = 1.0) -> float:
    """Wait until this process's threads are idle: until a ``window``-second sleep costs
    the process less than ``busy`` × ``window`` seconds of CPU time (worker threads of a
    finished render still spinning), or ``limit`` seconds have passed.  Returns the wait
    in seconds.  CPU time of other processes does not count: their load is what the
    alternation of the two sides evens out."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < limit:
        c0 = time.process_time()
        time.sleep(window)
        if time.process_time() - c0 < busy * window:
            break
    return time.perf_counter() - t0


def load_average() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return None


def run_rounds(tasks: list[Timed], repeats: int) -> dict:
    """Run every task once per round for ``repeats`` rounds (:func:`round_order`), each
    after :func:`settle`.

    Returns ``{"times": [[t_round0, t_round1, ...] per task], "order": [task names of
    round 0], "load": [1-minute load average before, after]}``.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    times: list[list[float]] = [[] for _ in tasks]
    load = [load_average()]
    for k in range(repeats):
        for i in round_order(tasks, k):
            settle()
            times[i].append(float(tasks[i].run(k)))
    load.append(load_average())
    return {"times": times, "order": [tasks[i].name for i in round_order(tasks, 0)], "load": load}


def spread(times) -> dict:
    """``{"min_s", "median_s", "max_s"}`` of a list of times."""
    times = [float(t) for t in times]
    if not times:
        raise ValueError("spread of no times")
    return {"min_s": min(times), "median_s": statistics.median(times), "max_s": max(times)}


def paired_ratios(a, b) -> list[float]:
    """``a[k] / b[k]`` for the rounds both have (times measured in the same round)."""
    return [float(x) / float(y) for x, y in zip(a, b) if float(y) > 0]
