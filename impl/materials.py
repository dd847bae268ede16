"""Per-material BSDF parameters as arrays for the numba tracers.

:func:`material_arrays` checks every used material of a scene against the
BSDFs an algorithm models and decodes Mitsuba's parameters (with Mitsuba's
defaults) into a :class:`MaterialArrays` named tuple, one row per material of
``scene.materials`` (numba takes the tuple as one typed argument):

* ``conductor`` / ``roughconductor``: ``specular_reflectance`` × the conductor
  Fresnel term of the complex index ``eta + i k`` (RGB).  ``material="none"``
  (Mitsuba's default) is ``eta = 0, k = 1``: Fresnel = 1.  A named conductor
  (``material="Au"``) takes the RGB ``eta``/``k`` Mitsuba's RGB variants
  derive from its measured spectra, stored in ``impl/data/conductors_rgb.json``
  (:func:`named_conductor`; written from Mitsuba by
  ``references/conductor_table.py``, which records the version).  A textured ``eta``
  or ``k`` is read at the hit (:func:`impl.lighting.textured_fresnel`): the row then
  holds 0 + 1i, whose Fresnel term is 1.
* ``dielectric`` / ``roughdielectric`` / ``thindielectric``: ``int_ior`` (default BK7),
  ``ext_ior`` (default air), ``specular_reflectance``,
  ``specular_transmittance`` (a texture is read at the hit,
  :func:`impl.lighting.transmittance_tint`; the row then holds Mitsuba's default 1).
* ``roughconductor`` / ``roughdielectric``: ``alpha`` (default 0.1, Mitsuba's),
  ``distribution`` (``beckmann``, the default; ``ggx`` only where the caller
  lists it in ``distributions``: :func:`distribution_codes` gives the rows),
  ``sample_visible`` (default true).  Anisotropic ``alpha_u``/``alpha_v`` (each a
  constant or a texture, as Mitsuba) only where the caller passes
  ``anisotropic=True``: ``alpha`` then holds α_u and :func:`wrapper_arrays` α_v;
  otherwise they are accepted only when equal and constant.  A textured roughness
  gets its mean here and its texture in :func:`wrapper_arrays`.

:func:`expand_components` gives a ``blendbsdf``'s components rows of their own;
:func:`wrapper_arrays` decodes ``mask`` opacities, blend weights and textured or
anisotropic roughness into :class:`WrapperArrays`; :func:`with_specular_textures`
moves the textured ``specular_reflectance`` of a conductor or dielectric (smooth,
rough or thin) to the material's texture, for the tracers.

The microfacet functions these rows feed are in :mod:`impl.microfacet`.

:func:`plastic_arrays` decodes ``plastic`` / ``roughplastic`` materials
(Mitsuba's defaults, :func:`impl.plastic.plastic_params`) into a
:class:`PlasticArrays` table for the functions of :mod:`impl.plastic`.
:func:`material_arrays` refuses both kinds by name unless the caller lists them
in ``kinds`` (the path tracer does, :func:`impl.bsdf.bsdf_arrays`); their
parameters are then :func:`plastic_arrays`'s.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from core.scene import Scene
from core.errors import SceneError, UnsupportedError

from .fresnel import lookup_ior
from .microfacet import DISTRIBUTIONS
from .envmap import LUMINANCE
from .scene_arrays import MATERIAL_CODES

__all__ = ["named_conductor", "distribution_codes", "CONDUCTOR_TABLE", "MaterialArrays", "SpecularArrays", "material_arrays", "PlasticArrays", "plastic_arrays", "MAT_DIFFUSE", "MAT_CONDUCTOR",
           "MAT_DIELECTRIC", "MAT_ROUGHCONDUCTOR", "MAT_ROUGHDIELECTRIC", "MAT_PLASTIC",
           "MAT_ROUGHPLASTIC", "MAT_COOKTORRANCE", "MAT_DIFFTRANS", "MAT_THINDIELECTRIC", "MAT_BLEND",
           "MAX_LOBES", "KIND_CODES", "DEFAULT_ALPHA", "expand_components", "with_specular_textures",
           "WrapperArrays", "N_SLOTS", "no_wrappers", "wrapper_arrays", "rgb_param", "texture_mean_value"]

MAT_DIFFUSE = MATERIAL_CODES["diffuse"]
MAT_CONDUCTOR = MATERIAL_CODES["conductor"]
MAT_DIELECTRIC = MATERIAL_CODES["dielectric"]
MAT_ROUGHCONDUCTOR = MATERIAL_CODES["roughconductor"]
MAT_ROUGHDIELECTRIC = MATERIAL_CODES["roughdielectric"]
MAT_PLASTIC = MATERIAL_CODES["plastic"]
MAT_ROUGHPLASTIC = MATERIAL_CODES["roughplastic"]
MAT_COOKTORRANCE = MATERIAL_CODES["gibench_cooktorrance"]
MAT_DIFFTRANS = MATERIAL_CODES["gibench_difftrans"]
MAT_THINDIELECTRIC = MATERIAL_CODES["thindielectric"]
MAT_BLEND = MATERIAL_CODES["blendbsdf"]
#: Most roughness lobes of a ``gibench_cooktorrance`` mixture (its row holds them in
#: ``cond_eta`` / ``cond_k``).
MAX_LOBES = 3
#: Material kind codes of :attr:`MaterialArrays.kind` (those of ``scene_arrays.MATERIAL_CODES``).
KIND_CODES = {"diffuse": MAT_DIFFUSE, "conductor": MAT_CONDUCTOR, "dielectric": MAT_DIELECTRIC,
              "roughconductor": MAT_ROUGHCONDUCTOR, "roughdielectric": MAT_ROUGHDIELECTRIC,
              "plastic": MAT_PLASTIC, "roughplastic": MAT_ROUGHPLASTIC,
              "gibench_cooktorrance": MAT_COOKTORRANCE, "gibench_difftrans": MAT_DIFFTRANS,
              "thindielectric": MAT_THINDIELECTRIC, "blendbsdf": MAT_BLEND}

#: Mitsuba's default roughness of roughconductor / roughdielectric.
DEFAULT_ALPHA = 0.1


#: Mitsuba's named conductors as RGB complex indices (see the module docstring).
CONDUCTOR_TABLE = Path(__file__).resolve().parent / "data" / "conductors_rgb.json"


@functools.cache
def _conductors() -> dict:
    return json.loads(CONDUCTOR_TABLE.read_text())["materials"]


def named_conductor(name: str, *, where: str = "conductor") -> tuple[np.ndarray, np.ndarray]:
    """``(eta, k)``, RGB, of Mitsuba's conductor ``material=name`` (case-sensitive, as
    Mitsuba); an unknown name raises :class:`SceneError` listing a few known ones."""
    table = _conductors()
    if name not in table:
        raise SceneError(f"{where}: unknown conductor material '{name}' (Mitsuba's names, e.g. "
                         f"{', '.join(n for n in ('Ag', 'Al', 'Au', 'Cr', 'Cu', 'W'))}; "
                         f"{len(table)} in {CONDUCTOR_TABLE.name})")
    row = table[name]
    return np.asarray(row["eta"], dtype=np.float64), np.asarray(row["k"], dtype=np.float64)


class MaterialArrays(NamedTuple):
    """Per-material parameters of the specular and microfacet BSDFs (one row per material).

    The gibench-only thesis models reuse the rows: a ``gibench_cooktorrance`` row holds
    ρ in ``spec_refl``, (k_d, k_s, 0) in ``spec_trans``, the mixture's roughnesses α_k
    in ``cond_eta`` and weights w_k in ``cond_k`` (``MAX_LOBES`` of them, unused lobes
    weight 0), int_ior/ext_ior in ``diel_eta``; a ``gibench_difftrans`` row holds ρ in
    ``spec_refl`` and τ in ``spec_trans``."""

    spec_refl: np.ndarray       # (M, 3) specular_reflectance
    spec_trans: np.ndarray      # (M, 3) specular_transmittance (dielectrics)
    cond_eta: np.ndarray        # (M, 3) conductors: real part of the relative IOR
    cond_k: np.ndarray          # (M, 3) conductors: imaginary part
    diel_eta: np.ndarray        # (M,) dielectrics: int_ior / ext_ior
    diel_int: np.ndarray        # (M,) dielectrics: int_ior
    diel_ext: np.ndarray        # (M,) dielectrics: ext_ior
    kind: np.ndarray            # (M,) int: KIND_CODES
    alpha: np.ndarray           # (M,) Beckmann roughness of the rough BSDFs (0 for smooth ones)
    visible: np.ndarray         # (M,) int: 1 = sample visible normals (Mitsuba's sample_visible)


#: The name whitted's tests and callers know (the first seven fields are the old ones).
SpecularArrays = MaterialArrays


def rgb_param(params: dict, name: str, default: float, where: str) -> np.ndarray:
    """Parameter ``name`` as RGB.  A ``<spectrum>`` of (wavelength, value) pairs becomes
    linear sRGB as Mitsuba's RGB variants pre-integrate it (D65-weighted CIE 1931,
    :meth:`core.scene.Spectrum.to_rgb`), clipped to [0, 1] except for the unbounded
    ``eta`` and ``k``, which are only kept >= 0."""
    from core.scene import Spectrum

    v = params.get(name, default)
    if isinstance(v, Spectrum):
        rgb = v.to_rgb(emitter=False)
        return np.maximum(rgb, 0.0) if name in ("eta", "k") else np.clip(rgb, 0.0, 1.0)
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape == (1,):
        a = np.repeat(a, 3)
    if a.shape != (3,):
        raise SceneError(f"{where}: '{name}' must be a float or rgb value, got {v!r}")
    return a


def _and_list(items) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _roughness(p: dict, where: str, distributions: tuple[str, ...] = ("beckmann",),
               textured: tuple[str, ...] = (), anisotropic: bool = False) -> tuple[float, float, int]:
    """(alpha_u, alpha_v, sample_visible) of a rough BSDF, Mitsuba's defaults and checks
    (``textured``: the names of its parameters given as textures, whose values here
    are placeholders); its ``distribution`` must be one of ``distributions``.  Unequal
    or textured ``alpha_u``/``alpha_v`` are refused unless ``anisotropic``."""
    dist = str(p.get("distribution", "beckmann")).lower()
    if dist not in DISTRIBUTIONS:
        raise SceneError(f"{where}: invalid distribution '{dist}' (Mitsuba accepts 'beckmann' or 'ggx')")
    if dist not in distributions:
        raise UnsupportedError(f"{where}: distribution '{dist}' is not modelled; only 'beckmann' "
                                  "(the thesis's Cook-Torrance D) is")
    given = set(p) | set(textured)
    has_uv = "alpha_u" in given or "alpha_v" in given
    if "alpha" in given and has_uv:
        raise SceneError(f"{where}: give either 'alpha' or 'alpha_u'/'alpha_v' (as Mitsuba requires)")
    if has_uv:
        if "alpha_u" not in given or "alpha_v" not in given:
            raise SceneError(f"{where}: both 'alpha_u' and 'alpha_v' must be given")
        tex_uv = "alpha_u" in textured or "alpha_v" in textured
        if not anisotropic and tex_uv:
            raise UnsupportedError(f"{where}: anisotropic roughness (textured 'alpha_u'/'alpha_v') "
                                   "is not modelled; give one 'alpha'")
        alpha = DEFAULT_ALPHA if "alpha_u" in textured else float(p["alpha_u"])
        alpha_v = DEFAULT_ALPHA if "alpha_v" in textured else float(p["alpha_v"])
        if not anisotropic and alpha != alpha_v:
            raise UnsupportedError(f"{where}: anisotropic roughness (alpha_u={p['alpha_u']}, "
                                      f"alpha_v={p['alpha_v']}) is not modelled; give one 'alpha'")
    else:
        alpha = DEFAULT_ALPHA if "alpha" in textured else p.get("alpha", DEFAULT_ALPHA)
        if not isinstance(alpha, int | float):
            raise SceneError(f"{where}: 'alpha' must be a float, got {alpha!r}")
        alpha = alpha_v = float(alpha)
    for name, a in (("alpha_u" if has_uv else "alpha", alpha), ("alpha_v", alpha_v)):
        if not a >= 0.0:
            raise SceneError(f"{where}: '{name}' must be >= 0, got {a}")
    return alpha, alpha_v, int(bool(p.get("sample_visible", True)))


def _mixture(p: dict, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The roughness mixture of a ``gibench_cooktorrance``: ``alphas`` and ``weights``
    (comma-separated strings; default one lobe α = 0.1), checked by
    :func:`impl.microfacet.mixture_arrays`, padded to ``MAX_LOBES`` lobes of weight 0
    (α of the last lobe)."""
    from core.errors import ParamError

    from .microfacet import mixture_arrays

    def floats(name, default):
        v = p.get(name, default)
        try:
            return [float(x) for x in str(v).replace(",", " ").split()]
        except ValueError:
            raise SceneError(f"{where}: '{name}' must be a list of numbers, got {v!r}") from None

    a, w = floats("alphas", "0.1"), floats("weights", "1")
    if len(a) > MAX_LOBES:
        raise UnsupportedError(f"{where}: at most {MAX_LOBES} roughness lobes are modelled, got {len(a)}")
    try:
        a, w = mixture_arrays(a, w)
    except ParamError as exc:
        raise SceneError(f"{where}: {exc}") from None
    pad = MAX_LOBES - len(a)
    return np.concatenate([a, np.full(pad, a[-1])]), np.concatenate([w, np.zeros(pad)])


