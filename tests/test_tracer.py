"""The tracer core (impl.tracer): the vectorised brute-force batch queries return, ray for
ray, what the scalar scene queries return (primitive, t, barycentrics, any-hit answer)
on the random rays and scenes of test_accel, in float64 and float32; their inner loops
compile to SIMD code; the per-scene memo of flattened arrays and ray configurations is
reused and rebuilt when the scene changes; renders report their setup and trace times."""

import re
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from gibench import registry
from core.loader import load_scene
from core.meshes import cube
from impl import raycast, tracer
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
    cull = tracer.new_cull(R, n)
    tracer.closest_batch(R, ray, n, t, prim, b, q, qt, qp, cull)
    blocked = np.empty(n, np.bool_)
    ray_sh = ray.copy()
    ray_sh[7] = 1.5                                      # finite shadow segments too
    tracer.occluded_batch(R, ray_sh, n, blocked, q, cull)
    F = dtype
    for i in range(n):
        args = [F(x) for x in ray[:8, i]]
        et, ep, eb1, eb2 = closest_hit_form(2, *args, R.sph_center, R.sph_radius, R.tri_v)
        assert prim[i] == ep, f"ray {i}"
        assert t[i] == float(et) and b[0, i] == float(eb1) and b[1, i] == float(eb2), f"ray {i}"
        sh = [F(x) for x in ray_sh[:8, i]]
        assert blocked[i] == any_hit_form(2, *sh, R.sph_center, R.sph_radius, R.tri_v), f"ray {i}"
    assert (prim >= 0).sum() > n // 8 and blocked.sum() > n // 16  # the rays do hit


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_one_origin_loops_equal_the_scalar_queries_bit_for_bit(dtype):
    """Rays from one origin (a camera's): the loops that compute a primitive's origin terms
    once return what the scalar test returns for each ray, t and barycentrics bit for bit,
    the same tie rule; and what the general loops return."""
    rng = np.random.default_rng(SEED)
    c, r, v, shape = random_scene(rng, 40, 60)
    R = config(c, r, v, shape, "none", dtype)
    _, d = random_rays(rng, 1500)
    d = d.astype(dtype)
    o = np.broadcast_to(np.array([0.1, -0.2, 0.3], dtype), d.shape)
    n = len(d)
    cols = [np.ascontiguousarray(x) for x in (*o.T, *d.T)]
    lo, hi = np.full(n, 1e-6, dtype), np.full(n, np.inf, dtype)
    sph, tri = np.arange(len(r)), np.arange(len(v))

    def outputs():
        return np.empty(n, dtype), np.empty(n, np.int32), np.empty(n, dtype), np.empty(n, dtype)
    one, every = outputs(), outputs()
    tracer._closest_loops_from(R.sph_center, R.sph_radius, R.tri_v, sph, tri, o[0, 0], o[0, 1], o[0, 2],
                               *cols[3:], lo, hi, *one)
    tracer._closest_loops(R.sph_center, R.sph_radius, R.tri_v, sph, tri, *cols, lo, hi, *every)
    for a, b in zip(one, every):
        assert np.array_equal(a, b)
    bt, bp, b1, b2 = one
    for i in range(n):
        et, ep, eb1, eb2 = closest_hit_form(2, *o[i], *d[i], lo[i], hi[i], R.sph_center, R.sph_radius,
                                            R.tri_v)
        assert bp[i] == ep, f"ray {i}"
        if ep >= 0:
            assert bt[i] == et and b1[i] == eb1 and b2[i] == eb2, f"ray {i}"
    assert (bp >= 0).sum() > n // 8                      # the rays do hit


def _avx2() -> bool:
    return _cpu_flag("avx2")


def _cpu_flag(flag: str) -> bool:
    try:
        return f" {flag}" in Path("/proc/cpuinfo").read_text()
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
    n = len(o)
    cols = [np.ascontiguousarray(x, np.float32) for x in (*o.T, *d.T)]
    lo, hi = np.zeros(n, np.float32), np.full(n, np.inf, np.float32)
    sph, tri = np.arange(len(r)), np.arange(len(v))
    closest = njit(error_model="numpy")(tracer._closest_loops.py_func)
    occluded = njit(error_model="numpy")(tracer._occluded_loops.py_func)
    from_origin = njit(error_model="numpy")(tracer._closest_loops_from.py_func)
    closest(R.sph_center, R.sph_radius, R.tri_v, sph, tri, *cols, lo, hi, np.empty(n, np.float32),
            np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32))
    occluded(R.sph_center, R.sph_radius, R.tri_v, sph, tri, *cols, lo, hi, np.empty(n, np.bool_))
    from_origin(R.sph_center, R.sph_radius, R.tri_v, sph, tri, np.float32(0), np.float32(0),
                np.float32(0), *cols[3:], lo, hi, np.empty(n, np.float32), np.empty(n, np.int32),
                np.empty(n, np.float32), np.empty(n, np.float32))
    for name, kernel in (("closest", closest), ("occluded", occluded), ("one origin", from_origin)):
        asm = "\n".join(kernel.inspect_asm().values())
        assert re.search(r"vsqrtps\s+%[yz]mm", asm) and re.search(r"vcmp\w*ps\s+%[yz]mm", asm), name


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_eye_rays_and_welford_loops_vectorise():
    """The pinhole eye rays of a batch (divisions and square roots) and the Welford
    update (divisions) compile to packed float64 arithmetic in 256-bit or wider registers."""
    from impl.camera import pinhole_rays
    n = 64
    f = [np.empty(n) for _ in range(12)]
    eye = njit(error_model="numpy")(pinhole_rays.py_func)
    eye(np.ones(21), np.ones(1), *f[:10])
    welford = njit(error_model="numpy")(tracer._welford.py_func)
    welford(2.0, *f[:9])
    from impl.sampling import jittered_film
    jitter = njit(jittered_film.py_func)
    jitter(16, 4, 5, 1, np.arange(n), *f[:4])
    asm = "\n".join(jitter.inspect_asm().values())
    assert re.search(r"vdivpd\s+%[yz]mm", asm), "jittered film positions"
    asm = "\n".join(eye.inspect_asm().values())
    assert re.search(r"vsqrtpd\s+%[yz]mm", asm) and re.search(r"vdivpd\s+%[yz]mm", asm)
    asm = "\n".join(welford.inspect_asm().values())
    assert re.search(r"vdivpd\s+%[yz]mm", asm)


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_area_light_lanes_vectorise():
    """An area emitter's light sample over a batch of points (distances, directions, the
    shadow rays' offset origins and directions) compiles to packed float64 square roots
    and divisions, in both intersection precisions."""
    from impl.lighting import _area_lanes
    n = 64
    lanes = njit(error_model="numpy")(_area_lanes.py_func)
    f = [np.random.default_rng(SEED).uniform(size=n) for _ in range(26)]
    for g in (np.ones(1), np.ones(1, np.float32)):
        lanes(False, 0.1, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0, False, 3, 1e-4, 1e-4, g, *f, np.zeros(n, np.int64))
    for asm in lanes.inspect_asm().values():
        assert re.search(r"vsqrtpd\s+%[yz]mm", asm) and re.search(r"vdivpd\s+[^\n]*%[yz]mm", asm)


