"""The HTML report and the dashboard open in a real browser: headless Chromium renders
each page to a PNG, and pixel statistics check that the image grid and the plots are
on screen (not just present in the markup).  Skipped, with the reason, where
Chromium is absent (Debian: ``apt-get install chromium``).
"""

import shutil
import subprocess

import matplotlib.image as mpimg
import numpy as np
import pytest

from gibench.history import add_record, benchmark_rows, connect, query
from core.imageio import write_exr
from reports.dashboard import write_dashboard
from reports.html import write_report
from core.records import Record

BROWSER = next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome")
                if shutil.which(b)), None)
pytestmark = pytest.mark.skipif(
    BROWSER is None, reason="headless-browser test skipped: no chromium on PATH "
                            "(Debian: apt-get install chromium)")

# The own image's colour, tone-mapped: magenta (R and B saturate, G ~ 0.25 -> sRGB ~137).
MAGENTA = np.array([0.8, 0.2, 0.8])
C0_BLUE = np.array([31, 119, 180])       # matplotlib's first colour: own points, dashboard lines
FRONT_RED = np.array([214, 39, 40])      # the own Pareto front


def _screenshot(page, out, height):
    cmd = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--window-size=1280,{height}", f"--screenshot={out}", page.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.is_file(), f"chromium wrote no screenshot: {proc.stderr[-2000:]}"
    img = mpimg.imread(out)[..., :3]
    return (img * 255).round().astype(np.int32)


def _count_near(img, rgb, tol=12):
    return int(np.count_nonzero(np.all(np.abs(img - rgb) <= tol, axis=-1)))


def _records(tmp_path):
    ref = np.broadcast_to(MAGENTA, (32, 32, 3)).astype(np.float32).copy()
    own = ref * np.float32(1.02)
    write_exr(tmp_path / "ref.exr", ref)
    write_exr(tmp_path / "var.exr", np.full_like(ref, 1e-4))
    write_exr(tmp_path / "own.exr", own)
    base = {"run_id": "r1", "scene": "synthetic/magenta", "scene_file": "synthetic.xml",
            "transport": "full", "commit": "abc", "created": "2026-01-01T00:00:00",
            "machine": {"host": "h"}, "versions": {}, "error": None}
    recs = [Record(**base, kind="case", algorithm="algo", label=f"cfg {n}", params={"spp": n},
                 image="own.exr", reference={"image": "ref.exr", "variance": "var.exr"},
                 metrics={"relmse": 0.05 / n, "flip": 0.1, "noise_floor_relmse": 1e-4},
                 time={"own_median_s": 0.02 * n, "repeats": 3}, checks=[])
            for n in (1, 4, 16)]
    recs += [Record(**base, kind="ladder", algorithm="mitsuba", label=f"Mitsuba {n} spp",
                  ladder_spp=n, params={"spp": n}, metrics={"relmse": 0.1 / n},
                  time={"own_median_s": 0.01 * n}) for n in (1, 4, 16, 64)]
    return recs


def test_report_renders_image_grid_and_speed_vs_error_plot(tmp_path):
    page = write_report(_records(tmp_path), tmp_path / "report.html", root=tmp_path)
    img = _screenshot(page, tmp_path / "report.png", 4200)
    assert img.std() > 20, "blank screenshot"
    # Image grid: three records x (reference + own) at 256 px display width.
    magenta = ((img[..., 0] > 200) & (img[..., 1] > 90) & (img[..., 1] < 180)
               & (img[..., 2] > 200))
    assert magenta.sum() > 3 * 2 * 256 * 200, f"image grid not on screen ({magenta.sum()} px)"
    # The speed-vs-error plot: own points (blue) and the Pareto front (red).
    assert _count_near(img, C0_BLUE) > 100, "no own points drawn"
    assert _count_near(img, FRONT_RED) > 100, "no Pareto front drawn"


def test_dashboard_renders_plots(tmp_path):
    con = connect(tmp_path / "h.sqlite")
    for i, commit in enumerate(["aaa", "bbb", "ccc"]):
        add_record(con, Record.from_json({"run_id": f"r{i}", "commit": commit, "created": f"2026-01-0{i + 1}",
                         "scene": "spheres/lit_sphere", "algorithm": "raycast", "label": "cfg",
                         "transport": "direct", "params": {},
                         "metrics": {"relmse": 1e-3 * (i + 1), "flip": 0.1},
                         "time": {"own_median_s": 0.1, "ratio": 3.0}, "error": None}))
    page = write_dashboard(query(con), benchmark_rows(con), tmp_path / "dashboard.html")
    img = _screenshot(page, tmp_path / "dashboard.png", 1400)
    assert img.std() > 20, "blank screenshot"
    assert _count_near(img, C0_BLUE) > 200, "no history lines drawn"
