"""Realistic calibrated captures: held-out materials photographed as a phone does, with the calibration a user states.

**Ranges** (:data:`RANGES`; U: uniform). A capture (:class:`RealisticCapture`) is one held-out
procedural material (:class:`~mi_svbrdf.data.heldout.HeldOutSet`'s material ``m``, ``holdout="test"``,
class ``CLASS_ORDER[m % 9]``) in N rectified S x S photos of the sample ``[-1, 1]^2``, 150 mm wide
(:data:`MM_PER_UNIT` = 75 mm per unit). Cameras: field of view U(45, 65) degrees, distance
``d = 1 / tan(fov / 2)`` (the frame spans the sample); photo 0 at ``(U(-0.3, 0.3), U(-0.3, 0.3), d)``,
photos 1..N-1 on the hemisphere at elevation U(45, 80) degrees and azimuth U(0, 360); every camera
aimed at the sample centre with the frame of :func:`camera_frame` (forward = -camera / |camera|,
right = normalize(forward x (0, 1, 0)), or x (1, 0, 0) when forward is within 0.999 of +-y,
up = right x forward). The flash is rigid to the phone: ``light = camera + ox right + oy up``,
``|o|`` U(5, 25) mm at an angle U(0, 360) drawn once per capture, an isotropic point light (no
cone). The capture file (``stated``) puts the light at the camera, each camera off the true one by
U(0, 0.03) x its distance in a uniformly random direction, and one grey intensity
``I = WHITE_LEVEL |P_cam0|^2`` (:data:`WHITE_LEVEL` = 0.8: a white matte sample facing photo 0's
flash reads 0.8, as ``capture-file make`` states ``|flash|^2``) for every photo. Photo k is rendered
(the texel renderer with fall-off, the optimiser's forward model) with intensity ``I g_k``, the
gain ``g_k`` = exposure 2^U(-0.7, 0.7) x per-channel white balance U(0.9, 1.1), normalised so that
each channel's geometric mean over the N photos is exactly 1; plus one unstated point light per
capture at elevation U(30, 70) degrees (distance :data:`UNMODELLED_DISTANCE`), grey intensity
U(0, 0.03) x 0.8 x ``g_k``, rendered like ``extra_lights`` (no fall-off: ``L = f pi I c(n . wl)``);
both times a vignetting ``1 - v (tan t / tan t_max)^2``, v U(0, 0.3) per photo (t: the angle between
the camera axis and the ray to the texel; t_max: its largest value over the sample's corners). The
photo pipeline: Gaussian noise of std :data:`NOISE_STD` = 0.003 (linear), clip to [0, 1], sRGB to
8 bits, JPEG of quality U{70..95} per photo (Pillow's defaults: 4:2:0), decoded as
:func:`~mi_svbrdf.io.calibrated_photos.load_capture` decodes (linear; a pixel with a channel at
code 255 is invalid). The **clean twin** (``realism="clean"``) has the same material, true cameras,
true lights and noise, stated exactly (``stated == true``): gain 1, no vignetting, no unmodelled
light, no JPEG. The **held-out evaluation** of material m (:meth:`RealisticCapture.heldout_error`):
:data:`HELDOUT_VIEWS` = 8 configurations of a camera and an isotropic point light at independent
hemisphere positions, elevation U(30, 80) degrees, distance ``1 / tan(U(45, 65) / 2)``, intensity
``WHITE_LEVEL |P_light|^2`` (each exposed like photo 0), no nuisance.

**Determinism.** The split's seed is :data:`TUNE_SEED` or :data:`TEST_SEED` (training uses 0-999).
Material m is ``HeldOutSet(seed=split seed).material(m)`` (``SeedSequence([seed, m])``: the same at
every N); capture (m, N) makes every draw above from ``SeedSequence([seed, m, N])`` in a fixed order
whatever the realism (the clean twin shares them; the gain normalisation is exact per N); the
held-out views of material m come from ``SeedSequence([seed, m, 0])`` (the same at every N: errors at
different N compare on the same views). Each split's first four materials (:data:`SPLIT_MATERIALS`)
are a metal (satin: held-out metals have roughness 0.6-0.7), a glossy dielectric, a rough diffuse
material and a medium one.

Examples:
    >>> cap = RealisticSet(split="test", size=16, materials=1, n_images=(2,), cache=False).capture(3, 2)
    >>> tuple(cap.images.shape), tuple(cap.valid.shape), cap.cls, cap.stated.n_images
    ((2, 3, 16, 16), (2, 1, 16, 16), 'metal', 2)
    >>> cap.heldout_error(cap.maps)
    0.0
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core import metrics
from mi_svbrdf.core.metrics import EvalLights
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.render import BACKENDS, render, texel_positions
from mi_svbrdf.data.cached_set import default_cache_dir, load_or_build
from mi_svbrdf.data.heldout import CLASS_ORDER, HeldOutSet
from mi_svbrdf.data.heldout import VERSION as HELDOUT_VERSION
from mi_svbrdf.data.parameter_split import HELD_OUT_RANGES
from mi_svbrdf.data.photo_setups import jpeg_codes
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.calibrated_photos import (
    CAPTURE_NAME,
    CameraSpec,
    CaptureSpec,
    ImageSpec,
    LightSpec,
    _decode,  # the decoding and saturation rule of load_capture, shared so both agree
    camera_frame,
    save_capture,
)
from mi_svbrdf.io.material_io import srgb_encode, write_material

__all__ = ["ERROR_FIELDS", "HELDOUT_VIEWS", "MM_PER_UNIT", "NOISE_STD", "RANGES", "REALISMS", "SPLITS",
           "SPLIT_MATERIALS", "SPLIT_SEEDS", "TEST_SEED", "TUNE_SEED", "UNMODELLED_DISTANCE", "WHITE_LEVEL",
           "RealisticCapture", "RealisticSet", "camera_frame", "heldout_views", "vignetting_factor"]

#: Millimetres per unit of the sample frame: the sample [-1, 1]^2 is 150 mm wide.
MM_PER_UNIT = 75.0
#: Seed of the split that defaults are tuned on (training seeds are 0-999).
TUNE_SEED = 2026_1301
#: Seed of the split that results are reported on.
TEST_SEED = 2026_1302
#: The splits and their seeds.
SPLIT_SEEDS: dict[str, int] = {"tune": TUNE_SEED, "test": TEST_SEED}
SPLITS = tuple(SPLIT_SEEDS)
#: Each split's materials, in order (the first ``materials`` are used; beyond them, the other indices
#: ascending). tune: metal (roughness 0.61), wood (0.22, glossy), stone (0.70), tiles (0.41);
#: test: metal (0.67), plastic (0.05, glossy), fabric (0.97), leather (0.48).
SPLIT_MATERIALS: dict[str, tuple[int, ...]] = {"tune": (3, 13, 15, 25), "test": (3, 1, 5, 20)}
#: ``"real"``: the nuisances of the module docstring; ``"clean"``: the clean twin.
REALISMS = ("real", "clean")
#: What a white matte sample facing photo 0's flash reads under the stated intensity (before exposure).
WHITE_LEVEL = 0.8
#: Standard deviation of the photos' Gaussian noise (linear radiance).
NOISE_STD = 0.003
#: Distance of the unmodelled light from the sample centre (units; it has no fall-off).
UNMODELLED_DISTANCE = 10.0
#: Held-out configurations per material.
HELDOUT_VIEWS = 8
#: Construction version (part of the cache key).
VERSION = 1
#: Every drawn range (closed; uniform draws; jpeg_quality: integers).
RANGES: dict[str, tuple[float, float]] = {
    "fov_deg": (45.0, 65.0),  # full field of view of every camera (distance 1 / tan(fov / 2))
    "first_camera_offset": (-0.3, 0.3),  # x and y of photo 0's camera
    "camera_elevation_deg": (45.0, 80.0),  # photos 1..N-1
    "flash_offset_mm": (5.0, 25.0),  # |o|, the flash beside the lens
    "pose_error": (0.0, 0.03),  # |stated camera - true camera| / |true camera|
    "exposure_stops": (-0.7, 0.7),  # before the normalisation of the gains
    "white_balance": (0.9, 1.1),  # per channel, before the normalisation
    "vignetting": (0.0, 0.3),  # fall-off at the corner farthest off the camera axis
    "unmodelled_light": (0.0, 0.03),  # intensity / WHITE_LEVEL
    "unmodelled_elevation_deg": (30.0, 70.0),
    "jpeg_quality": (70, 95),
    "heldout_elevation_deg": (30.0, 80.0),  # cameras and lights of the held-out views
}


#: The fields of :attr:`RealisticCapture.errors`. A clean twin has gains 1, camera errors 0, vignetting 0,
#: no JPEG and no unmodelled light; its flash offset is its geometry, which its capture file states.
ERROR_FIELDS: dict[str, str] = {
    "flash_offset_mm": "[ox, oy, 0]: true light - true camera in the camera frame (right, up, forward), mm",
    "flash_offset_units": "the same in units of the sample frame (mm / MM_PER_UNIT)",
    "gains": "N x 3 true per-photo RGB gains (geometric mean 1 per channel)",
    "exposure_stops": "N raw exposure draws (stops, before the normalisation)",
    "white_balance": "N x 3 raw white-balance draws (before the normalisation)",
    "camera_error": "N x 3 stated camera - true camera (units)",
    "camera_error_fraction": "N |camera_error| / |true camera|",
    "vignetting": "N vignetting strengths v",
    "jpeg_quality": "N JPEG qualities, or null (no JPEG)",
    "unmodelled_light": "{position, intensity (before the photo's gain), level}: the unstated light, or null",
    "intensity": "the stated RGB intensity (grey)",
    "noise_std": "the photos' noise standard deviation (linear)",
}


def _check(value: Any, ok: bool, name: str, expected: str) -> None:
    if not ok:
        raise ValueError(f"{name}: expected {expected}, got {value!r}")


def _on_hemisphere(elevation_deg: float, azimuth: float, distance: float) -> list[float]:
    e = math.radians(elevation_deg)
    return [distance * math.cos(e) * math.cos(azimuth), distance * math.cos(e) * math.sin(azimuth),
            distance * math.sin(e)]


def _distance(fov_deg: float) -> float:
    return 1.0 / math.tan(math.radians(fov_deg) / 2.0)


# ----------------------------------------------------------------------------- draws
@dataclass(frozen=True)
class _Scene:
    """The drawn truth and statement of capture (m, N): float64 tensors, positions ``(N, 3)``."""

    fov: list[float]  # (N,) degrees
    true_camera: torch.Tensor  # (N, 3)
    true_light: torch.Tensor  # (N, 3) camera + flash offset
    stated_camera: torch.Tensor  # (N, 3)
    flash_offset: torch.Tensor  # (3,) (ox, oy, 0) in the camera frame, units
    intensity: float  # the stated RGB intensity (grey)
    exposure_stops: list[float]  # (N,) raw draws
    white_balance: list[list[float]]  # (N, 3) raw draws
    gains: torch.Tensor  # (N, 3) normalised: geometric mean 1 per channel
    vignetting: list[float]  # (N,)
    jpeg_quality: list[int]  # (N,)
    unmodelled_position: list[float]  # (3,)
    unmodelled_level: float  # intensity / WHITE_LEVEL
    noise_seed: int


def _draw_scene(seed: int, m: int, n: int) -> _Scene:
    """Every draw of capture (m, N), from ``SeedSequence([seed, m, N])`` in a fixed order."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, m, n]))
    R = RANGES
    flash_mm, flash_angle = rng.uniform(*R["flash_offset_mm"]), rng.uniform(0.0, 2.0 * math.pi)
    level = rng.uniform(*R["unmodelled_light"])
    light_elevation, light_azimuth = rng.uniform(*R["unmodelled_elevation_deg"]), rng.uniform(0.0, 2.0 * math.pi)
    fov, cams, pose, stops, balance, vignetting, quality = [], [], [], [], [], [], []
    for k in range(n):  # every draw is made for every photo
        fov.append(rng.uniform(*R["fov_deg"]))
        offset = rng.uniform(*R["first_camera_offset"], size=2)
        elevation, azimuth = rng.uniform(*R["camera_elevation_deg"]), rng.uniform(0.0, 2.0 * math.pi)
        fraction, direction = rng.uniform(*R["pose_error"]), rng.normal(size=3)
        stops.append(rng.uniform(*R["exposure_stops"]))
        balance.append(rng.uniform(*R["white_balance"], size=3).tolist())
        vignetting.append(rng.uniform(*R["vignetting"]))
        quality.append(int(rng.integers(R["jpeg_quality"][0], R["jpeg_quality"][1], endpoint=True)))
        d = _distance(fov[-1])
        cams.append([offset[0], offset[1], d] if k == 0 else _on_hemisphere(elevation, azimuth, d))
        pose.append(fraction * direction / np.linalg.norm(direction))
    noise_seed = int(rng.integers(2**62))

    true_camera = torch.tensor(cams, dtype=torch.float64)
    right, up, _ = camera_frame(true_camera)
    o = flash_mm / MM_PER_UNIT
    ox, oy = o * math.cos(flash_angle), o * math.sin(flash_angle)
    true_light = true_camera + ox * right + oy * up
    stated_camera = true_camera + torch.tensor(np.stack(pose)) * true_camera.norm(dim=-1, keepdim=True)
    raw = torch.tensor(stops, dtype=torch.float64).exp2()[:, None] * torch.tensor(balance, dtype=torch.float64)
    gains = raw / raw.log().mean(dim=0, keepdim=True).exp()
    return _Scene(fov=fov, true_camera=true_camera, true_light=true_light, stated_camera=stated_camera,
                  flash_offset=torch.tensor([ox, oy, 0.0], dtype=torch.float64),
                  intensity=WHITE_LEVEL * float(stated_camera[0].square().sum()), exposure_stops=stops,
                  white_balance=balance, gains=gains, vignetting=vignetting, jpeg_quality=quality,
                  unmodelled_position=_on_hemisphere(light_elevation, light_azimuth, UNMODELLED_DISTANCE),
                  unmodelled_level=level, noise_seed=noise_seed)


