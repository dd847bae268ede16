"""The z-buffer visible-surface algorithm — registered as ``zbuffer``.

Thesis 1.3.1 (image precision): every polygon is scan-converted and a pixel
takes a fragment's colour when the fragment is nearer than the depth stored
for that pixel.  The polygons pass first through the geometry stage of
:mod:`impl.pipeline` (view transform, bounding-volume rejection, back-face
culling, extents, near/far clipping, projection; thesis 1.1, 1.2.2, 1.2.3),
are scan-converted by :mod:`impl.raster` (top-left fill rule,
perspective-correct interpolation) and shaded flat, Gouraud or Phong
(:mod:`impl.shading`, thesis 1.5) with the Phong model of ray casting, local
illumination only (no shadows).  Spheres are drawn as UV spheres of
``tessellation`` segments (:mod:`impl.tessellate`).

Depth buffer: window depth z_w = f/(f − n)(1 − n/z) as float32 or as 24- or
16-bit fixed point (``depth``); the strict test keeps the first of two
fragments with equal stored depth, so nearly coplanar surfaces "z-fight" when
their depth difference is below the buffer's resolution at that distance,
Δz ≈ z² / (n · 2^bits) (see :func:`gibench.studies.shading.zfighting`).

Pixel sampling: ``spp = 1`` samples pixel centres (the eye rays of
:func:`impl.camera.eye_ray`); ``spp = k²`` renders a k×k regular grid of
samples per pixel (a film k times larger, same camera) and averages it (box
filter).  The ``depth`` and ``shape_id`` AOVs are always at pixel centres
(an extra visibility pass when spp > 1): distance from the eye along the
pixel-centre ray (inf on a miss, comparable with
:func:`impl.raycast.cast_primary`) and the shape index (-1 on a miss).

Counters: ``triangles_in``, ``rejected_bv`` (whole shapes outside the
frustum), ``culled``, ``rejected`` (outcodes), ``clipped``,
``triangles_out``, ``fragments`` (covered samples), ``depth_passed``,
``shading_evaluations``.

Normal and bump maps (Mitsuba's ``normalmap`` and ``bumpmap`` around a diffuse
BSDF, on triangles with uvs) with ``shading=phong``: the model is taken about
the perturbed normal at each pixel, as ray casting takes it at its hits
(:func:`impl.lighting.local_shading`); flat and Gouraud shading refuse them.

Leaves out: shadows, transparency, texture filtering, the far-plane and
side clipping of hardware (a guard band instead), hierarchical z.  Materials
other than ``diffuse`` raise ``NotImplementedError``.

Parameters
----------
=============  ======  ========  =============================================
name           type    default   meaning
=============  ======  ========  =============================================
spp            int     1         1 = pixel centres, k² = k×k grid, box filter
shading        str     phong     flat | gouraud | phong
tessellation   int     64        segments around a sphere (N//2 rings)
depth          str     float32   float32 | fixed24 | fixed16 depth buffer
cull           bool    true      back-face culling
traversal      str     edge      edge | incremental (scan-line coherence, :mod:`impl.raster`)
light_samples  int     16        samples per area emitter per evaluation
ka, ambient    float   0, 0      ambient k_a, I_a
ks, shininess  float   0, 32     specular k_s, Phong exponent n
c1, c2, c3     float   0, 0, 1   f_att = 1 / (c1 + c2 d + c3 d²)
fatt_clamp     bool    false     clamp f_att to 1
=============  ======  ========  =============================================
"""

from __future__ import annotations

import numpy as np

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene, scene_features
from core.errors import ParamError, UnsupportedError

from .pipeline import ScreenTriangles, camera_frame, geometry_stage
from .raster import DEPTH_MODES, TRAVERSALS, VisibilityBuffer, rasterize
from .phong import PHONG_PARAMS
from .sampling import check_spp
from .scene_arrays import flatten
from .shading import SHADING_MODES, PhongParams, resolve
from .tessellate import TriangleSoup, scene_triangles

__all__ = ["render", "render_polygons", "pixel_centre_aovs", "zbuffer_visibility", "PARAMS", "ALGORITHM"]


def _check(scene: Scene, params: dict, algorithm: str) -> int:
    k = check_spp(params["spp"], algorithm)
    if params["tessellation"] < 3:
        raise ParamError(f"{algorithm}: tessellation must be >= 3 segments, got {params['tessellation']}")
    for shape in scene.shapes:
        m = scene.materials[shape.material]
        if m.kind != "diffuse":
            raise UnsupportedError(
                f"{algorithm}: shape '{shape.name or shape.source}' has a '{m.kind}' BSDF; local Phong "
                "illumination models diffuse surfaces only")
    if params["shading"] != "phong":
        features = scene_features(scene)
        for name in ("normalmap", "bumpmap"):
            if name in features:
                raise UnsupportedError(
                    f"{algorithm}: {features[name]} uses '{name}', which shading={params['shading']} "
                    f"cannot show (it evaluates the model {_WHERE[params['shading']]}, not per pixel); "
                    "use shading=phong")
    return k


#: Where flat and Gouraud shading evaluate the illumination model.
_WHERE = {"flat": "once per polygon", "gouraud": "at the vertices"}


