"""Benchmarks (not tests): own ``distributed`` vs Mitsuba on each distributed-effect scene —
the time each needs to reach the same error, measured in one run.

For each scene of ``suites/distributed.toml`` the own tracer and Mitsuba (the
scene's matched integrator: ``direct``, or the ``whitted`` Python integrator
following glossy lobes) render a ladder of sample counts; each render's MSE
against the stored 1024 × 8 spp reference and its wall time (median of 3,
warm-up excluded) are recorded.  The target error is the own tracer's MSE at
64 spp; each renderer's time to reach it is interpolated log–log along its
ladder.  ``extra_info``: both ladders, ``own_time_to_target``,
``mitsuba_time_to_target`` and their ratio (own / Mitsuba; > 1 = own slower).
The benchmark's own timing is the own render at 64 spp.

    .venv/bin/python -m pytest benchmarks/bench_distributed.py --benchmark-json out.json
"""

from pathlib import Path
import time

import numpy as np
import pytest

from gibench import registry
from core.loader import load_scene
from _timing import median_s

SUITES = Path(__file__).resolve().parent.parent / "suites"
CASES = [("distributed/penumbra.xml", "direct"), ("distributed/dof.xml", "direct"),
         ("distributed/gloss.xml", "whitted"), ("distributed/translucency.xml", "whitted")]
LADDER = (4, 16, 64, 256)


def _median_time(fn, rounds=3):
    fn()                                                          # warm-up
    ts, out = [], None
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), out


def _time_to(target, ladder):
    """Log–log interpolation of the time at which MSE reaches ``target`` ((time, mse) points)."""
    pts = sorted(ladder)
    for (t0, m0), (t1, m1) in zip(pts, pts[1:]):
        if m0 >= target >= m1 and m0 > 0 and m1 > 0 and m0 != m1:
            f = np.log(m0 / target) / np.log(m0 / m1)
            return float(np.exp(np.log(t0) + f * np.log(t1 / t0)))
    return float("nan")


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene, transport", CASES, ids=[c[0].split("/")[1][:-4] for c in CASES])
def bench_time_to_equal_error(benchmark, scene, transport):
    import drjit as dr

    from references.mitsuba_env import load_mitsuba
    from references.reference import get_reference, load_scene as mi_load_scene, prepare_scene_xml

    ref = get_reference(SUITES / scene, transport=transport, spp=1024, passes=8)
    algo = registry.get("distributed")
    sc = load_scene(SUITES / scene)
    own, mit = [], []
    for spp in LADDER:
        p = algo.parse_params({"spp": spp, "light_samples": 1})
        t, res = _median_time(lambda: algo.render(sc, p))
        own.append((t, float(((res.image - ref.image) ** 2).mean())))
    mi = load_mitsuba()
    for spp in LADDER:
        xml, _, _ = prepare_scene_xml(SUITES / scene, transport=transport, spp_per_pass=spp, seed=1)
        mi_scene = mi_load_scene(mi, SUITES / scene, xml)

        def render():
            img = mi.render(mi_scene, spp=spp, seed=1)
            dr.sync_thread()
            return np.asarray(img)[..., :3]

        t, img = _median_time(render)
        mit.append((t, float(((img - ref.image) ** 2).mean())))
    target = own[2][1]                                            # own MSE at 64 spp
    t_own, t_mi = _time_to(target, own), _time_to(target, mit)
    p64 = algo.parse_params({"spp": 64, "light_samples": 1})
    benchmark.pedantic(algo.render, args=(sc, p64), rounds=3, iterations=1)
    benchmark.extra_info.update(own_ladder=own, mitsuba_ladder=mit, target_mse=target,
                                own_time_to_target=t_own, mitsuba_time_to_target=t_mi,
                                own_over_mitsuba=t_own / t_mi if t_mi == t_mi and t_mi > 0 else None,
                                own_64spp_median_s=median_s(benchmark), variant=mi.variant())
