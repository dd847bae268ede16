"""Mitsuba 3 ground-truth references: render, store, verify and reuse.

A reference renders *the same scene file* the renderers under test read, with
a small set of documented overrides applied at the XML level (everything else,
including ``<default>`` elements and ``$name`` substitutions, is kept and left
for Mitsuba to resolve):

* the ``<integrator>`` is replaced according to ``transport``:
  ``"full"`` -> ``path`` with ``max_depth`` taken from the file's own
  integrator if that is ``path`` and sets ``max_depth`` (else -1, unbounded),
  or from the ``max_depth`` argument when given (the own ``path`` tracer's
  matched depth; keyed only when given, so existing entries keep their keys);
  ``"direct"`` -> ``direct``; ``"whitted"`` -> the Python integrator
  ``whitted`` of :mod:`references.whitted_integrator` (delta chains, then
  direct light from every emitter) with ``max_depth`` =
  :data:`WHITTED_MAX_DEPTH` (the own ``whitted``'s default) and
  ``lobe_choice`` = :data:`WHITTED_LOBE_CHOICE`.  A ``hide_emitters`` flag on
  the file's integrator is carried over (it changes what the image should
  show);
* every top-level sensor's ``<sampler>`` is replaced by ``independent`` with
  the per-pass sample count and the seed;
* the film's ``<rfilter>`` is replaced by ``box`` (``rfilter="box"``, default;
  ``rfilter="scene"`` keeps the file's filter -- Mitsuba's default is a
  Gaussian), and ``pixel_format=rgb``, ``component_format=float32`` are forced.

Every override is recorded in the entry's ``manifest.json``.

The image is the mean of ``passes`` independent passes (distinct seeds) and
the stored variance is the per-pixel variance *of that mean*: the unbiased
sample variance over passes divided by ``passes`` (as Mitsuba's own render
tests keep a ``_var.exr``).

Entries live in ``references/store/<first 16 hex of key>/`` as ``image.exr``,
``variance.exr`` and ``manifest.json``, read and written by
:mod:`references.store` (hash-checked reads, atomic installs).  The key is a sha256 over the scene
bytes, the bytes of every file the scene references by ``filename``, the
``-D name=value`` overrides of its ``<default>`` values (when any), the
transport, spp, passes, seed, rfilter choice, variant family and
:data:`STORE_FORMAT` (for ``"whitted"`` also :data:`WHITTED_MAX_DEPTH` and
:data:`WHITTED_LOBE_CHOICE`; the sha256 of the integrator's source file is
recorded in the manifest, not keyed).  A stored entry is used only if its key
and file hashes match and its images are readable and finite; otherwise it is
re-rendered (with a one-line message on stderr) or, with
``render_missing=False``, :class:`ReferenceMissing` is raised.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from lxml import etree

from core.errors import ParamError, ReferenceError_, SceneError, UnsupportedError
from core.imageio import ImageError, as_rgb, check_finite
from core.loader import MAX_FILM_PIXELS, MAX_FILM_SIDE
from core.xmlscene import check_defines as _check_defines
from core.xmlscene import expanded, parse_file, resolve as resolve_xml, substitute

from .mitsuba_env import load_mitsuba, mitsuba_versions, spectral_variant
from .motion_blur import has_motion
from .store import EntryInvalid, read_entry, write_entry
from .store import sha256_file as _sha256_file
from .phong_reference import is_phong_transport, prepare_phong_xml

__all__ = [
    "STORE_FORMAT",
    "DEFAULT_STORE",
    "TRANSPORTS",
    "WHITTED_MAX_DEPTH",
    "WHITTED_LOBE_CHOICE",
    "Reference",
    "ReferenceMissing",
    "SceneError",
    "get_reference",
    "reference_key",
    "scene_dependencies",
    "prepare_scene_xml",
    "load_scene",
    "time_mitsuba",
    "prepare_timing",
    "render_depth",
]

#: Version of the store layout and render procedure; part of every key.
STORE_FORMAT = 1

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_STORE = Path(__file__).resolve().parent / "store"

TRANSPORTS = ("full", "direct", "whitted")

#: ``max_depth`` of the ``whitted`` reference integrator (rays along a chain,
#: eye ray = 1); equal to the own ``whitted`` algorithm's default.
WHITTED_MAX_DEPTH = 10

#: How the ``whitted`` reference follows one of a dielectric's two lobes (see
#: :mod:`references.whitted_integrator`: Fresnel-proportional choice leaves
#: rare deep branches unseen and their variance unestimated).
WHITTED_LOBE_CHOICE = "uniform"

RFILTERS = ("box", "scene")

#: Upper bound on the lanes (pixels x samples) of one ``mi.render`` call while
#: building a reference; larger passes are split into several launches with
#: their own seeds (the LLVM backend holds one wavefront in memory).
LANE_BUDGET = 1 << 22



class ReferenceMissing(ReferenceError_):
    """No usable stored reference and rendering was not allowed."""


@dataclasses.dataclass(repr=False)
class Reference:
    """A stored Mitsuba reference.

    Attributes
    ----------
    key : str
        Full sha256 cache key.
    directory : Path
        Store entry directory.
    image : np.ndarray
        Mean radiance over passes, float32 ``(H, W, 3)``.
    variance : np.ndarray
        Per-pixel variance of ``image`` (of the mean), float32 ``(H, W, 3)``.
    manifest : dict
        Contents of ``manifest.json``.
    """

    key: str
    directory: Path
    image: np.ndarray
    variance: np.ndarray
    manifest: dict

    def __repr__(self) -> str:
        m = self.manifest
        return (f"Reference({m.get('scene')!r}, {m.get('transport')}, {m.get('spp')} spp/"
                f"{m.get('passes')} passes, {m.get('width')}x{m.get('height')}, "
                f"key={self.key[:16]})")


# ---------------------------------------------------------------------------
# Small helpers
# ---------------------------------------------------------------------------


def _first_line(exc: BaseException) -> str:
    for line in str(exc).splitlines():
        if line.strip():
            return line.strip()
    return type(exc).__name__


def _display_path(path: Path) -> str:
    """Path relative to the repository root if inside it, else absolute."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(REPO_ROOT))
    except ValueError:
        return str(p)


