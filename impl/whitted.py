"""Whitted ray tracing — registered as ``whitted``.

The recursive ray tracer of Whitted (T. Whitted, "An improved illumination
model for shaded display", CACM 23(6), 1980, :doi:`10.1145/358876.358882`)
as the thesis describes it: the four kinds of rays of 2.2 (eye, shadow,
reflection, transmission rays), the ray tree of 2.2.1 (every hit on a
specular surface spawns a reflection and, if transparent, a transmission
ray; the tree is followed until no ray remains), the reflection direction
R = I − 2(N·I)N and Snell's law with total internal reflection of 2.4.4, and
the adaptive tree depth of Hall's model (2.4.5.5 and 2.6: a branch is cut
when its largest possible contribution to the pixel falls below a threshold;
R. A. Hall and D. P. Greenberg, "A testbed for realistic image synthesis",
IEEE CG&A 3(8), 1983).

What it computes
----------------
For every eye ray, the ray tree over *delta* (perfectly specular) surfaces:

* ``conductor`` (Mitsuba semantics): mirror reflection weighted by
  ``specular_reflectance`` × the conductor Fresnel reflectance of the complex
  index ``eta + i k`` (RGB); ``material="none"`` (the default) is an ideal
  mirror, Fresnel = 1.  One-sided: seen from behind it is black.
* ``dielectric``: the exact unpolarised Fresnel reflectance F splits the ray
  *deterministically* into a reflected branch (weight F ×
  ``specular_reflectance``) and a transmitted branch (weight (1 − F) ×
  ``specular_transmittance`` × η_ti²; the η_ti² = (n_i / n_t)² factor is the
  radiance scaling of Mitsuba's Radiance transport mode: solid angle is
  compressed when light enters a denser medium).  Normals point outward, so a
  ray enters when cos θ_i = N·(−I) > 0; ``eta = int_ior / ext_ior``.
  Total internal reflection leaves the reflected branch only (F = 1).
* At the first non-delta (``diffuse``) hit of a branch: the direct light of
  every emitter — delta lights and area emitters (``light_samples`` shadow
  rays each) — with the Phong/Lambert model of ``raycast``
  (:mod:`impl.lighting`), and the branch ends.  With ``sampler=sobol`` the
  pixel positions and the light samples are Owen-scrambled Sobol points
  (:func:`impl.lighting.light_uv_sobol`; the k-th diffuse leaf of a sample
  has its own run of the sequence), except at the rare leaves beyond a
  batch's capacity, which draw hashed numbers.
* Emission ``L_e`` of area emitters met by eye rays and by every ray of a
  delta chain (front side only, as Mitsuba's ``area``).

So with the default parameters it estimates exactly what the matched Mitsuba
reference ``whitted`` (:mod:`references.whitted_integrator`) computes, which
follows one of the two branches at random instead of splitting.

Ray tree
--------
Depth counts rays along a branch: an eye ray has depth 1, a ray spawned at a
hit of a depth-d ray has depth d + 1, and rays deeper than ``max_depth`` are
not traced (``max_depth = 1`` is ray casting; Mitsuba's ``path`` with
``max_depth = m + 1`` truncates paths at the same length).  A child whose
weight — the product of the Fresnel/reflectance weights along its branch —
has every RGB channel below ``hall_threshold`` is cut (Hall's criterion);
``hall_threshold = 0`` follows every branch with a non-zero weight.  The
default 1e-5 keeps the cut-off bias (≤ 1e-5 × the radiance of a cut ray) below
the Z-test's noise floor against Mitsuba on the whitted scenes of ``suites/``.
The tree is walked depth-first with an explicit stack of pending rays
(origin, direction, RGB weight, depth, ray type, IOR of the medium it travels
in), never by recursion.

Counters: rays by type (``eye_rays``, ``shadow_rays``, ``reflection_rays``,
``transmission_rays``), ``hall_cuts`` and ``depth_cuts`` (branches not
traced), ``tir`` (total internal reflections), ``ior_mismatches`` (a ray hits
a dielectric from a medium whose IOR differs from the interface's: the
scene's indices are mutually inconsistent, as Mitsuba's manual warns),
``diffuse_hits`` (branch leaves lit by shadow rays) and
``tree_depth_histogram`` (index d: eye rays whose deepest traced ray had
depth d).  AOVs ``hall_cut_weight`` / ``depth_cut_weight``: per pixel, the
mean over samples of the summed largest-channel weight of the cut branches;
the bias of cutting is at most that weight times the largest radiance a cut
ray can carry.

Intersection, precision and self-intersection (thesis 2.3.3–2.3.4)
-----------------------------------------------------------------
Four parameters choose how every ray of the tree is intersected and how a
spawned ray leaves its surface (:mod:`impl.rays`, shared with ``raycast``):

* ``intersect`` — the ray–sphere form used for *every* sphere test: eye,
  reflection, transmission and shadow rays (:mod:`impl.intersect`):
  ``algebraic`` (the quadratic of 2.3.1), ``geometric`` (2.3.2) or ``stable``
  (Haines et al. 2019, the default).  Triangles always use Möller–Trumbore.
* ``precision`` — the precision of the intersection arithmetic.  ``float32``
  rounds each ray (origin and direction) and every primitive's coordinates
  to float32 and runs the intersection kernels, the sphere-hit refinement and
  the offset in float32; ``t`` comes back as float64.  The shading — hit
  point, normals, Fresnel weights, Snell directions, light sums — stays
  float64 in both: the precision problems of thesis 2.3.4 are those of the
  intersection computation (a sphere lost to cancellation in the
  discriminant, a hit point off its surface), and float64 shading keeps them
  apart from the rounding of the radiance arithmetic.  Each precision is a
  compiled specialisation of the kernels (the primitives' dtype), so the
  float64 default carries no float32 code.
* ``offset`` — how reflection, transmission and shadow rays leave the hit
  point p, towards the side of the geometric normal n they go to:
  ``epsilon`` keeps the origin at p and ignores hits with t ≤ ``epsilon``
  (t_min ε along the ray); ``normal`` moves the origin to p + ``epsilon``·n;
  ``robust`` (default) moves each coordinate by 256 ulps along n (Wächter &
  Binder 2019, :func:`impl.offset.offset_ray`), in the chosen precision, and
  ignores ``epsilon``.  Sphere hits are first projected back onto the sphere
  in the intersection precision (pbrt's refinement), which brings their error
  to a few ulps of p, below the robust offset.  Shadow rays are aimed from
  the offset origin at the light point.

Pixel sampling as in ``raycast``: ``spp = 1`` traces the pixel centre,
``spp = k²`` a k×k jittered grid (box filter), returning the variance of the
pixel mean.

Shadows through glass (thesis 2.2: shadow rays pass transparent objects,
attenuated by their transmittance): with ``shadow_mode=transmissive`` a
shadow ray that meets smooth ``dielectric`` surfaces keeps its light times
(1 − F) × ``specular_transmittance`` per interface, along the straight
segment (:func:`impl.lighting.shadow_filter`); any other surface still
blocks it.  This is Whitted's approximation, not light transport: the
segment is not refracted, so the light is not focused into a caustic; its
error against full transport (``path``) is a model error, reported by the
``thesis`` suite on ``thesis/glass_shadow.xml`` and checked by
``tests/test_transmissive_shadows.py``.  The default ``opaque`` stops shadow rays at
glass (the matched Mitsuba reference does the same).

Leaves out: indirect diffuse light (no interreflection between diffuse
surfaces), light transported *through* or *off* specular surfaces to a
diffuse one (caustics; shadow rays are blocked by glass unless
``shadow_mode=transmissive`` lets them through unrefracted), glossy BSDFs
(``roughconductor`` and other materials raise ``NotImplementedError``),
absorbing media inside dielectrics, named conductor IOR spectra.

Parameters
----------
==============  ======  =======  =============================================
name            type    default  meaning
==============  ======  =======  =============================================
spp             int     1        pixel samples: 1 = centre, k² = k×k strata
max_depth       int     10       deepest ray of a branch (eye ray = 1)
hall_threshold  float   1e-5     cut a branch whose weight is below this
light_samples   int     16       shadow rays per area emitter per diffuse hit
ka              float   0        ambient coefficient k_a (× ρ)
ambient         float   0        ambient intensity I_a
ks              float   0        Phong specular coefficient at diffuse hits
shininess       float   32       Phong exponent n
c1, c2, c3      float   0, 0, 1  f_att = 1 / (c1 + c2 d + c3 d²)
fatt_clamp      bool    false    clamp f_att to 1, as the thesis does
shadows         bool    true     cast shadow rays
shadow_mode     str     opaque   opaque: a shadow ray stops at any surface |
                                 transmissive: it passes smooth dielectrics,
                                 filtered by their Fresnel transmittance
intersect       str     stable   ray–sphere form for every sphere test:
                                 algebraic | geometric | stable
precision       str     float64  intersection arithmetic: float32 | float64
                                 (shading is float64 in both)
offset          str     robust   how secondary and shadow rays leave a
                                 surface: epsilon (t_min = ε) | normal
                                 (origin p + ε·n) | robust (Wächter–Binder)
epsilon         float   1e-4     ε of offset=epsilon and offset=normal, in
                                 scene units (robust ignores it)
accel           str     auto     acceleration structure of every ray query
                                 (thesis 2.6, :mod:`impl.accel`)
slab_normals    int     7        plane normals of accel=slabs
packets         bool    false    trace the eye rays of 8×8 pixel tiles as
                                 coherent packets (:mod:`impl.accel.packets`)
==============  ======  =======  =============================================

Structure: the tracer core of :mod:`impl.tracer` renders tile by tile and
traces each sample index's eye rays of a tile as one batch (with
``packets=true`` as packets through the tree, :mod:`impl.accel.packets`);
each pixel's ray tree (:func:`_trees`) then starts from its eye hit.
Reflection and transmission rays are traced one at a time; the diffuse
leaves of the trees are collected and lit together
(:func:`impl.lighting.direct_batch`, the shadow rays of one light sample as
one batch), with the random numbers each leaf would draw on its own (leaf k
of sample s those of "sample" s + k·spp).  Same image and counters with and
without packets, plus ``packet_nodes`` and ``packet_tests``; packets need a
tree (``accel=auto`` then means ``bvh-sah``).

Example::

    from core.loader import load_scene
    from impl.whitted import ALGORITHM as algo
    res = algo.render(load_scene("suites/spheres/whitted_classic.xml"),
                      algo.parse_params({"spp": 16}), seed=0)
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit, prange

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene
from core.errors import ParamError

from .camera import camera_params
from .kernel import batch_kernel, interleaved, task_stride
from .fresnel import fresnel_conductor, fresnel_dielectric, reflect, refract
from .lighting import (SHADOW_MODES, SP_G, SP_P, SP_RHO, SP_S, SP_V, LocalModel, diffuse_albedo,
                       direct_batch, direct_light_rays, environment_radiance, local_model, surface)
from .materials import SpecularArrays, material_arrays
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, hit, leave, ray_config, refine, round_ray
from .phong import PHONG_PARAMS
from .sampling import SAMPLER_PARAM, check_spp, sampler_code
from .scene_arrays import MATERIAL_CODES, SceneArrays, flatten, flatten_cached, scene_memo
from .tracer import (accumulate, Batch, DX, DY, DZ, eye_batch, Film, film_counters, film_result,
                     new_batch, new_film, new_points, OX, OY, OZ, ray_config_cached, run_tiles, store,
                     TMAX, TMIN)

__all__ = ["render", "trace", "material_arrays", "SpecularArrays", "COUNTERS", "ALGORITHM"]

MAT_DIFFUSE = MATERIAL_CODES["diffuse"]
MAT_CONDUCTOR = MATERIAL_CODES["conductor"]
MAT_DIELECTRIC = MATERIAL_CODES["dielectric"]

RAY_EYE, RAY_REFLECTION, RAY_TRANSMISSION = 0, 1, 2

#: Names of the per-pixel integer counters, in kernel order.
COUNTERS = ("eye_rays", "shadow_rays", "reflection_rays", "transmission_rays", "hall_cuts",
            "depth_cuts", "tir", "ior_mismatches", "diffuse_hits")
_C_EYE, _C_SHADOW, _C_REFL, _C_TRANS, _C_HALL, _C_DEPTH, _C_TIR, _C_IOR, _C_DIFFUSE = range(9)

#: Two IORs closer than this count as the same medium (Mitsuba stores them as float32).
IOR_TOLERANCE = 1e-5

#: Diffuse leaves lit together (one batch of shadow rays per light sample); the batch is
#: lit before the next tree once fewer than LEAF_MARGIN columns are free, and a tree that
#: still fills it lights its further leaves on the spot.
LEAF_BATCH = 512
LEAF_MARGIN = 64


# ------------------------------------------------------------------ kernels ---

@njit(inline="always", cache=True)
def _push(stack_f, stack_i, sp, R: RayConfig, px, py, pz, gx, gy, gz, dx, dy, dz, wr, wg, wb,
          depth, kind, medium):
    """Put a child ray on the stack, leaving the surface to the side it goes to (R's offset)."""
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
def _admit(wr, wg, wb, depth, max_depth, hall_threshold, counts, cut_w):
    """Whether a child branch of weight w and depth ``depth`` is traced; counts the cuts."""
    wmax = max(wr, wg, wb)
    if wmax <= 0.0:                  # contributes exactly nothing
        return False
    if depth > max_depth:
        counts[_C_DEPTH] += 1
        cut_w[1] += wmax
        return False
    if wmax < hall_threshold:        # Hall: largest possible contribution below the threshold
        counts[_C_HALL] += 1
        cut_w[0] += wmax
        return False
    return True


@batch_kernel
def _trees(A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
           hall_threshold, seed, sample, spp, T: Batch, traced, stack_f, stack_i, cut_w, P: Batch,
           lw, lcol, lsample, nshadow, lcount):
    """The radiance ``T.L`` of the batch's eye rays (``T.ray``), each by walking its ray
    tree depth-first with an explicit stack (``stack_f``, ``stack_i``); per-ray counters
    into ``T.cnt`` (:data:`COUNTERS`, then the tree-depth histogram), cut weights into
    ``cut_w``.  With ``traced`` the eye rays' closest hits are ``T.t``, ``T.prim``,
    ``T.b`` (:func:`impl.tracer.eye_batch`), else they are traced here like every other
    ray.

    Diffuse leaves are deferred: a leaf's shading point goes to the next free column of
    the point batch ``P`` (rows :data:`impl.lighting.SP_P` …) with its branch weight
    ``lw``, its eye ray's column ``lcol`` and its sample index ``lsample``, and
    :func:`_light_leaves` adds weight × its direct light to the eye ray's radiance: before
    the next tree once fewer than ``LEAF_MARGIN`` columns are free, and after the last.
    A tree that fills the batch lights its further leaves on the spot, one shadow ray at
    a time (:func:`impl.lighting.direct_light_rays`: the same light).
    """
    ns = A.sph_radius.shape[0]
    nc = len(COUNTERS)
    pts, lpixel, lactive = P.pts, P.pixel, P.active
    for col in range(T.n):
        if lcount[0] > LEAF_BATCH - LEAF_MARGIN:
            _light_leaves(A, R, M, P, lw, lcol, lsample, nshadow, lcount, T, seed)
        counts = T.cnt[col, :nc]
        hist = T.cnt[col, nc:]
        cut = cut_w[col]
        ox, oy, oz = T.ray[OX, col], T.ray[OY, col], T.ray[OZ, col]
        dx, dy, dz = T.ray[DX, col], T.ray[DY, col], T.ray[DZ, col]
        tmin, tmax = T.ray[TMIN, col], T.ray[TMAX, col]
        pre_t, pre_prim, pre_b1, pre_b2 = T.t[col], T.prim[col], T.b[0, col], T.b[1, col]
        pixel = T.pixel[col]
        r = g = b = 0.0
        sp = 0
        # The eye ray: unit weight, depth 1, medium unknown (0).
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
        deepest = 0
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
            if depth > deepest:
                deepest = depth

            # Intersect (and shade) the ray as rounded to the intersection precision.
            rox, roy, roz, rdx, rdy, rdz = round_ray(R, rox, roy, roz, rdx, rdy, rdz)
            if kind == RAY_EYE and traced:
                t, prim, b1, b2 = pre_t, pre_prim, pre_b1, pre_b2
            else:
                t, prim, b1, b2 = hit(R, rox, roy, roz, rdx, rdy, rdz, t0, t1)
            if prim < 0:                     # escaped: a constant environment, if any, else black
                er, eg, eb = environment_radiance(A, rdx, rdy, rdz)
                r += wr * er
                g += wg * eg
                b += wb * eb
                continue
            shape = A.prim_shape[prim]
            px, py, pz = refine(R, prim, b1, b2, rox + t * rdx, roy + t * rdy, roz + t * rdz)
            gx, gy, gz, sx, sy, sz = surface(prim, b1, b2, px, py, pz, ns, A.sph_center, A.sph_radius,
                                             A.tri_v, A.tri_n, A.tri_has_n, A.shape_flip[shape])
            vx, vy, vz = -rdx, -rdy, -rdz
            cos_v = sx * vx + sy * vy + sz * vz
            # Emitted radiance L_e of an area emitter (front side only).
            if cos_v > 0.0:
                r += wr * A.shape_emit[shape, 0]
                g += wg * A.shape_emit[shape, 1]
                b += wb * A.shape_emit[shape, 2]
            mat = A.shape_material[shape]
            mkind = A.mat_kind[mat]

            if mkind == MAT_DIELECTRIC:
                # Fresnel split at a smooth interface (thesis 2.4.4), Mitsuba's sign conventions.
                eta = S.diel_eta[mat]
                if medium > 0.0:
                    expected = S.diel_ext[mat] if cos_v >= 0.0 else S.diel_int[mat]
                    if abs(medium - expected) > IOR_TOLERANCE:
                        counts[_C_IOR] += 1
                F, cos_t, eta_it, eta_ti = fresnel_dielectric(cos_v, eta)
                if F == 1.0 and cos_t == 0.0:
                    counts[_C_TIR] += 1
                here = S.diel_ext[mat] if cos_v >= 0.0 else S.diel_int[mat]
                there = S.diel_int[mat] if cos_v >= 0.0 else S.diel_ext[mat]
                # Transmitted branch: (1 − F) T_s η_ti² (radiance scaling), pushed first so the
                # reflected branch is walked first.
                if F < 1.0:
                    scale = (1.0 - F) * eta_ti * eta_ti
                    twr = wr * scale * S.spec_trans[mat, 0]
                    twg = wg * scale * S.spec_trans[mat, 1]
                    twb = wb * scale * S.spec_trans[mat, 2]
                    if _admit(twr, twg, twb, depth + 1, max_depth, hall_threshold, counts, cut):
                        tx, ty, tz = refract(rdx, rdy, rdz, sx, sy, sz, cos_v, cos_t, eta_ti)
                        sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, tx, ty, tz,
                                   twr, twg, twb, depth + 1, RAY_TRANSMISSION, there)
                rwr = wr * F * S.spec_refl[mat, 0]
                rwg = wg * F * S.spec_refl[mat, 1]
                rwb = wb * F * S.spec_refl[mat, 2]
                if _admit(rwr, rwg, rwb, depth + 1, max_depth, hall_threshold, counts, cut):
                    qx, qy, qz = reflect(rdx, rdy, rdz, sx, sy, sz)
                    sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, qx, qy, qz,
                               rwr, rwg, rwb, depth + 1, RAY_REFLECTION, here)
                continue

            # Opaque one-sided BSDFs: a two-sided one is seen from the front on both sides.
            if A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0:
                gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
                cos_v = -cos_v
            if cos_v <= 0.0:
                continue

            if mkind == MAT_CONDUCTOR:
                # Mirror reflection R = I − 2(N·I)N weighted by specular_reflectance × F_conductor.
                fr = fresnel_conductor(cos_v, S.cond_eta[mat, 0], S.cond_k[mat, 0])
                fg = fresnel_conductor(cos_v, S.cond_eta[mat, 1], S.cond_k[mat, 1])
                fb = fresnel_conductor(cos_v, S.cond_eta[mat, 2], S.cond_k[mat, 2])
                rwr = wr * fr * S.spec_refl[mat, 0]
                rwg = wg * fg * S.spec_refl[mat, 1]
                rwb = wb * fb * S.spec_refl[mat, 2]
                if _admit(rwr, rwg, rwb, depth + 1, max_depth, hall_threshold, counts, cut):
                    qx, qy, qz = reflect(rdx, rdy, rdz, sx, sy, sz)
                    sp = _push(stack_f, stack_i, sp, R, px, py, pz, gx, gy, gz, qx, qy, qz,
                               rwr, rwg, rwb, depth + 1, RAY_REFLECTION, medium)
                continue

            # Diffuse: direct light from every emitter, and the branch ends (thesis 2.2).
            rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
            amb = M.ambient * M.ka
            # Leaf k of sample s draws the light samples of "sample" s + k·spp: leaf 0
            # uses raycast's numbers, the others are independent of them.
            k = lcount[0]
            if k < lactive.shape[0]:
                pts[SP_P, k], pts[SP_P + 1, k], pts[SP_P + 2, k] = px, py, pz
                pts[SP_G, k], pts[SP_G + 1, k], pts[SP_G + 2, k] = gx, gy, gz
                pts[SP_S, k], pts[SP_S + 1, k], pts[SP_S + 2, k] = sx, sy, sz
                pts[SP_V, k], pts[SP_V + 1, k], pts[SP_V + 2, k] = vx, vy, vz
                pts[SP_RHO, k], pts[SP_RHO + 1, k], pts[SP_RHO + 2, k] = rho_r, rho_g, rho_b
                lw[0, k], lw[1, k], lw[2, k] = wr, wg, wb
                lcol[k], lsample[k], lpixel[k] = col, sample + leaf * spp, pixel
                lactive[k] = True
                lcount[0] = k + 1
                lr = lg = lb = 0.0
            else:
                lr, lg, lb, nsh = direct_light_rays(
                    px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, rho_r, rho_g, rho_b, A, M.ks,
                    M.shininess, M.c1, M.c2, M.c3, M.fclamp, M.shadows, M.light_samples, seed, pixel,
                    sample + leaf * spp, R, M.shadow_eta, M.shadow_trans)
                counts[_C_SHADOW] += nsh
            leaf += 1
            counts[_C_DIFFUSE] += 1
            r += wr * (amb * rho_r + lr)
            g += wg * (amb * rho_g + lg)
            b += wb * (amb * rho_b + lb)
        hist[deepest] += 1
        T.L[0, col], T.L[1, col], T.L[2, col] = r, g, b
    _light_leaves(A, R, M, P, lw, lcol, lsample, nshadow, lcount, T, seed)


