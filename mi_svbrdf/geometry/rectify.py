"""Rectify flash photos of a framed sample and recover each camera: ``mi-svbrdf rectify``.

Per photo (the steps' pure functions live in :mod:`~mi_svbrdf.geometry.frame`,
:mod:`~mi_svbrdf.geometry.homography` and :mod:`~mi_svbrdf.geometry.poses`; the driver is
:func:`rectify_photos`):

1. **Read** (:func:`read_photo`): upright (EXIF orientation applied), sRGB-encoded values in
   [0, 1], the linear image (colour-science sRGB decoding), the saturated pixels (a channel at
   the top code) and the EXIF 35 mm-equivalent focal length.
2. **Corners**: found (:mod:`mi_svbrdf.geometry.frame`: threshold sweep, contours,
   ``approxPolyDP``, sub-pixel edge-line fit) or given (``--corners``: a JSON object mapping a
   photo's file name to four ``[x, y]`` points of the upright photo, OpenCV pixels, top-left
   first, clockwise; the order is checked and corrected, see below); then ordered clockwise and
   oriented by the frame's widest margin (the bottom of the sheet), so every photo shows the
   sample from above with +y up, whatever the camera's rotation or the order of the points.
   Given corners whose photo shows no clear margin keep the file's order (top-left first).
   A symmetric frame (no margin clearly the widest, the frame seen whole) cannot tell +y: when
   no photo of the set shows a widest margin, each photo is oriented by itself (the window's
   side nearest the photo's bottom edge is the bottom: the image's up is +y) and
   ``rectify.json``'s ``notes`` say so; when some photo shows one, it orients the set and a
   photo that does not show it fails (one rule for the whole set, :func:`orientation_rule`).
3. **Homography** (:func:`~mi_svbrdf.geometry.homography.plane_homography`): plane
   ``(x, y, 1)`` -> pixel, with the window's inside the plane ``[-1, 1]^2``.
4. **Warp** (:func:`~mi_svbrdf.geometry.homography.warp_to_plane`): the window seen from above
   at ``S x S`` texels, antialiased, on linear values, cropped inside the window's edge
   (:func:`inset_fraction`: the bright paper frame, spread by the photo's blur and the warp's
   interpolation, would otherwise show as a light border the fit reproduces). One crop for the set
   (:func:`common_coverage`, the largest photo's inset, so that texel (i, j) is the same point of the
   sample in every photo): each rectified image covers ``[-c, c]^2`` of the window (``c`` =
   ``rectify.json``'s ``window_covered``), and
   the positions written to ``capture.json`` are in its half-widths (the window's divided by ``c``).
   A texel that takes any weight from a saturated pixel is written saturated (so ``load_capture``
   masks it).
5. **Pose** (:func:`~mi_svbrdf.geometry.poses.camera_pose`): the intrinsics from ``--fov``
   (degrees across the photo's long side) or from the EXIF 35 mm-equivalent focal length,
   principal point at the centre, no distortion; OpenCV's planar PnP (IPPE) on the four corners
   with the frame's metric size.
6. **Flash** (:func:`~mi_svbrdf.geometry.poses.flash_position`): at the camera plus
   ``--flash-offset`` (millimetres, in the camera's frame: x right and y up in the upright
   photo, z forward), isotropic (no cone), intensity ``I = |flash|^2`` per photo
   (:func:`~mi_svbrdf.geometry.poses.default_intensity`) unless ``--intensity`` fixes one value.

Bad input (a :class:`RectifyError` naming the photo and what was seen): no frame, several
candidate frames, a frame cut by the image border, a photo or window too small, edges too
blurry (sigma above 1.5 output texels and 2 photo pixels), no FOV. The overlay is written for
failed photos too, and the other photos are still processed.

Outputs in OUT: ``NNN.png`` (the rectified photo of input NNN, sRGB 8-bit), ``overlay_NNN.png``,
``rectify.json`` (per photo: corners, homography, reprojection errors, how found and oriented,
camera, status/error; notes on the set) and ``capture.json`` (version 1, the rectified photos
that succeeded).
"""
from __future__ import annotations

import dataclasses

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from mi_svbrdf.geometry.frame import (
    DEFAULT_FRAME,
    MIN_PHOTO_PX,
    MIN_WINDOW_PX,
    ORIENTED_BY_FRAME,
    ORIENTED_BY_PHOTO,
    FrameError,
    FrameSpec,
    find_candidates,
    order_clockwise,
    orient_by_photo,
    orient_corners,
    paper_region,
    refine_corners,
)
from mi_svbrdf.geometry.homography import edge_residual_px, plane_homography, supersampling, warp_to_plane
from mi_svbrdf.geometry.poses import camera_pose, default_intensity, flash_position, focal_px, intrinsics
from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.io.calibrated_photos import DEFAULT_MAX_SIDE, CameraSpec, CaptureSpec, ImageSpec, LightSpec
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode
from mi_svbrdf.io.photos import ORIENTATION_TAG, orient

