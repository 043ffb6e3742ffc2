"""The rendering loss (thesis ch. 3.1.3, appendix A.1) and the ch. 4 mixed loss.

Prediction and ground truth are rendered under the same K configurations per sample
(:mod:`mi_svbrdf.core.configurations`) with the loss's light model
``L = f * pi * I * c(n.wl) / max(wl.z, 1e-3)`` (no distance fall-off, also for the near-field
configurations, as the authors' code) and compared as
``mean |log(R_gt + eps) - log(R_pred + eps)|`` over batch, configurations, pixels and channels.

Two presets reproduce the authors' public code:

======  =========  =====  ======  ================
preset  intensity  eps    r1_max  include_diffuse
======  =========  =====  ======  ================
2018    1.0        0.01   0.95    True
2019    1.5        0.1    0.90    True
======  =========  =====  ======  ================

On the ``"mitsuba"`` backend the renderings and the log-L1 are one fused Dr.Jit kernel; the
``"torch"`` backend renders with the plain-PyTorch reference.

Output model (thesis ch. 6.1.1): the prediction is rendered with ``distribution`` and the ground
truth with ``target_distribution`` (None: the same). The loss only compares renderings, so a
net or a fit can output one microfacet model (e.g. ``"beckmann"``) while its ground truth was
made with another (``"ggx"``, the capture simulator's): the loss of identical maps is then not 0.

Examples:
    >>> import torch, mi_svbrdf
    >>> pred = mi_svbrdf.core.maps.constant_maps(2, 16, 16, roughness=0.3).requires_grad_()
    >>> gt = mi_svbrdf.core.maps.constant_maps(2, 16, 16, roughness=0.6)
    >>> loss = mi_svbrdf.rendering_loss(pred, gt, generator=torch.Generator().manual_seed(0))
    >>> loss.backward()
    >>> bool(loss > 0), bool(pred.grad[:, 6].abs().sum() > 0)
    (True, True)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import nn

from mi_svbrdf.core import maps as M
from mi_svbrdf.core import render_drjit
from mi_svbrdf.core.configurations import Configurations, sample_configurations
from mi_svbrdf.core.render import BACKENDS, Backend, render
from mi_svbrdf.core.ssim import ms_ssim
from mi_svbrdf.core.transforms import log_encode
from mi_svbrdf.plugins.model import DISTRIBUTIONS


@dataclass(frozen=True)
class LossPreset:
    """Settings of the rendering loss."""

    intensity: float = 1.0  #: light intensity I of every configuration
    eps: float = 0.01  #: epsilon of log(R + eps)
    r1_max: float = 0.95  #: upper bound of the direction sampler's r1 (1 - eps_hi)
    n_diffuse: int = 3  #: far-field configurations per sample
    n_specular: int = 6  #: near-field mirror configurations per sample
    include_diffuse: bool = True  #: diffuse term in every rendering


#: The authors' two public configurations.
PRESETS: dict[str, LossPreset] = {
    "2018": LossPreset(intensity=1.0, eps=0.01, r1_max=0.95),
    "2019": LossPreset(intensity=1.5, eps=0.1, r1_max=0.90),
}


def resolve_preset(preset: str | LossPreset, **overrides: object) -> LossPreset:
    """A preset by name (or as given) with the non-None overrides applied; unknown names rejected."""
    if isinstance(preset, str):
        if preset not in PRESETS:
            raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {preset!r}")
        preset = PRESETS[preset]
    return replace(preset, **{k: v for k, v in overrides.items() if v is not None})


def resolve_distributions(distribution: str, target_distribution: str | None) -> tuple[str, str]:
    """``(pred, target)`` microfacet models: ``target_distribution`` None means ``distribution``; both checked.

    Examples:
        >>> resolve_distributions("beckmann", None), resolve_distributions("beckmann", "ggx")
        (('beckmann', 'beckmann'), ('beckmann', 'ggx'))
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if target_distribution is None:
        return distribution, distribution
    if target_distribution not in DISTRIBUTIONS:
        raise ValueError(f"target_distribution: expected None or one of {DISTRIBUTIONS}, got {target_distribution!r}")
    return distribution, target_distribution


def _check_pair(pred: torch.Tensor, target: torch.Tensor) -> None:
    M.check_maps(pred, "pred")
    M.check_maps(target, "target")
    if pred.shape != target.shape:
        raise ValueError(f"target: expected the shape of pred {tuple(pred.shape)}, got {tuple(target.shape)}")


