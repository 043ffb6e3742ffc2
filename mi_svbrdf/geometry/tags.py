"""The AprilTag print around a sample: its layout, finding its tags in a photo, the camera from them.

The print (the field's capture kit, :class:`TagSheet`): 16 tags of the tag36h11 family, IDs 0-15,
centred on the ring of a 5 x 5 grid, clockwise from the top left: the top row left to right
(0-4), the right column downwards (5-7), the bottom row right to left (8-12), the left column
upwards (13-15). In sheet *units* (origin at the centre, +y up): a tag's side is 2 units (its
black border included), the centres are 4 units apart, so the ring's outer edges are
:data:`RING_UNITS` = 18 units apart: that distance is the size ``S`` the user measures (mm).
Each tag is printed turned by 180 degrees from OpenCV's ``cv2.aruco.generateImageMarker``
drawing, so OpenCV reports each tag's first corner at its bottom right on the sheet. The window
cut in the middle is the square of +-6 units (side ``2 S / 3``): the sample plane ``[-1, 1]^2``
of a capture file (one capture unit is 6 sheet units, ``S / 3`` mm). The tag plane may lie
``depth_mm`` above the sample (a sheet on cardboard): the sample is at z = 0, the tags at
z = ``depth_mm / (S / 3)``.

Pixel coordinates are OpenCV's (centre of the top-left pixel at ``(0, 0)``).

* :func:`detect_tags`: the tags of a grey photo (``cv2.aruco.ArucoDetector``, tag36h11,
  sub-pixel corner refinement), IDs outside the print and repeated IDs dropped.
* :func:`calibrate`: focal length (square pixels), principal point and radial distortion
  (k1, k2) from every photo's corners (``cv2.calibrateCamera`` on the planar print seen from
  several angles; fewer parameters with fewer photos, :data:`CALIBRATION_MODELS`), tags whose
  corners do not fit dropped once.
* :func:`tag_pose`: a photo's camera from its tags (IPPE then Levenberg-Marquardt on all
  corners; a tag far off the others' fit is dropped), its reprojection error.
* :func:`window_maps`: where each texel of the rectified window lies in the photo (through the
  full camera model: distortion and depth included), for ``cv2.remap``.
* :func:`visible_reach`: how much of the window the print's edge, ``depth`` above the sample, leaves
  in view of a camera; :func:`edge_blur_px`: the photo's blur on the tags' edges (with the reach,
  how far from the window's edge a texel must be looked up to take nothing from the paper,
  :func:`~mi_svbrdf.geometry.tag_rectify.clear_limits`).

Examples:
    >>> tag_centres()[[0, 4, 5, 8, 12, 15]].tolist()
    [[-8.0, 8.0], [8.0, 8.0], [8.0, 4.0], [8.0, -8.0], [-8.0, -8.0], [-8.0, 4.0]]
    >>> TagSheet(180.0).window_mm
    120.0
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

#: The tag family: OpenCV's name of tag36h11.
DICTIONARY = cv2.aruco.DICT_APRILTAG_36h11
#: Tags on the print (IDs 0 .. TAG_COUNT - 1).
TAG_COUNT = 16
#: A tag's side in sheet units (black border included), the spacing of their centres, the ring's outer size.
TAG_UNITS, SPACING_UNITS, RING_UNITS = 2.0, 4.0, 18.0
#: Half-side of the cut window, sheet units: one capture unit.
WINDOW_HALF_UNITS = 6.0
#: Cells across a tag36h11 tag as OpenCV draws it (6 x 6 data cells and a one-cell black border).
TAG_CELLS = 8
#: Fewest tags a photo needs.
MIN_TAGS = 4
#: A tag whose corners lie this many times the median tag's error (and above MIN_OUTLIER_PX) off the fit is dropped.
OUTLIER_FACTOR, MIN_OUTLIER_PX = 5.0, 1.5
#: The intrinsics calibrated from ``n`` photos (the first row whose count is <= n): (photos, principal point
#: free, radial terms k1, k2 free). Fewer photos constrain fewer parameters.
CALIBRATION_MODELS = ((4, True, 2), (2, False, 1), (1, False, 0))
#: Largest relative standard deviation of the calibrated focal length accepted.
MAX_FOCAL_STD = 0.03
#: Fields of view (degrees across the long side) a calibration may find: phones and cameras, not a degenerate fit.
FOV_RANGE = (10.0, 130.0)


def _grid_cells() -> list[tuple[int, int]]:
    """``(column, row)`` of IDs 0..15 on the 5 x 5 grid (row 0 on top), clockwise from the top left."""
    return ([(c, 0) for c in range(5)] + [(4, r) for r in range(1, 4)] + [(c, 4) for c in range(4, -1, -1)]
            + [(0, r) for r in range(3, 0, -1)])


def tag_centres() -> np.ndarray:
    """``(16, 2)`` centres of tags 0..15 in sheet units (origin at the centre, +y up)."""
    return np.array([[(c - 2) * SPACING_UNITS, (2 - r) * SPACING_UNITS] for c, r in _grid_cells()])


#: The corners of a tag in OpenCV's order, from its centre, sheet units (+y up): printed turned by 180 degrees,
#: its first corner is at its bottom right, then bottom left, top left, top right.
CORNER_OFFSETS = 0.5 * TAG_UNITS * np.array([[1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]])


def tag_corners_units(ids: Sequence[int] | None = None) -> np.ndarray:
    """``(N, 4, 2)`` corners of tags ``ids`` (default all) in sheet units, in the order OpenCV reports them."""
    idx = np.arange(TAG_COUNT) if ids is None else np.asarray(ids, int)
    return tag_centres()[idx][:, None, :] + CORNER_OFFSETS[None]


@dataclass(frozen=True)
class TagSheet:
    """The AprilTag print as measured: ``size_mm`` (``S``, the ring's outer size) and the tag plane's height."""

    size_mm: float  #: S: outer edge to outer edge of the tag ring, mm (measured on the print)
    depth_mm: float = 0.0  #: height of the tag plane above the sample plane, mm (a sheet on cardboard)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.size_mm) and self.size_mm > 0):
            raise ValueError(f"--frame-size: expected the tag ring's outer size S in mm (> 0), got {self.size_mm!r}")
        if not (math.isfinite(self.depth_mm) and self.depth_mm >= 0):
            raise ValueError(f"--depth: expected millimetres >= 0, got {self.depth_mm!r}")

    @property
    def unit_mm(self) -> float:
        """One sheet unit in mm (``S / 18``)."""
        return self.size_mm / RING_UNITS

    @property
    def window_mm(self) -> float:
        """Side of the cut window, mm (``2 S / 3``)."""
        return 2.0 * WINDOW_HALF_UNITS * self.unit_mm

    @property
    def depth(self) -> float:
        """The tag plane's height above the sample in capture units (the window's half-side is 1)."""
        return self.depth_mm / (WINDOW_HALF_UNITS * self.unit_mm)

    def object_points(self, ids: Sequence[int]) -> np.ndarray:
        """``(N, 4, 3)`` corners of tags ``ids`` in the capture frame (window ``[-1, 1]^2`` at z = 0, tags at
        z = :attr:`depth`)."""
        xy = tag_corners_units(ids) / WINDOW_HALF_UNITS
        return np.concatenate([xy, np.full(xy.shape[:2] + (1,), self.depth)], axis=2)


def tag_image(tag_id: int, cells_px: int) -> np.ndarray:
    """``(8 c, 8 c)`` uint8 tag ``tag_id`` as printed (``c = cells_px`` pixels per cell): OpenCV's drawing turned
    by 180 degrees."""
    if not 0 <= int(tag_id) < TAG_COUNT:
        raise ValueError(f"tag_id: expected 0..{TAG_COUNT - 1}, got {tag_id!r}")
    dictionary = cv2.aruco.getPredefinedDictionary(DICTIONARY)
    drawn = cv2.aruco.generateImageMarker(dictionary, int(tag_id), TAG_CELLS * cells_px)
    return np.ascontiguousarray(drawn[::-1, ::-1])


def sheet_image(cells_px: int, margin_units: float = 2.0) -> tuple[np.ndarray, float, float]:
    """The print's ring as an image: white paper, the 16 tags, no window drawn.

    Args:
        cells_px: pixels per tag cell (a sheet unit is ``4 * cells_px`` pixels).
        margin_units: white paper beyond the ring's outer edges, sheet units (a multiple of 1/4).

    Returns:
        ``(image (N, N) uint8, origin, px_per_unit)``: the sheet point ``(x, y)`` (units, +y up) is at the
        pixel ``(origin + x * px_per_unit - 0.5, origin - y * px_per_unit - 0.5)`` (OpenCV pixels).

    Examples:
        >>> img, origin, ppu = sheet_image(2, 1.0)
        >>> img.shape, origin, ppu
        ((160, 160), 80.0, 8.0)
    """
    ppu = TAG_CELLS * cells_px / TAG_UNITS
    half = RING_UNITS / 2.0 + margin_units
    n = int(round(2.0 * half * ppu))
    img = np.full((n, n), 255, np.uint8)
    origin = n / 2.0
    side = TAG_CELLS * cells_px
    for tag_id, (x, y) in enumerate(tag_centres()):
        c0 = int(round(origin + (x - 1.0) * ppu))
        r0 = int(round(origin - (y + 1.0) * ppu))
        img[r0:r0 + side, c0:c0 + side] = tag_image(tag_id, cells_px)
    return img, origin, ppu


# ---------------------------------------------------------------------------------------------
# Detection


@dataclass
class Detections:
    """The print's tags found in a photo.

    Attributes:
        ids: ``(N,)`` tag IDs (0..15), sorted.
        corners: ``(N, 4, 2)`` their corners (OpenCV pixels, OpenCV's order: on the print bottom right first).
        ignored: what was dropped (IDs not on the print, repeated IDs).
    """

    ids: np.ndarray
    corners: np.ndarray
    ignored: list[str] = field(default_factory=list)


def detector() -> cv2.aruco.ArucoDetector:
    """OpenCV's tag36h11 detector with sub-pixel corner refinement."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 4
    params.cornerRefinementMaxIterations = 60
    params.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), params)


