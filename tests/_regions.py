"""Region statistics shared by the Z-tests of whole scenes against Mitsuba, and the
render-and-test steps of the vocabulary scenes' tests."""

import dataclasses
from pathlib import Path

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


def path_against_mitsuba(scene_file, materials=None, **fields):
    """Own ``path`` at 256 spp (seed 0) of ``scene_file`` and the Z-test against the
    stored Mitsuba ``path`` reference (1024 spp × 8 passes): (reference, render, z).
    ``materials`` (a function of one material) or ``fields`` (scene field → function
    of one of its items) change the loaded scene first, e.g. to mis-model a feature."""
    return against_mitsuba(scene_file, "path", {"spp": 256}, "full", materials, **fields)


def against_mitsuba(scene_file, algorithm, params, transport, materials=None, **fields):
    """Own ``algorithm`` with ``params`` (seed 0) of ``scene_file`` and the Z-test against
    the stored Mitsuba reference of ``transport`` (1024 spp × 8 passes): (reference,
    render, z); ``materials`` and ``fields`` as :func:`path_against_mitsuba` takes them.
    A file's ``path`` integrator's ``max_depth``, which the full-transport reference
    renders, goes to the own render too (:func:`gibench.suite.file_max_depth`)."""
    from core.loader import load_scene
    from gibench import registry
    from gibench.suite import file_max_depth
    from references.reference import get_reference
    from reports.metrics import z_test

    algo = registry.get(algorithm)
    params = {**params, **file_max_depth(Path(scene_file), algo, params, transport)}
    ref = get_reference(scene_file, transport=transport, spp=1024, passes=8)
    scene = load_scene(scene_file)
    if materials is not None:
        fields["materials"] = materials
    if fields:
        scene = dataclasses.replace(scene, **{k: [fn(x) for x in getattr(scene, k)]
                                               for k, fn in fields.items()})
    own = algo.render(scene, algo.parse_params(params), seed=0)
    z = z_test(ref.image, own.image, reference_variance=ref.variance, test_variance=own.variance)
    return ref, own, z


def assert_passes_by_pixel_and_thirds(name, ref, own, z):
    """The per-pixel Z-test passes, each third's mean is within 4 standard errors, and a
    3 % exposure error moves some third's mean by more than 4."""
    zt = thirds_z(ref, own.image, own.variance).astype(np.float64)
    z3 = thirds_z(ref, own.image * 1.03, own.variance).astype(np.float64)
    print(f"\n{name}: {z}\nz of the thirds' means {np.round(zt, 2).tolist()}; with a 3 % exposure "
          f"error {np.round(z3, 1).tolist()}")
    assert z.passed, z
    assert np.all(np.abs(zt) < 4.0)
    assert np.abs(z3).max() > 4.0
