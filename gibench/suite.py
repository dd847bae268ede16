"""Suite manifests and the ``gibench run`` pipeline.

A suite manifest (TOML, in ``suites/``) lists groups of scenes × algorithm
configurations × reference transport × expectations::

    [suite]
    name = "default"
    reference_spp = 1024        # Mitsuba samples per pixel of every reference
    reference_passes = 8        # independent passes (for the variance of the mean)
    repeats = 3                 # timed renders per configuration (after a warm-up)
    ladder = [1, 4, 16, 64]     # optional: Mitsuba's integrator at these spp, timed and
                                # compared in the same run (speed-vs-error plots)
    ladder_samplers = ["independent", "multijitter", "ldsampler"]
                                # optional: Mitsuba samplers probed per scene; the ladder
                                # uses the most efficient (default: independent only)
    seeds = 3                   # optional: own renders with seeds 0..seeds-1 (error mean
                                # and spread); seed 0 is timed with `repeats` and judged

    [[group]]
    scenes = ["spheres/lit_sphere.xml"]      # relative to the manifest
    algorithm = "raycast"                    # "auto": gibench.advise's choice per scene
                                             # (transport then defaults to "full")
    transport = "direct"                     # which reference to compare with
    [[group.config]]
    label = "4x4 strata"
    params = { spp = 16 }
    expect = "ztest"          # 'ztest': the Z-test must pass; 'report': error
                              # reported only; 'model-error': the algorithm
                              # computes less transport than the reference
    tolerances = { relmse = 1e-3 }           # optional upper bounds on metrics

Data flows one way: scene file → scene model → own render (image + counters)
and stored Mitsuba reference → metrics → one JSON record per case in the
results store → report.  Every record is appended as soon as its case ends,
so an interrupted run keeps what it finished.
"""

from __future__ import annotations

import hashlib
import json
import statistics
import sys
import time
import tomllib
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from core.errors import GibenchError, SuiteError, UnsupportedError
from core.imageio import write_exr
from core.loader import load_scene
from core.provenance import REPO_ROOT, git_commit, machine, utc_now, versions
from core.records import Record
from references.ladder import SAMPLERS as LADDER_SAMPLERS

from . import registry
from .studies import STUDY_SETS, load_study_set
from .runner import render_timed

__all__ = ["Case", "Suite", "load_suite", "run_suite", "SuiteError", "EXPECTATIONS"]

EXPECTATIONS = ("ztest", "report", "model-error")
TRANSPORTS = ("direct", "full", "whitted", "phong")


def _case_transport(transport: str, params: dict) -> str:
    """``phong`` names the matched Phong reference with the case's own coefficients
    (references/phong_reference.py): the reference store keys the full name."""
    if transport == "phong":
        from references.phong_reference import phong_transport
        return phong_transport(params)
    return transport


def file_max_depth(path: Path, algo, params: dict, transport: str = "full") -> dict:
    """``{"max_depth": n}`` when the file's integrator is Mitsuba's ``path`` with a
    ``max_depth``, the case is compared with full transport (``transport``) and ``algo``
    computes full transport with a ``max_depth`` of Mitsuba's meaning that the case's
    ``params`` do not give: the reference renders the file's depth
    (:func:`references.reference.prepare_scene_xml`), so the own render takes it too
    (without it an unbounded own path would be compared with a depth-limited
    reference: a model difference, and time spent on bounces the reference leaves out).
    ``{}`` otherwise, or when the file does not load (the case's render reports why)."""
    from core.loader import load_scene

    if (transport != "full" or algo.transport != "full" or "max_depth" in params
            or "max_depth" not in algo.defaults()):
        return {}
    try:
        integrator = load_scene(path).integrator
    except GibenchError:
        return {}
    if integrator.get("type") == "path" and "max_depth" in integrator:
        return {"max_depth": int(integrator["max_depth"])}
    return {}


@dataclass(frozen=True)
class Case:
    scene: Path                  # absolute path of the scene file
    scene_id: str                # e.g. 'cornell/cornell_point'
    algorithm: str
    params: dict                 # as written in the manifest (strings allowed)
    transport: str
    label: str
    expect: str
    tolerances: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        h = hashlib.sha1(json.dumps(self.params, sort_keys=True).encode()).hexdigest()[:8]
        return f"{self.scene_id.replace('/', '__')}__{self.algorithm}__{h}"


@dataclass(frozen=True)
class Suite:
    name: str
    path: Path
    cases: tuple[Case, ...]
    reference_spp: int = 1024
    reference_passes: int = 8
    repeats: int = 3
    description: str = ""
    studies: Path | None = None      # studies configuration (TOML)
    study_set: str | None = None     # the study set that runs them (gibench.studies.STUDY_SETS)
    pivots: dict = field(default_factory=dict)   # report layout of each study's table
    ladder: tuple = ()           # Mitsuba spp ladder for the speed-vs-error plots (empty: none)
    ladder_samplers: tuple = ("independent",)   # Mitsuba samplers probed for the ladder
    seeds: int = 1               # own-render seeds 0..seeds-1


# ------------------------------------------------------------ manifest schema ---
#
# Every table and key a manifest may hold, with its type and range; anything
# else (a typo, a wrong type, an out-of-range number) is a one-line SuiteError
# naming the manifest, the line and the key.

#: Tolerance names: the scalar metrics of :func:`reports.metrics.compare` that
#: ``tolerances`` may bound from above.
TOLERANCE_METRICS = ("mse", "rmse", "relmse", "mae", "bias", "flip", "delta_e2000", "nan_count",
                     "inf_count")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)) and v == v and abs(v) != float("inf")


