"""The ``gibench`` command line.

    gibench algorithms
    gibench render SCENE --algorithm NAME [--spp N] [--seed S] [--set k=v ...] [-D name=value ...] --out FILE.exr
    gibench reference SCENE --transport full|direct|whitted [--spp N] [--passes P] [-D name=value ...]
    gibench compare IMAGE REFERENCE [--reference-variance V] [--test-variance V] [--json]
    gibench run [SUITE] [--no-mitsuba-timing] [-D name=value ...]

``-D name=value`` replaces the value of the scene's ``<default name=...>``
(as Mitsuba's own ``mitsuba -D name=value``); the reference renders with the
same values and its cache key includes them.
    gibench report [--run RUN_ID] [--out FILE.html]
    gibench baseline [SUITE] --out FILE [--seeds K]
    gibench check --baseline FILE [SUITE] [--speed-factor F]
    gibench sweep SCENE --algorithm A --grid key=v1,v2 [--grid ...] [--transport T]
    gibench leaderboard SCENE [--algorithms a,b] [--seeds K]
    gibench advise SCENE [--target RELMSE]      (--algorithm auto: render and sweep)
    gibench history [--metric M] [--scene S] [--algorithm A]
    gibench dashboard [--out FILE.html] [--benchmarks DIR]

``run``, ``check``, ``baseline`` and ``sweep`` take ``--jobs N`` (local
worker processes) or ``--executor dask://HOST:PORT`` (a Dask cluster) and
store every record in the history database (``--history``, default
``history.sqlite`` beside ``--results``, i.e. ``reports/out/history.sqlite``;
``--no-history`` to skip).

Errors in the input (a bad scene, a missing file, an image with NaN, an
unknown algorithm or parameter) print one line, ``gibench: error: <cause>``,
and exit with status 2; ``run`` exits with 1 when a check failed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from core.errors import GibenchError, UsageError

from core.provenance import REPO_ROOT, git_commit, machine, utc_now, versions

from . import registry

OUT_ROOT = REPO_ROOT / "reports" / "out"
RESULTS = OUT_ROOT / "results.jsonl"
SUITES = REPO_ROOT / "suites"


CLIError = UsageError


def _parse_sets(items) -> dict:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"--set expects key=value, got '{item}'")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _parse_defines(items) -> dict:
    """``-D name=value`` items -> ``{name: value}`` (Mitsuba's scene-parameter overrides)."""
    import re

    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"-D expects name=value, got '{item}'")
        k, v = (x.strip() for x in item.split("=", 1))
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", k):
            raise CLIError(f"-D name must be an identifier, got '{k}'")
        out[k] = v
    return out


def cmd_algorithms(args) -> int:
    for algo in registry.algorithms():
        o = registry.origin(algo.name)
        src = "" if o["source"] == "builtin" else f"; from {o.get('dist') or o.get('file') or o['source']}"
        print(f"{algo.name}  —  {algo.summary} ({algo.section}; transport: {algo.transport}{src})")
        print(algo.param_table())
        print()
    for name, cause in registry.broken().items():
        print(f"BROKEN plugin {name}: {cause}")
    return 0


def _reference_transport(value: str) -> str:
    """argparse type of ``reference --transport``: a fixed name or a canonical phong(...) name."""
    if value in ("full", "direct", "whitted"):
        return value
    from references.phong_reference import parse_phong_transport, phong_transport
    try:
        return phong_transport(parse_phong_transport(value))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _auto(scene, results=None) -> tuple[str, dict]:
    """``--algorithm auto``: the advised algorithm and parameters (:mod:`gibench.advise`),
    from the leaderboard records in the results store when there are any."""
    from reports.results import ResultStore

    from .advise import resolve_auto

    records = ResultStore(Path(results or RESULTS)).load()
    name, params = resolve_auto(scene, records=records)
    print(f"--algorithm auto: {name} {params}")
    return name, params


def cmd_advise(args) -> int:
    from reports.results import ResultStore

    from .advise import advise

    print(advise(args.scene, records=ResultStore(Path(args.results)).load(), target=args.target))
    return 0


