"""Meshing planar shapes into radiosity patches (thesis 3.3: "the environment is
divided into n patches, each of constant radiosity").

What it computes
----------------
Every triangle mesh of the scene is split into *faces*: two consecutive
coplanar triangles that form a parallelogram (every ``rectangle`` and every
``cube`` face, as Mitsuba builds them) become one parallelogram face, any
other triangle is a triangle face.  A face with corner ``o`` and edges
``e1``, ``e2`` holds the points ``p = o + s e1 + t e2`` with ``(s, t)`` in
[0, 1]² (parallelogram) or in the triangle s, t ≥ 0, s + t ≤ 1.  Each face is
subdivided uniformly in ``(s, t)``:

* a parallelogram into ``nu × nv`` parallelogram patches, ``nu = ⌈|e1| / h⌉``,
  ``nv = ⌈|e2| / h⌉``;
* a triangle into ``n²`` triangles, ``n = ⌈longest edge / h⌉`` (the midpoint
  subdivision repeated: lower cells (a, b), (a+1, b), (a, b+1) and upper
  cells (a+1, b), (a+1, b+1), (a, b+1)).

``h`` is the target patch size; :func:`size_for_count` finds the ``h`` whose
patch count is closest to a requested total.  Because the subdivision lives in
the face's own ``(s, t)``, a ray hit on a scene triangle maps straight to its
patch and to the patch's interpolation weights (:func:`locate`): no patch
geometry needs to be ray-traced.

Per patch: polygon (3 or 4 vertices, counter-clockwise about the normal),
centroid, unit normal (the winding normal, reversed by ``flip_normals``),
area, diffuse reflectance ρ (RGB) and emitted radiosity ``E = π L_e`` (the
exitance of a Lambertian emitter of radiance ``L_e``).  Per face a vertex grid
is kept for Gouraud display: vertex radiosity = mean of the radiosities of the
patches of the same face that share the vertex.

Curved shapes: a ``sphere`` is meshed as a UV sphere of ``sphere_segments``
segments (:func:`impl.tessellate.uv_sphere`, an inscribed polyhedron whose
every triangle is a triangle face, so at least 2n(n/2 − 1) patches); the
loader already tessellates ``disk`` and ``cylinder`` (128 sides) into
triangles, each a face.  The patches are flat: the surface is the
polyhedron's (area 1 − O(n⁻²) of the sphere's, light leaving and arriving by
its facets), and Gouraud display never blends across faces, so such a shape
shows its facets.

Leaves out: non-diffuse and two-sided materials
(each refused with ``NotImplementedError`` naming the shape), textured
reflectance (the texture's mean is used, with a note), adaptive subdivision
and T-vertex handling across faces (Gouraud interpolation never crosses a face
edge, so faces with different ρ never blend).
"""

from __future__ import annotations

import hashlib
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from core.scene import Scene
from core.errors import ParamError, UnsupportedError

from .tessellate import uv_sphere

__all__ = ["PatchMesh", "SPHERE_SEGMENTS", "polygons_from_scene", "mesh_polygons", "mesh_scene", "size_for_count",
           "locate", "vertex_radiosity", "FACE_PARALLELOGRAM", "FACE_TRIANGLE"]

FACE_PARALLELOGRAM, FACE_TRIANGLE = 0, 1

#: Relative tolerance for coplanarity / parallelogram tests when pairing triangles.
PAIR_TOL = 1e-9


