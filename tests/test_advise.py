"""gibench.advise (scene features, model omissions, measured choice), gibench.leaderboard's
suite, the suite's seeds/ladder_samplers keys and the ladder's sampler choice."""

import json

import numpy as np
import pytest

from core.errors import SuiteError
from core.provenance import REPO_ROOT
from core.records import Record
from gibench import advise as adv

SUITES = REPO_ROOT / "suites"


def test_features_of_three_kinds_of_scene():
    box = adv.scene_features(SUITES / "cornell/cornell_box.xml")
    assert box["diffuse_only"] and not box["delta"] and not box["glossy"]
    assert box["lights"] == ["area"] and box["enclosing"] and box["primitives"] > 10
    glass = adv.scene_features(SUITES / "spheres/glass_sphere.xml")
    assert glass["delta"] and "dielectric" in glass["bsdfs"] and glass["delta_lights"]
    gloss = adv.scene_features(SUITES / "distributed/gloss.xml")
    assert gloss["glossy"] and not gloss["delta"]


def test_omissions_name_what_a_model_leaves_out():
    glass = adv.scene_features(SUITES / "spheres/glass_sphere.xml")
    assert adv.omissions("whitted", glass) == []
    assert "mirror/glass reflection and refraction" in adv.omissions("raycast", glass)
    assert "point/spot/directional lights" in adv.omissions("radiosity", glass)
    assert adv.omissions("path", glass) == []


def test_without_measurements_the_cheapest_covering_model_is_advised():
    a = adv.advise(SUITES / "cornell/cornell_box.xml")
    assert a.algorithm == "radiosity" and not a.measured       # diffuse, area light, enclosing
    assert "leaderboard" in a.reason
    a = adv.advise(SUITES / "spheres/glass_sphere.xml")
    assert a.algorithm == "whitted"
    a = adv.advise(SUITES / "distributed/gloss.xml")
    assert a.algorithm == "distributed"


def _lb(run, label, algorithm, err, t, seed=0, params=None):
    return Record(kind="case", run_id=run, suite="leaderboard spheres/glass_sphere",
                  scene="spheres/glass_sphere", algorithm=algorithm, label=label, seed=seed,
                  transport="full", params=params or {"spp": 4}, metrics={"relmse": err},
                  time={"own_median_s": t})


def test_measured_leaderboard_decides():
    run = "20260101T000000Z-aaaaaa"
    recs = [Record(kind="ladder", run_id=run, suite="leaderboard spheres/glass_sphere",
                   scene="spheres/glass_sphere", transport="full", label=f"m{n}", ladder_spp=n,
                   params={"spp": n, "sampler": "ldsampler"}, metrics={"relmse": 0.1 / n},
                   time={"own_median_s": 0.01 * n}) for n in (1, 4, 16, 64)]
    recs += [_lb(run, "whitted 2x2", "whitted", 0.05, 0.01),            # fast, above target
             _lb(run, "path 16", "path", 0.001, 0.5, params={"spp": 16}),
             _lb(run, "path 64", "path", 0.0012, 2.0, params={"spp": 64})]
    a = adv.advise(SUITES / "spheres/glass_sphere.xml", records=recs)
    assert a.measured and a.algorithm == "path" and a.params == {"spp": 16}
    assert "whitted" in str(a) and "0.05" in str(a)
    # A looser target: the fast Whitted configuration reaches it.
    a = adv.advise(SUITES / "spheres/glass_sphere.xml", records=recs, target=0.06)
    assert a.algorithm == "whitted"


def test_leaderboard_suite_covers_every_algorithm_against_full():
    from gibench import registry
    from gibench.leaderboard import leaderboard_suite

    s = leaderboard_suite(SUITES / "cornell/cornell_box.xml")
    assert {c.algorithm for c in s.cases} == {a.name for a in registry.algorithms()}
    assert {c.transport for c in s.cases} == {"full"}
    assert s.seeds == 3 and s.ladder == (1, 4, 16, 64) and len(s.ladder_samplers) == 4


def test_suite_keys_seeds_and_ladder_samplers(tmp_path):
    from gibench.suite import _seed_jobs, load_suite

    def write(head):
        p = tmp_path / "s.toml"
        p.write_text(f"[suite]\n{head}\n[[group]]\nscenes = ['{SUITES / 'spheres/lit_sphere.xml'}']\n"
                     "algorithm = 'raycast'\n")
        return p

    s = load_suite(write("seeds = 3\nladder = [1, 4]\nladder_samplers = ['independent', 'ldsampler']"))
    assert s.seeds == 3 and s.ladder_samplers == ("independent", "ldsampler")
    jobs = _seed_jobs(s, 10)
    assert [o["seed"] for _, _, o in jobs] == [10, 11, 12]
    assert [o.get("judge", True) for _, _, o in jobs] == [True, False, False]
    with pytest.raises(SuiteError, match="ladder_samplers"):
        load_suite(write("ladder_samplers = ['sobol']"))
    with pytest.raises(SuiteError, match="seeds"):
        load_suite(write("seeds = 0"))


def test_default_suite_has_a_ladder_for_every_case():
    from gibench.suite import load_suite

    s = load_suite(SUITES / "default.toml")
    assert s.ladder and 64 in s.ladder and s.seeds >= 3
    assert set(s.ladder_samplers) >= {"independent", "multijitter", "ldsampler"}


