"""Studies of the polygon pipeline: shading error vs tessellation, z-fighting, visibility.

Each study returns its table as a list of flat dicts of scalars (every
parameter and every measured number in each row), like :mod:`gibench.studies.intersection`.

========================  ====================================================
study                     what it measures
========================  ====================================================
``shading_convergence``   error of flat / Gouraud / Phong shading of a
                          tessellated sphere against the exact per-pixel
                          Phong model on the analytic sphere (ray casting,
                          same parameters, shadows off), with triangle count
                          and render time, per mode × tessellation
``zfighting``             pixels where the farther of two nearly coplanar
                          surfaces wins, per depth format × near plane
``visibility``            agreement of the shape-id and depth AOVs of
                          ``zbuffer`` and ``depthsort`` with ray casting of
                          the same meshes, per scene
``highlights``            how much of the exact Phong highlight (k_s > 0)
                          each shading technique keeps: its peak and its
                          energy over the highlight, per mode × tessellation
                          (thesis 1.5.5: Gouraud loses highlights that fall
                          inside a polygon, Phong shading keeps them)
``scan_coherence``        operation counts of scan conversion with per-pixel
                          edge functions against scan-line spans with
                          incremental interpolation (thesis 1.2.1), and the
                          render time of each, per scene
``frame_coherence``       frame coherence along a short camera path (thesis
                          1.2.1): what of frame k is still valid in frame
                          k+1 — visible triangle per pixel, triangles past
                          the geometry stage, Gouraud vertices shaded — and
                          the time share of the tessellation every frame
                          could reuse
``visibility_growth``     render time of the z-buffer and of depth sort as
                          the triangle count grows (thesis 1.3: the
                          z-buffer's cost tends to be independent of the
                          number of objects, depth sort's grows faster),
                          the two timed in alternation, with the fraction
                          of pixels where their images agree
``mach_bands``            Mach-band strength (:func:`reports.metrics.mach_band`:
                          jump of the log-luminance slope across polygon
                          edges beyond the exact image's) per mode ×
                          tessellation, on edge pixels and, for comparison,
                          off them (thesis 1.5.3)
========================  ====================================================

Error metric of ``shading_convergence``: relMSE (ε = 0.01, linear radiance,
:func:`reports.metrics.relmse`) and the mean absolute relative error over
the pixels whose centre ray hits the sphere in both images and whose 3×3
neighbourhood is all sphere in the reference (silhouette pixels left out:
the inscribed polyhedron's outline is a geometry error, not a shading one).
Times are medians of ``repeats`` renders after an untimed warm-up.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np

from impl import depth_sort, raycast, zbuffer
from impl.raycast import cast_primary
from impl.tessellate import sphere_triangle_count, tessellated_scene
from reports.metrics import mach_band, relmse

from core.loader import load_scene
from core.provenance import REPO_ROOT
from core.errors import SuiteError

__all__ = ["STUDIES", "TABLES", "boundary_mask", "polygon_edges", "shading_convergence", "highlights",
           "mach_bands", "scan_coherence", "frame_coherence", "zfighting", "visibility",
           "visibility_growth", "image_agreement", "run_studies"]

SUITES = REPO_ROOT / "suites"
ALGORITHMS = {"zbuffer": zbuffer.ALGORITHM, "depthsort": depth_sort.ALGORITHM}


def _scene(scene):
    p = Path(scene)
    return load_scene(p if p.is_absolute() else SUITES / p)


def boundary_mask(shape_id: np.ndarray) -> np.ndarray:
    """Pixels whose 3×3 neighbourhood holds more than one shape id (silhouettes and shape borders)."""
    H, W = shape_id.shape
    p = np.pad(shape_id, 1, mode="edge")
    out = np.zeros((H, W), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= p[1 + dy:1 + dy + H, 1 + dx:1 + dx + W] != shape_id
    return out


def _timed(fn, repeats):
    fn()                                           # warm-up: JIT compilation, caches
    times = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def shading_convergence(*, scene="spheres/lit_sphere.xml", tessellations=(8, 16, 32, 64, 128),
                        modes=("flat", "gouraud", "phong"), algorithm="zbuffer", ks=0.0, shininess=32.0,
                        ka=0.0, ambient=0.0, repeats=3) -> list[dict]:
    """Rows (mode, tessellation, triangles, relmse, mean_rel_err, time_ms, pixels) per mode × tessellation."""
    sc = _scene(scene)
    phong = {"ks": ks, "shininess": shininess, "ka": ka, "ambient": ambient}
    rc = raycast.ALGORITHM
    exact = rc.render(sc, rc.parse_params(dict(phong, shadows=False)), seed=0).image.astype(np.float64)
    _, ref_id = cast_primary(sc)
    spheres = [i for i, s in enumerate(sc.shapes) if s.kind == "sphere"]
    if not spheres:
        raise SuiteError(f"shading_convergence: {scene} has no sphere")
    interior = np.isin(ref_id, spheres) & ~boundary_mask(ref_id)
    algo = ALGORITHMS[algorithm]
    rows = []
    for n in tessellations:
        for mode in modes:
            params = algo.parse_params(dict(phong, shading=mode, tessellation=n))
            res, t = _timed(lambda: algo.render(sc, params, seed=0), repeats)
            mask = interior & (res.aovs["shape_id"] == ref_id)
            img = res.image.astype(np.float64)
            ref_px, img_px = exact[mask][:, None, :], img[mask][:, None, :]
            scale = np.maximum(ref_px, 1e-3 * exact.max())
            rows.append({"scene": str(scene), "algorithm": algorithm, "mode": mode, "tessellation": int(n),
                         "triangles": sphere_triangle_count(n) * len(spheres), "ks": ks,
                         "relmse": float(relmse(ref_px, img_px)),
                         "mean_rel_err": float(np.mean(np.abs(img_px - ref_px) / scale)),
                         "time_ms": 1e3 * t, "pixels": int(mask.sum())})
    return rows


def _exact(sc, phong):
    """The exact per-pixel Phong model on the analytic scene (ray casting, shadows off, pixel
    centres) and the pixels whose 3×3 neighbourhood is all sphere: (image, shape ids, interior)."""
    rc = raycast.ALGORITHM
    exact = rc.render(sc, rc.parse_params(dict(phong, shadows=False)), seed=0).image.astype(np.float64)
    _, ref_id = cast_primary(sc)
    spheres = [i for i, s in enumerate(sc.shapes) if s.kind == "sphere"]
    if not spheres:
        raise SuiteError("the scene has no sphere")
    return exact, ref_id, np.isin(ref_id, spheres) & ~boundary_mask(ref_id)


def polygon_edges(flat_image: np.ndarray) -> np.ndarray:
    """Pixels next to a polygon edge: where a flat-shaded image (one colour per polygon)
    changes value between 4-neighbours.  Two adjacent polygons of equal colour are missed."""
    img = np.asarray(flat_image, dtype=np.float64)
    out = np.zeros(img.shape[:2], bool)
    dx = np.any(img[:, 1:] != img[:, :-1], axis=-1)
    dy = np.any(img[1:, :] != img[:-1, :], axis=-1)
    out[:, 1:] |= dx
    out[:, :-1] |= dx
    out[1:, :] |= dy
    out[:-1, :] |= dy
    return out


def highlights(*, scene="spheres/lit_sphere.xml", tessellations=(8, 16, 32, 64, 128),
               modes=("flat", "gouraud", "phong"), algorithm="zbuffer", ks=0.5, shininess=50.0,
               threshold=0.1) -> list[dict]:
    """Rows (mode, tessellation, peak_kept, energy_kept, relmse_highlight, highlight_pixels).

    The exact highlight is S = Y(exact with k_s) − Y(exact with k_s = 0) (luminance, ray
    casting of the analytic scene at pixel centres, shadows off); its region is the interior
    sphere pixels with S > ``threshold`` · max S.  For a shaded image I the highlight it shows
    is I_S = Y(I) − Y(exact with k_s = 0): ``peak_kept`` = max I_S / max S over the region,
    ``energy_kept`` = Σ I_S / Σ S, ``relmse_highlight`` the relMSE of the colour over the region.
    """
    sc = _scene(scene)
    if not ks > 0:
        raise SuiteError(f"highlights: ks must be > 0, got {ks}")
    phong = {"ks": ks, "shininess": shininess}
    exact, ref_id, interior = _exact(sc, phong)
    diffuse, _, _ = _exact(sc, {"ks": 0.0, "shininess": shininess})
    lum = np.array([0.2126, 0.7152, 0.0722])
    spec = (exact - diffuse) @ lum
    region = interior & (spec > threshold * spec[interior].max())
    algo = ALGORITHMS[algorithm]
    rows = []
    for n in tessellations:
        for mode in modes:
            res = algo.render(sc, algo.parse_params(dict(phong, shading=mode, tessellation=n)), seed=0)
            img = res.image.astype(np.float64)
            shown = (img - diffuse) @ lum
            rows.append({"scene": str(scene), "algorithm": algorithm, "mode": mode, "tessellation": int(n),
                         "ks": ks, "shininess": shininess,
                         "peak_kept": float(shown[region].max() / spec[region].max()),
                         "energy_kept": float(shown[region].sum() / spec[region].sum()),
                         "relmse_highlight": float(relmse(exact[region][:, None, :], img[region][:, None, :])),
                         "highlight_pixels": int(region.sum())})
    return rows


def mach_bands(*, scene="spheres/lit_sphere.xml", tessellations=(8, 16, 32, 64),
               modes=("flat", "gouraud", "phong"), algorithm="zbuffer", ks=0.0,
               shininess=32.0, lit_fraction=0.05) -> list[dict]:
    """Rows (mode, tessellation, mach_edge, mach_off_edge, edge_pixels) per mode × tessellation.

    ``mach_edge`` is :func:`reports.metrics.mach_band` of the shaded image (pixel centres)
    against the exact per-pixel model over the lit interior sphere pixels next to a polygon
    edge (:func:`polygon_edges` of the flat-shaded image of the same tessellation);
    ``mach_off_edge`` the same over the other lit interior sphere pixels.  *Lit*: the exact
    luminance exceeds ``lit_fraction`` of its maximum over the sphere in the pixel and its
    4-neighbours (near the terminator the coarse polyhedron moves the shadow line, a geometry
    error the log-contrast would magnify).
    """
    from scipy.ndimage import binary_erosion

    sc = _scene(scene)
    phong = {"ks": ks, "shininess": shininess}
    exact, ref_id, interior = _exact(sc, phong)
    lum = exact @ np.array([0.2126, 0.7152, 0.0722])
    interior = interior & binary_erosion(lum > lit_fraction * lum[interior].max(), iterations=1)
    algo = ALGORITHMS[algorithm]
    rows = []
    for n in tessellations:
        flat = algo.render(sc, algo.parse_params(dict(phong, shading="flat", tessellation=n)), seed=0)
        same = interior & (flat.aovs["shape_id"] == ref_id)
        edges = polygon_edges(flat.image) & same
        for mode in modes:
            res = (flat if mode == "flat" else
                   algo.render(sc, algo.parse_params(dict(phong, shading=mode, tessellation=n)), seed=0))
            rows.append({"scene": str(scene), "algorithm": algorithm, "mode": mode, "tessellation": int(n),
                         "ks": ks,
                         "mach_edge": mach_band(exact, res.image, mask=edges),
                         "mach_off_edge": mach_band(exact, res.image, mask=same & ~edges),
                         "edge_pixels": int(edges.sum())})
    return rows


#: Arithmetic operations per counted step of :mod:`impl.raster` (see its docstring):
#: a full edge-function evaluation (2 multiplications, 5 additions), a per-row span solve
#: (the row's constant: 2 multiplications, 5 additions; one division, one comparison), a
#: full interpolation of λ0, λ1, λ2, 1/z (9 multiplications, 14 additions), an incremental
#: step (3 additions).
OPS_PER = {"edge_evals": 7, "span_solves": 9, "interp_evals": 23, "interp_steps": 3}


def scan_coherence(*, scenes=("spheres/lit_sphere.xml", "cornell/cornell_point.xml", "spheres/meshes.xml"),
                   tessellation=64, spp=1, repeats=3) -> list[dict]:
    """Rows (scene, traversal, counters, arithmetic operations, time_ms, identical) per scene ×
    traversal.  ``ops`` weighs the counters with :data:`OPS_PER`; ``identical`` says whether
    the image equals the per-pixel traversal's."""
    algo = zbuffer.ALGORITHM
    rows = []
    for scene in scenes:
        sc = _scene(scene)
        base = None
        for tr in ("edge", "incremental"):
            params = algo.parse_params({"traversal": tr, "tessellation": tessellation, "spp": spp,
                                        "shading": "gouraud"})
            res, t = _timed(lambda: algo.render(sc, params, seed=0), repeats)
            c = res.counters
            base = res.image if base is None else base
            rows.append({"scene": str(scene), "traversal": tr, "fragments": c["fragments"],
                         "pixels_visited": c["pixels_visited"], "edge_evals": c["edge_evals"],
                         "span_solves": c["span_solves"], "interp_evals": c["interp_evals"],
                         "interp_steps": c["interp_steps"],
                         "ops": int(sum(OPS_PER[k] * c[k] for k in OPS_PER)),
                         "time_ms": 1e3 * t, "identical": bool(np.array_equal(res.image, base))})
    return rows


