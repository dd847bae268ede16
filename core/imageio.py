"""HDR image input/output (OpenEXR) and image sanity checks.

Images in gibench are linear-radiance ``float32`` arrays of shape ``(H, W, 3)``
(linear sRGB primaries).  EXR I/O goes through the ``openexr`` package rather
than Mitsuba's writer, which can hang with one Dr.Jit thread.  Writes are
atomic (temporary file, then rename), so an interrupted run never leaves a
truncated image behind.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
from .errors import ImageError

__all__ = ["ImageError", "read_exr", "write_exr", "write_text", "check_finite", "as_rgb"]




def as_rgb(image, *, name: str = "image") -> np.ndarray:
    """Return ``image`` as a C-contiguous float32 ``(H, W, 3)`` array.

    A ``(H, W)`` or ``(H, W, 1)`` array is broadcast to three channels.
    Raises :class:`ImageError` naming ``name`` for any other shape.
    """
    a = np.asarray(image, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ImageError(f"{name}: expected shape (H, W, 3), got {a.shape}")
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a)


def check_finite(image, *, name: str = "image") -> None:
    """Raise :class:`ImageError` if ``image`` holds NaN or Inf values.

    The message names the image, the counts and the first offending pixel
    (x, y), so the cause can be found.
    """
    a = np.asarray(image)
    bad = ~np.isfinite(a)
    if bad.any():
        n_nan = int(np.isnan(a).sum())
        n_inf = int(np.isinf(a).sum())
        idx = np.argwhere(bad)[0]
        raise ImageError(
            f"{name}: {n_nan} NaN and {n_inf} Inf values "
            f"(first at pixel x={idx[1]}, y={idx[0]})"
        )


def _check_writable(path: Path) -> None:
    """Create the parent directory; refuse (one line) a path that is a directory or
    whose directory cannot be made or written."""
    if path.is_dir():
        raise ImageError(f"{path}: is a directory, not a file to write")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ImageError(f"{path}: cannot create its directory ({exc.strerror or exc})") from None
    if not os.access(path.parent, os.W_OK):
        raise ImageError(f"{path}: directory {path.parent} is not writable")


def write_exr(path, image, *, metadata: dict | None = None) -> Path:
    """Write a float32 RGB EXR (ZIP compression) atomically and return its path.

    ``metadata`` string values are stored as EXR header attributes.
    Non-finite values are written as they are (the EXR records what was
    computed); callers that must refuse them call :func:`check_finite` first.
    """
    path = Path(path)
    a = as_rgb(image, name=str(path))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (metadata or {}).items():
        header[str(key)] = str(value)
    _check_writable(path)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp.exr", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)       # mkstemp makes 0600; give the usual file mode
    try:
        with OpenEXR.File(header, {"RGB": a}) as f:
            f.write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def write_text(path, text: str) -> Path:
    """Write a text file (a report page, a baseline, JSON) atomically, fsync'd, mode 0644;
    return its path.  A crash leaves the old file or the new one, never a torn one."""
    path = Path(path)
    _check_writable(path)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


@contextlib.contextmanager
def _captured_output():
    """Collect what C libraries print on file descriptors 1 and 2 (OpenEXR reports a
    corrupt file there as well as by its exception); yields a list that receives the
    captured lines.  The caller decides what to show: one line, not a spill."""
    import io

    lines: list[str] = []
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    py_out = io.StringIO()               # what the binding prints through Python's sys.stdout
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            with contextlib.redirect_stdout(py_out), contextlib.redirect_stderr(py_out):
                yield lines
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace") + "\n" + py_out.getvalue()
            lines.extend(t.strip() for t in text.splitlines() if t.strip())


def exr_size(path) -> tuple[int, int]:
    """``(width, height)`` of an EXR from its header alone (no pixels read)."""
    path = Path(path)
    try:
        with _captured_output():
            with OpenEXR.File(str(path), header_only=True) as f:
                lo, hi = f.header()["dataWindow"]
    except Exception as exc:                              # noqa: BLE001
        raise ImageError(f"{path}: not a readable EXR file ({str(exc).splitlines()[0][:200]})") from None
    return int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)


def read_exr(path, *, allow_nonfinite: bool = True, max_pixels: int | None = None) -> np.ndarray:
    """Read an RGB EXR as a float32 ``(H, W, 3)`` array.

    Raises :class:`ImageError` naming the file if it is missing, is not a
    readable EXR (what OpenEXR prints about it is folded into the one-line
    message, not left on the terminal), has more than ``max_pixels`` pixels, or
    has no R, G, B channels; with ``allow_nonfinite=False`` also if it holds NaN
    or Inf.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: no such image file")
    if max_pixels is not None:
        w, h = exr_size(path)
        if w * h > max_pixels:
            raise ImageError(f"{path}: {w}x{h} pixels is more than the limit of {max_pixels}")
    printed: list[str] = []
    try:
        with _captured_output() as printed, OpenEXR.File(str(path)) as f:
            channels = f.channels()
            if "RGB" in channels:
                a = np.asarray(channels["RGB"].pixels, dtype=np.float32)
            elif all(c in channels for c in "RGB"):
                a = np.stack([np.asarray(channels[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
            elif "Y" in channels:
                a = np.asarray(channels["Y"].pixels, dtype=np.float32)
            else:
                raise ImageError(f"{path}: EXR has no RGB or Y channels (has {sorted(channels)})")
    except ImageError:
        raise
    except Exception as exc:  # OpenEXR raises bare RuntimeError/OSError
        why = (printed or str(exc).splitlines() or [type(exc).__name__])[0][:200]
        raise ImageError(f"{path}: not a readable EXR file ({why})") from None
    if printed:                 # OpenEXR reported damage but returned pixels: refuse them
        raise ImageError(f"{path}: not a readable EXR file ({printed[0][:200]})")
    a = as_rgb(a, name=str(path))
    if not allow_nonfinite:
        check_finite(a, name=str(path))
    return a
