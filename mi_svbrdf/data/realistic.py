"""Realistic calibrated captures: photos whose capture file is wrong the way a real one is.

The calibrated optimiser is exact on captures whose calibration is the truth. Real photos are not:
this set photographs held-out materials as a phone does and states in the capture file what the
user would have, not the truth. Per capture (one material, N rectified photos of ``size``^2):

* **Scale**: the sample ``[-1, 1]^2`` is 150 mm wide (:data:`MM_PER_UNIT` = 75 mm per unit).
* **Cameras**: photo 0 near fronto-parallel, at ``(U(-0.3, 0.3), U(-0.3, 0.3))`` above the centre;
  photos 1..N-1 on the hemisphere at elevation ``U(45, 80)`` degrees, any azimuth; distance
  ``1 / tan(fov / 2)``, ``fov ~ U(45, 65)`` degrees; every camera aimed at the sample centre
  (:func:`~mi_svbrdf.io.calibrated_photos.camera_frame`).
* **Flash** rigid to the lens: ``light = camera + ox right + oy up``, ``|o| ~ U(5, 25)`` mm in a
  direction drawn once per capture; isotropic (no cone). *Stated*: the flash at the camera.
* **Poses**: the stated camera is the true one off by ``U(0, 3) %`` of its distance in a random
  direction, per photo (the stated light with it).
* **Exposure and white balance**: the photo's intensity is the stated one times a gain
  ``2^U(-0.7, 0.7)`` x ``U(0.9, 1.1)`` per channel, normalised so that each channel's geometric
  mean over the capture's photos is 1 (the stated intensity is right on average: the global
  scale is the intensity calibration's business). Stated: one intensity for every photo, such
  that a white matte sample facing the flash at photo 0's distance reads :data:`WHITE_LEVEL`.
* **Vignetting**: ``1 - v (tan t / tan t_max)^2`` with ``v ~ U(0, 0.3)`` per photo, ``t`` the angle
  of a texel's ray to the camera axis, ``t_max`` the largest over the sample's corners.
* **Unmodelled light** (inter-reflections, room light): one point light per capture, not stated,
  at elevation ``U(30, 70)`` degrees, ``L = f pi I c(n . wl)`` (no fall-off), ``I ~ U(0, 0.03)``
  times the stated flash level at the sample.
* **Photo**: Gaussian noise (std :data:`NOISE_STD`, linear), clipping to [0, 1] (saturated
  highlights), the sRGB curve to 8 bits, JPEG at quality ``U{70..95}``, decoded as
  :func:`~mi_svbrdf.io.calibrated_photos.load_capture` decodes (a channel at the top code is
  saturated: ``valid`` False).

The **clean twin** (``realism="clean"``) photographs the same material from the same true cameras
and flashes and states them exactly: gain 1, no vignetting, no unmodelled light, no JPEG (noise
and 8 bits only). The **held-out evaluation** renders the maps under :data:`HELD_OUT_VIEWS` other
camera and light positions (isotropic lights at the stated intensity, no nuisance) and compares
display values with the truth's (:meth:`RealisticCapture.heldout_error`): it measures the
material, whatever the nuisances of the photos.

Each (split, material, N) draws from its own generator, ``SeedSequence([seed, m, N])``, every
number in a fixed order whatever ``realism`` is; the ``tune`` and ``test`` splits have different
seeds (:data:`SPLIT_SEEDS`) and so different materials: defaults are chosen on the first and
reported on the second.

Examples:
    >>> cap = RealisticSet(split="tune", size=16, materials=1, n_images=(3,), cache=False).capture(0, 3)
    >>> tuple(cap.images.shape), cap.stated.images[0].light.position == cap.stated.images[0].camera.position
    ((3, 3, 16, 16), True)
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from tqdm.auto import tqdm

from mi_svbrdf.core.maps import MAP_NAMES, SLICES
from mi_svbrdf.core.render import render, texel_positions
from mi_svbrdf.data.heldout import CLASS_ORDER, HeldOutSet, default_cache_dir
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.calibrated_photos import (CameraSpec, CaptureSpec, ImageSpec, LightSpec, camera_frame,
                                            save_capture)
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode

__all__ = ["MM_PER_UNIT", "RealisticCapture", "RealisticSet", "SPLIT_SEEDS"]

#: Millimetres per sample unit (the sample [-1, 1]^2 is 150 mm wide).
MM_PER_UNIT = 75.0
#: Seeds of the two splits (>= 1000: not training seeds).
SPLIT_SEEDS = {"tune": 2026_1203, "test": 2026_1204}
#: Materials of a split, in turn: held-out classes covering a glossy metal and a diffuse one.
SPLIT_CLASSES = {"tune": ("metal", "plastic", "stone", "leather", "tiles", "wood"),
                 "test": ("metal", "tiles", "fabric", "leather", "plastic", "stone")}
#: The display value of a white matte sample facing the flash at photo 0's distance.
WHITE_LEVEL = 0.5
#: Noise std of the photos (linear).
NOISE_STD = 0.003
#: Held-out views of the evaluation.
HELD_OUT_VIEWS = 8
#: Version of the set's construction (part of the cache key).
VERSION = 1
REALISMS = ("real", "clean")


def _uniform(gen: torch.Generator, lo: float, hi: float, *shape: int) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(shape or (1,), generator=gen, dtype=torch.float64)


def _hemisphere(gen: torch.Generator, elevation: tuple[float, float], distance: torch.Tensor) -> torch.Tensor:
    el = torch.deg2rad(_uniform(gen, *elevation))
    az = _uniform(gen, 0.0, 2 * math.pi)
    return torch.cat([torch.cos(el) * torch.cos(az), torch.cos(el) * torch.sin(az), torch.sin(el)]) * distance


def _jpeg(codes: np.ndarray, quality: int) -> np.ndarray:
    """8-bit ``(H, W, 3)`` codes through a JPEG of ``quality`` and back."""
    buf = io.BytesIO()
    Image.fromarray(codes).save(buf, format="JPEG", quality=int(quality))
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB")).copy()


@dataclass(frozen=True)
class RealisticCapture:
    """One capture of a :class:`RealisticSet` (module docstring)."""

    split: str  #: "tune" or "test"
    realism: str  #: "real" or "clean"
    material: int  #: material index m in its split
    cls: str  #: the material's procedural class
    n_images: int  #: N
    maps: torch.Tensor  #: (1, 10, S, S) the truth
    images: torch.Tensor  #: (N, 3, S, S) linear photos, as load_capture returns them
    valid: torch.Tensor  #: (N, 1, S, S) bool, False where a channel is saturated
    stated: CaptureSpec  #: what the capture file says
    true: CaptureSpec  #: true positions and intensity x gain (vignetting and the unmodelled light are not in it)
    errors: dict[str, Any]  #: the injected errors (JSON-ready)
    heldout_light: torch.Tensor  #: (1, K, 3) held-out light positions
    heldout_view: torch.Tensor  #: (1, K, 3) held-out camera positions
    heldout_intensity: float  #: intensity of the held-out lights
    heldout_truth: torch.Tensor = field(repr=False)  #: (K, 3, S, S) display values of the truth under them

    def heldout_display(self, maps: torch.Tensor) -> torch.Tensor:
        """Display values ``(K, 3, S, S)`` (sRGB of the clipped radiance) of ``maps`` under the held-out views."""
        with torch.no_grad():
            radiance = render(maps.detach().float().cpu(), self.heldout_light, self.heldout_view,
                              intensity=self.heldout_intensity, distance_falloff=True, backend="torch")[0]
        return torch.from_numpy(srgb_encode(radiance.clamp(0.0, 1.0).double().numpy()))

    def heldout_error(self, maps: torch.Tensor) -> float:
        """Display RMSE of ``maps`` ``(1, 10, S, S)`` against the truth under the held-out views."""
        return float((self.heldout_display(maps) - self.heldout_truth).square().mean().sqrt())

    def map_errors(self, maps: torch.Tensor) -> dict[str, float]:
        """Per-map RMSE of ``maps`` ``(1, 10, S, S)`` against the truth."""
        m = maps.detach().float().cpu()
        return {name: float((m[:, SLICES[name]] - self.maps[:, SLICES[name]]).square().mean().sqrt())
                for name in MAP_NAMES}

    def save(self, folder: str | Path) -> Path:
        """Write the photos and the *stated* capture file to ``folder`` (plus ``truth.json``: the true
        calibration and the injected errors); returns the capture file's path."""
        folder = Path(folder)
        path = folder / "capture.json"
        save_capture(path, self.stated, self.images)
        write_json(folder / "truth.json", {"class": self.cls, "material": self.material, "split": self.split,
                                           "realism": self.realism, "true": self.true.to_dict(),
                                           "errors": self.errors})
        return path


