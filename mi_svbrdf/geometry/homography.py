"""The plane-to-photo homography of the frame's window, and the warp of a photo onto the plane.

The sample plane is the window's inside ``[-1, 1]^2`` (+y up); pixels are OpenCV's (``(x, y)``,
the centre of the top-left pixel at ``(0, 0)``, y down).

* :func:`plane_homography`: plane ``(x, y, 1)`` -> pixel from the window's four corners
  (top-left, top-right, bottom-right, bottom-left).
* :func:`warp_to_plane`: output texel ``(i, j)`` at ``x = -1 + (2j + 1)/S``, ``y = 1 - (2i + 1)/S``;
  bilinear at ``k x S`` (``k`` from :func:`supersampling`, up to :data:`MAX_SUPERSAMPLE`: enough
  samples per output texel when shrinking) then area-averaged to ``S``: antialiased.
* :func:`edge_residual_px`: how far the frame's measured edge points lie from the homography's
  window sides.

Examples:
    >>> import numpy as np
    >>> hom = plane_homography(np.array([[10.0, 10.0], [90.0, 10.0], [90.0, 90.0], [10.0, 90.0]]))
    >>> (hom @ np.array([0.0, 0.0, 1.0])).round(6).tolist()
    [50.0, 50.0, 1.0]
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from mi_svbrdf.geometry.frame import PLANE_CORNERS

#: Largest supersampling factor of the warp.
MAX_SUPERSAMPLE = 4


def plane_homography(corners: np.ndarray) -> np.ndarray:
    """``(3, 3)`` homography from the plane ``(x, y, 1)`` (window ``[-1, 1]^2``) to pixels, ``H[2, 2] = 1``.

    Args:
        corners: ``(4, 2)`` top-left, top-right, bottom-right, bottom-left pixels.
    """
    hom = cv2.getPerspectiveTransform(PLANE_CORNERS.astype(np.float32), np.asarray(corners, np.float32))
    return hom / hom[2, 2]


def _texel_to_plane(size: int) -> np.ndarray:
    """Output pixel ``(j, i, 1)`` (OpenCV, centres at integers) -> plane ``(x, y, 1)``."""
    return np.array([[2.0 / size, 0.0, -1.0 + 1.0 / size], [0.0, -2.0 / size, 1.0 - 1.0 / size], [0.0, 0.0, 1.0]])


def supersampling(corners: np.ndarray, size: int) -> int:
    """Warp factor ``k``: the window's longest side in photo pixels per output texel, rounded up, in [1, 4]."""
    side = float(np.max(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))
    return int(np.clip(math.ceil(side / size), 1, MAX_SUPERSAMPLE))


def warp_to_plane(image: np.ndarray, hom: np.ndarray, size: int, *, supersample: int = 1) -> np.ndarray:
    """The window of ``image (H, W, C)`` seen from above: ``(size, size, C)`` float32 (see the module docstring)."""
    k = int(supersample)
    fine = k * size
    m = hom @ _texel_to_plane(fine)
    img = np.ascontiguousarray(image, dtype=np.float32)
    out = cv2.warpPerspective(img, m, (fine, fine), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)
    if out.ndim == 2:
        out = out[..., None]
    if k > 1:
        out = out.reshape(size, k, size, k, -1).mean(axis=(1, 3))
    return out.astype(np.float32)



def edge_residual_px(hom: np.ndarray, edge_points: list[np.ndarray]) -> float:
    """RMS distance (pixels) of edge points (per side, TL-TR first) to the homography's window sides."""
    sq = []
    for s, pts in enumerate(edge_points):
        if len(pts) == 0:
            continue
        a = hom @ np.append(PLANE_CORNERS[s], 1.0)
        b = hom @ np.append(PLANE_CORNERS[(s + 1) % 4], 1.0)
        a, b = a[:2] / a[2], b[:2] / b[2]
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]])
        sq.append(((pts - a) @ n) ** 2)
    return float(np.sqrt(np.mean(np.concatenate(sq)))) if sq else float("nan")