def rendering_loss(pred: torch.Tensor, target: torch.Tensor, *,
                   preset: str | LossPreset = "2018",
                   configurations: Configurations | None = None,
                   generator: torch.Generator | None = None,
                   n_diffuse: int | None = None, n_specular: int | None = None,
                   eps: float | None = None, intensity: float | None = None,
                   include_diffuse: bool | None = None,
                   distribution: str = "ggx",
                   target_distribution: str | None = None,
                   backend: Backend = "mitsuba") -> torch.Tensor:
    """Rendering loss between predicted and ground-truth maps.

    Args:
        pred: ``(B, 10, H, W)`` predicted maps (gradients flow to it).
        target: ``(B, 10, H, W)`` ground-truth maps (treated as constant).
        preset: ``"2018"``, ``"2019"`` or a :class:`LossPreset`; the keyword arguments below
            override its fields when given.
        configurations: explicit configurations ``(B, K, 4)``; drawn with ``generator`` if None.
        generator: seeded ``torch.Generator`` for the configurations.
        n_diffuse: override of the preset's far-field configuration count.
        n_specular: override of the preset's near-field configuration count.
        eps: override of the log epsilon.
        intensity: override of the light intensity.
        include_diffuse: override of the diffuse switch.
        distribution: ``"ggx"`` or ``"beckmann"``: the model ``pred`` is rendered with (the loss is
            agnostic to the BRDF model).
        target_distribution: the model ``target`` is rendered with; None: ``distribution``. E.g.
            ``distribution="beckmann", target_distribution="ggx"`` trains a Beckmann output on GGX
            ground truth (thesis ch. 6.1.1).
        backend: ``"mitsuba"`` (fused Dr.Jit kernel) or ``"torch"`` (reference).

    Returns:
        Scalar loss tensor.

    Examples:
        >>> import torch, mi_svbrdf
        >>> gt = mi_svbrdf.core.maps.constant_maps(1, 8, 8, roughness=0.4)
        >>> same = mi_svbrdf.rendering_loss(gt, gt, distribution="beckmann", generator=torch.Generator().manual_seed(0))
        >>> cross = mi_svbrdf.rendering_loss(gt, gt, distribution="beckmann", target_distribution="ggx",
        ...                                  generator=torch.Generator().manual_seed(0))
        >>> float(same), bool(cross > 0)
        (0.0, True)
    """
    _check_pair(pred, target)
    # Validate the options before dispatching: the fused kernel would otherwise fail deep inside
    # Dr.Jit (a RuntimeError from drjit.custom) instead of with a ValueError naming the argument.
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    distribution, target_distribution = resolve_distributions(distribution, target_distribution)
    cfg = resolve_preset(preset, n_diffuse=n_diffuse, n_specular=n_specular, eps=eps,
                         intensity=intensity, include_diffuse=include_diffuse)
    if configurations is None:
        configurations = sample_configurations(pred.shape[0], cfg.n_diffuse, cfg.n_specular,
                                               r1_max=cfg.r1_max, generator=generator, device=pred.device)
    if configurations.light.shape[0] != pred.shape[0]:
        raise ValueError(f"configurations: expected batch {pred.shape[0]}, got {configurations.light.shape[0]}")
    # The fused kernel reads the table unchecked (NaN or a w outside {0, 1} would give a silent
    # NaN or meaningless loss), so check here what render() checks for the torch backend.
    # One read of the device for both checks of both tables; the slow loop below only names what failed.
    both = torch.stack([configurations.light, configurations.view])
    finite, homogeneous = torch.stack([torch.isfinite(both).all(),
                                       ((both[..., 3] == 0) | (both[..., 3] == 1)).all()]).tolist()
    for name, t in ((("light", configurations.light), ("view", configurations.view))
                    if not (finite and homogeneous) else ()):
        if not torch.isfinite(t).all():
            raise ValueError(f"configurations: {name} contains NaN or Inf")
        if not bool(((t[..., 3] == 0) | (t[..., 3] == 1)).all()):
            raise ValueError(f"configurations: {name}'s homogeneous w must be 0 (direction) or 1 (position)")
    kwargs = dict(intensity=cfg.intensity, light_z_division=True, distance_falloff=False,
                  include_diffuse=cfg.include_diffuse)
    if backend == "mitsuba":
        batch, k_count = pred.shape[0], configurations.count
        flags = render_drjit.Flags(False, True, False, cfg.include_diffuse, True, distribution)
        light, view = configurations.light.to(pred), configurations.view.to(pred)
        inten = torch.full((batch, k_count, 3), float(cfg.intensity), dtype=pred.dtype, device=pred.device)
        table = render_drjit.pack_configurations(light, view, inten, None, None)
        return render_drjit.log_l1(pred, target, table, k_count, flags, cfg.eps,
                                   target_flags=replace(flags, distribution=target_distribution))
    r_pred = render(pred, configurations.light, configurations.view, backend=backend, distribution=distribution,
                    **kwargs)
    with torch.no_grad():
        r_gt = render(target, configurations.light, configurations.view, backend=backend,
                      distribution=target_distribution, **kwargs)
    # Radiance is >= 0 for valid maps; the clamp keeps invalid ones (negative albedo) finite.
    return (torch.log(r_gt.clamp_min(0.0) + cfg.eps) - torch.log(r_pred.clamp_min(0.0) + cfg.eps)).abs().mean()


