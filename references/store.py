"""The reference store: one directory per entry, ``<store>/<first 16 hex of key>/``,
holding ``image.exr``, ``variance.exr`` and ``manifest.json``.

One reader and one writer for every kind of entry (static references of
:mod:`references.reference`, motion-blur references of
:mod:`references.motion_blur`) and every caller (``gibench compare`` given a
store directory included):

* :func:`write_entry` writes the two images and the manifest into a temporary
  directory beside the entry, records the sha256 of both images in the
  manifest (``image_sha256``, ``variance_sha256``) and renames the complete
  directory into place (:func:`install`: the old entry is removed only
  afterwards), so a killed process never leaves a torn entry;
* :func:`read_entry` uses an entry only if its manifest is readable, its key
  is the one asked for, both image hashes are recorded and match, the images
  are finite, of the manifest's size, and the variance is non-negative.
  Anything else raises :class:`EntryInvalid` with the reason: the caller
  re-renders or reports it, a stored entry is never used silently.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from core.imageio import ImageError, read_exr, write_exr

__all__ = ["IMAGE_FILE", "VARIANCE_FILE", "MANIFEST_FILE", "EntryInvalid", "sha256_file",
           "entry_directory", "is_entry", "read_entry", "write_entry", "install",
           "remove_stale_temporaries"]

IMAGE_FILE = "image.exr"
VARIANCE_FILE = "variance.exr"
MANIFEST_FILE = "manifest.json"


class EntryInvalid(Exception):
    """Why a store entry cannot be used (one line)."""


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def entry_directory(store, key: str) -> Path:
    return Path(store) / key[:16]


def is_entry(directory) -> bool:
    """Whether ``directory`` looks like a store entry (has a manifest)."""
    return (Path(directory) / MANIFEST_FILE).is_file()


def _first_line(exc: BaseException) -> str:
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__


def read_entry(directory, key: str | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(image, variance, manifest)`` of a checked entry (see the module docstring).

    ``key`` None accepts the key the manifest records (``gibench compare`` given a
    directory); the hashes are checked all the same.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise EntryInvalid("no stored entry")
    try:
        manifest = json.loads((directory / MANIFEST_FILE).read_text())
    except FileNotFoundError:
        raise EntryInvalid(f"{MANIFEST_FILE} missing") from None
    except (OSError, ValueError) as exc:
        raise EntryInvalid(f"{MANIFEST_FILE} unreadable ({_first_line(exc)})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("key"), str):
        raise EntryInvalid(f"{MANIFEST_FILE} records no key")
    if key is not None and manifest["key"] != key:
        raise EntryInvalid("stale entry (stored key differs)")
    arrays = {}
    for fname, field in ((IMAGE_FILE, "image_sha256"), (VARIANCE_FILE, "variance_sha256")):
        path = directory / fname
        if not path.is_file():
            raise EntryInvalid(f"{fname} missing")
        if not isinstance(manifest.get(field), str):
            raise EntryInvalid(f"{MANIFEST_FILE} records no {field}")
        if sha256_file(path) != manifest[field]:
            raise EntryInvalid(f"{fname} sha256 does not match the manifest (corrupt or changed)")
        try:
            arrays[fname] = read_exr(path, allow_nonfinite=False)
        except ImageError as exc:
            raise EntryInvalid(f"{fname} unusable: {exc}") from None
    image, variance = arrays[IMAGE_FILE], arrays[VARIANCE_FILE]
    shape = (manifest.get("height"), manifest.get("width"), 3)
    if image.shape != shape or variance.shape != shape:
        raise EntryInvalid(f"image shapes {image.shape}/{variance.shape} differ from manifest {shape}")
    if (variance < 0).any():
        raise EntryInvalid(f"{VARIANCE_FILE} holds negative values")
    return image, variance, manifest


def remove_stale_temporaries(store: Path, max_age_s: float = 86400.0) -> None:
    """Delete ``.tmp-*``/``.old-*`` directories left by killed runs (older than a day)."""
    now = time.time()
    for pattern in (".tmp-*", ".old-*"):
        for p in Path(store).glob(pattern):
            try:
                if p.is_dir() and now - p.stat().st_mtime > max_age_s:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass


def install(tmp: Path, final: Path) -> None:
    """Move a complete entry into place; the old entry is removed only afterwards."""
    trash = None
    if final.exists():
        trash = Path(tempfile.mkdtemp(prefix=f".old-{final.name}-", dir=final.parent))
        os.rename(final, trash / "entry")
    try:
        os.rename(tmp, final)
    except OSError:
        if trash is not None and not final.exists():
            os.rename(trash / "entry", final)  # put the previous entry back
        raise
    finally:
        if trash is not None:
            shutil.rmtree(trash, ignore_errors=True)


def write_entry(directory: Path, key: str, image: np.ndarray, variance: np.ndarray,
                manifest: dict, *, exr_metadata: dict | None = None) -> dict:
    """Write and install an entry atomically; returns the manifest as stored (with
    ``key``, ``width``, ``height`` and the two image hashes).  Raises ``OSError`` if
    the rename fails (e.g. another process installed the entry meanwhile)."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(directory.parent)
    manifest = {**manifest, "key": key, "width": int(image.shape[1]), "height": int(image.shape[0])}
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{directory.name}-", dir=directory.parent))
    tmp.chmod(0o755)                    # mkdtemp makes 0700; store entries are shared files
    try:
        write_exr(tmp / IMAGE_FILE, image, metadata=exr_metadata)
        write_exr(tmp / VARIANCE_FILE, variance, metadata=exr_metadata)
        manifest["image_sha256"] = sha256_file(tmp / IMAGE_FILE)
        manifest["variance_sha256"] = sha256_file(tmp / VARIANCE_FILE)
        (tmp / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
        install(tmp, directory)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return manifest