_KEYS_SUITE = {
    "name": (lambda v: isinstance(v, str), "a string"),
    "description": (lambda v: isinstance(v, str), "a string"),
    "reference_spp": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
    "reference_passes": (lambda v: _is_int(v) and v >= 2, "an integer >= 2"),
    "repeats": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
    "ladder": (lambda v: isinstance(v, list) and all(_is_int(x) and x >= 1 for x in v),
               "a list of positive integers (spp)"),
    "studies": (lambda v: isinstance(v, str) and v != "", "a file name"),
    "study_set": (lambda v: isinstance(v, str) and v in STUDY_SETS,
                  f"one of {', '.join(STUDY_SETS)}"),
    "ladder_samplers": (lambda v: isinstance(v, list) and v and all(
        isinstance(x, str) and x in LADDER_SAMPLERS for x in v),
        f"a non-empty list of {', '.join(LADDER_SAMPLERS)}"),
    "seeds": (lambda v: _is_int(v) and v >= 1, "a positive integer"),
    "renderers": (lambda v: (isinstance(v, str) and v != "") or (
        isinstance(v, list) and all(isinstance(x, str) and x for x in v)),
        "a TOML file of command renderers, or a list of them"),
}
_TOLERANCES = (lambda v: isinstance(v, dict) and all(
    k in TOLERANCE_METRICS and _is_number(x) and x >= 0 for k, x in v.items()),
    f"a table of metric = non-negative number (metrics: {', '.join(TOLERANCE_METRICS)})")
_KEYS_GROUP = {
    "algorithm": (lambda v: isinstance(v, str), "an algorithm name (string)"),
    "scenes": (lambda v: isinstance(v, list) and v and all(isinstance(x, str) and x for x in v),
               "a non-empty list of scene file names (strings)"),
    "transport": (lambda v: v in TRANSPORTS, f"one of {', '.join(TRANSPORTS)}"),
    "expect": (lambda v: v in EXPECTATIONS, f"one of {', '.join(EXPECTATIONS)}"),
    "tolerances": _TOLERANCES,
    "config": (lambda v: isinstance(v, list) and v and all(isinstance(x, dict) for x in v),
               "a non-empty list of [[group.config]] tables"),
}
_KEYS_CONFIG = {
    "label": (lambda v: isinstance(v, str), "a string"),
    "params": (lambda v: isinstance(v, dict), "a table of algorithm parameters"),
    "expect": _KEYS_GROUP["expect"],
    "transport": _KEYS_GROUP["transport"],
    "tolerances": _TOLERANCES,
}


class _Manifest:
    """The manifest's text, for the line of a key in error messages (tomllib keeps none)."""

    def __init__(self, path: Path, text: str):
        self.path, self.lines = path, text.splitlines()

    def line(self, key: str, group: int | None = None) -> str:
        """``path:line`` of the first ``key =`` (inside the ``group``-th ``[[group]]``)."""
        start = 0
        if group is not None:
            seen = -1
            for i, ln in enumerate(self.lines):
                if ln.strip().startswith("[[group]]"):
                    seen += 1
                    if seen == group:
                        start = i
                        break
        for i in range(start, len(self.lines)):
            stripped = self.lines[i].lstrip()
            if stripped.startswith(f"{key} ") or stripped.startswith(f"{key}=") or \
                    f" {key} =" in self.lines[i] or f"{{{key} =" in self.lines[i]:
                return f"{self.path}:{i + 1}"
            if group is not None and i > start and self.lines[i].strip().startswith("[[group]]"):
                break
        return f"{self.path}:{start + 1 if group is not None else '?'}"

    def check(self, table, schema: dict, what: str, group: int | None = None) -> dict:
        if not isinstance(table, dict):
            raise SuiteError(f"{self.line(what.split()[0].strip('[]'), group)}: {what} must be a table")
        for key, value in table.items():
            if key not in schema:
                raise SuiteError(f"{self.line(key, group)}: unknown key '{key}' in {what} "
                                 f"(valid: {', '.join(schema)})")
            test, meaning = schema[key]
            if not test(value):
                raise SuiteError(f"{self.line(key, group)}: {what} '{key}' must be {meaning}, "
                                 f"got {str(value)[:60]}")
        return table


def _auto(scene_path: Path) -> tuple[str, dict]:
    """``algorithm = "auto"``: the advised algorithm and parameters for a scene, from
    the leaderboard records of the default results store when there are any."""
    from reports.results import ResultStore

    from .advise import resolve_auto

    store = ResultStore(REPO_ROOT / "reports" / "out" / "results.jsonl")
    return resolve_auto(scene_path, records=store.load())


