"""Ray casting with local illumination — registered as ``raycast``.

Thesis 1.3.3 (visible surfaces by ray casting: a ray from the eye through each
pixel, the closest intersection wins) shaded with the Phong model of 1.4.2
(:mod:`impl.phong`), with the light types of 1.4.1: point, directional, spot
and area lights, and Mitsuba's ``projector`` (a point light whose intensity is
its projected image, :mod:`impl.projector`), each tested for visibility with a
shadow ray.

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
emitter and pixel sample (stratified when it is a square); with
``sampler=sobol`` the pixel positions and the light samples are Owen-scrambled
Sobol points, the light's stratified over all of a pixel's samples
(:func:`impl.lighting.light_uv_sobol`).

Leaves out: indirect light, specular reflection and transmission of other
surfaces (see ``whitted``), glossy microfacet BSDFs.  Materials other than
``diffuse`` raise ``NotImplementedError``; a diffuse reflectance may be a
``checkerboard`` or ``bitmap`` texture (looked up at the hit's uv,
:mod:`impl.textures`), and a ``normalmap`` or ``bumpmap`` may wrap it (on
triangles with uvs, Mitsuba's adapters: the Lambert term about the perturbed
normal, light samples on opposite sides of the true and the perturbed normal
dropped, Estevez et al.'s shadowing term; :mod:`impl.shading_frame`).  A
``constant`` environment emitter is seen by eye rays that leave the scene and
lights surfaces through ``light_samples`` cosine-weighted shadow rays per
pixel sample (:mod:`impl.lighting`).
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
``whitted``, which documents them in full).

Structure: the tracer core of :mod:`impl.tracer` renders tile by tile, each
sample index's eye rays as one batch; this module is the shading step
(:func:`_shade`): the hit's surface, emission and ambient term, then the
direct light of :func:`impl.lighting.direct_batch`, whose shadow rays are
traced a light sample at a time over the whole batch (a delta light's sample,
contribution and shadow ray computed for every point in one vectorised loop).
With ``packets=true`` the eye rays of 8×8 tiles go through the tree as packets
(:mod:`impl.accel.packets`); the image and counters are those of
``packets=false`` bit for bit, plus the counters ``packet_nodes`` and
``packet_tests``.  ``RenderResult.timings`` splits the render's wall time into
``setup_s`` (flattened scene and ray configuration — both remembered per scene,
:func:`impl.scene_arrays.scene_memo` —, camera, output arrays), ``trace_s``
(the kernel) and ``finish_s`` (counters, output conversion).
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit, prange

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene
from core.errors import ParamError, UnsupportedError

from .camera import camera_params, eye_ray
from .intersect import closest_hit
from .kernel import batch_kernel, run_tasks, take_task
from .lighting import (LocalModel, MAP_NONE, SP_G, SP_MAP, SP_P, SP_RHO, SP_S, SP_V, diffuse_albedo,
                       direct_batch, environment_radiance, interpolated_normal, local_model,
                       mapped_normal, sphere_surface, store_point, surface_at)
from .phong import PHONG_PARAMS
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, refine, refine_sphere, refine_triangle
from .sampling import SAMPLER_PARAM, check_spp, sampler_code
from .scene_arrays import SceneArrays, flatten_cached
from .tracer import (accumulate, Batch, DX, DY, DZ, eye_batch, Film, film_counters, film_result,
                     new_batch, new_film, OX, OY, OZ, ray_config_cached, store)

__all__ = ["render", "cast_primary", "ALGORITHM"]

#: Per-pixel counters of the tile kernel.
COUNTERS = ("shadow_rays",)


@batch_kernel
def _shade(A: SceneArrays, R: RayConfig, M: LocalModel, T: Batch, s, seed, sidx, slow, smooth):
    """Radiance of the batch's eye rays from their closest hits into ``T.L``: a constant
    environment for escaped rays; L_e (front side) + ambient I_a k_a ρ + the Phong
    direct light of every light (:func:`impl.lighting.direct_batch`) at a hit.  A
    one-sided surface seen from behind gets nothing; a two-sided one is shaded on the
    side it is seen from.  Under a normal or bump map the bracket is taken about the
    perturbed normal (:func:`impl.lighting.mapped_normal`) and each light sample weighted
    as Mitsuba's adapter weights it (:func:`impl.lighting.map_weight`).

    The plain hits (spheres and triangles, untextured, no map) and the rays that escape
    to a constant environment (or none) (:func:`_plain_hits`) are shaded a ray per vector
    lane; the others (textures, maps, an environment map) ray by ray
    (:func:`_shade_ray`).  ``smooth``: some triangle of the scene has vertex normals.
    ``sidx`` (n,) and ``slow`` (n,) are scratch."""
    n = T.n
    amb = M.ambient * M.ka
    _lane_hits(A, R, amb, T, slow, smooth)
    for i in range(n):
        if slow[i]:
            _shade_ray(A, R, amb, T, i)
    sidx[:] = s
    direct_batch(A, R, M, T, sidx, seed, T.cnt[:, 0])


@batch_kernel(error_model="numpy", disjoint=True)
def _plain_hits(g, C, AC, AR, prim, ts, oxs, oys, ozs, b1s, b2s, dxs, dys, dzs, V, NG, TN, has_n,
                smooth, prim_shape, shape_flip, emit, shape_mat, twosided, shade, tex, rho, amb, sky,
                sky_r, sky_g, sky_b, Px, Py, Pz, Gx, Gy, Gz, Nx, Ny, Nz, Vx, Vy, Vz, Rr, Rg, Rb, code, Lr,
                Lg, Lb, active, slow):
    """:func:`_shade_ray`'s surface, emission and ambient term of every *plain* hit — on a
    sphere or a triangle under an untextured diffuse BSDF without a normal or bump map —
    a ray per vector lane: the same operations (the hit point of :func:`impl.rays.refine`
    in the precision of ``g``: a triangle's from its barycentrics, a sphere's projected
    onto it from o + t d; the normals of :func:`impl.lighting.surface_at`: the geometric
    one, and as the shading normal the vertex normals interpolated
    (:func:`impl.lighting.interpolated_normal`) where the triangle has them, else the
    geometric one; both turned to the viewer's side on a two-sided BSDF), selects for
    their branches, so the point rows, ``L`` and ``active`` of those rays are
    :func:`_shade_ray`'s bit for bit.  With ``sky`` (no environment map), an escaped ray
    gets the constant radiance (``sky_r``, ``sky_g``, ``sky_b``) and no point, as there.
    ``slow[i]``: ray i is neither (another surface, an escaped ray under an environment
    map) and is left to :func:`_shade_ray` (its other outputs are then meaningless).

    ``g``, ``C``: the spheres' radii and centres in the intersection precision (``R``'s),
    ``AC``, ``AR`` in float64 (``A``'s, the normal's).  The scene's tables are read at
    clamped indices, so every lane reads memory that exists (a scene without shapes
    leaves every ray to :func:`_shade_ray`); one loop per mix of primitives the scene
    has, so a scene of triangles alone does not pay the sphere's square root and
    divisions at every lane, nor a scene without vertex normals (``smooth`` false) their
    interpolation.  ``TN``: the triangles' vertex normals (float64)."""
    ns = g.shape[0]

    def lane(spheres, triangles, normals, i):
        p = prim[i]
        miss = p < 0
        tri = p >= ns
        shape = prim_shape[p if p >= 0 else 0]
        mat = shape_mat[shape]
        plain = (shade[mat] == 0) & (tex[mat] == 0)
        fast = miss & sky
        px = py = pz = gx = gy = gz = sx = sy = sz = 0.0
        if triangles:
            j = p - ns if tri else 0
            px, py, pz = refine_triangle(g, V, j, b1s[i], b2s[i])
            gx, gy, gz = NG[j, 0], NG[j, 1], NG[j, 2]
            sx, sy, sz = gx, gy, gz
            if normals:
                hn = has_n[j] != 0
                ix, iy, iz = interpolated_normal(TN, j, b1s[i], b2s[i])
                sx = ix if hn else gx
                sy = iy if hn else gy
                sz = iz if hn else gz
                fast = fast | (tri & plain)
            else:
                fast = fast | (tri & (not has_n[j]) & plain)
        if spheres:
            on = (not miss) & (not tri)
            k = p if on else 0
            t = ts[i]
            qx, qy, qz = refine_sphere(g, C, k, oxs[i] + t * dxs[i], oys[i] + t * dys[i],
                                       ozs[i] + t * dzs[i])
            hx, hy, hz, _, _, _ = sphere_surface(k, qx, qy, qz, AC, AR, False)
            px = qx if on else px
            py = qy if on else py
            pz = qz if on else pz
            gx = hx if on else gx
            gy = hy if on else gy
            gz = hz if on else gz
            if normals:                 # (only with triangles)
                sx = hx if on else sx
                sy = hy if on else sy
                sz = hz if on else sz
            else:
                sx, sy, sz = gx, gy, gz
            fast = fast | (on & plain)
        slow[i] = not fast
        Px[i], Py[i], Pz[i] = px, py, pz
        flip = shape_flip[shape]
        gx = -gx if flip else gx
        gy = -gy if flip else gy
        gz = -gz if flip else gz
        sx = -sx if flip else sx
        sy = -sy if flip else sy
        sz = -sz if flip else sz
        vx, vy, vz = -dxs[i], -dys[i], -dzs[i]
        gv = gx * vx + gy * vy + gz * vz
        front = sx * vx + sy * vy + sz * vz > 0.0       # L_e on the front side only
        er = emit[shape, 0] if front else 0.0
        eg = emit[shape, 1] if front else 0.0
        eb = emit[shape, 2] if front else 0.0
        back = twosided[mat] & (gv < 0.0)
        gx = -gx if back else gx
        gy = -gy if back else gy
        gz = -gz if back else gz
        sx = -sx if back else sx
        sy = -sy if back else sy
        sz = -sz if back else sz
        lit = (sx * vx + sy * vy + sz * vz > 0.0) & (not miss)
        rr, rg, rb = rho[mat, 0], rho[mat, 1], rho[mat, 2]
        Lr[i] = sky_r if miss else (er + amb * rr if lit else er)
        Lg[i] = sky_g if miss else (eg + amb * rg if lit else eg)
        Lb[i] = sky_b if miss else (eb + amb * rb if lit else eb)
        active[i] = lit
        Gx[i], Gy[i], Gz[i] = gx, gy, gz
        Nx[i], Ny[i], Nz[i] = sx, sy, sz
        Vx[i], Vy[i], Vz[i] = vx, vy, vz
        Rr[i], Rg[i], Rb[i] = rr, rg, rb
        code[i] = MAP_NONE

    if prim_shape.shape[0] == 0:         # no shape: every ray escapes, left to _shade_ray
        for i in range(prim.shape[0]):
            slow[i] = True
    elif ns == 0 and smooth:
        for i in range(prim.shape[0]):
            lane(False, True, True, i)
    elif ns == 0:
        for i in range(prim.shape[0]):
            lane(False, True, False, i)
    elif V.shape[0] == 0:
        for i in range(prim.shape[0]):
            lane(True, False, False, i)
    elif smooth:
        for i in range(prim.shape[0]):
            lane(True, True, True, i)
    else:
        for i in range(prim.shape[0]):
            lane(True, True, False, i)


