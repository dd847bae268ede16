"""Eye rays of the sensors, with Mitsuba's conventions: the pinhole camera
(thesis 1.3.3: "a ray from the centre of projection through the centre of each
pixel"), the thin lens of depth of field (thesis 2.5.5; R. L. Cook, T. Porter,
L. Carpenter, "Distributed ray tracing", SIGGRAPH 1984; Mitsuba ``thinlens``)
and the orthographic camera (Mitsuba ``orthographic``).

Film coordinates (u, v) ∈ [0, 1]² run right and down; the camera frame has +z
forward, +y up and +x to the *left*.

* ``perspective``: the camera-space direction is
  ``((1 − 2u)·tx, (1 − 2v)·tx / aspect, 1)`` with tx = tan(fov_x / 2), from the
  camera origin; as in Mitsuba the ray's valid range starts at the near clip
  plane and ends at the far one: t ∈ [near / d_z, far / d_z].
* ``thinlens``: the pinhole direction's point at depth ``focus_distance``,
  ``f = focus_distance · ((1 − 2u)·tx, (1 − 2v)·tx / aspect, 1)``, is in focus;
  the ray starts at a point ``a`` of the lens disk of radius
  ``aperture_radius`` (camera plane z = 0, Shirley–Chiu concentric map of two
  uniforms) and goes towards f: ``d = normalise(f − a)``, t ∈ [near/d_z,
  far/d_z] (Mitsuba's ``thinlens::sample_ray``).
* ``orthographic``: the ray starts at camera-space
  ``((1 − 2u), (1 − 2v)/aspect, near)`` and runs along +z (both through
  ``to_world``, so its scale sets the view size), t ∈ [0, far − near]
  (Mitsuba's ``orthographic::sample_ray``).
"""

import math

import numpy as np
from numba import njit

from core.scene import Camera
from core.errors import UnsupportedError

from .intersect import like

__all__ = ["camera_params", "eye_ray", "pinhole_rays", "eye_ray_lens", "concentric_disk", "SENSOR_CODES",
           "SENSOR_PERSPECTIVE", "SENSOR_THINLENS", "SENSOR_ORTHOGRAPHIC"]

SENSOR_PERSPECTIVE, SENSOR_THINLENS, SENSOR_ORTHOGRAPHIC = 0, 1, 2
SENSOR_CODES = {"perspective": SENSOR_PERSPECTIVE, "thinlens": SENSOR_THINLENS,
                "orthographic": SENSOR_ORTHOGRAPHIC}


def camera_params(camera: Camera, *, lens: bool = False) -> np.ndarray:
    """Pack a camera into the float64 vector that :func:`eye_ray` reads.

    Layout: 0–11 the to_world columns (x, y, z axes, origin), 12 tan(fov_x/2),
    13 aspect, 14 width, 15 height, 16 near_clip, 17 far_clip, 18 sensor code,
    19 aperture_radius, 20 focus_distance.

    Raises
    ------
    NotImplementedError
        A ``thinlens`` camera when the caller traces pinhole rays only
        (``lens=False``: it calls :func:`eye_ray`, which has no lens samples).
    """
    if camera.kind not in SENSOR_CODES:
        raise UnsupportedError(f"camera_params: unknown sensor '{camera.kind}' "
                                  f"(known: {', '.join(SENSOR_CODES)})")
    if camera.kind == "thinlens" and not lens:
        raise UnsupportedError(
            "camera_params: a 'thinlens' sensor (depth of field) is modelled only by the "
            "'distributed' ray tracer and the 'path' tracer; use a 'perspective' sensor with "
            "this algorithm")
    m = camera.to_world
    f = camera.film
    tx = camera.tan_half_fov_x if camera.kind != "orthographic" else 1.0
    return np.array([*m[:3, 0], *m[:3, 1], *m[:3, 2], *m[:3, 3],
                     tx, f.aspect, f.width, f.height,
                     camera.near_clip, camera.far_clip, SENSOR_CODES[camera.kind],
                     camera.aperture_radius, camera.focus_distance], dtype=np.float64)


@njit(inline="always", cache=True)
def eye_ray(cam, px, py):
    """World-space eye ray through film position (px, py) in pixels (pinhole or orthographic).

    Returns ``(ox, oy, oz, dx, dy, dz, tmin, tmax, dz_camera)``.
    """
    u = px * (1.0 / cam[14])
    v = py * (1.0 / cam[15])
    if cam[18] == SENSOR_ORTHOGRAPHIC:
        x = 1.0 - 2.0 * u
        y = (1.0 - 2.0 * v) / cam[13]
        z = cam[16]
        ox = cam[0] * x + cam[3] * y + cam[6] * z + cam[9]
        oy = cam[1] * x + cam[4] * y + cam[7] * z + cam[10]
        oz = cam[2] * x + cam[5] * y + cam[8] * z + cam[11]
        inv = 1.0 / math.sqrt(cam[6] * cam[6] + cam[7] * cam[7] + cam[8] * cam[8])
        return ox, oy, oz, cam[6] * inv, cam[7] * inv, cam[8] * inv, 0.0, cam[17] - cam[16], 1.0
    return _pinhole(u, v, cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[7], cam[8],
                    cam[9], cam[10], cam[11], cam[12], cam[13], cam[16], cam[17])


