"""Mitsuba 3 XML scene loader (a documented subset) → :class:`core.scene.Scene`.

The reference renders the very same file with ``mi.load_file``; this loader
builds the one scene model the own algorithms read.  It understands:

===============  ==============================================================
element          supported
===============  ==============================================================
scene            ``version`` 2.x / 3.x; older files (0.x, 1.x: Mitsuba 0.6) are
                 upgraded in memory as Mitsuba 3's ``upgrade_tree`` does:
                 camelCase ``name`` attributes become snake_case (``fovAxis`` ->
                 ``fov_axis``, ``intIOR`` -> ``int_ior``, ``toWorld`` ->
                 ``to_world``) and a diffuse bsdf's ``diffuse_reflectance``
                 becomes ``reflectance``.  Mitsuba does not rename in 2.x files,
                 so neither does the loader.  Mitsuba 0.6's ``<lookAt>`` stays an
                 error: the Mitsuba 3 parser gibench pins (3.6+) refuses it too
default          ``name``/``value``; ``$name`` is substituted in every attribute;
                 ``load_scene(path, defines={name: value})`` overrides them (as
                 Mitsuba's ``-D name=value`` and ``mi.load_file(path, name=value)``)
integrator       any type (read for the reference's transport; own algorithms ignore it)
sensor           ``perspective``: fov, fov_axis, near_clip, far_clip, to_world
                 (focus_distance is accepted and ignored: a pinhole has no focus);
                 ``focal_length`` instead of fov ("50mm", Mitsuba's default when
                 neither is given: the diagonal field of view of 35 mm film,
                 :func:`sensor_fov` = Mitsuba's ``parse_fov``);
                 ``thinlens``: the same plus aperture_radius (required, as in
                 Mitsuba) and focus_distance (default far_clip);
                 ``orthographic``: near_clip, far_clip, to_world; every sensor:
                 shutter_open, shutter_close
film             ``hdrfilm``: width, height, rfilter, pixel_format, component_format
rfilter          ``box``, ``gaussian`` (stddev)
sampler          any type: sample_count (seed, jitter accepted)
include          ``filename``: an XML file whose ``<scene>`` children (or whose
                 root element, e.g. a ``<bsdf>``) replace the element; looked up
                 in the including file's directory, the ``<path>`` directories,
                 the scene's directory (as Mitsuba 3.9's parser); errors inside
                 name the included file and the include chain
path             ``value``: a search directory for relative file names (meshes,
                 images, includes), relative to the declaring file; the latest
                 is searched first, then the scene file's directory
transform        lookat, translate, rotate, scale, matrix — composed in order
values           rgb, float, integer, boolean, string, point, vector, ref / id;
                 ``spectrum`` (a constant, or ``"λ:v, λ:v, ..."`` pairs in nm,
                 increasing): a :class:`core.scene.Spectrum`, converted to
                 RGB where an RGB value is read (as Mitsuba's RGB variants do)
                 and kept as a spectrum for spectral rendering (material
                 ``params``, ``Shape.emitter_spectrum``)
shape            sphere (center/radius or to_world; gibench's own
                 ``<vector name="gibench_velocity">`` makes it move linearly,
                 centre(τ) = center + velocity·τ over the sensor's shutter — see
                 references/motion_blur.py), rectangle, cube, obj, ply,
                 (meshes may move rigidly: ``gibench_velocity``,
                 ``gibench_angular_velocity`` about ``gibench_pivot``, default
                 the vertices' centroid; so may the sensor, about its origin),
                 disk, cylinder (p0, p1, radius; both tessellated, see
                 :mod:`core.meshes`), serialized (Mitsuba's compressed mesh format,
                 shape_index), flip_normals, face_normals; OBJ polygons are
                 fan-triangulated (as Mitsuba); ``shapegroup`` + ``instance``
                 (to_world): each instance's shapes flattened into world space
bsdf             diffuse, conductor, dielectric, roughconductor, roughdielectric, twosided,
                 plastic, roughplastic (diffuse_reflectance, specular_reflectance,
                 int_ior, ext_ior, nonlinear; alpha, distribution, sample_visible),
                 normalmap / bumpmap around one bsdf, inside or outside a
                 twosided (:attr:`Material.shading`: the texture, scale,
                 flip_invalid_normals, use_shadowing_function, the order);
                 thindielectric (int_ior, ext_ior, specular_reflectance,
                 specular_transmittance); mask (opacity, a float or texture,
                 outermost: :attr:`Material.opacity`); blendbsdf (weight, a
                 float or texture, two nested bsdfs: :attr:`Material.components`);
                 gibench-only ``gibench_cooktorrance`` (reflectance, kd, ks,
                 int_ior, ext_ior, alphas, weights: Cook–Torrance with a
                 roughness mixture) and ``gibench_difftrans`` (reflectance,
                 transmittance: diffuse transmission), thesis 2.4.5, decoded
                 by :func:`impl.materials.material_arrays`;
                 ``principled`` refused by name (not a thesis model); BSDFs no
                 shape uses are dropped
texture          on any parameter Mitsuba reads as a texture (a conductor's
                 specular_reflectance, eta, k; a rough BSDF's alpha; a plastic's
                 reflectances: :attr:`Material.textures`), declared at scene
                 level with an id and attached by ``<ref>``, or nested in a
                 diffuse bsdf as its ``reflectance``:
                 ``checkerboard`` (color0, color1, to_uv) and ``bitmap``
                 (filename: PNG/JPEG sRGB-decoded unless ``raw``, EXR linear;
                 filter_type bilinear|nearest, wrap_mode repeat|clamp|mirror,
                 to_uv), on ``rectangle`` (Mitsuba's uv: the local [-1, 1]²
                 square mapped to [0, 1]²) and ``obj`` shapes with ``vt``
                 coordinates (v flipped on loading, as Mitsuba does)
medium           refused by name: participating media are out of scope
(emitter)        ``envmap`` (filename, scale, to_world: :attr:`Scene.envmap`; at
                 most one environment emitter); ``projector`` (irradiance colour or
                 texture, scale, fov / focal_length, to_world); a spot's
                 ``texture``; an ``area`` emitter declared at scene level with an id
                 and attached by ``<ref>``
emitter          point, directional, spot; ``area`` inside a shape; ``constant``
                 (uniform environment radiance, :attr:`Scene.environment`)
===============  ==============================================================

Every property is checked at load against one schema (``_SCHEMA``): the element
it is given as (``<rgb name="radius">`` is refused), a finite value, and its
range (fov in (0, 180), radius > 0, colours >= 0, integral integers, an
invertible ``to_world``, ...); films are limited to :data:`MAX_FILM_SIDE` per
side and :data:`MAX_FILM_PIXELS` in all, bitmap textures to
:data:`MAX_TEXTURE_PIXELS`.  The XML layer (defaults, ``$name``, include, path,
entity-free parsing, the include limits) is :mod:`core.xmlscene`, shared with
the reference store.

Anything else raises :class:`SceneError` with one line naming the element, the
file and the line.   Properties that do not change what is rendered by the own
algorithms and that Mitsuba accepts (``id`` names, film pixel formats, a
sampler's seed) are accepted; any other property is an error, so nothing in a
file is silently ignored.

Which algorithm models the newer parts of the vocabulary (plastic, envmap,
projector, normal/bump maps, textured parameters, mask, blendbsdf,
thindielectric) is
:attr:`core.algorithm.Algorithm.models`; the others refuse a scene using them.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from lxml import etree

from . import transforms as tf
from .meshes import (MeshError, angle_weighted_normals, cube, cylinder, disk, load_mesh_uvs, load_serialized,
                     rectangle)
from .scene import (Camera, EnvMap, Film, Light, Material, Scene, Shape, Spectrum, anisotropic_roughness,
                    texture_mean)
from .errors import SceneError
from .xmlscene import Document, _snake_case, resolve, short  # noqa: F401  (_snake_case: tests)

__all__ = ["SceneError", "load_scene", "SUPPORTED", "REFUSED", "sensor_fov"]

SUPPORTED = {
    "shape": ("sphere", "rectangle", "cube", "disk", "cylinder", "obj", "ply", "serialized",
              "shapegroup", "instance"),
    "bsdf": ("diffuse", "conductor", "dielectric", "roughconductor", "roughdielectric", "twosided",
             "plastic", "roughplastic", "normalmap", "bumpmap", "thindielectric", "mask", "blendbsdf",
             "gibench_cooktorrance", "gibench_difftrans"),
    "emitter": ("point", "directional", "spot", "area", "constant", "envmap", "projector"),
    "sensor": ("perspective", "thinlens", "orthographic"),
    "film": ("hdrfilm",),
    "rfilter": ("box", "gaussian"),
    "texture": ("checkerboard", "bitmap"),
}

#: Shapes whose uv parameterisation the loader reproduces (for textures); an
#: ``obj`` needs ``vt`` coordinates in the file.
_UV_SHAPES = ("rectangle", "obj", "serialized")

_VALUE_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector",
               "transform")

# gibench-only motion properties (camera, meshes; see _motion).
_MOTION = ("gibench_velocity", "gibench_angular_velocity")
_MESH_MOTION = _MOTION + ("gibench_pivot",)

# Properties each plugin accepts: name -> what the own algorithms do with it.
_PROPS = {
    ("sensor", "perspective"): {"fov", "fov_axis", "near_clip", "far_clip", "to_world", "focus_distance",
                                "shutter_open", "shutter_close", "focal_length", *_MOTION},
    ("sensor", "thinlens"): {"fov", "fov_axis", "near_clip", "far_clip", "to_world", "focus_distance",
                             "aperture_radius", "shutter_open", "shutter_close", "focal_length", *_MOTION},
    ("sensor", "orthographic"): {"near_clip", "far_clip", "to_world", "shutter_open", "shutter_close",
                                 *_MOTION},
    ("film", "hdrfilm"): {"width", "height", "pixel_format", "component_format"},
    ("rfilter", "box"): set(),
    ("rfilter", "gaussian"): {"stddev"},
    ("shape", "sphere"): {"center", "radius", "to_world", "flip_normals", "gibench_velocity"},
    ("shape", "rectangle"): {"to_world", "flip_normals", *_MESH_MOTION},
    ("shape", "cube"): {"to_world", "flip_normals", *_MESH_MOTION},
    ("shape", "disk"): {"to_world", "flip_normals", *_MESH_MOTION},
    ("shape", "cylinder"): {"to_world", "flip_normals", "p0", "p1", "radius", *_MESH_MOTION},
    ("shape", "obj"): {"filename", "to_world", "flip_normals", "face_normals", *_MESH_MOTION},
    ("shape", "ply"): {"filename", "to_world", "flip_normals", "face_normals", *_MESH_MOTION},
    ("bsdf", "diffuse"): {"reflectance"},
    ("bsdf", "twosided"): set(),
    ("bsdf", "conductor"): {"material", "eta", "k", "specular_reflectance"},
    ("bsdf", "dielectric"): {"int_ior", "ext_ior", "specular_reflectance", "specular_transmittance",
                             "cauchy_b"},   # cauchy_b: gibench-only dispersion (impl.spectral)
    ("bsdf", "roughconductor"): {"material", "eta", "k", "specular_reflectance", "alpha", "alpha_u",
                                 "alpha_v", "distribution", "sample_visible"},
    ("bsdf", "roughdielectric"): {"int_ior", "ext_ior", "specular_reflectance", "specular_transmittance",
                                  "alpha", "alpha_u", "alpha_v", "distribution", "sample_visible"},
    # gibench-only BSDFs of the thesis's 2.4.5 models (impl.materials; no Mitsuba plugin).
    ("bsdf", "gibench_cooktorrance"): {"reflectance", "kd", "ks", "int_ior", "ext_ior", "alphas",
                                       "weights"},
    ("bsdf", "gibench_difftrans"): {"reflectance", "transmittance"},
    ("emitter", "point"): {"intensity", "position", "to_world"},
    ("emitter", "directional"): {"irradiance", "direction", "to_world"},
    ("emitter", "spot"): {"intensity", "cutoff_angle", "beam_width", "to_world"},
    ("emitter", "area"): {"radiance"},
    ("texture", "checkerboard"): {"color0", "color1", "to_uv"},
    ("texture", "bitmap"): {"filename", "filter_type", "wrap_mode", "raw", "to_uv", "format"},
    ("emitter", "constant"): {"radiance"},
    # The rest of the Mitsuba 3 vocabulary users' files bring (see _VOCABULARY_DOC).
    ("shape", "serialized"): {"filename", "shape_index", "to_world", "flip_normals", "face_normals"},
    ("shape", "shapegroup"): set(),
    ("shape", "instance"): {"to_world"},
    ("bsdf", "plastic"): {"diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior",
                          "nonlinear"},
    ("bsdf", "roughplastic"): {"diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior",
                               "nonlinear", "alpha", "distribution", "sample_visible"},
    ("bsdf", "normalmap"): {"flip_invalid_normals", "use_shadowing_function"},
    ("bsdf", "thindielectric"): {"int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"},
    ("bsdf", "mask"): {"opacity"},
    ("bsdf", "blendbsdf"): {"weight"},
    ("bsdf", "bumpmap"): {"scale", "flip_invalid_normals", "use_shadowing_function"},
    ("emitter", "envmap"): {"filename", "scale", "to_world", "mis_compensation"},
    ("emitter", "projector"): {"irradiance", "scale", "to_world", "fov", "fov_axis", "focal_length"},
}




#: Largest film gibench renders: each side at most 16384 pixels and at most
#: 2**25 pixels in all (8192 x 4096); larger films are refused at load rather
#: than failing on allocation (an image and its variance in float64 already
#: take 1.6 GB at the limit).
MAX_FILM_SIDE = 16384
MAX_FILM_PIXELS = 1 << 25

#: Largest world-space coordinate (and sphere radius): 1e18, so squared distances
#: (1e36) stay within float32's range (3.4e38), as Mitsuba's renders need.
MAX_COORDINATE = 1e18

#: Largest bitmap texture read (pixels): a 12000² PNG would need 3.5 GB as float64 RGB.
MAX_TEXTURE_PIXELS = 1 << 26

# What each property must be, whatever plugin it belongs to: (kind, check, meaning).
# kind: "number" (<float>/<integer>), "integer" (an integral <integer> or <float>),
# "colour" (<rgb>/<spectrum>/<float>/<integer>, every component >= 0), "vector"
# (<point>/<vector>), "transform", "boolean", "string", "ior" (a number > 0 or a
# material name).  check(v) -> True when the value is in range.
_SCHEMA = {
    "fov": ("number", lambda v: 0.0 < v < 180.0, "in (0, 180) degrees"),
    "near_clip": ("number", lambda v: v > 0.0, "> 0"),
    "far_clip": ("number", lambda v: v > 0.0, "> 0"),
    "focus_distance": ("number", lambda v: v > 0.0, "> 0"),
    "aperture_radius": ("number", lambda v: v >= 0.0, ">= 0"),
    "shutter_open": ("number", None, ""),
    "shutter_close": ("number", None, ""),
    "width": ("integer", lambda v: 1 <= v <= MAX_FILM_SIDE, f"in [1, {MAX_FILM_SIDE}]"),
    "height": ("integer", lambda v: 1 <= v <= MAX_FILM_SIDE, f"in [1, {MAX_FILM_SIDE}]"),
    "sample_count": ("integer", lambda v: v >= 1, ">= 1"),
    "seed": ("integer", None, ""),
    "stddev": ("number", lambda v: v > 0.0, "> 0"),
    "radius": ("number", lambda v: v > 0.0, "> 0"),
    "cutoff_angle": ("number", lambda v: 0.0 < v <= 180.0, "in (0, 180] degrees"),
    "beam_width": ("number", lambda v: 0.0 < v <= 180.0, "in (0, 180] degrees"),
    "alpha": ("number", lambda v: v >= 0.0, ">= 0"),
    "alpha_u": ("number", lambda v: v >= 0.0, ">= 0"),
    "alpha_v": ("number", lambda v: v >= 0.0, ">= 0"),
    "cauchy_b": ("number", lambda v: v >= 0.0, ">= 0"),
    "kd": ("number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
    "ks": ("number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
    "int_ior": ("ior", lambda v: v > 0.0, "> 0 or a material name"),
    "focal_length": ("string", None, ""),
    "shape_index": ("integer", lambda v: v >= 0, ">= 0"),
    "scale": ("number", None, ""),
    "diffuse_reflectance": ("colour", None, ">= 0"),
    "opacity": ("number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
    "weight": ("number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
    "nonlinear": ("boolean", None, ""),
    "flip_invalid_normals": ("boolean", None, ""),
    "use_shadowing_function": ("boolean", None, ""),
    "mis_compensation": ("boolean", None, ""),
    "ext_ior": ("ior", lambda v: v > 0.0, "> 0 or a material name"),
    **{name: ("colour", None, ">= 0") for name in (
        "reflectance", "radiance", "intensity", "irradiance", "specular_reflectance",
        "specular_transmittance", "color0", "color1", "eta", "k", "transmittance")},
    **{name: ("vector", None, "") for name in (
        "center", "position", "direction", "p0", "p1", "gibench_velocity", "gibench_angular_velocity",
        "gibench_pivot")},
    **{name: ("transform", None, "") for name in ("to_world", "to_uv")},
    **{name: ("boolean", None, "") for name in (
        "flip_normals", "face_normals", "raw", "sample_visible", "jitter")},
    **{name: ("string", None, "") for name in (
        "fov_axis", "filename", "material", "distribution", "filter_type", "wrap_mode",
        "pixel_format", "component_format", "format", "alphas", "weights")},
}

_KIND_TAGS = {
    "number": ("float", "integer"), "integer": ("integer", "float"),
    "colour": ("rgb", "spectrum", "float", "integer"), "vector": ("point", "vector"),
    "transform": ("transform",), "boolean": ("boolean",), "string": ("string",),
    "ior": ("float", "integer", "string"),
}


def _check_property(ctx, el, name: str, value):
    """``value`` of property ``name`` (from element ``el``) checked against
    :data:`_SCHEMA`: the right element type, finite, in range; returns it (an
    integral float for an integer property becomes an int)."""
    spec = _SCHEMA.get(name)
    if spec is None:
        return value
    kind, check, meaning = spec
    if el.tag not in _KIND_TAGS[kind]:
        raise ctx.error(el, f"'{name}' must be given as "
                            f"{' or '.join(f'<{t}>' for t in _KIND_TAGS[kind])}, not <{el.tag}>")
    if kind == "integer":
        if float(value) != int(value):
            raise ctx.error(el, f"'{name}' must be an integer, got {short(value)}")
        value = int(value)
    if kind == "colour":
        comps = value.values if isinstance(value, Spectrum) else np.atleast_1d(value)
        if np.any(np.asarray(comps, dtype=np.float64) < 0.0):
            raise ctx.error(el, f"'{name}' must be >= 0 in every component")
    if kind == "transform" and name == "to_world":
        det = float(np.linalg.det(value[:3, :3]))
        if not (np.isfinite(det) and abs(det) > 1e-300):
            raise ctx.error(el, "to_world is singular (a zero scale or a degenerate matrix)")
    if check is not None and not (kind == "ior" and isinstance(value, str)) and not check(value):
        raise ctx.error(el, f"'{name}' must be {meaning}, got {short(value)}")
    return value


class _Ctx(Document):
    """The resolved document plus the ``id``s of its elements (for ``<ref>``)."""

    def __init__(self, path: Path, defines: dict[str, str] | None = None):
        super().__init__(path, defines)
        self.ids: dict[str, etree._Element] = {}

# ---------------------------------------------------------------- values ---

def _floats(ctx, el, text: str, n: int | None = None) -> np.ndarray:
    try:
        vals = np.array([float(x) for x in re.split(r"[\s,]+", text.strip()) if x], dtype=np.float64)
    except ValueError:
        raise ctx.error(el, f"cannot parse numbers from '{short(text)}'") from None
    if not np.all(np.isfinite(vals)):
        raise ctx.error(el, f"not a finite number in '{short(text)}'")
    if n is not None and len(vals) != n:
        raise ctx.error(el, f"expected {n} numbers, got {len(vals)} in '{short(text)}'")
    return vals


def _vec3(ctx, el, key: str = "value") -> np.ndarray:
    """A 3-vector from ``value="x, y, z"`` or x/y/z attributes (missing ones are 0)."""
    v = ctx.attr(el, key)
    if v is not None:
        vals = _floats(ctx, el, v)
        if len(vals) == 1:
            return np.repeat(vals, 3)
        if len(vals) != 3:
            raise ctx.error(el, f"expected 3 numbers in {key}='{short(v)}'")
        return vals
    return np.array([_floats(ctx, el, ctx.attr(el, a, "0"), 1)[0] for a in "xyz"])


def _transform(ctx, el) -> np.ndarray:
    m = np.eye(4)
    for op in el:
        if not isinstance(op.tag, str):
            continue
        try:
            if op.tag == "translate":
                m = tf.translate(_vec3(ctx, op)) @ m
            elif op.tag == "scale":
                v = ctx.attr(op, "value")
                s = _floats(ctx, op, v) if v is not None else np.array(
                    [_floats(ctx, op, ctx.attr(op, a, "1"), 1)[0] for a in "xyz"])
                if len(s) not in (1, 3):
                    raise ctx.error(op, f"expected 1 or 3 numbers in value='{short(v)}'")
                m = tf.scale(s if len(s) == 3 else np.repeat(s, 3)) @ m
            elif op.tag == "rotate":
                axis = _vec3(ctx, op) if op.get("value") is not None else np.array(
                    [_floats(ctx, op, ctx.attr(op, a, "0"), 1)[0] for a in "xyz"])
                m = tf.rotate(axis, _floats(ctx, op, ctx.attr(op, "angle", "0"), 1)[0]) @ m
            elif op.tag == "lookat":
                o = _floats(ctx, op, ctx.attr(op, "origin", ""), 3)
                t = _floats(ctx, op, ctx.attr(op, "target", ""), 3)
                u = _floats(ctx, op, ctx.attr(op, "up", "0, 1, 0"), 3)
                m = tf.look_at(o, t, u) @ m
            elif op.tag == "matrix":
                vals = _floats(ctx, op, ctx.attr(op, "value", ""))
                if len(vals) == 9:
                    mm = np.eye(4)
                    mm[:3, :3] = vals.reshape(3, 3)
                elif len(vals) == 16:
                    mm = vals.reshape(4, 4)
                else:
                    raise ctx.error(op, f"matrix needs 9 or 16 values, got {len(vals)}")
                m = mm @ m
            else:
                raise ctx.error(op, "unsupported transform operation "
                                    "(supported: translate, rotate, scale, lookat, matrix)")
        except ValueError as exc:
            if isinstance(exc, SceneError):
                raise
            raise ctx.error(op, str(exc)) from None
    if not np.all(np.isfinite(m)):
        raise ctx.error(el, "the composed transform is not finite (overflow)")
    return m


def _value(ctx, el):
    tag = el.tag
    if tag == "transform":
        return _transform(ctx, el)
    v = ctx.attr(el, "value")
    if tag in ("point", "vector"):
        return _vec3(ctx, el)
    if v is None:
        raise ctx.error(el, "missing 'value' attribute")
    if tag == "float":
        return float(_floats(ctx, el, v, 1)[0])
    if tag == "integer":
        try:
            i = int(v)
        except ValueError:
            raise ctx.error(el, f"'{short(v)}' is not an integer") from None
        if not -2**63 <= i < 2**63:                 # Mitsuba's integers are 64-bit
            raise ctx.error(el, f"integer '{short(v)}' is outside the 64-bit range")
        return i
    if tag == "boolean":
        if v.lower() not in ("true", "false"):
            raise ctx.error(el, f"'{short(v)}' is not a boolean (true/false)")
        return v.lower() == "true"
    if tag == "string":
        return v
    if tag == "spectrum":
        return _spectrum(ctx, el, v)
    if tag == "rgb":
        vals = _floats(ctx, el, v)
        if len(vals) == 1:
            vals = np.repeat(vals, 3)
        if len(vals) != 3:
            raise ctx.error(el, f"rgb needs 1 or 3 values, got {len(vals)}")
        return vals
    raise ctx.error(el, "unsupported value element")


class _Plugin:
    """One plugin element: its type, properties (with source elements) and children."""

    def __init__(self, ctx: _Ctx, el, kind: str):
        self.ctx, self.el, self.kind = ctx, el, kind
        self.type = ctx.attr(el, "type")
        if self.type is None:
            raise ctx.error(el, "missing 'type' attribute")
        if (kind, self.type) in REFUSED:
            raise ctx.error(el, f"{kind} '{self.type}' is not supported: {REFUSED[(kind, self.type)]}")
        if kind in SUPPORTED and self.type not in SUPPORTED[kind]:
            raise ctx.error(el, f"unsupported {kind} type '{self.type}' "
                                f"(supported: {', '.join(SUPPORTED[kind])})")
        self.props: dict[str, object] = {}
        self.children: list[tuple[str | None, etree._Element]] = []
        allowed = _PROPS.get((kind, self.type))
        for c in el:
            if not isinstance(c.tag, str):
                continue
            if c.tag in _VALUE_TAGS:
                name = ctx.attr(c, "name")
                if name is None:
                    raise ctx.error(c, "missing 'name' attribute")
                if allowed is not None and name not in allowed:
                    raise ctx.error(c, f"unsupported property '{name}' of {kind} '{self.type}' "
                                       f"(supported: {', '.join(sorted(allowed)) or 'none'})")
                self.props[name] = _check_property(ctx, c, name, _value(ctx, c))
            elif c.tag == "ref":
                ref_id = ctx.attr(c, "id")
                if ref_id not in ctx.ids:
                    raise ctx.error(c, f"reference to unknown id '{ref_id}'")
                if ctx.ids[ref_id].tag == "medium":
                    raise _medium_error(ctx, c)
                self.children.append((ctx.attr(c, "name"), ctx.ids[ref_id]))
            elif c.tag == "medium":
                raise _medium_error(ctx, c)
            else:
                self.children.append((ctx.attr(c, "name"), c))

    def get(self, name, default=None):
        return self.props.get(name, default)

    def child_elements(self, tag: str):
        return [c for _, c in self.children if c.tag == tag]

    def unexpected_children(self, allowed: tuple[str, ...]):
        for _, c in self.children:
            if c.tag not in allowed:
                raise self.ctx.error(c, f"unsupported element inside {self.kind} '{self.type}'")


def _spectrum(ctx, el, text: str) -> Spectrum:
    """``<spectrum value="0.5"/>`` or ``value="400:0.1, 500:0.2, ..."`` (nm, increasing)."""
    items = [t for t in re.split(r"[,\s]+", text.strip()) if t]
    if not items:
        raise ctx.error(el, "spectrum needs a value")
    if len(items) == 1 and ":" not in items[0]:
        return Spectrum(values=(float(_floats(ctx, el, items[0], 1)[0]),))
    wl, vals = [], []
    for item in items:
        parts = item.split(":")
        if len(parts) != 2:
            raise ctx.error(el, f"spectrum entry '{item}' is not 'wavelength:value'")
        try:
            wl.append(float(parts[0]))
            vals.append(float(parts[1]))
        except ValueError:
            raise ctx.error(el, f"spectrum entry '{item}' is not 'wavelength:value'") from None
    if len(wl) < 2 or any(b <= a for a, b in zip(wl, wl[1:])):
        raise ctx.error(el, "spectrum wavelengths must be at least two and strictly increasing")
    if not all(np.isfinite(wl + vals)) or min(wl) <= 0:
        raise ctx.error(el, "spectrum wavelengths must be positive and values finite")
    return Spectrum(wavelengths=tuple(wl), values=tuple(vals))


def _rgb(ctx, plugin, name, default):
    v = plugin.get(name, default)
    if isinstance(v, Spectrum):
        v = v.to_rgb(emitter=plugin.kind == "emitter")
    if isinstance(v, float | int):
        v = np.repeat(float(v), 3)
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,):
        raise ctx.error(plugin.el, f"'{name}' must be an rgb or float value")
    if not np.all(np.isfinite(v)):
        raise ctx.error(plugin.el, f"'{name}' is not finite in RGB ({v.tolist()}: a spectrum "
                                   "too large to integrate)")
    if np.any(v < 0.0):
        # A non-negative spectrum can still fall outside the sRGB gamut; Mitsuba's RGB
        # variants clamp it with a warning, gibench refuses it rather than guess.
        raise ctx.error(plugin.el, f"'{name}' converts to an RGB outside the sRGB gamut "
                                   f"({', '.join(f'{x:.4g}' for x in v)})")
    return v


# ----------------------------------------------------------------- parts ---

def _material(ctx, el, materials: list, cache: dict) -> int:
    # Key by the element's path in the document: lxml proxies are transient,
    # so id(el) can be reused by another element once a proxy is freed.
    key = el.getroottree().getpath(el)
    if key in cache:
        return cache[key]
    p = _Plugin(ctx, el, "bsdf")
    p, opacity = _mask_wrapper(ctx, p)
    if p.type == "blendbsdf":
        materials.append(_blend(ctx, p, opacity))
        cache[key] = len(materials) - 1
        return cache[key]
    p, shading = _shading_wrapper(ctx, p)
    twosided = False
    if p.type == "twosided":
        inner = p.child_elements("bsdf")
        p.unexpected_children(("bsdf",))
        if len(inner) != 1:
            raise ctx.error(el, "twosided needs exactly one nested bsdf")
        p = _Plugin(ctx, inner[0], "bsdf")
        if p.type == "twosided":
            raise ctx.error(inner[0], "nested twosided bsdf")
        if shading is None:
            p, shading = _shading_wrapper(ctx, p)
        elif shading is not None:
            shading["wraps_twosided"] = True         # normalmap(twosided(bsdf)), not the reverse
        twosided = True
    if p.type in _WRAPPERS:
        raise ctx.error(p.el, f"a {p.type} bsdf must wrap a plain bsdf (at most one normalmap or "
                              "bumpmap, outside or inside twosided)")
    if p.type in ("mask", "blendbsdf"):
        raise ctx.error(p.el, f"a {p.type} bsdf must be the outermost bsdf (it may wrap twosided, "
                              "normalmap, bumpmap or a plain bsdf)")
    texture = None
    if p.type == "diffuse":
        p.unexpected_children(("texture",))
        texture = _texture(ctx, p)
        textures = {}
    else:
        textures = _param_textures(ctx, p)
    if p.type in ("roughconductor", "roughdielectric"):
        _check_roughness(ctx, p, textures)
    if texture is not None:
        refl = tuple(float(x) for x in texture_mean(texture))
    elif p.type in ("plastic", "roughplastic"):
        refl = _plastic_albedo(ctx, p, textures)
    else:
        refl = tuple(_rgb(ctx, p, "reflectance", 0.5)) if p.type == "diffuse" else (0.0, 0.0, 0.0)
    params = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in p.props.items()}
    materials.append(Material(kind=p.type, reflectance=refl, twosided=twosided, params=params,
                              name=ctx.attr(el, "id", "") or "", texture=texture, textures=textures,
                              shading=shading, opacity=opacity))
    cache[key] = len(materials) - 1
    return cache[key]


def _texture(ctx, bsdf) -> dict | None:
    """The ``reflectance`` texture nested in a diffuse bsdf, or None."""
    found = [(name, c) for name, c in bsdf.children if c.tag == "texture"]
    if not found:
        return None
    if len(found) > 1:
        raise ctx.error(found[1][1], "a diffuse bsdf takes at most one texture")
    name, el = found[0]
    if name != "reflectance":
        raise ctx.error(el, f"a texture of a diffuse bsdf must be named 'reflectance', got '{name}'")
    if "reflectance" in bsdf.props:
        raise ctx.error(el, "'reflectance' is given both as a value and as a texture")
    return _texture_element(ctx, el)


def _texture_element(ctx, el) -> dict:
    """A ``<texture>`` element (``checkerboard`` or ``bitmap``) as the model's texture dict."""
    t = _Plugin(ctx, el, "texture")
    t.unexpected_children(())
    m = np.asarray(t.get("to_uv", np.eye(4)), dtype=np.float64)
    # Mitsuba reads a 4x4 to_uv as a 2D affine map: the upper-left 2x2 block and
    # the first two entries of the translation column.
    to_uv = np.array([[m[0, 0], m[0, 1], m[0, 3]], [m[1, 0], m[1, 1], m[1, 3]], [0.0, 0.0, 1.0]])
    if t.type == "bitmap":
        return _bitmap(ctx, t, to_uv)
    return {"type": t.type, "color0": tuple(_rgb(ctx, t, "color0", 0.4)),
            "color1": tuple(_rgb(ctx, t, "color1", 0.2)), "to_uv": to_uv.tolist()}


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The exact sRGB decoding curve (IEC 61966-2-1), as Mitsuba's ``Bitmap`` applies it."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _bitmap(ctx, t, to_uv) -> dict:
    """Mitsuba's ``bitmap`` texture: the image in linear RGB and its lookup options.

    8-bit and 16-bit images (PNG, JPEG) are sRGB-encoded and decoded with the sRGB
    curve unless ``raw`` is true; float images (EXR) are taken as linear, as Mitsuba
    does.  Grey images become RGB; an alpha channel is dropped (Mitsuba's RGB
    reflectance ignores it too).
    """
    fn = t.get("filename")
    if fn is None:
        raise ctx.error(t.el, "bitmap texture needs a 'filename' string")
    path = ctx.resolve(t.el, fn, "image file")
    filt = t.get("filter_type", "bilinear")
    wrap = t.get("wrap_mode", "repeat")
    if filt not in ("bilinear", "nearest"):
        raise ctx.error(t.el, f"unknown filter_type '{filt}' (bilinear, nearest)")
    if wrap not in ("repeat", "clamp", "mirror"):
        raise ctx.error(t.el, f"unknown wrap_mode '{wrap}' (repeat, clamp, mirror)")
    if t.get("format", "variant") != "variant":
        raise ctx.error(t.el, "bitmap 'format' other than 'variant' is not supported")
    raw = bool(t.get("raw", False))
    try:
        if path.suffix.lower() == ".exr":
            from .imageio import read_exr

            img = np.asarray(read_exr(path, allow_nonfinite=False, max_pixels=MAX_TEXTURE_PIXELS),
                             dtype=np.float64)
            srgb = False
        else:
            from PIL import Image

            with Image.open(path) as im:
                if im.width * im.height > MAX_TEXTURE_PIXELS:
                    raise ValueError(f"{im.width}x{im.height} pixels is more than gibench's limit "
                                     f"of {MAX_TEXTURE_PIXELS} texture pixels")
                if im.mode not in ("L", "LA", "RGB", "RGBA", "I", "I;16", "I;16B", "I;16L"):
                    im = im.convert("RGBA" if "A" in im.mode or "transparency" in im.info else "RGB")
                mode = im.mode
                arr = np.asarray(im)
            if arr.dtype == np.uint8:
                img = arr.astype(np.float64) / 255.0
            elif arr.dtype in (np.uint16, np.int32) and mode.startswith("I"):
                img = arr.astype(np.float64) / 65535.0
            else:
                raise ValueError(f"unsupported pixel type {arr.dtype} (mode {mode})")
            srgb = not raw
    except Exception as exc:                      # noqa: BLE001 - any decoder failure is the file's
        raise ctx.error(t.el, f"cannot read image {path}: {short(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 200)}") from None
    if img.ndim == 2:
        img = img[:, :, None]
    if img.shape[2] in (2, 4):                     # grey + alpha, RGBA: drop alpha
        img = img[:, :, :-1]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    img = np.ascontiguousarray(img[:, :, :3], dtype=np.float64)
    if srgb:
        img = _srgb_to_linear(img)
    ctx.files.append(path)
    return {"type": "bitmap", "data": img, "filename": str(path), "wrap_mode": wrap,
            "filter_type": filt, "to_uv": to_uv.tolist()}


