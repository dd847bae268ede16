"""Benchmarks (not tests) of the acceleration structures (impl.accel).

* ``bench_build`` / ``bench_trace`` — every structure's build and closest-hit
  trace of the camera rays on 10⁴ random spheres and a 10⁵-triangle mesh.
* ``bench_build_1e6`` — the SAH build of a 10⁶-triangle mesh alone and with
  the wide collapse (``bvh-wide``).
* ``bench_build_vs_mitsuba`` — the same builds against Mitsuba's Embree build
  over the same triangles (``mi.load_dict`` of the mesh's scene, the upload
  excluded), rounds alternated; on all threads and on one thread each side;
  wall and CPU time.
* ``bench_build_pays_off`` — build time against the time the structure saves
  on the closest-hit queries of a 256×192 render (camera rays and one diffuse
  bounce) over brute force, brute force timed on 64 rays per set and
  extrapolated.
* ``bench_vs_mitsuba`` — own closest-hit rays per second (float32 and float64)
  against Mitsuba's ``ray_intersect_preliminary`` and ``ray_intersect`` (LLVM
  variant) on the same primitives and the same rays, own and Mitsuba rounds
  alternated in one run: primary rays (pixel centres of a 256×192 camera) and
  incoherent rays (one cosine-distributed diffuse bounce from each primary
  hit).  ``bvh-sah`` through :func:`impl.accel.trace_batch` (one call per ray,
  with counters), ``bvh-wide`` through :func:`impl.accel.wide.wide_closest_batch`
  (the SoA batch entry point, no counters).  ``extra_info`` carries both
  rays/s and the ratio own / Mitsuba (of the medians, and the median of the
  per-pair ratios).  In a round each side's timed pass follows an untimed pass
  of its own after ``settle`` (:func:`references.raybench.time_mitsuba` makes
  one), so both run with their thread pools awake; the own pass right after
  ``settle`` is reported too (``own_rays_per_s_after_idle``): waking numba's
  OpenMP workers after the process idled can take longer than a pass.
* ``bench_vs_mitsuba_cpu`` — single-thread CPU time per ray of the wide BVH's
  serial batch loop against Mitsuba's ``ray_intersect_preliminary`` on one
  Dr.Jit thread, rounds alternated (less moved by other processes' load than
  wall-clock time).
* ``bench_packets`` — 8×8 eye-ray packets vs single rays through the same tree.
* ``bench_wide_packets`` — the wide BVH's batch entry points on coherent rays
  (eye rays in 8×8 tile order, shadow rays from their hits to a point light):
  single rays vs packets of 64.

    .venv/bin/python -m pytest benchmarks/bench_accel.py --benchmark-json reports/out/bench_accel.json

Warm-up (numba compile or cache load; Dr.Jit kernel compile) is excluded;
pytest-benchmark quotes the median of the rounds.
"""

import statistics
import time

import numpy as np
import pytest

from gibench import registry
from gibench.studies.accel import bounce_rays, camera_rays, mesh_field, sphere_field
from gibench.interleave import settle
from impl import accel
from impl.accel.packets import primary_hits
from impl.accel.wide import (wide_closest_batch, wide_closest_packets, wide_closest_rays,
                             wide_occluded_batch, wide_occluded_packets)
from impl.rays import ray_config, structure
from impl.scene_arrays import flatten
from _timing import median_s

SCENES = {"spheres-1e4": lambda: sphere_field(10000, width=256, height=192),
          "mesh-1e5": lambda: mesh_field(100000, width=256, height=192)}
