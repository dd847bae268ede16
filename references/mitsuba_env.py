"""Locate a working libLLVM for Dr.Jit and load Mitsuba 3 with a suitable variant.

Dr.Jit's LLVM backend aborts the whole process (SIGABRT) with libLLVM 14–16
and works with libLLVM 19, and it reads ``DRJIT_LIBLLVM_PATH`` when its LLVM
backend starts.  A candidate library is therefore *probed in a child process*
(a tiny Mitsuba render) before this process commits to it.

Public API
----------
find_libllvm()      path of the newest usable libLLVM (major >= 17) or None
probe_llvm(path)    True if Dr.Jit + Mitsuba render correctly with that library
load_mitsuba()      the ``mitsuba`` module with a variant set (idempotent)
spectral_variant()  context manager: Mitsuba in its spectral variant (``llvm_ad_spectral``
                    with a usable libLLVM, else ``scalar_spectral``), the previous
                    variant restored on exit
mitsuba_versions()  versions, variant and libLLVM path, for manifests/reports

The environment variable ``GIBENCH_MITSUBA_VARIANT`` overrides the variant
choice (e.g. ``scalar_rgb`` to skip LLVM entirely).
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from core.errors import ReferenceError_

__all__ = [
    "MIN_LLVM_MAJOR",
    "libllvm_candidates",
    "llvm_major_version",
    "find_libllvm",
    "probe_llvm",
    "load_mitsuba",
    "mitsuba_versions",
    "spectral_variant",
]

#: Oldest libLLVM major version Dr.Jit is known to work with here.
MIN_LLVM_MAJOR = 17

#: Directories searched for ``libLLVM*.so*`` (globs allowed), in this order.
LIB_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/llvm-*/lib",
)

PROBE_TIMEOUT_S = 120.0
FALLBACK_VARIANT = "scalar_rgb"
LLVM_VARIANT = "llvm_ad_rgb"
SPECTRAL_FALLBACK_VARIANT = "scalar_spectral"
SPECTRAL_LLVM_VARIANT = "llvm_ad_spectral"

_CACHE_FILE = Path(__file__).resolve().parent / "cache" / "libllvm_probe.json"

# Per-process state.
_probe_results: dict[str, bool] = {}
_state: dict = {"module": None, "variant": None, "libllvm": None, "searched": False}

# The child renders a 4x4 image with the path tracer: a bare Dr.Jit
# computation is not enough, libLLVM 15 passes that and aborts on a render.
_PROBE_CODE = r"""
import drjit as dr, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "path", "max_depth": 3},
    "sensor": {"type": "perspective",
               "film": {"type": "hdrfilm", "width": 4, "height": 4},
               "sampler": {"type": "independent", "sample_count": 2}},
    "shape": {"type": "sphere", "to_world": mi.ScalarTransform4f().translate([0, 0, 3])},
    "light": {"type": "constant"},
})
img = mi.render(scene)
dr.eval(img)
dr.sync_thread()
x = dr.arange(mi.Float, 16)
s = dr.sum(x * x)
dr.sync_thread()
print("GIBENCH_PROBE_OK", float(s[0] if hasattr(s, "__len__") else s))
"""


def llvm_major_version(path) -> int | None:
    """Major LLVM version encoded in a library path, or None if unknown.

    Understands ``libLLVM-19.so``, ``libLLVM-14.0.6.so.1``, ``libLLVM.so.19.1``
    and, for an unversioned ``libLLVM.so``, a ``llvm-<N>`` parent directory.
    """
    p = Path(path)
    m = re.fullmatch(r"libLLVM-(\d+)(?:\.\d+)*(?:git)?\.so(?:\.[\w.]+)?", p.name)
    if m is None:
        m = re.fullmatch(r"libLLVM\.so\.(\d+)(?:\.[\w.]+)?", p.name)
    if m is None:
        m = re.search(r"/llvm-(\d+)(?:/|$)", str(p.parent))
    return int(m.group(1)) if m else None


def libllvm_candidates() -> list[str]:
    """Candidate libLLVM paths, best first.

    ``$DRJIT_LIBLLVM_PATH`` (if set and the file exists) comes first whatever
    its version -- the probe decides.  Then every ``libLLVM*.so*`` file in
    :data:`LIB_DIRS` with major version >= :data:`MIN_LLVM_MAJOR`, newest
    first.  Paths naming the same file (symlinks) appear once.
    """
    out: list[str] = []
    seen: set[str] = set()

    def add(path: str) -> None:
        real = os.path.realpath(path)
        if real not in seen and os.path.isfile(real):
            seen.add(real)
            out.append(path)

    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        add(env)
    found: list[tuple[int, int, str]] = []
    order = 0
    for pattern in LIB_DIRS:
        for d in sorted(glob.glob(pattern)):
            for f in sorted(glob.glob(os.path.join(d, "libLLVM*.so*"))):
                major = llvm_major_version(f)
                if major is not None and major >= MIN_LLVM_MAJOR:
                    found.append((-major, order, f))
                    order += 1
    for _, _, f in sorted(found):
        add(f)
    return out


def _probe_cache_key(path: str) -> str:
    """Identity of (library file, Python, Dr.Jit install) for the disk cache."""
    st = os.stat(os.path.realpath(path))
    try:
        from importlib.metadata import version

        drjit_version = version("drjit")
        mitsuba_version = version("mitsuba")
    except Exception:  # pragma: no cover - metadata missing
        drjit_version = mitsuba_version = "?"
    ident = [os.path.realpath(path), st.st_size, st.st_mtime_ns, sys.executable,
             drjit_version, mitsuba_version]
    return hashlib.sha256(json.dumps(ident).encode()).hexdigest()[:32]


def _read_disk_cache() -> dict:
    try:
        return json.loads(_CACHE_FILE.read_text())
    except (OSError, ValueError):
        return {}


def _write_disk_cache(key: str, path: str, ok: bool) -> None:
    try:
        data = _read_disk_cache()
        data[key] = {"path": path, "ok": ok}
        _CACHE_FILE.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=_CACHE_FILE.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=1)
        os.replace(tmp, _CACHE_FILE)
    except OSError:
        pass  # the cache is an optimisation only


def probe_llvm(path, *, timeout: float = PROBE_TIMEOUT_S, use_cache: bool = True) -> bool:
    """Return True if Dr.Jit and Mitsuba work with the libLLVM at ``path``.

    Runs a tiny ``llvm_ad_rgb`` render in a child process (same Python,
    ``DRJIT_LIBLLVM_PATH=path``), because a bad libLLVM aborts the process
    that loads it.  A missing file, a crash, a non-zero exit or a timeout all
    give False.  Results are cached for this process and, with
    ``use_cache``, in ``references/cache/libllvm_probe.json`` (keyed by the
    file's real path, size and mtime and the Python/Dr.Jit/Mitsuba install).
    """
    path = str(path)
    if path in _probe_results:
        return _probe_results[path]
    if not os.path.isfile(path):
        _probe_results[path] = False
        return False
    key = _probe_cache_key(path)
    if use_cache:
        cached = _read_disk_cache().get(key)
        if isinstance(cached, dict) and isinstance(cached.get("ok"), bool):
            _probe_results[path] = cached["ok"]
            return cached["ok"]
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=path)
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE_CODE],
            env=env, capture_output=True, text=True, timeout=timeout,
            cwd=tempfile.gettempdir(),
        )
        ok = proc.returncode == 0 and "GIBENCH_PROBE_OK 1240.0" in proc.stdout
    except (subprocess.TimeoutExpired, OSError):
        ok = False
    _probe_results[path] = ok
    if use_cache:
        _write_disk_cache(key, path, ok)
    return ok


def find_libllvm() -> str | None:
    """Path of the first candidate libLLVM that passes :func:`probe_llvm`, or None."""
    for path in libllvm_candidates():
        if probe_llvm(path):
            return path
    return None


def _warn(message: str) -> None:
    print(f"gibench: warning: {message}", file=sys.stderr, flush=True)


def load_mitsuba(variant: str | None = None):
    """Return the ``mitsuba`` module with a variant set.

    Parameters
    ----------
    variant
        Variant to use.  Default: ``$GIBENCH_MITSUBA_VARIANT`` if set, else
        ``llvm_ad_rgb`` when a usable libLLVM >= 17 is found, else
        ``scalar_rgb`` (with a one-line warning on stderr).

    Notes
    -----
    ``DRJIT_LIBLLVM_PATH`` is set before Dr.Jit is imported.  Idempotent:
    later calls return the same module without probing again; a later call
    asking for a *different* variant switches Mitsuba's global variant.
    Raises :class:`core.errors.ReferenceError_` if an explicitly requested LLVM variant has no usable
    libLLVM, or if the variant is not compiled into this Mitsuba.
    """
    requested = variant or os.environ.get("GIBENCH_MITSUBA_VARIANT") or None
    if _state["module"] is not None and requested in (None, _state["variant"]):
        return _state["module"]

    libllvm = _state["libllvm"]
    needs_llvm = requested is None or requested.startswith("llvm_")
    if needs_llvm and not _state["searched"]:
        libllvm = find_libllvm()
        _state["libllvm"], _state["searched"] = libllvm, True
    if requested is None:
        if libllvm:
            chosen = LLVM_VARIANT
        else:
            chosen = FALLBACK_VARIANT
            _warn(f"no libLLVM >= {MIN_LLVM_MAJOR} found; install Debian's libllvm19; "
                  f"references fall back to {FALLBACK_VARIANT} (slow)")
    else:
        chosen = requested
        if needs_llvm and not libllvm:
            raise ReferenceError_(
                f"Mitsuba variant {chosen!r} requested but no usable libLLVM >= "
                f"{MIN_LLVM_MAJOR} was found (install Debian's libllvm19 or set "
                f"DRJIT_LIBLLVM_PATH)")
    if libllvm and needs_llvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm

    import drjit  # noqa: F401  (imported after DRJIT_LIBLLVM_PATH is set)
    import mitsuba as mi

    if chosen not in mi.variants():
        raise ReferenceError_(
            f"Mitsuba variant {chosen!r} is not available (this build has: "
            f"{', '.join(mi.variants())})")
    mi.set_variant(chosen)
    _state["module"], _state["variant"] = mi, chosen
    return mi


@contextlib.contextmanager
def spectral_variant():
    """Mitsuba switched to its spectral variant for the ``with`` block.

    ``llvm_ad_spectral`` when the default choice found a usable libLLVM (the
    same probe as :func:`load_mitsuba`), else ``scalar_spectral``; the
    variant that was set before is restored on exit.  Yields the module.
    """
    mi = load_mitsuba()
    previous = _state["variant"]
    chosen = SPECTRAL_LLVM_VARIANT if _state["libllvm"] and previous.startswith("llvm_") \
        else SPECTRAL_FALLBACK_VARIANT
    try:
        yield load_mitsuba(chosen)
    finally:
        load_mitsuba(previous)


def mitsuba_versions() -> dict:
    """Versions and configuration of the loaded Mitsuba (loads it if needed).

    Returns ``dict(mitsuba=..., drjit=..., variant=..., libllvm=path or None)``;
    ``libllvm`` is None for variants that do not use the LLVM backend.
    """
    mi = load_mitsuba()
    import drjit as dr

    variant = mi.variant()
    uses_llvm = variant.startswith("llvm_")
    return {
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "variant": variant,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH") if uses_llvm else None,
    }
