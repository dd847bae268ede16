"""Error against time along Mitsuba's spp ladder (:mod:`references.ladder`).

The peer's error–time curve, measured in the same run as the own algorithms,
is what every equal-error and equal-time ratio is read from
(:mod:`reports.pareto`).  This module joins the two lower layers: Mitsuba's
timed renders and the metrics.
"""

from __future__ import annotations

from core.provenance import REPO_ROOT

__all__ = ["ladder_points", "mitsuba_ladder"]


def ladder_points(scene_path, *, transport: str, spps=(1, 4, 16, 64), reference, repeats: int = 3,
                  defines: dict | None = None, metrics=None) -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps``: time and error
    against ``reference`` (a :class:`references.reference.Reference`).

    ``metrics(ref, img, var)`` computes the error dictionary (default
    :func:`reports.metrics.compare` with the reference variance, so the Z-test
    is included).  Returns one dict per spp: ``spp``, ``median_s``,
    ``times_s``, ``metrics``, ``variant``, ``mitsuba``.
    """
    from references.ladder import render_ladder
    from reports.metrics import compare

    out = []
    for rung in render_ladder(scene_path, transport=transport, spps=spps, repeats=repeats,
                              defines=defines):
        img = rung.pop("image")
        rung["metrics"] = (metrics(reference.image, img, reference.variance) if metrics is not None
                           else compare(reference.image, img, reference_variance=reference.variance,
                                        allow_nonfinite=True))
        out.append(rung)
    return out


def mitsuba_ladder(*, scenes=("cornell/cornell_box.xml",), spps=(4, 16, 64, 256), repeats=3,
                   reference_spp=1024, passes=8) -> list[dict]:
    """Mitsuba's ``path`` at each spp against the stored full reference of each scene
    (a path under ``suites/``): rows (scene, spp, relmse, mae, median_s, variant)."""
    from references.ladder import render_ladder
    from references.reference import get_reference
    from reports.metrics import mae, relmse

    rows = []
    for scene_id in scenes:
        path = REPO_ROOT / "suites" / scene_id
        ref = get_reference(path, transport="full", spp=reference_spp, passes=passes)
        for rung in render_ladder(path, transport="full", spps=spps, repeats=repeats):
            rows.append({"scene": scene_id, "renderer": "mitsuba path", "spp": rung["spp"],
                         "relmse": relmse(ref.image, rung["image"]), "mae": mae(ref.image, rung["image"]),
                         "median_s": rung["median_s"], "variant": rung["variant"],
                         "mitsuba": rung["mitsuba"]})
    return rows
