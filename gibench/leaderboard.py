"""Per-scene leaderboard: every own algorithm against the full-transport reference.

``gibench leaderboard SCENE`` renders the scene with every registered own
algorithm that can render it, at its main settings (:data:`CONFIGS`), and
compares each with Mitsuba's full-transport (``path``) reference, with
Mitsuba's spp ladder measured in the same run: one error–time plot for all of
them.  The simplified models (local illumination, ray casting, Whitted,
distributed ray tracing, radiosity: thesis chapters 1–3) cannot converge to
full transport; their *error floor* — the error left when more samples no
longer help — is the model error on this scene, the ablation of what each
model leaves out (:func:`reports.pareto.model_floors`).

An algorithm that refuses the scene (a BSDF or light it does not model)
gives a record whose ``error`` names the cause; the table shows it as "cannot
render".  :mod:`gibench.advise` reads these records back.
"""

from __future__ import annotations

from pathlib import Path

from core.records import Record

from . import registry
from .suite import Case, Suite, SuiteError, file_max_depth

__all__ = ["CONFIGS", "SUITE_PREFIX", "leaderboard_suite", "leaderboard_table"]

SUITE_PREFIX = "leaderboard "

#: Main settings of each own algorithm: (label, params), cheapest first.
CONFIGS = {
    "zbuffer": [("z-buffer, Phong, 2x2", {"spp": 4})],
    "depthsort": [("depth sort, Phong, 2x2", {"spp": 4})],
    "raycast": [("ray casting, 2x2", {"spp": 4, "light_samples": 4}),
                ("ray casting, 4x4", {"spp": 16, "light_samples": 16})],
    "whitted": [("Whitted, 2x2", {"spp": 4}), ("Whitted, 6x6", {"spp": 36})],
    "distributed": [("distributed, 4x4", {"spp": 16}), ("distributed, 8x8", {"spp": 64})],
    "radiosity": [("radiosity, 256 patches", {"patches": 256, "spp": 4}),
                  ("radiosity, 1024 patches", {"patches": 1024, "spp": 4})],
    "path": [("path, 16 Sobol points", {"spp": 16, "sampler": "sobol"}),
             ("path, 64 Sobol points", {"spp": 64, "sampler": "sobol"})],
}


def leaderboard_suite(scene, *, algorithms=None, reference_spp: int = 1024, reference_passes: int = 8,
                      repeats: int = 3, seeds: int = 3, ladder=(1, 4, 16, 64),
                      ladder_samplers=("independent", "stratified", "multijitter", "ldsampler")) -> Suite:
    """The leaderboard of ``scene`` as a suite: every configuration of :data:`CONFIGS`
    (of ``algorithms``, default all registered) against the full reference."""
    from core.provenance import REPO_ROOT

    scene = Path(scene)
    if not scene.is_file():
        raise SuiteError(f"{scene}: scene file not found")
    scene = scene.resolve()
    try:
        scene_id = str(scene.relative_to(REPO_ROOT / "suites").with_suffix(""))
    except ValueError:
        scene_id = scene.stem
    names = list(algorithms or [a.name for a in registry.algorithms()])
    cases = []
    for name in names:
        algo = registry.get(name)
        for label, params in CONFIGS.get(name, [(f"{name} defaults", {})]):
            algo.parse_params(dict(params))
            params = {**params, **file_max_depth(scene, algo, params)}
            cases.append(Case(scene=scene, scene_id=scene_id, algorithm=name, params=dict(params),
                              transport="full", label=label,
                              expect="report" if algo.transport == "full" and name == "path"
                              else "model-error"))
    return Suite(name=f"{SUITE_PREFIX}{scene_id}", path=scene, cases=tuple(cases),
                 reference_spp=reference_spp, reference_passes=reference_passes, repeats=repeats,
                 ladder=tuple(ladder), ladder_samplers=tuple(ladder_samplers), seeds=seeds,
                 description="every own algorithm against full transport")


def leaderboard_table(records: list[Record], *, metric: str = "relmse") -> str:
    """Text table: per configuration error (mean ± spread over seeds), time, equal-error
    time ratio against Mitsuba's ladder, and each algorithm's model-error floor."""
    import math

    from reports.pareto import model_floors, points_from_records, summarize_points

    lines = []
    failed = [r for r in records if r.kind == "case" and r.error and r.seed == 0]
    for (scene, transport), g in points_from_records(records, metric=metric).items():
        s = summarize_points(g["own"], g["mitsuba"])
        floors = model_floors(g["own"])
        lines.append(f"{scene} vs Mitsuba {transport} (sampler {g.get('sampler')}; {metric}; "
                     f"reference noise floor {g['noise_floor']:.3g})" if g.get("noise_floor")
                     else f"{scene} vs Mitsuba {transport} ({metric})")
        lines.append(f"  {'configuration':<28} {metric:>10} {'± sd':>9} {'time ms':>9} {'t/t_mi @err':>11}")
        for r in s["rows"]:
            ee = r["equal_error_time_ratio"]
            ee_s = (("~" if r["equal_error_extrapolated"] else "") + f"{ee:.3g}") if math.isfinite(ee) else "—"
            sd = r.get("spread")
            sd_s = f"{sd:.2g}" if isinstance(sd, float) and math.isfinite(sd) else "—"
            lines.append(f"  {r['label'][:28]:<28} {r['error']:10.4g} {sd_s:>9} {r['time'] * 1e3:9.1f} {ee_s:>11}")
        for p in g["mitsuba"]:
            lines.append(f"  {p['label'][:28]:<28} {p['error']:10.4g} {'':>9} {p['time'] * 1e3:9.1f}")
        lines.append("  model error floors (error at the most converged setting; drop = its ratio "
                     "to the previous setting's, ~1: the floor is reached):")
        for algo, f in floors.items():
            lines.append(f"    {algo:<12} {f['floor']:10.4g}  ({f['label']}; drop {f['drop']:.2f})"
                         if math.isfinite(f["drop"]) else
                         f"    {algo:<12} {f['floor']:10.4g}  ({f['label']}; one setting)")
    for r in failed:
        lines.append(f"  cannot render: {r.algorithm} ({r.label}): {r.error}")
    return "\n".join(lines) if lines else "no leaderboard results"