@njit(inline="always", cache=True)
def _lane_hits(A: SceneArrays, R: RayConfig, amb, T: Batch, slow, smooth):
    """:func:`_plain_hits` over the batch's eye rays (``slow`` (≥n,) gets its flags;
    ``smooth``: some triangle has vertex normals)."""
    n = T.n
    P = T.pts
    sky = A.env_image.shape[0] == 0      # escaped rays see a constant radiance (maybe 0)
    er, eg, eb = environment_radiance(A, 0.0, 0.0, 1.0) if sky else (0.0, 0.0, 0.0)
    _plain_hits(R.sph_radius, R.sph_center, A.sph_center, A.sph_radius, T.prim[:n], T.t[:n],
                T.ray[OX, :n], T.ray[OY, :n], T.ray[OZ, :n], T.b[0, :n], T.b[1, :n], T.ray[DX, :n],
                T.ray[DY, :n], T.ray[DZ, :n], R.tri_v, A.tri_ng, A.tri_n, A.tri_has_n, smooth,
                A.prim_shape, A.shape_flip, A.shape_emit, A.shape_material, A.mat_twosided,
                A.mat_shade, A.mat_tex, A.mat_rho, amb, sky, er, eg, eb, P[SP_P, :n],
                P[SP_P + 1, :n], P[SP_P + 2, :n], P[SP_G, :n], P[SP_G + 1, :n], P[SP_G + 2, :n],
                P[SP_S, :n], P[SP_S + 1, :n], P[SP_S + 2, :n], P[SP_V, :n], P[SP_V + 1, :n],
                P[SP_V + 2, :n], P[SP_RHO, :n], P[SP_RHO + 1, :n], P[SP_RHO + 2, :n], P[SP_MAP, :n],
                T.L[0, :n], T.L[1, :n], T.L[2, :n], T.active[:n], slow[:n])