def zbuffer_visibility(scr: ScreenTriangles, scene: Scene, width: int, height: int, params: dict):
    """Z-buffer visibility of the screen triangles in input order: (visibility buffer, triangles, counters)."""
    cam = scene.camera
    vis, counters = rasterize(scr.xy, scr.cam[:, :, 2], width, height, depth_mode=DEPTH_MODES[params["depth"]],
                              near=cam.near_clip, far=cam.far_clip,
                              traversal=TRAVERSALS[params["traversal"]])
    return vis, scr, counters


def _aovs(vis: VisibilityBuffer, scr: ScreenTriangles, soup: TriangleSoup, scene: Scene) -> dict:
    cam = scene.camera
    H, W = vis.id.shape
    tx = cam.tan_half_fov_x
    cx = (1.0 - 2.0 * (np.arange(W) + 0.5) / W)[None, :] * tx
    cy = (1.0 - 2.0 * (np.arange(H) + 0.5) / H)[:, None] * tx / cam.film.aspect
    hit = vis.id >= 0
    # Distance along the pixel-centre ray = z_cam · |(cx, cy, 1)|.
    depth = np.full((H, W), np.inf)
    depth[hit] = (np.sqrt(cx ** 2 + cy ** 2 + 1.0) / np.where(hit, vis.invz, 1.0))[hit]
    shape_id = np.full((H, W), -1, np.int64)
    shape_id[hit] = soup.tri_shape[scr.src[vis.id[hit]]]
    return {"depth": depth, "shape_id": shape_id}


def pixel_centre_aovs(scene: Scene, params: dict, visibility=zbuffer_visibility) -> dict:
    """The ``depth`` and ``shape_id`` AOVs at pixel centres (no shading)."""
    soup = scene_triangles(scene, params["tessellation"])
    f = scene.camera.film
    scr = geometry_stage(soup, scene.camera, cull=params["cull"], n_shapes=len(scene.shapes))
    vis, scr, _ = visibility(scr, scene, f.width, f.height, params)
    return _aovs(vis, scr, soup, scene)


def render_polygons(scene: Scene, params: dict, *, seed: int, algorithm: str, visibility) -> RenderResult:
    """Geometry stage → ``visibility`` (z-buffer or depth sort) → shading → box filter."""
    k = _check(scene, params, algorithm)
    cam = scene.camera
    W, H = cam.film.width, cam.film.height
    soup = scene_triangles(scene, params["tessellation"])
    A = flatten(scene)
    _, eye = camera_frame(cam)
    scr = geometry_stage(soup, cam, cull=params["cull"], n_shapes=len(scene.shapes), width=k * W, height=k * H)
    counters = dict(scr.counters)
    vis, scr, vc = visibility(scr, scene, k * W, k * H, params)
    counters.update(vc)
    image, sc = resolve(SHADING_MODES[params["shading"]], vis, scr, soup, eye, A, PhongParams(params, seed))
    counters.update(sc)
    variance = None
    if k > 1:
        grid = image.reshape(H, k, W, k, 3).astype(np.float64)
        image = grid.mean(axis=(1, 3))
        # Spread of the k² grid samples as if they were independent: sample variance / k².
        # The grid is deterministic, so this is not the variance of a random estimate but the
        # size of its quadrature error's usual bound, which lets the Z-test judge the grid.
        variance = (grid.var(axis=(1, 3), ddof=1) / (k * k)).astype(np.float32)
        aovs = pixel_centre_aovs(scene, params, visibility)
    else:
        aovs = _aovs(vis, scr, soup, scene)
    return RenderResult(image=image.astype(np.float32), variance=variance, counters=counters, aovs=aovs)


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    return render_polygons(scene, params, seed=seed, algorithm="zbuffer", visibility=zbuffer_visibility)


#: The scene features ``zbuffer`` and ``depthsort`` model (:func:`core.scene.scene_features`):
#: normal and bump maps over diffuse triangles with uvs, per pixel (``shading=phong``).
MODELS = frozenset({"normalmap", "bumpmap"})

#: Parameters shared by ``zbuffer`` and ``depthsort``.
PARAMS = (
    Param("spp", int, 1, "pixel samples: 1 = pixel centre, k² = k×k regular grid (box filter)"),
    Param("shading", str, "phong", "shading technique (thesis 1.5)", choices=tuple(SHADING_MODES)),
    Param("tessellation", int, 64, "segments around a sphere (N//2 rings)"),
    Param("cull", bool, True, "back-face culling (thesis 1.2.3)"),
    Param("traversal", str, "edge", "scan conversion: per-pixel edge functions or scan-line spans with "
          "incremental interpolation (thesis 1.2.1)", choices=tuple(TRAVERSALS)),
    Param("light_samples", int, 16, "samples per area emitter per shading evaluation"),
    *PHONG_PARAMS,
)

ALGORITHM = Algorithm(
    name="zbuffer",
    summary="Z-buffer rasterisation with flat/Gouraud/Phong shading (local illumination, no shadows)",
    section="thesis 1.1, 1.2.2, 1.2.3, 1.3.1, 1.5",
    transport="direct",
    params=PARAMS[:5] + (Param("depth", str, "float32", "depth buffer format", choices=tuple(DEPTH_MODES)),)
    + PARAMS[5:],
    render=render,
    models=MODELS,
)
