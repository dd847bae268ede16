"""Unbiased Monte Carlo path tracing of the rendering equation — registered as ``path``.

The rendering equation (Kajiya 1986, :doi:`10.1145/15886.15902`; thesis
3.2.2) ``L(x, ω) = L_e(x, ω) + ∫ f(x, ω, ω') L(x', −ω') cos θ' dω'`` is
estimated by random walks from the eye: at every vertex the BSDF
(:mod:`impl.bsdf`, thesis 3.2.1) is sampled for the next direction, and
*next-event estimation* adds a light sample (:mod:`impl.light_sampling`)
combined with the BSDF-sampled hits of emitters by *multiple importance
sampling* with Veach's power heuristic (E. Veach, L. Guibas, "Optimally
combining sampling techniques for Monte Carlo rendering", SIGGRAPH 1995,
:doi:`10.1145/218380.218498`).  Paths are ended by Russian roulette
(Arvo & Kirk 1990) with Mitsuba 3's rule.

What it computes
----------------
Exactly the quantity of Mitsuba 3's ``path`` integrator at the same
``max_depth``, so the two are compared with a per-pixel Z-test:

* ``max_depth`` counts path *vertices after the eye*: 1 sees only emitters
  met by eye rays, 2 adds direct light, m adds light scattered m − 1 times;
  −1 is unbounded.  Emission at vertex k is added, and a light sample /
  BSDF sample taken only while k + 1 < ``max_depth`` (Mitsuba's
  ``active_next``).
* Emission: front side of area emitters only.  The BSDF-sampled hit of an
  emitter after a non-delta bounce is weighted w = p_bsdf² / (p_bsdf² +
  p_light²), the light sample by w = p_light² / (p_light² + p_bsdf²) (delta
  lights and delta BSDFs take w = 1).  ``mis=false`` turns MIS off: light
  samples with weight 1 and BSDF-sampled emitter hits after non-delta
  bounces ignored (plain next-event estimation, still unbiased).
* Russian roulette from depth ``rr_depth`` on (after the depth counter is
  incremented, as Mitsuba): continue with q = min(max(throughput)·η², 0.95),
  η the product of the relative IORs crossed; survivors are divided by q.
* Lights: area emitters (triangle meshes and spheres), point, spot and
  directional lights, projectors (:mod:`impl.projector`, RGB only), a spot's
  bitmap ``texture`` (:func:`impl.lighting.delta_filter`, Mitsuba's uv, RGB only);
  one light is picked uniformly per vertex.  A
  ``constant`` environment emitter is reached by BSDF sampling only: a ray
  that leaves the scene adds throughput · L_env with weight 1 (it is never
  light-sampled, so no MIS weight applies; unbiased, and noisier than
  sampling it would be on small-aperture views of the sky).  Without one,
  rays that leave the scene carry nothing.  An ``envmap`` is one more light
  (:func:`impl.light_sampling.sample_light` draws a direction by the map's
  luminance) and a ray that leaves the scene after a non-delta bounce is
  weighted by the power heuristic against it, as Mitsuba's ``path`` does.
* Materials (:mod:`impl.bsdf`): ``diffuse`` (textures included), smooth
  ``conductor`` and ``dielectric``, ``roughconductor`` and
  ``roughdielectric`` (Beckmann, Smith G; :mod:`impl.microfacet`), named
  conductors (``material="Au"``: Mitsuba's RGB indices,
  :func:`impl.materials.named_conductor`), ``plastic`` and ``roughplastic``
  (a textured ``diffuse_reflectance`` included: ρ(u, v) as for ``diffuse``);
  two-sided opaque materials; ``thindielectric`` (:mod:`impl.bsdf`); a
  ``blendbsdf`` of two of these or of other blendbsdfs (the component sampled by
  u0 against the weight, level by level, :func:`_pick_leaf`; the weight and pdf of
  the mixture as Mitsuba 3.9.1's ``blendbsdf.sample``: the other leaves' f·cos and
  pdf at the sampled direction are added, each times the product of the weights
  down to it, also when the sampled one is a delta; light samples see the weighted
  sum); a
  ``mask`` around any of them (with probability 1 − opacity a null event: the
  ray goes straight on, weight 1, counted as a delta bounce and a depth step,
  as Mitsuba's ``path`` counts it; the nested BSDF's f and pdf times the
  opacity); opacity, blend weight and the ``alpha`` of a roughconductor /
  roughdielectric may be a constant, a bitmap or (alpha) a checkerboard, read as
  Mitsuba's ``eval_1``; anisotropic roughness (``alpha_u``/``alpha_v``, each a
  constant or such a texture; Beckmann and GGX, :mod:`impl.microfacet`) in
  Mitsuba's shading frame, s along the surface's ∂p/∂u
  (:func:`impl.shading_frame.tangent`; under a normal map made orthogonal to the
  perturbed normal, :func:`impl.shading_frame.perturbed_tangent`; not under a bump
  map); a
  textured ``specular_reflectance`` of a conductor or dielectric (smooth, rough or
  thin; RGB; its value multiplies the reflected f and weights, as Mitsuba's,
  :func:`impl.materials.with_specular_textures`), a textured
  ``specular_transmittance`` the transmitted ones, and a conductor's textured
  ``eta`` or ``k`` gives the Fresnel term of its value at the hit (:func:`_tint`).  Shadow
  rays stop at any surface, masks and thin dielectrics included (Mitsuba's
  ``path`` tests visibility with ``ray_test``); ``normalmap`` and ``bumpmap``
  around any of them
  on triangles with uvs (:mod:`impl.shading_frame`: the BSDF evaluated and
  sampled in the perturbed frame, directions on opposite sides of the true
  and the perturbed shading normal dropped, Estevez et al.'s shadowing term).

Spectral mode (``spectral=true``, :mod:`impl.spectral`): each path carries
three hero-rotated wavelengths instead of RGB; reflectances and emissions come
from the scene's ``<spectrum>`` elements (grey RGB values accepted, coloured
RGB refused), and each sample is converted to linear sRGB through the CIE
1931 colour matching functions before the pixel mean.  A dielectric with the
gibench-only ``cauchy_b`` disperses: the hero wavelength's index decides the
direction and the other two wavelengths are dropped there.  Validated
against Mitsuba's ``llvm_ad_spectral`` on ``suites/cornell/cornell_spectral.xml``
and, for dispersion (which Mitsuba cannot render), against a prism's
analytic deviation angles.

Deliberately biased variants (the ``debug_bias`` keyword of :func:`render`, not
a parameter of the table) exist only to show that the
Z-test against Mitsuba has the power to reject a biased estimator:
``rr_no_reweight`` (Russian roulette without the 1/q weight) and
``mis_unnormalised`` (the light sample's power-heuristic weight computed
with its two pdfs swapped, a classic bug: w_light + w_bsdf =
2 p_bsdf² / (p_light² + p_bsdf²) ≠ 1, so direct light from area emitters
is mostly lost).  A variant that over-weights the *BSDF-sampled* emitter
hits is biased too, but its excess comes from rare, large samples, which a
per-pixel Z-test at test sample counts cannot see (z ≈ √(p n) for an event
of probability p per sample and n samples).

Pixel sampling as in ``raycast``/``whitted`` (:mod:`impl.sampling`):
``spp = k²`` jittered strata with a box filter, returning the variance of
the pixel mean.  ``sampler=sobol`` takes the pixel position from
Owen-scrambled Sobol points and every number a vertex draws from padded,
Owen-scrambled low-discrepancy points (:func:`_sobol_numbers`): the light
sample's and the BSDF sample's 2-D numbers a Sobol pair each, the choice of
light, of lobe and the roulette number a van der Corput dimension each, all
stratified over a pixel's samples (as Mitsuba's ``multijitter`` does every
dimension).  Without it (``jitter``) they are hashed uniform numbers.  A
``thinlens`` sensor adds a uniform aperture point per eye
ray (:func:`impl.camera.eye_ray_lens`, Mitsuba's ``thinlens``).  Every ray goes through :mod:`impl.rays` (parameters
``intersect``, ``precision``, ``offset``, ``epsilon``).

Counters: ``paths`` (= eye rays), ``shadow_rays``, ``bounce_rays``
(BSDF-sampled rays), ``rr_terminated``, ``depth_cut`` (paths stopped by
``max_depth``), ``segments`` and ``mean_path_length`` (segments per path).

Parameters
----------
==========  =====  =======  ===============================================
name        type   default  meaning
==========  =====  =======  ===============================================
spp         int    16       pixel samples: 1 = centre, k² = k×k strata
max_depth   int    -1       Mitsuba's meaning (1 = emitters only, 2 =
                            direct light, -1 = unbounded)
rr_depth    int    5        Russian roulette from this depth on
mis         bool   true     MIS (power heuristic) of light and BSDF samples
spectral    bool   false    hero-wavelength spectral rendering (impl.spectral)
lanes       bool   true     diffuse vertices a path per vector lane
                            (:mod:`impl.path_lanes`); false: scalar, same image
sampler     str    jitter   jitter | sobol (pixel position and every number
                            a vertex draws)
(rays)                      intersect, precision, offset, epsilon, accel,
                            slab_normals (:mod:`impl.rays`)
packets     bool   false    trace the eye rays of 8×8 pixel tiles as
                            coherent packets (:mod:`impl.accel.packets`)
==========  =====  =======  ===============================================

Structure: the tracer core of :mod:`impl.tracer` renders tile by tile and
traces each sample index's eye rays of a tile as one batch (with
``packets=true`` as packets through the tree, :mod:`impl.accel.packets`);
the tile's paths then walk on as a *wavefront*: one vertex of every walking
path at a time (:func:`_vertices`: emission, light sample, BSDF sample,
roulette), then the light samples' shadow rays as one
:func:`impl.tracer.occluded_batch` and the continuing rays as one
:func:`impl.tracer.closest_batch`, until every path has ended.  A path's
random numbers depend on its pixel, sample and vertex only, so the order in
which paths are walked does not change the image.  Same image and counters with and without
packets, plus ``packet_nodes`` / ``packet_tests``; packets need a tree
(``accel=auto`` then means ``bvh-sah``).

Vertices on plain ``diffuse`` surfaces (no mask, normal or bump map, parameter
texture; RGB, no ``debug_bias``) leave the scalar loop once their normals,
reflectance and random numbers are known: :func:`_to_lane` writes them into a
lane table, :mod:`impl.path_lanes` computes their light samples' contributions and
shadow rays, BSDF samples and roulette a path per vector lane, and
:func:`_from_lanes` queues and compacts what they give.  A light sample on a mesh
emitter taken for such a vertex is left half done by :func:`_light_samples` (the
point and the emitter), the lanes completing it.  The same operations in the same
order: ``lanes=false`` gives the same image and counters bit for bit, the vertices
all scalar.

Example::

    from core.loader import load_scene
    from impl.path import ALGORITHM as algo
    res = algo.render(load_scene("suites/cornell/cornell_box.xml"),
                      algo.parse_params({"spp": 64, "max_depth": 8}), seed=0)
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit

from core.algorithm import Algorithm, Param, RenderResult
from core.scene import Scene, scene_features
from core.errors import ParamError, UnsupportedError

from .bsdf import bsdf_arrays, bsdf_eval_at, bsdf_pdf_at, bsdf_sample_at, frame, is_delta, is_dielectric
from .bsdf import to_local, to_world
from .materials import (MAT_BLEND, MAT_CONDUCTOR, MAT_DIELECTRIC, MAT_DIFFUSE, MAT_ROUGHCONDUCTOR,
                        MAT_ROUGHDIELECTRIC, MAT_THINDIELECTRIC, MaterialArrays, expand_components,
                        with_specular_textures)
from .camera import camera_params
from .kernel import batch_kernel, run_tasks, take_task
from .light_sampling import (LightArrays, emitter_pdf, emitter_point, environment_pdf, flatten_with_lights,
                             light_index, power_heuristic, sample_light)
from .lighting import (diffuse_albedo, environment_radiance, param_rgb, surface_at, textured_fresnel,
                       textured_params, transmittance_tint)
from .rays import PARAMS as RAY_PARAMS
from .rays import RayConfig, leave, refine, round_ray
from .lowdiscrepancy import dimension_seed, pixel_seed, sample_1d_seeded, sample_2d_seeded
from . import path_lanes as pl
from .rng import uniform_from, uniform_prefix
from .sampling import SAMPLER_PARAM, check_spp, sampler_code
from .scene_arrays import PTEX_PLASTIC_SPECULAR, SHADE_BUMPMAP, SceneArrays, scene_memo
from .shading_frame import bump_tangent, perturbed_normal, perturbed_tangent, same_side, shadow_terminator, tangent
from .textures import bitmap, checkerboard, luminance, scalar_param
from .spectral import (SpectralArrays, eta_scale_at, rgb_arrays_placeholder, sample_wavelengths,
                       spectral_arrays, spectrum_at, to_linear_srgb)
from .tracer import (accumulate, Batch, closest_batch, DX, DY, DZ, eye_batch, Film, film_counters,
                     film_result, new_batch, new_film, occluded_batch, OX, OY, OZ, ray_config_cached,
                     store, TMAX, TMIN)

__all__ = ["render", "COUNTERS", "DEBUG_BIAS", "ALGORITHM"]

#: Per-pixel integer counters, in kernel order.
COUNTERS = ("paths", "shadow_rays", "bounce_rays", "rr_terminated", "depth_cut", "segments")
_C_PATH, _C_SHADOW, _C_BOUNCE, _C_RR, _C_DEPTH, _C_SEG = range(6)

#: Deliberately biased variants (for the power of the Z-test), by code.
DEBUG_BIAS = ("none", "rr_no_reweight", "mis_unnormalised")
_BIAS_NONE, _BIAS_RR, _BIAS_MIS = range(3)

#: Random dimensions used per path vertex (light: 3, BSDF: 3, roulette: 1).
_DIMS_PER_VERTEX = 8
#: The random dimension of the hero wavelength (beyond any path's vertices).
_DIM_WAVELENGTH = 1 << 30


@njit(inline="always", cache=True)
def _roughness(B, mat, ns, prim, tri_uv, b1, b2):
    """(α_u, α_v) of ``mat`` at a hit: the constants or their textures' values
    (:func:`impl.textures.scalar_param`, slots 2 and 3); α_v = α_u unless the row is
    anisotropic."""
    alpha = B.alpha[mat]
    if B.ptex[mat, 2, 0] != 0:
        alpha = scalar_param(B, mat, 2, alpha, ns, prim, tri_uv, b1, b2)
    alpha_v = alpha
    if B.aniso[mat] != 0:
        alpha_v = B.alpha_v[mat]
        if B.ptex[mat, 3, 0] != 0:
            alpha_v = scalar_param(B, mat, 3, alpha_v, ns, prim, tri_uv, b1, b2)
    return alpha, alpha_v


@njit(inline="always", cache=True)
def _coat(A: SceneArrays, B: MaterialArrays, mat, prim, b1, b2):
    """A plastic's ``specular_reflectance`` (r, g, b) at a hit, which weights its specular
    coat and not its diffuse base (Mitsuba's ``plastic`` and ``roughplastic`` multiply
    that lobe by the texture's ``eval``): its texture's value there
    (:func:`impl.lighting.param_rgb`, slot ``PTEX_PLASTIC_SPECULAR``) or the constant
    ``B.pl_specular[mat]`` (zeros for the other kinds, which ignore it)."""
    if A.mat_ptex[mat, PTEX_PLASTIC_SPECULAR, 0] != 0:
        return param_rgb(A, mat, PTEX_PLASTIC_SPECULAR, prim, b1, b2)
    return B.pl_specular[mat, 0], B.pl_specular[mat, 1], B.pl_specular[mat, 2]


@njit(inline="always", cache=True)
def _specular_texture(A: SceneArrays, B: MaterialArrays, mat):
    """Whether ``mat`` is a conductor or dielectric (smooth, rough or thin) whose
    ``specular_reflectance`` is a texture (:func:`impl.materials.with_specular_textures`
    moved it to the diffuse texture slot: ρ at the hit is its value)."""
    k = B.kind[mat]
    return A.mat_tex[mat] != 0 and (k == MAT_CONDUCTOR or k == MAT_ROUGHCONDUCTOR or k == MAT_DIELECTRIC
                                    or k == MAT_ROUGHDIELECTRIC or k == MAT_THINDIELECTRIC)


@njit(inline="always", cache=True)
def _tinted(A: SceneArrays, B: MaterialArrays, mat):
    """Whether ``mat``'s f or sample weight takes a factor read from a texture at the hit
    (:func:`_tint`)."""
    return _specular_texture(A, B, mat) or textured_params(A, mat)


@njit(inline="always", cache=True)
def _tint(A: SceneArrays, B: MaterialArrays, mat, prim, b1, b2, rho_r, rho_g, rho_b, wix, wiy, wiz, wox, woy,
          woz):
    """The factor (r, g, b) that textured parameters put on material ``mat``'s f·|cos| and
    sample weight between local directions wi and wo, as Mitsuba multiplies by their
    ``eval``: reflected (wi, wo on one side), a textured ``specular_reflectance`` (its
    value ρ at the hit) and a conductor's Fresnel term of its textured η + ik at the
    microfacet normal h = (wi + wo)/|wi + wo| (:func:`impl.lighting.textured_fresnel`;
    the row's own term is 1); transmitted, a textured ``specular_transmittance``
    (:func:`impl.lighting.transmittance_tint`)."""
    if wiz * woz <= 0.0:
        return transmittance_tint(A, mat, prim, b1, b2)
    kr = kg = kb = 1.0
    if _specular_texture(A, B, mat):
        kr, kg, kb = rho_r, rho_g, rho_b
    if textured_params(A, mat):
        hx, hy, hz = wix + wox, wiy + woy, wiz + woz
        lh = math.sqrt(hx * hx + hy * hy + hz * hz)
        c = (wix * hx + wiy * hy + wiz * hz) / lh if lh > 0.0 else 1.0
        fr, fg, fb = textured_fresnel(A, mat, prim, b1, b2, c)
        kr, kg, kb = kr * fr, kg * fg, kb * fb
    return kr, kg, kb


@njit(inline="always", cache=True)
def _leaf_weight(A: SceneArrays, B: MaterialArrays, mat, k, prim, b1, b2):
    """The weight of leaf ``k`` of blendbsdf ``mat`` at a hit: over its blendbsdf
    ancestors, the product of w (the second component taken) or 1 − w (the first), w
    each one's weight there."""
    ns = A.sph_radius.shape[0]
    wk = 1.0
    for d in range(B.leaf_node.shape[2]):
        node = B.leaf_node[mat, k, d]
        if node < 0:
            break
        w = scalar_param(B, node, 1, B.blend_w[node], ns, prim, A.tri_uv, b1, b2)
        wk *= w if B.leaf_branch[mat, k, d] == 1 else 1.0 - w
    return wk


@njit(inline="always", cache=True)
def _pick_leaf(A: SceneArrays, B: MaterialArrays, mat, u, prim, b1, b2):
    """The leaf of blendbsdf ``mat`` a BSDF sample comes from, chosen by ``u`` as Mitsuba's
    nested ``blendbsdf.sample`` calls choose (at each blendbsdf of weight w the first
    component when u > w, u then rescaled to (u − w)/(1 − w), else the second, u/w):
    ``(row, leaf index, its weight, the rescaled u)``."""
    ns = A.sph_radius.shape[0]
    row = mat
    for d in range(B.leaf_node.shape[2] + 1):
        if B.kind[row] != MAT_BLEND:
            break
        w = scalar_param(B, row, 1, B.blend_w[row], ns, prim, A.tri_uv, b1, b2)
        if u > w:
            row = B.comp[row, 0]
            u = (u - w) / (1.0 - w)
        else:
            row = B.comp[row, 1]
            u = u / w if w > 0.0 else 0.0
    k = 0
    while B.leaf[mat, k] != row:    # the path taken leads to one leaf; find its index
        k += 1
    return row, k, _leaf_weight(A, B, mat, k, prim, b1, b2), u


@njit(cache=True)
def _blend_eval_pdf(A: SceneArrays, B: MaterialArrays, mat, skip, prim, b1, b2, eta_scale,
                    wix, wiy, wiz, wox, woy, woz):
    """A blendbsdf's f·|cos θ_o| (RGB) and pdf at (wi, wo): the sum over its leaves of
    the leaf's weight (:func:`_leaf_weight`) × its f and pdf, as Mitsuba's
    ``blendbsdf.eval_pdf`` sums (1 − w) × its first component's + w × its second's,
    nested ones in turn; leaving out leaf ``skip`` (−1 none, passed as ``np.int64(-1)``:
    a literal would compile it a second time).  A plain call, not inlined: it holds a
    second copy of the BSDF dispatch, run only at blendbsdf vertices."""
    fr = fg = fb = pdf = 0.0
    for k in range(B.leaf.shape[1]):
        c = B.leaf[mat, k]
        if c < 0:
            break
        if k == skip:
            continue
        wk = _leaf_weight(A, B, mat, k, prim, b1, b2)
        rr, rg, rb = diffuse_albedo(A, c, prim, b1, b2)
        al, av = _roughness(B, c, A.sph_radius.shape[0], prim, A.tri_uv, b1, b2)
        cr, cg, cb = _coat(A, B, c, prim, b1, b2)
        er, eg, eb = bsdf_eval_at(B, c, al, av, rr, rg, rb, cr, cg, cb, eta_scale, wix, wiy, wiz, wox, woy,
                                  woz)
        if _tinted(A, B, c):
            kr, kg, kb = _tint(A, B, c, prim, b1, b2, rr, rg, rb, wix, wiy, wiz, wox, woy, woz)
            er, eg, eb = er * kr, eg * kg, eb * kb
        fr += wk * er
        fg += wk * eg
        fb += wk * eb
        pdf += wk * bsdf_pdf_at(B, c, al, av, eta_scale, wix, wiy, wiz, wox, woy, woz)
    return fr, fg, fb, pdf


class PathConfig(NamedTuple):
    """The path tracer's parameters as one kernel argument."""

    spectral: bool              # hero wavelengths instead of RGB
    max_depth: int              # Mitsuba's max_depth (-1 unbounded)
    rr_depth: int               # Russian roulette from this depth on
    mis: bool                   # power-heuristic MIS of light and BSDF samples
    bias: int                   # DEBUG_BIAS code
    sobol: bool                 # a vertex's numbers from padded Owen-scrambled points
    lanes: np.ndarray           # (M,) bool: the materials whose vertices run in lanes


class Walks(NamedTuple):
    """The state of a tile's paths between two bounces (:func:`_tile`), by eye-ray column
    ``c`` except ``col``: the wavefront of one sample index's paths.  The rays still
    walking sit in the first ``m`` columns of the tile's batch (``T.ray``, their hits in
    ``T.t``/``T.prim``/``T.b``), position ``k`` holding the path of column ``col[k]``."""

    col: np.ndarray             # (n,) int64 the path at each position of the batch
    thr: np.ndarray             # (3, n) path throughput
    f: np.ndarray               # (_W_ROWS, n) η, pdf of the last bounce, last vertex, wavelengths
    depth: np.ndarray           # (n,) int64 vertices after the eye so far
    delta: np.ndarray           # (n,) bool: the last bounce was a delta one (the eye ray is)
    single: np.ndarray          # (n,) bool: the secondary wavelengths were dropped (dispersion)
    h: np.ndarray               # (n,) uint64 the hashed numbers' prefix of the column's sample
    seq: np.ndarray             # (n,) uint64 the pixel's Sobol scramble seed
    ls: np.ndarray              # (_LS_ROWS, n) by position: hit point, light sample, BSDF numbers
    lane: np.ndarray            # (impl.path_lanes.ROWS, n) the diffuse vertices' lane table
    lane_i: np.ndarray          # (impl.path_lanes.INT_ROWS, n) its integer rows


#: Rows of ``Walks.f``.
_W_ETA, _W_PDF, _W_PX, _W_PY, _W_PZ, _W_L0, _W_L1, _W_L2 = range(8)
_W_ROWS = 8
#: Rows of ``Walks.ls`` (:func:`_light_samples`): the vertex, the light sample of
#: :func:`impl.light_sampling.sample_light` (ER = 0: none), the BSDF sample's (u1, u2);
#: with ``sampler=sobol`` the numbers of :func:`_sobol_numbers` (LU0..LU2 the light
#: sample's, U1, U2, ULOBE the BSDF sample's, URR the roulette's); at a vertex left to
#: the lanes whose sample is on a mesh emitter, only that sample's point Y, the
#: emitter's front normal N, its area (AREA > 0) and radiance E, the lanes computing the
#: rest (:func:`impl.light_sampling.emitter_sample`).
(_LS_PX, _LS_PY, _LS_PZ, _LS_WX, _LS_WY, _LS_WZ, _LS_DIST, _LS_YX, _LS_YY, _LS_YZ, _LS_ER, _LS_EG,
 _LS_EB, _LS_PDF, _LS_DELTA, _LS_LIGHT, _LS_U1, _LS_U2, _LS_NX, _LS_NY, _LS_NZ, _LS_AREA, _LS_LU0,
 _LS_LU1, _LS_LU2, _LS_ULOBE, _LS_URR) = range(27)
_LS_ROWS = 27
#: The ``Walks.ls`` row of :func:`_sobol_numbers` standing for hashed dimension
#: ``dim + j`` of a vertex (:func:`_number`): j = 0 the light's choice, 1 and 2 its
#: point, 3 the lobe, 4 and 5 the BSDF direction, 6 the roulette.
_NUMBER_ROWS = (_LS_LU0, _LS_LU1, _LS_LU2, _LS_ULOBE, _LS_U1, _LS_U2, _LS_URR)


@njit(inline="always", cache=True)
def _number(ls, k, h, dim, j, sobol):
    """Number ``j`` of the vertex at batch position ``k``: with ``sampler=sobol`` the one
    :func:`_sobol_numbers` put in ``ls``, else the path's hashed dimension ``dim + j``."""
    return ls[_NUMBER_ROWS[j], k] if sobol else uniform_from(h, dim + j)


@njit(cache=True)
def _new_walks(n):
    D, I = pl.new_lanes(n)
    return Walks(np.empty(n, np.int64), np.empty((3, n)), np.empty((_W_ROWS, n)),
                 np.empty(n, np.int64), np.empty(n, np.bool_), np.empty(n, np.bool_),
                 np.empty(n, np.uint64), np.empty(n, np.uint64), np.empty((_LS_ROWS, n)), D, I)


@batch_kernel
def _start(P: PathConfig, seed, sample, T: Batch, W: Walks):
    """Every column's path at its eye ray: throughput 1, no radiance, the hero wavelengths
    in spectral mode."""
    for c in range(T.n):
        W.col[c] = c
        W.thr[0, c] = W.thr[1, c] = W.thr[2, c] = 1.0
        T.L[0, c] = T.L[1, c] = T.L[2, c] = 0.0
        W.f[_W_ETA, c] = 1.0
        W.f[_W_PDF, c] = 1.0
        W.f[_W_PX, c], W.f[_W_PY, c], W.f[_W_PZ, c] = T.ray[OX, c], T.ray[OY, c], T.ray[OZ, c]
        h = uniform_prefix(seed, T.pixel[c], sample)
        W.h[c] = h
        W.seq[c] = pixel_seed(T.pixel[c], 0, seed)
        w0 = w1 = w2 = 0.0
        if P.spectral:
            w0, w1, w2 = sample_wavelengths(uniform_from(h, _DIM_WAVELENGTH))
        W.f[_W_L0, c], W.f[_W_L1, c], W.f[_W_L2, c] = w0, w1, w2
        W.depth[c] = 0
        W.delta[c] = True
        W.single[c] = False
        T.cnt[c, _C_PATH] += 1


@batch_kernel(disjoint=True)
def _sobol_numbers(col, depth, seq, ls, sample, m):
    """``sampler=sobol``: the numbers of sample ``sample``'s vertex of each of the ``m``
    walking paths into ``ls``: the light sample's choice (1-D) and point (2-D), the BSDF
    sample's lobe (1-D) and direction (2-D) and the roulette number (1-D).  Each is point
    ``sample`` of a pixel's sequence with scrambles of its own (padding, as pbrt-v4's
    ``PaddedSobolSampler``): the 2-D ones Sobol pairs
    (:func:`impl.lowdiscrepancy.sample_2d_seeded`), the 1-D ones van der Corput points
    (:func:`impl.lowdiscrepancy.sample_1d_seeded`), their 32-bit scramble seeds
    :func:`impl.lowdiscrepancy.dimension_seed` of the pixel's seed and
    ``_SEEDS_PER_VERTEX · depth + j``.  A pixel's first 2^m samples of a pair are a
    (0, m, 2)-net and of a 1-D number one per stratum of width 2^-m, and each number is
    uniform, so the estimate stays unbiased.  Stratifying the 1-D numbers matters: the
    roulette's survivors carry weights 1/q, and stratified numbers end a pixel's paths in
    the expected proportion instead of a binomial one.  A loop of its own, without
    branches: integer hashing in 32-bit vector lanes."""
    for k in range(m):
        c = col[k]
        s = seq[c]
        d0 = _SEEDS_PER_VERTEX * depth[c]
        ls[_LS_LU1, k], ls[_LS_LU2, k] = sample_2d_seeded(
            sample, dimension_seed(s, d0), dimension_seed(s, d0 + 1), dimension_seed(s, d0 + 2))
        ls[_LS_U1, k], ls[_LS_U2, k] = sample_2d_seeded(
            sample, dimension_seed(s, d0 + 3), dimension_seed(s, d0 + 4), dimension_seed(s, d0 + 5))
        ls[_LS_LU0, k] = sample_1d_seeded(sample, dimension_seed(s, d0 + 6), dimension_seed(s, d0 + 7))
        ls[_LS_ULOBE, k] = sample_1d_seeded(sample, dimension_seed(s, d0 + 8), dimension_seed(s, d0 + 9))
        ls[_LS_URR, k] = sample_1d_seeded(sample, dimension_seed(s, d0 + 10), dimension_seed(s, d0 + 11))


#: Scramble seeds of a vertex's numbers in :func:`_sobol_numbers`: three per 2-D pair, two
#: per 1-D number.
_SEEDS_PER_VERTEX = 12


@batch_kernel
def _light_samples(A: SceneArrays, L: LightArrays, B: MaterialArrays, R: RayConfig, P: PathConfig,
                   T: Batch, W: Walks, m):
    """The hit point of each of the ``m`` walking paths and, where its vertex takes one,
    its light sample (:func:`impl.light_sampling.sample_light`) into ``W.ls`` (with
    ``sampler=sobol``, from the numbers :func:`_sobol_numbers` put there).  A loop of its
    own, ahead of :func:`_vertices`: each sample is a chain of dependent square roots and
    divisions, and in a short loop the processor overlaps the chains of consecutive
    paths, which it cannot within the long body of a vertex."""
    ls = W.ls
    for k in range(m):
        prim = T.prim[k]
        ls[_LS_ER, k] = ls[_LS_EG, k] = ls[_LS_EB, k] = ls[_LS_AREA, k] = 0.0
        if prim < 0:
            continue
        c = W.col[k]
        depth = W.depth[c]
        t = T.t[k]
        px, py, pz = refine(R, prim, T.b[0, k], T.b[1, k], T.ray[OX, k] + t * T.ray[DX, k],
                            T.ray[OY, k] + t * T.ray[DY, k], T.ray[OZ, k] + t * T.ray[DZ, k])
        ls[_LS_PX, k], ls[_LS_PY, k], ls[_LS_PZ, k] = px, py, pz
        if P.max_depth >= 0 and depth + 1 >= P.max_depth:
            continue
        mat = A.shape_material[A.prim_shape[prim]]
        if L.n_lights == 0 or is_delta(B, mat):
            continue
        h = W.h[c]
        dim = 2 + _DIMS_PER_VERTEX * depth
        u0, u1, u2 = _number(ls, k, h, dim, 0, P.sobol), _number(ls, k, h, dim, 1, P.sobol), \
            _number(ls, k, h, dim, 2, P.sobol)
        e = light_index(L, u0) - A.light_kind.shape[0]
        if P.lanes[mat] and 0 <= e < A.em_area.shape[0] and A.em_area[e] > 0.0:   # the lanes complete it
            ls[_LS_YX, k], ls[_LS_YY, k], ls[_LS_YZ, k], ls[_LS_NX, k], ls[_LS_NY, k], ls[_LS_NZ, k] = \
                emitter_point(A, e, u1, u2)
            ls[_LS_AREA, k] = A.em_area[e]
            sh = A.em_shape[e]
            ls[_LS_ER, k], ls[_LS_EG, k], ls[_LS_EB, k] = L.shape_emit[sh, 0], L.shape_emit[sh, 1], \
                L.shape_emit[sh, 2]
            ls[_LS_DELTA, k] = 0.0
            continue
        (ls[_LS_WX, k], ls[_LS_WY, k], ls[_LS_WZ, k], ls[_LS_DIST, k], ls[_LS_YX, k], ls[_LS_YY, k],
         ls[_LS_YZ, k], ls[_LS_ER, k], ls[_LS_EG, k], ls[_LS_EB, k], ls[_LS_PDF, k], delta,
         li) = sample_light(A, L, px, py, pz, u0, u1, u2)
        ls[_LS_DELTA, k] = 1.0 if delta else 0.0
        ls[_LS_LIGHT, k] = li


@batch_kernel
def _vertices(A: SceneArrays, L: LightArrays, B: MaterialArrays, R: RayConfig, S: SpectralArrays,
              P: PathConfig, T: Batch, W: Walks, m):
    """One vertex of each of the ``m`` walking paths, at the closest hit of its ray: the
    emission it sees, the light sample of :func:`_light_samples` (its shadow ray and contribution queued in
    ``T.sh``/``T.sh_w``/``T.sh_i`` for :func:`occluded_batch`) and the BSDF sample
    that continues the path, or its end (the scene left, ``max_depth``, a zero
    weight, Russian roulette).  Continuing rays are moved to the front of the batch.
    Returns (paths walking on, shadow rays queued).

    The loop over the batch's rays lives here, so that the scene's arrays are handed
    over once per batch, not once per path.
    """
    ns = A.sph_radius.shape[0]
    spectral, max_depth, rr_depth, mis, bias = P.spectral, P.max_depth, P.rr_depth, P.mis, P.bias
    sobol = P.sobol
    walking = 0
    queued = 0
    nl = 0                           # vertices left to the lanes
    for k in range(m):
        c = W.col[k]
        h = W.h[c]                   # this path's random numbers: dimension d is
        ls = W.ls                    # uniform_from(h, d), or with sobol ls (_number)
        w0, w1, w2 = W.f[_W_L0, c], W.f[_W_L1, c], W.f[_W_L2, c]
        counts = T.cnt[c]
        dx, dy, dz = T.ray[DX, k], T.ray[DY, k], T.ray[DZ, k]
        t, prim, b1, b2 = T.t[k], T.prim[k], T.b[0, k], T.b[1, k]
        tr, tg, tb = W.thr[0, c], W.thr[1, c], W.thr[2, c]
        eta = W.f[_W_ETA, c]
        depth = W.depth[c]
        prev_pdf = W.f[_W_PDF, c]
        prev_delta = W.delta[c]
        ppx, ppy, ppz = W.f[_W_PX, c], W.f[_W_PY, c], W.f[_W_PZ, c]
        single = W.single[c]
        counts[_C_SEG] += 1
        if prim < 0:                 # left the scene: the environment
            er, eg, eb = environment_radiance(A, dx, dy, dz)
            if not prev_delta and A.env_image.shape[0] > 0:   # an envmap is light-sampled too
                w = power_heuristic(prev_pdf, environment_pdf(A, L, dx, dy, dz)) if mis else 0.0
                er, eg, eb = w * er, w * eg, w * eb
            T.L[0, c] += tr * er
            T.L[1, c] += tg * eg
            T.L[2, c] += tb * eb
            continue
        shape = A.prim_shape[prim]
        px, py, pz = ls[_LS_PX, k], ls[_LS_PY, k], ls[_LS_PZ, k]
        gx, gy, gz, sx, sy, sz = surface_at(A, prim, b1, b2, px, py, pz, A.shape_flip[shape])
        vx, vy, vz = -dx, -dy, -dz
        cos_v = sx * vx + sy * vy + sz * vz

        # Emitted radiance (front side), MIS-weighted after a non-delta bounce.
        if cos_v > 0.0 and (L.shape_emit[shape, 0] > 0.0 or L.shape_emit[shape, 1] > 0.0
                            or L.shape_emit[shape, 2] > 0.0):
            w = 1.0
            if not prev_delta:
                if mis:
                    cos_y = abs(gx * vx + gy * vy + gz * vz)
                    w = power_heuristic(prev_pdf, emitter_pdf(A, L, shape, ppx, ppy, ppz, t, cos_y))
                else:
                    w = 0.0          # plain NEE: the light sample already counted this
            if spectral:
                er = spectrum_at(S.emit_spec[shape], w0)
                eg = spectrum_at(S.emit_spec[shape], w1)
                eb = spectrum_at(S.emit_spec[shape], w2)
            else:
                er, eg, eb = L.shape_emit[shape, 0], L.shape_emit[shape, 1], L.shape_emit[shape, 2]
            T.L[0, c] += tr * w * er
            T.L[1, c] += tg * w * eg
            T.L[2, c] += tb * w * eb

        if max_depth >= 0 and depth + 1 >= max_depth:
            counts[_C_DEPTH] += 1
            continue
        mat = A.shape_material[shape]
        dim = 2 + _DIMS_PER_VERTEX * depth
        if P.lanes[mat]:             # a plain diffuse BSDF: the rest of the vertex in lanes
            _to_lane(A, W, nl, k, c, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz, tr, tg,
                     tb, eta, depth, h, dim, sobol)
            nl += 1
            continue
        delta = is_delta(B, mat)
        # A mask: its opacity here; a blendbsdf: the leaf the BSDF sample will come
        # from (Mitsuba: the second component when u0 <= w, at every level), its weight
        # and u0 rescaled for it.
        u0s = _number(ls, k, h, dim, 3, sobol)
        opac = B.opacity[mat]
        if opac < 1.0:
            opac = scalar_param(B, mat, 0, opac, ns, prim, A.tri_uv, b1, b2)
        smat = mat
        blend = B.kind[mat] == MAT_BLEND
        ck = 0
        wk = ub = 0.0
        if blend:
            us = u0s / opac if opac < 1.0 else u0s     # the nested BSDF's share of u0
            smat, ck, wk, ub = _pick_leaf(A, B, mat, us, prim, b1, b2)
        alpha, alpha_v = _roughness(B, smat, ns, prim, A.tri_uv, b1, b2)   # textured: its value here
        # A two-sided opaque BSDF is seen from the front on both sides.
        back = not is_dielectric(B, mat) and A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0
        # A normal or bump map: the BSDF's frame turns to the perturbed normal n.
        shade = A.mat_shade[mat]
        nx, ny, nz = sx, sy, sz
        if shade != 0 and prim >= ns:
            nx, ny, nz = perturbed_normal(shade, A.mat_shade_scale[mat], A.mat_shade_tex[mat],
                                          A.mat_shade_uv[mat], A.tex_data, A.tri_v[prim - ns],
                                          A.tri_uv[prim - ns], b1, b2, gx, gy, gz, sx, sy, sz, vx,
                                          vy, vz, back)
        # Anisotropic roughness: Mitsuba's frame, s along ∂p/∂u and t = n × s, kept on
        # the back of a two-sided BSDF (Mitsuba's twosided negates the local z only).
        aniso = B.aniso[mat] != 0
        if aniso:
            if shade == SHADE_BUMPMAP and prim >= ns:    # Mitsuba's bump frame's tangent
                fx, fy, fz = bump_tangent(A.tri_v[prim - ns], A.tri_uv[prim - ns], A.mat_shade_tex[mat],
                                          back, gx, gy, gz, sx, sy, sz, nx, ny, nz)
            else:
                fx, fy, fz = tangent(prim, ns, b1, b2, px, py, pz, A.sph_center, A.tri_v, A.tri_uv,
                                     A.tri_has_uv, gx, gy, gz, sx, sy, sz)
            if shade != 0:           # a normal map's frame: that tangent about n_p
                if shade != SHADE_BUMPMAP:
                    fx, fy, fz = perturbed_tangent(fx, fy, fz, nx, ny, nz)
                qx, qy, qz = ny * fz - nz * fy, nz * fx - nx * fz, nx * fy - ny * fx
            else:
                qx, qy, qz = sy * fz - sz * fy, sz * fx - sx * fz, sx * fy - sy * fx
        else:
            fx = fy = fz = qx = qy = qz = 0.0
        if back:
            gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
            if shade == 0:
                nx, ny, nz = sx, sy, sz
        terminator = shade != 0 and A.mat_shade_tex[mat, 6] != 0
        if not aniso:
            fx, fy, fz, qx, qy, qz = frame(nx, ny, nz)
        wix, wiy, wiz = to_local(fx, fy, fz, qx, qy, qz, nx, ny, nz, vx, vy, vz)
        if spectral:
            rho_r = spectrum_at(S.mat_spec[mat], w0)
            rho_g = spectrum_at(S.mat_spec[mat], w1)
            rho_b = spectrum_at(S.mat_spec[mat], w2)
        else:
            rho_r, rho_g, rho_b = diffuse_albedo(A, smat, prim, b1, b2)
        sp_r, sp_g, sp_b = _coat(A, B, smat, prim, b1, b2)
        eta_scale = eta_scale_at(S, mat, w0) if spectral else 1.0
        tinted = _tinted(A, B, smat)

        # Next-event estimation: one light sample, its MIS weight, and its shadow ray
        # queued with the contribution it adds if nothing blocks it.
        if not delta and L.n_lights > 0:
            lx, ly, lz, ldist = ls[_LS_WX, k], ls[_LS_WY, k], ls[_LS_WZ, k], ls[_LS_DIST, k]
            yx, yy, yz = ls[_LS_YX, k], ls[_LS_YY, k], ls[_LS_YZ, k]
            er, eg, eb, lpdf = ls[_LS_ER, k], ls[_LS_EG, k], ls[_LS_EB, k], ls[_LS_PDF, k]
            ldelta, li = ls[_LS_DELTA, k] != 0.0, int(ls[_LS_LIGHT, k])
            if spectral:                 # L and A carry unit emission: scale by the spectrum
                er *= spectrum_at(S.light_spec[li], w0)
                eg *= spectrum_at(S.light_spec[li], w1)
                eb *= spectrum_at(S.light_spec[li], w2)
            if shade != 0 and not same_side(nx, ny, nz, sx, sy, sz, lx, ly, lz):
                er = eg = eb = 0.0           # below the perturbed or the true horizon
            if er > 0.0 or eg > 0.0 or eb > 0.0:
                wox, woy, woz = to_local(fx, fy, fz, qx, qy, qz, nx, ny, nz, lx, ly, lz)
                bpdf = 0.0
                if blend:
                    fr, fg, fb, bpdf = _blend_eval_pdf(A, B, mat, np.int64(-1), prim, b1, b2,
                                                       eta_scale, wix, wiy, wiz, wox, woy, woz)
                else:
                    fr, fg, fb = bsdf_eval_at(B, mat, alpha, alpha_v, rho_r, rho_g, rho_b, sp_r, sp_g,
                                              sp_b, eta_scale, wix, wiy, wiz, wox, woy, woz)
                    if tinted:               # textured specular colours or conductor IOR
                        kr, kg, kb = _tint(A, B, smat, prim, b1, b2, rho_r, rho_g, rho_b, wix, wiy, wiz,
                                           wox, woy, woz)
                        fr, fg, fb = fr * kr, fg * kg, fb * kb
                if opac < 1.0:               # a mask scatters by its BSDF with probability opac
                    fr, fg, fb = fr * opac, fg * opac, fb * opac
                if terminator:
                    gt = shadow_terminator(nx, ny, nz, sx, sy, sz, lx, ly, lz)
                    fr, fg, fb = fr * gt, fg * gt, fb * gt
                if fr > 0.0 or fg > 0.0 or fb > 0.0:
                    counts[_C_SHADOW] += 1
                    side = 1.0 if gx * lx + gy * ly + gz * lz >= 0.0 else -1.0
                    sox, soy, soz, st0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
                    if math.isinf(ldist):
                        hx, hy, hz, st1 = lx, ly, lz, np.inf
                        hd = 1.0
                    else:
                        hx, hy, hz = yx - sox, yy - soy, yz - soz
                        hd = math.sqrt(hx * hx + hy * hy + hz * hz)
                        shrink = R.shrink_point if ldelta else R.shrink_area
                        st1 = hd * (1.0 - shrink)
                    if hd > 0.0:             # a light sample at the origin counts as blocked
                        w = 1.0
                        if not ldelta and mis:
                            if not blend:
                                bpdf = bsdf_pdf_at(B, mat, alpha, alpha_v, eta_scale, wix, wiy, wiz, wox,
                                                   woy, woz)
                            bpdf *= opac
                            if bias == _BIAS_MIS:   # debug: the classic swapped-argument bug
                                w = power_heuristic(bpdf, lpdf)
                            else:
                                w = power_heuristic(lpdf, bpdf)
                        sh = T.sh
                        sh[OX, queued], sh[OY, queued], sh[OZ, queued] = sox, soy, soz
                        sh[DX, queued], sh[DY, queued], sh[DZ, queued] = hx / hd, hy / hd, hz / hd
                        sh[TMIN, queued], sh[TMAX, queued] = st0, st1
                        T.sh_w[0, queued] = tr * w * fr * er
                        T.sh_w[1, queued] = tg * w * fg * eg
                        T.sh_w[2, queued] = tb * w * fb * eb
                        T.sh_i[queued] = c
                        queued += 1

        # BSDF sampling: the next direction.  A mask lets the ray pass straight on with
        # probability 1 − opacity (Mitsuba's null event: weight 1, a delta "bounce").
        u0 = u0s
        u1, u2 = _number(ls, k, h, dim, 4, sobol), _number(ls, k, h, dim, 5, sobol)
        if opac < 1.0 and u0 >= opac:
            ndx, ndy, ndz = dx, dy, dz
            pdf = 1.0 - opac
            sdelta = True
            seta = 1.0
        else:
            if opac < 1.0:
                u0 = u0 / opac
            if blend:                    # rescaled for the chosen leaf
                u0 = ub
            wox, woy, woz, wr, wg, wb, pdf, sdelta, seta = bsdf_sample_at(
                B, smat, alpha, alpha_v, rho_r, rho_g, rho_b, sp_r, sp_g, sp_b, eta_scale, wix, wiy, wiz,
                u0, u1, u2)
            if tinted and pdf > 0.0:     # textured specular colours or conductor IOR
                kr, kg, kb = _tint(A, B, smat, prim, b1, b2, rho_r, rho_g, rho_b, wix, wiy, wiz, wox, woy, woz)
                wr, wg, wb = wr * kr, wg * kg, wb * kb
            if blend and pdf > 0.0:
                # Mitsuba's blendbsdf.sample: the mixture's pdf, and the weight
                # (w_k f_k cos + the other leaves' weighted f cos) / that pdf.
                orr, org, orb, opdf = _blend_eval_pdf(A, B, mat, ck, prim, b1, b2, eta_scale,
                                                      wix, wiy, wiz, wox, woy, woz)
                mix = wk * pdf + opdf
                if mix > 0.0:
                    wr = (orr + wk * wr * pdf) / mix
                    wg = (org + wk * wg * pdf) / mix
                    wb = (orb + wk * wb * pdf) / mix
                else:
                    wr = wg = wb = 0.0
                pdf = mix
            pdf *= opac
            if pdf <= 0.0 or (wr <= 0.0 and wg <= 0.0 and wb <= 0.0):
                continue
            tr *= wr
            tg *= wg
            tb *= wb
            eta *= seta
            if eta_scale != 1.0 and not single:
                # Dispersion: the direction is the hero wavelength's; drop the others.
                tr *= 3.0
                tg = tb = 0.0
                single = True
            ndx, ndy, ndz = to_world(fx, fy, fz, qx, qy, qz, nx, ny, nz, wox, woy, woz)
            inv = 1.0 / math.sqrt(ndx * ndx + ndy * ndy + ndz * ndz)
            ndx, ndy, ndz = ndx * inv, ndy * inv, ndz * inv
            if shade != 0:
                if not same_side(nx, ny, nz, sx, sy, sz, ndx, ndy, ndz):
                    continue
                if terminator:
                    gt = shadow_terminator(nx, ny, nz, sx, sy, sz, ndx, ndy, ndz)
                    tr, tg, tb = tr * gt, tg * gt, tb * gt
        side = 1.0 if gx * ndx + gy * ndy + gz * ndz >= 0.0 else -1.0
        ox, oy, oz, t0 = leave(R, px, py, pz, side * gx, side * gy, side * gz)
        counts[_C_BOUNCE] += 1

        # Russian roulette (Mitsuba: after the depth increment, q = min(max(T)·η², 0.95)).
        depth += 1
        tmax_ = max(tr, tg, tb)
        if tmax_ <= 0.0:
            continue
        if depth >= rr_depth:
            q = min(tmax_ * eta * eta, 0.95)
            if _number(ls, k, h, dim, 6, sobol) >= q:
                counts[_C_RR] += 1
                continue
            if bias != _BIAS_RR:
                tr /= q
                tg /= q
                tb /= q

        # The path walks on: its next ray, rounded to the intersection precision, at the
        # front of the batch (position walking <= k, already read).
        j = walking
        W.col[j] = c
        ray = T.ray
        ray[OX, j], ray[OY, j], ray[OZ, j], ray[DX, j], ray[DY, j], ray[DZ, j] = round_ray(
            R, ox, oy, oz, ndx, ndy, ndz)
        ray[TMIN, j], ray[TMAX, j] = t0, np.inf
        W.thr[0, c], W.thr[1, c], W.thr[2, c] = tr, tg, tb
        W.f[_W_ETA, c] = eta
        W.f[_W_PDF, c] = pdf
        W.f[_W_PX, c], W.f[_W_PY, c], W.f[_W_PZ, c] = px, py, pz
        W.depth[c] = depth
        W.delta[c] = sdelta
        W.single[c] = single
        walking += 1
    if nl > 0:
        pl.diffuse_vertices(W.lane, W.lane_i, nl, mis, rr_depth, L.n_lights, R.strategy, R.eps,
                            R.shrink_point, R.shrink_area, R.sph_radius)
        walking, queued = _from_lanes(R, T, W, nl, walking, queued)
    return walking, queued


@njit(inline="always", cache=True)
def _to_lane(A: SceneArrays, W: Walks, j, k, c, mat, prim, b1, b2, gx, gy, gz, sx, sy, sz, vx, vy, vz,
             tr, tg, tb, eta, depth, h, dim, sobol):
    """Lane j of the table ``W.lane`` for the vertex of column c at batch position k, on a
    plain diffuse material (:mod:`impl.path_lanes`): what the lanes cannot load or hash
    themselves.  The normals face the viewer's side of a two-sided material; the BSDF
    sample's and roulette's numbers are those the scalar vertex draws."""
    D, ls = W.lane, W.ls
    if A.mat_twosided[mat] and gx * vx + gy * vy + gz * vz < 0.0:
        gx, gy, gz, sx, sy, sz = -gx, -gy, -gz, -sx, -sy, -sz
    rho_r, rho_g, rho_b = diffuse_albedo(A, mat, prim, b1, b2)
    D[pl.PX, j], D[pl.PY, j], D[pl.PZ, j] = ls[_LS_PX, k], ls[_LS_PY, k], ls[_LS_PZ, k]
    D[pl.GX, j], D[pl.GY, j], D[pl.GZ, j] = gx, gy, gz
    D[pl.NX, j], D[pl.NY, j], D[pl.NZ, j] = sx, sy, sz
    D[pl.VX, j], D[pl.VY, j], D[pl.VZ, j] = vx, vy, vz
    D[pl.RHO_R, j], D[pl.RHO_G, j], D[pl.RHO_B, j] = rho_r, rho_g, rho_b
    D[pl.THR_R, j], D[pl.THR_G, j], D[pl.THR_B, j] = tr, tg, tb
    D[pl.ETA, j] = eta
    D[pl.U1, j], D[pl.U2, j] = _number(ls, k, h, dim, 4, sobol), _number(ls, k, h, dim, 5, sobol)
    D[pl.URR, j] = _number(ls, k, h, dim, 6, sobol)
    for r in range(_LS_DELTA - _LS_WX + 1):       # the light sample, row for row
        D[pl.LX + r, j] = ls[_LS_WX + r, k]
    D[pl.ENX, j], D[pl.ENY, j], D[pl.ENZ, j] = ls[_LS_NX, k], ls[_LS_NY, k], ls[_LS_NZ, k]
    D[pl.AREA, j] = ls[_LS_AREA, k]
    W.lane_i[pl.COL, j] = c
    W.lane_i[pl.DEPTH, j] = depth


@njit(inline="always", cache=True)
def _from_lanes(R: RayConfig, T: Batch, W: Walks, nl, walking, queued):
    """The outcome of the ``nl`` lanes of ``W.lane``: counters, their shadow rays appended to
    the queue and their continuing rays to the walking paths, as the scalar vertex
    records them.  Returns (paths walking on, shadow rays queued)."""
    D, I, sh, ray = W.lane, W.lane_i, T.sh, T.ray
    for j in range(nl):
        c = I[pl.COL, j]
        counts = T.cnt[c]
        shadow = I[pl.SHADOW, j]
        if shadow != pl.SHADOW_NONE:
            counts[_C_SHADOW] += 1
        if shadow == pl.SHADOW_QUEUED:
            sh[OX, queued], sh[OY, queued], sh[OZ, queued] = D[pl.SOX, j], D[pl.SOY, j], D[pl.SOZ, j]
            sh[DX, queued], sh[DY, queued], sh[DZ, queued] = D[pl.SDX, j], D[pl.SDY, j], D[pl.SDZ, j]
            sh[TMIN, queued], sh[TMAX, queued] = D[pl.ST0, j], D[pl.ST1, j]
            T.sh_w[0, queued], T.sh_w[1, queued], T.sh_w[2, queued] = D[pl.SWR, j], D[pl.SWG, j], D[pl.SWB, j]
            T.sh_i[queued] = c
            queued += 1
        state = I[pl.STATE, j]
        if state == pl.ENDED:
            continue
        counts[_C_BOUNCE] += 1
        if state == pl.ROULETTE_ENDED:
            counts[_C_RR] += 1
        if state != pl.WALKS_ON:
            continue
        W.col[walking] = c
        ray[OX, walking], ray[OY, walking], ray[OZ, walking], ray[DX, walking], ray[DY, walking], \
            ray[DZ, walking] = round_ray(R, D[pl.OX, j], D[pl.OY, j], D[pl.OZ, j], D[pl.DX, j], D[pl.DY, j],
                                         D[pl.DZ, j])
        ray[TMIN, walking], ray[TMAX, walking] = D[pl.T0, j], np.inf
        W.thr[0, c], W.thr[1, c], W.thr[2, c] = D[pl.TOUT_R, j], D[pl.TOUT_G, j], D[pl.TOUT_B, j]
        W.f[_W_ETA, c] = D[pl.ETA, j]
        W.f[_W_PDF, c] = D[pl.PDF, j]
        W.f[_W_PX, c], W.f[_W_PY, c], W.f[_W_PZ, c] = D[pl.PX, j], D[pl.PY, j], D[pl.PZ, j]
        W.depth[c] = I[pl.DEPTH, j] + 1
        W.delta[c] = False
        walking += 1
    return walking, queued


@batch_kernel
def _unblocked(T: Batch, queued):
    """Add the contributions of the queued light samples whose shadow rays are clear."""
    for j in range(queued):
        if not T.blocked[j]:
            c = T.sh_i[j]
            T.L[0, c] += T.sh_w[0, j]
            T.L[1, c] += T.sh_w[1, j]
            T.L[2, c] += T.sh_w[2, j]


@batch_kernel
def _to_srgb(S: SpectralArrays, T: Batch, W: Walks):
    """Each column's three wavelengths' radiance as linear sRGB (spectral mode)."""
    for c in range(T.n):
        T.L[0, c], T.L[1, c], T.L[2, c] = to_linear_srgb(S, T.L[0, c], T.L[1, c], T.L[2, c], W.f[_W_L0, c],
                                                         W.f[_W_L1, c], W.f[_W_L2, c])


# Inlined into the task loop: as a function of its own it would be one more module that
# numba optimises and generates machine code for with the whole tracer linked in.
@njit(inline="always", cache=True)
def _tile(cam, A: SceneArrays, L: LightArrays, B: MaterialArrays, R: RayConfig, S: SpectralArrays,
          P: PathConfig, film: Film, tile, spp, seed):
    """One tile (:mod:`impl.tracer`): per sample index, the eye rays and their hits, then
    the paths as a wavefront: one vertex of every walking path (:func:`_vertices`), the
    shadow rays of its light samples as one batch, the continuing rays' closest hits as
    another, until every path has ended."""
    T = new_batch(film, R, tile, seed)
    W = _new_walks(T.n)
    for s in range(spp):
        eye_batch(cam, R, T, s, spp, seed, film.packets, film.sampler)
        _start(P, seed, s, T, W)
        m = T.n
        while m > 0:
            if P.sobol:
                _sobol_numbers(W.col, W.depth, W.seq, W.ls, s, m)
            _light_samples(A, L, B, R, P, T, W, m)
            m, queued = _vertices(A, L, B, R, S, P, T, W, m)
            if queued > 0:
                occluded_batch(R, T.sh, queued, T.blocked, T.q, T.cull)
                _unblocked(T, queued)
            if m > 0:
                closest_batch(R, T.ray, m, T.t, T.prim, T.b, T.q, T.qt, T.qp, T.cull)
        if P.spectral:
            _to_srgb(S, T, W)
        accumulate(T, s)
    store(T, film, spp)


@njit(nogil=True, cache=True)
def _render_kernel(cam, A: SceneArrays, L: LightArrays, B: MaterialArrays, R: RayConfig,
                   S: SpectralArrays, P: PathConfig, film: Film, spp, seed, queue):
    """The film's tiles, taken from ``queue`` (:func:`impl.kernel.run_tasks`)."""
    n = film.order.shape[0]
    c = take_task(queue)
    while c < n:
        _tile(cam, A, L, B, R, S, P, film, film.order[c], spp, seed)
        c = take_task(queue)


# ------------------------------------------------------------- orchestration ---

@njit(cache=True)
def _lane_materials(A: SceneArrays, B: MaterialArrays):
    """(M,) bool: the materials whose vertices :mod:`impl.path_lanes` computes: ``diffuse``
    (textured or not) without a mask, a normal or bump map or a parameter texture."""
    out = np.zeros(B.kind.shape[0], np.bool_)
    for mat in range(B.kind.shape[0]):
        out[mat] = (B.kind[mat] == MAT_DIFFUSE and B.opacity[mat] >= 1.0 and A.mat_shade[mat] == 0
                    and B.aniso[mat] == 0 and not _tinted(A, B, mat))
    return out


def _check(params: dict) -> None:
    check_spp(params["spp"], "path")
    if params["max_depth"] < -1 or params["max_depth"] == 0:
        raise ParamError(f"path: max_depth must be -1 (unbounded) or >= 1 (1 = emitters seen "
                         f"directly), got {params['max_depth']}")
    if params["rr_depth"] < 1:
        raise ParamError(f"path: rr_depth must be >= 1, got {params['rr_depth']}")


def render(scene: Scene, params: dict, *, seed: int = 0, debug_bias: str = "none") -> RenderResult:
    """Render ``scene`` with the path tracer; ``params`` as from ``ALGORITHM.parse_params``.

    ``debug_bias`` (a keyword for tests, not a parameter of the algorithm's table)
    renders one of the deliberately biased variants of :data:`DEBUG_BIAS`, which
    exist only to show that the Z-test against Mitsuba rejects them."""
    if debug_bias not in DEBUG_BIAS:
        raise ParamError(f"path: debug_bias must be one of {', '.join(DEBUG_BIAS)}, got {debug_bias!r}")
    t0 = time.perf_counter()
    _check(params)
    # A blendbsdf's components get rows of their own in A and B (kept alive by the memo).
    def expanded():              # None without a blendbsdf: the memo must not hold the scene itself
        e = expand_components(with_specular_textures(scene), algorithm="path")
        return None if e is scene else e

    full = scene_memo(scene, "path.expanded", expanded) or scene
    B = scene_memo(scene, "path.bsdf", lambda: bsdf_arrays(full, algorithm="path"))
    A, L = scene_memo(scene, "path.lights", lambda: flatten_with_lights(full))
    cam = camera_params(scene.camera, lens=True)
    H, W = scene.camera.film.height, scene.camera.film.width
    spp = params["spp"]
    R = ray_config_cached(scene, A, params, algorithm="path")
    spectral = bool(params["spectral"])
    if spectral:                 # RGB-only parts of the scene model
        for present, what in (
                (scene.environment is not None,
                 "the constant environment emitter (its radiance is RGB)"),
                (any(light.kind == "projector" for light in scene.lights),
                 "the projector emitter (its irradiance image is RGB)"),
                (any(light.kind == "spot" and light.texture is not None for light in scene.lights),
                 "a spot's texture (an RGB image)"),
                ("textured specular reflectance" in scene_features(scene),
                 "a textured specular_reflectance (an RGB texture)"),
                ("textured specular transmittance" in scene_features(scene),
                 "a textured specular_transmittance (an RGB texture)"),
                ("textured conductor eta/k" in scene_features(scene),
                 "a conductor's textured eta or k (an RGB texture)"),
                (any(m.kind == "blendbsdf" for m in full.materials),
                 "the blendbsdf BSDF (its components' reflectances are RGB here)")):
            if present:
                raise UnsupportedError(f"path: spectral=true does not model {what}; "
                                       "render it with spectral=false")
    if spectral:
        S = spectral_arrays(full, A, L)
        # Unit emission in A and L: the kernel scales light samples by S.light_spec.
        L = L._replace(shape_emit=(L.shape_emit > 0.0).any(axis=1)[:, None] * np.ones((1, 3)))
        A = A._replace(light_rad=np.ones_like(A.light_rad))
    else:
        S = rgb_arrays_placeholder()
    lanes = _lane_materials(A, B) & (not spectral) & (debug_bias == "none") & bool(params["lanes"])
    P = PathConfig(spectral, int(params["max_depth"]), int(params["rr_depth"]), bool(params["mis"]),
                   DEBUG_BIAS.index(debug_bias), params.get("sampler") == "sobol", lanes)
    film = new_film(W, H, len(COUNTERS), bool(params.get("packets", False)), sampler_code(params))
    t1 = time.perf_counter()
    run_tasks(_render_kernel, cam, A, L, B, R, S, P, film, spp, seed)
    t2 = time.perf_counter()
    counters = film_counters(film, COUNTERS)
    counters["mean_path_length"] = counters["segments"] / max(1, counters["paths"])
    return film_result(film, spp, counters, t0, t1, t2)


ALGORITHM = Algorithm(
    name="path",
    summary="Unbiased path tracing: BSDF sampling, next-event estimation with MIS (power "
            "heuristic), Russian roulette; Mitsuba's max_depth",
    section="thesis 3.2.1-3.2.2; Kajiya 1986, Veach & Guibas 1995",
    transport="full",
    params=(
        Param("spp", int, 16, "pixel samples: 1 = pixel centre, k² = k×k jittered strata (box filter)"),
        SAMPLER_PARAM,
        Param("max_depth", int, -1, "Mitsuba's max_depth: 1 = emitters only, 2 = direct light, "
              "-1 = unbounded"),
        Param("rr_depth", int, 5, "Russian roulette from this path depth on (Mitsuba's rule)"),
        Param("mis", bool, True, "multiple importance sampling (power heuristic) of light and "
              "BSDF samples; false = plain next-event estimation"),
        Param("spectral", bool, False, "spectral rendering: three hero-rotated wavelengths per "
              "path, scene spectra, CIE 1931 to linear sRGB (impl.spectral)"),
        Param("lanes", bool, True, "vertices on plain diffuse surfaces a path per vector lane "
              "(impl.path_lanes); false = the scalar vertex, the same image"),
        *RAY_PARAMS,
    ),
    render=render,
    models=frozenset({"envmap", "plastic", "roughplastic", "plastic texture", "normalmap", "bumpmap",
                      "projector", "thindielectric", "blendbsdf", "mask", "textured roughness",
                      "anisotropic roughness", "spot texture", "textured specular reflectance",
                      "textured specular transmittance", "textured conductor eta/k"}),
    kernel_variants=({"packets": True},),
)
