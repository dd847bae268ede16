"""External renderers as algorithms: the ``command`` adapter.

Any executable that renders a Mitsuba 3 XML scene file to an EXR can be
validated like a built-in algorithm.  The adapter runs it from an argument
template (no shell: the template is split once with :func:`shlex.split`,
then each argument has its placeholders replaced), reads the EXR it wrote,
times the process and records its version string.

Placeholders (``{name}``; ``{{`` and ``}}`` are literal braces):

==============  ============================================================
``{scene}``     absolute path of the scene file (the scene model's ``path``)
``{out}``       EXR the renderer must write: float RGB, the film's size
``{variance}``  optional EXR of the per-pixel variance of the pixel mean
                (when the template names it, the file must be written; it
                enables the Z-test)
``{counters}``  optional JSON file ``{"name": number, ...}`` of work counters
``{spp}``       samples per pixel; ``{seed}`` the seed; ``{width}``,
                ``{height}`` the film size; ``{python}`` this interpreter
``{<param>}``   any parameter a named renderer declares
==============  ============================================================

Two ways to use it:

* the generic algorithm ``command`` with parameters ``cmd`` (the template),
  ``version_cmd`` (a command printing the version), ``spp`` and ``timeout``::

      gibench render scene.xml -a command --set "cmd=my_renderer {scene} -o {out} -s {spp}" ...

* named renderers declared in a TOML file (``gibench --renderers FILE``, the
  ``GIBENCH_RENDERERS`` environment variable, or a suite's ``[suite]
  renderers = "file.toml"``), each becoming an algorithm of its own name::

      [renderer.mitsuba-path]
      summary = "Mitsuba 3 path tracer driven as an external executable"
      cmd = "{python} mitsuba_cli.py {scene} {out} --variance {variance} --spp {spp} --seed {seed}"
      version_cmd = "{python} mitsuba_cli.py --version"
      transport = "full"            # the reference it is compared with by default
      spp = 16                      # default spp
      timeout = 600                 # seconds
      [renderer.mitsuba-path.params]
      max_depth = -1                # extra parameters: name = default (its type)

  Commands run in the TOML file's directory, so relative paths in ``cmd``
  are relative to it.

Errors are one line (:class:`ExternalRendererError`): the executable not
found, a timeout, a non-zero exit with the tail of its stderr, a missing
output, an unreadable EXR, an image of the wrong size, NaN/Inf values.

Limits: the renderer sees the scene file only, so ``-D name=value``
overrides of the scene's ``<default>`` values do not reach it (gibench's
reference does apply them): a run with ``-D`` refuses command renderers.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.algorithm import Algorithm, Param, RenderResult
from core.errors import GibenchError, ImageError, ParamError
from core.imageio import check_finite, read_exr

__all__ = ["COMMAND", "CommandSpec", "ExternalRendererError", "command_algorithm",
           "load_renderer_file", "renderer_version", "run_command", "expand"]

STDERR_TAIL = 3          # lines of stderr quoted in an error
TRANSPORTS = ("direct", "full", "whitted")

_PLACEHOLDER = re.compile(r"\{\{|\}\}|\{([A-Za-z_][A-Za-z0-9_]*)\}")


class ExternalRendererError(GibenchError, RuntimeError):
    """An external renderer that failed: not found, timed out, non-zero exit, bad output."""


@dataclass(frozen=True)
class CommandSpec:
    """A command renderer: argument template, version command, working directory."""

    name: str
    cmd: tuple[str, ...]
    version_cmd: tuple[str, ...] = ()
    cwd: Path | None = None
    timeout: float = 600.0
    origin: dict = field(default_factory=dict)


def _split(template, where: str) -> tuple[str, ...]:
    if isinstance(template, (list, tuple)):
        if not all(isinstance(x, str) for x in template):
            raise ParamError(f"{where}: a command list must hold strings")
        return tuple(template)
    if not isinstance(template, str):
        raise ParamError(f"{where}: a command must be a string or a list of strings")
    try:
        return tuple(shlex.split(template))
    except ValueError as exc:
        raise ParamError(f"{where}: cannot split command {template!r}: {exc}") from None


def expand(argv, values: dict, *, where: str) -> list[str]:
    """Replace ``{name}`` in every argument with ``values[name]``; an unknown name
    raises :class:`ParamError` listing the known ones."""
    def one(m):
        tok = m.group(0)
        if tok in ("{{", "}}"):
            return tok[0]
        key = m.group(1)
        if key not in values:
            raise ParamError(f"{where}: unknown placeholder {{{key}}} in the command "
                             f"(known: {', '.join('{' + k + '}' for k in values)})")
        return str(values[key])

    return [_PLACEHOLDER.sub(one, a) for a in argv]


def _uses(argv, key: str) -> bool:
    return any(f"{{{key}}}" in a for a in argv)


def _tail(text: str) -> str:
    lines = [ln.strip() for ln in (text or "").strip().splitlines() if ln.strip()]
    return " | ".join(lines[-STDERR_TAIL:]) if lines else "(no stderr)"


def _run(argv: list[str], *, cwd, timeout: float, who: str) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL)
    except FileNotFoundError:
        raise ExternalRendererError(f"{who}: executable not found: {argv[0]!r}"
                                    + (f" (in {cwd})" if cwd else "")) from None
    except PermissionError:
        raise ExternalRendererError(f"{who}: not executable: {argv[0]!r}") from None
    except subprocess.TimeoutExpired:
        raise ExternalRendererError(f"{who}: {shlex.join(argv)[:200]} timed out after "
                                    f"{timeout:g} s") from None
    return proc, time.perf_counter() - t0


def run_command(spec: CommandSpec, scene, *, spp: int, seed: int, extra: dict | None = None) -> RenderResult:
    """Render ``scene`` (its file) with the command of ``spec`` and return the result.

    ``counters`` get ``process_s`` (the process's wall time, start to exit)
    and any counters the renderer wrote to ``{counters}``.
    """
    who = spec.name
    film = scene.camera.film
    with tempfile.TemporaryDirectory(prefix="gibench-ext-") as tmp:
        tmp = Path(tmp)
        values = {"scene": str(Path(scene.path).resolve()), "out": str(tmp / "out.exr"),
                  "variance": str(tmp / "variance.exr"), "counters": str(tmp / "counters.json"),
                  "spp": int(spp), "seed": int(seed), "width": film.width, "height": film.height,
                  "python": sys.executable, **(extra or {})}
        argv = expand(spec.cmd, values, where=who)
        proc, seconds = _run(argv, cwd=spec.cwd, timeout=spec.timeout, who=who)
        if proc.returncode != 0:
            raise ExternalRendererError(f"{who}: {Path(argv[0]).name} exited with status "
                                        f"{proc.returncode}: {_tail(proc.stderr)}")
        out = Path(values["out"])
        if not out.is_file():
            raise ExternalRendererError(f"{who}: {Path(argv[0]).name} exited 0 but wrote no "
                                        f"image to {{out}} ({shlex.join(argv)[:200]})")
        image = _read(out, who, "output", (film.height, film.width))
        variance = None
        if _uses(spec.cmd, "variance"):
            vpath = Path(values["variance"])
            if not vpath.is_file():
                raise ExternalRendererError(f"{who}: the command names {{variance}} but wrote no "
                                            "variance image")
            variance = _read(vpath, who, "variance", (film.height, film.width))
            if (variance < 0).any():
                raise ExternalRendererError(f"{who}: variance image has negative values")
        counters = {"process_s": seconds}
        if _uses(spec.cmd, "counters"):
            counters.update(_counters(Path(values["counters"]), who))
    return RenderResult(image=image, variance=variance, counters=counters)


def _read(path: Path, who: str, what: str, hw) -> np.ndarray:
    try:
        img = read_exr(path)
    except ImageError as exc:
        raise ExternalRendererError(f"{who}: cannot read its {what} EXR: {exc}") from None
    if img.shape[:2] != tuple(hw):
        raise ExternalRendererError(f"{who}: {what} image is {img.shape[1]}x{img.shape[0]}, the "
                                    f"scene's film is {hw[1]}x{hw[0]}")
    try:
        check_finite(img, name=f"{who} {what}")
    except ImageError as exc:
        raise ExternalRendererError(str(exc)) from None
    return img


def _counters(path: Path, who: str) -> dict:
    if not path.is_file():
        raise ExternalRendererError(f"{who}: the command names {{counters}} but wrote no counters file")
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ExternalRendererError(f"{who}: counters file is not JSON: {exc}") from None
    if not isinstance(data, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                             for v in data.values()):
        raise ExternalRendererError(f"{who}: counters file must be an object of numbers")
    return data


_VERSIONS: dict = {}


def _version(argv: tuple[str, ...], cwd, who: str) -> str | None:
    """First non-empty line of the version command's output (cached per command)."""
    if not argv:
        return None
    key = (argv, str(cwd))
    if key not in _VERSIONS:
        full = expand(argv, {"python": sys.executable}, where=f"{who} version_cmd")
        proc, _ = _run(full, cwd=cwd, timeout=60, who=f"{who} version_cmd")
        if proc.returncode != 0:
            raise ExternalRendererError(f"{who}: version command exited with status "
                                        f"{proc.returncode}: {_tail(proc.stderr)}")
        text = (proc.stdout.strip() or proc.stderr.strip()).splitlines()
        _VERSIONS[key] = text[0].strip() if text else ""
    return _VERSIONS[key]


# ------------------------------------------------------ the generic command ---

def _generic_spec(params: dict) -> CommandSpec:
    if not params.get("cmd"):
        raise ParamError("command: parameter 'cmd' is required (the renderer's argument "
                         "template, e.g. \"my_renderer {scene} -o {out} -s {spp}\")")
    cmd = _split(params["cmd"], "command: cmd")
    if not _uses(cmd, "out"):
        raise ParamError("command: cmd must name {out}, the EXR the renderer writes")
    return CommandSpec(name="command", cmd=cmd,
                       version_cmd=_split(params.get("version_cmd") or "", "command: version_cmd"),
                       timeout=float(params.get("timeout", 600.0)))


def _render_generic(scene, params: dict, *, seed: int = 0) -> RenderResult:
    return run_command(_generic_spec(params), scene, spp=params["spp"], seed=seed)


COMMAND = Algorithm(
    name="command",
    summary="any executable rendering the scene file to an EXR, from an argument template "
            "({scene} {out} {variance} {counters} {spp} {seed} {width} {height} {python})",
    section="external",
    params=(Param("cmd", str, "", "argument template (split like a shell line, run without one)"),
            Param("version_cmd", str, "", "command printing the renderer's version"),
            Param("spp", int, 16, "samples per pixel ({spp})"),
            Param("timeout", float, 600.0, "seconds before the process is killed")),
    render=_render_generic,
    transport="full",
)

_NAMED: dict[str, CommandSpec] = {}


def command_algorithm(name: str, cmd, *, version_cmd=None, transport: str = "full",
                      summary: str = "", spp: int = 16, timeout: float = 600.0,
                      params: dict | None = None, cwd=None, origin: dict | None = None) -> Algorithm:
    """A named command renderer as an :class:`Algorithm` (parameters ``spp``,
    ``timeout`` and the declared ``params``, each usable as a placeholder)."""
    where = f"renderer '{name}'"
    argv = _split(cmd, f"{where}: cmd")
    if not _uses(argv, "out"):
        raise ParamError(f"{where}: cmd must name {{out}}, the EXR the renderer writes")
    if transport not in TRANSPORTS:
        raise ParamError(f"{where}: transport must be one of {', '.join(TRANSPORTS)}, got {transport!r}")
    spec = CommandSpec(name=name, cmd=argv, version_cmd=_split(version_cmd or "", f"{where}: version_cmd"),
                       cwd=Path(cwd) if cwd else None, timeout=float(timeout), origin=dict(origin or {}))
    extra = dict(params or {})
    reserved = {"spp", "timeout", "scene", "out", "variance", "counters", "seed", "width", "height", "python"}
    for k, v in extra.items():
        if k in reserved:
            raise ParamError(f"{where}: parameter name '{k}' is reserved")
        if not isinstance(v, (bool, int, float, str)):
            raise ParamError(f"{where}: parameter '{k}' default must be a bool, number or string")
    table = (Param("spp", int, int(spp), "samples per pixel ({spp})"),
             Param("timeout", float, float(timeout), "seconds before the process is killed"),
             *(Param(k, type(v), v, f"renderer parameter ({{{k}}})") for k, v in extra.items()))

    def render(scene, p: dict, *, seed: int = 0) -> RenderResult:
        s = spec if p["timeout"] == spec.timeout else \
            CommandSpec(**{**spec.__dict__, "timeout": float(p["timeout"])})
        return run_command(s, scene, spp=p["spp"], seed=seed, extra={k: p[k] for k in extra})

    _NAMED[name] = spec
    return Algorithm(name=name, summary=summary or f"external renderer: {shlex.join(argv)}",
                     section="external", params=table, render=render, transport=transport)


def load_renderer_file(path) -> list[tuple[Algorithm, dict]]:
    """The ``[renderer.NAME]`` tables of a TOML file as ``(algorithm, origin)`` pairs;
    a malformed file raises :class:`ParamError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise ParamError(f"{path}: renderer file not found")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ParamError(f"{path}: malformed TOML: {exc}") from None
    tables = data.get("renderer")
    if not isinstance(tables, dict) or not tables:
        raise ParamError(f"{path}: no [renderer.NAME] tables")
    known = {"cmd", "version_cmd", "transport", "summary", "spp", "timeout", "params"}
    out = []
    for name, t in tables.items():
        where = f"{path}: [renderer.{name}]"
        if not isinstance(t, dict) or "cmd" not in t:
            raise ParamError(f"{where}: missing 'cmd'")
        unknown = set(t) - known
        if unknown:
            raise ParamError(f"{where}: unknown keys {', '.join(sorted(unknown))} "
                             f"(valid: {', '.join(sorted(known))})")
        origin = {"source": "renderer file", "file": str(path)}
        try:
            algo = command_algorithm(name, t["cmd"], version_cmd=t.get("version_cmd"),
                                     transport=t.get("transport", "full"), summary=t.get("summary", ""),
                                     spp=t.get("spp", 16), timeout=t.get("timeout", 600.0),
                                     params=t.get("params"), cwd=path.parent, origin=origin)
        except ParamError as exc:
            raise ParamError(f"{path}: {exc}") from None
        out.append((algo, origin))
    return out


def renderer_version(algo: Algorithm, params: dict) -> str | None:
    """The version string of a command renderer (None without a version command)."""
    if algo.name in _NAMED:
        spec = _NAMED[algo.name]
        return _version(spec.version_cmd, spec.cwd, algo.name)
    if algo is COMMAND:
        vc = params.get("version_cmd") or ""
        return _version(_split(vc, "command: version_cmd"), None, "command") if vc else None
    return None
