"""Tiled inference (:mod:`mi_svbrdf.nets.tiling`): the layout, the Gaussian blend, the interior of a fully
convolutional net equal to a whole-image run, no seam with a net that is not, and bad arguments."""
from __future__ import annotations

import itertools
import logging
import math
import weakref

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.core.maps import NUM_CHANNELS, from_network_output
from mi_svbrdf.nets.tiling import (
    TilePlan,
    mirror_pad,
    plan_tiles,
    seam_ratio,
    tile_borders,
    tile_weights,
    tiled_predict,
)
from tests.conftest import random_maps

pytestmark = pytest.mark.usefixtures("one_thread")

#: (H, W, tile, overlap): odd sizes, wide and tall photos, a side (or both) shorter than the tile, overlap tile - 1.
LAYOUTS = [(70, 101, 32, 16), (45, 129, 40, 12), (33, 200, 64, 20), (20, 25, 32, 8), (97, 31, 24, 23),
           (64, 64, 64, 0)]
#: Layouts whose interior (pixels no covering tile sees within the net's radius of its inner edges) is large.
INTERIOR_LAYOUTS = [(70, 101, 32, 16), (45, 129, 40, 12), (33, 200, 64, 20), (20, 25, 32, 8), (97, 31, 24, 12),
                    (64, 64, 64, 0), (131, 67, 48, 0)]


class StandIn(nn.Module):
    """A fixed random conv stack (3x3, zero padding: radius :attr:`RADIUS`) with a normal-producing head.

    ``global_mean``: also add a per-tile global term (a linear map of the tile's mean colour), like the
    real net's global-features track: then the net is no longer fully convolutional and tiles disagree.
    """

    RADIUS = 3

    def __init__(self, seed: int = 0, global_mean: bool = False) -> None:
        super().__init__()
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            self.body = nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.Tanh(), nn.Conv2d(8, 8, 3, padding=1),
                                      nn.Tanh(), nn.Conv2d(8, 9, 3, padding=1))
            self.mix = nn.Linear(3, 9)
        self.global_mean = global_mean

    def forward(self, photo: torch.Tensor) -> torch.Tensor:
        y = self.body(photo * 2.0 - 1.0)
        if self.global_mean:
            y = y + 4.0 * self.mix(photo.mean(dim=(2, 3)))[:, :, None, None]
        return from_network_output(torch.tanh(y), activation="tanh")