def test_pinhole_batch_rays_equal_eye_ray_bit_for_bit():
    """pinhole_rays computes eye_ray's arithmetic: the same bits, float64 and rounded to
    float32, on a rotated, off-centre camera."""
    from impl.camera import camera_params, eye_ray, pinhole_rays
    sc = load_scene(SUITES / "cornell/cornell_box.xml")
    cam = camera_params(sc.camera)
    cam[:9] = np.linalg.qr(np.random.default_rng(SEED).normal(size=(3, 3)))[0].T.ravel()
    rng = np.random.default_rng(SEED)
    fx, fy = rng.uniform(0, cam[14], 500), rng.uniform(0, cam[15], 500)
    for g in (np.ones(1), np.ones(1, np.float32)):
        out = [np.empty(500) for _ in range(8)]
        pinhole_rays(cam, g, fx, fy, *out)
        for i in range(500):
            want = list(eye_ray(cam, fx[i], fy[i])[:8])
            want[:6] = [float(g.dtype.type(x)) for x in want[:6]]
            assert [o[i] for o in out] == want, i


def test_jittered_film_equals_pixel_sample_bit_for_bit():
    from impl.sampling import PIXEL_JITTER, jittered_film, pixel_sample
    rng = np.random.default_rng(SEED)
    pixel = rng.integers(0, 1 << 20, 300)
    x, y = (pixel % 640).astype(float), (pixel // 640).astype(float)
    for spp, s in ((1, 0), (16, 0), (16, 7), (64, 63), (9, 4), (36, 35)):   # k a power of two or not
        k = int(round(np.sqrt(spp)))
        fx, fy = np.empty(300), np.empty(300)
        jittered_film(spp, k, s, 9, pixel, x, y, fx, fy)
        for i in range(300):
            ox, oy = pixel_sample(spp, k, s, 9, pixel[i], PIXEL_JITTER, int(x[i]), int(y[i]))
            assert (fx[i], fy[i]) == (x[i] + ox, y[i] + oy), (spp, s, i)


def test_sobol_film_equals_pixel_sample_bit_for_bit():
    from impl.sampling import PIXEL_SOBOL, pixel_sample, sobol_film, sobol_film_hashes
    rng = np.random.default_rng(SEED)
    pixel = rng.integers(0, 1 << 20, 300)
    x, y = (pixel % 640).astype(float), (pixel // 640).astype(float)
    h, h2 = np.empty(300, np.uint64), np.empty(300, np.uint64)
    sobol_film_hashes(9, x, y, h, h2)
    for spp, s in ((4, 0), (16, 7), (64, 63), (256, 200)):
        fx, fy = np.empty(300), np.empty(300)
        sobol_film(s, h, h2, x, y, fx, fy)
        for i in range(300):
            ox, oy = pixel_sample(spp, 0, s, 9, pixel[i], PIXEL_SOBOL, int(x[i]), int(y[i]))
            assert (fx[i], fy[i]) == (x[i] + ox, y[i] + oy), (spp, s, i)


def test_light_uv_sobol_lanes_equal_the_scalar_numbers_bit_for_bit():
    from impl.lighting import light_uv_sobol, light_uv_sobol_lanes
    rng = np.random.default_rng(SEED)
    pixel, sample = rng.integers(0, 1 << 20, 300), rng.integers(0, 64, 300)
    for light, k, ls in ((0, 0, 1), (2, 3, 4), (5, 15, 16)):
        u, v = np.empty(300), np.empty(300)
        light_uv_sobol_lanes(7, pixel, sample, light, k, ls, u, v)
        for i in range(300):
            assert (u[i], v[i]) == light_uv_sobol(7, pixel[i], sample[i], light, k, ls), (light, i)


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_sobol_film_loop_vectorises():
    """The Sobol film positions (the pixels' hashes precomputed; the index shuffle and
    value scrambles in 32-bit lanes, byte-table lookups) compile to packed 32-bit
    multiplies."""
    from impl.sampling import sobol_film
    n = 64
    film = njit(sobol_film.py_func)
    h = np.arange(n, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    film(3, h, h + np.uint64(1), np.arange(n, dtype=float), np.ones(n), np.empty(n), np.empty(n))
    asm = "\n".join(film.inspect_asm().values())
    assert re.search(r"vpmulld\s+%[xyz]mm", asm), "Sobol film positions"


@pytest.mark.skipif(not _cpu_flag("avx512dq"), reason="the host has no packed 64-bit multiply")
def test_sobol_light_numbers_loop_vectorises():
    """The light-sample numbers (64-bit pixel and pair hashes per point, then the 32-bit
    scrambles) compile to packed 64-bit multiplies in 256-bit or wider registers."""
    n = 64
    from impl.lighting import light_uv_sobol_lanes
    lanes = njit(light_uv_sobol_lanes.py_func)
    lanes(7, np.arange(n), np.ones(n, np.int64), 1, 0, 1, np.empty(n), np.empty(n))
    asm = "\n".join(lanes.inspect_asm().values())
    assert re.search(r"vpmullq\s+%[yz]mm", asm), "Sobol light samples"


@pytest.mark.skipif(not _avx2(), reason="the host has no AVX2")
def test_light_sample_lanes_and_frustum_loops_vectorise():
    """The per-point delta-light loop (a light sample, its contribution and its shadow
    ray's offset origin for every point: 15 input and 11 output arrays) and the frustum's
    projective coordinates compile to packed float64 divisions and square roots.  The
    light loop needs more run-time overlap checks between its arrays than LLVM allows by
    default (impl.kernel.LLVM_OPTIONS); without them it stays scalar."""
    from impl import lighting
    n = 64
    a = [np.ones(n) for _ in range(26)]
    lanes = njit(error_model="numpy")(lighting._delta_lanes.py_func)
    lanes(False, True, *([0.5] * 15), 0.9, 0.95, 0.0, 0.0, 1.0, False, 1.0, 1.0, 1.0, 3, 1e-4,
          1e-9, np.ones(1), np.ones(n, np.bool_), *a, np.empty(n, np.int64))
    uv = njit(error_model="numpy")(tracer._frustum_uv.py_func)
    uv(*a[:3], *([0.1] * 12), 0.01, a[3], a[4])
    for name, kernel in (("light lanes", lanes), ("frustum", uv)):
        asm = "\n".join(kernel.inspect_asm().values())
        assert re.search(r"vdivpd\s+%[yz]mm", asm), name
    assert re.search(r"vsqrtpd\s+%[yz]mm", "\n".join(lanes.inspect_asm().values()))


def test_the_integer_float_range_is_numpys_min_and_max_and_flags_a_nan():
    """The bound's min/max reductions run on the floats' bits as integers
    (impl.tracer._float_range): over values of both signs, zeros of both signs,
    subnormals and infinities they return numpy's min and max, the same floats; a NaN of
    either sign comes back as the min or the max, so ``lo <= hi`` fails."""
    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 64, 577):
        x = rng.standard_normal(n) * 10.0 ** rng.integers(-310, 300, n)
        x[rng.integers(0, n)] = rng.choice([0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324])
        lo, hi = tracer._float_range(x)
        assert (lo, hi) == (x.min(), x.max()), n
    assert tracer._float_range(np.array([-0.0, 0.0])) == (-0.0, 0.0)
    assert np.signbit(tracer._float_range(np.array([0.0, -0.0]))[0])
    bits = np.array([0x7FF8000000000000, 0xFFF8000000000000, 0x7FF0000000000001], np.uint64)
    for nan in bits.view(np.float64):                    # quiet NaNs of both signs, a signalling one
        x = np.array([1.0, -2.0, nan, 3.0])
        lo, hi = tracer._float_range(x)
        assert not lo <= hi


def test_the_segment_spreads_are_the_ends_and_origins_distances():
    """impl.tracer._spreads computes, lane by lane, the squared distances of a chunk's
    segment ends (impl.tracer._end's o + tmax·d) and origins from a point, bit for bit
    those of the scalar arithmetic, in both precisions of the rays; and its loop
    vectorises."""
    rng = np.random.default_rng(6)
    n = 100
    for dtype in (np.float64, np.float32):
        q = np.empty((8, n), dtype)
        q[:3] = rng.uniform(-3, 3, (3, n))
        d = rng.standard_normal((3, n))
        q[3:6] = d / np.linalg.norm(d, axis=0)
        q[6], q[7] = 0.0, rng.uniform(0.1, 9.0, n)
        ex, ey, ez = tracer._end(q, 0)
        s2, o2 = np.empty(n), np.empty(n)
        tracer._spreads(*q[[0, 1, 2, 3, 4, 5, 7]], ex, ey, ez, s2, o2)
        for i in range(n):
            x, y, z = tracer._end(q, i)
            x, y, z = x - ex, y - ey, z - ez
            assert s2[i] == x * x + y * y + z * z
            x, y, z = float(q[0, i]) - ex, float(q[1, i]) - ey, float(q[2, i]) - ez
            assert o2[i] == x * x + y * y + z * z
    spreads = njit(error_model="numpy")(tracer._spreads.py_func)   # compiled here: asm kept
    a = [np.ones(n) for _ in range(9)]
    spreads(*a[:7], 0.5, 0.5, 0.5, a[7], a[8])
    assert re.search(r"vmulpd\s+%[yz]mm", "\n".join(spreads.inspect_asm().values()))
    float_range = njit(error_model="numpy")(tracer._float_range.py_func)
    float_range(a[0])
    asm = "\n".join(float_range.inspect_asm().values())
    assert re.search(r"(vpmaxsq|vpminsq|vpcmpgtq)\s.*%[yz]mm", asm)   # AVX-512 or AVX2


def test_the_shaft_box_extent_is_that_of_the_segment_ends_or_nan():
    """The box of a chunk's finite segments (impl.tracer._shaft_box) takes each axis's
    extent over both ends of every segment (impl.tracer._axis_extent): numpy's min and
    max of o + t·d at tmin and tmax (in the rays' precision), the same floats;
    NaN when an end is not finite (an infinite tmax, either sign of direction, or a NaN
    ray), so the chunk keeps every primitive."""
    rng = np.random.default_rng(7)
    n = 90
    a, b = np.empty(n), np.empty(n)
    for dtype in (np.float64, np.float32):
        o = rng.uniform(-3, 3, n).astype(dtype)
        d = rng.uniform(-1, 1, n).astype(dtype)
        t0 = rng.uniform(0, 1e-3, n).astype(dtype)
        t1 = rng.uniform(0.1, 9.0, n).astype(dtype)
        ends = np.concatenate([o + t0 * d, o + t1 * d]).astype(float)   # numba's float() of a
        # float32 stays float32, as in impl.tracer._end
        assert tracer._axis_extent(o, d, t0, t1, a, b) == (ends.min(), ends.max())
        for bad in ((t1, np.inf, 1.0), (t1, np.inf, -1.0), (d, np.nan, 0.0)):
            arr, value, dv = bad
            o2, d2, t2 = o.copy(), d.copy(), t1.copy()
            (t2 if arr is t1 else d2)[17] = value
            if dv:
                d2[17] = dv
            lo, hi = tracer._axis_extent(o2, d2, t0, t2, a, b)
            assert np.isnan(lo) and np.isnan(hi), bad


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("batch", ["shared_origin", "to_a_point", "parallel"])
@pytest.mark.parametrize("structure", ["none", "bvh-wide"])
def test_culled_batches_equal_the_per_ray_queries(structure, batch, dtype):
    """Coherent batches — a narrow fan of rays from one origin (a tile's eye rays), rays
    from scattered points to one point (a light sample's shadow rays), parallel rays
    with an unbounded range (a directional light's) — get, ray for ray, the scalar
    queries' answers from the batch queries that test only the primitives their bounds
    keep: by brute force the batch's bound (:func:`impl.tracer._cull`), through the wide
    BVH each chunk's frustum, its primitives gathered from the tree's leaves
    (:func:`impl.tracer._wide_cull`); and those bounds do cull."""
    rng = np.random.default_rng(SEED + 3)
    c, r, v, shape = random_scene(rng, 40, 60)
    R = config(c, r, v, shape, structure, dtype)
    n = 256
    if batch == "shared_origin":
        o = np.tile([0.1, 0.2, 3.0], (n, 1))
        d = np.stack([rng.uniform(-0.12, 0.08, n), rng.uniform(-0.1, 0.1, n), -np.ones(n)], 1)
        tmin, tmax = 1e-3, 1e4
    elif batch == "to_a_point":
        p = np.stack([rng.uniform(-0.6, -0.2, n), np.full(n, -0.999), rng.uniform(0.1, 0.5, n)], 1)
        light = np.array([0.3, 0.9, -0.1])
        d = light - p
        tmax = np.linalg.norm(d, axis=1) * (1 - 1e-7)
        o, tmin = p, 1e-6
    else:
        o = np.stack([rng.uniform(-1.5, 1.5, n), np.full(n, 1.5), rng.uniform(-1.5, 1.5, n)], 1)
        d = np.tile([0.2, -1.0, 0.1], (n, 1))
        tmin, tmax = 1e-6, np.inf
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    o, d = o.astype(dtype).astype(np.float64), d.astype(dtype).astype(np.float64)
    ray = _batch(o, d, tmin, tmax)
    t, prim, b, blocked = got = _batch_answers(R, ray, dtype)
    _assert_same(got, _per_ray_answers(R, ray))
    q = np.empty((8, n), dtype)
    assert (prim >= 0).sum() > n // 8 and blocked.sum() > n // 8, "the rays do hit"
    tracer._in_precision(ray, n, q)
    uv, bound = np.empty((2, n)), np.empty(tracer._BOUND_WORDS)
    total = len(r) + len(v)
    if structure == "none":                             # the whole batch's bound
        spans = [(0, n)]
    else:                                               # each chunk's frustum in the tree
        spans = [(c0, min(n, c0 + tracer.CHUNK)) for c0 in range(0, n, tracer.CHUNK)]
    culled = 0
    for c0, c1 in spans:
        cand = np.full(2 + total, -9, np.int64)
        if structure == "none":
            cull(R, q, c0, c1, cand, uv, bound)
        else:
            wide_cull(R, q, c0, c1, cand, uv, bound, np.empty(2 * tracer.CHUNK_CAP, np.int64))
        if batch == "parallel":                         # unbounded segments: no bound
            assert (cand[0] == tracer._PER_RAY if structure != "none"
                    else cand[0] + cand[1] == total), cand[:2]
            continue
        if cand[0] == tracer._PER_RAY:
            continue
        culled += 1
        ns, nt = cand[0], cand[1]
        kept = ns + nt
        assert 0 < kept < total // 2, kept
        assert (np.diff(cand[2:2 + ns]) > 0).all() and (np.diff(cand[2 + ns:2 + kept]) > 0).all()
        hit_prims = set(prim[c0:c1][prim[c0:c1] >= 0].tolist())
        kept_ids = (set(cand[2:2 + ns].tolist())
                    | {len(r) + j for j in cand[2 + ns:2 + kept].tolist()})
        assert hit_prims <= kept_ids
    if batch != "parallel":
        assert culled >= len(spans) // 2, (culled, len(spans))


def _box_triangles(lo, hi):
    """The 12 triangles (T, 3, 3) of Mitsuba's cube (:func:`core.meshes.cube`) mapped onto
    the axis-aligned box [lo, hi]: two per face, faces in the order −x, +x, −y, +y, −z, +z."""
    v, f, _ = cube()
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return (lo + 0.5 * (v + 1.0) * (hi - lo))[f]


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("structure", ["none", "bvh-wide"])
def test_shadow_rays_skip_the_walls_whose_plane_they_never_cross(structure, dtype):
    """Shadow rays from a patch of a closed room's floor (a tile's shading points) to a
    point light inside it (the Cornell box with a point light): the candidates keep the
    floor they start on and the block between floor and light when it shadows them, and
    never the ceiling, whose plane no segment crosses (:func:`impl.tracer._plane_misses_box`:
    the frustum's planes alone keep it), nor the walls on the patch's far side; the
    answers are still those of the per-ray queries, ray for ray."""
    room = _box_triangles([-1, -1, -1], [1, 1, 1])            # faces −x, +x, −y (floor), +y, −z, +z
    block = _box_triangles([-0.3, -1, -0.3], [0.3, 0.2, 0.3])
    v = np.concatenate([room, block])
    R = config(np.empty((0, 3)), np.empty(0), v, np.zeros(len(v), np.int64), structure, dtype)
    rng = np.random.default_rng(SEED + 5)
    light = np.array([0.1, 0.8, -0.05])
    n = tracer.CHUNK                                          # one chunk, one bound
    q = np.empty((8, n), dtype)
    uv, bound = np.empty((2, n)), np.empty(tracer._BOUND_WORDS)
    ceiling, shadowed = {6, 7}, 0
    for cx in (-0.7, 0.0, 0.7):
        for cz in (-0.7, 0.0, 0.7):
            p = np.stack([cx + rng.uniform(-0.15, 0.15, n), np.full(n, -1.0),
                          cz + rng.uniform(-0.15, 0.15, n)], 1)
            d = light - p
            tmax = np.linalg.norm(d, axis=1) * (1 - 1e-7)
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
            o, d = p.astype(dtype).astype(np.float64), d.astype(dtype).astype(np.float64)
            ray = _batch(o, d, 1e-6, tmax)
            got = _batch_answers(R, ray, dtype)
            _assert_same(got, _per_ray_answers(R, ray), err_msg=f"patch at {cx}, {cz}")
            tracer._in_precision(ray, n, q)
            cand = np.full(2 + len(v), -9, np.int64)
            if structure == "none":
                cull(R, q, 0, n, cand, uv, bound)
            else:
                wide_cull(R, q, 0, n, cand, uv, bound, np.empty(2 * tracer.CHUNK_CAP, np.int64))
            assert cand[0] == 0, cand[:2]                     # culled, no spheres
            kept = set(cand[2:2 + cand[1]].tolist())
            far = ({2, 3} if cx < 0 else {0, 1} if cx > 0 else set()) | (
                {10, 11} if cz < 0 else {8, 9} if cz > 0 else set())
            assert not kept & (ceiling | far), (cx, cz, sorted(kept & (ceiling | far)))
            assert kept & {4, 5}, (cx, cz)                    # the floor under the points
            if got[3].any():
                shadowed += 1
                assert kept & set(range(12, 24)), "the block that shadows them"
    assert shadowed >= 3, "some patches lie in the block's shadow"


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_a_plane_culls_only_boxes_beyond_its_padding(dtype):
    """A triangle in the plane y = 0 culls a box of segments above it only when the box
    lies further than the padding (``_CULL_PAD``·(1 + the largest coordinate)) from the
    plane; a box touching, crossing or unbounded, and a degenerate triangle, cull
    nothing."""
    v = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                  [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]], dtype)
    pad = tracer._CULL_PAD * (1.0 + 2.0)                        # the largest coordinate: 2
    bound = np.zeros(tracer._BOUND_WORDS)

    def misses(j, lo, hi):
        bound[tracer._SEG:tracer._SEG + 3], bound[tracer._SEG + 3:] = lo, hi
        return plane_misses_box(v, j, bound)

    assert misses(0, [0.5, 1.01 * pad, 0.5], [2.0, 1.0, 2.0])
    assert misses(0, [0.5, -1.0, 0.5], [2.0, -1.01 * pad, 2.0])       # below it too
    assert not misses(0, [0.5, 0.99 * pad, 0.5], [2.0, 1.0, 2.0])
    assert not misses(0, [0.5, 0.0, 0.5], [2.0, 1.0, 2.0])
    assert not misses(0, [0.5, -0.5, 0.5], [2.0, 1.0, 2.0])
    assert not misses(0, [-np.inf] * 3, [np.inf] * 3)
    assert not misses(1, [0.5, 0.5, 0.5], [2.0, 1.0, 2.0])            # no plane at all


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_the_hit_test_meets_no_triangle_whose_plane_a_culled_segment_stays_beyond(dtype):
    """The plane culling's premise, on its hardest cases: segments that end just beyond
    the padding from a triangle's plane (1.001–1.5 paddings, above the triangle, from
    either side, slivers and scales from 0.01 to 100 included) are culled by
    :func:`impl.tracer._plane_misses_box`, and the batch loops' hit test (its rounding
    in the intersection precision) reports none of them as a hit."""
    rng = np.random.default_rng(SEED + 7)
    tested = 0
    bound = np.empty(tracer._BOUND_WORDS)
    for _ in range(3000):
        s = 10.0 ** rng.uniform(-2, 2)
        v = np.stack([rng.uniform(-1, 1, 3) * s, rng.normal(size=3) * s * 10 ** rng.uniform(-1, 0),
                      rng.normal(size=3) * s])
        v[1:] += v[0]
        V = v.astype(dtype)[None]
        v0, e1, e2 = (V[0].astype(float)[k] for k in range(3))
        e1, e2 = e1 - v0, e2 - v0
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n)
        pad = tracer._CULL_PAD * (1.0 + 3.0 * np.abs(V).max())
        side = rng.choice([-1.0, 1.0])
        end = (v0 + rng.uniform(0, 0.5) * e1 + rng.uniform(0, 0.5) * e2
               + side * pad * rng.uniform(1.001, 1.5) * n)
        start = end + side * n * s * rng.uniform(0.01, 2.0) + rng.normal(size=3) * s
        o = start.astype(dtype)
        w = end - o.astype(float)
        tmax = np.linalg.norm(w) * (1 - 1e-7)
        d = (w / np.linalg.norm(w)).astype(dtype)
        ends = np.stack([o.astype(float), o.astype(float) + tmax * d.astype(float)])
        bound[tracer._SEG:tracer._SEG + 3], bound[tracer._SEG + 3:] = ends.min(0), ends.max(0)
        if not plane_misses_box(V, 0, bound):
            continue                                        # the box reaches into the padding
        tested += 1
        F = dtype
        *_, hit = triangle_t(o[0], o[1], o[2], d[0], d[1], d[2], F(v0[0]), F(v0[1]), F(v0[2]),
                             F(e1[0]), F(e1[1]), F(e1[2]), F(e2[0]), F(e2[1]), F(e2[2]), F(1e-6),
                             F(tmax))
        assert not hit, (v.tolist(), o.tolist(), d.tolist(), tmax)
    assert tested > 500, tested


