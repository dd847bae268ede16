"""The geometry stage of the polygon pipeline (thesis 1.1, 1.2.2, 1.2.3).

World-space triangles go through, in the thesis's order (1.1):

1. **model → world**: done by the loader (the scene model is in world space);
2. **world → view** (camera space): ``p_cam = Rᵀ (p_world − eye)`` with
   Mitsuba's camera frame — +z forward, +y up, +x *left* (:mod:`impl.camera`);
3. **bounding-volume rejection** (1.2.2): a shape whose bounding sphere lies
   wholly outside one plane of the view frustum is dropped with all its
   triangles (counter ``rejected_bv``);
4. **back-face culling** (1.2.3): a triangle whose normal (right-hand winding,
   ``flip_normals`` applied) makes an angle ≥ 90° with the direction to the
   eye is dropped (``culled``).  Valid for closed surfaces seen from outside;
   an open surface seen from behind disappears (ray casting would show it
   black), so ``cull`` is a parameter;
5. **extents / outcodes** (1.2.2): a triangle with all three vertices outside
   the same frustum plane is dropped (``rejected``);
6. **clipping** (Sutherland–Hodgman in camera space) against the near and far
   planes ``z = near_clip``, ``z = far_clip`` — exactly the ray range
   t ∈ [near/d_z, far/d_z] of Mitsuba's perspective sensor — and against a
   guard band G = :data:`GUARD` times the field of view on the sides (so
   screen coordinates stay bounded; edges the guard band adds lie outside the
   image).  Clipped polygons are fanned back into triangles (``clipped``
   counts input triangles that needed it);
7. **projection and viewport**: the perspective divide onto the film in pixel
   units, with Mitsuba's film convention (u right, v down)::

       x_px = W/2 · (1 − x / (z tan(fov_x/2))),  y_px = H/2 · (1 − y·aspect / (z tan(fov_x/2)))

   so the centre of pixel (i, j) at (i + ½, j + ½) is exactly the pixel-centre
   ray of :func:`impl.camera.eye_ray`.

Every output triangle keeps the index of its source triangle and the
barycentric coordinates of its vertices in it, so clipped (and, in depth
sort, split) pieces interpolate the source's attributes.

Leaves out: clipping against the exact side planes (the guard band makes it
unnecessary), user clip planes, non-rigid camera transforms (refused).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from core.scene import Camera
from core.errors import UnsupportedError

from .tessellate import TriangleSoup

__all__ = ["GUARD", "ScreenTriangles", "camera_frame", "to_camera", "frustum_planes", "clip_planes",
           "geometry_stage", "project", "bounding_volume_visible"]

#: Guard band: side clipping planes at GUARD × the field of view.
GUARD = 8.0

#: Status codes of the triangle classification.
_DRAW, _CULLED, _REJECTED, _CLIPPED = 0, 1, 2, 3


class ScreenTriangles(NamedTuple):
    """Triangles after the geometry stage (M of them)."""

    cam: np.ndarray     # (M, 3, 3) camera-space vertices (z > 0)
    xy: np.ndarray      # (M, 3, 2) film position in pixels (x right, y down)
    src: np.ndarray     # (M,) source triangle index in the TriangleSoup
    bary: np.ndarray    # (M, 3, 3) barycentrics of each vertex in the source triangle
    counters: dict


def camera_frame(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R, eye): camera axes as the columns of R (x left, y up, z forward) and the eye.

    Raises ``NotImplementedError`` for a sensor other than the pinhole
    ``perspective`` one, and for a camera transform with scale or shear
    (distances along eye rays would not be camera-space lengths).
    """
    if camera.kind != "perspective":
        raise UnsupportedError(
            f"pipeline: the rasterisers (zbuffer, depthsort) project through a pinhole; the scene's "
            f"'{camera.kind}' sensor is not modelled (render it with raycast, whitted or distributed)")
    m = np.asarray(camera.to_world, dtype=np.float64)
    R = m[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-9):
        raise UnsupportedError("pipeline.camera_frame: the sensor's to_world has scale or shear; "
                                  "the rasteriser needs a rigid camera transform")
    return np.ascontiguousarray(R), m[:3, 3].copy()


def to_camera(p_world: np.ndarray, camera: Camera) -> np.ndarray:
    """World → camera space: p_cam = Rᵀ (p_world − eye), any (..., 3)."""
    R, eye = camera_frame(camera)
    return (np.asarray(p_world, np.float64) - eye) @ R


def _tans(camera: Camera) -> tuple[float, float]:
    tx = camera.tan_half_fov_x
    return tx, tx / camera.film.aspect


def frustum_planes(camera: Camera) -> np.ndarray:
    """The six view-frustum planes in camera space, (6, 4): inside where a x + b y + c z + d ≥ 0, unit (a, b, c)."""
    tx, ty = _tans(camera)
    p = np.array([[0, 0, 1, -camera.near_clip], [0, 0, -1, camera.far_clip],
                  [-1, 0, tx, 0], [1, 0, tx, 0], [0, -1, ty, 0], [0, 1, ty, 0]], dtype=np.float64)
    p /= np.linalg.norm(p[:, :3], axis=1, keepdims=True)
    return p