def cmd_leaderboard(args) -> int:
    from reports.html import write_report
    from reports.results import ResultStore, new_run_id

    from .leaderboard import leaderboard_suite, leaderboard_table
    from .suite import run_suite

    try:
        ladder = tuple(int(x) for x in args.ladder.split(",") if x.strip())
    except ValueError:
        raise CLIError(f"--ladder expects comma-separated spp, got {args.ladder!r}") from None
    suite = leaderboard_suite(args.scene, algorithms=args.algorithms.split(",") if args.algorithms
                              else None, repeats=args.repeats, seeds=args.seeds, ladder=ladder)
    store = ResultStore(Path(args.results))
    run_id = new_run_id()
    print(f"gibench leaderboard {run_id}: {suite.name}, {len(suite.cases)} configurations")
    records = run_suite(suite, store, run_id=run_id, out_root=Path(args.results).parent,
                        mitsuba_timing=False, reference_store=args.store,
                        history=_history(args), command="leaderboard", **_run_common(args))
    out = Path(args.report) if args.report else Path(args.results).parent / "leaderboard" / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench — {suite.name}")
    print(leaderboard_table(records))
    print(f"report:  {out}")
    return 0


def cmd_render(args) -> int:
    from core.imageio import check_finite, write_exr
    from core.loader import load_scene
    from .runner import render_timed

    values = _parse_sets(args.set)
    if args.algorithm == "auto":
        name, advised = _auto(args.scene, getattr(args, "results", None))
        values = {**advised, **values}
        args.algorithm = name
    algo = registry.get(args.algorithm)
    if args.spp is not None:
        if algo.spp_param is None:
            raise CLIError(f"{algo.name} takes no --spp")
        values[algo.spp_param] = args.spp
    params = algo.parse_params(values)
    defines = _parse_defines(args.define)
    scene = load_scene(args.scene, defines=defines)
    if args.spp is None and algo.spp_param is not None and algo.spp_param not in values:
        # As Mitsuba: without --spp the scene's sampler sample_count (after -D) is used.
        params = algo.parse_params({**values, algo.spp_param: scene.camera.sample_count})
    external = registry.provenance(algo.name, params, defines=defines)
    result, timing = render_timed(algo, scene, params, seed=args.seed, repeats=args.repeats)
    check_finite(result.image, name=f"{algo.name} output")
    out = Path(args.out)
    write_exr(out, result.image)
    sidecar = {"scene": str(args.scene), "defines": defines, "algorithm": algo.name,
               "params": params, "seed": args.seed,
               "time": timing, "counters": result.counters, "versions": versions(),
               "commit": git_commit(), "machine": machine(), "created": utc_now(),
               "variance": None, "external": external}
    if result.variance is not None:
        var_path = out.with_suffix(".var.exr")
        write_exr(var_path, result.variance)
        sidecar["variance"] = str(var_path)
    out.with_suffix(".json").write_text(json.dumps(sidecar, indent=2))
    print(f"{out}: {scene.camera.film.width}x{scene.camera.film.height}, "
          f"median {timing['own_median_s'] * 1e3:.1f} ms over {timing['repeats']} repeats "
          f"(warm-up {timing['warmup_s']:.2f} s), counters {result.counters}")
    return 0


def cmd_reference(args) -> int:
    from references.reference import get_reference

    ref = get_reference(args.scene, transport=args.transport, spp=args.spp, passes=args.passes,
                        seed=args.seed, render_missing=True, force=args.force,
                        defines=_parse_defines(args.define))
    m = ref.manifest
    print(f"{ref.directory}: {m.get('transport')} ({m.get('integrator', {}).get('type')}), "
          f"{m.get('spp')} spp in {m.get('passes')} passes, variant {m.get('variant')}, "
          f"{(m.get('wall_time_s') or {}).get('total', float('nan')):.2f} s")
    return 0


def _find_variance(image: Path) -> Path | None:
    for cand in (image.with_suffix(".var.exr"), image.parent / "variance.exr"):
        if cand != image and cand.is_file() and image.name != "variance.exr":
            return cand
    return None


