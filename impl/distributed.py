"""Distributed ray tracing — registered as ``distributed``.

The Whitted ray tracer (:mod:`impl.whitted`) with the distributed effects of
R. L. Cook, T. Porter, L. Carpenter, "Distributed ray tracing", SIGGRAPH 1984
(:doi:`10.1145/800031.808590`), as thesis 2.5.5–2.5.9 describes them, and the
anti-aliasing samplers of 2.5.1–2.5.4 (:mod:`impl.samplers`) with box or
Gaussian reconstruction (:mod:`impl.filters`).  Each pixel sample carries its
own random numbers for every other dimension of the pixel integral — lens
position, shutter time, light point, glossy direction — so one ray tree per
sample distributes the rays over all of them at once (2.5.8).

What it computes
----------------
Per sample, the ray tree of ``whitted`` (delta ``conductor`` and smooth
``dielectric`` split deterministically, Fresnel-weighted; Hall's adaptive
depth; emission of area emitters met by any ray; direct light at the first
diffuse hit of a branch, ``light_samples`` shadow rays per area emitter, each
at a point drawn uniformly over the emitter's area — the *penumbra* of 2.5.6),
plus:

* **gloss** — at a ``roughconductor`` the branch continues along *one*
  reflected direction sampled from the Cook–Torrance/Walter microfacet BSDF
  (:mod:`impl.microfacet`: Beckmann or GGX D, the material's ``distribution``;
  G = Smith (default) or the thesis's V-cavity, ``g=smith|vcavity``), weighted
  f·cos/pdf × conductor Fresnel × ``specular_reflectance``; visible-normal or
  D·cos sampling per the material's ``sample_visible``; a textured ``alpha`` (a
  ``bitmap`` or ``checkerboard``, read as Mitsuba's ``eval_1``) at the hit;
  anisotropic roughness (``alpha_u`` / ``alpha_v``, constants or textures) in
  Mitsuba's shading frame, its tangent along ∂p/∂u (static shapes; under a
  normal map made orthogonal to the perturbed normal; no bump map).  A textured
  ``specular_reflectance`` of a conductor or dielectric (smooth or rough)
  multiplies the reflected branch by its value at the hit, as Mitsuba's
  ``eval`` of the texture does
  (:func:`impl.lighting.specular_tint`), a textured ``specular_transmittance``
  the transmitted one (:func:`impl.lighting.transmittance_tint`), and a
  conductor's textured ``eta`` or ``k`` gives the Fresnel term of its value at
  the hit (:func:`impl.lighting.textured_fresnel`); none with ``shading=hall``;
* **translucency** — at a ``roughdielectric`` one sampled direction,
  reflected with probability F(wi·m) else refracted (Mitsuba's lobe choice),
  weight f·|cos|/pdf (radiance scaling η² on transmission) ×
  ``specular_reflectance``/``specular_transmittance``;
* **depth of field** — eye rays of a ``thinlens`` sensor start on the lens
  disk (:func:`impl.camera.eye_ray_lens`);
* **motion blur** (2.5.7) — every sample has its own time τ, uniform over
  the sensor's shutter [``shutter_open``, ``shutter_close``]; spheres with a
  ``gibench_velocity`` sit at ``center + velocity·τ`` for that sample's eye
  ray and every ray of its tree, shadow rays included (so shadows blur too);
  meshes with ``gibench_velocity`` / ``gibench_angular_velocity`` move
  rigidly, every vertex at ``pivot + Rot(ω τ)(v − pivot) + velocity·τ``
  (Rodrigues' rotation of the rotation vector ω τ; shading normals turn with
  them); a moving sensor's eye ray leaves ``c + Rot(ω τ)(o − c) + velocity·τ``
  along ``Rot(ω τ) d`` (c the camera's origin at τ = 0: it turns about its own
  centre).  Moving meshes are placed per sample in per-pixel copies of the
  triangle arrays (cost: the moving triangles, per sample); a moving mesh
  cannot be an emitter (the loader refuses it: its light samples would stay);
* **Cook–Torrance** (2.4.5.2) — a ``gibench_cooktorrance`` surface (k_d ρ/π
  + k_s F D G / (4 cos θ_i cos θ_o), D the roughness mixture Σ w_k D(m_k),
  F the exact dielectric Fresnel term, :func:`impl.bsdf.cook_torrance_sample`)
  continues its branch along one sampled direction, weight f·cos/pdf;
  one-sided;
* **diffuse transmission** (2.4.5.3) — a ``gibench_difftrans`` surface
  (ρ/π on the viewer's side, τ/π through it,
  :func:`impl.bsdf.diffuse_transmission_sample`) likewise; two-sided.
  Like the glossy surfaces, these receive light only along their sampled
  rays (no shadow rays, delta lights do not light them).  No Mitsuba plugin
  computes them: their reference is the white furnace's closed form
  (``tests/test_thesis_materials.py``);
* **normal and bump maps** — under Mitsuba's ``normalmap`` or ``bumpmap`` (on
  triangles with uvs, :mod:`impl.shading_frame`) every branch is taken about the
  perturbed normal: the Fresnel splits, the sampled glossy, translucent and thesis
  directions, and the direct light at diffuse hits, each scattered direction and
  light sample weighted as the adapters weight it (:func:`impl.lighting.map_weight`:
  no light leaking through the unperturbed shading normal, Estevez et al.'s
  shadowing term); a moving mesh's maps are evaluated on its triangles at the
  sample's time.  Hall's light-source terms take the perturbed normal as N;
* the thesis's Cook–Torrance terms with the V-cavity G are an option
  (``g=vcavity``); the difference from Smith (what Mitsuba uses) is a model
  difference, reported, not tested against Mitsuba.

``shading=hall`` — Hall's shading model (thesis 2.4.5.5; Hall & Greenberg
1983, Fig. 2.20): at every *specular* hit the light-source terms
``k_sr Σ_j I_j F_sr (N·H_j)^n`` and ``k_dr Σ_j I_j F_dr (N·L_j)`` (lights on
the viewer's side, shadow-tested; F_dr the surface's ``specular_reflectance``)
and ``k_st Σ_j I_j F_st (N·H'_j)^n'`` (lights behind a dielectric), from delta
lights, a spot's cone fall-off applied to its I_j; the reflected/transmitted
rays as before, weighted by k_sr = k_st and attenuated by ``T_r^Δ`` /
``T_t^Δ`` over the distance Δ they travel (an escaping ray is not attenuated);
diffuse and ambient terms of diffuse surfaces as ``whitted``'s.  The thesis's
constraints k_dr + k_sr = 1 and 0 ≤ k, T ≤ 1 are enforced: a parameter set
that breaks them is refused with its values (k_dt = 1 − k_st weights nothing:
the model has no diffuse transmission term).  Not physically based (a perfect mirror has no
highlight from a point light): its error against full transport is reported
as a model error (suites/distributed.toml).

Glossy surfaces receive light only along their sampled rays (an area emitter
hit by the continuing ray adds its emission); delta lights do not light them.
Diffuse hits take their light from :func:`impl.lighting.direct_light_dims`, the
ray casting's: a projector's image and a spot's ``texture`` included
(:func:`impl.lighting.delta_filter`); Hall's light-source terms leave those
images out, and ``shading=hall`` refuses a scene that has one.
With ``g=smith`` this is what the matched reference
(:mod:`references.whitted_integrator`, which follows glossy lobes by
``bsdf.sample``) computes.

Pixel samplers (``sampler``)
----------------------------
``uniform`` k×k sub-pixel centres; ``random``; ``jitter`` (``jitter=white``
with ``gamma``, or ``jitter=gaussian`` with ``sigma``); ``poisson`` (dart
throwing); ``adaptive`` (Whitted's corners + centre, recursive subdivision
while the five samples disagree by more than ``threshold``, depth limit
``adaptive_depth``, at most ``spp`` radiance samples per pixel); ``statistical``
(4 stratified samples, then random ones until the ``confidence`` interval of
the pixel mean is narrower than ±``tolerance`` or ``spp`` samples are spent).
``sobol``: the first ``spp`` points of an Owen-scrambled Sobol sequence per
pixel (:func:`impl.samplers.sobol_pattern`; a (0, m, 2)-net when spp = 2^m).
For the fixed patterns ``spp`` is the number of samples per pixel (a square
k² for ``uniform`` and ``jitter``); for ``adaptive`` and ``statistical`` it is
the per-pixel cap, and the counter ``samples`` (÷ pixels = the mean spp
actually spent) says what was used.

The other dimensions of a sample (``dimensions``; thesis 2.5.8)
-----------------------------------------------------------------
Besides its film position a sample draws numbers for its lens point (2-D),
shutter time (1-D), every light sample at every diffuse hit of its ray tree
(2-D each) and every sampled BSDF direction (2-D, plus a 1-D lobe choice).

* ``dimensions=independent`` (the default): independent hashed uniform
  numbers per (pixel, sample, dimension); only the pixel position follows the
  sampler's pattern.  With ``light_samples`` = q² the light samples of one
  pixel sample are stratified among themselves (q×q).
* ``dimensions=stratified`` (fixed-count samplers, square spp = k²): Cook's
  shuffled strata (Cook 1986, §5): every 2-D dimension has its own k×k
  jittered strata over the pixel's spp samples, every 1-D one spp strata, and
  sample s takes the stratum π_d(s) of a pseudo-random permutation drawn per
  pixel and dimension (:func:`impl.samplers.dim_2d`, ``dim_1d``), so each
  dimension covers its strata once and is paired at random with the pixel
  position and the other dimensions; the lens strata follow the pixel strata's
  rows and columns (:func:`impl.samplers.lens_stratified`), so film × lens is
  stratified along each axis, where an edge out of focus lies.  Light sample j at the tree's l-th
  diffuse hit is its own dimension (not stratified against the pixel sample's
  other light samples).
* ``sampler=sobol``: the film position and the lens point from one
  Owen-scrambled 4-D Sobol point per sample (:func:`impl.samplers.camera_sobol`),
  every other dimension from the padded per-pixel Sobol sequence
  (:data:`impl.samplers.DIM_SOBOL`; a scrambled (0, 2)-sequence per 2-D
  dimension, a scrambled van der Corput sequence per 1-D one, each with its own
  index shuffle; not an image-wide ZSobol sequence).

Both keep each sample uniform in every dimension, so the estimate stays
unbiased; the per-pixel variance (the sample variance / n) over-estimates the
variance of their mean, so Z-tests stay conservative.  ``adaptive`` and
``statistical`` draw independent numbers (their sample counts vary per pixel).

Reconstruction (``rfilter``): ``film`` (default) uses the scene film's
``rfilter`` — ``box`` or Mitsuba's ``gaussian`` — so the own image estimates
the reference's pixel values; ``box``/``gaussian`` override it.  The variance
of each pixel mean (for the Z-test) is the delta-method variance of the
normalised weighted sum (:mod:`impl.filters`).

Parameters
----------
==============  ======  ==============  ==========================================
name            type    default         meaning
==============  ======  ==============  ==========================================
spp             int     16              samples per pixel (cap for adaptive ones)
sampler         str     jitter          uniform | random | jitter | poisson |
                                        adaptive | statistical | sobol
dimensions      str     independent     independent | stratified (lens, time,
                                        light, BSDF numbers; see above)
jitter          str     white           white (U[−γT, γT]) | gaussian (N(0, σ²T²))
gamma           float   0.5             white-noise jitter amplitude γ
sigma           float   0.1538          Gaussian jitter σ (thesis: T/6.5)
threshold       float   0.02            adaptive: subdivide when a sample differs
                                        from the five's mean by more than this
adaptive_depth  int     3               adaptive: deepest subdivision
tolerance       float   0.01            statistical: CI half-width to reach
confidence      float   0.95            statistical: CI level
rfilter         str     film            film | box | gaussian
g               str     smith           smith | vcavity (masking–shadowing)
shading         str     cook-torrance   cook-torrance | hall (Hall's model, below)
hall_ks         float   1               Hall: k_sr = k_st (highlights and rays)
hall_kd         float   0               Hall: k_dr (diffuse light-source term);
                                        k_dr + k_sr = 1 is enforced
hall_n          float   50              Hall: highlight exponent n = n'
hall_t          float   1               Hall: transmissivity per unit length T_t
hall_tr         float   1               Hall: transmissivity per unit length T_r
max_depth       int     10              deepest ray of a branch (eye ray = 1)
hall_threshold  float   1e-5            cut a branch whose weight is below this
light_samples   int     1               shadow rays per area emitter per diffuse hit
(Phong)                                 ka, ambient, ks, shininess, c1–c3, fatt_clamp
shadows         bool    true            cast shadow rays
(rays)                                  intersect, precision, offset, epsilon,
                                        accel, slab_normals (:mod:`impl.rays`)
packets         bool    false           eye rays of 8×8 tiles as coherent packets
==============  ======  ==============  ==========================================

Structure
---------
Two drivers trace the same ray trees with the same random numbers.  The
fixed-count samplers ``uniform``, ``random``, ``jitter`` and ``sobol`` on a
static scene (no motion blur) with ``shading=cook-torrance`` run on the
tracer core of :mod:`impl.tracer`, as ``whitted``
does: tile by tile (``BATCH_TILE``² pixels per task), each sample index's eye
rays as one batch, the ray trees traced level by level (a wavefront of
reflection and transmission rays, the deepest level first), each chunk of rays
as one batch query and its diffuse leaves lit together
(:func:`impl.lighting.direct_batch`, the light numbers of
:func:`impl.lighting.direct_light_dims` per leaf); with a box filter each
pixel's samples are averaged in the tile, otherwise their records go to the
reconstruction filter.  Every other case — ``poisson``, ``adaptive`` and
``statistical`` (a pixel's sample count or next sample depends on its earlier
ones), motion blur (each sample's scene at its own time) and Hall's model —
traces each sample's tree on its own, depth first (:func:`_tree`).
Leaf k of a sample's tree draws the same light numbers in both, but "leaf k"
counts the leaves in the order each driver meets them, which differs below a
Fresnel split: there the two images differ within their noise, elsewhere they
are the same bit for bit.

Packets (thesis 2.6): with ``packets=true`` either driver runs over 8×8 pixel
tiles; for each sample index the eye rays of the tile's pixels that have that
sample — the same pattern position, lens point and rounding as without
packets — are traced as one packet through the tree, and each sample's ray tree
starts from its precomputed eye hit (secondary and shadow rays as without
packets: incoherent, packets of them are out of scope).  Same image and
counters as ``packets=false`` bit for bit, plus ``packet_nodes`` /
``packet_tests``.  Fixed-count samplers only:
``adaptive`` and ``statistical`` decide each pixel's next sample from its
previous ones, so a tile has no common sample index to batch, and
``packets=true`` with them is refused; so are scenes with moving spheres
(traced by brute force, there is no tree to send packets through).

Leaves out: indirect diffuse light and caustics (as ``whitted``), anisotropic
roughness on moving shapes and under normal or bump maps, delta lights on glossy surfaces, moving emitters,
deforming (non-rigid) meshes, motion other than linear in τ.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene, scene_features
from core.errors import ParamError, UnsupportedError

from .accel.packets import NOT_TRACED, packet_buffers, packet_hits, tile_count, tile_rect
from .camera import SENSOR_THINLENS, camera_params, eye_ray, eye_ray_lens
from .kernel import batch_kernel, by_reference, dereference, interleaved, run_tasks, take_task, task_stride
from .filters import FILTER_BOX, S_B, S_G, S_R, S_W, S_X, S_Y, film_filter, reconstruct
from .fresnel import fresnel_conductor, fresnel_dielectric
from .lighting import (MAP_NONE, SP_DDIM, SP_DSPP, LocalModel, diffuse_albedo, direct_light_dims,
                       environment_radiance,
                       local_model, map_weight, mapped_normal_at, specular_tint, spot_falloff, surface,
                       textured_fresnel, transmittance_tint)
from .bsdf import cook_torrance_sample, diffuse_transmission_sample
from .materials import (MAT_CONDUCTOR, MAT_COOKTORRANCE, MAT_DIELECTRIC, MAT_DIFFTRANS,
                        MAT_ROUGHCONDUCTOR, MAT_ROUGHDIELECTRIC, MaterialArrays, distribution_codes,
                        material_arrays, with_specular_textures_cached, wrapper_arrays)
from .microfacet import G_SMITH, G_VCAVITY, conductor_sample, dielectric_sample
from .phong import PHONG_PARAMS
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, hit, leave, occluded, refine, round_ray
from .rng import uniform, uniform_from, uniform_prefix
from .samplers import (DIM_INDEPENDENT, DIM_SOBOL, DIM_STRATIFIED, adaptive_children, adaptive_disagree,
                       camera_sobol, lens_stratified,
                       dim_1d, dim_2d, gaussian_jitter_pattern, jitter_pattern, poisson_disk_pattern,
                       random_pattern, sobol_pattern, statistical_done, uniform_pattern)
from .scene_arrays import LIGHT_DIRECTIONAL, LIGHT_SPOT, SceneArrays, flatten_cached, scene_memo
from .shading_frame import perturbed_tangent, tangent
from .textures import scalar_param
from .tracer import (DX, DY, DZ, OX, OY, OZ, TMAX, TMIN, Batch, Film, accumulate, closest_batch, first,
                     new_batch, new_film, packet_batch, ray_config_cached, store, take_pending)
from .whitted import (RAY_EYE, RAY_REFLECTION, RAY_TRANSMISSION, TreeWork, admit, arrive, conductor_mirror,
                      dielectric_split, diffuse_leaf, light_leaves, queue_child, queue_delta, tree_work)

__all__ = ["render", "ALGORITHM", "SAMPLERS", "COUNTERS", "Motion", "motion_arrays"]

SAMPLERS = ("uniform", "random", "jitter", "poisson", "adaptive", "statistical", "sobol")
SMP_UNIFORM, SMP_RANDOM, SMP_JITTER, SMP_POISSON, SMP_ADAPTIVE, SMP_STATISTICAL, SMP_SOBOL = range(7)
#: The samplers whose renders of a static scene go through the tracer core in tile batches
#: (a fixed sample count per pixel, each pattern drawn before its samples are traced).
BATCH_SAMPLERS = ("uniform", "random", "jitter", "sobol")
#: ``dimensions``: how the lens, time, light and BSDF numbers of a sample are drawn.
DIMENSIONS = ("independent", "stratified")
G_MODELS = {"smith": G_SMITH, "vcavity": G_VCAVITY}

#: Per-pixel integer counters, in kernel order (whitted's, then the distributed ones).
COUNTERS = ("eye_rays", "shadow_rays", "reflection_rays", "transmission_rays", "hall_cuts",
            "depth_cuts", "tir", "ior_mismatches", "diffuse_hits", "glossy_bounces", "samples")
(_C_EYE, _C_SHADOW, _C_REFL, _C_TRANS, _C_HALL, _C_DEPTH, _C_TIR, _C_IOR, _C_DIFFUSE, _C_GLOSSY,
 _C_SAMPLES) = range(11)

#: Seed offset of the tracer's own random stream (lens, time, BSDF samples), apart from the
#: light samples of :func:`impl.lighting.direct_light_rays` and the pixel patterns.
_STREAM = 0x2545F491

#: |k_dr + k_sr − 1| above this refuses a Hall parameter set.
HALL_SUM_TOLERANCE = 1e-9
_D_LENS, _D_TIME, _D_BSDF = 0, 2, 8  # dimensions of the stream: lens (2), time; bounce k: 8 + 3k ..
#: Dimension numbers of :func:`impl.samplers.dim_2d` / ``dim_1d`` (stratified and Sobol
#: modes): pixel 0, lens 1, time 2, bounce k's direction 3 + 2k and lobe choice 4 + 2k,
#: light sample j at the ray tree's l-th diffuse hit (l + 1)·2^16 + j.
_X_LENS, _X_TIME, _X_BSDF, _X_LIGHT = 1, 2, 3, 1 << 16


class Motion(NamedTuple):
    """What moves over the shutter (motion blur): linearly moving spheres,
    centre(τ) = center + velocity·τ; rigidly moving mesh triangles; the camera."""

    index: np.ndarray       # (K,) sphere index into SceneArrays.sph_*
    center: np.ndarray      # (K, 3) centre at τ = 0
    velocity: np.ndarray    # (K, 3) world units per unit time
    shutter: np.ndarray     # (2,) shutter_open, shutter_close
    tri_index: np.ndarray   # (T,) moving triangle index into SceneArrays.tri_*
    tri_rest: np.ndarray    # (T, 3, 3) its vertices at τ = 0
    tri_nrest: np.ndarray   # (T, 3, 3) its shading normals at τ = 0
    tri_motion: np.ndarray  # (T, 9) velocity, rotation vector ω (rad per unit time), pivot
    cam: np.ndarray         # (10,) moving (1/0), origin c at τ = 0, velocity, rotation vector ω


def motion_arrays(scene: Scene, A: SceneArrays) -> Motion:
    """The moving spheres (``gibench_velocity``), meshes and camera of ``scene`` as
    kernel arrays."""
    spheres = [s for s in scene.shapes if s.kind == "sphere"]
    moving = [(i, s) for i, s in enumerate(spheres) if s.velocity is not None]
    cam = scene.camera
    ns = len(A.sph_radius)
    tri_shape = A.prim_shape[ns:]
    idx, mot = [], []
    zero = np.zeros(3)
    for k, s in enumerate(scene.shapes):
        if s.kind == "mesh" and s.moves:
            tris = np.flatnonzero(tri_shape == k)
            m = np.concatenate([zero if s.velocity is None else s.velocity,
                                zero if s.angular_velocity is None else s.angular_velocity,
                                zero if s.pivot is None else s.pivot])
            idx.append(tris)
            mot.append(np.broadcast_to(m, (len(tris), 9)))
    tri_index = np.concatenate(idx).astype(np.int64) if idx else np.zeros(0, np.int64)
    cam_moves = bool(getattr(cam, "moves", False))
    cm = np.zeros(10)
    if cam_moves:
        cm[0] = 1.0
        cm[1:4] = cam.origin
        cm[4:7] = zero if cam.velocity is None else cam.velocity
        cm[7:10] = zero if cam.angular_velocity is None else cam.angular_velocity
    return Motion(index=np.array([i for i, _ in moving], dtype=np.int64),
                  center=np.array([s.center for _, s in moving], dtype=np.float64).reshape(-1, 3),
                  velocity=np.array([s.velocity for _, s in moving], dtype=np.float64).reshape(-1, 3),
                  shutter=np.array([cam.shutter_open, cam.shutter_close], dtype=np.float64),
                  tri_index=tri_index,
                  tri_rest=np.ascontiguousarray(A.tri_v[tri_index], dtype=np.float64).reshape(-1, 3, 3),
                  tri_nrest=np.ascontiguousarray(A.tri_n[tri_index], dtype=np.float64).reshape(-1, 3, 3),
                  tri_motion=np.ascontiguousarray(np.concatenate(mot) if mot else np.zeros((0, 9))),
                  cam=cm)


@njit(inline="always", cache=True)
def _push(stack_f, stack_i, sp, R: RayConfig, px, py, pz, gx, gy, gz, dx, dy, dz, wr, wg, wb,
          depth, kind, medium):
    """Put a child ray on the tree's stack, leaving the surface to the side it goes to (R's
    offset)."""
    side = 1.0 if gx * dx + gy * dy + gz * dz >= 0.0 else -1.0
    ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
    stack_f[sp, 0] = ox
    stack_f[sp, 1] = oy
    stack_f[sp, 2] = oz
    stack_f[sp, 10] = t0
    stack_f[sp, 3] = dx
    stack_f[sp, 4] = dy
    stack_f[sp, 5] = dz
    stack_f[sp, 6] = wr
    stack_f[sp, 7] = wg
    stack_f[sp, 8] = wb
    stack_f[sp, 9] = medium
    stack_i[sp, 0] = depth
    stack_i[sp, 1] = kind
    return sp + 1


@njit(inline="always", cache=True)
def _rotate(wx, wy, wz, tau, x, y, z):
    """(x, y, z) turned by the rotation vector ω·τ (Rodrigues:
    v cos θ + (k × v) sin θ + k (k·v)(1 − cos θ), θ = |ω|τ, k = ω/|ω|)."""
    w = math.sqrt(wx * wx + wy * wy + wz * wz)
    if w == 0.0:
        return x, y, z
    th = w * tau
    kx, ky, kz = wx / w, wy / w, wz / w
    c, s = math.cos(th), math.sin(th)
    kv = (kx * x + ky * y + kz * z) * (1.0 - c)
    return (x * c + (ky * z - kz * y) * s + kx * kv,
            y * c + (kz * x - kx * z) * s + ky * kv,
            z * c + (kx * y - ky * x) * s + kz * kv)


@njit(cache=True)
def _place_triangles(M: Motion, tau, tri, tri64, trin64):
    """The moving triangles at time τ into ``tri`` (intersection precision), ``tri64``
    and their shading normals into ``trin64``."""
    for k in range(M.tri_index.shape[0]):
        j = M.tri_index[k]
        m = M.tri_motion[k]
        for v in range(3):
            qx, qy, qz = _rotate(m[3], m[4], m[5], tau, M.tri_rest[k, v, 0] - m[6],
                                 M.tri_rest[k, v, 1] - m[7], M.tri_rest[k, v, 2] - m[8])
            px, py, pz = m[6] + qx + m[0] * tau, m[7] + qy + m[1] * tau, m[8] + qz + m[2] * tau
            tri64[j, v, 0], tri64[j, v, 1], tri64[j, v, 2] = px, py, pz
            tri[j, v, 0], tri[j, v, 1], tri[j, v, 2] = px, py, pz
            nx, ny, nz = _rotate(m[3], m[4], m[5], tau, M.tri_nrest[k, v, 0], M.tri_nrest[k, v, 1],
                                 M.tri_nrest[k, v, 2])
            trin64[j, v, 0], trin64[j, v, 1], trin64[j, v, 2] = nx, ny, nz


@njit(inline="always", cache=True)
def _frame(nx, ny, nz):
    """An orthonormal tangent frame (t, b) of the unit normal n (Duff et al. 2017)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


