"""``mi-svbrdf rectify --frame tags``: photos of a sample under the AprilTag print to a calibrated capture.

The driver :func:`rectify_tag_photos` (the steps' pure functions live in
:mod:`~mi_svbrdf.geometry.tags`; reading photos, overlays and the output conventions are those of
:mod:`~mi_svbrdf.geometry.rectify`):

1. **Read** each photo upright (EXIF orientation applied) and **find the tags**
   (:func:`~mi_svbrdf.geometry.tags.detect_tags`: OpenCV's tag36h11 detector, every corner
   refined on the tag's edges). The corners are mapped back to the photo's stored orientation,
   where every photo of one camera shares its intrinsics (a phone held upright or sideways).
   A photo with fewer than :data:`~mi_svbrdf.geometry.tags.MIN_TAGS` tags fails (reported with
   its overlay); the others go on.
2. **Intrinsics**, per stored photo size: from ``--fov`` (degrees across the long side;
   principal point at the centre, no distortion) when given; otherwise calibrated from all
   photos' corners (:func:`~mi_svbrdf.geometry.tags.calibrate`: focal length, principal point,
   radial distortion). The EXIF 35 mm-equivalent focal length (a pinhole, as ``--fov``) is used
   only when every photo has one and there are fewer than :data:`MIN_CALIBRATION_PHOTOS`
   photos, or the photos do not determine the calibration (``rectify.json`` records why); a
   calibration records the EXIF focal lengths beside its own. A calibration from fewer than
   :data:`MIN_CALIBRATION_PHOTOS` photos (no EXIF focal length, no ``--fov``) is noted
   (:func:`calibration_notes`: ``rectify.json``'s ``notes``, a line on the terminal).
3. **Pose** per photo (:func:`~mi_svbrdf.geometry.tags.tag_pose`): all corners, a tag far off
   the others' fit dropped; tags used and the RMS reprojection error are reported. A window whose
   outline falls outside the photo fails the photo.
4. **Warp**: the window (the sample plane ``[-1, 1]^2``, ``--depth`` below the tags) through the
   full camera model to ``S x S`` texels, supersampled and area-averaged on linear values; a texel
   that takes any weight from a saturated pixel is written saturated. No texel takes anything from
   the print's paper: per side of the window, :func:`clear_limits` says how far from the centre the
   photo shows the sample clear of it (the strip the print's edge hides when the tags lie above
   the sample, and the paper's reach through the photo's blur, :func:`~mi_svbrdf.geometry.tags.edge_blur_px`,
   and the lookup), and the texels beyond repeat the nearest one on that limit (``rectify.json``:
   ``clear_of_paper``, ``texels_repeated``; a photo with more than :data:`MAX_INSET` of the
   half-width beyond fails). The texel grid stays the window's, so texel ``(i, j)`` is the same
   point of the sample in every photo and the positions are the window's.
5. **Flash** at the camera plus ``--flash-offset`` (mm, x right and y up in the upright photo,
   z forward), intensity ``|flash|^2`` unless ``--intensity``.

Outputs in OUT: ``NNN.png``, ``overlay_NNN.png`` (the tags found, blue; the window, green),
``rectify.json`` (per photo: tags found and used, corners, reprojection error, intrinsics, camera,
the edges' blur and the part of the window clear of the paper, status/error; the calibration;
notes), ``summary.json`` (per photo: status, tags used, reprojection error, camera; the
intrinsics) and ``capture.json`` (the photos that succeeded).
"""
from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from mi_svbrdf.geometry.frame import FrameSpec
from mi_svbrdf.geometry.homography import MAX_SUPERSAMPLE
from mi_svbrdf.geometry.poses import Pose, default_intensity, flash_position, focal_px
from mi_svbrdf.geometry.rectify import (
    AUTO_MIN,
    INSET_BLURS,
    INSET_PX,
    INSET_UNKNOWN_BLUR_PX,
    OVERLAY_PX,
    PhotoData,
    PhotoResult,
    RectifyError,
    RectifyOptions,
    _check_photo_size,
    _exif,
    _write_png8,
    auto_size,
    auto_size_words,
    draw_overlay,
    read_photo,
    window_holds,
    write_capture_file,
)
from mi_svbrdf.geometry.tags import (
    MIN_TAGS,
    TAG_COUNT,
    CalibrationError,
    Detections,
    Intrinsics,
    TagPose,
    TagSheet,
    apply_affine,
    calibrate,
    detect_tags,
    edge_blur_px,
    pinhole,
    project,
    stored_from_upright,
    tag_pose,
    visible_reach,
    window_maps,
)
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.calibrated_photos import CameraSpec, ImageSpec, LightSpec
from mi_svbrdf.io.material_io import srgb_encode

