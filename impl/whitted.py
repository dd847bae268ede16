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
* A textured ``specular_reflectance`` (``checkerboard`` or ``bitmap``, on shapes with
  uvs) of either: its value at the hit multiplies the reflected branch, as Mitsuba
  multiplies by the texture's ``eval`` (:func:`impl.lighting.specular_tint`); a textured
  ``specular_transmittance`` of a dielectric the transmitted branch
  (:func:`impl.lighting.transmittance_tint`); a textured ``eta`` or ``k`` of a
  conductor gives the Fresnel reflectance of its value at the hit
  (:func:`impl.lighting.textured_fresnel`).
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
* A ``normalmap`` or ``bumpmap`` around any of these (on triangles with uvs,
  Mitsuba's adapters, :mod:`impl.shading_frame`): the Fresnel factors,
  reflection and refraction directions and the Lambert term about the
  perturbed normal n_p; a branch or light sample on opposite sides of the true
  and the perturbed shading normal carries nothing, and with the shadowing
  function each is weighted by Estevez et al.'s term
  (:func:`impl.lighting.map_weight`).

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
The tree is traced level by level (below), never by recursion; each pending
ray carries its origin, direction, RGB weight, depth, ray type and the IOR of
the medium it travels in.

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
``packets=true`` as packets through the tree, :mod:`impl.accel.packets`).
The tile's ray trees are then traced level by level, as a wavefront
(:func:`_trees`): the eye rays are shaded together (:func:`_shade`), their
reflection and transmission rays queued one level deeper
(:class:`impl.tracer.Pending`); the deepest pending level is drained first, a
chunk of at most one tile's worth of rays at a time, each chunk's closest
hits as one batch query (:func:`impl.tracer.closest_batch`) and its diffuse
leaves lit together (:func:`impl.lighting.direct_batch`, the shadow rays of
one light sample as one batch).  A level holds the children of one chunk (at
most two per ray), so the queue holds at most (max_depth + 2) × 2 × B rays per
thread (B = ``BATCH_TILE``², the rays of a batch).  Leaf k of a tree (in the
order the levels meet them) draws the light samples of "sample" s + k·spp, so
leaf 0 those of ``raycast``: without delta surfaces whitted renders raycast's
image bit for bit.  Same image and counters with and without packets, plus
``packet_nodes`` and ``packet_tests``; packets need a tree (``accel=auto``
then means ``bvh-sah``).

Example::

    from core.loader import load_scene
    from impl.whitted import ALGORITHM as algo
    res = algo.render(load_scene("suites/spheres/whitted_classic.xml"),
                      algo.parse_params({"spp": 16}), seed=0)
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numba import njit

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene, scene_features
from core.errors import ParamError, UnsupportedError

from .camera import camera_params
from .kernel import batch_kernel, run_tasks, take_task
from .fresnel import fresnel_conductor, fresnel_dielectric, reflect, refract
from .lighting import (MAP_NONE, SHADOW_MODES, LocalModel, diffuse_albedo, direct_batch, environment_radiance,
                       local_model, map_weight, mapped_normal, specular_tint, store_point, surface_at,
                       textured_fresnel, transmittance_tint)
from .materials import SpecularArrays, material_arrays, with_specular_textures_cached
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, leave, ray_config, refine, round_ray
from .phong import PHONG_PARAMS
from .sampling import SAMPLER_PARAM, check_spp, sampler_code
from .scene_arrays import MATERIAL_CODES, SceneArrays, flatten, flatten_cached, scene_memo
from .tracer import (accumulate, Batch, closest_batch, DX, DY, DZ, eye_batch, first, Film,
                     film_counters, film_result,
                     new_batch, new_film, new_points, OX, OY, OZ, ray_config_cached, store,
                     TMAX, Pending, new_pending, push_pending, take_pending)

__all__ = ["render", "trace", "material_arrays", "SpecularArrays", "COUNTERS", "ALGORITHM"]

MAT_DIFFUSE = MATERIAL_CODES["diffuse"]
MAT_CONDUCTOR = MATERIAL_CODES["conductor"]
MAT_DIELECTRIC = MATERIAL_CODES["dielectric"]
MAT_ROUGHDIELECTRIC = MATERIAL_CODES["roughdielectric"]    # (distributed's, which shares arrive)
MAT_DIFFTRANS = MATERIAL_CODES["gibench_difftrans"]

