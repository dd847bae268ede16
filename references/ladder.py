"""Mitsuba's spp ladder: the same scene rendered at several sample counts, timed.

For each spp of the ladder the scene is rendered with the reference overrides
of :func:`references.reference.prepare_scene_xml` (the transport's
integrator, box filter) and one of Mitsuba's samplers (:data:`SAMPLERS`:
``independent``, the references' sampler; ``stratified`` and ``multijitter``,
jittered strata; ``ldsampler``, a scrambled (0, 2)-sequence), with seeds
from :data:`LADDER_SEED` on — independent of every reference pass seed (those
are derived by hashing), so ladder and reference noise are independent.
Times: two untimed warm-up renders per spp with different seeds (kernel
compilation, and the recompilation Dr.Jit may do when a baked-in seed
changes, which would otherwise land in the first timed render), then
``repeats`` renders with the seeds ``LADDER_SEED + 1 .. LADDER_SEED +
repeats`` (the render time does not depend on the seed, so the timed renders
also give ``repeats`` independent images for the error's mean and spread),
the clock stopped after ``dr.sync_thread()``.  :func:`render_ladder` times the
rungs one after the other; :func:`prepare_ladder` returns the warmed-up rungs
so that a caller can interleave their timed renders with other work (the own
renders of the same scene, so both sides are timed under the same load).

What the images are compared with, and how, is the caller's business: this
module knows no metric.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

__all__ = ["render_ladder", "prepare_ladder", "Rung", "LADDER_SEED", "WARMUP_SEEDS", "SAMPLERS",
           "sampler_spec"]

LADDER_SEED = 987654
#: Seeds of a rung's two untimed warm-up renders (apart from the timed ones).
WARMUP_SEEDS = (LADDER_SEED, LADDER_SEED - 1)
#: Mitsuba's samplers a ladder may use.  ``stratified`` and ``multijitter`` round the
#: sample count up to a square, ``ldsampler`` to a square power of two above 1: a ladder
#: of powers of 4 from 4 on renders exactly its spp with all four.
SAMPLERS = ("independent", "stratified", "multijitter", "ldsampler")


def sampler_spec(sampler: str, spp: int, seed: int = LADDER_SEED) -> dict:
    """The ``<sampler>`` of a ladder rung (for :func:`references.reference.prepare_scene_xml`)."""
    if sampler not in SAMPLERS:
        raise ValueError(f"ladder sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    return {"type": sampler, "sample_count": int(spp), "seed": int(seed)}


class Rung:
    """One prepared rung of a ladder: the scene loaded with its sampler and warmed up.

    ``spp`` is what the sampler renders (``ldsampler`` rounds up), ``requested_spp`` what
    was asked; :meth:`render` renders once with ``seed`` and returns the image (float32
    ``(H, W, 3)``) and its wall time, the clock stopped after ``dr.sync_thread()``.
    """

    def __init__(self, mi, dr, scene, *, spp: int, requested_spp: int, sampler: str, warmup_s: float):
        self._mi, self._dr, self._scene = mi, dr, scene
        self.spp, self.requested_spp, self.sampler = spp, requested_spp, sampler
        self.warmup_s = warmup_s
        self.variant, self.mitsuba = mi.variant(), mi.__version__

    def render(self, seed: int) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        img = self._mi.render(self._scene, spp=self.requested_spp, seed=int(seed))
        self._dr.eval(img)
        self._dr.sync_thread()
        dt = time.perf_counter() - t0
        return np.asarray(img, dtype=np.float32)[..., :3], dt

    def __repr__(self) -> str:
        return f"Rung(spp={self.spp}, sampler={self.sampler!r}, variant={self.variant!r})"


def prepare_ladder(scene_path, *, transport: str, spps=(1, 4, 16, 64), defines: dict | None = None,
                   sampler: str = "independent") -> list[Rung]:
    """The rungs of ``spps`` with ``sampler``, each loaded and rendered twice untimed
    (:data:`WARMUP_SEEDS`; ``warmup_s`` their total), ready for timed renders in any
    order; a rung whose rendered count equals an earlier one's is dropped."""
    import drjit as dr

    from .mitsuba_env import load_mitsuba
    from .reference import load_scene, prepare_scene_xml

    if not spps or any(int(s) < 1 for s in spps):
        raise ValueError(f"ladder spps must be positive integers, got {list(spps)}")
    sampler_spec(sampler, 1)                     # checks the name before loading Mitsuba
    mi = load_mitsuba()
    path = Path(scene_path)
    out: list[Rung] = []
    for spp in spps:
        spp = int(spp)
        xml, _, _ = prepare_scene_xml(path, transport=transport, spp_per_pass=spp, seed=LADDER_SEED,
                                      defines=defines, sampler=sampler_spec(sampler, spp))
        scene = load_scene(mi, path, xml)
        # A sampler may round the count (ldsampler: 1 -> 4); the rung is what is rendered.
        actual = int(scene.sensors()[0].sampler().sample_count())
        if any(r.spp == actual for r in out):
            continue
        rung = Rung(mi, dr, scene, spp=actual, requested_spp=spp, sampler=sampler, warmup_s=0.0)
        # Two warm-up renders with different seeds: Dr.Jit compiles the kernel on the
        # first, and may compile it once more when a scalar it baked in (the seed)
        # changes; both compilations must happen before the timed renders.
        rung.warmup_s = sum(rung.render(s)[1] for s in WARMUP_SEEDS)
        out.append(rung)
    return out


def render_ladder(scene_path, *, transport: str, spps=(1, 4, 16, 64), repeats: int = 3,
                  defines: dict | None = None, sampler: str = "independent") -> list[dict]:
    """Mitsuba's integrator for ``transport`` at each spp of ``spps`` with ``sampler``,
    rung after rung (:func:`prepare_ladder`, then ``repeats`` timed renders per rung).

    Returns one dict per rendered sample count: ``spp`` (what the sampler
    rendered: ``ldsampler`` rounds up to a power of 4, and a rung equal to an
    earlier one is dropped), ``requested_spp``, ``images`` (float32 ``(H, W, 3)``, one per
    timed render, distinct seeds), ``image`` (the last), ``median_s``,
    ``times_s``, ``variant``, ``mitsuba``, ``sampler``.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    out = []
    for rung in prepare_ladder(scene_path, transport=transport, spps=spps, defines=defines,
                               sampler=sampler):
        times, images = [], []
        for k in range(repeats):
            img, dt = rung.render(LADDER_SEED + 1 + k)
            images.append(img)
            times.append(dt)
        out.append({"spp": rung.spp, "requested_spp": rung.requested_spp, "image": images[-1],
                    "images": images, "median_s": statistics.median(times), "times_s": times,
                    "variant": rung.variant, "mitsuba": rung.mitsuba, "sampler": sampler})
    return out
