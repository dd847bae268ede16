"""gibench.testing: the Z-test assertion for users' own test suites and its pytest
fixture, run as a user would (a separate pytest process loading the plugin)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from core.imageio import read_exr, write_exr
from gibench.testing import assert_consistent

REPO = Path(__file__).resolve().parent.parent


def _noisy(seed, shape=(16, 20, 3), sigma=0.05):
    rng = np.random.default_rng(seed)
    truth = np.linspace(0.2, 1.0, shape[0] * shape[1] * 3).reshape(shape)
    return truth + rng.normal(0.0, sigma, shape), np.full(shape, sigma ** 2)


def test_consistent_images_pass_and_paths_work(tmp_path):
    own, var = _noisy(1)
    ref, ref_var = _noisy(2)
    z = assert_consistent(own, ref, variance=var, reference_variance=ref_var, evidence_dir=tmp_path)
    assert z.passed and not any(tmp_path.iterdir())
    write_exr(tmp_path / "ref.exr", ref.astype(np.float32))
    write_exr(tmp_path / "ref_var.exr", ref_var.astype(np.float32))
    assert assert_consistent(own, tmp_path / "ref.exr", variance=var,
                             reference_variance=tmp_path / "ref_var.exr").passed


def test_biased_image_fails_with_evidence(tmp_path):
    own, var = _noisy(1)
    ref, ref_var = _noisy(2)
    own[4:8, 5:9] += 0.5                       # a bright patch: 48 entries at ~7 sigma
    with pytest.raises(AssertionError) as exc:
        assert_consistent(own, ref, variance=var, reference_variance=ref_var,
                          evidence_dir=tmp_path, name="bright patch")
    msg = str(exc.value)
    assert "Z-test failed" in msg and "need 0.9975" in msg and str(tmp_path / "bright_patch") in msg
    assert "worst entry x=" in msg
    ev = tmp_path / "bright_patch"
    assert {p.name for p in ev.iterdir()} == {"own.exr", "reference.exr", "error.exr", "pvalue.exr",
                                             "reference_variance.exr", "own_variance.exr"}
    p = read_exr(ev / "pvalue.exr")
    assert p[4:8, 5:9].max() < 1e-3 and np.median(p) > 0.1


def test_pytest_fixture_in_a_user_suite(tmp_path):
    """A user's test file using the ``gibench_consistent`` fixture, run by pytest with
    the plugin: one consistent case passes, one biased case fails with evidence in
    --gibench-evidence/<test name>/."""
    (tmp_path / "test_user.py").write_text(textwrap.dedent("""
        import numpy as np

        def _img(seed, bias=0.0):
            rng = np.random.default_rng(seed)
            return 0.5 + bias + rng.normal(0, 0.05, (8, 8, 3)), np.full((8, 8, 3), 0.0025)

        def test_same(gibench_consistent):
            (a, va), (b, vb) = _img(1), _img(2)
            gibench_consistent(a, b, variance=va, reference_variance=vb)

        def test_biased(gibench_consistent):
            (a, va), (b, vb) = _img(1, bias=0.3), _img(2)
            gibench_consistent(a, b, variance=va, reference_variance=vb)
        """))
    # The pytest11 entry point as pyproject.toml declares it (an installed gibench has it).
    site = tmp_path / "site" / "gibench_entry-0.dist-info"
    site.mkdir(parents=True)
    (site / "METADATA").write_text("Metadata-Version: 2.1\nName: gibench-entry\nVersion: 0\n")
    (site / "entry_points.txt").write_text("[pytest11]\ngibench.testing = gibench.testing\n")
    for how, extra, path in [("-p", ["-p", "gibench.testing"], [str(REPO)]),
                             ("entry point", [], [str(REPO), str(site.parent)]),
                             ("both", ["-p", "gibench.testing"], [str(REPO), str(site.parent)])]:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(path))
        ev = tmp_path / f"ev-{how.replace(' ', '_')}"
        proc = subprocess.run([sys.executable, "-m", "pytest", *extra, "-q", "-p", "no:cacheprovider",
                               "--gibench-evidence", str(ev), str(tmp_path / "test_user.py")],
                              cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert "1 failed, 1 passed" in proc.stdout, how + ": " + proc.stdout + proc.stderr
        assert "Z-test failed" in proc.stdout
        assert (ev / "test_biased" / "pvalue.exr").is_file()
        assert not (ev / "test_same").exists()
