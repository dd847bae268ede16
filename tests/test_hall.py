"""Hall shading (thesis 2.4.5.5, ``distributed shading=hall``) against its closed form on
``suites/thesis/hall_mirror.xml``: T_r^Δ on reflected rays, k_sr on the rays from other
bodies, the spot's cone on the light-source terms, the k_dr diffuse term, and the
thesis's constraint k_dr + k_sr = 1 refused when broken."""

import math
from pathlib import Path

import numpy as np
import pytest

from core.errors import ParamError
from core.loader import load_scene
from gibench import registry

SCENE = Path(__file__).resolve().parent.parent / "suites" / "thesis" / "hall_mirror.xml"
DIST = registry.get("distributed")
#: The scene's spot intensity, cone and beam (degrees), ceiling height over the mirror.
I, CUTOFF, BEAM, CEILING = 4.0, 30.0, 20.0, 3.0


def closed_form(ks, kd, tr, n, *, cone=True, ks_on_rays=True) -> np.ndarray:
    """The 9×9 image: pixel centre (col, row) sees the mirror at x = (col − 4)·4/9,
    z = (row − 4)·4/9 (orthographic, 4 × 4 units), whose reflected ray meets the ceiling
    (radiance 1) after Δ = 3: k_sr T_r^Δ; plus the spot at height 2 (d² = 4 + x² + z²,
    L = (−x, 2, −z)/d, V = N = +y) times its fall-off f (1 inside the beam, linear in
    angle to 0 at the cutoff): k_sr I f/d² (N·H)^n + k_dr I f/d² (N·L).  ``cone=False`` and
    ``ks_on_rays=False`` are the models with the cone ignored and with k_sr on the
    highlights only (the broken variants the check must reject)."""
    out = np.zeros((9, 9))
    for row in range(9):
        for col in range(9):
            x, z = (col - 4) * 4 / 9, (row - 4) * 4 / 9
            d2 = 4 + x * x + z * z
            d = math.sqrt(d2)
            lx, ly, lz = -x / d, 2 / d, -z / d
            angle = math.degrees(math.acos(ly))
            f = 1.0 if angle < BEAM or not cone else max(0.0, (CUTOFF - angle) / (CUTOFF - BEAM))
            ndh = (ly + 1) / math.sqrt(lx * lx + (ly + 1) ** 2 + lz * lz)
            rays = (ks if ks_on_rays else 1.0) * tr ** CEILING
            out[row, col] = rays + ks * I / d2 * f * ndh ** n + kd * I / d2 * f * ly
    return out


def render(defines=None, **params):
    p = DIST.parse_params({"spp": 1, "sampler": "uniform", "shading": "hall", **params})
    img = DIST.render(load_scene(SCENE, defines=defines), p, seed=0).image
    assert np.all(img[..., 0] == img[..., 1]) and np.all(img[..., 0] == img[..., 2])
    return np.asarray(img[..., 0], np.float64)


def close(a, b) -> bool:
    """Agreement to float32 rounding of the image."""
    return bool(np.allclose(a, b, rtol=1e-5, atol=1e-7))


def test_hall_matches_its_closed_form_and_rejects_the_broken_variants():
    ks, kd, tr, n = 0.75, 0.25, 0.5, 50.0
    img = render(hall_ks=ks, hall_kd=kd, hall_tr=tr, hall_n=n)
    assert close(img, closed_form(ks, kd, tr, n))
    # The check has power: each missing piece gives another image it rejects.
    assert not close(img, closed_form(ks, kd, 1.0, n))                    # T_r not applied
    assert not close(img, closed_form(ks, kd, tr, n, cone=False))         # cone ignored
    assert not close(img, closed_form(ks, kd, tr, n, ks_on_rays=False))   # k_sr on highlights only
    assert not close(img, closed_form(ks, 0.0, tr, n))                    # no k_dr term
    # Rendered broken variants: no T_r, and a spot whose cone covers everything (a point light).
    assert not close(render(hall_ks=ks, hall_kd=kd, hall_tr=1.0, hall_n=n), closed_form(ks, kd, tr, n))
    wide = render({"cutoff": "89", "beam": "89"}, hall_ks=ks, hall_kd=kd, hall_tr=tr, hall_n=n)
    assert close(wide, closed_form(ks, kd, tr, n, cone=False))
    assert not close(wide, closed_form(ks, kd, tr, n))


def test_a_spot_aimed_away_adds_nothing():
    """Aimed up, the spot's cone holds no point of the mirror: every pixel is k_sr T_r³."""
    img = render({"target": "0, 4, 0"}, hall_ks=0.6, hall_kd=0.4, hall_tr=0.8)
    assert np.all(np.abs(img - 0.6 * 0.8 ** 3) < 1e-6)


@pytest.mark.parametrize("params, words", [
    ({"hall_ks": 0.75, "hall_kd": 0.5}, "hall_kd=0.5 + hall_ks=0.75 = 1.25"),
    ({"hall_ks": 0.5}, "hall_kd=0.0 + hall_ks=0.5 = 0.5"),
    ({"hall_ks": 1.5, "hall_kd": -0.5}, "both in [0, 1]"),
    ({"hall_tr": 0.0}, "hall_tr=0.0"),
    ({"hall_tr": 1.5}, "0 < hall_tr <= 1"),
])
def test_parameters_breaking_the_thesis_constraints_are_refused(params, words):
    with pytest.raises(ParamError, match=words.replace("[", r"\[").replace("]", r"\]").replace("+", r"\+")):
        DIST.render(load_scene(SCENE), DIST.parse_params({"shading": "hall", "spp": 1, **params}), seed=0)
