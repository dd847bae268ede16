"""Mitsuba's spp ladder: the same scene rendered at several sample counts, timed.

For each spp of the ladder the scene is rendered with the reference overrides
of :func:`references.reference.prepare_scene_xml` (the transport's
integrator, box filter) and one of Mitsuba's samplers (:data:`SAMPLERS`:
``independent``, the references' sampler; ``stratified`` and ``multijitter``,
jittered strata; ``ldsampler``, a scrambled (0, 2)-sequence), with seeds
from :data:`LADDER_SEED` on — independent of every reference pass seed (those
are derived by hashing), so ladder and reference noise are independent.
Times: one untimed warm-up render per spp (kernel compilation), then
``repeats`` renders with the seeds ``LADDER_SEED + 1 .. LADDER_SEED +
repeats`` (the render time does not depend on the seed, so the timed renders
also give ``repeats`` independent images for the error's mean and spread),
the clock stopped after ``dr.sync_thread()``.

What the images are compared with, and how, is the caller's business: this
module knows no metric.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

__all__ = ["render_ladder", "LADDER_SEED", "SAMPLERS", "sampler_spec"]

LADDER_SEED = 987654
#: Mitsuba's samplers a ladder may use.  ``stratified`` and ``multijitter`` round the
#: sample count up to a square, ``ldsampler`` to a square power of two above 1: a ladder
#: of powers of 4 from 4 on renders exactly its spp with all four.
SAMPLERS = ("independent", "stratified", "multijitter", "ldsampler")


def sampler_spec(sampler: str, spp: int, seed: int = LADDER_SEED) -> dict:
    """The ``<sampler>`` of a ladder rung (for :func:`references.reference.prepare_scene_xml`)."""
    if sampler not in SAMPLERS:
        raise ValueError(f"ladder sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    return {"type": sampler, "sample_count": int(spp), "seed": int(seed)}


def render_ladder(scene_path, *, transport: str, spps=(1, 4, 16, 64), repeats: int = 3,
                  defines: dict | None = None, sampler: str = "independent") -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps`` with ``sampler``.

    Returns one dict per rendered sample count: ``spp`` (what the sampler
    rendered: ``ldsampler`` rounds up to a power of 4, and a rung equal to an
    earlier one is dropped), ``requested_spp``, ``images`` (float32 ``(H, W, 3)``, one per
    timed render, distinct seeds), ``image`` (the last), ``median_s``,
    ``times_s``, ``variant``, ``mitsuba``, ``sampler``.
    """
    import drjit as dr

    from .mitsuba_env import load_mitsuba
    from .reference import load_scene, prepare_scene_xml

    if not spps or any(int(s) < 1 for s in spps):
        raise ValueError(f"ladder spps must be positive integers, got {list(spps)}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    sampler_spec(sampler, 1)                     # checks the name before loading Mitsuba
    mi = load_mitsuba()
    path = Path(scene_path)
    out = []
    for spp in spps:
        spp = int(spp)
        xml, _, _ = prepare_scene_xml(path, transport=transport, spp_per_pass=spp, seed=LADDER_SEED,
                                      defines=defines, sampler=sampler_spec(sampler, spp))
        scene = load_scene(mi, path, xml)

        def once(seed):
            img = mi.render(scene, spp=spp, seed=seed)
            dr.eval(img)
            dr.sync_thread()
            return np.asarray(img, dtype=np.float32)[..., :3]

        once(LADDER_SEED)                            # warm-up: kernel compilation
        # A sampler may round the count (ldsampler: 1 -> 4); the rung is what was rendered.
        actual = int(scene.sensors()[0].sampler().sample_count())
        if any(r["spp"] == actual for r in out):
            continue
        times, images = [], []
        for k in range(repeats):
            t0 = time.perf_counter()
            images.append(once(LADDER_SEED + 1 + k))
            times.append(time.perf_counter() - t0)
        out.append({"spp": actual, "requested_spp": spp, "image": images[-1], "images": images,
                    "median_s": statistics.median(times), "times_s": times,
                    "variant": mi.variant(), "mitsuba": mi.__version__, "sampler": sampler})
    return out