def _shape(ctx, el, materials, cache, default_mat) -> Shape:
    p = _Plugin(ctx, el, "shape")
    p.unexpected_children(("bsdf", "emitter"))
    m = p.get("to_world", np.eye(4))
    bsdfs = p.child_elements("bsdf")
    if len(bsdfs) > 1:
        raise ctx.error(el, "a shape takes at most one bsdf")
    # Mitsuba's default BSDF: diffuse 0.5, black on an emitter (shape.cpp).
    emitting = any(ctx.attr(e, "type") == "area" for e in p.child_elements("emitter"))
    mat = _material(ctx, bsdfs[0], materials, cache) if bsdfs else default_mat(emitter=emitting)
    emit = emit_spectrum = None
    for e in p.child_elements("emitter"):
        ep = _Plugin(ctx, e, "emitter")
        if ep.type != "area":
            raise ctx.error(e, "only an 'area' emitter can be attached to a shape")
        ep.unexpected_children(())
        emit = _rgb(ctx, ep, "radiance", 1.0)
        emit_spectrum = ep.get("radiance") if isinstance(ep.get("radiance"), Spectrum) else None
    flip = bool(p.get("flip_normals", False))
    name = ctx.attr(el, "id", "") or ""
    tex = _uv_texture(materials[mat])
    if tex is not None and p.type not in _UV_SHAPES:
        raise ctx.error(el, f"a {tex['type']} texture on a {p.type} is not supported: the loader "
                            f"reproduces Mitsuba's uv only for {', '.join(_UV_SHAPES)}")
    if p.type == "sphere":
        center = np.asarray(p.get("center", np.zeros(3)), dtype=np.float64)
        radius = float(p.get("radius", 1.0))
        s = tf.uniform_scale_factor(m)
        if s is None:
            raise ctx.error(el, "sphere to_world must be a similarity transform (uniform scale)")
        if not (np.isfinite(radius * s) and radius * s > 0.0):
            raise ctx.error(el, f"sphere radius in world units must be finite and > 0, got {radius * s}")
        z = tf.transform_vectors(m, [0.0, 0.0, 1.0]) / s
        if anisotropic_roughness(materials[mat]) and abs(z[2]) < 1.0 - 1e-9:
            raise ctx.error(el, "anisotropic roughness on a sphere whose to_world turns its z axis is "
                                "not supported: the scene model keeps no sphere rotation, and the "
                                "tangent runs about the sphere's z axis (Mitsuba's)")
        velocity = _velocity(ctx, el, p)
        return Shape(kind="sphere", material=mat, name=name, source="sphere",
                     center=tf.transform_points(m, center), radius=radius * s,
                     flip_normals=flip, emitter_radiance=emit, emitter_spectrum=emit_spectrum,
                     velocity=velocity)
    uvs = None
    if p.type in ("disk", "cylinder"):
        v, f, n, m = _analytic_mesh(ctx, p, m)
    elif p.type in ("rectangle", "cube"):
        v, f, n = rectangle() if p.type == "rectangle" else cube()
        if p.type == "rectangle":
            uvs = 0.5 * (v[:, :2] + 1.0)      # Mitsuba: local (x, y) ∈ [-1, 1]² -> uv ∈ [0, 1]²
    elif p.type == "serialized":
        v, f, n, uvs = _serialized_mesh(ctx, p, tex)
    elif p.type in ("shapegroup", "instance"):
        raise ctx.error(el, f"a {p.type} must be at scene level (Mitsuba does not nest them)")
    else:
        fn = p.get("filename")
        if fn is None:
            raise ctx.error(el, "missing 'filename' string")
        path = ctx.resolve(el, fn, "mesh file")
        try:
            v, f, n, uvs = load_mesh_uvs(path, p.type)
        except MeshError as exc:
            raise ctx.error(el, str(exc)) from None
        ctx.files.append(path)
        if tex is not None and uvs is None:
            raise ctx.error(el, f"a {tex['type']} texture needs texture coordinates, and {path.name} "
                                "has none (OBJ 'vt' lines)")
        if n is None and not p.get("face_normals", False):
            n = angle_weighted_normals(v, f)
        if p.get("face_normals", False):
            n = None
    v_world = tf.transform_points(m, v)
    n_world = None if n is None else tf.transform_normals(m, n)
    if np.linalg.det(m[:3, :3]) < 0:
        f = f[:, ::-1].copy()          # a mirroring transform flips the winding; keep normals outward
    velocity, omega = _motion(ctx, el, p)
    pivot = None
    if omega is not None:
        pivot = p.get("gibench_pivot")
        pivot = v_world.mean(axis=0) if pivot is None else np.asarray(pivot, dtype=np.float64).reshape(-1)
        if pivot.shape != (3,) or not np.all(np.isfinite(pivot)):
            raise ctx.error(el, f"gibench_pivot must be a finite point, got {pivot.tolist()}")
    elif p.get("gibench_pivot") is not None:
        raise ctx.error(el, "gibench_pivot without gibench_angular_velocity (nothing turns about it)")
    if (velocity is not None or omega is not None) and emit is not None:
        raise ctx.error(el, "a moving mesh cannot be an emitter (its light samples would stay put)")
    return Shape(kind="mesh", material=mat, name=name, source=p.type, vertices=v_world,
                 faces=f, normals=n_world, flip_normals=flip, emitter_radiance=emit, uvs=uvs,
                 emitter_spectrum=emit_spectrum, velocity=velocity, angular_velocity=omega,
                 pivot=pivot)


