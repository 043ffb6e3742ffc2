"""How well maps predict photos they were not fitted to: the scorer of the folds, the early stop and the benchmarks.

A fit's maps re-render a photo it did not see; the error is the display-space RMSE (gamma 2.2, clipped at 1,
as the photo stores it) after **one exposure scale** fitted on the fit photos: a method's absolute albedo
scale is not held against it, its relative colours and shading are.

The exposure is fitted by least squares in linear light where **neither the photo nor the scaled render
clips** (:func:`exposure_scale`): a photo stores ``min(x, 1)``, so a pixel where the render lies above 1 says
nothing about the scale, whatever the photo holds there. Fitted over every unclipped photo pixel instead, a few
glossy texels that render far above 1 drag the scale down and darken every other pixel (a 2.4x error on a real
capture: the render clips at 1 anyway, so the spikes cost the maps nothing on the photos they were fitted to).
The clipped set depends on the scale: the fit alternates the two until the set no longer changes.

Where the exposure comes from is the scorer's choice (:class:`HeldOutScorer` ``exposure``): ``"fit"`` fits it on
the fit photos and carries it to the held-out ones (what a user sees: one exposure for the capture); ``"held"``
fits it on each held-out photo alone, so a shot's own exposure error (a real capture's photos are a few tenths of
a stop apart, which no maps can predict) is not held against the maps. The selection's folds rank recipes with
``"held"``: with ``"fit"``, a recipe whose brightness happens to drift with the left-out shot's error wins.

Examples:
    >>> import torch
    >>> photos = torch.full((1, 3, 4, 4), 0.25)
    >>> renders = torch.full((1, 3, 4, 4), 0.5)
    >>> renders[..., 0, 0] = 80.0  # a specular spike: renders far above 1, clipped in a photo anyway
    >>> round(exposure_scale(renders, photos), 4)
    0.5
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.device import RELEASE_TEXELS, release_memory
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.forward import TexelForward

__all__ = ["CLIPPED", "EXPOSURES", "EXPOSURE_PIXELS", "RENDER_TEXELS", "HeldOutScorer", "channel_bias",
           "exposure_scale", "exposure_stats", "held_out_rmse", "measured_rmse", "solve_exposure"]

#: Where :class:`HeldOutScorer` takes the held-out photos' exposure from (module docstring).
EXPOSURES = ("fit", "held")

#: A linear photo value at or above this is clipped (the top 8-bit code's lower edge).
CLIPPED = 254.5 / 255.0


def exposure_stats(renders: torch.Tensor, photos: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What :func:`solve_exposure` needs of each pixel of ``renders`` and ``photos`` (linear, ``(N, 3, H, W)`` both):
    ``(top, rp, rr)``, each ``(N, H, W)``: the render's largest channel (``inf`` where a channel of the photo is
    clipped), and the sums over channels of ``render x photo`` and ``render^2``."""
    if renders.shape != photos.shape:
        raise ValueError(f"renders, photos: expected equal shapes, got {tuple(renders.shape)} and "
                         f"{tuple(photos.shape)}")
    with torch.no_grad():
        ok = (photos < CLIPPED).all(dim=1)
        top = torch.where(ok, renders.amax(dim=1), torch.full_like(ok, math.inf, dtype=renders.dtype))
        return top, (renders * photos).sum(dim=1), renders.square().sum(dim=1)


def solve_exposure(stats: Sequence[tuple[torch.Tensor, torch.Tensor, torch.Tensor]], iterations: int = 50) -> float:
    """:func:`exposure_scale` from the :func:`exposure_stats` of one or more groups of photos (the scorer renders a
    large capture a few photos at a time and keeps only these); the sums are taken in double precision."""
    def total(which: int, use: list[torch.Tensor]) -> float:
        return sum(float(torch.where(u, group[which], 0.0).sum(dtype=torch.float64)) for u, group in zip(use, stats))

    with torch.no_grad():
        k, seen = 1.0, set()
        for _ in range(iterations):
            use = [top < 1.0 / k if k > 0 else torch.isfinite(top) for top, _, _ in stats]
            den = total(2, use)
            if den <= 1e-12:
                return k
            new = total(1, use) / den
            if new == k or new in seen:  # a fixed point (or a 2-cycle between two sets: either is as good)
                return new
            seen.add(k)
            k = new
        return k