#: EXIF tags: the Exif IFD and its 35 mm-equivalent focal length.
EXIF_IFD, FOCAL_35MM_TAG = 0x8769, 0xA405
#: Edge blur (Gaussian sigma of the frame's edges) accepted: up to this many texels of the
#: rectified output, or up to MAX_BLUR_PX photo pixels (when the output enlarges the photo).
MAX_BLUR_TEXELS = 1.5
#: The crop inside the window's edge, in photo pixels: the corners' and the warp's interpolation error, plus
#: :data:`INSET_BLURS` times the edge's blur (sigma; :data:`INSET_UNKNOWN_BLUR_PX` when it was not measured).
INSET_PX = 1.0
INSET_BLURS = 3.0
INSET_UNKNOWN_BLUR_PX = 1.0
#: The largest crop, as a fraction of the window's half-width.
MAX_INSET = 0.1
MAX_BLUR_PX = 2.0
#: Longest side of the overlay images.
OVERLAY_PX = 1600


class RectifyError(ValueError):
    """A photo could not be rectified; the message names it and says what was seen."""


@dataclass
class PhotoData:
    """A photo as read: upright, encoded and linear.

    Attributes:
        path: the file.
        encoded: ``(H, W, 3)`` float32 sRGB-encoded values in [0, 1].
        linear: ``(H, W, 3)`` float32 linear values.
        saturated: ``(H, W)`` bool, a channel at the top code.
        focal_35mm: EXIF 35 mm-equivalent focal length in mm, or None.
        notes: conversions applied (EXIF orientation ...).
    """

    path: Path
    encoded: np.ndarray
    linear: np.ndarray
    saturated: np.ndarray
    focal_35mm: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def grey(self) -> np.ndarray:
        """``(H, W)`` float32 darkest encoded channel: the neutral paper stays bright, a coloured sample darkens."""
        e = self.encoded
        return np.ascontiguousarray(np.minimum(np.minimum(e[..., 0], e[..., 1]), e[..., 2]), dtype=np.float32)

    @property
    def linear_grey(self) -> np.ndarray:
        """``(H, W)`` float32 darkest linear channel: :attr:`grey` decoded (the sRGB curve is increasing)."""
        v = self.linear
        return np.ascontiguousarray(np.minimum(np.minimum(v[..., 0], v[..., 1]), v[..., 2]), dtype=np.float32)

    @property
    def size(self) -> tuple[int, int]:
        """``(H, W)``."""
        return int(self.encoded.shape[0]), int(self.encoded.shape[1])


#: The 8-bit codes' encoded values, ``code / 255`` (float32).
_ENCODED8 = np.arange(256, dtype=np.float32) / np.float32(255.0)
_LINEAR8: list[np.ndarray] = []


def _linear8() -> np.ndarray:
    """The 8-bit codes' linear values: ``srgb_decode(code / 255)`` (float32), computed once."""
    if not _LINEAR8:
        _LINEAR8.append(srgb_decode(_ENCODED8).astype(np.float32))
    return _LINEAR8[0]


def _exif(path: Path) -> tuple[int, float | None]:
    """``(orientation, 35 mm-equivalent focal length or None)`` from a file's EXIF (1, None if none)."""
    from PIL import Image

    try:
        with Image.open(path) as img:
            exif = img.getexif()
            orientation = int(exif.get(ORIENTATION_TAG, 1) or 1)
            focal = exif.get_ifd(EXIF_IFD).get(FOCAL_35MM_TAG) or exif.get(FOCAL_35MM_TAG)
    except Exception:  # noqa: BLE001 - unreadable metadata: upright, no focal length
        return 1, None
    return orientation, (float(focal) if focal else None)


