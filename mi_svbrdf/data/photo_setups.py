"""Capture parameters of the online simulator (thesis ch. 4.3): flash, camera, ambient light, photo.

A *capture* is one photo of a flat sample: where the flash and the camera are, the flash's
intensity, colour and cone, a second (ambient) light, and the photo pipeline's noise.
:func:`sample_captures` draws N of them per sample from a :class:`CaptureConfig`;
:func:`render_captures` renders them with the texel renderer (inputs are rectified: no
perspective, the view direction varies per texel because the camera is a point at finite
distance); :func:`photograph` applies noise, clipping, gamma 1/2.2 and 8-bit quantisation
(:func:`mi_svbrdf.core.flash.photo_pipeline`). The returned :class:`Captures` are the exact
calibration of each photo, so an optimisation baseline can be fed the same photos.

The model, with the authors' 2019 numbers where their code gives them (``/work/shared/conventions.md``):

* **Flash** (switch ``flash``): a point light with ``1/d^2`` fall-off and an angular cone
  ``c(wl . a)^e``, ``a`` the unit vector from the cone target to the light.
  Intensity (``intensity_jitter``): ``I = |N(10, s)| * X``, ``s = exp(N(-2, 0.5))`` per sample
  (a sample's shots are sometimes alike, sometimes wildly different), ``|N(10, s)|`` per image,
  exposure ``X = exp(N(log 1.5, 0.4))`` per sample; off: ``I = intensity`` (13).
  White balance (``white_balance``): per image and channel ``|N(1, 0.03)|``.
  Cone exponent (``cone_exponent_jitter``): ``e = exp(N(log 5, 0.35))`` per sample (one flash);
  cone target (``cone_target_jitter``): ``(N(0, 0.25), N(0, 0.25), 0)`` per image.
  The authors draw s, X, e and the noise level once per mini-batch; here they are drawn per
  sample, so a sample's statistics do not depend on the batch it is in.
* **First image** (a fronto-parallel photo): light at ``(U(-0.75, 0.75)^2, 2.197)``
  (``light_offset``), camera at ``(U(-0.25, 0.25)^2, d)`` (``view_offset``). With
  ``flash_at_camera`` the light is instead at the camera plus ``U(-0.1, 0.1)^2`` in the
  camera's image plane (a phone's flash beside its lens).
* **Field of view** (``fov_jitter``): per image ``FOV ~ U(40 - 10, 40 + 10)`` degrees (the
  authors' comment: "a FOV between 30 and 50 degrees"). A rectified photo whose frame spans
  the sample's width ``[-1, 1]`` is taken from ``d = 1 / tan(FOV / 2)`` (2.75 at 40 degrees,
  the authors' camera height): the FOV enters as the camera distance, nothing else.
* **Images 2..N** (``hemisphere``): camera on the hemisphere at distance ``d``, aimed at the
  sample centre; light on the hemisphere at distance 2.197 (an independent direction, as the
  authors; with ``flash_at_camera`` beside the camera). Directions are cosine-weighted with
  the authors' sampler (``r1 ~ U(0.001, cos^2(min_elevation))``, ``r = sqrt(r1)``,
  ``phi ~ U(0, 2 pi)``) or area-uniform (``z ~ U(sin(min_elevation), 1)``); the minimum
  elevation 8.13 degrees is the authors' ``r1 < 0.98``. Off: every image uses the first
  image's sampler.
* **Ambient light** (``ambient``): ``ambient_lights`` point lights per sample, shared by its
  images, rendered as the authors' ambient light (no fall-off, no cone): direction
  cosine-weighted above 26.57 degrees of elevation (their ``r1 < 0.8``), distance
  ``30 * exp(N(0, 0.15))``, intensity ``0.15 * exp(N(0, 0.5))`` (theirs) times a colour
  ``exp(N(0, 0.15))`` per channel (ours: warm to cool room light, +-30 % at 2 sigma).
* **Photo** (``noise``, ``photo``): Gaussian noise of std ``exp(N(log 0.005, 0.3))`` per sample,
  then clip to [0, 1], ``x^(1/2.2)``, ``trunc(255.5 x)/255``, ``x^2.2``.

Every random number is drawn whatever the switches say, in a fixed order, so switching one
perturbation off (or changing its range) leaves every other draw unchanged.

Examples:
    >>> import torch
    >>> from mi_svbrdf.data.photo_setups import capture_config, sample_captures
    >>> cap = sample_captures(2, 3, capture_config("multiview"), torch.Generator().manual_seed(0))
    >>> tuple(cap.light.shape), tuple(cap.cone_exponent.shape), tuple(cap.ambient_light.shape)
    ((2, 3, 3), (2, 3), (2, 1, 3))
"""
from __future__ import annotations

