"""Motion-blur references: Mitsuba 3 has no moving shapes, so the reference of a
scene with moving spheres is the average of many Mitsuba renders at stratified
shutter times.

Scene syntax (gibench's own, read by :mod:`core.loader`): a sphere with
``<vector name="gibench_velocity" value="vx, vy, vz"/>`` moves linearly,
centre(τ) = ``center`` + velocity·τ, for τ over the sensor's
[``shutter_open``, ``shutter_close``].  Mitsuba would refuse the unknown
property, so :func:`scene_at_time` strips it and writes the sphere's ``center``
at time τ instead (a moving sphere must give ``center`` and no ``to_world``).

The reference (:func:`motion_reference`): the shutter interval is cut into
``times`` equal strata; stratum k is rendered by Mitsuba (the ``transport``'s
integrator, box filter, as :func:`references.reference.prepare_scene_xml`
sets it up) at a time drawn uniformly inside it (jittered, so the average is
an unbiased estimate of the time integral, not a midpoint rule), with
``spp`` samples per pixel and its own seed.  The image is the mean over the
strata; its variance (of the mean) is estimated by collapsing adjacent strata
in pairs, ``Σ_pairs (X_2j − X_2j+1)² / K²`` — conservative, since it also
counts the change of the image between neighbouring times.

Entries are stored like the other references, through :mod:`references.store`
(``references/store/<key>/``: ``image.exr``, ``variance.exr``, ``manifest.json``
with the images' sha256, written to a temporary directory and renamed into
place), keyed by the scene file's hash and the parameters; a stored entry is
reused only if the store's checks pass (key, hashes, finite images), otherwise
it is re-rendered with a one-line message on stderr.

This module renders nothing with Mitsuba itself: the caller
(:func:`references.reference.get_reference`) passes the function that renders
one scene file at one time, so the two modules do not import each other.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np
from lxml import etree

from core.errors import SceneError
from core.xmlscene import parse_file

from .store import EntryInvalid, entry_directory, read_entry, write_entry

__all__ = ["scene_at_time", "motion_reference", "has_motion", "VELOCITY", "STORE", "TIMES"]

VELOCITY = "gibench_velocity"
STORE = Path(__file__).resolve().parent / "store"
#: Shutter strata of the reference that :func:`references.reference.get_reference`
#: returns for a scene with moving spheres.
TIMES = 64


def has_motion(scene_path) -> bool:
    """Whether the scene file gives any shape or the sensor a ``gibench_velocity`` or
    ``gibench_angular_velocity`` (its reference must then come from
    :func:`motion_reference`, which refuses all but moving spheres: Mitsuba would
    refuse the file).  A file that is not well-formed XML has none; its loader
    reports it."""
    try:
        tree = parse_file(Path(scene_path))
    except SceneError:
        return False
    return any(c.get("name") in (VELOCITY, "gibench_angular_velocity") for c in tree.getroot().iter("vector"))


class MotionReference:
    """A stored motion-blur reference: ``image``, ``variance`` (of the mean), ``manifest``."""

    def __init__(self, directory: Path, image, variance, manifest):
        self.directory, self.image, self.variance, self.manifest = directory, image, variance, manifest

    @property
    def key(self) -> str:
        return self.manifest["key"]

    def __repr__(self) -> str:
        m = self.manifest
        return (f"MotionReference({m['scene']!r}, {m['transport']}, {m['times']} times x "
                f"{m['spp']} spp, key={self.directory.name})")


def _floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.replace(",", " ").split()])


def scene_at_time(scene_path, tau: float) -> str:
    """The scene file as Mitsuba can read it, every moving sphere placed at time ``tau``."""
    path = Path(scene_path)
    tree = parse_file(path)
    for el in tree.getroot().iter("vector"):
        parent = el.getparent()
        if el.get("name", "").startswith("gibench_") and not (
                el.get("name") == VELOCITY and parent.tag == "shape" and parent.get("type") == "sphere"):
            raise SceneError(f"{path}:{el.sourceline}: {el.get('name')} on a {parent.tag} "
                             f"'{parent.get('type')}': the shutter-averaged Mitsuba reference moves "
                             "spheres only (camera and mesh motion have no Mitsuba reference here)")
    for shape in tree.getroot().iter("shape"):
        vel = [c for c in shape if c.tag == "vector" and c.get("name") == VELOCITY]
        if not vel:
            continue
        try:
            v = _floats(vel[0].get("value"))
        except (AttributeError, ValueError):
            raise SceneError(f"{path}:{vel[0].sourceline}: gibench_velocity needs a value "
                             "'vx, vy, vz'") from None
        centre = [c for c in shape if c.tag == "point" and c.get("name") == "center"]
        if not centre or centre[0].get("value") is None:
            raise SceneError(f"{path}:{shape.sourceline}: a moving sphere needs "
                             "<point name=\"center\" value=\"x, y, z\"/>")
        try:
            c = _floats(centre[0].get("value")) + v * tau
        except ValueError:
            raise SceneError(f"{path}:{centre[0].sourceline}: a moving sphere's center must be "
                             "literal numbers 'x, y, z'") from None
        centre[0].set("value", ", ".join(repr(float(x)) for x in c))
        shape.remove(vel[0])
    return etree.tostring(tree, encoding="unicode")


def _key(scene_path: Path, transport, times, spp, seed) -> str:
    h = hashlib.sha256()
    h.update(b"gibench-motion-reference:1\0")
    h.update(scene_path.read_bytes())
    h.update(json.dumps({"transport": transport, "times": times, "spp": spp, "seed": seed}).encode())
    return h.hexdigest()


def _shutter(scene_path: Path) -> tuple[float, float]:
    from core.loader import load_scene

    cam = load_scene(scene_path).camera
    return cam.shutter_open, cam.shutter_close


#: ``render_at(scene_file, spp, sampler_seed, render_seed)``: Mitsuba's image of a
#: scene file (one moment of the shutter), float ``(H, W, 3)``.
RenderAt = Callable[[Path, int, int, int], np.ndarray]


def motion_reference(scene_path, *, transport: str = "direct", times: int = 64, spp: int = 64,
                     seed: int = 0, store: Path | None = None, render: bool = True,
                     render_at: RenderAt | None = None) -> MotionReference:
    """The stored reference of a scene with moving spheres, rendering it if missing or
    unusable.

    ``times`` (even) shutter strata, ``spp`` samples each, each rendered by
    ``render_at`` (required when the entry must be rendered).  With
    ``render=False`` a missing or unusable entry raises ``FileNotFoundError``
    naming the key and the reason.
    """
    if times < 2 or times % 2:
        raise ValueError(f"motion_reference: times must be even and >= 2, got {times}")
    scene_path = Path(scene_path).resolve()
    store = Path(store) if store is not None else STORE
    key = _key(scene_path, transport, times, spp, seed)
    final = entry_directory(store, key)
    try:
        image, variance, manifest = read_entry(final, key)
        return MotionReference(final, image, variance, manifest)
    except EntryInvalid as exc:
        cause = str(exc)
    if not render:
        raise FileNotFoundError(f"{scene_path}: no usable motion reference {final} "
                                f"(key {key[:16]}: {cause})")
    if render_at is None:
        raise ValueError("motion_reference: render_at is needed to render a missing entry")
    print(f"gibench: rendering motion-blur reference for {scene_path.name} ({transport}, "
          f"{times} times x {spp} spp): {final}: {cause}", file=sys.stderr, flush=True)
    imgs = _render_times(scene_path, transport, times, spp, seed, render_at)
    mean = imgs.mean(axis=0).astype(np.float32)
    pairs = imgs[0::2] - imgs[1::2]
    var = ((pairs ** 2).sum(axis=0) / times ** 2).astype(np.float32)
    manifest = {"key": key, "scene": os.path.relpath(scene_path, store.parent.parent),
                "transport": transport, "times": times, "spp": spp, "seed": seed,
                "kind": "motion-blur: mean of Mitsuba renders at jittered stratified shutter times"}
    manifest = write_entry(final, key, mean, var, manifest)
    return MotionReference(final, mean, var, manifest)


def _render_times(scene_path: Path, transport: str, times: int, spp: int, seed: int,
                  render_at: RenderAt) -> np.ndarray:
    t0, t1 = _shutter(scene_path)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(times):
        tau = t0 + (t1 - t0) * (k + rng.random()) / times
        with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=scene_path.parent, delete=False) as f:
            f.write(scene_at_time(scene_path, tau))
            tmp = Path(f.name)
        try:
            out.append(np.asarray(render_at(tmp, spp, seed + k, seed * 100003 + k))[..., :3])
        finally:
            tmp.unlink()
    return np.stack(out).astype(np.float64)
