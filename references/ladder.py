"""Mitsuba's spp ladder: the same scene rendered at several sample counts, timed.

For each spp of the ladder the scene is rendered with the reference overrides
of :func:`references.reference.prepare_scene_xml` (the transport's
integrator, independent sampler, box filter), with the seed
:data:`LADDER_SEED` — independent of every reference pass seed (those are
derived by hashing), so ladder and reference noise are independent.  Times:
one untimed warm-up render per spp (kernel compilation), then ``repeats``
renders, the clock stopped after ``dr.sync_thread()``.

What the images are compared with, and how, is the caller's business: this
module knows no metric.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

__all__ = ["render_ladder", "LADDER_SEED"]

LADDER_SEED = 987654


def render_ladder(scene_path, *, transport: str, spps=(1, 4, 16, 64), repeats: int = 3,
                  defines: dict | None = None) -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps``.

    Returns one dict per spp: ``spp``, ``image`` (float32 ``(H, W, 3)``, the
    last timed render), ``median_s``, ``times_s``, ``variant``, ``mitsuba``.
    """
    import drjit as dr

    from .mitsuba_env import load_mitsuba
    from .reference import load_scene, prepare_scene_xml

    if not spps or any(int(s) < 1 for s in spps):
        raise ValueError(f"ladder spps must be positive integers, got {list(spps)}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
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

        once()                                       # warm-up: kernel compilation
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            img = once()
            times.append(time.perf_counter() - t0)
        out.append({"spp": spp, "image": img, "median_s": statistics.median(times),
                    "times_s": times, "variant": mi.variant(), "mitsuba": mi.__version__})
    return out
