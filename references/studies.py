"""Mitsuba 3 side of the hard-case studies (:mod:`gibench.studies`).

``mitsuba_distant_sphere`` renders the distant-sphere configuration of
:func:`gibench.studies.distant_sphere` — the same camera (at the origin, aimed
at the sphere, field of view from the distance), the same sphere, one ray
through each pixel centre — with Mitsuba 3 from
``suites/hard/distant_sphere.xml`` and counts the pixels whose hit/miss
differs from the analytic silhouette.

How: the scene's ``aov`` integrator writes the depth of the first hit (0 on a
miss); the ``stratified`` sampler with ``jitter = false`` and one sample puts
that sample at the pixel centre, and the box filter keeps it in its pixel.

Provenance: each row carries the Mitsuba and Dr.Jit versions and the variant.
Both variants tried here (``scalar_rgb``, ``llvm_ad_rgb``) describe the scene
in float32 (sensor transform, ray origin and direction, sphere centre); the
sphere intersection itself runs in float64 in ``scalar_rgb`` and float32 in
``llvm_ad_rgb`` (Mitsuba's ``sphere.cpp`` picks float32 for JIT-differentiable
variants), after moving the ray origin to the plane through the centre
perpendicular to the ray.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["mitsuba_distant_sphere", "MITSUBA_DEFAULT_FAR_CLIP"]

#: The ``perspective`` sensor's default far clip distance (Mitsuba 3 docs and
#: ``sensor.far_clip()`` of a sensor loaded without one).
MITSUBA_DEFAULT_FAR_CLIP = 1e4


def mitsuba_distant_sphere(scene_path, *, distances, variants=("scalar_rgb", "llvm_ad_rgb"),
                           aims=("axis", "oblique"), far_clips=("default", "2d"), size=64,
                           fill=0.75, radius=1.0, band=2.0) -> list[dict]:
    """Wrong pixels of Mitsuba's render of the distant-sphere silhouette.

    Parameters
    ----------
    scene_path : path of ``distant_sphere.xml``
    distances : distances d of the sphere's centre from the camera
    variants : Mitsuba variants to render with (switched in turn)
    aims : keys of :data:`gibench.studies.AIMS`
    far_clips : 'default' (the sensor's own 1e4, as a scene that does not set
        it gets) and/or '2d' (twice the distance: nothing is clipped)
    band : as in :func:`gibench.studies.distant_sphere`: pixels within
        ``band``·u₃₂·d/r of the edge are ambiguous in float32
    """
    from gibench.studies import _silhouette_rays, unit_roundoff

    from .mitsuba_env import load_mitsuba, mitsuba_versions

    scene_path = Path(scene_path)
    rows = []
    for variant in variants:
        mi = load_mitsuba(variant)
        import drjit as dr

        vers = mitsuba_versions()
        for aim in aims:
            for d in distances:
                d = float(d)
                _, center, rel_edge, _ = _silhouette_rays(d, radius, size, fill, aim)
                inside = rel_edge < 0.0
                tan_alpha = radius / math.sqrt((d - radius) * (d + radius))
                fov = 2.0 * math.degrees(math.atan(tan_alpha / fill))
                beta = band * unit_roundoff("float32") * d / radius
                for policy in far_clips:
                    if policy == "default":
                        far = MITSUBA_DEFAULT_FAR_CLIP
                    elif policy == "2d":
                        far = 2.0 * d
                    else:
                        raise ValueError(f"mitsuba_distant_sphere: far_clips entries are 'default' "
                                         f"or '2d', got {policy!r}")
                    scene = mi.load_file(str(scene_path), cx=repr(float(center[0])), cy=repr(float(center[1])),
                                         cz=repr(float(center[2])), radius=repr(float(radius)),
                                         fov=repr(fov), far_clip=repr(far), size=str(size))
                    img = mi.render(scene, spp=1, seed=0)
                    dr.sync_thread()
                    depth = np.asarray(img, dtype=np.float64)[..., 0]
                    hit = (depth > 0.0).ravel()
                    wrong = hit != inside
                    rows.append({
                        "variant": variant, "aim": aim, "distance": d, "far_clip_policy": policy,
                        "far_clip": float(scene.sensors()[0].far_clip()),
                        "pixels": int(hit.size), "expected_hits": int(inside.sum()),
                        "hits": int(hit.sum()), "wrong": int(wrong.sum()),
                        "wrong_frac": float(wrong.mean()), "empty": bool(not hit.any()),
                        "band": float(beta),
                        "wrong_outside_band": int((wrong & (np.abs(rel_edge) > beta)).sum()),
                        "max_rel_edge_of_wrong": float(np.abs(rel_edge[wrong]).max()) if wrong.any() else 0.0,
                        "mitsuba": vers["mitsuba"], "drjit": vers["drjit"],
                    })
    return rows