def predictor(net: nn.Module):
    def run(tile: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            return net(tile)
    return run


def smooth_photo(h: int, w: int, seed: int = 0) -> torch.Tensor:
    """A smooth-ish photo: low-frequency colour variation (bicubic from a 5 x 7 grid) plus a little noise."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, 5, 7, generator=g)
    photo = F.interpolate(coarse, size=(h, w), mode="bicubic", align_corners=False)
    return (photo + 0.02 * torch.rand(1, 3, h, w, generator=g)).clamp(0.0, 1.0)


def affected(plan: TilePlan, radius: int) -> torch.Tensor:
    """``(H, W)`` bool: pixels where some covering tile's output can differ from a whole-image run.

    A tile's output differs within ``radius`` of its edges, except where the edge is the photo's own
    border (the whole-image run has the same zero padding there); a padded (small) photo differs within
    ``radius`` of the photo's border (mirrored content instead of zeros).
    """
    hp, wp = plan.padded_size
    bad = torch.zeros(hp, wp, dtype=torch.bool)
    for top, left in plan.boxes():
        bottom, right = top + plan.tile_h, left + plan.tile_w
        if top > 0:
            bad[top:top + radius, left:right] = True
        if bottom < hp:
            bad[bottom - radius:bottom, left:right] = True
        if left > 0:
            bad[top:bottom, left:left + radius] = True
        if right < wp:
            bad[top:bottom, right - radius:right] = True
    pt, pb, pl, pr = plan.pad
    bad = bad[pt:hp - pb, pl:wp - pr].clone()
    for side, amount in zip(("top", "bottom", "left", "right"), plan.pad):
        if amount:
            region = {"top": (slice(0, radius), slice(None)), "bottom": (slice(-radius, None), slice(None)),
                      "left": (slice(None), slice(0, radius)), "right": (slice(None), slice(-radius, None))}[side]
            bad[region] = True
    return bad


# --- layout ---------------------------------------------------------------------------------------------

def test_plan_layout_properties_over_random_sizes() -> None:
    g = torch.Generator().manual_seed(3)
    for _ in range(300):
        tile = int(torch.randint(1, 90, (1,), generator=g))
        overlap = int(torch.randint(0, tile, (1,), generator=g))
        h, w = (int(v) for v in torch.randint(1, 20 * tile, (2,), generator=g))
        plan = plan_tiles(h, w, tile=tile, overlap=overlap)
        hp, wp = plan.padded_size
        assert (hp, wp) == (max(h, tile), max(w, tile)) and (plan.tile_h, plan.tile_w) == (tile, tile)
        for starts, length in ((plan.tops, hp), (plan.lefts, wp)):
            assert starts[0] == 0 and starts[-1] + tile == length, (starts, length, tile)  # flush with both borders
            gaps = [b - a for a, b in itertools.pairwise(starts)]
            assert all(0 < gap <= tile - overlap for gap in gaps), (gaps, tile, overlap)  # overlap >= requested
            # the fewest tiles that achieve it
            assert len(starts) == (1 if length <= tile else math.ceil((length - tile) / (tile - overlap)) + 1)
            covered = torch.zeros(length, dtype=torch.int32)  # the grid is separable: cover each axis
            for start in starts:
                covered[start:start + tile] += 1
            assert int(covered.min()) >= 1
        assert plan.count == len(plan.tops) * len(plan.lefts) == len(list(plan.boxes()))


def test_small_photo_is_padded_by_reflection_with_a_note(caplog: pytest.LogCaptureFixture) -> None:
    plan = plan_tiles(100, 700, tile=256, overlap=64)
    assert plan.pad == (78, 78, 0, 0) and plan.tops == (0,) and len(plan.notes) == 1
    assert "100 px high" in plan.notes[0] and "padded by reflection" in plan.notes[0]
    assert plan_tiles(300, 700, tile=256, overlap=64).notes == ()
    seen: list[tuple[int, ...]] = []

    def record(tile: torch.Tensor) -> torch.Tensor:
        seen.append(tuple(tile.shape))
        return tile.mean(dim=1, keepdim=True)

    photo = torch.rand(1, 3, 100, 50)
    with caplog.at_level(logging.INFO, logger="mi_svbrdf.nets.tiling"):
        out = tiled_predict(record, photo, tile=64, overlap=16, progress=False, out_channels=1)
    assert seen == [(1, 3, 64, 64), (1, 3, 64, 64)]  # the net sees full tiles
    assert "50 px wide" in caplog.text and "padded by reflection" in caplog.text
    assert torch.allclose(out, photo.mean(dim=1, keepdim=True), atol=1e-6)  # cropped back, pixel for pixel


def test_mirror_pad_matches_reflect_padding_and_repeats_beyond_the_side() -> None:
    x = torch.rand(2, 3, 9, 11)
    assert torch.equal(mirror_pad(x, (3, 8, 10, 2)), F.pad(x, (10, 2, 3, 8), mode="reflect"))
    row = mirror_pad(torch.arange(4.0)[None], (0, 0, 7, 0))[0].tolist()
    assert row == [1.0, 0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0, 1.0, 2.0, 3.0]
    assert torch.equal(mirror_pad(torch.ones(1, 1, 1, 5) * 7, (2, 3, 0, 0)), torch.full((1, 1, 6, 5), 7.0))


# --- blending --------------------------------------------------------------------------------------------

def test_gaussian_weights_one_at_the_centre_about_zero_at_the_border() -> None:
    w = tile_weights(512)
    assert float(w.max()) == pytest.approx(1.0, abs=1e-4) and float(w[255]) == pytest.approx(1.0, abs=1e-4)
    assert float(w[0]) == pytest.approx(math.exp(-0.5 * (255.5 / (512 / 6)) ** 2), rel=1e-4) and float(w[0]) < 0.012
    assert torch.allclose(w, w.flip(0)) and bool((w[1:256] >= w[:255]).all())  # symmetric, rising to the centre
    left = tile_weights(512, flat_before=True)
    assert bool((left[:256] == 1.0).all()) and torch.equal(left[256:], w[256:])
    assert float(tile_weights(512, floor=0.05).min()) == pytest.approx(0.05)


@pytest.mark.parametrize("h, w, tile, overlap", LAYOUTS)
def test_every_pixel_gets_a_positive_weight_and_one_tile_its_value(h: int, w: int, tile: int, overlap: int) -> None:
    """A predictor of a constant per tile: each pixel gets a convex blend of its tiles' values (so the weight
    sum is positive and finite everywhere); pixels only one tile covers get exactly its value."""
    plan = plan_tiles(h, w, tile=tile, overlap=overlap)
    calls = iter(range(plan.count))

    def constant(t: torch.Tensor) -> torch.Tensor:
        return torch.full((1, 1, *t.shape[-2:]), float(next(calls)))

    out = tiled_predict(constant, torch.rand(3, h, w), tile=tile, overlap=overlap, progress=False, out_channels=1)[0, 0]
    assert torch.isfinite(out).all()
    hp, wp = plan.padded_size
    low, high = torch.full((hp, wp), math.inf), torch.full((hp, wp), -math.inf)
    count = torch.zeros(hp, wp)
    for k, (top, left) in enumerate(plan.boxes()):
        region = (slice(top, top + plan.tile_h), slice(left, left + plan.tile_w))
        low[region], high[region] = low[region].clamp(max=k), high[region].clamp(min=k)
        count[region] += 1
    pt, pb, pl, pr = plan.pad
    low, high, count = (t[pt:hp - pb, pl:wp - pr] for t in (low, high, count))
    assert bool((out >= low - 1e-4).all()) and bool((out <= high + 1e-4).all())
    assert torch.allclose(out[count == 1], low[count == 1], atol=1e-5)
    ones = tiled_predict(lambda t: torch.ones(1, 1, *t.shape[-2:]), torch.rand(3, h, w), tile=tile, overlap=overlap,
                         progress=False, out_channels=1)
    assert torch.allclose(ones, torch.ones_like(ones), atol=1e-6)


def test_blended_normals_are_unit_and_maps_stay_in_range() -> None:
    seeds = iter(range(100))

    def random_tile(t: torch.Tensor) -> torch.Tensor:  # every tile a different random material
        return random_maps(1, t.shape[-2], t.shape[-1], seed=next(seeds))

    out = tiled_predict(random_tile, torch.rand(3, 61, 90), tile=32, overlap=16, progress=False)
    assert out.shape == (1, NUM_CHANNELS, 61, 90)
    assert torch.allclose(out[:, :3].norm(dim=1), torch.ones(1, 61, 90), atol=1e-5)
    assert float(out[:, 3:].min()) >= 0.0 and float(out[:, 3:].max()) <= 1.0


@pytest.mark.parametrize("h, w, tile, overlap", INTERIOR_LAYOUTS)
def test_fully_convolutional_net_interior_equals_the_whole_image_run(h: int, w: int, tile: int, overlap: int) -> None:
    net = StandIn(seed=1)
    photo = torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(h * w))
    with torch.inference_mode():
        whole = net(photo)
    tiled = tiled_predict(predictor(net), photo, tile=tile, overlap=overlap, progress=False)
    assert tiled.shape == whole.shape == (1, NUM_CHANNELS, h, w)
    bad = affected(plan_tiles(h, w, tile=tile, overlap=overlap), StandIn.RADIUS)
    interior = ~bad
    assert interior.float().mean() > 0.3, "the interior is too small to test anything"
    diff = (tiled - whole).abs().amax(dim=1)[0]
    assert float(diff[interior].max()) < 2e-6, float(diff[interior].max())
    assert torch.allclose(tiled[:, :3].norm(dim=1), torch.ones(1, h, w), atol=1e-5)
    if bad.any():  # the excluded band really differs: the interior mask is what makes the equality hold
        assert float(diff[bad].max()) > 1e-4, float(diff[bad].max())


# --- seams -----------------------------------------------------------------------------------------------

def naive_stitch(net: nn.Module, photo: torch.Tensor, tile: int, overlap: int) -> torch.Tensor:
    """Each tile pasted over the previous ones (no blending): the control that must show seams."""
    plan = plan_tiles(photo.shape[-2], photo.shape[-1], tile=tile, overlap=overlap)
    assert not any(plan.pad)
    out = torch.zeros(1, NUM_CHANNELS, *photo.shape[-2:])
    with torch.inference_mode():
        for top, left in plan.boxes():
            out[:, :, top:top + tile, left:left + tile] = net(photo[:, :, top:top + tile, left:left + tile])
    return out


def test_no_seam_with_a_net_that_is_not_fully_convolutional() -> None:
    """A per-tile global term makes neighbouring tiles disagree; the Gaussian blend hides it (border gradients
    within 10 % of the inside ones), pasting tiles does not."""
    net = StandIn(seed=2, global_mean=True)
    photo = smooth_photo(150, 230)
    tile, overlap = 64, 32
    blended = tiled_predict(predictor(net), photo, tile=tile, overlap=overlap, progress=False)
    naive = naive_stitch(net, photo, tile, overlap)
    good, bad = seam_ratio(blended, tile, overlap), seam_ratio(naive, tile, overlap)
    print("seam ratio, blended:", {k: round(v, 3) for k, v in good.items()},
          "naive:", {k: round(v, 3) for k, v in bad.items()})
    assert set(good) == {"normal", "diffuse", "roughness", "specular"}
    assert max(good.values()) <= 1.10, good
    assert min(bad.values()) > 1.5, bad  # the measure sees seams when there are some


def test_seam_ratio_borders_and_edge_cases() -> None:
    plan = plan_tiles(100, 200, tile=64, overlap=32)
    rows, cols = tile_borders(plan)
    assert rows == [18, 36, 64, 82] and cols[:3] == [27, 54, 64]
    assert seam_ratio(torch.rand(1, 10, 50, 60), tile=64, overlap=32) == {}  # one tile: no border
    flat = torch.zeros(1, 10, 100, 200)
    assert seam_ratio(flat, 64, 32) == {name: 1.0 for name in ("normal", "diffuse", "roughness", "specular")}
    flat[..., 27:] = 1.0
    assert seam_ratio(flat, 64, 32)["roughness"] == math.inf
    with pytest.raises(ValueError, match=r"maps: expected shape \(1, 10, H, W\)"):
        seam_ratio(torch.rand(1, 9, 50, 60), 64, 32)


# --- memory, progress, bad arguments --------------------------------------------------------------------

def test_tiles_are_not_held_together() -> None:
    """Memory is bounded by the tile: when a tile is predicted, no earlier tile's output is alive but the last."""
    buffers: list[weakref.ref] = []  # the numpy buffer behind each output: alive while any view of it is
    alive: list[int] = []

    def run(t: torch.Tensor) -> torch.Tensor:
        alive.append(sum(r() is not None for r in buffers))
        data = np.random.default_rng(len(alive)).random((1, NUM_CHANNELS, *t.shape[-2:]), dtype=np.float32)
        buffers.append(weakref.ref(data))
        return torch.from_numpy(data)

    tiled_predict(run, torch.rand(3, 100, 150), tile=32, overlap=8, progress=False)
    assert len(alive) == plan_tiles(100, 150, tile=32, overlap=8).count == 24
    assert max(alive) <= 1, alive


