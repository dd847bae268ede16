"""Shared by the benchmark files: the median of a pytest-benchmark run."""

import math


def median_s(benchmark) -> float:
    """Median seconds of the timed rounds; NaN under ``--benchmark-disable`` (a smoke run)."""
    return benchmark.stats.stats.median if benchmark.stats else math.nan