def image_agreement(a, b, tolerance=1e-4) -> float:
    """Fraction of pixels whose RGB values differ by at most ``tolerance`` in every channel."""
    diff = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max(axis=-1)
    return float(np.mean(diff <= tolerance))


def visibility_growth(*, scene="spheres/lit_sphere.xml", segments=(4, 12, 32, 100, 318), repeats=3,
                      tolerance=1e-4) -> list[dict]:
    """Rows (algorithm, segments, triangles, median/min/max seconds, µs per triangle,
    agree) per tessellation × rasteriser: the scene's sphere as a UV sphere of
    ``segments`` (10 … 1e5 triangles with the default), rendered by ``zbuffer`` and
    ``depthsort`` after an untimed warm-up, the two timed in turn ``repeats`` times
    (load drifts over both alike).  ``agree``: the fraction of pixels whose RGB differs
    by at most ``tolerance`` between the two images (the same visible surfaces).
    Wall-clock times of a shared machine: a measurement, never a test's pass condition."""
    sc = _scene(scene)
    rows = []
    for n in segments:
        params = {k: a.parse_params({"tessellation": int(n)}) for k, a in ALGORITHMS.items()}
        times = {k: [] for k in ALGORITHMS}
        out = {}
        for k, a in ALGORITHMS.items():
            out[k] = a.render(sc, params[k], seed=0)              # warm-up, and the image
        for _ in range(int(repeats)):
            for k, a in ALGORITHMS.items():
                t0 = time.perf_counter()
                a.render(sc, params[k], seed=0)
                times[k].append(time.perf_counter() - t0)
        agree = image_agreement(out["zbuffer"].image, out["depthsort"].image, tolerance)
        for k in ALGORITHMS:
            tris = int(out[k].counters.get("triangles_in", sphere_triangle_count(int(n)) + 2))
            med = statistics.median(times[k])
            rows.append({"algorithm": k, "segments": int(n), "triangles": tris, "repeats": int(repeats),
                         "median_s": med, "min_s": min(times[k]), "max_s": max(times[k]),
                         "us_per_triangle": 1e6 * med / tris, "agree": agree})
    return rows


