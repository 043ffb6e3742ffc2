"""Synthetic real-world photos of a framed sample: the test bench of ``mi-svbrdf rectify``.

Mitsuba renders a perspective photo of a material (the ``svbrdf_ggx`` plugin on the
``[-1, 1]^2`` plane) inside a white paper frame (:data:`mi_svbrdf.geometry.frame.DEFAULT_FRAME`: an
A4 sheet with a square window, diffuse albedo :data:`PAPER_ALBEDO`) lying on a darker,
mottled table, lit by the flash only (a point light at the camera, plus an optional offset in
the camera's frame), from a random camera (:func:`sample_pose`): tilt up to 40 degrees from
the vertical, any azimuth, any rotation about the optical axis, field of view 40-70 degrees
(across the photo's long side) and a distance at which the whole sheet is in view (times
1-1.3). The photo pipeline: linear radiance + Gaussian noise, clipped, sRGB-encoded
(colour-science), 8-bit.

Units and conventions are the capture file's: the window's inside is ``[-1, 1]^2`` at z = 0,
+y up; the flash intensity follows the plugin (the emitter's intensity is ``pi * I``) and its
default is ``I = |light|^2``, the default of ``mi-svbrdf rectify`` (an auto-exposed photo: a
white Lambertian texel at the centre, facing the flash, reads 1). Ground-truth corners are in
OpenCV pixel coordinates (centre of the top-left pixel at (0, 0)), top-left first, clockwise.

:func:`ideal_captures` gives the same cameras and flashes as the capture simulator's
:class:`~mi_svbrdf.data.photo_setups.Captures` (no cone, no ambient light): the "ideally
rectified" photos of the same material.

Examples:
    >>> import numpy as np
    >>> pose = sample_pose(np.random.default_rng(0), width=320, height=240)
    >>> corners = project(pose, np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    >>> corners.shape
    (2, 2)
"""
from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import mitsuba as mi
import numpy as np
import torch

from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.geometry.frame import DEFAULT_FRAME, FrameSpec
from mi_svbrdf.geometry.poses import focal_35mm_of, focal_px_of_fov, fov_of_focal_35mm
from mi_svbrdf.geometry.rectify import EXIF_IFD, FOCAL_35MM_TAG
from mi_svbrdf.io.atomic import atomic_path
from mi_svbrdf.io.photos import ORIENTATION_TAG
from mi_svbrdf.scenes import material_bsdf
from mi_svbrdf.variant import scene_variant

#: Diffuse albedo of the paper.
PAPER_ALBEDO = 0.7
#: Range of the table's diffuse albedo (a smooth random pattern).
TABLE_ALBEDO = (0.06, 0.2)
#: Height of the table below the sample plane (the paper lies on the sample's level).
TABLE_DEPTH = 0.02


