"""Speed-vs-error functions (reports/pareto.py) on synthetic data with known answers."""

import math

import numpy as np
import pytest

from core.records import Record
from reports.pareto import (efficiency, equal_error_time_ratio, equal_time_error_ratio,
                            error_at_time, loglog_interp, noise_floor_relmse, pareto_front,
                            points_from_records, summarize_points, time_at_error)


def test_pareto_front_known_set():
    # (time, error): B dominates D (faster and better); E duplicates C's time with worse error.
    t = [1.0, 2.0, 4.0, 3.0, 4.0, 8.0]
    e = [8.0, 4.0, 1.0, 5.0, 3.0, 1.0]
    #     A     B    C    D    E    F (F: slower than C, equal error -> dominated)
    assert pareto_front(t, e).tolist() == [0, 1, 2]


def test_pareto_front_ignores_nonfinite_and_orders_by_time():
    t = [5.0, np.nan, 1.0, 3.0]
    e = [0.5, 0.1, 4.0, 1.0]
    assert pareto_front(t, e).tolist() == [2, 3, 0]


def test_pareto_front_random_points_are_not_dominated():
    rng = np.random.default_rng(7)
    t, e = rng.random(200), rng.random(200)
    f = pareto_front(t, e)
    for i in f:
        dominated = (t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))
        assert not dominated.any()
    off = np.setdiff1d(np.arange(200), f)
    for i in off:
        assert (((t <= t[i]) & (e <= e[i])) & ((t < t[i]) | (e < e[i]))).any()


def test_loglog_interp_is_exact_for_power_laws():
    x = np.array([1.0, 4.0, 16.0, 64.0])
    y = 3.0 * x**-1.0
    assert loglog_interp(x, y, 8.0) == pytest.approx(3.0 / 8.0, rel=1e-12)
    assert loglog_interp(x[::-1], y[::-1], 2.0) == pytest.approx(1.5, rel=1e-12)
    assert math.isnan(loglog_interp(x, y, 100.0))          # no extrapolation
    with pytest.raises(ValueError, match="positive"):
        loglog_interp([0.0, 1.0], [1.0, 2.0], 0.5)


def test_equal_error_and_equal_time_ratios_on_a_power_law_ladder():
    # Mitsuba ladder: error = 0.1 / t (MSE ~ 1/spp, time ~ spp).
    mt = np.array([0.01, 0.04, 0.16, 0.64])
    me = 0.1 / mt
    # An own configuration twice as fast for the same error: t = 0.04, e = 0.1 / 0.08.
    t_own, e_own = 0.04, 0.1 / 0.08
    assert time_at_error(mt, me, e_own) == pytest.approx(0.08)
    assert equal_error_time_ratio(t_own, e_own, mt, me) == pytest.approx(0.5)
    # At the same time Mitsuba's error is 0.1 / 0.04: the own error is half of it.
    assert error_at_time(mt, me, t_own) == pytest.approx(2.5)
    assert equal_time_error_ratio(t_own, e_own, mt, me) == pytest.approx(0.5)
    # Outside the ladder's range: NaN, not an extrapolated guess.
    assert math.isnan(equal_error_time_ratio(1.0, 1e-4, mt, me))


def test_efficiency_and_constant_for_an_unbiased_estimator():
    spp = np.array([1, 4, 16, 64], dtype=float)
    time, mse = 0.01 * spp, 0.2 / spp
    eff = efficiency(mse, time)
    assert np.allclose(eff, eff[0])
    assert efficiency(0.5, 2.0) == 1.0
    assert efficiency(0.0, 1.0) == math.inf


def test_noise_floor_relmse_matches_definition():
    ref = np.full((4, 4, 3), 2.0)
    var = np.full((4, 4, 3), 0.01)
    assert noise_floor_relmse(ref, var) == pytest.approx(0.01 / (4.0 + 0.01))
    with pytest.raises(ValueError, match="shape"):
        noise_floor_relmse(ref, var[:2])


def test_summarize_and_points_from_records():
    recs = [{"kind": "ladder", "scene": "s", "transport": "full", "label": f"Mitsuba {n}",
             "ladder_spp": n, "metrics": {"relmse": 0.1 / n, "noise_floor_relmse": 1e-4},
             "time": {"own_median_s": 0.01 * n}} for n in (1, 4, 16)]
    recs += [{"kind": "case", "scene": "s", "transport": "full", "label": "fast",
              "algorithm": "a", "metrics": {"relmse": 0.025}, "time": {"own_median_s": 0.02}},
             {"kind": "case", "scene": "s", "transport": "full", "label": "slow",
              "algorithm": "a", "metrics": {"relmse": 0.05}, "time": {"own_median_s": 0.1}},
             {"kind": "case", "scene": "s", "transport": "full", "label": "broken",
              "algorithm": "a", "error": "boom"}]
    groups = points_from_records([Record.from_json(r) for r in recs])
    g = groups[("s", "full")]
    assert [p["label"] for p in g["own"]] == ["fast", "slow"]
    assert g["noise_floor"] == 1e-4
    s = summarize_points(g["own"], g["mitsuba"])
    fast, slow = s["rows"]
    assert fast["pareto"] and not slow["pareto"]
    # Mitsuba reaches 0.025 at t = 0.04: fast is 2x faster at equal error.
    assert fast["equal_error_time_ratio"] == pytest.approx(0.5)
    assert s["best"]["equal_error_label"] == "fast"
    assert slow["efficiency"] == pytest.approx(1 / (0.05 * 0.1))


