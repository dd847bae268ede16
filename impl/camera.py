"""Eye rays of the pinhole camera (thesis 1.3.3: "a ray from the centre of
projection through the centre of each pixel"), with Mitsuba's conventions.

Film coordinates (u, v) ∈ [0, 1]² run right and down; the camera frame has +z
forward, +y up and +x to the *left*, so the camera-space direction is
``((1 − 2u)·tx, (1 − 2v)·tx / aspect, 1)`` with tx = tan(fov_x / 2).  As in
Mitsuba's ``perspective`` sensor, the ray's valid range starts at the near
clip plane and ends at the far one: t ∈ [near / d_z, far / d_z].
"""

import math

import numpy as np
from numba import njit

from gibench.scene import Camera

__all__ = ["camera_params", "eye_ray"]


def camera_params(camera: Camera) -> np.ndarray:
    """Pack a camera into the float64 vector that :func:`eye_ray` reads."""
    m = camera.to_world
    f = camera.film
    return np.array([*m[:3, 0], *m[:3, 1], *m[:3, 2], *m[:3, 3],
                     camera.tan_half_fov_x, f.aspect, f.width, f.height,
                     camera.near_clip, camera.far_clip], dtype=np.float64)


@njit(inline="always", cache=True)
def eye_ray(cam, px, py):
    """World-space eye ray through film position (px, py) in pixels.

    Returns ``(ox, oy, oz, dx, dy, dz, tmin, tmax, dz_camera)``.
    """
    u = px / cam[14]
    v = py / cam[15]
    cx = (1.0 - 2.0 * u) * cam[12]
    cy = (1.0 - 2.0 * v) * cam[12] / cam[13]
    inv = 1.0 / math.sqrt(cx * cx + cy * cy + 1.0)
    cx *= inv
    cy *= inv
    cz = inv
    dx = cam[0] * cx + cam[3] * cy + cam[6] * cz
    dy = cam[1] * cx + cam[4] * cy + cam[7] * cz
    dz = cam[2] * cx + cam[5] * cy + cam[8] * cz
    return cam[9], cam[10], cam[11], dx, dy, dz, cam[16] / cz, cam[17] / cz, cz
