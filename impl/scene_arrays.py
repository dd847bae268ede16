"""Flatten the scene model into the plain arrays the numba kernels take.

Primitives are numbered spheres first, then triangles; ``prim_shape`` maps a
primitive to its shape (the index used for shape-id images).  Area emitters
become per-emitter triangle lists with an area CDF for uniform area sampling.
Light ``kind`` codes: 0 point, 1 directional, 2 spot, 3 projector (Mitsuba's
``projector``: ``light_rad`` is π × scale × its constant irradiance, ``light_proj``
its projection constants and ``light_tex_*`` its ``irradiance`` bitmap, evaluated
by :func:`impl.projector.projector_weight`; a spot's ``texture`` bitmap is in
``light_tex_*`` too, evaluated by :func:`impl.lighting.spot_texture`).  Material ``kind``
codes: 0 diffuse, 1 conductor, 2 dielectric, 3 roughconductor, 4 roughdielectric, 5 plastic,
6 roughplastic, 9 thindielectric, 10 blendbsdf; an algorithm
refuses the kinds it cannot model.  Textured diffuse reflectance: ``mat_tex``
code 0 none, 1 checkerboard (colours and the 2x3 ``to_uv`` map per material),
2 bitmap (texels of every image concatenated in ``tex_data``, row-major, with
each material's offset, size, wrap and filter codes of :mod:`impl.textures`),
looked up at the triangle's interpolated ``tri_uv``.  RGB parameter textures, the
same codes in four slots (``mat_ptex``, :data:`PTEX_TRANSMITTANCE`, :data:`PTEX_ETA`,
:data:`PTEX_K`, :data:`PTEX_PLASTIC_SPECULAR`): a dielectric's ``specular_transmittance``,
a conductor's ``eta`` / ``k`` and a plastic's ``specular_reflectance``
(:func:`impl.lighting.param_rgb`).  A ``constant``
environment emitter is ``env_radiance`` (one row, or none); an ``envmap``
emitter is ``env_image`` (the map times its scale; 0 rows without one) with its
rotation ``env_frame`` and luminance sampling tables ``env_pdf`` / ``env_cdf``
(:func:`impl.envmap.envmap_tables`, evaluated and sampled by
:mod:`impl.envmap`'s inline functions).  The loader keeps at most one of the two.
A ``normalmap`` or ``bumpmap`` around a material is ``mat_shade`` (code 0
none, 1 normal map, 2 bump map) with its bitmap in ``tex_data``
(``mat_shade_*``) and the bump ``scale`` (:mod:`impl.shading_frame`).
"""

from __future__ import annotations

import math
import weakref
from collections import OrderedDict
from typing import Callable, NamedTuple

import numpy as np
from numba import njit

from core.scene import Scene
from core.errors import UnsupportedError

from .envmap import envmap_tables
from .textures import FILTER_BILINEAR, FILTER_NEAREST, WRAP_CLAMP, WRAP_MIRROR, WRAP_REPEAT

WRAP_CODES = {"repeat": WRAP_REPEAT, "clamp": WRAP_CLAMP, "mirror": WRAP_MIRROR}
FILTER_CODES = {"bilinear": FILTER_BILINEAR, "nearest": FILTER_NEAREST}

__all__ = ["SceneArrays", "diffuse_texture", "flatten", "triangle_normal", "triangle_normals", "flatten_cached", "scene_memo", "LIGHT_POINT", "LIGHT_DIRECTIONAL", "LIGHT_SPOT",
           "LIGHT_PROJECTOR", "SHADE_NONE", "SHADE_NORMALMAP", "SHADE_BUMPMAP",
           "TEX_NONE", "TEX_CHECKERBOARD", "TEX_BITMAP", "MATERIAL_CODES",
           "PTEX_TRANSMITTANCE", "PTEX_ETA", "PTEX_K", "PTEX_PLASTIC_SPECULAR"]

LIGHT_POINT, LIGHT_DIRECTIONAL, LIGHT_SPOT, LIGHT_PROJECTOR = 0, 1, 2, 3
SHADE_NONE, SHADE_NORMALMAP, SHADE_BUMPMAP = 0, 1, 2
TEX_NONE, TEX_CHECKERBOARD, TEX_BITMAP = 0, 1, 2

