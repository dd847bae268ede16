"""gibench warmup: every distinct built-in case of the suites renders once at a tiny
film size (numba compiles per argument type, so this fills the kernel cache);
external algorithms are skipped; a bad case is reported, not raised."""

import textwrap
from pathlib import Path

import pytest

from gibench import registry
from gibench.runner import warm_up

from test_cli import run_cli, small_scene

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "renderers.toml"


@pytest.fixture
def scenes(tmp_path, monkeypatch):
    """A folder with a small scene and one that fails to load, the registry without
    users' renderers (reset again afterwards)."""
    monkeypatch.delenv(registry.RENDERERS_ENV, raising=False)
    registry.reset()
    small_scene(tmp_path)
    (tmp_path / "broken.xml").write_text("<scene version='3.0.0'><shape type='nope'/></scene>")
    yield tmp_path
    registry.reset()


def test_warm_up_renders_each_builtin_case_once(scenes, capsys):
    manifest = scenes / "w.toml"
    manifest.write_text(textwrap.dedent(f"""
        [suite]
        name = "w"
        renderers = "{EXAMPLES}"
        [[group]]
        scenes = ["small.xml", "small.xml"]
        algorithm = "raycast"
        [[group.config]]
        params = {{ spp = 1 }}
        [[group.config]]
        params = {{ spp = "1" }}
        [[group]]
        scenes = ["small.xml"]
        algorithm = "mitsuba-direct"
        [[group]]
        scenes = ["broken.xml"]
        algorithm = "raycast"
        """))
    lines = []
    rows = warm_up([manifest], log=lines.append)
    # one raycast render (the four raycast cases have one scene and equal parsed params),
    # none for the external renderer, one failed scene
    assert [(r["scene"], r["algorithm"]) for r in rows] == [("small", "raycast"), ("broken", "raycast")]
    assert rows[0]["error"] is None and rows[0]["seconds"] > 0
    assert "unsupported" in rows[1]["error"] and len(lines) == 2
    code, out, _ = run_cli(capsys, "warmup", manifest)
    assert code == 1 and "warmup: 2 renders" in out and "1 failed" in out


def test_warm_up_in_worker_processes_renders_the_same_cases(scenes, capsys):
    manifest = scenes / "w.toml"
    manifest.write_text(textwrap.dedent("""
        [suite]
        name = "w"
        [[group]]
        scenes = ["small.xml", "broken.xml"]
        algorithm = "raycast"
        [[group]]
        scenes = ["small.xml"]
        algorithm = "zbuffer"
        """))
    serial = warm_up([manifest], log=None)
    lines = []
    parallel = warm_up([manifest], log=lines.append, jobs=2)
    key = lambda rows: sorted((r["scene"], r["algorithm"], r["error"] is None) for r in rows)
    assert key(parallel) == key(serial) == [("broken", "raycast", False), ("small", "raycast", True),
                                            ("small", "zbuffer", True)]
    assert len(lines) == 3
    code, out, _ = run_cli(capsys, "warmup", manifest, "--jobs", "2")
    assert code == 1 and "warmup: 3 renders" in out and "(2 processes)" in out and "1 failed" in out


def test_tile_tracers_of_one_precision_warm_up_in_one_task_other_precisions_first():
    """raycast and whitted share most kernels: at one precision they are one task (one
    process, whitted first, so raycast loads the shared kernels from the cache); the
    float32 task, whose kernels no float64 task shares, is handed out first."""
    from gibench.runner import _warm_tasks

    pairs = {("path", "float64"), ("distributed", "float64"), ("whitted", "float64"),
             ("raycast", "float64"), ("radiosity", None), ("zbuffer", None), ("whitted", "float32"),
             ("raycast", "float32")}
    assert _warm_tasks(pairs) == [(("whitted", "raycast"), "float32"), (("path",), "float64"),
                                  (("distributed",), "float64"), (("whitted", "raycast"), "float64"),
                                  (("radiosity",), None), (("zbuffer",), None)]
    assert _warm_tasks({("raycast", "float32"), ("zbuffer", None)}) == [(("raycast",), "float32"),
                                                                         (("zbuffer",), None)]