def _fake_rungs(monkeypatch, noise_by_spp, times, calls):
    """references.ladder.prepare_ladder replaced by rungs whose images are the
    reference plus Gaussian noise of a given size per (spp, sampler)."""
    import references.ladder as rl

    rng = np.random.default_rng(0)
    ref = np.ones((8, 8, 3), np.float32)

    class FakeRung:
        def __init__(self, spp, sampler):
            self.spp, self.requested_spp, self.sampler = spp, spp, sampler

        def render(self, seed):
            calls.append((self.spp, self.sampler, seed))
            noise = noise_by_spp[self.spp][self.sampler]
            return ref + noise * rng.standard_normal(ref.shape).astype(np.float32), times[self.sampler]

    def fake(scene, *, transport, spps, defines, sampler):
        return [FakeRung(int(spps[0]), sampler)]

    monkeypatch.setattr(rl, "prepare_ladder", fake)
    return ref


def test_choose_sampler_picks_the_most_efficient_and_caches(tmp_path, monkeypatch):
    from references.ladder import LADDER_SEED
    from gibench import ladder as gl

    noise = {"independent": 0.3, "stratified": 0.2, "multijitter": 0.1, "ldsampler": 0.15}
    times = {"independent": 1.0, "stratified": 1.0, "multijitter": 1.5, "ldsampler": 1.0}
    calls = []
    ref = _fake_rungs(monkeypatch, {16: noise}, times, calls)

    class Ref:
        key, variance = "k" * 64, None
        image = ref

    monkeypatch.setattr(gl, "_cache_key", lambda *a: "key")
    cache = tmp_path / "c.json"
    c = gl.choose_sampler("scene.xml", transport="full", reference=Ref(), cache=cache, repeats=2)
    # relMSE ~ noise^2: multijitter 0.01 x 1.5 beats ldsampler 0.0225 x 1.0.
    assert c["sampler"] == "multijitter" and not c["cached"] and len(calls) == 8
    # The probe's seeds are apart from the ladder's (LADDER_SEED + 1 .. + repeats), and
    # so are a rung's two warm-up seeds.
    assert {s for _, _, s in calls} == {LADDER_SEED + gl.PROBE_SEED_OFFSET + k for k in range(2)}
    from references.ladder import WARMUP_SEEDS
    assert len(set(WARMUP_SEEDS)) == 2 and not set(WARMUP_SEEDS) & set(range(LADDER_SEED + 1, LADDER_SEED + 100))
    assert set(json.loads(cache.read_text())["key"]["candidates"]) == set(noise)
    c = gl.choose_sampler("scene.xml", transport="full", reference=Ref(), cache=cache)
    assert c["cached"] and c["sampler"] == "multijitter" and len(calls) == 8
    with pytest.raises(ValueError, match="sampler"):
        gl.choose_sampler("scene.xml", transport="full", reference=Ref(), candidates=["sobol"])
    import references.ladder as rl
    assert rl.sampler_spec("ldsampler", 16)["type"] == "ldsampler"


def test_choose_sampler_decides_at_the_top_rung(tmp_path, monkeypatch):
    """At 16 spp ldsampler is the most efficient, at the top rung (64) stratified: the
    ladder uses the top rung's, where the equal-error race is read."""
    from gibench import ladder as gl

    noise = {16: {"independent": 0.3, "stratified": 0.2, "ldsampler": 0.1},
             64: {"independent": 0.15, "stratified": 0.03, "ldsampler": 0.06}}
    times = {"independent": 1.0, "stratified": 1.0, "ldsampler": 1.0}
    calls = []
    ref = _fake_rungs(monkeypatch, noise, times, calls)

    class Ref:
        key, variance = "k" * 64, None
        image = ref

    assert gl.probe_spps((1, 4, 16, 64)) == (16, 64) and gl.probe_spps((1, 4)) == (4,)
    c = gl.choose_sampler("scene.xml", transport="full", reference=Ref(), cache=None,
                          candidates=list(times), probe_spp=gl.probe_spps((1, 4, 16, 64)))
    assert c["best_by_spp"] == {"16": "ldsampler", "64": "stratified"}
    assert c["sampler"] == "stratified" and c["probe_spp"] == 64
    assert c["candidates"] is c["probes"]["64"] and {s for s, _, _ in calls} == {16, 64}
    # One candidate: nothing to probe.
    assert gl.choose_sampler("s.xml", transport="full", reference=Ref(), cache=None,
                             candidates=["ldsampler"])["sampler"] == "ldsampler"


def test_mitsuba_ladder_samplers_seeds_and_rounding(mitsuba):
    # Needs Mitsuba: a 64x48 scene, two timed renders per rung.
    from references.ladder import render_ladder

    scene = SUITES / "distributed/gloss.xml"
    rungs = render_ladder(scene, transport="whitted", spps=(1, 4), repeats=2, sampler="ldsampler")
    # ldsampler renders 1 spp as 4: one rung, recorded as what was rendered.
    assert [(r["spp"], r["requested_spp"]) for r in rungs] == [(4, 1)]
    a, b = rungs[0]["images"]
    assert a.shape == (48, 64, 3) and not np.array_equal(a, b)     # distinct seeds
    rungs = render_ladder(scene, transport="whitted", spps=(1, 4), repeats=1, sampler="multijitter")
    assert [r["spp"] for r in rungs] == [1, 4] and rungs[0]["sampler"] == "multijitter"