import dataclasses
import io
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from PIL import Image

from mi_svbrdf.core.colour import gamma_decode, gamma_encode
from mi_svbrdf.core.settings import from_dict
from mi_svbrdf.core.flash import photo_pipeline
from mi_svbrdf.core.render import Backend, render

HEMISPHERE_SAMPLINGS = ("cosine", "uniform")


@dataclass(frozen=True)
class CaptureConfig:
    """How captures are drawn: every perturbation has a switch and a documented range.

    Defaults are the ``"multiview"`` preset (thesis ch. 4). With every switch off a capture
    is the authors' un-augmented flash photo: light (0, 0, 2.197), camera (0, 0, 2.75),
    I = 13, cone e = 5 aimed at (0, 0, 0), no ambient light, no noise.
    """

    # --- flash ---
    flash: bool = True  #: render the flash (off: the ambient light alone lights the sample)
    intensity: float = 13.0  #: flash intensity I when intensity_jitter is off (authors: 13)
    intensity_jitter: bool = True  #: I = |N(10, exp(N(-2, 0.5)))| * exp(N(log 1.5, 0.4))
    white_balance: bool = True  #: per image and channel factor |N(1, white_balance_std)|
    white_balance_std: float = 0.03  #: std of the white balance factor (authors: 0.03), >= 0
    cone: bool = True  #: angular fall-off c(wl . a)^e of the flash (off: isotropic point light)
    cone_exponent: float = 5.0  #: e, or the median of e when jittered (authors: 5), > 0
    cone_exponent_jitter: bool = True  #: e = cone_exponent * exp(N(0, cone_exponent_log_std))
    cone_exponent_log_std: float = 0.35  #: log-std of e (authors: 0.35), >= 0
    cone_target_jitter: bool = True  #: cone target (N(0, s), N(0, s), 0) per image (off: origin)
    cone_target_std: float = 0.25  #: s, in half sample widths (authors: 0.25), >= 0
    # --- geometry ---
    light_height: float = 2.197  #: first light's height; hemisphere lights' distance (authors: 2.197), > 0
    light_offset: bool = True  #: first light at (U(-r, r)^2, light_height) (off: above the centre)
    light_offset_range: float = 0.75  #: r of light_offset (authors: 0.75), >= 0
    view_offset: bool = True  #: first camera at (U(-r, r)^2, d) (off: above the centre)
    view_offset_range: float = 0.25  #: r of view_offset (authors: 0.25), >= 0
    flash_at_camera: bool = False  #: light beside the camera (image-plane offset) instead of free
    flash_offset_range: float = 0.1  #: flash_at_camera offset U(-r, r)^2 (~1 cm for a 20 cm sample), >= 0
    fov: float = 40.0  #: field of view (degrees) of a frame spanning the sample; d = 1/tan(fov/2)
    fov_jitter: bool = True  #: FOV ~ U(fov - fov_jitter_range, fov + fov_jitter_range) per image
    fov_jitter_range: float = 10.0  #: degrees (authors' comment: 30 to 50 degrees), fov +- it in (0, 180)
    hemisphere: bool = True  #: images 2..N: camera and light on the hemisphere (off: like image 1)
    hemisphere_sampling: str = "cosine"  #: "cosine" (authors' sampler) or "uniform" (area-uniform)
    min_elevation: float = 8.13  #: degrees above the plane of hemisphere positions (authors: 8.13), [0, 90)
    # --- ambient light ---
    ambient: bool = True  #: add ambient_lights extra lights per sample (no fall-off, no cone)
    ambient_lights: int = 1  #: number of ambient lights per sample, >= 1
    ambient_intensity: float = 0.15  #: median intensity of each ambient light (authors: 0.15), >= 0
    ambient_intensity_log_std: float = 0.5  #: log-std of the ambient intensity (authors: 0.5), >= 0
    ambient_colour_std: float = 0.15  #: log-std of the per-channel ambient colour (ours), >= 0
    ambient_distance: float = 30.0  #: median distance of an ambient light (authors: 30), > 0
    ambient_distance_log_std: float = 0.15  #: log-std of that distance (authors: 0.15), >= 0
    ambient_min_elevation: float = 26.57  #: degrees above the plane (authors: r1 < 0.8), [0, 90)
    # --- photo ---
    noise: bool = True  #: additive Gaussian noise of std noise_median * exp(N(0, noise_log_std))
    noise_median: float = 0.005  #: median noise std (authors: 0.005), >= 0
    noise_log_std: float = 0.3  #: log-std of the noise std (authors: 0.3), >= 0
    photo: bool = True  #: clip to [0, 1], gamma 1/2.2, 8-bit quantisation, decode (off: raw radiance)

    def __post_init__(self) -> None:
        nonneg = ("intensity", "white_balance_std", "cone_exponent_log_std", "cone_target_std",
                  "light_offset_range", "view_offset_range", "flash_offset_range", "fov_jitter_range",
                  "ambient_intensity", "ambient_intensity_log_std", "ambient_colour_std",
                  "ambient_distance_log_std", "noise_median", "noise_log_std")
        for name in nonneg:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        for name in ("cone_exponent", "light_height", "ambient_distance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        low, high = self.fov - self.fov_jitter_range, self.fov + self.fov_jitter_range
        if not 0 < low <= high < 180:
            raise ValueError(f"fov, fov_jitter_range: expected fov +- fov_jitter_range inside (0, 180) degrees, "
                             f"got {low} to {high}")
        for name in ("min_elevation", "ambient_min_elevation"):
            if not 0 <= getattr(self, name) < 90:
                raise ValueError(f"{name}: expected degrees in [0, 90), got {getattr(self, name)!r}")
        if self.hemisphere_sampling not in HEMISPHERE_SAMPLINGS:
            raise ValueError(f"hemisphere_sampling: expected one of {HEMISPHERE_SAMPLINGS}, "
                             f"got {self.hemisphere_sampling!r}")
        if not isinstance(self.ambient_lights, int) or self.ambient_lights < 1:
            raise ValueError(f"ambient_lights: expected an int >= 1, got {self.ambient_lights!r}")
        if not self.flash and not self.ambient:
            raise ValueError("flash, ambient: expected at least one light, got both off")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CaptureConfig:
        """Build from a dict (e.g. parsed JSON); unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)


#: Named capture set-ups.
PRESETS: dict[str, CaptureConfig] = {
    # Thesis ch. 4: first image a fronto-parallel flash photo, the others on the hemisphere,
    # every augmentation of the authors' 2019 code plus an ambient light.
    "multiview": CaptureConfig(),
    # Thesis ch. 3: one fronto-parallel photo, the flash beside the lens, the 50 degrees FOV of
    # the ch. 3.2 renders (+-5), no ambient light; intensity, colour, cone and noise perturbed.
    "single_flash": CaptureConfig(flash_at_camera=True, hemisphere=False, fov=50.0, fov_jitter_range=5.0,
                                  ambient=False),
    # Thesis ch. 5: the guidance photo under room light: no flash, three ambient lights
    # (environment-like lighting), a fronto-parallel camera; brighter lights so that a mid-grey
    # albedo is exposed near mid-grey.
    "ambient": CaptureConfig(flash=False, hemisphere=False, ambient_lights=3, ambient_intensity=0.3),
    # The authors' un-augmented flash photo: every perturbation off (photo pipeline kept).
    "clean": CaptureConfig(intensity_jitter=False, white_balance=False, cone_exponent_jitter=False,
                           cone_target_jitter=False, light_offset=False, view_offset=False, fov_jitter=False,
                           hemisphere=False, ambient=False, noise=False),
}


def capture_config(preset: str | CaptureConfig = "multiview", **overrides: Any) -> CaptureConfig:
    """A preset (:data:`PRESETS`) or a given config, with ``overrides`` applied (unknown keys rejected)."""
    if isinstance(preset, str):
        if preset not in PRESETS:
            raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {preset!r}")
        preset = PRESETS[preset]
    if not isinstance(preset, CaptureConfig):
        raise ValueError(f"preset: expected a preset name or a CaptureConfig, got {type(preset).__name__}")
    return from_dict(CaptureConfig, {**dataclasses.asdict(preset), **overrides})


@dataclass(frozen=True)
class Captures:
    """N captures of each of B samples: the exact calibration of every photo.

    Positions are on the sample's frame: the plane spans ``[-1, 1]^2`` at z = 0, y up.
    """

    light: torch.Tensor  #: (B, N, 3) flash positions
    view: torch.Tensor  #: (B, N, 3) camera positions
    intensity: torch.Tensor  #: (B, N, 3) flash RGB intensity (I times white balance; 0 if no flash)
    cone_target: torch.Tensor  #: (B, N, 3) point the flash is aimed at
    cone_exponent: torch.Tensor  #: (B, N) cone exponent e
    ambient_light: torch.Tensor  #: (B, A, 3) ambient light positions (A = 0: none), shared by the N images
    ambient_intensity: torch.Tensor  #: (B, A, 3) ambient RGB intensity
    noise_std: torch.Tensor  #: (B,) std of the additive noise (0: none)
    fov: torch.Tensor  #: (B, N) field of view in degrees of a frame spanning the sample
    distance: torch.Tensor  #: (B, N) camera distance to the sample centre, 1 / tan(fov / 2)
    flash: bool = True  #: the flash is rendered
    cone: bool = True  #: the flash has its cone fall-off
    photo: bool = True  #: clip, gamma and 8-bit quantisation applied after the noise

    def __post_init__(self) -> None:
        b, n = self.light.shape[:2]
        shapes = {"light": (b, n, 3), "view": (b, n, 3), "intensity": (b, n, 3), "cone_target": (b, n, 3),
                  "cone_exponent": (b, n), "noise_std": (b,), "fov": (b, n), "distance": (b, n)}
        for name, shape in shapes.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"Captures.{name}: expected shape {shape}, got {tuple(getattr(self, name).shape)}")
        a = self.ambient_light.shape[1] if self.ambient_light.dim() == 3 else -1
        for name in ("ambient_light", "ambient_intensity"):
            if tuple(getattr(self, name).shape) != (b, a, 3):
                raise ValueError(f"Captures.{name}: expected shape (B={b}, A, 3), "
                                 f"got {tuple(getattr(self, name).shape)}")

    @property
    def batch_size(self) -> int:
        """B."""
        return self.light.shape[0]

    @property
    def n_images(self) -> int:
        """N, the photos per sample."""
        return self.light.shape[1]

    def take(self, index: int | slice | torch.Tensor) -> Captures:
        """The captures of some samples (batch index, slice or index tensor); a single int keeps B = 1."""
        if isinstance(index, int):
            index = slice(index, index + 1)
        return dataclasses.replace(self, **{f: getattr(self, f)[index] for f in _TENSOR_FIELDS})

    def images(self, index: int | slice | torch.Tensor) -> Captures:
        """The same samples with a subset of their N images (the ambient lights are kept)."""
        if isinstance(index, int):
            index = slice(index, index + 1)
        per_image = ("light", "view", "intensity", "cone_target", "cone_exponent", "fov", "distance")
        return dataclasses.replace(self, **{f: getattr(self, f)[:, index] for f in per_image})

    def to_dict(self) -> dict[str, Any]:
        """Nested lists and bools (JSON-ready)."""
        out: dict[str, Any] = {f: getattr(self, f).tolist() for f in _TENSOR_FIELDS}
        out.update(flash=self.flash, cone=self.cone, photo=self.photo)
        return out


_TENSOR_FIELDS = ("light", "view", "intensity", "cone_target", "cone_exponent", "ambient_light",
                  "ambient_intensity", "noise_std", "fov", "distance")


def _hemisphere(u1: torch.Tensor, u2: torch.Tensor, sampling: str, min_elevation: float) -> torch.Tensor:
    """Unit directions ``u1.shape + (3,)`` above ``min_elevation`` degrees from uniforms u1, u2 in [0, 1)."""
    cos_e = math.cos(math.radians(min_elevation))
    if sampling == "cosine":  # the authors' sampler: r1 ~ U(0.001, 1 - eps_hi), r = sqrt(r1)
        r1 = 0.001 + (cos_e**2 - 0.001) * u1
        r = r1.sqrt()
        z = (1.0 - r1).clamp_min(0.0).sqrt()
    else:  # area-uniform on the spherical cap: z ~ U(sin e, 1)
        z = math.sin(math.radians(min_elevation)) + (1.0 - math.sin(math.radians(min_elevation))) * u1
        r = (1.0 - z * z).clamp_min(0.0).sqrt()
    phi = 2.0 * math.pi * u2
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


def _image_plane(forward: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Orthonormal image-plane axes (right, up) of cameras looking along ``-forward`` (..., 3), forward.z > 0."""
    right = torch.stack([forward[..., 2], torch.zeros_like(forward[..., 0]), -forward[..., 0]], dim=-1)
    right = right / right.norm(dim=-1, keepdim=True)
    return right, torch.cross(forward, right, dim=-1)


def sample_captures(batch: int, n_images: int, config: CaptureConfig | str = "multiview",
                    generator: torch.Generator | None = None) -> Captures:
    """Draw N captures for each of B samples.

    Args:
        batch: B >= 1.
        n_images: N >= 1 photos per sample (image 0 is the fronto-parallel one).
        config: a :class:`CaptureConfig` or a preset name (:data:`PRESETS`).
        generator: seeded generator (CPU) for reproducible draws.

    Returns:
        :class:`Captures` with float32 tensors on the CPU.
    """
    cfg = capture_config(config) if isinstance(config, str) else config
    if not isinstance(cfg, CaptureConfig):
        raise ValueError(f"config: expected a CaptureConfig or a preset name, got {type(config).__name__}")
    if not (isinstance(batch, int) and batch >= 1 and isinstance(n_images, int) and n_images >= 1):
        raise ValueError(f"batch, n_images: expected ints >= 1, got {batch!r}, {n_images!r}")
    d = _draw(batch, n_images, cfg.ambient_lights, generator)
    fov, distance, view, light = _camera_and_light(cfg, d)
    cone_target, exponent, intensity = _flash(cfg, d)
    amb_light, amb_int = _ambient(cfg, d)
    noise = cfg.noise_median * torch.exp(cfg.noise_log_std * d.z_noise) if cfg.noise else torch.zeros(batch)
    return Captures(light=light, view=view, intensity=intensity, cone_target=cone_target,
                    cone_exponent=exponent[:, None].expand(batch, n_images).contiguous(), ambient_light=amb_light,
                    ambient_intensity=amb_int, noise_std=noise, fov=fov, distance=distance,
                    flash=cfg.flash, cone=cfg.cone, photo=cfg.photo)


@dataclass(frozen=True)
class _Draws:
    """Every random number of :func:`sample_captures` (``u_*`` uniform in [0, 1), ``z_*`` standard normal)."""

    u_light_xy: torch.Tensor  # (B, N, 2) fronto-parallel light offset
    u_view_xy: torch.Tensor  # (B, N, 2) fronto-parallel camera offset
    u_flash_xy: torch.Tensor  # (B, N, 2) flash offset from the camera (flash_at_camera)
    u_fov: torch.Tensor  # (B, N) field of view
    u_view_dir: torch.Tensor  # (B, N, 2) camera direction on the hemisphere
    u_light_dir: torch.Tensor  # (B, N, 2) light direction on the hemisphere
    z_target: torch.Tensor  # (B, N, 2) cone target
    z_exponent: torch.Tensor  # (B,) cone exponent
    z_spread: torch.Tensor  # (B,) spread of the flash intensity over a sample's images
    z_intensity: torch.Tensor  # (B, N) flash intensity
    z_exposure: torch.Tensor  # (B,) exposure
    z_balance: torch.Tensor  # (B, N, 3) white balance
    u_amb_dir: torch.Tensor  # (B, A, 2) ambient light directions
    z_amb_dist: torch.Tensor  # (B, A) ambient light distances
    z_amb_int: torch.Tensor  # (B, A) ambient light intensities
    z_amb_col: torch.Tensor  # (B, A, 3) ambient light colours
    z_noise: torch.Tensor  # (B,) photo noise level


def _draw(b: int, n: int, a: int, generator: torch.Generator | None) -> _Draws:
    """Every draw, in a fixed order, whatever the switches (see the module docstring)."""
    def unif(*shape: int) -> torch.Tensor:
        return torch.rand(shape, generator=generator)

    def gauss(*shape: int) -> torch.Tensor:
        return torch.randn(shape, generator=generator)

    # Keyword arguments are evaluated left to right: this is the draw order.
    return _Draws(u_light_xy=unif(b, n, 2), u_view_xy=unif(b, n, 2), u_flash_xy=unif(b, n, 2), u_fov=unif(b, n),
                  u_view_dir=unif(b, n, 2), u_light_dir=unif(b, n, 2),
                  z_target=gauss(b, n, 2), z_exponent=gauss(b),
                  z_spread=gauss(b), z_intensity=gauss(b, n), z_exposure=gauss(b), z_balance=gauss(b, n, 3),
                  u_amb_dir=unif(b, a, 2), z_amb_dist=gauss(b, a), z_amb_int=gauss(b, a), z_amb_col=gauss(b, a, 3),
                  z_noise=gauss(b))


def _camera_and_light(cfg: CaptureConfig, d: _Draws) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(fov, distance, view, light)``: field of view, camera distance, camera and flash positions."""
    b, n = d.u_fov.shape
    # Field of view -> camera distance of a frame spanning the sample.
    fov = torch.full((b, n), cfg.fov)
    if cfg.fov_jitter:
        fov = fov + cfg.fov_jitter_range * (2.0 * d.u_fov - 1.0)
    distance = 1.0 / torch.tan(torch.deg2rad(fov) / 2.0)

    # Fronto-parallel images (image 0, and all of them without the hemisphere).
    def offset(u: torch.Tensor, on: bool, r: float) -> torch.Tensor:
        return r * (2.0 * u - 1.0) if on else torch.zeros_like(u)

    view = torch.cat([offset(d.u_view_xy, cfg.view_offset, cfg.view_offset_range), distance[..., None]], dim=-1)
    light = torch.cat([offset(d.u_light_xy, cfg.light_offset, cfg.light_offset_range),
                       torch.full((b, n, 1), cfg.light_height)], dim=-1)
    forward = torch.zeros(b, n, 3)
    forward[..., 2] = 1.0
    if cfg.hemisphere and n > 1:
        view_dir = _hemisphere(d.u_view_dir[..., 0], d.u_view_dir[..., 1], cfg.hemisphere_sampling,
                               cfg.min_elevation)
        light_dir = _hemisphere(d.u_light_dir[..., 0], d.u_light_dir[..., 1], cfg.hemisphere_sampling,
                                cfg.min_elevation)
        view = torch.cat([view[:, :1], (view_dir * distance[..., None])[:, 1:]], dim=1)
        light = torch.cat([light[:, :1], (light_dir * cfg.light_height)[:, 1:]], dim=1)
        forward = torch.cat([forward[:, :1], view_dir[:, 1:]], dim=1)
    if cfg.flash_at_camera:
        right, up = _image_plane(forward)
        off = offset(d.u_flash_xy, True, cfg.flash_offset_range)
        light = view + off[..., :1] * right + off[..., 1:] * up
    return fov, distance, view, light


def _flash(cfg: CaptureConfig, d: _Draws) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(cone_target (B, N, 3), cone exponent (B,), RGB intensity (B, N, 3))`` of the flash."""
    b, n = d.z_intensity.shape
    cone_target = torch.zeros(b, n, 3)
    if cfg.cone_target_jitter:
        cone_target[..., :2] = cfg.cone_target_std * d.z_target
    exponent = cfg.cone_exponent * (torch.exp(cfg.cone_exponent_log_std * d.z_exponent)
                                    if cfg.cone_exponent_jitter else torch.ones(b))
    if cfg.intensity_jitter:
        spread = torch.exp(-2.0 + 0.5 * d.z_spread)  # per sample: shots sometimes alike, sometimes not
        strength = ((10.0 + spread[:, None] * d.z_intensity).abs()
                    * torch.exp(math.log(1.5) + 0.4 * d.z_exposure)[:, None])
    else:
        strength = torch.full((b, n), cfg.intensity)
    balance = (1.0 + cfg.white_balance_std * d.z_balance).abs() if cfg.white_balance else torch.ones(b, n, 3)
    intensity = strength[..., None] * balance if cfg.flash else torch.zeros(b, n, 3)
    return cone_target, exponent, intensity


def _ambient(cfg: CaptureConfig, d: _Draws) -> tuple[torch.Tensor, torch.Tensor]:
    """``(positions (B, A, 3), RGB intensities (B, A, 3))`` of the ambient lights (A = 0 when off)."""
    b = d.z_noise.shape[0]
    if not cfg.ambient:
        return torch.zeros(b, 0, 3), torch.zeros(b, 0, 3)
    amb_dir = _hemisphere(d.u_amb_dir[..., 0], d.u_amb_dir[..., 1], "cosine", cfg.ambient_min_elevation)
    amb_light = amb_dir * (cfg.ambient_distance * torch.exp(cfg.ambient_distance_log_std * d.z_amb_dist))[..., None]
    amb_int = ((cfg.ambient_intensity * torch.exp(cfg.ambient_intensity_log_std * d.z_amb_int))[..., None]
               * torch.exp(cfg.ambient_colour_std * d.z_amb_col))
    return amb_light, amb_int


def render_captures(maps: torch.Tensor, captures: Captures, *, backend: Backend = "mitsuba") -> torch.Tensor:
    """Linear radiance of every capture, before the photo pipeline: ``(B, N, 3, H, W)``.

    The flash is one :func:`mi_svbrdf.core.render` call (``distance_falloff=True``, the cone if
    ``captures.cone``); the ambient lights a second one (no fall-off, no cone), summed.

    Args:
        maps: ``(B, 10, H, W)`` SVBRDF, B as in ``captures``.
        captures: from :func:`sample_captures`.
        backend: ``"mitsuba"`` or ``"torch"``.
    """
    b, n = captures.batch_size, captures.n_images
    if maps.dim() != 4 or maps.shape[0] != b:
        raise ValueError(f"maps: expected shape (B={b}, 10, H, W) like captures, got {tuple(maps.shape)}")
    out = None
    if captures.flash:
        cone = dict(cone_target=captures.cone_target, cone_exponent=captures.cone_exponent) if captures.cone else {}
        out = render(maps, captures.light, captures.view, intensity=captures.intensity, distance_falloff=True,
                     backend=backend, **cone)
    a = captures.ambient_light.shape[1]
    if a > 0:
        light = captures.ambient_light[:, None].expand(b, n, a, 3).reshape(b, n * a, 3)
        view = captures.view[:, :, None].expand(b, n, a, 3).reshape(b, n * a, 3)
        inten = captures.ambient_intensity[:, None].expand(b, n, a, 3).reshape(b, n * a, 3)
        amb = render(maps, light, view, intensity=inten, backend=backend)
        amb = amb.view(b, n, a, *amb.shape[2:]).sum(dim=2)
        out = amb if out is None else out + amb
    if out is None:
        raise ValueError("captures: expected a flash or ambient lights, got neither")
    return out


def photograph(radiance: torch.Tensor, captures: Captures, generator: torch.Generator | None = None) -> torch.Tensor:
    """The photo pipeline on rendered radiance ``(B, N, 3, H, W)``: noise, then clip/gamma/8-bit if ``captures.photo``.

    Returns linear values (decoded with gamma 2.2), in [0, 1] when ``captures.photo``.
    """
    if radiance.dim() != 5 or radiance.shape[:2] != (captures.batch_size, captures.n_images):
        raise ValueError(f"radiance: expected shape (B={captures.batch_size}, N={captures.n_images}, 3, H, W), "
                         f"got {tuple(radiance.shape)}")
    noise: float | torch.Tensor = 0.0
    if bool((captures.noise_std > 0).any()):
        noise = captures.noise_std.to(radiance).view(-1, 1, 1, 1, 1)
    if captures.photo:
        return photo_pipeline(radiance, noise_std=noise, generator=generator)
    if isinstance(noise, torch.Tensor):
        radiance = radiance + torch.randn(radiance.shape, generator=generator, dtype=radiance.dtype) * noise
    return radiance


def jpeg_codes(codes: np.ndarray, quality: int) -> np.ndarray:
    """One 8-bit ``(H, W, 3)`` photo through Pillow's JPEG (its defaults: 4:2:0) at ``quality`` and back."""
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"quality: expected a JPEG quality in [1, 100], got {quality!r}")
    buf = io.BytesIO()
    Image.fromarray(codes).save(buf, format="JPEG", quality=int(quality))
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"), dtype=np.uint8)


def jpeg(photo: torch.Tensor, quality: int) -> torch.Tensor:
    """A linear photo ``(3, H, W)`` in [0, 1] gamma-encoded to 8 bits, JPEG-compressed at ``quality``, decoded
    (linear, float32, on ``photo``'s device)."""
    enc = (gamma_encode(photo.detach().cpu().float().clamp(0.0, 1.0)) * 255.0).round().to(torch.uint8)
    dec = jpeg_codes(enc.permute(1, 2, 0).numpy(), quality).astype(np.float32) / 255.0
    return gamma_decode(torch.from_numpy(dec).permute(2, 0, 1)).to(photo.device)


def simulate(maps: torch.Tensor, captures: Captures, generator: torch.Generator | None = None, *,
             backend: Backend = "mitsuba") -> torch.Tensor:
    """:func:`render_captures` then :func:`photograph`: the photos ``(B, N, 3, H, W)``, linear."""
    return photograph(render_captures(maps, captures, backend=backend), captures, generator)
