"""Mitsuba's own error-vs-time ladder (for the radiosity studies, issue 5).

Renders a scene with Mitsuba's path tracer (the reference overrides of
:func:`references.reference.prepare_scene_xml`: ``path`` with the file's
max_depth, independent sampler, box filter) at a ladder of spp, and compares
each image with the stored 1024-spp full reference.  The ladder's seed differs
from every reference pass seed (those are derived by hashing), so ladder and
reference noise are independent.  Times: one untimed warm-up render (kernel
compilation), then the median of ``repeats`` renders, the clock stopped after
``dr.sync_thread()``.

Provenance: every row carries the variant and the Mitsuba version.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np


__all__ = ["mitsuba_ladder", "ladder_points"]

REPO_ROOT = Path(__file__).resolve().parent.parent
LADDER_SEED = 987654


def mitsuba_ladder(*, scenes=("cornell/cornell_box.xml",), spps=(4, 16, 64, 256), repeats=3,
                   reference_spp=1024, passes=8) -> list[dict]:
    """Rows (scene, spp, relmse, mae, median_s, variant) for each scene × spp."""
    import drjit as dr

    from reports.metrics import mae, relmse

    from .mitsuba_env import load_mitsuba
    from .reference import get_reference, load_scene, prepare_scene_xml

    mi = load_mitsuba()
    rows = []
    for scene_id in scenes:
        path = REPO_ROOT / "suites" / scene_id
        ref = get_reference(path, transport="full", spp=reference_spp, passes=passes)
        for spp in spps:
            xml, _, _ = prepare_scene_xml(path, transport="full", spp_per_pass=spp, seed=LADDER_SEED)
            scene = load_scene(mi, path, xml)

            def once():
                img = mi.render(scene, spp=spp, seed=LADDER_SEED)
                dr.eval(img)
                dr.sync_thread()
                return np.asarray(img, dtype=np.float32)[..., :3]

            once()                                       # warm-up: kernel compilation
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                img = once()
                times.append(time.perf_counter() - t0)
            rows.append({"scene": scene_id, "renderer": "mitsuba path", "spp": spp,
                         "relmse": relmse(ref.image, img), "mae": mae(ref.image, img),
                         "median_s": statistics.median(times), "variant": mi.variant(),
                         "mitsuba": mi.__version__})
    return rows


def ladder_points(scene_path, *, transport: str, spps=(1, 4, 16, 64), reference, repeats: int = 3,
                  defines: dict | None = None, metrics=None) -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps``: time and error
    against ``reference`` (a :class:`references.reference.Reference`), for the
    speed-vs-error plots of ``gibench run``/``sweep`` (issue 9).

    The same overrides as the reference (:func:`prepare_scene_xml`), the seed
    :data:`LADDER_SEED` (independent of the reference's pass seeds); one
    untimed warm-up render per spp, then the median of ``repeats`` renders
    (clock stopped after ``dr.sync_thread()``).  ``metrics(ref, img, var)``
    computes the error dictionary (default :func:`reports.metrics.compare`
    with the reference variance, so the Z-test is included).

    Returns one dict per spp: ``spp``, ``median_s``, ``times_s``,
    ``metrics``, ``variant``, ``mitsuba``.
    """
    import drjit as dr

    from reports.metrics import compare

    from .mitsuba_env import load_mitsuba
    from .reference import load_scene, prepare_scene_xml

    if not spps or any(int(s) < 1 for s in spps):
        raise ValueError(f"ladder spps must be positive integers, got {list(spps)}")
    mi = load_mitsuba()
    path = Path(scene_path)
    out = []
    for spp in spps:
        spp = int(spp)
        xml, _, _ = prepare_scene_xml(path, transport=transport, spp_per_pass=spp, seed=LADDER_SEED,
                                      defines=defines)
        scene = load_scene(mi, path, xml)

        def once():
            img = mi.render(scene, spp=spp, seed=LADDER_SEED)
            dr.eval(img)
            dr.sync_thread()
            return np.asarray(img, dtype=np.float32)[..., :3]

        once()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            img = once()
            times.append(time.perf_counter() - t0)
        m = (metrics(reference.image, img, reference.variance) if metrics is not None else
             compare(reference.image, img, reference_variance=reference.variance,
                     allow_nonfinite=True))
        out.append({"spp": spp, "median_s": statistics.median(times), "times_s": times,
                    "metrics": m, "variant": mi.variant(), "mitsuba": mi.__version__})
    return out
