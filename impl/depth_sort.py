"""Depth sort (Newell, Newell & Sancha 1972) — registered as ``depthsort``.

Thesis 1.3.2 (a hybrid, object- and image-precision algorithm): polygons are
put in a priority list, farthest first, and painted in that order (the
painter's algorithm), each overwriting what is behind it.  Sorting by the
farthest z alone is not enough when z-extents overlap, so for the polygon P
at the head of the list and every Q whose z-extent overlaps P's, the tests
are run in the thesis's order — P can be painted before Q as soon as one
succeeds:

1. the x-extents (on the film) do not overlap;
2. the y-extents do not overlap;
3. P lies entirely behind Q's plane (on the side away from the eye);
4. Q lies entirely in front of P's plane (on the eye's side);
5. the projections do not overlap (separating axis test of two triangles).

If all fail, the swapped tests 3' (Q behind P's plane) and 4' (P in front
of Q's plane) are tried; when one succeeds Q is moved to the head of the list
and *marked*.  A cyclic overlap shows up as a marked Q that would have to be
moved again, and two interpenetrating polygons as failing swapped tests: in
both cases one polygon is split by the plane of the other (P by Q's plane if
it cuts P, else Q by P's plane; if neither plane cuts either polygon — a
cycle of three or more whose separating planes are none of the pair's —
Q is halved by a plane through the eye) and the pieces go back into the
sorted list (counter ``splits``).  Splitting is bounded by
:data:`MAX_SPLIT_FACTOR` × the polygon count; beyond it the head is painted
as it is (``unresolved``).

Plane tests are done in camera space (eye at the origin) with a tolerance of
:data:`EPS_REL` × (1 + the polygons' largest z), so vertices shared by
neighbouring polygons count as on the plane; extents and the separating axis
test on the film.  The painting itself is :func:`impl.raster.rasterize`
without a depth test, and the rest of the pipeline (geometry stage, shading,
AOVs, parameters except ``depth``) is that of :mod:`impl.zbuffer`.

Leaves out: the splitting of polygons whose z-extents do not overlap but whose
projections interleave through a third polygon is handled only through the
generic cycle rule; split pieces create T-junctions with their unsplit
neighbours (harmless in painting order, visible at most as single-pixel
coverage differences along split lines).

Counters: those of ``zbuffer`` (``depth_passed`` = fragments painted) plus
``comparisons`` (pairs tested), ``moves``, ``splits``, ``unresolved``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.algorithm import Algorithm, RenderResult
from core.scene import Scene

from .pipeline import ScreenTriangles, clip_polygon, project
from .raster import DEPTH_NONE, TRAVERSALS, rasterize
from .zbuffer import MODELS, PARAMS, render_polygons

__all__ = ["EPS_REL", "MAX_SPLIT_FACTOR", "depth_sort_order", "depthsort_visibility", "render", "ALGORITHM"]

EPS_REL = 1e-9
MAX_SPLIT_FACTOR = 4


# ------------------------------------------------------------ polygon data ---

@njit(cache=True)
def _set_poly(i, cam, ext, plane, tx, ty, W, H):
    """Film extents (x, y), z-extent and camera-space plane of polygon i."""
    xmin = ymin = zmin = np.inf
    xmax = ymax = zmax = -np.inf
    for k in range(3):
        z = cam[i, k, 2]
        x = 0.5 * W * (1.0 - cam[i, k, 0] / (z * tx))
        y = 0.5 * H * (1.0 - cam[i, k, 1] / (z * ty))
        xmin, xmax = min(xmin, x), max(xmax, x)
        ymin, ymax = min(ymin, y), max(ymax, y)
        zmin, zmax = min(zmin, z), max(zmax, z)
    ext[i, 0], ext[i, 1], ext[i, 2], ext[i, 3], ext[i, 4], ext[i, 5] = xmin, xmax, ymin, ymax, zmin, zmax
    e1 = cam[i, 1] - cam[i, 0]
    e2 = cam[i, 2] - cam[i, 0]
    nx = e1[1] * e2[2] - e1[2] * e2[1]
    ny = e1[2] * e2[0] - e1[0] * e2[2]
    nz = e1[0] * e2[1] - e1[1] * e2[0]
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln == 0.0:
        ln = 1.0
    nx, ny, nz = nx / ln, ny / ln, nz / ln
    plane[i, 0], plane[i, 1], plane[i, 2] = nx, ny, nz
    plane[i, 3] = -(nx * cam[i, 0, 0] + ny * cam[i, 0, 1] + nz * cam[i, 0, 2])


@njit(cache=True)
def _side(plane, r, cam, s, eps):
    """Where polygon s lies relative to polygon r's plane, seen from the eye:
    +1 all on the eye's side (or on it), -1 all on the far side, 0 straddles, 2 r is edge-on."""
    de = plane[r, 3]                       # plane value at the eye (origin)
    if abs(de) <= eps:
        return 2
    sg = 1.0 if de > 0.0 else -1.0
    front = True
    back = True
    for k in range(3):
        d = sg * (plane[r, 0] * cam[s, k, 0] + plane[r, 1] * cam[s, k, 1] + plane[r, 2] * cam[s, k, 2] + plane[r, 3])
        if d < -eps:
            front = False
        if d > eps:
            back = False
    if back:                               # all vertices on the plane count as behind (either is fine)
        return -1
    if front:
        return 1
    return 0


