"""The result record: what one case of a run produced, with a schema and a version.

Every run appends records to the results store (one JSON object per line,
:mod:`reports.results`) and to the history database; the CI gate, the
history, the report, the dashboard, the sweeps and the command line read them
back.  They all use this one type, so a field has one name, one type and one
meaning everywhere.

Three kinds share the type:

``case``
    an own algorithm's render of a scene against Mitsuba's reference: the
    image and variance files, counters, metrics, timing and checks;
``ladder``
    one rung of Mitsuba's spp ladder, measured in the same run (its time and
    error against the same reference; ``ladder_spp``, ``mitsuba``);
``study``
    one table of a study (``study``, ``title``, ``description``, ``rows``,
    ``pivot``, and figures as ``images``).

A case rendered by an algorithm that is not built in (a plugin package or a
command renderer) records where it came from in ``external``.

Nested values keep their producers' documented keys: ``metrics`` is
:func:`reports.metrics.compare`'s dictionary, ``time`` the timing of
:func:`gibench.runner.render_timed` (``own_median_s``, ``own_times_s``,
``warmup_s``, ``compile_s``, ``repeats``, and with Mitsuba timing
``mitsuba_median_s``, ``mitsuba_spp``, ``ratio``), ``reference`` the store
entry (``key``, ``dir``, ``image``, ``variance``, ``spp``, ``variant``,
``integrator``), ``checks`` a list of ``{name, expected, passed, detail}``.

Versions: records written before the schema had a version are version 1 and
read unchanged (their keys are this type's fields); a record of a newer
version than :data:`RECORD_VERSION` is refused, naming both versions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from .errors import StoreError

__all__ = ["Record", "RECORD_VERSION", "KINDS"]

#: The schema version written by this code.
RECORD_VERSION = 2
KINDS = ("case", "ladder", "study")


@dataclass
class Record:
    """One result record (see the module docstring for the kinds and nested keys)."""

    kind: str = "case"
    run_id: str = ""
    suite: str = ""
    scene: str = ""                       # scene id (suite-relative path without suffix)
    algorithm: str = ""
    label: str = ""
    scene_file: str | None = None         # repository-relative path of the scene file
    params: dict = field(default_factory=dict)
    defines: dict = field(default_factory=dict)
    seed: int = 0
    transport: str | None = None
    expect: str | None = None
    model_error: bool = False
    error: str | None = None              # "<ExceptionKind>: cause" when the case failed
    versions: dict = field(default_factory=dict)
    commit: str = ""
    machine: dict = field(default_factory=dict)
    created: str = ""
    reference: dict | None = None
    image: str | None = None              # repository-relative EXR paths
    variance: str | None = None
    counters: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    time: dict = field(default_factory=dict)
    checks: list = field(default_factory=list)
    external: dict | None = None          # an algorithm not built in: its origin and version
    ladder_spp: int | None = None         # kind == "ladder"
    mitsuba: str | None = None
    study: str | None = None              # kind == "study"
    title: str | None = None
    description: str | None = None
    rows: list = field(default_factory=list)
    pivot: dict = field(default_factory=dict)
    images: list = field(default_factory=list)    # figures of a study: [{"title", "src"}]
    version: int = RECORD_VERSION

    # -------------------------------------------------------------- queries

    @property
    def ok(self) -> bool:
        """No error."""
        return not self.error

    @property
    def failed_checks(self) -> list[dict]:
        return [c for c in self.checks if not c.get("passed")]

    def metric(self, name: str):
        """A metric or a timing figure by name (None when absent)."""
        if name in self.metrics:
            return self.metrics[name]
        return self.time.get(name)

    # ---------------------------------------------------------------- JSON

    def to_json(self) -> dict:
        """The record as a JSON-ready dict (fields left at their empty default are omitted)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ("kind", "version") or v != _default(f):
                out[f.name] = v
        return out

    @classmethod
    def from_json(cls, data: dict, *, where: str = "record") -> "Record":
        """The record of a dict read from JSON; a wrong type, an unknown field or a
        newer version raises :class:`core.errors.StoreError` naming ``where``."""
        if not isinstance(data, dict):
            raise StoreError(f"{where}: a record must be a JSON object, got {type(data).__name__}")
        version = data.get("version", 1)
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise StoreError(f"{where}: record version must be a positive integer, got {version!r}")
        if version > RECORD_VERSION:
            raise StoreError(f"{where}: record version {version} is newer than this gibench "
                             f"reads ({RECORD_VERSION})")
        known = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise StoreError(f"{where}: unknown record field(s) {', '.join(unknown)}")
        kw = {}
        for name, value in data.items():
            _check_type(known[name], value, where)
            kw[name] = value
        rec = cls(**kw)
        if rec.kind not in KINDS:
            raise StoreError(f"{where}: record kind must be one of {', '.join(KINDS)}, got {rec.kind!r}")
        rec.version = RECORD_VERSION
        return rec


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory()  # type: ignore[misc]


_TYPES = {"str": str, "int": int, "bool": bool, "dict": dict, "list": list}


def _check_type(f: dataclasses.Field, value, where: str) -> None:
    spec = str(f.type)
    if value is None and "None" in spec:
        return
    allowed = tuple(t for name, t in _TYPES.items() if name in spec.replace("None", "").split(" | "))
    ok = isinstance(value, allowed) and not (isinstance(value, bool) and bool not in allowed)
    if not ok:
        raise StoreError(f"{where}: field '{f.name}' must be {spec}, got {type(value).__name__}")