def _read_variance(path: Path):
    """A variance image: finite and non-negative, else a one-line :class:`ImageError`."""
    from core.imageio import ImageError, read_exr

    v = read_exr(path, allow_nonfinite=False)
    if (v < 0).any():
        raise ImageError(f"{path}: a variance image holds negative values")
    return v


def cmd_compare(args) -> int:
    from reports.metrics import compare

    from core.imageio import ImageError, read_exr
    from references.store import EntryInvalid, is_entry, read_entry

    test_path, ref_path = Path(args.image), Path(args.reference)
    entry = ref_path if ref_path.is_dir() else (
        ref_path.parent if ref_path.name == "image.exr" and is_entry(ref_path.parent) else None)
    test = read_exr(test_path, allow_nonfinite=False)
    if entry is not None:
        # A store entry is read through the store's checks (key, image hashes, finite, shapes).
        try:
            ref, ref_var, _ = read_entry(entry)
        except EntryInvalid as exc:
            raise ImageError(f"{entry}: stored reference not usable: {exc}") from None
        ref_path, rv = entry / "image.exr", entry / "variance.exr"
    else:
        ref = read_exr(ref_path, allow_nonfinite=False)
        rv = _find_variance(ref_path)
        ref_var = _read_variance(rv) if rv else None
    if args.reference_variance:
        rv = Path(args.reference_variance)
        ref_var = _read_variance(rv)
    tv = Path(args.test_variance) if args.test_variance else _find_variance(test_path)
    metrics = compare(ref, test, reference_variance=ref_var,
                      test_variance=_read_variance(tv) if tv else None)
    if args.json:
        print(json.dumps(metrics, indent=2, default=str))
        return 0
    print(f"test      {test_path}" + (f" (variance {tv})" if tv else ""))
    print(f"reference {ref_path}" + (f" (variance {rv})" if rv else " (no variance: no Z-test)"))
    for k, v in metrics.items():
        if k in ("ztest", "conventions"):
            continue
        print(f"  {k:<12} {v:.6g}" if isinstance(v, float) else f"  {k:<12} {v}")
    z = metrics.get("ztest")
    if z:
        print(f"  Z-test       {'pass' if z['passed'] else 'FAIL'}: {z['fraction']:.5f} consistent "
              f"(need {z['min_fraction']}, alpha {z['alpha']}, Šidák over {z['n']} entries)")
    for k, v in metrics["conventions"].items():
        print(f"  [{k}: {v}]")
    return 0


def _resolve_suite(name: str) -> Path:
    p = Path(name)
    if p.exists():
        return p
    cand = SUITES / (name if name.endswith(".toml") else f"{name}.toml")
    return cand if cand.exists() else p


def _history(args):
    """The open history database of a command (None with --no-history)."""
    if getattr(args, "no_history", False):
        return None
    import os

    from .history import connect

    if getattr(args, "history", None):
        return connect(args.history)
    if not os.environ.get("GIBENCH_HISTORY") and getattr(args, "results", None):
        # Beside the results file: reports/out/history.sqlite for the default results.
        return connect(Path(args.results).parent / "history.sqlite")
    return connect()


def _run_common(args) -> dict:
    return dict(jobs=args.jobs, executor=args.executor,
                progress=False if args.no_progress else None)