def load_suite(path) -> Suite:
    """Read and check a suite manifest against its schema (tables, keys, types,
    ranges; see ``_KEYS_*``): every scene file exists, every algorithm and
    parameter is known, expectations, transports, tolerances and the study set
    are valid.  Any problem is a :class:`SuiteError` naming the file and line."""
    path = Path(path)
    if path.is_dir():
        path = path / "suite.toml"
    if not path.is_file():
        raise SuiteError(f"{path}: suite manifest not found")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SuiteError(f"{path}: not a UTF-8 text file (byte {exc.start}); TOML is UTF-8") from None
    except OSError as exc:
        raise SuiteError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SuiteError(f"{path}: malformed TOML: {str(exc)[:200]}") from None
    m = _Manifest(path, text)
    for key, value in data.items():
        if key not in ("suite", "group", "pivot"):
            raise SuiteError(f"{m.line(key)}: unknown table '{key}' (valid: suite, group, pivot)")
    if "studies_module" in data.get("suite", {}):
        raise SuiteError(f"{m.line('studies_module')}: [suite] studies_module is no longer read; "
                         f"name the study set with study_set = one of {', '.join(STUDY_SETS)}")
    head = m.check(data.get("suite", {}), _KEYS_SUITE, "[suite]")
    groups = data.get("group", [])
    if not isinstance(groups, list):
        raise SuiteError(f"{m.line('group')}: 'group' must be [[group]] tables")
    pivots = data.get("pivot", {})
    if not isinstance(pivots, dict) or not all(isinstance(v, dict) for v in pivots.values()):
        raise SuiteError(f"{m.line('pivot')}: [pivot] must hold one table per study")
    cases = []
    suites_root = path.parent
    for f in [head["renderers"]] if isinstance(head.get("renderers"), str) else head.get("renderers", []):
        registry.add_renderer_file(suites_root / f)       # named command renderers
    for gi, group in enumerate(groups):
        where = f"{path}: group {gi + 1}"
        if not isinstance(group, dict):
            raise SuiteError(f"{where}: must be a [[group]] table")
        m.check(group, _KEYS_GROUP, f"group {gi + 1}", gi)
        for key in ("algorithm", "scenes"):
            if key not in group:
                raise SuiteError(f"{where}: missing '{key}'")
        auto = group["algorithm"] == "auto"
        algo = None if auto else registry.get(group["algorithm"])
        transport = group.get("transport", "full" if auto else algo.transport)
        if not auto and transport == "phong" and "ka" not in {p.name for p in algo.params}:
            raise SuiteError(f"{where}: transport 'phong' needs an algorithm with the Phong "
                             f"parameters (ka, ks, shininess, c1..c3), not '{algo.name}'")
        for ci, cfg in enumerate(group.get("config", [{}])):
            m.check(cfg, _KEYS_CONFIG, f"group {gi + 1}, config {ci + 1}", gi)
        for scene in group["scenes"]:
            scene_path = (suites_root / scene).resolve()
            if not scene_path.is_file():
                raise SuiteError(f"{m.line('scenes', gi)}: scene file not found: {scene_path}")
            scene_id = str(Path(scene).with_suffix("")).replace("\\", "/")
            advised = {}
            if auto:                     # the advised algorithm of this scene (gibench.advise)
                chosen, advised = _auto(scene_path)
                algo = registry.get(chosen)
            for ci, cfg in enumerate(group.get("config", [{}])):
                params = {**advised, **cfg.get("params", {})}
                try:
                    algo.parse_params(params)            # validates names, types and ranges now
                except GibenchError as exc:
                    raise SuiteError(f"{m.line('params', gi)}: {exc}") from None
                params.update(file_max_depth(scene_path, algo, params,
                                             cfg.get("transport", transport)))
                expect = cfg.get("expect", group.get("expect", "report"))
                tol = dict(group.get("tolerances", {}), **cfg.get("tolerances", {}))
                cases.append(Case(scene=scene_path, scene_id=scene_id, algorithm=algo.name,
                                  params=params,
                                  transport=_case_transport(cfg.get("transport", transport), params),
                                  label=cfg.get("label", f"{algo.name} {params}"),
                                  expect=expect, tolerances=tol))
    ladder = head.get("ladder", [])
    samplers = head.get("ladder_samplers", ["independent"])
    seeds = head.get("seeds", 1)
    studies = None
    study_set = head.get("study_set")
    if "studies" in head:
        studies = (suites_root / head["studies"]).resolve()
        if not studies.is_file():
            raise SuiteError(f"{m.line('studies')}: studies configuration not found: {studies}")
        if study_set is None:
            raise SuiteError(f"{m.line('studies')}: [suite] studies needs study_set = one of "
                             f"{', '.join(STUDY_SETS)}")
    if not cases and studies is None:
        raise SuiteError(f"{path}: the suite has no cases ([[group]] with scenes and an algorithm) "
                         "and no studies")
    return Suite(name=head.get("name", path.parent.name), path=path, cases=tuple(cases),
                 reference_spp=head.get("reference_spp", 1024),
                 reference_passes=head.get("reference_passes", 8),
                 repeats=head.get("repeats", 3), description=head.get("description", ""),
                 studies=studies, study_set=study_set,
                 pivots=dict(pivots), ladder=tuple(ladder),
                 ladder_samplers=tuple(samplers), seeds=seeds)


def _rel(p: Path) -> str:
    try:
        return str(Path(p).resolve().relative_to(REPO_ROOT))
    except ValueError:
        return str(p)


def _checks(case: Case, metrics: dict) -> list[dict]:
    checks = []
    if case.expect == "ztest":
        z = metrics.get("ztest") or {}
        checks.append({"name": f"Z-test vs Mitsuba {case.transport}", "expected": "pass",
                       "passed": bool(z.get("passed")),
                       "detail": f"{z.get('fraction', float('nan')):.5f} of entries consistent "
                                 f"(need {z.get('min_fraction')})"})
    for name, bound in case.tolerances.items():
        value = metrics.get(name)
        ok = value is not None and value <= bound
        checks.append({"name": f"{name} <= {bound:g}", "expected": "pass", "passed": bool(ok),
                       "detail": f"{name} = {value:.4g}" if value is not None else f"{name} missing"})
    return checks


