"""Shared fixtures: a Mitsuba AD variant and random materials."""
from __future__ import annotations

import pytest
import torch

import mi_svbrdf  # noqa: F401  (selects the variant, registers plugins)


def random_maps(batch: int, height: int, width: int, *, seed: int = 0, rough_range: tuple[float, float] = (0.0, 1.0),
                max_tilt: float = 1.2, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Random valid maps: unit normals tilted up to ``max_tilt`` radians, albedos and roughness uniform."""
    g = torch.Generator().manual_seed(seed)
    theta = torch.rand(batch, 1, height, width, generator=g) * max_tilt
    phi = torch.rand(batch, 1, height, width, generator=g) * 6.283185307
    n = torch.cat([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], 1)
    d = torch.rand(batch, 3, height, width, generator=g)
    lo, hi = rough_range
    r = lo + (hi - lo) * torch.rand(batch, 1, height, width, generator=g)
    s = torch.rand(batch, 3, height, width, generator=g)
    return torch.cat([n, d, r, s], 1).to(dtype)


@pytest.fixture
def maps_factory():
    return random_maps