def _turned(scene, degrees):
    """``scene`` with its camera turned about its own up axis by ``degrees``."""
    a = np.deg2rad(degrees)
    rot = np.eye(4)
    rot[0, 0], rot[0, 2], rot[2, 0], rot[2, 2] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    cam = dataclasses.replace(scene.camera, to_world=scene.camera.to_world @ rot)
    return dataclasses.replace(scene, camera=cam)


def frame_coherence(*, scene="cornell/cornell_point.xml", frames=8, step_deg=1.0, tessellation=64) -> list[dict]:
    """Rows per frame pair (k, k+1) of a camera turning ``step_deg`` per frame: fraction of
    pixels whose visible triangle is unchanged (``visible_same``, over pixels covered in either
    frame), Jaccard overlap of the triangles past the geometry stage (``survivors_same``),
    fraction of frame k+1's Gouraud vertex evaluations already made in frame k
    (``vertices_reused``: with k_s = 0 a vertex's diffuse shading does not depend on the
    view), and the time shares of frame k+1's stages (tessellation, geometry, raster, shading;
    tessellation is what a static scene never needs to redo)."""
    from impl.pipeline import camera_frame, geometry_stage
    from impl.raster import DEPTH_FLOAT32, rasterize
    from impl.scene_arrays import flatten
    from impl.shading import GOURAUD, PhongParams, resolve
    from impl.tessellate import scene_triangles

    base = _scene(scene)
    algo = zbuffer.ALGORITHM
    params = algo.parse_params({"tessellation": tessellation, "shading": "gouraud"})
    algo.render(base, params, seed=0)                    # warm-up (compilation)
    A = flatten(base)
    pp = PhongParams(params, 0)
    prev = None
    rows = []
    for k in range(frames):
        sc = _turned(base, k * step_deg)
        cam = sc.camera
        W, H = cam.film.width, cam.film.height
        t0 = time.perf_counter()
        soup = scene_triangles(sc, tessellation)
        t1 = time.perf_counter()
        scr = geometry_stage(soup, cam, cull=True, n_shapes=len(sc.shapes))
        t2 = time.perf_counter()
        vis, _ = rasterize(scr.xy, scr.cam[:, :, 2], W, H, depth_mode=DEPTH_FLOAT32, near=cam.near_clip,
                           far=cam.far_clip)
        t3 = time.perf_counter()
        _, eye = camera_frame(cam)
        resolve(GOURAUD, vis, scr, soup, eye, A, pp)
        t4 = time.perf_counter()
        src = np.where(vis.id >= 0, scr.src[np.maximum(vis.id, 0)], -1)
        survivors = set(np.unique(scr.src).tolist())
        verts = set(np.unique(soup.tri[np.unique(scr.src)]).tolist())
        if prev is not None:
            covered = (src >= 0) | (prev[0] >= 0)
            total = t4 - t0
            rows.append({"scene": str(scene), "frame": k, "step_deg": step_deg,
                         "visible_same": float(np.mean(src[covered] == prev[0][covered])),
                         "survivors_same": len(survivors & prev[1]) / max(len(survivors | prev[1]), 1),
                         "vertices_reused": len(verts & prev[2]) / max(len(verts), 1),
                         "tess_share": (t1 - t0) / total, "geometry_share": (t2 - t1) / total,
                         "raster_share": (t3 - t2) / total, "shading_share": (t4 - t3) / total,
                         "frame_ms": 1e3 * total})
        prev = (src, survivors, verts)
    return rows


