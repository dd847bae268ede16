"""Acceleration-structure studies (thesis 2.6): scaling with scene size.

=============  ==============================================================
study          what it measures
=============  ==============================================================
``scaling``    per structure × scene size: build time, Whitted render and
               trace time, primitive tests and nodes visited per camera
               ray, memory — on N random spheres (N = 10 … 1e5) and on
               tessellated meshes (up to 1e6 triangles)
``node_cost``  ns per node visited by camera rays through a tree vs N, with
               two controls: one pixel tile's rays repeated (tree in
               cache) and the tree's nodes shuffled in memory
``scaling_fit``  per structure × scene family: the exponent k of a
               least-squares fit trace_s ∝ N^k (log–log), next to the
               exponent of log N over the same sizes (what a logarithmic
               structure should not exceed) and of tests per ray
``grid_knobs`` the uniform grid's knobs of thesis 2.6.2 (resolution,
               mailboxing, the current-voxel rule): per setting, voxels and
               primitive tests per ray for camera and bounce rays, hits that
               differ from brute force, pixels that differ from the exact
               grid's Whitted image, and the render's phases
=============  ==============================================================

Scenes are generated in code with a fixed seed (nothing is written to disk):

* ``spheres`` — N spheres, centres uniform in [-1, 1]³, radius
  0.3·N^(-1/3) (constant fill fraction, so the number of spheres along a ray
  is the same at every N), diffuse with one in five a mirror, a floor
  quad, one point light; camera outside the cube.
* ``mesh`` — five UV-sphere meshes (:func:`impl.tessellate.uv_sphere`) of
  N/5 triangles each (one a mirror) on the floor, same light and camera.

Times are wall-clock on whatever machine runs the study (median of
``repeats``), after one untimed warm-up render per structure that compiles
the kernels.  ``render_s`` is the whole Whitted render (flatten, build,
trace) of a fresh copy of the scene each time (the tracers remember a
scene's flattened arrays and ray configuration per scene object, so a copy
makes each render pay its setup); ``setup_s`` and ``trace_s`` are that
render's own phases (:attr:`core.algorithm.RenderResult.timings`: flatten,
configuration and allocation; the ray tracing itself, fitted against N);
``build_s`` the time of :func:`impl.rays.ray_config` alone (which builds the
structure).  ``primary_query_s`` times that pass alone (closest hits of
the pixel-centre camera rays, :func:`impl.accel.trace_batch`); ``tests_per_ray`` and ``nodes_per_ray``
come from it too: a separate counting pass over the camera's pixel-centre rays
(:func:`impl.accel.trace_batch`), not from the timed render.  Brute force
runs only up to ``brute_max`` primitives (it grows as N).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from core.errors import SuiteError
from core.provenance import REPO_ROOT
from core.scene import Camera, Film, Light, Material, Scene, Shape
from core.transforms import look_at

from . import StudyInfo, as_config, read_config, run_registered, table_titles

__all__ = ["STUDIES", "TABLES", "DEFAULT_CONFIG", "load_config", "run_studies", "scaling",
           "fit_exponents", "node_cost", "grid_knobs", "shuffle_node_groups", "sphere_field", "mesh_field", "camera_rays", "bounce_rays"]

DEFAULT_CONFIG = REPO_ROOT / "suites" / "scaling" / "studies.toml"


# ================================================================== scenes ===

def _camera(width, height):
    return Camera(to_world=look_at([2.6, 1.9, 3.4], [0.0, -0.1, 0.0], [0.0, 1.0, 0.0]), fov=45.0,
                  film=Film(width=width, height=height, rfilter="box"), sample_count=1)


def _floor(material):
    v = np.array([[-3.0, -1.05, -3.0], [3.0, -1.05, -3.0], [3.0, -1.05, 3.0], [-3.0, -1.05, 3.0]])
    return Shape("mesh", material, name="floor", source="rectangle", vertices=v,
                 faces=np.array([[0, 2, 1], [0, 3, 2]]))


def _materials():
    return [Material("diffuse", (0.7, 0.4, 0.3), name="red"),
            Material("diffuse", (0.6, 0.6, 0.6), name="grey"),
            Material("conductor", (1.0, 1.0, 1.0), params={"material": "none"}, name="mirror")]


def _light():
    return Light("point", np.array([40.0, 40.0, 40.0]), position=np.array([2.0, 4.0, 3.0]), name="key")


def sphere_field(n: int, *, seed: int = 0, width: int = 64, height: int = 48) -> Scene:
    """N random spheres in [-1, 1]³ (radius 0.3·N^(-1/3)), one in five a mirror."""
    if n < 1:
        raise SuiteError(f"sphere_field: n must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1.0, 1.0, (n, 3))
    r = 0.3 * n ** (-1.0 / 3.0)
    shapes = [Shape("sphere", 2 if i % 5 == 4 else 0, name=f"s{i}", source="sphere",
                    center=centres[i], radius=r) for i in range(n)]
    shapes.append(_floor(1))
    return Scene(Path(f"<generated spheres N={n}>"), _camera(width, height), shapes, _materials(), [_light()])


def mesh_field(n_triangles: int, *, width: int = 64, height: int = 48) -> Scene:
    """Five tessellated spheres of about N/5 triangles each (the middle one a mirror)."""
    from impl.tessellate import uv_sphere

    if n_triangles < 40:
        raise SuiteError(f"mesh_field: n_triangles must be >= 40, got {n_triangles}")
    seg = max(3, int(round(math.sqrt(n_triangles / 5.0))))     # uv_sphere(n) has ~n² triangles
    spots = [(-0.6, -0.55, -0.6, 0.45), (0.6, -0.55, -0.6, 0.45), (0.0, -0.35, 0.0, 0.65),
             (-0.6, -0.55, 0.6, 0.45), (0.6, -0.55, 0.6, 0.45)]
    shapes = []
    for i, (x, y, z, r) in enumerate(spots):
        v, f = uv_sphere([x, y, z], r, seg)
        shapes.append(Shape("mesh", 2 if i == 2 else 0, name=f"m{i}", source="generated",
                            vertices=v, faces=f))
    shapes.append(_floor(1))
    return Scene(Path(f"<generated mesh N~{n_triangles}>"), _camera(width, height), shapes, _materials(), [_light()])


FAMILIES = {"spheres": sphere_field, "mesh": mesh_field}


# ==================================================================== rays ===

def camera_rays(scene: Scene):
    """Pixel-centre eye rays ``(origins (N, 3), directions (N, 3))`` of the scene's camera."""
    cam = scene.camera
    W, H = cam.film.width, cam.film.height
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    tx = cam.tan_half_fov_x
    d = np.stack(np.broadcast_arrays((1 - 2 * u)[None, :] * tx, (1 - 2 * v)[:, None] * tx / cam.film.aspect,
                                     np.ones((H, W))), axis=-1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d @ cam.to_world[:3, :3].T
    return np.broadcast_to(cam.origin, d.shape).copy(), np.ascontiguousarray(d)


def bounce_rays(A, o, d, t, prim, *, seed: int = 0):
    """Incoherent rays: at each hit of the rays (o, d) (``prim`` ≥ 0), a cosine-
    distributed direction about the normal facing the ray, from the hit point
    offset by 1e-6·(1 + |p|) along that normal.  ``(origins, directions)``."""
    keep = prim >= 0
    o, d, t, prim = o[keep], d[keep], t[keep], prim[keep]
    p = o + t[:, None] * d
    ns = len(A.sph_radius)
    n = np.empty_like(p)
    s = prim < ns
    n[s] = (p[s] - A.sph_center[prim[s]]) / A.sph_radius[prim[s], None]
    tv = A.tri_v[prim[~s] - ns]
    n[~s] = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= -np.sign(np.einsum("ij,ij->i", n, d))[:, None]
    rng = np.random.default_rng(seed)
    # Malley's method: uniform on the unit disc, lifted to the hemisphere (pdf cos θ/π).
    u1, u2 = rng.random(len(p)), rng.random(len(p))
    rad, phi = np.sqrt(u1), 2.0 * np.pi * u2
    local = np.stack([rad * np.cos(phi), rad * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0))], 1)
    # Frame (s, t, n) about each normal (Duff et al. 2017).
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s_ax = np.stack([1 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], 1)
    t_ax = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    dirs = local[:, :1] * s_ax + local[:, 1:2] * t_ax + local[:, 2:] * n
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    orig = p + 1e-6 * (1 + np.abs(p).max(axis=1, keepdims=True)) * n
    return np.ascontiguousarray(orig), np.ascontiguousarray(dirs)


