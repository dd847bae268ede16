"""Tests for the Mitsuba reference store (references/mitsuba_env.py, references/reference.py).

Scenes are tiny (16x16 or 15x15 films, low spp) so the whole file runs in a
few seconds with the LLVM variant.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from core.imageio import read_exr, write_exr
from references import mitsuba_env, reference
from references import store as store_module
from references.mitsuba_env import (
    libllvm_candidates,
    llvm_major_version,
    load_mitsuba,
    mitsuba_versions,
    probe_llvm,
)
from references.reference import (
    ReferenceMissing,
    SceneError,
    get_reference,
    reference_key,
    render_depth,
    time_mitsuba,
)

QUAD_OBJ = """\
v -2 -1 -2
v -2 -1 2
v 2 -1 2
v 2 -1 -2
f 1 2 3
f 1 3 4
"""

SCENE_XML = """\
<scene version="3.0.0">
  <default name="res" value="16"/>
  <default name="depth" value="{max_depth}"/>
  <integrator type="path"><integer name="max_depth" value="$depth"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 1, 4" target="0, -0.5, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm">
      <integer name="width" value="$res"/><integer name="height" value="$res"/>
    </film>
  </sensor>
  <shape type="sphere">
    <point name="center" x="0" y="-0.4" z="0"/><float name="radius" value="0.6"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.6, 0.4"/></bsdf>
  </shape>
  <shape type="obj">
    <string name="filename" value="meshes/quad.obj"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf>
  </shape>
  <emitter type="point">
    <point name="position" x="1.5" y="2" z="1.5"/><rgb name="intensity" value="20"/>
  </emitter>
</scene>
"""


def plane_scene_xml(distance: float, near_clip: float, res: int = 15, fov: float = 40.0) -> str:
    """Camera on the +z axis looking straight at a large plane z=0."""
    return f"""\
<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="{fov}"/>
    <float name="near_clip" value="{near_clip}"/>
    <transform name="to_world"><lookat origin="0, 0, {distance}" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="50"/></transform>
    <bsdf type="diffuse"/></shape>
  <emitter type="constant"/>