RAY_EYE, RAY_REFLECTION, RAY_TRANSMISSION = 0, 1, 2

#: Names of the per-pixel integer counters, in kernel order.
COUNTERS = ("eye_rays", "shadow_rays", "reflection_rays", "transmission_rays", "hall_cuts",
            "depth_cuts", "tir", "ior_mismatches", "diffuse_hits")
_C_EYE, _C_SHADOW, _C_REFL, _C_TRANS, _C_HALL, _C_DEPTH, _C_TIR, _C_IOR, _C_DIFFUSE = range(9)

#: Two IORs closer than this count as the same medium (Mitsuba stores them as float32).
IOR_TOLERANCE = 1e-5

# ------------------------------------------------------------------ kernels ---

@njit(inline="always", cache=True)
def admit(wr, wg, wb, depth, max_depth, hall_threshold, counts, cut_w):
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


class TreeWork(NamedTuple):
    """The working state of a tile's ray trees (:func:`_trees`, and ``distributed``'s): the
    pending rays by depth, a batch for a chunk of them, and per eye-ray column what the
    sample has done so far."""

    Q: Pending                  # reflection and transmission rays by depth (capacity 2B each)
    C: Batch                    # a chunk of at most B of them, traced and shaded together
    w: np.ndarray               # (4, B) the chunk's branch weights (RGB) and media (IOR, 0 unknown)
    col: np.ndarray             # (B,) the chunk's eye-ray columns
    kind: np.ndarray            # (B,) the chunk's ray kinds (RAY_*)
    lsample: np.ndarray         # (B,) the light-sample index of each diffuse leaf of a chunk
    nshadow: np.ndarray         # (B, 1) the shadow rays each leaf cast
    nleaf: np.ndarray           # (n,) diffuse leaves of each eye ray's tree so far
    nbsdf: np.ndarray           # (n,) BSDF directions it sampled so far (distributed's gloss)
    deepest: np.ndarray         # (n,) the depth of each tree's deepest traced ray
    cut: np.ndarray             # (n, 2) summed weights of branches cut (Hall, depth), over samples


@njit(cache=True)
def tree_work(n, max_depth, R: RayConfig):
    """The :class:`TreeWork` for a tile of ``n`` eye rays (chunks of B = n rays): depths
    1 .. max_depth + 1, each holding the children of one chunk (two per ray at most)."""
    return TreeWork(new_pending(max_depth + 2, 2 * n), new_points(n, R),
                    np.empty((4, n)), np.empty(n, np.int64), np.empty(n, np.int64),
                    np.empty(n, np.int64), np.zeros((n, 1), np.int64), np.zeros(n, np.int64),
                    np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros((n, 2)))


