"""Run an own algorithm over a directory of arbitrary Mitsuba scene files.

``gibench run --scenes DIR --algorithm A [--set k=v] [-D name=value]``: every
``*.xml`` file directly in ``DIR`` (sorted by name; sub-directories are left
alone, as they usually hold ``<include>`` fragments, meshes and textures) is
one case of an in-memory suite.  Each file either

* loads in the own loader, is rendered by ``A`` and compared with a Mitsuba
  reference of ``A``'s transport (``direct`` for ``raycast``), rendered on
  demand into the reference store as for any suite (a full-transport ``A``
  with a ``max_depth`` takes the file's ``path`` integrator's ``max_depth``,
  as the reference does, unless ``--set`` gives one); or
* is listed as **skipped** with its one-line reason: the loader's error
  (``file:line: <element>: cause``: malformed XML, an unsupported plugin such
  as ``envmap``), the algorithm's refusal (``NotImplementedError``: a
  material it does not model), or Mitsuba's own error on the file.  The first
  two are found by :func:`preflight` (the algorithm on a 2x2 film) before any
  reference is rendered.

A bad file never stops the run: every failure of one case, whatever its type,
becomes that case's skip reason.  Records go to the results store and the HTML
report exactly as a suite run's do.

Options (added to ``gibench run`` by :func:`add_arguments`)
------------------------------------------------------------
==================  ========  =================================================
option              default   meaning
==================  ========  =================================================
``--scenes DIR``              run the scene files of DIR instead of a suite
``--algorithm/-a``  raycast   the own algorithm
``--set k=v``                 algorithm parameter (repeatable)
``--expect``        ztest     ``ztest``: the Z-test must pass; ``report``: only
                              report the metrics
``--reference-spp`` 1024      Mitsuba samples per pixel of each reference pass
``--passes``        8         reference passes (variance of the mean)
``--repeats``       1         timed own renders after the warm-up
==================  ========  =================================================
"""

from __future__ import annotations

import re
from pathlib import Path

from core.errors import UsageError
from core.provenance import REPO_ROOT
from core.records import Record

from . import registry
from .suite import EXPECTATIONS, Case, Suite, file_max_depth, run_case

__all__ = ["add_arguments", "refuse_without_scenes", "directory_suite", "preflight", "run_directory",
           "cmd_run_scenes"]


#: Defaults of the directory-run options (None on the parser, so that a suite run
#: can refuse them instead of ignoring them).
DEFAULTS = {"algorithm": "raycast", "set": None, "expect": "ztest", "reference_spp": 1024,
            "passes": 8, "repeats": 1}


def add_arguments(parser) -> None:
    """The ``gibench run`` options of a directory run (see the module docstring)."""
    parser.add_argument("--scenes", metavar="DIR", help="run every scene file of DIR "
                        "(rendered and compared, or listed as skipped with its reason)")
    parser.add_argument("--algorithm", "-a", help="own algorithm of --scenes (default raycast)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="algorithm parameter of --scenes")
    parser.add_argument("--expect", choices=EXPECTATIONS, help="expectation of --scenes (default ztest)")
    parser.add_argument("--reference-spp", type=int, help="reference spp of --scenes (default 1024)")
    parser.add_argument("--passes", type=int, help="reference passes of --scenes (default 8)")
    parser.add_argument("--repeats", type=int, help="timed renders of --scenes (default 1)")


def refuse_without_scenes(args) -> None:
    """A suite run takes its algorithms and parameters from the manifest: the
    directory-run options are an error there, not silently ignored."""
    given = [k for k in DEFAULTS if getattr(args, k, None) is not None]
    if given:
        opts = ", ".join("--" + k.replace("_", "-") for k in given)
        raise UsageError(f"{opts} only apply with --scenes DIR (a suite takes them from its manifest)")


def _scene_id(path: Path) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem)


def directory_suite(directory, algorithm: str, params: dict | None = None, *,
                    expect: str = "ztest", reference_spp: int = 1024, reference_passes: int = 8,
                    repeats: int = 1) -> Suite:
    """An in-memory suite with one case per ``*.xml`` file directly in ``directory``."""
    directory = Path(directory)
    if not directory.is_dir():
        raise UsageError(f"--scenes: not a directory: {directory}")
    algo = registry.get(algorithm)
    params = dict(params or {})
    algo.parse_params(params)                       # bad names/values stop here, before any render
    if expect not in EXPECTATIONS:
        raise UsageError(f"expect must be one of {EXPECTATIONS}, got {expect!r}")
    files = sorted(p for p in directory.glob("*.xml") if p.is_file())
    if not files:
        raise UsageError(f"--scenes: no *.xml scene files in {directory}")
    cases = []
    for p in files:
        own = {**params, **file_max_depth(p, algo, params)}
        cases.append(Case(scene=p.resolve(), scene_id=f"{directory.name}/{_scene_id(p)}",
                          algorithm=algo.name, params=own, transport=algo.transport,
                          label=f"{algo.name} {own}" if own else algo.name, expect=expect))
    cases = tuple(cases)
    return Suite(name=f"scenes:{directory.name}", path=directory.resolve(), cases=cases,
                 reference_spp=reference_spp, reference_passes=reference_passes, repeats=repeats,
                 description=f"every scene file of {directory}")


