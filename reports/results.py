"""The results store: one JSON record per line, appended as runs progress.

Each ``gibench run`` appends one record (:class:`core.records.Record`) per
(scene, algorithm) comparison to a JSON-lines file.  Appends are crash-safe: a record is written as one complete
line with a single ``write`` on a file opened for appending, then flushed and
``fsync``-ed, so an interrupted run loses at most the line being written and
never earlier data.  :meth:`ResultStore.load` skips a malformed line (such as
a truncated last line after a crash) with a one-line warning naming
``file:line``.

The file stays strict JSON: float ``inf``, ``-inf`` and ``nan`` are stored as
the strings ``"inf"``, ``"-inf"`` and ``"nan"`` and turned back into floats on
load (so a genuine string value spelled exactly like that also comes back as a
float).  NumPy scalars and arrays are stored as plain numbers and lists, paths
as POSIX strings.

Paths inside records are relative to the repository root (``root``); use
:meth:`ResultStore.relative` to make one and :meth:`ResultStore.resolve` to
turn one back into a path.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import warnings
from datetime import datetime, timezone
from pathlib import Path, PurePath

import numpy as np

from core.errors import StoreError
from core.records import Record

__all__ = ["REPO_ROOT", "ResultStore", "ResultStoreWarning", "new_run_id"]

REPO_ROOT = Path(__file__).resolve().parent.parent

_NONFINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


class ResultStoreWarning(UserWarning):
    """A results-file line that could not be read and was skipped."""


def new_run_id() -> str:
    """A new run id: UTC start time plus a random suffix, e.g. ``20261123T163000Z-1a2b3c``."""
    return datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + secrets.token_hex(3)


def _encode(obj):
    """Make ``obj`` strict-JSON serialisable (non-finite floats become strings)."""
    if isinstance(obj, dict):
        return {str(k): _encode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_encode(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else ("nan" if math.isnan(x) else "inf" if x > 0 else "-inf")
    if isinstance(obj, PurePath):
        return obj.as_posix()
    return obj


def _decode(obj):
    if isinstance(obj, dict):
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    if isinstance(obj, str) and obj in _NONFINITE:
        return _NONFINITE[obj]
    return obj


def _reject_constant(name):
    raise ValueError(f"non-standard JSON constant {name}")


class ResultStore:
    """A JSON-lines results file; ``root`` is the directory record paths are relative to."""

    def __init__(self, path, *, root=None):
        self.path = Path(path)
        self.root = Path(root) if root is not None else REPO_ROOT

    def __repr__(self) -> str:
        return f"ResultStore({str(self.path)!r}, root={str(self.root)!r})"

    def resolve(self, relpath) -> Path:
        """The path of ``relpath`` (relative to ``root``; absolute paths pass through)."""
        p = Path(relpath)
        return p if p.is_absolute() else self.root / p

    def relative(self, path) -> str:
        """``path`` as a POSIX path relative to ``root`` (absolute if outside it)."""
        p = Path(path).resolve()
        try:
            return p.relative_to(self.root.resolve()).as_posix()
        except ValueError:
            return p.as_posix()

    def append(self, record: Record) -> None:
        """Append ``record`` as one line, flushed and fsync-ed before returning."""
        if not isinstance(record, Record):
            raise TypeError(f"a record must be a core.records.Record, got {type(record).__name__}")
        data = (json.dumps(_encode(record.to_json()), allow_nan=False) + "\n").encode("utf-8")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            # A line left unterminated by a crash must not swallow this record.
            size = os.fstat(fd).st_size
            if size and os.pread(fd, 1, size - 1) != b"\n":
                data = b"\n" + data
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)

    def load(self, run_id: str | None = None) -> list[Record]:
        """All records in file order (only ``run_id``'s if given); malformed lines (bad
        JSON, or a record that does not fit the schema) are skipped with a warning."""
        if not self.path.is_file():
            return []
        records = []
        with open(self.path, "rb") as f:
            for lineno, raw in enumerate(f, start=1):
                if not raw.strip():
                    continue
                try:
                    data = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant)
                    rec = Record.from_json(_decode(data) if isinstance(data, dict) else data)
                except (ValueError, StoreError) as exc:  # JSONDecodeError, UnicodeDecodeError included
                    msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                    warnings.warn(f"{self.path}:{lineno}: skipping malformed record ({msg})",
                                  ResultStoreWarning, stacklevel=2)
                    continue
                if run_id is None or rec.run_id == run_id:
                    records.append(rec)
        return records

    def runs(self) -> list[str]:
        """Run ids in the order their first record appears in the file."""
        return list(dict.fromkeys(r.run_id for r in self.load() if r.run_id))

    def latest_run_id(self) -> str | None:
        """The run that started last (its first record is the latest), or None if there is none."""
        runs = self.runs()
        return runs[-1] if runs else None
