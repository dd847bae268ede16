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

Entries are stored like the other references, in ``references/store/<key>/``
(``image.exr``, ``variance.exr``, ``manifest.json``; written to a temporary
directory and renamed into place), keyed by the scene file's hash and the
parameters; a stored entry is reused.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from lxml import etree
from core.errors import SceneError

__all__ = ["scene_at_time", "motion_reference", "has_motion", "VELOCITY", "STORE", "TIMES"]

VELOCITY = "gibench_velocity"
STORE = Path(__file__).resolve().parent / "store"
#: Shutter strata of the reference that :func:`references.reference.get_reference`
#: returns for a scene with moving spheres.
TIMES = 64


def has_motion(scene_path) -> bool:
    """Whether the scene file gives any shape a ``gibench_velocity`` (its reference
    must then come from :func:`motion_reference`: Mitsuba would refuse the file).
    A file that is not well-formed XML has none; its loader reports it."""
    try:
        tree = etree.parse(str(scene_path), etree.XMLParser(remove_comments=True))
    except etree.XMLSyntaxError:
        return False
    return any(c.get("name") == VELOCITY for c in tree.getroot().iter("vector"))


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
    tree = etree.parse(str(path), etree.XMLParser(remove_comments=True))
    for shape in tree.getroot().iter("shape"):
        vel = [c for c in shape if c.tag == "vector" and c.get("name") == VELOCITY]
        if not vel:
            continue
        v = _floats(vel[0].get("value"))
        centre = [c for c in shape if c.tag == "point" and c.get("name") == "center"]
        if not centre or centre[0].get("value") is None:
            raise SceneError(f"{path}:{shape.sourceline}: a moving sphere needs "
                             "<point name=\"center\" value=\"x, y, z\"/>")
        c = _floats(centre[0].get("value")) + v * tau
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


def motion_reference(scene_path, *, transport: str = "direct", times: int = 64, spp: int = 64,
                     seed: int = 0, store: Path | None = None, render: bool = True) -> MotionReference:
    """The stored reference of a scene with moving spheres, rendering it if missing.

    ``times`` (even) shutter strata, ``spp`` samples each.  With ``render=False`` a
    missing entry raises ``FileNotFoundError`` naming the key.
    """
    from core.imageio import read_exr, write_exr

    if times < 2 or times % 2:
        raise ValueError(f"motion_reference: times must be even and >= 2, got {times}")
    scene_path = Path(scene_path).resolve()
    store = Path(store) if store is not None else STORE
    key = _key(scene_path, transport, times, spp, seed)
    final = store / key[:16]
    if (final / "manifest.json").is_file():
        m = json.loads((final / "manifest.json").read_text())
        if m.get("key") == key:
            return MotionReference(final, read_exr(final / "image.exr"), read_exr(final / "variance.exr"), m)
    if not render:
        raise FileNotFoundError(f"{scene_path}: no stored motion reference {final} (key {key[:16]})")
    imgs = _render_times(scene_path, transport, times, spp, seed)
    mean = imgs.mean(axis=0)
    pairs = imgs[0::2] - imgs[1::2]
    var = (pairs ** 2).sum(axis=0) / times ** 2
    tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}-", dir=store))
    try:
        write_exr(tmp / "image.exr", mean.astype(np.float32))
        write_exr(tmp / "variance.exr", var.astype(np.float32))
        manifest = {"key": key, "scene": os.path.relpath(scene_path, store.parent.parent),
                    "transport": transport, "times": times, "spp": spp, "seed": seed,
                    "kind": "motion-blur: mean of Mitsuba renders at jittered stratified shutter times",
                    "width": int(mean.shape[1]), "height": int(mean.shape[0])}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1))
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return MotionReference(final, mean.astype(np.float32), var.astype(np.float32), manifest)


def _render_times(scene_path: Path, transport: str, times: int, spp: int, seed: int) -> np.ndarray:
    import drjit as dr

    from .mitsuba_env import load_mitsuba
    from .reference import _render_once, load_scene, prepare_scene_xml

    mi = load_mitsuba()
    t0, t1 = _shutter(scene_path)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(times):
        tau = t0 + (t1 - t0) * (k + rng.random()) / times
        with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=scene_path.parent, delete=False) as f:
            f.write(scene_at_time(scene_path, tau))
            tmp = Path(f.name)
        try:
            xml, _, _ = prepare_scene_xml(tmp, transport=transport, spp_per_pass=spp, seed=seed + k)
        finally:
            tmp.unlink()
        scene = load_scene(mi, scene_path, xml)
        out.append(_render_once(mi, dr, scene, spp, seed * 100003 + k)[..., :3])
    return np.stack(out).astype(np.float64)