class _CaseRun:
    """One case's steps, so that its timed renders can be interleaved with Mitsuba's:
    :meth:`setup` (algorithm, parameters, scene, reference), :meth:`render` (one
    render, timed), :meth:`finish` (images, metrics, timing, checks).  A
    :class:`core.errors.GibenchError` or ``OSError`` in any step becomes the
    record's ``error`` (:meth:`fail`)."""

    def __init__(self, case: Case, suite: Suite, *, run_id: str, out_dir: Path, reference_store=None,
                 defines: dict | None = None, seed: int = 0):
        self.case, self.suite, self.out_dir, self.seed = case, suite, out_dir, seed
        self.defines, self.reference_store = defines, reference_store
        self.record = Record(run_id=run_id, suite=suite.name, scene=case.scene_id,
                             scene_file=_rel(case.scene), algorithm=case.algorithm, label=case.label,
                             params=dict(case.params), defines=dict(defines or {}), seed=seed,
                             transport=case.transport, expect=case.expect,
                             model_error=case.expect == "model-error", versions=versions(),
                             commit=git_commit(), machine=machine(), created=utc_now())
        self.algo = self.params = self.scene = self.ref = None

    def setup(self) -> None:
        from references.reference import DEFAULT_STORE, get_reference

        case, record = self.case, self.record
        self.algo = registry.get(case.algorithm)
        self.params = self.algo.parse_params(case.params)
        record.params = self.params
        record.external = registry.provenance(case.algorithm, self.params, defines=self.defines)
        self.scene = load_scene(case.scene, defines=self.defines)
        self.ref = ref = get_reference(case.scene, transport=case.transport, spp=self.suite.reference_spp,
                                       passes=self.suite.reference_passes,
                                       store=self.reference_store or DEFAULT_STORE, defines=self.defines)
        record.reference = {"key": ref.key, "dir": _rel(ref.directory),
                            "image": _rel(ref.directory / "image.exr"),
                            "variance": _rel(ref.directory / "variance.exr"),
                            "spp": ref.manifest.get("spp"), "variant": ref.manifest.get("variant"),
                            "integrator": case.transport}

    @property
    def spp(self) -> int:
        """The case's samples per pixel (1 for an algorithm without an spp parameter)."""
        return self.params.get(self.algo.spp_param, 1) if self.algo.spp_param else 1

    def render(self):
        """One render with the case's seed: ``(result, seconds)``."""
        t0 = time.perf_counter()
        result = self.algo.render(self.scene, self.params, seed=self.seed)
        return result, time.perf_counter() - t0

    def finish(self, result, timing: dict, *, judge: bool = True) -> Record:
        from reports.metrics import compare

        case, record, ref = self.case, self.record, self.ref
        suffix = f".seed{self.seed}" if self.seed else ""
        image_path = self.out_dir / f"{case.name}{suffix}.exr"
        write_exr(image_path, result.image)
        record.image = _rel(image_path)
        record.variance = None
        if result.variance is not None:
            var_path = self.out_dir / f"{case.name}{suffix}.var.exr"
            write_exr(var_path, result.variance)
            record.variance = _rel(var_path)
        record.counters = result.counters
        record.metrics = compare(ref.image, result.image, reference_variance=ref.variance,
                                 test_variance=result.variance, allow_nonfinite=True)
        if ref.variance is not None:
            from reports.pareto import noise_floor_relmse

            record.metrics["noise_floor_relmse"] = noise_floor_relmse(ref.image, ref.variance)
        record.time = timing
        m = record.metrics
        if m["nan_count"] or m["inf_count"]:
            record.checks = [{"name": "finite image", "expected": "pass", "passed": False,
                              "detail": f"{m['nan_count']} NaN, {m['inf_count']} Inf"}]
        else:
            record.checks = [] if case.expect == "model-error" or not judge else _checks(case, m)
        return record

    def fail(self, exc, log=None) -> Record:
        self.record.error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        if log:
            log(f"  error: {self.record.error}")
            if "GIBENCH_TRACEBACK" in __import__("os").environ:
                traceback.print_exc(file=sys.stderr)
        return self.record


_MOTION_SKIP = "moving spheres: Mitsuba 3 cannot move shapes, so it has no equal-work render to time"


def run_case(case: Case, suite: Suite, *, run_id: str, out_dir: Path, mitsuba_timing: bool,
             timing_cache: dict, reference_store=None, log=print,
             defines: dict | None = None, seed: int = 0, repeats: int | None = None,
             judge: bool = True) -> Record:
    """Run one case on its own and return its result record (never raises for a bad
    case: the record's ``error`` names the cause).  ``defines`` overrides the scene's
    ``<default>`` values in both the own render and the reference (``-D``);
    ``seed`` is the own render's seed; ``repeats`` the timed renders after a
    warm-up (default ``suite.repeats``; 0: one render without warm-up, whose
    time may include compilation); ``judge=False`` records the metrics without the
    case's checks (a finite image is still required).  Mitsuba's equal-spp
    timing (``mitsuba_timing``) runs after the own renders: :func:`run_scene`
    interleaves the two instead."""
    from references.motion_blur import has_motion
    from references.reference import time_mitsuba

    run = _CaseRun(case, suite, run_id=run_id, out_dir=out_dir, reference_store=reference_store,
                   defines=defines, seed=seed)
    try:
        run.setup()
        if repeats == 0:                 # an extra seed: one render, for its error only
            result, t = run.render()
            timing = {"own_median_s": t, "own_times_s": [t], "repeats": 1, "warmup": False}
        else:
            result, timing = render_timed(run.algo, run.scene, run.params, seed=seed,
                                          repeats=repeats or suite.repeats)
            timing.update(own_min_s=min(timing["own_times_s"]), own_max_s=max(timing["own_times_s"]))
        if mitsuba_timing and has_motion(case.scene):
            timing["mitsuba_skipped"] = _MOTION_SKIP
        elif mitsuba_timing:
            key = (str(case.scene), case.transport, run.spp)
            if key not in timing_cache:
                timing_cache[key] = time_mitsuba(case.scene, transport=case.transport, spp=run.spp,
                                                 repeats=suite.repeats, defines=defines)
            mt = timing_cache[key]
            timing.update(mitsuba_median_s=mt["median_s"], mitsuba_times_s=mt["times_s"],
                          mitsuba_min_s=min(mt["times_s"]), mitsuba_max_s=max(mt["times_s"]),
                          mitsuba_spp=mt["spp"], mitsuba_variant=mt.get("variant"),
                          interleaved=False,
                          ratio=timing["own_median_s"] / mt["median_s"] if mt["median_s"] > 0 else None)
        return run.finish(result, timing, judge=judge)
    except (GibenchError, OSError) as exc:
        return run.fail(exc, log)