def clip_planes(camera: Camera, guard: float = GUARD) -> np.ndarray:
    """Clipping planes: near, far and the guard band (sides at ``guard`` × the field of view)."""
    tx, ty = _tans(camera)
    p = np.array([[0, 0, 1, -camera.near_clip], [0, 0, -1, camera.far_clip],
                  [-1, 0, guard * tx, 0], [1, 0, guard * tx, 0],
                  [0, -1, guard * ty, 0], [0, 1, guard * ty, 0]], dtype=np.float64)
    p /= np.linalg.norm(p[:, :3], axis=1, keepdims=True)
    return p


def bounding_volume_visible(soup: TriangleSoup, camera: Camera, n_shapes: int) -> np.ndarray:
    """Per shape: False when its bounding sphere is wholly outside a frustum plane (thesis 1.2.2)."""
    planes = frustum_planes(camera)
    vis = np.zeros(n_shapes, dtype=np.int64)
    if soup.n_triangles == 0:
        return vis
    p_cam = to_camera(soup.pos, camera)
    vshape = np.full(len(soup.pos), -1, np.int64)
    vshape[soup.tri.ravel()] = np.repeat(soup.tri_shape, 3)
    for s in range(n_shapes):
        pts = p_cam[vshape == s]
        if len(pts) == 0:
            continue
        lo, hi = pts.min(0), pts.max(0)
        c = 0.5 * (lo + hi)
        r = np.sqrt(((pts - c) ** 2).sum(1).max())
        dist = planes[:, :3] @ c + planes[:, 3]
        vis[s] = int(np.all(dist >= -r * (1 + 1e-12)))
    return vis


# ------------------------------------------------------------ numba kernels ---

@njit(inline="always", cache=True)
def _pdist(pl, x, y, z):
    return pl[0] * x + pl[1] * y + pl[2] * z + pl[3]


@njit(cache=True)
def _less(a, b):
    """Lexicographic a < b of two 3-vectors (the canonical edge direction for clipping)."""
    for k in range(3):
        if a[k] != b[k]:
            return a[k] < b[k]
    return False


@njit(cache=True)
def clip_polygon(pos, bary, n, planes, mask):
    """Sutherland–Hodgman: clip the convex polygon (pos, bary)[:n] by every plane in
    ``planes`` whose bit is set in ``mask``; returns (pos, bary, n).

    The intersection of an edge with a plane is computed from its
    lexicographically smaller end, so an edge shared by two triangles is cut at
    bit-identical points whichever way each triangle runs along it.
    """
    cap = pos.shape[0]
    for k in range(planes.shape[0]):
        if not (mask >> k) & 1 or n == 0:
            continue
        pl = planes[k]
        out_p = np.empty((cap, 3))
        out_b = np.empty((cap, 3))
        m = 0
        for i in range(n):
            j = (i + 1) % n
            a, b = pos[i], pos[j]
            da = _pdist(pl, a[0], a[1], a[2])
            db = _pdist(pl, b[0], b[1], b[2])
            if da >= 0.0:
                out_p[m] = a
                out_b[m] = bary[i]
                m += 1
            if (da >= 0.0) != (db >= 0.0):
                if _less(a, b):
                    t = da / (da - db)
                    out_p[m] = a + t * (b - a)
                    out_b[m] = bary[i] + t * (bary[j] - bary[i])
                else:
                    t = db / (db - da)
                    out_p[m] = b + t * (a - b)
                    out_b[m] = bary[j] + t * (bary[i] - bary[j])
                m += 1
        pos, bary, n = out_p, out_b, m
    return pos, bary, n


@njit(cache=True)
def _classify(v, flip, cull, frustum, clip):
    """(status, clip mask) of one camera-space triangle ``v`` (3, 3)."""
    # Back-face culling (1.2.3): N · (v0 − eye) ≥ 0 means the face turns away (eye at the origin).
    if cull:
        e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
        e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        d = nx * v[0, 0] + ny * v[0, 1] + nz * v[0, 2]
        if flip:
            d = -d
        if d >= 0.0:
            return _CULLED, 0
    # Outcodes against the frustum (1.2.2): all vertices outside one plane → rejected.
    for k in range(frustum.shape[0]):
        if (_pdist(frustum[k], v[0, 0], v[0, 1], v[0, 2]) < 0.0
                and _pdist(frustum[k], v[1, 0], v[1, 1], v[1, 2]) < 0.0
                and _pdist(frustum[k], v[2, 0], v[2, 1], v[2, 2]) < 0.0):
            return _REJECTED, 0
    mask = 0
    for k in range(clip.shape[0]):
        for i in range(3):
            if _pdist(clip[k], v[i, 0], v[i, 1], v[i, 2]) < 0.0:
                mask |= 1 << k
                break
    if mask:
        return _CLIPPED, mask
    return _DRAW, 0


@njit(cache=True)
def _clip_triangle(v, mask, clip):
    pos = np.zeros((3 + clip.shape[0], 3))
    bary = np.zeros((3 + clip.shape[0], 3))
    for i in range(3):
        pos[i] = v[i]
        bary[i, i] = 1.0
    return clip_polygon(pos, bary, 3, clip, mask)


