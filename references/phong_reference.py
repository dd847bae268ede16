"""The matched Mitsuba reference of the Phong model: a Python BSDF and a Python integrator.

Mitsuba 3 has no Phong BSDF and no ambient or f_att term, so the thesis's local
illumination model (1.4.2)::

    I = I_a k_a ρ  +  Σ_lights f_att(d) · I_p · [ k_d (N·L) + k_s (R·V)^n ],
    k_d = ρ/π,  R = 2(N·L)N − L,  f_att(d) = 1 / (c1 + c2 d + c3 d²)  (≤ 1 when clamped)

is rendered here with Mitsuba's own intersection, emitters, textures and
sampler, split where it belongs:

* the **BSDF** ``phong`` (:class:`PhongBSDF`, a ``mi.BSDF`` subclass registered
  with ``mi.register_bsdf``) is the bracket: ``eval`` returns
  ``ρ/π (N·L) + k_s (R·V)^n`` (Mitsuba's ``eval`` includes the cosine of the
  light direction, and the Phong bracket has it on the diffuse term only), 0
  when L or V is below the shading normal; the highlight is white.  ``sample``
  draws cosine-weighted directions (pdf cos/π) with weight eval/pdf, so the
  BSDF is usable by any Mitsuba integrator;
* the **integrator** ``phong_direct`` (:class:`PhongIntegrator`) supplies the
  light-transport terms the BSDF cannot: at the first hit it adds the emitted
  radiance, the ambient term ``I_a k_a ρ`` (ρ from
  ``bsdf.eval_diffuse_reflectance``; once per visible point, only where the
  point is seen from its front side, as ``impl.lighting.local_shading``
  does) and, for every emitter, one ``sample_direction`` with a shadow ray,
  its weight multiplied by ``d² · f_att(d)``: Mitsuba's weight of a point or
  spot light is I/d² and of an area light L_e A cosθ_y / d² (uniform area
  sampling), so the product replaces the physical 1/d² by the thesis's f_att.
  Emitters at infinity (``directional``, ``constant``) keep their weight
  (f_att = 1, as in the own code).

Exact match and its limits: with these two plugins the reference computes
the same expectation as the own ``raycast`` (shadows on) for point, spot,
directional and area lights and the constant environment.  It does *not*
model what the thesis's ambient term stands for (inter-reflected light):
that is an empirical constant in both, so the match is of the model, not of
physics.  The rasterisers (``zbuffer``, ``depthsort``) compute no shadows:
they match this reference only on scenes where no shadow falls on a visible
surface.  ``twosided`` wrapping of a ``phong`` BSDF is not supported (the
ambient term is added for front-side views only).

Transport name: ``phong(ka=…,ambient=…,ks=…,shininess=…,c1=…,c2=…,c3=…,clamp=…)``
(:func:`phong_transport` builds the canonical string from algorithm parameters,
:func:`parse_phong_transport` reads it).  The reference store keys the whole
string, so every coefficient set has its own entry.  :func:`prepare_phong_xml`
rewrites a scene for it: every ``diffuse`` BSDF becomes ``phong`` with the
same reflectance plus ``ks`` and ``shininess``, and the integrator becomes
``phong_direct`` with the light-transport coefficients.

.. pluginparameters (XML ``<bsdf type="phong">``)

===========  =======  =================================  =======
name         type     meaning                            default
===========  =======  =================================  =======
reflectance  texture  diffuse reflectance ρ (k_d = ρ/π)   0.5
ks           float    specular coefficient k_s           0
shininess    float    Phong exponent n                   32
===========  =======  =================================  =======

.. pluginparameters (XML ``<integrator type="phong_direct">``)

=============  =======  =====================================  =======
name           type     meaning                                default
=============  =======  =====================================  =======
ka, ambient    float    ambient k_a and intensity I_a          0, 0
c1, c2, c3     float    f_att = 1 / (c1 + c2 d + c3 d²)         0, 0, 1
clamp          boolean  clamp f_att to 1                       false
hide_emitters  boolean  hide emitters seen directly            false
=============  =======  =====================================  =======
"""

from __future__ import annotations

import math
import re

__all__ = ["BSDF_NAME", "INTEGRATOR_NAME", "PHONG_KEYS", "phong_transport", "parse_phong_transport",
           "is_phong_transport", "prepare_phong_xml", "register"]

BSDF_NAME = "phong"
INTEGRATOR_NAME = "phong_direct"

#: Coefficients of the transport name, in canonical order, with the own code's defaults.
PHONG_KEYS = {"ka": 0.0, "ambient": 0.0, "ks": 0.0, "shininess": 32.0, "c1": 0.0, "c2": 0.0,
              "c3": 1.0, "clamp": False}