def _ladder_base(suite, scene, scene_id, transport, run_id, defines) -> dict:
    return dict(run_id=run_id, suite=suite.name, kind="ladder", scene=scene_id,
                scene_file=_rel(scene), algorithm="mitsuba", transport=transport,
                defines=dict(defines or {}), versions=versions(), commit=git_commit(),
                machine=machine(), created=utc_now())


def _log_choice(log, scene_id, transport, choice) -> None:
    if not (log and choice["candidates"]):
        return
    for spp, table in (choice.get("probes") or {str(choice["probe_spp"]): choice["candidates"]}).items():
        log(f"  ladder {scene_id} ({transport}): probe at {spp} spp: "
            + ", ".join(f"{k} relMSE {v['relmse']:.3g} in {v['median_s'] * 1e3:.0f} ms"
                        for k, v in table.items())
            + f" -> {(choice.get('best_by_spp') or {}).get(spp, choice['sampler'])}")
    log(f"  ladder {scene_id} ({transport}): sampler {choice['sampler']} (best at "
        f"{choice['probe_spp']} spp{'; cached' if choice['cached'] else ''})")


def _ladder_record(base, ref, choice, pt, repeats) -> Record:
    from reports.pareto import noise_floor_relmse

    if ref.variance is not None:
        pt["metrics"]["noise_floor_relmse"] = noise_floor_relmse(ref.image, ref.variance)
    params = {"spp": pt["spp"], "sampler": choice["sampler"]}
    if choice["candidates"]:
        params.update(sampler_probe=choice["candidates"], probe_spp=choice["probe_spp"])
        if choice.get("best_by_spp"):
            params["sampler_best_by_spp"] = choice["best_by_spp"]
    times = pt["times_s"]
    timing = {"own_median_s": pt["median_s"], "own_times_s": times, "own_min_s": min(times),
              "own_max_s": max(times), "repeats": repeats, "variant": pt["variant"],
              "sampler": pt["sampler"]}
    timing.update(pt.get("timing") or {})
    return Record(**base, label=f"Mitsuba {base['transport']} {pt['spp']} spp",
                  params=params, metrics=pt["metrics"], time=timing,
                  reference={"key": ref.key, "dir": _rel(ref.directory),
                             "spp": ref.manifest.get("spp")},
                  ladder_spp=pt["spp"], mitsuba=pt["mitsuba"])