# ================================================================= scaling ===

def _median_time(fn, repeats):
    times = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def _timed_renders(algo, scene, params, repeats):
    """``(render_s, result, phases)``: medians over ``repeats`` renders of fresh shallow
    copies of ``scene`` (so none reuses a remembered setup) of the wall time and of each
    phase in :attr:`RenderResult.timings`; ``result`` is the last render."""
    import copy

    walls, phases, res = [], {}, None
    for _ in range(repeats):
        fresh = copy.copy(scene)
        t0 = time.perf_counter()
        res = algo.render(fresh, params)
        walls.append(time.perf_counter() - t0)
        for k, v in res.timings.items():
            phases.setdefault(k, []).append(v)
    return float(np.median(walls)), res, {k: float(np.median(v)) for k, v in phases.items()}


def scaling(*, families=("spheres", "mesh"), sizes=None, structures=None, width=64, height=48,
            brute_max=20000, repeats=3, max_depth=3, time_limit_s=120.0, log=print) -> list[dict]:
    """Whitted renders of generated scenes of growing size with every structure.

    ``sizes``: ``{family: [N, ...]}``; ``structures``: names of :data:`impl.accel.ACCELS`.
    A structure whose render exceeds ``time_limit_s`` is not run at larger N of that
    family (the row says so in ``note``)."""
    from impl import accel
    from impl.rays import ray_config, structure
    from impl.scene_arrays import flatten

    from .. import registry

    algo = registry.get("whitted")
    sizes = sizes or {"spheres": [10, 100, 1000, 10000, 100000], "mesh": [1000, 10000, 100000, 1000000]}
    structures = list(structures or accel.ACCELS)
    unknown = sorted(set(structures) - set(accel.ACCELS)) + sorted(set(families) - set(FAMILIES))
    if unknown:
        raise SuiteError(f"scaling: unknown structure or family {', '.join(unknown)} "
                         f"(structures: {', '.join(accel.ACCELS)}; families: {', '.join(FAMILIES)})")
    rows = []
    for fam in families:
        make = FAMILIES[fam]
        stopped = set()
        warm = make(min(sizes[fam]), width=8, height=6)
        for name in structures:                                   # compile outside the timings
            algo.render(warm, algo.parse_params({"accel": name, "max_depth": max_depth}))
        for N in sizes[fam]:
            scene = make(N, width=width, height=height)
            t0 = time.perf_counter()
            A = flatten(scene)
            flatten_s = time.perf_counter() - t0
            n_prims = len(A.sph_radius) + len(A.tri_v)
            o, d = camera_rays(scene)
            for name in structures:
                row = {"family": fam, "N": int(N), "prims": int(n_prims), "accel": name}
                if name == "none" and n_prims > brute_max:
                    rows.append({**row, "note": f"skipped: brute force beyond brute_max={brute_max}"})
                    continue
                if name in stopped:
                    rows.append({**row, "note": f"skipped: a smaller N exceeded {time_limit_s} s"})
                    continue
                params = algo.parse_params({"accel": name, "max_depth": max_depth})
                reps = repeats if n_prims <= 100000 else 1
                config_s, R = _median_time(lambda: ray_config(A, params, algorithm="whitted"), reps)
                acc_arrays = structure(R)
                render_s, res, phases = _timed_renders(algo, scene, params, reps)
                query_s, (_, prim, _, counts) = _median_time(lambda: accel.trace_batch(R, o, d), reps)
                rays = sum(res.counters.get(k, 0) for k in
                           ("eye_rays", "shadow_rays", "reflection_rays", "transmission_rays"))
                n_nodes = int(counts[:, 0].sum())
                row.update(build_s=config_s, render_s=render_s,
                           setup_s=phases["setup_s"], trace_s=phases["trace_s"], flatten_s=flatten_s,
                           primary_query_s=query_s,
                           query_ns_per_ray=query_s / len(o) * 1e9,
                           query_ns_per_node=query_s / n_nodes * 1e9 if n_nodes else float("nan"),
                           tests_per_ray=float(counts[:, 1].mean()),
                           nodes_per_ray=float(counts[:, 0].mean()),
                           memory_mb=accel.memory_bytes(acc_arrays) / 1e6,
                           hit_frac=float((prim >= 0).mean()), rays=int(rays),
                           image_mean=float(res.image.mean()))
                rows.append(row)
                log(f"  scaling {fam} N={N} {name}: build {config_s:.3f}s render {render_s:.3f}s "
                    f"tests/ray {row['tests_per_ray']:.1f}")
                if render_s > time_limit_s:
                    stopped.add(name)
    return rows