@njit(cache=True)
def _sat_disjoint(cam, p, q, tx, ty, W, H, tol):
    """Test 5: the film projections of triangles p and q do not overlap (touching counts as disjoint)."""
    px = np.empty(3)
    py = np.empty(3)
    qx = np.empty(3)
    qy = np.empty(3)
    for k in range(3):
        px[k] = 0.5 * W * (1.0 - cam[p, k, 0] / (cam[p, k, 2] * tx))
        py[k] = 0.5 * H * (1.0 - cam[p, k, 1] / (cam[p, k, 2] * ty))
        qx[k] = 0.5 * W * (1.0 - cam[q, k, 0] / (cam[q, k, 2] * tx))
        qy[k] = 0.5 * H * (1.0 - cam[q, k, 1] / (cam[q, k, 2] * ty))
    for which in range(2):
        ax = px if which == 0 else qx
        ay = py if which == 0 else qy
        for k in range(3):
            j = (k + 1) % 3
            nx, ny = -(ay[j] - ay[k]), ax[j] - ax[k]
            if nx == 0.0 and ny == 0.0:
                continue
            lo1 = hi1 = px[0] * nx + py[0] * ny
            for m in range(1, 3):
                v = px[m] * nx + py[m] * ny
                lo1, hi1 = min(lo1, v), max(hi1, v)
            lo2 = hi2 = qx[0] * nx + qy[0] * ny
            for m in range(1, 3):
                v = qx[m] * nx + qy[m] * ny
                lo2, hi2 = min(lo2, v), max(hi2, v)
            t = tol * (abs(nx) + abs(ny))
            if hi1 <= lo2 + t or hi2 <= lo1 + t:
                return True
    return False


@njit(cache=True)
def _grow(a, n):
    shape = (max(2 * a.shape[0], n),) + a.shape[1:]
    b = np.empty(shape, a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True)
def _split(cam, bary, src, n, s, pl):
    """Cut polygon s by the plane ``pl`` (4,); append the fan triangles of both pieces from index n.
    Returns the number of triangles appended."""
    planes = np.empty((1, 4))
    added = 0
    for sign in (1.0, -1.0):
        for c in range(4):
            planes[0, c] = sign * pl[c]
        pos, bar, m = clip_polygon(cam[s].copy(), bary[s].copy(), 3, planes, 1)
        for k in range(m - 2):
            i = n + added
            for c in range(3):
                cam[i, 0, c] = pos[0, c]
                cam[i, 1, c] = pos[k + 1, c]
                cam[i, 2, c] = pos[k + 2, c]
                bary[i, 0, c] = bar[0, c]
                bary[i, 1, c] = bar[k + 1, c]
                bary[i, 2, c] = bar[k + 2, c]
            src[i] = src[s]
            added += 1
    return added


@njit(cache=True)
def _cuts(plane, r, cam, s, eps):
    """Polygon r's plane separates vertices of polygon s (strictly, beyond eps)."""
    pos = False
    neg = False
    for k in range(3):
        d = plane[r, 0] * cam[s, k, 0] + plane[r, 1] * cam[s, k, 1] + plane[r, 2] * cam[s, k, 2] + plane[r, 3]
        if d > eps:
            pos = True
        if d < -eps:
            neg = True
    return pos and neg


