"""Benchmarks (not tests): the intersection kernels of :mod:`impl.intersect` on a
fixed batch of rays through the vectorised numba batch kernels — each
ray–sphere form × precision, Möller–Trumbore, slabs.

    .venv/bin/python -m pytest benchmarks/bench_intersect.py \\
        -o python_files='bench_*.py' -o python_functions='bench_*' \\
        --benchmark-json reports/out/bench_intersect.json

The inputs are cast to the precision once, outside the timing (the wrappers
then pass them through without a copy); a warm-up call keeps JIT compilation
or cache loading out of the timing; pytest-benchmark quotes the median of the
rounds.  Each result's ``extra_info`` carries the rays per second, and every
benchmark checks its own return value.
"""

import numpy as np
import pytest

from impl.intersect import SPHERE_FORMS, ray_box_batch, ray_sphere_batch, ray_triangle_batch
from _timing import median_s

N_RAYS = 1 << 18
SEED = 20240917
ROUNDS = 15


def _rays(dtype):
    """N rays from points around (0, 0, −10) towards random points of the [−1.5, 1.5]² window at z = 0."""
    rng = np.random.default_rng(SEED)
    o = np.array([0.0, 0.0, -10.0]) + rng.uniform(-0.5, 0.5, (N_RAYS, 3))
    target = np.column_stack([rng.uniform(-1.5, 1.5, (N_RAYS, 2)), np.zeros(N_RAYS)])
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o.astype(dtype), d.astype(dtype), o, d


def _run(benchmark, fn, *args, **kwargs):
    fn(*args, **kwargs)                                              # warm-up: JIT / cache load
    out = benchmark.pedantic(fn, args=args, kwargs=kwargs, rounds=ROUNDS, iterations=1)
    benchmark.extra_info.update(rays=N_RAYS, rays_per_s=N_RAYS / median_s(benchmark))
    return out


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("form", SPHERE_FORMS)
def bench_ray_sphere(benchmark, form, dtype):
    o, d, o64, d64 = _rays(dtype)
    center = np.zeros(3, dtype=dtype)
    t = _run(benchmark, ray_sphere_batch, o, d, center, 1.0, form=form, dtype=dtype)
    # Correctness: hits exactly where the (float64) line passes within r of the
    # centre, away from tangency; t within a few ulps of the float64 answer.
    f = o64
    b = -np.einsum("ij,ij->i", f, d64)
    perp = np.linalg.norm(f + b[:, None] * d64, axis=1)
    clear = np.abs(perp - 1.0) > 1e-3
    assert np.array_equal((t >= 0)[clear], (perp < 1.0)[clear])
    hit = clear & (perp < 1.0)
    t_ref = b[hit] - np.sqrt(1.0 - perp[hit] ** 2)
    np.testing.assert_allclose(t[hit], t_ref, rtol=1e-4 if dtype == "float32" else 1e-12)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def bench_moller_trumbore(benchmark, dtype):
    o, d, o64, d64 = _rays(dtype)
    v = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    t, b1, b2 = _run(benchmark, ray_triangle_batch, o, d, v.astype(dtype), dtype=dtype)
    # Correctness: t to the plane z = 0, barycentrics reproduce the hit point.
    hit = t >= 0
    assert 0.2 < hit.mean() < 0.6
    t_plane = -o64[:, 2] / d64[:, 2]
    np.testing.assert_allclose(t[hit], t_plane[hit], rtol=1e-5 if dtype == "float32" else 1e-12)
    p = o64[hit] + t_plane[hit, None] * d64[hit]
    q = v[0] + b1[hit, None] * (v[1] - v[0]) + b2[hit, None] * (v[2] - v[0])
    np.testing.assert_allclose(q, p, atol=1e-4 if dtype == "float32" else 1e-12)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def bench_slabs(benchmark, dtype):
    o, d, o64, d64 = _rays(dtype)
    lo, hi = np.array([-1.0, -0.5, -0.25]), np.array([1.0, 0.5, 0.25])
    t0, t1 = _run(benchmark, ray_box_batch, o, d, lo.astype(dtype), hi.astype(dtype), dtype=dtype)
    # Correctness: the slab intervals of the float64 rays overlap exactly where t0 ≥ 0
    # (no zero direction components here), away from the box's outline.
    ta, tb = (lo - o64) / d64, (hi - o64) / d64
    near = np.minimum(ta, tb).max(axis=1)
    far = np.maximum(ta, tb).min(axis=1)
    clear = np.abs(far - near) > 1e-3
    assert np.array_equal((t0 >= 0)[clear], (near <= far)[clear])
    hit = clear & (near <= far)
    np.testing.assert_allclose(t0[hit], near[hit], rtol=1e-5 if dtype == "float32" else 1e-12)
    assert np.all(t1[hit] >= t0[hit])