def _fit_ln(n, y):
    """Least squares y = a + b·ln N (``n`` = ln N): ``(a, b, R²)``."""
    y = np.asarray(y, dtype=np.float64)
    b, a = np.polyfit(n, y, 1)
    resid = y - (a + b * n)
    r2 = float(1.0 - resid.var() / y.var()) if y.var() > 0 else float("nan")
    return float(a), float(b), r2


# =============================================================== node cost ===

def shuffle_node_groups(R, rng):
    """The ray configuration R with its tree's nodes moved in memory: the sibling groups
    (the root alone, then each interior node's consecutive children) placed in random
    order, links renumbered.  The same tree — same answers, same nodes visited — with
    the builder's depth-first locality destroyed: the control for layout effects."""
    na, nb = np.asarray(R.node_a), np.asarray(R.node_b)
    n = len(na)
    inner = np.flatnonzero(nb < 0)
    starts = np.concatenate([[0], na[inner]])
    sizes = np.concatenate([[1], -nb[inner]])
    order = np.concatenate([[0], 1 + rng.permutation(len(inner))])
    new_start = np.empty(len(starts), dtype=np.int64)
    new_start[order] = np.concatenate([[0], np.cumsum(sizes[order])[:-1]])
    new_of = np.empty(n, dtype=np.int64)
    for g in range(len(starts)):
        new_of[starts[g]:starts[g] + sizes[g]] = new_start[g] + np.arange(sizes[g])
    if np.unique(new_of).size != n:
        raise ValueError("shuffle_node_groups: the sibling groups do not partition the nodes")
    lo, hi = np.empty_like(R.node_lo), np.empty_like(R.node_hi)
    a, b = np.empty_like(na), np.empty_like(nb)
    lo[new_of], hi[new_of], b[new_of] = R.node_lo, R.node_hi, nb
    a[new_of] = np.where(nb < 0, new_of[np.clip(na, 0, n - 1)], na)
    return R._replace(node_lo=lo, node_hi=hi, node_a=a, node_b=b)


