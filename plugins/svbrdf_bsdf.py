r"""The thesis's SVBRDF as a Mitsuba 3 BSDF (``svbrdf_ggx``, ``svbrdf_beckmann``).

.. _bsdf-svbrdf_ggx:

SVBRDF material (:monosp:`svbrdf_ggx`, :monosp:`svbrdf_beckmann`)
------------------------------------------------------------------

.. pluginparameters::

 * - normal
   - |texture|
   - Encoded tangent-space normal ``(n + 1) / 2`` (RGB, like :monosp:`normalmap`); decoded as
     ``2 v - 1`` and normalised (a zero vector falls back to the unperturbed normal).
     (Default: flat, (0.5, 0.5, 1))
   - |exposed|, |differentiable|, |discontinuous|

 * - diffuse
   - |spectrum| or |texture|
   - Linear diffuse albedo ``d``. (Default: 0.5)
   - |exposed|, |differentiable|

 * - roughness
   - |float| or |texture|
   - Roughness ``r`` (one channel); clipped to [1e-3, 1], the model uses ``alpha = r^2``.
     (Default: 0.5)
   - |exposed|, |differentiable|

 * - specular
   - |spectrum| or |texture|
   - Linear specular albedo ``s`` (Fresnel reflectance at normal incidence). (Default: 0.04)
   - |exposed|, |differentiable|

This is the analytic model of Deschaintre et al.'s SVBRDF-capture work (thesis, appendix A.3)
and of the authors' public code: a Cook-Torrance lobe with the GGX (``svbrdf_ggx``) or
Beckmann (``svbrdf_beckmann``) distribution, Schlick's approximation of Smith's G, the
spherical-Gaussian Schlick Fresnel, plus a Lambertian term ``d (1 - s) / pi``. The math is
not re-implemented here: every evaluation calls :func:`mi_svbrdf.plugins.model.eval_brdf`.

**Frames.** The four parameters are looked up at ``si.uv``. The normal is expressed in
Mitsuba's local shading frame ``(s, t, n)`` of the surface (tangent-space ``x`` = ``s``,
``y`` = ``t``, ``z`` = ``n``); for the default ``rectangle`` that frame is world
``(+X, +Y, +Z)``, so an OpenGL tangent-space normal map (x right, y up) lands unchanged in
world space. Note that the default rectangle's ``uv`` is ``((x + 1)/2, (y + 1)/2)`` and a
bitmap's row 0 sits at ``v = 0``, i.e. at the *bottom* (y = -1): to put image row 0 at the
top, give each bitmap the ``to_uv`` transform ``v -> 1 - v`` (see the XML example and
:func:`mi_svbrdf.scenes.material_bsdf`, which does this).

**Value.** With Mitsuba's convention (``si.wi`` points towards the sensor, ``wo`` towards
the light), :py:meth:`eval` returns ``f(n', wo, wi) * max(0, n' . wo)``, ``n'`` the
perturbed normal: the BSDF times the foreshortening cosine with respect to the *perturbed*
normal. A point light of Mitsuba intensity ``pi * I`` therefore reproduces the thesis's
``L = f * pi * I * c(n . wL)`` (times the ``1/d^2`` fall-off Mitsuba applies; the thesis's
loss renderings drop it). The material is one-sided: the value is zero when ``wi`` or
``wo`` lies below the geometric/shading-frame horizon (``cos_theta <= 0``) or ``wo`` below
the perturbed horizon. As in :monosp:`normalmap`, no adjoint correction for the shading
normal is applied.

**Sampling.** A mixture of two techniques in the frame of the perturbed normal: with
probability ``p_spec`` a microfacet normal is drawn from the distribution of visible normals
(:py:class:`mitsuba.MicrofacetDistribution`, same type as the model, ``alpha`` floored at
:data:`SAMPLING_ALPHA_MIN`) and ``wi`` is reflected about it; otherwise a cosine-weighted
direction about the perturbed normal is drawn. ``p_spec`` is the luminance ratio
``F / (F + d (1 - s))`` with ``F`` the model's Fresnel term at ``n' . wi``, clamped to
[0.1, 0.9] (0.5 where both vanish). :py:meth:`pdf` returns the matching mixture density
``p_spec * D_wi(m) / (4 |wo . m|) + (1 - p_spec) * cos / pi`` and zero wherever
:py:meth:`eval` is zero by the horizon rules, so ``sample``'s weight is exactly
``eval / pdf``.

.. code-block:: xml
    :name: svbrdf_ggx

    <bsdf type="svbrdf_ggx">
        <texture name="normal" type="bitmap">
            <string name="filename" value="textures/normal.exr"/>
            <boolean name="raw" value="true"/>
            <transform name="to_uv"><scale y="-1"/><translate y="1"/></transform>
        </texture>
        <texture name="diffuse" type="bitmap">
            <string name="filename" value="textures/diffuse.exr"/>
            <boolean name="raw" value="true"/>
            <transform name="to_uv"><scale y="-1"/><translate y="1"/></transform>
        </texture>
        <float name="roughness" value="0.3"/>
        <rgb name="specular" value="0.04"/>
    </bsdf>

The plugins are registered by :func:`mi_svbrdf.plugins.register` (called by
:func:`mi_svbrdf.variant.ensure_variant`); ``mi.traverse`` exposes the parameters of the
four textures under the prefixes ``normal.``, ``diffuse.``, ``roughness.`` and
``specular.`` (``normal.data`` etc. for bitmaps, ``diffuse.value`` for constants).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .model import DISTRIBUTIONS, clamp_roughness, cosine, diffuse_lobe, eval_brdf, fresnel, safe_normalize

#: Floor on the microfacet ``alpha`` used for *sampling* only (the model's GGX denominator
#: is floored at 1e-3, which flattens the peak of lobes narrower than about sqrt(1e-3)).
SAMPLING_ALPHA_MIN = 0.03
#: Bounds of the probability of sampling the specular lobe.
P_SPEC_MIN, P_SPEC_MAX = 0.1, 0.9
#: Floor on the cosine of ``wi`` seen by the visible-normal sampler (grazing/backfacing ``wi``).
_SAMPLING_COS_MIN = 1e-3

#: The variant whose ``mi.BSDF`` the classes below derive from (see :func:`mi_svbrdf.plugins.bsdf_classes`).
DEFINED_FOR = mi.variant()
_MICROFACET_TYPES = {"ggx": mi.MicrofacetType.GGX, "beckmann": mi.MicrofacetType.Beckmann}


class SVBRDF(mi.BSDF):
    """Spatially varying microfacet + Lambert BSDF of the thesis (see the module docstring)."""

    def __init__(self, props: mi.Properties, distribution: str = "ggx") -> None:
        mi.BSDF.__init__(self, props)
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"SVBRDF: distribution must be one of {DISTRIBUTIONS}, got {distribution!r}")
        self.m_distribution = distribution
        self.m_type = _MICROFACET_TYPES[distribution]

        self.m_normal = self._get_texture(props, "normal", None)
        self.m_diffuse = self._get_texture(props, "diffuse", 0.5)
        self.m_roughness = self._get_texture(props, "roughness", 0.5)
        self.m_specular = self._get_texture(props, "specular", 0.04)
        self._check_constant_range("diffuse", self.m_diffuse, 0.0, 1.0)
        self._check_constant_range("roughness", self.m_roughness, 0.0, 1.0)
        self._check_constant_range("specular", self.m_specular, 0.0, 1.0)

        extra = mi.BSDFFlags.FrontSide
        if any(t.is_spatially_varying() for t in self._textures()):
            extra = extra | mi.BSDFFlags.SpatiallyVarying
        self.m_components = [mi.BSDFFlags.DiffuseReflection | extra,
                             mi.BSDFFlags.GlossyReflection | extra]
        self.m_flags = self.m_components[0] | self.m_components[1]

    # ------------------------------------------------------------------ helpers
    def _textures(self) -> tuple[mi.Texture, ...]:
        return (self.m_normal, self.m_diffuse, self.m_roughness, self.m_specular)

    @staticmethod
    def _get_texture(props: mi.Properties, name: str, default: float | None) -> mi.Texture:
        """``props``' texture ``name``; ``default=None`` means the flat normal (0.5, 0.5, 1)."""
        try:
            if name in props:
                return props.get_texture(name)
            if default is None:
                return mi.load_dict({"type": "srgb", "color": [0.5, 0.5, 1.0]})
            return props.get_texture(name, default)
        except Exception as exc:  # noqa: BLE001 - re-raised with the parameter's name
            raise ValueError(f"SVBRDF: invalid parameter '{name}' (a texture, RGB or float value in "
                             f"[0, 1]): {exc}") from exc

    @staticmethod
    def _check_constant_range(name: str, tex: mi.Texture, lo: float, hi: float) -> None:
        """Reject a constant value outside ``[lo, hi]`` (spatially varying textures are not scanned)."""
        if tex.is_spatially_varying():
            return
        value = tex.eval(dr.zeros(mi.SurfaceInteraction3f, 1))
        channels = [float(value[i][0]) for i in range(3)]
        if not all(lo <= c <= hi for c in channels):
            raise ValueError(f"SVBRDF: parameter '{name}' must lie in [{lo}, {hi}], got {channels}")

    def _material(self, si: mi.SurfaceInteraction3f, active: mi.Bool):
        """Perturbed normal (local frame), diffuse, specular and clipped roughness at ``si``."""
        enc = mi.Vector3f(self.m_normal.eval(si, active))
        n = enc * 2.0 - 1.0
        len2 = dr.squared_norm(n)
        n_p = dr.select(len2 > 1e-12, n * dr.rsqrt(dr.maximum(len2, 1e-12)), mi.Vector3f(0.0, 0.0, 1.0))
        diffuse = self.m_diffuse.eval(si, active)
        specular = self.m_specular.eval(si, active)
        roughness = clamp_roughness(self.m_roughness.eval_1(si, active))
        return n_p, diffuse, specular, roughness

    def _lobe_selection(self, ctx: mi.BSDFContext):
        return (ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0),
                ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1))

    def _p_spec(self, n_p, wi, diffuse, specular, has_diffuse: bool, has_specular: bool) -> mi.Float:
        """Probability of sampling the specular lobe (see the module docstring)."""
        if not has_diffuse:
            return mi.Float(1.0)
        if not has_specular:
            return mi.Float(0.0)
        w_spec = mi.luminance(fresnel(dr.maximum(dr.dot(n_p, wi), 0.0), specular))
        w_diff = mi.luminance(diffuse * (1.0 - specular))
        total = w_spec + w_diff
        ratio = dr.select(total > 0.0, w_spec * dr.rcp(dr.select(total > 0.0, total, 1.0)), 0.5)
        return dr.detach(dr.clip(ratio, P_SPEC_MIN, P_SPEC_MAX))

    def _f_cos(self, n_p, wi, wo, diffuse, specular, roughness,
               has_diffuse: bool, has_specular: bool):
        """The model value times the perturbed cosine (no horizon masking)."""
        if has_specular:
            f = self._eval(n_p, wi, wo, diffuse, specular, roughness, has_diffuse)
        elif has_diffuse:
            f = diffuse_lobe(diffuse, specular)
        else:
            f = dr.zeros(mi.Color3f)
        return f * cosine(n_p, wo)

    def _eval(self, n_p, wi, wo, diffuse, specular, roughness, include_diffuse: bool):
        """The BRDF with its specular lobe (variants override this one method)."""
        return eval_brdf(n_p, wo, wi, diffuse, specular, roughness, self.m_distribution,
                         include_diffuse=include_diffuse)

    def _sampling_setup(self, n_p, wi, roughness):
        """Perturbed frame, ``wi`` in it, the sampler's ``wi`` and the microfacet distribution."""
        frame = mi.Frame3f(n_p)
        wi_p = frame.to_local(wi)
        wi_s = safe_normalize(mi.Vector3f(wi_p.x, wi_p.y, dr.maximum(wi_p.z, _SAMPLING_COS_MIN)))
        alpha = dr.detach(dr.maximum(roughness * roughness, SAMPLING_ALPHA_MIN))
        distr = mi.MicrofacetDistribution(self.m_type, alpha, True)
        return frame, wi_p, wi_s, distr

    @staticmethod
    def _valid(si: mi.SurfaceInteraction3f, n_p, wo, active) -> mi.Bool:
        """Both directions above the shading horizon and ``wo`` above the perturbed one."""
        return (active & (mi.Frame3f.cos_theta(si.wi) > 0.0) & (mi.Frame3f.cos_theta(wo) > 0.0)
                & (dr.dot(n_p, wo) > 0.0))

    def _pdf(self, si, wo, n_p, diffuse, specular, roughness, valid,
             has_diffuse: bool, has_specular: bool) -> mi.Float:
        p_spec = self._p_spec(n_p, si.wi, diffuse, specular, has_diffuse, has_specular)
        frame, wi_p, wi_s, distr = self._sampling_setup(n_p, si.wi, roughness)
        wo_p = frame.to_local(wo)
        pdf = dr.zeros(mi.Float)
        if has_specular:
            m = safe_normalize(wi_p + wo_p)
            wo_dot_m = dr.dot(wo_p, m)
            ok = (wo_dot_m > 0.0) & (dr.dot(wi_p, m) > 0.0)
            pdf_m = distr.pdf(wi_s, m)
            pdf = pdf + p_spec * dr.select(ok, pdf_m * dr.rcp(4.0 * dr.select(ok, wo_dot_m, 1.0)), 0.0)
        if has_diffuse:
            pdf = pdf + (1.0 - p_spec) * mi.warp.square_to_cosine_hemisphere_pdf(wo_p)
        return dr.select(valid, pdf, 0.0)

    # ------------------------------------------------------------------ BSDF interface
    def sample(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, sample1: mi.Float,
               sample2: mi.Point2f, active: mi.Bool = True) -> tuple[mi.BSDFSample3f, mi.Color3f]:
        has_diffuse, has_specular = self._lobe_selection(ctx)
        bs = dr.zeros(mi.BSDFSample3f)
        if not (has_diffuse or has_specular):
            return bs, dr.zeros(mi.Color3f)
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0.0)
        n_p, diffuse, specular, roughness = self._material(si, active)
        p_spec = self._p_spec(n_p, si.wi, diffuse, specular, has_diffuse, has_specular)
        frame, wi_p, wi_s, distr = self._sampling_setup(n_p, si.wi, roughness)

        choose_spec = sample1 < p_spec
        m, _ = distr.sample(wi_s, sample2)
        wo_spec = mi.reflect(wi_p, m)
        wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
        wo_p = dr.select(choose_spec, wo_spec, wo_diff)
        # A reflection about an m facing away from wi (possible only for back-facing wi_p,
        # where the sampler sees the clamped wi_s) is not covered by pdf(): reject it.
        active &= ~choose_spec | (dr.dot(wi_p, m) > 0.0)

        wo = frame.to_world(wo_p)
        valid = self._valid(si, n_p, wo, active)
        pdf = self._pdf(si, wo, n_p, diffuse, specular, roughness, valid, has_diffuse, has_specular)
        valid &= pdf > 0.0
        value = self._f_cos(n_p, si.wi, wo, diffuse, specular, roughness, has_diffuse, has_specular)

        bs.wo = wo
        bs.pdf = dr.select(valid, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_component = dr.select(choose_spec, mi.UInt32(1), mi.UInt32(0))
        bs.sampled_type = dr.select(choose_spec, mi.UInt32(int(mi.BSDFFlags.GlossyReflection)),
                                    mi.UInt32(int(mi.BSDFFlags.DiffuseReflection)))
        weight = value * dr.rcp(dr.select(valid, pdf, 1.0))
        return bs, dr.select(valid, weight, 0.0)

    def eval(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
             active: mi.Bool = True) -> mi.Color3f:
        has_diffuse, has_specular = self._lobe_selection(ctx)
        active = mi.Bool(active)
        n_p, diffuse, specular, roughness = self._material(si, active)
        valid = self._valid(si, n_p, wo, active)
        value = self._f_cos(n_p, si.wi, wo, diffuse, specular, roughness, has_diffuse, has_specular)
        return dr.select(valid, value, 0.0)

    def pdf(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
            active: mi.Bool = True) -> mi.Float:
        has_diffuse, has_specular = self._lobe_selection(ctx)
        active = mi.Bool(active)
        n_p, diffuse, specular, roughness = self._material(si, active)
        valid = self._valid(si, n_p, wo, active)
        return self._pdf(si, wo, n_p, diffuse, specular, roughness, valid, has_diffuse, has_specular)

    def eval_pdf(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
                 active: mi.Bool = True) -> tuple[mi.Color3f, mi.Float]:
        has_diffuse, has_specular = self._lobe_selection(ctx)
        active = mi.Bool(active)
        n_p, diffuse, specular, roughness = self._material(si, active)
        valid = self._valid(si, n_p, wo, active)
        value = self._f_cos(n_p, si.wi, wo, diffuse, specular, roughness, has_diffuse, has_specular)
        pdf = self._pdf(si, wo, n_p, diffuse, specular, roughness, valid, has_diffuse, has_specular)
        return dr.select(valid, value, 0.0), pdf

    def traverse(self, callback: mi.TraversalCallback) -> None:
        flags = mi.ParamFlags.Differentiable
        callback.put("normal", self.m_normal, flags | mi.ParamFlags.Discontinuous)
        callback.put("diffuse", self.m_diffuse, flags)
        callback.put("roughness", self.m_roughness, flags)
        callback.put("specular", self.m_specular, flags)

    def parameters_changed(self, keys: list[str] | None = None) -> None:
        # Textures update themselves (bitmap textures rebuild their data in their own
        # parameters_changed); this BSDF caches nothing derived from them.
        pass

    def to_string(self) -> str:
        return (f"SVBRDF[\n  distribution = {self.m_distribution},\n"
                f"  normal = {self.m_normal},\n  diffuse = {self.m_diffuse},\n"
                f"  roughness = {self.m_roughness},\n  specular = {self.m_specular}\n]")