def _scene_file(scene_path) -> Path:
    p = Path(scene_path).expanduser()
    if not p.is_file():
        raise SceneError(f"{p}: no such scene file")
    return p.resolve()


def _parse(path: Path) -> etree._ElementTree:
    tree = parse_file(path)
    if tree.getroot().tag != "scene":
        raise SceneError(f"{path}: root element is <{tree.getroot().tag}>, expected <scene>")
    return tree


def _defaults(root) -> dict[str, str]:
    return {d.get("name"): d.get("value") for d in root.iter("default") if d.get("name")}


def _apply_defines(root, defines: dict[str, str]) -> None:
    """Replace the values of the scene's top-level ``<default>`` elements by ``defines``
    (inserting a ``<default>`` for a name the file does not declare), as Mitsuba's
    ``-D name=value`` does."""
    for name, value in defines.items():
        found = [d for d in root if d.tag == "default" and d.get("name") == name]
        if found:
            for d in found:
                d.set("value", value)
        else:
            el = etree.Element("default", {"name": name, "value": value})
            el.tail = "\n    "
            root.insert(0, el)


def _substitute(value: str | None, defaults: dict[str, str]) -> str | None:
    """Resolve ``$name`` with the file's ``<default>`` values (for recording); the rule
    is :func:`core.xmlscene.substitute`'s, and a name without a value is an error."""
    if value is None or "$" not in value:
        return value
    return substitute(value, defaults,
                      lambda name: SceneError(f"'${name}' has no <default> value"))


def _properties(el) -> dict:
    """``{name: value}`` of an element's direct property children (resolved)."""
    defaults = _defaults(el.getroottree().getroot())
    out = {}
    for child in el:
        if not isinstance(child.tag, str):
            continue
        name = child.get("name")
        if name is not None and child.get("value") is not None:
            out[name] = _substitute(child.get("value"), defaults)
    return out


def _as_number(value):
    try:
        return int(value)
    except (TypeError, ValueError):
        try:
            return float(value)
        except (TypeError, ValueError):
            return value


def _variant_family(variant: str) -> str:
    parts = [p for p in variant.split("_") if p not in ("scalar", "llvm", "cuda", "ad")]
    return "_".join(parts)


