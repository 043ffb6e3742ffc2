"""Did the net leave the flash's highlight in the diffuse map? A check of one flash photo and the maps made from it.

A single flash photo cannot say by itself whether a bright spot is the flash's reflection or a light colour: the
single-image net decides from what it learnt, and on a dark glossy sample it can get it wrong (the highlight on a
button, the sheen on a fold, painted into ``diffuse.png`` as a pale disc). Where the photo is **clipped** it
measured nothing, so whatever the diffuse map holds there is the net's guess. The check asks whether that guess
stands out from everything the photo did measure:

1. The photo's clipped cells: the photo (``(3, H, W)`` linear, as the net saw it) and the diffuse map are averaged
   on a :data:`GRID` x :data:`GRID` grid; a cell is clipped when at least half its pixels have a channel at
   :data:`~mi_svbrdf.io.photos.SATURATED_LEVEL` or above. Clipped cells that touch (4-connected) make a spot.
2. A spot's contrast in the diffuse map as ``diffuse.png`` shows it (sRGB-encoded luminance, 0 black to 1 white):
   the median over the spot minus the median over a ring around it (from one cell away to the spot's radius away,
   at least 2 cells).
3. What the material's own pattern gives: the same spot-and-ring shape laid at every place of the map where the
   photo measured (no clipped or partly clipped cell under the shape or next to it), its contrast taken there;
   the largest of them. A spot too large to be laid anywhere else is compared with a disc and its ring instead,
   its radius the spot's halved until it fits.
4. The highlight is left in the diffuse map when a spot's contrast exceeds that largest one by more than
   :data:`VISIBLE_STEP`.

Step 3 makes the rule follow the material: a clipped white fleck on a fabric of white flecks stands out no more
than the flecks the photo measured, while a pale disc on black leather stands out from everything. Step 4's
margin is measured, not tuned on one photo: ``benchmarks/bench_diffuse_highlight.py`` runs the single net on
the held-out and foreign sets, the bundled example, the real phone photos of ``../shared/real`` and simulated dark
glossy samples, and ``docs/benchmarks/diffuse_highlight.md`` gives each one's excess (step 4's left side) with,
for the simulated ones, how much brighter the predicted diffuse map is than the true one at the spot.

What it cannot see: a highlight that is not clipped (the photo measured it, and the net read it as colour), and
a photo clipped nearly everywhere (nothing measured to compare with); it says nothing then. The benchmark's page
lists the leaks it missed.

Examples:
    >>> import torch
    >>> photo = torch.full((3, 64, 64), 0.02); photo[:, 28:36, 28:36] = 1.0          # a clipped highlight
    >>> maps = torch.zeros(1, 10, 64, 64); maps[:, 2] = 1.0; maps[:, 3:6] = 0.02      # dark diffuse ...
    >>> maps[:, 3:6, 28:36, 28:36] = 0.8                                               # ... with a pale square
    >>> highlight_in_diffuse(photo, maps).left
    True
    >>> maps[:, 3:6] = 0.02
    >>> highlight_in_diffuse(photo, maps).left
    False
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core.colour import luminance
from mi_svbrdf.io.material_io import srgb_encode
from mi_svbrdf.io.photos import SATURATED_LEVEL

#: Cells per side of the grid photo and diffuse map are compared on (4 x 4 pixels at the nets' 256).
GRID = 64
#: A spot is left in the diffuse map when its contrast exceeds the largest found where the photo measured by more
#: than this, in display units (sRGB-encoded, 0 to 1: about 51 of 255 codes). Measured:
#: docs/benchmarks/diffuse_highlight.md.
VISIBLE_STEP = 0.2
#: Only the largest clipped spots are examined (a photo of glitter has hundreds of clipped specks).
MAX_SPOTS = 32


@dataclass(frozen=True)
class DiffuseHighlight:
    """What :func:`highlight_in_diffuse` found.

    Attributes:
        left: True when a clipped spot of the photo stands out in the diffuse map (the module's rule).
        clipped: fraction of the grid's cells that are clipped.
        contrast: the most telling spot's contrast in the displayed diffuse map (spot minus ring), or None when the
            photo has no clipped spot.
        elsewhere: the largest contrast of the same shape where the photo measured, or None (no spot, or no place
            left to lay it).
        area: the spot's area, as a fraction of the map.
        centre: the spot's centre ``(x, y)`` in half-widths (x right, y up, 0 at the centre), or None.
        why: one sentence: what was compared, or why nothing was.
        spot: the spot's cells, ``(GRID, GRID)`` bool, or None (not in :meth:`summary`).
    """

    left: bool
    clipped: float
    contrast: float | None = None
    elsewhere: float | None = None
    area: float = 0.0
    centre: tuple[float, float] | None = None
    why: str = ""
    spot: torch.Tensor | None = field(default=None, repr=False, compare=False)

    @property
    def excess(self) -> float | None:
        """``contrast - elsewhere`` (compared with :data:`VISIBLE_STEP`), or None."""
        if self.contrast is None or self.elsewhere is None:
            return None
        return self.contrast - self.elsewhere

    def summary(self) -> dict[str, Any]:
        """JSON-ready, figures rounded."""
        r = lambda v: None if v is None else round(float(v), 4)  # noqa: E731
        return {"left": self.left, "clipped": r(self.clipped), "contrast": r(self.contrast),
                "elsewhere": r(self.elsewhere), "excess": r(self.excess), "visible_step": VISIBLE_STEP,
                "area": r(self.area), "centre": None if self.centre is None else [r(c) for c in self.centre],
                "why": self.why}

    def note(self, n_photos: int = 1) -> str | None:
        """The warning for the user, with what to do; None when the highlight was not left in the diffuse map.

        Args:
            n_photos: photos of the capture (the advice differs for one photo and several).
        """
        if not self.left:
            return None
        x, y = self.centre or (0.0, 0.0)
        side = lambda v, low, high: high if v > 1 / 3 else low if v < -1 / 3 else ""  # noqa: E731 (thirds of the frame)
        where = " ".join(filter(None, [side(y, "bottom", "top"), side(x, "left", "right")])) or "centre"
        more = ("take 3 or more photos, the flash photo and others from other angles "
                "(mi-svbrdf capture flash.jpg b.jpg c.jpg), or " if n_photos == 1 else "")
        return (f"warning: the flash's highlight is left in the diffuse map: where the photo is clipped ({where}, "
                f"{self.area:.1%} of the sample), diffuse.png is {self.contrast:.2f} brighter than around it "
                f"(0 black to 1 white), {self.excess:.2f} more than the sample's own pattern anywhere the photo "
                "measured; the single-image net took the reflection for colour there, and the specular and "
                f"roughness maps lack it. To separate them, {more}fit calibrated photos with mi-svbrdf optimize "
                "(docs/guides/optimise.md)")


def _grid(image: torch.Tensor) -> torch.Tensor:
    """``(H, W)`` -> ``(GRID, GRID)`` cell means."""
    return F.adaptive_avg_pool2d(image[None, None].float(), GRID)[0, 0]


def displayed_diffuse(maps: torch.Tensor) -> torch.Tensor:
    """``(10, h, w)`` maps -> ``(GRID, GRID)``: the diffuse map's luminance per cell, sRGB-encoded as ``diffuse.png``
    shows it (0 black, 1 white)."""
    return torch.from_numpy(srgb_encode(_grid(luminance(maps[3:6].float().clamp(0.0, 1.0))).numpy()))


def _dilate(mask: torch.Tensor, steps: int = 1) -> torch.Tensor:
    """``(h, w)`` bool grown by ``steps`` cells (8-connected)."""
    x = mask.float()[None, None]
    for _ in range(steps):
        x = F.max_pool2d(x, 3, 1, 1)
    return x[0, 0] > 0


def spots(mask: torch.Tensor) -> list[torch.Tensor]:
    """The 4-connected components of a ``(h, w)`` bool mask, largest first, each a ``(h, w)`` bool mask."""
    cross = torch.tensor([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.0]])[None, None]
    found, rest = [], mask.clone()
    while rest.any():
        grown = torch.zeros_like(rest)
        grown.view(-1)[int(torch.nonzero(rest.view(-1))[0])] = True
        while True:
            nxt = (F.conv2d(grown.float()[None, None], cross, padding=1)[0, 0] > 0) & rest
            if torch.equal(nxt, grown):
                break
            grown = nxt
        found.append(grown)
        rest &= ~grown
    return sorted(found, key=lambda m: -int(m.sum()))


def ring_of(spot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A spot's ring and the whole shape: ``(ring, outer)``, ``(h, w)`` bool; the ring runs from one cell away to the
    spot's radius away (at least 2 cells), the whole shape is the spot grown by that radius."""
    outer = _dilate(spot, max(2, round(math.sqrt(int(spot.sum()) / math.pi))))
    return outer & ~_dilate(spot), outer


def spot_contrast(shown: torch.Tensor, spot: torch.Tensor) -> float:
    """``shown (h, w)``'s median over ``spot`` minus its median over the spot's ring (:func:`ring_of`)."""
    ring, _ = ring_of(spot)
    return float(shown[spot].median() - shown[ring].median())


def _disc(radius: float) -> torch.Tensor:
    """A disc of ``radius`` cells at the grid's centre: ``(GRID, GRID)`` bool (one cell at least)."""
    ys, xs = torch.meshgrid(torch.arange(GRID), torch.arange(GRID), indexing="ij")
    return (ys - GRID // 2) ** 2 + (xs - GRID // 2) ** 2 <= max(radius, 0.0) ** 2


def _cropped(spot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A spot's shape cropped to its box: ``(spot, ring, outer)`` (:func:`ring_of`)."""
    ring, outer = ring_of(spot)
    rows, cols = torch.nonzero(outer, as_tuple=True)
    box = (slice(int(rows.min()), int(rows.max()) + 1), slice(int(cols.min()), int(cols.max()) + 1))
    return spot[box], ring[box], outer[box]


def _contrasts(shown: torch.Tensor, spot: torch.Tensor, ring: torch.Tensor, outer: torch.Tensor,
               allowed: torch.Tensor) -> torch.Tensor:
    """The spot-minus-ring contrast of ``shown (h, w)`` with the shape ``spot``/``ring`` (bool, cropped to the box of
    ``outer``, the shape with its gap) laid at every offset where ``outer`` covers ``allowed`` cells only: ``(K,)``
    (empty when there is no such offset)."""
    bh, bw = spot.shape
    patches = F.unfold(shown[None, None], (bh, bw))[0]  # (bh*bw, L): every offset
    barred = F.unfold((~allowed).float()[None, None], (bh, bw))[0]
    free = barred[outer.flatten()].sum(0) == 0
    if not bool(free.any()):
        return torch.empty(0)
    patches = patches[:, free]
    return patches[spot.flatten()].median(0).values - patches[ring.flatten()].median(0).values


def highlight_in_diffuse(photo: torch.Tensor, maps: torch.Tensor, *,
                         step: float = VISIBLE_STEP) -> DiffuseHighlight:
    """Whether the diffuse map of ``maps`` keeps the clipped highlight of the flash ``photo`` (the module's rule).

    Args:
        photo: ``(3, H, W)`` linear flash photo, the one the single-image net read (any size: both are compared on
            a :data:`GRID` grid).
        maps: ``(1, 10, h, w)`` or ``(10, h, w)`` maps made from it.
        step: the margin of the rule (default :data:`VISIBLE_STEP`).

    Returns:
        A :class:`DiffuseHighlight`.

    Raises:
        ValueError: a photo that is not ``(3, H, W)``, maps that are not 10 channels, either smaller than the grid.
    """
    if photo.dim() != 3 or photo.shape[0] != 3:
        raise ValueError(f"photo: expected shape (3, H, W), got {tuple(photo.shape)}")
    if maps.dim() == 4:
        if maps.shape[0] != 1:
            raise ValueError(f"maps: expected one material (1, 10, h, w), got {tuple(maps.shape)}")
        maps = maps[0]
    if maps.dim() != 3 or maps.shape[0] != 10:
        raise ValueError(f"maps: expected shape (10, h, w) or (1, 10, h, w), got {tuple(maps.shape)}")
    if min(*photo.shape[-2:], *maps.shape[-2:]) < GRID:
        raise ValueError(f"photo, maps: expected at least {GRID} pixels a side, got {tuple(photo.shape[-2:])} and "
                         f"{tuple(maps.shape[-2:])}")
    photo, maps = photo.detach().float().cpu(), maps.detach().float().cpu()
    shown = displayed_diffuse(maps)
    saturated = _grid((photo >= SATURATED_LEVEL).any(dim=0).float())
    clipped = saturated >= 0.5
    fraction = float(clipped.float().mean())
    if not bool(clipped.any()):
        return DiffuseHighlight(False, fraction, why="the photo has no clipped highlight: nothing to check")
    allowed = ~_dilate(saturated > 0)  # cells the photo measured, none of their neighbours clipped
    best: DiffuseHighlight | None = None
    for spot in spots(clipped)[:MAX_SPOTS]:
        area = int(spot.sum())
        ring, _ = ring_of(spot)
        if not bool(ring.any()):
            continue
        contrast = spot_contrast(shown, spot)
        others = _contrasts(shown, *_cropped(spot), allowed)
        radius = math.sqrt(area / math.pi)
        while not others.numel() and radius > 0.5:  # too large to lay elsewhere: the largest disc that fits
            radius /= 2
            others = _contrasts(shown, *_cropped(_disc(radius)), allowed)
        elsewhere = float(others.max()) if others.numel() else None
        ys, xs = torch.nonzero(spot, as_tuple=True)
        centre = (round(float((xs.float().mean() + 0.5) * 2 / GRID - 1), 3),
                  round(float(1 - (ys.float().mean() + 0.5) * 2 / GRID), 3))
        found = DiffuseHighlight(left=elsewhere is not None and contrast - elsewhere > step, clipped=fraction,
                                 contrast=contrast, elsewhere=elsewhere, area=area / GRID ** 2, centre=centre,
                                 spot=spot)
        key = lambda f: (f.excess is not None, f.excess if f.excess is not None else f.contrast)  # noqa: E731
        if best is None or key(found) > key(best):
            best = found
    if best is None:
        return DiffuseHighlight(False, fraction, why="the photo is clipped nearly everywhere: nothing measured to "
                                                     "compare with")
    if best.elsewhere is None:
        why = "the photo is clipped nearly everywhere: nothing measured to compare with"
    else:
        why = (f"the clipped spot at ({best.centre[0]:+.2f}, {best.centre[1]:+.2f}) is {best.contrast:.3f} brighter "
               f"than its ring in the displayed diffuse map; the same shape where the photo measured: at most "
               f"{best.elsewhere:.3f}; left when the difference exceeds {step:g}")
    return DiffuseHighlight(best.left, best.clipped, best.contrast, best.elsewhere, best.area, best.centre, why,
                            best.spot)
