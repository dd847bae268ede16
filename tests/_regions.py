"""Region statistics shared by the Z-tests of whole scenes against Mitsuba."""

import numpy as np


def thirds_z(ref, image, variance) -> np.ndarray:
    """z of the difference of the image means over each third of the columns, (3, 3):
    rows the thirds (left to right), columns RGB.  ``ref`` has ``image`` and ``variance``
    (per-pixel variance of the mean); ``image`` / ``variance`` are the tested render's."""
    H, W = ref.image.shape[:2]
    out = []
    for x0, x1 in ((0, W // 3), (W // 3, 2 * W // 3), (2 * W // 3, W)):
        n = H * (x1 - x0)
        diff = image[:, x0:x1].mean((0, 1)) - ref.image[:, x0:x1].mean((0, 1))
        se = np.sqrt(variance[:, x0:x1].sum((0, 1)) + ref.variance[:, x0:x1].sum((0, 1))) / n
        out.append(diff / se)
    return np.array(out)