@njit(inline="always", cache=True)
def arrive(A: SceneArrays, R: RayConfig, T: Batch, K: TreeWork, C: Batch, i, eye):
    """Ray i of batch ``C`` (its closest hit traced) where it arrives: its eye-ray column,
    branch weight, medium and kind (``eye``: ``T``'s own eye ray i, unit weight, unknown
    medium; else ``K``'s chunk, :data:`COUNTERS`' ray kind counted in its column's
    counters), the light of a miss (the environment) or of a hit's area emitter (front
    side) added to ``T.L``, and at a hit its point, geometric and shading normals, the
    direction to the viewer, the normal n its BSDF is taken about and n's map code
    (:func:`impl.lighting.mapped_normal`; normals turned to the viewer's side for a
    two-sided opaque BSDF seen from behind) and its material.  Returns ``(col, wr, wg,
    wb, medium, kind, prim, b1, b2, mat, hit)``, ``hit = (p, g, s, v, n, code)`` (vectors
    as three numbers); ``prim < 0`` on a miss, the hit's values then zero."""
    C.active[i] = False
    col = i if eye else K.col[i]
    if eye:
        wr = wg = wb = 1.0
        medium = 0.0
        kind = RAY_EYE
    else:
        wr, wg, wb, medium = K.w[0, i], K.w[1, i], K.w[2, i], K.w[3, i]
        kind = K.kind[i]
    T.cnt[col, _C_EYE if kind == RAY_EYE else _C_REFL if kind == RAY_REFLECTION else _C_TRANS] += 1
    rox, roy, roz = C.ray[OX, i], C.ray[OY, i], C.ray[OZ, i]
    rdx, rdy, rdz = C.ray[DX, i], C.ray[DY, i], C.ray[DZ, i]
    prim = C.prim[i]
    if prim < 0:                         # escaped: a constant environment, if any, else black
        er, eg, eb = environment_radiance(A, rdx, rdy, rdz)
        T.L[0, col] += wr * er
        T.L[1, col] += wg * eg
        T.L[2, col] += wb * eb
        return (col, wr, wg, wb, medium, kind, prim, 0.0, 0.0, np.int64(0),
                (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, MAP_NONE))
    t, b1, b2 = C.t[i], C.b[0, i], C.b[1, i]
    shape = A.prim_shape[prim]
    px, py, pz = refine(R, prim, b1, b2, rox + t * rdx, roy + t * rdy, roz + t * rdz)
    gx, gy, gz, sx, sy, sz = surface_at(A, prim, b1, b2, px, py, pz, A.shape_flip[shape])
    vx, vy, vz = -rdx, -rdy, -rdz
    if sx * vx + sy * vy + sz * vz > 0.0:   # emitted radiance L_e of an area emitter (front side)
        T.L[0, col] += wr * A.shape_emit[shape, 0]
        T.L[1, col] += wg * A.shape_emit[shape, 1]
        T.L[2, col] += wb * A.shape_emit[shape, 2]
    mat = A.shape_material[shape]
    mkind = A.mat_kind[mat]
    # A two-sided opaque BSDF is seen from the front on both sides; under a normal or
    # bump map the BSDF's normal n is the perturbed one (else s, or -s on the back).
    back = (A.mat_twosided[mat] and mkind != MAT_DIELECTRIC and mkind != MAT_ROUGHDIELECTRIC
            and mkind != MAT_DIFFTRANS and gx * vx + gy * vy + gz * vz < 0.0)
    nx, ny, nz, code = mapped_normal(A, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, back)
    if back:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    return (col, wr, wg, wb, medium, kind, prim, b1, b2, mat,
            (px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code))


@njit(inline="always", cache=True)
def dielectric_split(A: SceneArrays, S, mat, prim, b1, b2, dx, dy, dz, nx, ny, nz, sx, sy, sz, code, cos_v,
                     medium, wr, wg, wb, counts):
    """A ray of direction d and branch weight w meeting smooth dielectric ``mat`` (``S``:
    its material arrays; n the normal its BSDF is taken about, cos_v = n·(−d)): the exact
    Fresnel factor F splits it (thesis 2.4.4) into a transmitted branch of weight
    (1 − F) η_ti² × ``specular_transmittance`` (× its texture at the hit; the radiance
    scaling of Mitsuba's Radiance transport) and a reflected one of weight F × ``specular_reflectance``
    (× its texture at the hit), each direction weighted by the map's
    :func:`impl.lighting.map_weight`.  Counts a total internal reflection and an
    arriving medium whose IOR is not the interface's (``counts``: :data:`COUNTERS`).
    Returns ``(transmitted weight, direction, medium beyond; reflected weight, direction,
    medium here)``, the transmitted weight 0 under total internal reflection."""
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
    twr = twg = twb = tx = ty = tz = 0.0
    if F < 1.0:
        tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, cos_v, cos_t, eta_ti)
        scale = (1.0 - F) * eta_ti * eta_ti * map_weight(nx, ny, nz, sx, sy, sz, code, tx, ty, tz)
        ur, ug, ub = transmittance_tint(A, mat, prim, b1, b2)
        twr = wr * scale * S.spec_trans[mat, 0] * ur
        twg = wg * scale * S.spec_trans[mat, 1] * ug
        twb = wb * scale * S.spec_trans[mat, 2] * ub
    qx, qy, qz = reflect(dx, dy, dz, nx, ny, nz)
    F *= map_weight(nx, ny, nz, sx, sy, sz, code, qx, qy, qz)
    kr, kg, kb = specular_tint(A, mat, prim, b1, b2)
    rwr = wr * F * S.spec_refl[mat, 0] * kr
    rwg = wg * F * S.spec_refl[mat, 1] * kg
    rwb = wb * F * S.spec_refl[mat, 2] * kb
    return twr, twg, twb, tx, ty, tz, there, rwr, rwg, rwb, qx, qy, qz, here