</scene>
"""


@pytest.fixture
def scene(tmp_path) -> Path:
    """A small scene with interreflection and a relative mesh path."""
    d = tmp_path / "scene"
    (d / "meshes").mkdir(parents=True)
    (d / "meshes" / "quad.obj").write_text(QUAD_OBJ)
    path = d / "scene.xml"
    path.write_text(SCENE_XML.format(max_depth=6))
    return path


@pytest.fixture
def store(tmp_path, monkeypatch) -> Path:
    # Run from elsewhere so relative mesh names must resolve via the scene directory.
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    return tmp_path / "store"


def entry_files(ref) -> dict:
    return {p.name: p for p in ref.directory.iterdir()}


# ---------------------------------------------------------------------------
# mitsuba_env
# ---------------------------------------------------------------------------


def test_llvm_major_version_parsing():
    assert llvm_major_version("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert llvm_major_version("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert llvm_major_version("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert llvm_major_version("/usr/lib/llvm-17/lib/libLLVM.so") == 17
    assert llvm_major_version("/usr/lib/libLLVM.so") is None


def test_candidates_newest_first_and_filtered(tmp_path, monkeypatch):
    for name in ("libLLVM-15.so", "libLLVM-17.so", "libLLVM.so.19.1", "libLLVMCore.a"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "libLLVM-19.so").symlink_to(tmp_path / "libLLVM.so.19.1")
    monkeypatch.setattr(mitsuba_env, "LIB_DIRS", (str(tmp_path),))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    names = [Path(p).name for p in libllvm_candidates()]
    assert names == ["libLLVM-19.so", "libLLVM-17.so"]  # one entry per real file, >= 17
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-15.so"))
    assert Path(libllvm_candidates()[0]).name == "libLLVM-15.so"  # explicit choice first


@pytest.mark.mitsuba
def test_variant_is_llvm_here_and_idempotent():
    if os.environ.get("GIBENCH_MITSUBA_VARIANT"):
        pytest.skip("GIBENCH_MITSUBA_VARIANT overrides the variant choice")
    mi = load_mitsuba()
    assert mi.variant() == "llvm_ad_rgb"
    assert load_mitsuba() is mi
    v = mitsuba_versions()
    assert v["variant"] == "llvm_ad_rgb" and v["mitsuba"] == mi.__version__
    assert v["libllvm"] and llvm_major_version(v["libllvm"]) >= 17
    assert os.environ["DRJIT_LIBLLVM_PATH"] == v["libllvm"]


@pytest.mark.mitsuba
def test_probe_of_bad_library_is_false_without_crashing(tmp_path):
    assert probe_llvm(tmp_path / "libLLVM-99.so", use_cache=False) is False
    bad = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so"  # aborts Dr.Jit's LLVM backend
    if os.path.exists(bad):
        assert probe_llvm(bad, use_cache=False) is False


_CHILD = (
    "import sys, references.mitsuba_env as m\n"
    "m.LIB_DIRS = ()  # pretend no libLLVM is installed\n"
    "mi = m.load_mitsuba()\n"
    "assert m.load_mitsuba() is mi\n"
    "print(mi.variant())\n"
)


@pytest.mark.mitsuba
@pytest.mark.parametrize("override", [None, "scalar_rgb"])
def test_scalar_fallback_and_env_override(override):
    env = {k: v for k, v in os.environ.items()
           if k not in ("DRJIT_LIBLLVM_PATH", "GIBENCH_MITSUBA_VARIANT")}
    if override:
        env["GIBENCH_MITSUBA_VARIANT"] = override
    proc = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "scalar_rgb"
    warnings = [line for line in proc.stderr.splitlines() if "libLLVM" in line]
    if override:
        assert warnings == []
    else:
        assert len(warnings) == 1 and "no libLLVM >= 17 found" in warnings[0]
        assert "libllvm19" in warnings[0] and "scalar_rgb" in warnings[0]


# ---------------------------------------------------------------------------
# Keys, overrides and argument checks (no rendering)
# ---------------------------------------------------------------------------


def test_key_depends_on_scene_mesh_and_settings(scene):
    k0 = reference_key(scene, spp=16, passes=4)
    assert k0 == reference_key(scene, spp=16, passes=4)
    assert k0 != reference_key(scene, spp=32, passes=4)
    assert k0 != reference_key(scene, spp=16, passes=4, seed=1)
    assert k0 != reference_key(scene, spp=16, passes=4, transport="direct")
    assert k0 != reference_key(scene, spp=16, passes=4, rfilter="scene")
    mesh = scene.parent / "meshes" / "quad.obj"
    mesh.write_text(QUAD_OBJ.replace("v 2 -1 -2", "v 2.5 -1 -2"))
    k1 = reference_key(scene, spp=16, passes=4)
    assert k1 != k0
    scene.write_text(scene.read_text().replace('value="0.8, 0.6, 0.4"', 'value="0.5, 0.6, 0.4"'))
    assert reference_key(scene, spp=16, passes=4) not in (k0, k1)


def test_overrides_keep_the_rest_of_the_file(scene):
    scene.write_text(scene.read_text().replace(
        '<film type="hdrfilm">', '<film type="hdrfilm"><rfilter type="gaussian"/>'))
    xml, integrator, over = reference.prepare_scene_xml(
        scene, transport="direct", spp_per_pass=8, seed=3, rfilter="scene")
    assert integrator == {"type": "direct"}
    assert over["integrator"]["from"] == {"type": "path", "max_depth": "6"}
    assert over["sensor[0]"]["rfilter"] == {"from": {"type": "gaussian"}, "to": "kept"}
    assert '<rfilter type="gaussian"/>' in xml and 'value="$res"' in xml
    assert '<default name="res" value="16"/>' in xml and "meshes/quad.obj" in xml
    xml, _, _ = reference.prepare_scene_xml(scene, spp_per_pass=8, seed=3)
    assert '<rfilter type="box"/>' in xml and "gaussian" not in xml
    assert xml.count("<integrator") == 1 and xml.count("<sampler") == 1


def test_bad_arguments(scene, store):
    with pytest.raises(ValueError, match="multiple of passes"):
        get_reference(scene, spp=10, passes=4, store=store)
    with pytest.raises(ValueError, match="passes must be >= 2"):
        get_reference(scene, spp=10, passes=1, store=store)
    with pytest.raises(ValueError, match="transport"):
        get_reference(scene, spp=8, passes=4, transport="indirect", store=store)
    with pytest.raises(SceneError, match="nope.xml: no such scene file"):
        get_reference(scene.parent / "nope.xml", spp=8, passes=4, store=store)


@pytest.mark.mitsuba
def test_unloadable_scene_names_file_and_reason(tmp_path, store):
    # The mesh must exist, or Mitsuba's parallel loader may report the missing
    # mesh instead of the bad plugin, depending on thread timing.
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "quad.obj").write_text(QUAD_OBJ)
    bad = tmp_path / "bad.xml"
    bad.write_text(SCENE_XML.format(max_depth=3).replace('type="sphere"', 'type="no_such_plugin"'))
    with pytest.raises(SceneError) as info:
        get_reference(bad, spp=8, passes=4, store=store)
    msg = str(info.value)
    assert "bad.xml" in msg and "no_such_plugin" in msg and "\n" not in msg
    assert not store.exists() or not any(store.iterdir())
    broken = tmp_path / "broken.xml"
    broken.write_text("<scene version='3.0.0'><shape")
    with pytest.raises(SceneError, match="broken.xml"):
        get_reference(broken, spp=8, passes=4, store=store)


# ---------------------------------------------------------------------------
# Store: render, reuse, corruption, atomicity
# ---------------------------------------------------------------------------


@pytest.mark.mitsuba
def test_store_and_reuse(scene, store, monkeypatch, capsys):
    ref = get_reference(scene, spp=16, passes=4, store=store)
    assert "no stored entry" in capsys.readouterr().err
    assert ref.image.shape == ref.variance.shape == (16, 16, 3)
    assert ref.image.dtype == ref.variance.dtype == np.float32
    assert ref.directory == store / ref.key[:16]
    assert set(entry_files(ref)) == {"image.exr", "variance.exr", "manifest.json"}
    assert [p.name for p in store.iterdir()] == [ref.key[:16]]  # no temporary leftovers
    m = json.loads((ref.directory / "manifest.json").read_text())
    for field in ("key", "scene", "scene_sha256", "transport", "integrator", "overrides", "spp",
                  "passes", "seed", "mitsuba", "drjit", "variant", "libllvm", "wall_time_s",
                  "width", "height", "created", "image_sha256", "variance_sha256"):
        assert field in m, field
    assert m["integrator"] == {"type": "path", "max_depth": 6}  # from the file, via $depth
    over = m["overrides"]["sensor[0]"]
    assert over["sampler"]["to"] == {"type": "independent", "sample_count": 4, "seed": 0}
    assert over["rfilter"]["to"] == {"type": "box"}
    assert over["pixel_format"]["to"] == "rgb" and over["component_format"]["to"] == "float32"
    assert [d["name"] for d in m["dependencies"]] == ["meshes/quad.obj"]
    assert m["wall_time_s"]["total"] > 0 and len(m["wall_time_s"]["passes"]) == 4
    np.testing.assert_array_equal(read_exr(ref.directory / "image.exr"), ref.image)
    assert ref.image.max() > 0 and "key=" in repr(ref)

    def no_render(*args, **kwargs):
        raise AssertionError("re-rendered a valid stored reference")

    monkeypatch.setattr(reference, "_render_reference", no_render)
    again = get_reference(scene, spp=16, passes=4, store=store)
    assert capsys.readouterr().err == ""
    assert again.key == ref.key and again.manifest["created"] == m["created"]
    np.testing.assert_array_equal(again.image, ref.image)
    np.testing.assert_array_equal(again.variance, ref.variance)
    # A changed scene is a new key and a new entry.
    scene.write_text(scene.read_text().replace('value="20"', 'value="30"'))
    with pytest.raises(ReferenceMissing, match="scene.xml"):
        get_reference(scene, spp=16, passes=4, store=store, render_missing=False)


@pytest.mark.mitsuba
def test_corrupt_entry_is_rerendered_never_used(scene, store, capsys):
    ref = get_reference(scene, spp=16, passes=4, store=store)
    capsys.readouterr()
    image = ref.directory / "image.exr"
    data = bytearray(image.read_bytes())
    for i in range(len(data) // 2, len(data) // 2 + 16):
        data[i] ^= 0xFF
    image.write_bytes(bytes(data))

    with pytest.raises(ReferenceMissing, match=r"scene\.xml.*image\.exr sha256"):
        get_reference(scene, spp=16, passes=4, store=store, render_missing=False)
    fixed = get_reference(scene, spp=16, passes=4, store=store)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "image.exr sha256 does not match" in err
    np.testing.assert_array_equal(fixed.image, ref.image)  # deterministic seeds
    assert reference._load_entry(fixed.directory, fixed.key).manifest["key"] == fixed.key

    # A NaN image whose hash *does* match the manifest is still refused.
    bad = fixed.image.copy()
    bad[3, 4, 1] = np.nan
    write_exr(image, bad)
    manifest = json.loads((fixed.directory / "manifest.json").read_text())
    manifest["image_sha256"] = reference._sha256_file(image)
    (fixed.directory / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ReferenceMissing, match="NaN"):
        get_reference(scene, spp=16, passes=4, store=store, render_missing=False)
    assert np.isfinite(get_reference(scene, spp=16, passes=4, store=store).image).all()
    assert "NaN" in capsys.readouterr().err


@pytest.mark.mitsuba
def test_interrupted_write_keeps_previous_entry(scene, store, monkeypatch):
    ref = get_reference(scene, spp=16, passes=4, store=store)
    manifest = ref.directory / "manifest.json"
    manifest.write_text(manifest.read_text().replace(ref.key, "0" * 64))  # stale -> re-render
    before = {p.name: p.read_bytes() for p in ref.directory.iterdir()}

    def failing_write(path, image, **kwargs):
        if Path(path).name == "variance.exr":
            raise KeyboardInterrupt("simulated interruption")
        return write_exr(path, image, **kwargs)

    monkeypatch.setattr(store_module, "write_exr", failing_write)
    with pytest.raises(KeyboardInterrupt):
        get_reference(scene, spp=16, passes=4, store=store)
    assert [p.name for p in store.iterdir()] == [ref.key[:16]]  # no half entry left
    assert {p.name: p.read_bytes() for p in ref.directory.iterdir()} == before


# ---------------------------------------------------------------------------
# Variance, transport
# ---------------------------------------------------------------------------


@pytest.mark.mitsuba
def test_variance_matches_spread_between_seeds(scene, store):
    a = get_reference(scene, spp=64, passes=8, seed=0, store=store)
    b = get_reference(scene, spp=64, passes=8, seed=1, store=store)
    assert a.key != b.key
    diff = a.image.astype(np.float64) - b.image
    noisy = diff != 0
    assert noisy.mean() > 0.3
    # Where a pixel varies between seeds and is not a black (rare-event) pixel,
    # the passes varied too, so the variance estimate is positive.
    for r in (a, b):
        assert (r.variance[noisy & (r.image > 0)] > 0).all()
    assert (a.variance >= 0).all()
    # E[(a - b)^2] = Var(a) + Var(b) for independent means.
    ratio = np.mean(diff**2) / np.mean(a.variance.astype(np.float64) + b.variance)
    assert 0.5 < ratio < 2.0, ratio


@pytest.mark.mitsuba
def test_large_passes_are_split_into_launches(scene, store, monkeypatch):
    whole = get_reference(scene, spp=32, passes=4, seed=5, store=store / "a")
    monkeypatch.setattr(reference, "LANE_BUDGET", 16 * 16 * 3)  # 3 spp per launch
    split = get_reference(scene, spp=32, passes=4, seed=5, store=store / "b")
    assert [len(s) for s in split.manifest["render_seeds"]] == [3, 3, 3, 3]
    assert [len(s) for s in whole.manifest["render_seeds"]] == [1, 1, 1, 1]
    diff = split.image.sum(dtype=np.float64) - whole.image.sum(dtype=np.float64)
    sigma = math.sqrt(split.variance.sum(dtype=np.float64) + whole.variance.sum(dtype=np.float64))
    assert abs(diff) < 5 * sigma


@pytest.mark.mitsuba
def test_direct_and_full_transport_differ(scene, store):
    full = get_reference(scene, spp=32, passes=4, store=store)
    direct = get_reference(scene, spp=32, passes=4, transport="direct", store=store)
    assert direct.manifest["integrator"]["type"] == "direct"
    assert full.manifest["integrator"]["type"] == "path"
    extra = full.image.sum(dtype=np.float64) - direct.image.sum(dtype=np.float64)
    sigma = math.sqrt(full.variance.sum(dtype=np.float64) + direct.variance.sum(dtype=np.float64))
    assert extra > 10 * sigma > 0  # interreflection adds light


# ---------------------------------------------------------------------------
# Depth and timing
# ---------------------------------------------------------------------------


@pytest.mark.mitsuba
def test_render_depth_at_pixel_centres(tmp_path):
    distance, near, res, fov = 3.0, 0.25, 15, 40.0
    path = tmp_path / "plane.xml"
    path.write_text(plane_scene_xml(distance, near, res, fov))
    depth = render_depth(path)
    assert depth.shape == (res, res) and depth.dtype == np.float32
    c = res // 2
    assert depth[c, c] == pytest.approx(distance - near, rel=1e-4)
    # Off-axis: depth = (D - n) / cos(theta) at pixel centres.
    t = math.tan(math.radians(fov) / 2)
    u = ((np.arange(res) + 0.5) / res * 2 - 1) * t
    cos = 1 / np.sqrt(1 + u[None, :] ** 2 + u[:, None] ** 2)
    np.testing.assert_allclose(depth * cos, distance - near, rtol=1e-4)


@pytest.mark.mitsuba
def test_time_mitsuba(scene):
    t = time_mitsuba(scene, transport="full", spp=8, repeats=3)
    assert len(t["times_s"]) == 3 and all(x > 0 for x in t["times_s"])
    assert math.isfinite(t["median_s"]) and t["median_s"] > 0
    assert t["median_s"] == sorted(t["times_s"])[1]
    assert t["spp"] == 8 and t["variant"] == load_mitsuba().variant() and t["warmup_s"] > 0
