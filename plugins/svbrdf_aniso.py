r"""An anisotropic GGX variant of the thesis's SVBRDF (``svbrdf_aniso``): brushed metal our model cannot fit.

Parameters as :monosp:`svbrdf_ggx` (``normal``, ``diffuse``, ``specular``; see
:mod:`mi_svbrdf.plugins.svbrdf_bsdf`) with two roughness textures instead of one:

* ``roughness_u``: roughness ``r_u`` along the tangent ``s`` (for the default rectangle and
  a height-field mesh with ``uv = ((x+1)/2, (y+1)/2)``: world +X), ``alpha_u = r_u^2``;
* ``roughness_v``: roughness ``r_v`` along the bitangent, ``alpha_v = r_v^2``.

Both are clipped to [1e-3, 1] like the isotropic model's. The tangent frame follows the
normal map: ``t = normalize(s - (s . n') n')``, ``b = n' x t``. With ``h`` in that frame,
``c = max(n' . h, 0)`` and ``cos^2 phi = h_t^2 / (h_t^2 + h_b^2)`` (1 where both vanish)::

    T = (cos^2 phi * a_v/a_u + sin^2 phi * a_u/a_v) sin^2(theta_h) + c^2 a_u a_v
    D = a_u a_v / (pi * max(1e-3, T)^2)

the anisotropic GGX written so that for ``a_u = a_v = a`` it is *term for term* the thesis's
``a^2 / (pi max(1e-3, c^2 (a^2 - 1) + 1)^2)`` as :func:`mi_svbrdf.plugins.model.distribution_d`
evaluates it: ``sin^2(theta_h) = 1 - c^2`` computed as ``|n x h|^2`` where ``c > 1e-3`` (float32
cancellation, see that module's docstring). Smith-Schlick ``G`` uses per direction
``a(w) = sqrt((w_t^2 a_u^2 + w_b^2 a_v^2) / (w_t^2 + w_b^2))`` (``a`` when equal) and
``k = a(w)/2``; the Fresnel and diffuse terms are the model's (:mod:`mi_svbrdf.plugins.model`).
Hence ``svbrdf_aniso`` with ``roughness_u = roughness_v = r`` evaluates like ``svbrdf_ggx``
with ``roughness = r`` (``tests/test_failure_cases.py`` compares them on random directions).

Sampling draws visible normals of Mitsuba's anisotropic GGX (``alpha`` floored at
:data:`~mi_svbrdf.plugins.svbrdf_bsdf.SAMPLING_ALPHA_MIN`) in the same tangent frame, mixed
with cosine sampling as the isotropic plugin does; :py:meth:`pdf` is the matching density.

Register with :func:`register` (idempotent, per variant).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .model import EPS_DENOM, clamp_roughness, diffuse_lobe, fresnel, safe_normalize
from .svbrdf_bsdf import _SAMPLING_COS_MIN, SAMPLING_ALPHA_MIN, SVBRDF


#: The variant whose ``mi.BSDF`` the class below derives from (see :func:`mi_svbrdf.plugins.bsdf_classes`).
DEFINED_FOR = mi.variant()


def _ratio(num, den, fallback: float):
    """``num / den`` where ``den > 1e-12``, else ``fallback``."""
    ok = den > 1e-12
    return dr.select(ok, num * dr.rcp(dr.select(ok, den, 1.0)), fallback)


def eval_aniso(n, t, b, wl, wv, diffuse, specular, r_u, r_v, include_diffuse: bool = True):
    """The anisotropic BRDF value f (no cosine) in the frame ``(t, b, n)`` (see the module docstring).

    Args:
        n, t, b: unit normal, tangent and bitangent (Array3f).
        wl, wv: directions towards the light and the viewer (normalised here).
        diffuse, specular: linear albedos (Array3f / Color3f).
        r_u, r_v: roughness along t and b, already clipped; ``alpha = r^2``.
        include_diffuse: add ``d (1 - s) / pi``.
    """
    wl, wv = safe_normalize(wl), safe_normalize(wv)
    h = safe_normalize(wl + wv)
    a_u, a_v = r_u * r_u, r_v * r_v
    c = dr.maximum(dr.dot(n, h), 0.0)
    sin2 = dr.select(c > EPS_DENOM, dr.squared_norm(dr.cross(n, h)), 1.0 - c * c)
    ht2, hb2 = dr.square(dr.dot(t, h)), dr.square(dr.dot(b, h))
    cos2 = _ratio(ht2, ht2 + hb2, 1.0)
    big_t = (cos2 * a_v / a_u + (1.0 - cos2) * a_u / a_v) * sin2 + c * c * (a_u * a_v)
    denom = dr.maximum(EPS_DENOM, big_t)
    d_term = (a_u * a_v) / (dr.pi * denom * denom)

    def k_of(w):
        wt2, wb2 = dr.square(dr.dot(t, w)), dr.square(dr.dot(b, w))
        cw2 = _ratio(wt2, wt2 + wb2, 1.0)
        return dr.sqrt(cw2 * a_u * a_u + (1.0 - cw2) * a_v * a_v) * 0.5

    n_dot_l, n_dot_v = dr.maximum(dr.dot(n, wl), 0.0), dr.maximum(dr.dot(n, wv), 0.0)
    k_l, k_v = k_of(wl), k_of(wv)
    g_term = (dr.rcp(dr.maximum(EPS_DENOM, n_dot_l * (1.0 - k_l) + k_l))
              * dr.rcp(dr.maximum(EPS_DENOM, n_dot_v * (1.0 - k_v) + k_v)))
    f = fresnel(dr.maximum(dr.dot(wv, h), 0.0), specular) * (g_term * d_term * 0.25)
    if include_diffuse:
        f = f + diffuse_lobe(diffuse, specular)
    return f


def tangent_frame(n_p) -> mi.Frame3f:
    """Frame ``(t, b, n')`` of the perturbed normal with t the local +s projected (falls back to +t)."""
    s = mi.Vector3f(1.0, 0.0, 0.0)
    t = s - dr.dot(s, n_p) * n_p
    ok = dr.squared_norm(t) > 1e-8
    t = dr.select(ok, t, mi.Vector3f(0.0, 1.0, 0.0) - n_p.y * n_p)
    t = safe_normalize(t)
    return mi.Frame3f(t, dr.cross(n_p, t), n_p)


class AnisoSVBRDF(SVBRDF):
    """The isotropic plugin with ``roughness`` replaced by ``roughness_u`` / ``roughness_v``.

    Internally the "roughness" passed between the base class's helpers is a ``mi.Vector2f``
    ``(r_u, r_v)``; only the frame, the sampler and the value differ from :class:`SVBRDF`.
    """

    def __init__(self, props: mi.Properties) -> None:
        if "roughness" in props:
            raise ValueError("svbrdf_aniso: expected 'roughness_u' and 'roughness_v', got 'roughness'")
        super().__init__(props, distribution="ggx")
        self.m_roughness_u = self._get_texture(props, "roughness_u", 0.5)
        self.m_roughness_v = self._get_texture(props, "roughness_v", 0.5)
        self._check_constant_range("roughness_u", self.m_roughness_u, 0.0, 1.0)
        self._check_constant_range("roughness_v", self.m_roughness_v, 0.0, 1.0)
        if any(t.is_spatially_varying() for t in self._textures()):
            extra = mi.BSDFFlags.FrontSide | mi.BSDFFlags.SpatiallyVarying
            self.m_components = [mi.BSDFFlags.DiffuseReflection | extra, mi.BSDFFlags.GlossyReflection | extra]
            self.m_flags = self.m_components[0] | self.m_components[1]

    def _textures(self) -> tuple[mi.Texture, ...]:
        # The base __init__ asks before roughness_u/v exist: the flags are then recomputed here.
        extra = tuple(getattr(self, k) for k in ("m_roughness_u", "m_roughness_v") if hasattr(self, k))
        return (self.m_normal, self.m_diffuse, self.m_specular, *extra)

    def _material(self, si: mi.SurfaceInteraction3f, active: mi.Bool):
        n_p, diffuse, specular, _ = super()._material(si, active)
        rough = mi.Vector2f(clamp_roughness(self.m_roughness_u.eval_1(si, active)),
                            clamp_roughness(self.m_roughness_v.eval_1(si, active)))
        return n_p, diffuse, specular, rough

    def _sampling_setup(self, n_p, wi, roughness):
        frame = tangent_frame(n_p)
        wi_p = frame.to_local(wi)
        wi_s = safe_normalize(mi.Vector3f(wi_p.x, wi_p.y, dr.maximum(wi_p.z, _SAMPLING_COS_MIN)))
        a_u = dr.detach(dr.maximum(roughness.x * roughness.x, SAMPLING_ALPHA_MIN))
        a_v = dr.detach(dr.maximum(roughness.y * roughness.y, SAMPLING_ALPHA_MIN))
        return frame, wi_p, wi_s, mi.MicrofacetDistribution(self.m_type, a_u, a_v, True)

    def _eval(self, n_p, wi, wo, diffuse, specular, roughness, include_diffuse: bool):
        frame = tangent_frame(n_p)
        return eval_aniso(n_p, frame.s, frame.t, wo, wi, diffuse, specular, roughness.x, roughness.y,
                          include_diffuse=include_diffuse)

    def traverse(self, callback: mi.TraversalCallback) -> None:
        flags = mi.ParamFlags.Differentiable
        callback.put("normal", self.m_normal, flags | mi.ParamFlags.Discontinuous)
        callback.put("diffuse", self.m_diffuse, flags)
        callback.put("roughness_u", self.m_roughness_u, flags)
        callback.put("roughness_v", self.m_roughness_v, flags)
        callback.put("specular", self.m_specular, flags)

    def to_string(self) -> str:
        return (f"AnisoSVBRDF[\n  normal = {self.m_normal},\n  diffuse = {self.m_diffuse},\n"
                f"  roughness_u = {self.m_roughness_u},\n  roughness_v = {self.m_roughness_v},\n"
                f"  specular = {self.m_specular}\n]")