#: Photos of one size from which the intrinsics are calibrated even when EXIF has a focal length (fewer: the EXIF
#: focal length, when every photo has one). EXIF rounds the 35 mm-equivalent focal length to a whole mm (up to 2 %
#: on a phone) and says nothing of the principal point and the distortion.
MIN_CALIBRATION_PHOTOS = 3

#: The widest strip along the window's edge that a photo may see within the paper's reach (:func:`clear_limits`), a
#: fraction of the window's half-width: a photo with more (the print's edge hiding a wide strip of a deep sample from
#: an oblique camera, or a blurry photo) fails.
MAX_INSET = 0.2

#: The window's corners on the sample plane (top-left, top-right, bottom-right, bottom-left).
WINDOW = np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])


def _window_outline(per_side: int = 16) -> np.ndarray:
    """``(4 n, 3)`` points along the window's sides on the sample plane."""
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)[:, None]
    return np.concatenate([WINDOW[s] + t * (WINDOW[(s + 1) % 4] - WINDOW[s]) for s in range(4)])


class _Seen:
    """A photo read and its tags (between the passes of :func:`rectify_tag_photos`)."""

    def __init__(self, photo: PhotoData, detections: Detections, to_stored: np.ndarray, stored_wh: tuple[int, int]):
        self.photo = photo
        self.detections = detections
        self.to_stored = to_stored  # (3, 3) upright px -> stored px
        self.stored_wh = stored_wh

    @property
    def stored_corners(self) -> np.ndarray:
        return apply_affine(self.to_stored, self.detections.corners)


def _read(path: Path) -> _Seen:
    photo = read_photo(path)
    _check_photo_size(photo)
    orientation, _ = _exif(path)
    h, w = photo.size
    turned = orientation in (5, 6, 7, 8)
    stored_wh = (h, w) if turned else (w, h)
    det = detect_tags(photo.grey, photo.linear_grey)
    return _Seen(photo, det, stored_from_upright(orientation, stored_wh), stored_wh)


def _overlay(seen: _Seen, window: np.ndarray | None, message: str) -> np.ndarray:
    det = seen.detections
    img = draw_overlay(seen.photo, window, list(det.corners), message)
    h, w = seen.photo.size
    scale = min(1.0, OVERLAY_PX / max(h, w))
    thick = max(1, round(max(img.shape[:2]) / 500))
    for tag_id, quad in zip(det.ids, det.corners):
        c = (quad.mean(axis=0) + 0.5) * scale - 0.5
        first = (quad[0] + 0.5) * scale - 0.5
        cv2.circle(img, (int(round(first[0])), int(round(first[1]))), 3 * thick, (60, 120, 255), -1, cv2.LINE_AA)
        cv2.putText(img, str(int(tag_id)), (int(c[0]) - 5 * thick, int(c[1]) + 5 * thick), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45 * thick, (255, 0, 255), thick, cv2.LINE_AA)
    return img


def _fail(result: PhotoResult, out: Path, seen: _Seen | None, message: str) -> PhotoResult:
    if not message.startswith(result.photo):
        message = f"{result.photo}: {message}"
    result.error = message
    (out / f"{result.index:03d}.png").unlink(missing_ok=True)
    if seen is not None:
        _write_png8(out / result.entry["overlay"], _overlay(seen, None, message))
    else:
        result.entry.pop("overlay", None)
    return result