@njit(cache=True)
def _eye_bisector(cam, s):
    """Plane through the eye, the midpoint of s's longest edge and the opposite vertex."""
    best, bk = -1.0, 0
    for k in range(3):
        j = (k + 1) % 3
        d = 0.0
        for c in range(3):
            d += (cam[s, j, c] - cam[s, k, c]) ** 2
        if d > best:
            best, bk = d, k
    j, o = (bk + 1) % 3, (bk + 2) % 3
    m = 0.5 * (cam[s, bk] + cam[s, j])
    c = cam[s, o]
    nx, ny, nz = m[1] * c[2] - m[2] * c[1], m[2] * c[0] - m[0] * c[2], m[0] * c[1] - m[1] * c[0]
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    out = np.zeros(4)
    if ln > 0.0:
        out[0], out[1], out[2] = nx / ln, ny / ln, nz / ln
    return out


@njit(cache=True)
def _sorted_insert(lst, start, hi, ext, i):
    """Insert polygon i into lst[start:hi] (sorted by farthest z, descending); returns hi + 1."""
    a, b = start, hi
    key = ext[i, 5]
    while a < b:
        mid = (a + b) // 2
        if ext[lst[mid], 5] >= key:
            a = mid + 1
        else:
            b = mid
    for m in range(hi, a, -1):
        lst[m] = lst[m - 1]
    lst[a] = i
    return hi + 1


@njit(cache=True)
def _nns(cam0, bary0, src0, tx, ty, W, H, max_splits):
    """Newell–Newell–Sancha ordering; returns (cam, bary, src, paint order, counters[4])."""
    n0 = cam0.shape[0]
    cap = n0 + 16
    cam = np.empty((cap, 3, 3))
    bary = np.empty((cap, 3, 3))
    src = np.empty(cap, np.int64)
    cam[:n0] = cam0
    bary[:n0] = bary0
    src[:n0] = src0
    ext = np.empty((cap, 6))
    plane = np.empty((cap, 4))
    marked = np.zeros(cap, np.uint8)
    n = n0
    for i in range(n):
        _set_poly(i, cam, ext, plane, tx, ty, W, H)
    # The list: lst[lo] is P, lst[lo+1 : lo+1+nm] were moved (unsorted), the rest is sorted by farthest z.
    lst = np.argsort(-ext[:n, 5]).astype(np.int64)
    lst = _grow(lst, cap)
    lo, hi, nm = 0, n, 0
    order = np.empty(cap, np.int64)
    n_out = 0
    comparisons = moves = splits = unresolved = 0
    while lo < hi:
        p = lst[lo]
        action = 0            # 0 paint P, 1 move Q to head, 2 split
        qpos = -1
        for pos in range(lo + 1, hi):
            q = lst[pos]
            if pos >= lo + 1 + nm and ext[q, 5] <= ext[p, 4]:
                break          # sorted part: no further z-extent overlaps P's
            if ext[q, 5] <= ext[p, 4] or ext[p, 5] <= ext[q, 4]:
                continue       # z-extents disjoint (a moved polygon)
            comparisons += 1
            eps = EPS_REL * (1.0 + max(ext[p, 5], ext[q, 5]))
            # Tests 1-2: film extents; 3: P behind Q's plane; 4: Q in front of P's plane; 5: projections.
            if ext[p, 1] <= ext[q, 0] or ext[q, 1] <= ext[p, 0]:
                continue
            if ext[p, 3] <= ext[q, 2] or ext[q, 3] <= ext[p, 2]:
                continue
            sp = _side(plane, q, cam, p, eps)
            if sp == -1 or sp == 2:
                continue
            sq = _side(plane, p, cam, q, eps)
            if sq == 1 or sq == 2:
                continue
            if _sat_disjoint(cam, p, q, tx, ty, W, H, 1e-9 * (1.0 + W + H)):
                continue
            # Swapped tests 3' (Q behind P's plane) and 4' (P in front of Q's plane).
            if (sq == -1 or sp == 1) and not marked[q]:
                action, qpos = 1, pos
            else:
                action, qpos = 2, pos
            break
        if action == 0:
            order[n_out] = p
            n_out += 1
            lo += 1
            if nm > 0:
                nm -= 1
            continue
        q = lst[qpos]
        if action == 1:
            moves += 1
            for m in range(qpos, lo, -1):
                lst[m] = lst[m - 1]
            lst[lo] = q
            marked[q] = 1
            if qpos > lo + nm:         # Q came from the sorted part: P joins the moved part
                nm += 1
            continue
        # Split: P by Q's plane if it cuts P, else Q by P's plane, else halve Q through the eye.
        if splits >= max_splits:
            unresolved += 1
            order[n_out] = p
            n_out += 1
            lo += 1
            if nm > 0:
                nm -= 1
            continue
        eps = EPS_REL * (1.0 + max(ext[p, 5], ext[q, 5]))
        if _cuts(plane, q, cam, p, eps):
            victim, vpos, pl = p, lo, plane[q].copy()
        elif _cuts(plane, p, cam, q, eps):
            victim, vpos, pl = q, qpos, plane[p].copy()
        else:
            victim, vpos, pl = q, qpos, _eye_bisector(cam, q)
        if n + 6 > cam.shape[0]:
            newcap = 2 * cam.shape[0] + 6
            cam = _grow(cam, newcap)
            bary = _grow(bary, newcap)
            src = _grow(src, newcap)
            ext = _grow(ext, newcap)
            plane = _grow(plane, newcap)
            marked = _grow(marked, newcap)
            lst = _grow(lst, newcap)
            order = _grow(order, newcap)
        added = _split(cam, bary, src, n, victim, pl)
        if added <= 1:                 # the plane did not cut after all: paint P to make progress
            unresolved += 1
            order[n_out] = p
            n_out += 1
            lo += 1
            if nm > 0:
                nm -= 1
            continue
        splits += 1
        # Remove the victim from the list; the pieces go into the sorted part.
        head_from_sorted = vpos == lo and nm == 0
        if lo <= vpos <= lo + nm and nm > 0:
            nm -= 1                     # a moved polygon left (or the next head is one)
        for m in range(vpos, hi - 1):
            lst[m] = lst[m + 1]
        hi -= 1
        start = lo if head_from_sorted else lo + 1 + nm
        for k in range(added):
            i = n + k
            marked[i] = 0
            _set_poly(i, cam, ext, plane, tx, ty, W, H)
            hi = _sorted_insert(lst, start, hi, ext, i)
        n += added
    counters = np.array([comparisons, moves, splits, unresolved], np.int64)
    return cam[:n], bary[:n], src[:n], order[:n_out], counters


