"""Model only what a scene needs: ``gibench advise SCENE`` and ``--algorithm auto``.

The scene is read (:func:`scene_features`): which BSDFs its visible shapes use
(diffuse only? delta mirrors and glass? glossy microfacets?), which lights
(delta point/spot/directional, area emitters, a constant environment),
whether it is closed (every ray from the camera position hits geometry, so
light keeps bouncing; how many rays from the centre of its bounding box
escape) and how many primitives it has.  Each own algorithm's
light-transport model (:data:`MODELS`, thesis chapters 1–3) covers some of
these features; :func:`advise` names what each model leaves out on this
scene.

The choice rests on measurements when there are any: the records of
``gibench leaderboard SCENE`` in the results store (every own algorithm's
error against full transport and its time, with Mitsuba's ladder).  Then the
recommendation is the fastest measured configuration whose mean error
reaches the target (default: Mitsuba's most expensive ladder rung's error),
and each cheaper model is listed with its measured error floor.  Without
measurements, the cheapest algorithm whose model covers every feature is
recommended by the order of :data:`MODELS` (cheapest model first, an order
of model scope, not a measurement), and the advice says the leaderboard has
not been run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.errors import GibenchError
from core.loader import load_scene

__all__ = ["MODELS", "scene_features", "omissions", "advise", "Advice", "resolve_auto"]

DELTA_BSDFS = {"conductor", "dielectric", "thindielectric"}
GLOSSY_BSDFS = {"roughconductor", "roughdielectric", "roughplastic", "plastic"}

#: The own algorithms' models, cheapest model first: what each covers.
MODELS = {
    "zbuffer": {"thesis": "1", "shadows": False, "delta": False, "glossy": False,
                "interreflection": False, "delta_lights": True, "area_lights": True, "dof": False},
    "depthsort": {"thesis": "1", "shadows": False, "delta": False, "glossy": False,
                  "interreflection": False, "delta_lights": True, "area_lights": True, "dof": False},
    "raycast": {"thesis": "2.1-2.3", "shadows": True, "delta": False, "glossy": False,
                "interreflection": False, "delta_lights": True, "area_lights": True, "dof": False},
    "whitted": {"thesis": "2.4", "shadows": True, "delta": True, "glossy": False,
                "interreflection": False, "delta_lights": True, "area_lights": True, "dof": False},
    "radiosity": {"thesis": "3.3-3.4", "shadows": True, "delta": False, "glossy": False,
                  "interreflection": True, "delta_lights": False, "area_lights": True, "dof": False,
                  "spheres": False},
    "distributed": {"thesis": "2.5", "shadows": True, "delta": True, "glossy": True,
                    "interreflection": False, "delta_lights": True, "area_lights": True, "dof": True},
    "path": {"thesis": "3.2", "shadows": True, "delta": True, "glossy": True,
             "interreflection": True, "delta_lights": True, "area_lights": True, "dof": True},
}

_WHAT = {"shadows": "shadows", "delta": "mirror/glass reflection and refraction",
         "glossy": "glossy reflection", "interreflection": "diffuse interreflection",
         "delta_lights": "point/spot/directional lights", "area_lights": "area lights",
         "dof": "depth of field", "spheres": "analytic spheres (polygons only)"}


def _directions(n: int) -> np.ndarray:
    """``n`` unit vectors on a Fibonacci sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _escape_fraction(scene, origin: np.ndarray, n: int = 256) -> float:
    """Fraction of ``n`` rays from ``origin`` that hit no shape (numpy, brute force)."""
    d = _directions(n)
    hit = np.zeros(n, dtype=bool)
    for s in scene.shapes:
        if s.kind == "sphere":
            oc = origin - s.center
            b = d @ oc
            c = oc @ oc - s.radius ** 2
            disc = b * b - c
            t = -b - np.sqrt(np.maximum(disc, 0.0))      # near root: a sphere around the
            hit |= (disc >= 0) & (t > 1e-6)               # origin does not count as a hit
        elif s.vertices is not None and s.faces is not None:
            tri = s.vertices[s.faces]                    # (F, 3, 3)
            for lo in range(0, len(tri), 2048):
                chunk = tri[lo:lo + 2048]
                v0, e1, e2 = chunk[:, 0], chunk[:, 1] - chunk[:, 0], chunk[:, 2] - chunk[:, 0]
                # Moller-Trumbore for every (ray r, triangle t) pair of the chunk
                p = np.cross(d[:, None, :], e2[None])          # (R, T, 3)
                det = np.einsum("rtk,tk->rt", p, e1)
                ok = np.abs(det) > 1e-12
                inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
                tv = origin[None, :] - v0                      # (T, 3)
                q = np.cross(tv, e1)                           # (T, 3)
                u = np.einsum("rtk,tk->rt", p, tv) * inv
                v = (d @ q.T) * inv
                t = np.einsum("tk,tk->t", q, e2)[None, :] * inv
                hit |= np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6), axis=1)
    return float(1.0 - hit.mean())


