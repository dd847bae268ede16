"""Benchmarks (not tests): each own ray tracer against its matched Mitsuba integrator on
the default-suite scenes (``suites/default.toml``), both sides measured in the same run.

======== ============================================ =================== ===========
tracer   scenes                                       Mitsuba integrator  transport
======== ============================================ =================== ===========
raycast  the raycast ``ztest`` group                  ``direct``          direct
whitted  the whitted ``ztest`` group                  ``whitted`` (ours,  whitted
                                                      references/whitted_integrator.py)
path     cornell_box, diffuse_room                    ``path``            full
======== ============================================ =================== ===========

* ``bench_equal_spp``: own and Mitsuba render at the same spp (the suite's),
  alternated (own, Mitsuba, own, ...) for ``ROUNDS`` rounds after one warm-up
  render each (JIT / cache load; Dr.Jit kernel compile); each timed render
  starts once the process is idle (:func:`gibench.interleave.settle`: the
  other side's worker threads still spin after its render returns); medians,
  the clock stopped after ``dr.sync_thread()`` on the Mitsuba side.  ``extra_info``:
  both medians and spreads, their ratio, the own setup/trace split
  (``RenderResult.timings``) and the own rays per second.
* ``bench_equal_error``: both sides render a ladder of sample counts
  (alternated, medians of ``ROUNDS``) and are compared with the stored
  1024-spp reference of the transport (relMSE).  Both estimators are unbiased,
  so relMSE·spp is constant up to noise: from the largest rung, c = relMSE·spp
  and t₁ = time/spp, and the time to reach a relMSE ε is c·t₁/ε.  The target
  ε is Mitsuba's relMSE at ``TARGET_SPP`` spp (extrapolated the same way).
  The stratified own estimators (raycast, whitted) converge faster than 1/spp,
  so their extrapolation from the largest rung is conservative.

    .venv/bin/python -m pytest benchmarks/bench_tracers.py -s --benchmark-json reports/out/bench_tracers.json

``-k raycast`` (or ``whitted``, ``path``, ``equal_spp``) selects a part.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from gibench.interleave import settle
from core.loader import load_scene

SUITES = Path(__file__).resolve().parent.parent / "suites"
ROUNDS = 7
LADDER = (4, 16)
TARGET_SPP = 64

#: (tracer, scene, transport, own params at equal spp).  One shadow ray per emitter and
#: pixel sample, as Mitsuba's ``direct`` (one emitter sample, plus one BSDF sample) and the
#: matched ``whitted`` integrator (one ``sample_direction`` per emitter) trace: equal spp
#: is then equal work per sample.  The suites' 16 stratified light samples per pixel
#: sample are a lower-variance configuration, judged by the equal-error benchmark.
CASES = (
    [("raycast", s, "direct", {"spp": 16, "light_samples": 1})
     for s in ("spheres/lit_sphere.xml", "spheres/spot_directional.xml", "spheres/meshes.xml",
               "cornell/cornell_point.xml", "cornell/cornell_box.xml")]
    + [("whitted", s, "whitted", {"spp": 36, "light_samples": 1})
       for s in ("spheres/mirror_sphere.xml", "spheres/glass_sphere.xml", "spheres/nested_glass.xml",
                 "spheres/whitted_classic.xml", "spheres/sphere_grid.xml",
                 "cornell/cornell_mirror_glass.xml")]
    + [("path", s, "full", {"spp": 16}) for s in ("cornell/cornell_box.xml", "cornell/diffuse_room.xml")]
)
IDS = [f"{t}-{s.split('/')[1][:-4]}" for t, s, _, _ in CASES]


def _mitsuba(scene: str, transport: str, spp: int, seed: int):
    """A function rendering the scene with the matched Mitsuba integrator at ``spp``
    (the reference overrides of :func:`references.reference.prepare_scene_xml`),
    returning the (H, W, 3) image once the work is done."""
    import drjit as dr

    from references.mitsuba_env import load_mitsuba
    from references.reference import load_scene as mi_load_scene, prepare_scene_xml

    mi = load_mitsuba()
    path = SUITES / scene
    xml, _, _ = prepare_scene_xml(path, transport=transport, spp_per_pass=spp, seed=seed)
    mscene = mi_load_scene(mi, path, xml)

    def render():
        img = mi.render(mscene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()                                      # mi.render is lazy
        return np.asarray(img, dtype=np.float32)[..., :3]

    return render


def _own(tracer: str, scene: str, params: dict, seed: int):
    algo = registry.get(tracer)
    sc = load_scene(SUITES / scene)
    p = algo.parse_params(params)
    if tracer == "path":                # the reference's depth: the file's own max_depth
        p["max_depth"] = _file_depth(scene)
    return lambda: algo.render(sc, p, seed=seed)


def _file_depth(scene: str) -> int:
    from references.reference import get_reference

    ref = get_reference(SUITES / scene, transport="full", spp=1024, passes=8)
    return int(ref.manifest["integrator"]["max_depth"])


def alternated(a, b, rounds: int = ROUNDS):
    """Warm both up, then time ``a`` and ``b`` alternately, each after
    :func:`gibench.interleave.settle` (the other side's worker threads idle): (times_a,
    times_b, last a, last b)."""
    out_a, out_b = a(), b()
    ta, tb = [], []
    for _ in range(rounds):
        settle()
        t0 = time.perf_counter()
        out_a = a()
        ta.append(time.perf_counter() - t0)
        settle()
        t0 = time.perf_counter()
        out_b = b()
        tb.append(time.perf_counter() - t0)
    return ta, tb, out_a, out_b


def _spread(ts):
    return [min(ts), max(ts)]


@pytest.mark.mitsuba
@pytest.mark.parametrize("tracer, scene, transport, params", CASES, ids=IDS)
def bench_equal_spp(benchmark, tracer, scene, transport, params):
    own = _own(tracer, scene, params, seed=3)
    mit = _mitsuba(scene, transport, params["spp"], seed=3)
    t_own, t_mi, res, img = alternated(own, mit)
    assert np.isfinite(res.image).all() and np.isfinite(img).all()
    c = res.counters
    rays = sum(v for k, v in c.items() if k.endswith("_rays") or k == "segments")
    own_s, mi_s = statistics.median(t_own), statistics.median(t_mi)
    benchmark.pedantic(own, rounds=1, iterations=1)           # the JSON record's own timing
    benchmark.extra_info.update(
        own_median_s=own_s, own_spread_s=_spread(t_own), mitsuba_median_s=mi_s,
        mitsuba_spread_s=_spread(t_mi), ratio_own_over_mitsuba=own_s / mi_s, rays=int(rays),
        own_rays_per_s=rays / own_s, own_timings=res.timings, spp=params["spp"])
    print(f"\n{tracer:8s} {scene:34s} spp {params['spp']:3d}: own {own_s * 1e3:8.1f} ms "
          f"[{min(t_own) * 1e3:.1f}-{max(t_own) * 1e3:.1f}] (setup "
          f"{res.timings.get('setup_s', float('nan')) * 1e3:.2f} ms), Mitsuba {mi_s * 1e3:8.1f} ms "
          f"[{min(t_mi) * 1e3:.1f}-{max(t_mi) * 1e3:.1f}], own/Mitsuba {own_s / mi_s:5.2f}, "
          f"own {rays / own_s / 1e6:.1f} M rays/s")


@pytest.mark.mitsuba
@pytest.mark.parametrize("tracer, scene, transport, params", CASES, ids=IDS)
def bench_equal_error(benchmark, tracer, scene, transport, params):
    from references.reference import get_reference
    from reports.metrics import relmse

    ref = get_reference(SUITES / scene, transport=transport, spp=1024, passes=8)
    ladders = {"own": [], "mitsuba": []}
    for spp in LADDER:
        own = _own(tracer, scene, {**params, "spp": spp}, seed=11)
        mit = _mitsuba(scene, transport, spp, seed=11)
        t_own, t_mi, res, img = alternated(own, mit, rounds=3)
        ladders["own"].append({"spp": spp, "s": statistics.median(t_own),
                               "relmse": relmse(ref.image, res.image)})
        ladders["mitsuba"].append({"spp": spp, "s": statistics.median(t_mi),
                                   "relmse": relmse(ref.image, img)})

    def constants(rows):
        top = rows[-1]
        return top["relmse"] * top["spp"], top["s"] / top["spp"]

    c_own, t1_own = constants(ladders["own"])
    c_mi, t1_mi = constants(ladders["mitsuba"])
    target = c_mi / TARGET_SPP
    own_s, mi_s = c_own * t1_own / target, c_mi * t1_mi / target
    benchmark.pedantic(_own(tracer, scene, {**params, "spp": LADDER[-1]}, seed=11), rounds=1,
                       iterations=1)
    benchmark.extra_info.update(ladders=ladders, target_relmse=target, own_time_to_target_s=own_s,
                                mitsuba_time_to_target_s=mi_s, ratio_own_over_mitsuba=own_s / mi_s)
    print(f"\n{tracer:8s} {scene:34s} relMSE {target:.3g} (Mitsuba {TARGET_SPP} spp): own "
          f"{own_s * 1e3:8.1f} ms, Mitsuba {mi_s * 1e3:8.1f} ms, own/Mitsuba {own_s / mi_s:5.2f}")
