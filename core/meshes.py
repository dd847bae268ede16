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
           "angle_weighted_normals", "load_serialized", "MeshError"]




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


def load_mesh_file(path: Path, file_type: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read an OBJ or PLY file: (vertices, faces, normals-from-the-file or None)."""
    v, f, n, _ = load_mesh_uvs(path, file_type)
    return v, f, n


def _obj_text(path: Path, data: bytes) -> str:
    """The OBJ file as text after Mitsuba's checks, or a :class:`MeshError` naming the
    line: numbers must parse and be finite, face indices must be non-zero and refer
    to an existing vertex (1-based, negative = relative to the vertices so far).
    Bytes that are not UTF-8 (a Latin-1 comment) are read as Latin-1: only ASCII
    keywords and numbers matter, as in Mitsuba's byte-oriented parser."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    counts = {"v": 0, "vt": 0, "vn": 0}
    largest = {k: (0, 0) for k in counts}         # the largest positive index and its line
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        key = tok[0]
        if key in counts:
            need = 2 if key == "vt" else 3
            try:
                vals = [float(t) for t in tok[1:1 + need]]
            except ValueError:
                raise MeshError(f"{path}:{lineno}: cannot parse '{line.strip()[:60]}'") from None
            if len(vals) < need or not all(np.isfinite(vals)):
                raise MeshError(f"{path}:{lineno}: '{key}' needs {need} finite numbers")
            counts[key] += 1
        elif key == "f":
            if len(tok) < 4:
                raise MeshError(f"{path}:{lineno}: a face needs at least 3 vertices")
            for t in tok[1:]:
                parts = t.split("/")
                for kind, raw in zip(("v", "vt", "vn"), parts):
                    if raw == "" and kind != "v":
                        continue
                    try:
                        i = int(raw)
                    except ValueError:
                        raise MeshError(f"{path}:{lineno}: bad face index '{t[:30]}'") from None
                    n = counts[kind]
                    if i == 0 or -i > n:
                        raise MeshError(f"{path}:{lineno}: face index {i} does not refer to a "
                                        f"'{kind}' entry (1-based; {n} before this line)")
                    if i > largest[kind][0]:
                        largest[kind] = (i, lineno)
    for kind, (i, lineno) in largest.items():     # positive indices: any entry of the file
        if i > counts[kind]:
            raise MeshError(f"{path}:{lineno}: face index {i} is out of range (the file has "
                            f"{counts[kind]} '{kind}' entries)")
    return text


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
              "double": 8, "float64": 8}