@njit(inline="always", cache=True)
def conductor_mirror(A: SceneArrays, S, mat, prim, b1, b2, dx, dy, dz, nx, ny, nz, sx, sy, sz, code, cos_v,
                     wr, wg, wb):
    """A ray of direction d and branch weight w meeting smooth conductor ``mat``: the mirror
    direction R = I − 2(N·I)N about n and its weight w × the conductor Fresnel reflectance
    of η + ik (RGB; textured η or k read at the hit) at cos_v = n·(−d) ×
    ``specular_reflectance`` (× its texture at the hit) × the map's
    :func:`impl.lighting.map_weight`.  Returns ``(weight, direction)``."""
    qx, qy, qz = reflect(dx, dy, dz, nx, ny, nz)
    f = map_weight(nx, ny, nz, sx, sy, sz, code, qx, qy, qz)
    fr = fresnel_conductor(cos_v, S.cond_eta[mat, 0], S.cond_k[mat, 0])
    fg = fresnel_conductor(cos_v, S.cond_eta[mat, 1], S.cond_k[mat, 1])
    fb = fresnel_conductor(cos_v, S.cond_eta[mat, 2], S.cond_k[mat, 2])
    kr, kg, kb = specular_tint(A, mat, prim, b1, b2)
    ur, ug, ub = textured_fresnel(A, mat, prim, b1, b2, cos_v)
    return (wr * fr * S.spec_refl[mat, 0] * f * kr * ur, wg * fg * S.spec_refl[mat, 1] * f * kg * ug,
            wb * fb * S.spec_refl[mat, 2] * f * kb * ub, qx, qy, qz)


@njit(inline="always", cache=True)
def light_leaves(A: SceneArrays, R: RayConfig, M: LocalModel, T: Batch, K: TreeWork, C: Batch, m, seed, eye):
    """Light the diffuse leaves among the ``m`` rays of batch ``C`` (``C.active``, their
    points in ``C.pts``, leaf i's light-sample index in ``K.lsample[i]``) together
    (:func:`impl.lighting.direct_batch`) and add each one's light × its branch weight to
    its eye ray's ``T.L`` and its shadow rays to its counters.  With ``eye`` the leaves
    are ``T``'s own eye rays (unit weight): straight into ``T.L``, as ``raycast``
    lights them."""
    if eye:
        direct_batch(A, R, M, T, K.lsample, seed, T.cnt[:, _C_SHADOW])
        return
    nsh = K.nshadow[:, 0]
    for i in range(m):
        C.L[0, i] = C.L[1, i] = C.L[2, i] = 0.0
        nsh[i] = 0
        C.pixel[i] = T.pixel[K.col[i]]
    direct_batch(A, R, M, first(C, m), K.lsample, seed, nsh)
    for i in range(m):
        if C.active[i]:
            col = K.col[i]
            T.L[0, col] += K.w[0, i] * C.L[0, i]
            T.L[1, col] += K.w[1, i] * C.L[1, i]
            T.L[2, col] += K.w[2, i] * C.L[2, i]
            T.cnt[col, _C_SHADOW] += nsh[i]
            C.active[i] = False


