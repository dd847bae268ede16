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

:func:`time_mitsuba_build` times the construction of Mitsuba's acceleration
structure over a mesh already uploaded (:func:`mitsuba_mesh`): a scene of
that mesh alone loaded with ``mi.load_dict``.  In the LLVM variants the scene
constructor builds an Embree BVH (``rtcSetSceneBuildQuality`` HIGH, the
geometry buffers shared with the mesh, not copied) on the threads of
Dr.Jit's pool (one thread after ``dr.set_thread_count(1)``), and logs the build's own duration ("Embree ready. (took …)"), which
is returned too.  The wall time also holds the scene constructor's fixed
work, which a scene of a one-triangle mesh measures.
"""

from __future__ import annotations

import re
import time

import numpy as np

__all__ = ["mitsuba_mesh", "mitsuba_scene", "mitsuba_trace", "time_mitsuba", "time_mitsuba_build"]


def mitsuba_mesh(mi, tri_v):
    """A Mitsuba ``Mesh`` of the triangle soup ``tri_v`` (T, 3, 3) (three vertices a
    face, float32), its buffers evaluated."""
    import drjit as dr

    tri_v = np.asarray(tri_v, dtype=np.float64).reshape(-1, 3, 3)
    mesh = mi.Mesh("soup", vertex_count=3 * len(tri_v), face_count=len(tri_v),
                   has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(tri_v.reshape(-1).astype(np.float32))
    params["faces"] = mi.UInt32(np.arange(3 * len(tri_v), dtype=np.uint32))
    params.update()
    dr.eval()
    dr.sync_thread()
    return mesh


def mitsuba_scene(mi, sph_center, sph_radius, tri_v):
    """A Mitsuba scene holding the spheres and the triangle soup."""
    desc = {"type": "scene"}
    for i, (c, r) in enumerate(zip(np.asarray(sph_center, float), np.asarray(sph_radius, float))):
        desc[f"s{i}"] = {"type": "sphere", "center": [float(x) for x in c], "radius": float(r)}
    if len(tri_v):
        desc["soup"] = mitsuba_mesh(mi, tri_v)
    return mi.load_dict(desc)


_UNITS = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "m": 60.0, "h": 3600.0}


def _seconds(text):
    """Seconds of Mitsuba's ``util::time_string`` ("850ms", "1.62s", "2.1m"), or None."""
    m = re.search(r"took ([0-9.]+)\s*(us|ms|s|m|h)\b", text)
    return float(m.group(1)) * _UNITS[m.group(2)] if m else None


class _BuildLog:
    """Collects Mitsuba's "Embree ready. (took …)" line while it is installed."""

    def __init__(self, mi):
        self.mi, self.seconds = mi, []

    def __enter__(self):
        mi = self.mi
        log = self

        class Appender(mi.Appender):
            def append(self, level, text):
                if "ready" in text and "took" in text:
                    log.seconds.append(_seconds(text))

            def log_progress(self, *args):
                pass

        self.logger = mi.logger()
        self.level = self.logger.log_level()
        self.appender = Appender()
        self.logger.add_appender(self.appender)
        self.logger.set_log_level(mi.LogLevel.Info)
        return self

    def __exit__(self, *exc):
        self.logger.remove_appender(self.appender)
        self.logger.set_log_level(self.level)


def time_mitsuba_build(mi, mesh):
    """Build Mitsuba's acceleration structure over ``mesh`` once (a scene of that mesh
    alone, loaded with ``mi.load_dict``, then dropped): ``(wall s, process CPU s,
    Mitsuba's logged build s or None)``.  The clocks stop after ``dr.sync_thread()``."""
    import drjit as dr

    dr.sync_thread()
    with _BuildLog(mi) as log:
        c0, t0 = time.process_time(), time.perf_counter()
        scene = mi.load_dict({"type": "scene", "soup": mesh})
        dr.sync_thread()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    del scene
    dr.sync_thread()
    return wall, cpu, (log.seconds[-1] if log.seconds else None)


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
