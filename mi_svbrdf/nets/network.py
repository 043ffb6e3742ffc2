"""The thesis's networks: the single-image U-Net with a global-features track (ch. 3.1) and the
multi-image network built from shared copies of it (ch. 4.2).

**Single-image net.** A U-Net: ``depth`` stride-2 convolutions (``encoder_features``), then a
decoder that, per level, upsamples (nearest), concatenates the encoder's feature map of that
resolution and applies two stride-1 convolutions; a last level returns to the input resolution
with ``last_features`` features; a 1x1 convolution gives 9 channels and a sigmoid
(``normal xy | diffuse | specular | roughness``, decoded by :func:`mi_svbrdf.core.maps.from_network_output`).
Instance normalisation and leaky ReLU (0.2) everywhere (no normalisation of a 1x1 feature map,
which it would zero), dropout on the ``dropout_levels`` coarsest decoder levels.

**Global-features track** (ch. 3.1.2). Instance normalisation removes each channel's mean, the
very information a U-Net needs to pass global facts (the average colour, the light's fall-off)
across the image. At every stage the removed means are concatenated with the global vector and
mapped by a fully connected layer + SELU to the next global vector; the previous global vector
is re-injected, through another fully connected layer, as per-channel biases after the stage's
convolution, before its nonlinearity (in every convolution: the next instance normalisation
would remove a bias injected only once).

**Multi-image net** (ch. 4.2). One shared-weight copy of the single-image trunk per photo (two
pixel-coordinate channels added to its input; its last layer gives ``last_features`` features
instead of the 9 maps), max-pooling across photos of the feature maps and of the global vectors
(``pooling="mean"``: their mean, the ablation of ch. 4.2.2), then ``fuse_layers`` convolutions to the 9 maps (biased by the pooled global vector). Any
N >= 1 photos, and the output does not depend on their order.

Both nets take *linear* photos ``(B, N, 3, H, W)`` in [0, 1] (N = 1 for the single-image net),
apply the log transform of :func:`mi_svbrdf.core.transforms.network_input`, and return canonical maps
``(B, 10, H, W)``. Inputs whose size is not a multiple of ``2**depth`` are padded by reflection
and the output is cropped back (the nets are fully convolutional).

The presets: ``full`` is the thesis's network (8 levels of 4x4 convolutions, 128-512 features,
~102 M parameters for either net); ``compact`` (width 32, 3x3, 7 levels) is what a CPU
trains.

**Large-scale net** (``kind="large"``, ch. 5): the single-image trunk on a tile of an ambient-lit
photo plus an exemplar encoder whose pooled pyramid is concatenated at every level; it lives in
:mod:`mi_svbrdf.nets.large_scale` (:func:`build_network` returns it) and adds the ``exemplar_*``
fields and the per-preset sizes of :data:`LARGE_PRESETS`.

Examples:
    >>> import torch
    >>> net = build_network(network_config("compact", "multi", encoder_features=(8, 16, 16), last_features=8))
    >>> maps = net(torch.rand(2, 3, 3, 32, 32))
    >>> tuple(maps.shape)
    (2, 10, 32, 32)
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.core.maps import from_network_output
from mi_svbrdf.core.transforms import network_input
from mi_svbrdf.nets.fusion import FusionHead, from_fusion_space, to_fusion_space

KINDS = ("single", "multi", "large")
#: Fields only the large-scale net reads: left out of :meth:`NetConfig.to_dict` for the other kinds, so
#: their checkpoints and manifests written before these fields existed still compare equal (``fusion``
#: likewise is left out when False).
LARGE_FIELDS = ("exemplar_size", "exemplar_features")
#: Poolings across photos of the multi-image net.
POOLINGS = ("max", "mean")
#: Initial output of the sigmoid head (``normal xy | diffuse | specular | roughness``): a flat
#: normal and mid-range maps, about the training distribution's means. From sigmoid(0) = 0.5
#: everywhere (specular 0.5), a short CPU run drifts to the shiny-and-smooth explanation of the
#: flash highlight (high specular, low roughness) and stays there.
HEAD_PRIOR = (0.5, 0.5, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1, 0.5)


@dataclass(frozen=True)
class NetConfig:
    """Architecture of a network; :func:`network_config` builds one from a preset, unknown keys rejected."""

    kind: str = "single"  #: "single" (one photo) or "multi" (any N >= 1 photos, order invariant)
    encoder_features: tuple[int, ...] = (128, 256, 512, 512, 512, 512, 512, 512)  #: features per stride-2 level; depth = len
    last_features: int = 64  #: features of the full-resolution decoder level (what the multi-image net pools)
    kernel_size: int = 4  #: kernel of every convolution except the 1x1 output ones (thesis: 4)
    global_track: bool = True  #: the global-features track of ch. 3.1.2
    dropout: float = 0.5  #: dropout probability on the coarsest decoder levels (training only)
    dropout_levels: int = 3  #: how many of the coarsest decoder levels get dropout
    negative_slope: float = 0.2  #: leaky ReLU slope
    coordinates: bool | None = None  #: add two pixel-coordinate input channels (None: True for "multi")
    fuse_layers: int = 3  #: multi: convolutions after the pooling (the last one outputs the 9 maps)
    pooling: str = "max"  #: multi: pooling across photos, "max" (the thesis, ch. 4.2.2) or "mean" (its ablation)
    normal_scale: float | None = None  #: normal = normalize(s x, s y, 1) (None: 1 single, 3 multi, as the authors)
    resolution: int = 256  #: the resolution the net is trained at (predict resizes inputs to it); large: the tile
    exemplar_size: int = 256  #: large: side of the exemplar patches (exemplars are resized to it)
    exemplar_features: tuple[int, ...] | None = None  #: large: widths of the exemplar encoder (None: encoder_features)
    fusion: bool = False  #: multi: fuse with a frozen single-image net on photo 0 (mi_svbrdf.nets.fusion)

    def __post_init__(self) -> None:
        feats = tuple(self.encoder_features)
        counts = ("last_features", "kernel_size", "fuse_layers", "resolution")
        check_fields([
            ("kind", self.kind in KINDS, f"one of {KINDS}", self.kind),
            ("encoder_features", bool(feats) and all(isinstance(f, int) and f >= 1 for f in feats),
             "a non-empty tuple of ints >= 1", self.encoder_features),
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in counts),
            ("dropout", 0.0 <= self.dropout < 1.0, "a probability in [0, 1)", self.dropout),
            ("pooling", self.pooling in POOLINGS, f"one of {POOLINGS}", self.pooling),
            ("fusion", self.fusion in (False, True) and (not self.fusion or self.kind == "multi"),
             "False, or True for kind 'multi'", self.fusion),
        ], owner="NetConfig")
        object.__setattr__(self, "encoder_features", feats)
        check_fields([("resolution", self.resolution % (2 ** len(feats)) == 0,
                       f"a multiple of 2**depth = {2 ** len(feats)}", self.resolution)], owner="NetConfig")
        if self.exemplar_features is not None:
            ex = tuple(self.exemplar_features)
            ok = len(ex) == len(feats) and all(isinstance(f, int) and f >= 1 for f in ex)
            check_fields([("exemplar_features", ok, f"None or {len(feats)} ints >= 1 (one per encoder level)",
                           self.exemplar_features)], owner="NetConfig")
            object.__setattr__(self, "exemplar_features", ex)
        if self.kind == "large":  # an even kernel halves a 1x1 map to nothing: reach 1x1 at the last level at most
            smallest = 2 ** len(feats) if self.kernel_size % 2 == 0 else 8
            check_fields([("exemplar_size", isinstance(self.exemplar_size, int) and self.exemplar_size >= smallest,
                           f"an int >= {smallest}", self.exemplar_size)], owner="NetConfig")
        if self.coordinates is None:
            object.__setattr__(self, "coordinates", self.kind == "multi")
        if self.normal_scale is None:
            object.__setattr__(self, "normal_scale", 3.0 if self.kind == "multi" else 1.0)

    @property
    def depth(self) -> int:
        """Number of stride-2 levels."""
        return len(self.encoder_features)

    @property
    def exemplar_widths(self) -> tuple[int, ...]:
        """Features per exemplar-encoder level (``exemplar_features``, else ``encoder_features``)."""
        return self.exemplar_features or self.encoder_features

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (tuples as lists); the :data:`LARGE_FIELDS` only for ``kind="large"``."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()
                if (self.kind == "large" or k not in LARGE_FIELDS) and (k != "fusion" or self.fusion)}

    def single_branch(self) -> NetConfig:
        """The single-image net a fused multi-image net (``fusion``) runs on photo 0: this net's widths,
        no coordinate channels, the single-image normal scale."""
        return dataclasses.replace(self, kind="single", coordinates=False, normal_scale=1.0, fusion=False)


#: Architecture presets (any field can be overridden by :func:`network_config`).
PRESETS: dict[str, dict[str, Any]] = {
    # The thesis's network (for GPU users): 8 levels of 4x4 stride-2 convolutions.
    "full": {"encoder_features": (128, 256, 512, 512, 512, 512, 512, 512), "last_features": 64,
             "kernel_size": 4, "resolution": 256},
    # Trainable on a 2-core CPU: width 32, 3x3 convolutions, 7 levels (a 2x2 bottleneck at 256^2).
    "compact": {"encoder_features": (32, 64, 128, 256, 256, 256, 256), "last_features": 32,
                "kernel_size": 3, "resolution": 256},
}


#: What ``kind="large"`` changes in each preset. ``full``: the thesis's sizes (tile 512, exemplars 256 cut
#: from 2048^2 materials). ``compact``: every size divided by 4 (tile 128, exemplars 64, materials 512^2:
#: :mod:`mi_svbrdf.data.large_scale`), the image trunk the compact single-image net's (a warm start copies it)
#: and a narrow exemplar encoder, so that the weights stay near the compact nets' ~18 MB (fp16, compressed).
LARGE_PRESETS: dict[str, dict[str, Any]] = {
    "full": {"resolution": 512, "exemplar_size": 256},
    "compact": {"resolution": 128, "exemplar_size": 64, "exemplar_features": (16, 32, 32, 32, 32, 32, 32)},
}


def network_config(preset: str = "compact", kind: str = "single", **overrides: Any) -> NetConfig:
    """A preset's :class:`NetConfig` for ``kind`` with ``overrides``; unknown keys raise ``ValueError``."""
    if preset not in PRESETS:
        raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {preset!r}")
    extra = dict(LARGE_PRESETS[preset]) if kind == "large" else {}
    if "encoder_features" in overrides:  # the preset's exemplar widths fit its own encoder; else the encoder's widths
        extra.pop("exemplar_features", None)
    return config_from_dict({**PRESETS[preset], **extra, "kind": kind, **overrides})