def _centre(scene) -> np.ndarray:
    """Centre of the bounding box of every shape."""
    pts = []
    for s in scene.shapes:
        if s.kind == "sphere":
            pts += [s.center - s.radius, s.center + s.radius]
        elif s.vertices is not None and len(s.vertices):
            pts += [s.vertices.min(axis=0), s.vertices.max(axis=0)]
    if not pts:
        return np.zeros(3)
    pts = np.asarray(pts, dtype=np.float64)
    return 0.5 * (pts.min(axis=0) + pts.max(axis=0))


#: Below this fraction of escaping rays (from the scene's centre) the scene encloses
#: its light, and diffuse interreflection is asked of the model (a heuristic; the
#: leaderboard's measured floors replace it).
ENCLOSED = 0.3


def scene_features(scene) -> dict:
    """What a scene (a path or a loaded :class:`core.scene.Scene`) asks of a model."""
    if not hasattr(scene, "shapes"):
        scene = load_scene(scene)
    kinds = sorted({scene.materials[s.material].kind for s in scene.shapes if not s.is_emitter}
                   | {scene.materials[s.material].kind for s in scene.shapes
                      if s.is_emitter and scene.materials[s.material].kind != "diffuse"})
    prims = sum(1 if s.kind == "sphere" else (len(s.faces) if s.faces is not None else 0)
                for s in scene.shapes)
    cam = scene.camera
    escape = _escape_fraction(scene, _centre(scene))
    return {
        "bsdfs": kinds,
        "diffuse_only": all(k == "diffuse" for k in kinds),
        "delta": any(k in DELTA_BSDFS for k in kinds),
        "glossy": any(k in GLOSSY_BSDFS for k in kinds),
        "lights": sorted({l.kind for l in scene.lights}
                         | ({"area"} if scene.emitters else set())
                         | ({"environment"} if scene.environment is not None else set())),
        "delta_lights": bool(scene.lights),
        "area_lights": bool(scene.emitters) or scene.environment is not None,
        "escape_fraction": escape,
        "closed": escape == 0.0,
        "enclosing": escape < ENCLOSED,
        "primitives": int(prims),
        "spheres": any(s.kind == "sphere" for s in scene.shapes),
        "dof": cam.kind == "thinlens" and cam.aperture_radius > 0,
        "motion": any(s.moves for s in scene.shapes) or cam.moves,
    }


def omissions(algorithm: str, features: dict) -> list[str]:
    """What ``algorithm``'s model leaves out of this scene's features (empty: it covers them).

    Shadows are asked of every scene with more than one primitive, diffuse
    interreflection of scenes that enclose their light (``enclosing``: fewer than
    :data:`ENCLOSED` of the rays from the scene's centre escape): heuristics that
    the measured error floors of the leaderboard replace."""
    m = MODELS[algorithm]
    need = {"shadows": features["primitives"] > 1, "delta": features["delta"],
            "glossy": features["glossy"], "interreflection": features["enclosing"],
            "delta_lights": features["delta_lights"], "area_lights": features["area_lights"],
            "dof": features["dof"], "spheres": features["spheres"]}
    return [_WHAT[k] for k, v in need.items() if v and not m.get(k, True)]


@dataclass
class Advice:
    scene: str
    features: dict
    algorithm: str
    params: dict
    reason: str
    lines: list = field(default_factory=list)
    measured: bool = False

    def __str__(self) -> str:
        return "\n".join(self.lines)


def _measured_points(scene_id: str, records) -> dict | None:
    """The leaderboard's points of ``scene_id`` against full transport (latest run), or None."""
    from reports.pareto import points_from_records

    from .leaderboard import SUITE_PREFIX

    recs = [r for r in records if str(r.suite).startswith(SUITE_PREFIX) and r.scene == scene_id]
    if not recs:
        return None
    latest = max(str(r.run_id) for r in recs)
    recs = [r for r in recs if str(r.run_id) == latest]
    g = points_from_records(recs).get((scene_id, "full"))
    if g is None:
        return None
    g["failed"] = sorted({(r.algorithm, r.error) for r in recs if r.kind == "case" and r.error})
    g["run_id"] = latest
    return g


