"""The camera and the flash of a photo, from the frame's corners: intrinsics, pose, flash position.

* **Intrinsics** (:func:`focal_px`, :func:`intrinsics`): the focal length from a field of view
  (degrees across the photo's long side, :func:`focal_px_of_fov`) or from the EXIF 35 mm-equivalent
  focal length (defined on the diagonal; 35 mm film's is :data:`FILM_DIAGONAL_MM` = 43.27 mm,
  :func:`focal_px_of_35mm`), principal point at the centre, no distortion. These are the one home
  of the focal-length formulas (the synthetic framed photos of :mod:`mi_svbrdf.data.frame_photos`
  use them too).
* **Pose** (:func:`camera_pose`): OpenCV's planar PnP (IPPE) on the window's four corners with the
  frame's metric size. The camera position is in the sample frame (x in window half-widths, y in
  half-heights, z in their mean: exact for square windows).
* **Flash** (:func:`flash_position`, :func:`default_intensity`): at the camera plus an offset in
  millimetres in the camera's frame (x right and y up in the upright photo, z forward),
  isotropic, intensity ``I = |flash|^2`` by default (an auto-exposed photo: a white Lambertian
  texel at the centre facing the flash reads 1, so albedos are relative to the exposure).

Examples:
    >>> round(focal_px_of_fov(90.0, 640, 480), 6), round(fov_of_focal_35mm(focal_35mm_of(60.0, 640, 480), 640, 480), 6)
    (320.0, 60.0)
    >>> intrinsics((480, 640), 500.0).tolist()
    [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from mi_svbrdf.geometry.frame import DEFAULT_FRAME, PLANE_CORNERS, FrameSpec

#: Diagonal of 35 mm film (36 x 24 mm), for the EXIF 35 mm-equivalent focal length.
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)


def focal_px_of_fov(fov_deg: float, width: int, height: int) -> float:
    """Focal length in pixels of a pinhole photo ``width x height`` whose field of view across its long side is
    ``fov_deg`` degrees: ``0.5 * max(width, height) / tan(fov / 2)``."""
    return 0.5 * max(width, height) / math.tan(math.radians(fov_deg) / 2.0)


def fov_of_focal_px(focal: float, width: int, height: int) -> float:
    """Inverse of :func:`focal_px_of_fov`: the field of view (degrees, across the long side) of ``focal`` pixels."""
    return math.degrees(2.0 * math.atan(0.5 * max(width, height) / focal))


def focal_px_of_35mm(focal_35mm: float, width: int, height: int) -> float:
    """Focal length in pixels of a 35 mm-equivalent focal length (mm; defined on the diagonal, see
    :data:`FILM_DIAGONAL_MM`)."""
    return focal_35mm * math.hypot(width, height) / FILM_DIAGONAL_MM


def focal_35mm_of(fov_deg: float, width: int, height: int) -> float:
    """35 mm-equivalent focal length (mm, on the diagonal) of a FOV across the long side of a photo."""
    return focal_px_of_fov(fov_deg, width, height) * FILM_DIAGONAL_MM / math.hypot(width, height)


def fov_of_focal_35mm(focal_35mm: float, width: int, height: int) -> float:
    """Inverse of :func:`focal_35mm_of`."""
    return fov_of_focal_px(focal_px_of_35mm(focal_35mm, width, height), width, height)


def focal_px(size: tuple[int, int], fov_deg: float | None, focal_35mm: float | None) -> tuple[float, float, str]:
    """``(focal length in pixels, FOV across the long side in degrees, source)``.

    ``fov_deg`` (across the long side) wins; else the 35 mm-equivalent focal length, defined on
    the diagonal. ``ValueError`` when neither exists.
    """
    h, w = size
    if fov_deg is not None:
        if not 0 < fov_deg < 180:
            raise ValueError(f"--fov: expected degrees in (0, 180), got {fov_deg!r}")
        return focal_px_of_fov(fov_deg, w, h), float(fov_deg), "--fov"
    if focal_35mm is None or focal_35mm <= 0:
        raise ValueError("expected --fov or an EXIF 35 mm-equivalent focal length (FocalLengthIn35mmFilm), "
                         "got neither")
    f = focal_px_of_35mm(focal_35mm, w, h)
    return f, fov_of_focal_px(f, w, h), f"EXIF FocalLengthIn35mmFilm {focal_35mm:g} mm"


def intrinsics(size: tuple[int, int], focal: float) -> np.ndarray:
    """``(3, 3)`` camera matrix: focal ``focal`` pixels, principal point at the centre of ``size (H, W)``."""
    h, w = size
    return np.array([[focal, 0.0, 0.5 * (w - 1)], [0.0, focal, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Pose:
    """A camera recovered from the frame's corners.

    Attributes:
        rotation: ``(3, 3)`` world (sample frame, mm) -> OpenCV camera frame.
        translation_mm: ``(3,)`` of that transform.
        position: camera position in the sample frame (window half-sizes).
        reprojection_px: RMS distance of the reprojected corners to the given ones.
    """

    rotation: np.ndarray
    translation_mm: np.ndarray
    position: tuple[float, float, float]
    reprojection_px: float


def _unit_scale(frame: FrameSpec) -> np.ndarray:
    w, h = frame.window_mm
    return np.array([w / 2.0, h / 2.0, (w + h) / 4.0])


def camera_pose(corners: np.ndarray, camera_matrix: np.ndarray, frame: FrameSpec = DEFAULT_FRAME) -> Pose:
    """The camera that sees the window at ``corners`` (see the module docstring).

    Raises:
        ValueError: no solution with the camera above the sample.
    """
    scale = _unit_scale(frame)
    obj = np.concatenate([PLANE_CORNERS * scale[None, :2], np.zeros((4, 1))], axis=1)
    img = np.asarray(corners, np.float64).reshape(4, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj.reshape(4, 1, 3), img, camera_matrix, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("camera pose: expected a solution of the corners' PnP, got none")
    rot, _ = cv2.Rodrigues(rvec)
    t = tvec.reshape(3)
    centre = -rot.T @ t
    if centre[2] <= 0:
        raise ValueError(f"camera pose: expected the camera above the sample, got z = {centre[2]:.1f} mm "
                         "(corners mirrored?)")
    proj, _ = cv2.projectPoints(obj.reshape(4, 1, 3), rvec, tvec, camera_matrix, None)
    err = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - img.reshape(4, 2)) ** 2, axis=1))))
    return Pose(rot, t, tuple(float(v) for v in centre / scale), err)


def flash_position(pose: Pose, offset_mm: Sequence[float],
                   frame: FrameSpec = DEFAULT_FRAME) -> tuple[float, float, float]:
    """The flash in the sample frame: the camera plus ``offset_mm`` (x right, y up, z forward, camera frame)."""
    o = np.asarray(offset_mm, float)
    cv_offset = np.array([o[0], -o[1], o[2]])  # OpenCV camera: y down
    scale = _unit_scale(frame)
    centre_mm = np.asarray(pose.position) * scale
    return tuple(float(v) for v in (centre_mm + pose.rotation.T @ cv_offset) / scale)


def default_intensity(light: Sequence[float]) -> float:
    """``I = |light|^2``: unit irradiance at the sample's centre at normal incidence (see the module docstring)."""
    return float(np.dot(light, light))