def cmd_run(args) -> int:
    from reports.html import write_report
    from reports.results import ResultStore, new_run_id

    from .suite import load_suite, run_suite

    defines = _parse_defines(args.define)
    if args.scenes:                    # a directory of arbitrary scene files (gibench.scene_dir)
        from .scene_dir import cmd_run_scenes

        return cmd_run_scenes(args, results=Path(args.results), defines=defines)
    from .scene_dir import refuse_without_scenes

    refuse_without_scenes(args)
    suite = load_suite(_resolve_suite(args.suite))
    if args.ladder is not None:
        import dataclasses

        try:
            spps = tuple(int(x) for x in args.ladder.split(",") if x.strip())
        except ValueError:
            raise CLIError(f"--ladder expects comma-separated spp, got {args.ladder!r}") from None
        if any(x < 1 for x in spps):
            raise CLIError(f"--ladder spp must be positive, got {args.ladder!r}")
        suite = dataclasses.replace(suite, ladder=spps)
    store = ResultStore(Path(args.results))
    run_id = new_run_id()
    history = _history(args)
    print(f"gibench run {run_id}: suite '{suite.name}' ({len(suite.cases)} cases) from {suite.path}")
    records = run_suite(suite, store, run_id=run_id, out_root=Path(args.results).parent,
                        mitsuba_timing=not args.no_mitsuba_timing, reference_store=args.store,
                        defines=defines, history=history, command="run", **_run_common(args))
    if suite.study_set in ("radiosity", "accel") and not args.no_views:
        from .view import suite_views

        for rec in suite_views(suite):        # 3D views in the report (not in the history)
            rec.run_id = run_id
            store.append(rec)
            records.append(rec)
    out = Path(args.report) if args.report else Path(args.results).parent / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench — suite {suite.name}")
    cases = [r for r in records if r.kind == "case"]
    n_err = sum(1 for r in cases if r.error)
    failed = [(r.scene, c["name"]) for r in cases for c in r.failed_checks]
    print(f"results: {args.results} (run {run_id})")
    print(f"report:  {out}")
    if n_err or failed:
        for scene, name in failed:
            print(f"FAILED: {scene}: {name}")
        print(f"{len(failed)} failed checks, {n_err} cases with errors")
        return 1
    checks = sum(len(r.checks) for r in cases)
    print(f"all {checks} checks passed")
    return 0


def _baseline_suite(args, baseline: dict | None = None):
    from .suite import load_suite

    name = args.suite
    if name is None and baseline is not None:
        name = str(REPO_ROOT / baseline["suite_file"]) if baseline.get("suite_file") else baseline["suite"]
    import dataclasses

    # baseline and check choose their own seeds: one record per case and run.
    return dataclasses.replace(load_suite(_resolve_suite(name or "ci")), seeds=1)


def cmd_baseline(args) -> int:
    from reports.results import ResultStore, new_run_id

    from .check import make_baseline, write_baseline
    from .suite import _rel, run_suite

    if args.seeds < 1:
        raise CLIError(f"--seeds must be >= 1, got {args.seeds}")
    suite = _baseline_suite(args)
    store = ResultStore(Path(args.results))
    history = _history(args)
    seeds = list(range(args.seeds))
    runs = []
    for seed in seeds:
        run_id = new_run_id()
        print(f"gibench baseline {run_id}: suite '{suite.name}', seed {seed}")
        runs.append(run_suite(suite, store, run_id=run_id, out_root=Path(args.results).parent,
                              mitsuba_timing=(seed == 0 and not args.no_mitsuba_timing),
                              reference_store=args.store, seed=seed,
                              history=history if seed == 0 else None, command="baseline",
                              ladder=False, **_run_common(args)))
    doc = make_baseline(runs, suite=suite.name, suite_file=_rel(suite.path), seeds=seeds)
    out = write_baseline(doc, args.out)
    print(f"baseline: {out} ({len(doc['cases'])} cases, seeds {seeds})")
    return 0


def cmd_check(args) -> int:
    from reports.html import write_report
    from reports.results import ResultStore, new_run_id

    from .check import compare_with_baseline, format_findings, read_baseline, write_evidence
    from .suite import run_suite

    baseline = read_baseline(args.baseline)
    suite = _baseline_suite(args, baseline)
    store = ResultStore(Path(args.results))
    run_id = new_run_id()
    history = _history(args)
    print(f"gibench check {run_id}: suite '{suite.name}' ({len(suite.cases)} cases) "
          f"against {args.baseline} (commit {baseline.get('commit')})")
    records = run_suite(suite, store, run_id=run_id, out_root=Path(args.results).parent,
                        mitsuba_timing=not args.no_mitsuba_timing, reference_store=args.store,
                        history=history, command="check", ladder=False, **_run_common(args))
    out = Path(args.report) if args.report else Path(args.results).parent / "check" / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench check — suite {suite.name}")
    findings = compare_with_baseline(records, baseline, speed_factor=args.speed_factor)
    print(format_findings(findings, all_rows=args.all))
    failed = [f for f in findings if f.failed]
    import dataclasses

    from core.imageio import write_text

    write_text(out.parent / "check.json", json.dumps(
        {"run_id": run_id, "baseline": str(args.baseline), "passed": not failed,
         "findings": [dataclasses.asdict(f) for f in findings]}, indent=1, default=str) + "\n")
    print(f"report:  {out}")
    if failed:
        from .check import case_key

        bad = {f.case for f in failed}
        for r in records:
            if case_key(r) in bad and r.ok:
                ev = write_evidence(r, out.parent / "evidence")
                if ev is not None:
                    print(f"evidence: {ev}")
        print(f"check FAILED: {len(failed)} of {len(findings)} comparisons in {len(bad)} cases")
        return 1
    print(f"check passed: {len(findings)} comparisons over {len(baseline['cases'])} cases")
    return 0