def exposure_scale(renders: torch.Tensor, photos: torch.Tensor, iterations: int = 50) -> float:
    """The exposure ``k`` that best maps ``renders`` onto ``photos`` (linear, ``(N, 3, H, W)`` both).

    Least squares over the pixels where no channel of the photo is clipped (>= :data:`CLIPPED`) and no channel
    of ``k * renders`` reaches 1, alternated with that set until it is stable (module docstring), from the
    stated exposure (``k = 1``: the pixels whose render is below 1). A render that is zero where the photos are
    measured gives 1.
    """
    return solve_exposure([exposure_stats(renders, photos)], iterations)


def measured_rmse(renders: torch.Tensor, photos: torch.Tensor, valid: torch.Tensor) -> float | None:
    """Display RMSE (gamma 2.2, clipped at 1) of ``renders`` against ``photos`` (linear, ``(N, 3, H, W)`` both) over
    the pixels ``valid`` ``(N, 1, H, W)`` holds (a saturated pixel says only "at least this bright"); None where it
    holds none. One photo at a time: no full-size temporaries of the whole capture."""
    total, count = 0.0, 0
    with torch.no_grad():
        for r, p, v in zip(renders, photos, valid):
            d = (gamma_encode(r) - gamma_encode(p))[v.expand_as(p)]
            total += float(d.square().sum(dtype=torch.float64))
            count += d.numel()
    return math.sqrt(total / count) if count else None


def channel_bias(renders: torch.Tensor, photos: torch.Tensor) -> list[float]:
    """Mean display-space difference ``render - photo`` per channel (R, G, B) over pixels neither clips.

    Positive: the re-rendering is brighter than the photo in that channel; a colour cast shows as channels of
    opposite signs (a fit less yellow than its photos: blue above, red and green below).
    """
    ok = ((photos < CLIPPED) & (renders < 1.0)).all(dim=1, keepdim=True).expand_as(photos)
    diff = gamma_encode(renders) - gamma_encode(photos)
    return [float(diff[:, c][ok[:, c]].mean()) if bool(ok[:, c].any()) else 0.0 for c in range(3)]


#: The scorer renders the fit photos in groups of at most this many texels (photos x H x W): what it holds of them is
#: three values per pixel (:func:`exposure_stats`), not their renders (a 2048^2 capture's would be 50 MB a photo).
RENDER_TEXELS = 1 << 22
#: The exposure is one number: the scorer fits it on at most this many pixels of each fit photo (a regular grid
#: of every 2nd, 4th, ... pixel in each direction above 1024^2), and scores the held-out photos on all of theirs.
EXPOSURE_PIXELS = 1 << 20


