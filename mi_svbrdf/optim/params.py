"""Parameterisation of the optimised maps: unconstrained variables <-> valid canonical maps.

The optimiser works on a ``(1, 9, H, W)`` tensor of unconstrained reals:

* channels 0-1: normal *slopes* ``(p, q)``, normal = ``normalize(p, q, 1)`` -- the networks'
  parameterisation (``/work/shared/conventions.md``). Chosen over two angles because it has
  no singularity at the flat normal (where every sample starts and most texels stay: the
  azimuth of a (theta, phi) pair is undefined there) and always points above the plane.
* channels 2-4: diffuse logits, diffuse = ``sigmoid``;
* channel 5: roughness logit, roughness = ``sigmoid`` (renderer uses alpha = r^2);
* channels 6-8: specular logits, specular = ``sigmoid``.

**Map models** (:data:`MODELS`, simplest first): a fit may tie maps to one value over the sample or
hold them fixed, as the photos support (:mod:`~mi_svbrdf.optim.select` chooses per capture):

* ``"lambertian"``: normals and diffuse per texel; no specular (its logits held at ``logit(EPS)``);
* ``"uniform"``: normals and diffuse per texel, one roughness and one specular colour;
* ``"uniform_specular"``: roughness per texel too, one specular colour;
* ``"full"``: every map per texel (the thesis's SVBRDF).

A tied map is one parameter: :func:`tie_gradient` replaces its gradient by its mean over the
texels (the gradient of the shared value, up to a scale Adam ignores), so from a uniform start
(:func:`tie_variables`) Adam moves every texel alike and the map stays uniform.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.maps import constant_maps
    >>> m = constant_maps(1, 2, 2, diffuse=0.3, specular=0.04, roughness=0.5)
    >>> torch.allclose(to_maps(from_maps(m)), m, atol=1e-5)
    True
"""
from __future__ import annotations

import math

import torch

from mi_svbrdf.core.maps import check_maps, normal

#: Number of unconstrained channels.
N_VARIABLES = 9
#: Albedos and roughness are kept in [EPS, 1 - EPS] when converted to logits.
EPS = 1e-4
#: Map models, simplest first (module docstring).
MODELS = ("lambertian", "uniform", "uniform_specular", "full")
#: Per model: the channels tied to their mean over the texels, and the channels held fixed.
_TIED = {"lambertian": (), "uniform": (5, 6, 7, 8), "uniform_specular": (6, 7, 8), "full": ()}
_FIXED = {"lambertian": (5, 6, 7, 8), "uniform": (), "uniform_specular": (), "full": ()}
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


def _check_model(model: str) -> None:
    if model not in MODELS:
        raise ValueError(f"model: expected one of {MODELS}, got {model!r}")


def tie_variables(variables: torch.Tensor, model: str) -> torch.Tensor:
    """Variables ``(B, 9, H, W)`` made a start of ``model``: tied channels set to their mean over the
    texels, a Lambertian model's specular to ``EPS`` (roughness then has no effect; kept).

    Examples:
        >>> v = torch.randn(1, 9, 4, 4)
        >>> bool((tie_variables(v, "uniform")[:, 5:].std(dim=(2, 3)) < 1e-6).all())
        True
    """
    _check_model(model)
    out = variables.clone()
    tied = list(_TIED[model])
    if tied:
        out[:, tied] = variables[:, tied].mean(dim=(2, 3), keepdim=True).expand_as(out[:, tied])
    if model == "lambertian":
        out[:, 6:9] = math.log(EPS / (1.0 - EPS))
    return out


def tie_gradient(grad: torch.Tensor, model: str) -> None:
    """The gradient ``(B, 9, H, W)`` of ``model``'s parameters, in place: tied channels get their mean over
    the texels, fixed channels zero (module docstring). ``"full"`` leaves it as it is."""
    _check_model(model)
    tied, fixed = list(_TIED[model]), list(_FIXED[model])
    if tied:
        grad[:, tied] = grad[:, tied].mean(dim=(2, 3), keepdim=True).expand_as(grad[:, tied])
    if fixed:
        grad[:, fixed] = 0.0
