"""Mitsuba 3's closest-hit ray throughput on given primitives and rays (for
``benchmarks/bench_accel.py``).  No own algorithm imports this module.

The primitives are the flat arrays of :mod:`impl.scene_arrays` (spheres,
triangle soup); they become one Mitsuba scene — each sphere a ``sphere``
shape, all triangles one ``mesh`` built from the soup — so Mitsuba's own
acceleration structure (Embree in the LLVM variants, or its kd-tree) is built
over exactly the same geometry.  Rays are passed as one wide ``Ray3f`` and
intersected with ``scene.ray_intersect_preliminary`` (closest hit: t, shape,
primitive, uv — what the own ``hit`` returns) or ``scene.ray_intersect``
(plus the surface interaction); ``dr.sync_thread()`` ends each timing, since
Dr.Jit evaluates lazily.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["mitsuba_scene", "mitsuba_trace", "time_mitsuba"]


def mitsuba_scene(mi, sph_center, sph_radius, tri_v):
    """A Mitsuba scene holding the spheres and the triangle soup."""
    desc = {"type": "scene"}
    for i, (c, r) in enumerate(zip(np.asarray(sph_center, float), np.asarray(sph_radius, float))):
        desc[f"s{i}"] = {"type": "sphere", "center": [float(x) for x in c], "radius": float(r)}
    tri_v = np.asarray(tri_v, dtype=np.float64).reshape(-1, 3, 3)
    if len(tri_v):
        mesh = mi.Mesh("soup", vertex_count=3 * len(tri_v), face_count=len(tri_v),
                       has_vertex_normals=False, has_vertex_texcoords=False)
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(tri_v.reshape(-1).astype(np.float32))
        params["faces"] = mi.UInt32(np.arange(3 * len(tri_v), dtype=np.uint32))
        params.update()
        desc["soup"] = mesh
    return mi.load_dict(desc)


def _rays(mi, o, d):
    o = np.asarray(o, dtype=np.float32)
    d = np.asarray(d, dtype=np.float32)
    return mi.Ray3f(o=mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), d=mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))


def mitsuba_trace(mi, scene, o, d, *, full=False):
    """Closest-hit distance per ray (inf on a miss), evaluated."""
    import drjit as dr

    ray = _rays(mi, o, d)
    si = scene.ray_intersect(ray) if full else scene.ray_intersect_preliminary(ray)
    t = si.t
    dr.eval(t)
    dr.sync_thread()
    return np.asarray(t, dtype=np.float64)


def time_mitsuba(mi, scene, o, d, *, rounds=5, full=False):
    """``(median seconds, t)`` of :func:`mitsuba_trace` over ``rounds`` after one
    warm-up call (kernel compilation); the rays are uploaded before the clock starts."""
    import drjit as dr

    ray = _rays(mi, o, d)
    dr.eval(ray)
    dr.sync_thread()

    def once():
        si = scene.ray_intersect(ray) if full else scene.ray_intersect_preliminary(ray)
        dr.eval(si.t)
        dr.sync_thread()
        return si.t

    once()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        t = once()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), np.asarray(t, dtype=np.float64)