#: The inlined culling helpers, compiled to be called from the tests.
cull = njit(tracer._cull.py_func)
wide_cull = njit(_nrt=True)(tracer._wide_cull.py_func)
plane_misses_box = njit(tracer._plane_misses_box.py_func)
triangle_t = njit(error_model="numpy")(tracer._triangle_t.py_func)


def test_scene_memo_reuses_and_rebuilds():
    sc = load_scene(SUITES / "spheres/lit_sphere.xml")
    A = flatten_cached(sc)
    assert flatten_cached(sc) is A
    sc.lights = sc.lights[:0]                           # a changed scene is flattened again
    B = flatten_cached(sc)
    assert B is not A and len(B.light_kind) == 0
    other = replace(sc)
    assert flatten_cached(other) is not B


@pytest.mark.parametrize("name", ["raycast", "whitted", "path", "distributed"])
def test_renders_report_setup_and_trace_time(name):
    """Every ray tracer's render record splits its wall time into the fixed cost
    (``setup_s``), the kernel (``trace_s``) and what follows it (``finish_s``)."""
    sc = load_scene(SUITES / "spheres/lit_sphere.xml")
    algo = registry.get(name)
    t0 = time.perf_counter()
    res = algo.render(sc, algo.parse_params({"spp": 1}))
    wall = time.perf_counter() - t0
    assert set(res.timings) >= {"setup_s", "trace_s", "finish_s"}
    assert all(v >= 0.0 for v in res.timings.values())
    assert sum(res.timings.values()) <= wall


