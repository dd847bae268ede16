"""A self-contained HTML report page for a list of result records.

Images are embedded as base64 PNG ``data:`` URIs and the CSS is inline, so the
page is one file that can be mailed or archived.  Records are
:class:`core.records.Record` (read back from the results store,
:mod:`reports.results`); a field left empty shows as "—".  Missing or
unreadable image files become a placeholder naming the file.

Display conventions: reference and own image of a record are tone-mapped with
:func:`reports.tonemap.tonemap_srgb` at one common exposure chosen so the 99th
percentile of the reference's largest channel maps to white.  The error map
shows ``|own − ref| / (ref + 0.01)`` averaged over channels, with the fixed
colour range [0, 1] (colormap ``inferno``; non-finite errors show as 1).
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections import Counter
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np

from core.imageio import ImageError, read_exr, write_text
from core.records import Record
from reports import viewer
from reports.tonemap import tonemap_srgb

__all__ = ["write_report", "fmt"]

DASH = "—"
ERR_RANGE = (0.0, 1.0)
ERR_EPS = 0.01
CMAP = "inferno"
MAX_DISPLAY_PX = 512
METRIC_ORDER = ["mse", "rmse", "relmse", "mae", "bias", "psnr", "ssim", "flip", "delta_e2000",
                "nan_count", "inf_count", "noise_floor", "noise_floor_relmse"]
METRIC_NAMES = {"mse": "MSE", "rmse": "RMSE", "relmse": "rel. MSE", "mae": "MAE", "bias": "bias",
                "psnr": "PSNR [dB]", "ssim": "SSIM", "flip": "FLIP", "delta_e2000": "ΔE2000",
                "nan_count": "NaN pixels", "inf_count": "Inf pixels", "noise_floor": "noise floor",
                "noise_floor_relmse": "rel. MSE noise floor"}
TIMING_NOTE = "warm-up excluded; medians of {n} repeats; 2-core shared machine: compare ratios"

CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",sans-serif;color:#222;margin:0 auto;max-width:1400px;padding:1em 2em}
h1{margin:.2em 0}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}h3{margin:1.2em 0 .4em}
table{border-collapse:collapse;margin:.4em 0}th,td{padding:.2em .6em;border-bottom:1px solid #e4e4e4;text-align:left;vertical-align:top}
th{background:#f4f4f4}td.n{text-align:right;font-variant-numeric:tabular-nums}
.meta td:first-child{color:#666}.small{font-size:12px;color:#666}
.data td{font-variant-numeric:tabular-nums;font-size:13px}
.pass{color:#187a2f;font-weight:600}.fail,.errtext{color:#c0392b;font-weight:600}
.tag{display:inline-block;border-radius:3px;padding:0 .4em;font-size:12px;background:#eee;color:#444;margin-left:.4em}
.tag.model{background:#fff3cd;color:#7a5b00}.tag.err{background:#f8d7da;color:#a12622}
.record{border:1px solid #e4e4e4;border-radius:6px;padding:.6em 1em;margin:1em 0}
.images{display:flex;flex-wrap:wrap;gap:1em}.images figure{margin:0}
.images img.im{width:256px;image-rendering:pixelated;display:block;background:#000}
figcaption{font-size:12px;color:#555;max-width:256px}
.placeholder{width:256px;height:160px;display:flex;align-items:center;justify-content:center;text-align:center;
 background:repeating-linear-gradient(45deg,#f6f6f6,#f6f6f6 8px,#eee 8px,#eee 16px);color:#a12622;font-size:12px;word-break:break-all;padding:.5em;box-sizing:border-box}
.tables{display:flex;flex-wrap:wrap;gap:2em}
pre.errtext{white-space:pre-wrap;background:#fdf0f0;padding:.6em;border-radius:4px}
"""


# --- formatting -------------------------------------------------------------------------------

def fmt(x, unit: str = "") -> str:
    """Format a number for display (3–4 significant digits, scientific when small or huge)."""
    if x is None or x == "":
        return DASH
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        s = f"{int(x):,}"
    elif isinstance(x, (float, np.floating)):
        x = float(x)
        if not math.isfinite(x):
            s = "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
        elif x == 0:
            s = "0"
        elif abs(x) < 1e-3 or abs(x) >= 1e6:
            s = f"{x:.3e}"
        elif abs(x) >= 1000:
            s = f"{x:.0f}"
        else:
            s = f"{x:.4g}"
    else:
        return html.escape(str(x))
    return s + (f" {unit}" if unit else "")


def _d(x) -> dict:
    return x if isinstance(x, dict) else {}


def _e(x) -> str:
    return DASH if x is None or x == "" else html.escape(str(x))


def _num(x):
    return x if isinstance(x, (int, float)) and not isinstance(x, bool) else None


def _kv_table(items, cls="meta") -> str:
    rows = "".join(f"<tr><td>{_e(k)}</td><td>{v}</td></tr>" for k, v in items)
    return f'<table class="{cls}">{rows}</table>' if rows else DASH


