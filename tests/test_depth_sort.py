"""Depth sort (Newell, Newell & Sancha; thesis 1.3.2): the hard cases — a cyclic
overlap of three polygons and two interpenetrating polygons — and the suite
scenes, against ray casting of the same meshes."""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench.studies.shading import boundary_mask
from impl import depth_sort, zbuffer  # noqa: F401  (register 'depthsort', 'zbuffer')
from impl.pipeline import geometry_stage
from impl.raster import DEPTH_NONE, rasterize
from impl.raycast import cast_primary
from impl.tessellate import scene_triangles, tessellated_scene

SUITES = Path(__file__).resolve().parent.parent / "suites"
DEPTHSORT = depth_sort.ALGORITHM


def render(scene, **params):
    return DEPTHSORT.render(scene, DEPTHSORT.parse_params(params), seed=0)


def _check_against_raycast(scene, res, tessellation=64):
    depth_rc, id_rc = cast_primary(tessellated_scene(scene, tessellation))
    same = res.aovs["shape_id"] == id_rc
    inner = ~boundary_mask(id_rc)
    assert same[inner].mean() >= 0.9999, f"{np.sum(~same & inner)} pixels differ off shape borders"
    assert same.mean() >= 0.998, f"{np.sum(~same)} pixels differ"
    hit = same & np.isfinite(depth_rc)
    rel = np.abs(res.aovs["depth"][hit] - depth_rc[hit]) / depth_rc[hit]
    assert rel.max() <= 1e-4
    return id_rc


def _painter_by_farthest_z(scene):
    """Shape ids of the naive painter's algorithm: sort by farthest z only, no tests, no splits."""
    cam = scene.camera
    scr = geometry_stage(scene_triangles(scene, 16), cam, cull=True, n_shapes=len(scene.shapes))
    order = np.argsort(-scr.cam[:, :, 2].max(axis=1), kind="stable")
    vis, _ = rasterize(scr.xy, scr.cam[:, :, 2], cam.film.width, cam.film.height, depth_mode=DEPTH_NONE,
                       near=cam.near_clip, far=cam.far_clip, order=order)
    tri_shape = scene_triangles(scene, 16).tri_shape
    return np.where(vis.id >= 0, tri_shape[scr.src[np.maximum(vis.id, 0)]], -1)


@pytest.mark.parametrize("name", ["spheres/cyclic_overlap.xml", "spheres/interpenetrating.xml"])
def test_hard_cases_render_like_ray_casting(name):
    """Three sticks overlapping in a cycle, and two squares through each other: no order of the
    whole polygons is right (sorting by farthest z alone gets pixels wrong); depth sort splits
    and then agrees with ray casting."""
    scene = load_scene(SUITES / name)
    res = render(scene)
    assert res.counters["splits"] >= 1 and res.counters["unresolved"] == 0
    id_rc = _check_against_raycast(scene, res)
    naive = _painter_by_farthest_z(scene)
    assert np.sum(naive != id_rc) > 20, "the case should defeat a plain sort by farthest z"


def test_cycle_is_detected_by_the_marks():
    """The cyclic case moves polygons to the head before splitting (swapped tests pass pairwise)."""
    res = render(load_scene(SUITES / "spheres/cyclic_overlap.xml"))
    assert res.counters["moves"] >= 1 and res.counters["splits"] >= 1


@pytest.mark.parametrize("name", ["spheres/lit_sphere.xml", "spheres/spot_directional.xml", "spheres/meshes.xml",
                                  "cornell/cornell_point.xml", "cornell/cornell_box.xml"])
@pytest.mark.parametrize("cull", [True, False])
def test_suite_scenes_match_ray_casting_and_zbuffer(name, cull):
    scene = load_scene(SUITES / name)
    res = render(scene, tessellation=64, cull=cull)
    _check_against_raycast(scene, res)
    zb = zbuffer.ALGORITHM.render(scene, zbuffer.ALGORITHM.parse_params({"tessellation": 64, "cull": cull}), seed=0)
    same = res.aovs["shape_id"] == zb.aovs["shape_id"]
    assert same.mean() >= 0.999
    # Same visible triangles, same shading: images agree where the visible surfaces do (but for
    # ties on silhouette edges, where a back face of the same shape meets a front face).
    close = np.all(np.abs(res.image - zb.image) <= 1e-5 * np.abs(zb.image) + 1e-6, axis=-1)
    assert np.mean(close[same]) >= 0.999, f"{np.sum(same & ~close)} pixels shaded differently"


def test_counters():
    res = render(load_scene(SUITES / "spheres/lit_sphere.xml"), tessellation=32)
    c = res.counters
    assert c["comparisons"] > 0 and c["unresolved"] == 0
    assert c["fragments"] == c["depth_passed"] > 0          # the painter writes every fragment