_NAME_RE = re.compile(r"^phong(?:\((.*)\))?$")

_registered: set[str] = set()
mi = None
dr = None


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(float(v))


def phong_transport(params: dict) -> str:
    """Canonical transport name from Phong coefficients (``fatt_clamp`` or ``clamp``; missing
    keys take the own code's defaults)."""
    values = dict(PHONG_KEYS)
    for k in PHONG_KEYS:
        if k in params:
            values[k] = params[k]
    if "fatt_clamp" in params:
        values["clamp"] = params["fatt_clamp"]
    values["clamp"] = bool(values["clamp"])
    return "phong(" + ",".join(f"{k}={_fmt(values[k])}" for k in PHONG_KEYS) + ")"


def is_phong_transport(transport) -> bool:
    return isinstance(transport, str) and _NAME_RE.match(transport) is not None


def parse_phong_transport(transport: str) -> dict:
    """Coefficients of a ``phong(...)`` transport name; ValueError naming the bad part."""
    m = _NAME_RE.match(transport) if isinstance(transport, str) else None
    if m is None:
        raise ValueError(f"not a phong transport: {transport!r}")
    values = dict(PHONG_KEYS)
    body = m.group(1)
    for item in filter(None, (body or "").split(",")):
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or key not in PHONG_KEYS:
            raise ValueError(f"transport {transport!r}: unknown or malformed coefficient {item!r} "
                             f"(known: {', '.join(PHONG_KEYS)})")
        if key == "clamp":
            if raw.strip() not in ("true", "false"):
                raise ValueError(f"transport {transport!r}: clamp must be true or false, got {raw!r}")
            values[key] = raw.strip() == "true"
        else:
            try:
                values[key] = float(raw)
            except ValueError:
                raise ValueError(f"transport {transport!r}: {key} is not a number: {raw!r}") from None
            if not math.isfinite(values[key]) or values[key] < 0.0:
                raise ValueError(f"transport {transport!r}: {key} must be finite and >= 0")
    if values["c1"] == values["c2"] == values["c3"] == 0.0:
        raise ValueError(f"transport {transport!r}: c1, c2, c3 are all 0 (f_att undefined)")
    return values


def prepare_phong_xml(root, transport: str, make, prop) -> tuple:
    """Rewrite a parsed scene (lxml root) for a ``phong(...)`` transport: every ``diffuse``
    BSDF becomes ``phong`` (reflectance kept, k_s and n added).  Returns (integrator element,
    its record).  ``make(tag, attrib, children)`` and ``prop(tag, name, value)`` build elements."""
    c = parse_phong_transport(transport)
    for el in root.iter("bsdf"):
        if el.get("type") == "diffuse":
            el.set("type", BSDF_NAME)
            el.append(prop("float", "ks", c["ks"]))
            el.append(prop("float", "shininess", c["shininess"]))
    names = ("ka", "ambient", "c1", "c2", "c3")
    new = make("integrator", {"type": INTEGRATOR_NAME},
               [prop("float", k, c[k]) for k in names] + [prop("boolean", "clamp", c["clamp"])])
    used = {"type": INTEGRATOR_NAME, **c}
    return new, used


