"""The by-example large-scale network (thesis ch. 5.1.2): one tile of an ambient-lit photo of a large
surface plus 0-3 exemplar SVBRDF patches of it (or of a similar material) in, the tile's maps out.

**Image path.** The single-image U-Net of :mod:`mi_svbrdf.nets.network` (the same ``_Trunk``, its
global-features track and the same 9-channel sigmoid head) on the tile, log-encoded as the other nets'
photos. Its tensors have the single-image net's names and shapes but for the exemplar columns, so the
trunk and head start from the bundled single-image net (``init: "bundled:single"``, see
:func:`mi_svbrdf.nets.train.warm_start`): with the exemplar columns at zero it *is* that net.

**Exemplar path.** An exemplar is 13 channels (:func:`exemplar_input`: its 10 maps and a render under a
distant light). One shared-weight encoder (the trunk's stride-2 stages, with their own global track,
``config.exemplar_widths`` features per level) turns each exemplar into a pyramid of ``depth`` feature
maps; the pyramids of all exemplars are **max-pooled** across exemplars (any number, order-independent)
by :meth:`LargeScaleNet.exemplar_features`, once per photo. The encoder reads normals as they are,
roughness as ``2 r - 1`` and the albedos and the render through the photos' log encoding
(:func:`mi_svbrdf.core.transforms.network_input`).

**Where they meet.** Pooled level ``l`` is **resized bilinearly** (antialiased when it shrinks) to the
spatial size of the image encoder's level ``l`` and concatenated with it where the decoder reads it (the
skip of level ``l``; the deepest level beside the bottleneck). Why a resize, not a spatial alignment:
an exemplar is not registered with the tile (another place of the wall, possibly another texel
density), so its features carry appearance statistics, not positions; in training the patches are cut
at random positions, so the decoder cannot learn to read them as aligned, and the resize only makes the
sizes agree (tiles of any size reuse one pyramid).

**No exemplar** (``E = 0`` or ``exemplars=None``: the Fig. 5.7 baseline): the exemplar channels are
zeros, which the training data shows with probability ``no_exemplar``
(:class:`mi_svbrdf.data.large_scale.LargeScaleConfig`).

Examples:
    >>> import torch
    >>> from mi_svbrdf.core.maps import constant_maps
    >>> from mi_svbrdf.nets.network import build_network, network_config
    >>> net = build_network(network_config("compact", "large", encoder_features=(8, 16, 16), last_features=8,
    ...                                    exemplar_features=(4, 8, 8), resolution=32, exemplar_size=16)).eval()
    >>> ex = exemplar_input(constant_maps(2, 16, 16, roughness=0.3))[None]   # (B=1, E=2, 13, 16, 16)
    >>> pyramid = net.exemplar_features(ex)                                  # once per photo
    >>> tuple(net(torch.rand(1, 3, 32, 48), features=pyramid).shape)         # any tile size
    (1, 10, 32, 48)
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.core.maps import from_network_output
from mi_svbrdf.core.transforms import network_input
from mi_svbrdf.data.large_scale import EXEMPLAR_CHANNELS, exemplar_input
from mi_svbrdf.nets.network import BUILDERS, HEAD_PRIOR, NetConfig, _coordinates, _Stage, _Trunk, check_photo_values

__all__ = ["LargeScaleNet", "exemplar_input", "min_exemplar_size"]


def min_exemplar_size(config: NetConfig) -> int:
    """Smallest exemplar side the encoder takes: ``2**depth`` with even kernels (a stride-2 4x4 convolution
    of a 1x1 map is empty), else 8."""
    return 2 ** config.depth if config.kernel_size % 2 == 0 else 8


class _ExemplarEncoder(nn.Module):
    """The trunk's stride-2 stages on a 13-channel exemplar: ``(N, 13, h, w) -> [(N, C_l, h_l, w_l)] * depth``."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        k, s, gl = cfg.kernel_size, cfg.negative_slope, cfg.global_track
        self.stages = nn.ModuleList()
        prev, g_prev = EXEMPLAR_CHANNELS, None
        widths = cfg.exemplar_widths
        for level, f in enumerate(widths):  # the last level's global vector would feed nothing: no update layer
            self.stages.append(_Stage(prev, f, k, 2, s, g_prev, f if gl and level < len(widths) - 1 else None))
            prev, g_prev = f, (f if gl else None)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        # what the encoder reads: normals as they are, roughness 2r - 1, albedos and render log-encoded
        x = torch.cat([x[:, 0:3], network_input(x[:, 3:6].clamp(0.0, 1.0)), 2.0 * x[:, 6:7] - 1.0,
                       network_input(x[:, 7:13].clamp(0.0, 1.0))], dim=1)
        levels, g = [], None
        for stage in self.stages:
            if x.shape[-2] * x.shape[-1] == 1 and torch.is_autocast_enabled(x.device.type):
                # A stride-2 stage over a 1x1 input (the deepest levels of a small exemplar) in float32:
                # under CPU bf16 autocast its convolution's weight gradient came back NaN now and then
                # (1 of 12 steps, torch 2.13, oneDNN; never in float32), which stopped the first training
                # run at step 1. At 1x1 the cost is nil.
                with torch.autocast(x.device.type, enabled=False):
                    x, g = stage(x.float(), None if g is None else g.float())
            else:
                x, g = stage(x, g)
            levels.append(x)
        return levels


