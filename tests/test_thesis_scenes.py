"""The thesis's image sections as checks: Fig. 3.1's colour bleeding (3.1, 3.5) in
Mitsuba's reference and in the own radiosity and path tracer, with the grey-panel negative
control, and the suite manifest that maps 2.7 and 3.5 to their scenes."""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench import registry
from gibench.suite import load_suite
from impl.raycast import cast_primary

SUITES = Path(__file__).resolve().parent.parent / "suites"
PANELS = SUITES / "thesis" / "fig31_panels.xml"
#: R/G of the white faces above which they count as tinted by the red panels.
BLEED_MIN = 3.0


def _white_faces(scene):
    _, sid = cast_primary(scene)
    return np.isin(sid, [i for i, s in enumerate(scene.shapes) if s.name.endswith("_down")])


def bleeding(image, mask) -> float:
    """Mean red over mean green of the white faces' pixels."""
    m = np.asarray(image, np.float64)[mask].mean(axis=0)
    return float(m[0] / m[1])


def test_thesis_suite_maps_the_image_sections():
    suite = load_suite(SUITES / "thesis.toml")
    scenes = {c.scene_id for c in suite.cases}
    assert {"thesis/fig31_panels", "cornell/cornell_box", "spheres/whitted_classic"} <= scenes


@pytest.mark.mitsuba
def test_fig31_white_faces_take_the_colour_of_the_panels():
    """White faces lit only by the red faces below them: R/G ≥ 3 in Mitsuba's 1024-spp reference
    (measured 11) and in the own radiosity and path tracer, which agree with it to 15 %.  With
    grey panels (-D upper=0.5,0.5,0.5) the same check fails: R/G = 1."""
    from references.reference import get_reference

    scene = load_scene(PANELS)
    white = _white_faces(scene)
    assert white.sum() > 1000
    ref = bleeding(get_reference(PANELS, transport="full", spp=1024, passes=8).image, white)
    rad, path = registry.get("radiosity"), registry.get("path")
    own = {"radiosity": bleeding(rad.render(scene, rad.parse_params({"patches": 512, "spp": 4}), seed=0).image,
                                 white),
           "path": bleeding(path.render(scene, path.parse_params({"spp": 64}), seed=0).image, white)}
    print(f"R/G of the white faces: Mitsuba {ref:.2f}, {own}")
    assert ref >= BLEED_MIN
    for name, value in own.items():
        assert value >= BLEED_MIN and abs(value - ref) / ref < 0.15, name
    grey = load_scene(PANELS, defines={"upper": "0.5, 0.5, 0.5"})
    control = bleeding(rad.render(grey, rad.parse_params({"patches": 512, "spp": 4}), seed=0).image, white)
    print(f"grey panels: R/G {control:.3f}")
    assert not control >= BLEED_MIN


@pytest.mark.mitsuba
def test_fig31_path_ztest_passes_and_an_exposure_error_fails():
    """The suite's Z-test case of the panels (path, 256 spp, against Mitsuba's 1024-spp path
    reference) passes per pixel.  Negative controls: the per-pixel test has little power here
    (most pixels are black in both, the white faces are lit by one bounce only and noisy):
    measured, a 30 % exposure error still passes (0.9998) and 50 % fails (0.9969), which is
    asserted; the aggregate Z over the white faces' pixels, Σ(own − ref) / √Σ(var), rejects a
    5 % error."""
    from references.reference import get_reference
    from reports.metrics import z_test

    ref = get_reference(PANELS, transport="full", spp=1024, passes=8)
    path = registry.get("path")
    scene = load_scene(PANELS)
    own = path.render(scene, path.parse_params({"spp": 256}), seed=0)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    bad = z_test(ref.image, own.image * 1.5, reference_variance=ref.variance, test_variance=own.variance)
    print(z, bad.fraction)
    assert z.passed and not bad.passed
    white = _white_faces(scene)

    def aggregate(scale):
        d = (own.image[white] * scale - ref.image[white]).sum()
        return d / np.sqrt((own.variance[white] * scale ** 2 + ref.variance[white]).sum())

    print(f"aggregate Z: {aggregate(1.0):.2f} (as is), {aggregate(1.05):.2f} (5 % brighter)")
    assert abs(aggregate(1.0)) < 4.0 and abs(aggregate(1.05)) > 4.0


@pytest.mark.mitsuba
def test_radiosity_image_bounds_fail_without_interreflection():
    """Thesis 3.5: the suite's relMSE bounds of the radiosity images (Cornell room, Fig. 3.1
    panels) against Mitsuba's full transport hold for the suite's z-buffer-hemicube
    configurations and fail for the same solve cut to one bounce (direct light only,
    ``max_bounces=1``): the negative control of the bound."""
    from references.reference import get_reference
    from reports.metrics import relmse

    algo = registry.get("radiosity")
    cases = [c for c in load_suite(SUITES / "thesis.toml").cases
             if c.algorithm == "radiosity" and c.params.get("formfactor") == "hemicube-zbuffer"]
    assert len(cases) == 2
    for case in cases:
        bound = case.tolerances["relmse"]
        ref = get_reference(case.scene, transport="full", spp=1024, passes=8)
        scene = load_scene(case.scene)
        good = relmse(ref.image, algo.render(scene, algo.parse_params(case.params)).image)
        cut = relmse(ref.image, algo.render(scene, algo.parse_params({**case.params,
                                                                      "max_bounces": 1})).image)
        print(case.scene.name, good, cut, bound)
        assert good <= bound < cut