def material_arrays(scene: Scene, *, algorithm: str = "whitted",
                    model: str = "the Whitted ray tracer",
                    kinds: tuple[str, ...] = ("diffuse", "conductor", "dielectric"),
                    distributions: tuple[str, ...] = ("beckmann",),
                    anisotropic: bool = False) -> MaterialArrays:
    """Check every used material against ``kinds`` and decode its BSDF parameters.

    Parameters
    ----------
    scene
        The scene; only materials some shape uses are checked.
    algorithm, model
        Name the caller in error messages (``"{algorithm}: shape 'x' has a
        'y' BSDF, which {model} does not model"``).
    kinds
        The BSDF types the caller models (keys of :data:`KIND_CODES`).
    distributions
        The microfacet distributions the caller models (``beckmann``, ``ggx``);
        the rows' codes are :func:`distribution_codes`'s.
    anisotropic
        Whether the caller models anisotropic roughness (``alpha`` then holds α_u;
        α_v is in :func:`wrapper_arrays`).

    Raises
    ------
    NotImplementedError
        A material the algorithm does not model (naming the shape and the
        material), a two-sided
        dielectric, a GGX distribution, anisotropic roughness (unless ``anisotropic``).
    ValueError
        Conflicting or malformed parameters (e.g. both ``material`` and
        ``eta`` on a conductor, an unknown IOR or conductor name, equal indices on a
        roughdielectric, a negative alpha).
    """
    unknown = [k for k in kinds if k not in KIND_CODES]
    if unknown:
        raise ValueError(f"material_arrays: unknown BSDF kinds {unknown} (known: {', '.join(KIND_CODES)})")
    M = len(scene.materials)
    spec_refl = np.ones((M, 3))
    spec_trans = np.ones((M, 3))
    cond_eta = np.zeros((M, 3))
    cond_k = np.ones((M, 3))
    diel_eta = np.ones(M)
    diel_int = np.ones(M)
    diel_ext = np.ones(M)
    kind = np.zeros(M, dtype=np.int64)
    alpha = np.zeros(M)
    visible = np.ones(M, dtype=np.int64)
    users = {}
    for shape in scene.shapes:
        users.setdefault(shape.material, shape.name or shape.source)
    index = {id(m): i for i, m in enumerate(scene.materials)}
    for i, m in enumerate(scene.materials):      # a blendbsdf's components (expand_components)
        for c in m.components:
            if i in users and id(c) in index:
                users.setdefault(index[id(c)], users[i])
    for i, m in enumerate(scene.materials):
        if m.kind in KIND_CODES:
            kind[i] = KIND_CODES[m.kind]
        if i not in users:
            continue
        where = f"{algorithm}: shape '{users[i]}'"
        if m.kind not in kinds:
            raise UnsupportedError(
                f"{where} has a '{m.kind}' BSDF, which {model} does not model "
                f"({_and_list(kinds)} are modelled)")
        p = m.params
        if m.kind in ("conductor", "roughconductor"):
            material = p.get("material", "none")
            textured = [n for n in ("eta", "k") if n in m.textures]
            if textured and material != "none":
                raise SceneError(f"{where}: conductor gives both 'material' ('{material}') and a "
                                 f"textured '{textured[0]}'; give one of them (as Mitsuba requires)")
            if "eta" in p and material != "none":
                raise SceneError(f"{where}: conductor gives both 'material' ('{material}') and "
                                 "'eta'; give one of them (as Mitsuba requires)")
            if material != "none":
                if "k" in p:
                    raise SceneError(f"{where}: conductor gives both 'material' ('{material}') and "
                                     "'k'; give one of them (as Mitsuba requires)")
                cond_eta[i], cond_k[i] = named_conductor(str(material), where=where)
            elif textured:               # 0 + 1i: Fresnel 1; the caller multiplies by the
                cond_eta[i], cond_k[i] = 0.0, 1.0   # textured one at the hit (impl.lighting)
            else:
                cond_eta[i] = rgb_param(p, "eta", 0.0, where)
                cond_k[i] = rgb_param(p, "k", 1.0, where)
            spec_refl[i] = rgb_param(p, "specular_reflectance", 1.0, where)
        elif m.kind in ("dielectric", "roughdielectric", "thindielectric"):
            if m.twosided:
                raise UnsupportedError(f"{where}: a two-sided dielectric is not modelled")
            # Mitsuba's defaults: BK7 glass inside, air outside.
            n_int = lookup_ior(p.get("int_ior", "bk7"), what=f"{where}: int_ior")
            n_ext = lookup_ior(p.get("ext_ior", "air"), what=f"{where}: ext_ior")
            if n_int <= 0.0 or n_ext <= 0.0:
                raise SceneError(f"{where}: indices of refraction must be positive "
                                 f"(int_ior={n_int}, ext_ior={n_ext})")
            if m.kind == "roughdielectric" and n_int == n_ext:
                raise SceneError(f"{where}: roughdielectric needs int_ior != ext_ior "
                                 f"(both {n_int}), as Mitsuba requires")
            diel_int[i], diel_ext[i], diel_eta[i] = n_int, n_ext, n_int / n_ext
            spec_refl[i] = rgb_param(p, "specular_reflectance", 1.0, where)
            spec_trans[i] = rgb_param(p, "specular_transmittance", 1.0, where)
        if m.kind in ("roughconductor", "roughdielectric"):
            alpha[i], _, visible[i] = _roughness(p, where, distributions, tuple(m.textures), anisotropic)
            for name in ("alpha", "alpha_u"):
                if name in m.textures:              # the value where no uv: the texture's mean
                    alpha[i] = _scalar_texture_mean(m.textures[name])
        elif m.kind == "gibench_cooktorrance":
            spec_refl[i] = rgb_param(p, "reflectance", 0.5, where)
            kd, ks = float(p.get("kd", 0.5)), float(p.get("ks", 0.5))
            if kd + ks > 1.0 + 1e-12:
                raise SceneError(f"{where}: gibench_cooktorrance needs kd + ks <= 1 (the thesis's "
                                 f"d + s = 1), got kd={kd} + ks={ks} = {kd + ks}")
            spec_trans[i] = (kd, ks, 0.0)
            a, w = _mixture(p, where)
            cond_eta[i], cond_k[i] = a, w
            alpha[i] = a[0]
            n_int = lookup_ior(p.get("int_ior", 1.5), what=f"{where}: int_ior")
            n_ext = lookup_ior(p.get("ext_ior", 1.0), what=f"{where}: ext_ior")
            diel_int[i], diel_ext[i], diel_eta[i] = n_int, n_ext, n_int / n_ext
        elif m.kind == "gibench_difftrans":
            rho = rgb_param(p, "reflectance", 0.5, where)
            tau = rgb_param(p, "transmittance", 0.5, where)
            if np.any(rho + tau > 1.0 + 1e-12):
                raise SceneError(f"{where}: gibench_difftrans needs reflectance + transmittance <= 1 "
                                 f"per channel, got {rho.tolist()} + {tau.tolist()}")
            spec_refl[i], spec_trans[i] = rho, tau
    return MaterialArrays(spec_refl, spec_trans, cond_eta, cond_k, diel_eta, diel_int, diel_ext,
                          kind, alpha, visible)