def _derive_seed(seed: int, pass_index: int, chunk: int) -> int:
    """Deterministic 31-bit seed for one launch of one pass."""
    digest = hashlib.sha256(f"gibench-reference:{seed}:{pass_index}:{chunk}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def _sync(dr) -> None:
    sync = getattr(dr, "sync_thread", None)
    if sync is not None:
        sync()


def _render_once(mi, dr, scene, spp: int, seed: int) -> np.ndarray:
    """``mi.render`` and wait until the work is finished; returns (H, W, C) float32."""
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    _sync(dr)
    return np.array(img, dtype=np.float32)


# ---------------------------------------------------------------------------
# Scene dependencies and key
# ---------------------------------------------------------------------------


def scene_dependencies(scene_path, defines: dict | None = None) -> list[dict]:
    """Files a scene references by ``filename`` (attributes or ``<string>``), found as
    the loader finds them: the scene is resolved by :func:`core.xmlscene.resolve`
    (``<default>``/``-D`` values, ``$name``, ``<include>``, ``<path>``: one set of
    rules for the loader and the store), each ``<include>`` contributes the file it
    expanded, and every other ``filename`` is looked up in the ``<path>``
    directories (latest first), then the scene file's directory.  Returns
    ``[{name, path, sha256}]`` sorted by name (the name as written, ``$name``
    resolved), with ``path``/``sha256`` None for a file that cannot be found (the
    loader reports it).
    """
    doc = resolve_xml(_scene_file(scene_path), defines)
    found: dict[str, dict] = {}

    def add(name: str, path: Path | None) -> None:
        if name and name not in found:
            found[name] = {"name": name, "path": str(path) if path else None,
                           "sha256": _sha256_file(path) if path else None}

    for name, path in doc.includes:
        add(name, path)
    for el in doc.root.iter():
        if not isinstance(el.tag, str):
            continue
        if el.tag == "string" and el.get("name") == "filename":
            raw = el.get("value")
        elif el.get("filename") is not None:
            raw = el.get("filename")
        else:
            continue
        name = doc.subst(el, raw)
        if name in found:
            continue
        try:
            path = doc.resolve(el, name)
        except SceneError:
            path = None
        add(name, path)
    return [found[k] for k in sorted(found)]


def reference_key(scene_path, *, transport: str = "full", spp: int = 1024, passes: int = 8,
                  seed: int = 0, rfilter: str = "box", variant_family: str = "rgb",
                  defines: dict | None = None, max_depth: int | None = None) -> str:
    """Full sha256 cache key of a reference (see module docstring)."""
    scene = _scene_file(scene_path)
    defines = _check_defines(defines)
    payload = {
        "store_format": STORE_FORMAT,
        "scene_sha256": _sha256_file(scene),
        "dependencies": [[d["name"], d["sha256"]] for d in scene_dependencies(scene, defines)],
        "transport": transport,
        "spp": int(spp),
        "passes": int(passes),
        "seed": int(seed),
        "rfilter": rfilter,
        "variant_family": variant_family,
    }
    if transport == "whitted":         # other transports keep their existing keys
        payload["whitted_max_depth"] = WHITTED_MAX_DEPTH
        payload["whitted_lobe_choice"] = WHITTED_LOBE_CHOICE
    if defines:                        # scenes without -D overrides keep their existing keys
        payload["defines"] = dict(sorted(defines.items()))
    if max_depth is not None:          # only the full transport takes it (checked by the callers)
        payload["max_depth"] = int(max_depth)
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


# ---------------------------------------------------------------------------
# XML overrides and loading
# ---------------------------------------------------------------------------


def _make(tag: str, attrib: dict | None = None, children=()) -> etree._Element:
    el = etree.Element(tag, {k: str(v) for k, v in (attrib or {}).items()})
    for c in children:
        el.append(c)
    return el


def _prop(tag: str, name: str, value) -> etree._Element:
    if isinstance(value, bool):
        value = "true" if value else "false"
    return _make(tag, {"name": name, "value": value})


def _replace_integrator(root, new: etree._Element) -> dict:
    """Swap the top-level integrator(s) for ``new``; return the file's one as a dict."""
    old = [c for c in root if c.tag == "integrator"]
    before = {"type": old[0].get("type"), **_properties(old[0])} if old else None
    index = list(root).index(old[0]) if old else None
    for c in old:
        root.remove(c)
    if index is None:  # after any <default>s, before the rest
        index = sum(1 for c in root if c.tag == "default")
    root.insert(index, new)
    return before


def _override_sensors(root, sampler_factory, rfilter: str) -> dict:
    """Apply sampler and film overrides to every top-level sensor."""
    sensors = [c for c in root if c.tag == "sensor"]
    if not sensors:
        raise SceneError("scene has no <sensor>")
    record = {}
    for i, sensor in enumerate(sensors):
        rec = {}
        old = [c for c in sensor if c.tag == "sampler"]
        rec["sampler"] = {"from": ({"type": old[0].get("type"), **_properties(old[0])}
                                   if old else None)}
        position = list(sensor).index(old[0]) if old else len(sensor)
        for c in old:
            sensor.remove(c)
        new_sampler = sampler_factory()
        sensor.insert(position, new_sampler)
        rec["sampler"]["to"] = {"type": new_sampler.get("type"),
                                **{c.get("name"): _as_number(c.get("value")) for c in new_sampler}}

        films = [c for c in sensor if c.tag == "film"]
        if films:
            film = films[0]
        else:
            film = _make("film", {"type": "hdrfilm"})
            sensor.append(film)
        rec["film"] = {"type": film.get("type"), "added": not films}
        fprops = _properties(film)
        filters = [c for c in film if c.tag == "rfilter"]
        file_filter = ({"type": filters[0].get("type"), **_properties(filters[0])}
                       if filters else "film default (gaussian)")
        if rfilter == "box":
            for c in filters:
                film.remove(c)
            film.append(_make("rfilter", {"type": "box"}))
            rec["rfilter"] = {"from": file_filter, "to": {"type": "box"}}
        else:
            rec["rfilter"] = {"from": file_filter, "to": "kept"}
        for name, value in (("pixel_format", "rgb"), ("component_format", "float32")):
            for c in [c for c in film if c.get("name") == name]:
                film.remove(c)
            film.append(_prop("string", name, value))
            rec[name] = {"from": fprops.get(name, "film default"), "to": value}
        record[f"sensor[{i}]"] = rec
    return record


def _check_film_size(scene: Path, defines) -> None:
    """Refuse, before Mitsuba allocates it, a film larger than the loader's limits
    (:data:`core.loader.MAX_FILM_SIDE`, :data:`core.loader.MAX_FILM_PIXELS`): the
    same file renders on both sides, so both refuse the same sizes."""
    doc = resolve_xml(scene, defines)
    for film in doc.root.iter("film"):
        size = {}
        for c in film:
            if isinstance(c.tag, str) and c.get("name") in ("width", "height") and c.get("value"):
                try:
                    size[c.get("name")] = int(float(doc.subst(c, c.get("value"))))
                except (ValueError, OverflowError):
                    raise doc.error(c, f"film {c.get('name')} is not an integer") from None
        w, h = size.get("width", 768), size.get("height", 576)
        if not (1 <= w <= MAX_FILM_SIDE and 1 <= h <= MAX_FILM_SIDE and w * h <= MAX_FILM_PIXELS):
            raise doc.error(film, f"film of {w}x{h} pixels is outside gibench's limits (sides "
                                  f"1..{MAX_FILM_SIDE}, at most {MAX_FILM_PIXELS} pixels)")


def prepare_scene_xml(scene_path, *, transport: str = "full", spp_per_pass: int = 1,
                      seed: int = 0, rfilter: str = "box", integrator: dict | None = None,
                      sampler: dict | None = None,
                      defines: dict | None = None,
                      max_depth: int | None = None) -> tuple[str, dict, dict]:
    """Apply the reference overrides to a scene file.

    Parameters
    ----------
    scene_path
        Mitsuba 3 XML scene.
    transport
        ``"full"``, ``"direct"`` or ``"whitted"`` (ignored when ``integrator`` is given).
    spp_per_pass, seed
        Sample count and seed of the ``independent`` sampler put in each sensor.
    rfilter
        ``"box"`` (replace the film's filter) or ``"scene"`` (keep it).
    integrator, sampler
        Optional explicit ``{"type": ..., name: value}`` replacements
        (used by :func:`render_depth`).
    defines
        ``{name: value}`` replacing the file's ``<default>`` values (Mitsuba's
        ``-D name=value``); recorded under ``overrides["defines"]``.
    max_depth
        ``transport="full"`` only: the path integrator's ``max_depth``, replacing
        the file's own (Mitsuba's meaning: 1 = emitters seen directly, -1 =
        unbounded).

    Returns
    -------
    xml : str
        The modified scene as a string (load with :func:`load_scene`).
    integrator : dict
        The integrator that will be used (type and properties).
    overrides : dict
        Record of every override (``from``/``to``) for the manifest.
    """
    if transport not in TRANSPORTS and not is_phong_transport(transport):
        raise ParamError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if rfilter not in RFILTERS:
        raise ParamError(f"rfilter must be one of {RFILTERS}, got {rfilter!r}")
    _check_max_depth(max_depth, transport)
    scene = _scene_file(scene_path)
    _check_film_size(scene, defines)
    tree = _parse(scene)
    if any(True for _ in tree.getroot().iter("include")):
        # The sensor or the integrator may come from an included file: override them
        # in the expanded scene (core.xmlscene.expanded), which Mitsuba loads as the file.
        tree = etree.ElementTree(expanded(scene, defines))
    root = tree.getroot()
    defines = _check_defines(defines)
    _apply_defines(root, defines)
    defaults = _defaults(root)
    own = [c for c in root if c.tag == "integrator"]
    own = own[0] if own else None

    if integrator is not None:
        spec = dict(integrator)
        new = _make("integrator", {"type": spec.pop("type")})
        for name, value in spec.items():
            tag = ("boolean" if isinstance(value, bool) else "integer" if isinstance(value, int)
                   else "float" if isinstance(value, float) else "string")
            new.append(_prop(tag, name, value))
        used = dict(integrator)
    else:
        hide = None
        if own is not None:
            for c in own:
                if c.get("name") == "hide_emitters" and c.tag == "boolean":
                    hide = c.get("value")
        if transport == "full":
            raw_depth = None
            if own is not None and own.get("type") == "path":
                for c in own:
                    if c.get("name") == "max_depth" and c.get("value") is not None:
                        raw_depth = c.get("value")
            if max_depth is not None:
                raw_depth = str(int(max_depth))
            new = _make("integrator", {"type": "path"},
                        [_prop("integer", "max_depth", raw_depth if raw_depth is not None else -1)])
            used = {"type": "path",
                    "max_depth": _as_number(_substitute(raw_depth, defaults)) if raw_depth else -1}
        elif transport == "whitted":
            new = _make("integrator", {"type": "whitted"},
                        [_prop("integer", "max_depth", WHITTED_MAX_DEPTH),
                         _prop("string", "lobe_choice", WHITTED_LOBE_CHOICE)])
            source = Path(__file__).resolve().parent / "whitted_integrator.py"
            used = {"type": "whitted", "max_depth": WHITTED_MAX_DEPTH,
                    "lobe_choice": WHITTED_LOBE_CHOICE,
                    "source": _display_path(source), "source_sha256": _sha256_file(source)}
        elif is_phong_transport(transport):   # references/phong_reference.py: Phong BSDF + f_att/ambient
            new, used = prepare_phong_xml(root, transport, _make, _prop)
        else:
            new = _make("integrator", {"type": "direct"})
            used = {"type": "direct"}
        if hide is not None:
            new.append(_prop("boolean", "hide_emitters", hide))
            used["hide_emitters"] = _substitute(hide, defaults)
    before = _replace_integrator(root, new)
    overrides = {"integrator": {"from": before, "to": used}}
    if defines:
        overrides["defines"] = dict(defines)

    if sampler is None:
        def sampler_factory():
            return _make("sampler", {"type": "independent"},
                         [_prop("integer", "sample_count", spp_per_pass),
                          _prop("integer", "seed", seed)])
    else:
        def sampler_factory():
            spec = dict(sampler)
            el = _make("sampler", {"type": spec.pop("type")})
            for name, value in spec.items():
                tag = "boolean" if isinstance(value, bool) else "integer"
                el.append(_prop(tag, name, value))
            return el
    try:
        overrides.update(_override_sensors(root, sampler_factory, rfilter))
    except SceneError as exc:
        raise SceneError(f"{scene}: {exc}") from None
    xml = etree.tostring(tree, encoding="unicode")
    return xml, used, overrides


def load_scene(mi, scene_path, xml: str):
    """Load modified scene XML with relative names resolved against the scene's directory.

    The scene's directory is prepended to Mitsuba's file resolver for the
    duration of the load and the resolver is restored afterwards.  Raises
    :class:`SceneError` naming the file and the first line of Mitsuba's reason.
    """
    from .phong_reference import register as register_phong
    from .whitted_integrator import register as register_whitted

    register_whitted(mi)                # the "whitted" transport's integrator, per variant
    register_phong(mi)                  # the "phong(...)" transport's BSDF and integrator
    scene_path = Path(scene_path).resolve()
    get_resolver = getattr(mi, "file_resolver", None) or (
        lambda: mi.Thread.thread().file_resolver())
    resolver = get_resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    resolver.prepend(str(scene_path.parent))
    try:
        return mi.load_string(xml)
    except Exception as exc:
        raise SceneError(f"{scene_path}: Mitsuba cannot load the scene: {_first_line(exc)}") from None
    finally:
        resolver.clear()
        for p in saved:
            resolver.append(p)


# ---------------------------------------------------------------------------
# Store entries
# ---------------------------------------------------------------------------


_Invalid = EntryInvalid


def _load_entry(directory: Path, key: str) -> Reference:
    image, variance, manifest = read_entry(directory, key)
    return Reference(key=key, directory=directory, image=image, variance=variance,
                     manifest=manifest)


def _render_reference(scene: Path, key: str, directory: Path, *, transport: str, spp: int,
                      passes: int, seed: int, rfilter: str,
                      defines: dict | None = None, max_depth: int | None = None) -> Reference:
    mi = load_mitsuba()
    import drjit as dr

    t_start = time.perf_counter()
    spp_pass = spp // passes
    xml, integrator, overrides = prepare_scene_xml(
        scene, transport=transport, spp_per_pass=spp_pass, seed=seed, rfilter=rfilter,
        defines=defines, max_depth=max_depth)
    deps = scene_dependencies(scene, defines)
    t0 = time.perf_counter()
    mscene = load_scene(mi, scene, xml)
    load_s = time.perf_counter() - t0
    width, height = (int(v) for v in mscene.sensors()[0].film().crop_size())
    chunk = max(1, min(spp_pass, LANE_BUDGET // max(1, width * height)))

    mean = m2 = None
    pass_times, seeds = [], []
    for p in range(passes):
        t0 = time.perf_counter()
        acc, done, pass_seeds = None, 0, []
        while done < spp_pass:
            n = min(chunk, spp_pass - done)
            s = _derive_seed(seed, p, len(pass_seeds))
            img = as_rgb(_render_once(mi, dr, mscene, n, s)[..., :3], name=str(scene))
            img64 = img.astype(np.float64) * n
            acc = img64 if acc is None else acc + img64
            done += n
            pass_seeds.append(s)
        x = acc / spp_pass
        pass_times.append(time.perf_counter() - t0)
        seeds.append(pass_seeds)
        if mean is None:  # Welford's update, float64
            mean, m2 = x.copy(), np.zeros_like(x)
        else:
            delta = x - mean
            mean += delta / (p + 1)
            m2 += delta * (x - mean)
    image = mean.astype(np.float32)
    variance = (m2 / (passes - 1) / passes).astype(np.float32)
    try:
        check_finite(image, name=f"{scene}: Mitsuba reference image")
        check_finite(variance, name=f"{scene}: Mitsuba reference variance")
    except ImageError as exc:
        raise ReferenceError_(str(exc)) from None
    total_s = time.perf_counter() - t_start

    versions = mitsuba_versions()
    manifest = {
        "store_format": STORE_FORMAT,
        "key": key,
        "scene": _display_path(scene),
        "scene_sha256": _sha256_file(scene),
        "dependencies": [{"name": d["name"],
                          "path": _display_path(Path(d["path"])) if d["path"] else None,
                          "sha256": d["sha256"]} for d in deps],
        "transport": transport,
        "integrator": integrator,
        "overrides": overrides,
        "rfilter": rfilter,
        "spp": spp,
        "passes": passes,
        "spp_per_pass": spp_pass,
        "seed": seed,
        "render_seeds": seeds,
        "variance": "per-pixel variance of the mean image: unbiased sample variance over "
                    "passes / passes",
        "mitsuba": versions["mitsuba"],
        "drjit": versions["drjit"],
        "variant": versions["variant"],
        "variant_family": _variant_family(versions["variant"]),
        "libllvm": versions["libllvm"],
        "wall_time_s": {"total": total_s, "load": load_s,
                        "pass_median": statistics.median(pass_times), "passes": pass_times},
        "host": {"machine": platform.machine(), "cpus": os.cpu_count()},
        "width": width,
        "height": height,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }

    try:
        manifest = write_entry(directory, key, image, variance, manifest,
                               exr_metadata={"gibench_key": key, "gibench_scene": manifest["scene"]})
    except OSError:
        # Another process may have installed the same entry meanwhile.
        try:
            return _load_entry(directory, key)
        except _Invalid:
            raise ReferenceError_(f"{scene}: could not install reference entry "
                                  f"{_display_path(directory)}") from None
    return Reference(key=key, directory=directory, image=image, variance=variance,
                     manifest=manifest)


#: Where references render: ``auto`` (Mitsuba's CUDA variant when a GPU works,
#: else the default LLVM variant), ``cuda`` (the same, warning on fallback) or
#: ``llvm``; ``$GIBENCH_REFERENCE_DEVICE`` overrides.  CUDA and LLVM variants
#: share the variant family (``rgb``), hence the key: either renders the entry.
REFERENCE_DEVICE = "auto"
CUDA_VARIANT = "cuda_ad_rgb"
_CUDA_PROBE = ("import drjit as dr, mitsuba as mi; mi.set_variant('cuda_ad_rgb'); "
               "x = dr.arange(mi.Float, 16); dr.eval(x); print('GIBENCH_CUDA_OK')")
_cuda_ok: list = []


def cuda_available(timeout: float = 60.0) -> bool:
    """True if Mitsuba's CUDA variant renders here (probed once per process in a child,
    since a broken CUDA setup can abort the process that tries it)."""
    if not _cuda_ok:
        import subprocess

        try:
            proc = subprocess.run([sys.executable, "-c", _CUDA_PROBE], capture_output=True,
                                  text=True, timeout=timeout, cwd=tempfile.gettempdir())
            _cuda_ok.append(proc.returncode == 0 and "GIBENCH_CUDA_OK" in proc.stdout)
        except (subprocess.TimeoutExpired, OSError):
            _cuda_ok.append(False)
    return _cuda_ok[0]


def reference_device_variant(device: str | None = None) -> str | None:
    """The Mitsuba variant references render with: :data:`CUDA_VARIANT`, or None for
    :func:`load_mitsuba`'s default (LLVM) when CUDA is not asked for or not available."""
    device = device or os.environ.get("GIBENCH_REFERENCE_DEVICE") or REFERENCE_DEVICE
    if device not in ("auto", "cuda", "llvm"):
        raise ParamError(f"reference device must be auto, cuda or llvm, got {device!r} "
                         "(GIBENCH_REFERENCE_DEVICE)")
    if device == "llvm" or os.environ.get("GIBENCH_MITSUBA_VARIANT"):
        return None
    if cuda_available():
        return CUDA_VARIANT
    if device == "cuda":
        print("gibench: warning: Mitsuba's CUDA variant does not work here; references "
              "render with the LLVM variant", file=sys.stderr, flush=True)
    return None


def _check_max_depth(max_depth, transport) -> None:
    if max_depth is None:
        return
    if not isinstance(max_depth, (int, np.integer)) or isinstance(max_depth, bool):
        raise TypeError(f"max_depth must be an integer, got {max_depth!r}")
    if transport != "full":
        raise ParamError(f"max_depth applies to transport='full' only, got transport={transport!r}")
    if max_depth < -1 or max_depth == 0:
        raise ParamError(f"max_depth must be -1 (unbounded) or >= 1, got {max_depth}")


def _check_args(transport, spp, passes, seed, rfilter) -> None:
    if transport not in TRANSPORTS and not is_phong_transport(transport):
        raise ParamError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if rfilter not in RFILTERS:
        raise ParamError(f"rfilter must be one of {RFILTERS}, got {rfilter!r}")
    for name, v in (("spp", spp), ("passes", passes), ("seed", seed)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
            raise TypeError(f"{name} must be an integer, got {v!r}")
    if passes < 2:
        raise ParamError(f"passes must be >= 2 to estimate a variance, got {passes}")
    if spp < 1 or spp % passes:
        raise ParamError(f"spp ({spp}) must be a positive multiple of passes ({passes})")
    if seed < 0:
        raise ParamError(f"seed must be >= 0, got {seed}")


def get_reference(scene_path, *, transport: str = "full", spp: int = 1024, passes: int = 8,
                  seed: int = 0, rfilter: str = "box", store=DEFAULT_STORE,
                  render_missing: bool = True, force: bool = False,
                  defines: dict | None = None, max_depth: int | None = None,
                  spectral: bool = False) -> Reference:
    """Return the Mitsuba reference of a scene, rendering it if needed.

    Parameters
    ----------
    scene_path
        Mitsuba 3 XML scene file.
    transport
        ``"full"`` (path tracing), ``"direct"`` (direct illumination only) or
        ``"whitted"`` (delta chains + direct light, :mod:`references.whitted_integrator`).
    spp
        Total samples per pixel; must be a multiple of ``passes``.
    passes
        Independent passes (>= 2) the variance is estimated from.
    seed
        Base seed; per-pass seeds are derived from it.
    rfilter
        ``"box"`` (default) or ``"scene"`` (keep the file's reconstruction filter).
    store
        Store directory (default ``references/store``).
    render_missing
        If False, raise :class:`ReferenceMissing` instead of rendering.
    force
        Re-render even when a valid entry exists (the old entry is replaced
        only once the new one is complete).
    defines
        ``{name: value}`` overriding the scene's ``<default>`` values (Mitsuba's
        ``-D name=value``); part of the key when given.
    max_depth
        ``transport="full"`` only: the path integrator's ``max_depth`` instead
        of the file's (part of the key when given).
    spectral
        Render with Mitsuba's spectral variant (``llvm_ad_spectral``, or
        ``scalar_spectral`` without a usable libLLVM; see
        :func:`references.mitsuba_env.spectral_variant`) instead of the RGB one;
        keyed through the variant family (``spectral``).

    Returns
    -------
    Reference
        Image, variance of the mean, manifest.

    Raises
    ------
    SceneError
        Missing scene file or a scene Mitsuba cannot load.
    ReferenceMissing
        No usable entry and ``render_missing=False``.
    """
    if has_motion(_scene_file(scene_path)):
        _check_args(transport, spp, passes, seed, rfilter)
        return _motion(_scene_file(scene_path), transport=transport, spp=spp, seed=seed,
                       rfilter=rfilter, store=store, render_missing=render_missing,
                       defines=defines, max_depth=max_depth, force=force, spectral=spectral)
    if spectral:
        with spectral_variant():
            return get_reference(scene_path, transport=transport, spp=spp, passes=passes, seed=seed,
                                 rfilter=rfilter, store=store, render_missing=render_missing,
                                 force=force, defines=defines, max_depth=max_depth)
    _check_args(transport, spp, passes, seed, rfilter)
    _check_max_depth(max_depth, transport)
    scene = _scene_file(scene_path)
    _check_film_size(scene, defines)
    mi = load_mitsuba()
    family = _variant_family(mi.variant())
    defines = _check_defines(defines)
    key = reference_key(scene, transport=transport, spp=spp, passes=passes, seed=seed,
                        rfilter=rfilter, variant_family=family, defines=defines,
                        max_depth=max_depth)
    directory = Path(store) / key[:16]
    cause = "re-render requested (force)"
    if not force:
        try:
            return _load_entry(directory, key)
        except _Invalid as exc:
            cause = str(exc)
    where = _display_path(directory)
    if not render_missing:
        raise ReferenceMissing(f"{scene}: no usable reference in {where} ({cause})")
    print(f"gibench: rendering reference for {_display_path(scene)} ({transport}, {spp} spp): "
          f"{where}: {cause}", file=sys.stderr, flush=True)
    # The CUDA device renders the RGB family only; spectral references stay on LLVM/scalar.
    variant = reference_device_variant() if family == "rgb" else None
    previous = mi.variant()
    if variant is not None:
        load_mitsuba(variant)
    try:
        return _render_reference(scene, key, directory, transport=transport, spp=spp,
                                 passes=passes, seed=seed, rfilter=rfilter, defines=defines,
                                 max_depth=max_depth)
    finally:
        if variant is not None:
            load_mitsuba(previous)


def _motion(scene: Path, *, transport, spp, seed, rfilter, store, render_missing, defines,
            max_depth, force, spectral):
    """The reference of a scene with moving spheres (``gibench_velocity``): Mitsuba 3
    cannot move shapes, so it is :func:`references.motion_blur.motion_reference`, the
    mean of :data:`~references.motion_blur.TIMES` renders at jittered stratified shutter
    times with ``spp // 16`` samples each (four times the samples of a static
    reference: the time strata add variance; 1024 → 64 per time)."""
    from .motion_blur import TIMES, motion_reference

    unsupported = [name for name, given in (("defines", defines), ("max_depth", max_depth),
                                            ("force", force), ("spectral", spectral)) if given]
    if rfilter != "box":
        unsupported.append(f"rfilter={rfilter!r}")
    if unsupported:
        raise UnsupportedError(f"{_display_path(scene)}: moving spheres (gibench_velocity): the "
                         f"motion-blur reference does not support {', '.join(unsupported)}")
    def render_at(xml_file: Path, spp_at: int, sampler_seed: int, render_seed: int):
        mi = load_mitsuba()
        import drjit as dr

        xml, _, _ = prepare_scene_xml(xml_file, transport=transport, spp_per_pass=spp_at,
                                      seed=sampler_seed)
        return _render_once(mi, dr, load_scene(mi, scene, xml), spp_at, render_seed)

    try:
        return motion_reference(scene, transport=transport, times=TIMES, spp=max(1, spp // 16),
                                seed=seed, store=Path(store), render=render_missing,
                                render_at=render_at)
    except FileNotFoundError as exc:
        raise ReferenceMissing(str(exc)) from None


# ---------------------------------------------------------------------------
# Timing and depth
# ---------------------------------------------------------------------------


def prepare_timing(scene_path, *, transport: str, spp: int, seed: int = 0, rfilter: str = "box",
                   defines: dict | None = None, max_depth: int | None = None):
    """Mitsuba's render of a scene with the reference overrides, loaded and warmed up.

    Returns ``(render, info)``: ``render()`` renders ``spp`` samples per pixel
    in one ``mi.render`` call and returns its wall time (``time.perf_counter``,
    the clock stopped after ``dr.sync_thread()``); ``info`` holds ``spp``,
    ``variant``, ``warmup_s`` (the untimed first render: JIT compilation),
    ``transport``, ``width``, ``height``, ``scene``.
    """
    if transport not in TRANSPORTS and not is_phong_transport(transport):
        raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    scene = _scene_file(scene_path)
    mi = load_mitsuba()
    import drjit as dr

    xml, _, _ = prepare_scene_xml(scene, transport=transport, spp_per_pass=spp, seed=seed,
                                  rfilter=rfilter, defines=defines, max_depth=max_depth)
    mscene = load_scene(mi, scene, xml)

    def render() -> float:
        t0 = time.perf_counter()
        dr.eval(mi.render(mscene, spp=spp, seed=seed))
        _sync(dr)
        return time.perf_counter() - t0

    warmup = render()
    width, height = (int(v) for v in mscene.sensors()[0].film().crop_size())
    return render, {"spp": spp, "variant": mi.variant(), "warmup_s": warmup,
                    "transport": transport, "width": width, "height": height,
                    "scene": _display_path(scene)}


def time_mitsuba(scene_path, *, transport: str, spp: int, seed: int = 0, repeats: int = 3,
                 rfilter: str = "box", defines: dict | None = None,
                 max_depth: int | None = None) -> dict:
    """Time Mitsuba rendering a scene with the reference overrides.

    The scene is loaded once; one untimed warm-up render (JIT compilation)
    is followed by ``repeats`` timed renders of ``spp`` samples per pixel in
    one ``mi.render`` call each (:func:`prepare_timing`).

    Returns
    -------
    dict
        ``median_s``, ``times_s``, ``spp``, ``variant``, ``warmup_s`` (plus
        ``transport``, ``width``, ``height``, ``scene``).
    """
    if repeats < 1 or spp < 1:
        raise ValueError(f"repeats and spp must be >= 1, got {repeats}, {spp}")
    render, info = prepare_timing(scene_path, transport=transport, spp=spp, seed=seed,
                                  rfilter=rfilter, defines=defines, max_depth=max_depth)
    times = [render() for _ in range(repeats)]
    return dict(info, median_s=statistics.median(times), times_s=times)


def render_depth(scene_path, defines: dict | None = None) -> np.ndarray:
    """Depth image of a scene's first sensor at pixel centres, float32 ``(H, W)``.

    Uses Mitsuba's ``aov`` integrator (``aovs="dd.y:depth"``), a
    ``stratified`` sampler with one un-jittered sample per pixel (the pixel
    centre) and a box filter.

    Notes
    -----
    The value is the ray parameter *t* of the first hit along the unit camera
    ray, and Mitsuba's perspective sensor starts that ray at the near clip
    plane (origin moved forward by ``near_clip / cos``).  So
    ``depth = distance_from_eye - near_clip / cos(theta)`` where theta is the
    angle between the ray and the optical axis; callers comparing with
    eye-distances must subtract ``near_clip / cos``.  Pixels whose ray hits
    nothing are 0.
    """
    scene = _scene_file(scene_path)
    mi = load_mitsuba()
    import drjit as dr

    xml, _, _ = prepare_scene_xml(
        scene, integrator={"type": "aov", "aovs": "dd.y:depth"},
        sampler={"type": "stratified", "sample_count": 1, "jitter": False}, rfilter="box",
        defines=defines)
    mscene = load_scene(mi, scene, xml)
    img = _render_once(mi, dr, mscene, 1, 0)
    names = list(mscene.integrator().aov_names())
    if not names or img.ndim != 3 or img.shape[2] < len(names):
        raise RuntimeError(f"{scene}: unexpected AOV output {img.shape} for channels {names}")
    # The AOV channels come last, after any colour channels of a nested integrator.
    index = img.shape[2] - len(names) + next(
        (i for i, n in enumerate(names) if n.startswith("dd.y")), 0)
    return np.ascontiguousarray(img[:, :, index], dtype=np.float32)