@batch_kernel
def _hall_highlights(scene, rays, materials, mat, mkind, px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz,
                     hall_ks, hall_n, hall_kd, shadows, counts):
    """Hall's light-source terms at a specular surface (thesis 2.4.5.5, Fig. 2.20):
    k_sr Σ_j I_j F(V·H_j) (N·H_j)^n + k_dr Σ_j I_j F_dr (N·L_j) for lights on the
    viewer's side (F_dr: the surface's ``specular_reflectance`` as its colour curve)
    and, at a dielectric, k_st Σ_j I_j (1 − F) |N·H'_j|^n for lights behind the
    surface, H'_j the refraction half-vector −(η_v V + η_l L) (Walter 2007); there is
    no diffuse transmission term (Fig. 2.20 has none).  k_sr = k_st = ``hall_ks``,
    k_dr = ``hall_kd``.  Delta lights only: area emitters already reach specular
    surfaces along their reflected and transmitted rays.  I_j is the light's
    intensity / d² (point; spot times Mitsuba's cone fall-off: 1 inside the beam
    width, linear in angle to 0 at the cutoff, nothing outside) or irradiance
    (directional); reflection terms cast shadow rays.  ``scene``, ``rays`` and
    ``materials``: the flattened scene, the ray configuration and the material arrays by
    reference (:func:`impl.kernel.by_reference`).
    """
    A, R = dereference(scene), dereference(rays)
    S, _wraps, _dist = dereference(materials)
    r = g = b = 0.0
    for li in range(A.light_kind.shape[0]):
        if A.light_kind[li] == LIGHT_DIRECTIONAL:
            lx, ly, lz = -A.light_dir[li, 0], -A.light_dir[li, 1], -A.light_dir[li, 2]
            inv_d2 = 1.0
            dist = np.inf
        else:
            lx = A.light_pos[li, 0] - px
            ly = A.light_pos[li, 1] - py
            lz = A.light_pos[li, 2] - pz
            dist = math.sqrt(lx * lx + ly * ly + lz * lz)
            lx, ly, lz = lx / dist, ly / dist, lz / dist
            inv_d2 = 1.0 / (dist * dist)
            if A.light_kind[li] == LIGHT_SPOT:
                f = spot_falloff(-lx, -ly, -lz, A.light_local, li, A.light_cos_cutoff[li],
                                 A.light_cos_beam[li], A.light_cutoff[li], A.light_inv_tw[li])
                if f == 0.0:
                    continue
                inv_d2 *= f
        cos_l = sx * lx + sy * ly + sz * lz
        if cos_l > 0.0:
            hx, hy, hz = lx + vx, ly + vy, lz + vz
            hn = math.sqrt(hx * hx + hy * hy + hz * hz)
            hx, hy, hz = hx / hn, hy / hn, hz / hn
            ndh = sx * hx + sy * hy + sz * hz
            vdh = vx * hx + vy * hy + vz * hz
            if ndh <= 0.0 and hall_kd == 0.0:
                continue
            if shadows:
                counts[_C_SHADOW] += 1
                side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
                ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
                t1 = (dist * (1.0 - R.shrink_point)) if dist < np.inf else np.inf
                if occluded(R, ox, oy, oz, lx, ly, lz, t0, t1):
                    continue
            dif = hall_kd * cos_l * inv_d2
            r += dif * S.spec_refl[mat, 0] * A.light_rad[li, 0]
            g += dif * S.spec_refl[mat, 1] * A.light_rad[li, 1]
            b += dif * S.spec_refl[mat, 2] * A.light_rad[li, 2]
            if ndh <= 0.0:
                continue
            spec = hall_ks * ndh ** hall_n * inv_d2
            if mkind == MAT_DIELECTRIC:
                F, _, _, _ = fresnel_dielectric(vdh, S.diel_eta[mat])
                fr = fg = fb = F
            else:
                fr = fresnel_conductor(vdh, S.cond_eta[mat, 0], S.cond_k[mat, 0])
                fg = fresnel_conductor(vdh, S.cond_eta[mat, 1], S.cond_k[mat, 1])
                fb = fresnel_conductor(vdh, S.cond_eta[mat, 2], S.cond_k[mat, 2])
            r += spec * fr * S.spec_refl[mat, 0] * A.light_rad[li, 0]
            g += spec * fg * S.spec_refl[mat, 1] * A.light_rad[li, 1]
            b += spec * fb * S.spec_refl[mat, 2] * A.light_rad[li, 2]
        elif mkind == MAT_DIELECTRIC and cos_l < 0.0:
            outside = sx * vx + sy * vy + sz * vz >= 0.0
            eta_v = S.diel_ext[mat] if outside else S.diel_int[mat]
            eta_l = S.diel_int[mat] if outside else S.diel_ext[mat]
            hx, hy, hz = -(eta_v * vx + eta_l * lx), -(eta_v * vy + eta_l * ly), -(eta_v * vz + eta_l * lz)
            hn = math.sqrt(hx * hx + hy * hy + hz * hz)
            if hn == 0.0:
                continue
            ndh = abs(sx * hx + sy * hy + sz * hz) / hn
            F, _, _, _ = fresnel_dielectric(sx * vx + sy * vy + sz * vz, S.diel_eta[mat])
            spec = hall_ks * ndh ** hall_n * inv_d2 * (1.0 - F)
            r += spec * S.spec_trans[mat, 0] * A.light_rad[li, 0]
            g += spec * S.spec_trans[mat, 1] * A.light_rad[li, 1]
            b += spec * S.spec_trans[mat, 2] * A.light_rad[li, 2]
    return r, g, b