#: Slots of the RGB parameter textures (``mat_ptex``): a dielectric's
#: ``specular_transmittance``, a conductor's ``eta`` and ``k``.
PTEX_TRANSMITTANCE, PTEX_ETA, PTEX_K = 0, 1, 2
#: The slot of a plastic's or roughplastic's textured ``specular_reflectance``, which
#: weights its specular coat only (``impl.path``).
PTEX_PLASTIC_SPECULAR = 3


class SceneArrays(NamedTuple):
    """A named tuple of arrays: numba passes it to kernels as one typed argument."""

    sph_center: np.ndarray      # (S, 3)
    sph_radius: np.ndarray      # (S,)
    tri_v: np.ndarray           # (T, 3, 3) world-space vertices
    tri_n: np.ndarray           # (T, 3, 3) vertex shading normals (zeros if none)
    tri_has_n: np.ndarray       # (T,) 1 where the triangle has shading normals
    prim_shape: np.ndarray      # (S + T,) shape index
    shape_material: np.ndarray  # (N,)
    shape_flip: np.ndarray      # (N,) 1 where flip_normals
    shape_emit: np.ndarray      # (N, 3) area-emitter radiance (0 if none)
    mat_kind: np.ndarray        # (M,)
    mat_rho: np.ndarray         # (M, 3)
    mat_twosided: np.ndarray    # (M,)
    light_kind: np.ndarray      # (L,)
    light_pos: np.ndarray       # (L, 3)
    light_dir: np.ndarray       # (L, 3) direction of travel / spot axis
    light_rad: np.ndarray       # (L, 3) intensity or irradiance
    light_cos_cutoff: np.ndarray
    light_cos_beam: np.ndarray
    light_cutoff: np.ndarray    # radians
    light_inv_tw: np.ndarray    # 1 / (cutoff - beam width), radians
    light_local: np.ndarray     # (L, 3, 3) world -> emitter-local linear map (spot: inverse of to_world's 3x3)
    em_offset: np.ndarray       # (E + 1,) ranges into em_tri / em_cdf
    em_tri: np.ndarray          # (K,) triangle index (into tri_*)
    em_cdf: np.ndarray          # (K,) cumulative area fraction within its emitter
    em_area: np.ndarray         # (E,)
    em_shape: np.ndarray        # (E,)
    tri_uv: np.ndarray          # (T, 3, 2) vertex texture coordinates (zeros if none)
    tri_has_uv: np.ndarray      # (T,) 1 where the triangle has texture coordinates
    mat_tex: np.ndarray         # (M,) texture code of the diffuse reflectance
    mat_tex_c0: np.ndarray      # (M, 3) checkerboard color0
    mat_tex_c1: np.ndarray      # (M, 3) checkerboard color1
    mat_tex_uv: np.ndarray      # (M, 2, 3) 2D affine to_uv map (first two rows)
    tex_data: np.ndarray        # (K, 3) linear RGB texels of every bitmap, row-major, concatenated
    mat_tex_offset: np.ndarray  # (M,) first texel of the material's bitmap in tex_data
    mat_tex_size: np.ndarray    # (M, 2) bitmap width, height (0 if none)
    mat_tex_wrap: np.ndarray    # (M,) impl.textures WRAP_* code
    mat_tex_filter: np.ndarray  # (M,) impl.textures FILTER_* code
    env_radiance: np.ndarray    # (1, 3) radiance of a constant environment emitter, or (0, 3)
    env_image: np.ndarray       # (H, W, 3) envmap radiance (map × scale), or (0, 0, 3) without one
    env_frame: np.ndarray       # (2, 3, 3) envmap world -> map and map -> world rotations
    env_pdf: np.ndarray         # (H, W + 1) envmap sampling density at the grid vertices
    env_cdf: np.ndarray         # ((H - 1) W,) envmap cumulative cell integrals (all 0: black map)
    mat_shade: np.ndarray       # (M,) 0 none, 1 normalmap, 2 bumpmap (SHADE_*)
    mat_shade_scale: np.ndarray  # (M,) bumpmap scale
    mat_shade_tex: np.ndarray   # (M, 8) its bitmap: first texel in tex_data, width, height, wrap, filter;
                                # then Mitsuba's flip_invalid_normals and use_shadowing_function, and
                                # whether the map wraps a twosided (0/1)
    mat_shade_uv: np.ndarray    # (M, 2, 3) its 2D affine to_uv map
    light_proj: np.ndarray      # (L, 3) projector: cot(fov_x / 2), image aspect, |to_world · e_z|
    light_tex: np.ndarray       # (L, 5) projector irradiance / spot texture bitmap (width 0: none)
    light_tex_uv: np.ndarray    # (L, 2, 3) its to_uv map
    tri_ng: np.ndarray          # (T, 3) unit geometric normal (v1 − v0) × (v2 − v0) / |…|
    mat_ptex: np.ndarray        # (M, 4, 6) int RGB parameter textures (PTEX_*): code (TEX_*; 0 the
                                # constant in mat_ptex_c[:, :, 0]), first texel in tex_data, width,
                                # height, wrap, filter
    mat_ptex_c: np.ndarray      # (M, 4, 2, 3) a checkerboard's color0, color1; a bitmap's mean texel
                                # in row 0; the constant of an untextured slot in row 0
    mat_ptex_uv: np.ndarray     # (M, 4, 2, 3) their 2D affine to_uv maps

    @property
    def n_spheres(self) -> int:
        return len(self.sph_radius)


