"""The thesis's SVBRDF model in Dr.Jit: the one implementation of the BRDF math.

Both the Mitsuba BSDF plugins (``svbrdf_ggx``, ``svbrdf_beckmann``) and the texel
renderer's ``"mitsuba"`` backend call :func:`eval_brdf`; nothing else in mi_svbrdf
evaluates the model in Dr.Jit. The plain-PyTorch reference lives in
``mi_svbrdf/core/brdf_torch.py`` and is written independently so the two can be compared.

The formulas follow the thesis (appendix A.3) and the authors' public code,
with c(x) = max(x, 0) and every denominator floored at 1e-3 as that code does::

    h = normalize(wl + wv);  alpha = r^2
    D = alpha^2 / (pi * max(1e-3, c(n.h)^2 (alpha^2 - 1) + 1)^2)       (GGX)
    k = alpha / 2
    G = 1/max(1e-3, c(n.wl)(1-k)+k) * 1/max(1e-3, c(n.wv)(1-k)+k)     (Smith-Schlick / (n.wl n.wv))
    F = s + (1 - s) * 2^((-5.55473 c(wv.h) - 6.98316) c(wv.h))
    f = F G D / 4  [+ d (1 - s) / pi]

The Beckmann twin (thesis ch. 6.1.1) swaps D for the Beckmann distribution
``exp((c^2 - 1)/(alpha^2 c^2)) / (pi alpha^2 c^4)`` (c = c(n.h), floored at 1e-3) and k for
Schlick's Beckmann fit ``alpha * sqrt(2/pi)``; F and the diffuse term are shared.

**Float32.** Both D's depend on ``1 - c^2 = sin^2(theta_h)``, which near a steep lobe's peak is
about alpha^2 (1e-4 at r = 0.1): computed as ``1 - c^2`` from a float32 cosine near 1 it keeps an
absolute error of ~1e-7, which Beckmann's exponent divides by alpha^2 (a relative error of 4e-3 in
D at r = 0.1, 0.6 at r = 0.03) and GGX's squared denominator ``c^2 (alpha^2 - 1) + 1`` doubles
(7e-4 at r = 0.1). :func:`eval_brdf` therefore passes ``sin^2(theta_h) = |n x h|^2`` (exact in
exact arithmetic for unit n and h, and accurate to ~1e-7 *relative* in float32) and D is written
with it: ``exp(-sin^2/(alpha^2 c^2)) / (pi alpha^2 c^4)`` and ``alpha^2 / (pi (sin^2 + alpha^2 c^2)^2)``.

All functions are written with generic Dr.Jit operations, so they run on any
``*_ad_rgb`` variant (and on plain Dr.Jit arrays) and are differentiable.
"""
from __future__ import annotations

import math

import drjit as dr

#: The floor the authors' code applies to every denominator.
EPS_DENOM = 1e-3
#: Roughness is clipped to [ROUGHNESS_MIN, 1] before use (the authors' code: clip to [0, 1], floor 1e-3).
ROUGHNESS_MIN = 1e-3
#: Names accepted for the microfacet distribution.
DISTRIBUTIONS = ("ggx", "beckmann")


def safe_normalize(v):
    """``v / |v|`` with the squared norm floored at 1e-12 (finite value and gradient at 0)."""
    return v * dr.rsqrt(dr.maximum(dr.squared_norm(v), 1e-12))


def clamp_roughness(r):
    """Clip roughness to ``[ROUGHNESS_MIN, 1]`` as the authors' renderer does."""
    return dr.clip(r, ROUGHNESS_MIN, 1.0)


