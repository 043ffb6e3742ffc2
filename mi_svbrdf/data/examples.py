"""Built-in example materials, generated procedurally (nothing to download, deterministic).

Examples:
    >>> from mi_svbrdf.data.examples import example_material, EXAMPLES
    >>> sorted(EXAMPLES)
    ['metal_plate', 'tiles']
    >>> tuple(example_material("tiles", size=64).shape)
    (1, 10, 64, 64)
"""
from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F

from mi_svbrdf.core.maps import make_maps


def _value_noise(size: int, cells: int, gen: torch.Generator) -> torch.Tensor:
    """Smooth noise ``(1, 1, size, size)`` in [0, 1]: bicubic upsampling of a random grid."""
    grid = torch.rand(1, 1, cells + 3, cells + 3, generator=gen)
    up = F.interpolate(grid, size=(size + 2 * size // cells,) * 2, mode="bicubic", align_corners=False)
    off = size // cells
    return up[..., off:off + size, off:off + size].clamp(0.0, 1.0)


def normals_from_height(height: torch.Tensor, strength: float) -> torch.Tensor:
    """Unit normals ``(B, 3, H, W)`` of a height field ``(B, 1, H, W)`` (x right, y up, z out).

    ``height`` is in units of the sample's half width divided by ``strength`` per texel step.
    """
    h = F.pad(height, (1, 1, 1, 1), mode="replicate")
    dx = (h[..., 1:-1, 2:] - h[..., 1:-1, :-2]) * 0.5 * strength
    dy = (h[..., :-2, 1:-1] - h[..., 2:, 1:-1]) * 0.5 * strength  # row 0 is the top: +y is up
    n = torch.cat([-dx, -dy, torch.ones_like(dx)], dim=1)
    return n / n.norm(dim=1, keepdim=True)


def _tiles(size: int, gen: torch.Generator) -> torch.Tensor:
    """Glazed ceramic tiles with rough, darker grout; a smooth bump inside each tile."""
    tiles = 4
    coords = (torch.arange(size) + 0.5) / size * tiles
    u, v = coords[None, :].expand(size, size), coords[:, None].expand(size, size)
    fu, fv = u - u.floor(), v - v.floor()
    edge = torch.minimum(torch.minimum(fu, 1 - fu), torch.minimum(fv, 1 - fv))
    grout = (edge < 0.04).float()[None, None]
    bevel = (edge / 0.12).clamp(0, 1)[None, None]
    noise = _value_noise(size, 16, gen)
    height = (bevel * 0.6 + 0.05 * noise) * (1 - grout)
    tile_id = (u.floor() * tiles + v.floor()).long()
    palette = 0.6 * torch.tensor([[0.55, 0.18, 0.10], [0.60, 0.52, 0.35], [0.15, 0.28, 0.45], [0.70, 0.68, 0.62]])
    colour = palette[torch.randint(0, 4, (tiles * tiles,), generator=gen)][tile_id].permute(2, 0, 1)[None]
    colour = colour * (0.9 + 0.2 * noise)
    diffuse = colour * (1 - grout) + 0.25 * grout * (0.8 + 0.4 * noise)
    rough = 0.18 + 0.1 * noise
    rough = rough * (1 - grout) + 0.85 * grout
    spec = torch.full((1, 3, size, size), 0.04) * (1 - grout) + 0.02 * grout
    return make_maps(normals_from_height(height, strength=size / 24.0), diffuse.clamp(0, 1), rough,
                     spec)


def _metal_plate(size: int, gen: torch.Generator) -> torch.Tensor:
    """Coloured (gold-like) metal with hammered dents and a few rough scratches."""
    noise = _value_noise(size, 8, gen)
    fine = _value_noise(size, 32, gen)
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    scratches = torch.zeros(1, 1, size, size)
    for _ in range(6):
        angle = float(torch.rand(1, generator=gen)) * math.pi
        offset = float(torch.rand(1, generator=gen)) * 1.6 - 0.8
        dist = (xs * math.sin(angle) - ys * math.cos(angle) - offset).abs()
        scratches = torch.maximum(scratches, (1 - dist / 0.01).clamp(0, 1)[None, None])
    height = 0.5 * noise + 0.1 * fine - 0.2 * scratches
    spec = torch.tensor([1.0, 0.78, 0.34]).view(1, 3, 1, 1) * (0.85 + 0.15 * fine)
    diffuse = torch.full((1, 3, size, size), 0.02)
    rough = 0.25 + 0.15 * fine + 0.4 * scratches
    return make_maps(normals_from_height(height, strength=size / 16.0), diffuse, rough.clamp(0, 1),
                     spec.clamp(0, 1))


#: Example generators by name.
EXAMPLES: dict[str, Callable[[int, torch.Generator], torch.Tensor]] = {
    "tiles": _tiles,
    "metal_plate": _metal_plate,
}


def example_material(name: str = "tiles", size: int = 256, seed: int = 0) -> torch.Tensor:
    """A built-in example material ``(1, 10, size, size)``.

    Args:
        name: one of :data:`EXAMPLES`.
        size: resolution in texels (>= 16).
        seed: random seed (the same seed gives the same maps).
    """
    if name not in EXAMPLES:
        raise ValueError(f"name: expected one of {sorted(EXAMPLES)}, got {name!r}")
    if size < 16:
        raise ValueError(f"size: expected >= 16, got {size}")
    return EXAMPLES[name](size, torch.Generator().manual_seed(seed)).float().contiguous()