MATERIAL_CODES = {"diffuse": 0, "conductor": 1, "dielectric": 2, "roughconductor": 3, "roughdielectric": 4,
                  "plastic": 5, "roughplastic": 6, "gibench_cooktorrance": 7, "gibench_difftrans": 8,
                  "thindielectric": 9, "blendbsdf": 10}


def diffuse_texture(m) -> dict | None:
    """The texture of material ``m``'s diffuse reflectance ρ, or None: a diffuse BSDF's
    ``reflectance`` texture, a plastic's ``diffuse_reflectance`` texture."""
    if m.texture is not None:
        return m.texture
    if m.kind in ("plastic", "roughplastic"):
        return m.textures.get("diffuse_reflectance")
    return None


def projector_constants(light) -> tuple:
    """``(cot(fov_x / 2), aspect, |to_world · e_z|)`` of a projector: Mitsuba's
    ``projector`` maps a point in its frame to uv = (½ − ½ cot x/z, ½ − ½ aspect cot y/z)
    (its camera-to-sample projection) and divides by z² (−n · d), n = to_world · e_z
    not normalised."""
    m = np.asarray(light.to_world, dtype=np.float64)
    data = None if light.texture is None else light.texture.get("data")
    aspect = 1.0 if data is None else data.shape[1] / data.shape[0]
    return (1.0 / np.tan(0.5 * np.deg2rad(light.fov_x)), aspect, float(np.linalg.norm(m[:3, 2])))


def _light_local(light) -> np.ndarray:
    """The linear map taking a world direction into the light's own frame, where a spot
    points along +z (Mitsuba's ``spot`` evaluates its cone there: the inverse of its
    to_world applied to the direction, then normalised, so a non-uniform scale or a
    shear in to_world makes the world-space cone elliptical).  A spot without a
    to_world gets an orthonormal frame whose third row is its axis; other lights the
    identity (unused)."""
    if light.kind == "projector":
        return np.linalg.inv(np.asarray(light.to_world, dtype=np.float64)[:3, :3])
    if light.kind != "spot":
        return np.eye(3)
    if light.to_world is not None:
        return np.linalg.inv(np.asarray(light.to_world, dtype=np.float64)[:3, :3])
    z = np.asarray(light.direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


@njit(inline="always", cache=True)
def triangle_normal(v):
    """Unit normal (v1 − v0) × (v2 − v0) / |…| of the triangle with vertices ``v`` (3, 3)."""
    e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    gx, gy, gz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    inv = 1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)
    return gx * inv, gy * inv, gz * inv