def cmd_sweep(args) -> int:
    from reports.html import write_report
    from reports.results import ResultStore, new_run_id

    from .sweep import parse_grid, sweep_suite, sweep_table
    from .suite import run_suite

    base = _parse_sets(args.set)
    if args.algorithm == "auto":
        name, advised = _auto(args.scene, args.results)
        args.algorithm = name
        base = {**{k: v for k, v in advised.items()
                   if not any(g.split("=", 1)[0].strip() == k for g in args.grid)}, **base}
    algo = registry.get(args.algorithm)
    grid = parse_grid(args.grid, algo)
    suite = sweep_suite(args.scene, algo, grid, transport=args.transport,
                        reference_spp=args.reference_spp, reference_passes=args.reference_passes,
                        repeats=args.repeats, ladder=args.ladder, base_params=base,
                        ladder_samplers=tuple(x.strip() for x in args.ladder_samplers.split(",")
                                              if x.strip()),
                        seeds=args.seeds)
    store = ResultStore(Path(args.results))
    run_id = new_run_id()
    print(f"gibench sweep {run_id}: {suite.name}, {len(suite.cases)} configurations")
    records = run_suite(suite, store, run_id=run_id, out_root=Path(args.results).parent,
                        mitsuba_timing=not args.no_mitsuba_timing, reference_store=args.store,
                        history=_history(args), command="sweep", **_run_common(args))
    out = Path(args.report) if args.report else Path(args.results).parent / "sweep" / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench sweep — {suite.name}")
    print(sweep_table(records, metric=args.metric))
    print(f"report:  {out}")
    return 1 if any(r.error for r in records) else 0


def cmd_history(args) -> int:
    from .history import format_table, query

    con = _history(args) if not args.no_history else None
    if con is None:
        raise CLIError("history needs the database (drop --no-history)")
    rows = query(con, metric=args.metric, scene=args.scene, algorithm=args.algorithm,
                 limit=args.limit)
    if not rows:
        print("no matching records in the history database")
        return 0
    print(format_table(rows, metric=args.metric or "relmse"))
    return 0


def cmd_dashboard(args) -> int:
    from reports.dashboard import write_dashboard

    from .history import benchmark_rows, ingest_benchmarks, query

    con = _history(args)
    if con is None:
        raise CLIError("dashboard needs the database (drop --no-history)")
    for bench in args.benchmarks or [str(REPO_ROOT / ".benchmarks"), str(OUT_ROOT / "bench*.json")]:
        n = ingest_benchmarks(con, bench)
        print(f"benchmarks: {n} new rows from {bench}")
    out = write_dashboard(query(con), benchmark_rows(con), args.out, metrics=args.metric or None)
    print(f"dashboard: {out}")
    return 0


