"""Hostile and careless input: each case is one trial of a user who feeds gibench
a bad file, a bad value or a bad command line.  The promise under test (README,
"Bad input"): one line ``gibench: error: <cause>`` naming the file and line where
there is one, exit status 2 — never a traceback, a hang, a crash or a silently
used bad value.  Every hostile file is written by the test itself.

The fuzz test (mutated scene files) is in tests/test_fuzz_scenes.py.
"""

from __future__ import annotations

import json
import re
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from core.errors import SceneError, SuiteError
from core.imageio import read_exr, write_exr
from core.loader import MAX_FILM_PIXELS, load_scene
from gibench.cli import main

ROOT = Path(__file__).resolve().parent.parent
SUITES = ROOT / "suites"
LIT_SPHERE = SUITES / "spheres" / "lit_sphere.xml"


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err) -> str:
    assert code == 2, f"expected exit 2, got {code}: {err!r}"
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("gibench: rendering")]
    assert len(lines) == 1, f"expected one line, got: {err!r}"
    assert lines[0].startswith("gibench: error: ")
    return lines[0]


def scene_with(tmp_path, old: str, new: str, name="s.xml", base=LIT_SPHERE) -> Path:
    text = base.read_text()
    assert old in text, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


def scene_error(path, **kw) -> str:
    """The loader's message for ``path``: a SceneError, one line, naming file:line."""
    with pytest.raises(SceneError) as info:
        load_scene(path, **kw)
    msg = str(info.value)
    assert "\n" not in msg
    assert re.search(r"\.(xml|obj|ply):\d+: ", msg), msg
    return msg


# ---------------------------------------------------------------- scene values ---

SPHERE_RADIUS = '<float name="radius" value="1"/>'
CAMERA_LOOKAT = '<lookat origin="0, 2, 6" target="0, 0.8, 0" up="0, 1, 0"/>'


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "0", "-1", "1e400"])
def test_sphere_radius_must_be_finite_and_positive(tmp_path, value):
    msg = scene_error(scene_with(tmp_path, SPHERE_RADIUS, f'<float name="radius" value="{value}"/>'))
    assert "radius" in msg or "finite" in msg


@pytest.mark.parametrize("op", ['<scale value="nan"/>', '<scale value="0"/>', '<scale x="1" y="0" z="1"/>',
                                '<translate value="inf, 0, 0"/>', '<rotate y="1" angle="nan"/>',
                                '<matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 nan"/>'])
def test_camera_transform_must_be_finite_and_invertible(tmp_path, op):
    """A NaN camera made own and Mitsuba images both black, and the Z-test passed."""
    scene_error(scene_with(tmp_path, CAMERA_LOOKAT, CAMERA_LOOKAT + op))


@pytest.mark.parametrize("fov", ["0", "180", "nan", "-5", "200"])
def test_fov_in_range(tmp_path, fov):
    assert "fov" in scene_error(scene_with(tmp_path, '<float name="fov" value="40"/>',
                                           f'<float name="fov" value="{fov}"/>')) or fov == "nan"


def test_spot_cutoff_nan_and_negative_reflectance_refused(tmp_path):
    spot = '<emitter type="spot"><float name="cutoff_angle" value="nan"/></emitter>'
    scene_error(scene_with(tmp_path, "</scene>", spot + "</scene>"))
    spot = '<emitter type="spot"><float name="cutoff_angle" value="0"/></emitter>'
    assert "cutoff_angle" in scene_error(scene_with(tmp_path, "</scene>", spot + "</scene>"))
    msg = scene_error(scene_with(tmp_path, '<rgb name="reflectance" value="0.5"/>',
                                 '<rgb name="reflectance" value="0.5, -0.1, 0.5"/>'))
    assert "reflectance" in msg and ">= 0" in msg


def test_non_integral_width_is_refused_not_truncated(tmp_path):
    msg = scene_error(scene_with(tmp_path, '<integer name="width" value="160"/>',
                                 '<float name="width" value="32.7"/>'))
    assert "width" in msg and "integer" in msg
    scene_error(scene_with(tmp_path, '<integer name="width" value="160"/>',
                           '<integer name="width" value="32.7"/>'))