@njit(inline="always", cache=True)
def _pinhole(u, v, x0, x1, x2, y0, y1, y2, z0, z1, z2, px, py, pz, tx, aspect, near, far):
    """The perspective eye ray at film coordinates (u, v) of the camera whose to_world
    columns are x, y, z and origin p, tan(fov_x/2) ``tx`` and clip range (near, far):
    :func:`eye_ray`'s result, from scalars (so a loop over rays can hold the camera
    in registers).  One square root and one division per ray: the film's vertical scale
    tan(fov_x/2)/aspect is the same for every ray (a loop hoists it), and the clip
    distances along the unit direction are near·r and far·r, r = |(c_x, c_y, 1)| = 1/c_z."""
    cx = (1.0 - 2.0 * u) * tx
    cy = (1.0 - 2.0 * v) * (tx / aspect)
    r = math.sqrt(cx * cx + cy * cy + 1.0)
    inv = 1.0 / r
    cx *= inv
    cy *= inv
    cz = inv
    dx = x0 * cx + y0 * cy + z0 * cz
    dy = x1 * cx + y1 * cy + z1 * cz
    dz = x2 * cx + y2 * cy + z2 * cz
    return px, py, pz, dx, dy, dz, near * r, far * r, cz


@njit(cache=True, error_model="numpy", _nrt=False)
def pinhole_rays(cam, g, fx, fy, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """:func:`eye_ray` of a perspective camera through film positions (fx[i], fy[i]) (pixels)
    for every i, the origin and direction rounded to the precision of ``g`` (a float32
    or float64 array) and stored as float64, one output array per component.

    The same arithmetic as :func:`eye_ray`, ray for ray (hence the same bits), with the
    camera read into registers before the loop and every array a separate argument,
    so the loop has no branch and no possible store-to-camera dependence: LLVM
    vectorises it over the rays, divisions and square roots included.
    """
    x0, x1, x2, y0, y1, y2 = cam[0], cam[1], cam[2], cam[3], cam[4], cam[5]
    z0, z1, z2, px, py, pz = cam[6], cam[7], cam[8], cam[9], cam[10], cam[11]
    tx, aspect, near, far = cam[12], cam[13], cam[16], cam[17]
    iw, ih = 1.0 / cam[14], 1.0 / cam[15]
    for i in range(fx.shape[0]):
        a, b, c, d, e, f, t0, t1, _ = _pinhole(fx[i] * iw, fy[i] * ih, x0, x1, x2, y0, y1, y2, z0, z1,
                                               z2, px, py, pz, tx, aspect, near, far)
        ox[i], oy[i], oz[i] = float(like(g, a)), float(like(g, b)), float(like(g, c))
        dx[i], dy[i], dz[i] = float(like(g, d)), float(like(g, e)), float(like(g, f))
        tmin[i], tmax[i] = t0, t1


@njit(inline="always", cache=True)
def concentric_disk(u1, u2):
    """Shirley–Chiu concentric map of [0, 1)² onto the unit disk (uniform by area)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r = a
        phi = (math.pi / 4.0) * (b / a)
    else:
        r = b
        phi = math.pi / 2.0 - (math.pi / 4.0) * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


@njit(inline="always", cache=True)
def eye_ray_lens(cam, px, py, u1, u2):
    """:func:`eye_ray`, through the lens point of (u1, u2) for a ``thinlens`` sensor."""
    if cam[18] != SENSOR_THINLENS:
        return eye_ray(cam, px, py)
    u = px / cam[14]
    v = py / cam[15]
    fd = cam[20]
    fx = (1.0 - 2.0 * u) * cam[12] * fd
    fy = (1.0 - 2.0 * v) * cam[12] / cam[13] * fd
    ax, ay = concentric_disk(u1, u2)
    ax *= cam[19]
    ay *= cam[19]
    cx, cy, cz = fx - ax, fy - ay, fd
    inv = 1.0 / math.sqrt(cx * cx + cy * cy + cz * cz)
    cx *= inv
    cy *= inv
    cz *= inv
    ox = cam[0] * ax + cam[3] * ay + cam[9]
    oy = cam[1] * ax + cam[4] * ay + cam[10]
    oz = cam[2] * ax + cam[5] * ay + cam[11]
    dx = cam[0] * cx + cam[3] * cy + cam[6] * cz
    dy = cam[1] * cx + cam[4] * cy + cam[7] * cz
    dz = cam[2] * cx + cam[5] * cy + cam[8] * cz
    return ox, oy, oz, dx, dy, dz, cam[16] / cz, cam[17] / cz, cz