def heldout_views(seed: int, m: int, count: int = HELDOUT_VIEWS) -> EvalLights:
    """The held-out configurations of material ``m``: ``count`` cameras and isotropic point lights.

    Each camera and light sits at an independent hemisphere position, elevation
    ``RANGES["heldout_elevation_deg"]``, distance ``1 / tan(fov / 2)`` with fov ``RANGES["fov_deg"]``;
    intensity ``WHITE_LEVEL |P_light|^2`` (grey). Drawn from ``SeedSequence([seed, m, 0])``.

    Returns:
        :class:`~mi_svbrdf.core.metrics.EvalLights` with ``light``, ``view``, ``intensity`` ``(count, 3)``.
    """
    _check(count, isinstance(count, int) and count >= 1, "count", "an int >= 1")
    rng = np.random.default_rng(np.random.SeedSequence([seed, m, 0]))
    lights, views = [], []
    for _ in range(count):
        for out in (views, lights):
            fov = rng.uniform(*RANGES["fov_deg"])
            elevation, azimuth = rng.uniform(*RANGES["heldout_elevation_deg"]), rng.uniform(0.0, 2.0 * math.pi)
            out.append(_on_hemisphere(elevation, azimuth, _distance(fov)))
    light = torch.tensor(lights, dtype=torch.float32)
    intensity = (WHITE_LEVEL * light.double().square().sum(dim=-1, keepdim=True)).float().expand(count, 3)
    return EvalLights(light=light, view=torch.tensor(views, dtype=torch.float32), intensity=intensity.contiguous())


