"""The CI accuracy gate: compare a run's metrics with a committed baseline.

``gibench baseline [SUITE] --out FILE`` runs a suite with ``--seeds K``
different own-render seeds (0 … K-1) and writes, per case, the seed-0
metrics, the spread of every gated metric over the K seeds, a tolerance per
metric derived from that spread, the Z-test verdict and the own/Mitsuba time
ratio.  ``gibench check --baseline FILE [SUITE]`` runs the suite once (seed
0) and fails when, for any case of the baseline,

* a gated error metric rises beyond its tolerance
  (``now > base * (1 + rel) + abs``; for SSIM and PSNR, which fall as the
  error rises, ``now < base * (1 - rel) - abs``),
* a Z-test that passed in the baseline now fails,
* the case errors, produces non-finite pixels or is missing from the run,
* the own/Mitsuba time ratio grew more than ``speed_factor`` times (speed
  is gated only on large regressions: timings on a shared 2-core machine
  move by tens of percent from run to run).

Tolerances from measured variation
----------------------------------
The own renderers are deterministic for a given seed, so a rerun of the same
commit on the same machine reproduces every metric exactly (``check`` on an
unchanged tree shows no movement at all).  What legitimately moves a metric
is a change that consumes random numbers differently (a new sampler, a
reordered loop) or a different float rounding (another machine or numba
version): the error of a Monte Carlo estimate then moves within its
seed-to-seed spread.  So the tolerance of a metric is ``rel = max(REL_FLOOR,
SPREAD_FACTOR * (max - min) / base)`` over the K seeds, plus a small
``abs = ABS_FLOOR[metric]`` for metrics near zero; deterministic
configurations (spread 0) get the floor.  ``K``, the factor and the floors
are stored in the baseline file with the measured spreads.

Evidence
--------
For each failing case the check writes, next to its report, in
``evidence/<case>/``: ``own.exr``, ``reference.exr``,
``reference_variance.exr``, ``own_variance.exr`` (when the algorithm gives
one), ``error.exr`` (``|own - reference|``) and ``pvalue.exr`` (the Z-test's
per-entry two-sided p-values).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from core.errors import StoreError
from core.imageio import write_text
from core.provenance import REPO_ROOT, git_commit, machine, utc_now, versions
from core.records import Record

__all__ = ["BASELINE_FORMAT", "GATED_HIGHER", "GATED_LOWER", "REL_FLOOR", "SPREAD_FACTOR",
           "ABS_FLOOR", "SPEED_FACTOR", "BaselineError", "Finding", "case_key", "make_baseline",
           "write_baseline", "read_baseline", "compare_with_baseline", "format_findings",
           "write_evidence"]

BASELINE_FORMAT = 1
#: Error metrics that rise with the error (gated upwards).
GATED_HIGHER = ("relmse", "rmse", "mae", "flip", "delta_e2000")
#: Quality metrics that fall as the error rises (gated downwards).
GATED_LOWER = ("ssim",)
#: Smallest relative tolerance (deterministic configurations have no spread).
REL_FLOOR = 0.02
#: Tolerance = SPREAD_FACTOR x the (max - min) spread over the baseline seeds.
SPREAD_FACTOR = 2.0
#: Absolute slack per metric, for values near zero.
ABS_FLOOR = {"relmse": 1e-6, "rmse": 1e-5, "mae": 1e-5, "flip": 1e-4, "delta_e2000": 1e-3,
             "ssim": 1e-4}
#: The check fails when own/Mitsuba grows by more than this factor.
SPEED_FACTOR = 4.0



class BaselineError(StoreError, ValueError):
    """A missing or malformed baseline file."""



def case_key(record: Record) -> str:
    """The identity of a case across runs: scene, algorithm, label, transport
    (not the parameters: a broken parameter must show as a moved metric)."""
    return " | ".join(str(v) for v in (record.scene, record.algorithm, record.label, record.transport))


def _num(x):
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else None


def _ratio(rec: Record):
    return _num(rec.time.get("ratio"))


def make_baseline(runs: list[list[Record]], *, suite: str, suite_file: str, seeds: list[int]) -> dict:
    """The baseline document from ``runs`` (one record list per seed; the first is seed 0)."""
    if not runs or len(runs) != len(seeds):
        raise ValueError(f"need one record list per seed, got {len(runs)} lists for seeds {seeds}")
    per_seed = [{case_key(r): r for r in recs if r.kind == "case"} for recs in runs]
    cases = {}
    for key, rec in per_seed[0].items():
        if rec.error:
            raise BaselineError(f"case '{key}' failed in the baseline run: {rec.error}")
        m = rec.metrics
        entry = {"scene": rec.scene, "algorithm": rec.algorithm, "label": rec.label,
                 "transport": rec.transport, "params": rec.params, "expect": rec.expect,
                 "metrics": {}, "spread": {}, "tolerance": {},
                 "ztest_passed": bool((m.get("ztest") or {}).get("passed")) if m.get("ztest") else None,
                 "time_ratio": _ratio(rec), "own_median_s": _num(rec.time.get("own_median_s"))}
        for name in GATED_HIGHER + GATED_LOWER:
            base = _num(m.get(name))
            if base is None or not math.isfinite(base):
                continue
            vals = [base] + [_num(s[key].metrics.get(name)) if key in s else None for s in per_seed[1:]]
            vals = [v for v in vals if v is not None and math.isfinite(v)]
            spread = max(vals) - min(vals)
            rel = max(REL_FLOOR, SPREAD_FACTOR * spread / abs(base)) if base else REL_FLOOR
            entry["metrics"][name] = base
            entry["spread"][name] = [min(vals), max(vals)]
            entry["tolerance"][name] = {"rel": rel, "abs": ABS_FLOOR.get(name, 0.0)}
        cases[key] = entry
    return {"format": BASELINE_FORMAT, "suite": suite, "suite_file": suite_file,
            "created": utc_now(), "commit": git_commit(), "machine": machine(), "versions": versions(),
            "seeds": list(seeds),
            "tolerance_method": (f"rel = max({REL_FLOOR}, {SPREAD_FACTOR} x (max - min) over seeds "
                                 f"{list(seeds)} / seed-0 value); abs per metric {ABS_FLOOR}; "
                                 f"speed: fail when own/Mitsuba grows > {SPEED_FACTOR}x"),
            "speed_factor": SPEED_FACTOR, "cases": cases}


def write_baseline(doc: dict, path) -> Path:
    path = Path(path)
    write_text(path, json.dumps(doc, indent=1, sort_keys=False) + "\n")
    return path


def read_baseline(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise BaselineError(f"{path}: baseline file not found (write one with 'gibench baseline')")
    try:
        doc = json.loads(path.read_text())
    except ValueError as exc:
        raise BaselineError(f"{path}: malformed baseline JSON: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("cases"), dict):
        raise BaselineError(f"{path}: not a gibench baseline (no 'cases' table)")
    if doc.get("format") != BASELINE_FORMAT:
        raise BaselineError(f"{path}: baseline format {doc.get('format')!r}, expected {BASELINE_FORMAT}")
    return doc


@dataclass
class Finding:
    """One compared quantity of one case."""
    case: str
    what: str             # metric name, 'ztest', 'speed ratio', 'case'
    baseline: object
    now: object
    limit: str
    failed: bool
    note: str = ""

    @property
    def moved(self) -> bool:
        a, b = _num(self.baseline), _num(self.now)
        if a is None or b is None:
            return self.baseline != self.now
        return not (a == b or (math.isfinite(a) and math.isfinite(b)
                               and abs(a - b) <= 1e-9 * max(abs(a), abs(b))))


def compare_with_baseline(records: list[Record], baseline: dict, *,
                          speed_factor: float | None = None) -> list[Finding]:
    """Every finding of ``records`` against ``baseline`` (failed or not)."""
    speed_factor = float(speed_factor or baseline.get("speed_factor") or SPEED_FACTOR)
    now = {case_key(r): r for r in records if r.kind == "case"}
    out: list[Finding] = []
    for key, base in baseline["cases"].items():
        rec = now.get(key)
        if rec is None:
            out.append(Finding(key, "case", "present", "missing", "must run", True,
                               "the case is not in this run (suite changed? regenerate the baseline)"))
            continue
        if rec.error:
            out.append(Finding(key, "case", "ok", "error", "no error", True, rec.error))
            continue
        m = rec.metrics
        if m.get("nan_count") or m.get("inf_count"):
            out.append(Finding(key, "finite image", "0 NaN/Inf",
                               f"{m.get('nan_count')} NaN, {m.get('inf_count')} Inf", "0", True))
        for name, b in base.get("metrics", {}).items():
            tol = base.get("tolerance", {}).get(name, {"rel": REL_FLOOR, "abs": 0.0})
            v = _num(m.get(name))
            if name in GATED_LOWER:
                lim = b * (1 - tol["rel"]) - tol["abs"]
                bad = v is None or not math.isfinite(v) or v < lim
                limit = f">= {lim:.4g}"
            else:
                lim = b * (1 + tol["rel"]) + tol["abs"]
                bad = v is None or not math.isfinite(v) or v > lim
                limit = f"<= {lim:.4g}"
            out.append(Finding(key, name, b, v, limit, bad, f"tolerance {tol['rel']:.3g} rel"))
        if base.get("ztest_passed") is not None:
            z = m.get("ztest") or {}
            passed = bool(z.get("passed"))
            out.append(Finding(key, "ztest", "pass" if base["ztest_passed"] else "fail",
                               "pass" if passed else "fail",
                               "pass" if base["ztest_passed"] else "any",
                               bool(base["ztest_passed"] and not passed),
                               f"fraction {z.get('fraction', float('nan')):.5f}"))
        rb, rn = _num(base.get("time_ratio")), _ratio(rec)
        if rb is not None and rn is not None and rb > 0:
            out.append(Finding(key, "speed ratio", rb, rn, f"<= {rb * speed_factor:.3g}",
                               rn > rb * speed_factor, "own / Mitsuba median time, same run"))
    return out


def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.5g}"
    return str(x)


def format_findings(findings: list[Finding], *, all_rows: bool = False) -> str:
    """The table of what moved (and every failure); ``all_rows`` shows unchanged rows too."""
    rows = [f for f in findings if all_rows or f.failed or f.moved]
    if not rows:
        return "nothing moved: every metric equals the baseline"
    w = max(len(f.case) for f in rows)
    w = min(w, 70)
    head = f"{'case':<{w}}  {'metric':<12} {'baseline':>11} {'now':>11} {'change':>9}  {'limit':<14} status"
    lines = [head, "-" * len(head)]
    for f in rows:
        a, b = _num(f.baseline), _num(f.now)
        change = (f"{(b - a) / abs(a) * 100:+.1f}%" if a not in (None, 0.0) and b is not None
                  and math.isfinite(a) and math.isfinite(b) else "")
        lines.append(f"{f.case[:w]:<{w}}  {f.what:<12} {_fmt(f.baseline):>11} {_fmt(f.now):>11} "
                     f"{change:>9}  {f.limit:<14} {'FAIL' if f.failed else 'ok'}"
                     + (f"  ({f.note})" if f.failed and f.note else ""))
    return "\n".join(lines)


def _slug(key: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in key.replace(" | ", "__"))[:120]


def write_evidence(record: Record, directory, *, root=REPO_ROOT) -> Path | None:
    """Write own / reference / variances / error map / p-value map EXRs of a failing
    case into ``directory/<case>/``; returns the folder (None without images)."""
    import numpy as np

    from reports.metrics import z_test

    from core.imageio import read_exr, write_exr

    def load(rel):
        if not rel:
            return None
        p = Path(rel) if Path(rel).is_absolute() else Path(root) / rel
        return read_exr(p) if p.is_file() else None

    ref_info = record.reference or {}
    own, ref = load(record.image), load(ref_info.get("image"))
    if own is None or ref is None:
        return None
    ref_var, own_var = load(ref_info.get("variance")), load(record.variance)
    out = Path(directory) / _slug(case_key(record))
    out.mkdir(parents=True, exist_ok=True)
    write_exr(out / "own.exr", own)
    write_exr(out / "reference.exr", ref)
    own_f = np.where(np.isfinite(own), own, 0.0)
    write_exr(out / "error.exr", np.abs(own_f - ref).astype(np.float32))
    if own_var is not None:
        write_exr(out / "own_variance.exr", own_var)
    if ref_var is not None:
        write_exr(out / "reference_variance.exr", ref_var)
        z = z_test(ref, own_f, reference_variance=ref_var, test_variance=own_var)
        write_exr(out / "pvalue.exr", np.nan_to_num(z.p_values, nan=0.0).astype(np.float32))
    (out / "case.json").write_text(json.dumps({k: getattr(record, k) for k in (
        "scene", "algorithm", "label", "transport", "params", "run_id", "commit")}, indent=1,
        default=str) + "\n")
    return out
