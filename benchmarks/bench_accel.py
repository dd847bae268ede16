"""Benchmarks (not tests) of the acceleration structures (impl.accel, issue 7).

* ``bench_build`` / ``bench_trace`` — every structure's build and closest-hit
  trace of the camera rays on 10⁴ random spheres and a 10⁵-triangle mesh.
* ``bench_vs_mitsuba`` — own closest-hit rays per second (BVH-SAH, float32 and
  float64) against Mitsuba's ``ray_intersect_preliminary`` and
  ``ray_intersect`` (LLVM variant) on the same primitives and the same rays,
  measured in one run: primary rays (pixel centres of a 256×192 camera) and
  incoherent rays (one cosine-distributed diffuse bounce from each primary
  hit).  ``extra_info`` carries both rays/s and the ratio own / Mitsuba.
* ``bench_packets`` — 8×8 eye-ray packets vs single rays through the same BVH.

    .venv/bin/python -m pytest benchmarks/bench_accel.py --benchmark-json reports/out/bench_accel.json

Warm-up (numba compile or cache load; Dr.Jit kernel compile) is excluded;
pytest-benchmark quotes the median of the rounds.
"""

import numpy as np
import pytest

from gibench import registry
from gibench.studies.accel import bounce_rays, camera_rays, mesh_field, sphere_field
from impl import accel
from impl.accel.packets import primary_hits
from impl.rays import ray_config
from impl.scene_arrays import flatten
from _timing import median_s

SCENES = {"spheres-1e4": lambda: sphere_field(10000, width=256, height=192),
          "mesh-1e5": lambda: mesh_field(100000, width=256, height=192)}
_cache = {}


def scene(name):
    if name not in _cache:
        sc = SCENES[name]()
        A = flatten(sc)
        o, d = camera_rays(sc)
        R0 = config(A, "bvh-sah")
        t, prim, _, _ = accel.trace_batch(R0, o, d)
        bo, bd = bounce_rays(A, o, d, t, prim, seed=1)
        _cache[name] = (sc, A, {"primary": (o, d), "diffuse": (bo, bd)})
    return _cache[name]


def config(A, name, precision="float64"):
    algo = registry.get("whitted")
    return ray_config(A, algo.parse_params({"accel": name, "precision": precision}), algorithm="whitted")


@pytest.mark.parametrize("structure", accel.ACCELS[1:])
@pytest.mark.parametrize("name", list(SCENES))
def bench_build(benchmark, name, structure):
    _, A, _ = scene(name)
    config(A, structure)                                            # warm-up
    R = benchmark.pedantic(config, args=(A, structure), rounds=3, iterations=1)
    benchmark.extra_info.update(memory_mb=accel.memory_bytes(accel.Accel(*R[8:])) / 1e6,
                                prims=len(A.sph_radius) + len(A.tri_v))


@pytest.mark.parametrize("structure", accel.ACCELS)
@pytest.mark.parametrize("rays", ["primary", "diffuse"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_trace(benchmark, name, rays, structure):
    _, A, ray_sets = scene(name)
    o, d = ray_sets[rays]
    n_prims = len(A.sph_radius) + len(A.tri_v)
    if structure in ("none", "bv", "bv-sphere", "slabs") and n_prims * len(o) > 2e9:
        pytest.skip(f"{structure}: ~{n_prims * len(o):.0e} primitive tests per run")
    R = config(A, structure)
    accel.trace_batch(R, o, d)                                       # warm-up
    t, prim, _, counts = benchmark.pedantic(accel.trace_batch, args=(R, o, d), rounds=5, iterations=1)
    benchmark.extra_info.update(rays=len(o), rays_per_s=len(o) / median_s(benchmark),
                                tests_per_ray=float(counts[:, 1].mean()),
                                nodes_per_ray=float(counts[:, 0].mean()))


@pytest.mark.mitsuba
@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("rays", ["primary", "diffuse"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_vs_mitsuba(benchmark, name, rays, precision):
    """Own BVH-SAH closest hits vs Mitsuba on the same rays, timed in one run."""
    from references.mitsuba_env import load_mitsuba
    from references.raybench import mitsuba_scene, time_mitsuba

    mitsuba = load_mitsuba()
    _, A, ray_sets = scene(name)
    o, d = ray_sets[rays]
    R = config(A, "bvh-sah", precision)
    accel.trace_batch(R, o, d)                                       # warm-up
    t, prim, _, _ = benchmark.pedantic(accel.trace_batch, args=(R, o, d), rounds=7, iterations=1)
    own_s = median_s(benchmark)
    mi_scene = mitsuba_scene(mitsuba, A.sph_center, A.sph_radius, A.tri_v)
    mi_pre_s, t_mi = time_mitsuba(mitsuba, mi_scene, o, d, rounds=7)
    mi_full_s, _ = time_mitsuba(mitsuba, mi_scene, o, d, rounds=7, full=True)
    # Same rays, same geometry: hit/miss must agree except at silhouettes.
    agree = float(((prim >= 0) == np.isfinite(t_mi)).mean())
    assert agree > 0.99, f"own and Mitsuba hit/miss agree on only {agree:.4f} of the rays"
    n = len(o)
    benchmark.extra_info.update(
        variant=mitsuba.variant(), rays=n, own_rays_per_s=n / own_s,
        mitsuba_preliminary_rays_per_s=n / mi_pre_s, mitsuba_full_rays_per_s=n / mi_full_s,
        ratio_own_vs_mitsuba_preliminary=(n / own_s) / (n / mi_pre_s),
        ratio_own_vs_mitsuba_full=(n / own_s) / (n / mi_full_s), hit_miss_agreement=agree)


@pytest.mark.parametrize("packets", [False, True], ids=["single", "packets"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_packets(benchmark, name, packets):
    sc, A, _ = scene(name)
    R = config(A, "bvh-sah")
    primary_hits(R, sc.camera, packets=packets)                     # warm-up
    depth, prim, counts = benchmark.pedantic(primary_hits, args=(R, sc.camera),
                                             kwargs={"packets": packets}, rounds=7, iterations=1)
    n = prim.size
    benchmark.extra_info.update(rays=n, rays_per_s=n / median_s(benchmark),
                                nodes_per_ray=counts[0] / n, tests_per_ray=counts[1] / n)
