"""The HTML report and the dashboard open in a real browser: headless Chromium renders
each page to a PNG, and pixel statistics check that the image grid and the plots are
on screen (not just present in the markup).  The report's interactive image viewer
(reports.viewer) is driven by a script appended to the page (modes, flip, exposure,
zoom, pixel read-out), its state read back with ``--dump-dom``; with JavaScript off
the static triplet must be what shows.  Skipped, with the reason, where Chromium is
absent (Debian: ``apt-get install chromium``; setup.sh installs it).
"""

import json
import re
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


def _without_javascript(page):
    """A copy of ``page`` whose Content-Security-Policy forbids every script: the browser
    runs none, as with JavaScript switched off (headless Chromium's own switch,
    ``--blink-settings=scriptEnabled=false``, also stops its screenshot and DOM dump)."""
    text = page.read_text()
    csp = '<meta http-equiv="Content-Security-Policy" content="script-src \'none\'">'
    assert "<head>" in text
    out = page.with_name(page.stem + ".nojs.html")
    out.write_text(text.replace("<head>", "<head>" + csp, 1))
    return out


def _screenshot(page, out, height, *, javascript=True):
    if not javascript:
        page = _without_javascript(page)
    cmd = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--window-size=1280,{height}", f"--screenshot={out}", "--virtual-time-budget=5000",
           page.as_uri()]
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
    """With JavaScript off, the report is the static page: the image triplets show."""
    page = write_report(_records(tmp_path), tmp_path / "report.html", root=tmp_path)
    img = _screenshot(page, tmp_path / "report.png", 4200, javascript=False)
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


# --- the interactive image viewer ---------------------------------------------------------------

VW, VH = 32, 24


def _viewer_records(tmp_path):
    """One record whose reference is a horizontal ramp of magenta and own image 2 % brighter."""
    ramp = (1.0 + np.arange(VW) / VW)[None, :, None]
    ref = (np.broadcast_to(MAGENTA * 0.5, (VH, VW, 3)) * ramp).astype(np.float32)
    own = ref * np.float32(1.02)
    own[10, 20] = [4.0, 0.0, 0.0]                  # one wrong pixel: large relative error
    write_exr(tmp_path / "ref.exr", ref)
    write_exr(tmp_path / "own.exr", own)
    rec = Record(run_id="r1", scene="synthetic/ramp", kind="case", algorithm="algo",
                 label="ramp", image="own.exr", reference={"image": "ref.exr"})
    return [rec], ref, own


DRIVE = """
<script>
(function(){
 const box=document.querySelector('.gbv'), out={}, v=box.gbv, cv=v.canvas, W=%d, H=%d;
 const px=(x,y)=>Array.from(cv.getContext('2d').getImageData(x,y,1,1).data.slice(0,3));
 out.live=box.classList.contains('gbv-live');
 out.static_hidden=getComputedStyle(box.querySelector('.images')).display==='none';
 out.zoom0=cv.getBoundingClientRect().width/W;
 const r=cv.getBoundingClientRect();
 cv.dispatchEvent(new MouseEvent('mousemove',{clientX:r.left+(20.5)*r.width/W,clientY:r.top+(10.5)*r.height/H,bubbles:true}));
 out.readout=box.querySelector('.gbv-readout').textContent;
 v.set('own'); out.own=px(5,3);
 v.set('reference'); out.ref=px(5,3);
 v.flip(); out.flip_mode=box.dataset.mode;
 v.set('error'); out.err_bad=px(20,10); out.err_ok=px(5,3);
 v.set('own'); v.exposure(1); out.own_plus1=px(5,3); v.exposure(0);
 cv.dispatchEvent(new KeyboardEvent('keydown',{key:'4',bubbles:true})); out.key4_mode=box.dataset.mode;
 const r2=cv.getBoundingClientRect();
 cv.dispatchEvent(new MouseEvent('mousemove',{clientX:r2.left+(10.5)*r2.width/W,clientY:r2.top+5*r2.height/H,bubbles:true}));
 out.split_left=px(3,3); out.split_right=px(20,3);
 const z=+box.dataset.zoom; box.querySelector('button[data-zoom="1"]').click();
 out.zoom_ratio=cv.getBoundingClientRect().width/(W*z);
 document.body.setAttribute('data-result', JSON.stringify(out));
})();
</script></body>"""


def _srgb8(x):
    x = np.clip(x, 0, 1)
    return np.round(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))