def texture_mean_value(tex: dict) -> float:
    """The scalar mean Mitsuba's RGB variants give a texture record (``Texture::mean``):
    a ``bitmap``'s mean texel luminance, a ``checkerboard``'s mean of its two colours'
    channel means (``src/textures/bitmap.cpp``, ``checkerboard.cpp``; an ``rgb``
    constant's mean is that of its channels)."""
    if tex["type"] == "bitmap":
        return float((np.asarray(tex["data"], dtype=np.float64).reshape(-1, 3) @ LUMINANCE).mean())
    return float(0.5 * (np.mean(tex["color0"]) + np.mean(tex["color1"])))


def _scalar_texture_mean(tex: dict) -> float:
    """The mean of a texture read as Mitsuba's ``eval_1`` (the luminance of its RGB): a
    bitmap's is its :func:`texture_mean_value`; a checkerboard's the luminance of its
    colours' mean."""
    if tex["type"] == "bitmap":
        return texture_mean_value(tex)
    return float(0.5 * (np.asarray(tex["color0"]) + np.asarray(tex["color1"])) @ LUMINANCE)


def with_specular_textures(scene: Scene) -> Scene:
    """``scene`` with the textured ``specular_reflectance`` of every conductor and
    dielectric, smooth, rough or thin (a blendbsdf's components included), moved to the
    material's ``texture`` (so that :func:`impl.lighting.diffuse_albedo` reads it at a
    hit; its mean as ``reflectance``), the constant ``specular_reflectance`` then
    Mitsuba's default 1; or ``scene`` itself without one.  The caller multiplies the
    reflected weights by that value (:mod:`impl.path`), as Mitsuba's conductors and
    dielectrics multiply by their texture's ``eval``."""
    import dataclasses

    from core.scene import SPECULAR_TEXTURED, texture_mean

    def moved(m):
        if m.components:
            comps = tuple(moved(c) for c in m.components)
            return m if all(a is b for a, b in zip(comps, m.components)) else \
                dataclasses.replace(m, components=comps)
        if m.kind not in SPECULAR_TEXTURED or "specular_reflectance" not in m.textures:
            return m
        tex = m.textures["specular_reflectance"]
        mean = texture_mean(tex)
        rest = {k: v for k, v in m.textures.items() if k != "specular_reflectance"}
        return dataclasses.replace(m, texture=tex, reflectance=tuple(float(x) for x in mean), textures=rest)

    mats = [moved(m) for m in scene.materials]
    if all(a is b for a, b in zip(mats, scene.materials)):
        return scene
    return dataclasses.replace(scene, materials=mats)