class LargeScaleNet(nn.Module):
    """The large-scale network of a :class:`~mi_svbrdf.nets.network.NetConfig` with ``kind="large"``.

    Args:
        config: the architecture (``resolution``: the tile it is trained at; ``exemplar_size``: the
            exemplar side; ``exemplar_features``: the exemplar encoder's widths).

    Shape:
        - photo: ``(B, 3, H, W)`` linear in [0, 1], any ``H, W > 2**(depth - 1)`` (padded by reflection to a
          multiple of ``2**depth`` and cropped back).
        - exemplars: ``(B, E, 13, h, w)`` from :func:`exemplar_input` (``B`` = the photo's or 1; ``E >= 0``).
        - output: ``(B, 10, H, W)`` canonical maps.
    """

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        if config.kind != "large":
            raise ValueError(f"config.kind: expected 'large' for LargeScaleNet, got {config.kind!r}")
        self.config = config
        self.exemplar_encoder = _ExemplarEncoder(config)
        self.trunk = _Trunk(config, 3 + (2 if config.coordinates else 0), extra_channels=config.exemplar_widths)
        self.head = nn.Conv2d(self.trunk.features, 9, 1)
        with torch.no_grad():  # the single-image net's start (and names: a warm start copies the head too)
            self.head.bias.copy_(torch.logit(torch.tensor(HEAD_PRIOR)))

    def exemplar_features(self, exemplars: torch.Tensor | None) -> list[torch.Tensor] | None:
        """The exemplars' pooled pyramid: ``depth`` maps ``(B, C_l, h_l, w_l)``, max over the E exemplars.

        Computed once per photo and passed to :meth:`forward` as ``features`` for every tile. None for
        ``exemplars=None`` or ``E = 0`` (the no-exemplar baseline).

        Raises:
            ValueError: not ``(B, E, 13, h, w)``, exemplars smaller than :func:`min_exemplar_size`, NaN/Inf.
        """
        if exemplars is None:
            return None
        if not isinstance(exemplars, torch.Tensor) or exemplars.dim() != 5 or exemplars.shape[2] != EXEMPLAR_CHANNELS:
            shape = tuple(exemplars.shape) if isinstance(exemplars, torch.Tensor) else type(exemplars).__name__
            raise ValueError(f"exemplars: expected shape (B, E, {EXEMPLAR_CHANNELS}, h, w) from exemplar_input "
                             f"(maps + render), got {shape}")
        b, e, c, h, w = exemplars.shape
        if e == 0:
            return None
        smallest = min_exemplar_size(self.config)
        if min(h, w) < smallest:
            raise ValueError(f"exemplars: expected h, w >= {smallest} for this net, got {(h, w)} "
                             f"(resize them to exemplar_size = {self.config.exemplar_size})")
        if exemplars.device.type != "meta" and not torch.isfinite(exemplars).all():
            raise ValueError("exemplars: expected finite values, got NaN or Inf")
        levels = self.exemplar_encoder(exemplars.reshape(b * e, c, h, w))
        return [f.reshape(b, e, *f.shape[1:]).amax(dim=1) for f in levels]

    def forward(self, photo: torch.Tensor, exemplars: torch.Tensor | None = None, *,
                features: list[torch.Tensor] | None = None) -> torch.Tensor:
        """Maps ``(B, 10, H, W)`` of ``photo`` guided by ``exemplars`` (or their pooled ``features``, which
        take precedence: :meth:`exemplar_features` of the same exemplars gives the same output)."""
        photo = self._check_photo(photo)
        name = "features" if features is not None else "exemplars"
        if features is None:
            features = self.exemplar_features(exemplars)
        b, _, h, w = photo.shape
        self._check_features(features, b, name)
        unit = 2 ** self.config.depth
        ph, pw = -h % unit, -w % unit
        x = network_input(photo.clamp(0.0, 1.0))
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="reflect")
        if self.config.coordinates:
            x = torch.cat([x, _coordinates(x, h, w)], dim=1)
        sizes = [(x.shape[2] >> (level + 1), x.shape[3] >> (level + 1)) for level in range(self.config.depth)]
        if features is None:
            extra = [x.new_zeros(b, c, *size) for c, size in zip(self.config.exemplar_widths, sizes)]
        else:
            extra = [_resize(f, size).expand(b, -1, -1, -1) for f, size in zip(features, sizes)]
        feats, _ = self.trunk(x, extra)
        out = self.head(feats)[:, :, :h, :w]
        out = out if out.dtype == torch.float64 else out.float()  # float32 out of autocast; float64 kept (gradcheck)
        return from_network_output(torch.sigmoid(out), normal_scale=float(self.config.normal_scale),
                                   activation="sigmoid")

    def _check_photo(self, photo: torch.Tensor) -> torch.Tensor:
        if not isinstance(photo, torch.Tensor) or photo.dim() != 4 or photo.shape[1] != 3:
            shape = tuple(photo.shape) if isinstance(photo, torch.Tensor) else type(photo).__name__
            raise ValueError(f"photo: expected shape (B, 3, H, W) (one linear ambient-lit photo or tile), got {shape}")
        check_photo_values(photo, "photo", self.config.depth)
        return photo

    def _check_features(self, features: list[torch.Tensor] | None, batch: int, name: str) -> None:
        if features is None:
            return
        widths = self.config.exemplar_widths
        if (not isinstance(features, (list, tuple)) or len(features) != len(widths)
                or not all(isinstance(f, torch.Tensor) and f.dim() == 4 for f in features)):
            raise ValueError(f"features: expected a list of {len(widths)} tensors (B, C_l, h_l, w_l) from "
                             f"exemplar_features, got {_describe(features)}")
        got = [int(f.shape[1]) for f in features]
        if got != list(widths):
            raise ValueError(f"features: expected channels {list(widths)} per level, got {got}")
        batches = {int(f.shape[0]) for f in features}
        if len(batches) != 1 or batches.pop() not in (1, batch):
            raise ValueError(f"{name}: expected the photo's batch {batch} (or 1), "
                             f"got {sorted({int(f.shape[0]) for f in features})}")


def _resize(f: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Bilinear resize of a pooled exemplar level to an image level's size (antialiased when shrinking)."""
    if tuple(f.shape[-2:]) == size:
        return f
    shrink = f.shape[-2] > size[0] or f.shape[-1] > size[1]
    return F.interpolate(f, size=size, mode="bilinear", align_corners=False, antialias=shrink)


def _describe(value: object) -> str:
    if isinstance(value, (list, tuple)):
        items = [tuple(v.shape) if isinstance(v, torch.Tensor) else type(v).__name__ for v in value]
        return f"{type(value).__name__} of {items}"
    return type(value).__name__


BUILDERS["large"] = LargeScaleNet  # build_network (and so the weights loader and train) make it for kind "large"