def _ply_check(path: Path, data: bytes) -> dict[str, int]:
    """Check a PLY file's header and that its body holds every element the header
    declares (a truncated file is refused, as Mitsuba does); returns the element
    counts."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError(f"{path}: not a PLY file (no 'ply' magic or no end_header)")
    nl = data.find(b"\n", end)
    header = data[:end].decode("latin-1").splitlines()
    body = data[nl + 1:] if nl >= 0 else b""
    fmt, elements = None, []                        # [(name, count, [props])]
    for lineno, line in enumerate(header, 1):
        tok = line.split()
        try:
            if tok and tok[0] == "format":
                fmt = tok[1]
            elif tok and tok[0] == "element":
                elements.append((tok[1], int(tok[2]), []))
            elif tok and tok[0] == "property":
                if tok[1] == "list":
                    elements[-1][2].append((_PLY_SIZES[tok[2]], _PLY_SIZES[tok[3]], tok[2]))
                else:
                    elements[-1][2].append((None, _PLY_SIZES[tok[1]], tok[1]))
        except (IndexError, KeyError, ValueError):
            raise MeshError(f"{path}:{lineno}: malformed PLY header line '{line[:60]}'") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshError(f"{path}: unknown PLY format {fmt!r}")
    if any(count < 0 for _, count, _ in elements):
        raise MeshError(f"{path}: negative PLY element count")
    truncated = MeshError(f"{path}: truncated PLY file (the body holds fewer elements than "
                          "the header declares)")
    if fmt == "ascii":
        tokens = body.split()
        at = 0
        for _, count, props in elements:
            if all(c is None for c, _, _ in props):
                at += count * len(props)
                continue
            for _ in range(count):
                for c, _, _ in props:
                    if c is None:
                        at += 1
                    else:
                        if at >= len(tokens):
                            raise truncated
                        try:
                            at += 1 + int(tokens[at])
                        except ValueError:
                            raise MeshError(f"{path}: bad PLY list length {tokens[at][:20]!r}") from None
        if at > len(tokens):
            raise truncated
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        at = 0
        for _, count, props in elements:
            if all(c is None for c, _, _ in props):
                at += count * sum(sz for _, sz, _ in props)
                continue
            for _ in range(count):
                for c, sz, name in props:
                    if c is None:
                        at += sz
                        continue
                    if at + c > len(body):
                        raise truncated
                    n = int.from_bytes(body[at:at + c], "little" if order == "<" else "big",
                                       signed=False)
                    at += c + n * sz
        if at > len(body):
            raise truncated
    return {name: count for name, count, _ in elements}


def load_mesh_uvs(path: Path, file_type: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`load_mesh_file` plus the texture coordinates, (V, 2) or None.

    ``file_type`` (``"obj"``/``"ply"``, the shape's ``type``) decides the format,
    as in Mitsuba (default: the file's extension).  The file is checked first as
    Mitsuba checks it (see :func:`_obj_text`, :func:`_ply_check`), then read with
    trimesh; vertices must be finite and face indices in range.

    OBJ ``vt`` coordinates arrive as Mitsuba's OBJ loader stores them: v is
    flipped, (u, 1 − v), so that with the bitmap texture's row 0 = first file
    row an image maps upright (measured against Mitsuba 3.9's ``uv`` AOV).
    PLY texture coordinates are not read (None).
    """
    import io

    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    ext = (file_type or path.suffix.lower().lstrip(".")).lower()
    if ext not in ("obj", "ply"):
        raise MeshError(f"unsupported mesh file type '.{ext}': {path}")
    loader = trimesh.exchange.load.mesh_loaders.get(ext)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot read mesh file {path}: {exc}") from None
    declared = None
    if ext == "obj":
        source = io.StringIO(_obj_text(path, data))
    else:
        declared = _ply_check(path, data)
        source = io.BytesIO(data)
    try:
        kw = loader(source, file_type=ext)
    except Exception as exc:                      # noqa: BLE001 - any parser failure is the file's
        raise MeshError(f"cannot read mesh file {path}: {str(exc)[:200]}") from None
    # The format loaders return one geometry or a dict of them (OBJ objects).
    parts = list(kw["geometry"].values()) if "geometry" in kw else [kw]
    vs, fs, ns, uvs, base = [], [], [], [], 0
    for g in parts:
        uv = getattr(g.get("visual"), "uv", None) if ext == "obj" else None
        gv = np.asarray(g.get("vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        gf = np.asarray(g.get("faces", np.zeros((0, 3))), dtype=np.int64)
        if gf.ndim == 2 and len(gf) and gf.shape[1] > 3:
            gf = _fan(gf)              # polygons (trimesh keeps all-quad files as quads)
        if gf.ndim != 2 or (len(gf) and gf.shape[1] != 3):
            raise MeshError(f"mesh file {path} has non-triangular faces")
        if len(gf) and (gf.min() < 0 or gf.max() >= len(gv)):
            raise MeshError(f"mesh file {path}: a face index is out of range "
                            f"(0..{len(gv) - 1}): {int(gf.min())}..{int(gf.max())}")
        gn = g.get("vertex_normals")
        vs.append(gv)
        fs.append(gf.reshape(-1, 3) + base)
        ns.append(None if gn is None else np.asarray(gn, dtype=np.float64).reshape(-1, 3))
        uvs.append(None if uv is None or len(uv) != len(gv) else
                   np.asarray(uv, dtype=np.float64).reshape(-1, 2) * [1.0, -1.0] + [0.0, 1.0])
        base += len(gv)
    if not vs or sum(len(f) for f in fs) == 0:
        raise MeshError(f"mesh file {path} has no triangles")
    v, f = np.concatenate(vs), np.concatenate(fs)
    if declared is not None and len(v) != declared.get("vertex", len(v)):
        raise MeshError(f"mesh file {path}: {len(v)} vertices read, the header declares "
                        f"{declared['vertex']}")
    if not np.all(np.isfinite(v)):
        raise MeshError(f"mesh file {path} has non-finite vertex coordinates")
    normals = np.concatenate(ns) if all(n is not None and len(n) == len(vv) for n, vv in zip(ns, vs)) else None
    if normals is not None and not np.all(np.isfinite(normals)):
        raise MeshError(f"mesh file {path} has non-finite vertex normals")
    tex = np.concatenate(uvs) if all(u is not None for u in uvs) else None
    return v, f, normals, tex


def _fan(faces: np.ndarray) -> np.ndarray:
    """Polygons (F, k) as the triangle fan (0, i, i + 1), i = 1..k-2, Mitsuba's
    triangulation of an OBJ face with more than three corners."""
    k = faces.shape[1]
    return np.stack([faces[:, [0, i, i + 1]] for i in range(1, k - 1)], axis=1).reshape(-1, 3)


#: Flags of Mitsuba's serialized mesh format (``src/shapes/serialized.cpp``).
_SER_NORMALS, _SER_UVS, _SER_COLORS, _SER_FACE_NORMALS = 0x0001, 0x0002, 0x0008, 0x0010
_SER_SINGLE, _SER_DOUBLE = 0x1000, 0x2000


def load_serialized(path: Path, shape_index: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Shape ``shape_index`` of a Mitsuba ``.serialized`` file: (vertices, faces,
    normals or None, uvs or None).

    The format (Mitsuba's documentation of the ``serialized`` shape): each shape is
    a little-endian ``uint16`` 0x041C and a ``uint16`` version (3 or 4), then a
    zlib stream holding ``uint32`` flags, (version 4) a NUL-terminated name,
    ``uint64`` vertex and triangle counts, the positions, the optional normals,
    texture coordinates and colours (float32 or float64 by flag), and the
    triangle indices (``uint32``, or ``uint64`` past 2³² vertices).  A file with
    several shapes ends with their byte offsets (``uint64`` in version 4,
    ``uint32`` in version 3) and the ``uint32`` shape count.  Texture coordinates
    are stored as Mitsuba uses them (no flip).  A face-normals flag gives
    ``normals = None``.
    """
    import zlib

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot read mesh file {path}: {exc}") from None

    def bad(why):
        return MeshError(f"mesh file {path} is not a valid Mitsuba serialized file: {why}")

    if len(data) < 8 or int.from_bytes(data[:2], "little") != 0x041C:
        raise bad("missing the 0x041C header")
    version = int.from_bytes(data[2:4], "little")
    if version not in (3, 4):
        raise bad(f"unsupported version {version}")
    count = int.from_bytes(data[-4:], "little")
    if shape_index < 0:
        raise MeshError(f"{path}: shape_index must be >= 0, got {shape_index}")
    osize = 8 if version == 4 else 4
    if count < 1 or count * osize + 4 > len(data):
        offsets = [0]
    else:
        table = data[-4 - count * osize:-4]
        offsets = [int.from_bytes(table[i * osize:(i + 1) * osize], "little") for i in range(count)]
        if any(o < 0 or o + 8 > len(data) or int.from_bytes(data[o:o + 2], "little") != 0x041C
               for o in offsets):
            offsets = [0]
    if shape_index >= len(offsets):
        raise MeshError(f"{path}: shape_index {shape_index} is out of range (the file has "
                        f"{len(offsets)} shape{'s' if len(offsets) != 1 else ''})")
    start = offsets[shape_index]
    try:
        raw = zlib.decompressobj().decompress(data[start + 4:])
    except zlib.error as exc:
        raise bad(f"zlib: {exc}") from None
    pos = 0

    def take(n):
        nonlocal pos
        if pos + n > len(raw):
            raise bad("truncated shape data")
        out = raw[pos:pos + n]
        pos += n
        return out

    flags = int.from_bytes(take(4), "little")
    if version == 4:
        end = raw.find(b"\0", pos)
        if end < 0:
            raise bad("unterminated shape name")
        pos = end + 1
    nv = int.from_bytes(take(8), "little")
    nt = int.from_bytes(take(8), "little")
    if nv == 0 or nt == 0:
        raise MeshError(f"mesh file {path}: shape {shape_index} has no triangles")
    ftype = np.dtype("<f8") if flags & _SER_DOUBLE else np.dtype("<f4")

    def arr(n, dtype):
        return np.frombuffer(take(n * dtype.itemsize), dtype=dtype).astype(
            np.float64 if dtype.kind == "f" else np.int64)

    v = arr(3 * nv, ftype).reshape(-1, 3)
    n = arr(3 * nv, ftype).reshape(-1, 3) if flags & _SER_NORMALS else None
    uv = arr(2 * nv, ftype).reshape(-1, 2) if flags & _SER_UVS else None
    if flags & _SER_COLORS:
        arr(3 * nv, ftype)
    f = arr(3 * nt, np.dtype("<u8") if nv > 0xFFFFFFFF else np.dtype("<u4")).reshape(-1, 3)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"mesh file {path} has non-finite vertex coordinates")
    if f.min() < 0 or f.max() >= nv:
        raise MeshError(f"mesh file {path}: a face index is out of range (0..{nv - 1})")
    if flags & _SER_FACE_NORMALS:
        n = None
    return v, f, n, uv