def with_specular_textures_cached(scene: Scene) -> Scene:
    """:func:`with_specular_textures`, remembered per scene object
    (:func:`impl.scene_arrays.scene_memo`), so that the renders of one scene flatten the
    same moved scene once."""
    from .scene_arrays import scene_memo

    def moved():                 # None when nothing moves: the memo must not hold the scene itself
        m = with_specular_textures(scene)
        return None if m is scene else m

    return scene_memo(scene, "specular_textures", moved) or scene


def expand_components(scene: Scene, *, algorithm: str = "path") -> Scene:
    """``scene`` with the components of every ``blendbsdf`` appended to its materials,
    those of a blendbsdf nested in a component too (so that each has its own row in
    every per-material array; shapes keep their indices), or ``scene`` itself without a
    blendbsdf.  A blendbsdf's row takes its leaves' ``twosided`` (which must agree).

    Raises
    ------
    UnsupportedError
        A component with a mask or a normal / bump map, or leaves that differ in
        ``twosided``.
    """
    import dataclasses

    if not any(m.components for m in scene.materials):
        return scene
    mats = list(scene.materials)

    def leaves(m, where):
        for c in m.components:
            if c.opacity is not None or c.shading is not None:
                raise UnsupportedError(f"{where}: a mask, normalmap or bumpmap inside a blendbsdf is "
                                       "not modelled")
            yield from leaves(c, where) if c.components else (c,)

    def append(m):
        """Rows for the components of blendbsdf ``m`` and of those nested in them."""
        for c in m.components:
            mats.append(c)
            if c.components:
                append(c)

    for i, m in enumerate(scene.materials):
        if not m.components:
            continue
        where = f"{algorithm}: blendbsdf '{m.name or i}'"
        sides = {c.twosided for c in leaves(m, where)}
        if len(sides) != 1:
            raise UnsupportedError(f"{where}: one two-sided and one one-sided component is not modelled")
        mats[i] = dataclasses.replace(m, twosided=sides.pop())
        append(m)
    return dataclasses.replace(scene, materials=mats)