@pytest.mark.parametrize("name, scene, params", [
    ("raycast", "cornell/cornell_point.xml", {"spp": 4, "light_samples": 1}),
    ("raycast", "spheres/spot_directional.xml", {"spp": 4, "sampler": "sobol"}),
    ("whitted", "spheres/mirror_sphere.xml", {"spp": 4}),
    ("path", "cornell/cornell_box.xml", {"spp": 4, "max_depth": 4}),
], ids=["raycast-point", "raycast-spot-sobol", "whitted", "path"])
def test_images_do_not_depend_on_the_tile_size(monkeypatch, name, scene, params):
    """The tile (the batch) is a schedule, not part of the estimator: random numbers are
    keyed by pixel and sample, culling is conservative, counters are per pixel.  Tiles of
    7 and 13 pixels (partial tiles at every edge of the 160×120 film) give the image,
    variance and counters of the default tile bit for bit."""
    sc = load_scene(SUITES / scene)
    algo = registry.get(name)
    p = algo.parse_params(params)
    want = algo.render(sc, p, seed=3)
    for side in (7, 13):
        monkeypatch.setattr(tracer, "BATCH_TILE", side)
        got = algo.render(sc, p, seed=3)
        np.testing.assert_array_equal(got.image, want.image, err_msg=f"tile {side}")
        np.testing.assert_array_equal(got.variance, want.variance, err_msg=f"tile {side}")
        assert got.counters == want.counters, side