@njit(inline="always", cache=True)
def queue_delta(Q: Pending, R: RayConfig, A: SceneArrays, S, mkind, mat, prim, b1, b2, hit, medium, w, col,
                depth, max_depth, hall_threshold, counts, cut):
    """At a smooth dielectric (:func:`dielectric_split`) or a smooth conductor seen from
    above n (:func:`conductor_mirror`), queue the branches of a ray of weight ``w`` that
    :func:`admit` lets through as rays of depth ``depth`` (the transmitted one first);
    ``hit`` as :func:`arrive` returns it.  Whether the hit was on one of these (its
    branch goes on only in the children; a conductor seen from below is black)."""
    px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code = hit
    wr, wg, wb = w
    cos_v = nx * vx + ny * vy + nz * vz
    if mkind == MAT_DIELECTRIC:
        twr, twg, twb, tx, ty, tz, there, rwr, rwg, rwb, qx, qy, qz, here = dielectric_split(
            A, S, mat, prim, b1, b2, -vx, -vy, -vz, nx, ny, nz, sx, sy, sz, code, cos_v, medium, wr, wg, wb,
            counts)
        if admit(twr, twg, twb, depth, max_depth, hall_threshold, counts, cut):
            queue_child(Q, depth, R, px, py, pz, gx, gy, gz, tx, ty, tz, twr, twg, twb, there, col,
                        RAY_TRANSMISSION)
        if admit(rwr, rwg, rwb, depth, max_depth, hall_threshold, counts, cut):
            queue_child(Q, depth, R, px, py, pz, gx, gy, gz, qx, qy, qz, rwr, rwg, rwb, here, col,
                        RAY_REFLECTION)
        return True
    if mkind != MAT_CONDUCTOR:
        return False
    if cos_v > 0.0:
        rwr, rwg, rwb, qx, qy, qz = conductor_mirror(A, S, mat, prim, b1, b2, -vx, -vy, -vz, nx, ny, nz, sx,
                                                     sy, sz, code, cos_v, wr, wg, wb)
        if admit(rwr, rwg, rwb, depth, max_depth, hall_threshold, counts, cut):
            queue_child(Q, depth, R, px, py, pz, gx, gy, gz, qx, qy, qz, rwr, rwg, rwb, medium, col,
                        RAY_REFLECTION)
    return True


@njit(inline="always", cache=True)
def diffuse_leaf(A: SceneArrays, T: Batch, C: Batch, i, col, mat, prim, b1, b2, hit, w, amb):
    """Ray i of batch ``C``, of weight ``w``, ends its branch at a diffuse hit (thesis
    2.2): the ambient term ``amb`` ρ × w into its eye ray's ``T.L`` now, the shading point
    stored in ``C.pts`` and marked active for :func:`light_leaves`.  False (nothing done)
    where the viewer is below n: an opaque BSDF is black there."""
    px, py, pz, gx, gy, gz, sx, sy, sz, vx, vy, vz, nx, ny, nz, code = hit
    if nx * vx + ny * vy + nz * vz <= 0.0:
        return False
    rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
    T.L[0, col] += w[0] * (amb * rho_r)
    T.L[1, col] += w[1] * (amb * rho_g)
    T.L[2, col] += w[2] * (amb * rho_b)
    store_point(C.pts, i, px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz, rho_r, rho_g, rho_b, sx, sy, sz,
                code)
    C.active[i] = True
    return True


@batch_kernel
def _shade(A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
           hall_threshold, seed, sample, spp, T: Batch, K: TreeWork, C: Batch, m, depth, eye):
    """Shade the ``m`` rays of depth ``depth`` in batch ``C`` (hits traced): add each
    one's light to its eye ray's radiance ``T.L``, queue its reflection and transmission
    rays one level deeper (``K.Q``) and light its diffuse leaves together
    (:func:`impl.lighting.direct_batch`).  With ``eye`` the rays are the eye rays of the
    tile batch itself (``C`` is ``T``: unit weight, column = ray), whose leaves are lit
    straight into ``T.L`` as ``raycast`` lights them; otherwise ``K``'s chunk, the weight
    and column of each ray in ``K.w`` and ``K.col``.

    At a dielectric the exact Fresnel factor F splits the ray (thesis 2.4.4): a
    reflected branch of weight F × ``specular_reflectance`` and a transmitted one of
    weight (1 − F) η_ti² × ``specular_transmittance`` (none under total internal
    reflection); at a conductor the mirror branch carries its Fresnel reflectance ×
    ``specular_reflectance``; a diffuse hit is a leaf, lit by every emitter, where the
    branch ends.  Leaf k of a sample s (in the order the levels meet them) takes the light
    samples of "sample" s + k·spp, so leaf 0 those of ``raycast``."""
    amb = M.ambient * M.ka
    for i in range(m):
        col, wr, wg, wb, medium, kind, prim, b1, b2, mat, hit = arrive(A, R, T, K, C, i, eye)
        K.deepest[col] = max(K.deepest[col], depth)
        if prim < 0:
            continue
        counts = T.cnt[col]
        if queue_delta(K.Q, R, A, S, A.mat_kind[mat], mat, prim, b1, b2, hit, medium, (wr, wg, wb), col,
                       depth + 1, max_depth, hall_threshold, counts, K.cut[col]):
            continue
        # Diffuse: a leaf, lit by every emitter below (thesis 2.2); ambient term now.
        if diffuse_leaf(A, T, C, i, col, mat, prim, b1, b2, hit, (wr, wg, wb), amb):
            K.lsample[i] = sample + K.nleaf[col] * spp
            K.nleaf[col] += 1
            counts[_C_DIFFUSE] += 1
    light_leaves(A, R, M, T, K, C, m, seed, eye)


