"""Render a scene file in a chosen Mitsuba variant with ``-D`` values, as it is.

For studies that ask what Mitsuba itself computes (a silhouette at a great
distance, the sensor's clipping) rather than for a converged reference: the
scene is loaded with :func:`mitsuba.load_file` and the given defines, rendered
once in the given variant (``scalar_rgb``, ``llvm_ad_rgb``, ...), and the
image is returned with the sensor's far clip distance and the versions.
Nothing here knows what the caller measures.

Both RGB variants describe the scene in float32 (sensor transform, ray origin
and direction, sphere centre); Mitsuba's sphere intersection runs in float64
in ``scalar_rgb`` and float32 in ``llvm_ad_rgb`` (``sphere.cpp`` picks float32
for JIT-differentiable variants).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .mitsuba_env import load_mitsuba, mitsuba_versions

__all__ = ["render_in_variant", "MITSUBA_DEFAULT_FAR_CLIP"]

#: The ``perspective`` sensor's default far clip distance (Mitsuba 3 docs and
#: ``sensor.far_clip()`` of a sensor loaded without one).
MITSUBA_DEFAULT_FAR_CLIP = 1e4


def render_in_variant(scene_path, *, variant: str, defines: dict[str, str], spp: int = 1,
                      seed: int = 0) -> tuple[np.ndarray, dict]:
    """Render ``scene_path`` with ``defines`` in ``variant``.

    Returns the film's image as float64 ``(H, W, C)`` and ``{"far_clip",
    "variant", "mitsuba", "drjit"}``.
    """
    mi = load_mitsuba(variant)
    import drjit as dr

    scene = mi.load_file(str(Path(scene_path)), **{k: str(v) for k, v in defines.items()})
    img = mi.render(scene, spp=spp, seed=seed)
    dr.sync_thread()
    vers = mitsuba_versions()
    return np.asarray(img, dtype=np.float64), {
        "far_clip": float(scene.sensors()[0].far_clip()), "variant": variant,
        "mitsuba": vers["mitsuba"], "drjit": vers["drjit"]}