def _motion(ctx, el, p):
    """``(velocity, angular_velocity)`` of a moving camera or mesh (gibench-only
    ``<vector name="gibench_velocity">``, world units per unit of shutter time, and
    ``<vector name="gibench_angular_velocity">``, a rotation vector in radians per unit
    time), each None when absent; both finite 3-vectors."""
    out = []
    for key in _MOTION:
        v = p.get(key)
        if v is not None:
            v = np.asarray(v, dtype=np.float64).reshape(-1)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ctx.error(el, f"{key} must be a finite vector, got {v.tolist()}")
        out.append(v)
    return tuple(out)


def _analytic_mesh(ctx, p, m):
    """Mitsuba's ``disk`` / ``cylinder`` as a tessellated mesh (see :mod:`core.meshes`):
    (vertices, faces, normals, object-to-world).  The cylinder's object-to-world is
    Mitsuba's: to_world · translate(p0) · frame(p1 − p0) · scale(radius, radius, |p1 − p0|);
    Mitsuba refuses a non-uniform scale across the axis, and so does the loader."""
    if p.type == "disk":
        return (*disk(), m)
    p0 = np.asarray(p.get("p0", np.zeros(3)), dtype=np.float64)
    p1 = np.asarray(p.get("p1", [0.0, 0.0, 1.0]), dtype=np.float64)
    radius = float(p.get("radius", 1.0))
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length == 0.0 or radius <= 0.0:
        raise ctx.error(p.el, f"cylinder needs p0 != p1 and radius > 0 (radius {radius}, length {length})")
    zax = d / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(zax[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    xax = np.cross(helper, zax)
    xax /= np.linalg.norm(xax)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2] = xax, np.cross(zax, xax), zax
    m = m @ tf.translate(p0) @ frame @ tf.scale([radius, radius, length])
    ex, ey = m[:3, 0], m[:3, 1]
    if abs(np.linalg.norm(ex) - np.linalg.norm(ey)) > 1e-6 * np.linalg.norm(ex) or \
            abs(ex @ ey) > 1e-6 * (ex @ ex) or abs(ex @ m[:3, 2]) > 1e-6 * np.linalg.norm(ex) * np.linalg.norm(m[:3, 2]) \
            or abs(ey @ m[:3, 2]) > 1e-6 * np.linalg.norm(ey) * np.linalg.norm(m[:3, 2]):
        raise ctx.error(p.el, "cylinder to_world must scale the cross-section uniformly and keep it "
                              "perpendicular to the axis (as Mitsuba requires)")
    return (*cylinder(), m)


def _environment(ctx, el) -> np.ndarray:
    """Mitsuba's ``constant`` emitter: uniform radiance from every direction (RGB)."""
    p = _Plugin(ctx, el, "emitter")
    p.unexpected_children(())
    return _rgb(ctx, p, "radiance", 1.0)


def _velocity(ctx, el, p):
    """A moving sphere's ``<vector name="gibench_velocity">`` (world units per unit of
    shutter time; gibench-only: references/motion_blur.py strips it before Mitsuba
    reads the file and moves ``center`` instead, so the sphere must give ``center``
    and no ``to_world``)."""
    v = p.get("gibench_velocity")
    if v is None:
        return None
    if "to_world" in p.props or "center" not in p.props:
        raise ctx.error(el, "a moving sphere (gibench_velocity) needs a 'center' point and no "
                            "'to_world' (its reference moves the center)")
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ctx.error(el, f"gibench_velocity must be a finite vector, got {v.tolist()}")
    return v


def _unit(ctx, el, d) -> np.ndarray:
    """``d`` normalised (scaled by its largest component first, so that components
    near the float limit do not overflow the norm); a zero or non-finite direction
    is an error."""
    d = np.asarray(d, dtype=np.float64)
    big = np.abs(d).max() if d.size else 0.0
    if not (np.isfinite(big) and big > 0.0):
        raise ctx.error(el, f"the emitter's direction must be finite and non-zero, got {d.tolist()}")
    d = d / big
    return d / np.linalg.norm(d)


def _light(ctx, el) -> Light:
    p = _Plugin(ctx, el, "emitter")
    p.unexpected_children(())
    m = p.get("to_world", np.eye(4))
    name = ctx.attr(el, "id", "") or ""
    if p.type == "area":
        raise ctx.error(el, "an area emitter must be nested in a shape")
    if p.type == "point":
        pos = p.get("position")
        pos = tf.transform_points(m, np.zeros(3)) if pos is None else np.asarray(pos)
        return Light("point", _rgb(ctx, p, "intensity", 1.0), position=pos, name=name)
    if p.type == "directional":
        d = p.get("direction")
        d = tf.transform_vectors(m, [0.0, 0.0, 1.0]) if d is None else np.asarray(d, dtype=np.float64)
        return Light("directional", _rgb(ctx, p, "irradiance", 1.0), direction=_unit(ctx, el, d),
                     name=name)
    cutoff = float(p.get("cutoff_angle", 20.0))
    beam = float(p.get("beam_width", cutoff * 0.75))
    d = tf.transform_vectors(m, [0.0, 0.0, 1.0])
    return Light("spot", _rgb(ctx, p, "intensity", 1.0), position=tf.transform_points(m, np.zeros(3)),
                 direction=_unit(ctx, el, d), cutoff_angle=cutoff, beam_width=beam, name=name,
                 to_world=np.asarray(m, dtype=np.float64))


def _camera(ctx, el) -> Camera:
    p = _Plugin(ctx, el, "sensor")
    p.unexpected_children(("film", "sampler"))
    film, spp = Film(), 4
    for f in p.child_elements("film"):
        fp = _Plugin(ctx, f, "film")
        fp.unexpected_children(("rfilter",))
        rf, rfp = "gaussian", {}
        for r in fp.child_elements("rfilter"):
            rp = _Plugin(ctx, r, "rfilter")
            rp.unexpected_children(())
            rf, rfp = rp.type, dict(rp.props)
        film = Film(int(fp.get("width", 768)), int(fp.get("height", 576)), rf, rfp)
        if film.width * film.height > MAX_FILM_PIXELS:
            raise ctx.error(f, f"film of {film.width}x{film.height} pixels is larger than gibench's "
                               f"limit of {MAX_FILM_PIXELS} pixels")
    for s in p.child_elements("sampler"):
        sp = _Plugin(ctx, s, "sampler")
        spp = int(sp.get("sample_count", 4))
    near, far = float(p.get("near_clip", 1e-2)), float(p.get("far_clip", 1e4))
    if not 0.0 < near < far:
        raise ctx.error(el, f"need 0 < near_clip < far_clip, got near_clip={near}, far_clip={far}")
    s_open, s_close = float(p.get("shutter_open", 0.0)), float(p.get("shutter_close", 0.0))
    if s_close < s_open:
        raise ctx.error(el, f"shutter_close ({s_close}) must not be before shutter_open ({s_open})")
    velocity, omega = _motion(ctx, el, p)
    common = dict(to_world=p.get("to_world", np.eye(4)), near_clip=near, far_clip=far, film=film,
                  sample_count=spp, kind=p.type, shutter_open=s_open, shutter_close=s_close,
                  velocity=velocity, angular_velocity=omega)
    if p.type == "orthographic":
        return Camera(**common)
    fov, axis = _sensor_fov(ctx, p)
    lens = {}
    if p.type == "thinlens":
        if "aperture_radius" not in p.props:
            raise ctx.error(el, "thinlens sensor needs 'aperture_radius'")
        radius = float(p.get("aperture_radius"))
        focus = float(p.get("focus_distance", far))
        if radius < 0.0 or not focus > 0.0:
            raise ctx.error(el, f"thinlens needs aperture_radius >= 0 and focus_distance > 0, "
                                f"got {radius} and {focus}")
        lens = dict(aperture_radius=radius, focus_distance=focus)
    return Camera(fov=fov, fov_axis=axis, **common, **lens)


def _integrator(ctx, el) -> dict:
    """Read the integrator (and nested ones) into a plain dict; not validated against a list."""
    out = {"type": ctx.attr(el, "type")}
    for c in el:
        if not isinstance(c.tag, str):
            continue
        if c.tag == "integrator":
            out.setdefault("nested", []).append(_integrator(ctx, c))
        elif c.tag in _VALUE_TAGS and c.tag != "transform":
            v = _value(ctx, c)
            out[ctx.attr(c, "name")] = v.tolist() if isinstance(v, np.ndarray) else v
    return out



def _check_extent(ctx, el, values) -> None:
    """World-space coordinates (vertices, centres, radii, positions) must lie within
    :data:`MAX_COORDINATE`: squared distances then stay finite in float32, which
    Mitsuba renders in, and areas and light pdfs stay finite in float64."""
    big = float(np.abs(np.asarray(values, dtype=np.float64)).max(initial=0.0))
    if not big <= MAX_COORDINATE:
        raise ctx.error(el, f"world coordinates up to {big:.3g} exceed gibench's limit of "
                            f"{MAX_COORDINATE:g}")


def load_scene(path, defines: dict | None = None) -> Scene:
    """Parse a Mitsuba 3 XML scene file into a :class:`~core.scene.Scene`.

    ``defines`` maps ``<default>`` names to values that replace the file's
    defaults (Mitsuba's ``-D name=value``); a name the file does not declare is
    still usable as ``$name``.

    Raises
    ------
    SceneError
        One line naming the file, the line and the element, for a missing file,
        malformed XML, an unsupported plugin or property, or a missing mesh.
    """
    path = Path(path)
    # Pass 1 (core.xmlscene): defaults, includes and paths; then ids.
    ctx = resolve(path, defines, cls=_Ctx)
    root = ctx.root
    for c in root.iter():
        if isinstance(c.tag, str) and c.get("id") is not None and c.tag != "ref":
            ctx.ids[ctx.attr(c, "id")] = c

    materials: list[Material] = []
    cache: dict = {}
    default_mat_index: dict[bool, int] = {}

    def default_mat(emitter: bool = False) -> int:
        """The material of a shape without a bsdf: Mitsuba's default, a diffuse 0.5, or a
        black diffuse on an area emitter (Mitsuba's ``Shape`` does the same)."""
        if emitter not in default_mat_index:
            rho = 0.0 if emitter else 0.5
            materials.append(Material(kind="diffuse", reflectance=(rho, rho, rho),
                                      name="(default, emitter)" if emitter else "(default)"))
            default_mat_index[emitter] = len(materials) - 1
        return default_mat_index[emitter]

    camera, shapes, lights, integrator = None, [], [], {"type": "path"}
    environment = None
    vocab = _Vocabulary()
    for c in root:
        if not isinstance(c.tag, str) or c.tag == "default":
            continue
        if vocab.element(ctx, c, shapes, lights, materials, cache, default_mat):
            continue
        if c.tag == "integrator":
            integrator = _integrator(ctx, c)
        elif c.tag == "sensor":
            if camera is not None:
                raise ctx.error(c, "more than one sensor")
            camera = _camera(ctx, c)
            _check_extent(ctx, c, camera.to_world[:3, 3])
        elif c.tag == "bsdf":
            _material(ctx, c, materials, cache)
        elif c.tag == "shape":
            shape = _shape(ctx, c, materials, cache, default_mat)
            if shape.kind == "sphere":
                _check_extent(ctx, c, [*shape.center, shape.radius])
            else:
                _check_extent(ctx, c, shape.vertices)
            shapes.append(shape)
        elif c.tag == "emitter" and ctx.attr(c, "type") == "constant":
            if environment is not None:
                raise ctx.error(c, "more than one constant environment emitter")
            environment = _environment(ctx, c)
        elif c.tag == "emitter":
            lights.append(_light(ctx, c))
            if lights[-1].position is not None:
                _check_extent(ctx, c, lights[-1].position)
        else:
            raise ctx.error(c, f"unsupported element '{c.tag}' at scene level "
                               "(supported: default, integrator, sensor, bsdf, shape, emitter)")
    if camera is None:
        raise ctx.error(root, "the scene has no sensor")
    vocab.finish(ctx, environment)
    shapes, materials = _used_materials(shapes, materials)
    return Scene(path=path, camera=camera, shapes=shapes, materials=materials, lights=lights,
                 integrator=integrator, files=ctx.files, environment=environment,
                 envmap=vocab.envmap)


# ------------------------------------------------------------ vocabulary ---
# The rest of the Mitsuba 3 vocabulary real scene files use: focal lengths,
# nested and referenced definitions, instancing, the serialized mesh format,
# plastic BSDFs, textures on any texturable parameter, normal and bump maps,
# envmap and projector emitters.  What the scene model records for each is in
# core.scene; which algorithm models what is Algorithm.models.

#: Mitsuba plugins refused by name, with the reason.
REFUSED = {
    ("bsdf", "principled"): "Disney's principled BSDF is not a model of the thesis (use diffuse, "
                            "plastic/roughplastic, conductor or dielectric and their rough forms)",
    ("bsdf", "principledthin"): "the thin principled BSDF is not a model of the thesis",
    ("emitter", "sunsky"): "the sun-sky model is not a model of the thesis",
    ("emitter", "timed_sunsky"): "the sun-sky model is not a model of the thesis",
}

#: BSDFs that perturb the shading normal of the one BSDF they wrap.
_WRAPPERS = ("normalmap", "bumpmap")

#: Parameters Mitsuba reads as textures, per BSDF (beyond a diffuse reflectance).
_TEXTURABLE = {
    "conductor": ("specular_reflectance", "eta", "k"),
    "roughconductor": ("specular_reflectance", "eta", "k", "alpha", "alpha_u", "alpha_v"),
    "dielectric": ("specular_reflectance", "specular_transmittance"),
    "roughdielectric": ("specular_reflectance", "specular_transmittance", "alpha", "alpha_u", "alpha_v"),
    "plastic": ("diffuse_reflectance", "specular_reflectance"),
    "roughplastic": ("diffuse_reflectance", "specular_reflectance"),
    "thindielectric": ("specular_reflectance", "specular_transmittance"),
}


def _medium_error(ctx, el) -> SceneError:
    return ctx.error(el, "participating media are out of scope: gibench renders surfaces only "
                         "(no medium, interior or exterior)")


def sensor_fov(props: dict, aspect: float) -> float:
    """The horizontal field of view (degrees) Mitsuba's ``parse_fov`` gives a sensor or
    projector with properties ``props`` and film aspect ``aspect`` (width/height).

    ``fov`` along ``fov_axis`` (x, y, diagonal, smaller, larger), or ``focal_length``
    (``"<f>mm"`` or ``"<f>"``, default ``"50mm"``) of a 35 mm film: the diagonal
    field of view 2 atan(√(36² + 24²) / (2 f)); ``fov_axis`` without ``fov`` is an
    error (Mitsuba's unreferenced property).
    Raises ``ValueError`` with Mitsuba's reasons.
    """
    if "fov" in props and "focal_length" in props:
        raise ValueError("give either a focal length ('focal_length') or a field of view ('fov'), "
                         "not both (as Mitsuba requires)")
    if "fov" not in props and "fov_axis" in props:
        raise ValueError("'fov_axis' is read only with 'fov'; with a focal length the field of view "
                         "is diagonal (Mitsuba refuses the unused property too)")
    if "fov" in props:
        fov = float(props["fov"])
        axis = str(props.get("fov_axis", "x")).lower()
        if axis == "smaller":
            axis = "y" if aspect > 1 else "x"
        elif axis == "larger":
            axis = "x" if aspect > 1 else "y"
    else:
        text = str(props.get("focal_length", "50mm"))
        num = text[:-2] if text.endswith("mm") else text
        try:
            f = float(num)
        except ValueError:
            raise ValueError(f"cannot parse the focal length '{short(text)}' (must be of the form "
                             "<x>mm)") from None
        if not (np.isfinite(f) and f > 0.0):
            raise ValueError(f"focal_length must be a finite length > 0, got '{short(text)}'")
        fov = float(np.rad2deg(2.0 * np.arctan(np.sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * f))))
        axis = "diagonal"
    if axis == "x":
        x_fov = fov
    elif axis == "y":
        x_fov = float(np.rad2deg(2.0 * np.arctan(np.tan(0.5 * np.deg2rad(fov)) * aspect)))
    elif axis == "diagonal":
        diagonal = 2.0 * np.tan(0.5 * np.deg2rad(fov))
        width = diagonal / np.sqrt(1.0 + 1.0 / (aspect * aspect))
        x_fov = float(np.rad2deg(2.0 * np.arctan(width * 0.5)))
    else:
        raise ValueError(f"unknown fov_axis '{short(axis)}' (x, y, diagonal, smaller, larger)")
    if not 0.0 < x_fov < 180.0:
        raise ValueError(f"the horizontal field of view must be in (0, 180) degrees, got {x_fov}")
    return x_fov


