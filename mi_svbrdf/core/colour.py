"""Colour conventions: the one photo gamma and luminance.

* The photo gamma (:data:`GAMMA`, :func:`gamma_encode`, :func:`gamma_decode`): the authors' pipeline
  uses a plain 2.2 power for the nets' photos and the rendering loss's displays, not the sRGB curve
  (user photos and material PNGs are sRGB: :mod:`mi_svbrdf.io.material_io`).
* Luminance (:data:`LUMINANCE`, :func:`luminance`): Rec. 709 / sRGB weights of linear RGB.
* The sRGB curve on tensors (:func:`srgb_to_linear`, :func:`linear_to_srgb`): IEC 61966-2-1, as
  :mod:`mi_svbrdf.io.material_io` applies it to files with the ``colour`` library (a test holds them equal), for
  the fit's intervals of a photo's codes on the photos' own device.

Examples:
    >>> import torch
    >>> round(float(gamma_decode(gamma_encode(torch.tensor(0.25)))), 6)
    0.25
    >>> luminance(torch.ones(2, 3, 4, 4)).shape
    torch.Size([2, 4, 4])
    >>> round(float(srgb_to_linear(linear_to_srgb(torch.tensor(0.25)))), 6)
    0.25
"""
from __future__ import annotations

import torch

#: The one photo gamma of mi_svbrdf: the authors' pipeline uses a plain 2.2 power, not the sRGB
#: curve (user photos and material PNGs are sRGB: :mod:`mi_svbrdf.io.material_io`).
GAMMA = 2.2


def gamma_encode(linear: torch.Tensor) -> torch.Tensor:
    """``clip(x, 0, 1)^(1/2.2)``: a linear image as displayed or as an 8-bit photo stores it (before rounding)."""
    return linear.clamp(0.0, 1.0).pow(1.0 / GAMMA)


def gamma_decode(encoded: torch.Tensor) -> torch.Tensor:
    """``clip(x, 0, 1)^2.2``: the linear image of a gamma-encoded one."""
    return encoded.clamp(0.0, 1.0).pow(GAMMA)


#: Rec. 709 / sRGB luminance weights of linear R, G, B.
LUMINANCE: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)


def luminance(rgb: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """The luminance ``0.2126 R + 0.7152 G + 0.0722 B`` of linear RGB along ``dim`` (default: the channel
    axis of ``(..., 3, H, W)`` maps), which is removed.

    Raises:
        ValueError: ``rgb``'s ``dim`` does not have 3 entries.
    """
    if rgb.shape[dim] != 3:
        raise ValueError(f"rgb: expected 3 channels along dim {dim}, got shape {tuple(rgb.shape)}")
    w = torch.tensor(LUMINANCE, dtype=rgb.dtype, device=rgb.device)
    return torch.tensordot(rgb.movedim(dim, -1), w, dims=1)


def linear_to_srgb(linear: torch.Tensor) -> torch.Tensor:
    """The sRGB encoding of ``clip(x, 0, 1)``: ``12.92 x`` up to 0.0031308, else ``1.055 x^(1/2.4) - 0.055``;
    computed in double precision, returned in ``linear``'s dtype."""
    x = linear.double().clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.pow(1.0 / 2.4) - 0.055).to(linear.dtype)


def srgb_to_linear(encoded: torch.Tensor) -> torch.Tensor:
    """The linear value of sRGB-encoded ``v``: ``v / 12.92`` up to 0.04045, else ``((v + 0.055) / 1.055)^2.4``;
    computed in double precision, returned in ``encoded``'s dtype."""
    v = encoded.double()
    return torch.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055).pow(2.4)).to(encoded.dtype)
