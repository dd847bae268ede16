"""What an own algorithm is to the harness: its parameter table, its render
function and what it returns.

An algorithm module in ``impl/`` declares ``ALGORITHM = Algorithm(...)`` with a
short, stable name and a parameter table (name, type, default, meaning), in the
manner of Mitsuba's plugin parameter tables; the application's registry
(:mod:`gibench.registry`) collects them.  The table feeds ``gibench
algorithms``, the README and the report; parameter strings from the command
line or a suite manifest are parsed and checked against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import ParamError, UnsupportedError
from .scene import FEATURES, scene_features

__all__ = ["Param", "Algorithm", "RenderResult", "ParamError"]


@dataclass(frozen=True)
class Param:
    name: str
    type: type
    default: object
    doc: str
    choices: tuple | None = None
    #: Range of valid values: ``(test, meaning)``, e.g. ``(lambda v: v >= 0, ">= 0")``.
    valid: tuple | None = None

    def parse(self, value, *, algorithm: str):
        """Convert a CLI/manifest value (string or native) to this parameter's type;
        a float must be finite, and the value must pass :attr:`valid`."""
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
                             f"got {str(value)[:60]!r}") from None
        if self.type is float and not math.isfinite(v):
            raise ParamError(f"{algorithm}: parameter '{self.name}' must be a finite number, "
                             f"got {str(value)[:60]!r}")
        if self.valid is not None and not self.valid[0](v):
            raise ParamError(f"{algorithm}: parameter '{self.name}' must be {self.valid[1]}, "
                             f"got {str(v)[:60]}")
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
    #: Scene features (:data:`core.scene.FEATURES`) the algorithm models; a scene
    #: with any other one is refused by ``render`` before the algorithm runs.
    models: frozenset = frozenset()
    #: Parameter overrides that run kernels of their own (numba compiles per argument
    #: type and per call graph, so e.g. eye-ray packets or a per-pixel sample count
    #: compile apart from the default path): ``gibench warmup`` renders each once per
    #: precision it warms, beside the suites' cases.
    kernel_variants: tuple = ()

    def __post_init__(self):
        unknown = set(self.models) - set(FEATURES)
        if unknown:
            raise ValueError(f"Algorithm '{self.name}': unknown features {sorted(unknown)} "
                             f"(known: {', '.join(FEATURES)})")
        inner = self.render

        def render(scene, params, *args, **kwargs):
            self.check_scene(scene)
            return inner(scene, params, *args, **kwargs)

        render.__wrapped__ = inner
        render.__doc__ = inner.__doc__
        object.__setattr__(self, "render", render)

    def check_scene(self, scene) -> None:
        """Raise :class:`UnsupportedError` (one line) naming the first feature of
        ``scene`` (:func:`core.scene.scene_features`) this algorithm does not model."""
        for feature, where in scene_features(scene).items():
            if feature not in self.models:
                raise UnsupportedError(f"{self.name}: {where} uses '{feature}', which {self.name} does "
                                       "not model")

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
