"""Benchmarks (not tests): equal-time error of each pixel sampler of ``distributed``.

For each sampler on the convergence study's edge-heavy scenes (sphere
silhouettes, checkerboard to the horizon, soft shadow), the render at a fixed
sample budget is timed (pytest-benchmark median of 3 rounds, warm-up
excluded) and its MSE against the tracer's own converged image (jittered,
2 × 1024 spp) is recorded.  ``extra_info`` carries ``mse``, ``time_s``,
``mean_spp`` and ``mse_x_time`` — the error at equal time up to a constant for
samplers whose MSE falls as 1/time (lower is better; Mitchell's "efficiency"
is its inverse) — and ``mse_at_1s``, the MSE extrapolated to one second of
rendering along the sampler's measured log–log slope between spp 16 and 64.

    .venv/bin/python -m pytest benchmarks/bench_samplers.py --benchmark-json out.json
"""

from functools import lru_cache
from pathlib import Path
import time

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from _timing import median_s

SUITES = Path(__file__).resolve().parent.parent / "suites"
SCENES = ["distributed/silhouettes.xml", "distributed/checkerboard.xml", "distributed/penumbra.xml"]
SAMPLERS = [("uniform", {}), ("random", {}), ("jitter", {}), ("jitter-gaussian", {"jitter": "gaussian"}),
            ("poisson", {}), ("adaptive", {"threshold": 0.02, "spp": 145}),
            ("statistical", {"tolerance": 0.01, "spp": 256})]


@lru_cache(maxsize=None)
def _reference(scene):
    from gibench.studies.sampling import reference_image

    return reference_image(load_scene(SUITES / scene), spp=1024, seeds=2,
                           base={"light_samples": 1})[0]


def _mse(img, ref):
    return float(((img.astype(np.float64) - ref) ** 2).mean())


@pytest.mark.parametrize("scene", SCENES, ids=[s.split("/")[1][:-4] for s in SCENES])
@pytest.mark.parametrize("name, extra", SAMPLERS, ids=[s for s, _ in SAMPLERS])
def bench_sampler_equal_time(benchmark, scene, name, extra):
    algo = registry.get("distributed")
    sc = load_scene(SUITES / scene)
    ref = _reference(scene)
    smp = "jitter" if name == "jitter-gaussian" else name
    params = algo.parse_params({"spp": 64, "light_samples": 1, **extra, "sampler": smp})
    algo.render(sc, params)                                      # warm-up: JIT / cache load
    res = benchmark.pedantic(algo.render, args=(sc, params), rounds=3, iterations=1)
    t = median_s(benchmark)
    mse = _mse(res.image, ref)
    info = dict(mse=mse, time_s=t, mean_spp=res.counters["mean_spp"], mse_x_time=mse * t)
    if name not in ("adaptive", "statistical"):
        # Slope from a 16-spp render (timed once) to extrapolate the MSE to 1 s.
        p16 = algo.parse_params({**params, "spp": 16})
        t0 = time.perf_counter()
        r16 = algo.render(sc, p16)
        t16 = time.perf_counter() - t0
        m16 = _mse(r16.image, ref)
        if m16 > 0 and mse > 0 and t > t16:
            k = np.log(mse / m16) / np.log(t / t16)
            info["mse_at_1s"] = float(mse * (1.0 / t) ** k)
    benchmark.extra_info.update(info)