@njit(parallel=True, cache=True)
def _count_kernel(v_cam, tri_flip, tri_ok, cull, frustum, clip, status, n_out):
    for t in prange(v_cam.shape[0]):
        if not tri_ok[t]:
            status[t] = _REJECTED
            n_out[t] = 0
            continue
        st, mask = _classify(v_cam[t], tri_flip[t], cull, frustum, clip)
        status[t] = st
        if st == _DRAW:
            n_out[t] = 1
        elif st == _CLIPPED:
            _p, _b, n = _clip_triangle(v_cam[t], mask, clip)
            n_out[t] = max(n - 2, 0)
        else:
            n_out[t] = 0


@njit(parallel=True, cache=True)
def _emit_kernel(v_cam, tri_flip, cull, frustum, clip, status, offset, out_cam, out_bary, out_src):
    for t in prange(v_cam.shape[0]):
        st = status[t]
        o = offset[t]
        if st == _DRAW:
            for i in range(3):
                for c in range(3):
                    out_cam[o, i, c] = v_cam[t, i, c]
                    out_bary[o, i, c] = 1.0 if i == c else 0.0
            out_src[o] = t
        elif st == _CLIPPED:
            _st, mask = _classify(v_cam[t], tri_flip[t], cull, frustum, clip)
            p, b, n = _clip_triangle(v_cam[t], mask, clip)
            for k in range(n - 2):              # fan around vertex 0
                for c in range(3):
                    out_cam[o + k, 0, c] = p[0, c]
                    out_cam[o + k, 1, c] = p[k + 1, c]
                    out_cam[o + k, 2, c] = p[k + 2, c]
                    out_bary[o + k, 0, c] = b[0, c]
                    out_bary[o + k, 1, c] = b[k + 1, c]
                    out_bary[o + k, 2, c] = b[k + 2, c]
                out_src[o + k] = t


@njit(parallel=True, cache=True)
def _project_kernel(cam_v, tx, ty, W, H, out_xy):
    for t in prange(cam_v.shape[0]):
        for i in range(3):
            z = cam_v[t, i, 2]
            out_xy[t, i, 0] = 0.5 * W * (1.0 - cam_v[t, i, 0] / (z * tx))
            out_xy[t, i, 1] = 0.5 * H * (1.0 - cam_v[t, i, 1] / (z * ty))


def project(cam_v: np.ndarray, camera: Camera, width: int | None = None, height: int | None = None) -> np.ndarray:
    """Perspective divide and viewport: camera-space (M, 3, 3) → film pixels (M, 3, 2).

    ``width``/``height`` default to the film's (a supersampled film of the same
    aspect passes its own).
    """
    tx, ty = _tans(camera)
    W = camera.film.width if width is None else width
    H = camera.film.height if height is None else height
    out = np.empty(cam_v.shape[:2] + (2,))
    _project_kernel(np.ascontiguousarray(cam_v), tx, ty, float(W), float(H), out)
    return out


def geometry_stage(soup: TriangleSoup, camera: Camera, *, cull: bool, n_shapes: int,
                   width: int | None = None, height: int | None = None) -> ScreenTriangles:
    """Steps 2–7 above for every triangle of ``soup``; counters ``triangles_in``,
    ``rejected_bv``, ``culled``, ``rejected``, ``clipped``, ``triangles_out``."""
    R, eye = camera_frame(camera)
    v_cam = np.ascontiguousarray(((soup.pos - eye) @ R)[soup.tri])       # (T, 3, 3)
    shape_ok = bounding_volume_visible(soup, camera, n_shapes)
    tri_ok = shape_ok[soup.tri_shape] if soup.n_triangles else np.zeros(0, np.int64)
    T = soup.n_triangles
    status = np.empty(T, np.int64)
    n_out = np.empty(T, np.int64)
    frustum, clip = frustum_planes(camera), clip_planes(camera)
    _count_kernel(v_cam, soup.tri_flip, tri_ok, bool(cull), frustum, clip, status, n_out)
    offset = np.zeros(T + 1, np.int64)
    np.cumsum(n_out, out=offset[1:])
    M = int(offset[-1])
    out_cam = np.empty((M, 3, 3))
    out_bary = np.empty((M, 3, 3))
    out_src = np.empty(M, np.int64)
    _emit_kernel(v_cam, soup.tri_flip, bool(cull), frustum, clip, status, offset[:-1], out_cam, out_bary, out_src)
    counters = {
        "triangles_in": int(T),
        "rejected_bv": int(np.sum(tri_ok == 0)),
        "culled": int(np.sum(status == _CULLED)),
        "rejected": int(np.sum(status == _REJECTED) - np.sum(tri_ok == 0)),
        "clipped": int(np.sum(status == _CLIPPED)),
        "triangles_out": M,
    }
    xy = project(out_cam, camera, width, height)
    return ScreenTriangles(cam=out_cam, xy=xy, src=out_src, bary=out_bary, counters=counters)