#: The longest step of :func:`refine_tag`'s profiles across a tag's edge, pixels (a tag 200 px wide in a 12 MP photo:
#: 1/8 cell would be 3 px).
PROFILE_STEP_PX = 0.25


def refine_tag(linear: np.ndarray, quad: np.ndarray, passes: int = 2) -> np.ndarray:
    """A tag's corners from its four outer edges, to a fraction of a pixel.

    Along each side, profiles across the edge (bilinear, steps of 1/8 cell but at most :data:`PROFILE_STEP_PX`:
    coarser steps put a sharp edge's crossing between two samples, the same in every profile; from 3/4 of a cell inside
    the black border to 1 1/2 cells out on the paper) locate where the linear grey crosses halfway
    between the border's and the paper's (unbiased by a symmetric blur, unlike a corner fit on
    sRGB-encoded values, which pulls corners into the tag); a total-least-squares line per side
    and the intersections of neighbouring lines give the corners. Tags under 16 pixels, and sides
    without a clear step, keep the corners given.

    Args:
        linear: ``(H, W)`` float32 linear grey photo.
        quad: ``(4, 2)`` corners in OpenCV's order (clockwise in the photo).
        passes: refinement passes.

    Returns:
        ``(4, 2)`` corners in the same order.
    """
    corners = np.asarray(quad, np.float64).copy()
    for _ in range(passes):
        sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
        cell = float(sides.min()) / TAG_CELLS
        if cell < 2.0:
            return corners
        centre = corners.mean(axis=0)
        lines = []
        for s in range(4):
            a, b = corners[s], corners[(s + 1) % 4]
            along = (b - a) / np.linalg.norm(b - a)
            out = np.array([along[1], -along[0]])
            if np.dot(0.5 * (a + b) - centre, out) < 0:
                out = -out
            count = int(np.clip(sides[s] / 2.0, 8, 80))
            t = np.linspace(0.15, 0.85, count)
            base = a[None] + t[:, None] * (b - a)[None]
            offsets = np.arange(-0.75 * cell, 1.5 * cell + 1e-9, min(cell / 8.0, PROFILE_STEP_PX))
            pts = base[:, None, :] + offsets[None, :, None] * out[None, None, :]
            values = cv2.remap(linear, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32),
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
            inner = offsets < -0.25 * cell
            outer = offsets > 0.75 * cell
            dark = np.median(values[:, inner], axis=1)
            bright = np.median(values[:, outer], axis=1)
            ok = bright - dark > 0.5 * np.median(bright - dark)
            half = 0.5 * (dark + bright)
            found = []
            for r in np.flatnonzero(ok):
                above = values[r] >= half[r]
                # the last crossing from below to above, before the paper
                k = np.flatnonzero(~above[:-1] & above[1:])
                if len(k) != 1:
                    continue
                k = int(k[0])
                v0, v1 = values[r, k], values[r, k + 1]
                frac = (half[r] - v0) / (v1 - v0) if v1 != v0 else 0.5
                found.append(base[r] + (offsets[k] + frac * (offsets[k + 1] - offsets[k])) * out)
            if len(found) < 4:
                return np.asarray(quad, np.float64)
            p = np.array(found)
            c = p.mean(axis=0)
            _, _, vt = np.linalg.svd(p - c)
            lines.append((c, vt[0]))
        new = []
        for s in range(4):
            (p1, d1), (p2, d2) = lines[(s - 1) % 4], lines[s]
            m = np.array([d1, -d2]).T
            if abs(np.linalg.det(m)) < 1e-6:
                return np.asarray(quad, np.float64)
            new.append(p1 + np.linalg.solve(m, p2 - p1)[0] * d1)
        new = np.array(new)
        if np.abs(new - np.asarray(quad)).max() > 0.5 * cell:
            return np.asarray(quad, np.float64)
        corners = new
    return corners