def test_report_image_viewer_works_with_javascript(tmp_path):
    import matplotlib

    recs, ref, own = _viewer_records(tmp_path)
    page = write_report(recs, tmp_path / "report.html", root=tmp_path)
    text = page.read_text()
    assert "http://" not in text and "https://" not in text.replace("https://github.com", "")
    driven = tmp_path / "driven.html"
    driven.write_text(text.replace("</body>", DRIVE % (VW, VH), 1))
    dom = subprocess.run([BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
                          "--virtual-time-budget=5000", driven.as_uri()],
                         capture_output=True, text=True, timeout=120).stdout
    m = re.search(r'data-result="([^"]*)"', dom)
    assert m, "the driving script did not finish: " + dom[-1500:]
    out = json.loads(m.group(1).replace("&quot;", '"'))
    assert out["live"] and out["static_hidden"]
    assert out["zoom0"] == 8                                   # 32 px wide -> x8 (256 px)
    # Pixel values under the cursor: own and reference at (20, 10), to half precision.
    nums = [float(x) for x in re.findall(r"[-+]?\d+\.?\d*(?:e[-+]?\d+)?", out["readout"])]
    assert nums[:2] == [20, 10], out["readout"]
    assert np.allclose(nums[2:5], own[10, 20], rtol=2e-3, atol=1e-3), out["readout"]
    assert np.allclose(nums[5:8], ref[10, 20], rtol=2e-3), out["readout"]
    # The displayed pixels: sRGB at the report's exposure (reference 99th percentile -> 1).
    exposure = 1.0 / np.percentile(ref.max(axis=2), 99)
    assert np.abs(np.array(out["own"]) - _srgb8(own[3, 5] * exposure)).max() <= 2, out["own"]
    assert np.abs(np.array(out["ref"]) - _srgb8(ref[3, 5] * exposure)).max() <= 2, out["ref"]
    assert out["own"] != out["ref"]
    assert np.abs(np.array(out["own_plus1"]) - _srgb8(own[3, 5] * exposure * 2)).max() <= 2
    assert out["flip_mode"] == "own" and out["key4_mode"] == "split"
    # Error mode: inferno of the relative error (1 at the wrong pixel, ~0.02 elsewhere).
    lut = (matplotlib.colormaps["inferno"](np.linspace(0, 1, 256))[:, :3] * 255).round()
    assert np.abs(np.array(out["err_bad"]) - lut[255]).max() <= 1
    e = np.mean(np.abs(own[3, 5] - ref[3, 5]) / (np.abs(ref[3, 5]) + 0.01))
    assert np.abs(np.array(out["err_ok"]) - lut[int(round(e * 255))]).max() <= 1
    # Split at x = 10: own on the left, reference on the right.
    assert np.abs(np.array(out["split_left"]) - _srgb8(own[3, 3] * exposure)).max() <= 2
    assert np.abs(np.array(out["split_right"]) - _srgb8(ref[3, 20] * exposure)).max() <= 2
    assert out["zoom_ratio"] == 2
    # On screen: the viewer's canvas (x8, nearest neighbour) shows the magenta ramp.
    img = _screenshot(page, tmp_path / "viewer.png", 1200)
    magenta = (img[..., 0] > 120) & (img[..., 2] > 120) & (img[..., 1] < img[..., 0] - 40)
    assert magenta.sum() > 0.8 * VW * VH * 64, f"viewer canvas not on screen ({magenta.sum()} px)"


def test_report_image_viewer_degrades_to_static_triplet(tmp_path):
    recs, _, _ = _viewer_records(tmp_path)
    page = write_report(recs, tmp_path / "report.html", root=tmp_path)
    img = _screenshot(page, tmp_path / "static.png", 1200, javascript=False)
    magenta = (img[..., 0] > 120) & (img[..., 2] > 120) & (img[..., 1] < img[..., 0] - 40)
    # Reference and own figures, 256 px wide each (the viewer would show one image).
    assert magenta.sum() > 2 * 0.8 * 256 * 192, f"static triplet not on screen ({magenta.sum()} px)"
    dom = subprocess.run([BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
                          _without_javascript(page).as_uri()],
                         capture_output=True, text=True, timeout=120).stdout
    assert 'class="gbv"' in dom and 'class="gbv gbv-live"' not in dom and '<div class="gbv-ui"' not in dom