@njit(cache=True)
def _tile(cam, A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
          hall_threshold, film: Film, tile, spp, seed, cut):
    """One tile (:mod:`impl.tracer`): per sample index, the eye rays and their hits, then
    each pixel's ray tree from its eye hit (:func:`_trees`).  Per-pixel counters:
    :data:`COUNTERS`, then the tree-depth histogram (``max_depth + 1`` columns); cut
    weights go to ``cut``."""
    T = new_batch(film, R, tile)
    work = _scratch(T.n, max_depth, R)
    for s in range(spp):
        eye_batch(cam, R, T, s, spp, seed, film.packets, film.sampler)
        _trees(A, S, R, M, max_depth, hall_threshold, seed, s, spp, T, True, *work)
        accumulate(T, s)
    store(T, film, spp)
    cut_w = work[2]
    for i in range(T.n):
        x, y = T.x0 + i % T.nx, T.y0 + i // T.nx
        cut[y, x, 0] = cut_w[i, 0] / spp
        cut[y, x, 1] = cut_w[i, 1] / spp


@njit(cache=True)
def _scratch(n, max_depth, R: RayConfig):
    """The working arrays of :func:`_trees` for batches of ``n`` eye rays: the tree stack
    (depth-first: below the popped ray of depth d wait at most one sibling per level
    2..d, plus its two children, so max_depth + 1 slots suffice), the cut weights and
    the batch of deferred diffuse leaves."""
    return (np.empty((max_depth + 2, 11)), np.empty((max_depth + 2, 2), dtype=np.int64),
            np.zeros((n, 2)), new_points(LEAF_BATCH, R), np.empty((3, LEAF_BATCH)),
            np.empty(LEAF_BATCH, np.int64), np.empty(LEAF_BATCH, np.int64),
            np.zeros(LEAF_BATCH, np.int64), np.zeros(1, np.int64))