def detect_tags(grey: np.ndarray, linear: np.ndarray | None = None) -> Detections:
    """The print's tags in a grey photo.

    Args:
        grey: ``(H, W)`` uint8, or float in [0, 1] (sRGB-encoded).
        linear: ``(H, W)`` the same photo's linear grey, for :func:`refine_tag`; None: decoded from ``grey``.

    Returns:
        :class:`Detections`.
    """
    img = np.asarray(grey)
    if img.dtype != np.uint8:
        img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    if linear is None:
        from mi_svbrdf.io.material_io import srgb_decode

        linear = srgb_decode(img.astype(np.float32) / 255.0)
    linear = np.ascontiguousarray(linear, dtype=np.float32)
    corners, ids, _ = detector().detectMarkers(np.ascontiguousarray(img))
    corners = [refine_tag(linear, np.asarray(c, np.float64).reshape(4, 2)) for c in corners]
    found: dict[int, list[np.ndarray]] = {}
    ignored = []
    for c, i in zip(corners, [] if ids is None else ids.reshape(-1)):
        if 0 <= int(i) < TAG_COUNT:
            found.setdefault(int(i), []).append(np.asarray(c, np.float64).reshape(4, 2))
        else:
            ignored.append(f"tag {int(i)} (not on the print)")
    keep = sorted(i for i, cs in found.items() if len(cs) == 1)
    ignored += [f"tag {i} (seen {len(found[i])} times)" for i in sorted(found) if len(found[i]) > 1]
    return Detections(np.array(keep, int), np.array([found[i][0] for i in keep]).reshape(-1, 4, 2), ignored)


