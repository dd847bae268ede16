"""The distributed ray tracer (impl/distributed.py): each distributed effect against its
matched Mitsuba reference (Z-test), invariants against the Whitted tracer, the adaptive
samplers' sample allocation, and bad input.

Matched references (suites/distributed.toml): penumbra — Mitsuba ``direct``;
gloss and translucency — the ``whitted`` reference integrator, which follows
glossy lobes by ``bsdf.sample`` (Smith G, visible normals) as the own tracer does;
Gaussian reconstruction — Mitsuba ``direct`` keeping the film's ``gaussian``
rfilter.  Each Z-test has a negative control (a 10 % exposure error, or the
wrong filter) that must fail.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gibench import registry
from core.errors import UnsupportedError
from core.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
SUITES = ROOT / "suites"
DIST = registry.get("distributed")
WHITTED = registry.get("whitted")


def render(path, seed=0, algo=DIST, **params):
    return algo.render(load_scene(path), algo.parse_params(params), seed=seed)


def _ztest(ref, own, scale=1.0):
    from reports.metrics import z_test

    return z_test(ref.image, own.image * scale, reference_variance=ref.variance,
                  test_variance=own.variance)


# Scene, reference transport, own parameters (the suite's).
EFFECTS = [
    ("distributed/penumbra.xml", "direct", {"spp": 64, "light_samples": 1}),
    ("distributed/penumbra.xml", "direct", {"spp": 64, "light_samples": 1, "dimensions": "stratified"}),
    ("distributed/penumbra.xml", "direct", {"spp": 64, "light_samples": 1, "sampler": "sobol"}),
    ("distributed/dof.xml", "direct", {"spp": 256, "light_samples": 1, "dimensions": "stratified"}),
    ("distributed/dof.xml", "direct", {"spp": 256, "light_samples": 1, "sampler": "sobol"}),
    ("distributed/gloss.xml", "whitted", {"spp": 256, "light_samples": 1, "dimensions": "stratified"}),
    ("distributed/gloss.xml", "whitted", {"spp": 256, "light_samples": 1, "sampler": "sobol"}),
    ("distributed/gloss.xml", "whitted", {"spp": 256, "light_samples": 1}),
    ("distributed/translucency.xml", "whitted", {"spp": 256, "light_samples": 1}),
]


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene,transport,params", EFFECTS,
                         ids=[e[0] + "".join(f"-{v}" for k, v in e[2].items() if k in ("dimensions", "sampler"))
                              for e in EFFECTS])
def test_effect_passes_the_ztest_against_its_matched_reference(scene, transport, params):
    from references.reference import get_reference

    ref = get_reference(SUITES / scene, transport=transport, spp=1024, passes=8)
    own = render(SUITES / scene, **params)
    z = _ztest(ref, own)
    print(f"{scene}: {z}")
    assert z.passed, f"{scene}: {z}"
    bad = _ztest(ref, own, 1.10)
    assert not bad.passed, f"{scene}: a 10% exposure error went unnoticed: {bad}"


@pytest.mark.mitsuba
def test_gaussian_reconstruction_matches_mitsubas_gaussian_rfilter():
    from references.reference import get_reference

    scene = SUITES / "distributed/penumbra_gaussian.xml"
    ref = get_reference(scene, transport="direct", spp=1024, passes=8, rfilter="scene")
    own = render(scene, spp=64, light_samples=1)            # rfilter=film: the gaussian
    z = _ztest(ref, own)
    assert z.passed, z
    box = render(scene, spp=64, light_samples=1, rfilter="box")
    zb = _ztest(ref, box)
    assert not zb.passed, f"box reconstruction passed against a gaussian-filtered reference: {zb}"


@pytest.mark.mitsuba
def test_vcavity_g_is_a_small_model_difference_on_the_gloss_scene():
    from references.reference import get_reference
    from reports.metrics import relmse

    scene = SUITES / "distributed/gloss.xml"
    ref = get_reference(scene, transport="whitted", spp=1024, passes=8)
    smith = render(scene, spp=64, light_samples=1, g="smith")
    vcav = render(scene, spp=64, light_samples=1, g="vcavity")
    diff = float(np.abs(vcav.image - smith.image).mean())
    print(f"gloss: relMSE smith {relmse(ref.image, smith.image):.4f}, vcavity "
          f"{relmse(ref.image, vcav.image):.4f}, mean |vcavity - smith| {diff:.2e}, "
          f"mean ratio {vcav.image.mean() / smith.image.mean():.4f}")
    assert diff > 0.0                                     # the option changes the glossy lobes
    assert vcav.image.mean() == pytest.approx(smith.image.mean(), rel=0.03)


def test_centre_sample_equals_whitted_on_delta_scenes():
    """With one centre sample per pixel the distributed tracer is whitted: same rays,
    same light-sample random numbers, so the same image to rounding."""
    for scene in ("spheres/whitted_classic.xml", "spheres/glass_sphere.xml"):
        w = render(SUITES / scene, algo=WHITTED, spp=1, light_samples=4)
        d = render(SUITES / scene, sampler="uniform", spp=1, light_samples=4, rfilter="box")
        assert np.allclose(d.image, w.image, rtol=1e-6, atol=1e-7), scene
        assert d.counters["eye_rays"] == w.counters["eye_rays"]
        assert d.counters["transmission_rays"] == w.counters["transmission_rays"]


def test_adaptive_and_statistical_spend_samples_where_the_pixel_varies():
    scene = SUITES / "distributed/silhouettes.xml"
    ad = render(scene, sampler="adaptive", spp=145, threshold=0.02, adaptive_depth=3)
    spp = ad.aovs["spp"]
    from scipy.ndimage import maximum_filter

    ref = render(scene, sampler="jitter", spp=64)
    # Constant pixels (sky, flat floor) whose neighbours are constant too: adaptive's
    # corner samples lie on the pixel's border and see the neighbours' content.
    flat = maximum_filter(ref.variance.max(axis=2), size=3) == 0.0
    assert flat.sum() > 100 and (~flat).sum() > 100
    assert np.all(spp[flat] == 5)                        # corners + centre agree: no subdivision
    assert spp[~flat].mean() > 10 and spp.max() <= 145
    assert ad.counters["mean_spp"] == pytest.approx(spp.mean())
    st = render(scene, sampler="statistical", spp=64, tolerance=0.01)
    sst = st.aovs["spp"]
    assert np.all(sst[flat] == 4) and sst.max() <= 64 and sst[~flat].mean() > 4


@pytest.mark.parametrize("sampler,spp", [("uniform", 16), ("random", 10), ("jitter", 16), ("poisson", 12),
                                         ("adaptive", 41), ("statistical", 32), ("sobol", 16),
                                         ("sobol", 12), ("stratified", 16)])
def test_every_sampler_estimates_the_same_image(sampler, spp):
    """All samplers estimate the same box-filtered pixel integral: the mean over the
    image agrees with a converged render within a few percent (``stratified``:
    jitter with ``dimensions=stratified``)."""
    scene = SUITES / "distributed/penumbra.xml"
    ref = render(scene, spp=256, light_samples=1, seed=5)
    extra = {"sampler": "jitter", "dimensions": "stratified"} if sampler == "stratified" else {"sampler": sampler}
    img = render(scene, spp=spp, light_samples=1, **extra)
    assert img.image.mean() == pytest.approx(ref.image.mean(), rel=0.03)
    assert np.isfinite(img.image).all() and np.isfinite(img.variance).all()


def test_bad_parameters_and_materials_are_refused(tmp_path):
    scene = SUITES / "distributed/penumbra.xml"
    for params, msg in [({"spp": 8}, "square spp"), ({"sampler": "adaptive", "spp": 4}, "spp >= 5"),
                        ({"gamma": 0.7}, r"gamma must be in \[0, 0.5\]"),
                        ({"confidence": 1.0}, r"confidence must be in \(0, 1\)"),
                        ({"max_depth": 0}, "max_depth must be >= 1"),
                        ({"dimensions": "stratified", "sampler": "sobol"}, "sampler=sobol draws every"),
                        ({"dimensions": "stratified", "sampler": "adaptive", "spp": 16},
                         "chooses its sample count per pixel"),
                        ({"dimensions": "stratified", "sampler": "random", "spp": 10},
                         r"dimensions=stratified needs a square spp")]:
        with pytest.raises(ValueError, match=msg):
            render(scene, **params)
    with pytest.raises(registry.ParamError, match="sampler' must be one of"):
        DIST.parse_params({"sampler": "halton"})
    text = (SUITES / "distributed/gloss.xml").read_text().replace(
        '<string name="distribution" value="beckmann"/>', '<string name="distribution" value="ggx"/>', 1)
    p = tmp_path / "ggx.xml"
    p.write_text(text)
    # GGX is modelled (Z-tested in tests/test_vocabulary_*.py): the file's distribution is read.
    ggx, beckmann = render(p, spp=4), render(SUITES / "distributed/gloss.xml", spp=4)
    assert np.isfinite(ggx.image).all() and not np.array_equal(ggx.image, beckmann.image)
    aniso = '<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/>'
    text = (SUITES / "distributed/gloss.xml").read_text().replace('<float name="alpha" value="0.25"/>',
                                                                 aniso, 1)
    p = tmp_path / "aniso.xml"
    p.write_text(text)
    # Anisotropic roughness is modelled too (Z-tested in tests/test_vocabulary_anisotropic.py).
    aniso = render(p, spp=4)
    assert np.isfinite(aniso.image).all() and not np.array_equal(aniso.image, beckmann.image)
    with pytest.raises(NotImplementedError, match="shape 'gold' has a 'roughconductor' BSDF, which the "
                                                   "Whitted ray tracer does not model"):
        render(SUITES / "distributed/gloss.xml", algo=WHITTED)


def test_module_cites_the_sources():
    import impl.distributed as mod

    assert "Cook" in mod.__doc__ and "1984" in mod.__doc__ and "2.5.5" in mod.__doc__


# ------------------------------------------------------------- motion blur ---

@pytest.mark.mitsuba
def test_motion_blur_matches_the_mean_of_mitsuba_renders_over_the_shutter():
    """Moving sphere (gibench_velocity) vs the stored mean of 64 Mitsuba direct renders at
    jittered stratified shutter times (references/motion_blur.py).  256 spp: at 64 a few
    penumbra pixels see the light in none of their samples (measured 0.9952 consistent)."""
    import dataclasses

    from references.motion_blur import motion_reference
    from references.reference import get_reference

    path = SUITES / "distributed/motion/moving_sphere.xml"
    ref = motion_reference(path, times=64, spp=64, render=False)
    # get_reference (what suites call) routes a moving scene to that same entry.
    routed = get_reference(path, transport="direct", spp=1024, passes=8, render_missing=False)
    assert routed.key == ref.key and np.array_equal(routed.image, ref.image)
    scene = load_scene(path)
    own = DIST.render(scene, DIST.parse_params({"spp": 256, "light_samples": 1}), seed=1)
    z = _ztest(ref, own)
    print(f"motion: {z}")
    assert z.passed, z
    # The same scene with the sphere held still at its shutter-open position fails.
    i = [s.name for s in scene.shapes].index("ball")
    scene.shapes[i] = dataclasses.replace(scene.shapes[i], velocity=None)
    still = DIST.render(scene, DIST.parse_params({"spp": 256, "light_samples": 1}), seed=1)
    assert not _ztest(ref, still).passed


@pytest.mark.mitsuba
def test_motion_blur_runs_as_a_suite_case_without_mitsuba_timing(tmp_path):
    """A suite case on a moving scene: the motion reference, a Z-test, and the Mitsuba
    timing skipped with its reason (Mitsuba cannot move shapes) instead of an error;
    options the motion reference cannot honour are refused by name."""
    import json

    from gibench import cli
    from references.reference import get_reference
    from reports.results import ResultStore

    scene = (SUITES / "distributed/motion/moving_sphere.xml").as_posix()
    manifest = tmp_path / "motion.toml"
    manifest.write_text(f"""