@batch_kernel
def _light_leaves(A: SceneArrays, R: RayConfig, M: LocalModel, P: Batch, lw, lcol, lsample,
                  nshadow, lcount, T: Batch, seed):
    """Light the ``lcount[0]`` collected diffuse leaves together
    (:func:`impl.lighting.direct_batch`: each light sample's shadow rays as one batch) and
    add each one's weighted light to its eye ray's radiance and shadow-ray count."""
    m = lcount[0]
    if m == 0:
        return
    for k in range(m):
        P.L[0, k] = P.L[1, k] = P.L[2, k] = 0.0
        nshadow[k] = 0
    direct_batch(A, R, M, P, lsample, seed, nshadow)
    for k in range(m):
        i = lcol[k]
        T.L[0, i] += lw[0, k] * P.L[0, k]
        T.L[1, i] += lw[1, k] * P.L[1, k]
        T.L[2, i] += lw[2, k] * P.L[2, k]
        T.cnt[i, _C_SHADOW] += nshadow[k]
        P.active[k] = False
    lcount[0] = 0


@njit(parallel=True, cache=True)
def _render_kernel(cam, A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
                   hall_threshold, film: Film, spp, seed, cut):
    n = film.packet.shape[0]
    stride = task_stride(n)
    for c in prange(n):
        tile = interleaved(c, n, stride)
        _tile(cam, A, S, R, M, max_depth, hall_threshold, film, tile, spp, seed, cut)