def _sensor_fov(ctx, p) -> tuple[float, str]:
    """(fov, fov_axis) for :class:`Camera`: the file's ``fov``/``fov_axis``, or a
    ``focal_length`` (default 50mm) as its diagonal field of view."""
    try:
        sensor_fov(p.props, 4.0 / 3.0)             # Mitsuba's checks (the aspect does not matter)
    except ValueError as exc:
        raise ctx.error(p.el, str(exc)) from None
    if "fov" in p.props:
        axis = str(p.get("fov_axis", "x")).lower()
        return float(p.get("fov")), axis
    text = str(p.get("focal_length", "50mm"))
    f = float(text[:-2] if text.endswith("mm") else text)
    return float(np.rad2deg(2.0 * np.arctan(np.sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * f)))), "diagonal"


def _shading_wrapper(ctx, p):
    """``(inner plugin, shading)`` of a ``normalmap``/``bumpmap`` bsdf ``p``, or ``(p, None)``."""
    if p.type not in _WRAPPERS:
        return p, None
    p.unexpected_children(("bsdf", "texture"))
    inner = p.child_elements("bsdf")
    texs = [(name, c) for name, c in p.children if c.tag == "texture"]
    if len(inner) != 1 or len(texs) != 1:
        raise ctx.error(p.el, f"{p.type} needs exactly one nested bsdf and one texture")
    name, tex_el = texs[0]
    if p.type == "normalmap" and name != "normalmap":
        raise ctx.error(tex_el, f"the texture of a normalmap must be named 'normalmap', got '{name}'")
    shading = {"type": p.type, "texture": _texture_element(ctx, tex_el),
               "flip_invalid_normals": bool(p.get("flip_invalid_normals", True)),
               "use_shadowing_function": bool(p.get("use_shadowing_function", True))}
    if p.type == "bumpmap":
        shading["scale"] = float(p.get("scale", 1.0))
    return _Plugin(ctx, inner[0], "bsdf"), shading


