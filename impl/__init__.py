"""Own implementations of the thesis's algorithms, one module per concept.

Each algorithm module declares ``ALGORITHM`` (:class:`core.algorithm.Algorithm`);
the application's registry collects them.  Modules here import only the
bottom package :mod:`core` and third-party libraries: no module knows about
Mitsuba, the references, the metrics or the application.  They read the scene
model and return images and counters.

The numba kernels are compiled once and cached (``cache=True``).  Numba keys a
cached kernel on its own source file only, so a change in a kernel it calls
(say ``intersect.py`` under ``raycast.py``) would leave a stale machine-code
cache behind.  The cache therefore lives in ``.numba_cache/<hash of impl/**/*.py>``
(sub-packages such as ``impl/accel`` included)
at the repository root: any change to this package starts a fresh cache.  Set
``NUMBA_CACHE_DIR`` to override.
"""

import hashlib as _hashlib
import os as _os
import shutil as _shutil
from pathlib import Path as _Path


def _source_keyed_cache_dir() -> None:
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = _Path(__file__).resolve().parent
    digest = _hashlib.sha1()
    for src in sorted(here.rglob("*.py")):
        digest.update(src.relative_to(here).as_posix().encode() + b"\0" + src.read_bytes())
    root = here.parent / ".numba_cache"
    cache = root / digest.hexdigest()[:16]
    if root.is_dir():                       # caches of older sources are stale by construction
        for old in root.iterdir():
            if old != cache:
                _shutil.rmtree(old, ignore_errors=True)
    _os.environ["NUMBA_CACHE_DIR"] = str(cache)
    import numba

    numba.config.CACHE_DIR = str(cache)


_source_keyed_cache_dir()
