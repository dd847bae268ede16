"""Scene shapes as triangle meshes, for the polygon pipeline (thesis 1.1, 1.5).

The z-buffer and depth-sort algorithms draw polygons only, so every shape of
the scene model becomes triangles: meshes as they are, analytic spheres as UV
spheres with ``tessellation = N`` segments around (longitude) and ``N // 2``
rings (latitude), vertices *on* the sphere (an inscribed polyhedron, so its
silhouette lies inside the analytic one by at most r(1 − cos(π/N))).

Vertex normals (what Gouraud and Phong shading interpolate, thesis 1.5.4):

* tessellated spheres: the mean of the unit normals of the faces sharing the
  vertex (Gouraud's averaging, thesis fig. 1.13), not the analytic normal;
* meshes with shading normals in the scene model (OBJ without normals gets
  loader-computed ones): those normals;
* meshes without (rectangles, cubes, ``face_normals`` PLY): the face normal at
  every corner (vertices are duplicated per face), so every shading mode
  shows them flat — as ray casting and Mitsuba do.

:func:`tessellated_scene` returns a copy of a scene with its spheres replaced
by these meshes, so ray casting can render the *same* triangles the
rasterisers draw (the depth and visibility cross-checks).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from core.scene import Scene, Shape
from core.errors import ParamError

__all__ = ["TriangleSoup", "uv_sphere", "face_normals", "vertex_normals", "scene_triangles",
           "tessellated_scene", "sphere_triangle_count"]


class TriangleSoup(NamedTuple):
    """An indexed triangle list over all shapes of a scene (world space, float64)."""

    pos: np.ndarray         # (V, 3) vertex positions
    nrm: np.ndarray         # (V, 3) unit vertex shading normals (flip_normals applied)
    tri: np.ndarray         # (T, 3) vertex indices, right-hand winding = geometric normal
    tri_shape: np.ndarray   # (T,) shape index in scene.shapes
    tri_prim: np.ndarray    # (T,) primitive index in impl.scene_arrays numbering (albedo lookups)
    tri_flip: np.ndarray    # (T,) 1 where the shape has flip_normals

    @property
    def n_triangles(self) -> int:
        return len(self.tri)


def sphere_triangle_count(n: int) -> int:
    """Triangles of :func:`uv_sphere` with ``n`` segments: 2n (polar caps) + 2n(rings − 2)."""
    rings = max(2, n // 2)
    return 2 * n + 2 * n * (rings - 2)


def uv_sphere(center, radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere: ``n`` segments around, ``max(2, n // 2)`` rings; (vertices, faces).

    Faces wind counter-clockwise seen from outside (right-hand normal points
    out); the poles are single vertices.
    """
    if n < 3:
        raise ParamError(f"tessellation must be >= 3 segments around, got {n}")
    rings = max(2, n // 2)
    theta = np.pi * np.arange(1, rings) / rings            # polar angle of the inner rings
    phi = 2.0 * np.pi * np.arange(n) / n
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack(np.broadcast_arrays(st * np.cos(phi), ct, st * np.sin(phi)), axis=-1).reshape(-1, 3)
    unit = np.concatenate([[[0.0, 1.0, 0.0]], ring, [[0.0, -1.0, 0.0]]])
    top, bottom = 0, len(unit) - 1
    idx = lambda r, j: 1 + r * n + (j % n)  # noqa: E731  (ring r, segment j)
    faces = []
    j = np.arange(n)
    # Caps: (pole, next, this) winds outward for y-up, phi increasing towards +z.
    faces.append(np.stack([np.full(n, top), idx(0, j + 1), idx(0, j)], axis=1))
    for r in range(rings - 2):
        a, b = idx(r, j), idx(r, j + 1)
        c, d = idx(r + 1, j), idx(r + 1, j + 1)
        faces.append(np.stack([a, b, d], axis=1))
        faces.append(np.stack([a, d, c], axis=1))
    faces.append(np.stack([np.full(n, bottom), idx(rings - 2, j), idx(rings - 2, j + 1)], axis=1))
    faces = np.concatenate(faces).astype(np.int64)
    verts = np.asarray(center, dtype=np.float64) + radius * unit
    # Orientation check: the right-hand normal must point away from the centre.
    nf = face_normals(verts, faces)
    out = np.einsum("ij,ij->i", nf, verts[faces].mean(axis=1) - np.asarray(center))
    if np.any(out <= 0):
        faces = faces[:, ::-1].copy()
    return verts, faces


def face_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit right-hand normals (e1 × e2) of the faces, (F, 3)."""
    p = verts[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Gouraud's vertex normals: the mean of the unit normals of the adjacent faces, renormalised."""
    fn = face_normals(verts, faces)
    acc = np.zeros_like(verts)
    for k in range(3):
        np.add.at(acc, faces[:, k], fn)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)


