"""Shared by the benchmark files: the median of a pytest-benchmark run."""

import math


def median_s(benchmark) -> float:
    """Median seconds of the timed rounds; NaN under ``--benchmark-disable`` (a smoke run)."""
    return benchmark.stats.stats.median if benchmark.stats else math.nan


def thread_cpu() -> dict:
    """CPU seconds (user + system) of each thread of this process, by thread id, from
    ``/proc/self/task`` (Linux; 10 ms resolution); ``{}`` where there is none."""
    import os

    out = {}
    try:
        tids = os.listdir("/proc/self/task")
        tick = os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:                                  # the thread ended meanwhile
            continue
        out[tid] = (int(fields[11]) + int(fields[12])) / tick
    return out


def busy_threads(before: dict, after: dict, share: float = 0.1) -> int:
    """Threads that used at least ``share`` of the CPU time spent between two
    :func:`thread_cpu` readings."""
    d = [after[k] - before.get(k, 0.0) for k in after]
    total = sum(x for x in d if x > 0)
    return sum(1 for x in d if total > 0 and x >= share * total)
