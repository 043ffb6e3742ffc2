"""Forward models: canonical maps -> the linear radiance of every photo of a capture.

A forward model is any callable ``maps (1, 10, H, W) -> (N, 3, H, W)`` differentiable in the
maps (:class:`ForwardModel`). Two implement it:

* :class:`TexelForward` -- rectified photos, the texel renderer (:func:`mi_svbrdf.core.render`)
  with ``distance_falloff=True`` and the flash cone; the camera is a point at finite distance,
  so the view direction varies per texel (near field). Extra (ambient) lights: a second call
  without fall-off or cone, as the capture simulator renders them.

Both render the maps with a BRDF model ``distribution`` (``"ggx"``, the thesis's, or ``"beckmann"``):
the output model of the fit. The photos are whatever they are (e.g. of a GGX material), so a
Beckmann fit to them is a cross-model fit through the re-rendering loss (thesis ch. 6.1.1).
* ``MitsubaForward`` (:mod:`mi_svbrdf.optim.mitsuba_forward`) -- perspective photos rendered
  by Mitsuba with the maps as textures.

:func:`forward_for` picks one for a capture.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Literal, Protocol

import torch

from mi_svbrdf.core.render import Backend, render, texel_positions
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.fused_loss import FusedObjective
from mi_svbrdf.optim.mitsuba_forward import MitsubaForward
from mi_svbrdf.plugins.model import DISTRIBUTIONS

Path_ = Literal["auto", "texel", "mitsuba"]
PATHS = ("auto", "texel", "mitsuba")


class ForwardModel(Protocol):
    """``maps (1, 10, H, W) -> (N, 3, H, W)`` linear radiance, differentiable in ``maps``."""

    def __call__(self, maps: torch.Tensor) -> torch.Tensor:  # pragma: no cover - protocol
        ...


def _size(size: int | tuple[int, int]) -> tuple[int, int]:
    if isinstance(size, int):
        size = (size, size)
    if len(size) != 2 or min(size) < 1:
        raise ValueError(f"size: expected an int or (H, W) >= 1, got {size!r}")
    return int(size[0]), int(size[1])


class TexelForward:
    """The texel renderer over a rectified capture.

    Args:
        spec: the capture; every image must be rectified.
        size: ``H`` or ``(H, W)`` of the maps (and photos).
        backend: the texel renderer's backend; ``"auto"``: ``"mitsuba"`` (the fused Dr.Jit kernel; a fit's
            step is faster with it at every size measured, 8^2 to 256^2: ``benchmarks/bench_step.py``);
            ``"torch"``: PyTorch autograd through the texel renderer (the reference).
        distribution: the BRDF model the maps are rendered with, ``"ggx"`` or ``"beckmann"``.
    """

    def __init__(self, spec: CaptureSpec, size: int | tuple[int, int], backend: Backend | str = "auto",
                 distribution: str = "ggx") -> None:
        bad = [i for i, im in enumerate(spec.images) if not im.rectified]
        if bad:
            raise ValueError(f"spec: expected rectified images for the texel path, got unrectified images {bad}")
        self.size = _size(size)
        if backend == "auto":
            backend = "mitsuba"
        if backend not in ("torch", "mitsuba"):
            raise ValueError(f"backend: expected 'auto', 'torch' or 'mitsuba', got {backend!r}")
        self.backend: Backend = backend  # type: ignore[assignment]
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
        self.distribution = distribution
        ims = spec.images
        self.n = len(ims)
        self.light = torch.tensor([[im.light.position for im in ims]])  # (1, N, 3)
        self.view = torch.tensor([[im.camera.position for im in ims]])
        self.intensity = torch.tensor([[im.light.intensity for im in ims]])
        # An image without a cone gets a target right below its light and e = 0: c(wl.a)^0 = 1.
        self.cone_target = torch.tensor([[im.light.cone.target if im.light.cone else
                                          (im.light.position[0], im.light.position[1], im.light.position[2] - 1.0)
                                          for im in ims]])
        self.cone_exponent = torch.tensor([[im.light.cone.exponent if im.light.cone else 0.0 for im in ims]])
        self.has_cone = any(im.light.cone is not None for im in ims)
        # Extra lights flattened to (1, sum_k A_k, 3), with the image each belongs to.
        extra = [(k, e) for k, im in enumerate(ims) for e in im.extra_lights]
        self.extra_owner = torch.tensor([k for k, _ in extra], dtype=torch.long)
        self.extra_light = torch.tensor([[e.position for _, e in extra]]).reshape(1, len(extra), 3)
        self.extra_view = self.view[:, self.extra_owner] if extra else torch.zeros(1, 0, 3)
        self.extra_intensity = torch.tensor([[e.intensity for _, e in extra]]).reshape(1, len(extra), 3)
        # The stated calibration; set_calibration replaces the working one (light, view, intensity, ...).
        self.stated = (self.light, self.view, self.intensity, self.extra_view, self.extra_intensity)
        self._fused: list[FusedObjective] = []

    def set_calibration(self, light: torch.Tensor, view: torch.Tensor, gain: torch.Tensor) -> None:
        """Render with corrected positions and per-photo gains from now on (self-calibration).

        Args:
            light: ``(1, N, 3)`` light positions (replacing the stated ones).
            view: ``(1, N, 3)`` camera positions.
            gain: ``(N, 3)`` per-photo RGB gain (exposure and white balance) multiplying the stated
                intensity of the photo's flash and of its extra lights.

        The fused objectives this model made follow (:meth:`fused_objective`).
        """
        n = self.n
        if tuple(light.shape) != (1, n, 3) or tuple(view.shape) != (1, n, 3) or tuple(gain.shape) != (n, 3):
            raise ValueError(f"light, view, gain: expected (1, {n}, 3) twice and ({n}, 3), got "
                             f"{tuple(light.shape)}, {tuple(view.shape)}, {tuple(gain.shape)}")
        _, _, intensity, _, extra_intensity = self.stated
        gain = gain.detach().float().cpu()
        self.light, self.view = light.detach().float().cpu(), view.detach().float().cpu()
        self.intensity = intensity * gain[None]
        if self.extra_owner.numel():
            self.extra_view = self.view[:, self.extra_owner]
            self.extra_intensity = extra_intensity * gain[self.extra_owner][None]
        for fused in self._fused:
            fused.update(self.light, self.view, self.intensity, self.extra_view, self.extra_intensity)

    def __call__(self, maps: torch.Tensor) -> torch.Tensor:
        """Render ``maps`` ``(1, 10, H, W)`` under every photo's lights: ``(N, 3, H, W)``."""
        if maps.dim() != 4 or maps.shape[0] != 1 or tuple(maps.shape[2:]) != self.size:
            raise ValueError(f"maps: expected shape (1, 10, {self.size[0]}, {self.size[1]}), got {tuple(maps.shape)}")
        dev = maps.device  # the capture's tensors follow the maps' device
        cone = (dict(cone_target=self.cone_target.to(dev), cone_exponent=self.cone_exponent.to(dev))
                if self.has_cone else {})
        out = render(maps, self.light.to(dev), self.view.to(dev), intensity=self.intensity.to(dev),
                     distance_falloff=True, distribution=self.distribution, backend=self.backend, **cone)[0]
        if self.extra_owner.numel():
            amb = render(maps, self.extra_light.to(dev), self.extra_view.to(dev),
                         intensity=self.extra_intensity.to(dev), distribution=self.distribution,
                         backend=self.backend)[0]
            out = out.index_add(0, self.extra_owner.to(dev), amb)
        return out

    def fused_objective(self, lo: torch.Tensor, hi: torch.Tensor, kind: str,
                        tv_weight: float) -> Callable[[torch.Tensor], torch.Tensor] | None:
        """``variables -> residual(self(to_maps(v)), lo, hi, kind).mean() + tv_weight * TV`` in one kernel.

        None (use the unfused objective) with the torch backend. See
        :mod:`mi_svbrdf.optim.fused_loss`.
        """
        if self.backend != "mitsuba":
            return None
        cone = (self.cone_target, self.cone_exponent) if self.has_cone else (None, None)
        fused = FusedObjective(self.light, self.view, self.intensity, *cone, lo, hi, kind, tv_weight,
                               self.extra_owner, self.extra_light, self.extra_view, self.extra_intensity,
                               distribution=self.distribution)
        self._fused.append(fused)
        return fused

    def irradiance(self) -> torch.Tensor:
        """``I * c(n . wl) / |P_L - P|^2 * cone`` for the flat normal n = (0, 0, 1), plus each photo's
        extra lights (``I_e * c(n . wl_e)``, no fall-off, as they render): ``(N, 3, H, W)``.

        A Lambertian texel of albedo d with specular s renders as ``d (1 - s) * irradiance``;
        dividing a photo by it estimates the diffuse albedo (the initialisation). Without the
        extra lights a photo lit mostly by them divides into albedos above 1, which the
        parameterisation then cannot leave (its gradient vanishes at the clip).
        """
        pos = texel_positions(*self.size)  # (3, H, W)
        to_light = self.light[0, :, :, None, None] - pos[None]  # (N, 3, H, W)
        d2 = (to_light**2).sum(dim=1, keepdim=True)
        wl = to_light / d2.sqrt()
        irr = self.intensity[0, :, :, None, None] * wl[:, 2:3].clamp_min(0.0) / d2
        if self.has_cone:
            axis = self.light[0] - self.cone_target[0]
            axis = axis / axis.norm(dim=-1, keepdim=True)
            cos = (wl * axis[:, :, None, None]).sum(dim=1, keepdim=True).clamp_min(0.0)
            irr = irr * cos ** self.cone_exponent[0, :, None, None, None]
        if self.extra_owner.numel():
            to_extra = self.extra_light[0, :, :, None, None] - pos[None]  # (E, 3, H, W)
            cos_e = (to_extra[:, 2:3] / to_extra.norm(dim=1, keepdim=True)).clamp_min(0.0)
            irr = irr.index_add(0, self.extra_owner, self.extra_intensity[0, :, :, None, None] * cos_e)
        return irr


def forward_for(spec: CaptureSpec, size: int | tuple[int, int], path: Path_ | str = "auto",
                backend: Backend | str = "auto", distribution: str = "ggx", *,
                device: torch.device | str = "cpu") -> ForwardModel:
    """The forward model of a capture.

    Args:
        spec: the capture.
        size: ``H`` or ``(H, W)`` of the maps.
        path: ``"texel"``, ``"mitsuba"`` or ``"auto"`` (texel when every image is rectified).
        backend: the texel path's renderer backend (see :class:`TexelForward`).
        distribution: the BRDF model the maps are rendered with (``"ggx"`` or ``"beckmann"``).
        device: the maps' device (the Mitsuba path builds its scenes for that device's variant).
    """
    if path not in PATHS:
        raise ValueError(f"path: expected one of {PATHS}, got {path!r}")
    if path == "auto":
        path = "texel" if all(im.rectified for im in spec.images) else "mitsuba"
    if path == "texel":
        return TexelForward(spec, size, backend, distribution)
    return MitsubaForward(spec, size, distribution=distribution, device=device)