class PatchMesh(NamedTuple):
    """Faces, patches and the ray-tracing geometry, as plain arrays (a numba argument)."""

    # ray-tracing geometry: the scene's own triangles
    tri_v: np.ndarray          # (T, 3, 3)
    tri_face: np.ndarray       # (T,) face of each triangle
    # faces
    face_o: np.ndarray         # (F, 3) corner
    face_e1: np.ndarray        # (F, 3)
    face_e2: np.ndarray        # (F, 3)
    face_d1: np.ndarray        # (F, 3) dual basis: s = d1·(p − o)
    face_d2: np.ndarray        # (F, 3)             t = d2·(p − o)
    face_n: np.ndarray         # (F, 3) unit normal (front side)
    face_kind: np.ndarray      # (F,) FACE_PARALLELOGRAM or FACE_TRIANGLE
    face_nu: np.ndarray        # (F,) subdivisions along e1 (n for triangles)
    face_nv: np.ndarray        # (F,) subdivisions along e2 (n for triangles)
    face_p0: np.ndarray        # (F + 1,) offsets into the local patch table
    face_v0: np.ndarray        # (F + 1,) offsets into the vertex table
    face_shape: np.ndarray     # (F,) scene shape index
    local_patch: np.ndarray    # (sum,) local cell -> global patch (-1 unused)
    # patches
    poly: np.ndarray           # (N, 4, 3) vertices (the 4th repeats the 3rd for triangles)
    nverts: np.ndarray         # (N,) 3 or 4
    centre: np.ndarray         # (N, 3) centroid
    normal: np.ndarray         # (N, 3)
    area: np.ndarray           # (N,)
    rho: np.ndarray            # (N, 3) diffuse reflectance
    emit: np.ndarray           # (N, 3) emitted radiosity E = π L_e
    patch_face: np.ndarray     # (N,)
    patch_vidx: np.ndarray     # (N, 4) vertex-table indices of the corners (-1 unused)

    @property
    def n_patches(self) -> int:
        return len(self.area)

    def digest(self) -> str:
        """A hash of the geometry, reflectances and emission (the solution cache's key)."""
        h = hashlib.sha1()
        for a in (self.tri_v, self.face_nu, self.face_nv, self.rho, self.emit, self.face_n):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    def __repr__(self) -> str:
        return (f"PatchMesh({len(self.face_kind)} faces, {self.n_patches} patches, "
                f"{len(self.tri_v)} triangles, {int((self.emit.sum(axis=1) > 0).sum())} emitting)")


class Polygon(NamedTuple):
    """A planar face before subdivision (what :func:`mesh_polygons` takes)."""

    kind: int                  # FACE_PARALLELOGRAM or FACE_TRIANGLE
    o: np.ndarray
    e1: np.ndarray
    e2: np.ndarray             # normal = unit(e1 × e2)
    rho: tuple
    radiance: tuple            # emitted radiance L_e (0 if not an emitter)
    shape: int = 0
    name: str = ""


# ----------------------------------------------------------- scene → faces ---

def _pair_parallelogram(a: np.ndarray, b: np.ndarray, n: np.ndarray):
    """If triangles ``a`` and ``b`` (3×3) share an edge and form a coplanar parallelogram
    with normal ``n``, return (o, e1, e2) with unit(e1 × e2) = n, else None."""
    shared = [i for i in range(3) if any(np.array_equal(a[i], b[j]) for j in range(3))]
    if len(shared) != 2:
        return None
    p, q = a[shared[0]], a[shared[1]]
    r = a[3 - sum(shared)]
    s = b[[j for j in range(3) if not any(np.array_equal(b[j], a[i]) for i in shared)][0]]
    scale = max(np.abs(a).max(), np.abs(b).max(), 1.0)
    if np.abs((p + q) - (r + s)).max() > PAIR_TOL * scale:      # diagonals bisect each other
        return None
    # The parallelogram p, r, q, s: corner r, edges to p and q.
    e1, e2 = p - r, q - r
    if abs(np.dot(s - r, n)) > PAIR_TOL * scale * np.linalg.norm(s - r):
        return None
    if np.dot(np.cross(e1, e2), n) < 0.0:
        e1, e2 = e2, e1
    return r.copy(), e1, e2


#: Segments around a sphere meshed into patches (:func:`polygons_from_scene`).
SPHERE_SEGMENTS = 12


