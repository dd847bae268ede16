"""Spectral rendering: light as a spectrum (thesis 2.4.1-2.4.3).

The path tracer's ``spectral=true`` mode carries radiance at sampled
wavelengths instead of three RGB channels:

* **Hero wavelengths** (A. Wilkie, S. Nawaz, M. Droske, A. Weidlich, J. Hanika,
  "Hero wavelength spectral sampling", EGSR 2014, :doi:`10.1111/cgf.12419`):
  per path a hero λ_h uniform on [360, 830] nm and two more rotated by a third
  of the range, λ_k = 360 + ((λ_h − 360 + k·470/3) mod 470) — each marginally
  uniform, so the three channels of the path kernel are three estimates at
  three wavelengths.
* **CIE 1931**: a sample of radiance L(λ_k) contributes
  XYZ += L(λ_k) x̄ȳz̄(λ_k) · (470 / 3) / ∫ȳ dλ (uniform pdf 1/470 per
  wavelength, three wavelengths; normalised so that a constant emission 1
  has Y = 1, as Mitsuba's spectral film does), then linear sRGB = M · XYZ.
  The colour matching functions, D65 and M come from colour-science
  (:func:`core.scene.cie_tables`).
* **Spectra of the scene**: ``<spectrum>`` reflectances and emissions are
  tabulated at 1 nm on 360-830 nm and interpolated linearly.  Values the file
  gives as RGB must be grey (r = g = b): a grey reflectance is a constant
  spectrum, a grey emission v is v × D65 normalised to Y = v (Mitsuba's
  spectral variants upsample RGB emission against D65 the same way); coloured
  RGB would need Jakob-Hanika upsampling, which is not implemented (refused).

**Dispersion** (thesis 2.4.4: the index of refraction depends on the
wavelength): a ``dielectric`` may carry the gibench-specific parameter
``<float name="cauchy_b" value="B"/>`` (µm²), Cauchy's law
n(λ) = A + B/λ² with A chosen so that n(589.3 nm) = ``int_ior`` (the sodium
D line at which IOR tables are quoted).  RGB rendering ignores it (n =
``int_ior``); Mitsuba cannot render such a file (it refuses the unknown
property), so dispersion is validated against the analytic deviation of a
prism instead.  In spectral mode the hero wavelength's index decides the
refracted (or reflected) direction and the two other wavelengths are dropped
at that vertex, the hero's weight multiplied by 3 (their estimate would need
other directions; Wilkie et al. 2014, §4.3).

Leaves out: RGB-to-spectrum upsampling of coloured values, spectral conductor
IORs, textures in spectral mode, fluorescence and polarisation.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from core.scene import Scene, Spectrum, cie_tables
from core.errors import SceneError, UnsupportedError

from .kernel import batch_kernel

__all__ = ["SpectralArrays", "spectral_arrays", "rgb_arrays_placeholder", "cauchy_arrays",
           "cauchy_ior", "eta_scale_at", "LAMBDA_D_UM", "LAMBDA_MIN",
           "LAMBDA_MAX", "sample_wavelengths", "spectrum_at", "to_linear_srgb"]

LAMBDA_MIN, LAMBDA_MAX = 360.0, 830.0
_RANGE = LAMBDA_MAX - LAMBDA_MIN


class SpectralArrays(NamedTuple):
    """Spectra on the 1 nm grid of [360, 830] nm (numba takes it as one argument)."""

    mat_spec: np.ndarray        # (M, K) diffuse reflectance spectra
    emit_spec: np.ndarray       # (N, K) area emission spectra per shape (0 if none)
    light_spec: np.ndarray      # (n_lights, K) per NEE light entry (delta, mesh, sphere emitters)
    cauchy_b: np.ndarray        # (M,) dispersion B (µm²) of dielectrics, 0 = none
    ior_d: np.ndarray           # (M,) their int_ior, n at 589.3 nm
    cmf: np.ndarray             # (K, 3) x̄ ȳ z̄
    to_rgb: np.ndarray          # (3, 3) XYZ -> linear sRGB
    scale: float                # (470 / 3) / ∫ȳ dλ


def _grid():
    wl, xyz, d65, M = cie_tables()
    return wl, xyz, d65, M


def _grey(value, where: str, what: str) -> float:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.size == 1 or np.all(v == v[0]):
        return float(v[0])
    raise UnsupportedError(
        f"path (spectral=true): {where}: {what} is the RGB value {v.tolist()}; spectral "
        "rendering needs a <spectrum> or a grey value (RGB-to-spectrum upsampling is not "
        "implemented)")


def _emission_table(value, spectrum: Spectrum | None, where: str, what: str):
    wl, xyz, d65, _ = _grid()
    if spectrum is not None:
        return spectrum(wl)
    v = _grey(value, where, what)
    return v * d65 * xyz[:, 1].sum() / (d65 @ xyz[:, 1])


def spectral_arrays(scene: Scene, A, L) -> SpectralArrays:
    """Tabulate the scene's spectra for the spectral path tracer (checks every used value).

    ``A``, ``L``: the flattened scene and lights (:func:`impl.light_sampling.flatten_with_lights`),
    whose light-entry order the ``light_spec`` rows follow.
    """
    if getattr(scene, "envmap", None) is not None:
        raise UnsupportedError(f"path (spectral=true): envmap emitter '{scene.envmap.filename}': "
                               "its image is RGB (no spectral upsampling); render it with spectral=false")
    wl, xyz, d65, M = _grid()
    K = len(wl)
    used = {s.material for s in scene.shapes}
    mat_spec = np.zeros((len(scene.materials), K))
    for i, m in enumerate(scene.materials):
        if i not in used:
            continue
        where = f"material '{m.name or i}' ({m.kind})"
        if m.kind in ("plastic", "roughplastic"):
            raise UnsupportedError(f"path (spectral=true): {where}: plastic BSDFs are not modelled "
                                   "in spectral mode")
        if m.kind in ("conductor", "roughconductor") and m.params.get("material", "none") != "none":
            raise UnsupportedError(f"path (spectral=true): {where}: the named conductor "
                                   f"'{m.params['material']}' is tabulated in RGB only; its spectral "
                                   "IOR is not modelled")
        if m.texture is not None:
            raise UnsupportedError(f"path (spectral=true): {where}: textures are not "
                                      "supported in spectral mode")
        for name in ("specular_reflectance", "specular_transmittance", "eta", "k"):
            if name in m.params:
                if isinstance(m.params[name], Spectrum):
                    raise UnsupportedError(f"path (spectral=true): {where}: a spectral "
                                              f"'{name}' is not modelled")
                _grey(m.params[name], where, f"'{name}'")
        refl = m.params.get("reflectance")
        if isinstance(refl, Spectrum):
            mat_spec[i] = refl(wl)
        elif m.kind == "diffuse":
            mat_spec[i] = _grey(m.reflectance, where, "'reflectance'")
    emit_spec = np.zeros((len(scene.shapes), K))
    for j, s in enumerate(scene.shapes):
        if s.is_emitter:
            emit_spec[j] = _emission_table(s.emitter_radiance, s.emitter_spectrum,
                                           f"shape '{s.name or j}'", "its radiance")
    rows = [_emission_table(l.radiant, None, f"{l.kind} light '{l.name}'", "its intensity")
            for l in scene.lights]
    rows += [emit_spec[sh] for sh in A.em_shape]
    rows += [emit_spec[A.prim_shape[p]] for p in L.sph_em_prim]
    light_spec = np.array(rows).reshape(-1, K) if rows else np.zeros((0, K))
    cauchy_b, ior_d = cauchy_arrays(scene)
    return SpectralArrays(mat_spec, emit_spec, light_spec, cauchy_b, ior_d, np.ascontiguousarray(xyz),
                          np.ascontiguousarray(M), float(_RANGE / 3.0 / xyz[:, 1].sum()))


#: Wavelength (µm) at which a dispersive dielectric's n equals its int_ior.
LAMBDA_D_UM = 0.5893


def cauchy_arrays(scene: Scene):
    """Per-material Cauchy B (µm², 0 = none) and int_ior; checks ``cauchy_b``."""
    from .fresnel import lookup_ior

    M = len(scene.materials)
    b, n_d = np.zeros(M), np.ones(M)
    for i, m in enumerate(scene.materials):
        if "cauchy_b" not in m.params:
            continue
        where = f"material '{m.name or i}' ({m.kind})"
        v = m.params["cauchy_b"]
        if m.kind != "dielectric" or not isinstance(v, int | float) or not (0.0 <= v < 1.0):
            raise SceneError(f"path: {where}: 'cauchy_b' must be a float in [0, 1) µm² on a "
                             f"dielectric, got {v!r}")
        n_d[i] = lookup_ior(m.params.get("int_ior", "bk7"), what=f"{where}: int_ior")
        b[i] = float(v)
    return b, n_d


def cauchy_ior(n_d, b, wavelength_nm):
    """n(λ) = A + B/λ² with n(589.3 nm) = n_d (λ in nm, B in µm²)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64) / 1000.0
    return n_d + b * (1.0 / lam ** 2 - 1.0 / LAMBDA_D_UM ** 2)


