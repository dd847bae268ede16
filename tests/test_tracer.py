"""The tracer core (impl.tracer): the vectorised brute-force batch queries return, ray for
ray, what the scalar scene queries return (primitive, t, barycentrics, any-hit answer)
on the random rays and scenes of test_accel, in float64 and float32; their inner loops
compile to SIMD code; the per-scene memo of flattened arrays and ray configurations is
reused and rebuilt when the scene changes; renders report their setup and trace times."""

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from gibench import registry
from core.loader import load_scene
from impl import tracer
from impl.intersect import any_hit_form, closest_hit_form
from impl.rays import hit, occluded
from impl.scene_arrays import flatten_cached

from test_accel import SEED, config, random_rays, random_scene

SUITES = Path(__file__).resolve().parent.parent / "suites"


def _batch(o, d, tmin=1e-6, tmax=np.inf):
    n = len(o)
    ray = np.empty((8, n))
    ray[0:3] = o.T
    ray[3:6] = d.T
    ray[6] = tmin
    ray[7] = tmax
    return ray


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_batch_queries_equal_the_scalar_queries_ray_for_ray(dtype):
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    c, r, v, shape = random_scene(rng, 40, 60)
    R = config(c, r, v, shape, "none", dtype)
    o, d = random_rays(rng, 2000)
    o, d = o.astype(dtype).astype(np.float64), d.astype(dtype).astype(np.float64)
    ray = _batch(o, d)
    n = len(o)
    t, prim, b = np.empty(n), np.empty(n, np.int64), np.empty((2, n))
    q, qt, qp = np.empty((8, n), dtype), np.empty((3, n), dtype), np.empty(n, np.int32)
    tracer.closest_batch(R, ray, n, t, prim, b, q, qt, qp)
    blocked = np.empty(n, np.bool_)
    ray_sh = ray.copy()
    ray_sh[7] = 1.5                                      # finite shadow segments too
    tracer.occluded_batch(R, ray_sh, n, blocked, q)
    F = dtype
    for i in range(n):
        args = [F(x) for x in ray[:8, i]]
        et, ep, eb1, eb2 = closest_hit_form(2, *args, R.sph_center, R.sph_radius, R.tri_v)
        assert prim[i] == ep, f"ray {i}"
        assert t[i] == float(et) and b[0, i] == float(eb1) and b[1, i] == float(eb2), f"ray {i}"
        sh = [F(x) for x in ray_sh[:8, i]]
        assert blocked[i] == any_hit_form(2, *sh, R.sph_center, R.sph_radius, R.tri_v), f"ray {i}"
    assert (prim >= 0).sum() > n // 8 and blocked.sum() > n // 16  # the rays do hit


def _avx2() -> bool:
    try:
        return " avx2" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_brute_force_batch_loops_vectorise():
    """The primitive-outer / ray-inner loops use 256-bit registers (AVX2 ymm).  Compiled
    afresh here: numba shows no machine code for kernels loaded from its cache."""
    rng = np.random.default_rng(SEED)
    c, r, v, shape = random_scene(rng, 3, 3)
    R = config(c, r, v, shape, "none", np.float32)
    o, d = random_rays(rng, 64)
    ray = _batch(o, d)
    n = len(o)
    closest = njit(error_model="numpy")(tracer.closest_batch.py_func)
    occluded = njit(error_model="numpy")(tracer.occluded_batch.py_func)
    closest(R, ray, n, np.empty(n), np.empty(n, np.int64), np.empty((2, n)),
            np.empty((8, n), np.float32), np.empty((3, n), np.float32), np.empty(n, np.int32))
    occluded(R, ray, n, np.empty(n, np.bool_), np.empty((8, n), np.float32))
    for name, kernel in (("closest_batch", closest), ("occluded_batch", occluded)):
        asm = "\n".join(kernel.inspect_asm().values())
        assert re.search(r"vsqrtps\s+%ymm", asm) and re.search(r"vcmp\w*ps\s+%ymm", asm), name


def test_scene_memo_reuses_and_rebuilds():
    sc = load_scene(SUITES / "spheres/lit_sphere.xml")
    A = flatten_cached(sc)
    assert flatten_cached(sc) is A
    sc.lights = sc.lights[:0]                           # a changed scene is flattened again
    B = flatten_cached(sc)
    assert B is not A and len(B.light_kind) == 0
    other = replace(sc)
    assert flatten_cached(other) is not B


@pytest.mark.parametrize("name", ["raycast", "whitted"])
def test_renders_report_setup_and_trace_time(name):
    sc = load_scene(SUITES / "spheres/lit_sphere.xml")
    algo = registry.get(name)
    res = algo.render(sc, algo.parse_params({"spp": 1}))
    assert set(res.timings) >= {"setup_s", "trace_s"}
    assert all(v >= 0.0 for v in res.timings.values())