def node_cost(*, sizes=(1000, 3000, 10000, 30000, 100000), structure="bvh-sah", width=256,
              height=192, tile=16, repeats=9, threads=1, seed=1, log=print) -> list[dict]:
    """Cost per node visited of the camera-ray closest-hit query (:func:`impl.accel.trace_batch`)
    on sphere fields of growing N, and two controls on the same tree (is the
    growth of trace time beyond log N a memory effect?):

    * ``full`` — the pixel-centre rays of the whole image;
    * ``tile`` — the rays of one ``tile``×``tile`` pixel block at the image centre,
      repeated to the same ray count: the nodes they visit stay in cache;
    * ``shuffled`` — the whole image through the tree with its sibling groups in
      random memory order (:func:`shuffle_node_groups`).

    Time is the median of ``repeats`` after one warm-up, with numba limited to
    ``threads`` threads (1: no contention for the shared caches).  ns per node is the
    query time over the nodes visited (per-ray costs included)."""
    import numba

    from impl import accel
    from impl.rays import ray_config
    from impl.scene_arrays import flatten

    from .. import registry

    if structure not in ("bvh-median", "bvh-sah", "bvh-gs", "octree"):
        raise SuiteError(f"node_cost: structure must be a tree (bvh-median, bvh-sah, bvh-gs, "
                         f"octree), got {structure!r}")
    if not (1 <= tile <= min(width, height)):
        raise SuiteError(f"node_cost: tile must be in 1..{min(width, height)}, got {tile}")
    algo = registry.get("whitted")
    params = algo.parse_params({"accel": structure})
    rng = np.random.default_rng(seed)
    before = numba.get_num_threads()
    numba.set_num_threads(min(int(threads), numba.config.NUMBA_NUM_THREADS))
    rows = []
    try:
        for N in sizes:
            scene = sphere_field(int(N), width=width, height=height)
            A = flatten(scene)
            R = ray_config(A, params, algorithm="node_cost")
            o, d = camera_rays(scene)
            y0, x0 = (height - tile) // 2, (width - tile) // 2
            pix = ((y0 + np.arange(tile))[:, None] * width + (x0 + np.arange(tile))[None, :]).ravel()
            reps = max(1, len(o) // len(pix))
            cases = {"full": (R, o, d),
                     "tile": (R, np.tile(o[pix], (reps, 1)), np.tile(d[pix], (reps, 1))),
                     "shuffled": (shuffle_node_groups(R, rng), o, d)}
            ref = None
            for case, (RR, oo, dd) in cases.items():
                t, prim, _, counts = accel.trace_batch(RR, oo, dd)          # warm-up
                if case == "full":
                    ref = (t, prim, counts)
                elif case == "shuffled" and not (np.array_equal(prim, ref[1]) and
                                                 np.array_equal(counts, ref[2])):
                    raise RuntimeError(f"node_cost N={N}: the shuffled tree answers differently")
                secs, _ = _median_time(lambda: accel.trace_batch(RR, oo, dd), repeats)
                nodes = int(counts[:, 0].sum())
                rows.append({"N": int(N), "accel": structure, "case": case, "rays": len(oo),
                             "tree_nodes": len(R.node_a),
                             "node_bytes": int(R.node_lo.nbytes + R.node_hi.nbytes +
                                               R.node_a.nbytes + R.node_b.nbytes),
                             "nodes_per_ray": float(counts[:, 0].mean()),
                             "tests_per_ray": float(counts[:, 1].mean()), "query_s": secs,
                             "ns_per_ray": secs / len(oo) * 1e9, "ns_per_node": secs / nodes * 1e9})
                log(f"  node_cost N={N} {case}: {rows[-1]['ns_per_node']:.1f} ns/node, "
                    f"{rows[-1]['nodes_per_ray']:.1f} nodes/ray")
    finally:
        numba.set_num_threads(before)
    return rows


def fit_exponents(rows: list[dict], *, n_min: int = 100) -> list[dict]:
    """Least-squares slope k of log(trace_s) (and of log(tests_per_ray)) against log N
    per family × structure over N ≥ ``n_min``, with the slope of log(log N) over the
    same sizes: the exponent a structure of logarithmic cost should not exceed; and
    the nodes visited per ray fitted as a + b·ln N (slope b, R²), the direct test of
    logarithmic work (wall time adds cache effects the node count does not have).

    Why the first comparison can fail for logarithmic work: work
    a + b·ln N = b·ln(N/N₀) has the log–log slope 1/ln(N/N₀), larger than ln N's
    1/ln N whenever the intercept a is negative (N₀ = exp(−a/b) > 1; a tree's
    depth is log(N/leaf size), not log N).  The rows therefore also carry
    ``exponent_nodes_per_ray`` (the work's own log–log slope), ``nodes_lnN_N0``,
    the time fitted as a + b·ln N (``trace_lnN_r2``), and the split of the
    camera-ray query time into per-ray and per-node cost (``query_ns_per_node_fit``
    = the slope of ns per ray against nodes per ray, ``exponent_ns_per_node`` = the
    log–log slope of ns per node visited against N: 0 when a node costs the same
    at every N, > 0 when the cost per node grows, e.g. from cache misses)."""
    out = []
    keys = dict.fromkeys((r["family"], r["accel"]) for r in rows)
    for fam, name in keys:
        pts = [r for r in rows if r["family"] == fam and r["accel"] == name and "trace_s" in r
               and r["N"] >= n_min and r["trace_s"] > 0]
        if len(pts) < 2:
            continue
        n = np.log([r["prims"] for r in pts])
        k_time = float(np.polyfit(n, np.log([r["trace_s"] for r in pts]), 1)[0])
        k_query = float(np.polyfit(n, np.log([max(r["primary_query_s"], 1e-9) for r in pts]), 1)[0])
        k_tests = float(np.polyfit(n, np.log([max(r["tests_per_ray"], 1e-9) for r in pts]), 1)[0])
        k_log = float(np.polyfit(n, np.log(n), 1)[0])
        # Logarithmic cost means work = a + b·ln N: fit the nodes visited per ray
        # linearly in ln N and report the slope b and R² (1 = exactly logarithmic).
        nodes = np.array([r["nodes_per_ray"] for r in pts], dtype=np.float64)
        a_nodes, b_nodes, r2 = _fit_ln(n, nodes)
        fit = {"family": fam, "accel": name, "sizes": len(pts),
               "N_range": f"{pts[0]['prims']}–{pts[-1]['prims']}",
               "exponent_trace_time": k_time, "exponent_primary_query": k_query,
               "exponent_tests_per_ray": k_tests,
               "exponent_log_N": k_log,
               "nodes_per_ray_per_lnN": b_nodes, "nodes_lnN_r2": r2}
        if (nodes > 0).all():
            fit["exponent_nodes_per_ray"] = float(np.polyfit(n, np.log(nodes), 1)[0])
            fit["nodes_lnN_N0"] = float(np.exp(-a_nodes / b_nodes)) if b_nodes > 0 else float("nan")
        fit["trace_lnN_r2"] = _fit_ln(n, [r["trace_s"] for r in pts])[2]
        if all(r.get("query_ns_per_node", float("nan")) > 0 for r in pts):
            per_ray = [r["query_ns_per_ray"] for r in pts]
            if nodes.var() > 0:
                fit["query_ns_per_node_fit"] = float(np.polyfit(nodes, per_ray, 1)[0])
            fit["exponent_ns_per_node"] = float(
                np.polyfit(n, np.log([r["query_ns_per_node"] for r in pts]), 1)[0])
        out.append(fit)
    return out


# ============================================================== grid knobs ===

def grid_knobs(*, families=("spheres", "mesh"), sizes=None, densities=(0.25, 1.0, 4.0, 16.0),
               width=128, height=96, max_depth=3, repeats=3, brute_max=20000, seed=0,
               log=print) -> list[dict]:
    """The uniform grid's three knobs of thesis 2.6.2 on generated scenes: resolution
    (``grid_density``, voxels per primitive), mailboxing and the current-voxel rule,
    every combination per density.

    Per row: the grid's voxels and references per primitive, the build time; for the
    pixel-centre camera rays and for one cosine-distributed bounce ray per camera hit
    (:func:`bounce_rays`), voxels and primitive tests per ray and the hits whose
    primitive differs from the reference (brute force up to ``brute_max`` primitives,
    else the SAH BVH, which the tests hold to brute force's answers); the Whitted
    render's phases (median ``setup_s``, ``trace_s``, :func:`_timed_renders`) and the
    pixels whose value differs from the render with both rules on at that density.

    What it shows: with the current-voxel rule the grid answers as brute force at
    every density, mailbox or not (0 wrong hits); mailboxing only saves tests; without
    the rule a primitive hit beyond the voxel being examined hides a nearer one listed
    in the next voxel (Fig. 2.34), so hits and pixels go wrong."""
    from impl import accel
    from impl.rays import ray_config
    from impl.scene_arrays import flatten

    from .. import registry

    algo = registry.get("whitted")
    sizes = sizes or {"spheres": 1000, "mesh": 10000}
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown or not all(d > 0 for d in densities):
        raise SuiteError(f"grid_knobs: unknown family {', '.join(unknown) or '-'} (families: "
                         f"{', '.join(FAMILIES)}) or a density <= 0 in {list(densities)}")
    settings = [(m, v) for v in (True, False) for m in (True, False)]
    rows = []
    for fam in families:
        N = int(sizes[fam])
        scene = FAMILIES[fam](N, width=width, height=height)
        A = flatten(scene)
        n_prims = len(A.sph_radius) + len(A.tri_v)
        ref_name = "none" if n_prims <= brute_max else "bvh-sah"
        Rref = ray_config(A, algo.parse_params({"accel": ref_name}), algorithm="grid_knobs")
        o, d = camera_rays(scene)
        t0, p0, _, _ = accel.trace_batch(Rref, o, d)
        ob, db = bounce_rays(A, o, d, t0, p0, seed=seed)
        _, pb, _, _ = accel.trace_batch(Rref, ob, db)
        warm = FAMILIES[fam](N, width=8, height=6)
        for mailbox, rule in settings:                               # compile outside the timings
            algo.render(warm, algo.parse_params({"accel": "grid", "grid_mailbox": mailbox,
                                                 "grid_current_voxel": rule, "max_depth": max_depth}))
        for dens in densities:
            exact_image = None
            for mailbox, rule in settings:
                params = algo.parse_params({"accel": "grid", "grid_density": float(dens),
                                            "grid_mailbox": mailbox, "grid_current_voxel": rule,
                                            "max_depth": max_depth})
                build_s, R = _median_time(lambda: ray_config(A, params, algorithm="grid_knobs"), repeats)
                _, pc, _, cc = accel.trace_batch(R, o, d)
                _, pbb, _, cb = accel.trace_batch(R, ob, db)
                render_s, res, phases = _timed_renders(algo, scene, params, repeats)
                if mailbox and rule:
                    exact_image = res.image
                row = {"family": fam, "N": N, "prims": int(n_prims), "density": float(dens),
                       "mailbox": mailbox, "current_voxel": rule, "reference": ref_name,
                       "voxels": int(np.prod(R.acc_i[:3])),
                       "refs_per_prim": len(R.prim_idx) / n_prims, "build_s": build_s,
                       "voxels_per_ray": float(cc[:, 0].mean()), "tests_per_ray": float(cc[:, 1].mean()),
                       "wrong_hits": int((pc != p0).sum()), "rays": len(o),
                       "bounce_tests_per_ray": float(cb[:, 1].mean()),
                       "bounce_wrong_hits": int((pbb != pb).sum()), "bounce_rays": len(ob),
                       "wrong_pixels": int(np.any(res.image != exact_image, axis=-1).sum()),
                       "render_s": render_s, "setup_s": phases["setup_s"], "trace_s": phases["trace_s"]}
                rows.append(row)
                log(f"  grid_knobs {fam} density {dens} mailbox={mailbox} current_voxel={rule}: "
                    f"tests/ray {row['tests_per_ray']:.1f}, wrong hits {row['wrong_hits']} + "
                    f"{row['bounce_wrong_hits']}, wrong pixels {row['wrong_pixels']}")
    return rows


STUDIES = {s.name: s for s in (
    StudyInfo("scaling", "Acceleration structures: scaling with scene size",
              "Whitted renders (1 spp, max_depth 3; film size from the config) of N random spheres and of tessellated meshes "
              "with every structure of impl.accel: build time (ray_config), render and trace time, "
              "primitive tests and nodes per camera ray (counting pass), memory.", scaling),
    StudyInfo("node_cost", "Acceleration structures: cost per node visited vs scene size",
              "Camera-ray closest-hit queries through a tree on sphere fields of growing N (one "
              "thread): ns per node visited for the whole image, for one pixel tile's rays repeated "
              "(tree in cache) and for the same tree with its nodes shuffled in memory.", node_cost),
    StudyInfo("grid_knobs", "Uniform grid: resolution, mailboxing and the current-voxel rule",
              "Thesis 2.6.2 on a sphere field and a mesh: per grid density and on/off setting of "
              "mailboxing and of the current-voxel rule, voxels and primitive tests per camera and "
              "bounce ray, hits that differ from brute force, pixels that differ from the exact "
              "grid's Whitted render, and the render's setup and trace times. Without the "
              "current-voxel rule nearer objects are lost (Fig. 2.34): the negative control.",
              grid_knobs),
)}

TABLES = table_titles(STUDIES)
TABLES["scaling_fit"] = (
    "Acceleration structures: fitted exponent of trace time vs N",
    "Least-squares slope of log trace time (and of log tests per ray) against log N per structure and "
    "scene family, next to the slope of log N over the same sizes: brute force should be ≈ 1, a "
    "hierarchy at most about the log N slope (plus the constant overheads at small N and cache "
    "effects at large N); and nodes per ray fitted as a + b·ln N (R² near 1: logarithmic work). "
    "Work b·ln(N/N0) with N0 > 1 has a log-log slope above ln N's: exponent_nodes_per_ray is the "
    "work's own slope, nodes_lnN_N0 its N0, exponent_ns_per_node the slope of the camera-ray query "
    "time per node visited (0: a node costs the same at every N, i.e. no cache effect).")


def load_config(path=None) -> dict:
    """The studies' parameters from a TOML file (default ``suites/scaling/studies.toml``)."""
    return read_config(path, DEFAULT_CONFIG)


def run_studies(config=None, *, only=None, mitsuba: bool | None = None) -> dict[str, list[dict]]:
    """Run the studies named in ``config``; adds ``scaling_fit`` when ``scaling`` ran."""
    config = as_config(config, DEFAULT_CONFIG)
    cfg = dict(config)
    fit_min = cfg.pop("fit_n_min", 100)
    out = run_registered(STUDIES, cfg, only=only)
    if "scaling" in out:
        # One fit per least size: e.g. the whole range (N >= 10) and the large-N part.
        # A family whose sizes all lie above both minima gets one row.
        mins = fit_min if isinstance(fit_min, list) else [fit_min]
        fits = {}
        for m in mins:
            for row in fit_exponents(out["scaling"], n_min=int(m)):
                fits.setdefault((row["family"], row["accel"], row["N_range"]), row)
        out["scaling_fit"] = list(fits.values())
    return out
