"""Symmetry ensemble: a flash net run on the 8 flips and rotations of its photos, the maps turned back and averaged.

A fronto-parallel flash capture (camera and flash at the centre, a square frame) is unchanged in kind by the
symmetries of the square: the flipped or rotated photos are photos of the flipped or rotated surface. So a
net's maps of :func:`~mi_svbrdf.core.maps.symmetry_image` ``(photos, k)``, turned back by
:func:`~mi_svbrdf.core.maps.symmetry_maps` ``(..., k, inverse=True)``, are 8 estimates of the same maps;
their mean (normals renormalised) has the errors the estimates do not share. The ensemble is exactly
equivariant (its maps of a transformed photo are its transformed maps), whatever the net. For the
multi-image net every photo of a capture takes the same symmetry (the lights move with the surface).

Cost: ``symmetries`` passes of the net. Measured on the held-out sets (``benchmarks/bench_ensemble.py``).

Examples:
    >>> import torch
    >>> from mi_svbrdf.nets.network import build_network, network_config
    >>> net = build_network(network_config("compact", encoder_features=(8, 8, 8), last_features=8)).eval()
    >>> photos = torch.rand(1, 1, 3, 32, 32)
    >>> with torch.no_grad():
    ...     maps = symmetry_ensemble(net, photos)
    >>> tuple(maps.shape)
    (1, 10, 32, 32)
"""
from __future__ import annotations

import torch
from torch import nn

from mi_svbrdf.core.maps import SYMMETRIES, normalize_normals, symmetry_image, symmetry_maps

#: The ensemble's size where the bundled nets are run for a user (``predict``, ``capture``, ``evaluate``).
DEFAULT_SYMMETRIES = 8


def _check_count(symmetries: int) -> int:
    if isinstance(symmetries, bool) or not isinstance(symmetries, int) or not 1 <= symmetries <= len(SYMMETRIES):
        raise ValueError(f"symmetries: expected an int in [1, {len(SYMMETRIES)}] (1: the net alone), "
                         f"got {symmetries!r}")
    return symmetries


def symmetry_ensemble(net: nn.Module, photos: torch.Tensor, symmetries: int = 8) -> torch.Tensor:
    """The mean of ``net``'s maps over the first ``symmetries`` of :data:`~mi_svbrdf.core.maps.SYMMETRIES`.

    Args:
        net: a flash net (single or multi), ``photos -> (B, 10, H, W)`` maps.
        photos: ``(B, N, 3, H, W)`` or ``(B, 3, H, W)`` linear photos, as ``net`` takes them. Non-square
            photos are fine: the transposed ones are ``W x H``.
        symmetries: how many symmetries (1: ``net(photos)`` alone; 8: all of them, the default; 2 or 4:
            the flips, no transposition).

    Returns:
        ``(B, 10, H, W)`` maps, normals of unit length.
    """
    count = _check_count(symmetries)
    if count == 1:
        return net(photos)
    total: torch.Tensor | None = None
    for k in range(count):
        maps = symmetry_maps(net(symmetry_image(photos, k)).float(), k, inverse=True)
        total = maps if total is None else total + maps
    assert total is not None
    return normalize_normals(total / count)


class SymmetryEnsemble(nn.Module):
    """:func:`symmetry_ensemble` as a module wrapping ``net`` (it keeps the net's ``config``).

    Examples:
        >>> from mi_svbrdf.nets.network import build_network, network_config
        >>> net = SymmetryEnsemble(build_network(network_config("compact", encoder_features=(8, 8, 8), last_features=8)), symmetries=4)
        >>> net.config.kind, net.symmetries
        ('single', 4)
    """

    def __init__(self, net: nn.Module, symmetries: int = 8) -> None:
        super().__init__()
        self.net = net
        self.symmetries = _check_count(symmetries)
        self.config = net.config

    def forward(self, photos: torch.Tensor) -> torch.Tensor:
        return symmetry_ensemble(self.net, photos, self.symmetries)
