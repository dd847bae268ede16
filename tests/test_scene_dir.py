"""``gibench run --scenes DIR``: a directory of arbitrary Mitsuba scene files is
run file by file; each either renders and is compared with a Mitsuba ``direct``
reference rendered on demand, or is listed as skipped with its one-line reason,
and no bad file stops the run."""

import json
from pathlib import Path

import pytest

from core.records import Record
from gibench.cli import main

CAMERA = '''
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 2, 6" target="0, 0.7, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/>
            <rfilter type="box"/></film>
    </sensor>'''
SPHERE = '''
    <shape type="sphere"><point name="center" value="0, 0.8, 0"/><float name="radius" value="0.8"/>
        <bsdf type="{bsdf}"/></shape>'''


def _write(d: Path, name: str, text: str) -> None:
    (d / name).write_text(text)


def _scene_dir(d: Path) -> Path:
    d.mkdir()
    light = '<emitter type="point"><point name="position" value="2, 4, 3"/><rgb name="intensity" value="20"/></emitter>'
    _write(d, "a_good.xml", f'<scene version="3.0.0">{CAMERA}{light}{SPHERE.format(bsdf="diffuse")}\n'
                            '<emitter type="constant"><rgb name="radiance" value="0.3"/></emitter></scene>\n')
    _write(d, "b_malformed.xml", f'<scene version="3.0.0">{CAMERA}\n<shape type="sphere">\n</scene>\n')
    _write(d, "c_mask.xml", f'<scene version="3.0.0">{CAMERA}{light}\n<shape type="sphere">'
                            '<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="diffuse"/>'
                            '</bsdf></shape>\n</scene>\n')
    _write(d, "d_conductor.xml", f'<scene version="3.0.0">{CAMERA}{light}{SPHERE.format(bsdf="conductor")}'
                                 '</scene>\n')
    _write(d, "e_missing_mesh.xml", f'<scene version="3.0.0">{CAMERA}\n<shape type="obj">'
                                    '<string name="filename" value="gone.obj"/></shape></scene>\n')
    (d / "parts").mkdir()                      # sub-directories (include fragments) are not scenes
    _write(d / "parts", "fragment.xml", '<bsdf type="diffuse" version="3.0.0"/>\n')
    _write(d, "notes.txt", "not a scene\n")
    return d


@pytest.mark.mitsuba
def test_directory_run_renders_the_good_file_and_lists_the_others(tmp_path, capsys):
    d = _scene_dir(tmp_path / "scenes")
    results = tmp_path / "out" / "results.jsonl"
    code = main(["run", "--scenes", str(d), "--algorithm", "raycast", "--set", "spp=16",
                 "--set", "light_samples=16", "--store", str(tmp_path / "store"),
                 "--results", str(results), "--no-mitsuba-timing",
                 "--reference-spp", "256", "--passes", "4"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "1 rendered and compared, 0 failed checks, 4 skipped" in out
    skipped = {line.split(": ", 2)[1]: line.split(": ", 2)[2]
               for line in out.splitlines() if line.startswith("SKIPPED: ")}
    assert set(skipped) == {"b_malformed.xml", "c_mask.xml", "d_conductor.xml", "e_missing_mesh.xml"}
    assert "b_malformed.xml:" in skipped["b_malformed.xml"] and "malformed XML" in skipped["b_malformed.xml"]
    assert skipped["c_mask.xml"] == "raycast: shape 'sphere' uses 'mask', which raycast does not model"
    assert "'conductor' BSDF" in skipped["d_conductor.xml"]
    assert "mesh file 'gone.obj' not found" in skipped["e_missing_mesh.xml"]
    assert all("\n" not in r for r in skipped.values())
    # Every file has a record; the good one was compared with a reference rendered on demand.
    recs = [json.loads(line) for line in results.read_text().splitlines()]
    assert len(recs) == 5
    good = [r for r in recs if not r.get("error")]
    assert len(good) == 1 and good[0]["metrics"]["ztest"]["passed"]
    assert good[0]["transport"] == "direct"
    # Only the compared file got a reference: skipped files never reach Mitsuba.
    assert len([p for p in (tmp_path / "store").iterdir() if not p.name.startswith(".")]) == 1


def test_directory_run_needs_scene_files_and_valid_parameters(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code = main(["run", "--scenes", str(tmp_path / "empty"), "--results", str(tmp_path / "r.jsonl")])
    err = capsys.readouterr().err
    assert code == 2 and "no *.xml scene files" in err
    d = _scene_dir(tmp_path / "scenes")
    code = main(["run", "--scenes", str(d), "--set", "bogus=1", "--results", str(tmp_path / "r.jsonl")])
    assert code == 2 and "unknown parameter 'bogus'" in capsys.readouterr().err


def test_one_crashing_file_does_not_stop_the_run(tmp_path, monkeypatch):
    """Whatever a case raises (here an unexpected KeyError from the renderer), it
    becomes that file's skip reason and the next file still runs."""
    from gibench import scene_dir

    d = _scene_dir(tmp_path / "scenes")
    calls = []

    def fake_run_case(case, suite, **kw):
        calls.append(case.scene.name)
        if case.scene.name == "a_good.xml":
            raise KeyError("boom")
        return Record(scene=case.scene_id, error="SceneError: bad file")

    class Store(list):
        pass

    monkeypatch.setattr(scene_dir, "run_case", fake_run_case)
    monkeypatch.setattr(scene_dir, "preflight", lambda case, defines=None: None)
    suite = scene_dir.directory_suite(d, "raycast")
    records, skipped = scene_dir.run_directory(suite, Store(), run_id="t", out_root=tmp_path,
                                               log=lambda *a: None)
    assert calls == ["a_good.xml", "b_malformed.xml", "c_mask.xml", "d_conductor.xml",
                     "e_missing_mesh.xml"]
    assert skipped[0] == ("a_good.xml", "'boom'") and len(records) == 5


def test_directory_options_are_refused_for_a_suite_run(tmp_path, capsys):
    code = main(["run", "vocabulary", "--set", "spp=4", "--results", str(tmp_path / "r.jsonl")])
    err = capsys.readouterr().err
    assert code == 2 and "--set only apply with --scenes DIR" in err


def test_path_takes_the_files_max_depth_unless_set(tmp_path):
    """The reference renders a file's ``<integrator type="path">`` max_depth; a directory
    run of ``path`` takes it too (``--set max_depth`` wins), raycast has no such depth."""
    from gibench import scene_dir

    d = tmp_path / "scenes"
    d.mkdir()
    body = f'{CAMERA}{SPHERE.format(bsdf="diffuse")}</scene>\n'
    _write(d, "a_depth1.xml", '<scene version="3.0.0"><integrator type="path"><integer name="max_depth" '
                              f'value="1"/></integrator>{body}')
    _write(d, "b_direct.xml", f'<scene version="3.0.0"><integrator type="direct"/>{body}')
    cases = scene_dir.directory_suite(d, "path").cases
    assert [c.params for c in cases] == [{"max_depth": 1}, {}]
    cases = scene_dir.directory_suite(d, "path", {"max_depth": "3"}).cases
    assert [c.params for c in cases] == [{"max_depth": "3"}] * 2
    assert [c.params for c in scene_dir.directory_suite(d, "raycast").cases] == [{}, {}]
