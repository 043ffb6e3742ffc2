"""Tests of the optimiser's schedule, coarse multi-start and convergence stop."""
from __future__ import annotations

import math

import pytest
import torch

from mi_svbrdf.core.maps import roughness
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.loop import LoopConfig, _lr_at


def capture(size: int, n: int, seed: int = 0, name: str = "tiles", **params: float):
    """A calibrated rectified linear capture (flash with cone) of a procedural material."""
    gt = procedural.generate(name, 1, size, **params)[None]
    cap = sample_captures(1, n, capture_config(ambient=False, noise=False), torch.Generator().manual_seed(seed))
    spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="linear_exr")
    return gt, spec, images


def test_schedule_spans_schedule_steps_not_iterations():
    """The cosine ends at schedule_steps (then stays at its final lr), whatever the iteration cap."""
    cfg = LoopConfig(lr=0.1, schedule="cosine", min_lr_factor=0.05, iterations=5000, schedule_steps=400)
    assert _lr_at(cfg, 0, 0.0) == pytest.approx(0.1)
    assert _lr_at(cfg, 200, 0.0) == pytest.approx(0.1 * (0.05 + 0.95 * 0.5))
    assert _lr_at(cfg, 400, 0.0) == pytest.approx(0.005)
    assert _lr_at(cfg, 3000, 0.0) == pytest.approx(0.005)
    # The budget is a safety cap: if it would end first, it compresses the schedule.
    capped = LoopConfig(lr=0.1, iterations=5000, schedule_steps=400, budget_s=10.0)
    assert _lr_at(capped, 10, 10.0) == pytest.approx(0.1 * capped.min_lr_factor)
    # Without schedule_steps the schedule spans iterations (the loop's own default).
    assert _lr_at(LoopConfig(lr=0.1, iterations=100), 100, 0.0) == pytest.approx(0.1 * capped.min_lr_factor)


def test_config_rejects_bad_schedule_and_start_settings():
    for key in ("schedule_steps", "start_iterations", "start_scale"):
        with pytest.raises(ValueError, match=f"{key}: expected an int >= 1"):
            OptimizeConfig.from_dict({key: 0})


def test_starts_run_their_steps_at_half_resolution_then_full():
    """Each start runs start_iterations steps (counted) at 1/start_scale resolution, whatever the budget."""
    _, spec, images = capture(32, 6)
    sizes: list[tuple[int, int]] = []  # grad_hook sees each run's own step numbers: record in order

    def hook(step: int, grad: torch.Tensor) -> None:
        sizes.append(tuple(grad.shape[-2:]))

    cfg = OptimizeConfig(iterations=30, start_iterations=10, start_scale=2, tol=0.0, budget_s=600.0, progress=False)
    res = optimize(spec, images, config=cfg, grad_hook=hook)
    assert res.steps == 30 and [h[1] for h in res.history] == list(range(30))
    assert sizes == [(16, 16)] * 20 + [(32, 32)] * 10  # two starts x 10 steps, coarse; then full
    sizes.clear()
    full = optimize(spec, images, config=OptimizeConfig(iterations=22, start_iterations=10, tol=0.0, progress=False),
                    grad_hook=hook)  # default start_scale 1: full-resolution starts
    assert full.steps == 22 and sizes == [(32, 32)] * 22


def test_default_fit_stops_on_converged_and_recovers_roughness():
    """Without a budget a fit stops honestly on "converged", soon after its schedule ends.

    Defaults measured (32^2, 10 photos, stone r = 0.8, schedule 400 steps): converged after 608
    steps, roughness RMSE 0.012 (the glossy start 0.3 alone stays near r = 0.3). Here a shorter
    schedule and 6 photos at 24^2 keep the test short.
    """
    gt, spec, images = capture(24, 6, seed=1, name="stone", roughness=0.8)
    cfg = OptimizeConfig(progress=False, iterations=2000, schedule_steps=150, start_iterations=30, window=30)
    res = optimize(spec, images, config=cfg)
    assert res.stop_reason == "converged", (res.stop_reason, res.steps)
    assert 2 * cfg.start_iterations + 2 * cfg.window <= res.steps < 2000
    r_rmse = float((roughness(res.maps) - roughness(gt)).pow(2).mean().sqrt())
    assert r_rmse < 0.15, r_rmse
    assert math.isfinite(res.final_loss)


def test_run_scaled_window_keeps_a_slow_steady_descent_going():
    """A loss falling as 1/sqrt(t) after a fast start: the fixed 50-step window reads its slow phase
    as converged (the last window gains < 1 % of the run's gain), the run-scaled window does not
    until much later; a true plateau stops both."""
    from mi_svbrdf.optim.loop import LoopConfig, _converged

    def first_stop(losses: list[float], cfg: LoopConfig) -> int | None:
        return next((t for t in range(1, len(losses) + 1) if _converged(losses[:t], cfg)), None)

    slow = [1.0 / math.sqrt(t + 1) for t in range(4000)]
    fixed, scaled = LoopConfig(window=50, tol=1e-2), LoopConfig(window=50, tol=1e-2, window_fraction=0.25)
    stop_fixed, stop_scaled = first_stop(slow, fixed), first_stop(slow, scaled)
    assert stop_fixed is not None and (stop_scaled is None or stop_scaled > 4 * stop_fixed)
    plateau = [1.0 / math.sqrt(t + 1) if t < 300 else 1.0 / math.sqrt(301) for t in range(3000)]
    assert first_stop(plateau, scaled) is not None and first_stop(plateau, scaled) < 1000


def test_convergence_waits_for_the_schedule_and_for_the_calibration():
    """A fit that reaches its floor early (an exact 8x8 capture) stops only after its cosine has
    ended; a self-calibrating one only once the calibration has run two windows, whose losses
    alone the test then reads."""
    from mi_svbrdf.optim.fit import initial_maps
    from mi_svbrdf.optim.forward import TexelForward
    from mi_svbrdf.optim.loop import run, target_bounds
    from mi_svbrdf.optim.params import from_maps
    from mi_svbrdf.optim.selfcal import SelfCalibration

    _, spec, images = capture(8, 3)
    lo, hi = target_bounds(images, torch.ones(3, 1, 8, 8, dtype=torch.bool), [im.encoding for im in spec.images])
    x0 = from_maps(initial_maps(spec, images))
    for sched in (60, 240):
        cfg = LoopConfig(lr=0.1, schedule_steps=sched, iterations=2000, window=20, tol=1e-2, progress=False)
        res = run(TexelForward(spec, (8, 8)), lo, hi, x0, cfg)
        assert res.stop_reason == "converged" and res.steps >= sched
    cfg = LoopConfig(lr=0.1, schedule_steps=60, iterations=2000, window=20, tol=1e-2, progress=False)
    plain = run(TexelForward(spec, (8, 8)), lo, hi, x0, cfg)
    cal = SelfCalibration(spec, (8, 8), what=("gain",), texels=64)
    calibrated = run(TexelForward(spec, (8, 8)), lo, hi, x0, cfg, calibration=cal, calibration_after=plain.steps)
    assert calibrated.stop_reason == "converged" and calibrated.steps >= plain.steps + 2 * cfg.window