@dataclass(frozen=True)
class FramePose:
    """A pinhole camera looking at the framed sample (sample frame, +z above the plane)."""

    camera: tuple[float, float, float]  #: position
    target: tuple[float, float, float]  #: look-at point on the plane
    up: tuple[float, float, float]  #: up vector of the image, orthogonal to the viewing direction
    fov_deg: float  #: field of view across the photo's long side
    width: int  #: photo width, pixels
    height: int  #: photo height, pixels

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(right, up, forward)`` unit vectors of the image."""
        fwd = np.asarray(self.target, float) - np.asarray(self.camera, float)
        fwd /= np.linalg.norm(fwd)
        up = np.asarray(self.up, float)
        up = up - fwd * np.dot(up, fwd)
        up /= np.linalg.norm(up)
        return np.cross(fwd, up), up, fwd

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return focal_px_of_fov(self.fov_deg, self.width, self.height)


def project(pose: FramePose, points: np.ndarray) -> np.ndarray:
    """OpenCV pixel coordinates ``(N, 2)`` of world points ``(N, 3)`` in the photo of ``pose``."""
    right, up, fwd = pose.basis()
    q = np.asarray(points, float) - np.asarray(pose.camera, float)[None]
    z = q @ fwd
    f = pose.focal_px
    u = 0.5 * pose.width + f * (q @ right) / z - 0.5
    v = 0.5 * pose.height - f * (q @ up) / z - 0.5
    return np.stack([u, v], axis=1)


def save_photo(path: str | os.PathLike, image: np.ndarray, *, focal_35mm: float | None = None,
               orientation: int = 1, quality: int = 95) -> None:
    """Write an 8-bit photo ``(H, W, 3)`` (PNG or JPEG by suffix; JPEG at ``quality``) with EXIF tags.

    Args:
        path: target file.
        image: uint8 sRGB pixels as stored (before any EXIF orientation).
        focal_35mm: EXIF FocalLengthIn35mmFilm (rounded to whole mm, as EXIF stores it), or None.
        orientation: EXIF orientation tag (1: upright).
    """
    from PIL import Image

    exif = Image.Exif()
    if orientation != 1:
        exif[ORIENTATION_TAG] = int(orientation)
    if focal_35mm is not None:
        exif.get_ifd(EXIF_IFD)[FOCAL_35MM_TAG] = round(focal_35mm)
    extra = {"quality": int(quality)} if str(path).lower().endswith((".jpg", ".jpeg")) else {}
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(image)).save(tmp, format=None if extra == {} else "JPEG",
                                                          exif=exif.tobytes(), **extra)


def _sheet_corners(frame: FrameSpec) -> np.ndarray:
    x0, x1, y0, y1 = frame.sheet_plane()
    return np.array([[x0, y1, 0.0], [x1, y1, 0.0], [x1, y0, 0.0], [x0, y0, 0.0]])


def sample_pose(rng: np.random.Generator, *, width: int = 640, height: int = 480, max_tilt_deg: float = 40.0,
                fov_range: tuple[float, float] = (40.0, 70.0), frame: FrameSpec = DEFAULT_FRAME,
                margin: float = 0.04, extra_distance: tuple[float, float] = (1.0, 1.3),
                integer_focal_35mm: bool = False, roll_deg: tuple[float, float] | None = None) -> FramePose:
    """A random camera that sees the whole sheet.

    Tilt ``U(0, max_tilt_deg)`` from the vertical, azimuth uniform, roll uniform (``roll_deg``:
    ``U(*roll_deg)`` degrees, 0 the sheet's long side along the photo's vertical, 90 along its
    horizontal, as a landscape photo framing the sheet holds it), FOV
    ``U(*fov_range)`` (with ``integer_focal_35mm``, moved to the nearest FOV whose 35 mm-
    equivalent focal length is a whole number of mm, as EXIF stores it); aimed at a random
    point between the window's centre and the sheet's; distance: the smallest at which every
    sheet corner is ``margin`` (fraction of the image) inside the photo, times ``U(*extra_distance)``.
    """
    tilt = math.radians(rng.uniform(0.0, max_tilt_deg))
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    roll = rng.uniform(0.0, 2.0 * math.pi) if roll_deg is None else math.radians(rng.uniform(*roll_deg))
    fov = float(rng.uniform(*fov_range))
    if integer_focal_35mm:
        fov = fov_of_focal_35mm(round(focal_35mm_of(fov, width, height)), width, height)
    _, _, y0, y1 = frame.sheet_plane()
    t = rng.uniform(0.2, 0.7)
    target = np.array([rng.uniform(-0.15, 0.15), t * 0.5 * (y0 + y1), 0.0])
    direction = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
    fwd = -direction
    base = np.array([0.0, 1.0, 0.0]) - fwd * fwd[1]
    base /= np.linalg.norm(base)
    side = np.cross(fwd, base)
    up = math.cos(roll) * base + math.sin(roll) * side
    sheet = _sheet_corners(frame)

    def fits(d: float) -> bool:
        pose = FramePose(tuple(target + d * direction), tuple(target), tuple(up), fov, width, height)
        if np.any((sheet - np.asarray(pose.camera)[None]) @ fwd <= 0.1):
            return False
        uv = project(pose, sheet)
        mx, my = margin * width, margin * height
        return bool((uv[:, 0] >= mx).all() and (uv[:, 0] <= width - 1 - mx).all()
                    and (uv[:, 1] >= my).all() and (uv[:, 1] <= height - 1 - my).all())

    lo, hi = 0.5, 200.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    d = hi * float(rng.uniform(*extra_distance))
    return FramePose(tuple(float(v) for v in target + d * direction), tuple(float(v) for v in target),
                     tuple(float(v) for v in up), fov, width, height)


def _rect(x0: float, x1: float, y0: float, y1: float, z: float, bsdf: dict) -> dict:
    to_world = mi.ScalarTransform4f().translate([0.5 * (x0 + x1), 0.5 * (y0 + y1), z]).scale(
        [0.5 * (x1 - x0), 0.5 * (y1 - y0), 1.0])
    return {"type": "rectangle", "to_world": to_world, "bsdf": bsdf}


#: Rows of a photo noised and encoded at once (:func:`photo_pipeline`: a 12 MP photo in bands, not 1 GB of temporaries).
BAND_ROWS = 128


def photo_pipeline(radiance: np.ndarray, noise_std: float, seed: int) -> np.ndarray:
    """The photo pipeline of the synthetic photos: linear ``radiance (H, W, 3)`` + Gaussian noise (``seed``),
    clipped, sRGB-encoded, 8-bit: ``(H, W, 3)`` uint8.

    Bit for bit ``rint(srgb_encode(clip(radiance + noise, 0, 1)) * 255)`` with the noise drawn at once
    (:func:`mi_svbrdf.io.material_io.srgb_encode`'s sRGB curve in float64, then float32, as colour-science
    computes it), in bands of :data:`BAND_ROWS` rows: a phone-sized photo in about a second and no large
    temporaries.
    """
    rng = np.random.default_rng(seed)
    out = np.empty(radiance.shape, np.uint8)
    for r0 in range(0, radiance.shape[0], BAND_ROWS):
        band = radiance[r0:r0 + BAND_ROWS]
        x = np.clip(band + rng.normal(0.0, noise_std, band.shape).astype(np.float32), 0.0, 1.0).astype(np.float64)
        encoded = np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(np.float32)
        out[r0:r0 + BAND_ROWS] = np.clip(np.rint(encoded * 255.0), 0, 255).astype(np.uint8)
    return out


def _table_texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    coarse = torch.from_numpy(rng.uniform(0.0, 1.0, (1, 1, 12, 12)).astype(np.float32))
    fine = torch.nn.functional.interpolate(coarse, size=(256, 256), mode="bicubic", align_corners=False)[0, 0]
    lo, hi = TABLE_ALBEDO
    tint = np.array([1.0, 0.85, 0.7], np.float32)  # a brownish table
    return np.ascontiguousarray((lo + (hi - lo) * fine.clamp(0, 1).numpy())[..., None] * tint[None, None])


@dataclass
class FramePhoto:
    """A synthetic photo and its ground truth.

    Attributes:
        image: ``(H, W, 3)`` uint8, sRGB-encoded.
        corners: ``(4, 2)`` window corners (OpenCV pixels), top-left, top-right, bottom-right, bottom-left.
        pose: the camera.
        light: flash position (sample frame).
        intensity: flash intensity I (the emitter's is ``pi * I``).
        noise_std: std of the linear noise added.
    """

    image: np.ndarray
    corners: np.ndarray
    pose: FramePose
    light: tuple[float, float, float]
    intensity: float
    noise_std: float


def render_frame_photo(maps: torch.Tensor, pose: FramePose, *, flash_offset: Sequence[float] = (0.0, 0.0, 0.0),
                       intensity: float | None = None, frame: FrameSpec = DEFAULT_FRAME, spp: int = 16,
                       noise_std: float = 0.004, seed: int = 0) -> FramePhoto:
    """Render one framed photo of ``maps`` (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` material of the window.
        pose: the camera (:func:`sample_pose`).
        flash_offset: flash position from the camera in its frame (x right, y up, z forward), sample units.
        intensity: flash intensity I; None: ``|light|^2``.
        frame: the paper frame.
        spp: samples per pixel (box filter: antialiased edges).
        noise_std: linear Gaussian noise std before the 8-bit sRGB encoding.
        seed: seed of the noise, the table pattern and the sampler.
    """
    right, up, fwd = pose.basis()
    off = np.asarray(flash_offset, float)
    light = np.asarray(pose.camera, float) + off[0] * right + off[1] * up + off[2] * fwd
    if light[2] <= 0:
        raise ValueError(f"flash_offset: expected the flash above the sample, got light z = {light[2]:.3f}")
    inten = float(light @ light) if intensity is None else float(intensity)
    with scene_variant("cpu"):  # a Mitsuba scene (its dict too) is bound to a variant; the photo is a numpy array
        x0, x1, y0, y1 = frame.sheet_plane()
        paper = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [PAPER_ALBEDO] * 3}}
        table = {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(_table_texture(seed)),
                                                     "raw": True, "wrap_mode": "mirror"}}
        scene = {
            "type": "scene",
            "integrator": {"type": "direct"},
            "sensor": {"type": "perspective", "fov": float(pose.fov_deg), "fov_axis": "larger",
                       "to_world": mi.ScalarTransform4f().look_at(origin=list(pose.camera), target=list(pose.target),
                                                                  up=list(map(float, up))),
                       "sampler": {"type": "independent", "sample_count": int(spp)},
                       "film": {"type": "hdrfilm", "width": int(pose.width), "height": int(pose.height),
                                "pixel_format": "rgb", "rfilter": {"type": "box"}}},
            "sample": {"type": "rectangle", "bsdf": material_bsdf(maps, filter_type="bilinear")},
            "paper_top": _rect(x0, x1, 1.0, y1, 0.0, paper),
            "paper_bottom": _rect(x0, x1, y0, -1.0, 0.0, paper),
            "paper_left": _rect(x0, -1.0, -1.0, 1.0, 0.0, paper),
            "paper_right": _rect(1.0, x1, -1.0, 1.0, 0.0, paper),
            "table": _rect(-40.0, 40.0, -40.0, 40.0, -TABLE_DEPTH, table),
            "flash": {"type": "point", "position": [float(v) for v in light],
                      "intensity": {"type": "rgb", "value": math.pi * inten}},
        }
        # loaded on one thread: Mitsuba's parallel loading of the bitmaps was seen to hang beside another thread
        # calling into Dr.Jit (a test's kernel recorder), and the scene is a handful of objects
        scene = mi.load_dict(scene, parallel=False)
        radiance = np.array(mi.render(scene, seed=int(seed) % (2 ** 31)), dtype=np.float32)
    image = photo_pipeline(radiance, noise_std, seed)
    window = np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])
    return FramePhoto(image, project(pose, window), pose, tuple(float(v) for v in light), inten, noise_std)


def ideal_captures(photos: Sequence[FramePhoto]) -> Captures:
    """The capture simulator's calibration of the same cameras and flashes (B = 1, N photos).

    No cone, no ambient light, the same intensities and noise std; ``fov``/``distance`` are
    those of a frame spanning the sample from each camera's distance (as the simulator's).
    """
    view = torch.tensor([[p.pose.camera for p in photos]], dtype=torch.float32)
    light = torch.tensor([[p.light for p in photos]], dtype=torch.float32)
    n = len(photos)
    intensity = torch.tensor([[[p.intensity] * 3 for p in photos]], dtype=torch.float32)
    distance = view.norm(dim=-1)
    fov = torch.rad2deg(2.0 * torch.atan(1.0 / distance))
    return Captures(light=light, view=view, intensity=intensity, cone_target=torch.zeros(1, n, 3),
                    cone_exponent=torch.zeros(1, n), ambient_light=torch.zeros(1, 0, 3),
                    ambient_intensity=torch.zeros(1, 0, 3),
                    noise_std=torch.tensor([float(np.mean([p.noise_std for p in photos]))]),
                    fov=fov, distance=distance, flash=True, cone=False, photo=True)
