"""Closed forms the tests check the renderers against, written independently of impl/."""

import math


def fresnel_inside(theta, n=1.5):
    """Unpolarised reflectance from inside glass of index n at incidence θ (Hecht's amplitudes)."""
    s_t = n * math.sin(theta)
    if s_t >= 1.0:
        return 1.0
    ci, ct = math.cos(theta), math.sqrt(1 - s_t ** 2)
    r_s = (n * ci - ct) / (n * ci + ct)
    r_p = (ci - n * ct) / (ci + n * ct)
    return 0.5 * (r_s ** 2 + r_p ** 2)