def _mask_wrapper(ctx, p):
    """``(inner plugin, opacity)`` of a ``mask`` bsdf ``p`` (Mitsuba's: the wrapped BSDF
    with probability ``opacity``, else the ray passes through), or ``(p, None)``.
    ``opacity`` is ``{"type": "constant", "value": a}`` (Mitsuba's default 0.5) or a
    texture dict."""
    if p.type != "mask":
        return p, None
    p.unexpected_children(("bsdf", "texture"))
    inner = p.child_elements("bsdf")
    texs = [(name, c) for name, c in p.children if c.tag == "texture"]
    if len(inner) != 1 or len(texs) > 1:
        raise ctx.error(p.el, "mask needs exactly one nested bsdf and at most one texture")
    if texs:
        name, tex_el = texs[0]
        if name != "opacity":
            raise ctx.error(tex_el, f"the texture of a mask must be named 'opacity', got '{name}'")
        if "opacity" in p.props:
            raise ctx.error(tex_el, "'opacity' is given both as a value and as a texture")
        opacity = _texture_element(ctx, tex_el)
    else:
        opacity = {"type": "constant", "value": float(p.get("opacity", 0.5))}
    q = _Plugin(ctx, inner[0], "bsdf")
    if q.type == "mask":
        raise ctx.error(inner[0], "nested mask bsdf")
    return q, opacity


