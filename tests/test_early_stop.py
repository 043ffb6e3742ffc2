"""The held-out scorer (robust exposure), the early stop on left-out photos, and bars only where they are seen."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.render import texel_positions
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.fit import method_config, stop_photos
from mi_svbrdf.optim.forward import TexelForward
from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.optim import scoring
from mi_svbrdf.optim.scoring import (CLIPPED, HeldOutScorer, channel_bias, exposure_scale, exposure_stats, held_out_rmse,
                                     measured_rmse, solve_exposure)
from mi_svbrdf.optim.loop import LoopConfig, Monitor, run
from mi_svbrdf.optim.params import from_maps, to_maps

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_select", ROOT / "benchmarks" / "bench_select.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BENCH = _bench()


def _brute_force_exposure(renders: torch.Tensor, photos: torch.Tensor) -> float:
    """The definition, written plainly: least squares over the unclipped set, alternated from k = 1."""
    photo_ok = (photos < CLIPPED).all(dim=1, keepdim=True)
    k, seen = 1.0, []
    for _ in range(200):
        ok = (photo_ok & (renders * k < 1.0).all(dim=1, keepdim=True)).expand_as(photos)
        new = float((renders[ok].double() * photos[ok].double()).sum() / renders[ok].double().square().sum())
        if new == k or new in seen:
            return new
        seen.append(k)
        k = new
    return k


@pytest.mark.parametrize("seed", range(6))
def test_exposure_equals_its_plain_definition(seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    renders = torch.rand(3, 3, 16, 16, generator=g) * 1.5
    photos = (renders * (0.4 + torch.rand((), generator=g)) + 0.02 * torch.randn(3, 3, 16, 16, generator=g)).clamp(0, 1)
    spikes = torch.rand(3, 1, 16, 16, generator=g) < 0.02
    renders = torch.where(spikes, renders * 50.0, renders)
    assert exposure_scale(renders, photos) == pytest.approx(_brute_force_exposure(renders, photos), rel=1e-6)


def test_spiky_maps_keep_their_exposure() -> None:
    """Glossy texels that render far above 1 (a clipped highlight in a photo) do not drag the exposure down."""
    gt = BENCH.material("full", 2, 32)
    spec, images, _ = BENCH.simulated_capture(gt, 5, 2, noise=0.0)
    fit = [0, 1, 2, 3]
    fwd = TexelForward(spec.subset(fit), 32, "torch")
    pos = texel_positions(32, 32)  # (3, H, W)
    spiky = gt.clone()
    for k, (y, x) in zip(fit, [(8, 8), (8, 24), (24, 8), (24, 24)]):  # a mirror texel facing each photo's flash
        im = spec.images[k]
        to_l = torch.tensor(im.light.position) - pos[:, y, x]
        to_v = torch.tensor(im.camera.position) - pos[:, y, x]
        half = torch.nn.functional.normalize(to_l / to_l.norm() + to_v / to_v.norm(), dim=0)
        spiky[0, :3, y - 1:y + 2, x - 1:x + 2] = half.view(3, 1, 1)
        spiky[0, 6, y - 1:y + 2, x - 1:x + 2], spiky[0, 7:10, y - 1:y + 2, x - 1:x + 2] = 0.15, 1.0
    renders = fwd(spiky)
    assert float(renders.amax()) > 20.0  # spikes: far above the clip in some photo
    err_gt, k_gt, _ = held_out_rmse(gt, spec, images, fit, [4])
    err, k, _ = held_out_rmse(spiky, spec, images, fit, [4])
    assert k == pytest.approx(k_gt, rel=0.02) and err < err_gt + 0.05
    # the former fit over every unclipped photo pixel, whatever the render: dragged down by the spikes
    ok = (images[fit] < CLIPPED).all(dim=1, keepdim=True).expand_as(renders)
    plain = float((renders[ok] * images[fit][ok]).sum() / renders[ok].square().sum())
    assert plain < 0.9 * k


def test_exposure_of_a_black_render_and_bad_shapes() -> None:
    assert exposure_scale(torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.3)) == 1.0
    with pytest.raises(ValueError, match="expected equal shapes"):
        exposure_scale(torch.zeros(1, 3, 4, 4), torch.zeros(2, 3, 4, 4))
    with pytest.raises(ValueError, match="fit, held: expected two non-empty lists"):
        HeldOutScorer(*BENCH.simulated_capture(BENCH.material("full", 1, 8), 3, 1)[:2], [0, 1], [])


def test_exposure_of_groups_equals_the_whole() -> None:
    """The scorer renders a large capture a few photos at a time: the exposure of the groups' statistics is the
    exposure of the whole."""
    g = torch.Generator().manual_seed(7)
    renders = torch.rand(4, 3, 16, 16, generator=g) * 1.5
    photos = (renders * 0.7 + 0.02 * torch.randn(4, 3, 16, 16, generator=g)).clamp(0, 1)
    whole = exposure_scale(renders, photos)
    parts = solve_exposure([exposure_stats(renders[:1], photos[:1]), exposure_stats(renders[1:], photos[1:])])
    assert parts == pytest.approx(whole, rel=1e-12) and whole == pytest.approx(0.7, rel=0.05)


def test_scorer_in_groups_and_on_a_grid_scores_as_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A capture too large for one render is rendered one photo at a time (same score), and its exposure fitted on
    a grid of every 2nd pixel (a score within a thousandth), the held-out photos scored on all their pixels."""
    gt = BENCH.material("full", 4, 32)
    spec, images, _ = BENCH.simulated_capture(gt, 5, 3, noise=0.01)
    maps = M.constant_maps(1, 32, 32)
    fit, held = [0, 1, 2, 4], [3]
    at_once = HeldOutScorer(spec, images, fit, held)
    want = at_once(maps)
    monkeypatch.setattr(scoring, "RENDER_TEXELS", 32 * 32)
    grouped = HeldOutScorer(spec, images, fit, held)
    assert len(grouped.fit_forwards) == 4 and grouped.stride == 1
    assert grouped(maps) == pytest.approx(want, rel=1e-6) and grouped.exposure == pytest.approx(at_once.exposure,
                                                                                                rel=1e-6)
    assert torch.allclose(grouped.render_fit(maps), at_once.render_fit(maps))
    monkeypatch.setattr(scoring, "EXPOSURE_PIXELS", 16 * 16)
    grid = HeldOutScorer(spec, images, fit, held)
    assert grid.stride == 2 and grid.renders.numel() == 0
    assert grid(maps) == pytest.approx(want, abs=1e-3) and grid.renders.shape == (1, 3, 32, 32)
    with pytest.raises(ValueError, match="render_fit: expected a scorer with exposure 'fit'"):
        HeldOutScorer(spec, images, fit, held, exposure="held").render_fit(maps)