[suite]
name = "motion"
reference_spp = 1024
reference_passes = 8
repeats = 1
[[group]]
scenes = ["{scene}"]
algorithm = "distributed"
transport = "direct"
[[group.config]]
label = "motion"
params = {{ spp = 16, light_samples = 1 }}
expect = "report"
""")
    results = tmp_path / "results.jsonl"
    assert cli.main(["run", str(manifest), "--results", str(results), "--history",
                     str(tmp_path / "h.sqlite"), "--no-progress"]) == 0
    (rec,) = [r for r in ResultStore(results).load() if r.kind != "ladder"]
    assert rec.error is None, rec.error
    assert "cannot move shapes" in rec.time["mitsuba_skipped"]
    assert "mitsuba_median_s" not in rec.time and rec.metrics["relmse"] < 0.1
    json.dumps(rec.to_json())
    with pytest.raises(UnsupportedError, match="motion-blur reference does not support defines"):
        get_reference(scene, transport="direct", defines={"spp": "4"}, render_missing=False)
    # Its store key has no variant: a spectral motion reference would collide with the RGB one.
    with pytest.raises(UnsupportedError, match="does not support spectral"):
        get_reference(scene, transport="direct", spectral=True, render_missing=False)


def test_motion_syntax_is_stripped_for_mitsuba_and_checked_by_the_loader(tmp_path):
    from core.loader import SceneError
    from references.motion_blur import scene_at_time

    path = SUITES / "distributed/motion/moving_sphere.xml"
    xml = scene_at_time(path, 0.5)
    assert "gibench_velocity" not in xml and 'value="-0.6, 0.75, 0.0"' in xml
    ball = [s for s in load_scene(path).shapes if s.name == "ball"][0]
    assert ball.velocity.tolist() == [1.2, 0.3, 0.0]
    p = tmp_path / "bad.xml"
    p.write_text(path.read_text().replace('<point name="center" value="-1.2, 0.6, 0"/>',
                                          '<transform name="to_world"><translate value="-1.2, 0.6, 0"/></transform>'))
    with pytest.raises(SceneError, match="moving sphere .* needs a 'center' point and no 'to_world'"):
        load_scene(p)


def test_hall_shading_adds_highlights_and_transmissivity():
    scene = SUITES / "cornell/cornell_mirror_glass.xml"
    ct = render(scene, spp=4, light_samples=1)
    hall = render(scene, spp=4, light_samples=1, shading="hall")
    diff = hall.image - ct.image
    assert diff.min() >= 0.0 and diff.max() > 0.05       # highlights only add light
    assert hall.counters["shadow_rays"] > ct.counters["shadow_rays"]
    dim = render(scene, spp=4, light_samples=1, shading="hall", hall_t=0.5)
    d2 = dim.image - hall.image
    assert d2.max() <= 1e-7 and d2.min() < -0.01         # T_t^Δ only darkens (through the glass)
    with pytest.raises(ValueError, match="0 < hall_t <= 1"):
        render(scene, shading="hall", hall_t=0.0)