def polygons_from_scene(scene: Scene, *, sphere_segments: int = SPHERE_SEGMENTS) -> list[Polygon]:
    """The planar faces of every shape (spheres as UV spheres of ``sphere_segments``
    segments); refuses what radiosity cannot model."""
    if sphere_segments < 3:
        raise ParamError(f"radiosity: sphere_segments must be >= 3, got {sphere_segments}")
    out = []
    for si, shape in enumerate(scene.shapes):
        label = shape.name or shape.source
        mat = scene.materials[shape.material]
        if mat.kind != "diffuse":
            raise UnsupportedError(
                f"radiosity: shape '{label}' has a '{mat.kind}' BSDF; radiosity models diffuse "
                "(Lambertian) surfaces only")
        if mat.twosided:
            raise UnsupportedError(
                f"radiosity: shape '{label}' has a two-sided BSDF; patches here are one-sided "
                "(make the back side a separate shape)")
        radiance = tuple(shape.emitter_radiance) if shape.is_emitter else (0.0, 0.0, 0.0)
        rho = tuple(float(x) for x in mat.reflectance)
        if shape.kind == "sphere":
            verts, faces = uv_sphere(shape.center, shape.radius, sphere_segments)
            tris = verts[faces]
        else:
            tris = shape.vertices[shape.faces]
        normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        lens = np.linalg.norm(normals, axis=1)
        k = 0
        while k < len(tris):
            if lens[k] == 0.0:                      # degenerate triangle: no area, no patch
                k += 1
                continue
            n = normals[k] / lens[k]
            pair = _pair_parallelogram(tris[k], tris[k + 1], n) if k + 1 < len(tris) else None
            sign = -1.0 if shape.flip_normals else 1.0
            if pair is not None:
                o, e1, e2 = pair
                if sign < 0:
                    e1, e2 = e2, e1
                out.append(Polygon(FACE_PARALLELOGRAM, o, e1, e2, rho, radiance, si, label))
                k += 2
            else:
                o, e1, e2 = tris[k, 0], tris[k, 1] - tris[k, 0], tris[k, 2] - tris[k, 0]
                if sign < 0:
                    e1, e2 = e2, e1
                out.append(Polygon(FACE_TRIANGLE, o.copy(), e1, e2, rho, radiance, si, label))
                k += 1
    return out


# ------------------------------------------------------------ subdivision ---

def _divisions(poly: Polygon, h: float) -> tuple[int, int]:
    if poly.kind == FACE_PARALLELOGRAM:
        return (max(1, math.ceil(np.linalg.norm(poly.e1) / h - 1e-9)),
                max(1, math.ceil(np.linalg.norm(poly.e2) / h - 1e-9)))
    longest = max(np.linalg.norm(poly.e1), np.linalg.norm(poly.e2), np.linalg.norm(poly.e2 - poly.e1))
    n = max(1, math.ceil(longest / h - 1e-9))
    return n, n


def _count(polys, h) -> int:
    total = 0
    for p in polys:
        nu, nv = _divisions(p, h)
        total += nu * nv if p.kind == FACE_PARALLELOGRAM else nu * nu
    return total


def size_for_count(polys: list[Polygon], target: int) -> float:
    """The patch size h whose patch count is closest to ``target`` (bisection in log h)."""
    if target < len(polys):
        return float("inf")
    extent = max(max(np.linalg.norm(p.e1), np.linalg.norm(p.e2)) for p in polys)
    lo, hi = extent * 1e-4, extent * 1.001       # count(lo) ≥ target ≥ count(hi)
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if _count(polys, mid) > target:
            lo = mid
        else:
            hi = mid
    return lo if abs(_count(polys, lo) - target) < abs(_count(polys, hi) - target) else hi


