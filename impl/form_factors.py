"""Form factors F_ij between radiosity patches, three ways (thesis 3.4).

The form factor from patch i to patch j is the fraction of the power leaving
i (Lambertian) that arrives at j,

    F_ij = 1/A_i ∫_{A_i} ∫_{A_j} cosθ_i cosθ_j / (π r²) V(x, y) dA_j dA_i ,

with V the visibility.  Properties: reciprocity A_i F_ij = A_j F_ji, closure
Σ_j F_ij = 1 in a closed environment, F_ii = 0 for a planar patch.

=============  ===============================================================
method         how
=============  ===============================================================
``contour``    thesis 3.4.1 (hemisphere / Nusselt analog): the point-to-
               polygon form factor at quadrature points of patch i in closed
               form by Lambert's contour integral (polygon clipped to the
               hemisphere above the point),
               F(x → A_j) = 1/(2π) Σ_k β_k n·(r_k × r_{k+1}) / |r_k × r_{k+1}|,
               β_k the angle subtended by edge k; times the visibility
               estimated with ``vis_rays`` shadow rays to a stratified grid
               of points on j.  Exact for unoccluded pairs up to the
               quadrature over A_i (one point = patch centre, the thesis's
               approximation; ``points = k`` a k×k Gauss–Legendre rule,
               optionally ``graded`` towards the patch edges for the
               logarithmic singularity of patches sharing an edge).
``hemicube``   thesis 3.4.2 (Cohen & Greenberg 1985): a unit half-cube over
               each quadrature point, ``res × res`` cells on the top face and
               ``res × res/2`` on each side; a ray through each cell centre
               (an item buffer by ray casting) finds the visible patch, which
               receives the cell's delta form factor
               ΔF = ΔA / (π (x² + y² + 1)²) on the top face and
               ΔF = z ΔA / (π (y² + z² + 1)²) on a side face (z the height).
               The table is normalised to sum to 1 (its raw sum at ``res`` is
               :func:`hemicube_table`'s third value), so closure is exact in a
               closed scene and the error is the aliasing of small patches.
``hemicube-   thesis 3.4.2 as Cohen & Greenberg built it: every patch is
zbuffer``      *projected* onto the five faces of the hemicube with the
               z-buffer rasteriser (:func:`impl.raster.rasterize`: item buffer
               of patch ids, float32 window depth with near plane
               :data:`HEMICUBE_NEAR` × the scene's extent, top-left fill rule
               at cell centres), instead of one ray per cell.  Same cells
               and ΔF table as ``hemicube``, so the two differ only where a
               patch edge or a near-plane clip decides a cell differently.
               Triangles are clipped against the near plane first (a patch
               closer than it to the hemicube centre is cut, as in hardware
               hemicubes).
``point``      the thesis's point approximation (3.4.1, last formula): the
               integral over A_j replaced by its value at the centre of j,
               F_ij ≈ A_j cosθ_i cosθ_j / (π r²) · V (with the 1/π that
               normalises a cosine-weighted hemisphere; the thesis's formula
               omits it), at the quadrature points of i, times the visibility
               by the contour method's shadow rays.  Good when r ≫ √A_j,
               badly wrong for neighbouring patches (it can exceed 1; rows
               are not normalised): the ablation the thesis's approximation
               invites.
``montecarlo`` area-to-area by ray shooting (Malley's method): uniform points
               on A_i, cosine-distributed directions, the closest hit's patch
               scores 1/n.  F̂_ij is a binomial proportion: the 99 %
               confidence half-width is 2.576 √(F̂(1 − F̂)/n).  Slow, no
               singularity, used as the high-accuracy check.
=============  ===============================================================

Back faces: patches are one-sided, so a patch seen from behind receives
nothing (F = 0; the ray is absorbed — as Mitsuba's one-sided ``diffuse``).

References: J. H. Lambert, *Photometria* (1760) and Cohen & Wallace,
*Radiosity and Realistic Image Synthesis* (1993), ch. 4 (contour formula,
hemicube); M. F. Cohen, D. P. Greenberg, "The hemi-cube", SIGGRAPH 1985;
T. J. V. Malley, "A shading method for computer generated images" (1988);
J. R. Howell, *A Catalog of Radiation Heat Transfer Configuration Factors*
(C-11, C-14 are the checks of ``tests/test_form_factors.py``).

Leaves out: adaptive hemicubes, analytic area-to-area (Schröder & Hanrahan 1993).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from core.errors import ParamError

from .patches import PatchMesh, closest_face, locate, occluded
from .raster import DEPTH_FLOAT32, rasterize
from .rng import uniform

__all__ = ["METHODS", "HEMICUBE_NEAR", "FormFactors", "form_factors", "contour_point_polygon",
           "point_form_factor", "hemicube_table", "hemicube_face_weights", "patch_triangles", "quadrature_1d", "patch_quadrature", "Z99"]

METHODS = ("contour", "hemicube", "hemicube-zbuffer", "point", "montecarlo")
#: Near plane of the z-buffer hemicube, as a fraction of the scene's extent.
HEMICUBE_NEAR = 1e-3
#: Two-sided 99 % normal quantile, for the Monte Carlo confidence interval.
Z99 = 2.5758293035489004


class FormFactors(NamedTuple):
    F: np.ndarray                  # (N, N) row i = from patch i
    halfwidth: np.ndarray | None   # (N, N) 99 % CI half-width (montecarlo) or None
    rays: int                      # rays cast (visibility / item buffer / shooting)
    seconds: float
    method: str


# ------------------------------------------------------- contour formula ---

@njit(cache=True)
def contour_point_polygon(x, n, poly, nv):
    """Point-to-polygon form factor from point ``x`` with unit normal ``n`` to the
    polygon ``poly[:nv]`` (any winding), unoccluded: Lambert's contour integral
    over the part of the polygon above the tangent plane of x."""
    # Clip the polygon to the half-space (p − x)·n ≥ 0 (Sutherland–Hodgman, one plane).
    cx = np.empty((nv + 2, 3))
    m = 0
    for k in range(nv):
        a = poly[k]
        b = poly[(k + 1) % nv]
        da = (a[0] - x[0]) * n[0] + (a[1] - x[1]) * n[1] + (a[2] - x[2]) * n[2]
        db = (b[0] - x[0]) * n[0] + (b[1] - x[1]) * n[1] + (b[2] - x[2]) * n[2]
        if da >= 0.0:
            cx[m, 0], cx[m, 1], cx[m, 2] = a[0], a[1], a[2]
            m += 1
        if (da >= 0.0) != (db >= 0.0):
            u = da / (da - db)
            cx[m, 0] = a[0] + u * (b[0] - a[0])
            cx[m, 1] = a[1] + u * (b[1] - a[1])
            cx[m, 2] = a[2] + u * (b[2] - a[2])
            m += 1
    if m < 3:
        return 0.0
    # F = 1/(2π) Σ_k β_k  n·(r_k × r_{k+1}) / |r_k × r_{k+1}|,  β_k = ∠(r_k, r_{k+1}).
    total = 0.0
    for k in range(m):
        r0x, r0y, r0z = cx[k, 0] - x[0], cx[k, 1] - x[1], cx[k, 2] - x[2]
        j = (k + 1) % m
        r1x, r1y, r1z = cx[j, 0] - x[0], cx[j, 1] - x[1], cx[j, 2] - x[2]
        gx = r0y * r1z - r0z * r1y
        gy = r0z * r1x - r0x * r1z
        gz = r0x * r1y - r0y * r1x
        glen = math.sqrt(gx * gx + gy * gy + gz * gz)
        if glen <= 1e-300:                  # x on the edge's line: no contribution
            continue
        beta = math.atan2(glen, r0x * r1x + r0y * r1y + r0z * r1z)   # accurate for small and ~π angles
        total += beta * (n[0] * gx + n[1] * gy + n[2] * gz) / glen
    return abs(total) / (2.0 * math.pi)


def point_form_factor(x, n, polygon) -> float:
    """Python entry of :func:`contour_point_polygon`: ``polygon`` (k, 3), k ≥ 3."""
    p = np.ascontiguousarray(polygon, dtype=np.float64)
    return float(contour_point_polygon(np.asarray(x, dtype=np.float64), np.asarray(n, dtype=np.float64),
                                       p, p.shape[0]))


# --------------------------------------------------- quadrature over A_i ---

def quadrature_1d(k: int, graded: bool = False):
    """k Gauss–Legendre nodes and weights on [0, 1]; ``graded`` composes them with
    the sigmoidal map s = u³ / (u³ + (1 − u)³), which clusters nodes at both ends
    and turns an endpoint log singularity into a smooth integrand."""
    if k < 1:
        raise ValueError(f"quadrature needs k >= 1 points, got {k}")
    if k == 1:
        return np.array([0.5]), np.array([1.0])
    u, w = np.polynomial.legendre.leggauss(k)
    u = 0.5 * (u + 1.0)
    w = 0.5 * w
    if graded:
        a, b = u ** 3, (1.0 - u) ** 3
        s = a / (a + b)
        ds = 3.0 * u ** 2 * (1.0 - u) ** 2 / (a + b) ** 2
        return s, w * ds
    return u, w


def patch_quadrature(M: PatchMesh, k: int, graded: bool = False):
    """Points (N, k², 3) and weights (N, k²) summing to 1 per patch (area fractions).

    Parallelograms: the tensor rule in (s, t).  Triangles: the collapsed
    (Duffy) map t = b (1 − a), Jacobian 2 (1 − a); k = 1 is the centroid.
    """
    s, ws = quadrature_1d(k, graded)
    N = M.n_patches
    pts = np.empty((N, k * k, 3))
    wts = np.empty((N, k * k))
    S, T = np.meshgrid(s, s, indexing="ij")
    W = np.outer(ws, ws)
    S, T, W = S.ravel(), T.ravel(), W.ravel()
    for i in range(N):
        v = M.poly[i]
        if M.nverts[i] == 4:
            pts[i] = v[0] + S[:, None] * (v[1] - v[0]) + T[:, None] * (v[3] - v[0])
            wts[i] = W
        elif k == 1:
            pts[i] = v[:3].mean(axis=0)
            wts[i] = 1.0
        else:
            pts[i] = v[0] + S[:, None] * (v[1] - v[0]) + (T * (1.0 - S))[:, None] * (v[2] - v[0])
            wts[i] = 2.0 * W * (1.0 - S)
    return pts, wts


# -------------------------------------------------------------- contour ---

@njit(cache=True)
def _visibility(M: PatchMesh, x, j, k, eps):
    """Fraction of k×k shadow rays from x (already offset) to a stratified grid on patch j."""
    if k == 0:
        return 1.0, 0
    v = M.poly[j]
    nj = M.normal[j]
    free = 0
    for a in range(k):
        for b in range(k):
            u1 = (a + 0.5) / k
            u2 = (b + 0.5) / k
            if M.nverts[j] == 3 and u1 + u2 > 1.0:      # fold into the triangle
                u1, u2 = 1.0 - u1, 1.0 - u2
            e2 = 3 if M.nverts[j] == 4 else 2
            yx = v[0, 0] + u1 * (v[1, 0] - v[0, 0]) + u2 * (v[e2, 0] - v[0, 0]) + eps * nj[0]
            yy = v[0, 1] + u1 * (v[1, 1] - v[0, 1]) + u2 * (v[e2, 1] - v[0, 1]) + eps * nj[1]
            yz = v[0, 2] + u1 * (v[1, 2] - v[0, 2]) + u2 * (v[e2, 2] - v[0, 2]) + eps * nj[2]
            dx, dy, dz = yx - x[0], yy - x[1], yz - x[2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            if dist <= 0.0:
                continue
            if not occluded(M, x[0], x[1], x[2], dx / dist, dy / dist, dz / dist, 0.0, dist * (1.0 - 1e-9)):
                free += 1
    return free / (k * k), k * k


@njit(cache=True)
def _contour_row(M: PatchMesh, i, pts, wts, vis_k, eps, row):
    """Row i of F by the contour formula at each quadrature point; returns the rays cast."""
    N = M.area.shape[0]
    ni = M.normal[i]
    x = np.empty(3)
    rays = 0
    for q in range(pts.shape[0]):
        for c in range(3):
            x[c] = pts[q, c] + eps * ni[c]
        for j in range(N):
            if j == i or M.patch_face[j] == M.patch_face[i]:
                continue                        # F_ii = 0; coplanar patches of one face see nothing
            cj = M.centre[j]
            nj = M.normal[j]
            # One-sided: j is seen only from its front half-space.
            if (x[0] - cj[0]) * nj[0] + (x[1] - cj[1]) * nj[1] + (x[2] - cj[2]) * nj[2] <= 0.0:
                continue
            f = contour_point_polygon(x, ni, M.poly[j], M.nverts[j])
            if f <= 0.0:
                continue
            vis, nr = _visibility(M, x, j, vis_k, eps)
            rays += nr
            row[j] += wts[q] * f * vis
    return rays


@njit(parallel=True, cache=True)
def _contour_kernel(M: PatchMesh, pts, wts, vis_k, eps, F, rays):
    for c in prange(F.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        rays[i] = _contour_row(M, i, pts[i], wts[i], vis_k, eps, F[i])


# ------------------------------------------------------------- hemicube ---

def hemicube_table(res: int):
    """Cell directions (K, 3) in the local frame (z = normal) and normalised delta
    form factors (K,), plus the raw sum Σ ΔF (→ 1 as res → ∞).

    Top face z = 1, cells of side 2/res over [−1, 1]²: ΔF = ΔA / (π (x² + y² + 1)²).
    Side faces (e.g. y = 1), res × res/2 cells over x ∈ [−1, 1], z ∈ [0, 1]:
    ΔF = z ΔA / (π (x² + z² + 1)²).
    """
    if res < 2 or res % 2:
        raise ParamError(f"hemicube_res must be an even number >= 2, got {res}")
    h = 2.0 / res
    dA = h * h
    c = -1.0 + h * (np.arange(res) + 0.5)            # cell centres along a full edge
    z = h * (np.arange(res // 2) + 0.5)              # cell centres along a side's height
    X, Y = np.meshgrid(c, c, indexing="ij")
    top_d = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], axis=1)
    top_f = dA / (np.pi * (X.ravel() ** 2 + Y.ravel() ** 2 + 1.0) ** 2)
    U, Z = np.meshgrid(c, z, indexing="ij")
    U, Z = U.ravel(), Z.ravel()
    side_f = Z * dA / (np.pi * (U ** 2 + Z ** 2 + 1.0) ** 2)
    dirs = [top_d]
    for axis, sign in ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)):
        d = np.empty((U.size, 3))
        d[:, axis] = sign
        d[:, 1 - axis] = U
        d[:, 2] = Z
        dirs.append(d)
    dirs = np.concatenate(dirs)
    dF = np.concatenate([top_f] + [side_f] * 4)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    raw = float(dF.sum())
    return np.ascontiguousarray(dirs), dF / raw, raw


@njit(cache=True)
def _frame(n):
    """An orthonormal tangent frame (t, b) for the unit normal n (Duff et al. 2017)."""
    sign = 1.0 if n[2] >= 0.0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0],
            b, sign + n[1] * n[1] * a, -n[1])


@njit(cache=True)
def _trace_patch(M: PatchMesh, ox, oy, oz, dx, dy, dz):
    """Front-facing patch hit by a ray, or -1 (miss or back face)."""
    t, f = closest_face(M, ox, oy, oz, dx, dy, dz, 0.0, np.inf)
    if f < 0:
        return -1
    if dx * M.face_n[f, 0] + dy * M.face_n[f, 1] + dz * M.face_n[f, 2] >= 0.0:
        return -1
    return locate(M, f, ox + t * dx, oy + t * dy, oz + t * dz)[0]


@njit(cache=True)
def _hemicube_row(M: PatchMesh, i, pts, wts, dirs, dF, eps, row):
    n = M.normal[i]
    tx, ty, tz, bx, by, bz = _frame(n)
    for q in range(pts.shape[0]):
        ox, oy, oz = pts[q, 0] + eps * n[0], pts[q, 1] + eps * n[1], pts[q, 2] + eps * n[2]
        for c in range(dirs.shape[0]):
            lx, ly, lz = dirs[c, 0], dirs[c, 1], dirs[c, 2]
            dx = lx * tx + ly * bx + lz * n[0]
            dy = lx * ty + ly * by + lz * n[1]
            dz = lx * tz + ly * bz + lz * n[2]
            j = _trace_patch(M, ox, oy, oz, dx, dy, dz)
            if j >= 0 and j != i:
                row[j] += wts[q] * dF[c]
    return pts.shape[0] * dirs.shape[0]


@njit(parallel=True, cache=True)
def _hemicube_kernel(M: PatchMesh, pts, wts, dirs, dF, eps, F, rays):
    for c in prange(F.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        rays[i] = _hemicube_row(M, i, pts[i], wts[i], dirs, dF, eps, F[i])


# ------------------------------------------------------ z-buffer hemicube ---

def hemicube_face_weights(res: int):
    """ΔF of the cells of the five hemicube faces in the rasteriser's pixel layout: the top
    face (res, res) and a side face (res/2, res), rows from the top (row 0 of a side face
    is the cell row nearest the pole); normalised with :func:`hemicube_table`'s raw sum so
    both hemicube methods use the same table."""
    _, _, raw = hemicube_table(res)
    h = 2.0 / res
    c = -1.0 + h * (np.arange(res) + 0.5)
    U, V = np.meshgrid(c, -c, indexing="xy")                 # pixel (row, col) → (u, v), v up
    top = h * h / (np.pi * (U ** 2 + V ** 2 + 1.0) ** 2)
    z = 1.0 - h * (np.arange(res // 2) + 0.5)                # side rows: height above the horizon
    U2, Z = np.meshgrid(c, z, indexing="xy")
    side = Z * h * h / (np.pi * (U2 ** 2 + Z ** 2 + 1.0) ** 2)
    return top / raw, side / raw


def patch_triangles(M: PatchMesh):
    """The patches as triangles (T, 3, 3) and the patch of each (T,): a parallelogram
    patch gives two, a triangle one."""
    tris, src = [], []
    for i in range(M.n_patches):
        v = M.poly[i]
        tris.append(v[[0, 1, 2]])
        src.append(i)
        if M.nverts[i] == 4:
            tris.append(v[[0, 2, 3]])
            src.append(i)
    return np.ascontiguousarray(np.array(tris)), np.array(src, dtype=np.int64)


@njit(cache=True)
def _project_face(tris, x, r, up, f, near, res, out_xy, out_z, out_src):
    """Camera-space (u, v, w) of every triangle about x for the face looking along f (right r,
    up ``up``), clipped to w ≥ near, projected to a res-wide face (90° field of view,
    pixel y down).  Writes up to two triangles per input; returns their count."""
    m = 0
    poly = np.empty((4, 3))
    for t in range(tris.shape[0]):
        cam = np.empty((3, 3))
        inside = 0
        for k in range(3):
            dx = tris[t, k, 0] - x[0]
            dy = tris[t, k, 1] - x[1]
            dz = tris[t, k, 2] - x[2]
            cam[k, 0] = dx * r[0] + dy * r[1] + dz * r[2]
            cam[k, 1] = dx * up[0] + dy * up[1] + dz * up[2]
            cam[k, 2] = dx * f[0] + dy * f[1] + dz * f[2]
            if cam[k, 2] >= near:
                inside += 1
        if inside == 0:
            continue
        # Sutherland–Hodgman against w = near.
        n = 0
        for k in range(3):
            a = cam[k]
            b = cam[(k + 1) % 3]
            ia = a[2] >= near
            ib = b[2] >= near
            if ia:
                poly[n, 0], poly[n, 1], poly[n, 2] = a[0], a[1], a[2]
                n += 1
            if ia != ib:
                s = (near - a[2]) / (b[2] - a[2])
                poly[n, 0] = a[0] + s * (b[0] - a[0])
                poly[n, 1] = a[1] + s * (b[1] - a[1])
                poly[n, 2] = near
                n += 1
        for k in range(1, n - 1):
            for c, idx in enumerate((0, k, k + 1)):
                w = poly[idx, 2]
                out_xy[m, c, 0] = (poly[idx, 0] / w + 1.0) * 0.5 * res
                out_xy[m, c, 1] = (1.0 - poly[idx, 1] / w) * 0.5 * res
                out_z[m, c] = w
            out_src[m] = t
            m += 1
    return m


def _hemicube_zbuffer(M: PatchMesh, pts, wts, res: int, F: np.ndarray) -> int:
    """Rows of F by rasterised hemicubes; returns the number of hemicube cells evaluated."""
    tris, tri_patch = patch_triangles(M)
    top_w, side_w = hemicube_face_weights(res)
    extent = max(float(np.abs(M.tri_v).max()), 1.0)
    near, far = HEMICUBE_NEAR * extent, 4.0 * extent * math.sqrt(3.0)
    T = len(tris)
    xy = np.empty((2 * T, 3, 2))
    zc = np.empty((2 * T, 3))
    src = np.empty(2 * T, dtype=np.int64)
    eps = _eps(M)
    cells = 0
    for i in range(M.n_patches):
        n = M.normal[i]
        tx, ty, tz, bx, by, bz = _frame(n)
        t_ax, b_ax = np.array([tx, ty, tz]), np.array([bx, by, bz])
        # (forward, right, up, weights) of the top face and the four side faces.
        faces = ((n, t_ax, b_ax, top_w), (t_ax, b_ax, n, side_w), (-t_ax, -b_ax, n, side_w),
                 (b_ax, -t_ax, n, side_w), (-b_ax, t_ax, n, side_w))
        front = ((pts[i][:, None, :] + eps * n - M.centre[None, :, :]) * M.normal[None, :, :]).sum(-1) > 0.0
        for q in range(pts.shape[1]):
            x = pts[i, q] + eps * n
            for fwd, right, up, weights in faces:
                H = weights.shape[0]
                m = _project_face(tris, x, np.ascontiguousarray(right), np.ascontiguousarray(up),
                                  np.ascontiguousarray(fwd), near, res, xy, zc, src)
                cells += weights.size
                if m == 0:
                    continue
                vis, _ = rasterize(xy[:m], zc[:m], res, H, depth_mode=DEPTH_FLOAT32, near=near, far=far)
                ids = vis.id.ravel()
                hit = ids >= 0
                j = tri_patch[src[ids[hit]]]
                w = weights.ravel()[hit]
                keep = (j != i) & front[q, j]
                np.add.at(F[i], j[keep], wts[i, q] * w[keep])
    return cells


# ---------------------------------------------------------------- point ---

@njit(cache=True)
def _point_row(M: PatchMesh, i, pts, wts, vis_k, eps, row):
    """Row i of F by the point approximation A_j cosθ_i cosθ_j / (π r²) × visibility."""
    N = M.area.shape[0]
    ni = M.normal[i]
    x = np.empty(3)
    rays = 0
    for q in range(pts.shape[0]):
        for c in range(3):
            x[c] = pts[q, c] + eps * ni[c]
        for j in range(N):
            if j == i or M.patch_face[j] == M.patch_face[i]:
                continue
            cj = M.centre[j]
            nj = M.normal[j]
            dx, dy, dz = cj[0] - x[0], cj[1] - x[1], cj[2] - x[2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 <= 0.0:
                continue
            cos_i = (ni[0] * dx + ni[1] * dy + ni[2] * dz)
            cos_j = -(nj[0] * dx + nj[1] * dy + nj[2] * dz)
            if cos_i <= 0.0 or cos_j <= 0.0:
                continue
            f = M.area[j] * cos_i * cos_j / (math.pi * r2 * r2)     # the cosines carry r each
            vis, nr = _visibility(M, x, j, vis_k, eps)
            rays += nr
            row[j] += wts[q] * f * vis
    return rays


@njit(parallel=True, cache=True)
def _point_kernel(M: PatchMesh, pts, wts, vis_k, eps, F, rays):
    for c in prange(F.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        rays[i] = _point_row(M, i, pts[i], wts[i], vis_k, eps, F[i])


# ----------------------------------------------------------- Monte Carlo ---

@njit(cache=True)
def _mc_row(M: PatchMesh, i, n_samples, seed, eps, row):
    n = M.normal[i]
    tx, ty, tz, bx, by, bz = _frame(n)
    v = M.poly[i]
    e2 = 3 if M.nverts[i] == 4 else 2
    inc = 1.0 / n_samples
    for s in range(n_samples):
        u1 = uniform(seed, i, s, 0)
        u2 = uniform(seed, i, s, 1)
        if M.nverts[i] == 3 and u1 + u2 > 1.0:
            u1, u2 = 1.0 - u1, 1.0 - u2
        ox = v[0, 0] + u1 * (v[1, 0] - v[0, 0]) + u2 * (v[e2, 0] - v[0, 0]) + eps * n[0]
        oy = v[0, 1] + u1 * (v[1, 1] - v[0, 1]) + u2 * (v[e2, 1] - v[0, 1]) + eps * n[1]
        oz = v[0, 2] + u1 * (v[1, 2] - v[0, 2]) + u2 * (v[e2, 2] - v[0, 2]) + eps * n[2]
        # Cosine-weighted direction (Malley): a uniform disk point lifted to the hemisphere.
        r = math.sqrt(uniform(seed, i, s, 2))
        phi = 2.0 * math.pi * uniform(seed, i, s, 3)
        lx, ly = r * math.cos(phi), r * math.sin(phi)
        lz = math.sqrt(max(0.0, 1.0 - r * r))
        dx = lx * tx + ly * bx + lz * n[0]
        dy = lx * ty + ly * by + lz * n[1]
        dz = lx * tz + ly * bz + lz * n[2]
        j = _trace_patch(M, ox, oy, oz, dx, dy, dz)
        if j >= 0 and j != i:
            row[j] += inc
    return n_samples


@njit(parallel=True, cache=True)
def _mc_kernel(M: PatchMesh, n_samples, seed, eps, F, rays):
    for c in prange(F.shape[0]):
        i = np.int64(c)    # one index type in both typings of the loop (impl.kernel)
        rays[i] = _mc_row(M, i, n_samples, seed, eps, F[i])


# ---------------------------------------------------------------- driver ---

def _eps(M: PatchMesh) -> float:
    """Ray-origin offset along the normal: 1e-7 of the scene's extent."""
    return 1e-7 * max(float(np.abs(M.tri_v).max()), 1.0)