def _make_classes():
    jit = dr.is_jit_v(mi.Float)
    inv_pi = 1.0 / math.pi

    class PhongBSDF(mi.BSDF):
        """ρ/π cosθ_l + k_s (R·V)^n, one-sided (front side only)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.reflectance = (props.get_texture("reflectance") if "reflectance" in props
                                else props.get_texture("reflectance", 0.5))
            self.ks = float(props.get("ks", 0.0))
            self.shininess = float(props.get("shininess", 32.0))
            if self.ks < 0.0 or self.shininess < 0.0:
                raise ValueError(f"phong: ks and shininess must be >= 0, got {self.ks}, {self.shininess}")
            flags = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection
                     | mi.BSDFFlags.FrontSide)
            self.m_components = [flags]
            self.m_flags = flags

        def _bracket(self, si, wo, active):
            cos_v = mi.Frame3f.cos_theta(si.wi)
            cos_l = mi.Frame3f.cos_theta(wo)
            ok = active & (cos_v > 0.0) & (cos_l > 0.0)
            # R = 2(N·L)N − L in the local frame (N = z): (−l_x, −l_y, l_z).
            rv = -wo.x * si.wi.x - wo.y * si.wi.y + wo.z * si.wi.z
            spec = dr.select(rv > 0.0, self.ks * dr.power(dr.maximum(rv, 0.0), self.shininess), 0.0)
            rho = self.reflectance.eval(si, ok)
            value = rho * (cos_l * inv_pi) + spec
            return dr.select(ok, value, 0.0), ok, cos_l

        def eval(self, ctx, si, wo, active=True):
            value, _, _ = self._bracket(si, wo, active)
            return value

        def pdf(self, ctx, si, wo, active=True):
            cos_v = mi.Frame3f.cos_theta(si.wi)
            return dr.select((cos_v > 0.0) & (mi.Frame3f.cos_theta(wo) > 0.0),
                             mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = mi.BSDFSample3f()
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.wo = wo
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            value, ok, _ = self._bracket(si, wo, active)
            ok = ok & (bs.pdf > 0.0)
            return bs, dr.select(ok, value / dr.select(ok, bs.pdf, 1.0), 0.0)

        def eval_diffuse_reflectance(self, si, active=True):
            return self.reflectance.eval(si, active)

        def traverse(self, cb):
            cb.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)

        def to_string(self):
            return f"PhongBSDF[ks={self.ks}, shininess={self.shininess}, reflectance={self.reflectance}]"

    class PhongIntegrator(mi.SamplingIntegrator):
        """First hit: L_e + I_a k_a ρ + Σ_emitters (weight · d² f_att(d)) · Phong bracket."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.ka = float(props.get("ka", 0.0))
            self.ambient = float(props.get("ambient", 0.0))
            self.c1 = float(props.get("c1", 0.0))
            self.c2 = float(props.get("c2", 0.0))
            self.c3 = float(props.get("c3", 1.0))
            self.clamp = bool(props.get("clamp", False))
            self.hide_emitters = bool(props.get("hide_emitters", False))
            if self.c1 == self.c2 == self.c3 == 0.0:
                raise ValueError("phong_direct: c1, c2, c3 are all 0 (f_att undefined)")

        def to_string(self):
            return (f"PhongIntegrator[ka={self.ka}, ambient={self.ambient}, c=({self.c1}, {self.c2}, "
                    f"{self.c3}), clamp={self.clamp}]")

        def _fatt_scale(self, dist):
            """d² f_att(d): turns Mitsuba's 1/d² weight into the thesis's f_att."""
            f = 1.0 / (self.c1 + self.c2 * dist + self.c3 * dist * dist)
            if self.clamp:
                f = dr.minimum(f, 1.0)
            return dist * dist * f

        def sample(self, scene, sampler, ray, medium=None, active=True):
            ray = mi.Ray3f(ray)
            active = mi.Bool(active)
            ctx = mi.BSDFContext()
            si = scene.ray_intersect(ray, active)
            L = mi.Spectrum(0.0)
            if not self.hide_emitters:
                emitter = si.emitter(scene, active)
                if jit:
                    L = L + emitter.eval(si, active)
                elif emitter is not None and active:
                    L = L + emitter.eval(si, active)
            valid = active & si.is_valid()
            if not jit and not valid:
                return L, mi.Bool(False), []
            bsdf = si.bsdf(ray)
            front = valid & (mi.Frame3f.cos_theta(si.wi) > 0.0)
            if self.ka * self.ambient != 0.0:
                rho = bsdf.eval_diffuse_reflectance(si, front)
                L = dr.select(front, L + self.ka * self.ambient * rho, L)
            for em in scene.emitters():
                infinite = bool(int(em.flags()) & int(mi.EmitterFlags.Infinite))
                ds, weight = em.sample_direction(si, sampler.next_2d(front), front)
                ok = front & (ds.pdf != 0.0)
                if jit or ok:
                    ok = ok & ~scene.ray_test(si.spawn_ray_to(ds.p), ok) if jit else \
                        ok and not scene.ray_test(si.spawn_ray_to(ds.p), ok)
                if jit or ok:
                    f = bsdf.eval(ctx, si, si.to_local(ds.d), ok)
                    if not infinite:
                        weight = weight * self._fatt_scale(ds.dist)
                    L = dr.select(ok, L + f * weight, L)
            return L, valid, []

    return PhongBSDF, PhongIntegrator


def register(mitsuba) -> None:
    """Register the ``phong`` BSDF and ``phong_direct`` integrator for the current variant."""
    import drjit

    globals()["mi"] = mitsuba
    globals()["dr"] = drjit
    variant = mitsuba.variant()
    if variant in _registered:
        return
    bsdf_cls, integrator_cls = _make_classes()
    mitsuba.register_bsdf(BSDF_NAME, lambda props: bsdf_cls(props))
    mitsuba.register_integrator(INTEGRATOR_NAME, lambda props: integrator_cls(props))
    _registered.add(variant)
