"""Tests for the results store (reports.results) and the HTML report (reports.html)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from core.imageio import write_exr
from core.records import Record
from reports.html import fmt, write_report
from reports.results import ResultStore, ResultStoreWarning, new_run_id


# --- results store ----------------------------------------------------------------------------

def _records(run_id):
    return [Record.from_json(r) for r in [
        {"run_id": run_id, "scene": "cornell/cornell_point", "algorithm": "raycast",
         "metrics": {"relmse": 1.5e-4, "psnr": math.inf, "nan_count": 0},
         "time": {"own_times_s": [0.1, 0.2, 0.3]}, "model_error": False, "error": None},
        {"run_id": run_id, "scene": "cornell/cornell_area", "algorithm": "pt", "metrics": {"bias": -math.inf},
         "label": "pt, 16 spp ✓"},
        {"run_id": run_id, "scene": "spheres/two", "algorithm": "pt", "image": "reports/out/a.exr"},
    ]]


def test_store_round_trip_keeps_inf_and_writes_strict_json(tmp_path):
    store = ResultStore(tmp_path / "results.jsonl", root=tmp_path)
    recs = _records("r1")
    for r in recs:
        store.append(r)
    assert store.load() == recs
    assert store.load()[0].metrics["psnr"] == math.inf
    assert store.load()[1].metrics["bias"] == -math.inf
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    assert len(lines) == 3
    for line in lines:  # strict JSON: no bare Infinity / NaN tokens
        json.loads(line, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))


def test_store_nan_and_numpy_values(tmp_path):
    store = ResultStore(tmp_path / "r.jsonl")
    store.append(Record(run_id="r", scene="s", algorithm="a", metrics={
        "x": float("nan"), "n": np.int64(3), "f": np.float32(0.5), "arr": np.array([1.0, np.inf])}))
    (rec,) = store.load()
    m = rec.metrics
    assert math.isnan(m["x"]) and m["n"] == 3 and m["f"] == 0.5 and m["arr"] == [1.0, math.inf]


def test_store_refuses_a_record_that_does_not_fit_the_schema(tmp_path):
    """A line with an unknown field, a field of the wrong type or a newer version is
    skipped with a warning naming file and line; the well-formed lines load."""
    path = tmp_path / "r.jsonl"
    store = ResultStore(path)
    store.append(Record(run_id="r", scene="s", algorithm="a"))
    with open(path, "a") as f:
        f.write(json.dumps({"run_id": "r", "scene": "s", "algorithm": "a", "metrcs": {}}) + "\n")
        f.write(json.dumps({"run_id": "r", "scene": "s", "algorithm": "a", "metrics": [1]}) + "\n")
        f.write(json.dumps({"run_id": "r", "scene": "s", "algorithm": "a", "version": 99}) + "\n")
    with pytest.warns(ResultStoreWarning) as caught:
        recs = store.load()
    assert [r.scene for r in recs] == ["s"]
    msgs = [str(w.message) for w in caught]
    assert any("r.jsonl:2" in m and "metrcs" in m for m in msgs)
    assert any("r.jsonl:3" in m and "'metrics' must be dict" in m for m in msgs)
    assert any("r.jsonl:4" in m and "version 99 is newer" in m for m in msgs)
    with pytest.raises(TypeError):
        store.append({"run_id": "r"})                        # a plain dict is not a record


def test_truncated_last_line_is_skipped_with_warning(tmp_path):
    path = tmp_path / "results.jsonl"
    store = ResultStore(path)
    recs = _records("r1")
    for r in recs[:2]:
        store.append(r)
    line = json.dumps({"run_id": "r1", "scene": "x", "algorithm": "y", "metrics": {"mse": 1.0}})
    with open(path, "a") as f:  # a crash in the middle of writing the third record
        f.write(line[: len(line) // 2])
    with pytest.warns(ResultStoreWarning, match=r"results\.jsonl:3"):
        loaded = store.load()
    assert loaded == recs[:2]
    # A later append must not be glued onto the broken line: the new record survives.
    store.append(recs[2])
    with pytest.warns(ResultStoreWarning, match=r"results\.jsonl:3: skipping malformed record"):
        assert store.load() == recs
    assert len(path.read_text().splitlines()) == 4


def test_load_filters_by_run_and_lists_runs(tmp_path):
    store = ResultStore(tmp_path / "results.jsonl")
    assert store.load() == [] and store.runs() == [] and store.latest_run_id() is None
    a, b = new_run_id(), new_run_id()
    assert a != b and re.fullmatch(r"\d{8}T\d{6}Z-[0-9a-f]{6}", a)
    for r in _records(a) + _records(b)[:1]:
        store.append(r)
    assert [r.scene for r in store.load(b)] == ["cornell/cornell_point"]
    assert len(store.load(a)) == 3 and store.load("nope") == []
    assert store.runs() == [a, b] and store.latest_run_id() == b


def test_resolve_and_relative(tmp_path):
    store = ResultStore(tmp_path / "r.jsonl", root=tmp_path)
    assert store.resolve("reports/out/x.exr") == tmp_path / "reports/out/x.exr"
    assert store.relative(tmp_path / "a" / "b.exr") == "a/b.exr"
    assert ResultStore("r.jsonl").resolve("reports").is_dir()  # default root is the repository


# --- HTML report ------------------------------------------------------------------------------

def _full_record(run_id, scene, algorithm, ref, img, **kw):
    rec = {
        "run_id": run_id, "suite": "cornell", "scene": scene, "scene_file": f"suites/{scene}.xml",
        "algorithm": algorithm, "label": f"{algorithm}, 4x4 stratified", "params": {"spp": 16},
        "transport": "direct",
        "reference": {"key": "abc123", "dir": "references/store/abc123", "image": ref, "variance": None,
                      "spp": 4096, "variant": "llvm_ad_rgb", "integrator": "direct"},
        "image": img, "variance": None,
        "metrics": {"mse": 1.2e-5, "rmse": 3.4e-3, "relmse": 2.345e-4, "mae": 0.0021, "bias": -1e-6,
                    "psnr": 48.71, "ssim": 0.9931, "flip": 0.01234, "delta_e2000": 0.5, "nan_count": 0,
                    "inf_count": 0, "noise_floor": 1e-4,
                    "ztest": {"passed": True, "fraction": 0.987, "significance": 0.001, "alpha": 0.01,
                              "min_fraction": 0.95, "n": 4096},
                    "conventions": {"flip": "LDR FLIP on tonemap_srgb exposure 1"}},
        "time": {"own_median_s": 0.5, "own_times_s": [0.49, 0.5, 0.52], "compile_s": 3.1,
                 "mitsuba_median_s": 0.2, "mitsuba_spp": 16, "ratio": 2.5},
        "counters": {"camera_rays": 65536, "shadow_rays": 131072},
        "checks": [{"name": "Z-test vs Mitsuba direct", "expected": "pass", "passed": True, "detail": "98.7%"}],
        "model_error": False, "error": None,
        "versions": {"mitsuba": "3.6.4", "numpy": "2.1"}, "commit": "deadbeef",
        "machine": {"cpu": "2-core"}, "created": "2026-11-23T16:30:00Z",
    }
    rec.update(kw)
    return Record.from_json(rec)


@pytest.fixture
def report_records(tmp_path):
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 2.0, (16, 24, 3)).astype(np.float32)
    write_exr(tmp_path / "references/store/abc123/image.exr", ref)
    write_exr(tmp_path / "reports/out/runs/r1/raycast.exr", ref * 1.05)
    write_exr(tmp_path / "reports/out/runs/r1/pt.exr", ref + np.float32(np.nan) * (rng.uniform(size=ref.shape) < 0.01))
    refrel = "references/store/abc123/image.exr"
    return [
        _full_record("r1", "cornell/cornell_point", "raycast", refrel, "reports/out/runs/r1/raycast.exr"),
        _full_record("r1", "cornell/cornell_point", "pt", refrel, "reports/out/runs/r1/pt.exr",
                     transport="full", model_error=True),
        _full_record("r1", "spheres/two_spheres", "raycast", refrel, "reports/out/runs/r1/gone.exr"),
        _full_record("r1", "spheres/broken", "whitted", refrel, None,
                     error="RuntimeError: kernel launch failed <bad>", metrics={}, time={}),
        Record(scene="spheres/minimal", algorithm="pt", time={"ratio": None}),
    ]


def test_report_is_self_contained_and_complete(tmp_path, report_records):
    out = write_report(report_records, tmp_path / "out" / "report.html", root=tmp_path, title="Test <report>")
    assert out == tmp_path / "out" / "report.html"
    assert [p.name for p in out.parent.iterdir()] == ["report.html"]  # no temp file left behind
    text = out.read_text(encoding="utf-8")
    srcs = re.findall(r"""\b(?:src|href)\s*=\s*["']?([^"'\s>]*)""", text, flags=re.I)
    assert srcs and all(s.startswith(("data:", "#")) for s in srcs), srcs
    assert "http" not in "".join(srcs) and "url(" not in text and "@import" not in text
    # two reference + two own images and two error maps rendered from the EXRs
    assert len(re.findall(r'class="im" src="data:image/png;base64,', text)) >= 5
    for scene in ("cornell/cornell_point", "spheres/two_spheres", "spheres/broken", "spheres/minimal"):
        assert scene in text
    assert "2.5" in text and "Test &lt;report&gt;" in text
    assert "RuntimeError: kernel launch failed &lt;bad&gt;" in text
    assert "missing own image file: reports/out/runs/r1/gone.exr" in text
    assert "model error (reported, not judged)" in text
    assert "warm-up excluded; medians of 3 repeats; 2-core shared machine: compare ratios" in text
    assert "deadbeef" in text and "98.7%" in text and "LDR FLIP on tonemap_srgb exposure 1" in text


def test_report_missing_reference_and_empty(tmp_path):
    recs = [Record(scene="a/b", algorithm="x", reference={"image": "nope/ref.exr"}, image="nope/own.exr",
                   metrics={"relmse": "inf", "ztest": {"fraction": None}}, counters={}, checks=[None])]
    text = write_report(recs, tmp_path / "r.html", root=tmp_path).read_text()
    assert "missing reference image file: nope/ref.exr" in text and "a/b" in text
    assert "<h2>Summary</h2>" in write_report([], tmp_path / "e.html", root=tmp_path).read_text()


@pytest.mark.parametrize("x, s", [(None, "—"), (2.5, "2.5"), (0.012345, "0.01235"), (1.5e-5, "1.500e-05"),
                                  (48.7123, "48.71"), (12345.6, "12346"), (0, "0"), (65536, "65,536"),
                                  (math.inf, "inf"), (True, "yes")])
def test_fmt(x, s):
    assert fmt(x) == s


def test_study_records_become_tables_and_plots(tmp_path):
    rows = [{"mode": m, "triangles": t, "error": e / t ** 0.5, "time": 1e-3 * t}
            for m, e in (("flat", 1.0), ("phong", 0.2)) for t in (10, 100, 1000)]
    pivot = {"index": ["mode"], "columns": "triangles", "values": ["error"],
             "plots": [{"x": "triangles", "y": ["error", "time"], "series": ["mode"], "logx": True}]}
    study = Record(kind="study", study="shading", title="Shading error", description="d",
                   rows=rows, pivot=pivot, run_id="r1")
    page = write_report([study], tmp_path / "r.html", root=tmp_path).read_text()
    assert "<h2>Studies</h2>" in page and "Shading error" in page
    assert "triangles = 1,000" in page                       # the pivot's columns
    assert page.count("data:image/png;base64,") == 1          # one figure, two panels
    assert "<h2>Summary</h2>" not in page                     # no render records
    bare = Record(**{**study.to_json(), "pivot": {}})         # no layout: every row, every key
    page = write_report([bare], tmp_path / "b.html", root=tmp_path).read_text()
    table = page[page.index("<table class='data'>"):]
    assert table[:table.index("</table>")].count("<tr>") == len(rows) + 1


def test_speed_against_error_leads_the_report(tmp_path):
    from reports.html import render_report

    recs = [Record(kind="ladder", scene="s", transport="full", label=f"Mitsuba {n}", ladder_spp=n,
                   params={"spp": n, "sampler": "multijitter"},
                   metrics={"relmse": 0.1 / n, "relmse_seeds": [0.09 / n, 0.1 / n, 0.11 / n]},
                   time={"own_median_s": 0.01 * n}) for n in (1, 4, 16, 64)]
    for algo, err in (("raycast", 0.3), ("path", 0.004)):
        for seed in (0, 1, 2):
            recs.append(Record(kind="case", scene="s", transport="full", algorithm=algo,
                               label=f"{algo} 4", seed=seed, params={"spp": 4},
                               metrics={"relmse": err * (1 + 0.1 * seed)},
                               time={"own_median_s": 0.05}))
            recs.append(Record(kind="case", scene="s", transport="full", algorithm=algo,
                               label=f"{algo} 16", seed=seed, params={"spp": 16},
                               metrics={"relmse": err / 3 * (1 + 0.1 * seed)},
                               time={"own_median_s": 0.2}))
    page = render_report(recs, root=tmp_path)
    head = page.index("Speed against error")
    assert head < page.index("<h2>Summary</h2>")
    assert "multijitter" in page[head:page.index("<h2>Summary</h2>")]
    assert "Model error floors" in page
    # Extra seeds feed the means only: the summary shows one row per configuration.
    summary = page[page.index("<h2>Summary</h2>"):page.index("<h2>Timing</h2>")]
    assert summary.count("<tr>") == 1 + 4