@dataclass
class RealisticSet:
    """The realistic captures of one split: ``materials`` x ``n_images`` captures (module docstring)."""

    split: str = "test"  #: "tune" (choose defaults on it) or "test" (report on it)
    size: int = 256  #: S, side of the rectified photos and maps, >= 8
    materials: int = 4  #: materials (SPLIT_CLASSES in turn), >= 1
    n_images: tuple[int, ...] = (3, 5, 10)  #: photo counts N, each >= 1
    realism: str = "real"  #: "real" (the stated calibration is wrong) or "clean" (the twin: stated exactly)
    cache: bool = True  #: keep the captures in cache_dir (keyed by every setting)
    cache_dir: str | None = None  #: None: ~/.cache/mi_svbrdf/realistic ($MI_SVBRDF_CACHE)

    def __post_init__(self) -> None:
        if self.split not in SPLIT_SEEDS:
            raise ValueError(f"split: expected one of {tuple(SPLIT_SEEDS)}, got {self.split!r}")
        if self.realism not in REALISMS:
            raise ValueError(f"realism: expected one of {REALISMS}, got {self.realism!r}")
        if not (isinstance(self.size, int) and self.size >= 8):
            raise ValueError(f"size: expected an int >= 8, got {self.size!r}")
        if not (isinstance(self.materials, int) and self.materials >= 1):
            raise ValueError(f"materials: expected an int >= 1, got {self.materials!r}")
        self.n_images = tuple(self.n_images)
        if not self.n_images or not all(isinstance(n, int) and n >= 1 for n in self.n_images):
            raise ValueError(f"n_images: expected photo counts >= 1, got {self.n_images!r}")

    def key(self) -> str:
        """Cache key: a hash of the settings that change the captures."""
        settings = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("cache", "cache_dir")}
        settings.update(version=VERSION, torch=torch.__version__.split("+")[0])
        return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]

    def _path(self) -> Path:
        root = Path(self.cache_dir) if self.cache_dir else default_cache_dir("realistic")
        return root / f"realistic_{self.split}_{self.realism}_{self.size}px_{self.materials}m_{self.key()}.pt"

    def captures(self, progress: bool = True) -> list[RealisticCapture]:
        """Every capture, materials outer, N inner; identical at every call (cached)."""
        path = self._path()
        if self.cache and path.is_file():
            return torch.load(path, weights_only=False)
        caps = [self.capture(m, n) for m in tqdm(range(self.materials), desc=f"realistic {self.split}",
                                                   disable=not progress) for n in self.n_images]
        if self.cache:
            from mi_svbrdf.io.atomic import atomic_path

            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                torch.save(caps, tmp)
        return caps

    def material_maps(self, m: int) -> tuple[str, torch.Tensor]:
        """``(class, maps (1, 10, S, S))`` of material ``m``: a held-out material of its class."""
        classes = SPLIT_CLASSES[self.split]
        cls = classes[m % len(classes)]
        index = CLASS_ORDER.index(cls) + len(CLASS_ORDER) * (m // len(classes))  # HeldOutSet's material of that class
        held = HeldOutSet(size=self.size, materials=1, n_images=1, seed=SPLIT_SEEDS[self.split], cache=False)
        return cls, held.material(index)["maps"].float()

    def capture(self, m: int, n: int) -> RealisticCapture:
        """Capture of material ``m`` with ``n`` photos (module docstring)."""
        if not (isinstance(m, int) and m >= 0) or not (isinstance(n, int) and n >= 1):
            raise ValueError(f"m, n: expected an int >= 0 and an int >= 1, got {m!r}, {n!r}")
        cls, maps = self.material_maps(m)
        state = np.random.SeedSequence([SPLIT_SEEDS[self.split], m, n]).generate_state(1, dtype=np.uint64)[0]
        gen = torch.Generator().manual_seed(int(state))
        d = _draw(gen, n)
        real = self.realism == "real"
        s = self.size
        cams, lights = d["camera"], d["light"]
        intensity = WHITE_LEVEL * float(cams[0].square().sum())  # I / d^2 * 1 (white, facing) = WHITE_LEVEL
        gains = d["gain"] if real else torch.ones(n, 3, dtype=torch.float64)
        true_ims, stated_ims = [], []
        for k in range(n):
            cam, light = cams[k], lights[k]
            true_i = tuple(float(intensity * g) for g in gains[k])
            true_ims.append(ImageSpec(f"{k:03d}.png", "srgb8", True, CameraSpec(tuple(cam.tolist()), float(d["fov"][k])),
                                      LightSpec(tuple(light.tolist()), true_i)))
            said = d["stated_camera"][k] if real else cam
            said_light = said if real else light
            stated_ims.append(ImageSpec(f"{k:03d}.png", "srgb8", True,
                                        CameraSpec(tuple(said.tolist()), float(d["fov"][k])),
                                        LightSpec(tuple(said_light.tolist()), (intensity,) * 3)))
        true, stated = CaptureSpec(tuple(true_ims)), CaptureSpec(tuple(stated_ims))
        f32 = torch.float32
        radiance = render(maps, torch.stack(list(lights))[None].to(f32), torch.stack(list(cams))[None].to(f32),
                          intensity=(intensity * gains)[None].to(f32), distance_falloff=True, backend="torch")[0]
        if real:
            pos = texel_positions(s, s, dtype=torch.float64)
            radiance = radiance * _vignetting(cams, pos, d["vignetting"]).to(f32)
            amb = render(maps, d["ambient_light"][None, None].to(f32).expand(1, n, 3).contiguous(),
                         torch.stack(list(cams))[None].to(f32),
                         intensity=(d["ambient_intensity"] * intensity / float(cams[0].square().sum())
                                    * gains)[None].to(f32), backend="torch")[0]
            radiance = radiance + amb
        noisy = (radiance.double() + NOISE_STD * torch.randn(radiance.shape, generator=gen, dtype=torch.float64))
        codes = np.round(srgb_encode(noisy.clamp(0.0, 1.0).permute(0, 2, 3, 1).numpy()) * 255.0).astype(np.uint8)
        if real:
            codes = np.stack([_jpeg(c, int(q)) for c, q in zip(codes, d["jpeg_quality"])])
        valid = torch.from_numpy((codes < 255).all(axis=-1))[:, None]
        images = torch.from_numpy(srgb_decode(codes.astype(np.float64) / 255.0)).permute(0, 3, 1, 2).to(f32)
        offset = d["flash_offset"]
        errors = {
            "flash_offset_units": [float(offset[0]), float(offset[1]), 0.0] if real else [0.0, 0.0, 0.0],
            "flash_offset_mm": float(offset.norm()) * MM_PER_UNIT if real else 0.0,
            "gains": gains.tolist(),
            "exposure_stops": (gains.log().mean(dim=1) / math.log(2.0)).tolist(),
            "camera_error": (d["stated_camera"] - cams).tolist() if real else [[0.0] * 3] * n,
            "camera_error_fraction": ((d["stated_camera"] - cams).norm(dim=1) / cams.norm(dim=1)).tolist()
            if real else [0.0] * n,
            "vignetting": d["vignetting"].tolist() if real else [0.0] * n,
            "jpeg_quality": [int(q) for q in d["jpeg_quality"]] if real else None,
            "unmodelled_light": {"position": d["ambient_light"].tolist(),
                                 "relative_intensity": float(d["ambient_intensity"])} if real else None,
        }
        hl, hv = d["heldout_light"][None].to(f32), d["heldout_view"][None].to(f32)
        cap = RealisticCapture(self.split, self.realism, m, cls, n, maps, images, valid, stated, true, errors,
                               hl, hv, intensity, torch.empty(0))
        return dataclasses.replace(cap, heldout_truth=cap.heldout_display(maps))


def _vignetting(cams: torch.Tensor, pos: torch.Tensor, strength: torch.Tensor) -> torch.Tensor:
    """``(N, 1, H, W)`` factors ``1 - v (tan t / tan t_max)^2`` (module docstring)."""
    out = []
    corners = torch.tensor([[-1.0, -1.0, 0.0], [-1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0]], dtype=pos.dtype)
    for cam, v in zip(cams, strength):
        axis = -cam / cam.norm()

        def tan2(points: torch.Tensor) -> torch.Tensor:  # (..., 3) -> tan^2 of the angle to the axis
            ray = points - cam
            cos = (ray * axis).sum(-1) / ray.norm(dim=-1)
            return (1.0 - cos.square()).clamp_min(0.0) / cos.square()

        t2 = tan2(pos.permute(1, 2, 0))
        out.append(1.0 - v * t2 / tan2(corners).max())
    return torch.stack(out)[:, None]


def _draw(gen: torch.Generator, n: int) -> dict[str, torch.Tensor]:
    """Every random number of one capture, in a fixed order (module docstring)."""
    fov = _uniform(gen, 45.0, 65.0, n)
    dist = 1.0 / torch.tan(torch.deg2rad(fov / 2))
    cams = []
    for k in range(n):
        if k == 0:
            xy = _uniform(gen, -0.3, 0.3, 2)
            cams.append(torch.cat([xy, dist[:1]]))
            _uniform(gen, 0.0, 1.0, 2)  # keeps the draws aligned with the hemisphere's two
        else:
            cams.append(_hemisphere(gen, (45.0, 80.0), dist[k]))
    cams_t = torch.stack(cams)
    mag = _uniform(gen, 5.0, 25.0) / MM_PER_UNIT
    angle = _uniform(gen, 0.0, 2 * math.pi)
    offset = torch.cat([torch.cos(angle), torch.sin(angle)]) * mag
    right, up, _ = camera_frame(cams_t)
    lights = cams_t + offset[0] * right + offset[1] * up
    err_dir = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=torch.float64), dim=1)
    err = err_dir * _uniform(gen, 0.0, 0.03, n)[:, None] * cams_t.norm(dim=1, keepdim=True)
    stops = _uniform(gen, -0.7, 0.7, n)
    wb = _uniform(gen, 0.9, 1.1, n, 3)
    gain = (2.0 ** stops)[:, None] * wb
    gain = gain / gain.log().mean(dim=0, keepdim=True).exp()
    vignetting = _uniform(gen, 0.0, 0.3, n)
    quality = torch.randint(70, 96, (n,), generator=gen)
    ambient = _hemisphere(gen, (30.0, 70.0), torch.tensor(20.0, dtype=torch.float64))
    ambient_intensity = _uniform(gen, 0.0, 0.03)[0]
    heldout_view = torch.stack([_hemisphere(gen, (30.0, 80.0), dist.mean()) for _ in range(HELD_OUT_VIEWS)])
    heldout_light = torch.stack([_hemisphere(gen, (30.0, 80.0), dist.mean()) for _ in range(HELD_OUT_VIEWS)])
    return {"fov": fov, "camera": cams_t, "light": lights, "flash_offset": offset, "stated_camera": cams_t + err,
            "gain": gain, "vignetting": vignetting, "jpeg_quality": quality, "ambient_light": ambient,
            "ambient_intensity": ambient_intensity, "heldout_view": heldout_view, "heldout_light": heldout_light}
