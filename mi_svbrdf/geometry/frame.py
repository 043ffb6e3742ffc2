"""Finding the paper frame around a sample in a photo: its four inner corners, ordered and oriented.

The capture set-up (:data:`DEFAULT_FRAME`): the sample lies inside a square window cut in a
light sheet of paper (A4 portrait, 210 x 297 mm, with a 150 x 150 mm window 30 mm from its
left, right and top edges), on a darker table. The window's inside is the sample plane
``[-1, 1]^2`` (+y up); its bottom margin (117 mm) is much wider than the others, which tells
which way is up in every photo, whatever the camera's rotation. A frame whose margins are all
alike (a symmetric frame) cannot tell it: such a photo is oriented by the photo itself
(:func:`orient_by_photo`).

Pixel coordinates are OpenCV's: ``(x, y)`` with the centre of the top-left pixel at ``(0, 0)``,
x right, y down, in the upright photo (EXIF orientation applied).

What :func:`find_frame` does to a grey photo (sRGB-encoded values in [0, 1]):

1. **Candidates.** Binarise at a sweep of thresholds (:data:`THRESHOLD_LEVELS` of the range
   between the dark and bright percentiles); at each, every hole of a bright region (OpenCV
   contours, two-level hierarchy) that ``approxPolyDP`` reduces to a convex quadrilateral of
   enough area, filling its quadrilateral, inside a bright region much larger than itself and
   not touching the image border, is a candidate. Candidates found at several thresholds at
   the same place are one; those lying inside another candidate (texture of the sample) are
   dropped. Zero candidates or two distinct ones are errors (:class:`FrameError`) that say
   what was seen.
2. **Refinement** (:func:`refine_corners`). Along each side, grey profiles across the edge
   (bilinear, 1/4 px steps) locate the dark-to-bright step to sub-pixel precision (the peak of
   the derivative, parabola fit); a robust line fit per side and the intersection of
   neighbouring lines give the corners (three passes, narrowing the search). The spread of
   the step gives the edge blur; the residuals of the points to the lines the edge RMS.
3. **Order and orientation** (:func:`orient_corners`). Corners are sorted clockwise (as
   seen in the image), then rotated so that the side facing the frame's widest paper margin
   is the bottom: ``(top-left, top-right, bottom-right, bottom-left)``. When no margin is
   clearly the widest the frame does not tell (:class:`FrameError`, with ``symmetric`` set
   when the paper was seen whole around the window: a symmetric frame, not a cut one);
   :func:`orient_by_photo` then takes the photo's own orientation: the window's side nearest
   the photo's bottom edge becomes the bottom (the rotation that keeps the image's up as +y).

Examples:
    >>> import numpy as np
    >>> order_clockwise(np.array([[0.0, 10.0], [10.0, 0.0], [0.0, 0.0], [10.0, 10.0]])).tolist()
    [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

#: Fractions of the [dark, bright] grey range at which candidates are searched.
THRESHOLD_LEVELS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9)
#: Smallest side (pixels) of a window worth rectifying.
MIN_WINDOW_PX = 48
#: Smallest short side (pixels) of a photo.
MIN_PHOTO_PX = 200
#: The widest margin must exceed every other by this factor to tell the orientation.
ORIENTATION_RATIO = 1.6
#: Corner plane coordinates in the output order (top-left, top-right, bottom-right, bottom-left).
PLANE_CORNERS = np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])
#: How the corners were oriented: by the frame's widest margin (:func:`orient_corners`) or by the
#: photo itself (:func:`orient_by_photo`).
ORIENTED_BY_FRAME = "widest paper margin at the bottom"
ORIENTED_BY_PHOTO = "the photo's own orientation (the window's side nearest the photo's bottom at the bottom)"


@dataclass(frozen=True)
class FrameSpec:
    """A paper frame: a sheet with a rectangular window (millimetres, sheet portrait, y down).

    The window's inside is the sample plane ``[-1, 1]^2``. ``window_offset_mm`` is the
    window's top-left corner from the sheet's top-left corner.
    """

    sheet_mm: tuple[float, float] = (210.0, 297.0)  #: sheet (width, height): A4
    window_mm: tuple[float, float] = (150.0, 150.0)  #: window inner (width, height): --frame-size
    window_offset_mm: tuple[float, float] = (30.0, 30.0)  #: (left, top) margins

    def __post_init__(self) -> None:
        for name in ("sheet_mm", "window_mm", "window_offset_mm"):
            v = getattr(self, name)
            if len(v) != 2 or not all(np.isfinite(v)) or min(v) < 0 or (name != "window_offset_mm" and min(v) <= 0):
                raise ValueError(f"FrameSpec.{name}: expected two positive millimetre values, got {v!r}")

    @property
    def margins_mm(self) -> dict[str, float]:
        """Paper margins around the window: ``{"top", "right", "bottom", "left"}`` (negative: no sheet there)."""
        (sw, sh), (ww, wh), (ox, oy) = self.sheet_mm, self.window_mm, self.window_offset_mm
        return {"top": oy, "right": sw - ox - ww, "bottom": sh - oy - wh, "left": ox}

    def sheet_plane(self) -> tuple[float, float, float, float]:
        """The sheet's extent on the sample plane: ``(x_min, x_max, y_min, y_max)`` (window = [-1, 1]^2)."""
        m = self.margins_mm
        sx, sy = 2.0 / self.window_mm[0], 2.0 / self.window_mm[1]
        return (-1.0 - m["left"] * sx, 1.0 + m["right"] * sx, -1.0 - m["bottom"] * sy, 1.0 + m["top"] * sy)

    @property
    def symmetric(self) -> bool:
        """True when no margin is :data:`ORIENTATION_RATIO` times wider than every other: the frame cannot tell +y."""
        widths = sorted(self.margins_mm.values())
        return widths[-1] < ORIENTATION_RATIO * max(widths[-2], 1e-9)

    def with_window(self, width_mm: float, height_mm: float) -> FrameSpec:
        """The same sheet layout around a window of another size (the sheet grows or shrinks with it)."""
        m = self.margins_mm
        return FrameSpec((m["left"] + width_mm + m["right"], m["top"] + height_mm + m["bottom"]),
                         (width_mm, height_mm), (m["left"], m["top"]))


