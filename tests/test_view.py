"""``gibench view``: scene, radiosity solution and acceleration structures drawn off
screen with pyvista.  The geometry helpers are checked against the scene's numbers
(frustum angles, box nesting, occupied cells); the pictures must hold what was
drawn (the materials' colours, coloured patches, level-coloured box edges)."""

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

pytest.importorskip("pyvista")

from core.loader import load_scene
from gibench.view import accel_boxes, frustum_lines

from test_cli import one_line_error, run_cli

SUITES = Path(__file__).resolve().parent.parent / "suites"
CORNELL = SUITES / "cornell" / "cornell_box.xml"
GRID = SUITES / "spheres" / "sphere_grid.xml"


def _png(path):
    img = mpimg.imread(path)[..., :3]
    return (img * 255).round().astype(np.int32)


def _near(img, rgb, tol=40):
    return int(np.count_nonzero(np.all(np.abs(img - np.asarray(rgb)) <= tol, axis=-1)))


def test_frustum_spans_the_field_of_view():
    scene = load_scene(GRID)
    segs = frustum_lines(scene, 2.0)
    apex = scene.camera.origin
    assert np.allclose(segs[:4, 0], apex)
    d = segs[:4, 1] - apex
    d /= np.linalg.norm(d, axis=1)[:, None]
    mid_right, mid_left = (d[0] + d[3]) / 2, (d[1] + d[2]) / 2   # corners (+x,±y) and (-x,±y)
    cos = mid_right @ mid_left / np.linalg.norm(mid_right) / np.linalg.norm(mid_left)
    assert np.degrees(np.arccos(cos)) == pytest.approx(2 * np.degrees(np.arctan(scene.camera.tan_half_fov_x)), rel=1e-6)


def test_bvh_boxes_nest_and_count_levels():
    scene = load_scene(GRID)
    lo1, hi1, lev1, st1 = accel_boxes(scene, "bvh-sah", 1)
    assert len(lo1) == 1 and st1["drawn"] == 1
    lo, hi, lev, st = accel_boxes(scene, "bvh-sah", 3)
    assert set(lev) <= {1, 2, 3} and (lev == 2).sum() >= 2 and len(lo) == st["drawn"]
    # every box lies inside the root box, which bounds every primitive
    assert np.all(lo >= lo1[0] - 1e-9) and np.all(hi <= hi1[0] + 1e-9)
    for s in scene.shapes:
        if s.kind == "sphere":
            assert np.all(s.center - s.radius >= lo1[0] - 1e-9) and np.all(s.center + s.radius <= hi1[0] + 1e-9)


def test_grid_cells_are_the_occupied_ones():
    scene = load_scene(GRID)
    lo, hi, lev, st = accel_boxes(scene, "grid")
    assert st["occupied"] == len(lo) <= st["cells"]
    # every sphere's centre lies in a drawn cell
    for s in (s for s in scene.shapes if s.kind == "sphere"):
        assert np.any(np.all((lo <= s.center) & (s.center <= hi), axis=1))


def test_view_scene_png_shows_the_materials(tmp_path, capsys):
    out = tmp_path / "scene.png"
    code, text, err = run_cli(capsys, "view", CORNELL, "--out", out, "--size", "640x480")
    assert code == 0, err
    img = _png(out)
    assert img.shape == (480, 640, 3) and img.std() > 20
    # the red wall, shaded: pixels whose hue is red (R well above G and B)
    reddish = (img[..., 0] > img[..., 1] + 30) & (img[..., 0] > img[..., 2] + 30)
    assert reddish.sum() > 2000, reddish.sum()
    assert _near(img, [0, 191, 255], tol=30) > 200       # the camera frustum (deepskyblue)


def test_view_radiosity_and_bvh_and_html(tmp_path, capsys):
    out = tmp_path / "rad.png"
    code, text, err = run_cli(capsys, "view", CORNELL, "--radiosity", "--set", "patch_size=0.5",
                              "--out", out, "--size", "640x480")
    assert code == 0, err
    img = _png(out)
    colours = {tuple(c) for c in img.reshape(-1, 3)[::7] // 8}
    assert len(colours) > 60 and "patches" in text          # many patch colours, not flat shading
    out = tmp_path / "bvh.png"
    code, text, err = run_cli(capsys, "view", GRID, "--accel", "bvh-sah", "--depth", 3, "--out", out,
                              "--size", "640x480")
    assert code == 0, err
    img = _png(out)
    assert img.std() > 20 and "'drawn'" in text
    page = tmp_path / "v.html"
    code, _, err = run_cli(capsys, "view", GRID, "--out", page, "--size", "320x240")
    assert code == 0, err
    assert page.read_text().count("data:image/png;base64,") == 3


@pytest.mark.parametrize("args, cause", [
    (["--accel", "slabs"], "has no boxes to draw"),
    (["--accel", "kd"], "unknown structure 'kd'"),
    (["--out", "x.jpg"], "--out must end in .png or .html"),
    (["--size", "big"], "--size expects WIDTHxHEIGHT"),
])
def test_view_bad_arguments_one_line(tmp_path, capsys, args, cause):
    if "--out" not in args:
        args = args + ["--out", tmp_path / "x.png"]
    code, _, err = run_cli(capsys, "view", GRID, *args)
    assert cause in one_line_error(code, err)


def test_radiosity_suite_report_embeds_the_view(tmp_path):
    from gibench.suite import Case, Suite
    from gibench.view import suite_views
    from reports.html import render_report

    case = Case(scene=CORNELL, scene_id="cornell/cornell_box", algorithm="radiosity",
                params={"patch_size": 0.5}, transport="full", label="coarse", expect="report")
    suite = Suite(name="r", path=tmp_path / "r.toml", cases=(case,), study_set="radiosity")
    recs = suite_views(suite, size=(320, 240), log=None)
    assert len(recs) == 1 and len(recs[0].images) == 1
    assert recs[0].images[0]["src"].startswith("data:image/png;base64,")
    page = render_report(recs, root=tmp_path)
    assert recs[0].images[0]["src"] in page and "radiosity patches (coarse)" in page
    assert suite_views(Suite(name="x", path=tmp_path / "x.toml", cases=(case,)), log=None) == []