def _label(r: Record) -> str:
    return r.label or r.algorithm or DASH


def _checks(r: dict) -> list[dict]:
    c = r.checks
    return [x for x in c if isinstance(x, dict)] if isinstance(c, list) else []


def _scene(r: Record) -> str:
    return str(r.scene or DASH)


def _slug(s: str) -> str:
    return "scene-" + "".join(c if c.isalnum() else "-" for c in str(s))


# --- images -----------------------------------------------------------------------------------

def _png(arr, **kw) -> str:
    buf = io.BytesIO()
    mpimg.imsave(buf, arr, format="png", **kw)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _shrink(a: np.ndarray) -> np.ndarray:
    """Box-filter ``a`` by an integer factor so its longer side is at most MAX_DISPLAY_PX."""
    f = math.ceil(max(a.shape[:2]) / MAX_DISPLAY_PX)
    if f <= 1:
        return a
    h, w = a.shape[0] // f * f, a.shape[1] // f * f
    return a[:h, :w].reshape(h // f, f, w // f, f, *a.shape[2:]).mean(axis=(1, 3))


def _figure(src: str | None, alt: str, caption: str, problem: str = "") -> str:
    body = (f'<img class="im" src="{src}" alt="{alt}">' if src
            else f'<div class="placeholder">{html.escape(problem)}</div>')
    return f"<figure>{body}<figcaption>{caption}</figcaption></figure>"


def _colorbar() -> str:
    bar = np.tile(np.linspace(*ERR_RANGE, 256), (10, 1))
    return (f'<span class="small">{fmt(ERR_RANGE[0])} <img src="{_png(bar, cmap=CMAP, vmin=ERR_RANGE[0], vmax=ERR_RANGE[1])}" '
            f'alt="colour bar" style="width:160px;height:10px;vertical-align:middle"> ≥ {fmt(ERR_RANGE[1])}</span>')


class _Images:
    """Reads EXRs once per report; a failed read gives (None, one-line reason)."""

    def __init__(self, root: Path):
        self.root, self.cache = Path(root), {}

    def get(self, rel, what: str):
        if not rel:
            return None, f"no {what} image recorded"
        p = Path(rel) if Path(rel).is_absolute() else self.root / rel
        if p not in self.cache:
            try:
                self.cache[p] = (read_exr(p), "")
            except ImageError as exc:
                reason = f"missing {what} image file: {rel}" if not p.is_file() else str(exc)
                self.cache[p] = (None, reason)
        return self.cache[p]


def _image_row(r: dict, images: _Images, colorbar: str) -> str:
    ref, ref_err = images.get(_d(r.reference).get("image"), "reference")
    own, own_err = images.get(r.image, "own")
    base = ref if ref is not None else own
    exposure = 1.0
    if base is not None:
        finite = base.max(axis=2)[np.isfinite(base).all(axis=2)]
        p99 = float(np.percentile(finite, 99)) if finite.size else 0.0
        exposure = 1.0 / p99 if p99 > 0 else 1.0
    tm = f"sRGB, common exposure ×{fmt(exposure)} (reference 99th percentile → white)"
    figs = [_figure(_png(_shrink(tonemap_srgb(ref, exposure=exposure))) if ref is not None else None,
                    "reference", f"reference — {tm}", ref_err),
            _figure(_png(_shrink(tonemap_srgb(own, exposure=exposure))) if own is not None else None,
                    "own image", f"{html.escape(_label(r))} — {tm}", own_err)]
    cap = f"|own − ref| / (ref + {ERR_EPS}), mean over channels, range [0, 1]<br>{colorbar}"
    if ref is None or own is None:
        figs.append(_figure(None, "error map", cap, "no error map: " + (ref_err or own_err)))
    elif ref.shape != own.shape:
        figs.append(_figure(None, "error map", cap, f"no error map: shape {own.shape[:2]} ≠ reference {ref.shape[:2]}"))
    else:
        with np.errstate(all="ignore"):
            err = (np.abs(own.astype(np.float64) - ref) / (np.abs(ref) + ERR_EPS)).mean(axis=2)
        err = np.nan_to_num(err, nan=ERR_RANGE[1], posinf=ERR_RANGE[1])
        figs.append(_figure(_png(_shrink(err), cmap=CMAP, vmin=ERR_RANGE[0], vmax=ERR_RANGE[1]), "error map", cap))
        # Interactive comparison (reports.viewer); the static triplet stays for JavaScript off.
        return viewer.wrap(f'<div class="images">{"".join(figs)}</div>', _shrink(ref), _shrink(own),
                           exposure=exposure, err_eps=ERR_EPS, label=_label(r))
    return f'<div class="images">{"".join(figs)}</div>'


# --- tables -----------------------------------------------------------------------------------

def _ztest_cell(r: Record) -> str:
    z = _d(_d(r.metrics).get("ztest"))
    if not z:
        return DASH
    frac = _num(z.get("fraction"))
    s = f"{100 * frac:.1f}%" if frac is not None else DASH
    if r.model_error or r.expect == "report":
        # Only cases whose manifest expects the Z-test to pass are judged by it.
        return s + ' <span class="tag model">not judged</span>'
    passed = z.get("passed")
    if passed is None:
        return s
    return s + (' <span class="pass">pass</span>' if passed else ' <span class="fail">fail</span>')


def _checks_cell(r: Record) -> str:
    checks = _checks(r)
    if not checks:
        return DASH
    n_ok = sum(1 for c in checks if c.get("passed") is True)
    n_bad = len(checks) - n_ok
    return (f'<span class="pass">{n_ok} ✓</span>' if n_ok else "") + \
           (f' <span class="fail">{n_bad} ✗</span>' if n_bad else "")


def _tags(r: Record) -> str:
    t = ""
    if r.model_error:
        t += '<span class="tag model">model error (reported, not judged)</span>'
    if r.error:
        t += '<span class="tag err">run failed</span>'
    return t


def _summary(records: list[Record]) -> str:
    head = ("<tr><th>Scene</th><th>Algorithm</th><th>Transport</th><th>Rel. MSE</th><th>FLIP</th>"
            "<th>Z-test</th><th>Checks</th><th>Own [s]</th><th>Mitsuba [s]</th><th>Ratio</th></tr>")
    rows = []
    for r in records:
        m, t = _d(r.metrics), _d(r.time)
        rows.append(
            f'<tr><td><a href="#{_slug(_scene(r))}">{_e(_scene(r))}</a></td>'
            f"<td>{_e(_label(r))}{_tags(r)}</td><td>{_e(r.transport)}</td>"
            f'<td class="n">{fmt(m.get("relmse"))}</td><td class="n">{fmt(m.get("flip"))}</td>'
            f"<td>{_ztest_cell(r)}</td><td>{_checks_cell(r)}</td>"
            f'<td class="n">{fmt(t.get("own_median_s"))}</td><td class="n">{fmt(t.get("mitsuba_median_s"))}</td>'
            f'<td class="n">{fmt(t.get("ratio"))}</td></tr>')
    return f"<table>{head}{''.join(rows)}</table>"


def _metrics_table(r: Record) -> str:
    m = _d(r.metrics)
    keys = METRIC_ORDER + [k for k in m if k not in METRIC_ORDER and k not in ("ztest", "conventions")]
    items = [(METRIC_NAMES.get(k, k), fmt(m.get(k))) for k in keys]
    z = _d(m.get("ztest"))
    if z:
        detail = (f"{_ztest_cell(r)}<br><span class='small'>per-entry significance {fmt(z.get('significance'))}, "
                  f"α = {fmt(z.get('alpha'))}, required fraction {fmt(z.get('min_fraction'))}, "
                  f"n = {fmt(z.get('n'))}</span>")
    else:
        detail = DASH
    items.append(("Z-test", detail))
    conv = _d(m.get("conventions"))
    note = ("<p class='small'>Conventions: " + "; ".join(f"{_e(k)}: {_e(v)}" for k, v in conv.items()) + "</p>"
            if conv else "")
    return _kv_table(items) + note


def _time_table(r: Record) -> str:
    t = _d(r.time)
    times = t.get("own_times_s")
    times_s = ", ".join(fmt(x) for x in times) if isinstance(times, list) and times else DASH
    return _kv_table([
        ("own median", fmt(t.get("own_median_s"), "s")), ("own repeats", times_s + (" s" if times_s != DASH else "")),
        ("compile", fmt(t.get("compile_s"), "s")),
        ("setup (fixed cost)", fmt(t.get("own_setup_s"), "s")), ("trace", fmt(t.get("own_trace_s"), "s")), ("Mitsuba median", fmt(t.get("mitsuba_median_s"), "s")),
        ("Mitsuba spp", fmt(t.get("mitsuba_spp"))), ("ratio own/Mitsuba", fmt(t.get("ratio")))])


def _checks_table(r: Record) -> str:
    checks = _checks(r)
    if not checks:
        return ""
    rows = "".join(
        f"<tr><td>{_e(c.get('name'))}</td><td>{_e(c.get('expected'))}</td><td>"
        + ('<span class="pass">✓</span>' if c.get("passed") is True else '<span class="fail">✗</span>')
        + f"</td><td>{_e(c.get('detail'))}</td></tr>" for c in checks)
    return f"<h4>Checks</h4><table><tr><th>Check</th><th>Expected</th><th></th><th>Detail</th></tr>{rows}</table>"


def _record(r: dict, images: _Images, colorbar: str) -> str:
    ref = _d(r.reference)
    ref_desc = (f"reference {_e(ref.get('key'))}: Mitsuba {_e(ref.get('integrator'))}, "
                f"{fmt(ref.get('spp'))} spp, {_e(ref.get('variant'))}" if ref else "no reference recorded")
    params = _d(r.params)
    out = [f'<div class="record"><h3>{_e(_label(r))}{_tags(r)}</h3>',
           f"<p class='small'>algorithm {_e(r.algorithm)}; transport {_e(r.transport)}; {ref_desc}"
           + (f"; params: {_e(', '.join(f'{k}={v}' for k, v in params.items()))}" if params else "") + "</p>"]
    if r.error:
        out.append(f'<pre class="errtext">{_e(r.error)}</pre>')
    else:
        out.append(_image_row(r, images, colorbar))
    counters = _d(r.counters)
    out.append('<div class="tables">'
               f"<div><h4>Metrics</h4>{_metrics_table(r)}</div>"
               f"<div><h4>Counters</h4>{_kv_table((k, fmt(v)) for k, v in counters.items())}</div>"
               f"<div><h4>Time</h4>{_time_table(r)}</div></div>")
    out.append(_checks_table(r) + "</div>")
    return "".join(out)


def _rays_per_s(r: dict):
    """Own rays of every type (counters named ``*_rays``) per second of the median render."""
    rays = sum(v for k, v in _d(r.counters).items() if k.endswith("_rays") and isinstance(v, int))
    t = _num(_d(r.time).get("own_median_s"))
    return rays / t if rays and t else None


def _range(t: dict, side: str) -> str:
    """`` (min–max)`` of a timing side (``own``, ``mitsuba``: seconds; ``ratio``)."""
    lo, hi = (t.get("ratio_min"), t.get("ratio_max")) if side == "ratio" else (
        t.get(f"{side}_min_s"), t.get(f"{side}_max_s"))
    if not (isinstance(lo, (int, float)) and isinstance(hi, (int, float))):
        return ""
    unit = "" if side == "ratio" else "s"
    return f" <span class='small'>({fmt(lo, unit)}–{fmt(hi, unit)})</span>"


def _timing(records: list[Record]) -> str:
    rows, repeats = [], Counter()
    interleaved, loads = 0, []
    for r in sorted(records, key=lambda r: (_scene(r), str(r.transport))):
        t = _d(r.time)
        if t.get("own_median_s") is None and t.get("mitsuba_median_s") is None:
            continue
        if isinstance(t.get("own_times_s"), list):
            repeats[len(t["own_times_s"])] += 1
        spp = f" ({fmt(t.get('mitsuba_spp'))} spp)" if t.get("mitsuba_spp") is not None else ""
        interleaved += bool(t.get("interleaved"))
        loads += [x for x in (t.get("load_1min") or []) if isinstance(x, (int, float))]
        rows.append(f"<tr><td>{_e(_scene(r))}</td><td>{_e(r.transport)}</td><td>{_e(_label(r))}</td>"
                    f'<td class="n">{fmt(t.get("own_median_s"), "s")}{_range(t, "own")}</td>'
                    f'<td class="n">{fmt(t.get("mitsuba_median_s"), "s")}{spp}{_range(t, "mitsuba")}</td>'
                    f'<td class="n">{fmt(t.get("ratio"))}{_range(t, "ratio")}</td>'
                    f'<td class="n">{fmt(_rays_per_s(r))}</td></tr>')
    if not rows:
        return "<p>No timings recorded.</p>"
    ks = sorted(repeats)
    n = f"{ks[0]}–{ks[-1]}" if len(ks) > 1 else str(ks[0]) if ks else "N"
    return ("<table><tr><th>Scene</th><th>Transport</th><th>Algorithm</th><th>Own median</th>"
            "<th>Mitsuba median</th><th>Ratio own/Mitsuba</th><th>Own rays/s</th></tr>"
            + "".join(rows) + "</table>"
            f"<p class='small'>{TIMING_NOTE.format(n=n)}; in brackets the range of the timed renders "
            "(for the ratio: of the per-round ratios). Own and Mitsuba medians were timed in the same run "
            "on the same scene and transport"
            + (f"; {interleaved} of {len(rows)} rows in interleaved rounds (own and Mitsuba renders "
               "of a scene alternating)" if interleaved else "; not interleaved")
            + (f"; 1-minute load average {fmt(min(loads))}–{fmt(max(loads))} during the timings"
               if loads else "") + ".</p>")


def _header(records: list[Record], title: str) -> str:
    first = records[0] if records else Record()
    runs = list(dict.fromkeys(str(r.run_id) for r in records if r.run_id))
    fmt_dict = lambda d: ", ".join(f"{k} {v}" for k, v in _d(d).items()) or DASH  # noqa: E731
    return (f"<h1>{_e(title)}</h1>" + _kv_table([
        ("run", _e(", ".join(runs))), ("commit", _e(first.commit)), ("date", _e(first.created)),
        ("suite", _e(", ".join(dict.fromkeys(str(r.suite) for r in records if r.suite)))),
        ("machine", _e(fmt_dict(first.machine))), ("versions", _e(fmt_dict(first.versions))),
        ("records", str(len(records)))]))


# --- page -------------------------------------------------------------------------------------

def _pivot(rows: list[dict], spec: dict) -> str:
    """Rows as a table: one line per ``index`` combination, one column per value of
    ``columns``, cells the ``values`` joined by " / " (all rows when no spec)."""
    if not spec.get("columns"):
        keys = list(dict.fromkeys(k for r in rows for k in r))
        head = "".join(f"<th>{_e(k)}</th>" for k in keys)
        body = "".join("<tr>" + "".join(f"<td>{fmt(r.get(k)) if not isinstance(r.get(k), str) else _e(r[k])}</td>"
                                        for k in keys) + "</tr>" for r in rows)
        return f"<table class='data'><tr>{head}</tr>{body}</table>"
    index, col, values = list(spec.get("index", [])), spec.get("columns"), list(spec.get("values", []))
    cols = list(dict.fromkeys(r.get(col) for r in rows))
    lines: dict[tuple, dict] = {}
    for r in rows:
        cell = " / ".join(_e(r[v]) if isinstance(r.get(v), str) else fmt(r.get(v)) for v in values)
        lines.setdefault(tuple(r.get(k) for k in index), {})[r.get(col)] = cell
    head = "".join(f"<th>{_e(k)}</th>" for k in index) + "".join(f"<th>{_e(col)} = {fmt(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{_e(v) if isinstance(v, str) else fmt(v)}</td>" for v in key)
                   + "".join(f"<td>{cells.get(c, DASH)}</td>" for c in cols) + "</tr>"
                   for key, cells in lines.items())
    note = f"<p class='small'>cells: {_e(' / '.join(values))}</p>" if values else ""
    return f"<table class='data'><tr>{head}</tr>{body}</table>{note}"


