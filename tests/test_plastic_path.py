"""Mitsuba's ``plastic`` and ``roughplastic`` in the path tracer: the BSDF dispatch of
``impl.bsdf`` agrees with ``impl.plastic`` (sample weight = eval / pdf, pdf =
``bsdf_pdf``), and ``suites/vocabulary/plastic.xml`` (smooth, nonlinear and rough
plastic spheres) passes the Z-test against Mitsuba's ``path`` with the same XML."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _regions import thirds_z

from core.loader import load_scene
from gibench import registry
from impl.bsdf import bsdf_arrays, bsdf_eval, bsdf_pdf, bsdf_sample
from impl.materials import MAT_PLASTIC, MAT_ROUGHPLASTIC

PLASTIC = Path(__file__).resolve().parent.parent / "suites" / "vocabulary" / "plastic.xml"


def test_dispatch_sample_eval_pdf_agree():
    """For each plastic material of the scene: a non-delta sample's weight is
    eval / pdf and its pdf is bsdf_pdf's; smooth plastic also draws delta samples
    (the mirror direction), roughplastic never does."""
    scene = load_scene(PLASTIC)
    B = bsdf_arrays(scene)
    spheres = sorted((s for s in scene.shapes if s.kind == "sphere"), key=lambda s: s.center[0])
    mats = [s.material for s in spheres]
    assert [int(B.kind[m]) for m in mats] == [MAT_PLASTIC, MAT_PLASTIC, MAT_ROUGHPLASTIC]
    assert B.pl_nonlinear[mats[1]] == 1 and B.pl_alpha[mats[2]] == pytest.approx(0.2)
    rng = np.random.default_rng(0)
    for m in mats:
        rho = scene.materials[m].reflectance
        n_delta = 0
        for _ in range(300):
            wi = rng.normal(size=3)
            wi[2] = abs(wi[2]) + 0.05
            wi /= np.linalg.norm(wi)
            u = rng.random(3)
            ox, oy, oz, wr, wg, wb, pdf, delta, eta = bsdf_sample(B, m, *rho, 1.0, *wi, *u)
            assert eta == 1.0
            if delta:
                n_delta += 1
                assert (ox, oy, oz) == pytest.approx((-wi[0], -wi[1], wi[2]))
                continue
            if pdf <= 0.0:
                continue
            f = bsdf_eval(B, m, *rho, 1.0, *wi, ox, oy, oz)
            assert np.allclose(np.array([wr, wg, wb]) * pdf, f, rtol=1e-9, atol=1e-12)
            assert bsdf_pdf(B, m, 1.0, *wi, ox, oy, oz) == pytest.approx(pdf, rel=1e-9)
        assert (n_delta > 0) == (int(B.kind[m]) == MAT_PLASTIC)


@pytest.mark.mitsuba
def test_plastic_scene_passes_the_ztest_against_mitsuba_path():
    """Per pixel (Z-test) and per third of the image (the mean of each third, where a
    bias of a fraction of a per-cent shows): the three plastic spheres and the ground
    they light agree with Mitsuba's ``path``; a 3 % exposure error is rejected."""
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get("path")
    ref = get_reference(PLASTIC, transport="full", spp=1024, passes=8)
    own = algo.render(load_scene(PLASTIC), algo.parse_params({"spp": 256}), seed=0)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    print(f"\npath: {z}")
    assert z.passed, z
    zt = thirds_z(ref, own.image, own.variance)
    print(f"z of the thirds' means {np.round(zt, 2).tolist()}")
    assert np.all(np.abs(zt) < 4.0)
    assert not z_test(ref.image, own.image * 1.03, reference_variance=ref.variance,
                      test_variance=own.variance).passed


@pytest.mark.mitsuba
def test_the_ztest_sees_a_dropped_nonlinear_flag(tmp_path):
    """The middle sphere rendered without ``nonlinear`` (4.7 / 17 / 17 % darker in R / G / B
    over the middle third, measured) fails the Z-test against the reference with it."""
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get("path")
    ref = get_reference(PLASTIC, transport="full", spp=1024, passes=8)
    linear = tmp_path / "plastic.xml"
    linear.write_text(PLASTIC.read_text().replace('<boolean name="nonlinear" value="true"/>', ""))
    own = algo.render(load_scene(linear), algo.parse_params({"spp": 256}), seed=0)
    assert not z_test(ref.image, own.image, reference_variance=ref.variance,
                      test_variance=own.variance).passed


def test_only_path_models_plastic(tmp_path):
    import re

    from core.errors import UnsupportedError

    scene = load_scene(PLASTIC)
    for name in ("raycast", "whitted", "distributed"):
        algo = registry.get(name)
        with pytest.raises(UnsupportedError, match=f"{name}: shape '.*' uses 'plastic'"):
            algo.render(scene, algo.parse_params({}))
    path = registry.get("path")
    no_sky = tmp_path / "plastic.xml"         # without the constant sky spectral mode refuses first
    no_sky.write_text(re.sub(r'<emitter type="constant">.*?</emitter>', "", PLASTIC.read_text(),
                             flags=re.S))
    with pytest.raises(UnsupportedError, match=r"spectral=true.*plastic BSDFs are not modelled"):
        path.render(load_scene(no_sky), path.parse_params({"spectral": True, "spp": 1}))
