"""Light/view configurations of the rendering loss (thesis ch. 3.1.3, appendix A.1).

Per batch element: ``n_diffuse`` far-field configurations (view and light directions drawn
independently from the cosine-weighted hemisphere) followed by ``n_specular`` near-field
mirror configurations (a view direction, the light at its mirror direction ``(-x, -y, z)``,
both moved by a random shift on the plane and placed at independent random distances).
Configurations are homogeneous ``(B, K, 4)`` tensors (w = 0: direction, w = 1: position), drawn
from a seeded ``torch.Generator`` so two calls (or two backends) can use exactly the same ones.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.configurations import sample_configurations
    >>> c = sample_configurations(2, generator=torch.Generator().manual_seed(0))
    >>> tuple(c.light.shape), c.light[0, :3, 3].tolist(), c.light[0, 3:, 3].tolist()
    ((2, 9, 4), [0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class Configurations:
    """K light/view configurations per batch element."""

    light: torch.Tensor  #: (B, K, 4) homogeneous light positions/directions
    view: torch.Tensor  #: (B, K, 4) homogeneous viewer positions/directions

    def __post_init__(self) -> None:
        if self.light.dim() != 3 or self.light.shape[2] != 4 or self.light.shape != self.view.shape:
            raise ValueError("Configurations: expected light and view of the same shape (B, K, 4), "
                             f"got {tuple(self.light.shape)} and {tuple(self.view.shape)}")

    @property
    def count(self) -> int:
        """K, the number of configurations per batch element."""
        return self.light.shape[1]


def _uniform(shape: tuple[int, ...], low: float, high: float, gen: torch.Generator | None,
             device: torch.device | str) -> torch.Tensor:
    return low + (high - low) * torch.rand(shape, generator=gen, device=device)


def cosine_directions(shape: tuple[int, ...], *, r1_max: float = 0.95, generator: torch.Generator | None = None,
                      device: torch.device | str = "cpu") -> torch.Tensor:
    """Directions ``shape + (3,)`` on the upper hemisphere, cosine-weighted as the authors' sampler.

    r1 ~ U(0.001, r1_max), r2 ~ U(0, 1), r = sqrt(r1), phi = 2 pi r2,
    w = (r cos phi, r sin phi, sqrt(1 - r^2)); ``r1_max = 1 - eps_hi`` keeps away from grazing.
    """
    r1 = _uniform(shape, 0.001, r1_max, generator, device)
    r2 = _uniform(shape, 0.0, 1.0, generator, device)
    r = torch.sqrt(r1)
    phi = 2.0 * math.pi * r2
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), torch.sqrt(1.0 - r * r)], dim=-1)


def sample_configurations(batch: int, n_diffuse: int = 3, n_specular: int = 6, *, r1_max: float = 0.95,
                          generator: torch.Generator | None = None,
                          device: torch.device | str = "cpu") -> Configurations:
    """Draw the rendering loss's configurations for ``batch`` samples.

    Args:
        batch: B.
        n_diffuse: far-field configurations per sample (directions drawn independently).
        n_specular: near-field mirror configurations per sample.
        r1_max: upper bound of r1 (0.95 in the 2018 code, 0.90 in the 2019 code).
        generator: seeded generator for reproducible draws.
        device: device of the result.

    Returns:
        :class:`Configurations` with ``K = n_diffuse + n_specular``, diffuse ones first.
    """
    if batch < 1 or n_diffuse < 0 or n_specular < 0 or n_diffuse + n_specular < 1:
        raise ValueError(f"expected batch >= 1 and at least one configuration, got batch={batch}, "
                         f"n_diffuse={n_diffuse}, n_specular={n_specular}")
    if not 0.001 < r1_max <= 1.0:
        raise ValueError(f"r1_max: expected a value in (0.001, 1], got {r1_max}")
    out_device, device = device, "cpu"  # draw on the CPU (the generator's device), then move
    # Diffuse: independent directions, far field.
    view_d = cosine_directions((batch, n_diffuse), r1_max=r1_max, generator=generator, device=device)
    light_d = cosine_directions((batch, n_diffuse), r1_max=r1_max, generator=generator, device=device)
    # Specular: mirrored directions, shifted, at independent log-normal distances.
    v_dir = cosine_directions((batch, n_specular), r1_max=r1_max, generator=generator, device=device)
    l_dir = v_dir * torch.tensor([-1.0, -1.0, 1.0], device=device)
    shift = torch.stack([_uniform((batch, n_specular), -1.0, 1.0, generator, device),
                         _uniform((batch, n_specular), -1.0, 1.0, generator, device),
                         torch.full((batch, n_specular), 1e-4, device=device)], dim=-1)
    v_dist = torch.exp(0.5 + 0.75 * torch.randn((batch, n_specular, 1), generator=generator, device=device))
    l_dist = torch.exp(0.5 + 0.75 * torch.randn((batch, n_specular, 1), generator=generator, device=device))
    view_s = v_dir * v_dist + shift
    light_s = l_dir * l_dist + shift

    def hom(x: torch.Tensor, w: float) -> torch.Tensor:
        return torch.cat([x, torch.full_like(x[..., :1], w)], dim=-1)

    return Configurations(light=torch.cat([hom(light_d, 0.0), hom(light_s, 1.0)], dim=1).to(out_device),
                          view=torch.cat([hom(view_d, 0.0), hom(view_s, 1.0)], dim=1).to(out_device))
