"""How the ray tracers intersect and spawn rays: ray–sphere form, precision, offset.

The three choices of thesis 2.3.3–2.3.4 that decide a ray tracer's numerical
robustness, shared by ``whitted`` and ``raycast`` (their parameters
``intersect``, ``precision``, ``offset`` and ``epsilon``):

=========  ==========================  =======  ===================================
parameter  values                      default  meaning
=========  ==========================  =======  ===================================
intersect  algebraic|geometric|stable  stable   ray–sphere form of *every* sphere
                                                test (eye, secondary, shadow rays;
                                                :mod:`impl.intersect`)
precision  float32|float64             float64  precision of the intersection
                                                arithmetic
offset     epsilon|normal|robust       robust   how secondary and shadow rays leave
                                                a surface (:mod:`impl.offset`)
epsilon    float                       1e-4     ε of ``epsilon`` and ``normal``
                                                (scene units)
accel      auto|none|bv|bv-sphere|     auto     acceleration structure of every
           slabs|bvh-median|bvh-sah|            query (:mod:`impl.accel`, thesis
           bvh-gs|grid|octree|bvh-wide          2.6); none = brute force
slab_normals  3|7|13                   7        plane normals of ``accel=slabs``
grid_density  float                    4        ``accel=grid``: voxels per primitive
                                                (the grid's resolution)
grid_mailbox  bool                     true     ``accel=grid``: test a primitive once
                                                per ray (mailboxing)
grid_current_voxel  bool               true     ``accel=grid``: accept a hit only in
                                                the voxel being examined; false is
                                                the ablation of thesis Fig. 2.34
                                                (nearer objects lost)
packets    bool                        false    trace the eye rays of 8×8 pixel
                                                tiles as coherent packets through
                                                the tree (:mod:`impl.accel.packets`)
=========  ==========================  =======  ===================================

Acceleration.  :func:`ray_config` builds the chosen structure over the
primitives *in the intersection precision* and the ray configuration carries
its flat arrays (empty for ``none``); :func:`hit` and :func:`occluded`
dispatch on ``RayConfig.accel``.  Every structure tests the primitives it
reaches with the same kernels, form and precision as brute force and breaks
ties as brute force does, so the closest hit — and the image — is the same
(``tests/test_accel.py``); only the number of tests changes.

Packets (thesis 2.6, third strategy: tracing several rays together).  With
``packets=true`` the tracers trace each sample's eye rays of an 8×8 pixel tile
as one packet through the tree (:func:`impl.accel.packets.packet_hits`) and
continue every pixel's sample from its precomputed first hit; secondary and
shadow rays stay single-ray (incoherent: packets of them are out of scope).
The image and every counter are bit for bit those of ``packets=false`` with
the same structure (``tests/test_packets.py``); the tracers add the counters
``packet_nodes`` and ``packet_tests`` (nodes opened by packets, primitive
tests of packet rays).  Packets need a tree: ``accel=auto`` then always
chooses :data:`AUTO_ACCEL` (whatever the scene size and sphere form), and an
explicit non-tree structure is refused.  The default stays ``false``: eye
rays are a small part of a render and scalar numba loops over the packet's
rays at every node, so the saved node fetches buy little
(``benchmarks/bench_packets.py`` measures it).

Structures and brute force agree except where the sphere test itself is wrong: far from a sphere the
algebraic and geometric forms in float32 report hits that lie nowhere near
it (thesis 2.3.3: the cancelled discriminant; ``test_whitted``'s distant
sphere: the geometric form "hits" all 1024 pixels).  A bounding volume culls
those rays, so a structure would hide the very error those forms are kept to
show.  ``accel=auto`` (the default) therefore uses :data:`AUTO_ACCEL` with the
stable form only, on scenes of at least :data:`AUTO_MIN_PRIMS` primitives
(below that brute force is faster), and brute force with the other two; an explicit structure
with them is honoured, with equal results wherever the form's hits lie on
its sphere (to within the bounds' padding).

Precision.  With ``float32`` every ray is rounded to float32 before it is
intersected (origin and direction; the ray tracer then shades the rounded
ray, so the hit point lies on the ray that was intersected), the primitives
are float32 copies of the scene's coordinates, and the kernels of
:mod:`impl.intersect` compute in float32, as do the sphere-hit refinement
(:func:`refine`) and the offset; ``t`` and the barycentrics come back as
float64.  The shading — hit point ``o + t d``, normals, Fresnel,
lights — stays float64: the precision problems of thesis 2.3.4 (a sphere lost
to cancellation, the hit point's error that causes shadow acne) are those of
the intersection computation, and keeping shading in float64 isolates them
from the (much smaller) rounding of the radiance sums.

Offset.  A ray leaving the surface at ``p`` on the side of the geometric
normal ``n`` (flipped for transmission and for a light behind the surface):

* ``epsilon`` — origin ``p``, hits with ``t <= epsilon`` ignored (t_min ε
  along the ray; thesis 2.3.4);
* ``normal`` — origin ``p + epsilon·n``, t_min = 0;
* ``robust`` — origin moved by 256 ulps of each coordinate along ``n``
  (Wächter & Binder 2019, :func:`impl.offset.offset_ray`), computed in the
  chosen precision, t_min = 0.  No parameter: the offset follows the
  magnitude of ``p``.

Shadow rays go from their offset origin ``o`` to the light point ``y`` and
stop at ``|y − o|·(1 − s)`` (``s`` = 1e-9 for point/spot lights and 1e-7 for
area emitters in float64, 1e-4 in float32, where the emitter's own ``t``
carries a relative error of several float32 ulps).

:func:`legacy_config` is the fixed rule of the ray tracers' first version,
still the offset rule of :func:`impl.lighting.direct_light` for its other
callers: stable form, float64, no refinement, origin
``p + 1e-7·(1 + max|p_i|)·n`` (:func:`impl.offset.offset_scaled`), shadow rays
aimed from the offset origin.

The precision is the dtype of :class:`RayConfig`'s primitive arrays, so each
precision is its own compiled specialisation (the form and offset strategy
are run-time codes).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from core.algorithm import Param
from core.errors import ParamError

from . import accel as _accel
from .accel.wide import wide_any_bound, wide_bind, wide_closest_bound
from .intersect import SPHERE_FORMS, any_hit_form, closest_hit_form, like
from .offset import STRATEGIES, spawn, spawn_select

__all__ = ["RayConfig", "ray_config", "legacy_config", "PARAMS", "INTERSECT", "PRECISIONS",
           "OFFSETS", "PACKET_ACCELS", "hit", "refine", "refine_triangle", "refine_sphere", "occluded",
           "leave", "round_ray"]

INTERSECT = SPHERE_FORMS                       # ("algebraic", "geometric", "stable")
PRECISIONS = ("float32", "float64")
OFFSETS = ("epsilon", "normal", "robust")
#: The offset names as :func:`impl.offset.spawn` strategy codes.
_OFFSET_CODE = {"epsilon": STRATEGIES.index("tmin"), "normal": STRATEGIES.index("normal"),
                "robust": STRATEGIES.index("robust")}
_SCALED = STRATEGIES.index("scaled")

#: The structure of ``accel=auto``: the fastest per ray measured
#: (benchmarks/bench_accel.py, the scaling study).
AUTO_ACCEL = "bvh-wide"
#: ``accel=auto`` traces scenes with fewer primitives than this by brute force:
#: below it the wide BVH's traversal costs more than it saves.  Measured crossover
#: of whole renders (single-thread CPU time, brute force against the wide BVH, the
#: wide BVH's traversal on raw pointers): the wide BVH loses at 12 primitives
#: (Cornell box with a mirror and a glass sphere, whitted) and wins from 24 on
#: (thin_gap, cornell_point, raycast).
AUTO_MIN_PRIMS = 16
#: ``accel=auto`` answers the tracers' *batch* queries (a tile's eye rays, a light
#: sample's shadow rays: :func:`impl.tracer.closest_batch`, ``occluded_batch``) by
#: brute force on scenes of fewer primitives than this per SIMD lane count (float64:
#: 4 lanes; float32: 8), whatever the structure the per-ray queries use: the
#: brute-force batch loops test several rays per instruction and have no traversal,
#: so (with the batch's culling bounds, :func:`impl.tracer._cull`) they beat the wide
#: BVH's per-ray traversal on larger scenes than the scalar queries do.  Measured on
#: whole ray-cast renders (single-thread CPU, float64): brute force ahead on the 34-
#: and 36-triangle Cornell boxes, behind on the 43-primitive instancing scene.
AUTO_BATCH_PRIMS_PER_LANE = 10

#: The parameter-table rows of the ray tracers that take a ray configuration.
PARAMS = (
    Param("intersect", str, "stable", "ray-sphere form of every sphere test (eye, secondary, "
          "shadow rays)", choices=INTERSECT),
    Param("precision", str, "float64", "precision of the intersection arithmetic (rays and "
          "primitives rounded to it; shading stays float64)", choices=PRECISIONS),
    Param("offset", str, "robust", "how secondary and shadow rays leave a surface: t_min = ε, "
          "origin + ε·n, or Wächter-Binder ulp offset", choices=OFFSETS),
    Param("epsilon", float, 1e-4, "ε of offset=epsilon (t_min) and offset=normal (scene units)"),
    Param("accel", str, "auto", "acceleration structure of every ray query (thesis 2.6; "
          "impl.accel): none = brute force; auto = bvh-wide with the stable sphere form from "
          "16 primitives on, none below and with the algebraic/geometric forms", choices=("auto",) + _accel.ACCELS),
    Param("slab_normals", int, 7, "plane normals of accel=slabs (3 axes, 7 = + cube diagonals, "
          "13 = + face diagonals)", choices=_accel.SLAB_COUNTS),
    Param("grid_density", float, _accel.GRID_DENSITY, "accel=grid: voxels per primitive, the grid's "
          "resolution (thesis 2.6.2; at most 256 per axis)"),
    Param("grid_mailbox", bool, True, "accel=grid: mailboxing, a primitive listed in several voxels "
          "is tested once per ray (false: once per voxel; same hits, more tests)"),
    Param("grid_current_voxel", bool, True, "accel=grid: accept a hit only inside the voxel being "
          "examined (false: the ablation of thesis Fig. 2.34, which loses nearer objects)"),
    Param("packets", bool, False, "trace the eye rays of 8x8 pixel tiles as coherent packets "
          "through the tree (thesis 2.6; impl.accel.packets); needs a tree accel (auto = bvh-wide); "
          "secondary and shadow rays stay single-ray; same image as false"),
)

#: The structures packets can traverse (``impl.accel.KIND`` TREE or WIDE).
PACKET_ACCELS = tuple(name for name in _accel.ACCELS if _accel.KIND[name] in (_accel.TREE, _accel.WIDE))


class RayConfig(NamedTuple):
    """The ray configuration as numba kernel input (one typed argument).

    The precision is the dtype of the primitive arrays: float64 configurations
    carry the scene's own arrays, float32 ones rounded copies, so numba compiles
    one specialisation of each kernel per precision and neither carries the
    other's code (the form and offset strategy are run-time codes).
    """

    form: int                   # ray–sphere form code (index into SPHERE_FORMS)
    strategy: int               # impl.offset.spawn strategy code
    eps: float                  # its ε
    shrink_point: float         # shadow rays to point/spot lights end at d·(1 − shrink)
    shrink_area: float          # shadow rays to area emitters end at d·(1 − shrink)
    sph_center: np.ndarray      # (S, 3) the primitives in the intersection precision
    sph_radius: np.ndarray      # (S,)
    tri_v: np.ndarray           # (T, 3, 3)
    accel: int                  # traversal code (impl.accel.KIND; 0 = brute force)
    node_lo: np.ndarray         # the structure's flat arrays (impl.accel.Accel; empty if none)
    node_hi: np.ndarray
    node_a: np.ndarray
    node_b: np.ndarray
    prim_idx: np.ndarray
    acc_f: np.ndarray
    acc_i: np.ndarray
    batch_brute: bool = False   # batch queries (impl.tracer) by brute force despite the structure


def ray_config(A, params: dict, *, algorithm: str) -> RayConfig:
    """The :class:`RayConfig` of parameters ``intersect``, ``precision``, ``offset``
    and ``epsilon`` for the flattened scene ``A``."""
    eps = float(params["epsilon"])
    if not (eps >= 0.0 and np.isfinite(eps)):
        raise ParamError(f"{algorithm}: epsilon must be finite and >= 0, got {eps}")
    single = params["precision"] == "float32"
    F = np.float32 if single else np.float64
    sph_center = np.ascontiguousarray(A.sph_center, dtype=F)
    sph_radius = np.ascontiguousarray(A.sph_radius, dtype=F)
    tri_v = np.ascontiguousarray(A.tri_v, dtype=F)
    name = params.get("accel", "auto")
    packets = bool(params.get("packets", False))
    prims = len(sph_radius) + len(tri_v)
    batch_brute = False
    if name == "auto":
        stable = params["intersect"] == "stable"
        name = AUTO_ACCEL if packets or (stable and prims >= AUTO_MIN_PRIMS) else "none"
        lanes = 8 if single else 4
        batch_brute = stable and not packets and prims < AUTO_BATCH_PRIMS_PER_LANE * lanes
    if name not in _accel.ACCELS:
        raise ParamError(f"{algorithm}: unknown accel {name!r} (valid: auto, {', '.join(_accel.ACCELS)})")
    if packets and name not in PACKET_ACCELS:
        raise ParamError(f"{algorithm}: packets=true needs a tree to traverse the packets through, "
                         f"but accel={name}; valid with packets: auto, {', '.join(PACKET_ACCELS)} "
                         "(or packets=false)")
    density = float(params.get("grid_density", _accel.GRID_DENSITY))
    if not (density > 0.0 and np.isfinite(density)):
        raise ParamError(f"{algorithm}: grid_density must be finite and > 0, got {density}")
    acc = _accel.build(name, sph_center, sph_radius, tri_v, A.prim_shape,
                       slab_normals=params.get("slab_normals", 7), grid_density=density,
                       grid_mailbox=bool(params.get("grid_mailbox", True)),
                       grid_current_voxel=bool(params.get("grid_current_voxel", True)))
    return RayConfig(SPHERE_FORMS.index(params["intersect"]), _OFFSET_CODE[params["offset"]], eps,
                     1e-4 if single else 1e-9, 1e-4 if single else 1e-7,
                     sph_center, sph_radius, tri_v, *acc, batch_brute)


def structure(R: RayConfig) -> _accel.Accel:
    """The acceleration structure's arrays in R (:class:`impl.accel.Accel`: kind and
    flat arrays), e.g. for :func:`impl.accel.memory_bytes`."""
    return _accel.Accel(*R[8:8 + len(_accel.Accel._fields)])


@njit(cache=True)
def legacy_config(A, eps):
    """The fixed rule: stable form, float64, origin p + eps·(1 + max|p_i|)·n."""
    z2 = np.empty((0, 3))
    zi = np.empty(0, dtype=np.int64)
    return RayConfig(2, _SCALED, eps, 1e-9, 1e-7, A.sph_center, A.sph_radius, A.tri_v,
                     0, z2, z2, zi, zi, zi, np.empty(0), zi, False)


@njit(inline="always", cache=True)
def round_ray(R: RayConfig, ox, oy, oz, dx, dy, dz):
    """The ray as the intersection sees it: rounded to R's precision (float64 values)."""
    g = R.sph_radius
    return (float(like(g, ox)), float(like(g, oy)), float(like(g, oz)),
            float(like(g, dx)), float(like(g, dy)), float(like(g, dz)))


