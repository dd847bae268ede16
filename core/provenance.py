"""Where a result came from: git commit, package versions, machine."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent

__all__ = ["REPO_ROOT", "git_commit", "versions", "machine", "utc_now"]


@functools.cache
def git_commit() -> str:
    """The checkout's HEAD (with ``+dirty`` for uncommitted changes), or 'unknown'."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=REPO_ROOT,
                              capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=REPO_ROOT, capture_output=True, text=True, timeout=10)
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@functools.cache
def versions() -> dict:
    out = {"python": platform.python_version()}
    for pkg in ("gibench", "numpy", "numba", "mitsuba", "drjit", "scikit-image", "flip-evaluator",
                "colour-science"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


@functools.cache
def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"host": platform.node(), "system": f"{platform.system()} {platform.release()}",
            "cpu": cpu, "cores": os.cpu_count()}


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")
