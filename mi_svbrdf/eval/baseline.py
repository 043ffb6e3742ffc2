"""The trivial baseline of the thesis (Table 3.1): the photo as diffuse, everything else constant.

``trivial_baseline`` returns, per sample: normal (0, 0, 1) (flat), specular
:data:`BASELINE_SPECULAR` = 0.04 grey (the usual dielectric F0, ~1.5 IOR, the procedural
dielectrics' range [0.02, 0.08] centre), roughness :data:`BASELINE_ROUGHNESS` = 0.5 (mid-range:
the optimisation's start, see :mod:`mi_svbrdf.optim`), and as diffuse the most
fronto-parallel photo divided by ``(1 - s)`` times its **flat-normal irradiance** (flash with
``1/d^2`` fall-off and cone, plus the ambient lights), so a flat Lambertian sample of albedo d
with specular s gives back d: the baseline is as strong as a photo-as-diffuse can honestly be.
Without captures it assumes the default single-flash photo (:func:`default_captures`).

Examples:
    >>> import torch
    >>> from mi_svbrdf.eval.baseline import trivial_baseline
    >>> out = trivial_baseline(torch.full((2, 1, 3, 16, 16), 0.2))
    >>> tuple(out.shape), float(out[0, 6, 0, 0])
    ((2, 10, 16, 16), 0.5)
"""
from __future__ import annotations

import dataclasses

import torch

from mi_svbrdf.core.maps import make_maps
from mi_svbrdf.core.render import texel_positions
from mi_svbrdf.data.photo_setups import Captures, capture_config, sample_captures
from mi_svbrdf.optim.fit import frontality

#: Specular albedo of the baseline (grey).
BASELINE_SPECULAR = 0.04
#: Roughness of the baseline.
BASELINE_ROUGHNESS = 0.5


def default_captures(batch: int) -> Captures:
    """The default single-flash photo: preset ``"single_flash"`` with every perturbation off.

    Camera and flash together at ``(0, 0, 1 / tan(25 deg)) = (0, 0, 2.145)`` (50 degrees FOV),
    I = 13, cone e = 5 aimed at the centre, no ambient light: ``(B, 1)`` captures.
    """
    cfg = capture_config("single_flash", intensity_jitter=False, white_balance=False, cone_exponent_jitter=False,
                         cone_target_jitter=False, fov_jitter=False, view_offset=False, flash_offset_range=0.0,
                         noise=False)
    return sample_captures(batch, 1, cfg, torch.Generator().manual_seed(0))


def flat_irradiance(captures: Captures, height: int, width: int) -> torch.Tensor:
    """What a flat white Lambertian texel (d = 1, s = 0) radiates, ``(B, N, 3, H, W)``.

    Flash: ``I c(wl.z) / |P_L - P|^2 * c(wl . a)^e`` (cone if ``captures.cone``); ambient lights:
    ``I_a c(wl.z)`` (no fall-off, no cone), as :func:`mi_svbrdf.data.photo_setups.render_captures`.
    """
    pos = texel_positions(height, width)[None, None]  # (1, 1, 3, H, W)
    b, n = captures.batch_size, captures.n_images
    out = torch.zeros(b, n, 3, height, width)
    if captures.flash:
        to_light = captures.light[..., None, None] - pos  # (B, N, 3, H, W)
        d2 = to_light.square().sum(dim=2, keepdim=True)
        wl = to_light / d2.sqrt()
        irr = wl[:, :, 2:3].clamp_min(0.0) / d2
        if captures.cone:
            axis = captures.light - captures.cone_target
            axis = axis / axis.norm(dim=-1, keepdim=True)
            cos = (wl * axis[..., None, None]).sum(dim=2, keepdim=True).clamp_min(0.0)
            irr = irr * cos ** captures.cone_exponent[..., None, None, None]
        out = out + captures.intensity[..., None, None] * irr
    for a in range(captures.ambient_light.shape[1]):
        to_light = captures.ambient_light[:, a, :, None, None] - pos[:, 0]  # (B, 3, H, W)
        cos = (to_light[:, 2:3] / to_light.norm(dim=1, keepdim=True)).clamp_min(0.0)
        out = out + (captures.ambient_intensity[:, a, :, None, None] * cos)[:, None]
    return out


def _pick(captures: Captures, k: torch.Tensor) -> Captures:
    """The captures of image ``k[b]`` of each sample b: ``(B, 1)`` captures."""
    rows = torch.arange(captures.batch_size)
    per_image = ("light", "view", "intensity", "cone_target", "cone_exponent", "fov", "distance")
    return dataclasses.replace(captures, **{f: getattr(captures, f)[rows, k][:, None] for f in per_image})


def trivial_baseline(images: torch.Tensor, captures: Captures | None = None, *,
                     specular: float = BASELINE_SPECULAR, roughness: float = BASELINE_ROUGHNESS) -> torch.Tensor:
    """The thesis's trivial baseline (see the module docstring).

    Args:
        images: ``(B, N, 3, H, W)`` linear photos.
        captures: their exact capture parameters (B, N as ``images``); None: each sample's
            image 0 under :func:`default_captures`.
        specular: constant grey specular albedo s in [0, 1).
        roughness: constant roughness in [0, 1].

    Returns:
        ``(B, 10, H, W)`` maps; diffuse = photo / ((1 - s) * flat irradiance), clipped to [0, 1].
    """
    if not isinstance(images, torch.Tensor) or images.dim() != 5 or images.shape[2] != 3:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"images: expected shape (B, N, 3, H, W), got {shape}")
    if not 0.0 <= specular < 1.0:
        raise ValueError(f"specular: expected a value in [0, 1), got {specular!r}")
    if not 0.0 <= roughness <= 1.0:
        raise ValueError(f"roughness: expected a value in [0, 1], got {roughness!r}")
    b, n, _, h, w = images.shape
    if captures is None:
        captures, images = default_captures(b), images[:, :1]
    elif (captures.batch_size, captures.n_images) != (b, n):
        raise ValueError(f"captures: expected B={b}, N={n} like images, "
                         f"got B={captures.batch_size}, N={captures.n_images}")
    k = frontality(captures.light, captures.view).argmax(dim=1)  # (B,) most fronto-parallel photo
    rows = torch.arange(b)
    photo = images[rows, k].float()
    irr = flat_irradiance(_pick(captures, k), h, w)[:, 0]
    diffuse = (photo / ((1.0 - specular) * irr).clamp_min(1e-6)).clamp(0.0, 1.0)
    normal = torch.zeros(b, 3, h, w)
    normal[:, 2] = 1.0
    return make_maps(normal, diffuse, torch.full((b, 1, h, w), float(roughness)),
                     torch.full((b, 3, h, w), float(specular)))
