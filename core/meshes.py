"""Triangle meshes for the scene model: Mitsuba's built-in ``rectangle`` and
``cube``, tessellations of its analytic ``disk`` and ``cylinder``, and
``obj``/``ply`` files (read with trimesh).

``disk`` and ``cylinder`` are tessellated rather than intersected
analytically: every own algorithm's kernels (hit, shadow ray, area-light
sampling, radiosity patches) already take triangles, so the shapes reach all of
them unchanged.  With :data:`SEGMENTS` = 128 sides the polygon's area is
(sin(2π/128)/(2π/128)) = 1 − 4.0e-4 of the circle's and its boundary lies
within r·(1 − cos(π/128)) = 3.0e-4 r of the circle (0.01 pixel for a disk
30 pixels across); the cylinder's shading normals are the exact radial ones
at the vertices (interpolated and renormalised in between).

Vertex normals follow Mitsuba: normals stored in the file are used; a mesh
without them gets angle-weighted vertex normals unless ``face_normals`` is set,
in which case shading uses the geometric normal (``normals=None``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from .errors import MeshError

__all__ = ["rectangle", "cube", "disk", "cylinder", "SEGMENTS", "load_mesh_file", "load_mesh_uvs",
           "angle_weighted_normals", "MeshError"]




def rectangle() -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Mitsuba's rectangle: [-1, 1]² in the z = 0 plane, normal +z."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [2, 3, 0]], dtype=np.int64)
    return v, f, None


def cube() -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Mitsuba's cube: [-1, 1]³, outward-facing, flat-shaded (24 vertices, 12 triangles)."""
    verts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, w = [a for a in range(3) if a != axis]
            quad = []
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[u], p[w] = sign, a, b
                quad.append(p)
            base = len(verts)
            verts.extend(quad)
            tri = [[base, base + 1, base + 2], [base + 2, base + 3, base]]
            # Orient so the winding normal points outward (+sign along axis).
            n = np.cross(quad[1] - quad[0], quad[2] - quad[0])
            if n[axis] * sign < 0:
                tri = [t[::-1] for t in tri]
            faces.extend(tri)
    return np.array(verts), np.array(faces, dtype=np.int64), None


#: Sides of the polygon that stands for a circle in ``disk`` and ``cylinder``.
SEGMENTS = 128


def disk(segments: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray, None]:
    """Mitsuba's disk: the unit disk in the z = 0 plane, normal +z (a fan of
    ``segments`` triangles around the centre), flat-shaded."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    v = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([np.cos(phi), np.sin(phi), np.zeros(segments)], 1)])
    k = np.arange(segments)
    f = np.stack([np.zeros(segments, np.int64), 1 + k, 1 + (k + 1) % segments], 1)
    return v, f, None


def cylinder(segments: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mitsuba's cylinder in object space: radius 1 around the z axis from z = 0 to
    z = 1, open (no caps), normals pointing outward; vertex normals radial."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros(segments)], 1)
    v = np.concatenate([ring, ring + [0.0, 0.0, 1.0]])
    n = np.concatenate([ring, ring])
    k = np.arange(segments)
    k1 = (k + 1) % segments
    # Counter-clockwise seen from outside: (k, k+1, top k+1), (top k+1, top k, k).
    f = np.concatenate([np.stack([k, k1, segments + k1], 1), np.stack([segments + k1, segments + k, k], 1)])
    return v, f.astype(np.int64), n


def angle_weighted_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Vertex normals as the angle-weighted sum of adjacent face normals."""
    n = np.zeros_like(v)
    p = v[f]                                        # (F, 3, 3)
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    fn_len = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = np.divide(fn, fn_len, out=np.zeros_like(fn), where=fn_len > 0)
    for k in range(3):
        e1 = p[:, (k + 1) % 3] - p[:, k]
        e2 = p[:, (k + 2) % 3] - p[:, k]
        c = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        ang = np.arccos(np.clip(c, -1.0, 1.0))
        np.add.at(n, f[:, k], fn * ang[:, None])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)


def load_mesh_file(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read an OBJ or PLY file: (vertices, faces, normals-from-the-file or None)."""
    v, f, n, _ = load_mesh_uvs(path)
    return v, f, n


def load_mesh_uvs(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`load_mesh_file` plus the texture coordinates, (V, 2) or None.

    OBJ ``vt`` coordinates arrive as Mitsuba's OBJ loader stores them: v is
    flipped, (u, 1 − v), so that with the bitmap texture's row 0 = first file
    row an image maps upright (measured against Mitsuba 3.9's ``uv`` AOV).
    PLY texture coordinates are not read (None).
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    ext = path.suffix.lower().lstrip(".")
    loader = trimesh.exchange.load.mesh_loaders.get(ext)
    if loader is None:
        raise MeshError(f"unsupported mesh file type '.{ext}': {path}")
    try:
        with open(path, "rb") as fh:
            kw = loader(fh, file_type=ext)
    except Exception as exc:
        raise MeshError(f"cannot read mesh file {path}: {exc}") from None
    # The format loaders return one geometry or a dict of them (OBJ objects).
    parts = list(kw["geometry"].values()) if "geometry" in kw else [kw]
    vs, fs, ns, uvs, base = [], [], [], [], 0
    for g in parts:
        uv = getattr(g.get("visual"), "uv", None) if ext == "obj" else None
        gv = np.asarray(g.get("vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        gf = np.asarray(g.get("faces", np.zeros((0, 3))), dtype=np.int64)
        if gf.ndim != 2 or (len(gf) and gf.shape[1] != 3):
            raise MeshError(f"mesh file {path} has non-triangular faces")
        gn = g.get("vertex_normals")
        vs.append(gv)
        fs.append(gf.reshape(-1, 3) + base)
        ns.append(None if gn is None else np.asarray(gn, dtype=np.float64).reshape(-1, 3))
        uvs.append(None if uv is None or len(uv) != len(gv) else
                   np.asarray(uv, dtype=np.float64).reshape(-1, 2) * [1.0, -1.0] + [0.0, 1.0])
        base += len(gv)
    v, f = np.concatenate(vs), np.concatenate(fs)
    if len(f) == 0:
        raise MeshError(f"mesh file {path} has no triangles")
    normals = np.concatenate(ns) if all(n is not None and len(n) == len(vv) for n, vv in zip(ns, vs)) else None
    tex = np.concatenate(uvs) if all(u is not None for u in uvs) else None
    return v, f, normals, tex