@batch_kernel
def _tree(ray, scene, materials, rays, work, seed, pixel, sample, spp, dmode, pre):
    """Radiance (r, g, b) of one eye ray ``ray = (o, d, tmin, tmax)``: whitted's ray tree
    plus sampled glossy bounces.  This runs per sample, so what it reads goes by
    reference (:func:`impl.kernel.by_reference`): ``scene`` the flattened scene,
    ``materials`` its :class:`impl.materials.MaterialArrays`, its
    :class:`impl.materials.WrapperArrays` (for a textured roughness) and its microfacet
    distributions (:func:`impl.materials.distribution_codes`), ``rays`` the ray
    configuration every ray of the tree is intersected with, ``work = (sph_c, tri64,
    trin64, HL, shade, stack_f, stack_i, counts, cut_w)``: sphere centres, triangle
    vertices and shading normals (float64) at the sample's time, for shading; Hall's
    switch and parameters; the tree's and Phong's parameters (``shade`` as
    :func:`_trees` takes it); the ray stack; the pixel's counters and cut weights.  (By
    value, the arrays of these tuples went member by member at every call.)

    ``pre = (t, prim, b1, b2)``: the eye ray's closest hit as :func:`impl.rays.hit`
    returns it, traced in a packet; ``prim = NOT_TRACED`` traces it here like every
    other ray.
    """
    A, R = dereference(scene), dereference(rays)
    S, wraps, dist = dereference(materials)
    sph_c, tri64, trin64, HL, shade, stack_f, stack_i, counts, cut_w = dereference(work)
    ox, oy, oz, dx, dy, dz, tmin, tmax = ray
    hall, hall_ks, hall_n, hall_t, hall_tr, hall_kd = HL[0] > 0.0, HL[1], HL[2], HL[3], HL[4], HL[5]
    (gmodel, max_depth, hall_threshold, ka, ambient, ks, shininess, c1, c2, c3, fclamp, shadows,
     light_samples) = shade
    pre_t, pre_prim, pre_b1, pre_b2 = pre
    ns = A.sph_radius.shape[0]
    r = g = b = 0.0
    stack_f[0, 0] = ox
    stack_f[0, 1] = oy
    stack_f[0, 2] = oz
    stack_f[0, 3] = dx
    stack_f[0, 4] = dy
    stack_f[0, 5] = dz
    stack_f[0, 6] = 1.0
    stack_f[0, 7] = 1.0
    stack_f[0, 8] = 1.0
    stack_f[0, 9] = 0.0
    stack_f[0, 10] = tmin
    stack_i[0, 0] = 1
    stack_i[0, 1] = RAY_EYE
    sp = 1
    leaf = 0
    bounce = 0
    while sp > 0:
        sp -= 1
        rox, roy, roz = stack_f[sp, 0], stack_f[sp, 1], stack_f[sp, 2]
        rdx, rdy, rdz = stack_f[sp, 3], stack_f[sp, 4], stack_f[sp, 5]
        wr, wg, wb = stack_f[sp, 6], stack_f[sp, 7], stack_f[sp, 8]
        medium = stack_f[sp, 9]
        depth = stack_i[sp, 0]
        kind = stack_i[sp, 1]
        if kind == RAY_EYE:
            counts[_C_EYE] += 1
            t0, t1 = tmin, tmax
        else:
            counts[_C_REFL if kind == RAY_REFLECTION else _C_TRANS] += 1
            t0, t1 = stack_f[sp, 10], np.inf
        rox, roy, roz, rdx, rdy, rdz = round_ray(R, rox, roy, roz, rdx, rdy, rdz)
        if kind == RAY_EYE and pre_prim != NOT_TRACED:
            t, prim, b1, b2 = pre_t, pre_prim, pre_b1, pre_b2
        else:
            t, prim, b1, b2 = hit(R, rox, roy, roz, rdx, rdy, rdz, t0, t1)
        if prim < 0:                     # escaped: a constant environment, if any, else black
            er, eg, eb = environment_radiance(A, rdx, rdy, rdz)
            r += wr * er
            g += wg * eg
            b += wb * eb
            continue
        if hall and kind == RAY_TRANSMISSION and hall_t < 1.0:
            att = hall_t ** t             # Hall's T_t^Δ: transmissivity per unit length ^ distance
            wr *= att
            wg *= att
            wb *= att
        if hall and kind == RAY_REFLECTION and hall_tr < 1.0:
            att = hall_tr ** t            # Hall's T_r^Δ, over the distance the reflected ray travels
            wr *= att
            wg *= att
            wb *= att
        shape = A.prim_shape[prim]
        px, py, pz = refine(R, prim, b1, b2, rox + t * rdx, roy + t * rdy, roz + t * rdz)
        gx, gy, gz, sx, sy, sz = surface(prim, b1, b2, px, py, pz, ns, sph_c, A.sph_radius,
                                         tri64, trin64, A.tri_has_n, A.shape_flip[shape])
        vx, vy, vz = -rdx, -rdy, -rdz
        cos_v = sx * vx + sy * vy + sz * vz
        if cos_v > 0.0:
            r += wr * A.shape_emit[shape, 0]
            g += wg * A.shape_emit[shape, 1]
            b += wb * A.shape_emit[shape, 2]
        mat = A.shape_material[shape]
        mkind = S.kind[mat]
        # A two-sided opaque BSDF is seen from the front on both sides.  Every BSDF is
        # evaluated and sampled about n: under a normal or bump map the perturbed normal
        # (Mitsuba's adapters; each scattered direction then weighted by map_weight), else
        # s, or -s on the back.
        back = (A.mat_twosided[mat] and mkind != MAT_DIELECTRIC and mkind != MAT_ROUGHDIELECTRIC
                and mkind != MAT_DIFFTRANS and gx * vx + gy * vy + gz * vz < 0.0)
        nx, ny, nz, code = mapped_normal_at(A, tri64, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy,
                                            vz, back)
        if back:
            gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
        cos_v = nx * vx + ny * vy + nz * vz

        if hall and (mkind == MAT_DIELECTRIC or mkind == MAT_CONDUCTOR):
            hr, hg, hb = _hall_highlights(scene, rays, materials, mat, mkind, px, py, pz, gx, gy, gz, nx, ny,
                                          nz, vx, vy, vz, hall_ks, hall_n, hall_kd, shadows, counts)
            r += wr * hr
            g += wg * hg
            b += wb * hb
            # k_sr I_sr F_sr T_r^Δ and k_st I_st F_st T_t^Δ: the rays from other bodies
            # carry k_sr = k_st too.
            wr *= hall_ks
            wg *= hall_ks
            wb *= hall_ks

        if mkind == MAT_DIELECTRIC:
            twr, twg, twb, tx, ty, tz, there, rwr, rwg, rwb, qx, qy, qz, here = dielectric_split(
                A, S, mat, prim, b1, b2, rdx, rdy, rdz, nx, ny, nz, sx, sy, sz, code, cos_v, medium, wr, wg,
                wb, counts)
            if admit(twr, twg, twb, depth + 1, max_depth, hall_threshold, counts, cut_w):
                sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, tx, ty, tz,
                           twr, twg, twb, depth + 1, RAY_TRANSMISSION, there)
            if admit(rwr, rwg, rwb, depth + 1, max_depth, hall_threshold, counts, cut_w):
                sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, qx, qy, qz,
                           rwr, rwg, rwb, depth + 1, RAY_REFLECTION, here)
            continue

        if _sampled(mkind, cos_v):
            # One sampled direction: gloss and translucency (2.5.6), the thesis's Cook–Torrance
            # and diffuse transmission (2.4.5.2-3).
            ok, ox_, oy_, oz_, nwr, nwg, nwb, nxt, med = _sample_lobe(
                A, S, wraps, dist, gmodel, mat, mkind, prim, b1, b2,
                (px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code), medium, (wr, wg, wb),
                (dmode, seed, pixel, sample, spp), bounce, counts)
            bounce += 1
            if ok and admit(nwr, nwg, nwb, depth + 1, max_depth, hall_threshold, counts, cut_w):
                sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, ox_, oy_, oz_,
                           nwr, nwg, nwb, depth + 1, nxt, med)
            continue

        if cos_v <= 0.0:                 # an opaque BSDF sees the viewer below n: black
            continue

        if mkind == MAT_CONDUCTOR:
            rwr, rwg, rwb, qx, qy, qz = conductor_mirror(A, S, mat, prim, b1, b2, rdx, rdy, rdz, nx, ny, nz,
                                                         sx, sy, sz, code, cos_v, wr, wg, wb)
            if admit(rwr, rwg, rwb, depth + 1, max_depth, hall_threshold, counts, cut_w):
                sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, qx, qy, qz,
                           rwr, rwg, rwb, depth + 1, RAY_REFLECTION, medium)
            continue

        # Diffuse: direct light from every emitter (penumbra: area emitters sampled by area).
        rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
        amb = ambient * ka
        # Leaf k of sample s takes, independent, the light samples of "sample" s + k·spp (leaf
        # 0 those of raycast); stratified or Sobol, its own dimensions of sample s.
        if dmode == DIM_INDEPENDENT:
            lsample, ldim = sample + leaf * spp, 0
        else:
            lsample, ldim = sample, _X_LIGHT * (leaf + 1)
        lr, lg, lb, nsh = direct_light_dims(px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz, rho_r,
                                            rho_g, rho_b, scene, ks, shininess, c1, c2, c3, fclamp,
                                            shadows, light_samples, seed, pixel, lsample, rays,
                                            (dmode, spp, ldim), (sx, sy, sz, code))
        leaf += 1
        counts[_C_SHADOW] += nsh
        counts[_C_DIFFUSE] += 1
        r += wr * (amb * rho_r + lr)
        g += wg * (amb * rho_g + lg)
        b += wb * (amb * rho_b + lb)
    return r, g, b