@njit(inline="always", cache=True)
def queue_child(Q: Pending, depth, R: RayConfig, px, py, pz, gx, gy, gz, dx, dy, dz, wr, wg, wb,
                medium, col, kind):
    """Queue a child ray of depth ``depth``, leaving the surface to the side it goes to (R's
    offset), rounded to R's precision as it will be intersected and shaded."""
    side = 1.0 if gx * dx + gy * dy + gz * dz >= 0.0 else -1.0
    ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
    ox, oy, oz, dx, dy, dz = round_ray(R, ox, oy, oz, dx, dy, dz)
    push_pending(Q, depth, ox, oy, oz, dx, dy, dz, t0, np.inf, wr, wg, wb, medium, col, kind)


@batch_kernel
def _trees(A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
           hall_threshold, seed, sample, spp, T: Batch, traced, K: TreeWork):
    """The radiance ``T.L`` of the batch's eye rays (``T.ray``), their ray trees traced
    level by level: the eye rays (hits in ``T.t``, ``T.prim``, ``T.b`` when ``traced``,
    from :func:`impl.tracer.eye_batch`; else traced here), then, deepest level first,
    chunks of at most B pending reflection and transmission rays, each chunk's closest
    hits as one batch query (:func:`impl.tracer.closest_batch`) and its shading by
    :func:`_shade`.  Per-ray counters into ``T.cnt`` (:data:`COUNTERS`, then the
    tree-depth histogram), cut weights into ``K.cut``."""
    n = T.n
    nc = len(COUNTERS)
    for i in range(n):
        T.L[0, i] = T.L[1, i] = T.L[2, i] = 0.0
        K.nleaf[i] = 0
        K.deepest[i] = 0
    if not traced:
        for i in range(n):
            (T.ray[OX, i], T.ray[OY, i], T.ray[OZ, i], T.ray[DX, i], T.ray[DY, i],
             T.ray[DZ, i]) = round_ray(R, T.ray[OX, i], T.ray[OY, i], T.ray[OZ, i], T.ray[DX, i],
                                       T.ray[DY, i], T.ray[DZ, i])
        closest_batch(R, T.ray, n, T.t, T.prim, T.b, T.q, T.qt, T.qp, T.cull)
    # Typed values, not literals: a literal argument would compile _shade a second time.
    _shade(A, S, R, M, max_depth, hall_threshold, seed, sample, spp, T, K, T, n, np.int64(1),
           np.bool_(True))
    Q, C = K.Q, K.C
    cap = C.n
    d = np.int64(2)                      # typed: a literal 2 would compile _shade again
    while d >= 2:
        if Q.count[d] == 0:
            d -= 1
            continue
        m = take_pending(Q, d, C.ray, K.w, K.col, K.kind, cap)
        closest_batch(R, C.ray, m, C.t, C.prim, C.b, C.q, C.qt, C.qp, C.cull)
        _shade(A, S, R, M, max_depth, hall_threshold, seed, sample, spp, T, K, C, m, d,
               np.bool_(False))
        if Q.count[d + 1] > 0:           # its children first: a block holds one chunk's
            d += 1
    for i in range(n):
        T.cnt[i, nc + K.deepest[i]] += 1


