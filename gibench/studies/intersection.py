"""Hard-case stability studies of the intersection kernels (thesis 2.3.3–2.3.4).

Each study sweeps the parameters of one numerically hard situation, runs the
own kernels of :mod:`impl.intersect` and :mod:`impl.offset` in float32 and
float64, and scores them against the analytic answer.  A study returns its
table as a list of flat dicts of scalars (every parameter and every measured
number in each row), ready for a JSON store or an HTML table.

=====================  ======================================================
study                  what it measures
=====================  ======================================================
``distant_sphere``     wrong pixels of a unit sphere's silhouette seen from
                       distance d (1e2 … 1e12) by a narrow-field camera, per
                       ray–sphere form × precision × d
``self_intersection``  shadow acne and light leaking per self-intersection
                       strategy × ε × precision × distance of the scene from
                       the world origin
``grazing_sphere``     NaNs and hit/miss errors of rays tangent to a sphere
``grazing_plane``      NaNs and t errors of rays nearly parallel to a plane,
                       a polygon and a triangle
``sphere_form_cost``   time per ray of each ray–sphere form × precision on
                       one batch of rays (thesis 2.3.3: the algebraic
                       solution costs more than the geometric one), the
                       forms timed in alternation, with each form's hits
                       checked against the float64 closed form
=====================  ======================================================

The Mitsuba 3 side of the distant sphere is :func:`mitsuba_distant_sphere`;
:func:`run_studies` calls it (lazily, only when asked) so that this module
knows nothing about Mitsuba.  Parameters come from ``suites/hard/studies.toml``.

Conventions: the unit roundoff of a format is u = ε/2 (2⁻²⁴ for float32,
2⁻⁵³ for float64).  "Exact" answers are computed in float64 from the float64
description of the case (in scene-local coordinates where the scene is moved
far from the origin), so they are exact to ~1e-16 relative for the float64
inputs; each study states the band of ambiguous cases it leaves out and why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from impl.intersect import (SPHERE_FORMS, like, polygon_plane, ray_plane, ray_polygon,
                            ray_sphere_batch, ray_sphere_stable, ray_triangle)
from impl.offset import STRATEGIES, spawn

from core.errors import SuiteError
from core.provenance import REPO_ROOT
from core.transforms import look_at, rotate

from . import StudyInfo, as_config, read_config, run_registered, table_titles

__all__ = ["StudyInfo", "STUDIES", "TABLES", "PRECISIONS", "DEFAULT_CONFIG", "load_config", "run_studies",
           "unit_roundoff", "distant_sphere", "self_intersection", "grazing_sphere", "grazing_plane",
           "sphere_form_cost", "sphere_hits_agree"]

PRECISIONS = ("float32", "float64")
DEFAULT_CONFIG = REPO_ROOT / "suites" / "hard" / "studies.toml"

#: Aim directions of the distant-sphere camera.  'axis': the sphere lies on
#: the +z axis, so camera, sphere and the lateral ray components are exact in
#: both formats; 'oblique': a generic direction, whose coordinates are rounded.
AIMS = {"axis": (0.0, 0.0, 1.0), "oblique": (0.48, 0.6, 0.64)}


def unit_roundoff(precision) -> float:
    """u = ε/2 of ``precision`` ('float32' or 'float64')."""
    return float(np.finfo(np.dtype(precision)).eps) / 2.0


def _dtype(precision):
    if precision not in PRECISIONS:
        raise SuiteError(f"unknown precision {precision!r} (valid: {', '.join(PRECISIONS)})")
    return np.dtype(precision).type


# ============================================================ distant sphere ===

def _silhouette_rays(distance, radius, size, fill, aim):
    """Pixel-centre rays of a camera at the origin aimed at a sphere at ``distance``.

    The field of view is chosen so that the silhouette (angular radius
    asin(r/d)) spans ``fill`` of the half-width.  Returns the world-space unit
    directions (N, 3), the sphere centre, the signed relative distance of each
    pixel ray from the silhouette, p/r − 1 (p: distance from the centre to the
    ray's line; negative inside), and the exact t of the first hit (nan on a miss).
    """
    w = np.asarray(AIMS[aim], dtype=np.float64)
    w /= np.linalg.norm(w)
    center = w * distance
    cam = look_at([0.0, 0.0, 0.0], center, [0.0, 1.0, 0.0])
    tan_alpha = radius / math.sqrt((distance - radius) * (distance + radius))
    tx = tan_alpha / fill
    u = (np.arange(size) + 0.5) / size
    x = np.broadcast_to(((1.0 - 2.0 * u) * tx)[None, :], (size, size))
    y = np.broadcast_to(((1.0 - 2.0 * u) * tx)[:, None], (size, size))
    # Camera-space ray (x, y, 1): tan θ = ρ = hypot(x, y) off the axis; p = d sin θ.
    rho = np.hypot(x, y).ravel()
    sin_t = rho / np.sqrt(1.0 + rho * rho)
    cos_t = 1.0 / np.sqrt(1.0 + rho * rho)
    p = distance * sin_t
    rel_edge = p / radius - 1.0
    # t = d cos θ − √(r² − p²), with (r − p)(r + p) for accuracy near the edge.
    chord2 = (radius - p) * (radius + p)
    t_exact = np.where(chord2 >= 0.0, distance * cos_t - np.sqrt(np.maximum(chord2, 0.0)), np.nan)
    d_cam = np.stack([x.ravel() * cos_t, y.ravel() * cos_t, cos_t], axis=-1)
    dirs = d_cam @ cam[:3, :3].T
    return dirs, center, rel_edge, t_exact


def distant_sphere(*, distances, size=64, fill=0.75, radius=1.0, aims=("axis", "oblique"),
                   forms=SPHERE_FORMS, precisions=PRECISIONS, band=2.0) -> list[dict]:
    """Silhouette of a sphere of ``radius`` at each distance: wrong pixels per form × precision.

    Every input is rounded to the precision once (camera origin, sphere centre
    and radius, pixel-ray directions) and the chosen ray–sphere kernel runs in
    that precision.  A pixel is wrong when "hit" differs from the analytic
    answer for its float64 pixel-centre ray (angle to the axis < asin(r/d)).

    Band: at distance d the coordinates of that precision are spaced by
    ulp(d) ≈ 2u·d, so the sphere's outline cannot be placed more finely than
    that: rounding the unit direction moves the ray sideways by up to ~u·d at
    the sphere, and the stable form's products of size d round by as much.  A
    pixel whose centre ray passes within ``band``·u·d/r (relative; the default
    2 is one ulp of d) of the silhouette may legitimately come out either way,
    in any form; ``wrong_outside_band`` counts the wrong pixels beyond it.

    The 'axis' aim is a best case: the inputs are exact, and for d ≳ 10³ in
    float32 (10⁸ in float64) the direction's z component rounds to exactly 1,
    so the stable form's perpendicular vector is exact.  The 'oblique' aim
    shows the generic behaviour.
    """
    rows = []
    for aim in aims:
        for d in distances:
            dirs, center, rel_edge, t_exact = _silhouette_rays(float(d), radius, size, fill, aim)
            inside = rel_edge < 0.0
            for prec in precisions:
                _dtype(prec)
                u = unit_roundoff(prec)
                beta = band * u * d / radius
                for form in forms:
                    t = ray_sphere_batch(np.zeros(3), dirs, center, radius, form=form, dtype=prec)
                    t64 = t.astype(np.float64)
                    nan = ~np.isfinite(t64)
                    hit = t64 >= 0.0
                    wrong = hit != inside
                    both = hit & inside
                    terr = np.abs(t64[both] - t_exact[both]) / t_exact[both]
                    rows.append({
                        "aim": aim, "distance": float(d), "precision": prec, "form": form,
                        "pixels": int(inside.size), "expected_hits": int(inside.sum()),
                        "hits": int(hit.sum()), "wrong": int(wrong.sum()),
                        "wrong_frac": float(wrong.mean()),
                        "band": float(beta),
                        "wrong_outside_band": int((wrong & (np.abs(rel_edge) > beta)).sum()),
                        "max_rel_edge_of_wrong": float(np.abs(rel_edge[wrong]).max()) if wrong.any() else 0.0,
                        "t_rel_err_max": float(terr.max()) if terr.size else float("nan"),
                        "nan": int(nan.sum()),
                    })
    return rows


# ========================================================= self-intersection ===

# Primitive kinds of the small scene of the self-intersection study.
_SPHERE, _RECT = 0, 1


@njit(cache=True)
def _shade_kernel(cam, dirs, sph_c, sph_r, rect_v, rect_pl, light, strategy, eps,
                  prim_out, p_out, o_out, cos_out, blocker_out):
    """Primary hit, then one shadow ray spawned by ``strategy``, all in the arrays' precision.

    Primitives: spheres 0..ns-1, then rectangles (4-vertex polygons).  Outputs
    per ray: primitive (-1: none), hit point, shadow-ray origin, n·l (normal
    facing the viewer), and the primitive the shadow ray meets first (-1: lit,
    -2: facing away from the light, no shadow ray).
    """
    ns = sph_r.shape[0]
    nr = rect_v.shape[0]
    ox, oy, oz = cam[0], cam[1], cam[2]
    zero = like(cam, 0.0)
    inf = like(cam, np.inf)
    for k in range(dirs.shape[0]):
        dx, dy, dz = dirs[k, 0], dirs[k, 1], dirs[k, 2]
        best, prim = inf, -1
        for i in range(ns):
            t = ray_sphere_stable(ox, oy, oz, dx, dy, dz, sph_c[i, 0], sph_c[i, 1], sph_c[i, 2],
                                  sph_r[i], zero, best)
            if t >= zero:
                best, prim = t, i
        for j in range(nr):
            t = ray_polygon(ox, oy, oz, dx, dy, dz, rect_v[j], rect_pl[j], zero, best)
            if t >= zero:
                best, prim = t, ns + j
        prim_out[k] = prim
        if prim < 0:
            continue
        # Hit point and geometric normal, as a renderer computes them (thesis 2.3.1).
        px, py, pz = ox + best * dx, oy + best * dy, oz + best * dz
        if prim < ns:
            inv_r = like(cam, 1.0) / sph_r[prim]
            nx = (px - sph_c[prim, 0]) * inv_r
            ny = (py - sph_c[prim, 1]) * inv_r
            nz = (pz - sph_c[prim, 2]) * inv_r
        else:
            nx, ny, nz = rect_pl[prim - ns, 0], rect_pl[prim - ns, 1], rect_pl[prim - ns, 2]
        if nx * dx + ny * dy + nz * dz > zero:         # face the viewer
            nx, ny, nz = -nx, -ny, -nz
        lx, ly, lz = light[0] - px, light[1] - py, light[2] - pz
        dist = math.sqrt(lx * lx + ly * ly + lz * lz)
        lx, ly, lz = lx / dist, ly / dist, lz / dist
        cos = nx * lx + ny * ly + nz * lz
        p_out[k, 0], p_out[k, 1], p_out[k, 2] = px, py, pz
        cos_out[k] = cos
        if cos <= zero:
            blocker_out[k] = -2
            continue
        # Shadow ray towards the light, leaving on the lit side (n·l > 0).
        sx, sy, sz, tmin = spawn(strategy, px, py, pz, nx, ny, nz, eps)
        o_out[k, 0], o_out[k, 1], o_out[k, 2] = sx, sy, sz
        tb, blk = dist, -1
        for i in range(ns):
            t = ray_sphere_stable(sx, sy, sz, lx, ly, lz, sph_c[i, 0], sph_c[i, 1], sph_c[i, 2],
                                  sph_r[i], tmin, tb)
            if t >= zero:
                tb, blk = t, i
        for j in range(nr):
            t = ray_polygon(sx, sy, sz, lx, ly, lz, rect_v[j], rect_pl[j], tmin, tb)
            if t >= zero:
                tb, blk = t, ns + j
        blocker_out[k] = blk


@dataclass(frozen=True)
class _AcneScene:
    """Scene-local description: spheres, axis-aligned horizontal rectangles, a point light."""

    cam_origin: np.ndarray
    cam_target: np.ndarray
    fov: float
    spheres: np.ndarray          # (ns, 4): cx, cy, cz, r
    rects: np.ndarray            # (nr, 5): x0, x1, y0, y1, z
    light: np.ndarray

    @classmethod
    def from_config(cls, c: dict) -> "_AcneScene":
        return cls(np.array(c["camera_origin"], float), np.array(c["camera_target"], float),
                   float(c["fov"]), np.atleast_2d(np.array(c["spheres"], float)),
                   np.atleast_2d(np.array(c["rects"], float)), np.array(c["light"], float))

    @property
    def extent(self) -> float:
        """Largest local coordinate of the camera, light and geometry (the scene scale R)."""
        pts = [self.cam_origin, self.light, np.abs(self.spheres[:, :3]).max(0) + self.spheres[:, 3:].max()]
        pts.append(np.abs(self.rects[:, :4]).max() * np.ones(3))
        return float(np.max(np.abs(np.concatenate(pts))))

    def rect_vertices(self) -> np.ndarray:
        v = np.empty((len(self.rects), 4, 3))
        for j, (x0, x1, y0, y1, z) in enumerate(self.rects):
            v[j] = [[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]]
        return v


def _acne_rays(scene: _AcneScene, size: int):
    cam = look_at(scene.cam_origin, scene.cam_target, [0.0, 0.0, 1.0])
    tx = math.tan(math.radians(scene.fov) / 2.0)
    u = (np.arange(size) + 0.5) / size
    x = np.broadcast_to(((1.0 - 2.0 * u) * tx)[None, :], (size, size)).ravel()
    y = np.broadcast_to(((1.0 - 2.0 * u) * tx)[:, None], (size, size)).ravel()
    d = np.stack([x, y, np.ones_like(x)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d @ cam[:3, :3].T


def _sphere_line(o, d, c, r):
    """Exact (float64, local) first t ≥ 0 of rays o + t d with a sphere (nan: none),
    and the distance from the centre to each ray's line."""
    f = o - c
    b = -np.einsum("...i,...i->...", f, d)
    perp = f + b[..., None] * d
    dist = np.linalg.norm(perp, axis=-1)
    chord = np.sqrt(np.maximum((r - dist) * (r + dist), 0.0))
    t0, t1 = b - chord, b + chord
    t = np.where(t0 > 0.0, t0, np.where(t1 > 0.0, t1, np.nan))
    return np.where(dist <= r, t, np.nan), dist


def _rect_line(o, d, rect):
    """t where rays cross a rectangle's plane (nan if parallel or behind), and the
    crossing point's distance to the rectangle's border lines (negative: outside)."""
    x0, x1, y0, y1, z = rect
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z - o[..., 2]) / d[..., 2]
    t = np.where(np.isfinite(t) & (t > 0.0), t, np.nan)
    qx = o[..., 0] + t * d[..., 0]
    qy = o[..., 1] + t * d[..., 1]
    margin = np.minimum(np.minimum(qx - x0, x1 - qx), np.minimum(qy - y0, y1 - qy))
    return t, margin