_cache = {}
ROUNDS = 7


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
    benchmark.extra_info.update(memory_mb=accel.memory_bytes(structure(R)) / 1e6,
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


def soa(o, d):
    """The rays as the batch entry points take them: six contiguous (N,) arrays."""
    return [np.ascontiguousarray(x) for x in (*np.asarray(o).T, *np.asarray(d).T)]


def own_tracer(R, structure, o, d):
    """A no-argument closest-hit pass over the rays: ``trace_batch`` for the binary
    trees, the SoA batch kernel for the wide BVH; returns ``(t, prim)``."""
    if structure != "bvh-wide":
        return lambda: accel.trace_batch(R, o, d)[:2]
    cols, n = soa(o, d), len(o)
    tmin, tmax = np.zeros(n), np.full(n, np.inf)
    out = (np.empty(n), np.empty(n, dtype=np.int64), np.empty(n), np.empty(n))

    def run():
        wide_closest_batch(R, *cols, tmin, tmax, *out)
        return out[0], out[1]
    return run


def mesh_1e6():
    """The 10⁶-triangle mesh (:func:`mesh_field`, 256×192 camera), built once per session:
    ``(scene, arrays, {"primary": rays, "diffuse": rays})``; the ray sets are made on
    first use (:func:`mesh_1e6_rays`)."""
    if "mesh-1e6" not in _cache:
        sc = mesh_field(1_000_000, width=256, height=192)
        _cache["mesh-1e6"] = (sc, flatten(sc), {})
    return _cache["mesh-1e6"]


def mesh_1e6_rays():
    """The 10⁶-triangle mesh's camera rays (pixel centres) and one diffuse bounce
    from each camera hit (the ray sets of :func:`scene`)."""
    sc, A, ray_sets = mesh_1e6()
    if not ray_sets:
        o, d = camera_rays(sc)
        t, prim, _, _ = accel.trace_batch(config(A, "bvh-sah"), o, d)
        ray_sets["primary"] = (o, d)
        ray_sets["diffuse"] = bounce_rays(A, o, d, t, prim, seed=1)
    return sc, A, ray_sets


@pytest.mark.parametrize("structure", ["bvh-sah", "bvh-wide"])
def bench_build_1e6(benchmark, structure):
    """Build (and collapse) over 10⁶ triangles: the whole :func:`impl.rays.ray_config`."""
    _, A, _ = mesh_1e6()
    config(A, structure)                                            # warm-up
    R = benchmark.pedantic(config, args=(A, structure), rounds=3, iterations=1)
    benchmark.extra_info.update(prims=len(A.tri_v), memory_mb=accel.memory_bytes(structure(R)) / 1e6)


@pytest.mark.mitsuba
@pytest.mark.parametrize("threads", ["all", "one"])
def bench_build_vs_mitsuba(benchmark, threads):
    """Own SAH build (``bvh-sah``, and ``bvh-wide`` = the same build plus the collapse
    to 4-wide nodes) against Mitsuba's Embree build over the same 10⁶ triangles,
    rounds alternated in one process (:func:`gibench.interleave.run_rounds`: a
    settle before every timed task, every other round in reverse order).

    Own: :func:`impl.rays.ray_config` (bounds, build, collapse; serial numba code).
    Mitsuba: ``mi.load_dict`` of a scene of the mesh alone, the mesh uploaded before
    the clock (:func:`references.raybench.time_mitsuba_build`), next to the same for
    a one-triangle mesh (the scene constructor's fixed work) and Mitsuba's own log of
    the build.  ``threads``: ``all`` leaves Dr.Jit's pool and numba at their thread
    counts (Embree builds in parallel); ``one`` sets both to one thread.  Each task
    records wall time, process CPU time and the number of threads that did ≥ 10 %
    of the work (``/proc/self/task``), in ``extra_info``; pytest-benchmark's own row
    is one more ``bvh-sah`` build after the rounds."""
    import drjit as dr
    import numba

    from gibench.interleave import Timed, run_rounds
    from references.mitsuba_env import load_mitsuba
    from references.raybench import mitsuba_mesh, time_mitsuba_build
    from _timing import busy_threads, thread_cpu

    mi = load_mitsuba()
    _, A, _ = mesh_1e6()
    meshes = {"mitsuba": mitsuba_mesh(mi, A.tri_v), "mitsuba_1tri": mitsuba_mesh(mi, A.tri_v[:1])}
    extra = {}

    def own(structure):
        def run(k):
            before = thread_cpu()
            c0, t0 = time.process_time(), time.perf_counter()
            config(A, structure)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            extra.setdefault(structure, []).append((cpu, busy_threads(before, thread_cpu()), None))
            return wall
        return run

    def mitsuba(name):
        def run(k):
            before = thread_cpu()
            wall, cpu, logged = time_mitsuba_build(mi, meshes[name])
            extra.setdefault(name, []).append((cpu, busy_threads(before, thread_cpu()), logged))
            return wall
        return run

    tasks = [Timed("bvh-sah", "own", own("bvh-sah")), Timed("mitsuba", "mitsuba", mitsuba("mitsuba")),
             Timed("bvh-wide", "own", own("bvh-wide")),
             Timed("mitsuba_1tri", "mitsuba", mitsuba("mitsuba_1tri"))]
    dr_threads, nb_threads = dr.thread_count(), numba.get_num_threads()
    if threads == "one":
        dr.set_thread_count(1)
        numba.set_num_threads(1)
    try:
        for t in tasks:                                  # warm-up: numba cache, Embree device
            t.run(-1)
        extra.clear()
        res = run_rounds(tasks, ROUNDS)
        settle()
        benchmark.pedantic(config, args=(A, "bvh-sah"), rounds=1, iterations=1)   # the table's row
    finally:
        dr.set_thread_count(dr_threads)
        numba.set_num_threads(nb_threads)
    med = statistics.median
    info = {"prims": len(A.tri_v), "variant": mi.variant(), "threads": threads,
            "dr_threads": 1 if threads == "one" else dr_threads, "load_before_after": res["load"]}
    for t, times in zip(tasks, res["times"]):
        cpu = [c for c, _, _ in extra[t.name]]
        info[f"{t.name}_wall_s"] = (min(times), med(times), max(times))
        info[f"{t.name}_cpu_s"] = (min(cpu), med(cpu), max(cpu))
        info[f"{t.name}_busy_threads"] = max(b for _, b, _ in extra[t.name])
    logged = [x for _, _, x in extra["mitsuba"] if x is not None]
    if logged:
        info["mitsuba_logged_build_s"] = (min(logged), med(logged), max(logged))
    times = dict(zip([t.name for t in tasks], res["times"]))
    for s in ("bvh-sah", "bvh-wide"):
        pair = [o / m for o, m in zip(times[s], times["mitsuba"])]
        info[f"{s}_over_mitsuba_wall_pairs"] = (min(pair), med(pair), max(pair))
        cpu = [o[0] / m[0] for o, m in zip(extra[s], extra["mitsuba"])]
        info[f"{s}_over_mitsuba_cpu_pairs"] = (min(cpu), med(cpu), max(cpu))
    benchmark.extra_info.update(info)
    assert info["bvh-sah_busy_threads"] >= 1 and info["mitsuba_wall_s"][1] > info["mitsuba_1tri_wall_s"][1]


@pytest.mark.parametrize("structure", ["bvh-sah", "bvh-wide"])
def bench_build_pays_off(benchmark, structure):
    """Build time against the render time the structure saves over brute force on the
    10⁶-triangle mesh.  The render's queries: the closest hits of the 256×192 camera
    rays (pixel centres) and of one diffuse bounce from each camera hit.  Rounds
    alternated (build, trace with the structure, brute force), each after a settle.

    Brute force over 10⁶ triangles would take minutes a round, so it runs on a subset
    (every ``stride``-th ray of each set, :data:`BRUTE_RAYS` per set) and its time is
    extrapolated linearly in the number of rays (brute force costs the same
    N triangle tests per ray, whatever the ray); the subset's hits are checked
    against the structure's.  ``saved_s`` = extrapolated brute-force time − the
    structure's trace time; ``build_over_saved`` ≤ 1 means the build pays for itself
    in this one render; ``break_even_rays`` = rays at which it does.  The figures are
    in ``extra_info``; pytest-benchmark's own row is one more build after the rounds."""
    from gibench.interleave import load_average

    _, A, ray_sets = mesh_1e6_rays()
    R = config(A, structure)
    brute = config(A, "none")
    runs, subsets = {}, {}
    for name, (o, d) in ray_sets.items():
        runs[name] = own_tracer(R, structure, o, d)
        stride = max(1, len(o) // BRUTE_RAYS)
        subsets[name] = (slice(0, stride * BRUTE_RAYS, stride), o[::stride][:BRUTE_RAYS], d[::stride][:BRUTE_RAYS])
    for name, run in runs.items():                               # warm-up, and the subset check
        t, prim = run()
        sub, o, d = subsets[name]
        tb, pb, _, _ = accel.trace_batch(brute, o, d)
        assert np.array_equal(pb >= 0, prim[sub] >= 0), f"{name}: brute force and {structure} disagree on hit/miss"
        assert np.allclose(tb, t[sub], rtol=1e-9, atol=0), f"{name}: brute force and {structure} disagree on t"
    times = {"build": [], **{f"trace_{n}": [] for n in runs}, **{f"brute_{n}": [] for n in runs}}
    load = [load_average()]
    for _ in range(BRUTE_ROUNDS):
        settle()
        t0 = time.perf_counter()
        config(A, structure)
        times["build"].append(time.perf_counter() - t0)
        for name, run in runs.items():
            settle()
            t0 = time.perf_counter()
            run()
            times[f"trace_{name}"].append(time.perf_counter() - t0)
            settle()
            _, o, d = subsets[name]
            t0 = time.perf_counter()
            accel.trace_batch(brute, o, d)
            times[f"brute_{name}"].append(time.perf_counter() - t0)
    load.append(load_average())
    settle()
    benchmark.pedantic(config, args=(A, structure), rounds=1, iterations=1)   # the table's row
    med = statistics.median
    n_rays = {name: len(o) for name, (o, _) in ray_sets.items()}
    brute_per_ray = sum(med(times[f"brute_{n}"]) for n in runs) / (BRUTE_RAYS * len(runs))
    brute_s = sum(med(times[f"brute_{n}"]) / BRUTE_RAYS * n_rays[n] for n in runs)
    trace_s = sum(med(times[f"trace_{n}"]) for n in runs)
    build_s = med(times["build"])
    rays = sum(n_rays.values())
    info = {f"{k}_s": (min(v), med(v), max(v)) for k, v in times.items()}
    info.update(prims=len(A.tri_v), rays=n_rays, brute_rays_per_set=BRUTE_RAYS, load_before_after=load,
                brute_ns_per_ray_per_triangle=brute_per_ray / len(A.tri_v) * 1e9,
                brute_extrapolated_s=brute_s, trace_s=trace_s, build_s=build_s,
                saved_s=brute_s - trace_s, build_over_saved=build_s / (brute_s - trace_s),
                break_even_rays=build_s / (brute_per_ray - trace_s / rays))
    benchmark.extra_info.update(info)


#: Rays per ray set that brute force traces in :func:`bench_build_pays_off`, and its rounds.
BRUTE_RAYS = 64
BRUTE_ROUNDS = 5


@pytest.mark.mitsuba
@pytest.mark.parametrize("structure", ["bvh-sah", "bvh-wide"])
@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("rays", ["primary", "diffuse"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_vs_mitsuba(benchmark, name, rays, precision, structure):
    """Own closest hits vs Mitsuba on the same rays, rounds alternated in one run."""
    from references.mitsuba_env import load_mitsuba
    from references.raybench import mitsuba_scene, time_mitsuba

    mitsuba = load_mitsuba()
    _, A, ray_sets = scene(name)
    o, d = ray_sets[rays]
    R = config(A, structure, precision)
    run = own_tracer(R, structure, o, d)
    run()                                                            # warm-up
    t, prim = benchmark.pedantic(run, rounds=ROUNDS, iterations=1)
    own_s = median_s(benchmark)
    mi_scene = mitsuba_scene(mitsuba, A.sph_center, A.sph_radius, A.tri_v)
    mi_full_s, t_mi = time_mitsuba(mitsuba, mi_scene, o, d, rounds=ROUNDS, full=True)
    own, own_idle, mi = [], [], []
    for _ in range(ROUNDS):                                          # A B A B ...
        settle()                                  # the other side's threads idle
        t0 = time.perf_counter()
        run()                                     # as Mitsuba's first call: untimed in the ratio
        own_idle.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        run()
        own.append(time.perf_counter() - t0)
        settle()
        mi.append(time_mitsuba(mitsuba, mi_scene, o, d, rounds=1)[0])   # a call, then the timed one
    # Same rays, same geometry: hit/miss must agree except at silhouettes.
    agree = float(((prim >= 0) == np.isfinite(t_mi)).mean())
    assert agree > 0.99, f"own and Mitsuba hit/miss agree on only {agree:.4f} of the rays"
    n = len(o)
    mi_pre_s = statistics.median(mi)
    pair = [m / s for s, m in zip(own, mi)]
    benchmark.extra_info.update(
        variant=mitsuba.variant(), rays=n, own_rays_per_s=n / own_s,
        own_rays_per_s_alternated=n / statistics.median(own),
        own_rays_per_s_after_idle=n / statistics.median(own_idle),
        mitsuba_preliminary_rays_per_s=n / mi_pre_s, mitsuba_full_rays_per_s=n / mi_full_s,
        ratio_own_vs_mitsuba_preliminary=mi_pre_s / statistics.median(own),
        ratio_own_vs_mitsuba_preliminary_pairs_median=statistics.median(pair),
        ratio_own_vs_mitsuba_preliminary_pairs_range=(min(pair), max(pair)),
        ratio_own_vs_mitsuba_full=mi_full_s / own_s, hit_miss_agreement=agree)


@pytest.mark.mitsuba
@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("rays", ["primary", "diffuse"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_vs_mitsuba_cpu(benchmark, name, rays, precision):
    """Single-thread CPU time per ray, own wide BVH vs Mitsuba, rounds alternated.

    Own: the serial batch loop :func:`impl.accel.wide.wide_closest_rays` under
    ``time.thread_time``; Mitsuba: ``ray_intersect_preliminary`` with Dr.Jit's
    thread pool set to one thread, under ``time.process_time`` (all of the
    process's threads).  CPU time does not count the time a thread waits for a
    core, so on a shared machine it moves less than wall-clock time; one thread
    on each side leaves out both sides' parallel scaling."""
    import drjit as dr

    from references.mitsuba_env import load_mitsuba
    from references.raybench import mitsuba_scene

    mitsuba = load_mitsuba()
    _, A, ray_sets = scene(name)
    o, d = ray_sets[rays]
    R = config(A, "bvh-wide", precision)
    cols, n = soa(o, d), len(o)
    tmin, tmax = np.zeros(n), np.full(n, np.inf)
    out = (np.empty(n), np.empty(n, dtype=np.int64), np.empty(n), np.empty(n))

    def run():
        wide_closest_rays(R, *cols, tmin, tmax, *out)
        return out[0], out[1]
    run()                                                            # warm-up
    mi_scene = mitsuba_scene(mitsuba, A.sph_center, A.sph_radius, A.tri_v)
    o32, d32 = np.asarray(o, np.float32), np.asarray(d, np.float32)
    ray = mitsuba.Ray3f(o=mitsuba.Point3f(*o32.T), d=mitsuba.Vector3f(*d32.T))
    dr.eval(ray)                                                     # uploaded before the clock

    def mi_run():
        si = mi_scene.ray_intersect_preliminary(ray)
        dr.eval(si.t)
        dr.sync_thread()                                             # Dr.Jit evaluates lazily
        return si.t
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        t_mi = np.asarray(mi_run(), dtype=np.float64)                # warm-up (kernel compile)
        own, mi = [], []
        for _ in range(ROUNDS):                                      # A B A B ...
            c0 = time.thread_time()
            run()
            own.append(time.thread_time() - c0)
            c0 = time.process_time()
            mi_run()
            mi.append(time.process_time() - c0)
    finally:
        dr.set_thread_count(threads)
    benchmark.pedantic(run, rounds=1, iterations=1)
    agree = float(((out[1] >= 0) == np.isfinite(t_mi)).mean())
    assert agree > 0.99, f"own and Mitsuba hit/miss agree on only {agree:.4f} of the rays"
    own_ns, mi_ns = statistics.median(own) / n * 1e9, statistics.median(mi) / n * 1e9
    pair = [m / s for s, m in zip(own, mi)]
    benchmark.extra_info.update(
        variant=mitsuba.variant(), rays=n, own_cpu_ns_per_ray=own_ns, mitsuba_cpu_ns_per_ray=mi_ns,
        ratio_own_vs_mitsuba_cpu=mi_ns / own_ns,
        ratio_own_vs_mitsuba_cpu_pairs=(min(pair), statistics.median(pair), max(pair)))


@pytest.mark.parametrize("packets", [False, True], ids=["single", "packets"])
@pytest.mark.parametrize("structure", ["bvh-sah", "bvh-wide"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_packets(benchmark, name, structure, packets):
    sc, A, _ = scene(name)
    R = config(A, structure)
    primary_hits(R, sc.camera, packets=packets)                     # warm-up
    depth, prim, counts = benchmark.pedantic(primary_hits, args=(R, sc.camera),
                                             kwargs={"packets": packets}, rounds=7, iterations=1)
    n = prim.size
    benchmark.extra_info.update(rays=n, rays_per_s=n / median_s(benchmark),
                                nodes_per_ray=counts[0] / n, tests_per_ray=counts[1] / n)


def tile_order(width, height, tile=8):
    """Pixel indices of a width×height image tile by tile (row-major tiles of tile×tile)."""
    idx = np.arange(width * height).reshape(height // tile, tile, width // tile, tile)
    return idx.transpose(0, 2, 1, 3).reshape(-1)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("kind", ["eye", "shadow"])
@pytest.mark.parametrize("packets", [False, True], ids=["single", "packets64"])
@pytest.mark.parametrize("name", list(SCENES))
def bench_wide_packets(benchmark, name, packets, kind, precision):
    """Coherent rays through the wide BVH's batch entry points: eye rays in tile order
    (closest hit), or shadow rays from their hits to a point light above the scene
    (any hit; rays that missed are left out), single rays vs packets of 64."""
    sc, A, ray_sets = scene(name)
    R = config(A, "bvh-wide", precision)
    o, d = ray_sets["primary"]
    order = tile_order(sc.camera.film.width, sc.camera.film.height)
    o, d = np.ascontiguousarray(o[order]), np.ascontiguousarray(d[order])
    n = len(o)
    tmin, tmax = np.zeros(n), np.full(n, np.inf)
    out = (np.empty(n), np.empty(n, dtype=np.int64), np.empty(n), np.empty(n))
    if kind == "eye":
        cols = soa(o, d)
        if packets:
            def run():
                wide_closest_packets(R, *cols, tmin, tmax, *out, 64)
        else:
            def run():
                wide_closest_batch(R, *cols, tmin, tmax, *out)
    else:
        wide_closest_batch(R, *soa(o, d), tmin, tmax, *out)
        hit = out[1] >= 0
        p = o[hit] + out[0][hit, None] * d[hit]
        to_light = np.array([0.0, 10.0, 0.0]) - p
        dist = np.linalg.norm(to_light, axis=1)
        sd = to_light / dist[:, None]
        cols = soa(p + 1e-4 * sd, sd)
        n = len(p)
        s_min, s_max = np.zeros(n), dist * (1.0 - 1e-6)
        occ = np.empty(n, dtype=np.bool_)
        if packets:
            def run():
                wide_occluded_packets(R, *cols, s_min, s_max, occ, 64)
        else:
            def run():
                wide_occluded_batch(R, *cols, s_min, s_max, occ)
    run()                                                            # warm-up
    benchmark.pedantic(run, rounds=ROUNDS, iterations=1)
    benchmark.extra_info.update(rays=n, rays_per_s=n / median_s(benchmark))


def sphere_field_xml(path, n, *, width=256, height=192, seed=3):
    """A scene file of ``n`` diffuse spheres (centres uniform in [-1, 1]³, radius
    0.3·n^(-1/3)) lit by one point light, readable by the own loader and by Mitsuba."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-1.0, 1.0, (n, 3))
    r = 0.3 * n ** (-1.0 / 3.0)
    shapes = "\n".join(
        f'    <shape type="sphere"><point name="center" value="{x:.6f}, {y:.6f}, {z:.6f}"/>'
        f'<float name="radius" value="{r:.6f}"/><ref id="mat"/></shape>' for x, y, z in c)
    path.write_text(f"""<?xml version="1.0" encoding="utf-8"?>
<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0.5, 4.5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="point"><point name="position" value="2, 4, 4"/><rgb name="intensity" value="40, 40, 40"/></emitter>
    <bsdf type="diffuse" id="mat"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>
{shapes}
</scene>
""")
    return path


@pytest.mark.mitsuba
def bench_raycast_vs_mitsuba_direct(benchmark, tmp_path):
    """Own ``raycast`` (bvh-sah and bvh-wide) vs Mitsuba ``direct`` on 2000 spheres at
    4 spp, 256×192, renders alternated in one run (own render time includes the build)."""
    import drjit as dr

    from core.loader import load_scene
    from references.mitsuba_env import load_mitsuba
    from references.reference import load_scene as mi_load_scene, prepare_scene_xml

    path = sphere_field_xml(tmp_path / "spheres2000.xml", 2000)
    mi = load_mitsuba()
    xml, _, _ = prepare_scene_xml(path, transport="direct", spp_per_pass=4, seed=0)
    mi_scene = mi_load_scene(mi, path, xml)

    def mitsuba():
        img = mi.render(mi_scene, spp=4, seed=0)
        dr.sync_thread()                                      # mi.render is lazy
        return img

    algo = registry.get("raycast")
    sc = load_scene(path)
    params = {s: algo.parse_params({"spp": 4, "accel": s}) for s in ("bvh-sah", "bvh-wide")}
    runs = {"mitsuba": mitsuba, **{s: (lambda p=p: algo.render(sc, p, seed=0)) for s, p in params.items()}}
    for run in runs.values():                                 # warm-up: compile / cache load
        run()
    times = {k: [] for k in runs}
    for _ in range(ROUNDS):                                   # A B C A B C ...
        for k, run in runs.items():
            settle()                              # the other side's threads idle
            t0 = time.perf_counter()
            run()
            times[k].append(time.perf_counter() - t0)
    benchmark.pedantic(runs["bvh-wide"], rounds=1, iterations=1)
    med = {k: statistics.median(v) for k, v in times.items()}
    info = {f"{k}_s": v for k, v in med.items()}
    for s in params:
        pair = [m / o for o, m in zip(times[s], times["mitsuba"])]
        info[f"speed_{s}_vs_mitsuba"] = med["mitsuba"] / med[s]
        info[f"speed_{s}_vs_mitsuba_pairs"] = (min(pair), statistics.median(pair), max(pair))
    benchmark.extra_info.update(info)