def cmd_report(args) -> int:
    from reports.html import write_report
    from reports.results import ResultStore

    store = ResultStore(Path(args.results))
    run_id = args.run or store.latest_run_id()
    if run_id is None:
        raise CLIError(f"{args.results}: no results yet (run 'gibench run' first)")
    records = store.load(run_id)
    if not records:
        raise CLIError(f"{args.results}: no records for run '{run_id}'")
    out = Path(args.out) if args.out else Path(args.results).parent / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench — run {run_id}")
    print(f"report: {out}")
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse, with a bad command line reported as one line and exit status 2."""

    def error(self, message):
        print(f"gibench: error: {self.prog.split()[-1] if ' ' in self.prog else 'gibench'}: "
              f"{message} (see --help)", file=sys.stderr)
        sys.exit(2)


def _positive(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text[:40]!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


#: Seeds are unsigned 32-bit integers (Mitsuba's sampler seed).
SEED_MAX = 2**32 - 1


def _seed(text: str) -> int:
    """An argparse type: a seed in [0, 2**32 - 1]."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text[:40]!r}") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"a seed must be in [0, {SEED_MAX}], got {text[:40]}")
    return v


def cmd_warmup(args) -> int:
    import os
    import time

    from .runner import warm_up

    t0 = time.perf_counter()
    print(f"gibench warmup: suites {', '.join(args.suites)}")
    rows = warm_up([_resolve_suite(s) for s in args.suites], jobs=args.jobs)
    bad = [r for r in rows if r["error"]]
    print(f"warmup: {len(rows)} renders in {time.perf_counter() - t0:.1f} s"
          + (f" ({args.jobs} processes)" if args.jobs > 1 else "") + ", numba cache "
          f"{os.environ.get('NUMBA_CACHE_DIR', '(numba default)')}"
          + (f", {len(bad)} failed" if bad else ""))
    return 1 if bad else 0


