"""A path vertex on a diffuse surface, one path per vector lane.

At a vertex on a plain ``diffuse`` BSDF (opaque, no normal or bump map, RGB) the path
tracer's step (:func:`impl.path._vertices`, thesis 3.2.2) is the same arithmetic for
every path: the shading frame about the normal, the light sample's Lambertian
``f = ρ/π · cos θ`` and its power-heuristic weight against the cosine density, the
shadow ray, a cosine-weighted direction (:func:`impl.bsdf.sample_cosine_hemisphere`,
branch-free), the ray that leaves the surface and Russian roulette.  Written as one loop
over the paths with selects for the scalar code's branches and no library calls, LLVM
compiles it to packed instructions, several paths per instruction, where the scalar
vertex keeps one path in flight through a long branchy body.

The operations are those of the scalar code in the same order, so a lane gives the same
bits as :func:`impl.path._vertices` gives the same path (tests: the images with and
without lanes).  What the lanes leave to the caller: the hit's normals and reflectance
(indexed loads), the emission seen at the vertex, the random numbers (hashes), the
shadow-ray queue and the compaction of the walking paths.

Rows of the lane table ``D`` (a lane's column is one path).  In:

* ``P``, ``G``, ``N``, ``V``: hit point, geometric and shading normal (facing the
  viewer's side), direction to the viewer;
* ``RHO``, ``THR``, ``ETA``: reflectance, throughput, product of the IOR ratios;
* ``U1``, ``U2``, ``URR``: the BSDF sample's two numbers, the roulette number;
* ``L``, ``LDIST``, ``Y``, ``E``, ``LPDF``, ``LDELTA``: the light sample of
  :func:`impl.light_sampling.sample_light` (direction, distance, point, radiance,
  pdf, delta flag); where ``AREA`` > 0, only its point ``Y`` on a mesh emitter of
  that area, the emitter's front normal ``EN`` and radiance ``E``, the lane
  completing it (:func:`impl.light_sampling.emitter_sample`).

Out: ``SO``, ``SD``, ``ST0``, ``ST1``, ``SW``, the shadow ray and its contribution
if unblocked; ``O``, ``D``, ``T0``, ``TOUT``, ``PDF``, the continuing ray, the
throughput after roulette and the BSDF sample's pdf.  Integer rows ``I``: below.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .bsdf import (cosine_hemisphere_pdf, diffuse_eval, diffuse_pdf, frame, sample_cosine_hemisphere, to_local,
                   to_world)
from .light_sampling import emitter_sample, power_heuristic
from .kernel import batch_kernel
from .rays import leave_towards

__all__ = ["ROWS", "INT_ROWS", "new_lanes", "diffuse_vertices", "SHADOW_NONE", "SHADOW_COUNTED",
           "SHADOW_QUEUED", "ENDED", "BOUNCED_ENDED", "ROULETTE_ENDED", "WALKS_ON"]

(PX, PY, PZ, GX, GY, GZ, NX, NY, NZ, VX, VY, VZ, RHO_R, RHO_G, RHO_B, THR_R, THR_G, THR_B, ETA,
 U1, U2, URR, LX, LY, LZ, LDIST, YX, YY, YZ, ER, EG, EB, LPDF, LDELTA, ENX, ENY, ENZ, AREA,
 SOX, SOY, SOZ, SDX, SDY, SDZ, ST0, ST1, SWR, SWG, SWB,
 OX, OY, OZ, DX, DY, DZ, T0, TOUT_R, TOUT_G, TOUT_B, PDF) = range(60)
ROWS = 60
#: Integer rows of the lane table ``I``: the path's film column and depth (inputs), the
#: states of its light and BSDF samples (outputs).
COL, DEPTH, SHADOW, STATE = range(4)
INT_ROWS = 4

#: A lane's light sample: no shadow ray; a shadow ray counted but not traced (its
#: target at its origin: blocked); a shadow ray queued.
SHADOW_NONE, SHADOW_COUNTED, SHADOW_QUEUED = 0, 1, 2
#: A lane's BSDF sample: the path ended without a bounce (zero pdf or weight); bounced
#: and ended (zero throughput); bounced and ended by roulette; bounced and walks on.
ENDED, BOUNCED_ENDED, ROULETTE_ENDED, WALKS_ON = 0, 1, 2, 3


@njit(cache=True)
def new_lanes(n):
    """A lane table for ``n`` paths: float rows ``D`` and integer rows ``I`` (above)."""
    return np.empty((ROWS, n)), np.empty((INT_ROWS, n), np.int64)


@njit(inline="always", cache=True)
def diffuse_vertices(D, I, n, mis, rr_depth, n_lights, strategy, eps, shrink_point, shrink_area, g):
    """The first ``n`` lanes of the table ``D``, ``I`` (rows above) at once: :func:`_lanes`
    on its rows.  ``g`` is an array of the intersection precision (origins are offset in
    it, :func:`impl.rays.leave`); ``n_lights`` the number of lights the light samples
    choose from.  The random numbers come in rows: hashing them here, a
    64-bit multiply chain per number, measured slower than in the scalar loop that fills
    the table, where they overlap that loop's loads."""
    _lanes(mis, rr_depth, n_lights, strategy, eps, shrink_point, shrink_area, g,
           D[PX, :n], D[PY, :n], D[PZ, :n], D[GX, :n], D[GY, :n], D[GZ, :n], D[NX, :n], D[NY, :n],
           D[NZ, :n], D[VX, :n], D[VY, :n], D[VZ, :n], D[RHO_R, :n], D[RHO_G, :n], D[RHO_B, :n],
           D[THR_R, :n], D[THR_G, :n], D[THR_B, :n], D[ETA, :n], D[U1, :n], D[U2, :n], D[URR, :n],
           D[LX, :n], D[LY, :n], D[LZ, :n], D[LDIST, :n], D[YX, :n], D[YY, :n], D[YZ, :n], D[ER, :n],
           D[EG, :n], D[EB, :n], D[LPDF, :n], D[LDELTA, :n], D[ENX, :n], D[ENY, :n], D[ENZ, :n], D[AREA, :n],
           I[DEPTH, :n],
           D[SOX, :n], D[SOY, :n], D[SOZ, :n], D[SDX, :n], D[SDY, :n], D[SDZ, :n], D[ST0, :n],
           D[ST1, :n], D[SWR, :n], D[SWG, :n], D[SWB, :n], I[SHADOW, :n],
           D[OX, :n], D[OY, :n], D[OZ, :n], D[DX, :n], D[DY, :n], D[DZ, :n], D[T0, :n],
           D[TOUT_R, :n], D[TOUT_G, :n], D[TOUT_B, :n], D[PDF, :n], I[STATE, :n])


