"""Synthetic photos of a sample under the AprilTag print, with their true cameras: the bench of ``--frame tags``.

Two renderers of the same scene (:mod:`mi_svbrdf.geometry.tags`: the print's ring of tags on white
paper at z = ``depth``, the sample's window ``[-1, 1]^2`` at z = 0 seen through its cut, a darker
table around the sheet):

* :func:`project_photo`: a fast ray-cast in numpy / OpenCV through a full OpenCV camera
  (:class:`TrueCamera`: focal length, principal point, radial distortion), textures looked up
  bilinearly at ``supersample``\\ :sup:`2` rays per pixel, Lambertian shading by a flash at the
  camera; for tests of the detection, the calibration and the poses.
* :func:`render_tag_photo`: Mitsuba (as :func:`mi_svbrdf.data.frame_photos.render_frame_photo`),
  a material of the ``svbrdf_ggx`` plugin in the window, the print as textured paper, flash at
  the camera; for ``mi-svbrdf rectify example --frame tags``.

Units are the capture file's (window half-side 1); pixels OpenCV's. The photo pipeline of both:
linear radiance + Gaussian noise, clipped, sRGB-encoded (colour-science), 8-bit.

Examples:
    >>> import numpy as np
    >>> cam = look_at((0.0, -1.5, 4.0), focal=500.0, size=(320, 240))
    >>> cam.position.round(6).tolist()
    [0.0, -1.5, 4.0]
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from mi_svbrdf.geometry.tags import RING_UNITS, WINDOW_HALF_UNITS, sheet_image
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode

#: Diffuse albedo of the print's paper (its black ink: PAPER_ALBEDO * INK).
PAPER_ALBEDO, INK = 0.75, 0.06
#: White paper beyond the ring's outer edges, sheet units.
SHEET_MARGIN_UNITS = 2.0
#: Albedo of the table around the sheet.
TABLE_ALBEDO = 0.12


@dataclass(frozen=True)
class TrueCamera:
    """An OpenCV camera looking at the print (capture frame: sample at z = 0, +z up).

    Attributes:
        matrix: ``(3, 3)`` camera matrix.
        distortion: ``(5,)`` k1, k2, p1, p2, k3.
        rotation: ``(3, 3)`` capture frame -> camera frame.
        translation: ``(3,)``.
        size: ``(W, H)`` pixels.
    """

    matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    size: tuple[int, int]

    @property
    def position(self) -> np.ndarray:
        """``(3,)`` the camera's centre in the capture frame."""
        return -self.rotation.T @ self.translation

    def project(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixels of capture-frame points ``(N, 3)``."""
        rvec, _ = cv2.Rodrigues(self.rotation)
        proj, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), rvec, self.translation,
                                    self.matrix, self.distortion)
        return proj.reshape(-1, 2)


def look_at(position: Sequence[float], *, focal: float, size: tuple[int, int], target: Sequence[float] = (0, 0, 0),
            roll_deg: float = 0.0, principal: Sequence[float] | None = None,
            distortion: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> TrueCamera:
    """A camera at ``position`` aimed at ``target``, the image's up towards +y turned by ``roll_deg``.

    Args:
        position: camera centre (capture frame).
        focal: focal length, pixels (square pixels).
        size: ``(W, H)``.
        target: the point seen at the principal point.
        roll_deg: rotation about the optical axis.
        principal: ``(cx, cy)`` pixels; None: the image centre.
        distortion: OpenCV's k1, k2, p1, p2, k3.
    """
    c = np.asarray(position, np.float64)
    fwd = np.asarray(target, np.float64) - c
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, 1.0, 0.0]) - fwd * fwd[1]
    if np.linalg.norm(up) < 1e-6:
        up = np.array([0.0, 0.0, 1.0]) - fwd * fwd[2]
    up /= np.linalg.norm(up)
    right = np.cross(fwd, up)
    a = math.radians(roll_deg)
    right, up = math.cos(a) * right + math.sin(a) * up, -math.sin(a) * right + math.cos(a) * up
    rot = np.stack([right, -up, fwd])  # OpenCV camera: x right, y down, z forward
    w, h = size
    cx, cy = (0.5 * (w - 1), 0.5 * (h - 1)) if principal is None else principal
    k = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
    return TrueCamera(k, np.asarray(distortion, np.float64), rot, -rot @ c, (int(w), int(h)))


def sample_camera(rng: np.random.Generator, *, focal: float, size: tuple[int, int],
                  tilt_deg: tuple[float, float] = (15.0, 40.0), depth: float = 0.0, margin: float = 0.05,
                  extra_distance: tuple[float, float] = (1.0, 1.15),
                  principal: Sequence[float] | None = None,
                  distortion: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0), roll_deg: float = 30.0,
                  framed_units: float | None = None) -> TrueCamera:
    """A random camera that sees the whole sheet: tilt ``U(*tilt_deg)`` from the vertical, azimuth uniform, roll
    within ``roll_deg`` degrees, aimed near the window's centre, at the nearest distance keeping the sheet's corners
    ``margin`` (fraction of the image) inside the photo, times ``U(*extra_distance)``. ``framed_units``: keep only
    the square of that half-side (sheet units from the centre: :data:`~mi_svbrdf.geometry.tags.RING_UNITS` / 2
    plus a quiet zone frames the tags as a phone photo that fills its frame with them) in the photo instead of the
    whole sheet."""
    tilt = math.radians(rng.uniform(*tilt_deg))
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    roll = rng.uniform(-roll_deg, roll_deg)
    target = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 0.0])
    direction = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
    _, half = sheet_texture(1)
    if framed_units is not None:
        half = framed_units / WINDOW_HALF_UNITS
    corners = np.array([[x, y, depth] for x in (-half, half) for y in (-half, half)])
    w, h = size

    def camera(d: float) -> TrueCamera:
        return look_at(target + d * direction, focal=focal, size=size, target=target, roll_deg=roll,
                       principal=principal, distortion=distortion)

    def fits(d: float) -> bool:
        cam = camera(d)
        if np.any((corners - cam.position[None]) @ cam.rotation[2] <= 0.1):
            return False
        uv = cam.project(corners)
        return bool((uv[:, 0] >= margin * w).all() and (uv[:, 0] <= (1 - margin) * w).all()
                    and (uv[:, 1] >= margin * h).all() and (uv[:, 1] <= (1 - margin) * h).all())

    lo, hi = 0.5, 100.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return camera(hi * float(rng.uniform(*extra_distance)))


def sheet_texture(cells_px: int = 8) -> tuple[np.ndarray, float]:
    """``(albedo (N, N) float32, half extent in capture units)`` of the print: paper and ink, ring and margin."""
    img, _, _ = sheet_image(cells_px, SHEET_MARGIN_UNITS)
    albedo = PAPER_ALBEDO * np.where(img > 127, 1.0, INK).astype(np.float32)
    return albedo, (RING_UNITS / 2.0 + SHEET_MARGIN_UNITS) / WINDOW_HALF_UNITS


def _lookup(texture: np.ndarray, x: np.ndarray, y: np.ndarray, half: float) -> np.ndarray:
    """Bilinear ``texture (N, M, C)`` spanning ``[-half, half]^2`` (row 0 at +y) at plane points ``x, y``."""
    h, w = texture.shape[:2]
    u = ((x + half) / (2.0 * half) * w - 0.5).astype(np.float32)
    v = ((half - y) / (2.0 * half) * h - 0.5).astype(np.float32)
    out = cv2.remap(np.ascontiguousarray(texture, np.float32), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(x.shape + texture.shape[2:])


def project_photo(camera: TrueCamera, sample: np.ndarray, *, depth: float = 0.0, supersample: int = 3,
                  noise_std: float = 0.003, blur_px: float = 0.0, seed: int = 0,
                  cells_px: int = 8) -> np.ndarray:
    """A photo of the print over ``sample`` through ``camera`` (see the module docstring): ``(H, W, 3)`` uint8 sRGB.

    Args:
        camera: the true camera.
        sample: ``(h, w, 3)`` linear albedo of the window ``[-1, 1]^2`` (row 0 at +y).
        depth: the tag plane's height above the sample, capture units.
        supersample: rays per pixel along each axis (box filter).
        noise_std: linear Gaussian noise std.
        blur_px: Gaussian blur sigma (defocus), pixels.
        seed: the noise's seed.
        cells_px: texture pixels per tag cell.
    """
    w, h = camera.size
    s = int(supersample)
    # The rays' normalised coordinates: OpenCV's iterative undistortion on a grid of every STEP-th sample, then
    # cubic interpolation (the map is smooth).
    step = 4
    gw, gh = w * s // step + 2, h * s // step + 2
    gu = (np.arange(gw) * step + 0.5) / s - 0.5
    gv = (np.arange(gh) * step + 0.5) / s - 0.5
    grid = np.stack(np.meshgrid(gu, gv), axis=-1).reshape(-1, 1, 2)
    coarse = cv2.undistortPoints(grid, camera.matrix, camera.distortion, None, None,
                                 criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 40, 1e-10))
    coarse = coarse.reshape(gh, gw, 2)
    fine_x = (np.arange(w * s) / step).astype(np.float32)
    fine_y = (np.arange(h * s) / step).astype(np.float32)
    mx, my = np.meshgrid(fine_x, fine_y)
    norm = cv2.remap(coarse.astype(np.float64).astype(np.float32), mx, my, cv2.INTER_CUBIC).reshape(-1, 2)
    norm = norm.astype(np.float64)
    rays = np.concatenate([norm, np.ones((len(norm), 1))], axis=1) @ camera.rotation  # rows: R^T d
    centre = camera.position
    with np.errstate(divide="ignore", invalid="ignore"):
        t_sheet = (depth - centre[2]) / rays[:, 2]
        t_sample = -centre[2] / rays[:, 2]
    p_sheet = centre[None] + t_sheet[:, None] * rays
    p_sample = centre[None] + t_sample[:, None] * rays
    albedo_sheet, half = sheet_texture(cells_px)
    shape = (h * s, w * s)
    xs, ys = p_sheet[:, 0].reshape(shape), p_sheet[:, 1].reshape(shape)
    in_window = (np.abs(xs) <= 1.0) & (np.abs(ys) <= 1.0)
    on_sheet = (np.abs(xs) <= half) & (np.abs(ys) <= half) & (t_sheet.reshape(shape) > 0)
    paper = _lookup(albedo_sheet[..., None], xs, ys, half)[..., 0]
    sample_rgb = _lookup(np.asarray(sample, np.float32), p_sample[:, 0].reshape(shape), p_sample[:, 1].reshape(shape),
                         1.0)
    albedo = np.where(on_sheet[..., None], paper[..., None], TABLE_ALBEDO)
    albedo = np.where(in_window[..., None], sample_rgb, albedo).astype(np.float32)
    # Lambertian, flash at the camera: cos / d^2, normalised to 1 at the sample's centre seen from above.
    hit = np.where(in_window.reshape(-1, 1), p_sample, p_sheet)
    d = centre[None] - hit
    dist2 = np.sum(d * d, axis=1)
    shade = (np.abs(d[:, 2]) / np.sqrt(dist2) / dist2 * centre[2] ** 2).reshape(shape).astype(np.float32)
    radiance = albedo * shade[..., None]
    radiance = cv2.resize(radiance, (w, h), interpolation=cv2.INTER_AREA)
    if blur_px > 0:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur_px)
    rng = np.random.default_rng(seed)
    noisy = np.clip(radiance + rng.normal(0.0, noise_std, radiance.shape).astype(np.float32), 0.0, 1.0)
    return np.clip(np.rint(srgb_encode(noisy) * 255.0), 0, 255).astype(np.uint8)


def smooth_texture(size: int, seed: int) -> np.ndarray:
    """``(size, size, 3)`` float32 linear albedo in [0.05, 0.6]: a random, smooth, colourful pattern."""
    rng = np.random.default_rng(seed)
    coarse = torch.from_numpy(rng.uniform(0.0, 1.0, (1, 3, 10, 10)).astype(np.float32))
    fine = torch.nn.functional.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=False)[0]
    return np.ascontiguousarray(srgb_decode(0.25 + 0.55 * fine.clamp(0, 1).permute(1, 2, 0).numpy()), np.float32)


def render_tag_photo(maps: torch.Tensor, camera: TrueCamera, *, depth: float = 0.0, spp: int = 16,
                     noise_std: float = 0.004, seed: int = 0, cells_px: int = 8) -> np.ndarray:
    """A Mitsuba photo of ``maps (1, 10, H, W)`` under the print, through the pinhole part of ``camera``.

    ``camera`` must have no distortion and its principal point at the image centre (Mitsuba's
    perspective sensor); the flash is at the camera with intensity ``|camera|^2`` (the
    ``rectify`` default). Returns ``(H, W, 3)`` uint8 sRGB.
    """
    import mitsuba as mi

    from mi_svbrdf.data.frame_photos import _rect, _table_texture, photo_pipeline
    from mi_svbrdf.scenes import flip_v, material_bsdf
    from mi_svbrdf.variant import scene_variant

    w, h = camera.size
    if np.abs(camera.distortion).max() > 0 or not np.allclose(camera.matrix[:2, 2], [0.5 * (w - 1), 0.5 * (h - 1)]):
        raise ValueError("camera: expected no distortion and the principal point at the centre (Mitsuba's pinhole)")
    fov = math.degrees(2.0 * math.atan(0.5 * max(w, h) / camera.matrix[0, 0]))
    centre = camera.position
    fwd = camera.rotation[2]
    up = -camera.rotation[1]
    albedo, half = sheet_texture(cells_px)
    n = albedo.shape[0]
    px = n / (2.0 * half)  # texture pixels per capture unit

    def crop(x0: float, x1: float, y0: float, y1: float) -> dict:
        c0, c1 = round((x0 + half) * px), round((x1 + half) * px)
        r0, r1 = round((half - y1) * px), round((half - y0) * px)
        tex = np.ascontiguousarray(np.repeat(albedo[r0:r1, c0:c1, None], 3, axis=2))
        return {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True,
                                                   "filter_type": "bilinear", "wrap_mode": "clamp",
                                                   "to_uv": flip_v()}}

    inten = float(centre @ centre)
    with scene_variant("cpu"):
        table = {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(_table_texture(seed)),
                                                     "raw": True, "wrap_mode": "mirror"}}
        scene = {
            "type": "scene",
            "integrator": {"type": "direct"},
            "sensor": {"type": "perspective", "fov": fov, "fov_axis": "larger",
                       "to_world": mi.ScalarTransform4f().look_at(origin=centre.tolist(),
                                                                  target=(centre + fwd).tolist(), up=up.tolist()),
                       "sampler": {"type": "independent", "sample_count": int(spp)},
                       "film": {"type": "hdrfilm", "width": int(w), "height": int(h), "pixel_format": "rgb",
                                "rfilter": {"type": "box"}}},
            "sample": {"type": "rectangle", "bsdf": material_bsdf(maps, filter_type="bilinear")},
            "paper_top": _rect(-half, half, 1.0, half, depth, crop(-half, half, 1.0, half)),
            "paper_bottom": _rect(-half, half, -half, -1.0, depth, crop(-half, half, -half, -1.0)),
            "paper_left": _rect(-half, -1.0, -1.0, 1.0, depth, crop(-half, -1.0, -1.0, 1.0)),
            "paper_right": _rect(1.0, half, -1.0, 1.0, depth, crop(1.0, half, -1.0, 1.0)),
            "table": _rect(-40.0, 40.0, -40.0, 40.0, -0.02, table),
            "flash": {"type": "point", "position": centre.tolist(),
                      "intensity": {"type": "rgb", "value": math.pi * inten}},
        }
        # loaded on one thread: Mitsuba's parallel loading of the bitmaps was seen to hang beside another thread
        # calling into Dr.Jit (a test's kernel recorder), and the scene is a handful of objects
        scene = mi.load_dict(scene, parallel=False)
        radiance = np.array(mi.render(scene, seed=int(seed) % (2 ** 31)), dtype=np.float32)
    return photo_pipeline(radiance, noise_std, seed)
