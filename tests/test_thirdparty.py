"""Third-party Mitsuba 3 scenes (suites/thirdparty, see its NOTICE) through the loader.

Every scene file either loads or is refused with one line naming the file, the
line, the element and the reason.  The count of loaded files is pinned: a change
in the loader that loads more (or fewer) of them must update it knowingly.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from core.errors import GibenchError
from core.loader import load_scene

ROOT = Path(__file__).resolve().parent.parent / "suites" / "thirdparty"

#: The scene files: those directly in the scene directories (sub-directories hold
#: include fragments, meshes and textures).
SCENES = sorted([*ROOT.glob("docs/scenes/*.xml"), *ROOT.glob("scenes/*/*.xml"),
                 *ROOT.glob("tests/scenes/*/*.xml")])

#: Files refused, with the reason each is refused (a substring of the message).
REFUSED = {
    # Upstream, these need a <path> the documentation build adds (and -D spp=...).
    "sensor_orthographic.xml": "not found",
    # Upstream, the mesh it names does not exist (Mitsuba refuses it too).
    "sensor_orthographic_2.xml": "not found",
    "test_texturedprincipled1_path.xml": "not a model of the thesis",
}


def test_directory_size_and_notice():
    total = sum(p.stat().st_size for p in ROOT.rglob("*") if p.is_file())
    assert total < 2 * 1024 * 1024, total
    assert "BSD 3-Clause" in (ROOT / "NOTICE").read_text()
    assert len(SCENES) == 67


def test_load_or_refuse_with_one_line():
    loaded, refused = [], {}
    for path in SCENES:
        try:
            load_scene(path)
            loaded.append(path.name)
        except GibenchError as exc:
            msg = str(exc)
            refused[path.name] = msg
            assert "\n" not in msg
            # file:line: <element type="...">: reason
            assert re.match(r"^\S+\.xml:\d+: <\w+( type=\"[^\"]*\")?>: .+", msg), msg
    print(f"\nthirdparty: {len(loaded)}/{len(SCENES)} load")
    for name, msg in sorted(refused.items()):
        print(f"  refused {name}: {msg}")
    assert set(refused) == set(REFUSED), sorted(set(refused) ^ set(REFUSED))
    for name, why in REFUSED.items():
        assert why in refused[name], (name, refused[name])
    assert len(loaded) == len(SCENES) - len(REFUSED) == 64


def _closest_hits(scene, o, d):
    """Brute-force closest hit distance (inf for a miss) of rays (o, d) against the
    scene model's spheres and triangles (numpy, Möller-Trumbore)."""
    import numpy as np

    t_best = np.full(len(o), np.inf)
    for s in scene.shapes:
        if s.kind == "sphere":
            oc = o - s.center
            b = np.einsum("ij,ij->i", oc, d)
            c = np.einsum("ij,ij->i", oc, oc) - s.radius ** 2
            disc = b * b - c
            sq = np.sqrt(np.maximum(disc, 0.0))
            for t in (-b - sq, -b + sq):
                ok = (disc >= 0) & (t > 1e-6)
                t_best = np.where(ok & (t < t_best), t, t_best)
            continue
        tri = s.vertices[s.faces]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        for k in range(len(o)):
            p = np.cross(d[k], e2)
            det = np.einsum("ij,ij->i", e1, p)
            inv = 1.0 / np.where(det == 0, np.nan, det)
            tv = o[k] - tri[:, 0]
            u = np.einsum("ij,ij->i", tv, p) * inv
            q = np.cross(tv, e1)
            v = (q @ d[k]) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
            if ok.any():
                t_best[k] = min(t_best[k], t[ok].min())
    return t_best


@pytest.mark.parametrize("name", ["test_instancing_path.xml"])
def test_instancing_hits_match_mitsuba(mitsuba, name):
    """Instances are flattened into world-space shapes: rays towards the scene hit the
    scene model where they hit Mitsuba's instanced scene (a shapegroup of an OBJ
    sphere, an analytic sphere and a rectangle; three instances with rotations,
    scales and translations)."""
    import numpy as np

    mi = mitsuba
    path = ROOT / "tests" / "scenes" / "instancing" / name
    scene = load_scene(path)
    assert len(scene.shapes) == 3 * 3
    rng = np.random.default_rng(7)
    n = 400
    o = rng.normal(size=(n, 3))
    o = 12.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    target = rng.uniform(-2.0, 2.0, size=(n, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ours = _closest_hits(scene, o, d)
    ms = mi.load_file(str(path))
    ray = mi.Ray3f(mi.Point3f(*[o[:, i].astype(np.float32) for i in range(3)]),
                   mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)]))
    theirs = np.array(ms.ray_intersect(ray).t, dtype=np.float64)
    hit_o, hit_m = np.isfinite(ours), np.isfinite(theirs)
    print(f"\n{hit_o.sum()} of {n} rays hit")
    assert hit_o.sum() > n // 4
    # Rays grazing a silhouette may differ by float32 rounding: allow 1 %.
    assert (hit_o != hit_m).sum() <= n // 100
    both = hit_o & hit_m
    assert np.median(np.abs(ours[both] - theirs[both])) < 1e-4
    assert np.quantile(np.abs(ours[both] - theirs[both]), 0.99) < 1e-2


#: Of the files that load, those the path tracer renders (8x6 pixels, 1 spp,
#: max_depth 3 here): all of them; any other would be refused by name before
#: rendering.
PATH_RENDERS = 64
#: Of those, the scenes lit by an envmap and those with a plastic or roughplastic shape
#: (a blendbsdf's components included).
ENVMAPS, PLASTICS = 45, 20


def test_path_renders_or_refuses_by_name():
    """Every loaded third-party scene renders through ``path`` (finite image) or is
    refused with one line naming the part it does not model.  The envmap scenes
    (image-based lighting) and the plastic / roughplastic ones render."""
    import dataclasses

    import numpy as np

    from core.scene import scene_features
    from gibench import registry

    algo = registry.get("path")
    params = algo.parse_params({"spp": 1, "max_depth": 3})
    rendered, refused, envmaps, plastics = [], {}, 0, 0
    for path in SCENES:
        if path.name in REFUSED:
            continue
        scene = load_scene(path)
        cam = scene.camera
        scene = dataclasses.replace(scene, camera=dataclasses.replace(
            cam, film=dataclasses.replace(cam.film, width=8, height=6)))
        try:
            res = algo.render(scene, params, seed=0)
        except GibenchError as exc:
            refused[path.name] = str(exc)
            assert "\n" not in str(exc)
            continue
        assert res.image.shape == (6, 8, 3) and np.isfinite(res.image).all(), path.name
        rendered.append(path.name)
        features = scene_features(scene)
        envmaps += "envmap" in features
        plastics += "plastic" in features or "roughplastic" in features
    print(f"\nthirdparty: {len(rendered)}/{len(SCENES)} render with path ({envmaps} with an envmap, "
          f"{plastics} with plastic or roughplastic)")
    for name, msg in sorted(refused.items()):
        print(f"  refused {name}: {msg}")
    assert len(rendered) == PATH_RENDERS
    assert (envmaps, plastics) == (ENVMAPS, PLASTICS)
    reasons = ("which path does not model", "is modelled only by", "anisotropic roughness",
               "is not modelled; only 'beckmann' is")
    assert all(any(r in msg for r in reasons) for msg in refused.values()), refused