#: The default frame: A4 portrait with a 150 mm square window, margins 30 / 30 / 30 / 117 mm.
DEFAULT_FRAME = FrameSpec()


class FrameError(ValueError):
    """The frame could not be found or oriented; ``candidates``: the quads seen.

    ``symmetric``: the orientation failed on a frame seen whole with no margin clearly the widest
    (or a :class:`FrameSpec` without one), so only the photo itself can tell which way is up.
    """

    def __init__(self, message: str, candidates: list[np.ndarray] | None = None, *, symmetric: bool = False) -> None:
        super().__init__(message)
        self.candidates = candidates or []
        self.symmetric = symmetric


@dataclass
class Refined:
    """Sub-pixel frame corners and what the edge fit measured.

    Attributes:
        corners: ``(4, 2)`` refined corners, in the order given.
        edge_points: per side, ``(M, 2)`` sub-pixel edge points kept by the fit.
        edge_rms_px: RMS distance of the kept points to their side's line.
        blur_px: median 25-75 % width of the edge step / 1.349 (the sigma of a Gaussian blur).
        contrast: median grey step across the edges (bright side minus dark side).
    """

    corners: np.ndarray
    edge_points: list[np.ndarray] = field(default_factory=list)
    edge_rms_px: float = float("nan")
    blur_px: float = float("nan")
    contrast: float = float("nan")


def order_clockwise(corners: np.ndarray) -> np.ndarray:
    """Four points ``(4, 2)`` sorted clockwise as seen in the image (y down), starting nearest the top-left."""
    pts = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    c = pts.mean(axis=0)
    angle = np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0])  # y down: increasing angle is clockwise on screen
    pts = pts[np.argsort(angle)]
    start = int(np.argmin(pts.sum(axis=1)))
    return np.roll(pts, -start, axis=0)