def zfighting(*, scene="spheres/coplanar.xml", nears=(1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0), far=None,
              depths=("float32", "fixed24", "fixed16")) -> list[dict]:
    """Rows (depth, near, far, fight_pixels, fight_frac, predicted_dz_max) per depth format × near plane.

    The scene's shapes are drawn in file order (farther surface first); a
    *z-fighting pixel* is one whose pixel-centre ray hits the nearer surface
    (ray casting) but the z-buffer keeps the farther one.  ``predicted_dz_max``
    is the depth resolution at the largest visible distance z_max,
    Δz ≈ z_max² (f − n) / (f n) · δ_w with δ_w the buffer's step (2⁻²⁴ relative
    near 1 for float32, 1/(2^b − 1) for b-bit fixed point).
    """
    base = _scene(scene)
    algo = zbuffer.ALGORITHM
    rows = []
    for near in nears:
        cam = dataclasses.replace(base.camera, near_clip=float(near),
                                  far_clip=float(far) if far is not None else base.camera.far_clip)
        sc = dataclasses.replace(base, camera=cam)
        depth_rc, ref_id = cast_primary(sc)
        zmax = float(np.max(depth_rc[np.isfinite(depth_rc)]))
        nearer = ref_id == len(sc.shapes) - 1       # the last shape: the nearer surface
        for fmt in depths:
            res = algo.render(sc, algo.parse_params({"depth": fmt, "shading": "flat"}), seed=0)
            fight = nearer & (res.aovs["shape_id"] != ref_id)
            step = {"float32": 2.0 ** -24, "fixed24": 1.0 / (2 ** 24 - 1), "fixed16": 1.0 / (2 ** 16 - 1)}[fmt]
            f, n = cam.far_clip, cam.near_clip
            rows.append({"scene": str(scene), "depth": fmt, "near": float(near), "far": float(f),
                         "fight_pixels": int(fight.sum()), "nearer_pixels": int(nearer.sum()),
                         "fight_frac": float(fight.sum() / max(nearer.sum(), 1)),
                         "predicted_dz_max": zmax ** 2 * (f - n) / (f * n) * step})
    return rows