def read_photo(path: str | os.PathLike) -> PhotoData:
    """Read a photo upright (see the module docstring, step 1).

    Raises:
        FileNotFoundError: no such file.
        RectifyError: not an image.
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected a photo file, got no such file")
    orientation, focal = _exif(path)
    notes = []
    if path.suffix.lower() in (".png", ".exr"):
        try:
            image, info = read_image(path)
        except ValueError as exc:
            raise RectifyError(str(exc)) from exc  # the reader's message names the file and what was expected
        if image.shape[2] in (2, 4):
            image = image[:, :, :-1]
        if image.shape[2] == 1:
            image = np.repeat(image, 3, axis=2)
        if info.format == "exr":
            linear = np.clip(image, 0.0, None).astype(np.float32)
            encoded = srgb_encode(np.clip(linear, 0.0, 1.0)).astype(np.float32)
            saturated = np.zeros(image.shape[:2], bool)
        else:
            top = 1.0 - 0.5 / (2 ** info.bit_depth - 1)
            encoded = image.astype(np.float32)
            saturated = (encoded >= top).any(axis=2)
            linear = srgb_decode(encoded).astype(np.float32)
        if orientation != 1:
            notes.append(f"EXIF orientation {orientation} applied")
            encoded, linear = orient(encoded, orientation), orient(linear, orientation)
            saturated = orient(saturated[..., None], orientation)[..., 0]
    else:
        try:
            with Image.open(path) as img:
                img.load()
                upright = ImageOps.exif_transpose(img).convert("RGB")
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
            raise RectifyError(f"{path}: expected an image file (JPEG, PNG, TIFF ...), got one that no image "
                               f"reader understands ({exc})") from exc
        if orientation != 1:
            notes.append(f"EXIF orientation {orientation} applied")
        codes = np.ascontiguousarray(np.asarray(upright))
        # code / 255 and srgb_decode(code / 255) looked up per 8-bit code: a 12 MP photo in a fraction of a second
        encoded = cv2.LUT(codes, _ENCODED8.reshape(1, 256))
        linear = cv2.LUT(codes, _linear8().reshape(1, 256))
        saturated = np.maximum(np.maximum(codes[..., 0], codes[..., 1]), codes[..., 2]) >= 255
    return PhotoData(path, np.ascontiguousarray(encoded), np.ascontiguousarray(linear),
                     np.ascontiguousarray(saturated), focal, notes)


# ---------------------------------------------------------------------------------------------
# Corner finding for one photo


@dataclass
class Corners:
    """The window's corners in a photo and how they were obtained."""

    corners: np.ndarray  #: (4, 2) top-left, top-right, bottom-right, bottom-left (OpenCV pixels)
    found_by: str  #: "detected (...)" or "--corners FILE"
    orientation: str  #: what decided which corner is the top-left
    margins: dict[str, float] = field(default_factory=dict)  #: paper reach per side, window half-widths
    edge_points: list[np.ndarray] = field(default_factory=list)  #: per side (after orientation)
    blur_px: float = float("nan")  #: edge blur sigma, photo pixels
    candidates: list[np.ndarray] = field(default_factory=list)  #: quads seen (overlay)
    #: why the frame did not tell the orientation ("": it did); the corners are then oriented by the photo
    unoriented: str = ""
    symmetric: bool = False  #: the frame was seen whole with no widest margin (see FrameError.symmetric)


def _check_photo_size(photo: PhotoData) -> None:
    h, w = photo.size
    if min(h, w) < MIN_PHOTO_PX:
        raise RectifyError(f"{photo.path}: expected a photo at least {MIN_PHOTO_PX} px on its short side, got {w}x{h}")


def detect_corners(photo: PhotoData, frame: FrameSpec = DEFAULT_FRAME) -> Corners:
    """Find and orient the window's corners (:mod:`mi_svbrdf.geometry.frame`); ``RectifyError`` naming the photo.

    When the frame does not tell the orientation (no margin clearly the widest), the corners are
    oriented by the photo (:func:`~mi_svbrdf.geometry.frame.orient_by_photo`) and
    :attr:`Corners.unoriented` says why the frame did not: :func:`rectify_photos` decides for the
    whole set whether that is accepted.
    """
    grey = photo.grey
    quads, _, votes, seen = find_candidates(grey)
    name = photo.path
    if not quads:
        cut = "touching the image border" in seen
        why = ("the frame seems cut by the image border (no closed window)" if cut
               else "no light frame with a dark window")
        raise RectifyError(f"{name}: expected one paper frame around the sample, got {why}; seen: {seen}")
    best = int(np.argmax(votes))
    rivals = [i for i in range(len(quads)) if i != best and votes[i] >= max(1, 0.5 * votes[best])]
    if rivals:
        err = RectifyError(f"{name}: expected one paper frame around the sample, got {1 + len(rivals)} candidate "
                           f"windows (found at {[votes[best]] + [votes[i] for i in rivals]} thresholds) at "
                           + "; ".join(f"centre ({q.mean(axis=0)[0]:.0f}, {q.mean(axis=0)[1]:.0f}) px"
                                       for q in [quads[best]] + [quads[i] for i in rivals]))
        err.candidates = quads  # type: ignore[attr-defined]
        raise err
    try:
        refined = refine_corners(grey, quads[best])
    except FrameError as exc:
        err = RectifyError(f"{name}: {exc}")
        err.candidates = quads  # type: ignore[attr-defined]
        raise err from None
    unoriented, symmetric = "", False
    try:
        oriented, how, margins = orient_corners(refined.corners, paper_region(grey, refined.corners), photo.size,
                                                frame)
    except FrameError as exc:  # the frame does not tell: the photo's own orientation, for the set to accept or not
        oriented, how, margins = orient_by_photo(refined.corners), ORIENTED_BY_PHOTO, {}
        unoriented, symmetric = f"{name}: {exc}", exc.symmetric
    # Edge points follow the corners' rotation (side s joins corners s and s + 1).
    shift = next(s for s in range(4) if np.allclose(np.roll(refined.corners, -s, axis=0), oriented))
    points = [refined.edge_points[(s + shift) % 4] for s in range(4)]
    return Corners(oriented, "detected (threshold sweep, contours, approxPolyDP, sub-pixel edge-line fit)", how,
                   margins, points, refined.blur_px, quads, unoriented, symmetric)