def _exact_shading(scene: _AcneScene, dirs: np.ndarray, delta: float):
    """Analytic primary hit and lit/shadowed state of each pixel (float64, local).

    Returns ``(prim, p, lit, ambiguous, delta_px, shadow_margin, shadow_t)``.
    ``delta_px`` is the perturbation allowed for each pixel: ``delta`` for the
    inputs, amplified by 1/|cos| of the primary ray's incidence for the hit
    point (an error in t moves the hit point along the ray, which slides it
    along a surface seen at grazing angle by that much more).  A pixel is
    *ambiguous* when a perturbation by ``delta_px`` could change the answer:
    its primary ray passes within 4δ of a silhouette or rectangle border,
    |n·l| ≤ 8δ (terminator: the normal and the light direction each move by
    about δ), or its shadow segment passes within 4δ of an occluder's outline.
    ``shadow_margin`` is that last distance (inf where no occluder is near) and
    ``shadow_t`` the distance along the shadow segment where it is reached:
    moving the shadow ray's origin by Δ moves the segment at the occluder by
    at most |Δ|.
    """
    n = dirs.shape[0]
    o = np.broadcast_to(scene.cam_origin, dirs.shape)
    ns = len(scene.spheres)
    t_all, margins = [], []
    for s in scene.spheres:
        t, dist = _sphere_line(o, dirs, s[:3], s[3])
        t_all.append(t)
        margins.append(np.abs(dist - s[3]))
    for rect in scene.rects:
        t, m = _rect_line(o, dirs, rect)
        margins.append(np.where(np.isnan(t), np.inf, np.abs(m)))
        t_all.append(np.where(m >= 0.0, t, np.nan))
    T = np.stack(t_all)                                      # (nprim, n)
    prim = np.where(np.all(np.isnan(T), axis=0), -1, np.argmin(np.where(np.isnan(T), np.inf, T), axis=0))
    t = np.where(prim >= 0, T[np.maximum(prim, 0), np.arange(n)], np.nan)
    prim_margin = np.stack(margins).min(axis=0)
    p = scene.cam_origin + t[:, None] * dirs
    # Normals facing the viewer.
    nrm = np.zeros_like(p)
    for i, s in enumerate(scene.spheres):
        sel = prim == i
        nrm[sel] = (p[sel] - s[:3]) / s[3]
    nrm[prim >= ns] = [0.0, 0.0, 1.0]
    cos_i = np.einsum("ij,ij->i", nrm, dirs)
    nrm[cos_i > 0.0] *= -1.0
    delta_px = delta * (1.0 + 1.0 / np.maximum(np.abs(cos_i), 1e-3))
    ambiguous = (prim_margin <= 4.0 * delta) | (prim < 0)
    to_l = scene.light - p
    dist_l = np.linalg.norm(to_l, axis=-1)
    ldir = to_l / dist_l[:, None]
    cos = np.einsum("ij,ij->i", nrm, ldir)
    ambiguous |= np.abs(cos) <= 8.0 * delta_px
    # Occlusion of the segment p → light by the *other* primitives, and its
    # distance from their outlines.
    occluded = np.zeros(n, dtype=bool)
    shadow_margin = np.full(n, np.inf)
    shadow_t = np.full(n, np.inf)

    def closer(sel, margin, tt):
        nonlocal shadow_margin, shadow_t
        sel = sel & (margin < shadow_margin)
        shadow_margin = np.where(sel, margin, shadow_margin)
        shadow_t = np.where(sel, tt, shadow_t)

    for i, s in enumerate(scene.spheres):
        other = prim != i
        ts, dist = _sphere_line(p, ldir, s[:3], s[3])
        occluded |= other & (ts < dist_l)
        t_ca = np.einsum("ij,ij->i", s[:3] - p, ldir)          # closest approach
        closer(other & (t_ca > 0.0) & (t_ca < dist_l), np.abs(dist - s[3]), t_ca)
    for j, rect in enumerate(scene.rects):
        other = prim != ns + j
        tr, m = _rect_line(p, ldir, rect)
        crossing = other & (tr < dist_l)
        occluded |= crossing & (m >= 0.0)
        closer(crossing, np.abs(m), tr)
    ambiguous |= shadow_margin <= 4.0 * delta_px
    lit = (prim >= 0) & (cos > 0.0) & ~occluded
    return prim, p, lit, ambiguous, delta_px, shadow_margin, shadow_t