def test_measured_rmse_is_the_masked_display_rmse() -> None:
    g = torch.Generator().manual_seed(3)
    renders, photos = torch.rand(3, 3, 8, 8, generator=g), torch.rand(3, 3, 8, 8, generator=g)
    valid = torch.rand(3, 1, 8, 8, generator=g) > 0.3
    mask = valid.expand_as(photos)
    want = float((gamma_encode(renders) - gamma_encode(photos))[mask].pow(2).mean().sqrt())
    assert measured_rmse(renders, photos, valid) == pytest.approx(want, rel=1e-6)
    assert measured_rmse(renders, photos, torch.zeros_like(valid)) is None


def test_held_exposure_forgives_a_shots_own_exposure_error() -> None:
    """Scored with each held-out photo's own exposure, a left-out shot one stop too dark costs the true maps
    nothing; carried over from the fit photos, the same error costs them (a recipe would be judged by luck)."""
    gt = BENCH.material("full", 3, 32)
    spec, images, _ = BENCH.simulated_capture(gt, 5, 3, noise=0.0)
    dark = images.clone()
    dark[3:] = images[3:] * 0.5  # the held-out shots a stop under: nothing clips
    fit, held = [0, 1, 2], [3, 4]
    own = HeldOutScorer(spec, dark, fit, held, exposure="held")
    assert own(gt) == pytest.approx(HeldOutScorer(spec, images, fit, held, exposure="held")(gt), abs=5e-4)
    assert own(gt) < 2e-3 and own.exposure == pytest.approx(0.5, rel=1e-3)
    assert HeldOutScorer(spec, dark, fit, held)(gt) > 0.03  # "fit": the fit photos' exposure, 1
    with pytest.raises(ValueError, match=r"exposure: expected one of \('fit', 'held'\), got 'own'"):
        HeldOutScorer(spec, images, fit, held, exposure="own")


def test_channel_bias_says_which_channel_is_off() -> None:
    photos = torch.full((1, 3, 8, 8), 0.25)
    renders = photos.clone()
    renders[:, 2] = 0.4  # too blue
    bias = channel_bias(renders, photos)
    assert bias[0] == pytest.approx(0.0, abs=1e-7) and bias[1] == pytest.approx(0.0, abs=1e-7) and bias[2] > 0.05