def given_corners(photo: PhotoData, points: Any, source: str, frame: FrameSpec = DEFAULT_FRAME) -> Corners:
    """Corners from ``--corners``: validated, ordered clockwise and oriented by the frame's margin when visible."""
    arr = np.asarray(points, dtype=np.float64) if isinstance(points, list) else None
    if arr is None or arr.shape != (4, 2) or not np.isfinite(arr).all():
        raise RectifyError(f"{source}[{photo.path.name!r}]: expected four [x, y] pixel points, got {points!r}")
    h, w = photo.size
    if (arr[:, 0] < 0).any() or (arr[:, 1] < 0).any() or (arr[:, 0] > w - 1).any() or (arr[:, 1] > h - 1).any():
        raise RectifyError(f"{source}[{photo.path.name!r}]: expected points inside the upright photo of {w}x{h} "
                           f"(W x H), got {arr.tolist()}")
    pts = order_clockwise(arr)
    if cv2.contourArea(pts.astype(np.float32)) < 0.25 * MIN_WINDOW_PX ** 2 or not cv2.isContourConvex(
            pts.astype(np.float32).reshape(-1, 1, 2)):
        raise RectifyError(f"{source}[{photo.path.name!r}]: expected a convex quadrilateral of some area, "
                           f"got {arr.tolist()}")
    found_by = f"--corners {source}"
    try:
        oriented, how, margins = orient_corners(pts, paper_region(photo.grey, pts), photo.size, frame)
    except FrameError:
        # No visible margin: the file's own order (its first point is the top-left), made clockwise.
        first = int(np.argmin(np.linalg.norm(pts - arr[0][None], axis=1)))
        oriented, how, margins = np.roll(pts, -first, axis=0), "the file's order (first point top-left)", {}
    try:
        refined = refine_corners(photo.grey, oriented, passes=1)
        points, blur = refined.edge_points, refined.blur_px
    except FrameError:
        points, blur = [], float("nan")
    return Corners(oriented, found_by, how, margins, points, blur)


# ---------------------------------------------------------------------------------------------
# Overlay