def visibility(*, scenes=("spheres/lit_sphere.xml", "spheres/spot_directional.xml", "spheres/meshes.xml",
                          "cornell/cornell_point.xml", "cornell/cornell_box.xml", "spheres/cyclic_overlap.xml",
                          "spheres/interpenetrating.xml"),
               algorithms=("zbuffer", "depthsort"), tessellation=64, cull=True) -> list[dict]:
    """Rows (scene, algorithm, identical, identical_off_boundary, depth_max_rel, depth_frac_1e-4) against
    ray casting of the same tessellated scene at pixel centres."""
    rows = []
    for scene in scenes:
        sc = _scene(scene)
        d_rc, id_rc = cast_primary(tessellated_scene(sc, tessellation))
        inner = ~boundary_mask(id_rc)
        for name in algorithms:
            algo = ALGORITHMS[name]
            res = algo.render(sc, algo.parse_params({"tessellation": tessellation, "cull": cull}), seed=0)
            same = res.aovs["shape_id"] == id_rc
            both = same & np.isfinite(d_rc)
            rel = np.abs(res.aovs["depth"][both] - d_rc[both]) / d_rc[both]
            rows.append({"scene": str(scene), "algorithm": name, "tessellation": tessellation, "cull": cull,
                         "identical": float(same.mean()), "identical_off_boundary": float(same[inner].mean()),
                         "depth_max_rel": float(rel.max()) if rel.size else 0.0,
                         "depth_frac_1e-4": float(np.mean(rel <= 1e-4)) if rel.size else 1.0,
                         "splits": int(res.counters.get("splits", 0))})
    return rows


