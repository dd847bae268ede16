"""Benchmarks (not tests): each own ray tracer against its matched Mitsuba integrator on
the default-suite scenes (``suites/default.toml``), both sides measured in the same run.

======== ============================================ =================== ===========
tracer   scenes                                       Mitsuba integrator  transport
======== ============================================ =================== ===========
raycast  the raycast ``ztest`` group                  ``direct``          direct
whitted  the whitted ``ztest`` group                  ``whitted`` (ours,  whitted
                                                      references/whitted_integrator.py)
distrib. gloss (the distributed ``ztest`` group)      ``whitted`` (ours,  whitted
                                                      following glossy lobes)
path     cornell_box, diffuse_room; float64 (the      ``path``            full
         default) and float32 intersections
======== ============================================ =================== ===========

* ``bench_equal_spp``: own and Mitsuba render at the same spp (the suite's),
  alternated (own, Mitsuba, own, ...) for ``ROUNDS`` rounds after one warm-up
  render each (JIT / cache load; Dr.Jit kernel compile); each timed render
  starts once the process is idle (:func:`gibench.interleave.settle`: the
  other side's worker threads still spin after its render returns); medians,
  the clock stopped after ``dr.sync_thread()`` on the Mitsuba side.  ``extra_info``:
  both medians and spreads, their ratio, the own setup/trace split
  (``RenderResult.timings``) and the own rays per second.
* ``bench_equal_error``: the race to Mitsuba's error at the top of ``LADDER``.
  Mitsuba renders with its most efficient sampler on the scene, measured in the
  run: :func:`gibench.ladder.choose_sampler` at the top rung, as many renders
  per sampler as ``SEEDS`` has, not cached (one render's relMSE varies 2–5×
  from seed to seed on some scenes, so the choice needs several renders; its
  seeds are apart from the race's, so the target is not the lucky draw that
  won the choice).
  The own tracer renders with ``sampler=sobol`` (Sobol pixel, light and BSDF
  samples); both at the spp of ``LADDER`` (the own side also at
  ``OWN_EXTRA``), ``SEEDS`` seeds each, own and Mitsuba renders alternated
  (each after :func:`gibench.interleave.settle`); error = relMSE against the
  stored 1024-spp reference, the mean over the seeds (their spread in
  ``extra_info``); time = median.  The own
  time to Mitsuba's top-rung error is interpolated log-log between the own
  rungs (:func:`time_to_error`: an upper bound, ``<=``, when the own lowest
  rung is already below it; extrapolated, ``~``, when no own rung reaches it);
  the ratio is over Mitsuba's median time at its top rung.

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
#: Sample counts of the equal-error race; Mitsuba's last one is the target.  The own side
#: also renders ``OWN_EXTRA`` spp (whitted's split trees reach Mitsuba's 64-spp error
#: with fewer samples than Mitsuba's lowest rung).
LADDER = (16, 64)
OWN_EXTRA = (4,)
#: Seeds of every rung of the equal-error race (their count: the sampler choice's renders).
SEEDS = tuple(range(11, 19))

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
    + [("distributed", "distributed/gloss.xml", "whitted", {"spp": 16, "light_samples": 1})]
    + [("path", s, "full", {"spp": 16, **prec}) for prec in ({}, {"precision": "float32"})
       for s in ("cornell/cornell_box.xml", "cornell/diffuse_room.xml")]
)
IDS = [f"{t}-{s.split('/')[1][:-4]}" + (f"-{p['precision']}" if "precision" in p else "")
       for t, s, _, p in CASES]


def _label(scene: str, params: dict) -> str:
    """The scene, and the precision where the case sets one, for the printed lines."""
    return scene + (f" {params['precision']}" if "precision" in params else "")


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
    print(f"\n{tracer:8s} {_label(scene, params):34s} spp {params['spp']:3d}: own {own_s * 1e3:8.1f} ms "
          f"[{min(t_own) * 1e3:.1f}-{max(t_own) * 1e3:.1f}] (setup "
          f"{res.timings.get('setup_s', float('nan')) * 1e3:.2f} ms), Mitsuba {mi_s * 1e3:8.1f} ms "
          f"[{min(t_mi) * 1e3:.1f}-{max(t_mi) * 1e3:.1f}], own/Mitsuba {own_s / mi_s:5.2f}, "
          f"own {rays / own_s / 1e6:.1f} M rays/s")


def _mitsuba_seeded(scene: str, transport: str, spp: int, sampler: str):
    """A function ``seed -> image`` rendering the scene with the matched Mitsuba
    integrator and ``sampler`` at ``spp``, once the work is done."""
    import drjit as dr

    from references.ladder import sampler_spec
    from references.mitsuba_env import load_mitsuba
    from references.reference import load_scene as mi_load_scene, prepare_scene_xml

    mi = load_mitsuba()
    path = SUITES / scene
    xml, _, _ = prepare_scene_xml(path, transport=transport, spp_per_pass=spp,
                                  sampler=sampler_spec(sampler, spp))
    mscene = mi_load_scene(mi, path, xml)

    def render(seed):
        img = mi.render(mscene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return np.asarray(img, dtype=np.float32)[..., :3]

    return render


def time_to_error(points, target):
    """When the own (time, error) points reach ``target``: ``(seconds, how)``.
    ``how`` is ``"interpolated"`` (log-log between the two points around the target),
    ``"bound"`` (the fastest point is already below the target: its time is an upper
    bound) or ``"extrapolated"`` (no point reaches it: the log-log line through the
    two slowest points, continued)."""
    pts = sorted(points)
    if pts[0][1] <= target:
        return float(pts[0][0]), "bound"
    hi = [p for p in pts if p[1] <= target]
    if hi:
        b = hi[0]
        a = pts[pts.index(b) - 1]
        how = "interpolated"
    else:
        a, b = pts[-2], pts[-1]
        how = "extrapolated"
    slope = (np.log(b[1]) - np.log(a[1])) / (np.log(b[0]) - np.log(a[0]))
    return float(np.exp(np.log(a[0]) + (np.log(target) - np.log(a[1])) / slope)), how


@pytest.mark.mitsuba
@pytest.mark.parametrize("tracer, scene, transport, params", CASES, ids=IDS)
def bench_equal_error(benchmark, tracer, scene, transport, params):
    from gibench.ladder import choose_sampler
    from references.reference import get_reference
    from reports.metrics import relmse

    ref = get_reference(SUITES / scene, transport=transport, spp=1024, passes=8)
    choice = choose_sampler(SUITES / scene, transport=transport, reference=ref,
                            probe_spp=LADDER[-1], repeats=len(SEEDS), cache=None)
    sampler, candidates = choice["sampler"], choice["candidates"]
    rows = {"own": [], "mitsuba": []}
    for spp in sorted(set(LADDER) | set(OWN_EXTRA)):
        algo = registry.get(tracer)
        sc = load_scene(SUITES / scene)
        p = algo.parse_params({**params, "spp": spp, "sampler": "sobol"})
        if tracer == "path":
            p["max_depth"] = _file_depth(scene)
        mit = _mitsuba_seeded(scene, transport, spp, sampler) if spp in LADDER else None
        algo.render(sc, p, seed=SEEDS[0])                      # warm-up, both sides
        if mit:
            mit(SEEDS[0])
        t_own, t_mi, e_own, e_mi = [], [], [], []
        for seed in SEEDS:
            settle()
            t0 = time.perf_counter()
            res = algo.render(sc, p, seed=seed)
            t_own.append(time.perf_counter() - t0)
            e_own.append(relmse(ref.image, res.image))
            if mit:
                settle()
                t0 = time.perf_counter()
                img = mit(seed)
                t_mi.append(time.perf_counter() - t0)
                e_mi.append(relmse(ref.image, img))
        rows["own"].append({"spp": spp, "s": statistics.median(t_own), "times_s": t_own,
                            "relmse": float(np.mean(e_own)), "relmse_seeds": e_own})
        if mit:
            rows["mitsuba"].append({"spp": spp, "s": statistics.median(t_mi), "times_s": t_mi,
                                    "relmse": float(np.mean(e_mi)), "relmse_seeds": e_mi})
    target, mi_s = rows["mitsuba"][-1]["relmse"], rows["mitsuba"][-1]["s"]
    own_s, how = time_to_error([(r["s"], r["relmse"]) for r in rows["own"]], target)
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)
    benchmark.extra_info.update(rungs=rows, mitsuba_sampler=sampler, mitsuba_samplers=candidates,
                                target_relmse=target,
                                own_time_to_target_s=own_s, mitsuba_time_s=mi_s,
                                ratio_own_over_mitsuba=own_s / mi_s, how=how)
    own_txt = ", ".join(f"{r['spp']} spp {r['relmse']:.3g} in {r['s'] * 1e3:.0f} ms" for r in rows["own"])
    mi_txt = ", ".join(f"{r['spp']} spp {r['relmse']:.3g} in {r['s'] * 1e3:.0f} ms" for r in rows["mitsuba"])
    print(f"\n{tracer:8s} {_label(scene, params):34s} own (sobol): {own_txt}; Mitsuba ({sampler}): {mi_txt}; "
          f"to Mitsuba's {LADDER[-1]}-spp error: own/Mitsuba "
          f"{ {'bound': '<=', 'extrapolated': '~'}.get(how, '')}{own_s / mi_s:.2f}")