def draw_overlay(photo: PhotoData, corners: np.ndarray | None, candidates: Sequence[np.ndarray] = (),
                 message: str = "") -> np.ndarray:
    """The photo (sRGB 8-bit, at most :data:`OVERLAY_PX`) with candidates (blue), the frame (green) and
    its corners (TL red, the others yellow, labelled), and ``message`` (red text, for errors)."""
    h, w = photo.size
    scale = min(1.0, OVERLAY_PX / max(h, w))
    img = photo.encoded
    if scale < 1.0:  # downscaled before the 8-bit conversion: no full-size temporaries for a 12 MP photo
        img = cv2.resize(img, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    img = np.ascontiguousarray(np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8))
    thick = max(1, round(max(img.shape[:2]) / 500))
    shift = 4  # sub-pixel drawing

    def pts(q: np.ndarray) -> np.ndarray:
        return np.round((np.asarray(q) * scale + 0.5 * scale - 0.5) * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)

    for q in candidates:
        cv2.polylines(img, [pts(q)], True, (60, 120, 255), thick, cv2.LINE_AA, shift)
    if corners is not None:
        cv2.polylines(img, [pts(corners)], True, (0, 220, 0), thick, cv2.LINE_AA, shift)
        for k, (label, colour) in enumerate((("TL", (255, 0, 0)), ("TR", (255, 220, 0)), ("BR", (255, 220, 0)),
                                             ("BL", (255, 220, 0)))):
            p = pts(corners[k:k + 1])[0, 0]
            cv2.circle(img, (int(p[0]), int(p[1])), 6 * thick * (1 << shift), colour, thick, cv2.LINE_AA, shift)
            xy = (int(p[0] >> shift) + 6 * thick, int(p[1] >> shift) - 6 * thick)
            cv2.putText(img, label, xy, cv2.FONT_HERSHEY_SIMPLEX, 0.5 * thick, colour, thick, cv2.LINE_AA)
    if message:
        words, line, lines = message.split(), "", []
        width = max(20, img.shape[1] // (9 * thick))
        for word in words:
            if len(line) + len(word) + 1 > width:
                lines.append(line)
                line = word
            else:
                line = f"{line} {word}".strip()
        lines.append(line)
        for k, text in enumerate(lines[:8]):
            y = (k + 1) * 16 * thick
            cv2.putText(img, text, (5, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * thick, (0, 0, 0), 3 * thick, cv2.LINE_AA)
            cv2.putText(img, text, (5, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * thick, (255, 40, 40), thick, cv2.LINE_AA)
    return img


def _write_png8(path: Path, rgb8: np.ndarray) -> None:
    with atomic_path(path) as tmp:  # the temporary name keeps the .png suffix
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(rgb8[..., ::-1])):
            raise ValueError(f"{path}: expected to write a PNG, got a failed write")


# ---------------------------------------------------------------------------------------------
# The driver


@dataclass(frozen=True)
class RectifyOptions:
    """Settings of :func:`rectify_photos` (the command line's options)."""

    size: int | None = None  #: output side, texels; None: what the photos resolve, at most 1024 (:func:`auto_size`)
    fov_deg: float | None = None  #: FOV across the photo's long side; None: EXIF
    frame: FrameSpec = DEFAULT_FRAME  #: the paper frame (window = --frame-size)
    flash_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: flash from the camera (x right, y up, z fwd)
    intensity: float | None = None  #: flash intensity; None: |flash|^2 per photo

    def __post_init__(self) -> None:
        if not (self.size is None or (isinstance(self.size, int) and self.size >= 8)):
            raise ValueError(f"--size: expected auto or an int >= 8, got {self.size!r}")
        if self.intensity is not None and not (math.isfinite(self.intensity) and self.intensity > 0):
            raise ValueError(f"--intensity: expected a number > 0, got {self.intensity!r}")
        if len(self.flash_offset_mm) != 3 or not all(math.isfinite(v) for v in self.flash_offset_mm):
            raise ValueError(f"--flash-offset: expected X,Y,Z millimetres, got {self.flash_offset_mm!r}")


@dataclass
class PhotoResult:
    """What :func:`rectify_photos` did with one photo (``to_dict``: its ``rectify.json`` entry)."""

    photo: str
    index: int
    ok: bool = False
    error: str = ""
    entry: dict[str, Any] = field(default_factory=dict)
    image: ImageSpec | None = None
    #: left for the set's orientation rule (:func:`orientation_rule`): nothing written yet
    pending: bool = False
    corners: Corners | None = field(default=None, repr=False)  #: the corners found (kept while pending)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"photo": self.photo, "status": "ok" if self.ok else "error",
                **({"error": self.error} if self.error else {}), **self.entry}


def load_corners_file(path: str | os.PathLike) -> dict[str, Any]:
    """Read a ``--corners`` JSON (``{file name: [[x, y] x 4]}``); ``ValueError`` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--corners: expected a JSON file, got no such file {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: expected valid JSON, got {exc}") from exc
    if not isinstance(data, dict):  # a bad file's content: ValueError, like every input error here
        raise ValueError(f"{path}: expected an object mapping file names to four [x, y] points, "  # noqa: TRY004
                         f"got {type(data).__name__}")
    return data


def _lookup(table: dict[str, Any], photo: Path) -> Any:
    for key in (str(photo), photo.name):
        if key in table:
            return table[key]
    return None


def rectify_one(photo_path: Path, index: int, out: Path, options: RectifyOptions,
                corners_table: dict[str, Any] | None, corners_source: str, *, by_photo: bool | None = False,
                because: str = "", known: Corners | None = None, covered: float | None = None,
                detect_only: bool = False) -> PhotoResult:
    """Rectify one photo into ``out`` (``NNN.png``, ``overlay_NNN.png``); errors are caught into the result.

    Args:
        by_photo: a photo whose frame does not tell the orientation (no margin clearly the widest)
            is oriented by the photo (True), fails (False; ``because`` is added to the message), or
            is returned ``pending`` with nothing written (None: :func:`rectify_photos` decides for
            the whole set, then calls again with ``known``, the corners found).
        covered: the part of the window the rectified image covers, ``[-covered, covered]^2`` (one for the whole
            set, :func:`common_coverage`; None: this photo's own, ``1 -`` :func:`inset_fraction`).
        detect_only: find and check the corners only: a photo that passes is returned ``pending`` with its
            corners and nothing written (the first pass of :func:`rectify_photos`).
    """
    result = PhotoResult(str(photo_path), index)
    overlay_name, output_name = f"overlay_{index:03d}.png", f"{index:03d}.png"
    result.entry["overlay"] = overlay_name
    photo = None
    corners: Corners | None = None
    candidates: list[np.ndarray] = []
    try:
        photo = read_photo(photo_path)
        _check_photo_size(photo)
        if known is not None:
            corners = known
        else:
            given = _lookup(corners_table, photo_path) if corners_table else None
            corners = (given_corners(photo, given, corners_source, options.frame) if given is not None
                       else detect_corners(photo, options.frame))
        candidates = corners.candidates
        if corners.unoriented and not by_photo:
            if by_photo is None:
                result.pending, result.corners = True, corners
                return result
            err = RectifyError(corners.unoriented + (f"; {because}" if because else ""))
            corners = None  # not drawn: the frame did not orient them
            raise err
        result.entry.update(_geometry(photo, corners, options))
        if detect_only:
            _check_window(photo_path, corners, options.size)
            result.pending, result.corners = True, corners
            return result
        _check_window(photo_path, corners, options.size)
        result.image = _write_rectified(photo, corners, out / output_name, options, result.entry, covered)
        result.entry["output"] = output_name
        result.ok = True
    except (RectifyError, ValueError) as exc:
        msg = str(exc)
        if not msg.startswith(str(photo_path)):
            msg = f"{photo_path}: {msg}"
        result.error = msg
        candidates = getattr(exc, "candidates", candidates)
        stale = out / output_name
        stale.unlink(missing_ok=True)
    if photo is not None:
        ov = draw_overlay(photo, corners.corners if corners is not None else None, candidates,
                          "" if result.ok else result.error)
        _write_png8(out / overlay_name, ov)
    else:
        result.entry.pop("overlay")
    return result


def _geometry(photo: PhotoData, corners: Corners, options: RectifyOptions) -> dict[str, Any]:
    hom = plane_homography(corners.corners)
    entry: dict[str, Any] = {
        "size_hw": list(photo.size), "conversions": photo.notes,
        "corners_px": corners.corners.round(3).tolist(), "corner_order": ["top-left", "top-right", "bottom-right",
                                                                          "bottom-left"],
        "found_by": corners.found_by, "orientation": corners.orientation,
        "paper_margins_half_widths": {k: round(v, 3) for k, v in corners.margins.items()},
        "homography_plane_to_px": hom.tolist(),
        "edge_blur_px": None if not math.isfinite(corners.blur_px) else round(corners.blur_px, 3),
    }
    edge = edge_residual_px(hom, corners.edge_points) if corners.edge_points else float("nan")
    entry["reprojection_error_px"] = {"edges_rms": None if not math.isfinite(edge) else round(edge, 4)}
    return entry


def _shortest_side(corners: np.ndarray) -> float:
    """The shortest side, in photo pixels, of the window whose ``(4, 2)`` corners go round it."""
    return float(np.min(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))


def inset_fraction(corners: np.ndarray, blur_px: float, size: int) -> float:
    """How far inside the window's edge the rectified image starts, as a fraction of the window's half-width:
    :data:`INSET_PX` plus :data:`INSET_BLURS` blur sigmas (photo pixels, over the window's shortest side) and
    half an output texel, at most :data:`MAX_INSET`.

    Examples:
        >>> square = np.array([[0.0, 0.0], [200.0, 0.0], [200.0, 200.0], [0.0, 200.0]])
        >>> round(inset_fraction(square, 0.5, 256), 4)  # (1 + 1.5) px of 100 px half-width + 1/256
        0.0289
    """
    side = _shortest_side(corners)
    blur = blur_px if math.isfinite(blur_px) else INSET_UNKNOWN_BLUR_PX
    return min(MAX_INSET, (INSET_PX + INSET_BLURS * blur) / (side / 2.0) + 1.0 / size)


#: ``--size auto``: the rectified side is a multiple of this, at least :data:`AUTO_MIN` texels.
AUTO_STEP, AUTO_MIN = 32, 64


def window_holds(corners_px: np.ndarray, blur_px: float) -> float:
    """How many texels a photo resolves across the sample: its window's shortest side in photo pixels
    (``corners_px (4, 2)``, in order around the window), fewer when its edges are blurrier than
    :data:`MAX_BLUR_TEXELS` texels of that size (and than :data:`MAX_BLUR_PX`)."""
    side = _shortest_side(np.asarray(corners_px, dtype=np.float64))
    if math.isfinite(blur_px) and blur_px > MAX_BLUR_PX:
        side = min(side, side * MAX_BLUR_TEXELS / blur_px)
    return float(side)


def auto_size(holds: Sequence[float], cap: int = DEFAULT_MAX_SIDE) -> int:
    """``--size auto``: the median over the photos of the texels each resolves across the sample
    (:func:`window_holds`), rounded down to a multiple of :data:`AUTO_STEP`, within ``[AUTO_MIN, cap]``: the
    rectified photos keep the detail the photos hold, up to the maps artists use.

    Examples:
        >>> auto_size([1400.0, 1380.0, 900.0]), auto_size([300.0, 290.0]), auto_size([40.0])
        (1024, 288, 64)
    """
    if not holds:
        raise ValueError("holds: expected the texels of at least one photo, got none")
    median = float(np.median(np.asarray(holds, dtype=np.float64)))
    return int(min(cap, max(AUTO_MIN, AUTO_STEP * math.floor(median / AUTO_STEP))))


def auto_size_words(size: int, holds: Sequence[float], cap: int = DEFAULT_MAX_SIDE) -> str:
    """The line that says what ``--size auto`` chose and why."""
    median = float(np.median(np.asarray(holds, dtype=np.float64)))
    why = (f"at most {cap}" if size == cap and median >= cap else
           f"at least {AUTO_MIN}" if size == AUTO_MIN and median < AUTO_MIN else f"a multiple of {AUTO_STEP}")
    return (f"--size auto: {size}x{size} texels (the photos resolve {median:.0f} px across the sample, the median of "
            f"{len(holds)}; {why})")


def _check_window(photo_path: Path, corners: Corners, size: int) -> None:
    """A :class:`RectifyError` when the window is too small in the photo or its edges too blurry for ``size``."""
    side = _shortest_side(corners.corners)
    if side < MIN_WINDOW_PX:
        raise RectifyError(f"{photo_path}: expected the frame's window at least {MIN_WINDOW_PX} px on a side, "
                           f"got {side:.0f} px: the sample is too small in this photo")
    texel_px = side / size
    blur = corners.blur_px
    if math.isfinite(blur) and blur > max(MAX_BLUR_PX, MAX_BLUR_TEXELS * texel_px):
        raise RectifyError(f"{photo_path}: expected sharp frame edges, got a blur of {blur:.1f} px (sigma), "
                           f"{blur / texel_px:.1f} texels of the {size}^2 output (at most "
                           f"{MAX_BLUR_TEXELS} texels or {MAX_BLUR_PX} px): the photo is too blurry "
                           "(or use a smaller --size)")


def common_coverage(corners: Sequence[Corners], size: int) -> float:
    """The part of the window every rectified photo of a set covers, ``[-c, c]^2``: ``1 -`` the largest
    :func:`inset_fraction` of the photos' corners (one crop for the set: texel (i, j) is the same point of the
    sample in every photo); with no corners, half a texel's."""
    return 1.0 - max((inset_fraction(c.corners, c.blur_px, size) for c in corners), default=1.0 / size)


def _write_rectified(photo: PhotoData, corners: Corners, path: Path, options: RectifyOptions,
                     entry: dict[str, Any], covered: float | None = None) -> ImageSpec:
    focal, fov, fov_source = focal_px(photo.size, options.fov_deg, photo.focal_35mm)
    pose = camera_pose(corners.corners, intrinsics(photo.size, focal), options.frame)
    # the image covers [-c, c]^2 of the window: positions in its half-widths are the window's divided by c
    if covered is None:
        covered = 1.0 - inset_fraction(corners.corners, corners.blur_px, options.size)
    camera = tuple(float(v) / covered for v in pose.position)
    light = tuple(float(v) / covered for v in flash_position(pose, options.flash_offset_mm, options.frame))
    if light[2] <= 0:
        raise RectifyError(f"{photo.path}: expected the flash above the sample, got z = {light[2]:.3f} "
                           f"(--flash-offset {options.flash_offset_mm})")
    intensity = options.intensity if options.intensity is not None else default_intensity(light)
    hom = plane_homography(corners.corners) @ np.diag([covered, covered, 1.0])
    k = supersampling(corners.corners, options.size)
    linear = warp_to_plane(photo.linear, hom, options.size, supersample=k)
    sat = warp_to_plane(photo.saturated.astype(np.float32), hom, options.size, supersample=k)[..., 0] > 0.01
    encoded = srgb_encode(np.clip(linear, 0.0, 1.0))
    encoded[sat] = 1.0
    _write_png8(path, np.clip(np.rint(encoded * 255.0), 0, 255).astype(np.uint8))
    entry["reprojection_error_px"]["corners_rms_pose"] = round(pose.reprojection_px, 4)
    entry.update({"fov_deg": round(fov, 4), "fov_source": fov_source, "focal_px": round(focal, 3),
                  "supersampling": k, "saturated_texels": int(sat.sum()), "window_covered": round(covered, 6),
                  "camera_position": [round(v, 6) for v in camera],
                  "light_position": [round(v, 6) for v in light], "intensity": intensity})
    return ImageSpec(path.name, "srgb8", True, CameraSpec(camera, fov),
                     LightSpec(light, (intensity,) * 3, None))


def orientation_rule(results: Sequence[PhotoResult]) -> tuple[bool, str]:
    """One orientation rule for a set of photos: ``(orient by the photo, why not)``.

    A photo whose frame shows no widest margin is oriented by the photo
    (:func:`~mi_svbrdf.geometry.frame.orient_by_photo`) only when no photo of the set was oriented
    by the frame's widest margin and at least one shows the frame whole with no widest margin (a
    symmetric frame, not a cut one). Otherwise such photos fail, as they would alone, and the
    second value says why when other photos show the widest margin (one rule for the set: the
    frame's margin, or every photo's own orientation, never a mix).

    Args:
        results: the first pass of :func:`rectify_one` (``by_photo=None``) over the set.
    """
    by_frame = sum(r.entry.get("orientation") == ORIENTED_BY_FRAME for r in results)
    if by_frame:
        return False, (f"{by_frame} other photo{'s' if by_frame > 1 else ''} of the set "
                       f"show{'' if by_frame > 1 else 's'} the frame's widest margin, which then orients every photo")
    return any(r.pending and r.corners is not None and r.corners.symmetric for r in results), ""


def capture_notes(results: Sequence[PhotoResult]) -> list[str]:
    """What the user should know about a rectified set (``rectify.json``'s ``notes``; the command prints them)."""
    n = sum(r.ok and r.entry.get("orientation") == ORIENTED_BY_PHOTO for r in results)
    if not n:
        return []
    return [f"the orientation of {n} photo{'s was' if n > 1 else ' was'} taken from the photos, not the frame: no "
            "photo shows a paper margin clearly wider than the others (a symmetric frame), so in each photo the "
            "window's side nearest the photo's bottom edge is the sample's bottom (+y up as in the photo); the "
            "photos line up only if each was taken with the same side of the sample towards its bottom edge "
            "(a frame with one wide margin fixes +y whatever the camera's rotation)"]


def write_capture_file(out: Path, results: Sequence[Any]) -> None:
    """``out/capture.json`` of the photos that were rectified (each result's ``ok`` and ``image``), or none (a
    former one removed) when no photo was: a capture file never lists photos this run did not write."""
    images = tuple(r.image for r in results if r.ok and r.image is not None)
    if images:
        write_json(out / "capture.json", CaptureSpec(images).to_dict())
    else:
        (out / "capture.json").unlink(missing_ok=True)


def rectify_photos(photos: Sequence[str | os.PathLike], out: str | os.PathLike,
                   options: RectifyOptions = RectifyOptions(),
                   corners_file: str | os.PathLike | None = None) -> list[PhotoResult]:
    """Rectify every photo into ``out`` and write ``rectify.json`` and ``capture.json`` (module docstring).

    A photo that fails is reported in its result (and ``rectify.json``) and left out of
    ``capture.json``; the others go on. ``capture.json`` is written when at least one succeeded.
    The set has one orientation rule (:func:`orientation_rule`): photos whose frame shows no
    widest margin are looked at again once every photo has been seen; when they are oriented
    by the photos, :func:`capture_notes` says so (``rectify.json``'s ``notes``).

    Args:
        photos: photo files (the output index is the position in this list).
        out: output folder (created).
        options: :class:`RectifyOptions`.
        corners_file: optional ``--corners`` JSON; photos it does not list are detected.

    Returns:
        One :class:`PhotoResult` per photo.
    """
    if not photos:
        raise ValueError("photos: expected at least one photo file, got none")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = load_corners_file(corners_file) if corners_file is not None else None
    source = str(corners_file)
    # first the corners of every photo, then one crop for the set (common_coverage), then the photos rectified
    # --size auto: the corners first at the smallest size (the blur check is then the lenient one), the size from them
    provisional = options if options.size is not None else dataclasses.replace(options, size=AUTO_MIN)
    results = [rectify_one(Path(p), i, out, provisional, table, source, by_photo=None, detect_only=True)
               for i, p in enumerate(photos)]
    size_words = None
    if options.size is None:
        holds = [window_holds(r.corners.corners, r.corners.blur_px) for r in results
                 if r.pending and r.corners is not None]
        options = dataclasses.replace(options, size=auto_size(holds) if holds else AUTO_MIN)
        size_words = auto_size_words(options.size, holds) if holds else None
    by_photo, because = orientation_rule(results)
    covered = common_coverage([r.corners for r in results if r.pending and r.corners is not None], options.size)
    results = [rectify_one(Path(r.photo), r.index, out, options, table, source, by_photo=by_photo, because=because,
                           known=r.corners, covered=covered) if r.pending else r for r in results]
    report = {"version": 1, "frame": {"sheet_mm": list(options.frame.sheet_mm),
                                      "window_mm": list(options.frame.window_mm),
                                      "margins_mm": options.frame.margins_mm},
              "size": options.size, **({"size_auto": size_words} if size_words else {}),
              "pixel_convention": "OpenCV: centre of the top-left pixel at (0, 0), upright photo",
              "notes": capture_notes(results), "photos": [r.to_dict() for r in results]}
    write_json(out / "rectify.json", report)
    write_capture_file(out, results)
    return results
