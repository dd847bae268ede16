"""Z-test assertions for your own test suite, as Mitsuba's render tests do them.

    from gibench.testing import assert_consistent

    def test_my_renderer_matches_mitsuba():
        image, variance = my_renderer.render("scene.xml", spp=64)
        assert_consistent(image, "references/scene/image.exr", variance=variance,
                          reference_variance="references/scene/variance.exr")

:func:`assert_consistent` runs the per-pixel, per-channel Z-test of
:func:`reports.metrics.z_test` (two noisy estimates with the same
expectation; Šidák-corrected over every entry) and, when it fails, writes the
evidence EXRs (own and reference images, their variances, ``|own − ref|`` and
the p-value map) to a folder named in the assertion message.

The pytest plugin (this module; loaded through the ``pytest11`` entry point
when gibench is installed, or with ``pytest_plugins = ["gibench.testing"]``
in your root ``conftest.py`` or ``-p gibench.testing``) adds the fixture
``gibench_consistent``: :func:`assert_consistent` with the evidence folder
``<--gibench-evidence DIR, default gibench-evidence>/<test name>/``.

Images are ``(H, W, 3)`` linear float arrays or EXR paths; variances are
variances of the pixel *mean* (sample variance / sample count).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

__all__ = ["assert_consistent", "gibench_consistent", "DEFAULT_EVIDENCE"]

#: Where evidence goes without ``evidence_dir`` (or the ``GIBENCH_EVIDENCE`` variable).
DEFAULT_EVIDENCE = "gibench-evidence"


def _image(x, what: str):
    if x is None:
        return None
    if isinstance(x, (str, os.PathLike)):
        from core.imageio import read_exr

        return read_exr(x).astype(np.float64)
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] < 3:
        raise ValueError(f"{what}: expected an (H, W, 3) image or an EXR path, got shape {a.shape}")
    return a[..., :3]


def assert_consistent(image, reference, *, variance=None, reference_variance, alpha: float = 0.01,
                      min_fraction: float = 0.9975, evidence_dir=None, name: str = "image"):
    """Assert that ``image`` and ``reference`` have the same expectation (Z-test).

    Parameters
    ----------
    image, reference : ndarray (H, W, 3) or path of an EXR
        Linear radiance estimates.
    variance, reference_variance : ndarray, path or None
        Variances of the two pixel means; ``variance=None`` treats ``image``
        as exact.  ``reference_variance`` is required (without it there is no
        test).
    alpha, min_fraction : float
        Family-wise level and the fraction of entries that must be consistent
        (:func:`reports.metrics.z_test`).
    evidence_dir : path, optional
        Folder for the evidence of a failure (default ``$GIBENCH_EVIDENCE`` or
        ``gibench-evidence/``), in a sub-folder ``name``.

    Returns
    -------
    reports.metrics.ZTestResult
        When the test passes.

    Raises
    ------
    AssertionError
        When it fails: the fraction, the threshold, the worst entry and the
        evidence folder.
    """
    from core.imageio import write_exr
    from reports.metrics import z_test

    own, ref = _image(image, "image"), _image(reference, "reference")
    var, ref_var = _image(variance, "variance"), _image(reference_variance, "reference_variance")
    if ref_var is None:
        raise ValueError("assert_consistent: reference_variance is required for the Z-test")
    finite = np.isfinite(own)
    z = z_test(ref, np.where(finite, own, np.nan), reference_variance=ref_var, test_variance=var,
               alpha=alpha, min_fraction=min_fraction)
    if z.passed:
        return z
    folder = Path(evidence_dir or os.environ.get("GIBENCH_EVIDENCE") or DEFAULT_EVIDENCE)
    folder = folder / re.sub(r"[^A-Za-z0-9_.-]+", "_", name)
    folder.mkdir(parents=True, exist_ok=True)
    own0 = np.where(finite, own, 0.0)
    write_exr(folder / "own.exr", own0.astype(np.float32))
    write_exr(folder / "reference.exr", ref.astype(np.float32))
    write_exr(folder / "error.exr", np.abs(own0 - ref).astype(np.float32))
    write_exr(folder / "pvalue.exr", np.nan_to_num(z.p_values, nan=0.0).astype(np.float32))
    write_exr(folder / "reference_variance.exr", np.broadcast_to(ref_var, ref.shape).astype(np.float32))
    if var is not None:
        write_exr(folder / "own_variance.exr", np.broadcast_to(var, ref.shape).astype(np.float32))
    p = np.nan_to_num(z.p_values, nan=-1.0)
    y, x, c = np.unravel_index(np.argmin(p), p.shape)
    worst = (f"worst entry x={x}, y={y}, channel {'RGB'[c]}: own {own[y, x, c]:.6g}, reference "
             f"{ref[y, x, c]:.6g}, p = {max(p[y, x, c], 0.0):.3g}")
    raise AssertionError(
        f"{name}: Z-test failed: {z.fraction:.5f} of {z.n} entries consistent (need "
        f"{z.min_fraction}; per-entry level {z.significance:.3g}, alpha {z.alpha}); {worst}; "
        f"non-finite own values: {int((~finite).sum())}; evidence: {folder}")


# --- pytest plugin -------------------------------------------------------------------------------

def pytest_addoption(parser):
    parser.addoption("--gibench-evidence", default=None, metavar="DIR",
                     help=f"folder for gibench Z-test evidence EXRs (default: {DEFAULT_EVIDENCE})")


try:
    import pytest as _pytest
except ImportError:                          # pragma: no cover - the helper works without pytest
    _pytest = None

if _pytest is not None:
    @_pytest.fixture
    def gibench_consistent(request):
        """:func:`assert_consistent` writing its evidence to ``<--gibench-evidence>/<test name>/``."""
        root = (request.config.getoption("--gibench-evidence", default=None)
                or os.environ.get("GIBENCH_EVIDENCE") or DEFAULT_EVIDENCE)

        def check(image, reference, **kw):
            kw.setdefault("evidence_dir", root)
            kw.setdefault("name", request.node.name)
            return assert_consistent(image, reference, **kw)

        return check
