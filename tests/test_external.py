"""Algorithms from outside gibench: a Python package registered through the
``gibench.algorithms`` entry point group, and executables driven by the
``command`` adapter.  Both go through ``gibench run``, ``baseline``, ``check``,
``history`` and ``dashboard`` like a built-in; bad plugins and failing
executables give one-line errors naming them."""

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from core.errors import GibenchError
from core.imageio import read_exr
from core.loader import load_scene
from gibench import registry
from gibench.external import ExternalRendererError, run_command, _generic_spec
from reports.results import ResultStore

from test_cli import one_line_error, run_cli, small_scene

REPO = Path(__file__).resolve().parent.parent
EXAMPLE_RENDERERS = REPO / "examples" / "renderers.toml"


@pytest.fixture(autouse=True)
def fresh_registry(monkeypatch):
    """Each test starts from the built-ins and leaves no plugin behind."""
    monkeypatch.delenv(registry.RENDERERS_ENV, raising=False)
    registry.reset()
    yield
    registry.reset()


# --- an example plugin package, installed by a dist-info folder on sys.path --------------------

PLUGIN = '''
"""A user's algorithm package: gibench's ray caster under a name of its own."""
from core.algorithm import Algorithm, Param
from impl.raycast import ALGORITHM as _RC

ALGORITHM = Algorithm(name="my-raycast", summary="a user's ray caster (wraps raycast)",
                      section="plugin", params=_RC.params, render=_RC.render,
                      transport="direct")
'''


