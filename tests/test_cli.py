"""The command line end to end: one-line errors for bad input, render sidecars,
and a small suite run from scene files to the HTML report."""

import json
from pathlib import Path

import numpy as np
import pytest

from gibench.cli import main
from core.imageio import read_exr, write_exr
from reports.results import ResultStore

SUITES = Path(__file__).resolve().parent.parent / "suites"
LIT_SPHERE = SUITES / "spheres" / "lit_sphere.xml"


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err):
    assert code == 2, f"expected exit 2, got {code}"
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1, f"expected one line, got: {err!r}"
    assert lines[0].startswith("gibench: error: ")
    return lines[0]


def small_scene(tmp_path, name="small.xml", width=32, height=24, text=None):
    text = text or LIT_SPHERE.read_text()
    text = text.replace('name="width" value="160"', f'name="width" value="{width}"')
    text = text.replace('name="height" value="120"', f'name="height" value="{height}"')
    p = tmp_path / name
    p.write_text(text)
    return p


def test_algorithms_lists_raycast_with_parameters(capsys):
    code, out, _ = run_cli(capsys, "algorithms")
    assert code == 0
    assert "raycast" in out and "light_samples" in out and "thesis 1.3.3" in out


def test_render_writes_exr_and_sidecar(tmp_path, capsys):
    scene = small_scene(tmp_path)
    out = tmp_path / "img.exr"
    code, stdout, _ = run_cli(capsys, "render", scene, "--algorithm", "raycast", "--spp", 4,
                              "--set", "ks=0.2", "--repeats", 1, "--out", out)
    assert code == 0, stdout
    img = read_exr(out)
    assert img.shape == (24, 32, 3) and img.dtype == np.float32
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["params"]["spp"] == 4 and side["params"]["ks"] == 0.2
    assert side["counters"]["camera_rays"] == 32 * 24 * 4
    assert side["time"]["own_median_s"] > 0 and "compile_s" in side["time"]
    assert side["versions"]["numba"] and side["commit"]
    assert read_exr(out.with_suffix(".var.exr")).shape == img.shape


@pytest.mark.parametrize("body, expect", [
    ('<shape type="sphere">\n<float name="radius" value="1">\n</shape>', "malformed XML"),
    ('<shape type="linearcurve"/>', 'unsupported shape type \'linearcurve\''),
    ('<shape type="obj"><string name="filename" value="missing.obj"/></shape>', "missing.obj"),
])
def test_bad_scene_gives_one_line_error_naming_file_and_line(tmp_path, capsys, body, expect):
    scene = tmp_path / "bad.xml"
    scene.write_text('<scene version="3.0.0">\n<sensor type="perspective"><float name="fov" value="40"/></sensor>\n'
                     f"{body}\n</scene>\n")
    code, _, err = run_cli(capsys, "render", scene, "-a", "raycast", "--out", tmp_path / "x.exr")
    line = one_line_error(code, err)
    assert expect in line and f"{scene}:" in line
    assert not (tmp_path / "x.exr").exists()


def test_compare_refuses_nan_image_with_one_line(tmp_path, capsys):
    ref = np.ones((8, 8, 3), np.float32)
    bad = ref.copy()
    bad[2, 5, 1] = np.nan
    write_exr(tmp_path / "ref.exr", ref)
    write_exr(tmp_path / "bad.exr", bad)
    code, _, err = run_cli(capsys, "compare", tmp_path / "bad.exr", tmp_path / "ref.exr")
    line = one_line_error(code, err)
    assert "1 NaN" in line and "x=5, y=2" in line


def test_missing_image_and_unknown_algorithm(tmp_path, capsys):
    code, _, err = run_cli(capsys, "compare", tmp_path / "none.exr", tmp_path / "ref.exr")
    assert "no such image file" in one_line_error(code, err)
    code, _, err = run_cli(capsys, "render", LIT_SPHERE, "-a", "pathtracer", "--out", tmp_path / "x.exr")
    assert "unknown algorithm 'pathtracer'" in one_line_error(code, err)
    code, _, err = run_cli(capsys, "render", LIT_SPHERE, "-a", "raycast", "--set", "bogus=1",
                           "--out", tmp_path / "x.exr")
    assert "unknown parameter 'bogus'" in one_line_error(code, err)


@pytest.mark.mitsuba
def test_run_small_suite_end_to_end(tmp_path, capsys):
    """scene files → own render + Mitsuba reference → metrics → results store → report,
    with one broken case that must be recorded (not crash the run) and fail it."""
    scene = small_scene(tmp_path)
    broken = tmp_path / "broken.xml"
    broken.write_text(scene.read_text().replace('type="rectangle"', 'type="linearcurve"'))
    manifest = tmp_path / "small.toml"
    manifest.write_text("""
[suite]
name = "small"
reference_spp = 256
reference_passes = 8
repeats = 1

[[group]]
scenes = ["small.xml"]
algorithm = "raycast"
transport = "direct"
[[group.config]]
label = "4x4"
params = { spp = 16 }
expect = "ztest"
[[group.config]]
label = "centre"
params = { spp = 1 }
expect = "report"
tolerances = { relmse = 1.0 }

[[group]]
scenes = ["broken.xml"]
algorithm = "raycast"
""")
    results = tmp_path / "out" / "results.jsonl"
    code, out, err = run_cli(capsys, "run", manifest, "--results", results, "--store", tmp_path / "store")
    assert code == 1, out + err                 # the broken scene fails the run ...
    records = ResultStore(results).load()
    assert len(records) == 3                    # ... but every case is recorded
    ok, centre, bad = records
    assert ok.error is None and ok.checks[0]["passed"], ok.checks
    assert ok.metrics["ztest"]["passed"] and ok.time["mitsuba_median_s"] > 0
    assert ok.time["ratio"] == pytest.approx(ok.time["own_median_s"] / ok.time["mitsuba_median_s"])
    assert centre.checks and centre.checks[0]["name"].startswith("relmse")
    assert "unsupported shape type 'linearcurve'" in bad.error
    report = (tmp_path / "out" / "report.html").read_text()
    assert "small" in report and "unsupported shape type" in report
    # The references were stored and are reused by a second run (no new entries).
    entries = sorted(p.name for p in (tmp_path / "store").iterdir() if not p.name.startswith("."))
    assert len(entries) == 1
    code2, _, _ = run_cli(capsys, "report", "--results", results, "--out", tmp_path / "again.html")
    assert code2 == 0 and (tmp_path / "again.html").stat().st_size > 1000


@pytest.mark.mitsuba
def test_run_hard_writes_study_tables(tmp_path, capsys):
    """`gibench run hard`: the hard-case studies become records and report tables."""
    results = tmp_path / "results.jsonl"
    code, out, err = run_cli(capsys, "run", "hard", "--results", results)
    assert code == 0, out + err
    records = ResultStore(results).load()
    names = {r.study for r in records if r.kind == "study"}
    assert {"distant_sphere", "self_intersection", "grazing_sphere", "grazing_plane",
            "distant_sphere_mitsuba"} <= names
    ds = next(r for r in records if r.study == "distant_sphere")
    assert ds.pivot["columns"] == "distance" and len(ds.rows) > 50
    report = (tmp_path / "report.html").read_text()
    assert "Distant sphere silhouette" in report and "distance = 1.000e+12" in report
    assert "cells: wrong_frac / wrong_outside_band" in report