def _plot(rows: list[dict], spec: dict) -> str:
    """A line plot of ``y`` against ``x`` with one line per ``series`` combination
    (log axes on request), as an embedded PNG; rows missing x or y are skipped.
    Points are joined in row order, so an error-vs-time curve follows the sweep
    (tessellation, patch count, spp) even where time is not monotonic."""
    from matplotlib.figure import Figure

    x, ys, series = spec["x"], spec["y"], list(spec.get("series", []))
    ys = [ys] if isinstance(ys, str) else list(ys)
    fig = Figure(figsize=(4.2 * len(ys), 3.2), dpi=100)
    for i, y in enumerate(ys):
        ax = fig.add_subplot(1, len(ys), i + 1)
        lines: dict[tuple, list] = {}
        for r in rows:
            xv, yv = _num(r.get(x)), _num(r.get(y))
            if xv is not None and yv is not None and math.isfinite(xv) and math.isfinite(yv):
                lines.setdefault(tuple(r.get(k) for k in series), []).append((xv, yv))
        for key, pts in lines.items():             # joined in row order (the study's sweep order)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3,
                    label=", ".join(map(str, key)) or y)
        if spec.get("logx"):
            ax.set_xscale("log")
        if spec.get("logy"):
            ax.set_yscale("log")
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.grid(True, alpha=0.3)
        if lines:
            ax.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    src = "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
    return f"<img alt='{_e(spec.get('title', y))}' src='{src}'>"


