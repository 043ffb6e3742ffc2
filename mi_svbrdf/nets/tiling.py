"""Tiled inference on photos of any size: overlapping tiles, Gaussian blending, no seam (thesis ch. 5.1.3).

:func:`tiled_predict` runs a tile predictor (a network on a ``(1, 3, h, w)`` tile) over a photo of any
size and aspect ratio and blends the tiles' outputs into one ``(1, C, H, W)`` result:

- **Layout** (:func:`plan_tiles`). Along each axis of length ``L`` the ``n = ceil((L - tile) /
  (tile - overlap)) + 1`` tiles are spread evenly from the first edge to the last: the first tile
  starts at 0, the last ends at ``L`` (flush with the border: a border tile is shifted inward, never
  stretched, and interior content is never padded), and neighbours overlap by at least ``overlap``
  pixels (by more when ``L`` is not a whole number of strides: the slack is shared by all overlaps
  instead of being left to the last one).
- **A photo side shorter than the tile** is padded by reflection (mirrored, as often as needed) to
  the tile, centred, and the output cropped back: the net always sees a full tile, of the size it
  was trained at, and the padding holds mirrored photo content rather than zeros. The plan's
  ``notes`` say so (the ``large-scale`` command prints them and keeps them in ``summary.json``);
  :func:`tiled_predict` logs them (``logging``, this module's logger).
- **Blending** (:func:`tile_weights`). Each tile's output is weighted by a separable Gaussian,
  1 at the tile's centre and ``exp(-4.5) ~ 0.011`` at its border (sigma = tile / 6), floored at
  :data:`WEIGHT_FLOOR`; on a side where the tile touches the photo border the profile stays at 1
  out to that border (no other tile covers those pixels, and the photo border is no seam), so
  every pixel has a weight sum >= 1e-3 * 1e-3 > 0. The blend is ``sum_t w_t * y_t / sum_t w_t``;
  for canonical maps (``out_channels == 10``) the normals are renormalised after blending
  (:func:`mi_svbrdf.core.maps.normalize_normals`).
- **Memory** is bounded by the tile, not the photo: each tile's output is added into two buffers
  of the photo's size (``sum w y`` and ``sum w``) as soon as it is computed; tiles are never held
  together. At 3840 x 2160 the two buffers take 365 MB (10 + 1 float32 channels).

:func:`seam_ratio` measures seams: the mean absolute gradient of each map across the tile
borders against the same inside the tiles (1: no seam).

Examples:
    >>> import torch
    >>> plan = plan_tiles(300, 700, tile=256, overlap=64)
    >>> plan.tops, plan.lefts, plan.count
    ((0, 44), (0, 148, 296, 444), 8)
    >>> photo = torch.rand(3, 300, 700)
    >>> out = tiled_predict(lambda t: t.mean(1, keepdim=True), photo, tile=256, overlap=64, progress=False,
    ...                     out_channels=1)
    >>> tuple(out.shape), bool(torch.allclose(out, photo.mean(0, keepdim=True)[None], atol=1e-6))
    ((1, 1, 300, 700), True)
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
from torch import nn

from mi_svbrdf.core.maps import MAP_NAMES, NUM_CHANNELS, SLICES, normalize_normals
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.data.large_scale import exemplar_input

__all__ = ["WEIGHT_FLOOR", "TilePlan", "mirror_pad", "plan_tiles", "predict_large_scale", "seam_ratio", "tile_borders",
           "tile_weights", "tiled_predict"]

logger = logging.getLogger(__name__)

#: Smallest value of a tile's 1-D Gaussian profile (the 2-D weight is a product: >= WEIGHT_FLOOR ** 2).
WEIGHT_FLOOR = 1e-3
#: Gaussian sigma as a fraction of the tile side: the border is 3 sigma from the centre (weight exp(-4.5)).
SIGMA_FRACTION = 1.0 / 6.0


@dataclass(frozen=True)
class TilePlan:
    """Where the tiles of a photo go (:func:`plan_tiles`).

    Coordinates are those of the padded photo (equal to the photo's when ``pad`` is all zeros).

    Attributes:
        height: photo height H.
        width: photo width W.
        tile: requested tile side.
        overlap: requested minimum overlap of neighbouring tiles.
        tile_h: tile height (``tile``: a shorter photo side is padded to it).
        tile_w: tile width (``tile``).
        pad: ``(top, bottom, left, right)`` reflection padding added to the photo.
        tops: first row of each row of tiles.
        lefts: first column of each column of tiles.
        notes: what was done that the user should know (padding of a small photo).
    """

    height: int
    width: int
    tile: int
    overlap: int
    tile_h: int
    tile_w: int
    pad: tuple[int, int, int, int]
    tops: tuple[int, ...]
    lefts: tuple[int, ...]
    notes: tuple[str, ...] = ()

    @property
    def padded_size(self) -> tuple[int, int]:
        """``(H', W')`` of the padded photo."""
        top, bottom, left, right = self.pad
        return self.height + top + bottom, self.width + left + right

    @property
    def count(self) -> int:
        """Number of tiles."""
        return len(self.tops) * len(self.lefts)

    @property
    def grid(self) -> tuple[int, int]:
        """``(rows, columns)`` of tiles."""
        return len(self.tops), len(self.lefts)

    def boxes(self) -> Iterator[tuple[int, int]]:
        """``(top, left)`` of every tile (padded coordinates), row by row."""
        for top in self.tops:
            for left in self.lefts:
                yield top, left

    def to_dict(self) -> dict[str, object]:
        """JSON-ready description."""
        return {"photo_hw": [self.height, self.width], "tile": self.tile, "overlap": self.overlap,
                "tile_hw": [self.tile_h, self.tile_w], "grid": list(self.grid), "tiles": self.count,
                "pad_tblr": list(self.pad), "notes": list(self.notes)}


def _check_int(value: object, name: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        want = "a positive int" if low == 1 else f"an int >= {low}"
        raise ValueError(f"{name}: expected {want}, got {value!r}")
    return value


def _starts(length: int, tile: int, overlap: int) -> tuple[int, ...]:
    """Tile starts along one axis of ``length >= tile``: first at 0, last at ``length - tile``, even spacing."""
    if length <= tile:
        return (0,)
    stride = tile - overlap
    n = math.ceil((length - tile) / stride) + 1
    return tuple(round(i * (length - tile) / (n - 1)) for i in range(n))


def plan_tiles(height: int, width: int, *, tile: int = 512, overlap: int = 256) -> TilePlan:
    """The tile layout of an ``height`` x ``width`` photo (see the module docstring).

    Args:
        height: photo height H >= 1.
        width: photo width W >= 1.
        tile: tile side >= 1.
        overlap: minimum overlap of neighbouring tiles, ``0 <= overlap < tile``.

    Returns:
        A :class:`TilePlan`. A side shorter than ``tile`` is padded (by reflection, centred) to ``tile``.

    Raises:
        ValueError: naming the bad argument.

    Examples:
        >>> plan_tiles(1000, 512, tile=512, overlap=256).tops
        (0, 244, 488)
        >>> plan_tiles(100, 600, tile=512, overlap=256).pad
        (206, 206, 0, 0)
    """
    _check_int(height, "height", 1)
    _check_int(width, "width", 1)
    _check_int(tile, "tile", 1)
    _check_int(overlap, "overlap", 0)
    if overlap >= tile:
        raise ValueError(f"overlap: expected an int in [0, tile) = [0, {tile}), got {overlap}")
    notes = []
    pad = [0, 0, 0, 0]
    for axis, (length, name) in enumerate(((height, "high"), (width, "wide"))):
        if length < tile:
            extra = tile - length
            pad[2 * axis], pad[2 * axis + 1] = extra // 2, extra - extra // 2
            notes.append(f"the photo is {length} px {name}, less than the {tile} px tile: padded by reflection "
                         f"to {tile} px (mirrored photo content on both sides), the maps cropped back to {length} px")
    hp, wp = height + pad[0] + pad[1], width + pad[2] + pad[3]
    return TilePlan(height=height, width=width, tile=tile, overlap=overlap, tile_h=min(tile, hp),
                    tile_w=min(tile, wp), pad=(pad[0], pad[1], pad[2], pad[3]), tops=_starts(hp, tile, overlap),
                    lefts=_starts(wp, tile, overlap), notes=tuple(notes))


def tile_weights(size: int, *, flat_before: bool = False, flat_after: bool = False,
                 floor: float = WEIGHT_FLOOR) -> torch.Tensor:
    """The 1-D blending profile of a tile side: a Gaussian, 1 at the centre, ~0 at the ends.

    At the tile's edge (half a pixel beyond the last pixel centre) the Gaussian is exp(-4.5) =
    0.011; the end pixels get slightly more (0.0113 for a 512 px tile, 0.037 for 7 px).

    Args:
        size: tile side (pixels) >= 1.
        flat_before: hold the profile at 1 from the centre to index 0 (the tile touches the photo border there).
        flat_after: the same towards index ``size - 1``.
        floor: smallest value (keeps every pixel's weight sum positive).

    Returns:
        ``(size,)`` float32 weights in ``[floor, 1]``, ``exp(-(i - c)^2 / (2 sigma^2))`` with
        ``c = (size - 1) / 2`` and ``sigma = size / 6``.

    Examples:
        >>> w = tile_weights(7)
        >>> round(float(w[3]), 3), round(float(w[0]), 3), round(float(tile_weights(7, flat_before=True)[0]), 3)
        (1.0, 0.037, 1.0)
    """
    _check_int(size, "size", 1)
    i = torch.arange(size, dtype=torch.float64)
    centre = (size - 1) / 2.0
    d = i - centre
    if flat_before:
        d = torch.where(i < centre, torch.zeros_like(d), d)
    if flat_after:
        d = torch.where(i > centre, torch.zeros_like(d), d)
    sigma = size * SIGMA_FRACTION
    return torch.exp(-0.5 * (d / sigma) ** 2).clamp_min(floor).float()


def mirror_pad(images: torch.Tensor, pad: tuple[int, int, int, int]) -> torch.Tensor:
    """Reflection padding of ``(..., H, W)`` by ``(top, bottom, left, right)``, any amount.

    Like ``F.pad(mode="reflect")`` (the border pixel is not repeated) but the reflection repeats
    (back and forth) when the padding exceeds the side, which ``F.pad`` refuses; a side of 1 pixel
    is repeated.

    Examples:
        >>> mirror_pad(torch.arange(3.0)[None], (0, 0, 4, 4)).tolist()
        [[0.0, 1.0, 2.0, 1.0, 0.0, 1.0, 2.0, 1.0, 0.0, 1.0, 2.0]]
    """
    top, bottom, left, right = pad
    if not any(pad):
        return images

    def index(n: int, before: int, after: int) -> torch.Tensor:
        i = torch.arange(-before, n + after)
        if n == 1:
            return torch.zeros_like(i)
        period = 2 * (n - 1)
        j = i.remainder(period)
        return torch.where(j >= n, period - j, j).to(images.device)

    rows, cols = index(images.shape[-2], top, bottom), index(images.shape[-1], left, right)
    return images.index_select(-2, rows).index_select(-1, cols)


def _check_photo(photo: object) -> torch.Tensor:
    shape = tuple(photo.shape) if isinstance(photo, torch.Tensor) else None
    if shape is None or len(shape) not in (3, 4) or shape[-3] != 3 or len(shape) == 4 and shape[0] != 1 \
            or min(shape[-2:]) < 1:
        got = shape if shape is not None else f"a {type(photo).__name__}, not a torch.Tensor"
        raise ValueError(f"photo: expected a tensor of shape (3, H, W) or (1, 3, H, W), got {got}")
    if photo.dim() == 3:
        photo = photo[None]
    if not photo.is_floating_point():
        raise ValueError(f"photo: expected a floating-point tensor (linear values), got {photo.dtype}")
    if not torch.isfinite(photo).all():
        raise ValueError("photo: expected finite values, got NaN or Inf")
    return photo


def tiled_predict(predict_tile: Callable[[torch.Tensor], torch.Tensor], photo: torch.Tensor, *, tile: int = 512,
                  overlap: int = 256, progress: bool = True, out_channels: int = NUM_CHANNELS) -> torch.Tensor:
    """Run ``predict_tile`` on overlapping tiles of ``photo`` and blend the outputs with Gaussian weights.

    Args:
        predict_tile: ``(1, 3, h, w) -> (1, out_channels, h, w)``, e.g. a network with its exemplar
            features bound. Called once per tile, in row order; its output is moved to the
            photo's device and dtype float32.
        photo: ``(3, H, W)`` or ``(1, 3, H, W)`` float, finite (linear values for the networks).
        tile: tile side (pixels) >= 1.
        overlap: minimum overlap of neighbouring tiles, ``0 <= overlap < tile``.
        progress: show a tqdm progress bar over the tiles.
        out_channels: channels of ``predict_tile``'s output; 10 (canonical maps): the blended
            normals are renormalised.

    Returns:
        ``(1, out_channels, H, W)`` float32 on the photo's device.

    Raises:
        ValueError: naming ``photo``, ``tile``, ``overlap``, ``out_channels`` or ``predict_tile``
            (an output of the wrong shape or with NaN / Inf).

    Examples:
        >>> import torch
        >>> from mi_svbrdf.core.maps import constant_maps
        >>> net = lambda t: constant_maps(1, t.shape[-2], t.shape[-1], normal=(0.2, 0, 1))
        >>> out = tiled_predict(net, torch.rand(3, 100, 260), tile=64, overlap=32, progress=False)
        >>> tuple(out.shape), round(float(out[0, :3].norm(dim=0).min()), 5)
        ((1, 10, 100, 260), 1.0)
    """
    photo = _check_photo(photo)
    _check_int(out_channels, "out_channels", 1)
    plan = plan_tiles(photo.shape[-2], photo.shape[-1], tile=tile, overlap=overlap)
    for note in plan.notes:
        logger.info(note)
    source = mirror_pad(photo, plan.pad)
    hp, wp = plan.padded_size
    th, tw = plan.tile_h, plan.tile_w
    out = torch.zeros(1, out_channels, hp, wp, dtype=torch.float32, device=photo.device)
    total = torch.zeros(1, 1, hp, wp, dtype=torch.float32, device=photo.device)
    # a tile touching the (padded) photo's border keeps weight 1 out to that border
    rows = {top: tile_weights(th, flat_before=top == 0, flat_after=top + th == hp).to(photo.device)
            for top in plan.tops}
    cols = {left: tile_weights(tw, flat_before=left == 0, flat_after=left + tw == wp).to(photo.device)
            for left in plan.lefts}
    bar = tqdm(total=plan.count, desc="tiles", unit="tile", disable=not progress, leave=False)
    try:
        for top, left in plan.boxes():
            pred = predict_tile(source[:, :, top:top + th, left:left + tw].contiguous())
            expected = (1, out_channels, th, tw)
            if not isinstance(pred, torch.Tensor) or tuple(pred.shape) != expected:
                got = tuple(pred.shape) if isinstance(pred, torch.Tensor) else type(pred).__name__
                raise ValueError(f"predict_tile: expected an output of shape {expected} for the tile at "
                                 f"(top {top}, left {left}), got {got}")
            pred = pred.detach().to(device=photo.device, dtype=torch.float32)
            if not torch.isfinite(pred).all():
                raise ValueError(f"predict_tile: expected finite values, got NaN or Inf for the tile at "
                                 f"(top {top}, left {left})")
            weight = rows[top][:, None] * cols[left][None, :]
            out[:, :, top:top + th, left:left + tw].addcmul_(pred, weight)
            total[:, :, top:top + th, left:left + tw].add_(weight)
            bar.update(1)
    finally:
        bar.close()
    top, bottom, left, right = plan.pad
    out = out[:, :, top:hp - bottom, left:wp - right]
    out.div_(total[:, :, top:hp - bottom, left:wp - right])
    if out_channels == NUM_CHANNELS:
        out = normalize_normals(out)
    return out.contiguous()


def predict_large_scale(net: nn.Module, photo: torch.Tensor, exemplars: torch.Tensor | None = None, *,
                        tile: int | None = None, overlap: int | None = None, progress: bool = True) -> torch.Tensor:
    """The large-scale net (:class:`~mi_svbrdf.nets.large_scale.LargeScaleNet`) on a photo of any size, tile by tile.

    The exemplars' pooled feature pyramid is computed once (:meth:`LargeScaleNet.exemplar_features`) and
    reused for every tile of :func:`tiled_predict`; the net runs on its own device (tiles are moved there),
    the blend is accumulated on the photo's.

    Args:
        net: a large-scale net (in eval mode for inference).
        photo: ``(3, H, W)`` or ``(1, 3, H, W)`` linear ambient-lit photo in [0, 1].
        exemplars: ``(E, 10, s, s)`` canonical maps of the exemplars (``s``: ``net.config.exemplar_size``;
            :func:`mi_svbrdf.data.large_scale.exemplar_input` adds their render), or None / ``E = 0``: no
            exemplar (the Fig. 5.7 baseline).
        tile: tile side (default: ``net.config.resolution``, the tile the net is trained at).
        overlap: minimum overlap (default: ``tile // 2``).
        progress: a progress bar over the tiles.

    Returns:
        ``(1, 10, H, W)`` maps on the photo's device.

    Examples:
        >>> import torch
        >>> from mi_svbrdf.core.maps import constant_maps
        >>> from mi_svbrdf.nets.network import build_network, network_config
        >>> net = build_network(network_config("compact", "large", encoder_features=(8, 16, 16), last_features=8,
        ...                                    exemplar_features=(4, 8, 8), resolution=32, exemplar_size=16)).eval()
        >>> maps = predict_large_scale(net, torch.rand(3, 40, 90), constant_maps(2, 16, 16), progress=False)
        >>> tuple(maps.shape)
        (1, 10, 40, 90)
    """
    tile = int(net.config.resolution) if tile is None else tile
    overlap = tile // 2 if overlap is None and isinstance(tile, int) else overlap
    device = next(net.parameters()).device
    with torch.no_grad():
        features = None
        if exemplars is not None and exemplars.shape[0] > 0:
            features = net.exemplar_features(exemplar_input(exemplars.float())[None].to(device))
        return tiled_predict(lambda t: net(t.to(device), features=features), photo, tile=tile,
                             overlap=overlap, progress=progress)


def tile_borders(plan: TilePlan) -> tuple[list[int], list[int]]:
    """Rows and columns of the photo that start a tile or follow a tile's end: where a seam can be.

    Returns:
        ``(rows, columns)``: sorted indices ``k`` in ``1 .. H-1`` (``1 .. W-1``) such that pixel
        ``k - 1`` and pixel ``k`` are on two sides of a tile border (photo coordinates; borders on
        the photo's own edges or in the padding are left out).
    """
    top, _, left, _ = plan.pad

    def lines(starts: tuple[int, ...], side: int, offset: int, length: int) -> list[int]:
        edges = {s - offset for s in starts} | {s + side - offset for s in starts}
        return sorted(k for k in edges if 0 < k < length)

    return lines(plan.tops, plan.tile_h, top, plan.height), lines(plan.lefts, plan.tile_w, left, plan.width)


def seam_ratio(maps: torch.Tensor, tile: int, overlap: int) -> dict[str, float]:
    """Seams of a tiled prediction: per map, the mean absolute gradient across tile borders over that inside tiles.

    For each map (:data:`mi_svbrdf.core.maps.MAP_NAMES`) and each direction that has tile borders
    (:func:`tile_borders` of :func:`plan_tiles` ``(H, W, tile, overlap)``), the absolute difference
    between neighbouring pixels is averaged over the map's channels and the pixels of the lines
    across the borders (``across``) and over every other line (``inside``); the ratio is
    ``sum(across) / sum(inside)`` over the directions. It is ~1 without seams (a border looks like
    any other line) and large with them (a step where two tiles meet). Directions are summed
    separately, so a map that varies along one direction only is not mistaken for a seam.

    What it does not separate: where two tiles that disagree in their fine texture mix in equal parts
    (mid-overlap), the blend averages the texture down, so the borders (where one tile dominates) look
    a little busier and the ratio exceeds 1 somewhat without any step (measured 1.03-1.11 with a
    randomly initialised compact large-scale net, whose tiles disagree much; pasting its tiles without
    blending scores 1.45-1.7 on the same photo: ``benchmarks/bench_large_scale.py --naive-control``).
    Nor does it separate a material's own regular pattern: on a wall of tiles, borders that happen to
    fall on the grout lines or between them move the ratio both ways. The bundled wall's ground truth
    (``mi_svbrdf.cli.example_wall.truth_maps``, which has no seam) scores 0.13-2.1 as the tile grid is
    shifted by 0-48 px. On such a material, compare the ratio with the truth's when the truth is known.

    Args:
        maps: ``(1, 10, H, W)`` (or ``(10, H, W)``) maps of a photo tiled with ``tile``, ``overlap``.
        tile: the tile side used.
        overlap: the overlap used.

    Returns:
        ``{map name: ratio}``; empty when no tile border lies inside the photo (one tile).
        A ratio is ``inf`` when the maps are constant inside tiles but not across borders, 1 when
        both are 0.

    Examples:
        >>> import torch
        >>> ramp = torch.linspace(0, 1, 200).expand(1, 10, 100, 200)
        >>> round(seam_ratio(ramp, tile=64, overlap=32)["diffuse"], 4)
        1.0
        >>> steps = ramp.clone()
        >>> steps[..., 109:] += 0.2  # a step at column 109, where a tile starts
        >>> seam_ratio(steps, tile=64, overlap=32)["diffuse"] > 2
        True
    """
    if isinstance(maps, torch.Tensor) and maps.dim() == 3:
        maps = maps[None]
    if not isinstance(maps, torch.Tensor) or maps.dim() != 4 or maps.shape[:2] != (1, NUM_CHANNELS):
        got = tuple(maps.shape) if isinstance(maps, torch.Tensor) else type(maps).__name__
        raise ValueError(f"maps: expected shape (1, 10, H, W), got {got}")
    h, w = maps.shape[-2:]
    plan = plan_tiles(h, w, tile=tile, overlap=overlap)
    borders = tile_borders(plan)
    if not any(borders):
        return {}
    ratios = {}
    with torch.no_grad():
        for name in MAP_NAMES:
            m = maps[0, SLICES[name]].float()
            across = inside = 0.0
            for dim, lines in ((1, borders[0]), (2, borders[1])):
                if not lines:
                    continue
                n = m.shape[dim]
                # mean |difference| across line k (between pixels k - 1 and k), for k = 1 .. n - 1
                grad = (m.narrow(dim, 1, n - 1) - m.narrow(dim, 0, n - 1)).abs().mean(dim=(0, 3 - dim))
                on = torch.zeros(n - 1, dtype=torch.bool, device=grad.device)
                on[torch.tensor(lines, device=grad.device) - 1] = True
                across += float(grad[on].mean())
                inside += float(grad[~on].mean()) if bool((~on).any()) else 0.0
            if inside == 0.0:
                ratios[name] = 1.0 if across == 0.0 else math.inf
            else:
                ratios[name] = across / inside
    return ratios
