"""Self-calibration: what a real capture's stated calibration gets wrong, estimated with the maps.

A capture file states each photo's camera, flash and intensity. Real photos disagree with it:
auto exposure and white balance move between shots, a phone's flash sits 1-2 cm beside its lens,
and poses measured from a paper frame are off by a few per cent. Fitting one set of maps to
such photos under the stated calibration makes the maps absorb the disagreement as error.
:class:`SelfCalibration` estimates, jointly with the maps of a rectified capture:

* **gains** (``"gain"``): per photo an RGB gain ``g_k = exp(u_k)`` multiplying the stated
  intensities of its lights (exposure x white balance). Gains and albedos trade a global scale
  per channel, so it is **pinned**: ``u`` is centred over the photos, i.e. the geometric mean
  of each channel's gain over the photos is 1 (the stated intensity is right on average).
* **flash offset** (``"flash"``): one offset ``o = (ox, oy)`` in the image plane of the camera
  (:func:`~mi_svbrdf.io.calibrated_photos.camera_frame`: right, up), shared by every *flash
  photo* -- one whose stated light is within :data:`FLASH_RADIUS` x the camera distance of its
  camera, as a phone's flash is rigid to its lens: ``light_k = stated light_k + dc_k + o_x
  right_k + o_y up_k``.
* **poses** (``"pose"``): per photo a correction ``dc_k`` of the camera position (a flash photo's
  light moves with it) and, for a photo whose light is not its flash, ``dl_k`` of the light.

Each is pulled towards the stated calibration by a Gaussian prior whose width is how far the
user's numbers are trusted: exposure ``exposure_stops`` (stops), white balance
``white_balance`` (a channel's gain relative to the photo's exposure), flash offset ``flash``
and poses ``pose`` (fractions of the camera's or light's distance to the sample centre). The
variables are those corrections divided by their widths, so the prior is ``prior_weight x
sum z^2 / N`` and one learning rate serves all of them (``lr``, in widths per step).

Gradients. The maps' step runs on the fused Dr.Jit kernel, which differentiates the maps but
not the configuration. The calibration's step renders ``texels`` random texels of every photo
with the PyTorch texel renderer (:mod:`mi_svbrdf.core.brdf_torch`), the maps held fixed, and
takes one Adam step on the few calibration variables; the working calibration is then handed
to the forward model (:meth:`~mi_svbrdf.optim.forward.TexelForward.set_calibration`). The loss
is the maps' own (:func:`~mi_svbrdf.optim.loop.residual` against the target intervals), so a
saturated pixel only penalises a render *below* its clip level: a gain is never pushed down to
explain a clipped highlight away.

Examples:
    >>> import torch
    >>> from mi_svbrdf.io.calibrated_photos import CaptureSpec
    >>> spec = CaptureSpec.from_dict({"version": 1, "images": [{"file": f"{k}.png", "encoding": "srgb8",
    ...     "rectified": True, "camera": {"position": [0.3 * k, 0, 2.75]},
    ...     "light": {"position": [0.3 * k, 0, 2.75], "intensity": [8, 8, 8], "cone": None}} for k in range(3)]})
    >>> cal = SelfCalibration(spec, (16, 16))
    >>> light, view, gain = cal.configuration()
    >>> tuple(light.shape), tuple(gain.shape), cal.flash_photos
    ((1, 3, 3), (3, 3), (0, 1, 2))
"""
from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core.render import point, texel_positions
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, LightSpec, camera_frame
from mi_svbrdf.optim.loop import residual

__all__ = ["CORRECTIONS", "FLASH_RADIUS", "SelfCalibration"]

#: What can be calibrated.
CORRECTIONS = ("gain", "flash", "pose")
#: A photo is a flash photo when its stated light is within this fraction of the camera's distance of the camera.
FLASH_RADIUS = 0.25