def _scene_id(path: Path) -> str:
    from core.provenance import REPO_ROOT

    try:
        return str(path.resolve().relative_to(REPO_ROOT / "suites").with_suffix(""))
    except ValueError:
        return path.stem


def advise(scene_path, *, records=None, target: float | None = None) -> Advice:
    """The cheapest own algorithm and settings whose model covers the scene.

    ``records``: result records to read leaderboard measurements from (None:
    none).  ``target``: the error to reach (default: Mitsuba's most expensive
    ladder rung in the leaderboard run)."""
    from .leaderboard import CONFIGS

    path = Path(scene_path)
    scene_id = _scene_id(path)
    feats = scene_features(path)
    lines = [f"scene: {scene_id} ({feats['primitives']} primitives)",
             "  BSDFs: " + ", ".join(feats["bsdfs"])
             + ("  (diffuse only)" if feats["diffuse_only"] else ""),
             "  lights: " + (", ".join(feats["lights"]) or "none"),
             f"  {'closed' if feats['closed'] else 'enclosing' if feats['enclosing'] else 'open'} "
             f"({feats['escape_fraction']:.0%} of rays from the scene's centre escape)"]
    if feats["dof"]:
        lines.append("  thin-lens camera: depth of field")
    covering = [a for a in MODELS if not omissions(a, feats)]
    g = _measured_points(scene_id, records or [])
    if g is not None and g["own"]:
        top = max(g["mitsuba"], key=lambda p: p.get("spp") or 0)
        goal = target if target is not None else top["error"]
        goal_txt = (f"target relMSE {goal:.3g}" + ("" if target is not None else
                    f" (Mitsuba {top.get('spp')} spp, {g.get('sampler')} sampler, "
                    f"{top['time'] * 1e3:.0f} ms)"))
        ok = [p for p in g["own"] if p["error"] <= goal]
        if ok:
            best = min(ok, key=lambda p: p["time"])
            reason = (f"fastest measured configuration reaching the {goal_txt}: relMSE "
                      f"{best['error']:.3g} in {best['time'] * 1e3:.0f} ms (leaderboard run {g['run_id']})")
        else:
            best = min(g["own"], key=lambda p: p["error"])
            reason = (f"no measured configuration reaches the {goal_txt}; the lowest error is "
                      f"{best['error']:.3g} in {best['time'] * 1e3:.0f} ms (leaderboard run "
                      f"{g['run_id']}); a finer setting of it, or path with more samples, is needed")
        algo, params = best["algorithm"], _non_default(best["algorithm"], best.get("params") or {})
        lines.append(f"recommended: {algo} {params}: {reason}")
        floors = {}
        for p in g["own"]:
            f = floors.get(p["algorithm"])
            if f is None or p["time"] > f["time"]:
                floors[p["algorithm"]] = p
        lines.append("what each model leaves out here (error at its most converged setting):")
        failed = dict(g["failed"])
        for a in MODELS:
            om = omissions(a, feats)
            fl = floors.get(a)
            meas = (f"relMSE {fl['error']:.3g} at {fl['label']} ({fl['time'] * 1e3:.0f} ms)" if fl
                    else f"cannot render ({failed[a]})" if a in failed else "not measured")
            lines.append(f"  {a:<12} {'covers the scene' if not om else 'no ' + ', no '.join(om)}; {meas}")
        return Advice(scene_id, feats, algo, params, reason, lines, measured=True)
    algo = covering[0] if covering else "path"
    params = dict(CONFIGS[algo][-1][1])
    reason = ("cheapest model covering every feature of the scene (by model scope: no "
              "leaderboard measurements of this scene; run `gibench leaderboard "
              f"{path}` to choose from measured error and time)")
    lines.append(f"recommended: {algo} {params}: {reason}")
    lines.append("what each cheaper model leaves out here:")
    for a in MODELS:
        if a == algo:
            break
        lines.append(f"  {a:<12} no {', no '.join(omissions(a, feats))}")
    return Advice(scene_id, feats, algo, params, reason, lines)


def _non_default(algorithm: str, params: dict) -> dict:
    """``params`` without the values equal to the algorithm's defaults (the sample count
    is kept)."""
    from . import registry

    try:
        algo = registry.get(algorithm)
    except GibenchError:
        return dict(params)
    defaults = {p.name: p.default for p in algo.params}
    return {k: v for k, v in params.items()
            if k not in defaults or defaults[k] != v or k == algo.spp_param}


def resolve_auto(scene_path, *, records=None) -> tuple[str, dict]:
    """``--algorithm auto``: the advised algorithm and its parameters."""
    try:
        a = advise(scene_path, records=records)
    except GibenchError:
        raise
    return a.algorithm, a.params