def _blend(ctx, p, opacity) -> Material:
    """Mitsuba's ``blendbsdf``: (1 − weight) × the first nested BSDF + weight × the
    second; ``weight`` a float (default 0.5) or a texture (``textures["weight"]``).
    The two BSDFs are :attr:`Material.components`; ``reflectance`` is the blend of
    their reflectances at the mean weight."""
    p.unexpected_children(("bsdf", "texture"))
    inner = p.child_elements("bsdf")
    if len(inner) != 2:
        raise ctx.error(p.el, f"blendbsdf needs exactly two nested bsdfs, got {len(inner)}")
    textures = {}
    for name, c in p.children:
        if c.tag != "texture":
            continue
        if name != "weight" or "weight" in p.props or textures:
            raise ctx.error(c, f"the texture of a blendbsdf must be one, named 'weight', got '{name}'")
        textures["weight"] = _texture_element(ctx, c)
    parts: list[Material] = []
    for c in inner:
        _material(ctx, c, parts, {})
    w = float(np.mean(texture_mean(textures["weight"]))) if textures else float(p.get("weight", 0.5))
    refl = tuple((1.0 - w) * np.asarray(parts[0].reflectance) + w * np.asarray(parts[1].reflectance))
    params = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in p.props.items()}
    return Material(kind="blendbsdf", reflectance=refl, params=params, name=ctx.attr(p.el, "id", "") or "",
                    textures=textures, opacity=opacity, components=tuple(parts))