#: name → (title, description, function)
STUDIES = {
    "shading_convergence": ("Shading error vs tessellation",
                            "Flat, Gouraud and Phong shading of a UV-sphere mesh against the exact per-pixel "
                            "Phong model on the analytic sphere (ray casting, shadows off): relMSE and mean "
                            "relative error over interior sphere pixels, triangles and render time (thesis 1.5).",
                            shading_convergence),
    "highlights": ("Highlights kept by each shading technique",
                   "Share of the exact Phong highlight (k_s > 0, ray casting of the analytic sphere) that "
                   "flat, Gouraud and Phong shading keep: peak and energy over the highlight, per "
                   "tessellation (thesis 1.5.5: Gouraud loses a highlight inside a polygon).",
                   highlights),
    "mach_bands": ("Mach bands vs shading technique and tessellation",
                   "Excess curvature of log-luminance over the exact image, on pixels at polygon edges "
                   "and off them: the slope jumps the eye sees as Mach bands (thesis 1.5.3).",
                   mach_bands),
    "scan_coherence": ("Scan conversion: per-pixel edge functions vs scan-line coherence",
                       "Pixels visited, edge-function evaluations, span solves, full and incremental "
                       "interpolations, weighted arithmetic operations and time of the two traversals "
                       "of impl.raster, and whether the images are identical (thesis 1.2.1).",
                       scan_coherence),
    "frame_coherence": ("Frame coherence along a camera path",
                        "Consecutive frames of a turning camera: share of pixels with the same visible "
                        "triangle, of triangles past the geometry stage, of Gouraud vertices already "
                        "shaded, and the time share of each pipeline stage (thesis 1.2.1).",
                        frame_coherence),
    "visibility_growth": ("Z-buffer vs depth sort as the triangle count grows",
                          "Median wall-clock render time of zbuffer and depthsort on a UV-sphere mesh of 10 … "
                          "1e5 triangles, the two timed in alternation, µs per triangle, and the fraction of "
                          "pixels where their images agree (thesis 1.3: the z-buffer's cost tends to be "
                          "independent of the number of objects; depth sort's sort and overlap tests grow "
                          "faster).  Shared-machine timings: a measurement, not a check.",
                          visibility_growth),
    "zfighting": ("Z-fighting vs near plane and depth format",
                  "Two surfaces 0.01 apart seen at a slant: pixels where the z-buffer keeps the farther one, "
                  "per depth format (float32, 24- and 16-bit fixed point) and near clip distance (thesis 1.3.1).",
                  zfighting),
    "visibility": ("Visibility against ray casting",
                   "Shape id and depth at pixel centres of zbuffer and depthsort against ray casting the same "
                   "meshes (thesis 1.3.1, 1.3.2, 1.3.3).",
                   visibility),
}
TABLES = {k: v[:2] for k, v in STUDIES.items()}


def run_studies(config: dict | str | Path | None = None, *, only=None) -> dict[str, list[dict]]:
    """Run the studies: ``config`` maps a study name to its keyword arguments
    (default: every study with its defaults), or is a TOML file of such tables
    (``suites/visibility/studies.toml``); ``{"enabled": False}`` skips one."""
    if isinstance(config, (str, Path)):
        import tomllib

        config = tomllib.loads(Path(config).read_text())
    config = {k: {} for k in STUDIES} if config is None else config
    out = {}
    for name, kwargs in config.items():
        if name not in STUDIES:
            raise SuiteError(f"unknown study '{name}' (valid: {', '.join(STUDIES)})")
        kwargs = dict(kwargs)
        if not kwargs.pop("enabled", True) or (only is not None and name not in only):
            continue
        out[name] = STUDIES[name][2](**kwargs)
    return out
