"""SSIM and MS-SSIM of image batches (Wang et al. 2003/2004), differentiable.

Gaussian window 11 x 11, sigma 1.5, C1 = (0.01 L)^2, C2 = (0.03 L)^2 with data range L;
MS-SSIM uses the standard five scale weights, dropping the coarsest scales that would be
smaller than the window (renormalising the weights).

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.ssim import ssim
    >>> x = torch.rand(1, 3, 32, 32)
    >>> round(float(ssim(x, x)), 6)
    1.0
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def _gaussian_window(size: int, sigma: float, channels: int, like: torch.Tensor) -> torch.Tensor:
    coords = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2.0
    g = torch.exp(-coords**2 / (2.0 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, size, size).contiguous()


def _check(x: torch.Tensor, y: torch.Tensor) -> None:
    if x.dim() != 4 or x.shape != y.shape:
        raise ValueError(f"expected two tensors of the same shape (B, C, H, W), got {tuple(x.shape)} and {tuple(y.shape)}")


def _ssim_parts(x: torch.Tensor, y: torch.Tensor, data_range: float, window: int,
                sigma: float) -> tuple[torch.Tensor, torch.Tensor]:
    c = x.shape[1]
    size = min(window, x.shape[2], x.shape[3])
    w = _gaussian_window(size, sigma, c, x)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_x, mu_y = F.conv2d(x, w, groups=c), F.conv2d(y, w, groups=c)
    sxx = F.conv2d(x * x, w, groups=c) - mu_x**2
    syy = F.conv2d(y * y, w, groups=c) - mu_y**2
    sxy = F.conv2d(x * y, w, groups=c) - mu_x * mu_y
    cs = (2.0 * sxy + c2) / (sxx + syy + c2)
    lum = (2.0 * mu_x * mu_y + c1) / (mu_x**2 + mu_y**2 + c1)
    return (lum * cs).mean(dim=(1, 2, 3)), cs.mean(dim=(1, 2, 3))


def ssim(x: torch.Tensor, y: torch.Tensor, *, data_range: float = 1.0, window: int = 11,
         sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM per batch element ``(B,)`` of ``(B, C, H, W)`` images."""
    _check(x, y)
    return _ssim_parts(x, y, data_range, window, sigma)[0]


def ms_ssim(x: torch.Tensor, y: torch.Tensor, *, data_range: float = 1.0, window: int = 11,
            sigma: float = 1.5) -> torch.Tensor:
    """Multi-scale SSIM per batch element ``(B,)``; negative contrast terms are clamped at 0."""
    _check(x, y)
    scales = 1
    while scales < len(MS_SSIM_WEIGHTS) and min(x.shape[2], x.shape[3]) // 2**scales >= window:
        scales += 1
    weights = torch.tensor(MS_SSIM_WEIGHTS[:scales], dtype=x.dtype, device=x.device)
    weights = weights / weights.sum()
    factors = []
    for s in range(scales):
        full, cs = _ssim_parts(x, y, data_range, window, sigma)
        factors.append((full if s == scales - 1 else cs).clamp_min(1e-6))
        if s < scales - 1:
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
    return torch.prod(torch.stack(factors, dim=0) ** weights[:, None], dim=0)
