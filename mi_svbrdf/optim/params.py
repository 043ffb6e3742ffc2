"""Parameterisation of the optimised maps: unconstrained variables <-> valid canonical maps.

The optimiser works on a ``(1, 9, H, W)`` tensor of unconstrained reals:

* channels 0-1: normal *slopes* ``(p, q)``, normal = ``normalize(p, q, 1)`` -- the networks'
  parameterisation (``/work/shared/conventions.md``). Chosen over two angles because it has
  no singularity at the flat normal (where every sample starts and most texels stay: the
  azimuth of a (theta, phi) pair is undefined there) and always points above the plane.
* channels 2-4: diffuse logits, diffuse = ``sigmoid``;
* channel 5: roughness logit, roughness = ``sigmoid`` (renderer uses alpha = r^2);
* channels 6-8: specular logits, specular = ``sigmoid``.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.maps import constant_maps
    >>> m = constant_maps(1, 2, 2, diffuse=0.3, specular=0.04, roughness=0.5)
    >>> torch.allclose(to_maps(from_maps(m)), m, atol=1e-5)
    True
"""
from __future__ import annotations

import torch

from mi_svbrdf.core.maps import check_maps, normal

#: Number of unconstrained channels.
N_VARIABLES = 9
#: Albedos and roughness are kept in [EPS, 1 - EPS] when converted to logits.
EPS = 1e-4
#: Normals are kept at least this far above the plane (n.z >= MIN_NORMAL_Z) when converted to slopes.
MIN_NORMAL_Z = 0.05


def to_maps(variables: torch.Tensor) -> torch.Tensor:
    """Unconstrained ``(B, 9, H, W)`` -> canonical maps ``(B, 10, H, W)`` (differentiable)."""
    if variables.dim() != 4 or variables.shape[1] != N_VARIABLES:
        raise ValueError(f"variables: expected shape (B, {N_VARIABLES}, H, W), got {tuple(variables.shape)}")
    slopes = variables[:, 0:2]
    normal = torch.cat([slopes, torch.ones_like(slopes[:, :1])], dim=1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    values = torch.sigmoid(variables[:, 2:])
    return torch.cat([normal, values], dim=1)


def from_maps(maps: torch.Tensor) -> torch.Tensor:
    """Canonical maps ``(B, 10, H, W)`` -> unconstrained ``(B, 9, H, W)`` (inverse of :func:`to_maps`).

    Normals below ``MIN_NORMAL_Z`` are raised to it; albedos and roughness are clipped to
    ``[EPS, 1 - EPS]`` so their logits are finite.
    """
    check_maps(maps)
    n = normal(maps)
    n = n / n.norm(dim=1, keepdim=True).clamp_min(1e-12)
    slopes = n[:, 0:2] / n[:, 2:3].clamp_min(MIN_NORMAL_Z)
    return torch.cat([slopes, torch.logit(maps[:, 3:].clamp(EPS, 1.0 - EPS))], dim=1).contiguous()


def total_variation(maps: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference between horizontal and vertical neighbours, over all channels (scalar)."""
    dx = (maps[..., :, 1:] - maps[..., :, :-1]).abs().mean()
    dy = (maps[..., 1:, :] - maps[..., :-1, :]).abs().mean()
    return dx + dy


def resize_variables(variables: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Bilinearly resample unconstrained variables ``(B, 9, h, w)`` to ``size`` (coarse-to-fine)."""
    if tuple(variables.shape[-2:]) == tuple(size):
        return variables.clone()
    down = size[0] < variables.shape[-2]
    return torch.nn.functional.interpolate(variables, size=size, mode="bilinear", align_corners=False, antialias=down)