class WrapperArrays(NamedTuple):
    """Per-material rows of the wrappers ``mask`` and ``blendbsdf`` and of a textured or
    anisotropic roughness (one row per material of a scene after
    :func:`expand_components`).  The scalar textures' slots: 0 the mask's opacity, 1 the
    blend weight, 2 the ``alpha`` (or ``alpha_u``) and 3 the ``alpha_v`` of a
    roughconductor / roughdielectric."""

    opacity: np.ndarray         # (M,) mask opacity (1: no mask; a texture's mean when textured)
    comp: np.ndarray            # (M, 2) int: a blendbsdf's component rows (else the row itself)
    blend_w: np.ndarray         # (M,) blend weight of the second component (a texture's mean when textured)
    ptex: np.ndarray            # (M, 4, 6) int: a slot's texture: code (scene_arrays TEX_*: 0 none,
                                # 1 checkerboard, 2 bitmap), first texel in ptex_data, width, height,
                                # wrap, filter
    ptex_uv: np.ndarray         # (M, 4, 2, 3) its 2D affine to_uv map
    ptex_c: np.ndarray          # (M, 4, 2) a checkerboard's two values (luminance of color0, color1)
    ptex_data: np.ndarray       # (K, 3) linear RGB texels of those bitmaps, row-major, concatenated
    alpha_v: np.ndarray         # (M,) roughness α_v along the tangent t (= alpha when isotropic; a
                                # texture's mean when textured)
    aniso: np.ndarray           # (M,) int 1: anisotropic (α_u ≠ α_v or either textured); a
                                # blendbsdf's row when any of its leaves is
    leaf: np.ndarray            # (M, NL) int: a blendbsdf's leaves (the non-blend BSDFs of its tree,
                                # first component first; −1 after the last); a row's own index else
    leaf_node: np.ndarray       # (M, NL, D) int: each leaf's blendbsdf ancestors from the row down
                                # (−1 after the last) ...
    leaf_branch: np.ndarray     # (M, NL, D) int: ... and the component (0, 1) taken at each


