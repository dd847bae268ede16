"""``gibench sweep``: a parameter grid of any registered algorithm, Mitsuba's spp ladder
in the same run, the speed-vs-error table and report section."""

import pytest

from gibench import cli, registry
from core.provenance import REPO_ROOT
from gibench.registry import ParamError
from gibench.sweep import parse_grid, sweep_suite
from reports.results import ResultStore

SUITES = REPO_ROOT / "suites"

SCENE = REPO_ROOT / "suites" / "spheres" / "lit_sphere.xml"


def test_grid_is_checked_against_the_parameter_table():
    algo = registry.get("raycast")
    grid = parse_grid(["spp=1,4", "light_samples=2"], algo)
    assert grid == {"spp": [1, 4], "light_samples": [2]}
    suite = sweep_suite(SCENE, algo, grid, ladder="1,4")
    assert [c.params for c in suite.cases] == [{"spp": 1, "light_samples": 2},
                                              {"spp": 4, "light_samples": 2}]
    assert suite.ladder == (1, 4) and {c.transport for c in suite.cases} == {"direct"}
    with pytest.raises(ParamError, match="unknown parameter 'nope'.*valid: spp"):
        parse_grid(["nope=1"], algo)
    with pytest.raises(ParamError, match="expects int"):
        parse_grid(["spp=1,two"], algo)
    with pytest.raises(ParamError, match="at least one"):
        parse_grid([], algo)
    # Any algorithm's table works, strings and choices included.
    zb = parse_grid(["shading=flat,phong", "tessellation=8,16"], registry.get("zbuffer"))
    assert len(sweep_suite(SCENE, registry.get("zbuffer"), zb).cases) == 4
    with pytest.raises(ParamError, match="must be one of"):
        parse_grid(["shading=toon"], registry.get("zbuffer"))


@pytest.mark.mitsuba
def test_sweep_cli_writes_table_report_and_ladder(tmp_path, capsys, mitsuba):
    results = tmp_path / "results.jsonl"
    report = tmp_path / "sweep.html"
    rc = cli.main(["sweep", str(SCENE), "--algorithm", "raycast", "--grid", "spp=1,4,16",
                   "--transport", "direct", "--ladder", "1,4,16,64", "--repeats", "1",
                   "--results", str(results), "--report", str(report), "--history",
                   str(tmp_path / "h.sqlite"), "--no-mitsuba-timing", "--no-progress"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "spp=1" in out and "spp=16" in out and "Mitsuba direct 64 spp" in out
    assert "own best: equal-error time ratio" in out
    # The race to Mitsuba's top rung, its cases and ladder timed in the same rounds.
    assert "to Mitsuba's 64-spp error" in out and "paired rounds" in out
    recs = ResultStore(results).load()
    assert len({r.time["timing_group"] for r in recs}) == 1
    cases = [r for r in recs if r.kind == "case"]
    ladder = [r for r in recs if r.kind == "ladder"]
    assert len(cases) == 3 and [r.ladder_spp for r in ladder] == [1, 4, 16, 64]
    # More samples, less error: both for the own strata and for Mitsuba's ladder.
    own = [r.metrics["relmse"] for r in cases]
    mi = [r.metrics["relmse"] for r in ladder]
    assert own[0] > own[1] > own[2] and mi[0] > mi[-1]
    assert all(r.metrics["noise_floor_relmse"] < min(own) for r in cases)
    page = report.read_text()
    assert "Speed vs error" in page and "class='pareto'" in page and "pareto-table" in page


def test_sweep_rejects_missing_scene(tmp_path, capsys):
    assert cli.main(["sweep", str(tmp_path / "none.xml"), "--algorithm", "raycast",
                     "--grid", "spp=1", "--no-history"]) == 2
    assert "scene file not found" in capsys.readouterr().err


def test_full_transport_cases_take_the_files_max_depth():
    """The full-transport reference renders the file's ``path`` max_depth, so a suite's,
    a sweep's and a leaderboard's own ``path`` cases take it too (unless the case sets
    one); other transports and algorithms without Mitsuba's max_depth are left alone."""
    from gibench.leaderboard import leaderboard_suite
    from gibench.suite import load_suite

    suite = load_suite(SUITES / "default.toml")
    paths = [c for c in suite.cases if c.algorithm == "path"]
    assert paths and all(c.params["max_depth"] == 8 for c in paths)      # cornell_box.xml: 8
    assert all("max_depth" not in c.params for c in suite.cases if c.algorithm == "raycast")
    sw = sweep_suite(SUITES / "spheres" / "glass_sphere.xml", registry.get("path"), {"spp": [4]})
    assert sw.cases[0].params["max_depth"] == 11
    sw = sweep_suite(SUITES / "spheres" / "glass_sphere.xml", registry.get("path"), {"spp": [4]},
                     base_params={"max_depth": 3})
    assert sw.cases[0].params["max_depth"] == 3
    lb = leaderboard_suite(SUITES / "cornell" / "cornell_box.xml", algorithms=["path", "whitted"])
    assert {c.algorithm: c.params.get("max_depth") for c in lb.cases}["path"] == 8