@njit(inline="always", cache=True)
def _alpha(A, S, wraps, mat, prim, b1, b2):
    """The roughness (α_u, α_v) of a rough conductor or dielectric at a hit: textured
    ``alpha`` / ``alpha_u`` and ``alpha_v`` (slots 2 and 3 of the
    :class:`impl.materials.WrapperArrays` ``wraps``) read as path reads them
    (:func:`impl.textures.scalar_param`), else the constants; α_v = −1 (isotropic, the
    microfacet functions' convention) unless the material is anisotropic."""
    ns = A.sph_radius.shape[0]
    alpha = scalar_param(wraps, mat, 2, S.alpha[mat], ns, prim, A.tri_uv, b1, b2)
    if wraps.aniso[mat] == 0:
        return alpha, -1.0
    return alpha, scalar_param(wraps, mat, 3, wraps.alpha_v[mat], ns, prim, A.tri_uv, b1, b2)


@njit(inline="always", cache=True)
def _eye(cam, seed, pixel, sample, spp, dmode, fx, fy):
    """The eye ray of pixel sample ``sample`` (of ``spp``) at film position (fx, fy),
    through its lens point (drawn only for a ``thinlens`` sensor)."""
    if cam[18] != SENSOR_THINLENS:
        return eye_ray(cam, fx, fy)
    if dmode == DIM_INDEPENDENT:
        u1 = uniform(seed + _STREAM, pixel, sample, _D_LENS)
        u2 = uniform(seed + _STREAM, pixel, sample, _D_LENS + 1)
    elif dmode == DIM_SOBOL:
        u1 = camera_sobol(seed, pixel, sample, 2)
        u2 = camera_sobol(seed, pixel, sample, 3)
    else:
        u1, u2 = lens_stratified(seed, pixel, sample, spp, _X_LENS)
    return eye_ray_lens(cam, fx, fy, u1, u2)


@njit(inline="always", cache=True)
def _bsdf_u(dmode, seed, pixel, sample, spp, bounce):
    """The three numbers (lobe choice, direction) of the ray tree's ``bounce``-th sampled
    BSDF direction of pixel sample ``sample`` (of ``spp``)."""
    if dmode == DIM_INDEPENDENT:
        dim = _D_BSDF + 3 * bounce
        h = uniform_prefix(seed + _STREAM, pixel, sample)
        return uniform_from(h, dim), uniform_from(h, dim + 1), uniform_from(h, dim + 2)
    u1, u2 = dim_2d(dmode, seed, pixel, sample, spp, _X_BSDF + 2 * bounce)
    return dim_1d(dmode, seed, pixel, sample, spp, _X_BSDF + 1 + 2 * bounce), u1, u2


@njit(inline="always", cache=True)
def _sampled(mkind, cos_v):
    """Whether a hit on material kind ``mkind`` continues along one sampled direction: a
    rough dielectric or diffuse transmitter from either side, a rough conductor or
    Cook–Torrance surface seen from above its normal (cos_v > 0)."""
    return mkind == MAT_ROUGHDIELECTRIC or mkind == MAT_DIFFTRANS or (
        cos_v > 0.0 and (mkind == MAT_COOKTORRANCE or mkind == MAT_ROUGHCONDUCTOR))