@njit(cache=True)
def _trace_one(ox, oy, oz, dx, dy, dz, A: SceneArrays, S: SpecularArrays, R: RayConfig, max_depth,
               hall_threshold, M: LocalModel, seed):
    """:func:`_trees` of a batch of one ray (tmin = 0): its radiance, per-ray counters
    and cut weights."""
    T = new_points(1, R, len(COUNTERS) + max_depth + 1)
    T.ray[OX, 0], T.ray[OY, 0], T.ray[OZ, 0] = ox, oy, oz
    T.ray[DX, 0], T.ray[DY, 0], T.ray[DZ, 0] = dx, dy, dz
    T.ray[TMIN, 0], T.ray[TMAX, 0] = 0.0, np.inf
    work = _scratch(1, max_depth, R)
    _trees(A, S, R, M, max_depth, hall_threshold, seed, 0, 1, T, False, *work)
    return T.L[:, 0].copy(), T.cnt[0].copy(), work[2][0].copy()


# ------------------------------------------------------------- orchestration ---

def _check(params: dict) -> None:
    check_spp(params["spp"], "whitted")
    if params["max_depth"] < 1:
        raise ParamError(f"whitted: max_depth must be >= 1 (1 = eye rays only), got {params['max_depth']}")
    if not params["hall_threshold"] >= 0.0:
        raise ParamError(f"whitted: hall_threshold must be >= 0, got {params['hall_threshold']}")
    if params["light_samples"] < 0:
        raise ParamError("whitted: light_samples must be >= 0")


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    """Render ``scene`` with the Whitted ray tracer; ``params`` as from ``ALGORITHM.parse_params``."""
    t0 = time.perf_counter()
    _check(params)
    S = scene_memo(scene, "whitted.materials", lambda: material_arrays(scene))
    A = flatten_cached(scene)
    R = ray_config_cached(scene, A, params, algorithm="whitted")
    cam = camera_params(scene.camera)
    H, W = scene.camera.film.height, scene.camera.film.width
    spp, max_depth = params["spp"], params["max_depth"]
    film = new_film(W, H, len(COUNTERS) + max_depth + 1, bool(params.get("packets", False)),
                    sampler_code(params))
    cut = np.zeros((H, W, 2))
    t1 = time.perf_counter()
    run_tiles(_render_kernel, cam, A, S, R, local_model(params, S), max_depth,
              float(params["hall_threshold"]), film, spp, seed, cut)
    t2 = time.perf_counter()
    counters = film_counters(film, COUNTERS)
    hist = film.cnt[..., len(COUNTERS):].reshape(-1, max_depth + 1).sum(axis=0)
    counters["tree_depth_histogram"] = [int(v) for v in hist]
    return film_result(film, spp, counters, t0, t1, t2,
                       aovs={"hall_cut_weight": cut[..., 0].astype(np.float32),
                             "depth_cut_weight": cut[..., 1].astype(np.float32)})