def depth_sort_order(scr: ScreenTriangles, camera, width: int, height: int) -> tuple[ScreenTriangles, np.ndarray, dict]:
    """Newell–Newell–Sancha: (triangles after splitting, painting order, counters)."""
    tx = camera.tan_half_fov_x
    ty = tx / camera.film.aspect
    max_splits = MAX_SPLIT_FACTOR * max(len(scr.src), 16)
    cam, bary, src, order, c = _nns(np.ascontiguousarray(scr.cam), np.ascontiguousarray(scr.bary),
                                    np.ascontiguousarray(scr.src), tx, ty, float(width), float(height),
                                    max_splits)
    xy = project(cam, camera, width, height)
    out = ScreenTriangles(cam=cam, xy=xy, src=src, bary=bary, counters=scr.counters)
    return out, order, {"comparisons": int(c[0]), "moves": int(c[1]), "splits": int(c[2]),
                        "unresolved": int(c[3])}


def depthsort_visibility(scr: ScreenTriangles, scene: Scene, width: int, height: int, params: dict):
    """Sort, then paint farthest first without a depth test: (visibility buffer, triangles, counters)."""
    cam = scene.camera
    scr2, order, counters = depth_sort_order(scr, cam, width, height)
    vis, rc = rasterize(scr2.xy, scr2.cam[:, :, 2], width, height, depth_mode=DEPTH_NONE,
                        near=cam.near_clip, far=cam.far_clip, order=order,
                        traversal=TRAVERSALS[params.get("traversal", "edge")])
    counters.update(rc)
    return vis, scr2, counters


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    return render_polygons(scene, params, seed=seed, algorithm="depthsort", visibility=depthsort_visibility)


ALGORITHM = Algorithm(
    name="depthsort",
    summary="Depth sort (Newell-Newell-Sancha) with flat/Gouraud/Phong shading (local illumination, no shadows)",
    section="thesis 1.1, 1.2.2, 1.2.3, 1.3.2, 1.5",
    transport="direct",
    params=PARAMS,
    render=render,
    models=MODELS,
)
