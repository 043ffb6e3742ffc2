"""Which photo is the fronto-parallel flash photo: the one whose highlight lies in the frame, nearest the centre.

The single-image net, and the single-image branch of the fused multi-image net, expect a photo
taken square-on with the flash beside the lens: the flash's lobe (its fall-off and specular
highlight) peaks inside the frame, near the centre. A photo lit from the side has its peak
outside the frame, or none.

:func:`highlight_positions` finds each photo's peak as the maximum of a quadratic surface fitted
by least squares to its log luminance (averaged over a ``GRID x GRID`` grid): the fit averages
out texture and noise, which a brightest-pixel search would mistake for the highlight, and
returns nothing where the surface has no maximum (a photo lit from the side: its log luminance
is a slope). Positions are in half-widths, ``(x right, y up)``, 0 at the centre, the frame's
edges at +-1.

:func:`choose_flash_photo` keeps the first photo when its peak is in the frame (the user's order
is trusted: on the held-out captures, whose first photo's flash is offset by up to 0.75
half-widths, other photos lit from near the zenith often peak nearer the centre); otherwise it
takes the photo whose peak in the frame is nearest the centre, and when no photo peaks in the
frame it keeps the first and says so.

Examples:
    >>> import torch
    >>> ys, xs = torch.meshgrid(torch.linspace(1, -1, 64), torch.linspace(-1, 1, 64), indexing="ij")
    >>> side = torch.exp(2 * xs).expand(3, 64, 64) / 8          # lit from the right: no peak in the frame
    >>> flash = torch.exp(-2 * (xs ** 2 + ys ** 2)).expand(3, 64, 64)  # a flash above the centre
    >>> choose_flash_photo(torch.stack([side, flash])).index
    1
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

#: Cells per side of the grid the log luminance is averaged on before the fit.
GRID = 32
#: Rec. 709 luminance weights of linear RGB.
LUMINANCE = (0.2126, 0.7152, 0.0722)
#: Luminance floor before the logarithm (a black cell).
FLOOR = 1e-4


def highlight_positions(photos: torch.Tensor) -> list[tuple[float, float] | None]:
    """Each photo's flash peak, from a quadratic fit to its log luminance (see the module docstring).

    Args:
        photos: ``(N, 3, H, W)`` linear photos (H, W >= :data:`GRID`).

    Returns:
        Per photo ``(x, y)`` in half-widths (0 at the centre, the frame's edges at +-1), or None when the
        fitted surface has no maximum.

    Raises:
        ValueError: a wrong shape or photos smaller than the grid.
    """
    if photos.dim() != 4 or photos.shape[1] != 3:
        raise ValueError(f"photos: expected shape (N, 3, H, W), got {tuple(photos.shape)}")
    if min(photos.shape[-2:]) < GRID:
        raise ValueError(f"photos: expected H, W >= {GRID}, got {tuple(photos.shape[-2:])}")
    photos = photos.detach().double()
    weights = torch.tensor(LUMINANCE, dtype=photos.dtype, device=photos.device)
    luminance = (photos * weights[:, None, None]).sum(dim=1, keepdim=True)
    cells = F.adaptive_avg_pool2d(luminance, GRID)[:, 0].clamp_min(FLOOR).log().flatten(1)
    c = (torch.arange(GRID, dtype=photos.dtype, device=photos.device) + 0.5) / GRID * 2 - 1
    y, x = torch.meshgrid(-c, c, indexing="ij")
    design = torch.stack([torch.ones_like(x), x, y, x * x, x * y, y * y], dim=-1).reshape(-1, 6)
    coef = torch.linalg.lstsq(design, cells.T).solution.T  # (N, 6): log L = a + b x + c y + d x^2 + e xy + f y^2
    out: list[tuple[float, float] | None] = []
    for _, b, cy, d, e, f in coef.tolist():
        det = 4 * d * f - e * e  # of the Hessian [[2d, e], [e, 2f]]: a maximum where it is negative definite
        if not (d < 0 and det > 0):
            out.append(None)
            continue
        px, py = -(2 * f * b - e * cy) / det, -(2 * d * cy - e * b) / det
        out.append((round(px, 4), round(py, 4)))
    return out


def in_frame(position: tuple[float, float] | None) -> bool:
    """Whether a peak of :func:`highlight_positions` lies inside the frame."""
    return position is not None and max(abs(position[0]), abs(position[1])) <= 1.0


@dataclass(frozen=True)
class FlashChoice:
    """What :func:`choose_flash_photo` decided."""

    index: int  #: the photo taken as the fronto-parallel flash photo (0-based)
    positions: tuple[tuple[float, float] | None, ...]  #: each photo's peak (half-widths), None: none
    assumed: bool  #: no photo peaks in the frame: the first is assumed to be the flash photo
    why: str  #: one sentence for the user

    def summary(self) -> dict[str, object]:
        """JSON-ready fields (``summary.json``'s ``flash_photo``)."""
        return {"index": self.index, "assumed": self.assumed, "why": self.why,
                "peaks": [list(p) if p is not None else None for p in self.positions]}


def choose_flash_photo(photos: torch.Tensor, names: list[str] | None = None) -> FlashChoice:
    """The fronto-parallel flash photo among ``photos`` (rule of the module docstring).

    Args:
        photos: ``(N, 3, H, W)`` linear photos.
        names: how to call the photos in :attr:`FlashChoice.why` (default ``"photo 1"``, ...).

    Returns:
        A :class:`FlashChoice`.
    """
    positions = highlight_positions(photos)
    names = names or [f"photo {i + 1}" for i in range(len(positions))]
    framed = [i for i, p in enumerate(positions) if in_frame(p)]
    if framed and framed[0] == 0:
        index, assumed = 0, False
        why = f"{names[0]} is taken as the fronto-parallel flash photo: the flash's peak lies in the frame"
    elif framed:
        index = min(framed, key=lambda i: positions[i][0] ** 2 + positions[i][1] ** 2)  # type: ignore[index]
        assumed = False
        why = (f"{names[index]} is taken as the fronto-parallel flash photo and put first: {names[0]}'s light peaks "
               f"outside the frame, {names[index]}'s inside, the nearest the centre (pass --flash-photo to choose)")
    else:
        index, assumed = 0, True
        why = (f"no photo's light peaks inside the frame: {names[0]} is assumed to be the fronto-parallel flash "
               "photo (pass --flash-photo to choose)")
    if len(positions) == 1:
        why = f"one photo: {names[0]} is the flash photo" + (" (its light peaks outside the frame)" if assumed else "")
    return FlashChoice(index=index, positions=tuple(positions), assumed=assumed, why=why)
