"""Mitsuba 3's ``projector`` emitter: a delta-position light projecting an irradiance image.

What it computes
----------------
The light a projector at p_l sends to a point x, as Mitsuba 3.9's
``src/emitters/projector.cpp`` (``sample_direction``) returns it: with
x_l = to_world⁻¹ (x − p_l) the point in the projector's frame (+z forward, its
to_world's 3×3 inverted, so scale and shear count),

* uv = (½ − ½ cot(fov_x/2) x_l.x / x_l.z, ½ − ½ aspect cot(fov_x/2) x_l.y / x_l.z),
  the camera-to-sample projection of Mitsuba's perspective sensor with the
  image's aspect (width / height; 1 for a constant irradiance) and the
  horizontal field of view of ``parse_fov``;
* zero unless x_l.z > 0 and uv ∈ [0, 1]²;
* otherwise π · scale · E(uv) / (x_l.z² · (−n · d)), E the ``irradiance``
  texture (or constant), n = to_world · e_z (not normalised) and d the unit
  direction from x to the light: the value a point light's I / d² takes.  With
  an orthonormal to_world this is π · scale · E / (d² cos³ θ): the irradiance
  π · scale · E on the plane z = 1 in front of the projector.

The image is looked up by :func:`impl.textures.bitmap` after its to_uv map
(bilinear or nearest, Mitsuba's wrap modes at the edges of [0, 1]²).

Per-light-sample helper (``inline="always"``, scalars and a few arrays).
"""

from __future__ import annotations

from numba import njit

from .textures import bitmap

__all__ = ["projector_weight"]


@njit(inline="always", cache=True)
def projector_weight(local, li, lpx, lpy, lpz, ldx, ldy, ldz, proj, tex, uvm, data, px, py, pz, lx, ly,
                     lz):
    """RGB factor ``π scale E(uv) d² / (x_l.z² (−n · d))`` / (π scale E_const) of
    projector ``li`` (its world → local 3×3 ``local[li]``, position ``lp``, unit axis
    ``ld`` = n / |n|, constants ``proj`` = (cot(fov_x/2), aspect, |n|), bitmap record
    ``tex`` (offset, width, height, wrap, filter; width 0: a constant) with to_uv
    ``uvm`` into ``data``) at point p seen along the unit direction l from p to the
    light.  Times π·scale·E_const (``light_rad``) and 1 / d² it is Mitsuba's sample
    weight.  (0, 0, 0) outside the image."""
    qx, qy, qz = px - lpx, py - lpy, pz - lpz
    xl = local[li, 0, 0] * qx + local[li, 0, 1] * qy + local[li, 0, 2] * qz
    yl = local[li, 1, 0] * qx + local[li, 1, 1] * qy + local[li, 1, 2] * qz
    zl = local[li, 2, 0] * qx + local[li, 2, 1] * qy + local[li, 2, 2] * qz
    r = g = b = 0.0
    cos_n = -(lx * ldx + ly * ldy + lz * ldz) * proj[2]       # -n·d
    if zl > 0.0 and cos_n > 0.0:
        cot, aspect = proj[0], proj[1]
        u = 0.5 - 0.5 * cot * xl / zl
        v = 0.5 - 0.5 * aspect * cot * yl / zl
        if u >= 0.0 and u <= 1.0 and v >= 0.0 and v <= 1.0:
            s = (qx * qx + qy * qy + qz * qz) / (zl * zl * cos_n)
            r = g = b = s
            if tex[1] > 0:
                uu = uvm[0, 0] * u + uvm[0, 1] * v + uvm[0, 2]
                vv = uvm[1, 0] * u + uvm[1, 1] * v + uvm[1, 2]
                er, eg, eb = bitmap(data, tex[0], tex[1], tex[2], tex[3], tex[4], uu, vv)
                r, g, b = s * er, s * eg, s * eb
    return r, g, b
