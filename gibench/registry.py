"""The application's algorithm registry.

Each own algorithm module in ``impl/`` declares ``ALGORITHM`` (a
:class:`core.algorithm.Algorithm`: name, thesis section, parameter table,
render function); this registry collects them by name.  The algorithm
modules know nothing of the registry: the dependency runs one way, from the
application down.
"""

from __future__ import annotations

import importlib

from core.algorithm import Algorithm, Param, RenderResult
from core.errors import ParamError

__all__ = ["Param", "Algorithm", "RenderResult", "register", "get", "algorithms", "ParamError",
           "BUILTIN_MODULES"]

#: The modules of the built-in algorithms, each declaring ``ALGORITHM``.
BUILTIN_MODULES = ("impl.raycast", "impl.whitted", "impl.distributed", "impl.radiosity",
                   "impl.zbuffer", "impl.depth_sort", "impl.path")

_REGISTRY: dict[str, Algorithm] = {}
_loaded = False


def register(algo: Algorithm) -> Algorithm:
    """Add ``algo`` under its name; a second algorithm of the same name is refused."""
    if not isinstance(algo, Algorithm):
        raise TypeError(f"register() takes an Algorithm, got {type(algo).__name__}")
    if algo.name in _REGISTRY and _REGISTRY[algo.name] is not algo:
        raise ParamError(f"algorithm '{algo.name}' registered twice")
    _REGISTRY[algo.name] = algo
    return algo


def _load() -> None:
    global _loaded
    if _loaded:
        return
    for name in BUILTIN_MODULES:
        register(importlib.import_module(name).ALGORITHM)
    _loaded = True


def get(name: str) -> Algorithm:
    """The algorithm registered as ``name``; an unknown name raises :class:`ParamError`."""
    _load()
    if name not in _REGISTRY:
        raise ParamError(f"unknown algorithm '{name}' (registered: {', '.join(sorted(_REGISTRY))})")
    return _REGISTRY[name]


def algorithms() -> list[Algorithm]:
    """Every registered algorithm, sorted by name."""
    _load()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]