def test_progress_bar(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_PROGRESS", "1")  # pytest's captured stderr is no terminal: bars would be off
    tiled_predict(lambda t: torch.zeros(1, 1, *t.shape[-2:]), torch.rand(3, 40, 40), tile=16, overlap=8,
                  out_channels=1)
    assert "tiles" in capsys.readouterr().err
    tiled_predict(lambda t: torch.zeros(1, 1, *t.shape[-2:]), torch.rand(3, 40, 40), tile=16, overlap=8,
                  out_channels=1, progress=False)
    assert capsys.readouterr().err == ""


def _zeros(t: torch.Tensor) -> torch.Tensor:
    return torch.zeros(1, NUM_CHANNELS, *t.shape[-2:])


@pytest.mark.parametrize("kwargs, match", [
    ({"tile": 0}, r"tile: expected a positive int, got 0"),
    ({"tile": 32.0}, r"tile: expected a positive int, got 32.0"),
    ({"overlap": -1}, r"overlap: expected an int >= 0, got -1"),
    ({"tile": 32, "overlap": 32}, r"overlap: expected an int in \[0, tile\) = \[0, 32\), got 32"),
    ({"tile": 32, "overlap": 40}, r"overlap: expected an int in \[0, tile\) = \[0, 32\), got 40"),
    ({"out_channels": 0}, r"out_channels: expected a positive int, got 0"),
    ({"photo": torch.rand(4, 20, 20)},
     r"photo: expected a tensor of shape \(3, H, W\) or \(1, 3, H, W\), got \(4, 20, 20\)"),
    ({"photo": torch.rand(2, 3, 20, 20)}, r"photo: expected a tensor of shape .*, got \(2, 3, 20, 20\)"),
    ({"photo": torch.full((3, 20, 20), math.nan)}, r"photo: expected finite values, got NaN or Inf"),
    ({"photo": torch.zeros(3, 20, 20, dtype=torch.uint8)}, r"photo: expected a floating-point tensor"),
    ({"photo": [[0.5]]}, r"photo: expected a tensor .*, got a list, not a torch.Tensor"),
    ({"predict_tile": lambda t: torch.zeros(1, 9, *t.shape[-2:])},
     r"predict_tile: expected an output of shape \(1, 10, 16, 16\) .*got \(1, 9, 16, 16\)"),
    ({"predict_tile": lambda t: torch.full((1, 10, *t.shape[-2:]), math.inf)},
     r"predict_tile: expected finite values, got NaN or Inf"),
])
def test_bad_arguments_name_the_argument(kwargs: dict, match: str) -> None:
    args = {"predict_tile": _zeros, "photo": torch.rand(3, 20, 30), "tile": 16, "overlap": 8, "progress": False,
            **kwargs}
    with pytest.raises(ValueError, match=match):
        tiled_predict(args.pop("predict_tile"), args.pop("photo"), **args)