def vignetting_factor(camera: torch.Tensor, strength: torch.Tensor, size: int) -> torch.Tensor:
    """Vignetting of rectified photos: ``1 - v (tan t / tan t_max)^2`` per texel.

    Args:
        camera: ``(N, 3)`` true camera positions, aimed at the sample centre.
        strength: ``(N,)`` v, the fall-off at the corner farthest off the camera axis.
        size: S, the photos' H = W.

    Returns:
        ``(N, 1, S, S)`` float64: t is the angle between the camera axis and the ray from the camera
        to the texel, t_max its largest value over the sample's four corners.
    """
    camera = camera.to(torch.float64)
    if camera.dim() != 2 or camera.shape[1] != 3 or tuple(strength.shape) != (camera.shape[0],):
        raise ValueError(f"camera, strength: expected (N, 3) and (N,), got {tuple(camera.shape)}, "
                         f"{tuple(strength.shape)}")
    forward = camera_frame(camera)[2]  # (N, 3)

    def tan2(points: torch.Tensor) -> torch.Tensor:  # points (3, ...) -> (N, ...) tan^2 of the ray's angle
        ray = points[None] - camera.view(-1, 3, *([1] * (points.dim() - 1)))
        along = (ray * forward.view(-1, 3, *([1] * (points.dim() - 1)))).sum(dim=1)
        return (ray.square().sum(dim=1) - along.square()).clamp_min(0.0) / along.square()

    corners = torch.tensor([[-1.0, -1.0, 1.0, 1.0], [-1.0, 1.0, -1.0, 1.0], [0.0] * 4], dtype=torch.float64)
    t2_max = tan2(corners).amax(dim=1)  # (N,)
    t2 = tan2(texel_positions(size, size, dtype=torch.float64))  # (N, S, S)
    return (1.0 - strength.to(torch.float64).view(-1, 1, 1) * t2 / t2_max.view(-1, 1, 1))[:, None]