def cmd_view(args) -> int:
    from core.loader import load_scene

    from .view import write_view

    try:
        w, h = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise CLIError(f"--size expects WIDTHxHEIGHT, got {args.size!r}") from None
    scene = load_scene(args.scene, defines=_parse_defines(args.define))
    info = write_view(scene, args.out, radiosity=args.radiosity, accel=args.accel, depth=args.depth,
                      params=_parse_sets(args.set), size=(w, h))
    detail = {k: v for k, v in info.items() if k not in ("out", "seconds")}
    print(f"{info['out']}: {info['seconds']:.2f} s, {detail}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="gibench", description="Validation and benchmarking harness "
                                "for global-illumination algorithms, against Mitsuba 3 references.")
    p.add_argument("--renderers", action="append", metavar="FILE.toml",
                   help="register the named command renderers of this TOML file "
                   "(see gibench.external; also the GIBENCH_RENDERERS variable)")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("algorithms", help="list registered algorithms and their parameters")
    s.set_defaults(func=cmd_algorithms)

    s = sub.add_parser("render", help="render a scene with an own algorithm")
    s.add_argument("scene")
    s.add_argument("--algorithm", "-a", required=True, help="own algorithm, or auto (gibench advise)")
    s.add_argument("--spp", type=_positive, help="samples per pixel (default: the scene's sampler sample_count)")
    s.add_argument("--seed", type=_seed, default=0)
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="algorithm parameter")
    s.add_argument("--repeats", type=_positive, default=3, help="timed renders after the warm-up")
    s.add_argument("--out", "-o", required=True, help="output EXR (a .json sidecar is written beside it)")
    s.add_argument("-D", dest="define", action="append", metavar="NAME=VALUE",
                   help="override the scene's <default name=NAME> value (as Mitsuba's -D)")
    s.set_defaults(func=cmd_render)

    s = sub.add_parser("reference", help="render (or reuse) a Mitsuba reference")
    s.add_argument("scene")
    s.add_argument("--transport", type=_reference_transport, default="full",
                   help="full: Mitsuba path; direct: Mitsuba direct; whitted: delta bounces, then "
                        "direct light; phong(ka=..,ambient=..,ks=..,shininess=..,c1=..,c2=..,c3=..,"
                        "clamp=..): the matched Phong model (missing coefficients take the "
                        "algorithms' defaults)")
    s.add_argument("--spp", type=_positive, default=1024)
    s.add_argument("--passes", type=_positive, default=8)
    s.add_argument("--seed", type=_seed, default=0)
    s.add_argument("--force", action="store_true", help="re-render even if a valid entry exists")
    s.add_argument("-D", dest="define", action="append", metavar="NAME=VALUE",
                   help="override the scene's <default name=NAME> value (as Mitsuba's -D)")
    s.set_defaults(func=cmd_reference)

    s = sub.add_parser("compare", help="image metrics of IMAGE against REFERENCE")
    s.add_argument("image")
    s.add_argument("reference", help="an EXR, or a reference store directory")
    s.add_argument("--reference-variance")
    s.add_argument("--test-variance")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_compare)

    def common(s, *, mitsuba=True):
        s.add_argument("--results", default=str(RESULTS))
        s.add_argument("--report", help="HTML output (default: beside the results)")
        s.add_argument("--store", help="reference store directory (default: references/store)")
        s.add_argument("--history", help="history database (default: reports/out/history.sqlite)")
        s.add_argument("--no-history", action="store_true", help="do not store the records in it")
        s.add_argument("--jobs", "-j", type=_positive, default=1, help="local worker processes")
        s.add_argument("--executor", help="dask://HOST:PORT: run the cases on a Dask cluster")
        s.add_argument("--no-progress", action="store_true", help="no progress bar")
        if mitsuba:
            s.add_argument("--no-mitsuba-timing", action="store_true",
                           help="skip timing Mitsuba on the same scenes")

    s = sub.add_parser("baseline", help="run a suite with several seeds and write a CI baseline")
    s.add_argument("suite", nargs="?", default=None, help="suite (default: ci)")
    s.add_argument("--out", "-o", required=True, help="baseline JSON to write")
    s.add_argument("--seeds", type=_positive, default=3,
                   help="own-render seeds 0..K-1; their spread sets the tolerances")
    common(s)
    s.set_defaults(func=cmd_baseline)

    s = sub.add_parser("check", help="run a suite and compare with a baseline (exit 1 on regression)")
    s.add_argument("suite", nargs="?", default=None, help="suite (default: the baseline's)")
    s.add_argument("--baseline", "-b", required=True)
    s.add_argument("--speed-factor", type=float, help="fail when own/Mitsuba grows more than "
                   "this factor (default: the baseline's, 4)")
    s.add_argument("--all", action="store_true", help="show unchanged comparisons too")
    common(s)
    s.set_defaults(func=cmd_check)

    s = sub.add_parser("sweep", help="speed vs error over a parameter grid of one algorithm")
    s.add_argument("scene")
    s.add_argument("--algorithm", "-a", required=True, help="own algorithm, or auto (gibench advise)")
    s.add_argument("--grid", "-g", action="append", metavar="KEY=V1,V2,...", required=True)
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="fixed algorithm parameter")
    s.add_argument("--transport", choices=("full", "direct", "whitted"),
                   help="reference transport (default: the algorithm's)")
    s.add_argument("--reference-spp", type=_positive, default=1024)
    s.add_argument("--reference-passes", type=_positive, default=8)
    s.add_argument("--repeats", type=_positive, default=3)
    s.add_argument("--ladder", default="1,4,16,64,256", help="Mitsuba spp ladder ('' for none)")
    s.add_argument("--ladder-samplers", default="independent,stratified,multijitter,ldsampler",
                   help="Mitsuba samplers probed for the ladder; the best on the scene is used")
    s.add_argument("--seeds", type=_positive, default=3, help="own-render seeds per configuration")
    s.add_argument("--metric", default="relmse", help="error metric of the table")
    common(s)
    s.set_defaults(func=cmd_sweep)

    s = sub.add_parser("leaderboard", help="every own algorithm on one scene against full "
                       "transport, with each model's error floor")
    s.add_argument("scene")
    s.add_argument("--algorithms", help="comma-separated subset (default: every registered one)")
    s.add_argument("--seeds", type=int, default=3, help="own-render seeds per configuration")
    s.add_argument("--repeats", type=int, default=3)
    s.add_argument("--ladder", default="1,4,16,64", help="Mitsuba spp ladder")
    common(s, mitsuba=False)
    s.set_defaults(func=cmd_leaderboard)

    s = sub.add_parser("advise", help="the cheapest own algorithm whose model covers a scene")
    s.add_argument("scene")
    s.add_argument("--results", default=str(RESULTS), help="results store with leaderboard runs")
    s.add_argument("--target", type=float, help="relMSE to reach (default: Mitsuba's top ladder rung)")
    s.set_defaults(func=cmd_advise)

    s = sub.add_parser("history", help="metrics and times across commits, from the history database")
    s.add_argument("--metric", help="metric or time key (default relmse)")
    s.add_argument("--scene")
    s.add_argument("--algorithm")
    s.add_argument("--limit", type=_positive)
    s.add_argument("--history")
    s.add_argument("--no-history", action="store_true", help=argparse.SUPPRESS)
    s.set_defaults(func=cmd_history)

    s = sub.add_parser("dashboard", help="HTML dashboard of the history database and benchmarks")
    s.add_argument("--out", default=str(OUT_ROOT / "dashboard.html"))
    s.add_argument("--benchmarks", action="append",
                   help="pytest-benchmark JSON to ingest first: file, directory or glob "
                   "(default: .benchmarks/ and reports/out/bench*.json)")
    s.add_argument("--metric", action="append", help="metrics to plot (default relmse, flip, own time)")
    s.add_argument("--history")
    s.add_argument("--no-history", action="store_true", help=argparse.SUPPRESS)
    s.set_defaults(func=cmd_dashboard)

    s = sub.add_parser("run", help="run a suite against the stored references and write the report")
    s.add_argument("suite", nargs="?", default="default")
    s.add_argument("--no-views", action="store_true",
                   help="no 3D views in the report of the radiosity and scaling suites")
    s.add_argument("--ladder", help="Mitsuba spp ladder for the speed-vs-error plots, e.g. "
                   "1,4,16,64 (default: the suite's [suite] ladder; '' for none)")
    common(s)
    s.add_argument("-D", dest="define", action="append", metavar="NAME=VALUE",
                   help="override the scene's <default name=NAME> value in every scene (as Mitsuba's -D)")
    from .scene_dir import add_arguments as _scene_dir_arguments

    _scene_dir_arguments(s)           # --scenes DIR and its options
    s.set_defaults(func=cmd_run)

    s = sub.add_parser("warmup", help="compile the numba kernels the suites need (fills .numba_cache/)")
    s.add_argument("suites", nargs="*", default=["default", "ci"], help="suites (default: default ci)")
    s.add_argument("--jobs", "-j", type=int, default=1,
                   help="compile in N worker processes, an algorithm at a time each (default 1)")
    s.set_defaults(func=cmd_warmup)

    s = sub.add_parser("view", help="the scene, a radiosity solution or an acceleration "
                       "structure in 3D (pyvista, off screen)")
    s.add_argument("scene")
    s.add_argument("--out", "-o", default="view.png", help="FILE.png or FILE.html")
    s.add_argument("--radiosity", action="store_true", help="the solved patches, coloured by B")
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="radiosity parameter")
    s.add_argument("--accel", help="structure whose boxes to draw (bvh-sah, octree, grid, ...)")
    s.add_argument("--depth", type=int, default=3, help="tree levels drawn (root = 1)")
    s.add_argument("--size", default="1024x768", help="image size WIDTHxHEIGHT")
    s.add_argument("-D", dest="define", action="append", metavar="NAME=VALUE",
                   help="override the scene's <default name=NAME> value")
    s.set_defaults(func=cmd_view)

    s = sub.add_parser("report", help="write the HTML report of a stored run")
    s.add_argument("--run", help="run id (default: the latest)")
    s.add_argument("--results", default=str(RESULTS))
    s.add_argument("--out")
    s.set_defaults(func=cmd_report)
    return p


def main(argv=None) -> int:
    """Run the command line.  Bad input (:class:`core.errors.GibenchError`) prints one
    line ``gibench: error: <cause>`` and exits 2; any other exception is a bug and
    keeps its traceback."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:            # a bad command line (one line, see _Parser) or --help
        return exc.code if isinstance(exc.code, int) else 2
    try:
        for f in args.renderers or []:
            registry.add_renderer_file(f)
        return args.func(args)
    except GibenchError as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"gibench: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gibench: interrupted (results already appended are kept)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