def run_scene(cases: list[Case], suite: Suite, *, run_id: str, out_dir: Path, mitsuba_timing: bool,
              ladder: bool, reference_store=None, log=print, defines: dict | None = None,
              seed: int = 0, sampler_cache=None, group: str = "") -> list[Record]:
    """The cases of one scene and that scene's Mitsuba timings, timed side by side.

    Every case (seed ``seed``), Mitsuba's equal-spp render of each (transport,
    spp) when ``mitsuba_timing``, and each rung of Mitsuba's spp ladder of each
    transport when ``ladder`` (the sampler: :func:`gibench.ladder.choose_sampler`
    probed at :func:`gibench.ladder.probe_spps` of the ladder) is set up and
    rendered once untimed (warm-up), then all are timed in ``suite.repeats``
    rounds in which own and Mitsuba renders alternate
    (:func:`gibench.interleave.run_rounds`): both sides are timed under the
    same machine load.  Each record's ``time`` keeps the per-round times, their
    min / median / max, ``interleaved``, ``timing_group`` (shared by the
    records timed together) and the load average before and after; a case's
    equal-spp ``ratio`` is the ratio of the medians, ``ratio_rounds`` the paired
    per-round ratios.  Then the extra seeds ``seed + 1 .. seed + suite.seeds - 1``
    render once each (error spread, untimed).  Returns the case records in
    ``cases`` order, then the extra seeds', then the ladder records.
    """
    from references.ladder import LADDER_SEED, prepare_ladder
    from references.motion_blur import has_motion
    from references.reference import DEFAULT_STORE, get_reference, prepare_timing

    from .interleave import Timed, paired_ratios, run_rounds
    from .ladder import SAMPLER_CACHE, choose_sampler, probe_spps, rung_metrics

    tasks: list[Timed] = []
    runs, results, failed = [], {}, []
    # Own cases: set up and warm up (JIT compile or cache load).
    for n, case in enumerate(cases):
        run = _CaseRun(case, suite, run_id=run_id, out_dir=out_dir, reference_store=reference_store,
                       defines=defines, seed=seed)
        run.index = n
        try:
            run.setup()
            t0 = time.perf_counter()
            results[id(run)] = run.render()[0]
            run.warmup_s = time.perf_counter() - t0
            run.phases = {}
        except (GibenchError, OSError) as exc:
            failed.append((n, run.fail(exc, log)))
            continue
        runs.append(run)

        def own(k, run=run):
            result, dt = run.render()
            results[id(run)] = result
            for p, v in (result.timings or {}).items():
                run.phases.setdefault(p, []).append(float(v))
            return dt
        tasks.append(Timed(f"{case.label} ({case.transport})", "own", own))
    # Mitsuba at the cases' spp (the equal-spp ratio).
    equal_spp: dict = {}
    mi_errors: dict = {}
    if mitsuba_timing:
        for run in runs:
            key = (run.case.transport, run.spp)
            if has_motion(run.case.scene) or key in equal_spp or key in mi_errors:
                continue
            try:
                render, info = prepare_timing(run.case.scene, transport=key[0], spp=key[1],
                                              defines=defines)
            except (GibenchError, OSError) as exc:
                mi_errors[key] = exc
                continue
            equal_spp[key] = info
            tasks.append(Timed(f"Mitsuba {key[0]} {key[1]} spp", "mitsuba", lambda k, r=render: r()))
    # Mitsuba's ladder of each transport, with its best sampler.
    ladders, ladder_recs = [], []
    if ladder and suite.ladder:
        scene = cases[0].scene
        for transport in dict.fromkeys(c.transport for c in cases):
            base = _ladder_base(suite, scene, cases[0].scene_id, transport, run_id, defines)
            try:
                if has_motion(scene):
                    raise UnsupportedError("moving spheres: Mitsuba 3 cannot move shapes, so it has "
                                           "no spp ladder for this scene")
                ref = get_reference(scene, transport=transport, spp=suite.reference_spp,
                                    passes=suite.reference_passes,
                                    store=reference_store or DEFAULT_STORE, defines=defines)
                choice = choose_sampler(scene, transport=transport, reference=ref,
                                        candidates=suite.ladder_samplers,
                                        probe_spp=probe_spps(suite.ladder), defines=defines,
                                        cache=sampler_cache if sampler_cache is not None else SAMPLER_CACHE)
                _log_choice(log, cases[0].scene_id, transport, choice)
                rungs = prepare_ladder(scene, transport=transport, spps=suite.ladder, defines=defines,
                                       sampler=choice["sampler"])
            except (GibenchError, OSError) as exc:
                msg = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                if log:
                    log(f"  ladder {cases[0].scene_id} ({transport}): error: {msg}")
                ladder_recs.append(Record(**base, label=f"Mitsuba {transport}", error=msg))
                continue
            for rung in rungs:
                images: list = []

                def mi_rung(k, rung=rung, images=images):
                    img, dt = rung.render(LADDER_SEED + 1 + k)
                    images.append(img)
                    return dt
                ladders.append((base, ref, choice, rung, images, len(tasks)))
                tasks.append(Timed(f"Mitsuba {transport} {rung.spp} spp ({rung.sampler})", "mitsuba",
                                   mi_rung))
    # The timed rounds: own and Mitsuba renders alternate.
    timed = run_rounds(tasks, suite.repeats) if tasks else {"times": [], "order": [], "load": []}
    group_info = {"interleaved": True, "timing_group": group, "timing_order": timed["order"],
                  "load_1min": timed["load"]}
    times = timed["times"]
    out = []
    mi_times = {}
    k = len(runs)
    for key in equal_spp:
        mi_times[key] = times[k]
        k += 1
    for i, run in enumerate(runs):
        own_t = times[i]
        timing = {"own_median_s": statistics.median(own_t), "own_times_s": own_t,
                  "own_min_s": min(own_t), "own_max_s": max(own_t), "warmup_s": run.warmup_s,
                  "compile_s": max(run.warmup_s - statistics.median(own_t), 0.0),
                  "repeats": suite.repeats}
        timing.update({f"own_{p}": statistics.median(v) for p, v in run.phases.items()})
        timing.update(group_info)
        key = (run.case.transport, run.spp)
        try:
            if mitsuba_timing and has_motion(run.case.scene):
                timing["mitsuba_skipped"] = _MOTION_SKIP
            elif key in mi_errors:
                raise mi_errors[key]
            elif key in mi_times:
                mt, info = mi_times[key], equal_spp[key]
                med = statistics.median(mt)
                rr = paired_ratios(own_t, mt)
                timing.update(mitsuba_median_s=med, mitsuba_times_s=mt, mitsuba_min_s=min(mt),
                              mitsuba_max_s=max(mt), mitsuba_spp=info["spp"],
                              mitsuba_variant=info.get("variant"),
                              ratio=timing["own_median_s"] / med if med > 0 else None,
                              ratio_rounds=rr, ratio_min=min(rr) if rr else None,
                              ratio_max=max(rr) if rr else None)
            out.append((run.index, run.finish(results[id(run)], timing)))
        except (GibenchError, OSError) as exc:
            out.append((run.index, run.fail(exc, log)))
    # The cases in the given order (failed ones included).
    out = [rec for _, rec in sorted(out + failed, key=lambda x: x[0])]
    # Extra seeds: the error's spread (untimed, unjudged).
    for case in cases:
        for j in range(1, suite.seeds):
            out.append(run_case(case, suite, run_id=run_id, out_dir=out_dir, mitsuba_timing=False,
                                timing_cache={}, reference_store=reference_store, log=log,
                                defines=defines, seed=seed + j, repeats=0, judge=False))
    # The ladder's records, from the rounds' renders.
    for base, ref, choice, rung, images, idx in ladders:
        pt = {"spp": rung.spp, "median_s": statistics.median(times[idx]), "times_s": times[idx],
              "variant": rung.variant, "mitsuba": rung.mitsuba, "sampler": rung.sampler,
              "metrics": rung_metrics(ref, images), "timing": dict(group_info, warmup_s=rung.warmup_s)}
        rec = _ladder_record(base, ref, choice, pt, suite.repeats)
        ladder_recs.append(rec)
        if log:
            log(f"  ladder {base['scene']} ({base['transport']}, {rung.sampler}) {rung.spp} spp: relMSE "
                f"{pt['metrics']['relmse']:.3g}, {pt['median_s'] * 1e3:.1f} ms "
                f"({min(times[idx]) * 1e3:.1f}-{max(times[idx]) * 1e3:.1f})")
    return out + ladder_recs