def distribution_d(n_dot_h, alpha, distribution: str = "ggx", sin2_h=None):
    """Normal distribution D(h) for ``alpha = r^2`` (floored denominators).

    Args:
        n_dot_h: c(n . h).
        alpha: r^2.
        distribution: ``"ggx"`` or ``"beckmann"``.
        sin2_h: ``sin^2`` of the angle between n and h, ``|n x h|^2`` (see the module docstring:
            ``1 - c^2`` from a float32 cosine near 1 loses the peak of steep lobes). None: ``1 - c^2``
            (for a caller that has only the cosine). Where ``n_dot_h <= 1e-3`` (the floors' range, h
            at or behind n's horizon) ``1 - c^2`` of the floored cosine is used either way, as before.
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    c = dr.maximum(n_dot_h, EPS_DENOM) if distribution == "beckmann" else n_dot_h
    c2 = c * c
    s2 = 1.0 - c2
    if sin2_h is not None:
        s2 = dr.select(n_dot_h > EPS_DENOM, sin2_h, s2)
    a2 = alpha * alpha
    if distribution == "ggx":
        # c^2 (a2 - 1) + 1, written as sin^2 + a2 c^2
        denom = dr.maximum(EPS_DENOM, s2 + a2 * c2)
        return a2 / (dr.pi * denom * denom)
    # (c^2 - 1)/(a2 c^2) = -sin^2/(a2 c^2); exp(u) / (pi a2 c^4) written as one exp: at tiny alpha
    # the quotient's derivative squares a denominator of ~1e-24, which underflows float32 and gives
    # 0 * inf = NaN.
    return dr.exp(-s2 / (a2 * c2) - dr.log(dr.pi * a2) - 2.0 * dr.log(c2))


def smith_k(alpha, distribution: str = "ggx"):
    """The Schlick approximation's k: alpha/2 (GGX) or alpha*sqrt(2/pi) (Beckmann)."""
    if distribution == "ggx":
        return alpha * 0.5
    if distribution == "beckmann":
        return alpha * math.sqrt(2.0 / math.pi)
    raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")


def fresnel(v_dot_h, specular):
    """Spherical-Gaussian Schlick Fresnel ``s + (1 - s) 2^((-5.55473 c - 6.98316) c)``."""
    return specular + (1.0 - specular) * dr.exp2((-5.55473 * v_dot_h - 6.98316) * v_dot_h)


def diffuse_lobe(diffuse, specular):
    """The diffuse term ``d (1 - s) / pi`` of the model."""
    return diffuse * (1.0 - specular) * dr.inv_pi


def eval_brdf(n, wl, wv, diffuse, specular, roughness,
              distribution: str = "ggx", include_diffuse: bool = True):
    """Evaluate the BRDF value f (no cosine factor).

    Args:
        n: unit shading normal (Array3f).
        wl: direction towards the light (normalised here).
        wv: direction towards the viewer (normalised here).
        diffuse: diffuse albedo d (Array3f / Color3f), linear.
        specular: specular albedo s (Array3f / Color3f), linear.
        roughness: roughness r (Float), already clipped by the caller if wanted; alpha = r^2.
        distribution: ``"ggx"`` or ``"beckmann"``.
        include_diffuse: add ``d (1 - s) / pi``.

    Returns:
        f as an Array3f of the same type as ``diffuse``.
    """
    wl = safe_normalize(wl)
    wv = safe_normalize(wv)
    h = safe_normalize(wl + wv)
    n_dot_h = dr.maximum(dr.dot(n, h), 0.0)
    sin2_h = dr.squared_norm(dr.cross(n, h))  # 1 - (n.h)^2 without its cancellation near the peak
    n_dot_l = dr.maximum(dr.dot(n, wl), 0.0)
    n_dot_v = dr.maximum(dr.dot(n, wv), 0.0)
    v_dot_h = dr.maximum(dr.dot(wv, h), 0.0)

    alpha = roughness * roughness
    d_term = distribution_d(n_dot_h, alpha, distribution, sin2_h)
    k = smith_k(alpha, distribution)
    g_term = (dr.rcp(dr.maximum(EPS_DENOM, n_dot_l * (1.0 - k) + k))
              * dr.rcp(dr.maximum(EPS_DENOM, n_dot_v * (1.0 - k) + k)))
    f_term = fresnel(v_dot_h, specular)
    f = f_term * (g_term * d_term * 0.25)
    if include_diffuse:
        f = f + diffuse_lobe(diffuse, specular)
    return f


def cosine(n, wl):
    """c(n . wl) with wl normalised."""
    return dr.maximum(dr.dot(n, safe_normalize(wl)), 0.0)