def _study(r: Record) -> str:
    if r.error:
        return f"<h3>{_e(r.title or r.study)}</h3><p class='fail'>{_e(r.error)}</p>"
    rows = [x for x in r.rows or [] if isinstance(x, dict)]
    plots = [p for p in (_d(r.pivot).get("plots") or []) if isinstance(p, dict) and "x" in p and "y" in p]
    return (f"<h3 id='{_slug('study-' + str(r.study))}'>{_e(r.title or r.study)}</h3>"
            f"<p>{_e(r.description)}</p>" + "".join(_plot(rows, p) for p in plots)
            + f"{_pivot(rows, _d(r.pivot))}"
            + "".join(f"<figure><img src='{_e(i.get('src'))}' alt='{_e(i.get('title'))}' style='max-width:100%'>"
                      f"<figcaption>{_e(i.get('title'))}</figcaption></figure>"
                      for i in r.images if isinstance(i, dict))
            + f"<p class='small'>{len(rows)} rows; study '{_e(r.study)}'</p>")


def _fmt_ratio(x, extrapolated: bool = False) -> str:
    if isinstance(x, float) and math.isnan(x):
        return DASH
    return ("~" if extrapolated else "") + fmt(x)


def _ee_cell(r: dict) -> str:
    """The equal-error ratio, or '> bound' when the error exceeds Mitsuba's cheapest rung's."""
    b = r.get("equal_error_lower_bound")
    if math.isnan(r["equal_error_time_ratio"]) and isinstance(b, float) and math.isfinite(b):
        return f"&gt; {fmt(b)}"
    return _fmt_ratio(r["equal_error_time_ratio"], r["equal_error_extrapolated"])


