"""The fusion of the single-image and multi-image nets: more photos never start from worse maps.

The multi-image net alone, given the fronto-parallel flash photo and others, can be worse than the
single-image net given that photo alone (it spreads its capacity over any N, and max-pooling
drops what only the flash photo shows). The *fused* multi-image net (``NetConfig.fusion``) runs
both: the single-image net on photo 0 and the multi-image net on all N photos, and a small head
blends their maps per texel:

    u = u_single + g * (u_multi - u_single) + r

in an unbounded space ``u`` (:func:`to_fusion_space`: the normal's slopes ``x/z, y/z`` and the
logits of the albedos and the roughness), where the gate ``g`` and the residual ``r`` (9 channels
each) come from two convolutions on both nets' last features and both nets' maps. The last
convolution starts at zero, so the untrained fused net returns the single-image net's maps
exactly: training on simulated captures can only move it where the other photos help, on average.
``g = 1`` is the multi-image net's maps; ``g`` outside ``[0, 1]`` and ``r`` let it go beyond both.

Examples:
    >>> import torch
    >>> maps = torch.rand(1, 10, 8, 8)
    >>> maps[:, :3] = torch.nn.functional.normalize(maps[:, :3] + torch.tensor([0., 0., 1.])[:, None, None], dim=1)
    >>> back = from_fusion_space(to_fusion_space(maps))
    >>> bool(torch.allclose(back, maps, atol=1e-5))
    True
"""
from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.core.maps import normalize_normals, symmetry_image, symmetry_maps

#: Values of the [0, 1] maps are clamped to [EPS, 1 - EPS] before their logit (the nets' sigmoids stay inside).
EPS = 1e-6
#: Channels of the fusion space: normal slopes (2), diffuse (3), specular (3), roughness (1).
CHANNELS = 9
#: The maps a fused net makes from one pass of each of its nets (:func:`net_candidates`), simplest first.
NET_CANDIDATES = ("single", "multi", "fused")


def to_fusion_space(maps: torch.Tensor) -> torch.Tensor:
    """Canonical maps ``(B, 10, H, W)`` -> ``(B, 9, H, W)``: ``x/z, y/z`` of the normal, then the logits
    of diffuse, specular and roughness (the canonical order ``normal | diffuse | roughness | specular``
    becomes ``slopes | diffuse | specular | roughness``, the networks' output order)."""
    n = maps[:, 0:3]
    slopes = n[:, 0:2] / n[:, 2:3].clamp_min(1e-3)
    rest = torch.cat([maps[:, 3:6], maps[:, 7:10], maps[:, 6:7]], dim=1).clamp(EPS, 1.0 - EPS)
    return torch.cat([slopes, torch.logit(rest)], dim=1)


def from_fusion_space(u: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_fusion_space`: ``(B, 9, H, W)`` -> canonical ``(B, 10, H, W)`` maps
    (the normal ``normalize(x, y, 1)``, the other maps the sigmoid of their logits)."""
    n = torch.cat([u[:, 0:2], torch.ones_like(u[:, :1])], dim=1)
    n = n / n.square().sum(dim=1, keepdim=True).sqrt()
    rest = torch.sigmoid(u[:, 2:])
    return torch.cat([n, rest[:, 0:3], rest[:, 6:7], rest[:, 3:6]], dim=1)


class FusionHead(nn.Module):
    """Gate and residual of the fusion (see the module docstring), zero at initialisation.

    Args:
        single_features: channels of the single-image net's last feature map.
        multi_features: channels of the multi-image net's pooled (fused) feature map.
        hidden: channels of the hidden convolution.
        kernel: kernel size of both convolutions.
        slope: leaky ReLU slope.

    Shape:
        - ``forward(f_single, f_multi, u_single, u_multi)``: features ``(B, Fs, H, W)``, ``(B, Fm, H, W)``
          and both nets' maps in the fusion space ``(B, 9, H, W)``.
        - Output: the fused maps in the fusion space ``(B, 9, H, W)``.
    """

    def __init__(self, single_features: int, multi_features: int, hidden: int = 32, kernel: int = 3,
                 slope: float = 0.2) -> None:
        super().__init__()
        cin = single_features + multi_features + 3 * CHANNELS
        self.hidden = nn.Conv2d(cin, hidden, kernel, padding="same")
        self.out = nn.Conv2d(hidden, 2 * CHANNELS, kernel, padding="same")
        self.slope = slope
        nn.init.zeros_(self.out.weight)  # the untrained fusion is the single-image net
        nn.init.zeros_(self.out.bias)

    def forward(self, f_single: torch.Tensor, f_multi: torch.Tensor, u_single: torch.Tensor,
                u_multi: torch.Tensor) -> torch.Tensor:
        diff = u_multi - u_single
        x = torch.cat([f_single, f_multi, u_single, u_multi, diff], dim=1)
        gate, residual = self.out(F.leaky_relu(self.hidden(x), self.slope)).to(u_single.dtype).chunk(2, dim=1)
        return u_single + gate * diff + residual


def net_candidates(net: Any, photos: torch.Tensor, symmetries: int = 1) -> dict[str, torch.Tensor]:
    """The three maps a fused net makes of ``photos``, each as its symmetry ensemble, from one pass of each net
    per symmetry: ``single`` (the single-image branch on photo 0), ``multi`` (the multi-image branch on all N,
    before the fusion) and ``fused`` (the net's output).

    Args:
        net: a fused multi-image net (:class:`mi_svbrdf.nets.network.SVBRDFNet` with ``config.fusion``).
        photos: ``(B, N, 3, H, W)`` linear photos, photo 0 the fronto-parallel flash photo.
        symmetries: the symmetry ensemble's size, 1 to 8 (1: the nets alone).

    Returns:
        ``{"single": (B, 10, H, W), "multi": ..., "fused": ...}``, normals of unit length; ``fused`` is what
        :func:`mi_svbrdf.nets.ensemble.symmetry_ensemble` of ``net`` returns.

    Raises:
        ValueError: an unfused net, or photos of the wrong shape.

    Examples:
        >>> from mi_svbrdf.nets.network import build_network, network_config
        >>> cfg = network_config("compact", kind="multi", fusion=True, encoder_features=(8, 8, 8), last_features=8)
        >>> maps = net_candidates(build_network(cfg).eval(), torch.rand(1, 2, 3, 32, 32))
        >>> sorted(maps), tuple(maps["fused"].shape)
        (['fused', 'multi', 'single'], (1, 10, 32, 32))
    """
    if not getattr(getattr(net, "config", None), "fusion", False):
        raise ValueError("net: expected a fused multi-image net (config.fusion), got an unfused one")
    if not 1 <= int(symmetries) <= 8:
        raise ValueError(f"symmetries: expected an int in [1, 8], got {symmetries!r}")
    total: dict[str, torch.Tensor] = {}
    with torch.no_grad():
        for k in range(int(symmetries)):
            x = net._check(symmetry_image(photos, k))
            raw_m, f_m = net._run(x)
            raw_s, f_s = net.single._run(x[:, :1])
            multi, single = net.decode(raw_m), net.single.decode(raw_s)
            fused = from_fusion_space(net.fusion(f_s, f_m, to_fusion_space(single), to_fusion_space(multi)))
            for name, maps in zip(NET_CANDIDATES, (single, multi, fused)):
                maps = symmetry_maps(maps.float(), k, inverse=True)
                total[name] = maps if name not in total else total[name] + maps
    if int(symmetries) == 1:
        return total
    return {name: normalize_normals(maps / int(symmetries)) for name, maps in total.items()}
