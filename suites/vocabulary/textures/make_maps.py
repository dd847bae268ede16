"""Write the small images of the normal-map, bump-map and projector scenes.

Run from anywhere (``python suites/vocabulary/textures/make_maps.py``); the PNGs
land beside this script:

* ``bumps_normal.png`` (32×32, 8-bit RGB, read with ``raw=true``): the
  tangent-space normals (n + 1)/2 of a 4×4 grid of spherical caps (radius 0.45 of
  a cell, tilting the normal by up to about 60°) plus a uniform tilt of the flat
  part towards +u, so that a mix-up of the tangent frame (u, v swapped or t
  negated) changes the image;
* ``bumps_height.png`` (32×32, 8-bit grey, ``raw=true``): a height field of
  ridges along v, h = ½ + ½ sin(2π·3u) · (½ + ½ v), whose gradient has both
  components (the bump map's eval_1_grad);
* ``slide.png`` (24×16, 8-bit sRGB): an asymmetric picture for the projector
  (a colour ramp along x, a bright block top left, a dark stripe bottom right),
  so a mirrored or transposed projection differs.
"""

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent


def bumps_normal(n: int = 32, cells: int = 4) -> np.ndarray:
    u = (np.arange(n) + 0.5) / n
    U, V = np.meshgrid(u, u)               # row j is v, column i is u
    cu = (U * cells) % 1.0 - 0.5
    cv = (V * cells) % 1.0 - 0.5
    r = 0.45
    d2 = cu * cu + cv * cv
    inside = d2 < r * r
    z = np.sqrt(np.maximum(r * r - d2, 1e-12))
    nx = np.where(inside, cu / r, 0.25)
    ny = np.where(inside, cv / r, 0.0)
    nz = np.where(inside, np.maximum(z / r, 0.5), 1.0)
    nrm = np.stack([nx, ny, nz], axis=-1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return np.round((nrm + 1.0) * 0.5 * 255.0).astype(np.uint8)


def bumps_height(n: int = 32) -> np.ndarray:
    u = (np.arange(n) + 0.5) / n
    U, V = np.meshgrid(u, u)
    h = 0.5 + 0.5 * np.sin(2.0 * np.pi * 3.0 * U) * (0.5 + 0.5 * V)
    return np.round(h * 255.0).astype(np.uint8)


def slide(w: int = 24, h: int = 16) -> np.ndarray:
    x = (np.arange(w) + 0.5) / w
    img = np.zeros((h, w, 3))
    img[:, :, 0] = 0.2 + 0.8 * x[None, :]
    img[:, :, 1] = 0.5
    img[:, :, 2] = 1.0 - 0.8 * x[None, :]
    img[: h // 3, : w // 3] = 1.0
    img[3 * h // 4:, w // 2:] = 0.05
    return np.round(img * 255.0).astype(np.uint8)


def main() -> None:
    Image.fromarray(bumps_normal(), "RGB").save(HERE / "bumps_normal.png")
    Image.fromarray(bumps_height(), "L").save(HERE / "bumps_height.png")
    Image.fromarray(slide(), "RGB").save(HERE / "slide.png")


if __name__ == "__main__":
    main()
