"""Benchmarks (not tests) of eye-ray packets in the ray tracers (``packets=true``).

``bench_tracer_packets`` renders 10⁴ random spheres (``sphere_field``) and a
10⁵-triangle mesh (``mesh_field``) at 256×192 with ``raycast``, ``whitted``
and ``path`` (small spp), ``packets=false`` and ``packets=true``, both through
the same structure: the binary SAH BVH (``accel=bvh-sah``; packets loop over
their rays at each node) or the wide BVH (``accel=bvh-wide``; vectorised over
the packet's rays, switching to single rays when few are active).  The two variants of a case run one after the
other in the same pytest run; the ``packets=true`` one stores in ``extra_info``
the ratio ``single / packets`` of the two medians (> 1: packets faster), the
same ratio from ``ALTERNATED`` further renders of each alternating single and
packets (less exposed to a shared machine's drift), and the packets' nodes and
primitive tests per eye ray next to single-ray traversal's (pixel-centre eye
rays through the same BVH, :func:`impl.accel.packets.primary_hits`: the
tracers do not count single-ray work).  Render time includes building
the BVH (``render`` builds it); ``extra_info.build_s`` is that build's median,
to subtract.  ``raycast`` renders the fields with every material diffuse (it
refuses mirrors).

    .venv/bin/python -m pytest benchmarks/bench_packets.py --benchmark-json reports/out/bench_packets.json

Warm-up (numba compile or cache load) is excluded; pytest-benchmark quotes the
median of the rounds.  Figures measured on the shared 2-core VM are in the
integrator's notes (README); the default stays ``packets=false`` unless packets
are measured faster.
"""

import statistics
import time
from dataclasses import replace

import pytest

from gibench import registry
from gibench.studies_accel import mesh_field, sphere_field
from impl.accel.packets import primary_hits
from impl.rays import ray_config
from impl.scene_arrays import flatten
from _timing import median_s

W, H = 256, 192
SCENES = {"spheres-1e4": lambda: sphere_field(10000, width=W, height=H),
          "mesh-1e5": lambda: mesh_field(100000, width=W, height=H)}
TRACERS = {"raycast": {"spp": 4, "light_samples": 4},
           "whitted": {"spp": 4, "light_samples": 4},
           "path": {"spp": 4, "max_depth": 4}}
ROUNDS = 5
ALTERNATED = 7
_scenes = {}
_single = {}                                   # (tracer, scene, accel) -> median s of packets=false


def scene(name, tracer):
    key = (name, tracer == "raycast")
    if key not in _scenes:
        sc = _scenes.get((name, False)) or SCENES[name]()
        if tracer == "raycast":             # raycast shades diffuse surfaces only
            diffuse = next(i for i, m in enumerate(sc.materials) if m.kind == "diffuse")
            sc = replace(sc, shapes=[s if sc.materials[s.material].kind == "diffuse"
                                     else replace(s, material=diffuse) for s in sc.shapes])
        _scenes[key] = sc
    return _scenes[key]


@pytest.mark.parametrize("packets", [False, True], ids=["single", "packets"])
@pytest.mark.parametrize("accel", ["bvh-sah", "bvh-wide"])
@pytest.mark.parametrize("tracer", list(TRACERS))
@pytest.mark.parametrize("name", list(SCENES))
def bench_tracer_packets(benchmark, name, tracer, accel, packets):
    sc = scene(name, tracer)
    algo = registry.get(tracer)
    params = algo.parse_params({**TRACERS[tracer], "accel": accel, "packets": packets})
    algo.render(sc, params, seed=0)                                 # warm-up
    res = benchmark.pedantic(algo.render, args=(sc, params), kwargs={"seed": 0},
                             rounds=ROUNDS, iterations=1)
    t = median_s(benchmark)
    info = {"pixels": W * H, "spp": params["spp"]}
    if not packets:
        _single[(tracer, name, accel)] = (t, res.image)
    else:
        eye = W * H * params["spp"]
        info.update(packet_nodes_per_eye_ray=res.counters["packet_nodes"] / eye,
                    packet_tests_per_eye_ray=res.counters["packet_tests"] / eye)
        if (tracer, name, accel) in _single:
            t_single, img = _single[(tracer, name, accel)]
            info["ratio_single_over_packets"] = t_single / t
            assert (img == res.image).all(), "packets changed the image"
        single_params = {**params, "packets": False}
        t_s, t_p = [], []
        for _ in range(ALTERNATED):
            for flag, times in ((False, t_s), (True, t_p)):
                t0 = time.perf_counter()
                algo.render(sc, params if flag else single_params, seed=0)
                times.append(time.perf_counter() - t0)
        info["ratio_single_over_packets_alternated"] = statistics.median(t_s) / statistics.median(t_p)
        A = flatten(sc)
        R = ray_config(A, params, algorithm=tracer)
        for flag in (False, True):
            _, _, counts = primary_hits(R, sc.camera, packets=flag)
            label = "packet" if flag else "single"
            info[f"centre_rays_{label}_nodes_per_ray"] = counts[0] / (W * H)
            info[f"centre_rays_{label}_tests_per_ray"] = counts[1] / (W * H)
        builds = []
        for _ in range(3):
            t0 = time.perf_counter()
            ray_config(A, params, algorithm=tracer)
            builds.append(time.perf_counter() - t0)
        info["build_s"] = statistics.median(builds)
    benchmark.extra_info.update(info)