def _param_textures(ctx, p) -> dict:
    """The textures nested in (or referenced by) bsdf ``p``, by parameter name."""
    allowed = _TEXTURABLE.get(p.type, ())
    p.unexpected_children(("texture",) if allowed else ())
    out = {}
    for name, c in p.children:
        if name not in allowed:
            raise ctx.error(c, f"a texture of a {p.type} bsdf must be named one of "
                               f"{', '.join(allowed)}, got '{name}'")
        if name in p.props or name in out:
            raise ctx.error(c, f"'{name}' is given twice (a value or texture already)")
        out[name] = _texture_element(ctx, c)
    return out


def _check_roughness(ctx, p, textures: dict) -> None:
    """Mitsuba's rule for a rough BSDF's roughness: ``alpha`` or both of
    ``alpha_u``/``alpha_v`` (each a value or a texture), not both forms."""
    given = set(p.props) | set(textures)
    uv = {"alpha_u", "alpha_v"} & given
    if uv and "alpha" in given:
        raise ctx.error(p.el, "give either 'alpha' or 'alpha_u'/'alpha_v' (as Mitsuba requires)")
    if len(uv) == 1:
        raise ctx.error(p.el, f"'{uv.pop()}' needs its partner: both 'alpha_u' and 'alpha_v' must be "
                              "given (as Mitsuba requires)")


def _plastic_albedo(ctx, p, textures) -> tuple:
    """A plastic's ``diffuse_reflectance`` (Mitsuba's default 0.5; a texture's mean)."""
    if "diffuse_reflectance" in textures:
        return tuple(float(x) for x in texture_mean(textures["diffuse_reflectance"]))
    return tuple(_rgb(ctx, p, "diffuse_reflectance", 0.5))


def _uv_texture(m: Material) -> dict | None:
    """Any texture of material ``m`` that needs the shape's uv (None without one)."""
    if m.texture is not None:
        return m.texture
    for t in m.textures.values():
        return t
    if m.opacity is not None and m.opacity["type"] != "constant":
        return m.opacity
    for c in m.components:
        t = _uv_texture(c)
        if t is not None:
            return t
    return None if m.shading is None else m.shading["texture"]