@njit(cache=True, error_model="numpy")
def triangle_normals(tri_v):
    """(T, 3) :func:`triangle_normal` of every triangle of ``tri_v`` (T, 3, 3): the table
    the shading steps read (``SceneArrays.tri_ng``), the same bits as the kernel computes
    from the vertices.  A degenerate triangle gets a non-finite normal; no ray hits it."""
    out = np.empty((tri_v.shape[0], 3))
    for j in range(tri_v.shape[0]):
        out[j, 0], out[j, 1], out[j, 2] = triangle_normal(tri_v[j])
    return out


def flatten(scene: Scene) -> SceneArrays:
    spheres = [s for s in scene.shapes if s.kind == "sphere"]
    meshes = [s for s in scene.shapes if s.kind == "mesh"]
    index = {id(s): i for i, s in enumerate(scene.shapes)}
    prim_shape = [index[id(s)] for s in spheres]
    tri_v, tri_n, tri_has_n, tri_uv, tri_has_uv = [], [], [], [], []
    tri_base = {}
    for s in meshes:
        tri_base[id(s)] = sum(len(t) for t in tri_v)
        tri_v.append(s.vertices[s.faces])
        if s.uvs is not None:
            tri_uv.append(s.uvs[s.faces])
            tri_has_uv.append(np.ones(len(s.faces), np.int64))
        else:
            tri_uv.append(np.zeros((len(s.faces), 3, 2)))
            tri_has_uv.append(np.zeros(len(s.faces), np.int64))
        if s.normals is not None:
            tri_n.append(s.normals[s.faces])
            tri_has_n.append(np.ones(len(s.faces), np.int64))
        else:
            tri_n.append(np.zeros((len(s.faces), 3, 3)))
            tri_has_n.append(np.zeros(len(s.faces), np.int64))
        prim_shape += [index[id(s)]] * len(s.faces)
    tri_v = np.ascontiguousarray(np.concatenate(tri_v) if tri_v else np.zeros((0, 3, 3)),
                                 dtype=np.float64)
    tri_n = np.concatenate(tri_n) if tri_n else np.zeros((0, 3, 3))
    tri_has_n = np.concatenate(tri_has_n) if tri_has_n else np.zeros(0, np.int64)
    tri_uv = np.concatenate(tri_uv) if tri_uv else np.zeros((0, 3, 2))
    tri_has_uv = np.concatenate(tri_has_uv) if tri_has_uv else np.zeros(0, np.int64)

    em_offset, em_tri, em_cdf, em_area, em_shape = [0], [], [], [], []
    for s in scene.emitters:
        if s.kind != "mesh":
            raise UnsupportedError(
                f"scene_arrays.flatten: area emitter on a {s.source} ('{s.name}') cannot be "
                "sampled yet; only triangle-mesh emitters (rectangle, cube, obj, ply) are")
        p = s.vertices[s.faces]
        a = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        em_tri.extend(tri_base[id(s)] + np.arange(len(a)))
        em_cdf.extend(np.cumsum(a) / a.sum())
        em_area.append(a.sum())
        em_shape.append(index[id(s)])
        em_offset.append(len(em_tri))

    tex_codes = {"checkerboard": TEX_CHECKERBOARD, "bitmap": TEX_BITMAP}
    texs = [diffuse_texture(m) for m in scene.materials]   # the textures ρ(u, v) reads
    mat_tex = [tex_codes[t["type"]] if t else TEX_NONE for t in texs]
    is_cb = [t is not None and t["type"] == "checkerboard" for t in texs]
    mat_tex_c0 = [t["color0"] if cb else (0.0, 0.0, 0.0) for t, cb in zip(texs, is_cb)]
    mat_tex_c1 = [t["color1"] if cb else (0.0, 0.0, 0.0) for t, cb in zip(texs, is_cb)]
    texels, tex_offset, tex_size, tex_wrap, tex_filter, n_texels = [], [], [], [], [], 0
    for t in texs:
        if t is not None and t["type"] == "bitmap":
            img = np.asarray(t["data"], dtype=np.float64)
            tex_offset.append(n_texels)
            tex_size.append((img.shape[1], img.shape[0]))
            tex_wrap.append(WRAP_CODES[t["wrap_mode"]])
            tex_filter.append(FILTER_CODES[t["filter_type"]])
            texels.append(img.reshape(-1, 3))
            n_texels += img.shape[0] * img.shape[1]
        else:
            tex_offset.append(0)
            tex_size.append((0, 0))
            tex_wrap.append(0)
            tex_filter.append(0)
    mat_tex_uv = [np.asarray(t["to_uv"])[:2] if t else np.eye(3)[:2] for t in texs]

    def bitmap_record(t, role: str):
        """(offset, width, height, wrap, filter) of bitmap ``t`` appended to the texels."""
        nonlocal n_texels
        if t is None:
            return (0, 0, 0, 0, 0)
        if t["type"] != "bitmap":
            raise UnsupportedError(f"scene_arrays.flatten: a {t['type']} texture as {role} is not "
                                   "modelled; only a bitmap is")
        img = np.asarray(t["data"], dtype=np.float64)
        rec = (n_texels, img.shape[1], img.shape[0], WRAP_CODES[t["wrap_mode"]], FILTER_CODES[t["filter_type"]])
        texels.append(img.reshape(-1, 3))
        n_texels += img.shape[0] * img.shape[1]
        return rec

    shade_codes = {"normalmap": SHADE_NORMALMAP, "bumpmap": SHADE_BUMPMAP}
    mat_shade = [shade_codes[m.shading["type"]] if m.shading else SHADE_NONE for m in scene.materials]
    mat_shade_tex = [bitmap_record(m.shading["texture"], f"the texture of a {m.shading['type']}")
                     + (int(m.shading.get("flip_invalid_normals", True)),
                        int(m.shading.get("use_shadowing_function", True)),
                        int(m.shading.get("wraps_twosided", False)))
                     if m.shading else (0,) * 8 for m in scene.materials]
    mat_shade_uv = [np.asarray(m.shading["texture"]["to_uv"])[:2] if m.shading else np.eye(3)[:2]
                    for m in scene.materials]
    mat_shade_scale = [float(m.shading.get("scale", 1.0)) if m.shading else 0.0 for m in scene.materials]

    mat_ptex, mat_ptex_c, mat_ptex_uv = _param_textures(scene.materials, bitmap_record)

    envmap = getattr(scene, "envmap", None)
    if envmap is not None:
        env = envmap_tables(envmap)
    else:
        env = (np.zeros((0, 0, 3)), np.stack([np.eye(3), np.eye(3)]), np.zeros((0, 1)), np.zeros(0))

    lights = scene.lights
    f64 = lambda x, shape: np.asarray(x, dtype=np.float64).reshape(shape)  # noqa: E731
    kinds = {"point": LIGHT_POINT, "directional": LIGHT_DIRECTIONAL, "spot": LIGHT_SPOT,
             "projector": LIGHT_PROJECTOR}
    cutoff = np.deg2rad([l.cutoff_angle for l in lights])
    beam = np.deg2rad([l.beam_width for l in lights])
    is_proj = [l.kind == "projector" for l in lights]
    imaged = [p or (l.kind == "spot" and l.texture is not None) for l, p in zip(lights, is_proj)]
    light_tex = [bitmap_record(l.texture, "a projector's irradiance" if p else "a spot's texture")
                 if i else (0, 0, 0, 0, 0) for l, p, i in zip(lights, is_proj, imaged)]
    light_tex_uv = [np.asarray(l.texture["to_uv"])[:2] if i and l.texture is not None else np.eye(3)[:2]
                    for l, i in zip(lights, imaged)]
    light_proj = [projector_constants(l) if p else (0.0, 0.0, 0.0) for l, p in zip(lights, is_proj)]
    light_rad = [np.pi * l.scale * np.asarray(l.radiant) if p else l.radiant for l, p in zip(lights, is_proj)]
    tex_data = np.ascontiguousarray(np.concatenate(texels) if texels else np.zeros((0, 3)), dtype=np.float64)
    return SceneArrays(
        sph_center=f64([s.center for s in spheres], (-1, 3)),
        sph_radius=f64([s.radius for s in spheres], (-1,)),
        tri_v=tri_v,
        tri_n=np.ascontiguousarray(tri_n, dtype=np.float64),
        tri_has_n=tri_has_n,
        tri_ng=triangle_normals(tri_v),
        prim_shape=np.asarray(prim_shape, dtype=np.int64),
        shape_material=np.asarray([s.material for s in scene.shapes], dtype=np.int64),
        shape_flip=np.asarray([int(s.flip_normals) for s in scene.shapes], dtype=np.int64),
        shape_emit=f64([s.emitter_radiance if s.is_emitter else np.zeros(3) for s in scene.shapes], (-1, 3)),
        mat_kind=np.asarray([MATERIAL_CODES[m.kind] for m in scene.materials], dtype=np.int64),
        mat_rho=f64([m.reflectance for m in scene.materials], (-1, 3)),
        mat_twosided=np.asarray([int(m.twosided) for m in scene.materials], dtype=np.int64),
        light_kind=np.asarray([kinds[l.kind] for l in lights], dtype=np.int64),
        light_pos=f64([l.position if l.position is not None else np.zeros(3) for l in lights], (-1, 3)),
        light_dir=f64([l.direction if l.direction is not None else np.zeros(3) for l in lights], (-1, 3)),
        light_rad=f64(light_rad, (-1, 3)),
        light_cos_cutoff=np.cos(cutoff).reshape(-1),
        light_cos_beam=np.cos(beam).reshape(-1),
        light_cutoff=cutoff.reshape(-1),
        light_inv_tw=np.where(cutoff > beam, 1.0 / np.maximum(cutoff - beam, 1e-12), np.inf).reshape(-1),
        light_local=np.asarray([_light_local(l) for l in lights], dtype=np.float64).reshape(-1, 3, 3),
        em_offset=np.asarray(em_offset, dtype=np.int64),
        em_tri=np.asarray(em_tri, dtype=np.int64),
        em_cdf=np.asarray(em_cdf, dtype=np.float64),
        em_area=np.asarray(em_area, dtype=np.float64),
        em_shape=np.asarray(em_shape, dtype=np.int64),
        tri_uv=np.ascontiguousarray(tri_uv, dtype=np.float64),
        tri_has_uv=tri_has_uv,
        mat_tex=np.asarray(mat_tex, dtype=np.int64),
        mat_tex_c0=f64(mat_tex_c0, (-1, 3)),
        mat_tex_c1=f64(mat_tex_c1, (-1, 3)),
        mat_tex_uv=f64(mat_tex_uv, (-1, 2, 3)),
        tex_data=tex_data,
        mat_tex_offset=np.asarray(tex_offset, dtype=np.int64),
        mat_tex_size=np.asarray(tex_size, dtype=np.int64).reshape(-1, 2),
        mat_tex_wrap=np.asarray(tex_wrap, dtype=np.int64),
        mat_tex_filter=np.asarray(tex_filter, dtype=np.int64),
        env_radiance=f64([] if scene.environment is None else [scene.environment], (-1, 3)),
        env_image=env[0],
        env_frame=env[1],
        env_pdf=env[2],
        env_cdf=env[3],
        mat_shade=np.asarray(mat_shade, dtype=np.int64),
        mat_shade_scale=f64(mat_shade_scale, (-1,)),
        mat_shade_tex=np.asarray(mat_shade_tex, dtype=np.int64).reshape(-1, 8),
        mat_shade_uv=f64(mat_shade_uv, (-1, 2, 3)),
        light_proj=f64(light_proj, (-1, 3)),
        light_tex=np.asarray(light_tex, dtype=np.int64).reshape(-1, 5),
        light_tex_uv=f64(light_tex_uv, (-1, 2, 3)),
        mat_ptex=mat_ptex,
        mat_ptex_c=mat_ptex_c,
        mat_ptex_uv=mat_ptex_uv,
    )