# ---------------------------------------------------------------------------------------------
# Camera


@dataclass(frozen=True)
class Intrinsics:
    """A camera's intrinsics in the stored (sensor) orientation of its photos.

    Attributes:
        matrix: ``(3, 3)`` OpenCV camera matrix.
        distortion: ``(5,)`` OpenCV distortion (k1, k2, p1, p2, k3).
        size: ``(W, H)`` of the photos, stored orientation.
        source: where it came from (``calibrated from N photos``, ``--fov``, EXIF).
        rms_px: RMS reprojection error of the calibration (NaN when not calibrated).
        photos: how many photos the calibration used (0: not calibrated).
    """

    matrix: np.ndarray
    distortion: np.ndarray
    size: tuple[int, int]
    source: str
    rms_px: float = float("nan")
    photos: int = 0

    @property
    def focal_px(self) -> float:
        """The focal length in pixels (square pixels)."""
        return float(self.matrix[0, 0])

    @property
    def fov_deg(self) -> float:
        """Field of view across the photo's long side, degrees."""
        return math.degrees(2.0 * math.atan(0.5 * max(self.size) / self.focal_px))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready."""
        k = self.matrix
        return {"source": self.source, "size_wh": list(self.size), "focal_px": round(float(k[0, 0]), 3),
                "principal_point_px": [round(float(k[0, 2]), 3), round(float(k[1, 2]), 3)],
                "distortion_k1_k2_p1_p2_k3": [round(float(v), 6) for v in self.distortion.reshape(-1)[:5]],
                "fov_deg": round(self.fov_deg, 4), "photos": self.photos,
                "rms_px": None if not math.isfinite(self.rms_px) else round(self.rms_px, 4)}


def pinhole(size: tuple[int, int], focal: float, source: str) -> Intrinsics:
    """A pinhole camera of ``focal`` pixels, principal point at the centre of ``size (W, H)``, no distortion."""
    w, h = size
    k = np.array([[focal, 0.0, 0.5 * (w - 1)], [0.0, focal, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])
    return Intrinsics(k, np.zeros(5), (int(w), int(h)), source)


class CalibrationError(ValueError):
    """The photos do not determine the intrinsics; the message says why and what to do."""


def _calibrate_once(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
                    flags: int) -> tuple[float, np.ndarray, np.ndarray, list, list, np.ndarray]:
    w, h = size
    k0 = np.array([[max(w, h), 0.0, 0.5 * (w - 1)], [0.0, max(w, h), 0.5 * (h - 1)], [0.0, 0.0, 1.0]])
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, k, dist, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended(
        [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img], (w, h), k0, np.zeros(5),
        flags=flags, criteria=criteria)
    return float(rms), k, dist.reshape(-1), list(rvecs), list(tvecs), std.reshape(-1)


def calibrate(views: Sequence[tuple[np.ndarray, np.ndarray]], size: tuple[int, int]) -> tuple[Intrinsics,
                                                                                               list[np.ndarray]]:
    """The intrinsics from photos of the planar print (see the module docstring).

    Args:
        views: per photo ``(object points (N, 3) on the plane z = 0, image points (N, 2))`` (stored orientation),
            the corners of its tags in the same order, 4 per tag.
        size: ``(W, H)`` of the photos (stored orientation).

    Returns:
        ``(intrinsics, kept)``: ``kept[i]`` a bool mask of view i's points used (tags off the fit dropped).

    Raises:
        CalibrationError: no photo, or a focal length the photos do not determine (every photo square-on
            to the print).
    """
    if not views:
        raise CalibrationError("expected at least one photo with enough tags to calibrate the camera, got none")
    n = len(views)
    _, free_pp, radial = next(m for m in CALIBRATION_MODELS if n >= m[0])
    flags = cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    flags |= 0 if free_pp else cv2.CALIB_FIX_PRINCIPAL_POINT
    flags |= 0 if radial >= 2 else cv2.CALIB_FIX_K2
    flags |= 0 if radial >= 1 else cv2.CALIB_FIX_K1
    obj = [np.asarray(o, np.float64) for o, _ in views]
    img = [np.asarray(i, np.float64) for _, i in views]
    kept = [np.ones(len(o), bool) for o in obj]
    for attempt in range(2):
        rms, k, dist, rvecs, tvecs, std = _calibrate_once([o[m] for o, m in zip(obj, kept)],
                                                          [i[m] for i, m in zip(img, kept)], size, flags)
        if attempt:
            break
        # Per tag (4 points), its RMS error: a tag far off the others' fit (glare, a misread corner) is dropped.
        errors = []
        for o, i, r, t in zip(obj, img, rvecs, tvecs):
            proj, _ = cv2.projectPoints(o, r, t, k, dist)
            errors.append(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - i) ** 2, axis=1).reshape(-1, 4), axis=1)))
        median = float(np.median(np.concatenate(errors)))
        limit = max(MIN_OUTLIER_PX, OUTLIER_FACTOR * median)
        new = [np.repeat(e <= limit, 4) for e in errors]
        if all(m.all() for m in new) or any(m.sum() < 4 * MIN_TAGS for m in new):
            break
        kept = new
    # With a fixed aspect ratio OpenCV reports the focal length's deviation on fy (index 1).
    spread = float(np.max(std[:2]))
    focal_std = spread / float(k[0, 0]) if np.isfinite(spread) and k[0, 0] > 0 else float("inf")
    fov = math.degrees(2.0 * math.atan(0.5 * max(size) / k[0, 0])) if k[0, 0] > 0 else 0.0
    if not (focal_std <= MAX_FOCAL_STD and FOV_RANGE[0] <= fov <= FOV_RANGE[1]):
        raise CalibrationError(f"expected photos that determine the focal length, got {n} photo{'s' * (n > 1)} "
                               f"that leave it uncertain by {100 * focal_std:.0f} % (calibrated {k[0, 0]:.0f} px, a "
                               f"field of view of {fov:.1f} degrees; expected {FOV_RANGE[0]:g}-{FOV_RANGE[1]:g}): take "
                               "some photos at an angle (20-40 degrees from straight above), or give --fov")
    what = "focal length" + (", principal point" if free_pp else "") + (f", k1..k{radial}" if radial else "")
    intr = Intrinsics(k, dist[:5].copy(), (int(size[0]), int(size[1])),
                      f"calibrated from the tags of {n} photo{'s' * (n > 1)} ({what})", rms, n)
    return intr, kept


@dataclass(frozen=True)
class TagPose:
    """A photo's camera from its tags.

    Attributes:
        rvec, tvec: ``(3,)`` OpenCV's pose of the capture frame (sample at z = 0) in the camera (stored orientation).
        position: camera position in the capture frame.
        used: IDs of the tags used.
        dropped: IDs of tags found but left out (off the others' fit).
        reprojection_px: RMS distance of the used corners to their reprojection.
    """

    rvec: np.ndarray
    tvec: np.ndarray
    position: tuple[float, float, float]
    used: tuple[int, ...]
    dropped: tuple[int, ...]
    reprojection_px: float


def _solve(obj: np.ndarray, img: np.ndarray, camera: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rvec, tvec, per-point error)`` of planar ``obj (N, 3)`` (z constant) seen at ``img (N, 2)``."""
    z = float(obj[0, 2])
    flat = obj - np.array([0.0, 0.0, z])
    ok, rvec, tvec = cv2.solvePnP(flat, img, camera.matrix, camera.distortion, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("camera pose: expected a solution of the tags' PnP, got none")
    rvec, tvec = cv2.solvePnPRefineLM(flat, img, camera.matrix, camera.distortion, rvec, tvec,
                                      (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    rot, _ = cv2.Rodrigues(rvec)
    tvec = tvec.reshape(3) - z * rot[:, 2]  # the tag plane at z: the capture frame's origin is z below it
    proj, _ = cv2.projectPoints(obj, rvec, tvec, camera.matrix, camera.distortion)
    return rvec.reshape(3), tvec, np.linalg.norm(proj.reshape(-1, 2) - img, axis=1)


def tag_pose(ids: np.ndarray, corners: np.ndarray, sheet: TagSheet, camera: Intrinsics) -> TagPose:
    """The camera of a photo whose tags ``ids (N,)`` were found at ``corners (N, 4, 2)`` (stored orientation).

    Raises:
        ValueError: fewer than :data:`MIN_TAGS` tags, or the camera below the print.
    """
    ids = np.asarray(ids, int)
    if len(ids) < MIN_TAGS:
        raise ValueError(f"expected at least {MIN_TAGS} of the print's {TAG_COUNT} tags, got {len(ids)}")
    obj = sheet.object_points(ids)
    img = np.asarray(corners, np.float64).reshape(-1, 4, 2)
    keep = np.ones(len(ids), bool)
    for _ in range(3):
        rvec, tvec, err = _solve(obj[keep].reshape(-1, 3), img[keep].reshape(-1, 2), camera)
        per_tag = np.sqrt(np.mean(err.reshape(-1, 4) ** 2, axis=1))
        limit = max(MIN_OUTLIER_PX, OUTLIER_FACTOR * float(np.median(per_tag)))
        worst = int(np.argmax(per_tag))
        if per_tag[worst] <= limit or keep.sum() <= MIN_TAGS:
            break
        keep[np.flatnonzero(keep)[worst]] = False
    rot, _ = cv2.Rodrigues(rvec)
    centre = -rot.T @ tvec
    if centre[2] <= 0:
        raise ValueError(f"camera pose: expected the camera above the print, got z = {centre[2]:.3f}")
    rms = float(np.sqrt(np.mean(err ** 2)))
    return TagPose(rvec, tvec, tuple(float(v) for v in centre), tuple(int(i) for i in ids[keep]),
                   tuple(int(i) for i in ids[~keep]), rms)


def project(points: np.ndarray, pose: TagPose, camera: Intrinsics) -> np.ndarray:
    """``(N, 2)`` pixels (stored orientation) of capture-frame points ``(N, 3)`` through the full camera model."""
    proj, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), pose.rvec, pose.tvec,
                                camera.matrix, camera.distortion)
    return proj.reshape(-1, 2)


#: Rows of texels :func:`window_maps` projects at once.
MAP_ROWS = 128


def window_maps(pose: TagPose, camera: Intrinsics, size: int, supersample: int = 1,
                clear: Sequence[float] | None = None) -> np.ndarray:
    """``(k S, k S, 2)`` float32 pixels (stored orientation) of the window's texels on the sample plane.

    Texel ``(i, j)`` of the ``k S`` grid lies at ``x = -1 + (2 j + 1) / (k S)``, ``y = 1 - (2 i + 1) / (k S)``,
    z = 0 (the convention of :func:`~mi_svbrdf.geometry.homography.warp_to_plane`). ``clear``: how far from the
    centre the photo shows the sample clear of the print's paper, per side ``(+x, -x, +y, -y)`` (capture units);
    a texel beyond is looked up on that limit (it repeats the nearest texel seen clear of the paper).
    """
    fine = int(size) * int(supersample)
    c = -1.0 + (2.0 * np.arange(fine) + 1.0) / fine
    xs, ys = c, -c
    if clear is not None:
        px, nx, py, ny = (float(v) for v in clear)
        if not min(px, nx, py, ny) > 0:
            raise ValueError(f"clear: expected four limits > 0 (+x, -x, +y, -y), got {list(clear)!r}")
        xs, ys = np.clip(xs, -nx, px), np.clip(ys, -ny, py)
    out = np.empty((fine, fine, 2), np.float32)
    for r0 in range(0, fine, MAP_ROWS):  # in bands of rows: small temporaries for the millions of texels
        x, y = np.meshgrid(xs, ys[r0:r0 + MAP_ROWS])
        out[r0:r0 + MAP_ROWS] = _project_plane(x, y, pose, camera)
    return out


def _project_plane(x: np.ndarray, y: np.ndarray, pose: TagPose, camera: Intrinsics) -> np.ndarray:
    """``(..., 2)`` pixels of the sample plane's points ``(x, y, 0)``: :func:`project`'s OpenCV camera model
    (k1, k2, p1, p2, k3) evaluated in NumPy (``cv2.projectPoints`` also builds its Jacobians: seconds and a
    gigabyte for the millions of texels of a large window)."""
    dist = np.zeros(5)
    given = np.asarray(camera.distortion, np.float64).reshape(-1)
    if given.size > 5 and np.any(given[5:] != 0):
        pts = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3)
        return project(pts, pose, camera).reshape(*x.shape, 2)
    dist[:min(5, given.size)] = given[:5]
    k1, k2, p1, p2, k3 = dist
    rot, _ = cv2.Rodrigues(np.asarray(pose.rvec, np.float64))
    t = np.asarray(pose.tvec, np.float64).reshape(3)
    cx, cy, cz = (rot[i, 0] * x + rot[i, 1] * y + t[i] for i in range(3))
    u, v = cx / cz, cy / cz
    r2 = u * u + v * v
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ud = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u)
    vd = v * radial + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v
    m = np.asarray(camera.matrix, np.float64)
    return np.stack([m[0, 0] * ud + m[0, 2], m[1, 1] * vd + m[1, 2]], axis=-1)