def _serialized_mesh(ctx, p, tex):
    """Mitsuba's ``serialized`` shape: (vertices, faces, normals, uvs) in object space."""
    fn = p.get("filename")
    if fn is None:
        raise ctx.error(p.el, "missing 'filename' string")
    path = ctx.resolve(p.el, fn, "mesh file")
    try:
        v, f, n, uvs = load_serialized(path, int(p.get("shape_index", 0)))
    except MeshError as exc:
        raise ctx.error(p.el, str(exc)) from None
    ctx.files.append(path)
    if tex is not None and uvs is None:
        raise ctx.error(p.el, f"a {tex['type']} texture needs texture coordinates, and shape "
                              f"{int(p.get('shape_index', 0))} of {path.name} has none")
    if p.get("face_normals", False):
        n = None
    elif n is None:
        n = angle_weighted_normals(v, f)
    return v, f, n, uvs


def _emitter_texture(ctx, p, name: str) -> dict | None:
    """The texture ``name`` nested in emitter ``p`` (a spot's ``texture``, a
    projector's ``irradiance``), or None."""
    found = [(n, c) for n, c in p.children if c.tag == "texture"]
    if not found:
        return None
    n, el = found[0]
    if len(found) > 1 or n != name:
        raise ctx.error(el, f"a {p.type} emitter takes one texture, named '{name}'")
    return _texture_element(ctx, el)


def _projector(ctx, p) -> Light:
    """Mitsuba's ``projector``: a pinhole at to_world's origin projecting ``irradiance``
    (a texture, or a constant) × ``scale``; its field of view by ``parse_fov`` with
    the texture's aspect (1 for a constant)."""
    p.unexpected_children(("texture",))
    m = np.asarray(p.get("to_world", np.eye(4)), dtype=np.float64)
    tex = _emitter_texture(ctx, p, "irradiance")
    if tex is not None and "irradiance" in p.props:
        raise ctx.error(p.el, "'irradiance' is given both as a value and as a texture")
    aspect = 1.0
    if tex is not None and tex["type"] == "bitmap":
        h, w = tex["data"].shape[:2]
        aspect = w / h
    try:
        x_fov = sensor_fov(p.props, aspect)
    except ValueError as exc:
        raise ctx.error(p.el, str(exc)) from None
    d = tf.transform_vectors(m, [0.0, 0.0, 1.0])
    return Light("projector", _rgb(ctx, p, "irradiance", 1.0) if tex is None else np.ones(3),
                 position=tf.transform_points(m, np.zeros(3)), direction=d / np.linalg.norm(d),
                 name=ctx.attr(p.el, "id", "") or "", texture=tex, to_world=m, fov_x=x_fov,
                 scale=float(p.get("scale", 1.0)))


def _envmap(ctx, el) -> EnvMap:
    """Mitsuba's ``envmap``: the lat-long image in linear RGB (EXR as stored, 8-bit
    images sRGB-decoded), ``scale`` and ``to_world``."""
    p = _Plugin(ctx, el, "emitter")
    p.unexpected_children(())
    if p.get("filename") is None:
        raise ctx.error(el, "envmap emitter needs a 'filename' string")
    data = _bitmap(ctx, p, np.eye(3))["data"]
    if data.shape[0] < 2 or data.shape[1] < 2:
        raise ctx.error(el, f"envmap image must be at least 2x2 pixels, got "
                            f"{data.shape[1]}x{data.shape[0]}")
    scale = float(p.get("scale", 1.0))
    if not scale >= 0.0:
        raise ctx.error(el, f"envmap 'scale' must be >= 0, got {scale}")
    m = np.asarray(p.get("to_world", np.eye(4)), dtype=np.float64)
    return EnvMap(data=data, scale=scale, to_world=m, filename=str(p.get("filename")))


def _instance(ctx, el, materials, cache, default_mat) -> list[Shape]:
    """Mitsuba's ``instance`` of a ``shapegroup``: the group's shapes moved to world
    space by the instance's ``to_world`` (composed after each shape's own)."""
    p = _Plugin(ctx, el, "shape")
    p.unexpected_children(("shape",))
    groups = [c for _, c in p.children if c.tag == "shape"]
    if len(groups) != 1 or ctx.attr(groups[0], "type") != "shapegroup":
        raise ctx.error(el, "an instance needs exactly one reference to a shapegroup")
    g = _Plugin(ctx, groups[0], "shape")
    g.unexpected_children(("shape",))
    m = np.asarray(p.get("to_world", np.eye(4)), dtype=np.float64)
    out = []
    for _, c in g.children:
        if ctx.attr(c, "type") in ("shapegroup", "instance"):
            raise ctx.error(c, "a shapegroup cannot hold another shapegroup or an instance "
                               "(as in Mitsuba)")
        shape = _shape(ctx, c, materials, cache, default_mat)
        if shape.is_emitter:
            raise ctx.error(c, "a shape in a shapegroup cannot be an emitter (Mitsuba does not "
                               "instance emitters)")
        out.append(_transformed(ctx, c, shape, m))
    return out


def _transformed(ctx, el, shape: Shape, m: np.ndarray) -> Shape:
    """``shape`` (world space of its group) moved by the 4x4 ``m``."""
    import dataclasses

    if shape.kind == "sphere":
        s = tf.uniform_scale_factor(m)
        if s is None:
            raise ctx.error(el, "an instanced sphere's to_world must be a similarity transform "
                                "(uniform scale)")
        if shape.velocity is not None:
            raise ctx.error(el, "a moving sphere cannot be instanced")
        return dataclasses.replace(shape, center=tf.transform_points(m, shape.center),
                                   radius=shape.radius * s)
    if shape.moves:
        raise ctx.error(el, "a moving mesh cannot be instanced")
    f = shape.faces[:, ::-1].copy() if np.linalg.det(m[:3, :3]) < 0 else shape.faces
    n = None if shape.normals is None else tf.transform_normals(m, shape.normals)
    return dataclasses.replace(shape, vertices=tf.transform_points(m, shape.vertices), faces=f,
                               normals=n)


def _used_materials(shapes, materials):
    """(shapes, materials) keeping only the materials some shape uses, in their order
    (shape indices remapped): a BSDF a file declares but no shape uses (a
    documentation scene's spare plastic) does not reach the algorithms, as it does
    not reach Mitsuba's image."""
    import dataclasses

    used = sorted({s.material for s in shapes})
    if len(used) == len(materials):
        return shapes, materials
    index = {old: new for new, old in enumerate(used)}
    return ([dataclasses.replace(s, material=index[s.material]) for s in shapes],
            [materials[i] for i in used])


def _textured_spot(ctx, el) -> Light:
    """A ``spot`` with a ``texture``: the spot as :func:`_light` reads it (from a copy
    of the element without the texture) plus the texture and the emitter's to_world."""
    import copy
    import dataclasses

    p = _Plugin(ctx, el, "emitter")
    p.unexpected_children(("texture",))
    tex = _emitter_texture(ctx, p, "texture")
    bare = copy.deepcopy(el)
    for c in list(bare):
        if isinstance(c.tag, str) and (c.tag == "texture" or (c.tag == "ref" and c.get("id") in ctx.ids
                                                              and ctx.ids[c.get("id")].tag == "texture")):
            bare.remove(c)
    light = _light(ctx, bare)
    return dataclasses.replace(light, texture=tex, to_world=np.asarray(p.get("to_world", np.eye(4)),
                                                                       dtype=np.float64))


class _Vocabulary:
    """The scene-level elements of the vocabulary beyond the original subset, read
    before the original ones (:func:`load_scene` asks :meth:`element` first):
    instances (their shapes flattened) and shapegroup definitions, an ``envmap``,
    ``projector`` and textured ``spot`` emitters, area emitters and textures
    declared with an id for ``<ref>``, and media (refused)."""

    def __init__(self):
        self.envmap: EnvMap | None = None
        self.envmap_el = None

    def element(self, ctx, c, shapes, lights, materials, cache, default_mat) -> bool:
        """Handle scene-level element ``c`` if it is one of these; True when handled."""
        kind = ctx.attr(c, "type")
        if c.tag == "shape" and kind == "shapegroup":
            return True                # a definition: its shapes appear through instances
        if c.tag == "shape" and kind == "instance":
            shapes.extend(_instance(ctx, c, materials, cache, default_mat))
            return True
        if c.tag == "emitter" and kind == "envmap":
            if self.envmap_el is not None:
                raise ctx.error(c, "only one environment emitter can be specified per scene (as "
                                   f"Mitsuba requires); another is at line {self.envmap_el.sourceline}")
            self.envmap_el, self.envmap = c, _envmap(ctx, c)
            return True
        if c.tag == "emitter" and kind == "projector":
            lights.append(_projector(ctx, _Plugin(ctx, c, "emitter")))
            return True
        if c.tag == "emitter" and kind == "spot" and any(
                isinstance(x.tag, str) and (x.tag == "texture" or x.tag == "ref") for x in c):
            lights.append(_textured_spot(ctx, c))
            return True
        if c.tag == "emitter" and kind == "area" and c.get("id") is not None:
            return True                # a definition, attached to shapes by <ref>
        if c.tag == "texture" and c.get("id") is not None:
            _Plugin(ctx, c, "texture")  # a definition, used by <ref>; its type is checked here
            return True
        if c.tag == "medium":
            raise _medium_error(ctx, c)
        return False

    def finish(self, ctx, environment) -> None:
        """Checks over the whole scene: at most one environment emitter."""
        if self.envmap_el is not None and environment is not None:
            raise ctx.error(self.envmap_el, "only one environment emitter (constant or envmap) can "
                                            "be specified per scene (as Mitsuba requires)")