#: Scalar texture slots of :class:`WrapperArrays`.
N_SLOTS = 4


def no_wrappers(n: int, alpha: np.ndarray | None = None) -> WrapperArrays:
    """:class:`WrapperArrays` of ``n`` materials without a mask, a blendbsdf or a
    textured or anisotropic roughness: opacity 1, each row its own components, no
    textures (identity ``to_uv`` maps), α_v = ``alpha`` (zeros when not given)."""
    uv = np.zeros((n, N_SLOTS, 2, 3))
    uv[:, :, 0, 0] = uv[:, :, 1, 1] = 1.0
    alpha_v = np.zeros(n) if alpha is None else np.array(alpha, dtype=np.float64)
    rows = np.arange(n, dtype=np.int64)
    return WrapperArrays(np.ones(n), np.repeat(rows[:, None], 2, axis=1),
                         np.zeros(n), np.zeros((n, N_SLOTS, 6), dtype=np.int64), uv,
                         np.zeros((n, N_SLOTS, 2)), np.zeros((0, 3)), alpha_v, np.zeros(n, dtype=np.int64),
                         rows[:, None].copy(), np.full((n, 1, 1), -1, dtype=np.int64),
                         np.zeros((n, 1, 1), dtype=np.int64))


def _leaf_tables(kind, comp):
    """``leaf``, ``leaf_node`` and ``leaf_branch`` of :class:`WrapperArrays` from the rows'
    kinds and blendbsdf components ``comp`` (M, 2)."""
    n = len(kind)
    paths = []
    for i in range(n):
        out, stack = [], [(i, ())]
        while stack:                                  # depth first, first component first
            row, path = stack.pop()
            if kind[row] == MAT_BLEND:
                stack += [(comp[row, 1], path + ((row, 1),)), (comp[row, 0], path + ((row, 0),))]
            else:
                out.append((row, path))
        paths.append(out)
    nl = max(len(p) for p in paths) if n else 1
    d = max([len(path) for p in paths for _, path in p] + [1])
    leaf = np.full((n, nl), -1, dtype=np.int64)
    node = np.full((n, nl, d), -1, dtype=np.int64)
    branch = np.zeros((n, nl, d), dtype=np.int64)
    for i, p in enumerate(paths):
        for k, (row, path) in enumerate(p):
            leaf[i, k] = row
            for j, (a, b) in enumerate(path):
                node[i, k, j], branch[i, k, j] = a, b
    return leaf, node, branch