# Inlined into the task loop: as a function of its own it would be one more module that
# numba optimises and generates machine code for with the whole tracer linked in.
@njit(inline="always", cache=True)
def _tile(cam, A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
          hall_threshold, film: Film, tile, spp, seed, cut):
    """One tile (:mod:`impl.tracer`): per sample index, the eye rays and their hits, then
    the tile's ray trees level by level (:func:`_trees`).  Per-pixel counters:
    :data:`COUNTERS`, then the tree-depth histogram (``max_depth + 1`` columns); cut
    weights go to ``cut``."""
    T = new_batch(film, R, tile, seed)
    K = tree_work(T.n, max_depth, R)
    for s in range(spp):
        eye_batch(cam, R, T, s, spp, seed, film.packets, film.sampler)
        _trees(A, S, R, M, max_depth, hall_threshold, seed, s, spp, T, np.bool_(True), K)
        accumulate(T, s)
    store(T, film, spp)
    for i in range(T.n):
        x, y = int(T.xy[0, i]), int(T.xy[1, i])
        cut[y, x, 0] = K.cut[i, 0] / spp
        cut[y, x, 1] = K.cut[i, 1] / spp


@njit(nogil=True, cache=True)
def _render_kernel(cam, A: SceneArrays, S: SpecularArrays, R: RayConfig, M: LocalModel, max_depth,
                   hall_threshold, film: Film, spp, seed, cut, queue):
    """The film's tiles, taken from ``queue`` (:func:`impl.kernel.run_tasks`)."""
    n = film.order.shape[0]
    c = take_task(queue)
    while c < n:
        _tile(cam, A, S, R, M, max_depth, hall_threshold, film, film.order[c], spp, seed, cut)
        c = take_task(queue)


# ------------------------------------------------------------- orchestration ---

def _check(params: dict) -> None:
    check_spp(params["spp"], "whitted")
    if params["max_depth"] < 1:
        raise ParamError(f"whitted: max_depth must be >= 1 (1 = eye rays only), got {params['max_depth']}")
    if not params["hall_threshold"] >= 0.0:
        raise ParamError(f"whitted: hall_threshold must be >= 0, got {params['hall_threshold']}")
    if params["light_samples"] < 0:
        raise ParamError("whitted: light_samples must be >= 0")


def _check_scene(scene: Scene, params: dict) -> None:
    """Refuse what transmissive shadow rays leave out: a textured
    ``specular_transmittance`` (they filter by the material's constant one)."""
    if params["shadow_mode"] != "transmissive":
        return
    where = scene_features(scene).get("textured specular transmittance")
    if where is not None:
        raise UnsupportedError(f"whitted shadow_mode=transmissive: {where}: shadow rays filter by a "
                               "constant specular_transmittance; a textured one is not modelled on them")


def render(scene: Scene, params: dict, *, seed: int = 0) -> RenderResult:
    """Render ``scene`` with the Whitted ray tracer; ``params`` as from ``ALGORITHM.parse_params``."""
    t0 = time.perf_counter()
    _check(params)
    _check_scene(scene, params)
    scene = with_specular_textures_cached(scene)
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
    run_tasks(_render_kernel, cam, A, S, R, local_model(params, S), max_depth,
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
    _check_scene(scene, p)
    scene = with_specular_textures_cached(scene)
    S = material_arrays(scene)
    A = flatten(scene)
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    R = ray_config(A, p, algorithm="whitted")
    max_depth = int(p["max_depth"])
    # The tile kernel's own batch step on a batch of one ray, called with the types the
    # tile kernel passes: numba reuses its compiled version (a kernel of its own around
    # it would compile the whole ray tree again).
    T = new_points(1, R, len(COUNTERS) + max_depth + 1)
    T.ray[:TMAX + 1, 0] = (o[0], o[1], o[2], d[0], d[1], d[2], 0.0, np.inf)
    K = tree_work(1, max_depth, R)
    _trees(A, S, R, local_model(p, S), max_depth, float(p["hall_threshold"]), int(seed), np.int64(0),
           np.int64(1), T, np.bool_(False), K)
    rgb, cnt, cut_w = T.L[:, 0].copy(), T.cnt[0].copy(), K.cut[0].copy()
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
    models=frozenset({"envmap", "projector", "spot texture", "normalmap", "bumpmap",
                      "textured specular reflectance", "textured specular transmittance",
                      "textured conductor eta/k"}),
    kernel_variants=({"packets": True},),
)