def visible_reach(position: Sequence[float], depth: float) -> np.ndarray:
    """How far from the window's centre the sample is seen through the cut, per side ``(+x, -x, +y, -y)``, capture
    units (1: the whole window up to its edge; less: the print's edge, ``depth`` above the sample, hides a strip).

    A point of the sample is seen when its ray to the camera passes the tag plane inside the cut ``[-1, 1]^2``: the
    seen part of the sample plane is the cut projected from the camera's centre ``(cx, cy, cz)``, a square of
    half-side ``s = cz / (cz - depth)`` centred at ``(cx, cy) (1 - s)``. The strip under the print lies on the
    camera's side (lens distortion bends rays only inside the camera: the projection is exact).

    Examples:
        >>> visible_reach((0.0, 0.0, 5.0), 0.0).tolist()
        [1.0, 1.0, 1.0, 1.0]
        >>> visible_reach((3.0, 0.0, 4.0), 0.1).round(4).tolist()  # the +x side, towards the camera, is hidden
        [0.9487, 1.1026, 1.0256, 1.0256]
    """
    cx, cy, cz = (float(v) for v in position)
    if not cz > depth:
        raise ValueError(f"camera: expected above the print's tag plane (z > {depth:g}), got z = {cz:g}")
    s = cz / (cz - depth)
    return np.array([s - cx * (s - 1.0), s + cx * (s - 1.0), s - cy * (s - 1.0), s + cy * (s - 1.0)])