def self_intersection(*, scene: dict, offsets, direction=(1.0, 1.0, 1.0), rotation=(1.0, 2.0, 3.0, 25.0),
                      size=64, precisions=PRECISIONS, strategies=None, band=4.0) -> list[dict]:
    """Shadow acne and light leaking per self-intersection strategy, ε, precision and offset.

    The scene (spheres and horizontal rectangles lit by a point light, in
    local coordinates) is rotated by ``rotation`` (axis x, y, z and an angle in
    degrees: no plane stays axis-aligned, whose coordinate a rounded hit point
    would snap onto exactly) and moved by ``offset`` along ``direction``;
    every world coordinate is rounded to the precision, and the primary hit,
    hit point, normal and the shadow ray spawned by
    :func:`impl.offset.spawn` are computed in it.  The answer for each pixel
    is computed in local float64.

    Counted over the *classified* pixels (the analytic answer is robust to a
    perturbation δ = ``band``·u·(offset + R) of every input and of the hit
    point, R the scene extent: the inputs are rounded by u·(offset + R) and the
    hit point o + t d carries a few such roundings; the row records the
    largest hit-point error measured, ``hit_err_max``, to show δ covers it):

    * ``acne``: analytically lit pixels whose shadow ray meets the very
      surface it leaves;
    * ``edge_shift``: pixels whose shadow segment passes within the origin
      offset |Δ| (+ 4δ) of an occluder's outline, at a distance beyond |Δ|,
      and that flip either way — moving the origin by Δ moves the shadow
      outline by up to |Δ|, a geometric effect of any origin offset, not a
      failure of the test;
    * ``leak``: the other analytically shadowed pixels (behind an occluder or
      facing away from the light) that come out lit: the shadow ray stepped
      over its occluder;
    * ``false_shadow``: the other analytically lit pixels shadowed by another
      primitive.

    ``strategies`` is a list of ``{"strategy": name, "eps": [values]}`` with
    names from :data:`impl.offset.STRATEGIES`.
    """
    sc = _AcneScene.from_config(scene)
    if strategies is None:
        strategies = [{"strategy": "robust", "eps": [0.0]}]
    w = np.asarray(direction, dtype=np.float64)
    w /= np.linalg.norm(w)
    R = rotate(rotation[:3], rotation[3])[:3, :3]
    dirs = _acne_rays(sc, size)
    dirs_world = dirs @ R.T
    verts_local = sc.rect_vertices()
    rows = []
    for offset in offsets:
        shift = w * float(offset)
        for prec in precisions:
            F = _dtype(prec)
            u = unit_roundoff(prec)
            delta = band * u * (float(offset) + sc.extent)
            prim_x, p_x, lit_x, amb, delta_px, sh_margin, sh_t = _exact_shading(sc, dirs, delta)
            classified = ~amb
            cam = (R @ sc.cam_origin + shift).astype(F)
            sph_c = (sc.spheres[:, :3] @ R.T + shift).astype(F)
            sph_r = sc.spheres[:, 3].astype(F)
            rect_v = (verts_local @ R.T + shift).astype(F)
            rect_pl = np.stack([polygon_plane(v) for v in rect_v])
            light = (R @ sc.light + shift).astype(F)
            d_f = dirs_world.astype(F)
            for spec in strategies:
                name = spec["strategy"]
                if name not in STRATEGIES:
                    raise SuiteError(f"self_intersection: unknown strategy {name!r} "
                                     f"(valid: {', '.join(STRATEGIES)})")
                for eps in spec.get("eps", [0.0]):
                    n = dirs.shape[0]
                    prim = np.empty(n, np.int64)
                    p = np.zeros((n, 3), F)
                    o = np.zeros((n, 3), F)
                    cos = np.zeros(n, F)
                    blk = np.full(n, -3, np.int64)
                    _shade_kernel(cam, d_f, sph_c, sph_r, rect_v, rect_pl, light,
                                  STRATEGIES.index(name), F(eps), prim, p, o, cos, blk)
                    same = prim == prim_x
                    lit = (blk == -1)
                    spawned = blk >= -1
                    err = np.linalg.norm((p.astype(np.float64) - shift) @ R - p_x, axis=-1)
                    off_len = np.linalg.norm(o.astype(np.float64) - p.astype(np.float64), axis=-1)
                    # Outline moved by the offset: near it, and the occluder
                    # farther along the ray than the origin moved.
                    near_edge = (sh_margin <= 4.0 * delta_px + off_len) & (sh_t > off_len)
                    c_lit = classified & same & lit_x
                    c_sh = classified & same & ~lit_x
                    acne = c_lit & (blk == prim)
                    shadowed_by_other = (blk >= 0) & (blk != prim)
                    edge = near_edge & ((c_lit & shadowed_by_other) | (c_sh & lit))
                    false_sh = c_lit & shadowed_by_other & ~near_edge
                    leak = c_sh & lit & ~near_edge
                    rows.append({
                        "offset": float(offset), "precision": prec, "strategy": name,
                        "eps": float(eps) if name != "robust" else 0.0,
                        "pixels": int(n), "classified": int(classified.sum()),
                        "lit": int(c_lit.sum()), "shadowed": int(c_sh.sum()),
                        "acne": int(acne.sum()), "acne_frac": _frac(acne.sum(), c_lit.sum()),
                        "leak": int(leak.sum()), "leak_frac": _frac(leak.sum(), c_sh.sum()),
                        "edge_shift": int(edge.sum()),
                        "false_shadow": int(false_sh.sum()),
                        "primary_mismatch": int((classified & ~same).sum()),
                        "delta": float(delta),
                        "hit_err_max": float(err[classified & same].max()) if (classified & same).any() else 0.0,
                        "hit_err_over_delta": float((err / delta_px)[classified & same].max())
                        if (classified & same).any() else 0.0,
                        "offset_len_median": float(np.median(off_len[spawned])) if spawned.any() else 0.0,
                        "nan": int((~np.isfinite(p[prim >= 0])).any(axis=-1).sum()),
                    })
    return rows


