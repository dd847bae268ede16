"""Studies: measurements that are not one image against one reference.

Each module here is a *study set* (intersection hard cases, acceleration
structures, radiosity, sampling, shading and visibility): a table of
:class:`StudyInfo` entries (``STUDIES``), the titles of the tables it returns
(``TABLES``) and ``run_studies(config) -> {name: rows}``.  A suite manifest
chooses a set by its name in :data:`STUDY_SETS` (``study_set = "accel"``),
never by import path, and passes the set its TOML configuration, whose tables
are the studies' keyword arguments.

Studies call the algorithms, the references and the metrics through their
public functions; the few small numba kernels they carry measure one
question each (a ray–sphere form's silhouette, a shadow ray's answer) and
render no image.
"""

from __future__ import annotations

import importlib
import inspect
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from core.errors import SuiteError

__all__ = ["StudyInfo", "STUDY_SETS", "load_study_set", "read_config", "as_config",
           "table_titles", "run_registered"]

#: Study sets by the name a suite manifest gives (``study_set = NAME``).
STUDY_SETS = {
    "intersection": "gibench.studies.intersection",
    "accel": "gibench.studies.accel",
    "radiosity": "gibench.studies.radiosity",
    "sampling": "gibench.studies.sampling",
    "shading": "gibench.studies.shading",
}


def load_study_set(name: str):
    """The module of the study set ``name``; an unknown name raises :class:`SuiteError`."""
    if name not in STUDY_SETS:
        raise SuiteError(f"unknown study set {name!r} (valid: {', '.join(STUDY_SETS)})")
    return importlib.import_module(STUDY_SETS[name])


@dataclass(frozen=True)
class StudyInfo:
    name: str
    title: str
    description: str
    run: Callable[..., list[dict]]

    def __repr__(self) -> str:
        return f"StudyInfo({self.name!r}, {self.title!r})"


def read_config(path, default) -> dict:
    """A studies configuration from a TOML file (``default`` when ``path`` is None),
    with its own path under ``"_path"`` for error messages."""
    path = Path(path) if path is not None else default
    try:
        cfg = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SuiteError(f"{path}: studies configuration not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise SuiteError(f"{path}: {exc}") from None
    cfg["_path"] = str(path)
    return cfg


def as_config(config, default) -> dict:
    """A study set's configuration: ``config`` itself when it is a dict, else the TOML
    file it names (``default`` when it is None), read by :func:`read_config`."""
    if config is None or isinstance(config, (str, Path)):
        return read_config(config, default)
    return config


def table_titles(studies: dict) -> dict:
    """``{name: (title, description)}`` of the tables a set's :class:`StudyInfo` entries return."""
    return {name: (info.title, info.description) for name, info in studies.items()}


def run_registered(studies: dict, config: dict, *, only=None) -> dict[str, list[dict]]:
    """Run every study of ``studies`` (name → :class:`StudyInfo`) that ``config`` has a
    table for, without ``enabled = false``, restricted to ``only``; the table's keys
    are the study function's keyword arguments (an unknown key is an error naming it)."""
    where = config.get("_path", "the studies configuration")
    out: dict[str, list[dict]] = {}
    for name, info in studies.items():
        if name not in config or (only is not None and name not in only):
            continue
        params = dict(config[name])
        if not params.pop("enabled", True):
            continue
        valid = list(inspect.signature(info.run).parameters)
        unknown = sorted(set(params) - set(valid))
        if unknown:
            raise SuiteError(f"{where}: [{name}] has unknown key(s) {', '.join(unknown)} "
                             f"(valid: {', '.join(valid)}, enabled)")
        out[name] = info.run(**params)
    return out