def mesh_polygons(polys: list[Polygon], *, patch_size: float = 0.0, patches: int = 0) -> PatchMesh:
    """Subdivide planar faces into patches.

    Parameters
    ----------
    polys : faces (:func:`polygons_from_scene`, or built by hand in tests)
    patch_size : target patch edge length h (> 0), or 0 to use ``patches``
    patches : target total patch count (used when ``patch_size`` is 0); 0 = one patch per face
    """
    if not polys:
        raise ParamError("radiosity: the scene has no planar shapes to mesh")
    if patch_size < 0 or patches < 0:
        raise ParamError(f"radiosity: patch_size and patches must be >= 0, got {patch_size}, {patches}")
    h = patch_size if patch_size > 0 else (size_for_count(polys, patches) if patches > 0 else float("inf"))

    tri_v, tri_face = [], []
    f_o, f_e1, f_e2, f_d1, f_d2, f_n, f_kind, f_nu, f_nv, f_p0, f_v0, f_shape = ([] for _ in range(12))
    local, P, NV, RHO, EM, PF, VIDX = [], [], [], [], [], [], []
    vbase = 0
    for fi, p in enumerate(polys):
        o, e1, e2 = (np.asarray(x, dtype=np.float64) for x in (p.o, p.e1, p.e2))
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n)
        # Dual basis of (e1, e2) in the plane: d1·e1 = 1, d1·e2 = 0, ...
        g = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
        gi = np.linalg.inv(g)
        d1 = gi[0, 0] * e1 + gi[0, 1] * e2
        d2 = gi[1, 0] * e1 + gi[1, 1] * e2
        nu, nv = _divisions(p, h)
        f_o.append(o), f_e1.append(e1), f_e2.append(e2), f_d1.append(d1), f_d2.append(d2), f_n.append(n)
        f_kind.append(p.kind), f_nu.append(nu), f_nv.append(nv), f_shape.append(p.shape)
        f_p0.append(len(local))
        f_v0.append(vbase)
        emit = np.pi * np.asarray(p.radiance, dtype=np.float64)
        stride = nv + 1
        if p.kind == FACE_PARALLELOGRAM:
            c = o + e1 + e2
            tri_v += [np.array([o, o + e1, c]), np.array([c, o + e2, o])]
            tri_face += [fi, fi]
            for a in range(nu):
                for b in range(nv):
                    s0, s1, t0, t1 = a / nu, (a + 1) / nu, b / nv, (b + 1) / nv
                    local.append(len(P))
                    P.append([o + s0 * e1 + t0 * e2, o + s1 * e1 + t0 * e2,
                              o + s1 * e1 + t1 * e2, o + s0 * e1 + t1 * e2])
                    NV.append(4)
                    VIDX.append([vbase + a * stride + b, vbase + (a + 1) * stride + b,
                                 vbase + (a + 1) * stride + b + 1, vbase + a * stride + b + 1])
                    RHO.append(p.rho), EM.append(emit), PF.append(fi)
        else:
            tri_v.append(np.array([o, o + e1, o + e2]))
            tri_face.append(fi)
            for a in range(nu):
                for b in range(nu):
                    for upper in (0, 1):
                        ok = a + b <= nu - 1 if upper == 0 else a + b <= nu - 2
                        if not ok:
                            local.append(-1)
                            continue
                        local.append(len(P))
                        if upper == 0:
                            st = [(a, b), (a + 1, b), (a, b + 1)]
                        else:
                            st = [(a + 1, b), (a + 1, b + 1), (a, b + 1)]
                        verts = [o + (i / nu) * e1 + (j / nu) * e2 for i, j in st]
                        P.append(verts + [verts[2]])
                        NV.append(3)
                        VIDX.append([vbase + i * stride + j for i, j in st] + [-1])
                        RHO.append(p.rho), EM.append(emit), PF.append(fi)
        vbase += (nu + 1) * (nv + 1)
    f_p0.append(len(local))
    f_v0.append(vbase)

    poly = np.asarray(P, dtype=np.float64)
    nverts = np.asarray(NV, dtype=np.int64)
    centre = np.empty((len(P), 3))
    area = np.empty(len(P))
    for i in range(len(P)):
        v = poly[i, :nverts[i]]
        if nverts[i] == 4:
            area[i] = np.linalg.norm(np.cross(v[1] - v[0], v[3] - v[0]))
        else:
            area[i] = 0.5 * np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0]))
        centre[i] = v.mean(axis=0)            # centroid of a parallelogram or a triangle
    patch_face = np.asarray(PF, dtype=np.int64)
    f_n = np.asarray(f_n)
    return PatchMesh(
        tri_v=np.ascontiguousarray(tri_v, dtype=np.float64), tri_face=np.asarray(tri_face, dtype=np.int64),
        face_o=np.asarray(f_o), face_e1=np.asarray(f_e1), face_e2=np.asarray(f_e2),
        face_d1=np.asarray(f_d1), face_d2=np.asarray(f_d2), face_n=f_n,
        face_kind=np.asarray(f_kind, dtype=np.int64), face_nu=np.asarray(f_nu, dtype=np.int64),
        face_nv=np.asarray(f_nv, dtype=np.int64), face_p0=np.asarray(f_p0, dtype=np.int64),
        face_v0=np.asarray(f_v0, dtype=np.int64), face_shape=np.asarray(f_shape, dtype=np.int64),
        local_patch=np.asarray(local, dtype=np.int64),
        poly=poly, nverts=nverts, centre=centre, normal=np.ascontiguousarray(f_n[patch_face]), area=area,
        rho=np.asarray(RHO, dtype=np.float64).reshape(-1, 3), emit=np.asarray(EM, dtype=np.float64).reshape(-1, 3),
        patch_face=patch_face, patch_vidx=np.asarray(VIDX, dtype=np.int64))