@njit(inline="always", cache=True)
def _sample_lobe(A, S, wraps, dist, gmodel, mat, mkind, prim, b1, b2, hit, medium, weight, dims, bounce,
                 counts):
    """The one direction a ray of weight ``weight`` continues along at a :func:`_sampled`
    hit (``hit = (p, g, s, v, n, map code)``), drawn from the material's BSDF about n with
    the numbers of the sample's ``bounce``-th sampled direction (:func:`_bsdf_u` of
    ``dims = (dmode, seed, pixel, sample, spp)``; u0 the lobe choice), and the child's
    weight: ``weight`` × f·|cos|/pdf × the material's colour × the map's
    :func:`impl.lighting.map_weight`: ``(ok, direction, weight r, g, b, ray kind,
    medium)``, ``ok`` false where the sample carries nothing; a sample that does counts
    as a glossy bounce in ``counts``.

    * ``roughconductor`` (gloss, 2.5.6): the Cook–Torrance/Walter microfacet BSDF
      (:func:`impl.microfacet.conductor_sample`: the material's D, G = ``gmodel``,
      visible-normal or D·cos sampling, (α_u, α_v) of :func:`_alpha`, in Mitsuba's
      shading frame where anisotropic) × conductor Fresnel at the microfacet (of a
      textured η or k's value at the hit) × ``specular_reflectance`` (× its texture);
    * ``roughdielectric`` (translucency, 2.5.6): reflected with probability F(wi·m), else
      refracted (η² on transmission; :func:`impl.microfacet.dielectric_sample`) ×
      ``specular_reflectance`` / ``specular_transmittance`` (× their textures), the ray
      then in the medium on its side;
    * ``gibench_cooktorrance`` (2.4.5.2): k_d ρ/π + k_s F D G / (4 cos cos), D a roughness
      mixture (:func:`impl.bsdf.cook_torrance_sample`);
    * ``gibench_difftrans`` (2.4.5.3): ρ/π on the viewer's side, τ/π through it
      (:func:`impl.bsdf.diffuse_transmission_sample`)."""
    px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code = hit
    cos_v = nx * vx + ny * vy + nz * vz
    dmode, seed, pixel, sample, spp = dims
    u0, u1, u2 = _bsdf_u(dmode, seed, pixel, sample, spp, bounce)
    au, av = (1.0, -1.0)
    if mkind == MAT_ROUGHDIELECTRIC or mkind == MAT_ROUGHCONDUCTOR:
        au, av = _alpha(A, S, wraps, mat, prim, b1, b2)
    if av >= 0.0:
        # Anisotropic roughness: Mitsuba's shading frame, its tangent along ∂p/∂u
        # (:func:`impl.shading_frame.tangent`); under a normal map that tangent made
        # orthogonal to the perturbed normal (a bump map is refused).
        if code != MAP_NONE:
            tx, ty, tz = tangent(prim, A.sph_radius.shape[0], b1, b2, px, py, pz, A.sph_center, A.tri_v,
                                 A.tri_uv, A.tri_has_uv, gx, gy, gz, sx, sy, sz)
            tx, ty, tz = perturbed_tangent(tx, ty, tz, nx, ny, nz)
        else:
            tx, ty, tz = tangent(prim, A.sph_radius.shape[0], b1, b2, px, py, pz, A.sph_center, A.tri_v,
                                 A.tri_uv, A.tri_has_uv, gx, gy, gz, nx, ny, nz)
        bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
    else:
        tx, ty, tz, bx, by, bz = _frame(nx, ny, nz)
    wix = tx * vx + ty * vy + tz * vz
    wiy = bx * vx + by * vy + bz * vz
    nxt, med = RAY_REFLECTION, medium
    if mkind == MAT_ROUGHDIELECTRIC:
        lx, ly, lz, w, pdf, refl, _eti = dielectric_sample(au, gmodel, S.visible[mat] == 1, S.diel_eta[mat],
                                                          wix, wiy, cos_v, u0, u1, u2, dist[mat], av)
        ok = w > 0.0
        if refl:
            kr, kg, kb = specular_tint(A, mat, prim, b1, b2)
            cr, cg, cb = S.spec_refl[mat, 0] * kr, S.spec_refl[mat, 1] * kg, S.spec_refl[mat, 2] * kb
            med = S.diel_ext[mat] if cos_v >= 0.0 else S.diel_int[mat]
        else:
            kr, kg, kb = transmittance_tint(A, mat, prim, b1, b2)
            cr, cg, cb = S.spec_trans[mat, 0] * kr, S.spec_trans[mat, 1] * kg, S.spec_trans[mat, 2] * kb
            nxt = RAY_TRANSMISSION
            med = S.diel_int[mat] if cos_v >= 0.0 else S.diel_ext[mat]
        cr, cg, cb = w * cr, w * cg, w * cb
    elif mkind == MAT_DIFFTRANS:
        lx, ly, lz, cr, cg, cb, pdf = diffuse_transmission_sample(
            S.spec_refl[mat, 0], S.spec_refl[mat, 1], S.spec_refl[mat, 2], S.spec_trans[mat, 0],
            S.spec_trans[mat, 1], S.spec_trans[mat, 2], wix, wiy, cos_v, u0, u1, u2)
        ok = pdf > 0.0
        if lz * cos_v <= 0.0:
            nxt = RAY_TRANSMISSION
    elif mkind == MAT_COOKTORRANCE:
        lx, ly, lz, cr, cg, cb, pdf = cook_torrance_sample(
            S.spec_trans[mat, 0], S.spec_trans[mat, 1], S.cond_eta[mat], S.cond_k[mat], gmodel,
            S.diel_eta[mat], S.spec_refl[mat, 0], S.spec_refl[mat, 1], S.spec_refl[mat, 2], wix, wiy, cos_v,
            u0, u1, u2)
        ok = pdf > 0.0
    else:
        lx, ly, lz, w, pdf, cos_ih = conductor_sample(au, gmodel, S.visible[mat] == 1, wix, wiy, cos_v, u1,
                                                      u2, dist[mat], av)
        ok = w > 0.0
        fr = fresnel_conductor(cos_ih, S.cond_eta[mat, 0], S.cond_k[mat, 0])
        fg = fresnel_conductor(cos_ih, S.cond_eta[mat, 1], S.cond_k[mat, 1])
        fb = fresnel_conductor(cos_ih, S.cond_eta[mat, 2], S.cond_k[mat, 2])
        kr, kg, kb = specular_tint(A, mat, prim, b1, b2)
        ur, ug, ub = textured_fresnel(A, mat, prim, b1, b2, cos_ih)
        cr = w * fr * S.spec_refl[mat, 0] * kr * ur
        cg = w * fg * S.spec_refl[mat, 1] * kg * ug
        cb = w * fb * S.spec_refl[mat, 2] * kb * ub
    dx = tx * lx + bx * ly + nx * lz
    dy = ty * lx + by * ly + ny * lz
    dz = tz * lx + bz * ly + nz * lz
    f = map_weight(nx, ny, nz, sx, sy, sz, code, dx, dy, dz) if ok else 0.0
    if ok:
        counts[_C_GLOSSY] += 1
    return ok, dx, dy, dz, weight[0] * (cr * f), weight[1] * (cg * f), weight[2] * (cb * f), nxt, med


@njit(inline="always", cache=True)
def _radiance(cam, scene, materials, rays, work, M: Motion, cen, cen64, tri, tri64, trin64, fx, fy, sample,
              spp, dmode, seed, pixel, counts, pre_t, pre_prim, pre_b1, pre_b2):
    """Radiance of the pixel sample number ``sample`` (of ``spp``) at film position (fx, fy).

    The sample's own lens point and shutter time; moving spheres are placed at
    that time in the per-pixel copies ``cen`` (intersection precision) and
    ``cen64`` (shading) of the sphere centres, moving triangles in ``tri`` /
    ``tri64`` / ``trin64`` (copies when meshes move, else the scene's own
    arrays), which the ray configuration ``rays`` and the tree's ``work`` hold
    (:func:`_trees`), and a moving camera's eye ray is moved and turned with the
    camera.  ``scene``, ``materials``, ``rays``, ``work``: the tree's inputs by
    reference (:func:`_tree`).  ``pre_*``: the eye ray's hit traced in a packet (static
    scenes only), or ``pre_prim = NOT_TRACED``.
    """
    ox, oy, oz, dx, dy, dz, tmin, tmax, _ = _eye(cam, seed, pixel, sample, spp, dmode, fx, fy)
    counts[_C_SAMPLES] += 1
    if M.index.shape[0] > 0 or M.tri_index.shape[0] > 0 or M.cam[0] != 0.0:
        if dmode == DIM_INDEPENDENT:
            ut = uniform(seed + _STREAM, pixel, sample, _D_TIME)
        else:
            ut = dim_1d(dmode, seed, pixel, sample, spp, _X_TIME)
        tau = M.shutter[0] + (M.shutter[1] - M.shutter[0]) * ut
        for k in range(M.index.shape[0]):
            i = M.index[k]
            for c in range(3):
                p = M.center[k, c] + M.velocity[k, c] * tau
                cen64[i, c] = p
                cen[i, c] = p
        if M.tri_index.shape[0] > 0:
            _place_triangles(M, tau, tri, tri64, trin64)
        if M.cam[0] != 0.0:
            C = M.cam
            qx, qy, qz = _rotate(C[7], C[8], C[9], tau, ox - C[1], oy - C[2], oz - C[3])
            ox, oy, oz = C[1] + qx + C[4] * tau, C[2] + qy + C[5] * tau, C[3] + qz + C[6] * tau
            dx, dy, dz = _rotate(C[7], C[8], C[9], tau, dx, dy, dz)
    return _tree((ox, oy, oz, dx, dy, dz, tmin, tmax), scene, materials, rays, work, seed, pixel, sample,
                 spp, dmode, (pre_t, pre_prim, pre_b1, pre_b2))


@batch_kernel
def _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64, film, first, spp, dmode,
           shade, seed, pixel, stack_f, stack_i, counts, cut_w, pre_t, pre_prim, pre_b, rgb):
    """:func:`_radiance` of the pixel samples ``first``, ``first + 1``, ... (of ``spp``) at
    the film positions ``film`` (k, 2) into ``rgb`` (k, 3).  ``pre_t``, ``pre_prim``,
    ``pre_b`` ((k,), (k,), (k, 2)): their eye hits traced in a packet, or ``pre_prim[q] =
    NOT_TRACED``.  ``shade = (G model, max_depth, hall_threshold, k_a, I_a, k_s, n, c1, c2,
    c3, fatt_clamp, shadows, light_samples)``.

    ``scene``, ``materials``, ``config``, ``motion``: the flattened scene, its material
    and wrapper arrays (:func:`_tree`), the ray configuration and the :class:`Motion`
    arrays by reference (:func:`impl.kernel.by_reference`, made once per row or tile by
    the caller).  A call of a separate function passes a tuple's arrays member by
    member, which cost more than the ray tree itself when it was made per sample: the
    callers pass a pixel's samples at once (or one at a time where the sampler needs each
    value before choosing the next), and the tree of each sample gets what it reads by
    reference, copied here once per call."""
    R, M = dereference(config), dereference(motion)
    # The rays intersect the pixel's copies of the sphere centres and triangles (moved to
    # each sample's time in place); the structure (if any) is static: render() traces
    # scenes with moving shapes by brute force.
    rays = by_reference(RayConfig(R.form, R.strategy, R.eps, R.shrink_point, R.shrink_area, cen,
                                  R.sph_radius, tri, R.accel, R.node_lo, R.node_hi, R.node_a, R.node_b,
                                  R.prim_idx, R.acc_f, R.acc_i, R.batch_brute))
    work = by_reference((cen64, tri64, trin64, HL, shade, stack_f, stack_i, counts, cut_w))
    for q in range(film.shape[0]):
        rgb[q, 0], rgb[q, 1], rgb[q, 2] = _radiance(
            cam, scene, materials, rays, work, M, cen, cen64, tri, tri64, trin64, film[q, 0], film[q, 1],
            first + q, spp, dmode, seed, pixel, counts, pre_t[q], pre_prim[q], pre_b[q, 0], pre_b[q, 1])


@njit(cache=True)
def _triangle_copies(A, R, M: Motion):
    """Per-pixel triangle vertices (R's precision, float64) and shading normals that
    :func:`_place_triangles` may overwrite: copies when meshes move, else the scene's
    own arrays (nothing is written to them then)."""
    if M.tri_index.shape[0] > 0:
        return R.tri_v.copy(), A.tri_v.copy(), A.tri_n.copy()
    return R.tri_v, A.tri_v, A.tri_n


@njit(inline="always", cache=True)
def _store(recs, pixel, i, fx, fy, w, r, g, b):
    """Sample record i of ``pixel`` (film position, weight, radiance), written by index:
    a view of the shared record array per pixel would count references to it."""
    recs[pixel, i, S_X] = fx
    recs[pixel, i, S_Y] = fy
    recs[pixel, i, S_W] = w
    recs[pixel, i, S_R] = r
    recs[pixel, i, S_G] = g
    recs[pixel, i, S_B] = b