def _param_textures(materials, bitmap_record):
    """The RGB parameter textures of ``materials`` (``mat_ptex``, ``mat_ptex_c``,
    ``mat_ptex_uv`` of :class:`SceneArrays`): a dielectric's textured
    ``specular_transmittance``; a conductor's textured ``eta`` or ``k``, the other of the
    two then its constant (Mitsuba's defaults 0 and 1) in an untextured slot, so that
    both are read at the hit; a plastic's textured ``specular_reflectance``.  ``bitmap_record`` appends a bitmap's texels to the
    scene's and returns its record."""
    from core.scene import IOR_TEXTURED, TRANSMITTANCE_TEXTURED, texture_mean

    from .materials import rgb_param

    n = len(materials)
    code = np.zeros((n, 4, 6), dtype=np.int64)
    c = np.zeros((n, 4, 2, 3))
    uv = np.zeros((n, 4, 2, 3))
    uv[:, :, 0, 0] = uv[:, :, 1, 1] = 1.0
    for i, m in enumerate(materials):
        slots = []
        if m.kind in TRANSMITTANCE_TEXTURED and "specular_transmittance" in m.textures:
            slots.append((PTEX_TRANSMITTANCE, "specular_transmittance", 1.0))
        if m.kind in IOR_TEXTURED and ("eta" in m.textures or "k" in m.textures):
            slots += [(PTEX_ETA, "eta", 0.0), (PTEX_K, "k", 1.0)]
        if m.kind in ("plastic", "roughplastic") and "specular_reflectance" in m.textures:
            slots.append((PTEX_PLASTIC_SPECULAR, "specular_reflectance", 1.0))
        for slot, name, default in slots:
            t = m.textures.get(name)
            if t is None:
                c[i, slot, 0] = rgb_param(m.params, name, default, f"material '{m.name or i}'")
                continue
            uv[i, slot] = np.asarray(t["to_uv"])[:2]
            if t["type"] == "checkerboard":
                code[i, slot, 0] = TEX_CHECKERBOARD
                c[i, slot] = (t["color0"], t["color1"])
            else:
                code[i, slot] = (TEX_BITMAP,) + bitmap_record(t, f"the {name} of a {m.kind}")
                c[i, slot, 0] = texture_mean(t)
    return code, c, uv