def test_extrapolation_follows_the_end_segment_power_law():
    mt = np.array([0.01, 0.04, 0.16])
    me = 0.1 / mt
    # Interpolation alone cannot reach error 0.1 / 0.64; the power law can, exactly.
    assert math.isnan(time_at_error(mt, me, 0.1 / 0.64))
    assert time_at_error(mt, me, 0.1 / 0.64, extrapolate=True) == pytest.approx(0.64)
    assert error_at_time(mt, me, 0.64, extrapolate=True) == pytest.approx(0.1 / 0.64)
    # Never towards less time than the cheapest rung (fewer than its samples).
    assert math.isnan(error_at_time(mt, me, 0.0025, extrapolate=True))
    assert math.isnan(time_at_error(mt, me, 40.0, extrapolate=True))
    assert loglog_interp([1.0, 2.0], [4.0, 1.0], 4.0, extrapolate=True) == pytest.approx(0.25)
    # summarize_points extrapolates and says so.
    s = summarize_points([{"label": "x", "time": 1.28, "error": 0.1 / 0.64}],
                         [{"label": f"m{t}", "time": t, "error": 0.1 / t} for t in mt])
    (row,) = s["rows"]
    assert row["equal_error_time_ratio"] == pytest.approx(2.0) and row["equal_error_extrapolated"]
    assert s["best"]["equal_error_extrapolated"]


def _ladder(errs_by_spp, sampler="multijitter"):
    return [Record.from_json({"kind": "ladder", "scene": "s", "transport": "full",
                              "label": f"Mitsuba {n}", "ladder_spp": n,
                              "params": {"spp": n, "sampler": sampler},
                              "metrics": {"relmse": float(np.mean(e)), "relmse_seeds": e},
                              "time": {"own_median_s": 0.01 * n}})
            for n, e in errs_by_spp.items()]


def _case(label, seed, err, t, algorithm="a"):
    return Record.from_json({"kind": "case", "scene": "s", "transport": "full", "label": label,
                             "algorithm": algorithm, "seed": seed, "params": {"spp": 4},
                             "metrics": {"relmse": err}, "time": {"own_median_s": t}})


def test_seeds_of_one_configuration_are_one_point_with_mean_and_spread():
    from reports.pareto import primary_records

    recs = _ladder({1: [0.1, 0.12, 0.08], 4: [0.025, 0.03, 0.02], 16: [0.006, 0.007, 0.005]})
    recs += [_case("c", 0, 0.02, 0.05), _case("c", 1, 0.04, 0.9), _case("c", 2, 0.03, 0.9)]
    g = points_from_records(recs)[("s", "full")]
    (p,) = g["own"]
    assert p["seeds"] == 3 and p["error"] == pytest.approx(0.03)
    assert p["spread"] == pytest.approx(0.01)
    assert p["time"] == 0.05                              # the lowest seed's (timed) median
    assert g["sampler"] == "multijitter"
    m = g["mitsuba"][0]
    assert m["error"] == pytest.approx(0.1) and m["spread"] == pytest.approx(0.02)
    prim = primary_records(recs)
    assert [r.seed for r in prim if r.kind == "case"] == [0]
    assert sum(r.kind == "ladder" for r in prim) == 3


def test_top_rung_race_against_mitsubas_most_expensive_error():
    from reports.pareto import top_rung_race

    mitsuba = [{"label": f"m{n}", "spp": n, "time": 0.01 * n, "error": 0.1 / n} for n in (1, 4, 16, 64)]
    # Own curve error = 0.01 / t: reaches 0.1/64 at t = 6.4 vs Mitsuba's 0.64 -> ratio 10.
    own = [{"label": f"o{k}", "time": t, "error": 0.01 / t} for k, t in enumerate((0.5, 1.0, 2.0))]
    race = top_rung_race(own, mitsuba)
    assert race["spp"] == 64 and race["extrapolated"]
    assert race["ratio"] == pytest.approx(10.0)
    # A faster own curve inside its range: error = 1e-4 / t reaches 0.1/64 at t = 0.064.
    own = [{"label": f"o{k}", "time": t, "error": 1e-4 / t} for k, t in enumerate((0.01, 0.1))]
    race = top_rung_race(own, mitsuba)
    assert not race["extrapolated"] and race["ratio"] == pytest.approx(0.1)
    assert top_rung_race([], mitsuba) is None


def test_model_floors_per_algorithm():
    from reports.pareto import model_floors

    own = [{"algorithm": "raycast", "label": "r4", "time": 1.0, "error": 0.2},
           {"algorithm": "raycast", "label": "r16", "time": 4.0, "error": 0.19},
           {"algorithm": "path", "label": "p4", "time": 2.0, "error": 0.1},
           {"algorithm": "path", "label": "p16", "time": 8.0, "error": 0.025}]
    f = model_floors(own)
    assert f["raycast"]["floor"] == 0.19 and f["raycast"]["drop"] == pytest.approx(0.95)
    assert f["path"]["label"] == "p16" and f["path"]["drop"] == pytest.approx(0.25)


def test_worse_than_the_cheapest_rung_gets_a_lower_bound():
    mitsuba = [{"label": f"m{n}", "spp": n, "time": 0.01 * n, "error": 0.1 / n} for n in (1, 4)]
    s = summarize_points([{"label": "bad", "time": 0.05, "error": 0.3}], mitsuba)
    (row,) = s["rows"]
    assert math.isnan(row["equal_error_time_ratio"])
    assert row["equal_error_lower_bound"] == pytest.approx(5.0)