def test_property_of_the_wrong_element_type(tmp_path):
    """<rgb name="radius"> and <string name="radius" value="abc"> were tracebacks."""
    msg = scene_error(scene_with(tmp_path, SPHERE_RADIUS, '<rgb name="radius" value="1, 2, 3"/>'))
    assert "'radius' must be given as <float> or <integer>, not <rgb>" in msg
    scene_error(scene_with(tmp_path, SPHERE_RADIUS, '<string name="radius" value="abc"/>'))
    scene_error(scene_with(tmp_path, '<point name="center" value="0, 1, 0"/>',
                           '<point name="center" x="abc"/>'))


def test_a_5000_digit_value_is_not_echoed_in_full(tmp_path):
    digits = "9" * 5000
    msg = scene_error(scene_with(tmp_path, '<integer name="width" value="160"/>',
                                 f'<integer name="width" value="{digits}"/>'))
    assert len(msg) < 400, len(msg)
    msg = scene_error(scene_with(tmp_path, SPHERE_RADIUS, f'<float name="radius" value="1{digits}"/>'))
    assert len(msg) < 400, len(msg)


def test_film_size_limit_on_both_sides(tmp_path, capsys):
    """-D width=100000 -D height=100000 was a MemoryError (own side) and a Dr.Jit error
    (reference side); both now refuse it at load, with the limit stated."""
    scene = scene_with(tmp_path, '<integer name="width" value="160"/>', '<integer name="width" value="$w"/>')
    msg = scene_error(scene, defines={"w": "100000"})
    assert "16384" in msg
    big = int(np.sqrt(MAX_FILM_PIXELS)) + 10
    scene2 = scene_with(tmp_path, '<integer name="height" value="120"/>',
                        '<integer name="height" value="$w"/>', name="s2.xml", base=scene)
    assert "pixels" in scene_error(scene2, defines={"w": str(big)})
    from references.reference import _check_film_size

    with pytest.raises(SceneError, match="outside gibench's limits"):
        _check_film_size(scene, {"w": "100000"})
    code, _, err = run_cli(capsys, "reference", scene, "-D", "w=100000", "--spp", 8, "--passes", 2)
    assert "limits" in one_line_error(code, err)


def test_xml_entities_and_external_entities_are_refused(tmp_path):
    bomb = ('<?xml version="1.0"?><!DOCTYPE scene [<!ENTITY a "aaaaaaaaaa">'
            '<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;"><!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>'
            '<scene version="3.0.0"><string name="x" value="&c;"/></scene>')
    (tmp_path / "bomb.xml").write_text(bomb)
    with pytest.raises(SceneError):
        load_scene(tmp_path / "bomb.xml")
    (tmp_path / "secret.txt").write_text("secret")
    xxe = ('<?xml version="1.0"?><!DOCTYPE scene [<!ENTITY x SYSTEM "secret.txt">]>'
           '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>'
           '<string name="fov_axis" value="&x;"/></sensor></scene>')
    (tmp_path / "xxe.xml").write_text(xxe)
    with pytest.raises(SceneError) as info:
        load_scene(tmp_path / "xxe.xml")
    assert "secret" not in str(info.value) or "entit" in str(info.value)


def test_include_fan_out_is_capped_quickly(tmp_path):
    """Ten includes per level, six levels (seven files, ~3 kB) expanded 10^6 files in
    166 s; the expansion limit refuses it at once."""
    for level in range(6):
        body = "".join(f'<include filename="l{level + 1}.xml"/>' for _ in range(10))
        (tmp_path / f"l{level}.xml").write_text(f'<scene version="3.0.0">{body}</scene>')
    (tmp_path / "l6.xml").write_text('<scene version="3.0.0"><bsdf type="diffuse"/></scene>')
    t0 = time.perf_counter()
    msg = scene_error(tmp_path / "l0.xml")
    assert "include" in msg and time.perf_counter() - t0 < 20
    from references.reference import scene_dependencies

    with pytest.raises(SceneError, match="include"):
        scene_dependencies(tmp_path / "l0.xml")


def test_one_resolver_for_loader_and_store(tmp_path):
    """The store's dependency scan and the loader share core.xmlscene: an unknown $name
    is refused by both (the store used to keep it), and so is a 16th nested include."""
    from references.reference import scene_dependencies

    scene = scene_with(tmp_path, SPHERE_RADIUS, '<float name="radius" value="$nope"/>')
    scene_error(scene)
    with pytest.raises(SceneError, match=r"\$nope"):
        scene_dependencies(scene)
    for level in range(17):
        (tmp_path / f"d{level}.xml").write_text(
            f'<scene version="3.0.0"><include filename="d{level + 1}.xml"/></scene>')
    (tmp_path / "d17.xml").write_text('<scene version="3.0.0"/>')
    with pytest.raises(SceneError, match="nested"):
        load_scene(tmp_path / "d0.xml")
    with pytest.raises(SceneError, match="nested"):
        scene_dependencies(tmp_path / "d0.xml")