@njit(error_model="numpy")
def _per_ray(R, ray, t, prim, b, blocked):
    """impl.rays.hit / occluded ray by ray (the reference of the batch queries)."""
    for i in range(ray.shape[1]):
        t[i], prim[i], b[0, i], b[1, i] = hit(R, ray[0, i], ray[1, i], ray[2, i], ray[3, i],
                                              ray[4, i], ray[5, i], ray[6, i], ray[7, i])
        blocked[i] = occluded(R, ray[0, i], ray[1, i], ray[2, i], ray[3, i], ray[4, i],
                              ray[5, i], ray[6, i], ray[7, i])


def _batch_answers(R, ray, dtype):
    """closest_batch / occluded_batch over every ray of ``ray`` (8, n): (t, prim, b, blocked)."""
    n = ray.shape[1]
    t, prim, b = np.empty(n), np.empty(n, np.int64), np.empty((2, n))
    q, qt, qp = np.empty((8, n), dtype), np.empty((3, n), dtype), np.empty(n, np.int32)
    cull = tracer.new_cull(R, n)
    tracer.closest_batch(R, ray, n, t, prim, b, q, qt, qp, cull)
    blocked = np.empty(n, np.bool_)
    tracer.occluded_batch(R, ray, n, blocked, q, cull)
    return t, prim, b, blocked


