"""The flash input rendering of the authors' multi-image code, and their 8-bit photo pipeline.

Without augmentation their input photo is the sample under a flash at (0, 0, 2.197) seen
from (0, 0, 2.75) (about 40 degrees FOV, rendered orthographically per texel), with
``L = f * I * pi / |P_L - P|^2 * c(wl . a)^5 * c(n . wl)``, I = 13, ``a`` the unit vector from
the cone target (0, 0, 0) to the light, and no ``wl.z`` division. Their data reader then
clips to [0, 1], encodes with gamma 1/2.2, quantises to 8 bits as ``trunc(255.5 x)`` and
decodes with gamma 2.2: :func:`photo_pipeline`.

Examples:
    >>> import torch, mi_svbrdf
    >>> maps = mi_svbrdf.core.maps.constant_maps(1, 8, 8)
    >>> img = mi_svbrdf.core.flash.render_flash(maps)
    >>> tuple(img.shape), bool((img >= 0).all() and (img <= 1).all())
    ((1, 3, 8, 8), True)
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from mi_svbrdf.core.colour import GAMMA
from mi_svbrdf.core.render import Backend, render


@dataclass(frozen=True)
class FlashSetup:
    """Geometry and light of a flash photo (defaults: the authors' un-augmented setting)."""

    light: tuple[float, float, float] = (0.0, 0.0, 2.197)  #: flash position
    camera: tuple[float, float, float] = (0.0, 0.0, 2.75)  #: camera position (~40 deg FOV)
    cone_target: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: point the flash is aimed at
    cone_exponent: float = 5.0  #: cone fall-off exponent e in c(wl . a)^e
    intensity: float = 13.0  #: flash intensity I


def photo_pipeline(linear: torch.Tensor, *, noise_std: float | torch.Tensor = 0.0,
                   generator: torch.Generator | None = None, quantize: bool = True) -> torch.Tensor:
    """Simulate the 8-bit photo the networks see, returned linear again.

    Adds Gaussian noise (std ``noise_std``), clips to [0, 1], encodes ``x^(1/2.2)``, quantises
    ``trunc(255.5 x) / 255`` (if ``quantize``) and decodes ``x^2.2``. Not differentiable through
    the quantisation (use ``quantize=False`` for a differentiable variant).
    """
    x = linear
    if isinstance(noise_std, torch.Tensor) or noise_std > 0:
        x = x + torch.randn(x.shape, generator=generator, dtype=x.dtype).to(x.device) * noise_std
    x = x.clamp(0.0, 1.0)
    if not quantize:
        # (x^(1/2.2))^2.2 = x: skip the round trip, whose gradient at x = 0 is 0 * inf = NaN.
        return x
    # Encode with a base kept away from 0 where x == 0, so the backward pass through the
    # (zero-gradient) quantisation gives 0, not 0 * inf = NaN, at black pixels.
    positive = x > 0
    x = torch.where(positive, torch.where(positive, x, torch.ones_like(x)) ** (1.0 / GAMMA), torch.zeros_like(x))
    x = torch.trunc((255.5 * x).clamp(0.0, 255.0)) / 255.0
    return x**GAMMA


def render_flash(maps: torch.Tensor, setup: FlashSetup = FlashSetup(), *, pipeline: bool = True,
                 backend: Backend = "mitsuba") -> torch.Tensor:
    """Render the flash input photo of each material: ``(B, 10, H, W)`` -> ``(B, 3, H, W)`` linear.

    Args:
        maps: SVBRDF maps.
        setup: flash and camera placement (the authors' defaults).
        pipeline: apply :func:`photo_pipeline` (clip, gamma, 8-bit quantisation, decode).
        backend: ``"mitsuba"`` or ``"torch"``.
    """
    b = maps.shape[0]

    def per_batch(v: tuple[float, float, float]) -> torch.Tensor:
        return torch.tensor(v, dtype=maps.dtype, device=maps.device).expand(b, 1, 3)

    img = render(maps, per_batch(setup.light), per_batch(setup.camera), intensity=setup.intensity,
                 distance_falloff=True, cone_target=per_batch(setup.cone_target),
                 cone_exponent=setup.cone_exponent, backend=backend)[:, 0]
    return photo_pipeline(img) if pipeline else img
