"""Benchmarks (not tests): z-buffer, depth sort and ray casting on the same scene
as the triangle count grows (thesis 1.3.1-1.3.3: z-buffer time "tends to be
independent of the number of objects", depth sort's comparisons grow faster
than linearly, brute-force ray casting is n·pixels).

The scene is ``spheres/lit_sphere.xml`` with its sphere drawn as a UV sphere
of N segments (N² − 2N triangles; the ground adds 2): 10 → 1e6 triangles for
the rasterisers.  Ray casting renders the *same* tessellated mesh
(:func:`impl.tessellate.tessellated_scene`), brute force over all primitives
(no acceleration structure yet), so it stops at 1e5 triangles (about ten
seconds a frame on 2 cores) and runs one round there.  Phong shading, pixel
centres, shadows off for ray casting (the rasterisers have none).

    .venv/bin/python -m pytest benchmarks/bench_visibility.py --benchmark-json reports/out/bench_visibility.json

Warm-up (numba compile or cache load) runs outside the timing on a small
mesh; pytest-benchmark quotes the median of the rounds.  Each result's
``extra_info`` carries ``triangles`` (input), ``triangles_per_s`` (input
triangles / median frame time) and the algorithm's counters.
"""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from impl import depth_sort, raycast, zbuffer
from impl.tessellate import sphere_triangle_count, tessellated_scene
from _timing import median_s

SUITES = Path(__file__).resolve().parent.parent / "suites"
SCENE = SUITES / "spheres/lit_sphere.xml"
#: Segments around the sphere → about 10, 1e2, 1e3, 1e4, 1e5, 1e6 triangles.
SEGMENTS = [4, 12, 32, 100, 318, 1000]
RAYCAST_MAX_TRIANGLES = 200_000


def _rounds(triangles):
    return 5 if triangles < 2e5 else 2


def _warm(algo, scene, params):
    algo.render(scene, algo.parse_params(dict(params, tessellation=8)), seed=0)


@pytest.mark.parametrize("n", SEGMENTS, ids=[f"{sphere_triangle_count(n) + 2}tri" for n in SEGMENTS])
@pytest.mark.parametrize("name", ["zbuffer", "depthsort"])
def bench_rasteriser(benchmark, name, n):
    algo = {"zbuffer": zbuffer.ALGORITHM, "depthsort": depth_sort.ALGORITHM}[name]
    scene = load_scene(SCENE)
    _warm(algo, scene, {})
    params = algo.parse_params({"tessellation": n})
    result = benchmark.pedantic(algo.render, args=(scene, params), kwargs={"seed": 0},
                                rounds=_rounds(sphere_triangle_count(n)), iterations=1)
    assert np.isfinite(result.image).all()
    tris = result.counters["triangles_in"]
    benchmark.extra_info.update(algorithm=name, triangles=tris,
                                triangles_per_s=tris / median_s(benchmark), **result.counters)


@pytest.mark.parametrize("n", [s for s in SEGMENTS if sphere_triangle_count(s) <= RAYCAST_MAX_TRIANGLES],
                         ids=[f"{sphere_triangle_count(s) + 2}tri" for s in SEGMENTS
                              if sphere_triangle_count(s) <= RAYCAST_MAX_TRIANGLES])
def bench_raycast_same_mesh(benchmark, n):
    algo = raycast.ALGORITHM
    params = algo.parse_params({"shadows": False})
    algo.render(tessellated_scene(load_scene(SCENE), 8), params, seed=0)     # warm-up
    scene = tessellated_scene(load_scene(SCENE), n)
    tris = sphere_triangle_count(n) + 2
    result = benchmark.pedantic(algo.render, args=(scene, params), kwargs={"seed": 0},
                                rounds=1 if tris > 5e4 else 3, iterations=1)
    assert np.isfinite(result.image).all()
    benchmark.extra_info.update(algorithm="raycast", triangles=tris,
                                triangles_per_s=tris / median_s(benchmark), **result.counters)