def _per_ray_answers(R, ray):
    """impl.rays.hit / occluded ray by ray: (t, prim, b, blocked)."""
    n = ray.shape[1]
    out = np.empty(n), np.empty(n, np.int64), np.empty((2, n)), np.empty(n, np.bool_)
    _per_ray(R, ray, *out)
    return out


def _assert_same(got, want, err_msg=""):
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w, err_msg=err_msg)


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
    brute = _per_ray_answers(R0, ray)
    p0 = brute[1]
    unbounded = ray.copy()
    unbounded[6], unbounded[7] = 0.0, np.inf
    pu = _per_ray_answers(R0, unbounded)[1]
    assert 0.1 < (p0 >= 0).mean() < 0.9, "hits and misses"
    assert ((pu >= 0) & (p0 < 0)).sum() > n // 20, "hits cut off by tmin / tmax"
    assert ((pu >= 0) & (p0 >= 0) & (pu != p0)).sum() > n // 200, "nearer hits skipped by tmin"
    for name, form in (("bvh-wide", 2), ("bvh-sah", 2), ("grid", 2), ("none", 0)):
        R = config(c, r, v, shape, name, dtype, form=form)
        got = _batch_answers(R, ray, dtype)
        _assert_same(got, _per_ray_answers(R, ray), name)
        if form == 2:                                    # a structure: brute force's answers
            _assert_same(got, brute, name)


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


@pytest.mark.parametrize("scene, sampler", [("cornell/cornell_box.xml", "jitter"),
                                            ("spheres/spot_directional.xml", "sobol"),
                                            ("spheres/meshes.xml", "jitter")])