@njit(inline="always", cache=True)
def _shade_ray(A: SceneArrays, R: RayConfig, amb, T: Batch, i):
    """Eye ray i's emission, ambient term and shading point (``T.L``, ``T.pts``,
    ``T.active``): a constant environment for an escaped ray; at a hit, L_e (front side)
    + I_a k_a ρ and, where the BSDF sees the viewer above its normal, the point to
    light."""
    pts, active = T.pts, T.active
    active[i] = False
    dx, dy, dz = T.ray[DX, i], T.ray[DY, i], T.ray[DZ, i]
    prim = T.prim[i]
    if prim < 0:                    # escaped: a constant environment, if any
        T.L[0, i], T.L[1, i], T.L[2, i] = environment_radiance(A, dx, dy, dz)
        return
    t, b1, b2 = T.t[i], T.b[0, i], T.b[1, i]
    shape = A.prim_shape[prim]
    px, py, pz = refine(R, prim, b1, b2, T.ray[OX, i] + t * dx, T.ray[OY, i] + t * dy,
                        T.ray[OZ, i] + t * dz)
    gx, gy, gz, sx, sy, sz = surface_at(A, prim, b1, b2, px, py, pz, A.shape_flip[shape])
    vx, vy, vz = -dx, -dy, -dz
    r = g = b = 0.0
    if sx * vx + sy * vy + sz * vz > 0.0:       # emitted radiance L_e, front side only
        r, g, b = A.shape_emit[shape, 0], A.shape_emit[shape, 1], A.shape_emit[shape, 2]
    mat = A.shape_material[shape]
    back = A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0
    nx, ny, nz, code = mapped_normal(A, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, back)
    if back:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    if nx * vx + ny * vy + nz * vz > 0.0:       # the BSDF sees the viewer above n
        rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
        r += amb * rho_r
        g += amb * rho_g
        b += amb * rho_b
        store_point(pts, i, px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz, rho_r, rho_g, rho_b,
                    sx, sy, sz, code)
        active[i] = True
    T.L[0, i], T.L[1, i], T.L[2, i] = r, g, b


