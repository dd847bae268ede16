"""Fuzzing the scene loader with mutated copies of the suite's own scene files.

Each case takes one scene of ``suites/`` (copied, with its meshes, textures and
included files, to a temporary directory) and applies one to three mutations:
a number replaced by a hostile value (NaN, ±inf, 0, -1, 1e308, 5000 digits, a
word, an unknown ``$name``), a line deleted, duplicated or swapped, a byte
flipped, the file truncated, an element or plugin type or property name
exchanged for another one of the vocabulary, or a hostile element inserted
(an entity declaration, a self-include, a dangling ``ref``).

The promise checked for every case: loading either succeeds with a finite
scene (camera, film, shapes, lights) or raises :class:`core.errors.GibenchError`
with a one-line message — never another exception (a traceback on the command
line), a hang (each case has a 20 s alarm) or a crash.

The normal test command runs :data:`QUICK_CASES` cases (a few seconds).  The
opt-in run is chosen with environment variables::

    GIBENCH_FUZZ_CASES=2000 GIBENCH_FUZZ_RENDER=1 python -m pytest tests/test_fuzz_scenes.py -q -s

``GIBENCH_FUZZ_CASES`` sets the number of cases; ``GIBENCH_FUZZ_RENDER=1``
also renders each scene that loads with ``raycast`` (1 spp) on an 8x6 film and
requires a finite image or a one-line GibenchError.  ``GIBENCH_FUZZ_SEED``
changes the mutation seed (default 0).  The run prints its figures (cases,
loaded, refused, rendered, by kind of mutation).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import re
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from core.errors import GibenchError
from core.loader import load_scene

ROOT = Path(__file__).resolve().parent.parent
SUITES = ROOT / "suites"
QUICK_CASES = 150
CASE_TIMEOUT_S = 20

HOSTILE_NUMBERS = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "1e-320", "9" * 5000,
                   "abc", "", "1,2", "0x10", "$nope", "1e999", "-0", "3.5", "2147483648",
                   "1 2 3 4", "NaN, 1, 1"]
TAGS = ["float", "integer", "rgb", "spectrum", "string", "boolean", "point", "vector", "transform",
        "shape", "bsdf", "emitter", "sensor", "film", "sampler", "texture", "include", "ref",
        "default", "path", "scale", "rotate", "translate", "matrix", "lookat", "rfilter"]
TYPES = ["sphere", "rectangle", "cube", "disk", "cylinder", "obj", "ply", "diffuse", "conductor",
         "dielectric", "roughconductor", "roughdielectric", "twosided", "point", "directional",
         "spot", "area", "constant", "perspective", "thinlens", "orthographic", "hdrfilm", "box",
         "gaussian", "checkerboard", "bitmap", "envmap", "independent", "path"]
NAMES = ["radius", "center", "fov", "width", "height", "to_world", "reflectance", "radiance",
         "intensity", "filename", "int_ior", "alpha", "cutoff_angle", "beam_width", "near_clip",
         "far_clip", "sample_count", "position", "direction", "p0", "p1", "stddev", "to_uv",
         "aperture_radius", "focus_distance", "shutter_open", "shutter_close", "gibench_velocity"]
INSERTS = ['<!DOCTYPE scene [<!ENTITY a "aaaa"><!ENTITY b "&a;&a;&a;&a;">]>',
           '<include filename="SELF"/>', '<ref id="nowhere"/>', '<default name="x" value="$x"/>',
           '<path value="/"/>', '<include filename="/etc/passwd"/>',
           "<shape type=\"sphere\">" * 50 + "</shape>" * 50,
           '<float name="radius" value="1"/>', '<emitter type="spot"/>']
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")


def _seeds() -> list[Path]:
    return sorted(p for p in SUITES.rglob("*.xml") if "include_parts" not in p.parts)


def _mutate(text: str, rng: np.random.Generator, self_name: str) -> tuple[str, list[str]]:
    kinds = []
    for _ in range(int(rng.integers(1, 4))):
        kind = str(rng.choice(["number", "number", "number", "delete", "duplicate", "swap", "byte",
                               "truncate", "tag", "type", "name", "insert"]))
        kinds.append(kind)
        lines = text.split("\n")
        if kind == "number":
            spots = list(NUMBER.finditer(text))
            if spots:
                m = spots[int(rng.integers(len(spots)))]
                text = text[:m.start()] + str(rng.choice(HOSTILE_NUMBERS)) + text[m.end():]
        elif kind == "delete" and len(lines) > 1:
            del lines[int(rng.integers(len(lines)))]
            text = "\n".join(lines)
        elif kind == "duplicate":
            i = int(rng.integers(len(lines)))
            lines.insert(i, lines[i])
            text = "\n".join(lines)
        elif kind == "swap" and len(lines) > 1:
            i, j = rng.integers(len(lines), size=2)
            lines[i], lines[j] = lines[j], lines[i]
            text = "\n".join(lines)
        elif kind == "byte" and text:
            i = int(rng.integers(len(text)))
            text = text[:i] + chr(int(rng.integers(1, 256))) + text[i + 1:]
        elif kind == "truncate" and text:
            text = text[:int(rng.integers(len(text)))]
        elif kind == "tag":
            spots = list(re.finditer(r"(?<=<)/?([a-z_]+)", text))
            if spots:
                m = spots[int(rng.integers(len(spots)))]
                text = text[:m.start(1)] + str(rng.choice(TAGS)) + text[m.end(1):]
        elif kind == "type":
            spots = list(re.finditer(r'type="([^"]*)"', text))
            if spots:
                m = spots[int(rng.integers(len(spots)))]
                text = text[:m.start(1)] + str(rng.choice(TYPES)) + text[m.end(1):]
        elif kind == "name":
            spots = list(re.finditer(r'name="([^"]*)"', text))
            if spots:
                m = spots[int(rng.integers(len(spots)))]
                text = text[:m.start(1)] + str(rng.choice(NAMES)) + text[m.end(1):]
        else:
            snippet = str(rng.choice(INSERTS)).replace("SELF", self_name)
            if snippet.startswith("<!DOCTYPE"):
                text = re.sub(r"(<\?xml[^>]*\?>)?", lambda m: (m.group(0) or "") + snippet, text, count=1)
            else:
                cut = [m.end() for m in re.finditer(r">", text)]
                at = cut[int(rng.integers(len(cut)))] if cut else 0
                text = text[:at] + snippet + text[at:]
    return text, kinds


def _finite_scene(scene) -> None:
    cam = scene.camera
    assert np.all(np.isfinite(cam.to_world)) and abs(np.linalg.det(cam.to_world[:3, :3])) > 0
    assert cam.film.width >= 1 and cam.film.height >= 1 and np.isfinite(cam.near_clip)
    for s in scene.shapes:
        if s.kind == "sphere":
            assert np.isfinite(s.radius) and s.radius > 0 and np.all(np.isfinite(s.center))
        else:
            assert np.all(np.isfinite(s.vertices)) and len(s.faces)
            assert s.faces.min() >= 0 and s.faces.max() < len(s.vertices)
        if s.emitter_radiance is not None:
            assert np.all(np.isfinite(s.emitter_radiance)) and np.all(np.asarray(s.emitter_radiance) >= 0)
    for m in scene.materials:
        assert np.all(np.isfinite(m.reflectance)) and min(m.reflectance) >= 0
    for light in scene.lights:
        assert np.all(np.isfinite(light.radiant)) and np.all(np.asarray(light.radiant) >= 0)
        if light.direction is not None:
            assert np.all(np.isfinite(light.direction)) and abs(np.linalg.norm(light.direction) - 1) < 1e-9


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang()


def _render_tiny(scene):
    """raycast at 1 spp on an 8x6 film: a finite image, or a GibenchError."""
    from core.imageio import check_finite
    from gibench import registry

    cam = dataclasses.replace(scene.camera, film=dataclasses.replace(scene.camera.film, width=8, height=6))
    scene = dataclasses.replace(scene, camera=cam)
    algo = registry.get("raycast")
    result = algo.render(scene, algo.parse_params({"spp": 1}))
    check_finite(result.image, name="raycast output")


def run_fuzz(tmp_path: Path, cases: int, *, seed: int = 0, render: bool = False) -> dict:
    work = tmp_path / "suites"
    shutil.copytree(SUITES, work)
    seeds = [work / p.relative_to(SUITES) for p in _seeds()]
    rng = np.random.default_rng(seed)
    stats = collections.Counter()
    by_kind = collections.Counter()
    failures = []
    refusals = collections.Counter()          # why rendering refused a loaded scene
    old = signal.signal(signal.SIGALRM, _alarm)
    t0 = time.perf_counter()
    try:
        for case in range(cases):
            base = seeds[int(rng.integers(len(seeds)))]
            text, kinds = _mutate(base.read_text(), rng, base.name)
            path = base.with_name(f"fuzz_{case}.xml")
            path.write_text(text, errors="surrogateescape")
            by_kind.update(kinds)
            signal.alarm(CASE_TIMEOUT_S)
            try:
                scene = load_scene(path)
                _finite_scene(scene)
                stats["loaded"] += 1
                if render:
                    try:
                        _render_tiny(scene)
                        stats["rendered"] += 1
                    except GibenchError as exc:
                        assert "\n" not in str(exc), str(exc)
                        stats["render refused"] += 1
                        refusals[re.sub(r"\b\d[\d.]*(e[+-]?\d+)?\b|/\S+", "#", str(exc))[:90]] += 1
            except GibenchError as exc:
                stats["refused"] += 1
                if "\n" in str(exc):
                    failures.append((case, base.name, kinds, f"multi-line message: {exc!r}"))
            except _Hang:
                failures.append((case, base.name, kinds, f"no answer within {CASE_TIMEOUT_S} s"))
            except Exception as exc:                       # noqa: BLE001 - the failure under test
                failures.append((case, base.name, kinds, f"{type(exc).__name__}: {str(exc)[:200]}"))
            finally:
                signal.alarm(0)
                path.unlink()
    finally:
        signal.signal(signal.SIGALRM, old)
    stats["cases"] = cases
    stats["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"fuzz (seed {seed}): {dict(stats)}; mutations {dict(by_kind)}")
    for why, n in refusals.most_common(12):
        print(f"  render refused x{n}: {why}")
    for f in failures[:20]:
        print("  FAIL", f)
    return {"stats": stats, "failures": failures}


def test_fuzz_mutated_scenes_quick(tmp_path):
    out = run_fuzz(tmp_path, QUICK_CASES, seed=0)
    assert not out["failures"], out["failures"][:5]
    assert out["stats"]["refused"] > 0 and out["stats"]["loaded"] > 0   # both outcomes exercised


@pytest.mark.skipif(not os.environ.get("GIBENCH_FUZZ_CASES"),
                    reason="opt-in: GIBENCH_FUZZ_CASES=N (and GIBENCH_FUZZ_RENDER=1) runs N cases")
def test_fuzz_mutated_scenes_long(tmp_path):
    out = run_fuzz(tmp_path, int(os.environ["GIBENCH_FUZZ_CASES"]),
                   seed=int(os.environ.get("GIBENCH_FUZZ_SEED", "0")),
                   render=os.environ.get("GIBENCH_FUZZ_RENDER") == "1")
    assert not out["failures"], out["failures"][:5]