def test_monitor_stops_at_its_patience_and_returns_the_best_maps() -> None:
    """The run keeps the maps at the lowest held-out score, not its last ones, and stops after the patience."""
    gt = BENCH.material("full", 3, 16)
    spec, images, valid = BENCH.simulated_capture(gt, 4, 3)
    fwd = TexelForward(spec, 16, "torch")
    seen: dict[int, torch.Tensor] = {}

    def score(maps: torch.Tensor) -> float:
        length = 10 * (len(seen) + 1)
        seen[length] = maps.clone()
        return (length - 60) ** 2 / 100.0  # lowest after 60 updates

    monitor = Monitor(score, every=10, patience=50, patience_fraction=0.0)
    variables = from_maps(BENCH.material("full", 4, 16))
    cfg = LoopConfig(iterations=1000, schedule="constant", tol=0.0, progress=False)
    res = run(fwd, images, images, variables, cfg, monitor=monitor)
    assert res.stop_reason == "held-out" and res.steps == 110 and monitor.best_length == 60
    assert torch.allclose(to_maps(res.variables), seen[60], atol=1e-6)
    assert [c[1] for c in monitor.curve] == list(range(10, 120, 10))
    seen.clear()  # a decaying schedule is not stopped before it has decayed: a rise at a high lr is its noise
    monitor = Monitor(score, every=10, patience=50, patience_fraction=0.0)
    res = run(fwd, images, images, variables, dataclasses.replace(cfg, schedule="cosine", schedule_steps=200),
              monitor=monitor)
    assert res.stop_reason == "held-out" and res.steps == 250 and monitor.best_length == 200  # kept from 200 on
    assert len(monitor.curve) == 25
    with pytest.raises(ValueError, match="every: expected an int >= 1"):
        Monitor(score, every=0)


def test_optimize_stops_on_a_left_out_photo_and_records_its_curve() -> None:
    gt = BENCH.material("full", 5, 24)
    spec, images, valid = BENCH.simulated_capture(gt, 6, 5)
    res = optimize(spec, images, valid, config=method_config("pixel", iterations=400, progress=False))
    ho = res.held_out
    assert ho is not None and ho["photos"] == stop_photos(6) == [2] and ho["then"] in ("refit", "continued")
    lengths = [k for _, k, _ in ho["curve"]]
    assert lengths == sorted(lengths) and all(k % 10 == 0 for k in lengths) and ho["best_length"] in lengths
    assert ho["best"] == pytest.approx(min(e for _, _, e in ho["curve"]))
    assert res.steps <= 400 and ho["first_fit"]["steps"] + ho["final_steps"] == res.steps
    if ho["then"] == "refit":
        assert ho["final_steps"] <= ho["best_length"]
    json.dumps(ho, allow_nan=False)  # strict JSON
    assert [name for name, _ in res.phases][0].startswith("early stop (5 of 6 photos)")
    off = optimize(spec, images, valid, config=method_config("pixel", iterations=50, progress=False, early_stop="off"))
    assert off.held_out is None and off.steps == 50
    few = optimize(spec.subset([0, 1, 2]), images[:3], valid[:3], config=OptimizeConfig(iterations=30, progress=False))
    assert few.held_out is None  # 3 photos: the held-out shrinkage instead (validate_photo)
    with pytest.raises(ValueError, match="early_stop: expected one of"):
        OptimizeConfig(early_stop="on")


def test_the_early_stop_helps_where_a_fit_overfits() -> None:
    """Noisy photos of a few lights: a long plain fit overfits; the early stop's maps predict a new light better."""
    gt = BENCH.material("full", 6, 24)
    spec, images, valid = BENCH.simulated_capture(gt, 6, 6, noise=0.08)
    fit, held = [0, 1, 2, 3, 4], [5]
    errs = {}
    for mode in ("off", "auto"):
        cfg = method_config("pixel", iterations=1200, lr=0.1, progress=False, early_stop=mode)
        res = optimize(spec.subset(fit), images[fit], valid[fit], config=cfg)
        errs[mode] = held_out_rmse(res.maps, spec, images, fit, held)[0]
        assert bool(torch.isfinite(M.normal(res.maps)).all())
    assert errs["auto"] < errs["off"], errs


def test_api_fits_draw_no_bar_on_a_file(capsys: pytest.CaptureFixture[str]) -> None:
    """progress=True means a bar where one is seen: none on a captured (non-terminal) stderr."""
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 7, 16), 4, 7)
    optimize(spec, images, valid, config=OptimizeConfig(iterations=30, progress=True))
    err = capsys.readouterr().err
    assert "\r" not in err and "%|" not in err and "it/s" not in err, repr(err[:200])