def mesh_scene(scene: Scene, *, patch_size: float = 0.0, patches: int = 0,
               sphere_segments: int = SPHERE_SEGMENTS) -> PatchMesh:
    """:func:`polygons_from_scene` then :func:`mesh_polygons`."""
    return mesh_polygons(polygons_from_scene(scene, sphere_segments=sphere_segments),
                         patch_size=patch_size, patches=patches)


# ------------------------------------------------------ hit → patch lookup ---

@njit(cache=True)
def locate(M: PatchMesh, face, px, py, pz):
    """Patch of the point p on ``face`` and its Gouraud weights.

    Returns ``(patch, v0, v1, v2, v3, w0, w1, w2, w3)``: the vertex-table
    indices and interpolation weights (bilinear on parallelograms, barycentric
    on triangles; unused slots have weight 0 and index v0).
    """
    qx, qy, qz = px - M.face_o[face, 0], py - M.face_o[face, 1], pz - M.face_o[face, 2]
    s = qx * M.face_d1[face, 0] + qy * M.face_d1[face, 1] + qz * M.face_d1[face, 2]
    t = qx * M.face_d2[face, 0] + qy * M.face_d2[face, 1] + qz * M.face_d2[face, 2]
    nu, nv = M.face_nu[face], M.face_nv[face]
    stride = nv + 1
    vb = M.face_v0[face]
    su, tv = s * nu, t * nv
    a = min(max(int(math.floor(su)), 0), nu - 1)
    b = min(max(int(math.floor(tv)), 0), nv - 1)
    fs = min(max(su - a, 0.0), 1.0)
    ft = min(max(tv - b, 0.0), 1.0)
    if M.face_kind[face] == 0:
        patch = M.local_patch[M.face_p0[face] + a * nv + b]
        i00 = vb + a * stride + b
        return (patch, i00, i00 + stride, i00 + stride + 1, i00 + 1,
                (1.0 - fs) * (1.0 - ft), fs * (1.0 - ft), fs * ft, (1.0 - fs) * ft)
    # Triangle face: keep the cell inside the triangle a + b ≤ n − 1.
    if a + b > nu - 1:
        a = nu - 1 - b
        fs = 1.0 - ft
    upper = 1 if (fs + ft > 1.0 and a + b <= nu - 2) else 0
    patch = M.local_patch[M.face_p0[face] + 2 * (a * nu + b) + upper]
    if upper == 0:
        w0 = max(1.0 - fs - ft, 0.0)
        return (patch, vb + a * stride + b, vb + (a + 1) * stride + b, vb + a * stride + b + 1,
                vb + a * stride + b, w0, fs, ft, 0.0)
    return (patch, vb + (a + 1) * stride + b + 1, vb + a * stride + b + 1, vb + (a + 1) * stride + b,
            vb + a * stride + b, fs + ft - 1.0, 1.0 - fs, 1.0 - ft, 0.0)