def config_from_dict(data: dict[str, Any]) -> NetConfig:
    """Build a :class:`NetConfig` from a dict (e.g. JSON); unknown keys raise ``ValueError``."""
    return from_dict(NetConfig, {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


class _Stage(nn.Module):
    """Convolution, instance norm (channel means go to the global track), global bias, leaky ReLU."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, slope: float,
                 global_in: int | None, global_out: int | None) -> None:
        super().__init__()
        pad: int | str = (kernel - 1) // 2 if stride == 2 else "same"
        if stride == 2 and kernel % 2 == 0:
            pad = kernel // 2 - 1
        self.conv = nn.Conv2d(cin, cout, kernel, stride=stride, padding=pad)
        self.norm = nn.InstanceNorm2d(cout, affine=True)
        self.slope = slope
        self.inject = nn.Linear(global_in, cout) if global_in else None
        self.update = nn.Linear(cout + (global_in or 0), global_out) if global_out else None
        for fc in (self.inject, self.update):  # LeCun normal: SELU's self-normalising init
            if fc is not None:
                nn.init.normal_(fc.weight, std=fc.in_features ** -0.5)
                nn.init.zeros_(fc.bias)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        x = self.conv(x)
        mean = x.mean(dim=(2, 3))
        if x.shape[2] * x.shape[3] > 1:
            x = self.norm(x)
        if self.inject is not None and g is not None:
            x = x + self.inject(g)[:, :, None, None]
        if self.update is not None:
            g = F.selu(self.update(mean if g is None else torch.cat([mean, g], dim=1)))
        return F.leaky_relu(x, self.slope), g


class _Trunk(nn.Module):
    """The U-Net up to its last full-resolution features: ``(B, C, H, W) -> ((B, F, H, W), (B, G))``.

    ``extra_channels`` (one count per encoder level, default none): :meth:`forward` then takes one
    feature map per level, at that level's resolution, and concatenates it with the level's
    features where the decoder reads them: level ``l < depth - 1`` beside its skip, the deepest
    level beside the bottleneck (after its upsampling: the same as before it, as upsampling is
    nearest). The extra channels come last in every decoder input, so weights of a trunk without
    them are its weights with zero columns appended (:func:`mi_svbrdf.nets.train.warm_start`).
    """

    def __init__(self, cfg: NetConfig, in_channels: int, extra_channels: tuple[int, ...] | None = None) -> None:
        super().__init__()
        k, s, feats = cfg.kernel_size, cfg.negative_slope, cfg.encoder_features
        gl = cfg.global_track
        extra = tuple(extra_channels) if extra_channels else (0,) * len(feats)
        if len(extra) != len(feats):
            raise ValueError(f"extra_channels: expected {len(feats)} counts (one per level), got {extra}")
        self.extra_channels = extra
        self.encoder = nn.ModuleList()
        prev, g_prev = in_channels, None
        for f in feats:
            self.encoder.append(_Stage(prev, f, k, 2, s, g_prev, f if gl else None))
            prev, g_prev = f, (f if gl else None)
        # Decoder level i returns to the resolution of encoder level i - 1 (level 0: the input's).
        self.decoder = nn.ModuleList()
        self.dropout = []
        outs = [cfg.last_features, *feats[:-1]]
        for i in reversed(range(len(feats))):
            skip = (feats[i - 1] + extra[i - 1] if i > 0 else 0) + (extra[i] if i == len(feats) - 1 else 0)
            cout = outs[i]
            first = _Stage(prev + skip, cout, k, 1, s, g_prev, cout if gl else None)
            second = _Stage(cout, cout, k, 1, s, cout if gl else None, None)
            self.decoder.append(nn.ModuleList([first, second]))
            self.dropout.append(len(self.decoder) <= cfg.dropout_levels and cfg.dropout > 0)
            prev, g_prev = cout, (cout if gl else None)
        self.p = cfg.dropout
        self.features, self.global_features = prev, g_prev

    def forward(self, x: torch.Tensor, extra: list[torch.Tensor] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor | None]:
        skips, g = [], None
        for stage in self.encoder:
            x, g = stage(x, g)
            skips.append(x)
        if extra is not None:  # beside each skip; the deepest level's after the bottleneck's upsampling
            skips = [torch.cat([f, e], dim=1) for f, e in zip(skips[:-1], extra[:-1])] + skips[-1:]
            extra = [F.interpolate(extra[-1], scale_factor=2.0, mode="nearest")]
        x = skips.pop()
        for (first, second), drop in zip(self.decoder, self.dropout):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            if skips:
                x = torch.cat([x, skips.pop()], dim=1)
            if extra:
                x = torch.cat([x, extra.pop()], dim=1)
            x, g = first(x, g)
            x, _ = second(x, g)
            if drop:
                x = F.dropout(x, self.p, self.training)
        return x, g


class SVBRDFNet(nn.Module):
    """The single-image or multi-image network of a :class:`NetConfig`: photos in, maps out.

    Args:
        config: the architecture.

    Shape:
        - Input: ``(B, N, 3, H, W)`` linear photos in [0, 1] (``N = 1`` for ``kind="single"``;
          a ``(B, 3, H, W)`` tensor is read as ``N = 1``).
        - Output: ``(B, 10, H, W)`` canonical maps.
    """

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        if config.kind not in ("single", "multi"):
            raise ValueError(f"config.kind: expected 'single' or 'multi' for SVBRDFNet, got {config.kind!r} "
                             "(build_network makes the large-scale net)")
        self.config = config
        in_channels = 3 + (2 if config.coordinates else 0)
        self.trunk = _Trunk(config, in_channels)
        f, gdim = self.trunk.features, self.trunk.global_features
        if config.kind == "single":
            self.head = nn.Conv2d(f, 9, 1)
        else:
            k, s = config.kernel_size, config.negative_slope
            self.fuse = nn.ModuleList([_Stage(f, f, k, 1, s, gdim, None) for _ in range(config.fuse_layers - 1)])
            self.head = nn.Conv2d(f, 9, 1) if config.fuse_layers == 1 else nn.Conv2d(f, 9, k, padding="same")
        with torch.no_grad():  # start at the prior's mean maps, not at sigmoid(0) = 0.5 everywhere
            self.head.bias.copy_(torch.logit(torch.tensor(HEAD_PRIOR)))
        if config.fusion:  # the frozen single-image net on photo 0 and the head fusing both (nets.fusion)
            self.single = SVBRDFNet(config.single_branch())
            self.single.requires_grad_(False)
            self.fusion = FusionHead(self.single.trunk.features, f, hidden=f, kernel=k, slope=s)

    def train(self, mode: bool = True) -> SVBRDFNet:
        """As :meth:`torch.nn.Module.train`, but a submodule whose parameters are all frozen (a fused net's
        single-image branch; what training's ``freeze`` holds fixed) stays in eval mode: no dropout."""
        super().train(mode)
        for child in self.children():
            params = list(child.parameters())
            if params and not any(p.requires_grad for p in params):
                child.eval()
        return self

    def raw(self, photos: torch.Tensor) -> torch.Tensor:
        """The 9-channel sigmoid output ``(B, 9, H, W)`` (``normal xy | diffuse | specular | roughness``);
        a fused net's is its multi-image branch's."""
        return self._run(photos)[0]

    def _run(self, photos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(sigmoid output (B, 9, H, W), last features (B, F, H, W))``; multi: the pooled, fused features."""
        photos = self._check(photos)
        b, n, _, h, w = photos.shape
        unit = 2 ** self.config.depth
        ph, pw = -h % unit, -w % unit
        x = network_input(photos.reshape(b * n, 3, h, w).clamp(0.0, 1.0))
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="reflect")
        if self.config.coordinates:
            x = torch.cat([x, _coordinates(x, h, w)], dim=1)
        feats, g = self.trunk(x)
        if self.config.kind == "single":
            out = self.head(feats)
        else:  # (b, n, F, H, W) -> pooled across photos
            pool = (lambda t: t.amax(dim=1)) if self.config.pooling == "max" else (lambda t: t.mean(dim=1))
            feats = pool(feats.reshape(b, n, *feats.shape[1:]))
            g = pool(g.reshape(b, n, -1)) if g is not None else None
            for stage in self.fuse:
                feats, _ = stage(feats, g)
            out = self.head(feats)
        return torch.sigmoid(out[:, :, :h, :w].float()), feats[:, :, :h, :w]

    def decode(self, raw: torch.Tensor) -> torch.Tensor:
        """Canonical maps ``(B, 10, H, W)`` of a 9-channel sigmoid output of this net."""
        return from_network_output(raw, normal_scale=float(self.config.normal_scale), activation="sigmoid")

    def forward(self, photos: torch.Tensor) -> torch.Tensor:
        if not self.config.fusion:
            return self.decode(self.raw(photos))
        return self.fused_and_branch(photos)[0]

    def fused_and_branch(self, photos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A fused net's maps and its multi-image branch's own (before the fusion), from one pass of each net."""
        if not self.config.fusion:
            raise ValueError("fused_and_branch: expected a fused multi-image net (config.fusion), got an unfused one")
        photos = self._check(photos)  # (B, 3, H, W) -> (B, 1, 3, H, W) before photo 0 is taken
        raw_m, f_m = self._run(photos)
        raw_s, f_s = self.single._run(photos[:, :1])
        multi = self.decode(raw_m)
        u_s, u_m = to_fusion_space(self.single.decode(raw_s)), to_fusion_space(multi)
        return from_fusion_space(self.fusion(f_s, f_m, u_s, u_m)), multi

    def _check(self, photos: torch.Tensor) -> torch.Tensor:
        if photos.dim() == 4:
            photos = photos[:, None]
        if photos.dim() != 5 or photos.shape[2] != 3 or photos.shape[1] < 1:
            raise ValueError(f"photos: expected shape (B, N, 3, H, W) or (B, 3, H, W), got {tuple(photos.shape)}")
        if self.config.kind == "single" and photos.shape[1] != 1:
            raise ValueError(f"photos: the single-image net expected N = 1 photo, got N = {photos.shape[1]}")
        check_photo_values(photos, "photos", self.config.depth)
        return photos


def check_photo_values(photo: torch.Tensor, name: str, depth: int) -> None:
    """The checks every net makes on its input photo(s) ``(..., H, W)`` beyond the layout: large enough for
    ``depth`` halvings of the U-Net, and finite. Raises ``ValueError`` naming ``name``."""
    if min(photo.shape[-2:]) < 2 ** (depth - 1) + 1:
        raise ValueError(f"{name}: expected H, W > {2 ** (depth - 1)} for a net of depth "
                         f"{depth}, got {tuple(photo.shape[-2:])}")
    # (meta tensors have shapes but no values: shape-only runs skip the value check)
    if photo.device.type != "meta" and not torch.isfinite(photo).all():
        raise ValueError(f"{name}: expected finite values, got NaN or Inf")


def _coordinates(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Pixel-centre coordinates ``(B, 2, H', W')`` (x right, y up, in [-1, 1] over the unpadded image)."""
    hp, wp = x.shape[-2:]
    xs = (torch.arange(wp, device=x.device, dtype=x.dtype) * 2 + 1) / w - 1
    ys = 1 - (torch.arange(hp, device=x.device, dtype=x.dtype) * 2 + 1) / h
    grid = torch.stack([xs[None, :].expand(hp, wp), ys[:, None].expand(hp, wp)])
    return grid[None].expand(x.shape[0], -1, -1, -1)


#: The classes of the kinds defined in modules built on this one (``kind -> class``):
#: :mod:`mi_svbrdf.nets.large_scale` registers ``"large"`` when imported, which the package
#: ``mi_svbrdf.nets`` does (this module cannot import it: it would be an import cycle).
BUILDERS: dict[str, Callable[[NetConfig], nn.Module]] = {}


def build_network(config: NetConfig) -> nn.Module:
    """The network of ``config``: an :class:`SVBRDFNet` (single, multi) or a
    :class:`~mi_svbrdf.nets.large_scale.LargeScaleNet` (large, from :data:`BUILDERS`)."""
    if config.kind in BUILDERS:
        return BUILDERS[config.kind](config)
    return SVBRDFNet(config)


def parameter_count(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