def preflight(case: Case, defines: dict | None = None) -> str | None:
    """Why the own side cannot run ``case`` (loader error, the algorithm's refusal),
    or None; found on a 2x2 copy of the film, before any Mitsuba reference is
    rendered for a file that would be skipped anyway.  It costs one render of 4
    pixels, plus whatever the algorithm computes independently of the view
    (radiosity meshes and solves the scene once more)."""
    import dataclasses

    from core.loader import load_scene

    try:
        algo = registry.get(case.algorithm)
        params = algo.parse_params(case.params)
        scene = load_scene(case.scene, defines=defines)
        film = dataclasses.replace(scene.camera.film, width=2, height=2)
        scene.camera = dataclasses.replace(scene.camera, film=film)
        algo.render(scene, params)
    except Exception as exc:  # noqa: BLE001 - any failure is this file's skip reason
        first = str(exc).splitlines()[0] if str(exc) else ""
        return first or type(exc).__name__
    return None


def _error_record(case, suite: Suite, run_id: str, reason: str) -> Record:
    """The record of a file that could not be rendered or compared."""
    return Record(run_id=run_id, suite=suite.name, scene=case.scene_id, scene_file=str(case.scene),
                  algorithm=case.algorithm, label=case.label, params=dict(case.params),
                  transport=case.transport, expect=case.expect, error=reason)


def run_directory(suite: Suite, store, *, run_id: str, out_root: Path, mitsuba_timing: bool = False,
                  reference_store=None, log=print, defines: dict | None = None):
    """Run every case of a :func:`directory_suite`; returns (records, skipped) where
    ``skipped`` is ``[(file name, one-line reason)]``.  Never raises for one file."""
    out_dir = out_root / "runs" / run_id
    records, skipped = [], []
    for i, case in enumerate(suite.cases):
        log(f"[{i + 1}/{len(suite.cases)}] {case.scene.name}")
        reason = preflight(case, defines)
        if reason is not None:
            rec = _error_record(case, suite, run_id, reason)
            try:
                store.append(rec)
            except (ValueError, TypeError, OSError) as exc:
                log(f"  record not stored: {type(exc).__name__}: {exc}")
            records.append(rec)
            skipped.append((case.scene.name, reason))
            log(f"  skipped: {reason}")
            continue
        try:
            rec = run_case(case, suite, run_id=run_id, out_dir=out_dir, mitsuba_timing=mitsuba_timing,
                           timing_cache={}, reference_store=reference_store, log=None,
                           defines=defines)
        except Exception as exc:  # noqa: BLE001 - one bad file must not stop the run
            first = str(exc).splitlines()[0] if str(exc) else ""
            rec = _error_record(case, suite, run_id, f"{type(exc).__name__}: {first}")
        try:
            store.append(rec)
        except (ValueError, TypeError, OSError) as exc:      # the run goes on; say what was lost
            log(f"  record not stored: {type(exc).__name__}: {exc}")
        records.append(rec)
        if rec.error:
            reason = rec.error.split(": ", 1)[-1] if rec.error.split(": ", 1)[0].endswith(
                ("Error", "Exception", "Error_")) else rec.error
            skipped.append((case.scene.name, reason))
            log(f"  skipped: {reason}")
        else:
            m = rec.metrics
            verdict = "; ".join(f"{c['name']}: {'ok' if c['passed'] else 'FAILED'}" for c in rec.checks)
            log(f"  relMSE {m['relmse']:.3g}, FLIP {m['flip']:.3g}" + (f" -- {verdict}" if verdict else
                                                                      " -- reported"))
    return records, skipped


def cmd_run_scenes(args, *, results: Path, defines: dict) -> int:
    """``gibench run --scenes DIR``: run, print the skipped files with their reasons,
    write the report; exit status 1 only if a compared file failed a check."""
    from reports.html import write_report
    from reports.results import ResultStore, new_run_id

    for k, v in DEFAULTS.items():
        if getattr(args, k, None) is None:
            setattr(args, k, v)
    params = {}
    for item in args.set or []:
        if "=" not in item:
            raise UsageError(f"--set expects KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        params[k.strip()] = v.strip()
    suite = directory_suite(args.scenes, args.algorithm, params, expect=args.expect,
                            reference_spp=args.reference_spp, reference_passes=args.passes,
                            repeats=args.repeats)
    store = ResultStore(results)
    run_id = new_run_id()
    print(f"gibench run {run_id}: {len(suite.cases)} scene files of {args.scenes} with {args.algorithm}")
    records, skipped = run_directory(suite, store, run_id=run_id, out_root=results.parent,
                                     mitsuba_timing=not args.no_mitsuba_timing,
                                     reference_store=args.store, defines=defines)
    out = Path(args.report) if args.report else results.parent / "report.html"
    write_report(records, out, root=REPO_ROOT, title=f"gibench — scenes of {args.scenes}")
    compared = [r for r in records if r.ok]
    failed = [(r.scene, c["name"]) for r in compared for c in r.failed_checks]
    print(f"results: {results} (run {run_id})")
    print(f"report:  {out}")
    print(f"{len(compared)} rendered and compared, {len(failed)} failed checks, {len(skipped)} skipped")
    for name, reason in skipped:
        print(f"SKIPPED: {name}: {reason}")
    for scene, name in failed:
        print(f"FAILED: {scene}: {name}")
    return 1 if failed else 0
