"""Plain-PyTorch reference of the thesis's BRDF and texel renderer.

Written independently of the Dr.Jit implementation (``mi_svbrdf/plugins/model.py``) so the
two can be compared value for value and gradient for gradient (nvdiffrec's pattern: a
reference beside each fast op). Readable first, not fast; float64-capable for ``gradcheck``.

All tensors broadcast; vectors have their 3 components in dimension ``dim`` (default -3,
i.e. ``(..., 3, H, W)``).
"""
from __future__ import annotations

import math

import torch

from mi_svbrdf.core.maps import SLICES

EPS_DENOM = 1e-3
ROUGHNESS_MIN = 1e-3


def dot(a: torch.Tensor, b: torch.Tensor, dim: int) -> torch.Tensor:
    """Dot product along ``dim``, kept as a size-1 dimension."""
    return (a * b).sum(dim=dim, keepdim=True)


def normalize(v: torch.Tensor, dim: int) -> torch.Tensor:
    """``v`` scaled to unit length along ``dim`` (a zero vector stays zero)."""
    return v * torch.rsqrt(dot(v, v, dim).clamp_min(1e-12))


def eval_brdf(n: torch.Tensor, wl: torch.Tensor, wv: torch.Tensor, diffuse: torch.Tensor,
              specular: torch.Tensor, roughness: torch.Tensor, *, distribution: str = "ggx",
              include_diffuse: bool = True, dim: int = -3) -> torch.Tensor:
    """BRDF value f of the thesis model (no cosine), see ``plugins/model.py`` for the formulas.

    Args:
        n: unit normals ``(..., 3, H, W)``.
        wl: directions towards the light (normalised here), broadcastable to ``n``.
        wv: directions towards the viewer (normalised here).
        diffuse: diffuse albedo ``(..., 3, H, W)``.
        specular: specular albedo ``(..., 3, H, W)``.
        roughness: roughness ``(..., 1, H, W)`` (alpha = roughness^2).
        distribution: ``"ggx"`` or ``"beckmann"``.
        include_diffuse: add ``d (1 - s) / pi``.
        dim: the vector dimension.

    Returns:
        f with the broadcast shape ``(..., 3, H, W)``.
    """
    wl = normalize(wl, dim)
    wv = normalize(wv, dim)
    h = normalize(wl + wv, dim)
    n_h = dot(n, h, dim).clamp_min(0.0)
    # sin^2 of the angle between n and h as |n x h|^2: 1 - (n.h)^2 from a float32 cosine near 1 keeps an
    # absolute error of ~1e-7, which a steep lobe's D divides by alpha^2 (plugins/model.py, "Float32");
    # where n.h <= 1e-3 (the floors' range) 1 - c^2 of the floored cosine, as the formulas are written.
    (nx, ny, nz), (hx, hy, hz) = n.unbind(dim), h.unbind(dim)
    sin2_h = ((ny * hz - nz * hy) ** 2 + (nz * hx - nx * hz) ** 2 + (nx * hy - ny * hx) ** 2).unsqueeze(dim)
    n_l = dot(n, wl, dim).clamp_min(0.0)
    n_v = dot(n, wv, dim).clamp_min(0.0)
    v_h = dot(wv, h, dim).clamp_min(0.0)
    alpha = roughness * roughness
    a2 = alpha * alpha
    if distribution == "ggx":
        sin2 = torch.where(n_h > EPS_DENOM, sin2_h, 1.0 - n_h * n_h)
        base = (sin2 + a2 * n_h * n_h).clamp_min(EPS_DENOM)  # c^2 (a2 - 1) + 1
        d_term = a2 / (math.pi * base * base)
        k = alpha / 2.0
    elif distribution == "beckmann":
        c2 = n_h.clamp_min(EPS_DENOM) ** 2
        sin2 = torch.where(n_h > EPS_DENOM, sin2_h, 1.0 - c2)
        d_term = torch.exp(-sin2 / (a2 * c2)) / (math.pi * a2 * c2 * c2)  # exp((c^2 - 1)/(a2 c^2)) / ...
        k = alpha * math.sqrt(2.0 / math.pi)
    else:
        raise ValueError(f"distribution: expected 'ggx' or 'beckmann', got {distribution!r}")
    g_term = 1.0 / (n_l * (1.0 - k) + k).clamp_min(EPS_DENOM) / (n_v * (1.0 - k) + k).clamp_min(EPS_DENOM)
    fresnel = specular + (1.0 - specular) * torch.pow(2.0, (-5.55473 * v_h - 6.98316) * v_h)
    f = fresnel * g_term * d_term / 4.0
    if include_diffuse:
        f = f + diffuse * (1.0 - specular) / math.pi
    return f


def render(maps: torch.Tensor, positions: torch.Tensor, light: torch.Tensor, view: torch.Tensor,
           intensity: torch.Tensor, cone_target: torch.Tensor | None, cone_exponent: torch.Tensor | None,
           *, distance_falloff: bool, light_z_division: bool, include_diffuse: bool,
           normalize_normals: bool, distribution: str) -> torch.Tensor:
    """Reference texel renderer (the ``"torch"`` backend of :func:`mi_svbrdf.core.render`).

    Args:
        maps: ``(B, 10, H, W)``.
        positions: ``(3, H, W)`` texel positions on the plane.
        light: ``(B, K, 4)`` homogeneous light positions (w = 0: a direction).
        view: ``(B, K, 4)`` homogeneous viewer positions.
        intensity: ``(B, K, 3)``.
        cone_target: ``(B, K, 3)`` or None.
        cone_exponent: ``(B, K)`` or None.

    Returns:
        ``(B, K, 3, H, W)`` radiance.
    """
    n = maps[:, None, SLICES["normal"]]
    if normalize_normals:
        n = normalize(n, -3)
    d = maps[:, None, SLICES["diffuse"]]
    r = maps[:, None, SLICES["roughness"]].clamp(ROUGHNESS_MIN, 1.0)
    s = maps[:, None, SLICES["specular"]]
    p = positions[None, None]

    def towards(q: torch.Tensor) -> torch.Tensor:  # (B, K, 4) -> (B, K, 3, H, W)
        return q[..., :3, None, None] - q[..., 3:4, None, None] * p

    wl, wv = towards(light), towards(view)
    f = eval_brdf(n, wl, wv, d, s, r, distribution=distribution, include_diffuse=include_diffuse)
    wl_unit = normalize(wl, -3)
    radiance = f * math.pi * intensity[..., None, None] * dot(n, wl_unit, -3).clamp_min(0.0)
    if distance_falloff:
        w = light[..., 3, None, None, None]
        radiance = radiance * (w / dot(wl, wl, -3).clamp_min(1e-12) + (1.0 - w))
    if light_z_division:
        radiance = radiance / wl_unit[:, :, 2:3].clamp_min(EPS_DENOM)
    if cone_target is not None and cone_exponent is not None:
        axis = normalize(light[..., :3] - cone_target, -1)[..., None, None]
        cos_cone = dot(wl_unit, axis, -3).clamp_min(1e-12)
        radiance = radiance * cos_cone ** cone_exponent[..., None, None, None]
    return radiance
