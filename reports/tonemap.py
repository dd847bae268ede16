"""Display transforms shared by the image metrics and the report pages.

Convention (stated wherever an LDR metric is quoted): linear radiance is
multiplied by ``exposure``, clipped to [0, 1] and encoded with the sRGB
transfer function (IEC 61966-2-1), through colour-science.
"""

from __future__ import annotations

import colour
import numpy as np

__all__ = ["tonemap_srgb"]


def tonemap_srgb(image, *, exposure: float = 1.0) -> np.ndarray:
    """Map linear sRGB radiance ``(H, W, 3)`` to display sRGB in [0, 1] (float64).

    Non-finite values are mapped to 0 so a broken pixel cannot poison a
    display; metrics count them separately.
    """
    a = np.asarray(image, dtype=np.float64) * float(exposure)
    a = np.where(np.isfinite(a), a, 0.0)
    a = np.clip(a, 0.0, 1.0)
    return np.clip(colour.cctf_encoding(a, function="sRGB"), 0.0, 1.0)