# ----------------------------------------------------------------------------- photos
def _to_codes(radiance: torch.Tensor, noise_seed: int) -> np.ndarray:
    """Linear ``(N, 3, S, S)`` + noise, clipped, sRGB-encoded to 8 bits: ``(N, S, S, 3)`` uint8."""
    gen = torch.Generator().manual_seed(noise_seed)
    noisy = radiance.double() + NOISE_STD * torch.randn(radiance.shape, generator=gen, dtype=torch.float64)
    linear = noisy.clamp(0.0, 1.0).float().permute(0, 2, 3, 1).numpy()
    return np.round(srgb_encode(linear) * 255.0).astype(np.uint8)


def _decode_codes(codes: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """8-bit sRGB ``(N, S, S, 3)`` -> ``(images (N, 3, S, S) linear float32, valid (N, 1, S, S) bool)``."""
    pairs = [_decode(c.astype(np.float32) / 255.0, "srgb8") for c in codes]
    images = torch.from_numpy(np.stack([p[0] for p in pairs])).permute(0, 3, 1, 2).contiguous()
    return images, torch.from_numpy(np.stack([p[1] for p in pairs]))[:, None]


def _spec(camera: torch.Tensor, fov: list[float], light: torch.Tensor, intensity: torch.Tensor) -> CaptureSpec:
    """Rectified ``srgb8`` photos ``NNN.png`` with isotropic lights; ``intensity`` ``(N, 3)``."""
    return CaptureSpec(tuple(
        ImageSpec(f"{k:03d}.png", "srgb8", True, CameraSpec(tuple(camera[k].tolist()), float(fov[k])),
                  LightSpec(tuple(light[k].tolist()), tuple(intensity[k].tolist())))
        for k in range(camera.shape[0])))


# ----------------------------------------------------------------------------- one capture
@dataclass(frozen=True, eq=False)
class RealisticCapture:
    """One realistic capture (or its clean twin) and its truth; see the module docstring.

    Built by :class:`RealisticSet`; :meth:`save` writes it as a capture folder.
    """

    material: int  #: m, the held-out material index
    cls: str  #: its class, CLASS_ORDER[m % 9]
    n_images: int  #: N
    split: str  #: "tune" or "test"
    realism: str  #: "real" or "clean"
    maps: torch.Tensor  #: (1, 10, S, S) the true maps
    images: torch.Tensor  #: (N, 3, S, S) linear photos, as load_capture returns them
    valid: torch.Tensor  #: (N, 1, S, S) bool, False where a channel is at the top code
    stated: CaptureSpec  #: what the user's capture file says
    true: CaptureSpec  #: true cameras and lights, intensity x true gain (no vignetting, no unmodelled light)
    errors: dict[str, Any]  #: JSON-ready nuisances, the keys of ERROR_FIELDS
    heldout: EvalLights  #: the material's held-out views (heldout_views)
    info: dict[str, Any]  #: JSON-ready description of the material (class, parameters, transform)

    @property
    def size(self) -> int:
        """S."""
        return int(self.maps.shape[-1])

    def _check_maps(self, maps: torch.Tensor) -> torch.Tensor:
        if not isinstance(maps, torch.Tensor) or tuple(maps.shape) != tuple(self.maps.shape):
            shape = tuple(maps.shape) if isinstance(maps, torch.Tensor) else type(maps).__name__
            raise ValueError(f"maps: expected shape {tuple(self.maps.shape)}, got {shape}")
        return maps.detach().to("cpu", torch.float32)

    def heldout_error(self, maps: torch.Tensor, backend: str = "mitsuba") -> float:
        """Display RMSE of ``maps`` ``(1, 10, S, S)`` against the truth over the held-out views.

        Both are rendered under :attr:`heldout` (point lights with fall-off), clipped to [0, 1] and
        sRGB-encoded; the RMSE is over views, texels and channels. 0 for the true maps; invariant
        of the capture's nuisances (it measures the material).
        """
        maps = self._check_maps(maps)
        with torch.no_grad():
            shown = [srgb_encode(metrics.rerender(x, self.heldout, backend=backend).clamp(0.0, 1.0).numpy())
                     for x in (maps, self.maps)]
        return float(np.sqrt(np.mean(np.square(shown[0].astype(np.float64) - shown[1].astype(np.float64)))))

    def map_errors(self, maps: torch.Tensor) -> dict[str, float]:
        """Per-map RMSE against the truth: ``{"normal", "diffuse", "roughness", "specular"}``
        (:func:`mi_svbrdf.core.metrics.map_rmse`: normals as ``(n + 1) / 2``, the others linear)."""
        return {k: float(v[0]) for k, v in metrics.map_rmse(self._check_maps(maps), self.maps).items()}

    def vignetting(self) -> torch.Tensor:
        """``(N, 1, S, S)`` float64: the vignetting the photos were rendered with (ones for a clean twin)."""
        camera = torch.tensor([im.camera.position for im in self.true.images], dtype=torch.float64)
        return vignetting_factor(camera, torch.tensor(self.errors["vignetting"], dtype=torch.float64), self.size)

    def rendering_spec(self) -> CaptureSpec:
        """:attr:`true` with the unmodelled light as every photo's ``extra_lights``: with
        :meth:`vignetting`, everything the photos were rendered with before noise, clipping and JPEG."""
        light = self.errors["unmodelled_light"]
        if light is None:
            return self.true
        return dataclasses.replace(self.true, images=tuple(
            dataclasses.replace(im, extra_lights=(LightSpec(tuple(light["position"]),
                                                            tuple(i * g for i, g in zip(light["intensity"], gain))),))
            for im, gain in zip(self.true.images, self.errors["gains"])))

    def save(self, folder: str | os.PathLike) -> Path:
        """Write the capture to ``folder``: ``capture.json`` and ``NNN.png`` (:func:`save_capture`; the
        photos as decoded, so :func:`load_capture` returns :attr:`images`), ``truth.json`` (the material,
        the true calibration and :attr:`errors`) and the true maps in ``truth/``. Returns the capture.json path."""
        folder = Path(folder)
        path = folder / CAPTURE_NAME
        save_capture(path, self.stated, self.images)
        write_material(folder / "truth", self.maps)
        write_json(folder / "truth.json", {
            "material": f"held-out material {self.material} ({self.cls}) of the {self.split} split",
            "made_by": "mi_svbrdf.data.realistic.RealisticSet", "split": self.split, "realism": self.realism,
            "index": self.material, "class": self.cls, "n_images": self.n_images, "size": self.size,
            "version": VERSION, "info": self.info, "errors": self.errors, "true": self.true.to_dict()})
        return path

    def _data(self, codes: np.ndarray) -> dict[str, Any]:
        """Tensors and JSON text for the cache (``torch.load(weights_only=True)``)."""
        meta = {f: getattr(self, f) for f in ("material", "cls", "n_images", "split", "realism", "errors", "info")}
        return {"maps": self.maps, "codes": torch.from_numpy(codes), "meta": json.dumps(meta),
                "stated": json.dumps(self.stated.to_dict()), "true": json.dumps(self.true.to_dict()),
                "heldout": {"light": self.heldout.light, "view": self.heldout.view,
                            "intensity": self.heldout.intensity}}

    @classmethod
    def _from_data(cls, data: dict[str, Any]) -> RealisticCapture:
        images, valid = _decode_codes(data["codes"].numpy())
        return cls(**json.loads(data["meta"]), maps=data["maps"], images=images, valid=valid,
                   stated=CaptureSpec.from_dict(json.loads(data["stated"])),
                   true=CaptureSpec.from_dict(json.loads(data["true"])), heldout=EvalLights(**data["heldout"]))


# ----------------------------------------------------------------------------- the set
@dataclass(frozen=True)
class RealisticSet:
    """Realistic captures of held-out materials, materials x photo counts (see the module docstring)."""

    split: str = "test"  #: "tune" (tune defaults on it) or "test" (report on it): seeds TUNE_SEED, TEST_SEED
    size: int = 256  #: S, H = W of the maps and rectified photos, >= 8
    materials: int | tuple[int, ...] = 4  #: how many of the split's SPLIT_MATERIALS, or explicit indices m >= 0
    n_images: tuple[int, ...] = (3, 5, 10)  #: photo counts N (one capture per material and N), each >= 1
    realism: str = "real"  #: "real" (nuisances) or "clean" (the clean twins)
    backend: str = "mitsuba"  #: texel renderer backend of the photos
    cache: bool = True  #: keep each capture in cache_dir as .pt (atomic write), keyed by every setting
    cache_dir: str | None = None  #: None: default_cache_dir("realistic")

    def __post_init__(self) -> None:
        _check(self.split, self.split in SPLITS, "split", f"one of {SPLITS}")
        _check(self.size, isinstance(self.size, int) and self.size >= 8, "size", "an int >= 8")
        if isinstance(self.materials, list):
            object.__setattr__(self, "materials", tuple(self.materials))
        if isinstance(self.n_images, (int, list)):
            object.__setattr__(self, "n_images", (self.n_images,) if isinstance(self.n_images, int)
                               else tuple(self.n_images))
        ok = (isinstance(self.materials, int) and self.materials >= 1) or (
            isinstance(self.materials, tuple) and len(self.materials) >= 1
            and all(isinstance(m, int) and m >= 0 for m in self.materials))
        _check(self.materials, ok, "materials", "an int >= 1 or a non-empty tuple of ints >= 0")
        _check(self.n_images, isinstance(self.n_images, tuple) and len(self.n_images) >= 1
               and all(isinstance(n, int) and n >= 1 for n in self.n_images), "n_images",
               "a non-empty tuple of ints >= 1")
        _check(self.realism, self.realism in REALISMS, "realism", f"one of {REALISMS}")
        _check(self.backend, self.backend in BACKENDS, "backend", f"one of {BACKENDS}")

    @property
    def seed(self) -> int:
        """The split's seed."""
        return SPLIT_SEEDS[self.split]

    def material_indices(self) -> tuple[int, ...]:
        """The material indices m of the set, in order."""
        if isinstance(self.materials, tuple):
            return self.materials
        first = SPLIT_MATERIALS[self.split]
        rest = (m for m in range(self.materials + max(first) + 1) if m not in first)
        return (first + tuple(rest))[:self.materials]

    def key(self, m: int, n: int) -> str:
        """Cache key of capture (m, N): a hash of every setting that changes it."""
        settings = {"seed": self.seed, "size": self.size, "m": m, "n": n, "realism": self.realism,
                    "backend": self.backend, "version": VERSION, "ranges": RANGES, "white_level": WHITE_LEVEL,
                    "noise_std": NOISE_STD, "unmodelled_distance": UNMODELLED_DISTANCE, "views": HELDOUT_VIEWS,
                    "heldout_version": HELDOUT_VERSION, "held_out_ranges": HELD_OUT_RANGES,
                    "torch": torch.__version__.split("+")[0]}
        return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]

    def path(self, m: int, n: int) -> Path:
        """The cache file of capture (m, N)."""
        root = Path(self.cache_dir) if self.cache_dir else default_cache_dir("realistic")
        return root / f"realistic_{self.split}_{self.realism}_{self.size}px_m{m}_n{n}_{self.key(m, n)}.pt"

    def captures(self, progress: bool = True) -> list[RealisticCapture]:
        """Every capture, materials (outer) x ``n_images`` (inner), identical at every call."""
        out, memo = [], {}
        pairs = [(m, n) for m in self.material_indices() for n in self.n_images]
        for m, n in tqdm(pairs, desc=f"realistic {self.split} {self.realism}", disable=not progress):
            out.append(self._capture(m, n, memo))
        return out

    def capture(self, m: int, n: int) -> RealisticCapture:
        """Capture (m, N) of the split: held-out material ``m`` (>= 0) in ``n`` (>= 1) photos."""
        return self._capture(m, n, {})

    def _capture(self, m: int, n: int, memo: dict[int, Any]) -> RealisticCapture:
        _check(m, isinstance(m, int) and m >= 0, "m", "an int >= 0")
        _check(n, isinstance(n, int) and n >= 1, "n", "an int >= 1")

        def build() -> dict[str, Any]:
            if m not in memo:  # the material is the same at every N: made once per captures() call
                memo.clear()
                part = HeldOutSet(size=self.size, materials=1, n_images=1, seed=self.seed, backend=self.backend,
                                  cache=False).material(m)
                memo[m] = (part["maps"].float().contiguous(), part["info"])
            return self._build(m, n, *memo[m])

        return RealisticCapture._from_data(load_or_build(self.path(m, n), self.cache, build))

    def _build(self, m: int, n: int, maps: torch.Tensor, info: dict[str, Any]) -> dict[str, Any]:
        """Render, photograph and describe capture (m, N): its cache dict."""
        s = _draw_scene(self.seed, m, n)
        real = self.realism == "real"
        intensity = s.intensity * (s.gains if real else torch.ones_like(s.gains))  # (N, 3) true
        with torch.no_grad():
            radiance = render(maps, s.true_light[None].float(), s.true_camera[None].float(),
                              intensity=intensity[None].float(), distance_falloff=True, backend=self.backend)[0]
            unmodelled = None
            if real:
                grey = [WHITE_LEVEL * s.unmodelled_level] * 3
                unmodelled = {"position": s.unmodelled_position, "intensity": grey, "level": s.unmodelled_level}
                extra = torch.tensor(s.unmodelled_position, dtype=torch.float32).expand(1, n, 3)
                extra_intensity = (torch.tensor(grey, dtype=torch.float64) * s.gains)[None].float()
                radiance = radiance + render(maps, extra, s.true_camera[None].float(), intensity=extra_intensity,
                                             backend=self.backend)[0]
                radiance = (radiance.double() * vignetting_factor(s.true_camera, torch.tensor(s.vignetting),
                                                                  self.size)).float()
        codes = _to_codes(radiance, s.noise_seed)
        if real:
            codes = np.stack([jpeg_codes(c, q) for c, q in zip(codes, s.jpeg_quality)])
        images, valid = _decode_codes(codes)
        true = _spec(s.true_camera, s.fov, s.true_light, intensity)
        nominal = torch.full((n, 3), s.intensity, dtype=torch.float64)
        stated = _spec(s.stated_camera, s.fov, s.stated_camera, nominal) if real else true
        offset = s.flash_offset.tolist()
        error = (s.stated_camera - s.true_camera) if real else torch.zeros_like(s.true_camera)
        errors = {"flash_offset_mm": [v * MM_PER_UNIT for v in offset], "flash_offset_units": offset,
                  "gains": (s.gains if real else torch.ones_like(s.gains)).tolist(),
                  "exposure_stops": s.exposure_stops if real else [0.0] * n,
                  "white_balance": s.white_balance if real else [[1.0] * 3] * n,
                  "camera_error": error.tolist(),
                  "camera_error_fraction": (error.norm(dim=-1) / s.true_camera.norm(dim=-1)).tolist(),
                  "vignetting": s.vignetting if real else [0.0] * n,
                  "jpeg_quality": s.jpeg_quality if real else None, "unmodelled_light": unmodelled,
                  "intensity": [s.intensity] * 3, "noise_std": NOISE_STD}
        cap = RealisticCapture(material=m, cls=CLASS_ORDER[m % len(CLASS_ORDER)], n_images=n, split=self.split,
                               realism=self.realism, maps=maps, images=images, valid=valid, stated=stated,
                               true=true, errors=errors, heldout=heldout_views(self.seed, m), info=info)
        return cap._data(codes)