def install_package(root: Path, name: str, entry_points: str, code: str, version="1.2.3"):
    """Write package ``name`` and its ``name-version.dist-info`` (METADATA,
    entry_points.txt) under ``root``: importlib.metadata finds it on sys.path."""
    (root / name).mkdir(parents=True)
    (root / name / "__init__.py").write_text(code)
    di = root / f"{name}-{version}.dist-info"
    di.mkdir()
    (di / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (di / "entry_points.txt").write_text(entry_points)


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    site = tmp_path / "site"
    install_package(site, "mytracer", "[gibench.algorithms]\nmy-raycast = mytracer:ALGORITHM\n",
                    PLUGIN)
    monkeypatch.syspath_prepend(str(site))
    registry.reset()
    return site


def suite_file(tmp_path, algorithm, params, *, transport="direct", extra_head=""):
    small_scene(tmp_path)
    p = tmp_path / f"{algorithm}.toml"
    p.write_text(textwrap.dedent(f"""
        [suite]
        name = "byo-{algorithm}"
        reference_spp = 256
        reference_passes = 8
        repeats = 1
        {extra_head}
        [[group]]
        scenes = ["small.xml"]
        algorithm = "{algorithm}"
        transport = "{transport}"
        [[group.config]]
        label = "{algorithm} external"
        params = {params}
        expect = "ztest"
        """))
    return p


def run_check_cycle(tmp_path, capsys, manifest, algorithm, *pre):
    """run, baseline (2 seeds), check, history, dashboard; returns the run's records."""
    results = tmp_path / "out" / "results.jsonl"
    store = tmp_path / "store"
    common = ["--results", results, "--store", store, "--no-progress"]
    code, out, err = run_cli(capsys, *pre, "run", manifest, *common)
    assert code == 0, out + err
    records = [r for r in ResultStore(results).load() if r.kind == "case"]
    assert len(records) == 1 and records[0].algorithm == algorithm
    rec = records[0]
    assert rec.error is None and rec.metrics["ztest"]["passed"], rec
    assert rec.time["mitsuba_median_s"] > 0
    report = (tmp_path / "out" / "report.html").read_text()
    assert f"{algorithm} external" in report
    base = tmp_path / "base.json"
    code, out, err = run_cli(capsys, *pre, "baseline", manifest, "--out", base, "--seeds", 2,
                             "--no-mitsuba-timing", *common)
    assert code == 0, out + err
    assert algorithm in base.read_text()
    code, out, err = run_cli(capsys, *pre, "check", manifest, "--baseline", base,
                             "--no-mitsuba-timing", *common)
    assert code == 0 and "check passed" in out, out + err
    code, out, err = run_cli(capsys, "history", "--algorithm", algorithm,
                             "--history", tmp_path / "out" / "history.sqlite")
    assert code == 0
    rows = [ln for ln in out.splitlines() if algorithm in ln]
    assert len(rows) == 3, out            # run, baseline (seed 0 is stored), check
    code, out, err = run_cli(capsys, "dashboard", "--out", tmp_path / "dash.html",
                             "--history", tmp_path / "out" / "history.sqlite",
                             "--benchmarks", tmp_path / "none")
    assert code == 0 and "3 results from 3 runs" in (tmp_path / "dash.html").read_text()
    return rec


# --- entry points --------------------------------------------------------------------------------

def test_plugin_package_is_registered_with_its_distribution(plugin):
    algo = registry.get("my-raycast")
    assert algo.section == "plugin"
    o = registry.origin("my-raycast")
    assert o["source"] == "entry point" and o["dist"] == "mytracer" and o["dist_version"] == "1.2.3"
    assert registry.provenance("raycast") is None           # built-ins record nothing extra
    assert registry.provenance("my-raycast")["dist"] == "mytracer"


def test_plugin_package_goes_through_run_check_history_dashboard(plugin, tmp_path, capsys):
    manifest = suite_file(tmp_path, "my-raycast", "{ spp = 16, light_samples = 16 }")
    rec = run_check_cycle(tmp_path, capsys, manifest, "my-raycast")
    assert rec.external["dist"] == "mytracer" and rec.external["dist_version"] == "1.2.3"
    code, out, _ = run_cli(capsys, "algorithms")
    assert "my-raycast" in out and "from mytracer" in out


@pytest.mark.parametrize("entry, code, cause", [
    ("bad = badplug:ALGORITHM", "raise ImportError('no module named numpyy')", "ImportError: no module named numpyy"),
    ("bad = badplug:ALGORITHM", "ALGORITHM = 42", "gives a int, not a core.algorithm.Algorithm"),
    ("bad = badplug", "X = 1", "declares no ALGORITHM"),
    ("bad = badplug:ALGORITHM",
     "from impl.raycast import ALGORITHM", "algorithm name 'raycast' is taken by builtin"),
])
def test_broken_plugin_gives_one_line_error_naming_it(tmp_path, monkeypatch, capsys, entry, code, cause):
    install_package(tmp_path / "site", "badplug", f"[gibench.algorithms]\n{entry}\n", code)
    monkeypatch.delitem(sys.modules, "badplug", raising=False)
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    registry.reset()
    assert registry.get("raycast").name == "raycast"          # the others still load
    rc, out, err = run_cli(capsys, "render", small_scene(tmp_path), "-a", "bad", "-o", tmp_path / "x.exr")
    line = one_line_error(rc, err)
    assert "plugin 'bad'" in line and "badplug" in line and cause in line, line
    rc, out, err = run_cli(capsys, "algorithms")
    assert rc == 0 and "BROKEN plugin bad" in out


# --- the command adapter ---------------------------------------------------------------------------

SCRIPT = '''
import sys
sys.path.insert(0, {repo!r})
import numpy as np
from core.imageio import write_exr
mode, out, w, h = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
if mode == "fail":
    print("loading scene", file=sys.stderr)
    print("fatal: cannot parse <bsdf type=foo>", file=sys.stderr)
    sys.exit(3)
if mode == "nothing":
    sys.exit(0)
img = np.full((h, w, 3), 0.25, np.float32)
if mode == "small":
    img = img[: h // 2]
if mode == "nan":
    img[1, 2, 0] = np.nan
write_exr(out, img)
'''


@pytest.fixture
def script(tmp_path):
    p = tmp_path / "tiny_renderer.py"
    p.write_text(SCRIPT.format(repo=str(REPO)))
    return p


def _cmd(script, mode):
    return f"{{python}} {script} {mode} {{out}} {{width}} {{height}}"


def test_command_renders_and_times_the_process(tmp_path, script):
    scene = load_scene(small_scene(tmp_path))
    res = run_command(_generic_spec({"cmd": _cmd(script, "ok"), "timeout": 60}), scene, spp=4, seed=0)
    assert res.image.shape == (24, 32, 3) and np.all(res.image == np.float32(0.25))
    assert res.variance is None and res.counters["process_s"] > 0


@pytest.mark.parametrize("mode, cause", [
    ("fail", "exited with status 3: loading scene | fatal: cannot parse <bsdf type=foo>"),
    ("nothing", "exited 0 but wrote no image"),
    ("small", "output image is 32x12, the scene's film is 32x24"),
    ("nan", "1 NaN and 0 Inf values (first at pixel x=2, y=1)"),
])
def test_command_failures_are_one_line_errors(tmp_path, capsys, script, mode, cause):
    rc, out, err = run_cli(capsys, "render", small_scene(tmp_path), "-a", "command", "--set",
                           f"cmd={_cmd(script, mode)}", "--repeats", 1, "-o", tmp_path / "x.exr")
    line = one_line_error(rc, err)
    assert cause in line, line


def test_command_argument_errors(tmp_path, capsys, script):
    scene = small_scene(tmp_path)
    for cmd, cause in [("no_such_renderer_xyz {scene} {out}", "executable not found: 'no_such_renderer_xyz'"),
                       ("{python} x.py {scene} {out} {output}", "unknown placeholder {output}"),
                       ("{python} x.py {scene}", "cmd must name {out}"),
                       ("", "parameter 'cmd' is required")]:
        rc, _, err = run_cli(capsys, "render", scene, "-a", "command", "--set", f"cmd={cmd}",
                             "--repeats", 1, "-o", tmp_path / "x.exr")
        assert cause in one_line_error(rc, err)
    rc, _, err = run_cli(capsys, "render", scene, "-a", "command", "--set", f"cmd={_cmd(script, 'ok')}",
                         "-D", "spp=4", "-o", tmp_path / "x.exr")
    assert "cannot reach an external renderer" in one_line_error(rc, err)


def test_renderer_file_errors(tmp_path, capsys):
    bad = tmp_path / "r.toml"
    for text, cause in [("[renderer.x]\nversion_cmd = 'v'\n", "[renderer.x]: missing 'cmd'"),
                        ("[renderer.x]\ncmd = 'r {out}'\ncolour = 1\n", "unknown keys colour"),
                        ("[renderer.x]\ncmd = 'r {out}'\ntransport = 'fancy'\n", "transport must be one of"),
                        ("[renderer.raycast]\ncmd = 'r {out}'\n", "'raycast' is taken by builtin")]:
        bad.write_text(text)
        registry.reset()
        rc, _, err = run_cli(capsys, "--renderers", bad, "algorithms")
        assert cause in one_line_error(rc, err)


@pytest.mark.mitsuba
def test_mitsuba_as_external_renderer_through_run_and_check(tmp_path, capsys):
    """The worked example: examples/mitsuba_cli.py, declared in examples/renderers.toml,
    renders Mitsuba's direct integrator as an external process; it must pass the
    Z-test against gibench's own Mitsuba direct reference and go through the gate."""
    manifest = suite_file(tmp_path, "mitsuba-direct", "{ spp = 64 }",
                          extra_head=f'renderers = "{EXAMPLE_RENDERERS}"')
    rec = run_check_cycle(tmp_path, capsys, manifest, "mitsuba-direct")
    ext = rec.external
    assert ext["source"] == "renderer file" and ext["version"].startswith("mitsuba 3.")
    assert rec.counters["process_s"] > 0 and rec.variance
    assert read_exr(REPO / rec.variance if not Path(rec.variance).is_absolute()
                    else rec.variance).shape == (24, 32, 3)


@pytest.mark.mitsuba
def test_generic_command_with_jobs(tmp_path, capsys):
    """The generic ``command`` algorithm from a manifest, in 2 worker processes (spawned:
    the renderer file reaches them through GIBENCH_RENDERERS)."""
    small_scene(tmp_path)
    cmd = (f"{{python}} {REPO / 'examples' / 'mitsuba_cli.py'} {{scene}} {{out}} --variance {{variance}} "
           "--spp {spp} --seed {seed} --passes 8 --integrator direct")
    manifest = tmp_path / "g.toml"
    manifest.write_text(textwrap.dedent(f"""
        [suite]
        name = "generic"
        reference_spp = 256
        repeats = 1
        renderers = "{EXAMPLE_RENDERERS}"
        [[group]]
        scenes = ["small.xml"]
        algorithm = "command"
        transport = "direct"
        [[group.config]]
        params = {{ cmd = {json.dumps(cmd)}, version_cmd = "mitsuba_version_cmd_unused", spp = 32 }}
        expect = "report"
        [[group]]
        scenes = ["small.xml"]
        algorithm = "mitsuba-direct"
        [[group.config]]
        params = {{ spp = 64 }}
        expect = "ztest"
        """))
    results = tmp_path / "out" / "results.jsonl"
    code, out, err = run_cli(capsys, "run", manifest, "--results", results, "--store", tmp_path / "store",
                             "--jobs", 2, "--no-mitsuba-timing", "--no-progress")
    recs = {r.algorithm: r for r in ResultStore(results).load()}
    # The generic case names a version command that does not exist: its record says so.
    assert "version_cmd" in recs["command"].error and "not found" in recs["command"].error
    assert recs["mitsuba-direct"].error is None and recs["mitsuba-direct"].checks[0]["passed"]
    assert code == 1                       # the failed case fails the run


def test_command_through_sweep(tmp_path, capsys, script):
    """``gibench sweep`` over a command renderer's parameter (here the generic ``command``
    and its spp): one record per grid point, each with the process timed."""
    scene = small_scene(tmp_path)
    results = tmp_path / "out" / "results.jsonl"
    code, out, err = run_cli(capsys, "sweep", scene, "-a", "command", "--set", f"cmd={_cmd(script, 'ok')}",
                             "--grid", "spp=1,4", "--transport", "direct", "--reference-spp", 64,
                             "--reference-passes", 4, "--repeats", 1, "--ladder", "", "--results", results,
                             "--store", tmp_path / "store", "--no-mitsuba-timing", "--no-progress")
    assert code == 0, out + err
    recs = [r for r in ResultStore(results).load() if r.kind == "case"]
    assert sorted(r.params["spp"] for r in recs) == [1, 4]
    assert all(r.error is None and r.counters["process_s"] > 0 for r in recs)
    assert all(r.external["source"] == "command adapter" for r in recs)