@njit(error_model="numpy")
def _per_ray(R, ray, t, prim, b, blocked):
    """impl.rays.hit / occluded ray by ray (the reference of the batch queries)."""
    for i in range(ray.shape[1]):
        t[i], prim[i], b[0, i], b[1, i] = hit(R, ray[0, i], ray[1, i], ray[2, i], ray[3, i],
                                              ray[4, i], ray[5, i], ray[6, i], ray[7, i])
        blocked[i] = occluded(R, ray[0, i], ray[1, i], ray[2, i], ray[3, i], ray[4, i],
                              ray[5, i], ray[6, i], ray[7, i])


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("kind", ["spheres", "triangles", "mixed"])
def test_structure_batches_equal_the_per_ray_queries(kind, dtype):
    """closest_batch / occluded_batch through the wide BVH, a binary tree, the grid and
    brute force with the algebraic form return, ray for ray, what impl.rays.hit /
    occluded return (primitive, t, barycentrics, any-hit), and the structures return
    brute force's hits: random rays with hits, misses and rays cut short by their
    tmin / tmax."""
    rng = np.random.default_rng(SEED + 29)
    ns, nt = {"spheres": (300, 0), "triangles": (0, 300), "mixed": (150, 150)}[kind]
    c, r, v, shape = random_scene(rng, ns, nt)
    if kind == "spheres":
        v, shape = v[:0], shape[:ns]
    o, d = random_rays(rng, 3000)
    n = len(o)
    ray = _batch(o, d)
    ray[6] = rng.choice([0.0, 1e-6, 0.3, 1.0], n)
    ray[7] = rng.choice([np.inf, np.inf, 2.0, 0.5, 1e-3], n)
    R0 = config(c, r, v, shape, "none", dtype)
    t0, p0, b0, h0 = np.empty(n), np.empty(n, np.int64), np.empty((2, n)), np.empty(n, np.bool_)
    _per_ray(R0, ray, t0, p0, b0, h0)
    unbounded = ray.copy()
    unbounded[6], unbounded[7] = 0.0, np.inf
    tu, pu, bu, hu = np.empty(n), np.empty(n, np.int64), np.empty((2, n)), np.empty(n, np.bool_)
    _per_ray(R0, unbounded, tu, pu, bu, hu)
    assert 0.1 < (p0 >= 0).mean() < 0.9, "hits and misses"
    assert ((pu >= 0) & (p0 < 0)).sum() > n // 20, "hits cut off by tmin / tmax"
    assert ((pu >= 0) & (p0 >= 0) & (pu != p0)).sum() > n // 200, "nearer hits skipped by tmin"
    for name, form in (("bvh-wide", 2), ("bvh-sah", 2), ("grid", 2), ("none", 0)):
        R = config(c, r, v, shape, name, dtype, form=form)
        t, prim, b = np.empty(n), np.empty(n, np.int64), np.empty((2, n))
        q, qt, qp = np.empty((8, n), dtype), np.empty((3, n), dtype), np.empty(n, np.int32)
        tracer.closest_batch(R, ray, n, t, prim, b, q, qt, qp)
        blocked = np.empty(n, np.bool_)
        tracer.occluded_batch(R, ray, n, blocked, q)
        te, pe, be, he = np.empty(n), np.empty(n, np.int64), np.empty((2, n)), np.empty(n, np.bool_)
        _per_ray(R, ray, te, pe, be, he)
        np.testing.assert_array_equal(prim, pe, err_msg=name)
        np.testing.assert_array_equal(t, te, err_msg=name)
        np.testing.assert_array_equal(b, be, err_msg=name)
        np.testing.assert_array_equal(blocked, he, err_msg=name)
        if form == 2:                                    # a structure: brute force's answers
            np.testing.assert_array_equal(prim, p0, err_msg=name)
            np.testing.assert_array_equal(t, t0, err_msg=name)
            np.testing.assert_array_equal(b, b0, err_msg=name)
            np.testing.assert_array_equal(blocked, h0, err_msg=name)


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_wide_bvh_leaf_triangles_are_tested_in_vector_registers():
    """The wide BVH's batch loop tests a leaf's four triangles with packed arithmetic
    (float64: 256-bit ymm divides, one per group) and its four child boxes likewise
    (packed float64 compares in ymm).  Compiled afresh: numba shows no machine code for
    kernels loaded from its cache."""
    from impl.accel.wide import wide_closest_rays
    rng = np.random.default_rng(SEED)
    c, r, v, shape = random_scene(rng, 0, 60)
    R = config(c, r, v, shape, "bvh-wide", np.float64)
    o, d = random_rays(rng, 64)
    n = len(o)
    kernel = njit(error_model="numpy")(wide_closest_rays.py_func)
    cols = [np.ascontiguousarray(x) for x in (*o.T, *d.T)]
    kernel(R, *cols, np.zeros(n), np.full(n, np.inf), np.empty(n), np.empty(n, np.int64),
           np.empty(n), np.empty(n))
    asm = "\n".join(kernel.inspect_asm().values())
    assert re.search(r"vdivpd\s+%ymm", asm), "triangle lanes"
    assert re.search(r"vcmp\w*pd\s+%ymm", asm), "box and triangle lane compares"