def trace(scene: Scene, origin, direction, params: dict | None = None, *, seed: int = 0):
    """Radiance along one ray (tmin = 0) and the counters of its tree: ``(rgb, counters)``.

    For tests and debugging; ``params`` are algorithm parameters (defaults
    filled in).  The direction is normalised here.
    """
    p = ALGORITHM.parse_params(params or {})
    _check(p)
    S = material_arrays(scene)
    A = flatten(scene)
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    R = ray_config(A, p, algorithm="whitted")
    rgb, cnt, cut_w = _trace_one(o[0], o[1], o[2], d[0], d[1], d[2], A, S, R, p["max_depth"],
                                 float(p["hall_threshold"]), local_model(p, S), seed)
    counts, hist = cnt[:len(COUNTERS)], cnt[len(COUNTERS):]
    counters = {name: int(v) for name, v in zip(COUNTERS, counts)}
    counters["tree_depth_histogram"] = [int(v) for v in hist]
    counters["hall_cut_weight"] = float(cut_w[0])
    counters["depth_cut_weight"] = float(cut_w[1])
    return np.array(rgb), counters


ALGORITHM = Algorithm(
    name="whitted",
    summary="Whitted ray tracing: eye, shadow, reflection and Fresnel-split transmission rays, "
            "ray tree with Hall's adaptive depth",
    section="thesis 2.2, 2.2.1, 2.4.4, 2.4.5.5; Whitted 1980",
    transport="whitted",
    params=(
        Param("spp", int, 1, "pixel samples: 1 = pixel centre, k² = k×k jittered strata (box filter)"),
        SAMPLER_PARAM,
        Param("max_depth", int, 10, "deepest ray of a tree branch (eye ray = 1; 1 = ray casting)"),
        Param("hall_threshold", float, 1e-5, "cut a branch whose weight (every RGB channel) is below this"),
        Param("light_samples", int, 16, "shadow rays per area emitter per diffuse hit"),
        *PHONG_PARAMS,
        Param("shadows", bool, True, "cast shadow rays"),
        Param("shadow_mode", str, "opaque", "shadow rays at a smooth dielectric: opaque (stop) | "
              "transmissive (pass, filtered by its Fresnel transmittance)", choices=SHADOW_MODES),
        *RAY_PARAMS,
    ),
    render=render,
    models=frozenset({"envmap", "projector", "spot texture"}),
)
