"""The application's algorithm registry.

Algorithms come from three places, collected on first use:

1. the built-ins: each module of :data:`BUILTIN_MODULES` (``impl/``) declares
   ``ALGORITHM`` (a :class:`core.algorithm.Algorithm`: name, thesis section,
   parameter table, render function);
2. installed Python packages, through the entry point group
   ``gibench.algorithms`` (:data:`ENTRY_POINT_GROUP`).  An entry point names an
   :class:`Algorithm`, a module declaring ``ALGORITHM``, or a callable
   returning an Algorithm or a list of them::

       # the plugin's pyproject.toml
       [project.entry-points."gibench.algorithms"]
       my_tracer = "my_package.tracer:ALGORITHM"

3. external executables, through the ``command`` adapter
   (:mod:`gibench.external`): the generic ``command`` algorithm, and the
   named renderers of the TOML files listed in the environment variable
   ``GIBENCH_RENDERERS`` (``os.pathsep``-separated; ``gibench --renderers
   FILE`` and a suite's ``[suite] renderers`` add to it, so worker processes
   see the same algorithms).

A plugin that cannot be loaded (import error, wrong type, a name already
taken) does not stop the others: asking for it by name raises
:class:`PluginError`, one line naming the entry point and its distribution,
and ``gibench algorithms`` lists it as broken.  The algorithm modules know
nothing of the registry: the dependency runs one way, from the application
down.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import types
from pathlib import Path

from core.algorithm import Algorithm, Param, RenderResult
from core.errors import GibenchError, ParamError

__all__ = ["Param", "Algorithm", "RenderResult", "register", "get", "algorithms", "ParamError",
           "PluginError", "BUILTIN_MODULES", "ENTRY_POINT_GROUP", "RENDERERS_ENV", "origin",
           "provenance", "broken", "add_renderer_file", "reset"]

#: The modules of the built-in algorithms, each declaring ``ALGORITHM``.
BUILTIN_MODULES = ("impl.raycast", "impl.whitted", "impl.distributed", "impl.radiosity",
                   "impl.zbuffer", "impl.depth_sort", "impl.path")

#: The entry point group external Python packages register algorithms under.
ENTRY_POINT_GROUP = "gibench.algorithms"

#: Environment variable listing renderer TOML files (``os.pathsep``-separated).
RENDERERS_ENV = "GIBENCH_RENDERERS"


class PluginError(GibenchError, RuntimeError):
    """An algorithm plugin (entry point or renderer file) that cannot be loaded."""


_REGISTRY: dict[str, Algorithm] = {}
_ORIGIN: dict[str, dict] = {}         # name -> where it came from (None-free dict)
_BROKEN: dict[str, str] = {}          # entry point / renderer name -> one-line cause
_FILES: set[str] = set()              # renderer files already read
_loaded = False


def register(algo: Algorithm, *, origin: dict | None = None) -> Algorithm:
    """Add ``algo`` under its name; a second algorithm of the same name is refused."""
    if not isinstance(algo, Algorithm):
        raise TypeError(f"register() takes an Algorithm, got {type(algo).__name__}")
    if algo.name in _REGISTRY and _REGISTRY[algo.name] is not algo:
        raise ParamError(f"algorithm '{algo.name}' registered twice "
                         f"({_describe(_ORIGIN.get(algo.name))} and {_describe(origin)})")
    _REGISTRY[algo.name] = algo
    _ORIGIN[algo.name] = dict(origin or {"source": "builtin"})
    return algo


def _describe(origin: dict | None) -> str:
    o = origin or {"source": "builtin"}
    if o["source"] == "entry point":
        return f"entry point '{o['entry_point']}' of {o.get('dist') or '?'} {o.get('dist_version') or ''}".strip()
    if o["source"] == "renderer file":
        return f"renderer file {o['file']}"
    return o["source"]


def _algorithms_of(obj, where: str) -> list[Algorithm]:
    """What an entry point's object gives: an Algorithm, a module with ALGORITHM,
    or a callable returning an Algorithm or a list of them."""
    if isinstance(obj, types.ModuleType):
        if not hasattr(obj, "ALGORITHM"):
            raise PluginError(f"{where}: module {obj.__name__} declares no ALGORITHM")
        obj = obj.ALGORITHM
    if callable(obj) and not isinstance(obj, Algorithm):
        obj = obj()
    items = obj if isinstance(obj, (list, tuple)) else [obj]
    for a in items:
        if not isinstance(a, Algorithm):
            raise PluginError(f"{where}: gives a {type(a).__name__}, not a "
                              "core.algorithm.Algorithm")
    return list(items)


def _entry_points():
    """The installed entry points of :data:`ENTRY_POINT_GROUP` (tests patch this)."""
    return importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)


def _load_entry_points() -> None:
    for ep in _entry_points():
        dist = getattr(ep, "dist", None)
        dname = dist.metadata["Name"] if dist is not None else None
        dver = dist.version if dist is not None else None
        where = (f"plugin '{ep.name}' ({ep.value}"
                 + (f", from {dname} {dver}" if dname else "") + f") in {ENTRY_POINT_GROUP}")
        origin = {"source": "entry point", "entry_point": ep.name, "target": ep.value,
                  "dist": dname, "dist_version": dver}
        try:
            algos = _algorithms_of(ep.load(), where)
            for a in algos:
                if a.name in _REGISTRY:
                    raise PluginError(f"{where}: algorithm name '{a.name}' is taken by "
                                      f"{_describe(_ORIGIN[a.name])}")
            for a in algos:
                register(a, origin=origin)
        except PluginError as exc:
            _BROKEN[ep.name] = str(exc)
        except Exception as exc:          # a broken third-party import: name it, keep the rest
            first = str(exc).splitlines()[0] if str(exc) else ""
            _BROKEN[ep.name] = f"{where} failed to load: {type(exc).__name__}: {first}"


def add_renderer_file(path) -> list[str]:
    """Register the named command renderers of the TOML file ``path``
    (see :mod:`gibench.external`) and add it to :data:`RENDERERS_ENV`, so
    worker processes register them too.  Returns the names registered."""
    from .external import load_renderer_file

    path = Path(path).resolve()
    key = str(path)
    if key in _FILES:
        return []
    _load()
    names = []
    for algo, origin in load_renderer_file(path):
        if algo.name in _REGISTRY:
            raise PluginError(f"{path}: renderer name '{algo.name}' is taken by "
                              f"{_describe(_ORIGIN[algo.name])}")
        register(algo, origin=origin)
        names.append(algo.name)
    _FILES.add(key)
    listed = [p for p in os.environ.get(RENDERERS_ENV, "").split(os.pathsep) if p]
    if key not in listed:
        os.environ[RENDERERS_ENV] = os.pathsep.join(listed + [key])
    return names


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True                    # first: add_renderer_file() calls _load() again
    try:
        for name in BUILTIN_MODULES:
            register(importlib.import_module(name).ALGORITHM)
        from .external import COMMAND

        register(COMMAND, origin={"source": "command adapter"})
        _load_entry_points()
        for p in os.environ.get(RENDERERS_ENV, "").split(os.pathsep):
            if p:
                add_renderer_file(p)
    except BaseException:
        reset()                       # a half-loaded registry would hide the cause next time
        raise


def reset() -> None:
    """Forget every registered algorithm (the next look-up loads them again)."""
    global _loaded
    _REGISTRY.clear()
    _ORIGIN.clear()
    _BROKEN.clear()
    _FILES.clear()
    _loaded = False


def get(name: str) -> Algorithm:
    """The algorithm registered as ``name``; an unknown name raises :class:`ParamError`,
    a plugin that failed to load :class:`PluginError`."""
    _load()
    if name not in _REGISTRY:
        if name in _BROKEN:
            raise PluginError(_BROKEN[name])
        extra = f"; broken plugins: {', '.join(sorted(_BROKEN))}" if _BROKEN else ""
        raise ParamError(f"unknown algorithm '{name}' (registered: {', '.join(sorted(_REGISTRY))}"
                         f"{extra})")
    return _REGISTRY[name]


def algorithms() -> list[Algorithm]:
    """Every registered algorithm, sorted by name."""
    _load()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def broken() -> dict[str, str]:
    """Plugins that failed to load: ``{entry point name: one-line cause}``."""
    _load()
    return dict(_BROKEN)


def origin(name: str) -> dict:
    """Where algorithm ``name`` comes from: ``{"source": "builtin" | "entry point" |
    "command adapter" | "renderer file", ...}`` with the distribution and its version
    for an entry point, the file for a renderer file."""
    get(name)
    return dict(_ORIGIN[name])


def provenance(name: str, params: dict | None = None, *, defines: dict | None = None) -> dict | None:
    """What a result record keeps about an algorithm that is not built in (None for
    a built-in): its :func:`origin`, and for a command renderer the executable's
    version string (``version_cmd``'s output).  A command renderer with scene
    ``defines`` (``-D``) is refused: the executable reads the file as written."""
    o = origin(name)
    if o["source"] == "builtin":
        return None
    if o["source"] in ("command adapter", "renderer file"):
        if defines:
            from core.errors import UsageError

            raise UsageError(f"{name}: -D {', '.join(defines)} cannot reach an external "
                             "renderer (it reads the scene file as written)")
        from .external import renderer_version

        o["version"] = renderer_version(get(name), params or {})
    return o