@njit(inline="always", cache=True)
def hit(R: RayConfig, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit ``(t, prim, b1, b2)`` (float64 t and barycentrics) in R's form and precision."""
    g = R.sph_radius
    if R.accel == _accel.WIDE:          # pointers passed, not R's arrays (impl.kernel)
        W, root, _ = wide_bind(R)
        t, prim, b1, b2 = wide_closest_bound(W, root, like(g, ox), like(g, oy), like(g, oz),
                                             like(g, dx), like(g, dy), like(g, dz),
                                             like(g, tmin), like(g, tmax))
        return float(t), prim, float(b1), float(b2)
    if R.accel != 0:
        t, prim, b1, b2, _, _ = _accel.closest(R, like(g, ox), like(g, oy), like(g, oz),
                                               like(g, dx), like(g, dy), like(g, dz),
                                               like(g, tmin), like(g, tmax))
        return float(t), prim, float(b1), float(b2)
    t, prim, b1, b2 = closest_hit_form(R.form, like(g, ox), like(g, oy), like(g, oz),
                                       like(g, dx), like(g, dy), like(g, dz),
                                       like(g, tmin), like(g, tmax),
                                       R.sph_center, R.sph_radius, R.tri_v)
    return float(t), prim, float(b1), float(b2)


@njit(inline="always", cache=True)
def refine(R: RayConfig, prim, b1, b2, px, py, pz):
    """The hit point p = o + t d refined, in R's precision.

    On a sphere, projected onto it, p = c + r (p − c)/|p − c| (pbrt's "refine
    sphere intersection point"), which leaves an error of a few ulps of p
    instead of ~u·|o| + u·t (the offsets' 256 ulps clear the former, not the
    latter: measured on ``nested_glass``, the robust offset without it lets
    ~5 % of the transmitted rays re-hit their own sphere).  On a triangle,
    recomputed from the barycentrics, p = b0 v0 + b1 v1 + b2 v2 (Wächter &
    Binder's premise: an error relative to the vertices, not to |o| + t — a
    vertex coordinate of 0 stays exactly 0, where o + t d carries ~u·(|o| + t),
    more than the robust offset's absolute step near zero in mm-scale scenes).
    """
    g = R.sph_radius
    ns = g.shape[0]
    if prim >= ns:
        return refine_triangle(g, R.tri_v, prim - ns, b1, b2)
    return refine_sphere(g, R.sph_center, prim, px, py, pz)


@njit(inline="always", cache=True)
def refine_triangle(g, V, j, b1, b2):
    """:func:`refine` on triangle j of the vertices ``V`` (in the precision of the array
    ``g``): b0 v0 + b1 v1 + b2 v2."""
    c1, c2 = like(g, b1), like(g, b2)
    c0 = like(g, 1.0) - c1 - c2
    return (float(c0 * V[j, 0, 0] + c1 * V[j, 1, 0] + c2 * V[j, 2, 0]),
            float(c0 * V[j, 0, 1] + c1 * V[j, 1, 1] + c2 * V[j, 2, 1]),
            float(c0 * V[j, 0, 2] + c1 * V[j, 1, 2] + c2 * V[j, 2, 2]))


@njit(inline="always", cache=True)
def refine_sphere(g, C, k, px, py, pz):
    """:func:`refine` on sphere k (centres ``C``, radii ``g``, in their precision): p
    projected onto it, c + r (p − c)/|p − c|."""
    cx, cy, cz, r = C[k, 0], C[k, 1], C[k, 2], g[k]
    qx, qy, qz = like(g, px) - cx, like(g, py) - cy, like(g, pz) - cz
    f = r / math.sqrt(qx * qx + qy * qy + qz * qz)
    return float(cx + f * qx), float(cy + f * qy), float(cz + f * qz)


@njit(inline="always", cache=True)
def occluded(R: RayConfig, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Whether anything lies on the ray within (tmin, tmax), in R's form and precision."""
    g = R.sph_radius
    if R.accel == _accel.WIDE:
        W, root, _ = wide_bind(R)
        return wide_any_bound(W, root, like(g, ox), like(g, oy), like(g, oz), like(g, dx),
                              like(g, dy), like(g, dz), like(g, tmin), like(g, tmax))
    if R.accel != 0:
        h, _, _ = _accel.any_hit(R, like(g, ox), like(g, oy), like(g, oz), like(g, dx),
                                 like(g, dy), like(g, dz), like(g, tmin), like(g, tmax))
        return h
    return any_hit_form(R.form, like(g, ox), like(g, oy), like(g, oz), like(g, dx), like(g, dy),
                        like(g, dz), like(g, tmin), like(g, tmax),
                        R.sph_center, R.sph_radius, R.tri_v)


@njit(inline="always", cache=True)
def leave(R: RayConfig, px, py, pz, nx, ny, nz):
    """Origin and t_min ``(ox, oy, oz, tmin)`` of a ray leaving p on the side of the
    unit normal n, by R's strategy, computed in R's precision (float64 results)."""
    g = R.sph_radius
    ox, oy, oz, t0 = spawn(R.strategy, like(g, px), like(g, py), like(g, pz),
                           like(g, nx), like(g, ny), like(g, nz), like(g, R.eps))
    return float(ox), float(oy), float(oz), float(t0)


@njit(inline="always", cache=True)
def leave_towards(strategy, g, eps, px, py, pz, gx, gy, gz, wx, wy, wz):
    """:func:`leave` from p on the side of the direction w (geometric normal g), without
    branches, for loops that LLVM vectorises over rays: R's ``strategy``, ``eps`` and an
    array ``g`` of its precision given apart (:func:`impl.offset.spawn_select`)."""
    side = 1.0 if gx * wx + gy * wy + gz * wz >= 0.0 else -1.0
    ox, oy, oz, t0 = spawn_select(strategy, like(g, px), like(g, py), like(g, pz), like(g, side * gx),
                                  like(g, side * gy), like(g, side * gz), like(g, eps))
    return float(ox), float(oy), float(oz), float(t0)