def form_factors(M: PatchMesh, method: str = "contour", *, hemicube_res: int = 64, points: int = 1,
                 graded: bool = False, vis_rays: int = 4, mc_samples: int = 4096,
                 seed: int = 0) -> FormFactors:
    """The form-factor matrix F (N × N, row i from patch i) by ``method``.

    Parameters
    ----------
    method : 'contour' | 'hemicube' | 'hemicube-zbuffer' | 'point' | 'montecarlo'
    hemicube_res : hemicube top-face resolution (even)
    points : k for a k×k quadrature over patch i (all but montecarlo); 1 = centre
    graded : grade the quadrature towards the patch edges (adjacent patches)
    vis_rays : shadow rays per (point, patch) pair for the contour and point
        methods, a square k² (0 = assume visible)
    mc_samples : rays per patch (montecarlo)
    """
    if method not in METHODS:
        raise ParamError(f"radiosity: unknown form-factor method {method!r} (valid: {', '.join(METHODS)})")
    N = M.n_patches
    F = np.zeros((N, N))
    rays = np.zeros(N, dtype=np.int64)
    eps = _eps(M)
    t0 = time.perf_counter()
    half = None
    if method in ("contour", "point"):
        k = int(round(math.sqrt(vis_rays)))
        if vis_rays < 0 or k * k != vis_rays:
            raise ParamError(f"radiosity: vis_rays must be 0 or a square k², got {vis_rays}")
        pts, wts = patch_quadrature(M, points, graded)
        (_contour_kernel if method == "contour" else _point_kernel)(M, pts, wts, k, eps, F, rays)
    elif method == "hemicube-zbuffer":
        hemicube_table(hemicube_res)                    # checks the resolution
        pts, wts = patch_quadrature(M, points, graded)
        rays[0] = _hemicube_zbuffer(M, pts, wts, hemicube_res, F)
    elif method == "hemicube":
        dirs, dF, _ = hemicube_table(hemicube_res)
        pts, wts = patch_quadrature(M, points, graded)
        _hemicube_kernel(M, pts, wts, dirs, dF, eps, F, rays)
    else:
        if mc_samples < 1:
            raise ParamError(f"radiosity: mc_samples must be >= 1, got {mc_samples}")
        _mc_kernel(M, mc_samples, seed, eps, F, rays)
        half = Z99 * np.sqrt(F * (1.0 - F) / mc_samples)
    return FormFactors(F=F, halfwidth=half, rays=int(rays.sum()), seconds=time.perf_counter() - t0,
                       method=method)