def edge_blur_px(linear: np.ndarray, corners: np.ndarray) -> float:
    """The photo's blur at the print: the median over the tags' outer edges of the 25-75 % width of the linear
    step from a tag's black border to the paper, / 1.349 (a Gaussian blur's sigma, px; a sharp photo's pixels
    read about 0.37). NaN when no tag's cells span 2 px.

    Args:
        linear: ``(H, W)`` float32 linear grey photo.
        corners: ``(N, 4, 2)`` tags' corners in that photo (OpenCV pixels, clockwise).
    """
    img = np.ascontiguousarray(linear, dtype=np.float32)
    widths = []
    for quad in np.asarray(corners, np.float64).reshape(-1, 4, 2):
        sides = np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)
        cell = float(sides.min()) / TAG_CELLS
        if cell < 2.0:
            continue
        centre = quad.mean(axis=0)
        offsets = np.arange(-0.75 * cell, 1.5 * cell + 1e-9, 0.125)
        inner, outer = offsets < -0.25 * cell, offsets > 0.75 * cell
        for s in range(4):
            a, b = quad[s], quad[(s + 1) % 4]
            along = (b - a) / np.linalg.norm(b - a)
            out = np.array([along[1], -along[0]])
            if np.dot(0.5 * (a + b) - centre, out) < 0:
                out = -out
            base = a[None] + np.linspace(0.2, 0.8, 12)[:, None] * (b - a)[None]
            pts = base[:, None, :] + offsets[None, :, None] * out[None, None, :]
            values = cv2.remap(img, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
            dark, bright = np.median(values[:, inner], axis=1), np.median(values[:, outer], axis=1)
            contrast = bright - dark
            for row in np.flatnonzero(contrast > 0.5 * max(float(np.median(contrast)), 1e-6)):
                f = (values[row] - dark[row]) / contrast[row]
                crossings = []
                for level in (0.25, 0.75):
                    k = np.flatnonzero((f[:-1] < level) & (f[1:] >= level))
                    if len(k) != 1:
                        break
                    k = int(k[0])
                    crossings.append(offsets[k] + (level - f[k]) / (f[k + 1] - f[k]) * (offsets[k + 1] - offsets[k]))
                if len(crossings) == 2:
                    widths.append(crossings[1] - crossings[0])
    return float(np.median(widths) / 1.349) if widths else float("nan")


# ---------------------------------------------------------------------------------------------
# Photo orientation: pixels of the upright photo <-> pixels as stored (the sensor's orientation)


def stored_from_upright(orientation: int, stored_size: tuple[int, int]) -> np.ndarray:
    """``(3, 3)`` affine map of upright-photo pixels to stored pixels, for EXIF ``orientation`` (1-8).

    ``stored_size`` is ``(W, H)`` as stored. The calibration and the poses work in the stored orientation,
    where every photo of one camera shares the intrinsics (a phone held upright or sideways).

    Examples:
        >>> stored_from_upright(6, (4, 3)) @ [0.0, 0.0, 1.0]  # turned a quarter clockwise: upright TL was stored BL
        array([0., 2., 1.])
    """
    from mi_svbrdf.io.photos import orient

    w, h = stored_size
    # The stored (x, y) of the photo's four corner pixels, turned as the photo is (a 2 x 2 image: the corners go
    # where the whole photo's would), and the upright photo's size.
    corners = np.array([[[0.0, 0.0], [w - 1.0, 0.0]], [[0.0, h - 1.0], [w - 1.0, h - 1.0]]])
    up = orient(corners, int(orientation))
    hu, wu = (w, h) if int(orientation) in (5, 6, 7, 8) else (h, w)
    src = np.array([[0.0, 0.0], [wu - 1.0, 0.0], [0.0, hu - 1.0]])
    dst = np.array([up[0, 0], up[0, -1], up[-1, 0]])
    m = cv2.getAffineTransform(src.astype(np.float32), dst.astype(np.float32)).astype(np.float64)
    return np.vstack([np.rint(m), [0.0, 0.0, 1.0]])


def apply_affine(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(..., 2)`` points mapped by the ``(3, 3)`` affine ``m``."""
    p = np.asarray(points, np.float64)
    return p @ m[:2, :2].T + m[:2, 2]