@njit(inline="always", cache=True)
def eta_scale_at(S, mat, pos):
    """n(λ)/int_ior of material ``mat`` at grid position ``pos`` (1 without dispersion)."""
    b = S.cauchy_b[mat]
    if b == 0.0:
        return 1.0
    lam = (LAMBDA_MIN + pos) / 1000.0
    n_d = S.ior_d[mat]
    return (n_d + b * (1.0 / (lam * lam) - 1.0 / (LAMBDA_D_UM * LAMBDA_D_UM))) / n_d


def rgb_arrays_placeholder() -> SpectralArrays:
    """Empty tables for the RGB mode (the kernel does not read them)."""
    z = np.zeros((1, 1))
    return SpectralArrays(z, z, z, np.zeros(1), np.ones(1), np.zeros((1, 3)), np.eye(3), 1.0)


@njit(inline="always", cache=True)
def sample_wavelengths(u):
    """Hero wavelength and its two rotations, as positions on the 1 nm grid (λ − 360)."""
    h = u * _RANGE
    third = _RANGE / 3.0
    return h, (h + third) % _RANGE, (h + 2.0 * third) % _RANGE


@njit(inline="always", cache=True)
def spectrum_at(row, pos):
    """Linear interpolation of a 1 nm table at grid position ``pos`` (λ − 360 nm)."""
    i = min(int(pos), row.shape[0] - 2)
    f = pos - i
    return row[i] * (1.0 - f) + row[i + 1] * f


@batch_kernel
def to_linear_srgb(S: SpectralArrays, l0, l1, l2, p0, p1, p2):
    """Linear sRGB of radiance samples (l0, l1, l2) at grid positions (p0, p1, p2)."""
    X = Y = Z = 0.0
    for li, p in ((l0, p0), (l1, p1), (l2, p2)):
        if li != 0.0:
            X += li * spectrum_at(S.cmf[:, 0], p)
            Y += li * spectrum_at(S.cmf[:, 1], p)
            Z += li * spectrum_at(S.cmf[:, 2], p)
    X *= S.scale
    Y *= S.scale
    Z *= S.scale
    M = S.to_rgb
    return (M[0, 0] * X + M[0, 1] * Y + M[0, 2] * Z, M[1, 0] * X + M[1, 1] * Y + M[1, 2] * Z,
            M[2, 0] * X + M[2, 1] * Y + M[2, 2] * Z)