@njit(cache=True)
def _tile(cam, A: SceneArrays, R: RayConfig, M: LocalModel, film: Film, tile, spp, seed, smooth):
    """One tile: per sample index, eye rays and hits, shading, accumulation (``smooth``:
    some triangle has vertex normals)."""
    T = new_batch(film, R, tile, seed)
    sidx = np.empty(T.n, np.int64)
    slow = np.empty(T.n, np.bool_)
    for s in range(spp):
        eye_batch(cam, R, T, s, spp, seed, film.packets, film.sampler)
        _shade(A, R, M, T, s, seed, sidx, slow, smooth)
        accumulate(T, s)
    store(T, film, spp)


@njit(nogil=True, cache=True)
def _render_kernel(cam, A: SceneArrays, R: RayConfig, M: LocalModel, film: Film, spp, seed, smooth,
                   queue):
    """The film's tiles, taken from ``queue`` (:func:`impl.kernel.run_tasks`)."""
    n = film.order.shape[0]
    c = take_task(queue)
    while c < n:
        _tile(cam, A, R, M, film, film.order[c], spp, seed, smooth)
        c = take_task(queue)


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
    _primary_kernel(cam, flatten_cached(scene), depth, shape_id)
    return depth, shape_id


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    t0 = time.perf_counter()
    spp = params["spp"]
    check_spp(spp, "raycast")
    if params["light_samples"] < 0:
        raise ParamError("raycast: light_samples must be >= 0")
    _check_materials(scene)
    A = flatten_cached(scene)
    R = ray_config_cached(scene, A, params, algorithm="raycast")
    cam = camera_params(scene.camera)
    H, W = scene.camera.film.height, scene.camera.film.width
    packets = bool(params.get("packets", False))
    film = new_film(W, H, len(COUNTERS), packets, sampler_code(params))
    smooth = bool(A.tri_has_n.any())     # the lanes' loops with interpolated normals
    t1 = time.perf_counter()
    run_tasks(_render_kernel, cam, A, R, local_model(params), film, spp, seed, smooth)
    t2 = time.perf_counter()
    counters = {"camera_rays": int(W * H * spp), **film_counters(film, COUNTERS)}
    return film_result(film, spp, counters, t0, t1, t2)


ALGORITHM = Algorithm(
    name="raycast",
    summary="Ray casting with Phong local illumination and shadow rays (direct light only)",
    section="thesis 1.3.3, 1.4",
    transport="direct",
    params=(
        Param("spp", int, 1, "pixel samples: 1 = pixel centre, k² = k×k jittered strata (box filter)"),
        SAMPLER_PARAM,
        Param("light_samples", int, 16, "shadow rays per area emitter per pixel sample"),
        *PHONG_PARAMS,
        Param("shadows", bool, True, "cast shadow rays"),
        *RAY_PARAMS,
    ),
    render=render,
    models=frozenset({"envmap", "projector", "spot texture", "normalmap", "bumpmap"}),
    kernel_variants=({"packets": True},),
)
