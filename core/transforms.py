"""4×4 affine transforms with Mitsuba 3 semantics.

Inside a ``<transform>`` element each operation is *left*-multiplied onto the
running matrix (``T ← op · T``), so operations apply in the order written.
``look_at`` follows Mitsuba's camera frame: +z looks at the target, +y is up
and +x points to the *left* of the image.
"""

from __future__ import annotations

import numpy as np

__all__ = ["translate", "scale", "rotate", "look_at", "transform_points",
           "transform_vectors", "transform_normals", "uniform_scale_factor"]


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, dtype=np.float64)
    return m


def scale(v) -> np.ndarray:
    v = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Rotation by ``angle_deg`` degrees about ``axis`` (right-handed, Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0.0:
        raise ValueError("rotate: the axis is the zero vector")
    x, y, z = a / n
    th = np.deg2rad(angle_deg)
    c, s = np.cos(th), np.sin(th)
    C = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [[x * x * C + c, x * y * C - z * s, x * z * C + y * s],
                 [y * x * C + z * s, y * y * C + c, y * z * C - x * s],
                 [z * x * C - y * s, z * y * C + x * s, z * z * C + c]]
    return m


def look_at(origin, target, up) -> np.ndarray:
    """Camera-to-world matrix: columns (left, up, forward, origin), as Mitsuba's ``look_at``."""
    o, t, u = (np.asarray(v, dtype=np.float64) for v in (origin, target, up))
    d = t - o
    if np.linalg.norm(d) == 0.0:
        raise ValueError("lookat: origin and target coincide")
    d /= np.linalg.norm(d)
    left = np.cross(u, d)
    if np.linalg.norm(left) < 1e-12:
        raise ValueError("lookat: 'up' is parallel to the viewing direction")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def transform_points(m: np.ndarray, p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def transform_vectors(m: np.ndarray, v) -> np.ndarray:
    return np.asarray(v, dtype=np.float64) @ m[:3, :3].T


def transform_normals(m: np.ndarray, n) -> np.ndarray:
    """Normals transform by the inverse transpose; the result is renormalised."""
    out = np.asarray(n, dtype=np.float64) @ np.linalg.inv(m[:3, :3])
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def uniform_scale_factor(m: np.ndarray, rtol: float = 1e-6) -> float | None:
    """The scale of a similarity transform, or ``None`` if the scale is not uniform."""
    lin = m[:3, :3]
    g = lin.T @ lin
    s2 = np.trace(g) / 3.0
    if not np.allclose(g, s2 * np.eye(3), rtol=rtol, atol=rtol * s2):
        return None
    return float(np.sqrt(s2))
