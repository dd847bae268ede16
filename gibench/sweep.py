"""Ablation sweeps: ``gibench sweep SCENE --algorithm A --grid key=v1,v2 [--grid ...]``.

A sweep is an ordinary suite built on the fly: one case per point of the
Cartesian product of the grids (parameter names and values checked against
the algorithm's registry table, so any registered algorithm and any of its
parameters can be swept without code here knowing them), with Mitsuba's spp
ladder measured in the same run.  The report shows the speed-vs-error plot
(:mod:`reports.pareto`) and the table printed by :func:`sweep_table`.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

from .registry import Algorithm, ParamError
from core.records import Record

from .suite import LADDER_SAMPLERS, TRANSPORTS, Case, Suite, SuiteError, file_max_depth

__all__ = ["parse_grid", "sweep_suite", "sweep_table"]


def parse_grid(items, algo: Algorithm) -> dict[str, list]:
    """``["key=v1,v2", ...]`` -> ``{key: [parsed v1, parsed v2]}`` (checked against ``algo``'s
    parameter table; an unknown key lists the valid ones)."""
    table = {p.name: p for p in algo.params}
    grid: dict[str, list] = {}
    for item in items or []:
        if "=" not in item:
            raise ParamError(f"--grid expects key=v1,v2,..., got '{item}'")
        key, values = (x.strip() for x in item.split("=", 1))
        if key not in table:
            raise ParamError(f"{algo.name}: unknown parameter '{key}' in --grid "
                             f"(valid: {', '.join(table)})")
        if key in grid:
            raise ParamError(f"--grid names '{key}' twice")
        vals = [v.strip() for v in values.split(",") if v.strip()]
        if not vals:
            raise ParamError(f"--grid {key}: no values")
        grid[key] = [table[key].parse(v, algorithm=algo.name) for v in vals]
    if not grid:
        raise ParamError("sweep needs at least one --grid key=v1,v2,...")
    return grid


def sweep_suite(scene, algo: Algorithm, grid: dict[str, list], *, transport: str | None = None,
                reference_spp: int = 1024, reference_passes: int = 8, repeats: int = 3,
                ladder="1,4,16,64,256", base_params: dict | None = None,
                ladder_samplers=("independent",), seeds: int = 1) -> Suite:
    """The suite of a sweep: every grid point of ``algo`` on ``scene``; Mitsuba's
    ladder with the best of ``ladder_samplers`` on that scene
    (:func:`gibench.ladder.choose_sampler`), own errors over ``seeds`` seeds."""
    from core.provenance import REPO_ROOT

    scene = Path(scene)
    if not scene.is_file():
        raise SuiteError(f"{scene}: scene file not found")
    scene = scene.resolve()
    transport = transport or algo.transport
    if transport not in TRANSPORTS:
        raise SuiteError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if isinstance(ladder, str):
        try:
            ladder = [int(x) for x in ladder.split(",") if x.strip()]
        except ValueError:
            raise SuiteError(f"--ladder expects comma-separated spp, got {ladder!r}") from None
    if any(x < 1 for x in ladder):
        raise SuiteError(f"--ladder spp must be positive, got {ladder}")
    if not ladder_samplers or any(x not in LADDER_SAMPLERS for x in ladder_samplers):
        raise SuiteError(f"--ladder-samplers must name some of {', '.join(LADDER_SAMPLERS)}, "
                         f"got {', '.join(ladder_samplers) or 'none'}")
    try:
        scene_id = str(scene.relative_to(REPO_ROOT / "suites").with_suffix(""))
    except ValueError:
        scene_id = scene.stem
    base = dict(base_params or {})
    algo.parse_params(base)
    keys = list(grid)
    cases = []
    for values in itertools.product(*(grid[k] for k in keys)):
        params = dict(base, **dict(zip(keys, values)))
        algo.parse_params(params)
        params.update(file_max_depth(scene, algo, params, transport))
        label = ", ".join(f"{k}={v}" for k, v in zip(keys, values))
        cases.append(Case(scene=scene, scene_id=scene_id, algorithm=algo.name, params=params,
                          transport=transport, label=label, expect="report"))
    name = f"sweep {algo.name} on {scene_id} ({' x '.join(keys)})"
    return Suite(name=name, path=scene, cases=tuple(cases), reference_spp=reference_spp,
                 reference_passes=reference_passes, repeats=repeats, ladder=tuple(ladder),
                 ladder_samplers=tuple(ladder_samplers), seeds=seeds, description=f"grid {grid}")


def sweep_table(records: list[Record], *, metric: str = "relmse") -> str:
    """A text table of a sweep: configuration, error, time, efficiency, and the
    equal-error / equal-time ratios against Mitsuba's ladder (:mod:`reports.pareto`)."""
    from reports.pareto import points_from_records, summarize_points, top_rung_race

    groups = points_from_records(records, metric=metric)
    lines = []
    for (scene, transport), pts in groups.items():
        summary = summarize_points(pts["own"], pts["mitsuba"])
        lines.append(f"{scene} vs Mitsuba {transport} ({metric}; noise floor "
                     f"{pts['noise_floor']:.3g})" if pts.get("noise_floor") is not None
                     else f"{scene} vs Mitsuba {transport} ({metric})")
        head = (f"  {'configuration':<40} {metric:>10} {'time ms':>9} {'efficiency':>11} "
                f"{'pareto':>6} {'t/t_mi @err':>11} {'e/e_mi @t':>10}")
        lines += [head, "  " + "-" * (len(head) - 2)]
        for row in summary["rows"]:
            def f(x, spec):
                width = int(spec.split(".")[0] or 0)
                return format(x, spec) if isinstance(x, float) and math.isfinite(x) else "—".rjust(width)
            def r(x, spec, extrapolated):
                width = int(spec.split(".")[0])
                return (("~" if extrapolated else "") + f(x, "." + spec.split(".")[1]).strip()).rjust(width)
            lines.append(f"  {row['label'][:40]:<40} {f(row['error'], '10.4g')} "
                         f"{f(row['time'] * 1e3, '9.1f')} {f(row['efficiency'], '11.4g')} "
                         f"{'*' if row['pareto'] else '':>6} "
                         f"{r(row['equal_error_time_ratio'], '11.3g', row['equal_error_extrapolated'])} "
                         f"{r(row['equal_time_error_ratio'], '10.3g', row['equal_time_extrapolated'])}")
        for row in summary["mitsuba_rows"]:
            lines.append(f"  {row['label'][:40]:<40} {row['error']:10.4g} {row['time'] * 1e3:9.1f} "
                         f"{row['efficiency']:11.4g}")
        best = summary["best"]
        if best:
            x1 = "~" if best["equal_error_extrapolated"] else ""
            x2 = "~" if best["equal_time_extrapolated"] else ""
            lines.append(f"  own best: equal-error time ratio {x1}{best['equal_error_time_ratio']:.3g} "
                         f"({best['equal_error_label']}), equal-time error ratio "
                         f"{x2}{best['equal_time_error_ratio']:.3g} ({best['equal_time_label']}); "
                         "< 1 means the own configuration wins; ~ extrapolated beyond Mitsuba's ladder")
        race = top_rung_race(pts["own"], pts["mitsuba"])
        if race and math.isfinite(race["ratio"]):
            rng = (f" (range {race['ratio_min']:.3g}-{race['ratio_max']:.3g} over "
                   + (f"{len(race['ratio_rounds'])} paired rounds)" if race["spread"] == "paired"
                      else "fastest vs slowest renders)") if race["spread"] else "")
            lines.append(f"  to Mitsuba's {race['spp']}-spp error ({race['sampler'] or 'independent'}, "
                         f"{race['error']:.3g}): own {race['own_time'] * 1e3:.1f} ms vs "
                         f"{race['time'] * 1e3:.1f} ms, ratio {'~' if race['extrapolated'] else ''}"
                         f"{race['ratio']:.3g}{rng}")
        lines.append("")
    return "\n".join(lines) if lines else ("no speed-vs-error table: no finished configuration "
                                            "with a Mitsuba ladder point (--ladder)")
