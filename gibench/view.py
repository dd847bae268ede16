"""``gibench view``: a scene, a radiosity solution or an acceleration structure in 3D.

Drawn with pyvista (VTK) off screen, so it runs without an X server: VTK's
wheels fall back to an EGL context (Mesa's ``libEGL``; setup.sh installs it
on Debian where it is missing).  What is drawn:

* the scene's geometry (spheres and triangle meshes, coloured by their
  diffuse reflectance; area emitters in their emitted colour), the delta
  lights (point and spot lights as yellow markers, a spot's axis and a
  directional light's direction as arrows) and the camera: its position and
  its viewing frustum out to a quarter of the scene's diagonal;
* ``radiosity=True``: the solved patches of :func:`impl.radiosity.solve_scene`
  (the ``radiosity`` algorithm's parameters, ``params`` overriding), each
  patch in its radiosity ``B`` tone-mapped to sRGB (the 99th percentile of
  the non-emitting patches maps to white);
* ``accel=NAME, depth=K``: the boxes of the first K levels of a tree
  (``bvh-*``, ``octree``), coloured by level, the occupied cells of a
  ``grid``, or the per-object boxes of ``bv``, built by
  :func:`impl.accel.build` over the scene's primitives as the tracers hold
  them (float64).  ``slabs`` and ``bv-sphere`` bound with other shapes than
  boxes and are refused by name.

Output: a PNG, or a self-contained HTML page with PNG views from three
directions (an interactive 3D page would need pyvista's trame server
packages: not a dependency).
"""

from __future__ import annotations

import base64
import html
import time
from pathlib import Path

import numpy as np

from core.errors import ParamError, UsageError
from core.records import Record
from core.scene import Scene

__all__ = ["view_scene", "scene_actors", "accel_boxes", "radiosity_patches", "write_view"]

#: Boxes drawn at most (a deep tree or a fine grid would swamp the picture and the memory).
MAX_BOXES = 200_000
SPHERE_RES = 48


def _pv():
    import os

    if not os.environ.get("DISPLAY"):
        # No X server: ask VTK for its EGL window directly (else it tries X first and warns).
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista as pv
    except ImportError:
        raise UsageError("gibench view needs pyvista (pip install pyvista; setup.sh installs it)") from None
    pv.OFF_SCREEN = True
    return pv


def _diag(scene: Scene) -> float:
    pts = [scene.camera.origin]
    for s in scene.shapes:
        if s.kind == "sphere":
            pts += [s.center - s.radius, s.center + s.radius]
        else:
            pts += [s.vertices.min(axis=0), s.vertices.max(axis=0)]
    pts = np.array(pts)
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0