def _intrinsics(seen: dict[int, _Seen], options: RectifyOptions) -> tuple[dict[int, Intrinsics], dict[int, str],
                                                                           list[dict[str, Any]]]:
    """Per usable photo its intrinsics, per photo that could not be calibrated the reason, the calibrations (step 2
    of the module docstring)."""
    cams: dict[int, Intrinsics] = {}
    errors: dict[int, str] = {}
    calibrations: list[dict[str, Any]] = []

    def exif(i: int) -> Intrinsics:
        w, h = seen[i].stored_wh
        focal, _, source = focal_px((h, w), options.fov_deg, seen[i].photo.focal_35mm)
        return pinhole((w, h), focal, source)

    if options.fov_deg is not None:
        return {i: exif(i) for i in seen}, errors, calibrations
    for size in sorted({s.stored_wh for s in seen.values()}):
        group = [i for i, s in seen.items() if s.stored_wh == size]
        has_exif = all(seen[i].photo.focal_35mm for i in group)
        if has_exif and len(group) < MIN_CALIBRATION_PHOTOS:
            cams.update({i: exif(i) for i in group})
            continue
        views = [(TagSheet(1.0).object_points(seen[i].detections.ids).reshape(-1, 3),  # the tag plane, z = 0
                  seen[i].stored_corners.reshape(-1, 2)) for i in group]
        try:
            intr, _ = calibrate(views, size)
        except CalibrationError as exc:
            if has_exif:  # the EXIF focal length, with what the calibration said
                cams.update({i: exif(i) for i in group})
                calibrations.append({"size_wh": list(size), "photos": len(group), "error": str(exc),
                                     "used": "the EXIF focal length"})
                continue
            for i in group:
                errors[i] = (f"could not calibrate the camera from the {len(group)} photo{'s' * (len(group) > 1)} "
                             f"of {size[0]}x{size[1]} px: {exc}")
            continue
        record = intr.to_dict()
        if has_exif:
            record["exif_focal_px"] = [round(exif(i).focal_px, 3) for i in group]
        calibrations.append(record)
        cams.update({i: intr for i in group})
    return cams, errors, calibrations


def clear_limits(pose: TagPose, camera: Intrinsics, depth: float, blur_px: float) -> np.ndarray:
    """How far from the window's centre a photo shows the sample clear of the print's paper, per side
    ``(+x, -x, +y, -y)``, capture units (1: up to the window's edge; the window's texels beyond are looked up on the
    limit, :func:`~mi_svbrdf.geometry.tags.window_maps`).

    Per side: the sample's reach in view (:func:`~mi_svbrdf.geometry.tags.visible_reach`: the print's edge, when
    the tags lie ``depth`` above the sample, hides a strip on the camera's side), less the paper's reach into the
    photo's pixels beyond the edge seen: :data:`~mi_svbrdf.geometry.rectify.INSET_PX` (the corners' and the
    bilinear lookup's reach) plus :data:`~mi_svbrdf.geometry.rectify.INSET_BLURS` blur sigmas (``blur_px``, photo
    pixels; NaN: :data:`~mi_svbrdf.geometry.rectify.INSET_UNKNOWN_BLUR_PX`), in capture units where that edge is
    seen coarsest (the paper frame's margin, :func:`~mi_svbrdf.geometry.rectify.inset_fraction`).
    """
    reach = np.minimum(visible_reach(pose.position, depth), 1.0)
    margin = INSET_PX + INSET_BLURS * (blur_px if math.isfinite(blur_px) else INSET_UNKNOWN_BLUR_PX)
    along = np.linspace(-1.0, 1.0, 33)
    step = 1e-3
    limits = np.empty(4)
    for side, (axis, sign) in enumerate(((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))):
        edge = np.zeros((len(along), 3))
        edge[:, axis] = sign * reach[side]
        edge[:, 1 - axis] = along
        inside = edge.copy()
        inside[:, axis] -= sign * step
        px_per_unit = np.linalg.norm(project(edge, pose, camera) - project(inside, pose, camera), axis=1) / step
        limits[side] = reach[side] - margin / float(px_per_unit.min())
    return limits


def repeated_texels(clear: np.ndarray, size: int) -> list[int]:
    """Per side ``(+x, -x, +y, -y)`` how many of the ``size`` texels across the window lie beyond ``clear`` (each
    repeats the nearest texel seen clear of the paper)."""
    centres = 1.0 - (2.0 * np.arange(size) + 1.0) / size  # from the edge inwards
    return [int(np.sum(centres > limit)) for limit in clear]