@njit(cache=True)
def _row(cam, A, S, wraps, dist, R, M, HL, y, sampler, dmode, spp, jitter_gauss, gamma, sigma, threshold,
         adaptive_depth, tolerance, z, shade, seed, recs, nrec, counts_all):
    """The sample records of row ``y``'s pixels: pixel p's ``recs[p, :n] = (x, y, weight,
    r, g, b)`` and ``nrec[p] = n``; ``shade`` as :func:`_trees` takes it.  A row per call:
    the call passes the scene's arrays, and the scratch arrays and the references
    :func:`_trees` takes are made once per row."""
    W = int(cam[14])
    scene, config, motion = by_reference(A), by_reference(R), by_reference(M)
    materials = by_reference((S, wraps, dist))
    max_depth = shade[1]
    stack_f = np.empty((max_depth + 2, 11))
    stack_i = np.empty((max_depth + 2, 2), dtype=np.int64)
    cut_w = np.zeros(2)
    cen = R.sph_center.copy()
    cen64 = A.sph_center.copy()
    tri, tri64, trin64 = _triangle_copies(A, R, M)
    k = max(spp, 8)                          # film positions and values of a call of _trees
    film, rgb = np.empty((k, 2)), np.empty((k, 3))
    pre_t, pre_prim, pre_b = np.zeros(k), np.full(k, NOT_TRACED, dtype=np.int64), np.zeros((k, 2))
    for x in range(W):
        pixel = y * W + x
        counts = counts_all[pixel]
        if sampler == SMP_ADAPTIVE:
            # Whitted's adaptive supersampling: squares of (corner, size, depth, 5 value indices).
            cap = max(spp, 5)
            vals = np.zeros((cap, 3))
            pos = np.zeros((cap, 2))
            wts = np.zeros(cap)
            pts = np.zeros((8, 2))
            sq_f = np.zeros((4 * adaptive_depth + 4, 3))
            sq_i = np.zeros((4 * adaptive_depth + 4, 6), dtype=np.int64)
            # Root: corners c00, c10, c01, c11 and the centre.
            pos[0, 0], pos[0, 1] = 0.0, 0.0
            pos[1, 0], pos[1, 1] = 1.0, 0.0
            pos[2, 0], pos[2, 1] = 0.0, 1.0
            pos[3, 0], pos[3, 1] = 1.0, 1.0
            pos[4, 0], pos[4, 1] = 0.5, 0.5
            for i in range(5):
                film[i, 0], film[i, 1] = x + pos[i, 0], y + pos[i, 1]
            _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64, film[:5],
                   np.int64(0), cap, dmode, shade, seed, pixel, stack_f, stack_i, counts, cut_w, pre_t[:5],
                   pre_prim[:5], pre_b[:5], rgb[:5])
            vals[:5] = rgb[:5]
            n = np.int64(5)       # not the literal 5: numba would type the calls below for it too
            sq_f[0, 0], sq_f[0, 1], sq_f[0, 2] = 0.0, 0.0, 1.0
            sq_i[0, 0], sq_i[0, 1], sq_i[0, 2], sq_i[0, 3], sq_i[0, 4], sq_i[0, 5] = 0, 1, 2, 3, 4, 0
            sp = 1
            idx = np.zeros(5, dtype=np.int64)
            while sp > 0:
                sp -= 1
                x0, y0, size = sq_f[sp, 0], sq_f[sp, 1], sq_f[sp, 2]
                for q in range(5):
                    idx[q] = sq_i[sp, q]
                d = sq_i[sp, 5]
                if d < adaptive_depth and n + 8 <= cap and adaptive_disagree(vals, idx, threshold):
                    adaptive_children(x0, y0, size, pts)
                    for q in range(8):
                        pos[n + q, 0], pos[n + q, 1] = pts[q, 0], pts[q, 1]
                        film[q, 0], film[q, 1] = x + pts[q, 0], y + pts[q, 1]
                    _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64,
                           film[:8], n, cap, dmode, shade, seed, pixel, stack_f, stack_i, counts, cut_w,
                           pre_t[:8], pre_prim[:8], pre_b[:8], rgb[:8])
                    vals[n:n + 8] = rgb[:8]
                    e_b, e_l, e_r, e_t = n, n + 1, n + 2, n + 3
                    c = idx[4]
                    h = 0.5 * size
                    # Quadrants (corners c00, c10, c01, c11, centre), pushed 11, 01, 10, 00.
                    quads = ((x0 + h, y0 + h, e_r, idx[3], c, e_t, n + 7),
                             (x0, y0 + h, e_l, c, idx[2], e_t, n + 6),
                             (x0 + h, y0, e_b, idx[1], c, e_r, n + 5),
                             (x0, y0, idx[0], e_b, e_l, c, n + 4))
                    # (corner order per quadrant: c00, c10, c01, c11)
                    quad_c = ((c, e_r, e_t, idx[3]), (e_l, c, idx[2], e_t),
                              (e_b, idx[1], c, e_r), (idx[0], e_b, e_l, c))
                    for k in range(4):
                        qx0, qy0 = quads[k][0], quads[k][1]
                        sq_f[sp, 0], sq_f[sp, 1], sq_f[sp, 2] = qx0, qy0, h
                        sq_i[sp, 0] = quad_c[k][0]
                        sq_i[sp, 1] = quad_c[k][1]
                        sq_i[sp, 2] = quad_c[k][2]
                        sq_i[sp, 3] = quad_c[k][3]
                        sq_i[sp, 4] = quads[k][6]
                        sq_i[sp, 5] = d + 1
                        sp += 1
                    n += 8
                else:
                    a = size * size / 5.0            # a leaf: its five samples share its area
                    for q in range(5):
                        wts[idx[q]] += a
            for i in range(n):
                _store(recs, pixel, i, x + pos[i, 0], y + pos[i, 1], wts[i], vals[i, 0], vals[i, 1],
                       vals[i, 2])
            nrec[pixel] = n
            continue

        if sampler == SMP_STATISTICAL:
            # 4 stratified samples, then uniform ones until the CI is narrow enough.
            pts = np.zeros((4, 2))
            jitter_pattern(2, 0.5, seed, pixel, pts)
            m0 = m1 = m2 = 0.0
            q0 = q1 = q2 = 0.0
            n = np.int64(0)       # not the literal 0: numba would type the calls below for it too
            cap = max(spp, 4)
            while n < cap:
                if n < 4:
                    fx, fy = pts[n, 0], pts[n, 1]
                else:
                    fx = uniform(seed + _STREAM, pixel, n, 6)
                    fy = uniform(seed + _STREAM, pixel, n, 7)
                film[0, 0], film[0, 1] = x + fx, y + fy
                _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64, film[:1], n,
                       cap, dmode, shade, seed, pixel, stack_f, stack_i, counts, cut_w, pre_t[:1], pre_prim[:1],
                       pre_b[:1], rgb[:1])
                rr, gg, bb = rgb[0, 0], rgb[0, 1], rgb[0, 2]
                _store(recs, pixel, n, x + fx, y + fy, 1.0, rr, gg, bb)
                c = n + 1.0
                d0, d1, d2 = rr - m0, gg - m1, bb - m2
                m0 += d0 / c
                m1 += d1 / c
                m2 += d2 / c
                q0 += d0 * (rr - m0)
                q1 += d1 * (gg - m1)
                q2 += d2 * (bb - m2)
                n += 1
                if statistical_done(n, q0, q1, q2, z, tolerance):
                    break
            nrec[pixel] = n
            continue

        pts = np.zeros((spp, 2))
        n = _pattern(sampler, spp, jitter_gauss, gamma, sigma, seed, pixel, pts)
        for s in range(n):
            film[s, 0], film[s, 1] = x + pts[s, 0], y + pts[s, 1]
        _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64, film[:n], np.int64(0),
               n, dmode, shade, seed, pixel, stack_f, stack_i, counts, cut_w, pre_t[:n], pre_prim[:n],
               pre_b[:n], rgb[:n])
        for s in range(n):
            _store(recs, pixel, s, film[s, 0], film[s, 1], 1.0, rgb[s, 0], rgb[s, 1], rgb[s, 2])
        nrec[pixel] = n


@njit(inline="always", cache=True)
def _pattern(sampler, spp, jitter_gauss, gamma, sigma, seed, pixel, pts):
    """A fixed-count sampler's sample positions in the pixel, ``pts[:n]``; returns n."""
    k = int(math.sqrt(spp) + 0.5)
    if sampler == SMP_UNIFORM:
        n = uniform_pattern(k, pts)
    elif sampler == SMP_RANDOM:
        n = random_pattern(spp, seed, pixel, pts)
    elif sampler == SMP_JITTER:
        if jitter_gauss:
            n = gaussian_jitter_pattern(k, sigma, seed, pixel, pts)
        else:
            n = jitter_pattern(k, gamma, seed, pixel, pts)
    elif sampler == SMP_SOBOL:
        n = sobol_pattern(spp, seed, pixel, pts)
    else:
        n, _r = poisson_disk_pattern(spp, seed, pixel, pts)
    return n


