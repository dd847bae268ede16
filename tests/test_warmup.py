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
    # one raycast render (the four raycast cases have one scene and equal parsed params)
    # and one of its kernel variant (eye-ray packets), none for the external renderer,
    # one failed scene
    assert registry.get("raycast").kernel_variants == ({"packets": True},)
    assert [(r["scene"], r["algorithm"], r.get("variant")) for r in rows] == [
        ("small", "raycast", None), ("small", "raycast", {"packets": True}), ("broken", "raycast", None)]
    assert rows[0]["error"] is None and rows[0]["seconds"] > 0 and rows[1]["error"] is None
    assert "unsupported" in rows[2]["error"] and len(lines) == 3
    assert lines[1].endswith(" s") and "+ packets=True" in lines[1]
    code, out, _ = run_cli(capsys, "warmup", manifest)
    assert code == 1 and "warmup: 3 renders" in out and "1 failed" in out


def test_a_kernel_variant_a_case_refuses_is_tried_on_the_next_case(scenes):
    """Packets need a tree to traverse: with the first case's accel=none the variant is
    refused (not reported), and the next case renders it, once."""
    manifest = scenes / "w.toml"
    manifest.write_text(textwrap.dedent("""
        [suite]
        name = "w"
        [[group]]
        scenes = ["small.xml"]
        algorithm = "raycast"
        [[group.config]]
        params = { spp = 1, accel = "none" }
        [[group.config]]
        params = { spp = 1 }
        [[group.config]]
        params = { spp = 4 }
        """))
    rows = warm_up([manifest], log=None)
    assert [(r.get("variant"), r["error"]) for r in rows] == [
        (None, None), (None, None), ({"packets": True}, None), (None, None)]


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
                                            ("small", "raycast", True), ("small", "zbuffer", True)]
    assert len(lines) == 4
    code, out, _ = run_cli(capsys, "warmup", manifest, "--jobs", "2")
    assert code == 1 and "warmup: 4 renders" in out and "(2 processes)" in out and "1 failed" in out


def test_tracers_on_the_shared_kernels_wait_for_the_ray_caster_of_their_precision():
    """The ray caster's kernels are most of what whitted, distributed and path compile: at
    each precision raycast is handed out first and those three wait for it (so that they
    load the shared kernels from the cache); the others do not wait; then the longest
    compiles first, a precision other than float64 before float64."""
    from gibench.runner import _warm_tasks

    pairs = {("path", "float64"), ("distributed", "float64"), ("whitted", "float64"),
             ("raycast", "float64"), ("radiosity", None), ("zbuffer", None), ("whitted", "float32"),
             ("raycast", "float32")}
    r32, r64 = ("raycast", "float32"), ("raycast", "float64")
    assert _warm_tasks(pairs) == [("raycast", "float32", None), ("raycast", "float64", None),
                                  ("whitted", "float32", r32), ("path", "float64", r64),
                                  ("distributed", "float64", r64), ("zbuffer", None, None),
                                  ("whitted", "float64", r64), ("radiosity", None, None)]
    # without a ray caster at that precision nothing waits
    assert _warm_tasks({("whitted", "float32"), ("zbuffer", None)}) == [("whitted", "float32", None),
                                                                         ("zbuffer", None, None)]