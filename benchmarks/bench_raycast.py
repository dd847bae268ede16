"""Benchmarks (not tests): own ``raycast`` vs Mitsuba on the same scenes, spp and
transport, measured in one run so that the ratio is meaningful on a shared
machine.  Warm-up (numba compile or cache load; Dr.Jit kernel compile) is
excluded; pytest-benchmark quotes the median of the rounds.

    .venv/bin/python -m pytest benchmarks --benchmark-json reports/out/bench.json

Each result's ``extra_info`` carries the rays traced and rays per second.
"""

from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from _timing import median_s

SUITES = Path(__file__).resolve().parent.parent / "suites"
CASES = [("cornell/cornell_point.xml", 1), ("cornell/cornell_point.xml", 16),
         ("cornell/cornell_box.xml", 16), ("spheres/meshes.xml", 16)]
IDS = [f"{s.split('/')[1][:-4]}-{n}spp" for s, n in CASES]


@pytest.mark.parametrize("scene, spp", CASES, ids=IDS)
def bench_raycast(benchmark, scene, spp):
    algo = registry.get("raycast")
    sc = load_scene(SUITES / scene)
    params = algo.parse_params({"spp": spp})
    algo.render(sc, params)                                   # warm-up: JIT / cache load
    result = benchmark.pedantic(algo.render, args=(sc, params), rounds=5, iterations=1)
    assert np.isfinite(result.image).all()
    rays = result.counters["camera_rays"] + result.counters["shadow_rays"]
    benchmark.extra_info.update(rays=rays, rays_per_s=rays / median_s(benchmark))


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene, spp", CASES, ids=IDS)
def bench_mitsuba_direct(benchmark, scene, spp):
    import drjit as dr

    from references.mitsuba_env import load_mitsuba
    from references.reference import load_scene as mi_load_scene, prepare_scene_xml

    mi = load_mitsuba()
    xml, _, _ = prepare_scene_xml(SUITES / scene, transport="direct", spp_per_pass=spp, seed=0)
    mi_scene = mi_load_scene(mi, SUITES / scene, xml)

    def render():
        img = mi.render(mi_scene, spp=spp, seed=0)
        dr.sync_thread()                                      # mi.render is lazy
        return img

    render()                                                  # warm-up: kernel compile
    img = benchmark.pedantic(render, rounds=5, iterations=1)
    assert np.isfinite(np.asarray(img)).all()
    benchmark.extra_info.update(variant=mi.variant())
