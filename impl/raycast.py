"""Ray casting with local illumination — registered as ``raycast``.

Thesis 1.3.3 (visible surfaces by ray casting: a ray from the eye through each
pixel, the closest intersection wins) shaded with the Phong model of 1.4.2
(:mod:`impl.phong`), with the light types of 1.4.1: point, directional, spot
and area lights, each tested for visibility with a shadow ray.

What it computes: direct illumination only.  With the default parameters
(k_a = k_s = 0, f_att = 1/d²) it estimates exactly what Mitsuba's ``direct``
integrator computes for diffuse scenes — the pixel integral of L_e + the
direct radiance — so it is validated against that reference; against a
full-transport reference the difference is *model error*.

Pixel sampling: ``spp = 1`` traces the pixel centre (the thesis's ray
casting); ``spp = k²`` traces a k×k jittered stratified grid and averages it
(a box filter over the pixel, comparable with a box-filtered reference); the
per-pixel variance of that mean is returned from the sample variance (an
over-estimate for stratified samples, so Z-tests stay conservative).  Area
lights are sampled uniformly by area with ``light_samples`` shadow rays per
emitter and pixel sample (stratified when it is a square).

Leaves out: indirect light, specular reflection and transmission of other
surfaces (see ``whitted``), glossy microfacet BSDFs.  Materials other than
``diffuse`` raise ``NotImplementedError``; a diffuse reflectance may be a
``checkerboard`` or ``bitmap`` texture (looked up at the hit's uv,
:mod:`impl.textures`).  A ``constant`` environment emitter is seen by eye rays
that leave the scene and lights surfaces through ``light_samples``
cosine-weighted shadow rays per pixel sample (:mod:`impl.lighting`).
The shared direct-lighting helpers live in :mod:`impl.lighting`.

Parameters
----------
=============  ======  =======  ==============================================
name           type    default  meaning
=============  ======  =======  ==============================================
spp            int     1        pixel samples: 1 = centre, k² = k×k strata
light_samples  int     16       shadow rays per area emitter per pixel sample
ka             float   0        ambient coefficient k_a (× ρ)
ambient        float   0        ambient intensity I_a
ks             float   0        specular coefficient k_s (white highlight)
shininess      float   32       Phong exponent n
c1, c2, c3     float   0, 0, 1  f_att = 1 / (c1 + c2 d + c3 d²)
fatt_clamp     bool    false    clamp f_att to 1, as the thesis does
shadows        bool    true     cast shadow rays
intersect      str     stable   ray–sphere form of every sphere test
precision      str     float64  precision of the intersection arithmetic
offset         str     robust   epsilon | normal | robust: how shadow rays
                                leave the surface
epsilon        float   1e-4     ε of offset=epsilon / normal (scene units)
accel          str     auto     acceleration structure (thesis 2.6)
slab_normals   int     7        plane normals of accel=slabs
packets        bool    false    eye rays of 8×8 tiles as coherent packets
=============  ======  =======  ==============================================

The last seven are the ray configuration of :mod:`impl.rays` (shared with
``whitted``, which documents them in full).  With ``packets=true`` the kernel
runs over 8×8 pixel tiles and traces each sample's 64 eye rays as one packet
(:mod:`impl.accel.packets`); shading and shadow rays go on per pixel, single
ray, and the image and counters are those of ``packets=false`` bit for bit,
plus the counters ``packet_nodes`` and ``packet_tests``.  Before they existed shadow rays
left the surface p + 1e-7·(1 + max|p_i|)·n.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene

from .accel.packets import NOT_TRACED, packet_buffers, tile_count, tile_eye_packet, tile_rect
from .camera import camera_params, eye_ray
from .intersect import closest_hit
from .lighting import environment_radiance, local_shading, surface
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, hit, ray_config, refine, round_ray
from .phong import PHONG_PARAMS
from .sampling import check_spp, pixel_sample, strata, variance_of_mean, welford_add, welford_row
from .scene_arrays import SceneArrays, flatten
from core.errors import ParamError, UnsupportedError

__all__ = ["render", "cast_primary", "ALGORITHM"]


@njit(cache=True)
def _radiance(ox, oy, oz, dx, dy, dz, tmin, tmax, A: SceneArrays, R: RayConfig, ka, ambient, ks,
              shininess, c1, c2, c3, fclamp, shadows, light_samples, seed, pixel, sample, pre_t,
              pre_prim, pre_b1, pre_b2):
    """Radiance along one eye ray: emitted + ambient + Phong direct; (r, g, b, shadow rays).

    ``pre_*``: the eye ray's closest hit as :func:`impl.rays.hit` returns it, traced
    in a packet; ``pre_prim = NOT_TRACED`` traces it here.
    """
    ox, oy, oz, dx, dy, dz = round_ray(R, ox, oy, oz, dx, dy, dz)
    if pre_prim == NOT_TRACED:
        t, prim, b1, b2 = hit(R, ox, oy, oz, dx, dy, dz, tmin, tmax)
    else:
        t, prim, b1, b2 = pre_t, pre_prim, pre_b1, pre_b2
    if prim < 0:                        # escaped: a constant environment, if any
        er, eg, eb = environment_radiance(A, dx, dy, dz)
        return er, eg, eb, 0
    ns = A.sph_radius.shape[0]
    shape = A.prim_shape[prim]
    px, py, pz = refine(R, prim, b1, b2, ox + t * dx, oy + t * dy, oz + t * dz)
    gx, gy, gz, sx, sy, sz = surface(prim, b1, b2, px, py, pz, ns, A.sph_center, A.sph_radius,
                                      A.tri_v, A.tri_n, A.tri_has_n, A.shape_flip[shape])
    return local_shading(px, py, pz, gx, gy, gz, sx, sy, sz, -dx, -dy, -dz, shape, prim, b1, b2, A, R,
                         ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows, light_samples,
                         seed, pixel, sample)


@njit(cache=True)
def _pixel(cam, A: SceneArrays, R: RayConfig, x, y, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows,
           light_samples, seed):
    """Mean and variance of the mean of one pixel's samples, and its shadow-ray count.

    A function of its own so that every accumulator is private to the thread
    that runs the pixel (a prange body's locals can be hoisted and shared).
    """
    pixel = y * int(cam[14]) + x
    k = strata(spp)
    m0 = m1 = m2 = 0.0
    q0 = q1 = q2 = 0.0
    nsh = 0
    for s in range(spp):
        fx, fy = pixel_sample(spp, k, s, seed, pixel)
        ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + fx, y + fy)
        r, g, b, n = _radiance(ox, oy, oz, dx, dy, dz, tmin, tmax, A, R, ka, ambient, ks, shininess,
                               c1, c2, c3, fclamp, shadows, light_samples, seed, pixel, s, 0.0,
                               np.int64(NOT_TRACED), 0.0, 0.0)
        nsh += n
        m0, m1, m2, q0, q1, q2 = welford_add(s, r, g, b, m0, m1, m2, q0, q1, q2)
    return (m0, m1, m2, variance_of_mean(q0, spp), variance_of_mean(q1, spp),
            variance_of_mean(q2, spp), nsh)


@njit(cache=True)
def _tile(cam, A: SceneArrays, R: RayConfig, tile, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp,
          shadows, light_samples, seed, mean, var, shadow_count, packet_counts):
    """One 8×8 tile: per sample index, its eye rays (those of :func:`_pixel`) traced as
    one packet, then each pixel's sample shaded from its hit.  The per-pixel Welford
    state lives here, private to the thread running the tile."""
    W, H = int(cam[14]), int(cam[15])
    x0, y0, nx, ny = tile_rect(tile, W, H)
    P = nx * ny
    k = strata(spp)
    rays, hit_t, hit_p, hit_b = packet_buffers(P)
    acc = np.zeros((P, 6))                  # Welford m0, m1, m2, q0, q1, q2 per pixel
    nsh = np.zeros(P, dtype=np.int64)
    for s in range(spp):
        tile_eye_packet(R, cam, x0, nx, y0, P, spp, k, s, seed, rays, hit_t, hit_p, hit_b,
                        packet_counts)
        for i in range(P):
            x, y = x0 + i % nx, y0 + i // nx
            r, g, b, n = _radiance(rays[i, 0], rays[i, 1], rays[i, 2], rays[i, 3], rays[i, 4],
                                   rays[i, 5], rays[i, 6], rays[i, 7], A, R, ka, ambient, ks,
                                   shininess, c1, c2, c3, fclamp, shadows, light_samples, seed,
                                   y * W + x, s, hit_t[i], hit_p[i], hit_b[i, 0], hit_b[i, 1])
            nsh[i] += n
            welford_row(acc, i, s, r, g, b)
    for i in range(P):
        x, y = x0 + i % nx, y0 + i // nx
        for c in range(3):
            mean[y, x, c] = acc[i, c]
            var[y, x, c] = variance_of_mean(acc[i, 3 + c], spp)
        shadow_count[y, x] = nsh[i]


@njit(parallel=True, cache=True)
def _render_tiles(cam, A: SceneArrays, R: RayConfig, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp,
                  shadows, light_samples, seed, mean, var, shadow_count, packet_counts):
    W, H = int(cam[14]), int(cam[15])
    for tile in prange(tile_count(W, H)):
        _tile(cam, A, R, tile, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows,
              light_samples, seed, mean, var, shadow_count, packet_counts[tile])


@njit(parallel=True, cache=True)
def _render_kernel(cam, A: SceneArrays, R: RayConfig, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows,
                   light_samples, seed, mean, var, shadow_count):
    W, H = int(cam[14]), int(cam[15])
    for pixel in prange(W * H):
        x = pixel % W
        y = pixel // W
        out = _pixel(cam, A, R, x, y, spp, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows,
                     light_samples, seed)
        mean[y, x, 0] = out[0]
        mean[y, x, 1] = out[1]
        mean[y, x, 2] = out[2]
        var[y, x, 0] = out[3]
        var[y, x, 1] = out[4]
        var[y, x, 2] = out[5]
        shadow_count[y, x] = out[6]


@njit(parallel=True, cache=True)
def _primary_kernel(cam, A: SceneArrays, depth, shape_id):
    W, H = int(cam[14]), int(cam[15])
    for pixel in prange(W * H):
        x, y = pixel % W, pixel // W
        ox, oy, oz, dx, dy, dz, tmin, tmax, _ = eye_ray(cam, x + 0.5, y + 0.5)
        t, prim, b1, b2 = closest_hit(ox, oy, oz, dx, dy, dz, tmin, tmax, A.sph_center, A.sph_radius, A.tri_v)
        if prim >= 0:
            depth[y, x] = t
            shape_id[y, x] = A.prim_shape[prim]


def _check_materials(scene: Scene) -> None:
    for shape in scene.shapes:
        m = scene.materials[shape.material]
        if m.kind != "diffuse":
            raise UnsupportedError(
                f"raycast: shape '{shape.name or shape.source}' has a '{m.kind}' BSDF; local Phong "
                "illumination models diffuse surfaces only (specular transport is the whitted algorithm)")


def cast_primary(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Eye rays through pixel centres: (distance from the eye to the closest hit
    (inf on a miss), shape index (-1 on a miss)), both (H, W)."""
    cam = camera_params(scene.camera)
    H, W = scene.camera.film.height, scene.camera.film.width
    depth = np.full((H, W), np.inf)
    shape_id = np.full((H, W), -1, dtype=np.int64)
    _primary_kernel(cam, flatten(scene), depth, shape_id)
    return depth, shape_id


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    spp = params["spp"]
    check_spp(spp, "raycast")
    if params["light_samples"] < 0:
        raise ParamError("raycast: light_samples must be >= 0")
    _check_materials(scene)
    A = flatten(scene)
    cam = camera_params(scene.camera)
    H, W = scene.camera.film.height, scene.camera.film.width
    mean = np.zeros((H, W, 3))
    var = np.zeros((H, W, 3))
    shadow = np.zeros((H, W), dtype=np.int64)
    R = ray_config(A, params, algorithm="raycast")
    args = (cam, A, R, spp, params["ka"], params["ambient"], params["ks"], params["shininess"],
            params["c1"], params["c2"], params["c3"], params["fatt_clamp"], params["shadows"],
            params["light_samples"], seed, mean, var, shadow)
    if params.get("packets", False):
        packet_counts = np.zeros((tile_count(W, H), 2), dtype=np.int64)
        _render_tiles(*args, packet_counts)
    else:
        _render_kernel(*args)
    counters = {"camera_rays": int(W * H * spp), "shadow_rays": int(shadow.sum())}
    if params.get("packets", False):
        counters["packet_nodes"], counters["packet_tests"] = (int(v) for v in packet_counts.sum(axis=0))
    return RenderResult(image=mean.astype(np.float32),
                        variance=var.astype(np.float32) if spp > 1 else None,
                        counters=counters)


ALGORITHM = Algorithm(
    name="raycast",
    summary="Ray casting with Phong local illumination and shadow rays (direct light only)",
    section="thesis 1.3.3, 1.4",
    transport="direct",
    params=(
        Param("spp", int, 1, "pixel samples: 1 = pixel centre, k² = k×k jittered strata (box filter)"),
        Param("light_samples", int, 16, "shadow rays per area emitter per pixel sample"),
        *PHONG_PARAMS,
        Param("shadows", bool, True, "cast shadow rays"),
        *RAY_PARAMS,
    ),
    render=render,
)