def _frac(a, b) -> float:
    """a / b, NaN when nothing could be counted (b = 0): an empty class is not a 0 % rate."""
    return float(a) / float(b) if b else float("nan")


# ======================================================== grazing: sphere ===

def grazing_sphere(*, distances=(4.0, 1e2, 1e4), etas=None, azimuths=16, radius=1.0,
                   center=(0.3, -0.2, 0.1), forms=SPHERE_FORMS, precisions=PRECISIONS,
                   tol_factor=8.0) -> list[dict]:
    """Rays passing at distance r(1 + η) from a sphere's centre, from a distance D.

    For each η (both signs, and 0 = exactly tangent) ``azimuths`` rays come
    from a point at distance D from the centre (direction (0.48, 0.6, 0.64)),
    tilted around it.  Expected: a hit for η < 0, a miss for η > 0, anything
    for η = 0; never a NaN.

    Tolerance (relative miss distance |η| within which an error is allowed),
    from each form's error: the algebraic and geometric discriminants subtract
    squares of size D², an absolute error ~u·D² against r², so
    τ = ``tol_factor``·u·(D/r)²; the stable form's perpendicular vector errs by
    ~u·D in length (and rounding the direction moves the ray by as much), so
    τ = ``tol_factor``·u·(1 + D/r).
    """
    if etas is None:
        etas = [10.0 ** -k for k in range(1, 16)]
    etas = sorted({float(e) for e in etas} | {-float(e) for e in etas} | {0.0})
    c = np.asarray(center, dtype=np.float64)
    w = np.array([0.48, 0.6, 0.64])
    w /= np.linalg.norm(w)
    e1 = np.cross(w, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    phi = 2.0 * np.pi * (np.arange(azimuths) + 0.5) / azimuths
    rows = []
    for D in distances:
        o = c + D * w
        eta_all, dirs = [], []
        for eta in etas:
            rho = radius * (1.0 + eta)
            s = rho / D                                  # sin of the angle off the centre
            lateral = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
            dirs.append(-w * math.sqrt(1.0 - s * s) + s * lateral)
            eta_all.append(np.full(azimuths, eta))
        dirs = np.concatenate(dirs)
        eta_all = np.concatenate(eta_all)
        for prec in precisions:
            u = unit_roundoff(prec)
            for form in forms:
                t = ray_sphere_batch(o, dirs, c, radius, form=form, dtype=prec).astype(np.float64)
                nan = ~np.isfinite(t)
                hit = t >= 0.0
                decided = eta_all != 0.0
                wrong = decided & (hit != (eta_all < 0.0))
                if form == "stable":
                    tol = tol_factor * u * (1.0 + D / radius)
                else:
                    tol = tol_factor * u * (1.0 + (D / radius) ** 2)
                rows.append({
                    "distance": float(D), "precision": prec, "form": form,
                    "rays": int(t.size), "nan": int(nan.sum()), "wrong": int(wrong.sum()),
                    "eta_wrong_max": float(np.abs(eta_all[wrong]).max()) if wrong.any() else 0.0,
                    "tolerance": float(tol),
                    "wrong_beyond_tolerance": int((wrong & (np.abs(eta_all) > tol)).sum()),
                    "tangent_hits": int((hit & (eta_all == 0.0)).sum()),
                })
    return rows


# ========================================================= grazing: plane ===

@njit(cache=True)
def _grazing_kernel(o, d, plane, poly, poly_plane, tri, out):
    zero = like(o, 0.0)
    inf = like(o, np.inf)
    for k in range(d.shape[0]):
        ox, oy, oz = o[k, 0], o[k, 1], o[k, 2]
        dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
        out[k, 0] = ray_plane(ox, oy, oz, dx, dy, dz, plane[0], plane[1], plane[2], plane[3], zero, inf)
        out[k, 1] = ray_polygon(ox, oy, oz, dx, dy, dz, poly[k], poly_plane[k], zero, inf)
        out[k, 2] = ray_triangle(ox, oy, oz, dx, dy, dz, tri[k], zero, inf)[0]


#: Plane normals of the grazing-plane study: 'aligned' (z = 0, n·d is one
#: rounded component) and 'tilted' (n·d a sum of products that cancels).
PLANE_NORMALS = {"aligned": (0.0, 0.0, 1.0), "tilted": (1.0, 2.0, 3.0)}


def grazing_plane(*, thetas=None, height=1.0, planes=("aligned", "tilted"), precisions=PRECISIONS,
                  tol_factor=8.0) -> list[dict]:
    """Rays from height h above a plane through the origin, descending at angle θ to it.

    Primitives: the plane itself (2.3.5), a square polygon (2.3.6) and a
    triangle (Möller–Trumbore) in it, sized to contain the hit (4 h / sin θ).
    Expected: a hit at t = h / sin θ for θ > 0; a miss for θ = 0 (parallel),
    and for a ray lying in the plane (h = 0, θ = 0: a 0/0 if unguarded, added
    to every sweep); never a NaN.

    Tolerance: rounding the unit direction to precision u changes n·d = −sin θ
    by up to about u (absolute) — exactly the component itself for the
    'aligned' plane, a cancelling sum of products for the 'tilted' one — and
    the vertices' rounding tilts the polygon by as much, so t is known to
    τ = ``tol_factor``·u / sin θ relative.  Möller–Trumbore computes t as a
    ratio of triple products of vectors of length L (the triangle's size): the
    numerator, of size L²h, carries an error ~u·L³, so for the triangle
    τ = ``tol_factor``·u·L/h, i.e. 4·``tol_factor``·u / sin θ with
    L = 4h / sin θ.  Where τ ≥ 1/2 a miss is allowed too.
    """
    if thetas is None:
        thetas = [1e-1, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 0.0]
    cases = [(float(th), float(height)) for th in thetas] + [(0.0, 0.0)]
    smallest = min([th for th, _ in cases if th > 0.0], default=1e-3)
    rows = []
    for kind in planes:
        n = np.asarray(PLANE_NORMALS[kind], dtype=np.float64)
        n /= np.linalg.norm(n)
        a = np.cross(n, [0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        o64 = np.array([h * n for th, h in cases])
        d64 = np.array([math.cos(th) * a - math.sin(th) * n for th, h in cases])
        ext = np.array([4.0 * max(h, 1.0) / math.sin(max(th, smallest)) for th, h in cases])
        poly64 = np.stack([np.stack([-L * a - L * b, L * a - L * b, L * a + L * b, -L * a + L * b])
                           for L in ext])
        tri64 = np.stack([np.stack([-L * a - L * b, L * a - L * b, L * b]) for L in ext])
        for prec in precisions:
            F = _dtype(prec)
            u = unit_roundoff(prec)
            o, d = o64.astype(F), d64.astype(F)
            poly, tri = poly64.astype(F), tri64.astype(F)
            planes_f = np.stack([polygon_plane(v) for v in poly])
            plane = np.array([*n, 0.0], dtype=F)
            out = np.zeros((len(cases), 3), dtype=F)
            _grazing_kernel(o, d, plane, poly, planes_f, tri, out)
            for k, (th, h) in enumerate(cases):
                expect_hit = th > 0.0 and h > 0.0
                t_exact = h / math.sin(th) if expect_hit else float("nan")
                for col, prim in enumerate(("plane", "polygon", "triangle")):
                    tol = float("inf")
                    if expect_hit:
                        tol = tol_factor * u / math.sin(th)
                        if prim == "triangle":
                            tol = tol_factor * u * ext[k] / h
                    t = float(out[k, col])
                    hit = t >= 0.0
                    rel = abs(t - t_exact) / t_exact if (hit and expect_hit) else float("nan")
                    if math.isnan(t):
                        ok = False
                    elif not expect_hit:
                        ok = not hit
                    elif hit:
                        ok = rel <= tol
                    else:
                        ok = tol >= 0.5
                    rows.append({
                        "plane": kind, "primitive": prim, "precision": prec, "theta": th, "height": h,
                        "t_exact": t_exact, "t": t, "rel_err": float(rel), "tolerance": float(tol),
                        "nan": int(math.isnan(t)), "expect_hit": bool(expect_hit), "hit": bool(hit),
                        "ok": bool(ok),
                    })
    return rows


# ============================================== Mitsuba's own silhouette ===

def mitsuba_distant_sphere(scene_path, *, distances, variants=("scalar_rgb", "llvm_ad_rgb"),
                           aims=("axis", "oblique"), far_clips=("default", "2d"), size=64,
                           fill=0.75, radius=1.0, band=2.0) -> list[dict]:
    """Wrong pixels of Mitsuba's render of the distant-sphere silhouette.

    Parameters
    ----------
    scene_path : path of ``distant_sphere.xml``
    distances : distances d of the sphere's centre from the camera
    variants : Mitsuba variants to render with (switched in turn)
    aims : keys of :data:`AIMS`
    far_clips : 'default' (the sensor's own 1e4, as a scene that does not set
        it gets) and/or '2d' (twice the distance: nothing is clipped)
    band : as in :func:`distant_sphere`: pixels within
        ``band``·u₃₂·d/r of the edge are ambiguous in float32
    """
    from references.probe import MITSUBA_DEFAULT_FAR_CLIP, render_in_variant

    scene_path = Path(scene_path)
    rows = []
    for variant in variants:
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
                        raise SuiteError(f"mitsuba_distant_sphere: far_clips entries are 'default' "
                                         f"or '2d', got {policy!r}")
                    img, info = render_in_variant(
                        scene_path, variant=variant,
                        defines={"cx": repr(float(center[0])), "cy": repr(float(center[1])),
                                 "cz": repr(float(center[2])), "radius": repr(float(radius)),
                                 "fov": repr(fov), "far_clip": repr(far), "size": str(size)})
                    depth = img[..., 0]
                    hit = (depth > 0.0).ravel()
                    wrong = hit != inside
                    rows.append({
                        "variant": variant, "aim": aim, "distance": d, "far_clip_policy": policy,
                        "far_clip": info["far_clip"],
                        "pixels": int(hit.size), "expected_hits": int(inside.sum()),
                        "hits": int(hit.sum()), "wrong": int(wrong.sum()),
                        "wrong_frac": float(wrong.mean()), "empty": bool(not hit.any()),
                        "band": float(beta),
                        "wrong_outside_band": int((wrong & (np.abs(rel_edge) > beta)).sum()),
                        "max_rel_edge_of_wrong": float(np.abs(rel_edge[wrong]).max()) if wrong.any() else 0.0,
                        "mitsuba": info["mitsuba"], "drjit": info["drjit"],
                    })
    return rows


# ======================================================== sphere form cost ===

def _cost_rays(n: int, seed: int):
    """n unit rays from points around (0, 0, −10) towards the [−1.5, 1.5]² window at z = 0
    (about a third of them meet the unit sphere at the origin)."""
    rng = np.random.default_rng(seed)
    o = np.array([0.0, 0.0, -10.0]) + rng.uniform(-0.5, 0.5, (n, 3))
    target = np.column_stack([rng.uniform(-1.5, 1.5, (n, 2)), np.zeros(n)])
    d = target - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def sphere_hits_agree(t: np.ndarray, o: np.ndarray, d: np.ndarray, radius: float = 1.0,
                      precision: str = "float64") -> bool:
    """Whether the hits ``t`` (−1 = miss) of the rays (o, d) with the sphere of ``radius``
    at the origin are the float64 closed form's: hit exactly where the line passes
    within the radius (rays within 1e-3 of tangency left out), t = b − sqrt(r² − p²)
    to 1e-4 (float32) or 1e-12 (float64) relative."""
    b = -np.einsum("ij,ij->i", o, d)
    perp = np.linalg.norm(o + b[:, None] * d, axis=1)
    clear = np.abs(perp - radius) > 1e-3
    if not np.array_equal((t >= 0)[clear], (perp < radius)[clear]):
        return False
    hit = clear & (perp < radius)
    exact = b[hit] - np.sqrt(radius * radius - perp[hit] ** 2)
    rtol = 1e-4 if precision == "float32" else 1e-12
    return bool(np.allclose(t[hit], exact, rtol=rtol, atol=0.0))


def sphere_form_cost(*, rays=1 << 16, repeats=31, forms=SPHERE_FORMS, precisions=PRECISIONS,
                     seed=20240917) -> list[dict]:
    """Time of :func:`impl.intersect.ray_sphere_batch` on ``rays`` rays against the unit
    sphere, per form × precision: one untimed warm-up each, then ``repeats`` rounds in
    which every form × precision is timed once in turn (so machine load drifts over all
    of them alike); median, min and max seconds, rays per second, the median relative
    to the algebraic form's in the same precision, and whether the hits are the closed
    form's (:func:`sphere_hits_agree`).  Wall-clock times of a shared machine: a
    measurement for the report, never a test's pass condition."""
    import time as _time

    o64, d64 = _cost_rays(int(rays), int(seed))
    cases = [(f, p) for p in precisions for f in forms]
    inputs = {p: (o64.astype(p), d64.astype(p)) for p in precisions}
    times = {c: [] for c in cases}
    agree = {}
    for f, p in cases:
        o, d = inputs[p]
        t = ray_sphere_batch(o, d, np.zeros(3, dtype=p), 1.0, form=f, dtype=p)
        agree[(f, p)] = sphere_hits_agree(np.asarray(t, np.float64), o64, d64, 1.0, p)
    for _ in range(int(repeats)):
        for f, p in cases:
            o, d = inputs[p]
            t0 = _time.perf_counter()
            ray_sphere_batch(o, d, np.zeros(3, dtype=p), 1.0, form=f, dtype=p)
            times[(f, p)].append(_time.perf_counter() - t0)
    med = {c: float(np.median(v)) for c, v in times.items()}
    rows = []
    for f, p in cases:
        base = med.get(("algebraic", p))
        rows.append({"form": f, "precision": p, "rays": int(rays), "repeats": int(repeats),
                     "median_s": med[(f, p)], "min_s": float(min(times[(f, p)])),
                     "max_s": float(max(times[(f, p)])), "mrays_per_s": rays / med[(f, p)] / 1e6,
                     "vs_algebraic": med[(f, p)] / base if base else float("nan"),
                     "hits_agree": agree[(f, p)]})
    return rows


# ================================================================ registry ===

STUDIES = {s.name: s for s in (
    StudyInfo("distant_sphere", "Distant sphere silhouette",
              "A unit sphere at distance d (1e2 … 1e12) through a narrow-field 64×64 camera aimed at it "
              "(along an axis: exact inputs; obliquely: rounded inputs): fraction of pixels whose hit/miss "
              "differs from the analytic silhouette (angle to the axis < asin(r/d)), per ray–sphere form "
              "(thesis 2.3.1 algebraic, 2.3.2 geometric, Haines et al. 2019 stable) and precision.  The "
              "algebraic and geometric discriminants cancel catastrophically (error ~u·d²), the stable one "
              "does not (~u·d); 'wrong_outside_band' leaves out pixels within one ulp of d of the edge.",
              distant_sphere),
    StudyInfo("self_intersection", "Self-intersection: shadow acne and light leaking",
              "A sphere and a thin card floating 0.25 and 0.3 above a ground square, lit by a point light, "
              "rotated and moved 1 … 1e6 from the world origin: fraction of analytically lit pixels whose "
              "shadow ray hits its own surface (acne) and of shadowed pixels that come out lit (leaking: "
              "the shadow ray stepped over its occluder; flips within the offset of a shadow outline are "
              "counted apart as edge_shift), per strategy (t_min ε, normal offset ε, relative offset, "
              "Wächter–Binder robust offset), ε and precision (thesis 2.3.4).  Pixels whose answer a "
              "rounding-size perturbation could change are left out ('classified' counts the rest).",
              self_intersection),
    StudyInfo("grazing_sphere", "Grazing rays: tangent to a sphere",
              "Rays passing at r(1 + η) from a sphere's centre, |η| = 1e-1 … 1e-15 and 0: NaNs, and "
              "hit/miss errors beyond each form's stated error tolerance.",
              grazing_sphere),
    StudyInfo("grazing_plane", "Grazing rays: nearly parallel to a plane",
              "Rays at angle θ = 1e-1 … 1e-12 and 0 to an axis-aligned and a tilted plane (the plane, a "
              "square polygon and a triangle in it), and a ray lying in the plane: NaNs, hit/miss and the "
              "relative error of t = h / sin θ against a tolerance ~u / sin θ.",
              grazing_plane),
    StudyInfo("sphere_form_cost", "Ray–sphere cost: algebraic vs geometric (thesis 2.3.3)",
              "Median wall-clock time of the batch ray–sphere kernel per form and precision on one batch "
              "of rays (about a third hit), the forms timed in alternation over the repeats; vs_algebraic "
              "is the median over the algebraic form's in the same precision, hits_agree whether the "
              "hits match the float64 closed form.  Shared-machine timings: a measurement, not a check.",
              sphere_form_cost),
)}


#: Title and description of every table :func:`run_studies` can return.
TABLES = table_titles(STUDIES)
TABLES["distant_sphere_mitsuba"] = (
    "Distant sphere silhouette in Mitsuba 3",
    "The distant-sphere camera and sphere rendered by Mitsuba 3 (scalar_rgb, llvm_ad_rgb; float32 scene "
    "description) from suites/hard/distant_sphere.xml, one ray per pixel centre (depth AOV): wrong pixels "
    "against the analytic silhouette, with the perspective sensor's default far_clip (1e4) and with "
    "far_clip = 2d.  With the default, everything beyond the far clip plane is empty.")


def load_config(path=None) -> dict:
    """The studies' parameters from a TOML file (default ``suites/hard/studies.toml``)."""
    return read_config(path, DEFAULT_CONFIG)


def run_studies(config=None, *, only=None, mitsuba: bool | None = None) -> dict[str, list[dict]]:
    """Run the studies of ``config`` (a dict from :func:`load_config`, a path, or None
    for the default file): ``{study name: rows}``.

    A study runs when the config has a table of its name (its keys are the
    keyword arguments of the study's function) without ``enabled = false``;
    ``only`` restricts to some names.  ``mitsuba`` (default: the config's
    ``[distant_sphere_mitsuba] enabled``) adds the ``distant_sphere_mitsuba``
    table from :func:`mitsuba_distant_sphere`.  Titles and
    descriptions of the tables are in :data:`TABLES`.
    """
    config = as_config(config, DEFAULT_CONFIG)
    out = run_registered(STUDIES, config, only=only)
    mi_cfg = dict(config.get("distant_sphere_mitsuba", {}))
    enabled = mi_cfg.pop("enabled", False)
    if mitsuba is not None:
        enabled = mitsuba
    if enabled and (only is None or "distant_sphere_mitsuba" in only):
        scene = mi_cfg.pop("scene", "distant_sphere.xml")
        base = Path(config.get("_path", DEFAULT_CONFIG)).parent
        out["distant_sphere_mitsuba"] = mitsuba_distant_sphere(base / scene, **mi_cfg)
    return out
