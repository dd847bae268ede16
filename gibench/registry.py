"""Algorithm registry: each own algorithm registers a short, stable name with a
parameter table (name, type, default, meaning), in the manner of Mitsuba's
plugin parameter tables.  The table feeds ``gibench algorithms``, the README
and the report; parameter strings from the CLI or a suite manifest are parsed
and checked against it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["Param", "Algorithm", "RenderResult", "register", "get", "algorithms", "ParamError"]


class ParamError(ValueError):
    """An unknown algorithm, unknown parameter or a value of the wrong type."""


@dataclass(frozen=True)
class Param:
    name: str
    type: type
    default: object
    doc: str
    choices: tuple | None = None

    def parse(self, value, *, algorithm: str):
        """Convert a CLI/manifest value (string or native) to this parameter's type."""
        try:
            if self.type is bool:
                if isinstance(value, str):
                    if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                        raise ValueError(value)
                    v = value.lower() in ("true", "1", "yes")
                else:
                    v = bool(value)
            else:
                v = self.type(value)
        except (TypeError, ValueError):
            raise ParamError(f"{algorithm}: parameter '{self.name}' expects {self.type.__name__}, "
                             f"got {value!r}") from None
        if self.choices is not None and v not in self.choices:
            raise ParamError(f"{algorithm}: parameter '{self.name}' must be one of "
                             f"{', '.join(map(str, self.choices))}; got {v!r}")
        return v


@dataclass
class RenderResult:
    """What an own algorithm returns.

    ``image`` and ``variance`` are float32 ``(H, W, 3)`` linear radiance and
    the per-pixel variance of the pixel mean (None where the estimator is
    deterministic); ``counters`` count the work done (rays by type, ...);
    ``aovs`` holds optional extra images (e.g. ``depth``); ``timings`` the
    wall-clock seconds of the render's phases (``setup_s``: flattening, ray
    configuration, allocation; ``trace_s``: the kernel), where measured.
    """

    image: np.ndarray
    variance: np.ndarray | None = None
    counters: dict = field(default_factory=dict)
    aovs: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)     # seconds: setup_s (fixed cost), trace_s, ...

    def __repr__(self) -> str:
        h, w = self.image.shape[:2]
        return f"RenderResult({w}x{h}, counters={self.counters})"


@dataclass(frozen=True)
class Algorithm:
    name: str
    summary: str
    section: str                     # thesis section(s) implemented
    params: tuple[Param, ...]
    render: Callable                 # render(scene, params: dict, *, seed: int) -> RenderResult
    transport: str = "direct"        # the light transport it computes: 'direct' or 'full'
    spp_param: str | None = "spp"    # which parameter the CLI's --spp sets

    def defaults(self) -> dict:
        return {p.name: p.default for p in self.params}

    def parse_params(self, values: dict | None = None) -> dict:
        """Defaults overridden by ``values``; unknown names raise :class:`ParamError` listing the valid ones."""
        table = {p.name: p for p in self.params}
        out = self.defaults()
        for key, value in (values or {}).items():
            if key not in table:
                raise ParamError(f"{self.name}: unknown parameter '{key}' "
                                 f"(valid: {', '.join(table)})")
            out[key] = table[key].parse(value, algorithm=self.name)
        return out

    def param_table(self) -> str:
        rows = [f"  {p.name:<14} {p.type.__name__:<6} {str(p.default):<10} {p.doc}"
                + (f" [{'|'.join(map(str, p.choices))}]" if p.choices else "") for p in self.params]
        return "\n".join(rows)

    def __repr__(self) -> str:
        return f"Algorithm('{self.name}', {self.section}, params={[p.name for p in self.params]})"


_REGISTRY: dict[str, Algorithm] = {}


def register(algo: Algorithm) -> Algorithm:
    if algo.name in _REGISTRY:
        raise ValueError(f"algorithm '{algo.name}' registered twice")
    _REGISTRY[algo.name] = algo
    return algo


def _load_impl():
    import impl  # noqa: F401  (importing the package registers every algorithm)


def get(name: str) -> Algorithm:
    _load_impl()
    if name not in _REGISTRY:
        raise ParamError(f"unknown algorithm '{name}' (registered: {', '.join(sorted(_REGISTRY))})")
    return _REGISTRY[name]


def algorithms() -> list[Algorithm]:
    _load_impl()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]