def run_studies(suite: Suite, *, run_id: str, log=print) -> list[Record]:
    """The suite's studies, one record (``kind = "study"``) per table.

    ``suite.study_set`` names the set (:data:`gibench.studies.STUDY_SETS`) whose
    ``run_studies(config_path) -> {name: rows}`` and ``TABLES = {name: (title,
    description)}`` run them.
    """
    st = load_study_set(suite.study_set)

    base = dict(run_id=run_id, suite=suite.name, kind="study", algorithm="study",
                versions=versions(), commit=git_commit(), machine=machine(), created=utc_now())
    try:
        tables = st.run_studies(suite.studies)
    except (GibenchError, OSError) as exc:
        log(f"  studies failed: {exc}")
        return [Record(**base, study="studies", scene="studies", error=f"{type(exc).__name__}: {exc}")]
    records = []
    for name, rows in tables.items():
        title, description = st.TABLES.get(name, (name, ""))
        log(f"[study] {name}: {len(rows)} rows")
        records.append(Record(**base, study=name, scene=f"study/{name}", label=title, title=title,
                              description=description, rows=rows,
                              pivot=suite.pivots.get(name, {})))
    return records


def _case_task(job: tuple) -> Record:
    """Run one case in a worker (module level so process and Dask workers can unpickle it)."""
    case, suite, kw = job
    return run_case(case, suite, timing_cache={}, log=None, **kw)


def _seed_jobs(suite: Suite, seed: int) -> list[tuple[int, Case, dict]]:
    """(case index, case, run_case options) of every case and seed: the first seed is
    timed with ``suite.repeats``, Mitsuba-timed and judged; the others (seeds
    ``seed + 1 ..``) give the error's spread: one render each (no warm-up: the
    point's time is the first seed's), no checks."""
    jobs = []
    for i, case in enumerate(suite.cases):
        jobs.append((i, case, {"seed": seed}))
        for k in range(1, suite.seeds):
            jobs.append((i, case, {"seed": seed + k, "repeats": 0, "judge": False,
                                   "mitsuba_timing": False}))
    return jobs


def _summary_line(rec: Record) -> str:
    if rec.error:
        return f"  error: {rec.error}"
    m, t = rec.metrics, rec.time
    verdict = "; ".join(f"{c['name']}: {'ok' if c['passed'] else 'FAILED'}" for c in rec.checks)
    ratio = f", {t['ratio']:.2f}x Mitsuba" if t.get("ratio") else ""
    return (f"  relMSE {m['relmse']:.3g}, FLIP {m['flip']:.3g}, own {t['own_median_s'] * 1e3:.1f} ms"
            f"{ratio}" + (f" -- {verdict}" if verdict else " -- reported"))


