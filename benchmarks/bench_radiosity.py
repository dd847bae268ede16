"""Benchmarks (not tests): radiosity form factors per method and solvers, vs patch
count, on the Cornell box (suites/cornell/cornell_box.xml).  Warm-up (numba
compile or cache load) is outside the timing; pytest-benchmark quotes the
median of the rounds.

    .venv/bin/python -m pytest benchmarks/bench_radiosity.py \\
        --benchmark-json reports/out/bench_radiosity.json

``extra_info`` carries the patch count, the time per patch pair
(form factors: seconds / N²) and the solver's iterations.
"""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from impl.form_factors import form_factors
from impl.patches import mesh_scene
from impl.radiosity_solvers import SOLVERS, solve
from _timing import median_s

SCENE = Path(__file__).resolve().parent.parent / "suites" / "cornell" / "cornell_box.xml"
COUNTS = (64, 256, 1024)
METHODS = [("contour", {"vis_rays": 4}), ("hemicube", {"hemicube_res": 64}),
           ("montecarlo", {"mc_samples": 1024})]


def _mesh(n):
    return mesh_scene(load_scene(SCENE), patches=n)


@pytest.mark.parametrize("n", COUNTS)
@pytest.mark.parametrize("method, kw", METHODS, ids=[m for m, _ in METHODS])
def bench_form_factors(benchmark, method, kw, n):
    M = _mesh(n)
    form_factors(_mesh(16), method, **kw)                      # warm-up: JIT / cache load
    ff = benchmark.pedantic(form_factors, args=(M, method), kwargs=kw, rounds=3, iterations=1)
    assert np.isfinite(ff.F).all()
    N = M.n_patches
    benchmark.extra_info.update(patches=N, rays=ff.rays,
                                s_per_pair=median_s(benchmark) / (N * N))


@pytest.mark.parametrize("n", COUNTS)
@pytest.mark.parametrize("solver", SOLVERS)
def bench_solver(benchmark, solver, n):
    M = _mesh(n)
    F = form_factors(M, "contour").F
    solve(F, M.rho, M.emit, M.area, solver, tol=1e-8)          # warm-up
    res = benchmark.pedantic(solve, args=(F, M.rho, M.emit, M.area, solver), kwargs={"tol": 1e-8},
                             rounds=5, iterations=1)
    assert res.converged
    benchmark.extra_info.update(patches=M.n_patches, iterations=res.iterations, shots=res.shots,
                                residual=float(res.residuals[-1]))
