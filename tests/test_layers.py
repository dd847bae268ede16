"""The layering contract: data flows one way, and the import graph says so.

``core`` (scene model, loader, image I/O, algorithm and record types, errors)
imports no other package of the project; ``impl``, ``references`` and
``reports`` import only ``core`` (and third-party libraries), never each other
nor the application; ``gibench`` sits on top.  The contract lives in
``pyproject.toml`` (``[tool.importlinter]``) and is checked here with
import-linter, on the real tree and on a copy with one upward import added
(the negative control: the same contract must then fail).
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "impl", "references", "reports", "gibench")


def _lint(tree: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lint-imports")
    return subprocess.run([str(exe), "--config", str(tree / "pyproject.toml"), "--no-cache"],
                          cwd=tree, env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
                          capture_output=True, text=True, timeout=240)


def _copy_tree(dst: Path) -> Path:
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__", "store"))
    shutil.copy(ROOT / "pyproject.toml", dst / "pyproject.toml")
    return dst


def test_the_layering_contract_holds():
    out = _lint(ROOT)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "1 kept, 0 broken" in out.stdout


@pytest.mark.parametrize("module, line", [
    ("impl/raycast.py", "import gibench.registry  # an algorithm reaching up to the application"),
    ("core/scene.py", "import impl.sampling  # the bottom package reaching up"),
    ("reports/metrics.py", "import references.reference  # a metric that knows the references"),
    ("references/ladder.py", "import reports.metrics  # a reference that knows the metrics"),
])
def test_the_contract_fails_on_an_upward_or_sideways_import(tmp_path, module, line):
    tree = _copy_tree(tmp_path)
    path = tree / module
    path.write_text(path.read_text() + "\n" + line + "\n")
    out = _lint(tree)
    assert out.returncode != 0
    assert "0 kept, 1 broken" in out.stdout, out.stdout[-3000:] + out.stderr[-2000:]