@njit(cache=True)
def _tile(cam, A, S, wraps, dist, R, M, HL, tile, sampler, dmode, spp, jitter_gauss, gamma, sigma, shade, seed,
          recs, nrec, counts, packet_counts):
    """One 8×8 tile of a fixed-count sampler: per sample index s, the eye rays of the
    tile's pixels that have a sample s (the pattern positions and lens points of
    :func:`_row`) traced as one packet, then each one's ray tree from its eye hit.
    Static scenes only (the packet is traced through R's tree as built)."""
    W, H = int(cam[14]), int(cam[15])
    x0, y0, nx, ny = tile_rect(tile, W, H)
    P = nx * ny
    scene, config, motion = by_reference(A), by_reference(R), by_reference(M)
    materials = by_reference((S, wraps, dist))
    max_depth = shade[1]
    stack_f = np.empty((max_depth + 2, 11))
    stack_i = np.empty((max_depth + 2, 2), dtype=np.int64)
    cut_w = np.zeros(2)
    cen = R.sph_center.copy()
    cen64 = A.sph_center.copy()
    tri, tri64, trin64 = _triangle_copies(A, R, M)
    pts = np.zeros((P, spp, 2))
    npt = np.zeros(P, dtype=np.int64)
    n_max = 0
    for i in range(P):
        pixel = (y0 + i // nx) * W + x0 + i % nx
        npt[i] = _pattern(sampler, spp, jitter_gauss, gamma, sigma, seed, pixel, pts[i])
        n_max = max(n_max, npt[i])
    rays, hit_t, hit_p, hit_b = packet_buffers(P)
    film, rgb = np.empty((1, 2)), np.empty((1, 3))
    who = np.empty(P, dtype=np.int64)      # packet ray j is pixel who[j] of the tile
    for s in range(n_max):
        m = 0
        for i in range(P):
            if s < npt[i]:
                x, y = x0 + i % nx, y0 + i // nx
                ox, oy, oz, dx, dy, dz, tmin, tmax, _ = _eye(cam, seed, y * W + x, s, npt[i], dmode,
                                                             x + pts[i, s, 0], y + pts[i, s, 1])
                rays[m, 0], rays[m, 1], rays[m, 2] = ox, oy, oz
                rays[m, 3], rays[m, 4], rays[m, 5] = dx, dy, dz
                rays[m, 6], rays[m, 7] = tmin, tmax
                who[m] = i
                m += 1
        packet_hits(R, rays, m, hit_t, hit_p, hit_b, packet_counts)
        for j in range(m):
            i = who[j]
            x, y = x0 + i % nx, y0 + i // nx
            pixel = y * W + x
            fx, fy = x + pts[i, s, 0], y + pts[i, s, 1]
            film[0, 0], film[0, 1] = fx, fy
            _trees(cam, scene, materials, config, motion, HL, cen, cen64, tri, tri64, trin64, film[:1], s,
                   npt[i], dmode, shade, seed, pixel, stack_f, stack_i, counts[pixel], cut_w, hit_t[j:j + 1],
                   hit_p[j:j + 1], hit_b[j:j + 1], rgb[:1])
            _store(recs, pixel, s, fx, fy, 1.0, rgb[0, 0], rgb[0, 1], rgb[0, 2])
    for i in range(P):
        nrec[(y0 + i // nx) * W + x0 + i % nx] = npt[i]


@njit(parallel=True, cache=True)
def _render_kernel(cam, A, S, wraps, dist, R, M, HL, sampler, dmode, spp, jitter_gauss, gamma, sigma, threshold,
                   adaptive_depth, tolerance, z, shade, seed, recs, nrec, counts, packet_counts):
    """The film's tasks in parallel: rows of pixels (:func:`_row`), or with packets
    (``packet_counts`` (tiles, 2), else (0, 2)) 8×8 tiles (:func:`_tile`), in a
    golden-ratio order (:func:`impl.kernel.interleaved`); ``S``, ``wraps`` and ``dist``
    the material arrays, the wrapper arrays and the microfacet distributions
    :func:`_tree` reads (apart: a tuple of tuples cannot be a parallel loop's argument),
    ``shade`` as :func:`_trees` takes it.

    One loop for both: numba compiles a kernel with its whole call tree linked in, so a
    second kernel would compile the ray tree once more.  A ``prange`` loop, not a task
    loop (:func:`impl.kernel.run_tasks`): the tasks take views of the shared record and
    counter arrays per pixel (per packet ray), and numba's parallel body gets its arrays
    without reference counts, where a task loop's threads would update the same counts
    atomically."""
    W, H = int(cam[14]), int(cam[15])
    packets = packet_counts.shape[0] > 0
    n = tile_count(W, H) if packets else H
    stride = task_stride(n)
    for c in prange(n):
        task = interleaved(np.int64(c), n, stride)
        if packets:
            _tile(cam, A, S, wraps, dist, R, M, HL, task, sampler, dmode, spp, jitter_gauss, gamma, sigma,
                  shade, seed, recs, nrec, counts, packet_counts[task])
        else:
            _row(cam, A, S, wraps, dist, R, M, HL, task, sampler, dmode, spp, jitter_gauss, gamma, sigma,
                 threshold, adaptive_depth, tolerance, z, shade, seed, recs, nrec, counts)


# ------------------------------------------------------------ tile batches ---
#
# Fixed-count samplers on static scenes go through the tracer core (:mod:`impl.tracer`)
# as whitted does: a tile's eye rays of one sample index form a batch, and the tile's
# ray trees are traced level by level, each chunk of rays as one batch query and its
# diffuse leaves lit together (:func:`impl.lighting.direct_batch`).  The other cases
# (adaptive and statistical samplers, Poisson patterns, motion blur, Hall's model)
# keep the per-sample trees above.


@batch_kernel
def _shade_batch(A: SceneArrays, S: MaterialArrays, wraps, dist, R: RayConfig, M: LocalModel, gmodel, dmode,
                 max_depth, hall_threshold, seed, sample, spp, T: Batch, K: TreeWork, C: Batch, m, depth,
                 eye):
    """:func:`_tree`'s step at the ``m`` rays of depth ``depth`` in batch ``C`` (hits
    traced), as :func:`impl.whitted._shade` takes it for whitted: each ray's light into
    its eye ray's ``T.L``, its children queued one level deeper (``K.Q``) — both
    Fresnel branches at a smooth dielectric, the mirror branch at a conductor, one
    sampled direction at a glossy, translucent or thesis surface (the ``K.nbsdf``-th of
    its sample, :func:`_bsdf_u`) — and its diffuse leaves lit together, leaf l of the
    sample with the light numbers :func:`_tree` gives it.  ``eye``: the rays are ``T``'s
    own eye rays (unit weight, column = ray)."""
    amb = M.ambient * M.ka
    for i in range(m):
        col, wr, wg, wb, medium, kind, prim, b1, b2, mat, hit = arrive(A, R, T, K, C, i, eye)
        if prim < 0:
            continue
        counts, cut = T.cnt[col], K.cut[col]
        mkind = S.kind[mat]
        if queue_delta(K.Q, R, A, S, mkind, mat, prim, b1, b2, hit, medium, (wr, wg, wb), col, depth + 1,
                       max_depth, hall_threshold, counts, cut):
            continue
        px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code = hit
        if _sampled(mkind, nx * vx + ny * vy + nz * vz):     # one sampled direction (2.4.5, 2.5.6)
            ok, dx, dy, dz, nwr, nwg, nwb, nxt, med = _sample_lobe(
                A, S, wraps, dist, gmodel, mat, mkind, prim, b1, b2, hit, medium, (wr, wg, wb),
                (dmode, seed, T.pixel[col], sample, spp), K.nbsdf[col], counts)
            K.nbsdf[col] += 1
            if ok and admit(nwr, nwg, nwb, depth + 1, max_depth, hall_threshold, counts, cut):
                queue_child(K.Q, depth + 1, R, px, py, pz, gx, gy, gz, dx, dy, dz, nwr, nwg, nwb, med, col,
                            nxt)
            continue
        # Diffuse: a leaf, lit with the rest of the chunk's below; the ambient term now.
        if not diffuse_leaf(A, T, C, i, col, mat, prim, b1, b2, hit, (wr, wg, wb), amb):
            continue
        leaf = K.nleaf[col]
        if dmode == DIM_INDEPENDENT:
            K.lsample[i] = sample + leaf * spp
        else:
            K.lsample[i] = sample
            C.pts[SP_DSPP, i] = spp
            C.pts[SP_DDIM, i] = _X_LIGHT * (leaf + 1)
        K.nleaf[col] = leaf + 1
        counts[_C_DIFFUSE] += 1
    light_leaves(A, R, M, T, K, C, m, seed, eye)


@batch_kernel
def _trees_batch(A: SceneArrays, S: MaterialArrays, wraps, dist, R: RayConfig, M: LocalModel, gmodel, dmode,
                 max_depth, hall_threshold, seed, sample, spp, T: Batch, K: TreeWork):
    """The radiance ``T.L`` of the batch's eye rays (``T.ray``, unrounded): their ray
    trees level by level as :func:`impl.whitted._trees` traces them, the deepest pending
    level first, a chunk of at most one batch at a time (:func:`_shade_batch`).  In a
    packet tile (``T.aos`` not empty) the eye rays go through the tree as one packet
    (:func:`impl.accel.packets.packet_hits`), as the per-sample packet tiles trace them."""
    n = T.n
    for i in range(n):
        T.L[0, i] = T.L[1, i] = T.L[2, i] = 0.0
        K.nleaf[i] = 0
        K.nbsdf[i] = 0
        T.cnt[i, _C_SAMPLES] += 1
        (T.ray[OX, i], T.ray[OY, i], T.ray[OZ, i], T.ray[DX, i], T.ray[DY, i],
         T.ray[DZ, i]) = round_ray(R, T.ray[OX, i], T.ray[OY, i], T.ray[OZ, i], T.ray[DX, i],
                                   T.ray[DY, i], T.ray[DZ, i])
    if T.aos.shape[0] > 0:               # packets: the eye rays through the tree together
        packet_batch(R, T)
    else:
        closest_batch(R, T.ray, n, T.t, T.prim, T.b, T.q, T.qt, T.qp, T.cull)
    # Typed values, not literals: a literal argument would compile _shade_batch again.
    _shade_batch(A, S, wraps, dist, R, M, gmodel, dmode, max_depth, hall_threshold, seed, sample, spp, T,
                 K, T, n, np.int64(1), np.bool_(True))
    Q, C = K.Q, K.C
    d = np.int64(2)
    while d >= 2:
        if Q.count[d] == 0:
            d -= 1
            continue
        m = take_pending(Q, d, C.ray, K.w, K.col, K.kind, C.n)
        closest_batch(R, C.ray, m, C.t, C.prim, C.b, C.q, C.qt, C.qp, C.cull)
        _shade_batch(A, S, wraps, dist, R, M, gmodel, dmode, max_depth, hall_threshold, seed, sample, spp,
                     T, K, C, m, d, np.bool_(False))
        if Q.count[d + 1] > 0:           # its children first: a block holds one chunk's
            d += 1


# Inlined into the task loop, as whitted's tile.
@njit(inline="always", cache=True)
def _batch_tile(cam, A: SceneArrays, S: MaterialArrays, wraps, dist, R: RayConfig, M: LocalModel,
                film: Film, tile, sampler, dmode, spp, jitter_gauss, gamma, sigma, gmodel, max_depth,
                hall_threshold, seed, recs):
    """One tile: each pixel's sample pattern (:func:`_pattern`, as :func:`_row` draws
    it), then per sample index s the tile's eye rays (:func:`_eye`) and their trees
    (:func:`_trees_batch`).  With a box filter each pixel's samples are averaged here
    (:func:`impl.tracer.accumulate`: the box filter's mean and variance of the mean);
    otherwise (``recs`` not empty) each sample's record goes to ``recs[pixel, s]`` for
    :func:`impl.filters.reconstruct`.  Counters (:data:`COUNTERS`) into ``film.cnt``."""
    T = new_batch(film, R, tile, seed)
    n = T.n
    K = tree_work(n, max_depth, R)
    pts = np.empty((n, spp, 2))
    for i in range(n):
        _pattern(sampler, spp, jitter_gauss, gamma, sigma, seed, T.pixel[i], pts[i])
    records = recs.shape[0] > 0
    for s in range(spp):
        for i in range(n):
            fx, fy = T.xy[0, i] + pts[i, s, 0], T.xy[1, i] + pts[i, s, 1]
            T.film[0, i], T.film[1, i] = fx, fy
            (T.ray[OX, i], T.ray[OY, i], T.ray[OZ, i], T.ray[DX, i], T.ray[DY, i], T.ray[DZ, i],
             T.ray[TMIN, i], T.ray[TMAX, i], _) = _eye(cam, seed, T.pixel[i], s, spp, dmode, fx, fy)
        _trees_batch(A, S, wraps, dist, R, M, gmodel, dmode, max_depth, hall_threshold, seed, s, spp, T, K)
        if records:
            for i in range(n):
                _store(recs, T.pixel[i], s, T.film[0, i], T.film[1, i], 1.0, T.L[0, i], T.L[1, i], T.L[2, i])
        else:
            accumulate(T, s)
    store(T, film, spp)


@njit(nogil=True, cache=True)
def _batch_kernel(cam, A: SceneArrays, S: MaterialArrays, wraps, dist, R: RayConfig, M: LocalModel,
                  film: Film, sampler, dmode, spp, jitter_gauss, gamma, sigma, gmodel, max_depth,
                  hall_threshold, seed, recs, queue):
    """The film's tiles, taken from ``queue`` (:func:`impl.kernel.run_tasks`)."""
    n = film.order.shape[0]
    c = take_task(queue)
    while c < n:
        _batch_tile(cam, A, S, wraps, dist, R, M, film, film.order[c], sampler, dmode, spp, jitter_gauss,
                    gamma, sigma, gmodel, max_depth, hall_threshold, seed, recs)
        c = take_task(queue)


# ------------------------------------------------------------- orchestration ---

def _check(p: dict) -> None:
    name = "distributed"
    spp, sampler = p["spp"], p["sampler"]
    if spp < 1:
        raise ParamError(f"{name}: spp must be >= 1, got {spp}")
    if sampler in ("uniform", "jitter"):
        k = int(round(math.sqrt(spp)))
        if k * k != spp:
            raise ParamError(f"{name}: sampler={sampler} needs a square spp (k×k grid), got {spp}")
    if sampler == "adaptive" and spp < 5:
        raise ParamError(f"{name}: sampler=adaptive needs spp >= 5 (corners + centre), got {spp}")
    if sampler == "statistical" and spp < 4:
        raise ParamError(f"{name}: sampler=statistical needs spp >= 4, got {spp}")
    if p.get("dimensions", "independent") == "stratified":
        if sampler in ("adaptive", "statistical", "sobol"):
            raise ParamError(f"{name}: dimensions=stratified shuffles k×k strata over a fixed sample "
                             f"count (sampler uniform, random, jitter or poisson); sampler={sampler} "
                             + ("draws every dimension from its own sequence already"
                                if sampler == "sobol" else "chooses its sample count per pixel"))
        k = int(round(math.sqrt(spp)))
        if k * k != spp:
            raise ParamError(f"{name}: dimensions=stratified needs a square spp (k×k strata per "
                             f"dimension), got {spp}")
    if not 0.0 <= p["gamma"] <= 0.5:
        raise ParamError(f"{name}: gamma must be in [0, 0.5] (ζ within ±γT), got {p['gamma']}")
    if not p["sigma"] >= 0.0:
        raise ParamError(f"{name}: sigma must be >= 0, got {p['sigma']}")
    if not p["threshold"] >= 0.0:
        raise ParamError(f"{name}: threshold must be >= 0, got {p['threshold']}")
    if not 0 <= p["adaptive_depth"] <= 8:
        raise ParamError(f"{name}: adaptive_depth must be in 0..8, got {p['adaptive_depth']}")
    if not p["tolerance"] > 0.0:
        raise ParamError(f"{name}: tolerance must be > 0, got {p['tolerance']}")
    if not 0.0 < p["confidence"] < 1.0:
        raise ParamError(f"{name}: confidence must be in (0, 1), got {p['confidence']}")
    if p["max_depth"] < 1:
        raise ParamError(f"{name}: max_depth must be >= 1 (1 = eye rays only), got {p['max_depth']}")
    if not p["hall_threshold"] >= 0.0:
        raise ParamError(f"{name}: hall_threshold must be >= 0, got {p['hall_threshold']}")
    if p["light_samples"] < 0:
        raise ParamError(f"{name}: light_samples must be >= 0")
    if not (0.0 < p["hall_t"] <= 1.0 and 0.0 < p["hall_tr"] <= 1.0) or p["hall_n"] < 0.0:
        raise ParamError(f"{name}: Hall needs 0 < hall_t <= 1, 0 < hall_tr <= 1, hall_n >= 0 "
                         f"(got hall_t={p['hall_t']}, hall_tr={p['hall_tr']}, hall_n={p['hall_n']})")
    kd, ks = p["hall_kd"], p["hall_ks"]
    if not (0.0 <= kd <= 1.0 and 0.0 <= ks <= 1.0) or abs(kd + ks - 1.0) > HALL_SUM_TOLERANCE:
        raise ParamError(f"{name}: Hall's coefficients must satisfy k_dr + k_sr = 1 with both in "
                         f"[0, 1] (thesis 2.4.5.5); got hall_kd={kd} + hall_ks={ks} = {kd + ks}")


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    """Render ``scene`` with distributed ray tracing; ``params`` as from ``ALGORITHM.parse_params``.
    ``RenderResult.timings`` splits the wall time as the tile tracers do: ``setup_s``
    (materials, flattened scene, ray configuration, sample records), ``trace_s`` (the
    kernel) and ``finish_s`` (reconstruction filter, counters)."""
    t0 = time.perf_counter()
    _check(params)
    if params["shading"] == "hall":
        found = scene_features(scene)
        image = ("Hall's light-source terms model point, spot and directional lights; {} has an image "
                 "(a projector's or a spot's texture), which they leave out")
        for feature, why in (("projector", image), ("spot texture", image),
                             ("textured specular reflectance",
                              "Hall's highlights take a surface's specular_reflectance as one colour; "
                              "{} is a texture"),
                             ("textured specular transmittance",
                              "Hall's highlights take a surface's specular_transmittance as one colour; "
                              "{} is a texture"),
                             ("textured conductor eta/k",
                              "Hall's highlights take a conductor's Fresnel term from one eta + ik; "
                              "{} is a texture")):
            if feature in found:
                where = found[feature] + (f" of {scene.path}" if getattr(scene, "path", None) else "")
                raise UnsupportedError("distributed: shading=hall: " + why.format(where))
    scene = with_specular_textures_cached(scene)
    # The scene's arrays and ray configurations are built once per scene object (as the
    # tile tracers do): a render of the same scene reuses them.
    S = scene_memo(scene, "distributed.materials", lambda: material_arrays(
        scene, algorithm="distributed", model="the distributed ray tracer",
        kinds=("diffuse", "conductor", "dielectric", "roughconductor", "roughdielectric",
               "gibench_cooktorrance", "gibench_difftrans"), distributions=("beckmann", "ggx"),
        anisotropic=True))
    # A textured roughness: the wrappers' texture slots (the scene's other wrappers are refused).
    wraps = scene_memo(scene, "distributed.wrappers", lambda: wrapper_arrays(scene, algorithm="distributed"))
    dist = scene_memo(scene, "distributed.distributions", lambda: distribution_codes(scene))
    A = flatten_cached(scene)
    cam = camera_params(scene.camera, lens=True)
    H, W = scene.camera.film.height, scene.camera.film.width
    fkind, stddev = film_filter(scene.camera.film, params["rfilter"])
    spp = params["spp"]
    sampler = SAMPLERS.index(params["sampler"])
    dmode = (DIM_SOBOL if params["sampler"] == "sobol" else
             DIM_STRATIFIED if params.get("dimensions", "independent") == "stratified" else DIM_INDEPENDENT)
    M = motion_arrays(scene, A)
    packets = bool(params.get("packets", False))
    if packets and params["sampler"] in ("adaptive", "statistical"):
        raise ParamError(f"distributed: packets=true needs a fixed-count sampler (uniform, random, "
                         f"jitter, poisson, sobol); sampler={params['sampler']} chooses each pixel's next "
                         "sample from its previous ones, so a tile has no common sample to batch")
    moving_shapes = M.index.shape[0] > 0 or M.tri_index.shape[0] > 0
    if packets and (moving_shapes or M.cam[0] != 0.0):
        raise ParamError("distributed: packets=true traces a tile's eye rays at one time through a "
                         "static tree, but this scene moves (moving spheres or meshes are traced by "
                         "brute force, a moving camera's eye rays differ per sample time); "
                         "render it with packets=false")
    if moving_shapes and np.any(wraps.aniso):
        where = f" of {scene.path}" if getattr(scene, "path", None) else ""
        raise UnsupportedError(f"distributed: anisotropic roughness on a moving scene{where}: the shading "
                               "frame's tangent is taken from the shapes at rest, not at each sample's time")
    if moving_shapes:
        # A structure built over the primitives at one time would miss them at
        # another: scenes with moving spheres or meshes are traced by brute force.
        if params["accel"] not in ("auto", "none"):
            raise UnsupportedError(
                f"distributed: accel={params['accel']} is built over static primitives; a scene "
                "with moving spheres or meshes is traced with accel=none (or auto)")
        params = {**params, "accel": "none"}
    R = ray_config_cached(scene, A, params, algorithm="distributed")
    z = 0.0                      # the statistical sampler's normal quantile (the others ignore it)
    if params["sampler"] == "statistical":
        from scipy.stats import norm

        z = float(norm.ppf(0.5 * (1.0 + params["confidence"])))
    HL = np.array([1.0 if params["shading"] == "hall" else 0.0, params["hall_ks"], params["hall_n"],
                   params["hall_t"], params["hall_tr"], params["hall_kd"]])
    shade = (G_MODELS[params["g"]], params["max_depth"], float(params["hall_threshold"]),
             params["ka"], params["ambient"], params["ks"], params["shininess"], params["c1"],
             params["c2"], params["c3"], params["fatt_clamp"], params["shadows"],
             params["light_samples"])
    packet_counts = np.zeros((tile_count(W, H) if packets else 0, 2), dtype=np.int64)
    batched = (params["sampler"] in BATCH_SAMPLERS and params["shading"] != "hall" and not moving_shapes
               and M.cam[0] == 0.0)
    # Sample records for the reconstruction filter; a box filter's tile batches average
    # their pixels' samples themselves and keep none.
    records = not batched or fkind != FILTER_BOX
    cap = max(spp, 5)
    recs = np.zeros((W * H if records else 0, cap, 6))
    nrec = np.full(W * H, spp if batched else 0, dtype=np.int64)
    t1 = time.perf_counter()
    if batched:
        film = new_film(W, H, len(COUNTERS), packets)
        light = local_model(params)._replace(sobol=False, dims=dmode)   # distributed's light numbers
        run_tasks(_batch_kernel, cam, A, S, wraps, dist, R, light, film, sampler, dmode, spp,
                  params["jitter"] == "gaussian", float(params["gamma"]), float(params["sigma"]), shade[0],
                  shade[1], shade[2], seed, recs)
        counts = film.cnt.reshape(W * H, len(COUNTERS))
    else:
        counts = np.zeros((W * H, len(COUNTERS)), dtype=np.int64)
        _render_kernel(cam, A, S, wraps, dist, R, M, HL, sampler, dmode, spp, params["jitter"] == "gaussian",
                       float(params["gamma"]), float(params["sigma"]), float(params["threshold"]),
                       int(params["adaptive_depth"]), float(params["tolerance"]), z, shade, seed, recs, nrec,
                       counts, packet_counts)
    t2 = time.perf_counter()
    if records:
        mean, var = reconstruct(recs, nrec, W, H, fkind, stddev)
    else:
        mean, var = film.mean, film.var
    totals = counts.sum(axis=0)
    counters = {name: int(v) for name, v in zip(COUNTERS, totals)}
    counters["mean_spp"] = counters["samples"] / (W * H)
    if packets:
        pc = film.packet if batched else packet_counts
        counters["packet_nodes"], counters["packet_tests"] = (int(v) for v in pc.sum(axis=0))
    spp_img = counts[:, _C_SAMPLES].reshape(H, W).astype(np.float32)
    return RenderResult(image=mean.astype(np.float32), variance=var.astype(np.float32),
                        counters=counters, aovs={"spp": spp_img},
                        timings={"setup_s": t1 - t0, "trace_s": t2 - t1,
                                 "finish_s": time.perf_counter() - t2})


ALGORITHM = Algorithm(
    name="distributed",
    summary="Distributed ray tracing: Whitted's ray tree with anti-aliasing samplers, box/Gaussian "
            "reconstruction, area-light penumbrae, glossy and translucent microfacet BSDFs, thin-lens "
            "depth of field",
    section="thesis 2.4.5, 2.5.1-2.5.9; Cook, Porter, Carpenter 1984",
    transport="whitted",
    params=(
        Param("spp", int, 16, "samples per pixel (the cap for adaptive and statistical)"),
        Param("sampler", str, "jitter", "pixel sampling pattern (sobol: padded Owen-scrambled Sobol "
              "points for the pixel and every other dimension)", choices=SAMPLERS),
        Param("dimensions", str, "independent", "lens, time, light and BSDF numbers: independent "
              "(hashed uniform) or stratified (k×k jittered strata per 2-D dimension, shuffled per "
              "pixel and dimension)", choices=DIMENSIONS),
        Param("jitter", str, "white", "jitter kind: white-noise (gamma) or Gaussian (sigma)",
              choices=("white", "gaussian")),
        Param("gamma", float, 0.5, "white-noise jitter: ζ ~ U[-γT, γT]"),
        Param("sigma", float, 1.0 / 6.5, "Gaussian jitter: ζ ~ N(0, (σT)²)"),
        Param("threshold", float, 0.02, "adaptive: subdivide when a sample differs from the mean by more"),
        Param("adaptive_depth", int, 3, "adaptive: deepest subdivision"),
        Param("tolerance", float, 0.01, "statistical: target half-width of the pixel-mean CI"),
        Param("confidence", float, 0.95, "statistical: confidence level of that interval"),
        Param("rfilter", str, "film", "reconstruction filter (film = the scene film's rfilter)",
              choices=("film", "box", "gaussian")),
        Param("g", str, "smith", "microfacet masking-shadowing G", choices=tuple(G_MODELS)),
        Param("shading", str, "cook-torrance", "cook-torrance (microfacet BSDFs, Mitsuba's model) or "
              "hall (adds Hall's light-source highlights at specular surfaces and T^Δ)",
              choices=("cook-torrance", "hall")),
        Param("hall_ks", float, 1.0, "Hall: k_sr = k_st, weight of the highlights and of the "
              "reflected and transmitted rays at specular surfaces"),
        Param("hall_kd", float, 0.0, "Hall: k_dr, weight of the diffuse light-source term at "
              "specular surfaces (k_dr + k_sr = 1)"),
        Param("hall_n", float, 50.0, "Hall: highlight exponent n = n'"),
        Param("hall_t", float, 1.0, "Hall: transmissivity per unit length T_t of transmitted rays"),
        Param("hall_tr", float, 1.0, "Hall: transmissivity per unit length T_r of reflected rays"),
        Param("max_depth", int, 10, "deepest ray of a tree branch (eye ray = 1)"),
        Param("hall_threshold", float, 1e-5, "cut a branch whose weight (every RGB channel) is below this"),
        Param("light_samples", int, 1, "shadow rays per area emitter per diffuse hit"),
        *PHONG_PARAMS,
        Param("shadows", bool, True, "cast shadow rays"),
        *RAY_PARAMS,
    ),
    render=render,
    models=frozenset({"camera motion", "mesh motion", "envmap", "gibench_cooktorrance",
                      "gibench_difftrans", "projector", "spot texture", "normalmap", "bumpmap",
                      "textured specular reflectance", "textured specular transmittance",
                      "textured conductor eta/k", "textured roughness", "anisotropic roughness"}),
    # Poisson-disk patterns (a per-pixel sample count) run the per-sample ray trees.
    kernel_variants=({"sampler": "poisson"}, {"packets": True}),
)