def wrapper_arrays(scene: Scene, *, algorithm: str = "path", bump_tangent: bool = False) -> WrapperArrays:
    """:class:`WrapperArrays` of ``scene`` (expanded by :func:`expand_components`);
    ``bump_tangent``: the caller takes an anisotropic BSDF's tangent under a bump map
    as Mitsuba's bump frame does (:func:`impl.shading_frame.bump_tangent`).  A
    scalar texture is read as Mitsuba's ``eval_1``: the luminance of the bitmap's linear
    RGB (a grey image's value), clipped to [0, 1] where used (opacity, weight; not a
    roughness).

    Raises
    ------
    UnsupportedError
        A texture other than a bitmap or checkerboard as opacity, blend weight or
        roughness; anisotropic roughness under a bump map unless ``bump_tangent``.
    """
    from .scene_arrays import FILTER_CODES, TEX_BITMAP, TEX_CHECKERBOARD, WRAP_CODES

    index = {id(m): i for i, m in enumerate(scene.materials)}
    opacity, comp, blend_w, ptex, ptex_uv, ptex_c, _, alpha_v, aniso, *_ = no_wrappers(len(scene.materials))
    texels, n = [], 0

    def scalar(i, slot, value, role):
        """Record texture ``value`` in ``slot`` of row i; its constant or mean value."""
        nonlocal n
        if value["type"] == "constant":
            return float(value["value"])
        ptex_uv[i, slot] = np.asarray(value["to_uv"])[:2]
        if value["type"] == "checkerboard":
            ptex[i, slot, 0] = TEX_CHECKERBOARD
            ptex_c[i, slot] = (np.asarray(value["color0"]) @ LUMINANCE,
                               np.asarray(value["color1"]) @ LUMINANCE)
            return _scalar_texture_mean(value)
        if value["type"] != "bitmap":
            raise UnsupportedError(f"{algorithm}: material '{scene.materials[i].name or i}': a "
                                   f"{value['type']} texture as {role} is not modelled")
        img = np.asarray(value["data"], dtype=np.float64)
        ptex[i, slot] = (TEX_BITMAP, n, img.shape[1], img.shape[0], WRAP_CODES[value["wrap_mode"]],
                         FILTER_CODES[value["filter_type"]])
        texels.append(img.reshape(-1, 3))
        n += img.shape[0] * img.shape[1]
        return _scalar_texture_mean(value)

    for i, m in enumerate(scene.materials):
        if m.opacity is not None:
            opacity[i] = scalar(i, 0, m.opacity, "a mask's opacity")
        if m.kind == "blendbsdf":
            if any(id(c) not in index for c in m.components):
                raise ValueError("wrapper_arrays: the scene's blendbsdf components have no rows; "
                                 "expand it with expand_components first")
            comp[i] = [index[id(c)] for c in m.components]
            w = m.textures.get("weight", {"type": "constant", "value": m.params.get("weight", 0.5)})
            blend_w[i] = scalar(i, 1, w, "a blendbsdf's weight")
        if m.kind in ("roughconductor", "roughdielectric"):
            where = f"{algorithm}: material '{m.name or i}'"
            au, alpha_v[i], _ = _roughness(m.params, where, tuple(DISTRIBUTIONS), tuple(m.textures), True)
            for slot, name in ((2, "alpha"), (2, "alpha_u"), (3, "alpha_v")):
                if name in m.textures:
                    mean = scalar(i, slot, m.textures[name], "a roughness")
                    if slot == 3:
                        alpha_v[i] = mean
                    else:
                        au = mean
            if "alpha" in m.textures:
                alpha_v[i] = au
            aniso[i] = int(au != alpha_v[i] or "alpha_u" in m.textures or "alpha_v" in m.textures)
            if aniso[i] and not bump_tangent and m.shading is not None and m.shading["type"] == "bumpmap":
                raise UnsupportedError(f"{where}: anisotropic roughness under a bumpmap is not modelled "
                                       "(the bump frame's tangent)")
    kind = np.array([KIND_CODES.get(m.kind, -1) for m in scene.materials])
    leaf, leaf_node, leaf_branch = _leaf_tables(kind, comp)
    for i, m in enumerate(scene.materials):
        if m.kind == "blendbsdf":
            aniso[i] = max(aniso[r] for r in leaf[i] if r >= 0)
            if aniso[i] and not bump_tangent and m.shading is not None and m.shading["type"] == "bumpmap":
                raise UnsupportedError(f"{algorithm}: material '{m.name or i}': anisotropic roughness "
                                       "under a bumpmap is not modelled (the bump frame's tangent)")
    opacity, blend_w = np.clip(opacity, 0.0, 1.0), np.clip(blend_w, 0.0, 1.0)
    data = np.ascontiguousarray(np.concatenate(texels) if texels else np.zeros((0, 3)), dtype=np.float64)
    return WrapperArrays(opacity, comp, blend_w, ptex, ptex_uv, ptex_c, data, alpha_v, aniso, leaf, leaf_node,
                         leaf_branch)