class SelfCalibration:
    """Per-photo gains, a shared flash offset and per-photo pose corrections (module docstring).

    Args:
        spec: the capture (rectified photos); its calibration is the prior's centre.
        size: ``(H, W)`` of the photos (texel grid sampled by :meth:`step`).
        what: the corrections estimated, a subset of :data:`CORRECTIONS`.
        exposure_stops: prior width of a photo's exposure, stops, > 0.
        white_balance: prior width of a channel's log gain relative to its photo's exposure, > 0.
        flash: prior width of the flash offset, fraction of the mean camera distance, > 0.
        pose: prior width of a camera or light correction, fraction of its distance, > 0.
        prior_weight: weight of the priors, ``prior_weight x sum z^2 / N``, >= 0.
        lr: Adam learning rate of the variables (corrections / prior widths), > 0.
        texels: texels of each photo rendered per :meth:`step`, >= 1.
        seed: seed of the texel sampling.
        distribution: the BRDF model the maps are rendered with (the fit's).
        device: the device of the variables (the maps').
    """

    def __init__(self, spec: CaptureSpec, size: tuple[int, int], *, what: Sequence[str] = CORRECTIONS,
                 exposure_stops: float = 1.0, white_balance: float = 0.1, flash: float = 0.1, pose: float = 0.03,
                 prior_weight: float = 0.01, lr: float = 0.05, texels: int = 4096, seed: int = 0,
                 distribution: str = "ggx", device: torch.device | str = "cpu") -> None:
        unknown = sorted(set(what) - set(CORRECTIONS))
        if unknown:
            raise ValueError(f"what: expected a subset of {CORRECTIONS}, got unknown {unknown}")
        for name, value in (("exposure_stops", exposure_stops), ("white_balance", white_balance),
                            ("flash", flash), ("pose", pose), ("lr", lr)):
            if not (isinstance(value, (int, float)) and value > 0 and math.isfinite(value)):
                raise ValueError(f"{name}: expected a finite value > 0, got {value!r}")
        if not prior_weight >= 0:
            raise ValueError(f"prior_weight: expected >= 0, got {prior_weight!r}")
        if not (isinstance(texels, int) and texels >= 1):
            raise ValueError(f"texels: expected an int >= 1, got {texels!r}")
        bad = [k for k, im in enumerate(spec.images) if not im.rectified]
        if bad:
            raise ValueError(f"spec: expected rectified photos for self-calibration, got unrectified photos {bad}")
        self.spec, self.size, self.what = spec, (int(size[0]), int(size[1])), tuple(w for w in CORRECTIONS if w in what)
        self.prior_weight, self.texels, self.device = float(prior_weight), texels, torch.device(device)
        self.distribution = distribution
        ims = spec.images
        n = self.n = len(ims)
        f32 = {"dtype": torch.float32, "device": self.device}
        self.cam0 = torch.tensor([im.camera.position for im in ims], **f32)  # (N, 3) stated cameras
        self.light0 = torch.tensor([im.light.position for im in ims], **f32)  # (N, 3) stated lights
        cam_dist = self.cam0.norm(dim=-1)
        near = (self.light0 - self.cam0).norm(dim=-1) <= FLASH_RADIUS * cam_dist
        self.flash_photos = tuple(int(k) for k in torch.nonzero(near).flatten())
        self.is_flash = near
        right, up, _ = camera_frame(self.cam0)
        self.plane = torch.stack([right, up], dim=1)  # (N, 2, 3) image-plane axes of the stated cameras
        self.sigma_exposure = exposure_stops * math.log(2.0)
        self.sigma_wb = float(white_balance)
        self.sigma_flash = flash * float(cam_dist.mean())
        self.sigma_cam = (pose * cam_dist)[:, None]  # (N, 1)
        self.sigma_light = (pose * self.light0.norm(dim=-1))[:, None]
        # Variables: corrections in units of their prior widths (all zero: the stated calibration).
        self.z_exposure = torch.zeros(n, **f32, requires_grad="gain" in self.what)
        self.z_wb = torch.zeros(n, 3, **f32, requires_grad="gain" in self.what)
        self.z_flash = torch.zeros(2, **f32, requires_grad="flash" in self.what and bool(self.flash_photos))
        self.z_cam = torch.zeros(n, 3, **f32, requires_grad="pose" in self.what)
        self.z_light = torch.zeros(n, 3, **f32, requires_grad="pose" in self.what and not bool(near.all()))
        self.variables = [v for v in (self.z_exposure, self.z_wb, self.z_flash, self.z_cam, self.z_light)
                          if v.requires_grad]
        self.lr = float(lr)
        self.opt = torch.optim.Adam(self.variables, lr=self.lr) if self.variables else None
        self.generator = torch.Generator().manual_seed(int(seed))
        self.resize(self.size)
        self.cone = [(im.light.cone.target, im.light.cone.exponent) if im.light.cone else None for im in ims]
        self.steps = 0

    def resize(self, size: tuple[int, int]) -> None:
        """Sample the texels of a ``(H, W)`` grid from now on (a coarse-to-fine level)."""
        self.size = (int(size[0]), int(size[1]))
        self.positions = texel_positions(*self.size, device=self.device).reshape(3, -1)  # (3, H*W)

    # ------------------------------------------------------------------ the calibration
    def log_gain(self) -> torch.Tensor:
        """``(N, 3)`` log gains, centred over the photos per channel (the pin)."""
        wb = self.z_wb - self.z_wb.mean(dim=1, keepdim=True)  # the exposure is the channels' mean
        u = self.sigma_exposure * self.z_exposure[:, None] + self.sigma_wb * wb
        return u - u.mean(dim=0, keepdim=True)

    def configuration(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The working calibration: light and camera positions ``(1, N, 3)`` and gains ``(N, 3)``."""
        d_cam = self.sigma_cam * self.z_cam
        flash = self.sigma_flash * (self.z_flash[None, :, None] * self.plane).sum(dim=1)  # (N, 3)
        mask = self.is_flash[:, None].to(flash)
        d_light = mask * (d_cam + flash) + (1.0 - mask) * self.sigma_light * self.z_light
        return (self.light0 + d_light)[None], (self.cam0 + d_cam)[None], self.log_gain().exp()

    def prior(self) -> torch.Tensor:
        """``prior_weight x sum z^2 / N`` over the estimated variables (scalar)."""
        total = self.z_exposure.new_zeros(())
        for v in self.variables:
            total = total + v.square().sum()
        return self.prior_weight * total / self.n

    # ------------------------------------------------------------------ one step
    def _render(self, maps: torch.Tensor, index: torch.Tensor, light: torch.Tensor, view: torch.Tensor,
                gain: torch.Tensor) -> torch.Tensor:
        """Radiance ``(N, 3, M)`` of the texels ``index`` ``(M,)``, whose maps are ``maps`` ``(1, 10, 1, M)``."""
        m = maps
        pos = self.positions[:, index][:, None]  # (3, 1, M)
        ims = self.spec.images
        intensity = torch.tensor([[im.light.intensity for im in ims]], dtype=maps.dtype, device=maps.device)
        has_cone = any(c is not None for c in self.cone)
        cone_t = cone_e = None
        if has_cone:
            cone_t = torch.tensor([[c[0] if c else (p[0], p[1], p[2] - 1.0) for c, p in
                                    zip(self.cone, self.light0.tolist())]], dtype=maps.dtype, device=maps.device)
            cone_e = torch.tensor([[c[1] if c else 0.0 for c in self.cone]], dtype=maps.dtype, device=maps.device)
        flags = {"light_z_division": False, "include_diffuse": True, "normalize_normals": True,
                 "distribution": self.distribution}
        out = brdf_torch.render(m, pos, point(light), point(view), intensity * gain[None], cone_t, cone_e,
                                distance_falloff=True, **flags)[0]  # (N, 3, 1, M)
        for k, im in enumerate(ims):
            for extra in im.extra_lights:
                e_int = torch.tensor([[extra.intensity]], dtype=maps.dtype, device=maps.device) * gain[k]
                e_pos = torch.tensor([[extra.position]], dtype=maps.dtype, device=maps.device)
                amb = brdf_torch.render(m, pos, point(e_pos), point(view[:, k:k + 1]), e_int, None, None,
                                        distance_falloff=False, **flags)[0, 0]
                out = out.index_add(0, torch.tensor([k], device=out.device), amb[None])
        return out[:, :, 0]

    def step(self, maps: torch.Tensor | Callable[[torch.Tensor], torch.Tensor], lo: torch.Tensor, hi: torch.Tensor,
             kind: str, lr_factor: float = 1.0) -> float:
        """One Adam step of the calibration on ``texels`` random texels, ``maps`` ``(1, 10, H, W)`` fixed.

        Args:
            maps: the current maps (detached here), or a function of texel indices ``(M,)`` returning their maps
                ``(1, 10, 1, M)`` (the loop's: only the sampled texels' maps are computed, not all 4M at 2048^2).
            lo, hi: ``(N, 3, H, W)`` target intervals (:func:`~mi_svbrdf.optim.loop.target_bounds`).
            kind: the re-rendering error, ``"log_l1"`` or ``"l2"``.
            lr_factor: the maps' schedule factor (current lr / base lr), applied to ``lr``.

        Returns:
            the sampled objective before the step (data + prior).
        """
        if self.opt is None:
            return 0.0
        h, w = self.size
        count = h * w
        index = (torch.randperm(count, generator=self.generator)[:self.texels] if self.texels < count
                 else torch.arange(count)).to(self.device)
        for group in self.opt.param_groups:
            group["lr"] = self.lr * lr_factor
        self.opt.zero_grad(set_to_none=True)
        light, view, gain = self.configuration()
        texel_maps = maps(index) if callable(maps) else maps.reshape(1, 10, 1, -1)[..., index]
        render = self._render(texel_maps.detach(), index, light, view, gain)
        n = self.n
        lo_s = lo.reshape(n, 3, -1)[..., index]
        hi_s = hi.reshape(n, 3, -1)[..., index]
        loss = residual(render, lo_s, hi_s, kind).mean() + self.prior()
        loss.backward()
        value = float(loss.detach())
        if math.isfinite(value):
            self.opt.step()
        self.steps += 1
        return value

    def apply(self, forward: Any) -> None:
        """Hand the working calibration to ``forward`` (a :class:`~mi_svbrdf.optim.forward.TexelForward`)."""
        with torch.no_grad():
            light, view, gain = self.configuration()
        forward.set_calibration(light.cpu(), view.cpu(), gain.cpu())

    def state(self) -> dict[str, Any]:
        """A copy of the variables and the Adam state (the loop's recovery guard restores it)."""
        return {"z": [v.detach().clone() for v in self.variables],
                "opt": copy.deepcopy(self.opt.state_dict()) if self.opt is not None else None}

    def load_state(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state`."""
        with torch.no_grad():
            for v, saved in zip(self.variables, state["z"]):
                v.copy_(saved)
        if self.opt is not None:
            self.opt.load_state_dict(copy.deepcopy(state["opt"]))

    # ------------------------------------------------------------------ results
    def calibrated_spec(self) -> CaptureSpec:
        """The capture with the estimated calibration (positions corrected, intensities x gains)."""
        with torch.no_grad():
            light, view, gain = (t.cpu() for t in self.configuration())
        images = []
        for k, im in enumerate(self.spec.images):
            g = gain[k].tolist()
            lit = LightSpec(tuple(light[0, k].tolist()), tuple(i * gk for i, gk in zip(im.light.intensity, g)),
                            im.light.cone)
            extras = tuple(dataclasses.replace(e, intensity=tuple(i * gk for i, gk in zip(e.intensity, g)))
                           for e in im.extra_lights)
            images.append(dataclasses.replace(im, camera=CameraSpec(tuple(view[0, k].tolist()), im.camera.fov_deg),
                                              light=lit, extra_lights=extras))
        return dataclasses.replace(self.spec, images=tuple(images))

    def estimates(self) -> dict[str, Any]:
        """JSON-ready estimates: what was calibrated, gains, exposure (stops), flash offset, corrections."""
        with torch.no_grad():
            light, view, gain = (t.cpu() for t in self.configuration())
            u = self.log_gain().cpu()
            flash = (self.sigma_flash * self.z_flash).cpu()
        r4 = lambda t: [[round(float(v), 5) for v in row] for row in t]  # noqa: E731
        return {
            "calibrated": list(self.what), "steps": self.steps,
            "pin": "the geometric mean of each channel's gain over the photos is 1",
            "gain": r4(gain),
            "exposure_stops": [round(float(v), 4) for v in u.mean(dim=1) / math.log(2.0)],
            "flash_photos": list(self.flash_photos),
            "flash_offset": [round(float(v), 5) for v in flash] if self.flash_photos else None,
            "flash_offset_frame": "camera image plane (right, up), sample units (the sample spans [-1, 1])",
            "camera_correction": r4(view[0] - self.cam0.cpu()),
            "light_correction": r4(light[0] - self.light0.cpu()),
        }
