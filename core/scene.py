"""The scene model: the one representation every own algorithm reads.

A scene file (Mitsuba 3 XML subset, see :mod:`core.loader`) becomes a
:class:`Scene`: a camera with its film, shapes with materials (and area
emitters), and the delta lights.  Everything is in world space, float64, linear
sRGB.  The model holds what the scene file says and nothing an algorithm adds:
Phong coefficients, sample counts and the like are algorithm parameters.

Shapes are either analytic spheres or triangle meshes; ``rectangle`` and
``cube`` arrive as the triangle meshes Mitsuba itself builds for them,
``disk`` and ``cylinder`` as 128-sided tessellations of Mitsuba's analytic
shapes (:mod:`core.meshes`).  A ``constant`` environment emitter is
:attr:`Scene.environment`; an ``envmap`` emitter (image-based lighting) is
:attr:`Scene.envmap`.  ``shapegroup``/``instance`` arrive flattened: each
instance's shapes in world space, as ordinary shapes.

Parts of the vocabulary that not every algorithm models (``plastic``, an
``envmap``, a ``projector``, normal and bump maps, textures on parameters other
than a diffuse reflectance, a rough conductor's or dielectric's textured ``alpha``
(``textured roughness``), a plastic's textured ``diffuse_reflectance``
(``plastic texture``), ``mask``, ``blendbsdf``, ``thindielectric``) are named by
:func:`scene_features`; an algorithm
renders a scene only if it models every feature the scene has
(:class:`core.algorithm.Algorithm` ``models``), so none of them is silently
rendered as something else.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Film", "Camera", "Material", "Shape", "Light", "Scene", "Spectrum", "EnvMap", "cie_tables",
           "scene_features", "FEATURES", "SPECULAR_TEXTURED", "TRANSMITTANCE_TEXTURED", "IOR_TEXTURED",
           "anisotropic_roughness"]


@dataclass(frozen=True)
class Spectrum:
    """A spectrum as a scene file's ``<spectrum>`` gives it (thesis 2.4.1-2.4.3).

    Either a constant (``wavelengths`` empty, ``values`` one number) or
    piecewise-linear samples ``(λ_i, v_i)`` in nanometres, increasing; zero
    outside [λ_0, λ_n] (as Mitsuba's ``irregular``/``regular`` spectra).
    RGB algorithms read :meth:`to_rgb`, which converts as Mitsuba 3's RGB
    variants do; the spectral path tracer reads the samples.
    """

    wavelengths: tuple = ()
    values: tuple = (1.0,)

    @property
    def is_constant(self) -> bool:
        return len(self.wavelengths) == 0

    def __call__(self, wavelengths):
        """Values at ``wavelengths`` (nm): linear interpolation, 0 outside the range."""
        w = np.asarray(wavelengths, dtype=np.float64)
        if self.is_constant:
            return np.full(w.shape, float(self.values[0]))
        lo, hi = self.wavelengths[0], self.wavelengths[-1]
        return np.where((w >= lo) & (w <= hi), np.interp(w, self.wavelengths, self.values), 0.0)

    def to_rgb(self, *, emitter: bool) -> np.ndarray:
        """Linear sRGB as Mitsuba 3's RGB variants convert it (CIE 1931 2°, colour-science).

        Reflectances (``emitter=False``): XYZ = ∫ s D65 x̄ dλ / ∫ D65 ȳ dλ, so a
        constant 1 is white (1, 1, 1); a constant stays that grey.  Emission:
        XYZ = ∫ s x̄ dλ / ∫ ȳ dλ (illuminant E, as Mitsuba), then XYZ → linear sRGB.
        """
        if self.is_constant and not emitter:
            return np.full(3, float(self.values[0]))
        wl, xyz, d65, to_rgb = cie_tables()
        s = self(wl)
        w = np.ones_like(wl) if emitter else d65
        XYZ = (s * w) @ xyz / (w @ xyz[:, 1])          # 1 nm steps: the sums are the integrals
        return to_rgb @ XYZ


@functools.lru_cache(maxsize=1)
def cie_tables():
    """``(λ, x̄ȳz̄, D65, M)``: the CIE 1931 2° colour matching functions and the D65
    illuminant on 360-830 nm at 1 nm (colour-science), and the XYZ → linear sRGB matrix."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    shape = colour.SpectralShape(360, 830, 1)
    cmfs = cmfs.copy().align(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    M = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
    return (np.asarray(cmfs.wavelengths, dtype=np.float64), np.asarray(cmfs.values, dtype=np.float64),
            np.asarray(d65.values, dtype=np.float64), M)


@dataclass(frozen=True)
class Film:
    width: int = 768
    height: int = 576
    rfilter: str = "gaussian"          # 'box' or 'gaussian' (Mitsuba's hdrfilm default)
    rfilter_params: dict = field(default_factory=dict)

    @property
    def aspect(self) -> float:
        return self.width / self.height


@dataclass(frozen=True)
class Camera:
    """The sensor: Mitsuba's ``perspective`` (pinhole), ``thinlens`` or ``orthographic``.

    ``thinlens`` adds a lens of ``aperture_radius`` focused at
    ``focus_distance`` (both in scene units, along the camera's +z);
    ``orthographic`` ignores ``fov``: its view spans camera-space
    x ∈ [−1, 1], y ∈ [−1/aspect, 1/aspect], scaled by ``to_world``.
    ``shutter_open``/``shutter_close`` bound the ray times (motion blur).
    """

    to_world: np.ndarray               # 4x4 camera-to-world; camera +z forward, +y up, +x left
    fov: float = 90.0                  # degrees, along ``fov_axis``
    fov_axis: str = "x"
    near_clip: float = 1e-2
    far_clip: float = 1e4
    film: Film = field(default_factory=Film)
    sample_count: int = 4              # the scene's sampler sample_count
    kind: str = "perspective"          # perspective | thinlens | orthographic
    aperture_radius: float = 0.0       # thinlens
    focus_distance: float = 1e4        # thinlens (Mitsuba's default: far_clip)
    shutter_open: float = 0.0
    shutter_close: float = 0.0
    # gibench-only camera motion over the shutter: the camera at time τ is translated
    # by velocity·τ and turned by the rotation vector angular_velocity·τ (rad) about its
    # own origin (None: still).
    velocity: np.ndarray | None = None
    angular_velocity: np.ndarray | None = None

    @property
    def moves(self) -> bool:
        return self.velocity is not None or self.angular_velocity is not None

    @property
    def origin(self) -> np.ndarray:
        return self.to_world[:3, 3].copy()

    @property
    def tan_half_fov_x(self) -> float:
        """tan of half the horizontal field of view, resolving ``fov_axis`` as Mitsuba does."""
        t = np.tan(np.deg2rad(self.fov) / 2.0)
        aspect = self.film.aspect
        axis = self.fov_axis
        if axis == "smaller":
            axis = "y" if aspect > 1.0 else "x"
        elif axis == "larger":
            axis = "x" if aspect > 1.0 else "y"
        if axis == "x":
            return float(t)
        if axis == "y":
            return float(t * aspect)
        # diagonal: tan(fov/2) spans half the diagonal
        return float(t * aspect / np.hypot(aspect, 1.0))

    def __repr__(self) -> str:
        return (f"Camera({self.kind}, origin={np.round(self.origin, 4).tolist()}, fov={self.fov} ({self.fov_axis}), "
                f"film={self.film.width}x{self.film.height}, spp={self.sample_count})")


@dataclass(frozen=True)
class Material:
    """A BSDF as the scene file gives it.

    ``kind`` is the Mitsuba plugin name (``diffuse``, ``conductor``,
    ``dielectric``, ``roughconductor``); ``reflectance`` is the diffuse albedo
    (RGB) for ``diffuse``; the rest of the plugin's parameters stay in
    ``params`` for the algorithms that model them.

    ``texture`` is set when the diffuse reflectance is a texture instead of a
    colour: ``{"type": "checkerboard", "color0": (r, g, b), "color1": (r, g, b),
    "to_uv": 3x3 list}`` (Mitsuba's ``checkerboard``; ``to_uv`` is the 2D
    affine map applied to the shape's uv), or ``{"type": "bitmap", "data":
    (H, W, 3) linear RGB float64, "filename", "wrap_mode", "filter_type",
    "to_uv"}`` (Mitsuba's ``bitmap``, see :mod:`impl.textures`).
    ``reflectance`` then holds the texture's mean, for algorithms that want
    one colour.
    """

    kind: str = "diffuse"
    reflectance: tuple = (0.5, 0.5, 0.5)
    twosided: bool = False
    params: dict = field(default_factory=dict)
    name: str = ""
    texture: dict | None = None
    #: Textures on other parameters, name -> texture dict (as ``texture``): a
    #: plastic's ``diffuse_reflectance``/``specular_reflectance``, a conductor's
    #: ``specular_reflectance``, a rough BSDF's ``alpha``/``alpha_u``/``alpha_v``, ...
    textures: dict = field(default_factory=dict)
    #: A ``normalmap`` or ``bumpmap`` wrapped around the BSDF, or None:
    #: ``{"type": "normalmap", "texture": tex}`` (tangent-space normals in [0, 1]³,
    #: Mitsuba's ``normalmap``) or ``{"type": "bumpmap", "texture": tex, "scale": s}``
    #: (a height field; Mitsuba's ``bumpmap``), both with Mitsuba's booleans
    #: ``flip_invalid_normals`` and ``use_shadowing_function`` (default true), and
    #: ``wraps_twosided`` true where the map wraps a ``twosided`` (absent: the map is
    #: inside it, or the material is one-sided).
    #: ``kind``/``params`` are the wrapped BSDF's.
    shading: dict | None = None
    #: A ``mask`` wrapped around the BSDF, or None: the opacity, ``{"type": "constant",
    #: "value": a}`` or a texture dict; Mitsuba's ``mask`` scatters by the wrapped BSDF
    #: with probability a and lets the ray pass unchanged otherwise.
    opacity: dict | None = None
    #: ``blendbsdf``: its two BSDFs (Materials), blended as (1 − weight)·first +
    #: weight·second (``params["weight"]`` or ``textures["weight"]``).
    components: tuple = ()


@dataclass(frozen=True)
class EnvMap:
    """Mitsuba's ``envmap`` emitter: radiance from an equirectangular (lat-long) image.

    ``data`` is the (H, W, 3) image in linear RGB (float64), ``scale`` multiplies
    it, ``to_world`` rotates the map (Mitsuba's convention: a world direction d
    maps to the local direction to_world⁻¹ d, whose (u, v) are
    u = (1 + atan2(x, −z)/π)/2, v = acos(y)/π, row 0 the top, +y up; see
    :mod:`impl.envmap`).
    """

    data: np.ndarray
    scale: float = 1.0
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    filename: str = ""

    def __repr__(self) -> str:
        h, w = self.data.shape[:2]
        return f"EnvMap('{self.filename}', {w}x{h}, scale={self.scale:g})"


@dataclass(frozen=True)
class Shape:
    """A sphere (``center``/``radius``) or a triangle mesh (``vertices``/``faces``)."""

    kind: str                          # 'sphere' or 'mesh'
    material: int                      # index into Scene.materials
    name: str = ""
    source: str = ""                   # plugin type: sphere, rectangle, cube, obj, ply
    center: np.ndarray | None = None
    radius: float = 0.0
    vertices: np.ndarray | None = None  # (V, 3) world space
    faces: np.ndarray | None = None     # (F, 3) int
    normals: np.ndarray | None = None   # (V, 3) shading normals, or None for face normals
    uvs: np.ndarray | None = None       # (V, 2) texture coordinates, or None (see the loader)
    flip_normals: bool = False
    emitter_radiance: np.ndarray | None = None  # RGB radiance of an area emitter, or None
    emitter_spectrum: Spectrum | None = None    # its spectrum, when the file gives one
    velocity: np.ndarray | None = None  # sphere moving linearly: centre(τ) = center + velocity·τ
    # A mesh's rigid motion: vertex(τ) = pivot + Rot(angular_velocity·τ)(vertex − pivot)
    # + velocity·τ (rotation vector in rad per unit time; pivot: the world point it
    # turns about).  None: still.
    angular_velocity: np.ndarray | None = None
    pivot: np.ndarray | None = None

    @property
    def moves(self) -> bool:
        return self.velocity is not None or self.angular_velocity is not None

    @property
    def is_emitter(self) -> bool:
        return self.emitter_radiance is not None

    def __repr__(self) -> str:
        if self.kind == "sphere":
            geo = f"center={np.round(self.center, 4).tolist()}, radius={self.radius:g}"
        else:
            geo = f"{len(self.faces)} triangles"
        em = ", emitter" if self.is_emitter else ""
        return f"Shape({self.source} '{self.name}', {geo}, material={self.material}{em})"


@dataclass(frozen=True)
class Light:
    """A delta light: ``point`` (intensity, W/sr), ``spot`` (intensity, cone),
    ``directional`` (irradiance) or ``projector`` (Mitsuba's: a pinhole projecting an
    irradiance image or constant, ``radiant`` × ``scale``)."""

    kind: str
    radiant: np.ndarray                # RGB intensity (point, spot) or irradiance (directional)
    position: np.ndarray | None = None
    direction: np.ndarray | None = None  # direction the light travels (directional) or spot axis
    cutoff_angle: float = 20.0         # spot: degrees
    beam_width: float = 15.0           # spot: degrees (Mitsuba default: 3/4 of cutoff)
    name: str = ""
    #: spot: a texture modulating the beam (Mitsuba's ``texture``); projector: the
    #: projected ``irradiance`` texture (None: the constant ``radiant``).
    texture: dict | None = None
    #: spot and projector: the emitter's to_world (+z forward; a spot's cone is evaluated
    #: in this frame, as Mitsuba's); projector: its horizontal field of view (degrees,
    #: Mitsuba's ``parse_fov``) and ``scale``.
    to_world: np.ndarray | None = None
    fov_x: float = 0.0
    scale: float = 1.0


@dataclass
class Scene:
    path: Path
    camera: Camera
    shapes: list[Shape]
    materials: list[Material]
    lights: list[Light]
    integrator: dict = field(default_factory=lambda: {"type": "path"})
    files: list[Path] = field(default_factory=list)  # files the scene reads (meshes, includes, images)
    # RGB radiance of a ``constant`` environment emitter (uniform from every direction), or None.
    environment: np.ndarray | None = None
    # An ``envmap`` emitter (image-based lighting), or None.
    envmap: EnvMap | None = None

    @property
    def emitters(self) -> list[Shape]:
        return [s for s in self.shapes if s.is_emitter]

    def __repr__(self) -> str:
        return (f"Scene('{self.path}', {len(self.shapes)} shapes, {len(self.lights)} delta lights, "
                f"{len(self.emitters)} area emitters, {self.camera!r})")


#: The features :func:`scene_features` names: parts of the scene vocabulary an
#: algorithm must model explicitly (``Algorithm.models``) to render a scene that has them.
FEATURES = ("envmap", "projector", "spot texture", "plastic", "roughplastic", "normalmap", "bumpmap",
            "textured parameter", "textured roughness", "anisotropic roughness",
            "textured specular reflectance", "textured specular transmittance",
            "textured conductor eta/k", "plastic texture",
            "camera motion", "mesh motion",
            "mask", "blendbsdf", "thindielectric", "gibench_cooktorrance", "gibench_difftrans")


#: The BSDFs whose textured ``specular_reflectance`` weights all they reflect (the
#: feature "textured specular reflectance", which a plastic's textured specular
#: coat is too; its diffuse base does not take it).
SPECULAR_TEXTURED = ("conductor", "roughconductor", "dielectric", "roughdielectric", "thindielectric")

#: The BSDFs whose textured ``specular_transmittance`` is the feature "textured specular
#: transmittance".
TRANSMITTANCE_TEXTURED = ("dielectric", "roughdielectric", "thindielectric")

#: The BSDFs whose textured ``eta`` or ``k`` is the feature "textured conductor eta/k".
IOR_TEXTURED = ("conductor", "roughconductor")


def scene_features(scene: Scene) -> dict[str, str]:
    """The features of :data:`FEATURES` that ``scene`` uses: feature -> where (for
    the error message), e.g. ``{"plastic": "shape 'ball'"}``.  Only materials some
    shape uses count."""
    found: dict[str, str] = {}
    if getattr(scene, "envmap", None) is not None:
        found["envmap"] = f"envmap emitter '{scene.envmap.filename}'"
    for light in scene.lights:
        if light.kind == "projector":
            found.setdefault("projector", f"projector emitter '{light.name}'" if light.name else
                             "a projector emitter")
        elif light.texture is not None:
            found.setdefault("spot texture", f"spot emitter '{light.name}'" if light.name else
                             "a textured spot emitter")
    if getattr(scene.camera, "moves", False):
        found["camera motion"] = "the sensor (gibench_velocity / gibench_angular_velocity)"
    for shape in scene.shapes:
        where = f"shape '{shape.name or shape.source}'"
        if shape.kind == "mesh" and shape.moves:
            found.setdefault("mesh motion", where)
        _material_features(scene.materials[shape.material], where, found)
    return found


def _material_features(m: Material, where: str, found: dict) -> None:
    """Add material ``m``'s features (and its ``blendbsdf`` components') to ``found``.
    A blendbsdf's ``weight`` texture belongs to the ``blendbsdf`` feature."""
    if m.kind in ("plastic", "roughplastic", "blendbsdf", "thindielectric", "gibench_cooktorrance",
                  "gibench_difftrans"):
        found.setdefault(m.kind, where)
    if m.opacity is not None:
        found.setdefault("mask", where)
    if m.shading is not None:
        found.setdefault(m.shading["type"], where)
    if m.kind in ("roughconductor", "roughdielectric") and anisotropic_roughness(m):
        found.setdefault("anisotropic roughness", f"{where} ('alpha_u'/'alpha_v' of its {m.kind} BSDF)")
    for name in m.textures:
        if m.kind in ("plastic", "roughplastic") and name == "diffuse_reflectance":
            found.setdefault("plastic texture", where)
        elif m.kind in ("plastic", "roughplastic") and name == "specular_reflectance":
            found.setdefault("textured specular reflectance", f"{where} ('{name}' of its {m.kind} BSDF)")
        elif m.kind in ("roughconductor", "roughdielectric") and name in ("alpha", "alpha_u", "alpha_v"):
            found.setdefault("textured roughness", f"{where} ('{name}' of its {m.kind} BSDF)")
        elif m.kind in SPECULAR_TEXTURED and name == "specular_reflectance":
            found.setdefault("textured specular reflectance", f"{where} ('{name}' of its {m.kind} BSDF)")
        elif m.kind in TRANSMITTANCE_TEXTURED and name == "specular_transmittance":
            found.setdefault("textured specular transmittance", f"{where} ('{name}' of its {m.kind} BSDF)")
        elif m.kind in IOR_TEXTURED and name in ("eta", "k"):
            found.setdefault("textured conductor eta/k", f"{where} ('{name}' of its {m.kind} BSDF)")
        elif not (m.kind == "blendbsdf" and name == "weight"):
            found.setdefault("textured parameter", f"{where} ('{name}' of its {m.kind} BSDF)")
    for c in m.components:
        _material_features(c, where, found)


def texture_mean(tex: dict) -> np.ndarray:
    """The mean RGB of a texture record (a ``bitmap``'s texels, or the mean of a
    ``checkerboard``'s two colours, which cover equal areas): the constant that stands
    for it where no uv is available."""
    if tex["type"] == "bitmap":
        return tex["data"].reshape(-1, 3).mean(axis=0)
    return 0.5 * (np.asarray(tex["color0"]) + np.asarray(tex["color1"]))


def anisotropic_roughness(m: Material) -> bool:
    """Whether material ``m`` (or a blendbsdf component of it) is a rough BSDF with
    anisotropic roughness: a textured ``alpha_u`` or ``alpha_v``, or two different
    constants."""
    if any(anisotropic_roughness(c) for c in m.components):
        return True
    if m.kind not in ("roughconductor", "roughdielectric"):
        return False
    if "alpha_u" in m.textures or "alpha_v" in m.textures:
        return True
    p = m.params
    try:
        return "alpha_u" in p and "alpha_v" in p and float(p["alpha_u"]) != float(p["alpha_v"])
    except (TypeError, ValueError):
        return False