def map_l1(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Sum over the four maps of each map's mean absolute difference."""
    _check_pair(pred, target)
    return sum((pred[:, s] - target[:, s]).abs().mean() for s in M.SLICES.values())


def rendering_ms_ssim_loss(pred: torch.Tensor, target: torch.Tensor, configurations: Configurations, *,
                           preset: str | LossPreset = "2018", distribution: str = "ggx",
                           target_distribution: str | None = None,
                           backend: Backend = "mitsuba") -> torch.Tensor:
    """``1 - MS-SSIM`` of log-encoded renderings (clipped to [0, 1]) under ``configurations``; ``pred``
    rendered with ``distribution``, ``target`` with ``target_distribution`` (None: the same)."""
    distribution, target_distribution = resolve_distributions(distribution, target_distribution)
    cfg = resolve_preset(preset)
    kwargs = dict(intensity=cfg.intensity, light_z_division=True, include_diffuse=cfg.include_diffuse,
                  backend=backend)
    r_pred = render(pred, configurations.light, configurations.view, distribution=distribution, **kwargs)
    with torch.no_grad():
        r_gt = render(target, configurations.light, configurations.view, distribution=target_distribution, **kwargs)
    b, k, c, h, w = r_pred.shape
    x = log_encode(r_pred.clamp(0.0, 1.0)).reshape(b * k, c, h, w)
    y = log_encode(r_gt.clamp(0.0, 1.0)).reshape(b * k, c, h, w)
    return 1.0 - ms_ssim(x, y).mean()


def mixed_loss(pred: torch.Tensor, target: torch.Tensor, *, map_weight: float = 0.1,
               ms_ssim_weight: float = 0.0, preset: str | LossPreset = "2019",
               configurations: Configurations | None = None, generator: torch.Generator | None = None,
               distribution: str = "ggx", target_distribution: str | None = None,
               backend: Backend = "mitsuba") -> torch.Tensor:
    """Ch. 4 loss: ``rendering_loss + map_weight * map_l1 [+ ms_ssim_weight * (1 - MS-SSIM)]``.

    ``distribution`` / ``target_distribution``: the models ``pred`` and ``target`` are rendered with
    (None: the same), as :func:`rendering_loss`; the map L1 compares the maps as they are (across
    models a roughness is not the same lobe, so a cross-model training may prefer ``map_weight=0``).
    """
    cfg = resolve_preset(preset)
    if configurations is None:
        configurations = sample_configurations(pred.shape[0], cfg.n_diffuse, cfg.n_specular,
                                               r1_max=cfg.r1_max, generator=generator, device=pred.device)
    loss = rendering_loss(pred, target, preset=cfg, configurations=configurations,
                          distribution=distribution, target_distribution=target_distribution, backend=backend)
    if map_weight:
        loss = loss + map_weight * map_l1(pred, target)
    if ms_ssim_weight:
        loss = loss + ms_ssim_weight * rendering_ms_ssim_loss(pred, target, configurations, preset=cfg,
                                                              distribution=distribution,
                                                              target_distribution=target_distribution,
                                                              backend=backend)
    return loss


class RenderingLoss(nn.Module):
    """``nn.Module`` twin of :func:`rendering_loss` (configurations drawn from its own generator)."""

    def __init__(self, preset: str | LossPreset = "2018", *, seed: int | None = None,
                 distribution: str = "ggx", target_distribution: str | None = None,
                 backend: Backend = "mitsuba") -> None:
        super().__init__()
        resolve_distributions(distribution, target_distribution)  # fail here, not at the first call
        self.preset = resolve_preset(preset)
        self.generator = torch.Generator().manual_seed(seed) if seed is not None else None
        self.distribution = distribution
        self.target_distribution = target_distribution
        self.backend = backend

    def configurations(self, batch: int, device: torch.device | str = "cpu") -> Configurations:
        """A new draw of the preset's configurations for ``batch`` samples (from the module's generator), on ``device``."""
        return sample_configurations(batch, self.preset.n_diffuse, self.preset.n_specular,
                                     r1_max=self.preset.r1_max, generator=self.generator, device=device)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return rendering_loss(pred, target, preset=self.preset, configurations=self.configurations(pred.shape[0], pred.device),
                              distribution=self.distribution, target_distribution=self.target_distribution,
                              backend=self.backend)


class MixedLoss(RenderingLoss):
    """``nn.Module`` twin of :func:`mixed_loss`."""

    def __init__(self, preset: str | LossPreset = "2019", *, map_weight: float = 0.1,
                 ms_ssim_weight: float = 0.0, seed: int | None = None, distribution: str = "ggx",
                 target_distribution: str | None = None, backend: Backend = "mitsuba") -> None:
        super().__init__(preset, seed=seed, distribution=distribution, target_distribution=target_distribution,
                         backend=backend)
        self.map_weight = map_weight
        self.ms_ssim_weight = ms_ssim_weight

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return mixed_loss(pred, target, map_weight=self.map_weight, ms_ssim_weight=self.ms_ssim_weight,
                          preset=self.preset, configurations=self.configurations(pred.shape[0], pred.device),
                          distribution=self.distribution, target_distribution=self.target_distribution,
                          backend=self.backend)