#: Per-scene memo of :func:`scene_memo`: id(scene) -> (weak reference, content key, {key: value}).
_MEMO: OrderedDict = OrderedDict()
#: Scenes kept in the memo at once (least recently used dropped first).
MEMO_SCENES = 8


def _content_key(scene: Scene) -> tuple:
    """What the flattened arrays depend on, cheap to compute: the identities of the
    (immutable) shapes, materials and lights in order, the environment radiance and the
    (immutable) envmap."""
    env = None if scene.environment is None else tuple(np.asarray(scene.environment).ravel())
    return (tuple(map(id, scene.shapes)), tuple(map(id, scene.materials)),
            tuple(map(id, scene.lights)), env, id(getattr(scene, "envmap", None)))


def scene_memo(scene: Scene, key, build: Callable):
    """``build()``, remembered per scene object and ``key`` while the scene lives and its
    shapes, materials, lights and environment (constant or envmap) are the same; a render of the same
    scene reuses its flattened arrays and ray configurations instead of rebuilding them.
    Shapes, materials and lights are frozen; changing a mesh's arrays in place is not seen."""
    sid = id(scene)
    content = _content_key(scene)
    entry = _MEMO.get(sid)
    if entry is None or entry[0]() is not scene or entry[1] != content:
        entry = (weakref.ref(scene, lambda _ref, sid=sid: _MEMO.pop(sid, None)), content, {})
        _MEMO[sid] = entry
        while len(_MEMO) > MEMO_SCENES:
            _MEMO.popitem(last=False)
    _MEMO.move_to_end(sid)
    values = entry[2]
    if key not in values:
        values[key] = build()
    return values[key]


def flatten_cached(scene: Scene) -> SceneArrays:
    """:func:`flatten`, computed once per scene (:func:`scene_memo`)."""
    return scene_memo(scene, "flatten", lambda: flatten(scene))