# ----------------------------------------------------------------------- meshes ---

OCTA_PLY = SUITES / "spheres" / "meshes" / "octahedron.ply"
ICO_OBJ = SUITES / "spheres" / "meshes" / "icosphere.obj"


def mesh_scene(tmp_path, filename, kind=None):
    kind = kind or Path(filename).suffix.lstrip(".")
    shape = f'<shape type="{kind}"><string name="filename" value="{filename}"/></shape>'
    return scene_with(tmp_path, "</scene>", shape + "</scene>")


def test_truncated_ply_is_refused(tmp_path):
    data = OCTA_PLY.read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-12])
    assert "truncated" in scene_error(mesh_scene(tmp_path, "t.ply"))


def test_ply_face_index_out_of_range_is_refused(tmp_path):
    (tmp_path / "o.ply").write_text(OCTA_PLY.read_text().replace("3 0 2 4", "3 0 2 40"))
    assert "out of range" in scene_error(mesh_scene(tmp_path, "o.ply"))


def test_obj_index_zero_and_out_of_range_are_refused(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    (tmp_path / "z.obj").write_text(text + "f 0 1 2\n")
    assert "z.obj:4" in scene_error(mesh_scene(tmp_path, "z.obj"))
    (tmp_path / "r.obj").write_text(text + "f 1 2 4\n")
    assert "out of range" in scene_error(mesh_scene(tmp_path, "r.obj"))
    (tmp_path / "n.obj").write_text(text + "f -1 -2 -4\n")
    scene_error(mesh_scene(tmp_path, "n.obj"))


def test_obj_type_on_a_ply_file_is_read_as_obj_and_refused(tmp_path):
    """Mitsuba reads the file as the shape's type says; so does the loader."""
    shutil.copy(OCTA_PLY, tmp_path / "octa.ply")
    scene_error(mesh_scene(tmp_path, "octa.ply", kind="obj"))
    shutil.copy(ICO_OBJ, tmp_path / "ico.obj")
    assert "PLY" in scene_error(mesh_scene(tmp_path, "ico.obj", kind="ply"))


def test_obj_with_a_latin1_comment_loads_like_its_ascii_twin(tmp_path):
    (tmp_path / "l.obj").write_bytes(b"# caf\xe9 cr\xe8me\n" + ICO_OBJ.read_bytes())
    shutil.copy(ICO_OBJ, tmp_path / "a.obj")
    a = load_scene(mesh_scene(tmp_path, "a.obj")).shapes[-1]
    b = load_scene(mesh_scene(tmp_path, "l.obj")).shapes[-1]
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_empty_and_nan_meshes_name_file_and_line(tmp_path):
    (tmp_path / "e.obj").write_text("# nothing\n")
    assert "no triangles" in scene_error(mesh_scene(tmp_path, "e.obj"))
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    assert "nan.obj:2" in scene_error(mesh_scene(tmp_path, "nan.obj"))
    (tmp_path / "nan.ply").write_text(OCTA_PLY.read_text().replace("\n1 0 0\n", "\nnan 0 0\n"))
    assert "non-finite" in scene_error(mesh_scene(tmp_path, "nan.ply"))


# ---------------------------------------------------------------------- images ---

def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG whose IHDR claims ``width`` x ``height`` (the pixel data is one empty
    IDAT): what matters is that the size is refused before any decoding."""
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
                     + chunk(b"IEND", b""))


def test_huge_png_texture_is_refused_before_decoding(tmp_path):
    _png_header_only(tmp_path / "big.png", 12000, 12000)
    tex = ('<texture type="bitmap" name="reflectance"><string name="filename" value="big.png"/>'
           '</texture>')
    shape = f'<shape type="rectangle"><bsdf type="diffuse">{tex}</bsdf></shape>'
    msg = scene_error(scene_with(tmp_path, "</scene>", shape + "</scene>"))
    assert "12000x12000" in msg and "limit" in msg


def test_corrupt_exr_gives_one_line_and_nothing_else(tmp_path, capfd):
    ok = write_exr(tmp_path / "ok.exr", np.random.default_rng(1).random((64, 64, 3)).astype(np.float32))
    data = bytearray(ok.read_bytes())
    for i in range(400, len(data), 7):
        data[i] ^= 0x5A
    (tmp_path / "bad.exr").write_bytes(bytes(data))
    code = main(["compare", str(tmp_path / "bad.exr"), str(ok)])
    out, err = capfd.readouterr()                  # file descriptors: OpenEXR prints from C++
    one_line_error(code, err)
    assert out.strip() == ""


# --------------------------------------------------------------- reference store ---

def _fake_entry(store: Path, key: str = "ab" * 32) -> Path:
    from references.store import entry_directory, write_entry

    rng = np.random.default_rng(3)
    image = rng.random((12, 16, 3)).astype(np.float32)
    variance = np.full_like(image, 1e-4)
    d = entry_directory(store, key)
    write_entry(d, key, image, variance, {"scene": "x.xml"})
    return d


def test_compare_checks_a_store_entry_hashes(tmp_path, capsys):
    """An entry's image scaled x1.5 changed relMSE from 1e-4 to 4e-2 with exit 0."""
    d = _fake_entry(tmp_path / "store")
    test = tmp_path / "test.exr"
    write_exr(test, read_exr(d / "image.exr") * 1.01)
    code, out, _ = run_cli(capsys, "compare", test, d)
    assert code == 0 and "relmse" in out
    write_exr(d / "image.exr", read_exr(d / "image.exr") * 1.5)
    for ref in (d, d / "image.exr"):
        code, _, err = run_cli(capsys, "compare", test, ref)
        assert "sha256" in one_line_error(code, err)


def test_compare_refuses_nan_or_negative_variance(tmp_path, capsys):
    img = np.ones((8, 8, 3), np.float32)
    write_exr(tmp_path / "ref.exr", img)
    write_exr(tmp_path / "test.exr", img)
    var = np.full_like(img, 1e-3)
    var[2, 3, 1] = np.nan
    write_exr(tmp_path / "v.exr", var)
    code, _, err = run_cli(capsys, "compare", tmp_path / "test.exr", tmp_path / "ref.exr",
                           "--reference-variance", tmp_path / "v.exr")
    assert "NaN" in one_line_error(code, err)
    write_exr(tmp_path / "v.exr", -var)
    code, _, err = run_cli(capsys, "compare", tmp_path / "test.exr", tmp_path / "ref.exr",
                           "--reference-variance", tmp_path / "v.exr")
    one_line_error(code, err)


MOTION_ENTRY = ROOT / "references" / "store" / "9f93b3569cd31221"


def test_motion_blur_entries_are_hash_checked(tmp_path):
    """Motion-blur entries recorded no hashes: an image scaled x1.5 was used silently,
    and a corrupt one became a case error instead of a re-render."""
    from references.motion_blur import motion_reference
    from references.reference import ReferenceMissing, get_reference

    scene = SUITES / "distributed" / "motion" / "moving_sphere.xml"
    store = tmp_path / "store"
    shutil.copytree(MOTION_ENTRY, store / MOTION_ENTRY.name)
    ref = motion_reference(scene, times=64, spp=64, store=store, render=False)
    assert np.isfinite(ref.image).all()
    entry = store / MOTION_ENTRY.name
    write_exr(entry / "image.exr", read_exr(entry / "image.exr") * 1.5)
    with pytest.raises(FileNotFoundError, match="sha256"):
        motion_reference(scene, times=64, spp=64, store=store, render=False)
    with pytest.raises(ReferenceMissing, match="sha256"):
        get_reference(scene, transport="direct", spp=1024, store=store, render_missing=False)
    (entry / "image.exr").write_bytes(b"garbage")
    with pytest.raises(FileNotFoundError, match="sha256"):
        motion_reference(scene, times=64, spp=64, store=store, render=False)
    m = json.loads((entry / "manifest.json").read_text())
    del m["image_sha256"]
    (entry / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(FileNotFoundError, match="records no image_sha256"):
        motion_reference(scene, times=64, spp=64, store=store, render=False)


def test_reference_and_motion_blur_do_not_import_each_other():
    import ast

    for name, other in (("motion_blur", "reference"), ("store", "reference"), ("store", "motion_blur")):
        tree = ast.parse((ROOT / "references" / f"{name}.py").read_text())
        imported = {(n.module or "") for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        assert not any(m.split(".")[-1] == other for m in imported), (name, imported)


# ------------------------------------------------------------------ command line ---

def test_bad_parameters_and_seeds(tmp_path, capsys):
    scene = scene_with(tmp_path, '<integer name="width" value="160"/>', '<integer name="width" value="16"/>')
    base = ["render", scene, "-a", "raycast", "--spp", 1, "--repeats", 1, "--out", tmp_path / "o.exr"]
    for extra, word in ((["--set", "ks=nan"], "finite"), (["--set", "ks=-1"], ">= 0"),
                        (["--set", "c3=-1"], ">= 0"), (["--seed", "-1"], "seed"),
                        (["--seed", "1e23"], "seed"), (["--seed", str(10 ** 23)], "seed"),
                        (["--spp", "0"], "positive")):
        code, _, err = run_cli(capsys, *base, *extra)
        assert word in one_line_error(code, err), extra


def test_reference_arguments_are_one_line_errors(capsys):
    for argv in (["--spp", 10, "--passes", 3], ["--spp", 16, "--passes", 1]):
        code, _, err = run_cli(capsys, "reference", LIT_SPHERE, *argv)
        assert "passes" in one_line_error(code, err)


def test_zero_attenuation_denominator_is_not_a_kernel_exception(tmp_path, capsys):
    """--set c3=0 (with c1 = c2 = 0) divided by zero inside the kernel: a traceback."""
    scene = scene_with(tmp_path, '<integer name="width" value="160"/>', '<integer name="width" value="16"/>')
    code, _, err = run_cli(capsys, "render", scene, "-a", "raycast", "--spp", 1, "--repeats", 1,
                           "--set", "c3=0", "--out", tmp_path / "o.exr")
    assert "Inf" in one_line_error(code, err)


def test_out_and_history_that_are_directories(tmp_path, capsys):
    code, _, err = run_cli(capsys, "render", LIT_SPHERE, "-a", "raycast", "--spp", 1, "--repeats", 1,
                           "--out", tmp_path)
    assert "directory" in one_line_error(code, err)
    from gibench.history import HistoryError, connect

    with pytest.raises(HistoryError, match="directory"):
        connect(tmp_path)
    import sqlite3

    con = sqlite3.connect(tmp_path / "foreign.db")
    con.execute("CREATE TABLE results (a, b)")
    con.commit()
    con.close()
    with pytest.raises(HistoryError):
        connect(tmp_path / "foreign.db")
    code, _, err = run_cli(capsys, "history", "--history", tmp_path / "foreign.db")
    one_line_error(code, err)


# ------------------------------------------------------------------------ suites ---

GOOD_SUITE = """[suite]
name = "t"
reference_spp = 16
reference_passes = 2

[[group]]
scenes = ["s.xml"]
algorithm = "raycast"
[[group.config]]
params = { spp = 1 }
tolerances = { relmse = 1e-2 }
"""


@pytest.mark.parametrize("old, new, word", [
    ('scenes = ["s.xml"]', "scenes = [123]", "scenes"),
    ("[[group.config]]\nparams = { spp = 1 }", 'config = "oops"', "config"),
    ("relmse = 1e-2", 'relmse = "small"', "tolerances"),
    ("relmse = 1e-2", "nonsense = 1", "tolerances"),
    ('[[group]]\nscenes = ["s.xml"]\nalgorithm = "raycast"\n[[group.config]]\nparams = { spp = 1 }\n'
     'tolerances = { relmse = 1e-2 }', "group = 5", "group"),
    ("reference_spp = 16", 'reference_spp = "abc"', "reference_spp"),
    ("reference_passes = 2", "reference_passes = 1", "reference_passes"),
    ('name = "t"', 'name = "t"\nstudies_module = "os"', "studies_module"),
    ('name = "t"', 'name = "t"\nstudies = "s.xml"\nstudy_set = "os"', "study_set"),
    ('name = "t"', 'name = "t"\nrepeat = 3', "unknown key"),
    ("params = { spp = 1 }", 'params = { spp = "many" }', "spp"),
])
def test_suite_manifest_schema(tmp_path, old, new, word):
    shutil.copy(LIT_SPHERE, tmp_path / "s.xml")
    from gibench.suite import load_suite

    assert old in GOOD_SUITE, old
    (tmp_path / "suite.toml").write_text(GOOD_SUITE.replace(old, new))
    with pytest.raises(SuiteError) as info:
        load_suite(tmp_path / "suite.toml")
    msg = str(info.value)
    assert word in msg and "\n" not in msg and "suite.toml" in msg
    (tmp_path / "ok.toml").write_text(GOOD_SUITE)
    assert len(load_suite(tmp_path / "ok.toml").cases) == 1


def test_suite_errors_name_the_line_and_binary_manifests_are_refused(tmp_path):
    from gibench.suite import load_suite

    shutil.copy(LIT_SPHERE, tmp_path / "s.xml")
    (tmp_path / "a.toml").write_text(GOOD_SUITE.replace("reference_spp = 16", 'reference_spp = "abc"'))
    with pytest.raises(SuiteError, match=r"a\.toml:3: "):
        load_suite(tmp_path / "a.toml")
    (tmp_path / "b.toml").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(SuiteError, match="UTF-8|TOML"):
        load_suite(tmp_path / "b.toml")


def test_study_sets_come_from_the_registry_only():
    from gibench.studies import STUDY_SETS, load_study_set

    assert set(STUDY_SETS) == {"intersection", "accel", "radiosity", "sampling", "shading"}
    assert all(v.startswith("gibench.studies.") for v in STUDY_SETS.values())
    with pytest.raises(SuiteError):
        load_study_set("os")
    assert load_study_set("shading").__name__ == "gibench.studies.shading"


# --------------------------------------------------------------------- executor ---

def test_dask_handshake_has_a_deadline():
    """A port that accepts and never answers hung past the 10 s timeout (killed at 120 s)."""
    from gibench.executor import ExecutorError, map_unordered

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    port = srv.getsockname()[1]
    held = []
    stop = threading.Event()

    def accept():
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(srv.accept()[0])
            except OSError:
                pass

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(ExecutorError, match="did not answer"):
            list(map_unordered(str, [1], kind="dask", detail=f"tcp://127.0.0.1:{port}",
                               connect_timeout=2.0))
    finally:
        stop.set()
        t.join()
        for c in held:
            c.close()
        srv.close()
    assert time.perf_counter() - t0 < 15


# ------------------------------------------------------------------ kernel cache ---

KERNEL = """
import numpy as np
from impl.radiosity_solvers import _gs_sweep
F = np.full((4, 4), 0.1); rho = np.full((4, 3), 0.5); E = np.ones((4, 3)); B = E.copy()
_gs_sweep(F, rho, E, B)
print("B", round(float(B.sum()), 9))
"""


def test_corrupt_numba_cache_is_detected_and_rebuilt(tmp_path):
    """A truncated cache file was a traceback, a byte-flipped one a SIGSEGV."""
    import os

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}

    def run():
        p = subprocess.run([sys.executable, "-c", KERNEL], capture_output=True, text=True,
                           env=env, cwd=ROOT, timeout=300)
        assert p.returncode == 0, p.stderr[-2000:]
        return p.stdout.strip(), p.stderr

    first, _ = run()
    data = next((tmp_path / "cache").rglob("*_gs_sweep*.nbc"))
    index = next((tmp_path / "cache").rglob("*_gs_sweep*.nbi"))
    blob = bytearray(data.read_bytes())
    for i in range(64, len(blob), 37):
        blob[i] ^= 0xFF
    data.write_bytes(bytes(blob))
    out, err = run()
    assert out == first and "corrupt" in err
    out, err = run()                              # rebuilt: clean again
    assert out == first and "corrupt" not in err
    index.write_bytes(index.read_bytes()[:30])
    out, err = run()
    assert out == first and "corrupt" in err


def test_a_kernel_cache_in_use_by_a_running_process_is_not_removed(tmp_path):
    """The caches of other sources are removed when impl is imported, except one that a
    running process still holds (a long run started before impl/ was edited would lose
    its cache in the middle of compiling into it); once that process exits, its cache is
    removed like any stale one."""
    import os

    from impl import remove_stale_caches

    root = tmp_path / ".numba_cache"
    mine, held, stale = root / "aaaa", root / "bbbb", root / "cccc"
    for d in (mine, held, stale):
        d.mkdir(parents=True)
        (d / "kernel.nbi").write_bytes(b"x")
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from pathlib import Path; import impl; "
         "impl._hold(Path(sys.argv[1])); print('held', flush=True); sys.stdin.read()", str(held)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        assert remove_stale_caches(root, mine) == [stale]
        assert mine.is_dir() and (held / "kernel.nbi").is_file() and not stale.exists()
    finally:
        holder.communicate("", timeout=60)
    assert remove_stale_caches(root, mine) == [held]
    assert sorted(p.name for p in root.iterdir()) == ["aaaa"]
