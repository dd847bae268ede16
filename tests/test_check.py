"""The CI accuracy gate (gibench/check.py, ``gibench baseline`` / ``gibench check``).

Unit tests on synthetic records (a scaled image, a Z-test that stops passing, a
missing case, a speed regression), then the command line end to end on a
one-case suite whose reference is in references/store: an unchanged run passes
with nothing moved, a broken algorithm parameter fails with a table naming the
metrics and writes the evidence EXRs.
"""

import dataclasses
import json
import sqlite3

import numpy as np
import pytest

from gibench import cli
from gibench.check import (BaselineError, compare_with_baseline, format_findings, make_baseline,
                           read_baseline)
from reports.metrics import compare

from _suites import raycast_suite
from core.records import Record

SEED = 1234


def _record(ref, var, img, *, label="cfg", ratio=10.0, test_var=None):
    return Record(kind="case", scene="synthetic", algorithm="algo", label=label,
                  transport="direct", params={"spp": 16},
                  metrics=compare(ref, img, reference_variance=var, test_variance=test_var),
                  time={"own_median_s": 0.1, "ratio": ratio})


@pytest.fixture(scope="module")
def synthetic():
    """A reference with its variance and own renders at two seeds (the baseline) and a
    third seed standing for an unchanged rerun."""
    rng = np.random.default_rng(SEED)
    print(f"seed {SEED}")
    ref = rng.uniform(0.2, 1.0, (32, 32, 3))
    var = np.full_like(ref, 1e-4)
    renders = [ref + rng.normal(0, 1e-2, ref.shape) for _ in range(3)]
    tvar = np.full_like(ref, 1e-4)
    return ref, var, renders, tvar


def test_unchanged_passes_scaled_image_fails(synthetic):
    ref, var, renders, tvar = synthetic
    base = make_baseline([[_record(ref, var, renders[0], test_var=tvar)],
                          [_record(ref, var, renders[1], test_var=tvar)]],
                         suite="t", suite_file="t.toml", seeds=[0, 1])
    same = compare_with_baseline([_record(ref, var, renders[0], test_var=tvar)], base)
    assert not any(f.failed for f in same)
    assert "nothing moved" in format_findings(same)
    # Another seed moves the metrics inside the tolerance the seed spread set.
    other = compare_with_baseline([_record(ref, var, renders[2], test_var=tvar)], base)
    assert not [f for f in other if f.failed], format_findings(other)
    # A 10 % brighter image is a regression of every error metric.
    scaled = compare_with_baseline([_record(ref, var, renders[0] * 1.1, test_var=tvar)], base)
    failed = {f.what for f in scaled if f.failed}
    assert {"relmse", "mae", "rmse", "ztest"} <= failed
    table = format_findings(scaled)
    assert "relmse" in table and "FAIL" in table and "synthetic | algo | cfg | direct" in table


def test_missing_case_error_and_speed(synthetic):
    ref, var, renders, tvar = synthetic
    base = make_baseline([[_record(ref, var, renders[0], test_var=tvar),
                           _record(ref, var, renders[0], label="other", test_var=tvar)]],
                         suite="t", suite_file="t.toml", seeds=[0])
    now = [_record(ref, var, renders[0], test_var=tvar)]
    f = compare_with_baseline(now, base)
    assert [x.what for x in f if x.failed] == ["case"]          # 'other' is missing
    slow = [_record(ref, var, renders[0], test_var=tvar, ratio=50.0),
            _record(ref, var, renders[0], label="other", test_var=tvar, ratio=20.0)]
    f = compare_with_baseline(slow, base)
    assert [(x.case.split(" | ")[2], x.what) for x in f if x.failed] == [("cfg", "speed ratio")]
    broken = [dataclasses.replace(now[0], error="RuntimeError: boom"),
              dataclasses.replace(now[0], label="other")]
    f = compare_with_baseline(broken, base)
    assert [(x.what, x.now) for x in f if x.failed] == [("case", "error")]


def test_bad_baseline_file_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "b.json"
    bad.write_text("{not json")
    with pytest.raises(BaselineError, match="malformed baseline JSON"):
        read_baseline(bad)
    assert cli.main(["check", "--baseline", str(tmp_path / "none.json")]) == 2
    assert "baseline file not found" in capsys.readouterr().err


def _suite(tmp_path, name, spp):
    return raycast_suite(tmp_path / f"{name}.toml", "checktest", ["spheres/lit_sphere.xml"],
                         spp=spp, light_samples=4, expect="ztest", reference_spp=1024,
                         reference_passes=8)


@pytest.mark.mitsuba
def test_check_cli_unchanged_passes_broken_parameter_fails(tmp_path, capsys, mitsuba):
    good = _suite(tmp_path, "good", 16)
    results, db = tmp_path / "out" / "results.jsonl", tmp_path / "h.sqlite"
    common = ["--results", str(results), "--history", str(db), "--no-progress",
              "--no-mitsuba-timing"]
    base = tmp_path / "baseline.json"
    assert cli.main(["baseline", str(good), "--out", str(base), "--seeds", "2", *common]) == 0
    doc = json.loads(base.read_text())
    (entry,) = doc["cases"].values()
    assert entry["ztest_passed"] is True and entry["metrics"]["relmse"] > 0
    assert doc["seeds"] == [0, 1] and entry["spread"]["relmse"][0] <= entry["spread"]["relmse"][1]
    capsys.readouterr()

    report = tmp_path / "check" / "report.html"
    assert cli.main(["check", str(good), "--baseline", str(base), "--report", str(report),
                     *common]) == 0
    out = capsys.readouterr().out
    assert "nothing moved" in out and "check passed" in out
    assert not (report.parent / "evidence").exists()

    # A broken parameter: 2x2 strata instead of 4x4 (same case label).
    broken = _suite(tmp_path, "broken", 4)
    assert cli.main(["check", str(broken), "--baseline", str(base), "--report", str(report),
                     *common]) == 1
    out = capsys.readouterr().out
    assert "check FAILED" in out
    summary = json.loads((report.parent / "check.json").read_text())
    assert not summary["passed"] and any(f["what"] == "relmse" and f["failed"]
                                         for f in summary["findings"])
    failing = [line for line in out.splitlines() if line.rstrip().endswith("FAIL")
               or "FAIL  (" in line]
    assert any(" relmse " in line for line in failing), out
    (ev,) = (report.parent / "evidence").iterdir()
    for name in ("own.exr", "reference.exr", "reference_variance.exr", "error.exr",
                 "pvalue.exr", "own_variance.exr"):
        assert (ev / name).is_file(), name
    from core.imageio import read_exr
    p = read_exr(ev / "pvalue.exr")
    assert p.min() >= 0 and p.max() <= 1 and (p < 1e-6).any()

    # Every run of baseline (seed 0) and check went into the history database.
    con = sqlite3.connect(db)
    cmds = [r[0] for r in con.execute("SELECT command FROM results ORDER BY id")]
    assert cmds == ["baseline", "check", "check"]
