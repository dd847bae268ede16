"""Benchmarks (not tests): the own path tracer against Mitsuba's ``path`` (LLVM)
on the scenes of ``suites/path.toml``, at matched max_depth, in one run.

* ``bench_path``: own render at 16 spp (pytest-benchmark median of 3 rounds
  after a warm-up); ``extra_info`` has paths, rays and paths per second.
* ``bench_path_time_to_relmse``: own and Mitsuba each render a ladder of
  sample counts (median of 3 timed renders after a warm-up each); relMSE
  against the stored 1024-spp Mitsuba reference.  Both estimators are
  unbiased, so relMSE·spp is constant (noise only): from the largest rung,
  c = relMSE·spp and t₁ = time/spp, and the time to reach a relMSE ε is
  c·t₁/ε.  ``extra_info`` carries the ladders, the time each needs to reach
  the relMSE Mitsuba has at 64 spp, and their ratio (own / Mitsuba).

    .venv/bin/python -m pytest benchmarks/bench_path.py --benchmark-json reports/out/bench_path.json
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from _timing import median_s

SUITES = Path(__file__).resolve().parent.parent / "suites"
#: scene, max_depth (the file's own path max_depth: what the stored reference uses)
SCENES = [("cornell/cornell_box.xml", 8), ("cornell/diffuse_room.xml", -1),
          ("spheres/glass_sphere.xml", 11)]
IDS = [s.split("/")[1][:-4] for s, _ in SCENES]
LADDER = (4, 16)
REPEATS = 3
TARGET_SPP = 64          # the target relMSE: Mitsuba's at this many spp (extrapolated)


def _timed(fn, repeats=REPEATS):
    fn()                                                      # warm-up: JIT / kernel compile
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


@pytest.mark.parametrize("scene, depth", SCENES, ids=IDS)
def bench_path(benchmark, scene, depth):
    algo = registry.get("path")
    sc = load_scene(SUITES / scene)
    params = algo.parse_params({"spp": 16, "max_depth": depth})
    algo.render(sc, params)                                   # warm-up: JIT / cache load
    result = benchmark.pedantic(algo.render, args=(sc, params), rounds=3, iterations=1)
    assert np.isfinite(result.image).all()
    c = result.counters
    rays = c["segments"] + c["shadow_rays"]
    benchmark.extra_info.update(paths=c["paths"], rays=rays, paths_per_s=c["paths"] / median_s(benchmark),
                                rays_per_s=rays / median_s(benchmark),
                                mean_path_length=c["mean_path_length"])


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene, depth", SCENES, ids=IDS)
def bench_path_time_to_relmse(benchmark, scene, depth):
    import drjit as dr

    from references.mitsuba_env import load_mitsuba
    from references.reference import get_reference, load_scene as mi_load_scene, prepare_scene_xml
    from reports.metrics import relmse

    path = SUITES / scene
    ref = get_reference(path, transport="full", spp=1024, passes=8)
    assert ref.manifest["integrator"]["max_depth"] == depth
    algo = registry.get("path")
    sc = load_scene(path)
    mi = load_mitsuba()
    ladders = {"own": [], "mitsuba": []}
    for spp in LADDER:
        params = algo.parse_params({"spp": spp, "max_depth": depth})
        t, res = _timed(lambda: algo.render(sc, params, seed=11))
        ladders["own"].append({"spp": spp, "s": t, "relmse": relmse(ref.image, res.image)})
        xml, _, _ = prepare_scene_xml(path, transport="full", spp_per_pass=spp, seed=11)
        mscene = mi_load_scene(mi, path, xml)

        def mi_render():
            img = mi.render(mscene, spp=spp, seed=11)
            dr.eval(img)
            dr.sync_thread()
            return np.asarray(img, dtype=np.float32)[..., :3]

        t, img = _timed(mi_render)
        ladders["mitsuba"].append({"spp": spp, "s": t, "relmse": relmse(ref.image, img)})

    def constants(rows):
        top = rows[-1]
        return top["relmse"] * top["spp"], top["s"] / top["spp"]

    c_own, t1_own = constants(ladders["own"])
    c_mi, t1_mi = constants(ladders["mitsuba"])
    target = c_mi / TARGET_SPP
    own_s, mi_s = c_own * t1_own / target, c_mi * t1_mi / target
    # Time the own 16-spp render once more under pytest-benchmark for the JSON record.
    params = algo.parse_params({"spp": 16, "max_depth": depth})
    benchmark.pedantic(algo.render, args=(sc, params), rounds=1, iterations=1)
    benchmark.extra_info.update(ladders=ladders, target_relmse=target, own_time_to_target_s=own_s,
                                mitsuba_time_to_target_s=mi_s, ratio_own_over_mitsuba=own_s / mi_s,
                                mitsuba_variant=mi.variant())
    print(f"{scene}: relMSE target {target:.3g}: own {own_s:.2f} s, Mitsuba {mi_s:.2f} s "
          f"({own_s / mi_s:.2f}x); ladders {ladders}")