def vertex_radiosity(M: PatchMesh, B: np.ndarray) -> np.ndarray:
    """Radiosity at the vertices of each face's grid: the mean of the patches
    of that face sharing the vertex (Gouraud's vertex colours)."""
    nvert = int(M.face_v0[-1])
    acc = np.zeros((nvert, 3))
    cnt = np.zeros(nvert)
    for k in range(4):
        idx = M.patch_vidx[:, k]
        ok = idx >= 0
        np.add.at(acc, idx[ok], B[ok])
        np.add.at(cnt, idx[ok], 1.0)
    return acc / np.maximum(cnt, 1.0)[:, None]


# ------------------------------------------------------- ray–face queries ---

#: Faces are inflated by this much in (s, t) for ray queries, so that a ray through
#: a shared edge or corner hits one of the faces meeting there (watertight; the
#: triangle-pair tests of Möller–Trumbore can miss both by rounding, and the
#: hemicube's regular directions hit edges exactly).
FACE_TOL = 1e-9


@njit(cache=True)
def closest_face(M: PatchMesh, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest face hit in (tmin, tmax): (t, face), face = -1 on a miss.  Both sides count;
    at a tie (a ray through an edge where faces meet) a front face wins over a back face."""
    best_t = tmax
    best_f = -1
    best_back = False
    for f in range(M.face_kind.shape[0]):
        nx, ny, nz = M.face_n[f, 0], M.face_n[f, 1], M.face_n[f, 2]
        denom = dx * nx + dy * ny + dz * nz
        if denom == 0.0:
            continue
        t = ((M.face_o[f, 0] - ox) * nx + (M.face_o[f, 1] - oy) * ny + (M.face_o[f, 2] - oz) * nz) / denom
        if not (t > tmin and t < best_t * (1.0 + 1e-12)):
            continue
        if t > best_t * (1.0 - 1e-12) and not (best_back and denom < 0.0):
            continue                        # a tie that would not replace a back face by a front one
        qx = ox + t * dx - M.face_o[f, 0]
        qy = oy + t * dy - M.face_o[f, 1]
        qz = oz + t * dz - M.face_o[f, 2]
        s = qx * M.face_d1[f, 0] + qy * M.face_d1[f, 1] + qz * M.face_d1[f, 2]
        u = qx * M.face_d2[f, 0] + qy * M.face_d2[f, 1] + qz * M.face_d2[f, 2]
        if s < -FACE_TOL or u < -FACE_TOL:
            continue
        if M.face_kind[f] == 0:
            if s > 1.0 + FACE_TOL or u > 1.0 + FACE_TOL:
                continue
        elif s + u > 1.0 + FACE_TOL:
            continue
        best_t = t
        best_f = f
        best_back = denom > 0.0
    return best_t, best_f


@njit(cache=True)
def occluded(M: PatchMesh, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """True if any face lies on the ray within (tmin, tmax) (shadow rays)."""
    return closest_face(M, ox, oy, oz, dx, dy, dz, tmin, tmax)[1] >= 0