def _spread(p: dict) -> str:
    sd = p.get("spread")
    if isinstance(sd, float) and math.isfinite(sd):
        return f" <span class='small'>± {fmt(sd)} (n={p.get('seeds')})</span>"
    return ""


def _err_bar(p: dict) -> list[float]:
    """Lower and upper error bar of a point: the seeds' standard deviation, clipped at
    the error (log axes), zero without a spread."""
    sd = p.get("spread")
    if not (isinstance(sd, float) and math.isfinite(sd)):
        return [0.0, 0.0]
    return [min(sd, 0.9 * p["error"]), sd]


def _pareto_plot(scene, transport, g: dict, metric: str) -> str:
    from matplotlib.figure import Figure

    from reports.pareto import pareto_front

    fig = Figure(figsize=(6.4, 4.2), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    mi = g["mitsuba"]
    ax.plot([p["time"] for p in mi], [p["error"] for p in mi], "s-", color="#444", ms=4,
            label=f"Mitsuba {transport} ({g.get('sampler') or 'independent'} sampler, spp ladder)")
    for p in mi:
        if p.get("spp"):
            ax.annotate(f"{p['spp']}", (p["time"], p["error"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points", color="#444")
    spread = [p.get("spread") for p in mi]
    if any(isinstance(x, float) and math.isfinite(x) for x in spread):
        ax.errorbar([p["time"] for p in mi], [p["error"] for p in mi],
                    yerr=np.array([_err_bar(p) for p in mi]).T, fmt="none", ecolor="#444", lw=0.8)
    own = g["own"]
    if own:
        t = np.array([p["time"] for p in own])
        e = np.array([p["error"] for p in own])
        algos = list(dict.fromkeys(p["algorithm"] for p in own))
        colors = ["#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]
        for k, a in enumerate(algos):
            sel = [i for i, p in enumerate(own) if p["algorithm"] == a]
            ax.errorbar(t[sel], e[sel], yerr=np.array([_err_bar(own[i]) for i in sel]).T, fmt="o", ms=5, color=colors[k % len(colors)],
                        label=f"own {a}", zorder=3, lw=0.8)
        f = pareto_front(t, e)
        ax.plot(t[f], e[f], "-", color="#d62728", lw=1.5, label="own Pareto front", zorder=2)
        for p in own:
            ax.annotate(p["label"][:28], (p["time"], p["error"]), fontsize=6, xytext=(3, -8),
                        textcoords="offset points", color="#1f77b4")
    if g.get("noise_floor"):
        ax.axhline(g["noise_floor"], color="#2ca02c", ls="--", lw=1,
                   label=f"reference noise floor ({g['noise_floor']:.2g})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time [s] (median, warm-up excluded)")
    ax.set_ylabel(METRIC_NAMES.get(metric, metric))
    ax.set_title(f"{scene}: speed vs error", fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    src = "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
    return f"<img class='pareto' alt='speed vs error {_e(scene)}' src='{src}'>"


def _race_cell(race: dict | None) -> str:
    """A race to a Mitsuba rung's error: the ratio of medians, its spread, the rung."""
    if not race or not math.isfinite(race["ratio"]):
        return DASH
    win = race["ratio"] < 1
    spread = ""
    if race.get("spread") and math.isfinite(race["ratio_min"]):
        how = (f"{len(race['ratio_rounds'])} paired rounds" if race["spread"] == "paired"
               else "fastest vs slowest renders")
        spread = f" ({fmt(race['ratio_min'])}–{fmt(race['ratio_max'])}, {how})"
    warn = ""
    if not race.get("same_run"):
        warn = " <span class='fail'>points from different runs</span>"
    elif not race.get("interleaved"):
        warn = " <span class='small'>(not interleaved)</span>"
    return (f"{'<b>' if win else ''}{_fmt_ratio(race['ratio'], race['extrapolated'])}{'</b>' if win else ''}"
            f"<span class='small'>{spread}: {fmt(race['own_time'] * 1e3)} vs {fmt(race['time'] * 1e3)} ms "
            f"to {fmt(race['error'])}, Mitsuba {race['spp']} spp {_e(race.get('sampler') or '')}</span>{warn}")


def _headline(records: list[Record], metric: str = "relmse") -> str:
    """The report's leading table: per scene and transport with a Mitsuba ladder, the
    race to Mitsuba's most expensive ladder error (own time / Mitsuba time, ratio of
    median times measured in the same interleaved rounds, with its spread), and the
    own side's best equal-error time ratio and equal-time error ratio."""
    from reports.pareto import points_from_records, summarize_points, top_rung_race

    groups = points_from_records(records, metric=metric)
    if not groups:
        return ""
    rows = []
    for (scene, transport), g in groups.items():
        s = summarize_points(g["own"], g["mitsuba"])
        best = s["best"] or {}
        race = top_rung_race(g["own"], g["mitsuba"])
        seeds = sorted({p["seeds"] for p in g["own"]})
        mseeds = sorted({p["seeds"] for p in g["mitsuba"]})
        rows.append(
            f"<tr><td><a href='#{_slug('sve-' + scene + '-' + str(transport))}'>{_e(scene)}</a></td>"
            f"<td>{_e(transport)}</td><td>{_e(g.get('sampler') or 'independent')}</td>"
            f"<td class='n'>{_race_cell(race)}</td>"
            f"<td class='n'>{_fmt_ratio(best.get('equal_error_time_ratio', math.nan), best.get('equal_error_extrapolated', False))}</td>"
            f"<td class='small'>{_e(best.get('equal_error_label', DASH))}</td>"
            f"<td class='n'>{_fmt_ratio(best.get('equal_time_error_ratio', math.nan), best.get('equal_time_extrapolated', False))}</td>"
            f"<td class='n'>{'/'.join(map(str, seeds))} / {'/'.join(map(str, mseeds))}</td></tr>")
    return ("<h2 id='speed-vs-error-summary'>Speed against error</h2>"
            "<p class='small'>Each row: the own configurations on one scene against Mitsuba's "
            "spp ladder measured in the same run, with Mitsuba's most efficient sampler on that "
            "scene at the ladder's top rung (probed per scene; column <i>sampler</i>). "
            "<i>Equal error at Mitsuba's top rung</i>: the time the own Pareto front needs for "
            "the error of Mitsuba's most expensive rung (log–log interpolation between the own "
            "configurations' median times; ~ power-law extrapolation beyond them), over Mitsuba's "
            "median time for that rung; in brackets the range of the same ratio over the timing "
            "rounds, in which own and Mitsuba renders of the scene alternate (paired: each "
            "round's own and Mitsuba times were measured seconds apart). "
            "Best equal-error ratio = own time / Mitsuba's (interpolated) time for the same error; "
            "equal-time ratio = own error / Mitsuba's error in the same time (best own "
            "configuration of each; &lt; 1: the own side wins). "
            f"Errors ({_e(METRIC_NAMES.get(metric, metric))}) are means over the seeds "
            "(own / Mitsuba counts in the last column); times are medians with warm-up excluded."
            "</p><table class='data'><tr><th>scene</th><th>vs Mitsuba</th><th>sampler</th>"
            "<th>equal error at Mitsuba's top rung: t/t<sub>Mi</sub></th>"
            "<th>best equal-error t/t<sub>Mi</sub></th><th>(own config)</th><th>equal-time e/e<sub>Mi</sub></th>"
            "<th>seeds</th></tr>" + "".join(rows) + "</table>")


def _ms(p: dict) -> str:
    """Median time in ms with the range of the timed renders."""
    lo, hi = p.get("min_s"), p.get("max_s")
    rng = (f" <span class='small'>({fmt(lo * 1e3)}–{fmt(hi * 1e3)})</span>"
           if isinstance(lo, float) and isinstance(hi, float) and hi > lo else "")
    return fmt(p["time"] * 1e3) + rng


def _rung_races(g: dict) -> str:
    """The race to each rung's error (:func:`reports.pareto.rung_race`)."""
    from reports.pareto import rung_race

    rows = []
    for m in g["mitsuba"]:
        race = rung_race(g["own"], g["mitsuba"], spp=m.get("spp"))
        if race:
            rows.append(f"<tr><td class='n'>{m.get('spp')}</td><td class='n'>{fmt(m['error'])}</td>"
                        f"<td class='n'>{_race_cell(race)}</td><td class='small'>{_e(race['label'])}</td></tr>")
    if not rows:
        return ""
    return ("<p class='small'>Own time to reach the error of each Mitsuba rung over Mitsuba's time "
            "for it (ratio of medians; range over the paired timing rounds).</p>"
            "<table class='data'><tr><th>Mitsuba spp</th><th>error</th><th>t<sub>own</sub>/t<sub>Mi</sub></th>"
            "<th>nearest own configuration</th></tr>" + "".join(rows) + "</table>")


def _speed_vs_error(records: list[Record], metric: str = "relmse") -> str:
    """The speed-vs-error section: per scene/transport with a Mitsuba ladder, the plot
    and the table of efficiency and equal-error / equal-time ratios."""
    from reports.pareto import points_from_records, summarize_points

    groups = points_from_records(records, metric=metric)
    if not groups:
        return ""
    out = ["<h2 id='speed-vs-error'>Speed vs error</h2><p class='small'>Every own configuration "
           "(median wall time, warm-up excluded) and Mitsuba's own integrator at a ladder of spp, "
           "measured in the same run; log–log axes; the dashed line is the reference's own noise "
           "floor (errors near it cannot be resolved). Efficiency = 1 / (error × time). "
           "Equal-error time ratio = own time / Mitsuba's time for the same error, equal-time error "
           "ratio = own error / Mitsuba's error in the same time (log–log interpolation along "
           "Mitsuba's ladder; ~ marks a power-law extrapolation of its end segment beyond it; "
           "&gt; x: more error than Mitsuba's 1-spp render, which is x times faster); "
           "below 1 the own configuration wins.</p>"]
    for (scene, transport), g in groups.items():
        s = summarize_points(g["own"], g["mitsuba"])
        rows = "".join(
            f"<tr><td>{_e(r['label'])}</td><td class='n'>{fmt(r['error'])}{_spread(r)}</td>"
            f"<td class='n'>{_ms(r)}</td><td class='n'>{fmt(r['efficiency'])}</td>"
            f"<td>{'★' if r['pareto'] else ''}</td><td class='n'>{_ee_cell(r)}</td>"
            f"<td class='n'>{_fmt_ratio(r['equal_time_error_ratio'], r['equal_time_extrapolated'])}</td></tr>" for r in s["rows"])
        rows += "".join(
            f"<tr class='small'><td>{_e(r['label'])} ({_e(r.get('sampler', 'independent'))})</td><td class='n'>{fmt(r['error'])}{_spread(r)}</td>"
            f"<td class='n'>{_ms(r)}</td><td class='n'>{fmt(r['efficiency'])}</td>"
            f"<td></td><td></td><td></td></tr>" for r in s["mitsuba_rows"])
        best = s["best"]
        best_txt = (f"<p>Own best: equal-error time ratio <b>{_fmt_ratio(best['equal_error_time_ratio'], best['equal_error_extrapolated'])}</b> "
                    f"({_e(best['equal_error_label'])}); equal-time error ratio "
                    f"<b>{_fmt_ratio(best['equal_time_error_ratio'], best['equal_time_extrapolated'])}</b> ({_e(best['equal_time_label'])}).</p>"
                    if best else "<p class='small'>No own configuration falls inside Mitsuba's ladder.</p>")
        floors_html = _floors(g["own"])
        out.append(f"<h3 id='{_slug('sve-' + scene + '-' + str(transport))}'>{_e(scene)} vs Mitsuba {_e(transport)}</h3>"
                   + _pareto_plot(scene, transport, g, metric) + best_txt
                   + f"<table class='data pareto-table'><tr><th>configuration</th><th>{_e(METRIC_NAMES.get(metric, metric))}</th>"
                   "<th>time [ms] (range)</th><th>efficiency</th><th>front</th><th>t / t<sub>Mitsuba</sub> at equal error</th>"
                   f"<th>e / e<sub>Mitsuba</sub> at equal time</th></tr>{rows}</table>" + _rung_races(g)
                   + floors_html)
    return "".join(out)


def _floors(own: list[dict]) -> str:
    """Leaderboard rows: each algorithm's error at its most converged setting (an upper
    bound of its model-error floor) when a scene has several own algorithms."""
    from reports.pareto import model_floors

    floors = model_floors(own)
    if len(floors) < 2:
        return ""
    rows = "".join(
        f"<tr><td>{_e(a)}</td><td class='n'>{fmt(f['floor'])}</td><td>{_e(f['label'])}</td>"
        f"<td class='n'>{fmt(f['drop'])}</td></tr>"
        for a, f in sorted(floors.items(), key=lambda kv: kv[1]["floor"]))
    return ("<p class='small'>Model error floors: each algorithm's error at its most converged "
            "setting; <i>drop</i> = that error over the previous setting's (near 1: more samples "
            "no longer help, the rest is the model's error).</p><table class='data'><tr>"
            "<th>algorithm</th><th>error</th><th>at</th><th>drop</th></tr>" + rows + "</table>")


def render_report(records: list[Record], *, root, title: str = "gibench report") -> str:
    """The report page for ``records`` as an HTML string (image paths relative to ``root``).

    Records of ``kind == "study"`` (hard-case tables) get their own section.
    """
    from reports.pareto import primary_records

    records = list(records)
    bad = sorted({type(r).__name__ for r in records if not isinstance(r, Record)})
    if bad:
        raise TypeError(f"render_report takes core.records.Record items, got {', '.join(bad)}")
    studies = [r for r in records if r.kind == "study"]
    headline = _headline(records)
    pareto = _speed_vs_error(records)
    # Extra seeds feed the error means above; the tables and images below show the
    # judged (lowest) seed of each configuration.
    records = [r for r in primary_records(records) if r.kind not in ("study", "ladder")]
    images, colorbar = _Images(Path(root)), _colorbar()
    scenes: dict[str, list[Record]] = {}
    for r in records:
        scenes.setdefault(_scene(r), []).append(r)
    sections = []
    for scene, recs in scenes.items():
        files = ", ".join(dict.fromkeys(str(r.scene_file) for r in recs if r.scene_file))
        sections.append(f'<h2 id="{_slug(scene)}">{_e(scene)}</h2><p class="small">{_e(files)}</p>'
                        + "".join(_record(r, images, colorbar) for r in recs))
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{_e(title)}</title><style>{CSS}</style></head><body>"
            + _header(records or studies, title)
            + headline + pareto
            + ("<h2>Summary</h2>" + _summary(records) + "<h2>Timing</h2>"
               + _timing(records) if records or not studies else "")
            + "".join(sections)
            + ("<h2>Studies</h2>" + "".join(_study(r) for r in studies) if studies else "")
            + viewer.assets() + "</body></html>\n")


def write_report(records: list[Record], out_path, *, root, title: str = "gibench report") -> Path:
    """Write the self-contained report page for ``records`` to ``out_path`` atomically."""
    return write_text(out_path, render_report(records, root=root, title=title))