def _srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def frustum_lines(scene: Scene, distance: float) -> np.ndarray:
    """The camera's frustum as line segments ``(S, 2, 3)``: apex (or the near
    rectangle of an orthographic camera) to the four corners at ``distance``
    along the view axis, and the far rectangle."""
    cam = scene.camera
    M = cam.to_world
    if cam.kind == "orthographic":
        hx, hy = 1.0, 1.0 / cam.film.aspect
        near = np.array([[sx * hx, sy * hy, 0.0] for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
        far = near + [0.0, 0.0, distance / np.linalg.norm(M[:3, 2])]
    else:
        tx = cam.tan_half_fov_x
        ty = tx / cam.film.aspect
        far = np.array([[sx * tx, sy * ty, 1.0] for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
        far *= distance / np.linalg.norm(M[:3, :3] @ far[0])
        near = np.zeros((4, 3))

    def world(p):
        return p @ M[:3, :3].T + M[:3, 3]

    n, f = world(near), world(far)
    segs = [(n[i], f[i]) for i in range(4)] + [(f[i], f[(i + 1) % 4]) for i in range(4)]
    if cam.kind == "orthographic":
        segs += [(n[i], n[(i + 1) % 4]) for i in range(4)]
    return np.array(segs)


def _lines(pv, segs: np.ndarray):
    segs = np.asarray(segs, dtype=np.float64).reshape(-1, 2, 3)
    n = len(segs)
    cells = np.column_stack([np.full(n, 2), 2 * np.arange(n), 2 * np.arange(n) + 1]).ravel()
    return pv.PolyData(segs.reshape(-1, 3), lines=cells)


def scene_actors(plotter, scene: Scene, *, surfaces: bool = True, opacity: float = 1.0) -> None:
    """Add the scene's shapes (when ``surfaces``), lights and camera frustum to ``plotter``."""
    pv = _pv()
    d = _diag(scene)
    if surfaces:
        for s in scene.shapes:
            if s.is_emitter:
                c = np.asarray(s.emitter_radiance, dtype=np.float64)
                color = tuple(_srgb(c / max(c.max(), 1e-12)))
            else:
                color = tuple(_srgb(np.asarray(scene.materials[s.material].reflectance, dtype=np.float64)))
            if s.kind == "sphere":
                mesh = pv.Sphere(radius=s.radius, center=s.center, theta_resolution=SPHERE_RES,
                                 phi_resolution=SPHERE_RES)
            else:
                faces = np.column_stack([np.full(len(s.faces), 3), s.faces]).ravel()
                mesh = pv.PolyData(np.asarray(s.vertices, dtype=np.float64), faces)
            plotter.add_mesh(mesh, color=color, opacity=opacity, smooth_shading=s.kind == "sphere")
    for light in scene.lights:
        if light.position is not None:
            plotter.add_mesh(pv.Sphere(radius=0.01 * d, center=light.position), color="yellow")
        if light.direction is not None:
            start = light.position if light.position is not None else \
                -np.asarray(light.direction) * 0.3 * d
            plotter.add_mesh(pv.Arrow(start=start, direction=light.direction, scale=0.15 * d),
                             color="gold")
    plotter.add_mesh(_lines(pv, frustum_lines(scene, 0.25 * d)), color="deepskyblue", line_width=2)
    plotter.add_mesh(pv.Sphere(radius=0.008 * d, center=scene.camera.origin), color="deepskyblue")


def _primitives(scene: Scene):
    spheres = [s for s in scene.shapes if s.kind == "sphere"]
    meshes = [s for s in scene.shapes if s.kind == "mesh"]
    index = {id(s): i for i, s in enumerate(scene.shapes)}
    sph_center = np.array([s.center for s in spheres], dtype=np.float64).reshape(-1, 3)
    sph_radius = np.array([s.radius for s in spheres], dtype=np.float64)
    tri_v = (np.concatenate([s.vertices[s.faces] for s in meshes]).astype(np.float64)
             if meshes else np.zeros((0, 3, 3)))
    prim_shape = np.array([index[id(s)] for s in spheres]
                          + [index[id(s)] for s in meshes for _ in range(len(s.faces))], dtype=np.int64)
    return sph_center, sph_radius, tri_v, prim_shape


def accel_boxes(scene: Scene, name: str, depth: int = 3):
    """``(lo, hi, level)`` of the boxes to draw for structure ``name``: a tree's nodes
    of levels 1..``depth`` (root = 1), a grid's occupied cells (level 1), or the
    per-object boxes of ``bv`` (level 1); plus the build's statistics."""
    from impl.accel import ACCELS, GRID, TREE, BV, build

    if name not in ACCELS:
        raise ParamError(f"view: unknown structure {name!r} (valid: {', '.join(ACCELS)})")
    if name in ("none", "slabs", "bv-sphere"):
        raise ParamError(f"view: structure {name!r} has no boxes to draw "
                         "(drawn: bv, bvh-median, bvh-sah, bvh-gs, octree, grid)")
    if depth < 1:
        raise ParamError(f"view: --depth must be >= 1, got {depth}")
    prims = _primitives(scene)
    t0 = time.perf_counter()
    acc = build(name, *prims)
    build_s = time.perf_counter() - t0
    if acc.kind == TREE:
        n = len(acc.node_a)
        level = np.zeros(n, dtype=np.int64)
        level[0] = 1
        for i in range(n):                    # children come after their parent
            if acc.node_b[i] < 0:
                level[acc.node_a[i]:acc.node_a[i] - acc.node_b[i]] = level[i] + 1
        keep = level <= depth
        lo, hi, lev = acc.node_lo[keep, :3], acc.node_hi[keep, :3], level[keep]
        stats = {"nodes": n, "levels": int(level.max()), "drawn": int(keep.sum())}
    elif acc.kind == GRID:
        res = acc.acc_i[:3].astype(np.int64)
        cs = acc.acc_f[:3]
        occupied = np.flatnonzero(np.diff(acc.node_a) > 0)
        x = occupied % res[0]
        y = (occupied // res[0]) % res[1]
        z = occupied // (res[0] * res[1])
        ijk = np.column_stack([x, y, z]).astype(np.float64)
        lo = acc.node_lo[0] + ijk * cs
        hi = lo + cs
        lev = np.ones(len(lo), dtype=np.int64)
        stats = {"cells": int(np.prod(res)), "occupied": int(len(occupied)),
                 "resolution": res.tolist(), "drawn": int(len(lo))}
    elif acc.kind == BV:
        lo, hi = acc.node_lo, acc.node_hi
        lev = np.ones(len(lo), dtype=np.int64)
        stats = {"objects": int(len(lo)), "drawn": int(len(lo))}
    else:                                     # pragma: no cover - excluded above
        raise ParamError(f"view: structure {name!r} has no boxes to draw")
    if len(lo) > MAX_BOXES:
        raise ParamError(f"view: {len(lo)} boxes to draw (> {MAX_BOXES}); lower --depth")
    stats["build_s"] = build_s
    return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64), lev, stats


_BOX_EDGES = [(0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def _box_segments(lo, hi) -> np.ndarray:
    corners = np.stack([np.where([(k >> a) & 1 for a in range(3)], hi, lo) for k in range(8)], axis=1)
    return np.stack([corners[:, [a, b]] for a, b in _BOX_EDGES], axis=1).reshape(-1, 2, 3)


def radiosity_patches(scene: Scene, params: dict | None = None, *, seed: int = 0):
    """``(poly (N, 4, 3), nverts (N,), B (N, 3), solution)`` of the radiosity solution."""
    from impl.radiosity import ALGORITHM, solve_scene

    sol = solve_scene(scene, ALGORITHM.parse_params(params or {}), seed=seed)
    M = sol.mesh
    return M.poly, M.nverts, np.asarray(sol.B_display, dtype=np.float64), sol


def view_scene(scene: Scene, *, radiosity: bool = False, accel: str | None = None, depth: int = 3,
               params: dict | None = None, size=(1024, 768), views=("overview",)) -> tuple[list, dict]:
    """Render the 3D views; returns ``([RGB uint8 (H, W, 3) per view], info)``.

    ``views`` from ``overview`` (isometric, the whole scene and the camera),
    ``camera`` (from the scene's camera), ``top`` (along −y).
    """
    pv = _pv()
    info: dict = {}
    t0 = time.perf_counter()
    p = pv.Plotter(off_screen=True, window_size=list(size))
    p.set_background("white")
    if radiosity:
        poly, nverts, B, sol = radiosity_patches(scene, params)
        emit = np.asarray(sol.mesh.emit).sum(axis=1) > 0
        ref = B[~emit].max(axis=1) if (~emit).any() else B.max(axis=1)
        p99 = float(np.percentile(ref, 99)) if ref.size else 1.0
        rgb = (255 * _srgb(B / (p99 if p99 > 0 else 1.0))).round().astype(np.uint8)
        faces = []
        for i in range(len(poly)):
            k = int(nverts[i])
            faces += [k, *range(4 * i, 4 * i + k)]
        mesh = pv.PolyData(poly.reshape(-1, 3).astype(np.float64), np.array(faces))
        mesh.cell_data["B"] = rgb
        p.add_mesh(mesh, scalars="B", rgb=True, show_edges=True, edge_color="gray", line_width=0.5,
                   lighting=False)
        scene_actors(p, scene, surfaces=False)
        info["radiosity"] = {"patches": int(len(poly)), "solver": sol.result.solver,
                             "iterations": int(sol.result.iterations), "white_B": p99}
    elif accel:
        lo, hi, lev, stats = accel_boxes(scene, accel, depth)
        scene_actors(p, scene, opacity=0.35)
        segs = _box_segments(lo, hi)
        lines = _lines(pv, segs)
        lines.cell_data["level"] = np.repeat(lev, 12)
        p.add_mesh(lines, scalars="level", cmap="viridis", line_width=1.5, show_scalar_bar=len(set(lev)) > 1,
                   scalar_bar_args={"title": "level"})
        info["accel"] = dict(stats, name=accel, depth=depth)
    else:
        scene_actors(p, scene)
    info["shapes"] = len(scene.shapes)
    images = []
    for v in views:
        if v == "overview":
            p.view_isometric()
            p.reset_camera()
        elif v == "top":
            p.view_xz()
            p.reset_camera()
        elif v == "camera":
            cam = scene.camera
            M = cam.to_world
            p.camera_position = [tuple(cam.origin), tuple(cam.origin + M[:3, 2]), tuple(M[:3, 1])]
            if cam.kind != "orthographic":
                ty = cam.tan_half_fov_x / cam.film.aspect
                p.camera.view_angle = float(np.degrees(2 * np.arctan(ty)))
        else:
            raise ParamError(f"view: unknown view {v!r} (overview, camera, top)")
        images.append(np.asarray(p.screenshot(return_img=True))[..., :3].copy())
    p.close()
    info["seconds"] = time.perf_counter() - t0
    return images, info


def write_view(scene: Scene, out, **kw) -> dict:
    """Write the view(s) to ``out``: ``.png`` (the overview), or ``.html`` (a
    self-contained page with the overview, camera and top views)."""
    import matplotlib.image as mpimg

    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".html"):
        raise UsageError(f"view: --out must end in .png or .html, got {out.name}")
    views = ("overview",) if suffix == ".png" else ("overview", "camera", "top")
    images, info = view_scene(scene, views=views, **kw)
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        mpimg.imsave(out, images[0])
    else:
        import io

        from core.imageio import write_text

        figs = []
        for name, img in zip(views, images):
            buf = io.BytesIO()
            mpimg.imsave(buf, img, format="png")
            src = "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
            figs.append(f"<figure><img src='{src}' alt='{name} view' style='max-width:100%'>"
                        f"<figcaption>{name}</figcaption></figure>")
        rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
                       for k, v in info.items())
        write_text(out, "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
                        f"<title>gibench view — {html.escape(str(scene.path))}</title></head><body>"
                        f"<h1>{html.escape(str(scene.path))}</h1><table>{rows}</table>"
                        + "".join(figs) + "</body></html>\n")
    info["out"] = str(out)
    return info


def _data_uri(img) -> str:
    import io

    import matplotlib.image as mpimg

    buf = io.BytesIO()
    mpimg.imsave(buf, img, format="png")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def suite_views(suite, *, size=(800, 600), log=print) -> list[Record]:
    """3D views for a suite's report, where they are cheap: the radiosity solution
    of each radiosity case's scene (its first configuration's parameters) for the
    ``radiosity`` study set, a SAH BVH (4 levels) and a grid over a 1000-sphere
    field for the ``accel`` (scaling) study set.  One study-kind record with the
    PNGs (``images``: ``[{"title", "src"}]``); none without pyvista or for other
    suites.  A view that fails is left out with a log line: views never fail a run.
    """
    try:
        _pv()
    except UsageError:
        return []
    jobs = []
    if suite.study_set == "radiosity":
        from core.loader import load_scene

        seen = set()
        for case in suite.cases:
            if case.algorithm == "radiosity" and case.scene not in seen:
                seen.add(case.scene)
                jobs.append((f"{case.scene_id}: radiosity patches ({case.label})",
                             lambda c=case: view_scene(load_scene(c.scene), radiosity=True,
                                                       params=dict(c.params), size=size)))
    elif suite.study_set == "accel":
        from .studies.accel import sphere_field

        field = sphere_field(1000)
        jobs += [("1000-sphere field: SAH BVH, levels 1-4",
                  lambda: view_scene(field, accel="bvh-sah", depth=4, size=size)),
                 ("1000-sphere field: uniform grid, occupied cells",
                  lambda: view_scene(field, accel="grid", size=size))]
    images = []
    for title, job in jobs:
        try:
            imgs, info = job()
        except Exception as exc:          # a view is an illustration: log and go on
            if log:
                log(f"  view '{title}' skipped: {type(exc).__name__}: {exc}")
            continue
        images.append({"title": f"{title} ({info['seconds']:.1f} s)", "src": _data_uri(imgs[0])})
    if not images:
        return []
    return [Record(kind="study", study="views", suite=suite.name, title="3D views",
                   description="gibench view: the scene geometry, camera frustum and lights with "
                               "the structure or solution drawn in 3D (pyvista, off screen).",
                   images=images)]