def _warp(seen: _Seen, pose: TagPose, camera: Intrinsics, size: int,
          clear: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """``(linear (S, S, 3), saturated (S, S), supersampling)`` of the window seen from above (texels beyond
    ``clear`` repeat those on it)."""
    corners = apply_affine(np.linalg.inv(seen.to_stored), project(WINDOW, pose, camera))
    side = float(np.max(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))
    k = int(np.clip(math.ceil(side / size), 1, MAX_SUPERSAMPLE))
    maps = apply_affine(np.linalg.inv(seen.to_stored), window_maps(pose, camera, size, k, clear)).astype(np.float32)
    photo = seen.photo
    linear = cv2.remap(photo.linear, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    sat = cv2.remap(photo.saturated.astype(np.float32), maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    if k > 1:
        linear = linear.reshape(size, k, size, k, 3).mean(axis=(1, 3))
        sat = sat.reshape(size, k, size, k).mean(axis=(1, 3))
    return linear.astype(np.float32), sat > 0.01 / (k * k), k


def _flash(pose: TagPose, seen: _Seen, sheet: TagSheet, options: RectifyOptions) -> tuple[float, float, float]:
    """The flash in the capture frame: the camera plus ``--flash-offset`` in the upright photo's camera frame."""
    rot, _ = cv2.Rodrigues(pose.rvec)
    turn = np.eye(3)
    turn[:2, :2] = np.linalg.inv(seen.to_stored)[:2, :2]  # stored -> upright image axes
    frame = FrameSpec(window_mm=(sheet.window_mm, sheet.window_mm))
    half = 0.5 * sheet.window_mm
    return flash_position(Pose(turn @ rot, turn @ pose.tvec * half, pose.position, pose.reprojection_px),
                          options.flash_offset_mm, frame)


def _one(result: PhotoResult, seen: _Seen, camera: Intrinsics, sheet: TagSheet, options: RectifyOptions,
         out: Path) -> PhotoResult:
    det = seen.detections
    entry = result.entry
    entry.update({"size_hw": list(seen.photo.size), "conversions": seen.photo.notes,
                  "tags_found": det.ids.tolist(), "tags_ignored": det.ignored,
                  "tag_corners_px": {str(int(i)): q.round(3).tolist() for i, q in zip(det.ids, det.corners)},
                  "intrinsics_source": camera.source})
    pose = tag_pose(det.ids, seen.stored_corners, sheet, camera)
    window = apply_affine(np.linalg.inv(seen.to_stored), project(WINDOW, pose, camera))
    h, w = seen.photo.size
    edge = apply_affine(np.linalg.inv(seen.to_stored), project(_window_outline(), pose, camera))
    outside = (edge[:, 0] < -0.5) | (edge[:, 1] < -0.5) | (edge[:, 0] > w - 0.5) | (edge[:, 1] > h - 0.5)
    if outside.any():
        raise RectifyError(f"expected the whole window (the sample) in the photo, got {100 * outside.mean():.0f} % "
                           f"of its outline outside the {w}x{h} photo ({len(pose.used)} tags used): step back or "
                           "aim at the window")
    light = _flash(pose, seen, sheet, options)
    if light[2] <= 0:
        raise RectifyError(f"expected the flash above the sample, got z = {light[2]:.3f} "
                           f"(--flash-offset {options.flash_offset_mm})")
    lin = seen.photo.linear  # the channels' mean (as .mean(axis=2), without its slow reduction over a 12 MP photo)
    blur = edge_blur_px((lin[..., 0] + lin[..., 1] + lin[..., 2]) / np.float32(3.0), det.corners)
    clear = clear_limits(pose, camera, sheet.depth, blur)
    entry.update({"edge_blur_px": None if not math.isfinite(blur) else round(blur, 3),
                  "clear_of_paper": [round(float(v), 5) for v in clear],
                  "texels_repeated": repeated_texels(clear, options.size)})
    if 1.0 - float(clear.min()) > MAX_INSET:
        hidden = 1.0 - float(np.min(visible_reach(pose.position, sheet.depth)))
        raise RectifyError(f"expected the window's edges in clear view, got {100 * (1.0 - clear.min()):.0f} % of its "
                           f"half-width within the paper's reach (at most {100 * MAX_INSET:.0f} %): the print's edge "
                           f"hides {100 * max(hidden, 0.0):.0f} % (--depth {sheet.depth_mm:g} mm), the photo's blur is "
                           f"{'unmeasured' if not math.isfinite(blur) else f'{blur:.1f} px'}: take it from higher "
                           "above, or sharper")
    intensity = options.intensity if options.intensity is not None else default_intensity(light)
    linear, sat, k = _warp(seen, pose, camera, options.size, clear)
    encoded = srgb_encode(np.clip(linear, 0.0, 1.0))
    encoded[sat] = 1.0
    name = f"{result.index:03d}.png"
    _write_png8(out / name, np.clip(np.rint(encoded * 255.0), 0, 255).astype(np.uint8))
    entry.update({"tags_used": list(pose.used), "tags_dropped": list(pose.dropped),
                  "reprojection_error_px": {"tags_rms": round(pose.reprojection_px, 4)},
                  "window_corners_px": window.round(3).tolist(),
                  "corner_order": ["top-left", "top-right", "bottom-right", "bottom-left"],
                  "fov_deg": round(camera.fov_deg, 4), "focal_px": round(camera.focal_px, 3), "supersampling": k,
                  "saturated_texels": int(sat.sum()), "camera_position": [round(v, 6) for v in pose.position],
                  "light_position": [round(v, 6) for v in light], "intensity": intensity, "output": name})
    result.image = ImageSpec(name, "srgb8", True, CameraSpec(pose.position, camera.fov_deg),
                             LightSpec(light, (intensity,) * 3, None))
    result.ok = True
    _write_png8(out / entry["overlay"], _overlay(seen, window, ""))
    return result


def rectify_tag_photos(photos: Sequence[str | os.PathLike], out: str | os.PathLike, options: RectifyOptions,
                       sheet: TagSheet, *, before_writing: Callable[[], None] | None = None) -> list[PhotoResult]:
    """Rectify every photo of the AprilTag print into ``out`` (module docstring); ``rectify.json``, ``summary.json``
    and ``capture.json`` (when at least one photo succeeded).

    Args:
        photos: photo files (the output index is the position in this list).
        out: output folder (created).
        options: the shared options (``size``, ``fov_deg``, ``flash_offset_mm``, ``intensity``; ``frame`` unused).
        sheet: the print as measured (``--frame-size S``, ``--depth``).
        before_writing: called once every photo is read and its tags found, before anything is written (the
            command claims its output folder there).

    Returns:
        One :class:`~mi_svbrdf.geometry.rectify.PhotoResult` per photo.
    """
    if not photos:
        raise ValueError("photos: expected at least one photo file, got none")
    out = Path(out)
    results: list[PhotoResult] = []
    seen: dict[int, _Seen] = {}
    unread: dict[int, tuple[_Seen | None, str]] = {}  # failed photos, reported once the photos are read
    for i, path in enumerate(photos):
        result = PhotoResult(str(path), i)
        result.entry["overlay"] = f"overlay_{i:03d}.png"
        results.append(result)
        try:
            s = _read(Path(path))
        except (RectifyError, ValueError) as exc:
            unread[i] = (None, str(exc))
            continue
        n = len(s.detections.ids)
        if n < MIN_TAGS:
            ignored = f" (ignored: {', '.join(s.detections.ignored)})" if s.detections.ignored else ""
            unread[i] = (s, f"expected at least {MIN_TAGS} of the print's {TAG_COUNT} tags (tag36h11, IDs "
                            f"0-{TAG_COUNT - 1}), got {n}{ignored}: the print out of the photo, too small, too blurry "
                            "or under glare")
            continue
        seen[i] = s
    if before_writing is not None:
        before_writing()
    out.mkdir(parents=True, exist_ok=True)
    for i, (s, message) in unread.items():
        _fail(results[i], out, s, message)
    cams, cal_errors, calibrations = _intrinsics(seen, options)
    size_words = None
    if options.size is None:  # --size auto: what the photos resolve across the window (auto_size)
        holds = []
        for i, s in seen.items():
            if i in cal_errors:
                continue
            try:
                pose = tag_pose(s.detections.ids, s.stored_corners, sheet, cams[i])
            except (RectifyError, ValueError):
                continue  # reported by _one
            window = apply_affine(np.linalg.inv(s.to_stored), project(WINDOW, pose, cams[i]))
            holds.append(window_holds(window, math.nan))
        options = dataclasses.replace(options, size=auto_size(holds) if holds else AUTO_MIN)
        size_words = auto_size_words(options.size, holds) if holds else None
    for i, s in seen.items():
        result = results[i]
        if i in cal_errors:
            _fail(result, out, s, cal_errors[i])
            continue
        try:
            _one(result, s, cams[i], sheet, options, out)
        except (RectifyError, ValueError) as exc:
            result.ok, result.image = False, None
            _fail(result, out, s, str(exc))
    frame = {"kind": "tags", "size_mm": sheet.size_mm, "depth_mm": sheet.depth_mm, "window_mm": sheet.window_mm}
    report = {"version": 1, "frame": frame, "size": options.size, **({"size_auto": size_words} if size_words else {}),
              "calibrations": calibrations,
              "pixel_convention": "OpenCV: centre of the top-left pixel at (0, 0), upright photo",
              "notes": calibration_notes(calibrations), "photos": [r.to_dict() for r in results]}
    write_json(out / "rectify.json", report)
    write_json(out / "summary.json", summary(results, sheet, calibrations))
    write_capture_file(out, results)
    return results


def calibration_notes(calibrations: Sequence[dict[str, Any]]) -> list[str]:
    """A note per calibration from fewer than :data:`MIN_CALIBRATION_PHOTOS` photos (no EXIF focal length, no --fov):
    a focal length from so few views of a plane is only as good as their tilt."""
    notes = []
    for cal in calibrations:
        n = int(cal.get("photos") or 0)
        if "error" not in cal and 0 < n < MIN_CALIBRATION_PHOTOS:
            w, h = cal["size_wh"]
            notes.append(f"the focal length ({cal['focal_px']:.0f} px, a field of view of {cal['fov_deg']:.1f} "
                         f"degrees) was calibrated from the tags of only {n} photo{'s' * (n > 1)} of {w}x{h} px, "
                         f"without an EXIF focal length: give --fov, or take at least {MIN_CALIBRATION_PHOTOS} photos "
                         "at an angle (20-40 degrees from straight above) for a camera the tags determine")
    return notes


def summary(results: Sequence[PhotoResult], sheet: TagSheet, calibrations: list[dict[str, Any]]) -> dict[str, Any]:
    """The short report of a run (``summary.json``): per photo its status, tags used, reprojection error, camera."""
    photos = []
    for r in results:
        e = r.entry
        photos.append({"photo": r.photo, "status": "ok" if r.ok else "error",
                       "tags_found": len(e.get("tags_found", [])), "tags_used": len(e.get("tags_used", [])),
                       "reprojection_error_px": e.get("reprojection_error_px", {}).get("tags_rms"),
                       "camera_position": e.get("camera_position"), "fov_deg": e.get("fov_deg"),
                       **({"error": r.error} if r.error else {})})
    return {"frame": "tags", "size_mm": sheet.size_mm, "depth_mm": sheet.depth_mm,
            "rectified": sum(r.ok for r in results), "photos_total": len(results),
            "intrinsics": calibrations, "photos": photos}


def terminal_line(result: PhotoResult) -> str:
    """One line per rectified photo: tags used, reprojection error, camera."""
    e = result.entry
    dropped = f", dropped {e['tags_dropped']}" if e.get("tags_dropped") else ""
    return (f"{result.photo} -> {e['output']}: {len(e['tags_used'])} of {TAG_COUNT} tags used{dropped}, reprojection "
            f"{e['reprojection_error_px']['tags_rms']:.3f} px rms, camera {e['camera_position']}, "
            f"{e['intrinsics_source']}")
