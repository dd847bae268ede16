"""The performance dashboard: each metric and time across commits, from the history
database (:mod:`gibench.history`), plus the pytest-benchmark microbenchmarks.

One self-contained HTML page (inline CSS, matplotlib plots as base64 PNG), in
the manner of asv's and Blender's benchmark pages: per scene, one plot per
metric with one line per algorithm configuration, the x axis the runs in date
order labelled by commit; then one plot per benchmark group of the median
time per benchmark across commits.  Timings from different machines are not
comparable; the machine of each run is listed in the table under the plots.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

from core.imageio import write_text

__all__ = ["render_dashboard", "write_dashboard", "DEFAULT_METRICS"]

DEFAULT_METRICS = ("relmse", "flip", "own_median_s", "ratio")
NAMES = {"relmse": "rel. MSE", "flip": "FLIP", "own_median_s": "own time [s]",
         "ratio": "own / Mitsuba time", "mae": "MAE", "ssim": "SSIM", "ztest_fraction": "Z-test fraction"}

CSS = """
body{font:14px/1.45 system-ui,sans-serif;color:#222;margin:0 auto;max-width:1500px;padding:1em 2em}
h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse}td,th{padding:.15em .5em;border-bottom:1px solid #e4e4e4;text-align:left;font-size:12px}
.small{font-size:12px;color:#666}img.plot{max-width:100%}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _value(row: dict, metric: str):
    v = row["metrics"].get(metric, row["times"].get(metric))
    return float(v) if isinstance(v, (int, float)) and math.isfinite(float(v)) else None


def _runs(rows: list[dict]) -> list[tuple[str, str]]:
    """(run_id, commit) in date order: the x axis."""
    seen = {}
    for r in rows:
        seen.setdefault(r["run_id"], (str(r["created"]), str(r["commit"])))
    return sorted(((rid, c) for rid, (d, c) in seen.items()), key=lambda x: seen[x[0]][0])


def _scene_plot(scene: str, rows: list[dict], metrics) -> str:
    from matplotlib.figure import Figure

    runs = _runs(rows)
    xi = {rid: i for i, (rid, _) in enumerate(runs)}
    fig = Figure(figsize=(4.0 * len(metrics), 3.2), dpi=90)
    for k, metric in enumerate(metrics):
        ax = fig.add_subplot(1, len(metrics), k + 1)
        series: dict[str, list] = {}
        for r in rows:
            v = _value(r, metric)
            if v is not None:
                series.setdefault(f"{r['algorithm']}: {r['label']}", []).append((xi[r["run_id"]], v))
        for name, pts in series.items():
            pts.sort()
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3, label=name[:40])
        if series and all(v > 0 for pts in series.values() for _, v in pts) and metric != "ssim":
            ax.set_yscale("log")
        ax.set_title(NAMES.get(metric, metric), fontsize=9)
        ax.set_xticks(range(len(runs)))
        ax.set_xticklabels([c[:8] for _, c in runs], rotation=60, fontsize=6)
        ax.grid(True, alpha=0.3)
        if k == 0 and series:
            ax.legend(fontsize=6)
    fig.suptitle(scene, fontsize=10)
    fig.tight_layout()
    return f"<img class='plot' alt='history {_e(scene)}' src='{_png(fig)}'>"


def _bench_plots(bench: list[dict]) -> str:
    from matplotlib.figure import Figure

    groups: dict[str, list[dict]] = {}
    for b in bench:
        groups.setdefault(b.get("group") or "(no group)", []).append(b)
    out = []
    for g, rows in groups.items():
        commits = list(dict.fromkeys(f"{r['created']}|{r['commit']}" for r in
                                     sorted(rows, key=lambda r: str(r["created"]))))
        xi = {c: i for i, c in enumerate(commits)}
        fig = Figure(figsize=(7.5, 3.4), dpi=90)
        ax = fig.add_subplot(1, 1, 1)
        series: dict[str, list] = {}
        for r in rows:
            if isinstance(r.get("median_s"), (int, float)):
                series.setdefault(r["name"], []).append((xi[f"{r['created']}|{r['commit']}"],
                                                         r["median_s"]))
        for name, pts in series.items():
            pts.sort()
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3,
                    label=name.split("::")[-1][:40])
        ax.set_yscale("log")
        ax.set_ylabel("median [s]")
        ax.set_xticks(range(len(commits)))
        ax.set_xticklabels([str(c.split("|")[1])[:8] for c in commits], rotation=60, fontsize=6)
        ax.set_title(f"benchmarks: {g}", fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
        fig.tight_layout()
        out.append(f"<img class='plot' alt='benchmarks {_e(g)}' src='{_png(fig)}'>")
    return "".join(out)


def render_dashboard(rows: list[dict], bench: list[dict], *, metrics=DEFAULT_METRICS,
                     title: str = "gibench dashboard") -> str:
    """The dashboard page for history ``rows`` (:func:`gibench.history.query`) and
    benchmark rows (:func:`gibench.history.benchmark_rows`)."""
    metrics = tuple(metrics or DEFAULT_METRICS)
    rows = [r for r in rows if not r.get("error") and r.get("kind", "case") == "case"]
    scenes: dict[str, list[dict]] = {}
    for r in rows:
        scenes.setdefault(str(r["scene"]), []).append(r)
    runs = _runs(rows)
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_e(title)}</title>"
             f"<style>{CSS}</style></head><body><h1>{_e(title)}</h1>"
             f"<p class='small'>{len(rows)} results from {len(runs)} runs; {len(bench)} benchmark "
             "rows. Each metric and time across runs (date order, labelled by commit); timings "
             "are medians with warm-up excluded and compare only within one machine.</p>"]
    parts.append("<h2>Metrics and times across commits</h2>")
    if not scenes:
        parts.append("<p>No results in the history database yet (run <code>gibench run</code>).</p>")
    for scene, srows in scenes.items():
        parts.append(f"<h3>{_e(scene)}</h3>" + _scene_plot(scene, srows, metrics))
    parts.append("<h2>Microbenchmarks (pytest-benchmark)</h2>")
    parts.append(_bench_plots(bench) if bench else
                 "<p>No benchmark JSON ingested (run <code>pytest benchmarks --benchmark-autosave</code>; "
                 "the dashboard reads <code>.benchmarks/</code>).</p>")
    machines = {}
    for r in rows:
        machines.setdefault((r["run_id"], r["commit"], r["created"], r.get("command")),
                            r.get("machine") or {})
    parts.append("<h2>Runs</h2><table><tr><th>run</th><th>command</th><th>commit</th><th>date</th>"
                 "<th>machine</th></tr>" + "".join(
                     f"<tr><td>{_e(rid)}</td><td>{_e(cmd)}</td><td>{_e(c)}</td><td>{_e(d)}</td>"
                     f"<td>{_e((m or {}).get('host'))} — {_e((m or {}).get('cpu'))}</td></tr>"
                     for (rid, c, d, cmd), m in machines.items()) + "</table>")
    parts.append("</body></html>\n")
    return "".join(parts)


def write_dashboard(rows, bench, out_path, *, metrics=None) -> Path:
    """Write the dashboard of history ``rows`` and benchmark rows ``bench`` (as the
    history database returns them) to ``out_path`` (atomically)."""
    text = render_dashboard(rows, bench, metrics=metrics or DEFAULT_METRICS)
    return write_text(out_path, text)