def _binary_candidates(grey8: np.ndarray, threshold: int) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """``([(quad (4, 2), paper contour (K, 2))...], binary)`` at one threshold."""
    h, w = grey8.shape
    binary = (grey8 > threshold).astype(np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    found = []
    if hierarchy is None:
        return found, binary
    min_area = max(MIN_WINDOW_PX ** 2 * 0.5, 0.002 * h * w)
    for k, (_, _, _, parent) in enumerate(hierarchy[0]):
        if parent < 0:
            continue  # an outer boundary: holes are what we want
        hole = contours[k]
        area = cv2.contourArea(hole)
        if area < min_area:
            continue
        outer_area = cv2.contourArea(contours[parent])
        if outer_area < 1.5 * area:
            continue
        peri = cv2.arcLength(hole, True)
        quad = cv2.approxPolyDP(hole, 0.02 * peri, True)
        if len(quad) != 4 or not cv2.isContourConvex(quad):
            continue
        if area < 0.85 * cv2.contourArea(quad):
            continue
        q = quad.reshape(4, 2).astype(np.float64)
        if (q[:, 0].min() < 2 or q[:, 1].min() < 2 or q[:, 0].max() > w - 3 or q[:, 1].max() > h - 3):
            continue
        found.append((order_clockwise(q), contours[parent].reshape(-1, 2)))
    return found, binary


def _levels(grey: np.ndarray) -> tuple[float, float]:
    lo, hi = np.percentile(grey, [2.0, 99.5])
    return float(lo), float(hi)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    side = max(np.linalg.norm(a - np.roll(a, 1, axis=0), axis=1).mean(), 1.0)
    return bool(np.abs(a - b).max() < 0.05 * side)


def _inside(inner: np.ndarray, outer: np.ndarray) -> bool:
    poly = outer.astype(np.float32).reshape(-1, 1, 2)
    return all(cv2.pointPolygonTest(poly, (float(x), float(y)), False) >= 0 for x, y in inner)


def _describe_binary(binary: np.ndarray) -> str:
    h, w = binary.shape
    n, _, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n <= 1:
        return "no bright (paper) region at all"
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, bw, bh, area = stats[big]
    sides = [name for name, cut in (("left", x <= 1), ("top", y <= 1), ("right", x + bw >= w - 1),
                                     ("bottom", y + bh >= h - 1)) if cut]
    where = f", touching the image border at the {'/'.join(sides)}" if sides else ""
    return f"the largest bright region covers {100.0 * area / (h * w):.0f} % of the photo{where}"


def find_candidates(grey: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[int], str]:
    """Frame candidates of a grey photo (see the module docstring, step 1).

    Args:
        grey: ``(H, W)`` float in [0, 1] (sRGB-encoded grey).

    Returns:
        ``(quads, papers, votes, seen)``: distinct candidate quads ``(4, 2)`` (clockwise, rough),
        the paper contour ``(K, 2)`` around each, the number of thresholds that found each, and
        a description of the bright regions (for error messages).
    """
    lo, hi = _levels(grey)
    grey8 = np.clip(cv2.GaussianBlur(grey, (0, 0), 1.0) * 255.0, 0, 255).astype(np.uint8)
    quads: list[np.ndarray] = []
    papers: list[np.ndarray] = []
    votes: list[int] = []
    seen = ""
    for level in THRESHOLD_LEVELS:
        t = round(255.0 * (lo + level * (hi - lo)))
        found, binary = _binary_candidates(grey8, t)
        if level == 0.5:
            seen = _describe_binary(binary)
        for quad, paper in found:
            for i, q in enumerate(quads):
                if _same(q, quad):
                    votes[i] += 1
                    break
            else:
                quads.append(quad)
                papers.append(paper)
                votes.append(1)
    # Drop candidates inside another one (texture of the sample).
    keep = [i for i, q in enumerate(quads) if not any(j != i and not _same(q, quads[j]) and _inside(q, quads[j])
                                                       for j in range(len(quads)))]
    return [quads[i] for i in keep], [papers[i] for i in keep], [votes[i] for i in keep], seen


def _profiles(grey: np.ndarray, a: np.ndarray, b: np.ndarray, outward: np.ndarray, radius: float,
              count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grey profiles across side a->b: ``(centres (M, 2), offsets (S,), values (M, S))``."""
    t = np.linspace(0.1, 0.9, count)
    centres = a[None] + t[:, None] * (b - a)[None]
    offsets = np.arange(-radius, radius + 1e-9, 0.25)
    pts = centres[:, None, :] + offsets[None, :, None] * outward[None, None, :]
    map_x = pts[..., 0].astype(np.float32)
    map_y = pts[..., 1].astype(np.float32)
    values = cv2.remap(grey, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return centres, offsets, values


def _edge_offsets(offsets: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel step position per profile, its 25-75 % width, contrast and a validity mask."""
    d = np.gradient(values, offsets, axis=1)
    # The outermost strong rise: the paper's edge (the sample's own edges lie inside it).
    peak = np.zeros_like(d, dtype=bool)
    peak[:, 1:-1] = (d[:, 1:-1] >= d[:, :-2]) & (d[:, 1:-1] >= d[:, 2:])
    strong = peak & (d >= 0.5 * d.max(axis=1, keepdims=True)) & (d > 0)
    last = d.shape[1] - 1 - np.argmax(strong[:, ::-1], axis=1)
    k = np.where(strong.any(axis=1), last, np.argmax(d, axis=1))
    k = np.clip(k, 1, len(offsets) - 2)
    rows = np.arange(len(k))
    y0, y1, y2 = d[rows, k - 1], d[rows, k], d[rows, k + 1]
    den = y0 - 2.0 * y1 + y2
    frac = np.where(np.abs(den) > 1e-12, 0.5 * (y0 - y2) / np.where(np.abs(den) > 1e-12, den, 1.0), 0.0)
    step = offsets[1] - offsets[0]
    pos = offsets[k] + np.clip(frac, -1.0, 1.0) * step
    n = values.shape[1]
    low = np.median(values[:, : max(2, n // 6)], axis=1)
    high = np.median(values[:, -max(2, n // 6):], axis=1)
    contrast = high - low
    widths = np.full(len(k), np.nan)
    for r in range(len(k)):
        if contrast[r] <= 0:
            continue
        f = (values[r] - low[r]) / contrast[r]
        # The 25 % and 75 % crossings of this step, walked out from it (the sample's own texture -- a highlight on
        # a glossy grain a few pixels inside -- may rise above 25 % too, far from the edge).
        lo = int(k[r])
        while lo > 0 and f[lo] >= 0.25:
            lo -= 1
        while lo < n - 1 and f[lo + 1] < 0.25:
            lo += 1
        hi = lo + 1
        while hi < n and f[hi] < 0.75:
            hi += 1
        if f[lo] < 0.25 <= f[min(lo + 1, n - 1)] and hi < n:
            widths[r] = max(offsets[hi] - offsets[lo + 1], 0.0)
    ok = (contrast > 0.25 * np.median(np.maximum(contrast, 0))) & (contrast > 0.03) & (k > 1) & (k < n - 2)
    return pos, widths, contrast, ok


def _fit_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust total-least-squares line: ``(point, unit direction, inlier mask)``."""
    keep = np.ones(len(points), dtype=bool)
    for _ in range(4):
        p = points[keep]
        c = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - c)
        direction, normal = vt[0], vt[1]
        r = np.abs((points - c) @ normal)
        mad = np.median(r[keep]) * 1.4826 + 0.05
        new = r < max(3.0 * mad, 0.3)
        if new.sum() < 4 or (new == keep).all():
            break
        keep = new
    return c, direction, keep


def _intersect(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    a = np.array([d1, -d2]).T
    s = np.linalg.solve(a, p2 - p1)
    return p1 + s[0] * d1


def refine_corners(grey: np.ndarray, corners: np.ndarray, *, passes: int = 3) -> Refined:
    """Sub-pixel corners of the window from edge profiles and line fits (module docstring, step 2).

    Args:
        grey: ``(H, W)`` float32 grey photo; the paper is brighter than the sample.
        corners: ``(4, 2)`` rough corners, clockwise in the image (each within a few pixels).
        passes: refinement passes (the search radius shrinks with each).

    Returns:
        :class:`Refined` (corners in the same order).

    Raises:
        FrameError: a side shows no consistent dark-to-bright step.
    """
    grey = np.ascontiguousarray(grey, dtype=np.float32)
    corners = np.asarray(corners, dtype=np.float64).copy()
    side = float(np.mean(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))
    radius = max(6.0, 0.03 * side)
    result = Refined(corners)
    for _ in range(passes):
        lines, kept, contrasts = [], [], []
        centre = corners.mean(axis=0)
        for s in range(4):
            a, b, outward = _side(corners, s, centre)
            count = int(np.clip(np.linalg.norm(b - a) / 2.0, 12, 400))
            cen, offs, vals = _profiles(grey, a, b, outward, radius, count)
            pos, _, con, ok = _edge_offsets(offs, vals)
            if ok.sum() < 6:
                raise FrameError(f"no sharp dark-to-bright edge along side {s} of the frame's window "
                                 f"({int(ok.sum())} of {count} profiles show one)")
            pts = cen[ok] + pos[ok, None] * outward[None]
            p, d, inl = _fit_line(pts)
            lines.append((p, d))
            kept.append(pts[inl])
            contrasts.append(con[ok][inl])
        new = np.array([_intersect(*lines[(s - 1) % 4], *lines[s]) for s in range(4)])
        corners = new
        radius = max(3.0, radius * 0.5)
        residuals = []
        for (p, d), pts in zip(lines, kept):
            normal = np.array([-d[1], d[0]])
            residuals.append((pts - p) @ normal)
        result = Refined(corners, kept, float(np.sqrt(np.mean(np.concatenate(residuals) ** 2))),
                         float("nan"), float(np.median(np.concatenate(contrasts))))
    result.blur_px = _edge_blur(grey, corners, max(12.0, 0.08 * side))
    return result


def _side(corners: np.ndarray, s: int, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Side ``s`` of a quadrilateral: its end points and its unit normal pointing away from ``centre``."""
    a, b = corners[s], corners[(s + 1) % 4]
    along = (b - a) / np.linalg.norm(b - a)
    outward = np.array([along[1], -along[0]])
    if np.dot(0.5 * (a + b) - centre, outward) < 0:
        outward = -outward
    return a, b, outward


def _edge_blur(grey: np.ndarray, corners: np.ndarray, radius: float) -> float:
    """Median edge blur (Gaussian sigma, px) over the four sides, from wide profiles across them."""
    centre = corners.mean(axis=0)
    widths = []
    for s in range(4):
        a, b, outward = _side(corners, s, centre)
        _, offs, vals = _profiles(grey, a, b, outward, radius, 24)
        _, wid, _, ok = _edge_offsets(offs, vals)
        widths.append(wid[ok])
    allw = np.concatenate(widths)
    return float(np.nanmedian(allw) / 1.349) if np.isfinite(allw).any() else float("nan")


def paper_region(grey: np.ndarray, corners: np.ndarray) -> np.ndarray | None:
    """The outer contour ``(K, 2)`` of the bright region around the window ``corners`` (None if not found).

    Binarises halfway between the grey just outside the window and just inside it and takes
    the connected region containing the ring just outside.
    """
    h, w = grey.shape
    c = corners.mean(axis=0)
    inner = c + 0.85 * (corners - c)
    outer = c + 1.08 * (corners - c)
    mask_in = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(mask_in, np.round(inner).astype(np.int32), 1)
    ring = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(ring, np.round(outer).astype(np.int32), 1)
    hole = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(hole, np.round(c + 1.02 * (corners - c)).astype(np.int32), 1)
    ring &= 1 - hole
    if ring.sum() < 10 or mask_in.sum() < 10:
        return None
    paper_level = float(np.median(grey[ring > 0]))
    sample_level = float(np.median(grey[mask_in > 0]))
    if paper_level <= sample_level:
        return None
    binary = (grey > 0.5 * (paper_level + sample_level)).astype(np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    _, labels = cv2.connectedComponents(binary, connectivity=8)
    ids = labels[ring > 0]
    ids = ids[ids > 0]
    if ids.size == 0:
        return None
    label = int(np.bincount(ids).argmax())
    contours, _ = cv2.findContours((labels == label).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)


def margin_extents(corners: np.ndarray, paper: np.ndarray,
                   image_size: tuple[int, int]) -> dict[int, tuple[float, bool]]:
    """How far the paper reaches beyond each side of the window, in window half-widths.

    Args:
        corners: ``(4, 2)`` window corners, clockwise; side ``s`` joins corners ``s`` and ``s + 1``.
        paper: ``(K, 2)`` outer contour of the paper.
        image_size: ``(H, W)`` of the photo.

    Returns:
        ``{side index (0..3): (extent, cut)}``: the paper's reach beyond side s on the plane
        whose window is ``[-1, 1]^2`` with side 0 on top, and whether the paper's contour
        touches the image border there (its true reach may be larger).
    """
    h, w = image_size
    hom = cv2.getPerspectiveTransform(corners.astype(np.float32), PLANE_CORNERS.astype(np.float32))
    pts = cv2.perspectiveTransform(paper.reshape(-1, 1, 2).astype(np.float64), hom.astype(np.float64)).reshape(-1, 2)
    on_border = ((paper[:, 0] <= 1) | (paper[:, 1] <= 1) | (paper[:, 0] >= w - 2) | (paper[:, 1] >= h - 2))
    out: dict[int, tuple[float, bool]] = {}
    x, y = pts[:, 0], pts[:, 1]
    # side 0: top (y = 1), 1: right (x = 1), 2: bottom (y = -1), 3: left (x = -1)
    band_x, band_y = np.abs(x) <= 1.0, np.abs(y) <= 1.0
    reach = {0: (y - 1.0, band_x), 1: (x - 1.0, band_y), 2: (-1.0 - y, band_x), 3: (-1.0 - x, band_y)}
    for s, (r, band) in reach.items():
        sel = band & (r > 0)
        if not sel.any():
            out[s] = (0.0, False)
            continue
        k = np.argmax(np.where(sel, r, -np.inf))
        cut = bool(on_border[sel & (r > 0.9 * r[k])].any())
        out[s] = (float(r[k]), cut)
    return out


def orient_corners(corners: np.ndarray, paper: np.ndarray | None, image_size: tuple[int, int],
                   frame: FrameSpec = DEFAULT_FRAME) -> tuple[np.ndarray, str, dict[str, float]]:
    """Rotate clockwise corners so that the frame's widest margin is below the bottom side.

    Args:
        corners: ``(4, 2)`` window corners in any order.
        paper: the paper's outer contour (:func:`paper_region`), or None.
        image_size: ``(H, W)``.
        frame: the frame, whose widest margin is taken as the bottom (a frame rotated so).

    Returns:
        ``(corners (4, 2) top-left, top-right, bottom-right, bottom-left; how; margins)``:
        ``how`` says what decided; ``margins`` the measured reach of the paper per side
        (``"top"``, ... after orientation, in window half-widths).

    Raises:
        FrameError: no paper region, or no margin clearly the widest (the frame cut by the
            image border, or a symmetric frame: then ``symmetric`` is set).
    """
    pts = order_clockwise(corners)
    if paper is None:
        raise FrameError("could not tell the sample's orientation: no paper region around the window")
    ext = margin_extents(pts, paper, image_size)
    reach = np.array([ext[s][0] for s in range(4)])
    order = np.argsort(reach)[::-1]
    widest, second = int(order[0]), int(order[1])
    names = ("top", "right", "bottom", "left")
    if reach[widest] < ORIENTATION_RATIO * max(reach[second], 1e-3) or frame.symmetric:
        cut = [names[s] for s in range(4) if ext[s][1]]
        seen = ", ".join(f"{reach[s]:.2f}" for s in range(4))
        why = ("the frame's layout has no widest margin (a symmetric frame)" if frame.symmetric
               else f"the frame is cut by the image border ({'/'.join(cut)} side as found)" if cut
               else "no margin of the frame is clearly the widest")
        raise FrameError(f"could not tell the sample's orientation: {why}; paper reach beyond the window's "
                         f"sides (clockwise, window half-widths): {seen}; expected one margin "
                         f">= {ORIENTATION_RATIO}x the others (the bottom of the sheet)",
                         symmetric=frame.symmetric or not cut)
    # The widest side becomes the bottom (index 2 in TL, TR, BR, BL order: side 2 joins BR and BL).
    shift = (widest - 2) % 4
    oriented = np.roll(pts, -shift, axis=0)
    margins = {names[(s - shift) % 4]: float(reach[s]) for s in range(4)}
    return oriented, ORIENTED_BY_FRAME, margins


def orient_by_photo(corners: np.ndarray) -> np.ndarray:
    """Rotate clockwise corners so that the window's side nearest the photo's bottom edge is the bottom.

    The rotation that keeps the image's up as +y: of the four sides, the one whose midpoint lies
    most nearly straight below the window's centre (image y down) joins the bottom-right and
    bottom-left corners. For a frame that does not tell its own orientation (all margins alike).

    Args:
        corners: ``(4, 2)`` window corners in any order (OpenCV pixels of the upright photo).

    Returns:
        ``(4, 2)`` top-left, top-right, bottom-right, bottom-left.

    Examples:
        >>> import numpy as np
        >>> turned = np.array([[12.0, 0.0], [100.0, 12.0], [88.0, 100.0], [0.0, 88.0]])  # a square turned 8 degrees
        >>> orient_by_photo(turned[[2, 0, 3, 1]]).tolist()
        [[12.0, 0.0], [100.0, 12.0], [88.0, 100.0], [0.0, 88.0]]
    """
    pts = order_clockwise(corners)
    mid = 0.5 * (pts + np.roll(pts, -1, axis=0)) - pts.mean(axis=0)  # side s joins corners s and s + 1
    down = mid[:, 1] / np.maximum(np.linalg.norm(mid, axis=1), 1e-12)
    shift = (int(np.argmax(down)) - 2) % 4
    return np.roll(pts, -shift, axis=0)