@batch_kernel(error_model="numpy", disjoint=True)
def _lanes(mis, rr_depth, n_lights, strategy, eps, shrink_point, shrink_area, g,
           px, py, pz, gx, gy, gz, nx, ny, nz, vx, vy, vz, rho_r, rho_g, rho_b, thr_r, thr_g, thr_b, eta_,
           u1_, u2_, urr_, lx_, ly_, lz_, ldist_, yx_, yy_, yz_, er_, eg_, eb_, lpdf_, ldelta_, enx, eny, enz,
           area_, depth,
           sox, soy, soz, sdx, sdy, sdz, st0, st1, swr, swg, swb, shadow,
           ox, oy, oz, dx, dy, dz, t0, tout_r, tout_g, tout_b, pdf_, state):
    """One diffuse vertex per lane i, branch-free (see the module docstring): the scalar
    vertex's light sample, shadow ray, BSDF sample and roulette, its branches as selects."""
    for i in range(px.shape[0]):
        p_x, p_y, p_z = px[i], py[i], pz[i]
        g_x, g_y, g_z = gx[i], gy[i], gz[i]
        n_x, n_y, n_z = nx[i], ny[i], nz[i]
        r_r, r_g, r_b = rho_r[i], rho_g[i], rho_b[i]
        t_r, t_g, t_b = thr_r[i], thr_g[i], thr_b[i]
        eta = eta_[i]
        # The shading frame (Duff et al. 2017) and wi in it.
        fx, fy, fz, qx, qy, qz = frame(n_x, n_y, n_z)
        _, _, wiz = to_local(fx, fy, fz, qx, qy, qz, n_x, n_y, n_z, vx[i], vy[i], vz[i])

        # Next-event estimation: f·cos of the light sample, its shadow ray and weight.
        y_x, y_y, y_z, area = yx_[i], yy_[i], yz_[i], area_[i]
        e_r, e_g, e_b = er_[i], eg_[i], eb_[i]
        mx, my, mz, md, mr, mg, mb, mpdf = emitter_sample(p_x, p_y, p_z, y_x, y_y, y_z, enx[i], eny[i], enz[i],
                                                          area, n_lights, e_r, e_g, e_b)
        mesh = area > 0.0                # a point on a mesh emitter: the sample completed here
        l_x, l_y, l_z, ldist = (mx if mesh else lx_[i]), (my if mesh else ly_[i]), (mz if mesh else lz_[i]), \
            (md if mesh else ldist_[i])
        e_r, e_g, e_b = (mr if mesh else e_r), (mg if mesh else e_g), (mb if mesh else e_b)
        lpdf = mpdf if mesh else lpdf_[i]
        ldelta = ldelta_[i] != 0.0
        _, _, woz = to_local(fx, fy, fz, qx, qy, qz, n_x, n_y, n_z, l_x, l_y, l_z)
        fr, fg, fb = diffuse_eval(r_r, r_g, r_b, wiz, woz)
        lit = ((e_r > 0.0) | (e_g > 0.0) | (e_b > 0.0)) & ((fr > 0.0) | (fg > 0.0) | (fb > 0.0))
        s_x, s_y, s_z, s_t0 = leave_towards(strategy, g, eps, p_x, p_y, p_z, g_x, g_y, g_z, l_x, l_y, l_z)
        far = math.isinf(ldist)
        hx = l_x if far else y_x - s_x
        hy = l_y if far else y_y - s_y
        hz = l_z if far else y_z - s_z
        hd = 1.0 if far else math.sqrt(hx * hx + hy * hy + hz * hz)
        shrink = shrink_point if ldelta else shrink_area
        w = 1.0 if ldelta | (not mis) else power_heuristic(lpdf, diffuse_pdf(wiz, woz))
        shadow[i] = (SHADOW_QUEUED if hd > 0.0 else SHADOW_COUNTED) if lit else SHADOW_NONE
        sox[i], soy[i], soz[i] = s_x, s_y, s_z
        sdx[i], sdy[i], sdz[i] = hx / hd, hy / hd, hz / hd
        st0[i] = s_t0
        st1[i] = math.inf if far else hd * (1.0 - shrink)
        swr[i] = t_r * w * fr * e_r
        swg[i] = t_g * w * fg * e_g
        swb[i] = t_b * w * fb * e_b

        # The BSDF sample: a cosine-weighted direction, weight ρ, pdf cos θ / π.
        x, y, z = sample_cosine_hemisphere(u1_[i], u2_[i])
        pdf = cosine_hemisphere_pdf(z)
        ok = (wiz > 0.0) & (pdf > 0.0) & ((r_r > 0.0) | (r_g > 0.0) | (r_b > 0.0))
        t_r, t_g, t_b = t_r * r_r, t_g * r_g, t_b * r_b
        d_x, d_y, d_z = to_world(fx, fy, fz, qx, qy, qz, n_x, n_y, n_z, x, y, z)
        inv = 1.0 / math.sqrt(d_x * d_x + d_y * d_y + d_z * d_z)
        d_x, d_y, d_z = d_x * inv, d_y * inv, d_z * inv
        ox[i], oy[i], oz[i], t0[i] = leave_towards(strategy, g, eps, p_x, p_y, p_z, g_x, g_y, g_z, d_x, d_y, d_z)
        dx[i], dy[i], dz[i] = d_x, d_y, d_z

        # Russian roulette (Mitsuba: after the depth increment, q = min(max(T)·η², 0.95)).
        tmax = max(t_r, t_g, t_b)
        roulette = depth[i] + 1 >= rr_depth
        q = min(tmax * eta * eta, 0.95)
        killed = roulette & (urr_[i] >= q)
        tout_r[i] = t_r / q if roulette else t_r
        tout_g[i] = t_g / q if roulette else t_g
        tout_b[i] = t_b / q if roulette else t_b
        pdf_[i] = pdf
        state[i] = ((ROULETTE_ENDED if killed else WALKS_ON) if not (tmax <= 0.0) else BOUNCED_ENDED) \
            if ok else ENDED