def distribution_codes(scene: Scene) -> np.ndarray:
    """(M,) int: the microfacet distribution of each rough material
    (:data:`impl.microfacet.DISTRIBUTIONS`; Beckmann for the others)."""
    out = np.zeros(len(scene.materials), dtype=np.int64)
    for i, m in enumerate(scene.materials):
        if m.kind in ("roughconductor", "roughdielectric", "roughplastic"):
            out[i] = DISTRIBUTIONS.get(str(m.params.get("distribution", "beckmann")).lower(), 0)
    return out


class PlasticArrays(NamedTuple):
    """Per-material rows of the plastic BSDFs (:mod:`impl.plastic`); rows of other
    materials hold zeros and ``is_plastic = 0``."""

    is_plastic: np.ndarray      # (M,) int: 0 other, 1 plastic, 2 roughplastic
    eta: np.ndarray             # (M,) int_ior / ext_ior
    diffuse: np.ndarray         # (M, 3) diffuse_reflectance (a texture's mean when textured)
    specular: np.ndarray        # (M, 3) specular_reflectance
    spec_weight: np.ndarray     # (M,) probability weight of the specular lobe
    nonlinear: np.ndarray       # (M,) int
    alpha: np.ndarray           # (M,) Beckmann roughness (roughplastic)
    visible: np.ndarray         # (M,) int: sample visible normals
    fdr_int: np.ndarray         # (M,) plastic: inner diffuse Fresnel reflectance
    ext_t: np.ndarray           # (M, TABLE_RES) roughplastic: coat transmittance over cos θ
    int_r: np.ndarray           # (M,) roughplastic: internal diffuse reflectance


def plastic_arrays(scene: Scene, *, algorithm: str = "plastic",
                   distributions: tuple[str, ...] = ("beckmann",)) -> PlasticArrays:
    """:class:`PlasticArrays` for ``scene.materials`` (only plastic kinds are decoded).

    Raises
    ------
    UnsupportedError
        A roughplastic distribution not in ``distributions``.
    SceneError
        Malformed parameters (an unknown IOR name, equal indices on a roughplastic).
    """
    from .plastic import TABLE_RES, plastic_params

    M = len(scene.materials)
    out = PlasticArrays(np.zeros(M, dtype=np.int64), np.ones(M), np.zeros((M, 3)), np.zeros((M, 3)),
                        np.zeros(M), np.zeros(M, dtype=np.int64), np.zeros(M),
                        np.ones(M, dtype=np.int64), np.zeros(M), np.zeros((M, TABLE_RES)), np.zeros(M))
    for i, m in enumerate(scene.materials):
        if m.kind not in ("plastic", "roughplastic"):
            continue
        p = plastic_params(m, where=f"{algorithm}: material '{m.name or i}'", distributions=distributions)
        out.is_plastic[i] = 1 if m.kind == "plastic" else 2
        out.eta[i], out.spec_weight[i], out.alpha[i] = p.eta, p.spec_weight, p.alpha
        out.diffuse[i], out.specular[i] = np.asarray(m.reflectance), p.specular
        out.nonlinear[i], out.visible[i] = int(p.nonlinear), int(p.visible)
        out.fdr_int[i], out.ext_t[i], out.int_r[i] = p.fdr_int, p.ext_t, p.int_r
    return out