def _shape_mesh(shape: Shape, n: int):
    """(vertices, faces, vertex normals) of one shape, before flip_normals."""
    if shape.kind == "sphere":
        v, f = uv_sphere(shape.center, shape.radius, n)
        return v, f, vertex_normals(v, f)
    v, f = np.asarray(shape.vertices, np.float64), np.asarray(shape.faces, np.int64)
    if shape.normals is not None:
        nv = np.asarray(shape.normals, np.float64)
        return v, f, nv / np.maximum(np.linalg.norm(nv, axis=1, keepdims=True), 1e-300)
    # Face normals: one vertex per corner.
    fn = face_normals(v, f)
    return v[f].reshape(-1, 3), np.arange(3 * len(f), dtype=np.int64).reshape(-1, 3), np.repeat(fn, 3, axis=0)


def scene_triangles(scene: Scene, tessellation: int) -> TriangleSoup:
    """All shapes of ``scene`` as one indexed triangle list (spheres tessellated)."""
    n_spheres = sum(1 for s in scene.shapes if s.kind == "sphere")
    sphere_prim, tri_base = 0, n_spheres    # impl.scene_arrays numbering: spheres, then triangles
    pos, nrm, tri, tshape, tprim, tflip = [], [], [], [], [], []
    nv = 0
    for si, shape in enumerate(scene.shapes):
        v, f, vn = _shape_mesh(shape, tessellation)
        if shape.flip_normals:
            vn = -vn
        pos.append(v)
        nrm.append(vn)
        tri.append(f + nv)
        nv += len(v)
        tshape.append(np.full(len(f), si, np.int64))
        tflip.append(np.full(len(f), int(shape.flip_normals), np.int64))
        if shape.kind == "sphere":
            tprim.append(np.full(len(f), sphere_prim, np.int64))
            sphere_prim += 1
        else:
            tprim.append(tri_base + np.arange(len(f), dtype=np.int64))
            tri_base += len(f)
    cat = lambda xs, shape, dt: np.ascontiguousarray(np.concatenate(xs), dt) if xs else np.zeros(shape, dt)  # noqa: E731
    return TriangleSoup(pos=cat(pos, (0, 3), np.float64), nrm=cat(nrm, (0, 3), np.float64),
                        tri=cat(tri, (0, 3), np.int64), tri_shape=cat(tshape, (0,), np.int64),
                        tri_prim=cat(tprim, (0,), np.int64), tri_flip=cat(tflip, (0,), np.int64))


def tessellated_scene(scene: Scene, tessellation: int) -> Scene:
    """A copy of ``scene`` whose spheres are UV-sphere meshes with Gouraud vertex normals.

    Shape order (and so shape ids) is kept; ray casting this scene renders
    the same triangles and interpolated normals the rasterisers draw.
    """
    shapes = []
    for s in scene.shapes:
        if s.kind == "sphere":
            v, f = uv_sphere(s.center, s.radius, tessellation)
            s = dataclasses.replace(s, kind="mesh", source="sphere (tessellated)", center=None, radius=0.0,
                                    vertices=v, faces=f, normals=vertex_normals(v, f))
        shapes.append(s)
    return dataclasses.replace(scene, shapes=shapes)