def _progress(total: int, desc: str, enabled):
    """A tqdm bar on stderr (``enabled=None``: only on a terminal)."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="case", disable=(not enabled) if enabled is not None
                else None, file=sys.stderr, dynamic_ncols=True, leave=False)


def run_ladders(suite: Suite, cases, *, run_id: str, reference_store=None, log=print,
                defines: dict | None = None, sampler_cache=None) -> list[Record]:
    """Mitsuba's spp ladder (``suite.ladder``) for every (scene, transport) of ``cases``,
    rung after rung: one record (``kind = "ladder"``) per spp with Mitsuba's time
    and error.  What a run with a parallel executor does after its cases (whose
    renders run concurrently, so no interleaving could make the timings comparable;
    the records say ``interleaved: false``); a serial run times each scene's ladder
    with its own cases instead (:func:`run_scene`).

    The ladder's sampler is Mitsuba's most efficient of ``suite.ladder_samplers``
    on the scene at the ladder's top rung (:func:`gibench.ladder.choose_sampler`;
    ``sampler_cache``: its JSON cache, default :data:`gibench.ladder.SAMPLER_CACHE`);
    each record's ``params`` name it (``sampler``) with the probe's figures
    (``sampler_probe``).  The error is the mean over the ``suite.repeats``
    timed renders, each with its own seed (``metrics["relmse_seeds"]``)."""
    from .ladder import SAMPLER_CACHE, choose_sampler, ladder_points, probe_spps
    from references.motion_blur import has_motion
    from references.reference import DEFAULT_STORE, get_reference

    records = []
    pairs = list(dict.fromkeys((c.scene, c.scene_id, c.transport) for c in cases))
    for scene, scene_id, transport in pairs:
        base = _ladder_base(suite, scene, scene_id, transport, run_id, defines)
        try:
            if has_motion(scene):
                raise UnsupportedError("moving spheres: Mitsuba 3 cannot move shapes, so it has no "
                                       "spp ladder for this scene")
            ref = get_reference(scene, transport=transport, spp=suite.reference_spp,
                                passes=suite.reference_passes,
                                store=reference_store or DEFAULT_STORE, defines=defines)
            choice = choose_sampler(scene, transport=transport, reference=ref,
                                    candidates=suite.ladder_samplers,
                                    probe_spp=probe_spps(suite.ladder), defines=defines,
                                    cache=sampler_cache if sampler_cache is not None else SAMPLER_CACHE)
            _log_choice(log, scene_id, transport, choice)
            points = ladder_points(scene, transport=transport, spps=suite.ladder, reference=ref,
                                   repeats=suite.repeats, defines=defines, sampler=choice["sampler"])
        except (GibenchError, OSError) as exc:
            msg = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            if log:
                log(f"  ladder {scene_id} ({transport}): error: {msg}")
            records.append(Record(**base, label=f"Mitsuba {transport}", error=msg))
            continue
        for pt in points:
            pt["timing"] = {"interleaved": False}
            records.append(_ladder_record(base, ref, choice, pt, suite.repeats))
            if log:
                log(f"  ladder {scene_id} ({transport}, {pt['sampler']}) {pt['spp']} spp: relMSE "
                    f"{pt['metrics']['relmse']:.3g}, {pt['median_s'] * 1e3:.1f} ms")
    return records


def run_suite(suite: Suite, store, *, run_id: str, out_root: Path, mitsuba_timing: bool = True,
              reference_store=None, log=print, defines: dict | None = None, seed: int = 0,
              history=None, command: str = "run", jobs: int = 1, executor: str | None = None,
              progress=None, ladder: bool | None = None) -> list[Record]:
    """Run every case, appending each record to ``store`` as it completes.

    A serial run (the default) goes scene by scene (:func:`run_scene`): a
    scene's cases, Mitsuba's equal-spp renders and its spp ladder are timed in
    interleaved rounds, so own and Mitsuba times come from the same minutes of
    machine load.  ``history``: an open :func:`gibench.history.connect` connection (or None)
    that receives every record too, one transaction each.  ``jobs`` /
    ``executor``: where cases execute (:mod:`gibench.executor`; the cases run
    concurrently there, the ladders after them, and the records say
    ``interleaved: false``); records always flow back to this process, which
    alone writes the stores.
    ``progress``: a tqdm bar on stderr (None: only on a terminal).
    ``ladder``: time Mitsuba's spp ladder (default: when ``suite.ladder``
    is set).  ``seed``: the first own-render seed; with ``suite.seeds`` = K
    every case also renders seeds ``seed + 1 .. seed + K - 1`` (error spread;
    :func:`_seed_jobs`).
    """
    from .executor import map_unordered, parse_executor

    kind, detail = parse_executor(executor, jobs)
    out_dir = out_root / "runs" / run_id
    records = []

    def keep(rec):
        store.append(rec)
        if history is not None:
            from .history import add_record

            add_record(history, rec, command=command)
        records.append(rec)

    seed_jobs = _seed_jobs(suite, seed)
    n = len(seed_jobs)
    ladder_done = False
    bar = _progress(n, f"{suite.name}", progress)
    # Lines go above the bar while it is shown; nothing is printed with log=None.
    say = ((bar.write if not bar.disable else log) if log else (lambda s: None))

    def head(case, opts):
        extra = f" (seed {opts['seed']})" if suite.seeds > 1 else ""
        return f"{case.scene_id}: {case.label} vs {case.transport}{extra}"

    try:
        if kind == "serial":
            # Scene by scene: its cases, its Mitsuba equal-spp renders and ladders,
            # timed in interleaved rounds (run_scene).
            by_scene: dict = {}
            for case in suite.cases:
                by_scene.setdefault(case.scene, []).append(case)
            do_ladder = bool((suite.ladder if ladder is None else ladder) and suite.ladder)
            k = 0
            for g, (scene, cases) in enumerate(by_scene.items()):
                say(f"[{k + 1}/{n}] {cases[0].scene_id}: {len(cases)} configuration"
                    f"{'s' if len(cases) > 1 else ''} and Mitsuba, interleaved"
                    + (f", {suite.seeds} seeds" if suite.seeds > 1 else ""))
                for rec in run_scene(cases, suite, run_id=run_id, out_dir=out_dir,
                                     mitsuba_timing=mitsuba_timing, ladder=do_ladder,
                                     reference_store=reference_store, log=log, defines=defines,
                                     seed=seed, group=f"{run_id}/{g}"):
                    keep(rec)
                    if rec.kind == "case":
                        k += 1
                        bar.update(1)
                        if rec.ok and rec.seed == seed:
                            say(f"  {rec.label} vs {rec.transport}:")
                            say(_summary_line(rec))
            ladder_done = True
        else:
            say(f"running {n} cases on {kind} ({detail})")
            jobs_ = []
            for i, case, opts in seed_jobs:
                kw = dict(run_id=run_id, out_dir=out_dir, mitsuba_timing=mitsuba_timing,
                          reference_store=reference_store, defines=defines)
                kw.update(opts)
                jobs_.append((case, suite, kw))
            done = 0
            for j, rec in map_unordered(_case_task, jobs_, kind=kind, detail=detail):
                keep(rec)
                done += 1
                bar.update(1)
                _, c, opts = seed_jobs[j]
                say(f"[{done}/{n}] {head(c, opts)}\n{_summary_line(rec)}")
    finally:
        bar.close()
    if (suite.ladder if ladder is None else ladder) and suite.ladder and not ladder_done:
        for rec in run_ladders(suite, suite.cases, run_id=run_id, reference_store=reference_store,
                               log=log, defines=defines):
            keep(rec)
    if suite.studies is not None:
        for rec in run_studies(suite, run_id=run_id, log=log):
            keep(rec)
    return records
