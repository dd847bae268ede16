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
at the repository root: any change to this package starts a fresh cache, and the caches
of other sources are removed, except those a running process still uses (each process
holds a shared lock on its cache while it runs: a long run started before an edit keeps
its cache).  Set ``NUMBA_CACHE_DIR`` to override.

A cache file damaged on disk (truncated, bytes flipped) must not crash the
process: numba unpickles machine code from it, and garbage there can end in a
segmentation fault.  Every index and data file numba writes therefore carries
a sha256 of its payload (:func:`_checksummed_cache`); a file whose checksum
does not match is reported on stderr in one line
(``gibench: numba cache: ... corrupt ...; recompiling``), removed, and the
kernel is compiled afresh and cached again.
"""

import hashlib as _hashlib
import os as _os
import shutil as _shutil
from pathlib import Path as _Path


#: A file in each kernel cache that every process using the cache holds a shared
#: ``flock`` on for as long as it runs (the operating system releases the lock when the
#: process ends, however it ends).
_IN_USE = ".in-use"
_held = []                                  # the open lock file: kept for the process's life


def _hold(cache: _Path) -> None:
    """Take a shared lock on ``cache``'s :data:`_IN_USE` file for this process's life
    (nothing where ``fcntl`` is missing or the folder cannot be written)."""
    try:
        import fcntl

        cache.mkdir(parents=True, exist_ok=True)
        f = open(cache / _IN_USE, "a+b")    # noqa: SIM115 - held open on purpose
        fcntl.flock(f, fcntl.LOCK_SH)
    except (ImportError, OSError):
        return
    _held.append(f)


def _in_use(cache: _Path) -> bool:
    """Whether some running process holds ``cache``'s lock (:func:`_hold`)."""
    try:
        import fcntl

        with open(cache / _IN_USE, "rb") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(f, fcntl.LOCK_UN)
    except (ImportError, OSError):          # no lock file: a cache no process holds
        return False
    return False


def remove_stale_caches(root: _Path, keep: _Path) -> list[_Path]:
    """Remove the kernel caches under ``root`` other than ``keep`` (compiled from other
    sources, so stale) that no running process holds (:func:`_in_use`): a run started
    before ``impl/`` was edited keeps compiling into its own cache.  Returns those removed."""
    removed = []
    if root.is_dir():
        for old in root.iterdir():
            if old != keep and old.is_dir() and not _in_use(old):
                _shutil.rmtree(old, ignore_errors=True)
                removed.append(old)
    return removed


def _source_keyed_cache_dir() -> None:
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = _Path(__file__).resolve().parent
    digest = _hashlib.sha1()
    for src in sorted(here.rglob("*.py")):
        digest.update(src.relative_to(here).as_posix().encode() + b"\0" + src.read_bytes())
    root = here.parent / ".numba_cache"
    cache = root / digest.hexdigest()[:16]
    _hold(cache)
    remove_stale_caches(root, cache)
    _os.environ["NUMBA_CACHE_DIR"] = str(cache)
    import numba

    numba.config.CACHE_DIR = str(cache)


_MAGIC = b"GIBENCH-NUMBA-SHA256\0"


def _seal(payload: bytes) -> bytes:
    return _MAGIC + _hashlib.sha256(payload).digest() + payload


def _unseal(blob: bytes, path) -> bytes:
    """The payload of a sealed cache file; ``OSError`` (numba's "cache miss") if the
    file is not sealed or its checksum does not match."""
    head = len(_MAGIC) + 32
    if (len(blob) < head or not blob.startswith(_MAGIC)
            or _hashlib.sha256(blob[head:]).digest() != blob[len(_MAGIC):head]):
        import sys

        print(f"gibench: numba cache: {path} is corrupt (checksum mismatch); recompiling",
              file=sys.stderr, flush=True)
        try:
            _os.unlink(path)
        except OSError:
            pass
        raise OSError(f"corrupt numba cache file {path}")
    return blob[head:]


def _checksummed_cache() -> None:
    """Seal numba's cache files with a sha256 and check it before unpickling.

    Wraps ``numba.core.caching.IndexDataCacheFile`` (numba >= 0.60): ``_dump`` (the
    pickled payload of both the index and the data files) is sealed; ``_load_data``
    and ``_load_index`` check the seal first.  A bad data file raises ``OSError``,
    which numba's ``load`` treats as a miss; a bad index reads as empty, so numba
    recompiles and rewrites it."""
    import pickle

    from numba.core import caching

    cls = caching.IndexDataCacheFile
    if getattr(cls, "_gibench_sealed", False):
        return
    dump = cls._dump

    def _dump(self, obj):
        return _seal(dump(self, obj))

    def _load_data(self, name):
        path = self._data_path(name)
        with open(path, "rb") as f:
            blob = f.read()
        return pickle.loads(_unseal(blob, path))

    def _load_index(self):
        try:
            with open(self._index_path, "rb") as f:
                version = pickle.load(f)
                blob = f.read()
        except FileNotFoundError:
            return {}
        except Exception:                         # noqa: BLE001 - a damaged index is a miss
            blob, version = b"", self._version
        if version != self._version:
            return {}
        try:
            stamp, overloads = pickle.loads(_unseal(blob, self._index_path))
        except Exception:                         # noqa: BLE001 - reported by _unseal
            return {}
        return overloads if stamp == self._source_stamp else {}

    cls._dump, cls._load_data, cls._load_index = _dump, _load_data, _load_index
    cls._gibench_sealed = True


_source_keyed_cache_dir()
_checksummed_cache()