def test_tile_frustum_keeps_every_primitive_an_eye_ray_hits(scene, sampler):
    """A pinhole's eye rays are culled once per tile, for all its samples, by the
    frustum through the corners of each pixel block of the tile
    (impl.tracer._tile_candidates): every eye ray of every sample, jittered or Sobol, gets
    the per-ray query's answer over all primitives, and the tiles' lists do cull (on the
    Cornell box most blocks keep few of its 34 triangles; on the spheres the sky blocks
    keep no sphere).  On the meshes (the wide BVH) blocks over the icosphere keep too
    many and are split into runs of rows, each run's list within CHUNK_CAP (on average
    under three quarters of it)."""
    from impl.camera import camera_params
    from impl.sampling import sampler_code
    from impl.tracer import eye_batch, new_batch, new_film

    sc = load_scene(SUITES / scene)
    p = registry.get("raycast").parse_params({"spp": 4, "sampler": sampler})
    A = flatten_cached(sc)
    R = tracer.ray_config_cached(sc, A, p, algorithm="raycast")
    wide = scene.endswith("meshes.xml")
    assert tracer.brute_force(R) != wide
    cam = camera_params(sc.camera)
    W, H = sc.camera.film.width, sc.camera.film.height
    film = new_film(W, H, 1, False, sampler_code(p))
    total = len(A.sph_radius) + len(A.tri_v)
    kept, runs, split = [], [], 0
    for tile in range(film.packet.shape[0]):
        T = new_batch(film, R, tile, 5)
        for s in range(4):
            eye_batch(cam, R, T, s, 4, 5, False, film.sampler)
            got = (T.t.copy(), T.prim.copy(), T.b.copy())
            want = _per_ray_answers(R, T.ray)[:3]
            _assert_same(got, want, err_msg=f"tile {tile} sample {s}")
        nb = tracer.pixel_blocks(T.nx, T.n // T.nx)
        heads = T.cand[:nb, 0]
        kept.extend((T.cand[:nb, 0] + T.cand[:nb, 1])[heads >= 0].tolist())
        assert set(heads[heads < 0].tolist()) <= {tracer._PER_RAY, tracer._SPLIT}
        for g in np.flatnonzero(heads == tracer._SPLIT):
            split += 1
            rows = T.cand[nb + g * tracer._RUNS:nb + (g + 1) * tracer._RUNS]
            rows = rows[rows[:, 0] != tracer._UNKNOWN]
            runs.extend((rows[:, 0] + rows[:, 1])[rows[:, 0] >= 0].tolist())
    kept = np.array(kept)
    assert (kept >= 0).all() and (kept <= min(total, T.cand.shape[1] - 2)).all()
    assert np.median(kept) < total / 2, np.median(kept)
    if wide:
        assert split > 10 and len(runs) >= 3 * split, (split, len(runs))
        assert max(runs) <= tracer.CHUNK_CAP < total and np.mean(runs) < 0.75 * tracer.CHUNK_CAP


@pytest.mark.parametrize("W, H", [(37, 29), (160, 120), (3, 50)])
def test_a_batch_holds_its_tile_block_by_block(W, H):
    """A batch's columns are its tile's pixels, each once, in pixel blocks of
    tracer.BLOCK (impl.tracer.pixel_block: the blocks in row order, cut at the tile's
    edges, each a run of columns holding its pixels in row order), and store() writes
    every pixel of the image exactly once, from the column holding it."""
    from impl.tracer import new_batch, new_film, pixel_block, store

    sc = load_scene(SUITES / "spheres/lit_sphere.xml")
    A = flatten_cached(sc)
    R = tracer.ray_config_cached(sc, A, registry.get("raycast").parse_params({}), algorithm="raycast")
    film = new_film(W, H, 1, False)
    B = tracer.BLOCK
    for tile in range(film.packet.shape[0]):
        T = new_batch(film, R, tile, 0)
        ny = T.n // T.nx
        xy = T.xy.astype(np.int64)
        np.testing.assert_array_equal(T.pixel, xy[1] * W + xy[0])
        c = 0
        for g in range(-(-T.nx // B) * -(-ny // B)):
            c0, bx, by, w, h = pixel_block(T.nx, ny, g)
            assert c0 == c and 0 < w <= B and 0 < h <= B
            yy, xx = np.mgrid[T.y0 + by:T.y0 + by + h, T.x0 + bx:T.x0 + bx + w]
            np.testing.assert_array_equal(xy[:, c0:c0 + w * h], [xx.ravel(), yy.ravel()])
            c += w * h
        assert c == T.n
        T.acc[:3] = T.pixel
        store(T, film, 1)
    np.testing.assert_array_equal(film.mean[..., 0], np.arange(W * H).reshape(H, W))


@pytest.mark.parametrize("params", [{}, {"precision": "float32"}, {"offset": "normal"},
                                    {"offset": "epsilon"}, {"shadows": False},
                                    {"accel": "bvh-wide"}, {"fatt_clamp": True, "c3": 4.0}])
def test_delta_light_lanes_equal_the_scalar_light_samples(params):
    """direct_batch computes a point, spot or directional light at every point of a batch
    in one branch-free loop (impl.lighting._delta_lanes; the spot's cone edge goes back to
    the scalar sample): each point gets, bit for bit, the light and the shadow-ray count
    of the scalar per-point estimator (impl.lighting.direct_light_dims), in every ray
    configuration; points in the spot's transition band and in shadow are among them."""
    sc = load_scene(SUITES / "spheres/spot_directional.xml")
    A = flatten_cached(sc)
    spot = int(np.flatnonzero(A.light_kind == 2)[0])
    lit = dark = band = 0
    for P, i, r, nsh, M, *_ in _lanes_against_scalar(sc, {"spp": 4, "light_samples": 1, **params}):
        lit += r > 0.0
        dark += nsh > 0 and r == 0.0
        lx = A.light_pos[spot] - P[0:3, i]
        cos_t = -(A.light_dir[spot] @ lx) / np.linalg.norm(lx)
        band += A.light_cos_cutoff[spot] < cos_t < A.light_cos_beam[spot]
    assert lit > 100 and band > 10
    assert dark > 10 or not M.shadows


@pytest.mark.parametrize("params", [{}, {"shadows": False}, {"precision": "float32"}])
def test_the_scalar_light_samples_weigh_a_normal_or_bump_map_as_the_batch_does(params):
    """Under normal and bump maps (suites/vocabulary/maps_direct.xml: a point light and a
    rectangle light over mapped diffuse surfaces, two of them two-sided panels seen from
    behind) the scalar per-point estimator that distributed ray tracing calls
    (impl.lighting.direct_light_dims, given the perturbed normal, the unperturbed one and
    the map's code) weights every light sample as direct_batch does: the same light and
    shadow-ray count at every point, bit for bit.  The weights matter: at some points the
    same estimator without them (code MAP_NONE) gives other light."""
    from impl import lighting
    from impl.samplers import DIM_INDEPENDENT

    sc = load_scene(SUITES / "vocabulary/maps_direct.xml")
    A = flatten_cached(sc)
    mapped = weighed = 0
    for P, i, r, nsh, M, pixel, R in _lanes_against_scalar(sc, {"spp": 4, "light_samples": 4, **params}):
        if P[lighting.SP_MAP, i] == lighting.MAP_NONE:
            continue
        mapped += 1
        plain = lighting.direct_light_dims(
            *P[:lighting.SP_N0, i], A, M.ks, M.shininess, M.c1, M.c2, M.c3, M.fclamp, M.shadows,
            M.light_samples, 7, pixel, 2, R, (DIM_INDEPENDENT, 0, 0), (0.0, 0.0, 0.0, lighting.MAP_NONE))
        weighed += plain[0] != r
    assert mapped > 500 and weighed > 50


@njit(cache=True)
def _shade_ray_by_ray(A, R, amb, T):
    for i in range(T.n):
        raycast._shade_ray(A, R, amb, T, i)


@pytest.mark.parametrize("scene", ["spheres/meshes.xml", "cornell/cornell_box.xml",
                                   "vocabulary/maps_direct.xml", "spheres/spot_directional.xml",
                                   "vocabulary/constant_env_room.xml", "vocabulary/envmap.xml",
                                   "spheres/lit_sphere.xml", "spheres/sphere_grid.xml", "spheres only",
                                   "meshes and a sphere"])
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_raycast_plain_hit_lanes_equal_the_ray_by_ray_shading(scene, precision, tmp_path):
    """raycast shades the plain hits (spheres, triangles with or without vertex normals) a
    ray per vector lane (impl.raycast._plain_hits) and the others ray by ray: every eye
    ray's emission and ambient term, whether it is lit, and its shading point are those of
    the ray-by-ray step (impl.raycast._shade_ray) at every ray, bit for bit.  The scenes
    mix plain hits on triangles and spheres (an emitter's among them; spheres alone,
    triangles alone, both; triangles with interpolated normals beside flat ones, alone and
    with a sphere) and escaped rays (into a constant environment or none) with the others
    (an environment map), or have no plain hit (normal and bump maps)."""
    from impl import lighting
    from impl.camera import camera_params
    from impl.tracer import eye_batch, new_batch, new_film

    if scene == "spheres only":         # lit_sphere with its ground a large sphere: no triangle
        text = (SUITES / "spheres/lit_sphere.xml").read_text()
        ground = re.search(r'<shape type="rectangle".*?</shape>', text, flags=re.S)
        (tmp_path / "spheres.xml").write_text(text.replace(ground.group(0), (
            '<shape type="sphere"><point name="center" value="0, -1000, 0"/>'
            '<float name="radius" value="1000"/><bsdf type="diffuse"/></shape>')))
        sc = load_scene(tmp_path / "spheres.xml")
        assert len(sc.shapes) == 2 and all(s.kind == "sphere" for s in sc.shapes)
    elif scene == "meshes and a sphere":  # smooth and flat meshes, a rectangle, a sphere
        text = (SUITES / "spheres/meshes.xml").read_text()
        text = text.replace('value="meshes/', f'value="{SUITES / "spheres/meshes"}/').replace(
            "</scene>", '<shape type="sphere"><point name="center" value="0, 0.5, 1.5"/>'
                        '<float name="radius" value="0.5"/><bsdf type="diffuse"/></shape></scene>')
        (tmp_path / "mixed.xml").write_text(text)
        sc = load_scene(tmp_path / "mixed.xml")
    else:
        sc = load_scene(SUITES / scene)
    p = registry.get("raycast").parse_params({"spp": 4, "precision": precision, "ka": 0.3,
                                              "ambient": 0.5})
    A = flatten_cached(sc)
    R = tracer.ray_config_cached(sc, A, p, algorithm="raycast")
    amb = p["ambient"] * p["ka"]
    cam = camera_params(sc.camera)
    film = new_film(sc.camera.film.width, sc.camera.film.height, 1, False, 0)
    rows = lighting.SP_MAP + 1
    plain = slow = spheres = smooth = sky_seen = 0
    for tile in range(film.packet.shape[0]):
        T = new_batch(film, R, tile, 7)
        n = T.n
        eye_batch(cam, R, T, 1, 4, 7, False, film.sampler)
        flags = np.empty(n, np.bool_)
        raycast._lane_hits(A, R, amb, T, flags, bool(A.tri_has_n.any()))
        lanes = (T.pts[:rows, :n].copy(), T.L[:, :n].copy(), T.active[:n].copy())
        _shade_ray_by_ray(A, R, amb, T)
        fast = ~flags
        lit = fast & T.active[:n]
        assert np.array_equal(lanes[2][fast], T.active[:n][fast]), tile
        assert np.array_equal(lanes[1][:, fast], T.L[:, :n][:, fast]), tile
        for r in list(range(lighting.SP_N0)) + [lighting.SP_MAP]:
            assert np.array_equal(lanes[0][r, lit], T.pts[r, :n][lit]), (tile, r)
        plain += fast.sum()
        slow += flags.sum()
        spheres += (fast & (T.prim[:n] >= 0) & (T.prim[:n] < R.sph_radius.shape[0])).sum()
        sky_seen += (fast & (T.prim[:n] < 0)).sum()
        if len(A.tri_has_n):
            tri = np.maximum(T.prim[:n] - R.sph_radius.shape[0], 0)
            smooth += (fast & (T.prim[:n] >= R.sph_radius.shape[0]) & (A.tri_has_n[tri] != 0)).sum()
    # (plain hits, slow hits, plain hits on spheres, on smooth triangles) over 1000; None: either
    expect = {"spheres/meshes.xml": (True, False, False, True),
              "meshes and a sphere": (True, False, True, True),
              "cornell/cornell_box.xml": (True, False, False, False),
              "vocabulary/maps_direct.xml": (False, True, False, False),
              "spheres/spot_directional.xml": (True, False, True, False),
              "vocabulary/constant_env_room.xml": (True, None, None, False),
              "vocabulary/envmap.xml": (None, True, None, None),
              "spheres/lit_sphere.xml": (True, False, True, False),
              "spheres/sphere_grid.xml": (True, None, True, False),
              "spheres only": (True, False, True, False)}[scene]
    got = (plain > 1000, slow > 1000, spheres > 1000, smooth > 1000)
    assert all(e in (None, g) for e, g in zip(expect, got)), (plain, slow, spheres, smooth)
    if scene == "vocabulary/constant_env_room.xml":     # escaped rays, in the lanes
        assert sky_seen > 1000


def _lanes_against_scalar(sc, params):
    """Shade a third of the tiles of scene ``sc`` with raycast's batch step (sample 2 of 4,
    seed 7; its direct light by impl.lighting.direct_batch) and compare every lit point,
    bit for bit, with the scalar per-point estimator (impl.lighting.direct_light_dims):
    its light and its shadow-ray count (points on emitters left out).  Yields (points, column, red light, shadow rays,
    local model, pixel, ray configuration) per point."""
    from impl import lighting, raycast
    from impl.camera import camera_params
    from impl.samplers import DIM_INDEPENDENT
    from impl.sampling import sampler_code
    from impl.tracer import eye_batch, new_batch, new_film

    p = registry.get("raycast").parse_params(params)
    A = flatten_cached(sc)
    R = tracer.ray_config_cached(sc, A, p, algorithm="raycast")
    M = lighting.local_model(p)
    cam = camera_params(sc.camera)
    W, H = sc.camera.film.width, sc.camera.film.height
    film = new_film(W, H, 1, False, sampler_code(p))
    for tile in range(0, film.packet.shape[0], 3):
        T = new_batch(film, R, tile, 7)
        sidx = np.empty(T.n, np.int64)
        eye_batch(cam, R, T, 2, 4, 7, False, film.sampler)
        raycast._shade(A, R, M, T, 2, 7, sidx, np.empty(T.n, np.bool_), bool(A.tri_has_n.any()))
        P = T.pts
        for i in np.flatnonzero(T.active[:T.n]):
            if A.shape_emit[A.prim_shape[T.prim[i]]].any():
                continue                 # T.L holds its emission too
            r, g, b, nsh = lighting.direct_light_dims(
                *P[:lighting.SP_N0, i], A, M.ks, M.shininess, M.c1, M.c2, M.c3, M.fclamp, M.shadows,
                M.light_samples, 7, T.pixel[i], 2, R, (DIM_INDEPENDENT, 0, 0),
                tuple(P[lighting.SP_N0:lighting.SP_MAP + 1, i]))
            assert (T.L[0, i], T.L[1, i], T.L[2, i]) == (r, g, b), (tile, i)
            assert T.cnt[i, 0] == nsh, (tile, i)
            yield P, i, r, nsh, M, T.pixel[i], R


@pytest.mark.parametrize("params", [{}, {"precision": "float32"}, {"offset": "normal"},
                                    {"offset": "epsilon"}, {"shadows": False},
                                    {"accel": "bvh-wide"}, {"c1": 0.5, "c3": 2.0, "fatt_clamp": True}])
def test_area_light_lanes_equal_the_scalar_light_samples(params):
    """direct_batch computes an area emitter's light sample at every point of a batch in one
    branch-free loop (impl.lighting._area_lanes, after the emitter triangle's search point
    by point): each point of the Cornell box (four stratified light samples; points lit,
    in shadow, and facing away from the light among them) gets, bit for bit, the light and
    the shadow-ray count of the scalar per-point estimator, in every ray configuration."""
    sc = load_scene(SUITES / "cornell/cornell_box.xml")
    lit = dark = 0
    for P, i, r, nsh, M, *_ in _lanes_against_scalar(sc, {"spp": 4, "light_samples": 4, **params}):
        lit += r > 0.0
        dark += r == 0.0
    assert lit > 1000 and dark > 10