class HeldOutScorer:
    """Scores maps on held-out photos, repeatedly (the early stop calls it every few steps).

    Args:
        spec: the rectified capture; images: its ``(N, 3, H, W)`` linear photos (read, not copied: leave them as
            they are while the scorer is in use).
        fit, held: indices of the fitted photos (they set the exposure) and of the held-out ones.
        distribution: the BRDF model of the maps scored.
        backend: the texel renderer's backend (``"auto"``: the fused kernel).
        exposure: ``"fit"`` (one exposure fitted on the fit photos) or ``"held"`` (each held-out photo's own; module
            docstring).

    Calling it on maps ``(1, 10, H, W)`` returns the display RMSE of the held-out photos (:func:`held_out_rmse`).
    """

    def __init__(self, spec: CaptureSpec, images: torch.Tensor, fit: Sequence[int], held: Sequence[int],
                 distribution: str = "ggx", backend: str = "auto", exposure: str = "fit") -> None:
        if exposure not in EXPOSURES:
            raise ValueError(f"exposure: expected one of {EXPOSURES}, got {exposure!r}")
        if not fit or not held:
            raise ValueError(f"fit, held: expected two non-empty lists of photos, got {list(fit)} and {list(held)}")
        size = tuple(images.shape[-2:])
        self.images = images.detach()
        self.fit, self.held = [int(k) for k in fit], [int(k) for k in held]
        per = max(1, RENDER_TEXELS // (size[0] * size[1]))
        self.stride = 1  # the grid of pixels the exposure is fitted on (EXPOSURE_PIXELS)
        while (size[0] // self.stride) * (size[1] // self.stride) > EXPOSURE_PIXELS:
            self.stride *= 2
        groups = [self.fit[i:i + per] for i in range(0, len(self.fit), per)]
        # "held" fits each exposure on its own photo: the fit photos are never rendered
        self.fit_forwards = ([(g, TexelForward(spec.subset(g), size, backend, distribution)) for g in groups]
                             if exposure == "fit" else [])
        self.held_forward = TexelForward(spec.subset(self.held), size, backend, distribution)
        self.mode = exposure
        self.exposure = 1.0  #: the exposure of the last call (``"held"``: their mean)
        self.renders = torch.empty(0)  #: the last call's held-out renders, exposed, ``(len(held), 3, H, W)``

    @property
    def held_photos(self) -> torch.Tensor:
        """The held-out photos, ``(len(held), 3, H, W)``."""
        return self.images[self.held]

    def render_fit(self, maps: torch.Tensor) -> torch.Tensor:
        """``maps`` ``(1, 10, H, W)`` rendered under the fit photos' lights, not exposed: ``(len(fit), 3, H, W)``
        (``"fit"`` only: the fit photos are not rendered otherwise)."""
        if not self.fit_forwards:
            raise ValueError("render_fit: expected a scorer with exposure 'fit', got 'held'")
        with torch.no_grad():
            return torch.cat([forward(maps.detach().to(self.images)) for _, forward in self.fit_forwards])

    def __call__(self, maps: torch.Tensor) -> float:
        if self.images.shape[-2] * self.images.shape[-1] >= RELEASE_TEXELS:
            # the fit's freed blocks (its kernel's, 300 MB at 2048^2) go first, not beside the renders
            release_memory(collect=False)
        maps = maps.detach().to(self.images)
        held = self.held_photos
        with torch.no_grad():
            if self.mode == "held":
                raw = self.held_forward(maps)
                scales = [exposure_scale(r[None], p[None]) for r, p in zip(raw, held)]
                self.exposure = sum(scales) / len(scales)
                self.renders = raw * torch.tensor(scales, dtype=raw.dtype, device=raw.device)[:, None, None, None]
            else:
                g = self.stride
                self.exposure = solve_exposure([exposure_stats(forward(maps)[..., ::g, ::g],
                                                               self.images[group][..., ::g, ::g])
                                                for group, forward in self.fit_forwards])
                self.renders = self.held_forward(maps) * self.exposure
            diff = gamma_encode(self.renders).sub_(gamma_encode(held))
            return float(diff.square_().mean().sqrt())


def held_out_rmse(maps: torch.Tensor, spec: CaptureSpec, images: torch.Tensor, fit: Sequence[int],
                  held: Sequence[int], distribution: str = "ggx") -> tuple[float, float, torch.Tensor]:
    """How well ``maps`` predict photos they were not fitted to.

    Args:
        maps: ``(1, 10, H, W)`` maps fitted to the photos ``fit``.
        spec: the rectified capture; images: its ``(N, 3, H, W)`` linear photos.
        fit, held: indices of the fitted and of the held-out photos.
        distribution: the BRDF model of ``maps``.

    Returns:
        ``(display RMSE of the held-out photos, the exposure scale, the held-out renders (len(held), 3, H, W))``:
        the renders are scaled by one exposure fitted on the fit photos (:func:`exposure_scale`), then compared
        gamma-encoded (2.2).
    """
    scorer = HeldOutScorer(spec, images, fit, held, distribution)
    err = scorer(maps)
    return err, scorer.exposure, scorer.renders
