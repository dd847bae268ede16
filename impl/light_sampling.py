"""Light sampling for next-event estimation in the path tracer (thesis 3.2.2).

Every light of the scene — delta lights (``point``, ``spot``,
``directional``) and area emitters (triangle meshes and spheres) — is one
entry of a list; next-event estimation picks one entry uniformly (as
Mitsuba's ``scene.sample_emitter_direction`` does) and samples a direction
towards it:

* triangle-mesh emitters: a point uniform by area (:func:`impl.lighting.sample_emitter`),
  pdf (solid angle) = d² / (A |cos θ_y|);
* sphere emitters seen from outside: a direction uniform in the cone of
  directions subtending the sphere (:func:`sample_sphere_cone`), pdf =
  1 / (2π (1 − cos α_max)), cos α_max = √(1 − r²/d²) — the solid-angle
  sampling of Mitsuba's ``sphere``; from inside, uniform by area;
* point and spot lights: the direction to the light, weight I·falloff / d²;
  projectors (:mod:`impl.projector`): weight π·scale·E(uv) / (z_l² (−n·d));
  directional: the reverse of its direction, weight E (irradiance).

The arrays here hold what :mod:`impl.scene_arrays` does not: sphere
emitters and the shape → emitter map the MIS weights need.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from core.scene import Scene

from .envmap import envmap_direction_pdf, envmap_draw
from .lighting import delta_filter, sample_emitter, spot_falloff
from .scene_arrays import LIGHT_DIRECTIONAL, LIGHT_SPOT, SceneArrays, flatten

__all__ = ["LightArrays", "flatten_with_lights", "sample_sphere_cone", "sphere_cone_pdf",
           "sample_light", "emitter_pdf", "sample_uniform_sphere"]

TWO_PI = 2.0 * math.pi


class LightArrays(NamedTuple):
    """Emitters for next-event estimation (numba takes it as one argument)."""

    shape_emit: np.ndarray      # (N, 3) area-emitter radiance of every shape (0 if none)
    shape_tri_em: np.ndarray    # (N,) index into em_area of a mesh emitter, or -1
    sph_em_prim: np.ndarray     # (Q,) sphere primitive of each sphere emitter
    shape_sph_em: np.ndarray    # (N,) index into sph_em_prim, or -1
    n_lights: int               # delta lights + mesh emitters + sphere emitters


def flatten_with_lights(scene: Scene) -> tuple[SceneArrays, LightArrays]:
    """:func:`impl.scene_arrays.flatten` plus the path tracer's emitter tables.

    Sphere emitters are handed to ``flatten`` without their emission (it
    samples triangle emitters only) and kept here.
    """
    stripped = [dataclasses.replace(s, emitter_radiance=None)
                if s.kind == "sphere" and s.is_emitter else s for s in scene.shapes]
    A = flatten(dataclasses.replace(scene, shapes=stripped))
    N = len(scene.shapes)
    shape_emit = np.zeros((N, 3))
    for i, s in enumerate(scene.shapes):
        if s.is_emitter:
            shape_emit[i] = s.emitter_radiance
    shape_tri_em = np.full(N, -1, dtype=np.int64)
    for e, sh in enumerate(A.em_shape):
        shape_tri_em[sh] = e
    spheres = [i for i, s in enumerate(scene.shapes) if s.kind == "sphere"]
    sph_em_prim, shape_sph_em = [], np.full(N, -1, dtype=np.int64)
    for prim, i in enumerate(spheres):            # spheres come first among primitives
        if scene.shapes[i].is_emitter:
            shape_sph_em[i] = len(sph_em_prim)
            sph_em_prim.append(prim)
    n = len(A.light_kind) + len(A.em_area) + len(sph_em_prim) + (1 if len(A.env_image) else 0)
    return A, LightArrays(shape_emit, shape_tri_em, np.asarray(sph_em_prim, dtype=np.int64),
                          shape_sph_em, int(n))


#: A point within this relative distance of a sphere counts as inside it: a path
#: vertex *on* a sphere emitter (the inside of a closed emitting sphere) must be
#: sampled by area, not by the cone, which degenerates there to the point itself.
SPHERE_SURFACE_RTOL = 1e-6


@njit(inline="always", cache=True)
def _outside(d2, r):
    return d2 > r * r * (1.0 + SPHERE_SURFACE_RTOL)


# ------------------------------------------------------------------- warps ---

@njit(inline="always", cache=True)
def sample_uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    return r * math.cos(phi), r * math.sin(phi), z


@njit(cache=True)
def sphere_cone_pdf(cx, cy, cz, r, px, py, pz):
    """Solid-angle pdf of :func:`sample_sphere_cone` from p (outside the sphere), else 0."""
    d2 = (cx - px) ** 2 + (cy - py) ** 2 + (cz - pz) ** 2
    if not _outside(d2, r):
        return 0.0
    sin2 = r * r / d2
    # 1 − cos α_max, written to avoid cancellation for small spheres.
    one_minus = sin2 / (1.0 + math.sqrt(max(0.0, 1.0 - sin2)))
    return 1.0 / (TWO_PI * one_minus)


@njit(cache=True)
def sample_sphere_cone(cx, cy, cz, r, px, py, pz, u1, u2):
    """A direction from p uniform in the cone subtending the sphere (c, r), and its point.

    Returns ``(wx, wy, wz, yx, yy, yz, pdf)``: unit direction, the sphere point
    it meets first, solid-angle pdf.  p must lie outside the sphere.
    """
    ax, ay, az = cx - px, cy - py, cz - pz
    d = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / d, ay / d, az / d
    sin2_max = (r / d) ** 2
    one_minus = sin2_max / (1.0 + math.sqrt(max(0.0, 1.0 - sin2_max)))
    # cos θ uniform in [cos α_max, 1].
    one_minus_cos = u1 * one_minus
    cos_t = 1.0 - one_minus_cos
    sin_t = math.sqrt(max(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = TWO_PI * u2
    # Basis about the axis (Duff et al. 2017).
    sign = 1.0 if az >= 0.0 else -1.0
    a = -1.0 / (sign + az)
    b = ax * ay * a
    sx, sy, sz = 1.0 + sign * ax * ax * a, sign * b, -sign * ax
    tx, ty, tz = b, sign + ay * ay * a, -ay
    cp, sp = math.cos(phi) * sin_t, math.sin(phi) * sin_t
    wx = cp * sx + sp * tx + cos_t * ax
    wy = cp * sy + sp * ty + cos_t * ay
    wz = cp * sz + sp * tz + cos_t * az
    # First hit along w: t = d cos θ − √(r² − d² sin² θ).
    disc = max(0.0, r * r - d * d * sin_t * sin_t)
    t = d * cos_t - math.sqrt(disc)
    return wx, wy, wz, px + t * wx, py + t * wy, pz + t * wz, 1.0 / (TWO_PI * one_minus)


# ------------------------------------------------------------- emitters ---

@njit(inline="always", cache=True)
def power_heuristic(a, b):
    """Veach's power heuristic weight a² / (a² + b²) of a sample of pdf a against a
    technique of pdf b (0 when both vanish, 1 for an infinite a, as Mitsuba); selects,
    no branch, so a loop over lanes calling it vectorises."""
    a2 = a * a
    s = a2 + b * b
    return a2 / s if (s > 0.0) & math.isfinite(s) else (1.0 if math.isinf(a) else 0.0)


@njit(inline="always", cache=True)
def light_index(L: LightArrays, u0):
    """The light :func:`sample_light` picks with ``u0``: delta lights, then mesh emitters,
    then sphere emitters and the envmap (uniformly, one entry each)."""
    n = L.n_lights
    return min(int(u0 * n), n - 1)


@njit(inline="always", cache=True)
def emitter_point(A: SceneArrays, e, u1, u2):
    """The point y that (u1, u2) pick on mesh emitter ``e`` (uniform by area,
    :func:`impl.lighting.sample_emitter`) and the unit normal of its front there."""
    yx, yy, yz, tri = sample_emitter(e, u1, u2, A.em_offset, A.em_tri, A.em_cdf, A.tri_v)
    nx, ny, nz = A.tri_ng[tri, 0], A.tri_ng[tri, 1], A.tri_ng[tri, 2]   # unit normal
    if A.shape_flip[A.em_shape[e]]:
        nx, ny, nz = -nx, -ny, -nz
    return yx, yy, yz, nx, ny, nz


@njit(inline="always", cache=True)
def emitter_sample(px, py, pz, yx, yy, yz, nx, ny, nz, area, n_lights, le_r, le_g, le_b):
    """The light sample from p of the point y on a mesh emitter of area ``area`` (front
    normal n, radiance L_e), one of ``n_lights`` lights: ``(wx, wy, wz, dist, w_r, w_g,
    w_b, pdf)``, the unit direction to y, its distance, L_e / pdf and the solid-angle pdf
    d² / (A cos θ_y) / n.  No light (zero weight and pdf) from the emitter's back or at
    y = p (there the direction is +z and the distance 0).  Written with selects, so a
    loop over lanes that calls it vectorises; no division by zero either way."""
    wx, wy, wz = yx - px, yy - py, yz - pz
    d2 = wx * wx + wy * wy + wz * wz
    d = math.sqrt(d2)
    at = d == 0.0
    dd = 1.0 if at else d
    wx, wy, wz = wx / dd, wy / dd, wz / dd
    cos_y = -(nx * wx + ny * wy + nz * wz)
    lit = (cos_y > 0.0) & (not at)              # area emitters radiate from their front only
    pdf = d2 / (area * (cos_y if lit else 1.0)) / n_lights
    pd = pdf if lit else 1.0
    return (0.0 if at else wx, 0.0 if at else wy, 1.0 if at else wz, d, le_r / pd if lit else 0.0,
            le_g / pd if lit else 0.0, le_b / pd if lit else 0.0, pdf if lit else 0.0)


@njit(inline="always", cache=True)
def sample_light(A: SceneArrays, L: LightArrays, px, py, pz, u0, u1, u2):
    """Next-event estimation: pick a light uniformly and sample a direction from p.

    Returns ``(wx, wy, wz, dist, y_x, y_y, y_z, w_r, w_g, w_b, pdf, delta, i)``:
    unit direction to the light, distance (inf for directional), the light
    point, the weight L_e / pdf (incl. the 1/n_lights selection; I/d² etc. for
    delta lights), the solid-angle pdf (incl. selection; 0 for delta lights)
    whether the light is a delta light, and the light entry ``i`` (delta
    lights, then mesh emitters, then sphere emitters).  A zero weight means no
    contribution (back of an emitter, outside a spot cone).
    """
    n = L.n_lights
    i = light_index(L, u0)
    nd = A.light_kind.shape[0]
    ne = A.em_area.shape[0]
    if i < nd:
        kind = A.light_kind[i]
        if kind == LIGHT_DIRECTIONAL:
            wx, wy, wz = -A.light_dir[i, 0], -A.light_dir[i, 1], -A.light_dir[i, 2]
            return (wx, wy, wz, np.inf, px + wx, py + wy, pz + wz, n * A.light_rad[i, 0],
                    n * A.light_rad[i, 1], n * A.light_rad[i, 2], 0.0, True, i)
        yx, yy, yz = A.light_pos[i, 0], A.light_pos[i, 1], A.light_pos[i, 2]
        wx, wy, wz = yx - px, yy - py, yz - pz
        d = math.sqrt(wx * wx + wy * wy + wz * wz)
        wx, wy, wz = wx / d, wy / d, wz / d
        fr = fg = fb = 1.0
        if kind == LIGHT_SPOT:
            fr = fg = fb = spot_falloff(-wx, -wy, -wz, A.light_local, i, A.light_cos_cutoff[i],
                                        A.light_cos_beam[i], A.light_cutoff[i], A.light_inv_tw[i])
        if fr > 0.0:                            # a projector's image, a spot's texture
            tr, tg, tb = delta_filter(A, i, kind, px, py, pz, wx, wy, wz)
            fr, fg, fb = fr * tr, fg * tg, fb * tb
        s = n / (d * d)
        return (wx, wy, wz, d, yx, yy, yz, s * fr * A.light_rad[i, 0], s * fg * A.light_rad[i, 1],
                s * fb * A.light_rad[i, 2], 0.0, True, i)
    if i < nd + ne:
        e = i - nd
        sh = A.em_shape[e]
        yx, yy, yz, nx, ny, nz = emitter_point(A, e, u1, u2)
        wx, wy, wz, d, er, eg, eb, pdf = emitter_sample(px, py, pz, yx, yy, yz, nx, ny, nz, A.em_area[e], n,
                                                        L.shape_emit[sh, 0], L.shape_emit[sh, 1],
                                                        L.shape_emit[sh, 2])
        return wx, wy, wz, d, yx, yy, yz, er, eg, eb, pdf, False, i
    q = i - nd - ne
    if q == L.sph_em_prim.shape[0]:             # the envmap (last entry): its luminance sampling
        wx, wy, wz, pdf, er, eg, eb = envmap_draw(A.env_image, A.env_frame, A.env_pdf, A.env_cdf,
                                                  u1, u2)
        if not pdf > 0.0:
            return wx, wy, wz, np.inf, px, py, pz, 0.0, 0.0, 0.0, 0.0, False, i
        pdf /= n
        return (wx, wy, wz, np.inf, px + wx, py + wy, pz + wz, er / pdf, eg / pdf, eb / pdf, pdf,
                False, i)
    prim = L.sph_em_prim[q]
    sh = A.prim_shape[prim]
    cx, cy, cz, r = A.sph_center[prim, 0], A.sph_center[prim, 1], A.sph_center[prim, 2], A.sph_radius[prim]
    flip = A.shape_flip[sh]
    if _outside((cx - px) ** 2 + (cy - py) ** 2 + (cz - pz) ** 2, r):
        wx, wy, wz, yx, yy, yz, pdf = sample_sphere_cone(cx, cy, cz, r, px, py, pz, u1, u2)
        d = math.sqrt((yx - px) ** 2 + (yy - py) ** 2 + (yz - pz) ** 2)
    else:                                       # inside: uniform by area
        sx, sy, sz = sample_uniform_sphere(u1, u2)
        yx, yy, yz = cx + r * sx, cy + r * sy, cz + r * sz
        wx, wy, wz = yx - px, yy - py, yz - pz
        d = math.sqrt(wx * wx + wy * wy + wz * wz)
        if d == 0.0:
            return 0.0, 0.0, 1.0, 0.0, yx, yy, yz, 0.0, 0.0, 0.0, 0.0, False, i
        wx, wy, wz = wx / d, wy / d, wz / d
        cos_y = abs(sx * wx + sy * wy + sz * wz)
        pdf = d * d / (4.0 * math.pi * r * r * cos_y) if cos_y > 0.0 else 0.0
    nx, ny, nz = (yx - cx) / r, (yy - cy) / r, (yz - cz) / r
    if flip:
        nx, ny, nz = -nx, -ny, -nz
    if -(nx * wx + ny * wy + nz * wz) <= 0.0 or pdf <= 0.0:
        return wx, wy, wz, d, yx, yy, yz, 0.0, 0.0, 0.0, 0.0, False, i
    pdf /= n
    return (wx, wy, wz, d, yx, yy, yz, L.shape_emit[sh, 0] / pdf, L.shape_emit[sh, 1] / pdf,
            L.shape_emit[sh, 2] / pdf, pdf, False, i)


@njit(inline="always", cache=True)
def emitter_pdf(A: SceneArrays, L: LightArrays, shape, px, py, pz, dist, cos_y):
    """Solid-angle pdf (incl. selection) with which :func:`sample_light` from p would
    produce the emitter point at distance ``dist`` on ``shape`` (|cos θ_y| there)."""
    n = L.n_lights
    e = L.shape_tri_em[shape]
    if e >= 0:
        if cos_y <= 0.0:
            return 0.0
        return dist * dist / (A.em_area[e] * cos_y) / n
    q = L.shape_sph_em[shape]
    if q >= 0:
        prim = L.sph_em_prim[q]
        cx, cy, cz, r = (A.sph_center[prim, 0], A.sph_center[prim, 1], A.sph_center[prim, 2],
                         A.sph_radius[prim])
        if _outside((cx - px) ** 2 + (cy - py) ** 2 + (cz - pz) ** 2, r):
            return sphere_cone_pdf(cx, cy, cz, r, px, py, pz) / n
        if cos_y <= 0.0:
            return 0.0
        return dist * dist / (4.0 * math.pi * r * r * cos_y) / n
    return 0.0


@njit(inline="always", cache=True)
def environment_pdf(A: SceneArrays, L: LightArrays, dx, dy, dz):
    """Solid-angle pdf (incl. selection) with which :func:`sample_light` draws the
    direction (dx, dy, dz) towards an envmap (0 without one)."""
    if A.env_image.shape[0] == 0:
        return 0.0
    return envmap_direction_pdf(A.env_image, A.env_frame, A.env_pdf, dx, dy, dz) / L.n_lights
