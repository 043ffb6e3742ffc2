"""Classical multi-image SVBRDF optimisation (thesis ch. 4.4.2): calibrated inverse rendering.

Given N photos of a flat sample and the light and camera of each (a :class:`CaptureSpec`,
from a capture file or the capture simulator), :func:`optimize` fits the four maps by
minimising the re-rendering error (log-L1 by default, clipping and 8-bit quantisation
modelled) plus a total-variation term, with Adam on unconstrained variables
(:mod:`~mi_svbrdf.optim.params`) and a cosine schedule, optionally coarse-to-fine.
Rectified photos go through the texel renderer; perspective ones through Mitsuba
(:func:`~mi_svbrdf.optim.forward.forward_for`).

Initialisation (thesis, with a measured fix): diffuse = the most fronto-parallel rectified
photo divided by its flat-normal irradiance (grey 0.5 without a rectified photo), normal up,
specular 0.04 grey, roughness mid-range -- the thesis's near-zero start stalls because the
gradient through alpha = r^2 vanishes there. By default two short fits start from roughness
0.3 and 0.7 and the better one is continued (:func:`_multi_start`: a rough material started
glossy stays glossy and a glossy one started rough stays rough). ``init_maps`` (e.g. a network's prediction)
replaces it (learned-init + refine).

Examples:
    >>> import torch
    >>> from mi_svbrdf.data import procedural
    >>> from mi_svbrdf.data.photo_setups import sample_captures, capture_config, render_captures
    >>> from mi_svbrdf.io.calibrated_photos import capture_from_simulator
    >>> gt = procedural.generate("tiles", 1, 32)[None]
    >>> cap = sample_captures(1, 4, capture_config(ambient=False, noise=False), torch.Generator().manual_seed(0))
    >>> spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="linear_exr")
    >>> res = optimize(spec, images, config=OptimizeConfig(iterations=20, progress=False))
    >>> tuple(res.maps.shape), res.steps
    ((1, 10, 32, 32), 20)
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core.config import check_fields, from_dict
from mi_svbrdf.core.maps import check_maps, make_maps
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.forward import ForwardModel, TexelForward, forward_for
from mi_svbrdf.optim.loop import LoopConfig, residual, run, target_bounds
from mi_svbrdf.optim.params import from_maps, resize_variables, to_maps

__all__ = ["OptimizeConfig", "OptimizeResult", "initial_maps", "optimize"]


@dataclass
class OptimizeConfig:
    """Settings of :func:`optimize`; :meth:`from_dict` rejects unknown keys."""

    loss: str = "log_l1"  #: re-rendering error: "log_l1" (thesis) or "l2"
    tv_weight: float = 1e-3  #: total-variation weight, >= 0
    lr: float = 0.1  #: Adam learning rate on the unconstrained variables
    schedule: str = "cosine"  #: "cosine", "step" or "constant" (per level)
    schedule_steps: int = 300  #: full-resolution steps the schedule spans (then final lr until converged)
    iterations: int = 1000  #: maximum steps over all levels and starts, >= 1
    budget_s: float = math.inf  #: wall-time safety cap over all levels, seconds (compresses the schedule if hit first)
    tol: float = 1e-2  #: convergence: the last window improved by < tol x the improvement since the first window (0: never)
    window: int = 50  #: convergence window, steps
    levels: int = 1  #: coarse-to-fine levels (1: full resolution only; 2: half then full; ...)
    path: str = "auto"  #: forward model: "auto" (texel if all rectified), "texel" or "mitsuba"
    backend: str = "auto"  #: texel renderer backend: "auto", "torch" or "mitsuba"
    rise_factor: float = 2.0  #: loss above rise_factor * best -> recovery
    max_recoveries: int = 20  #: stop after this many recoveries
    roughness_starts: tuple[float, ...] = (0.3, 0.7)  #: default-init roughness; several: multi-start (_multi_start)
    start_iterations: int = 50  #: steps of each multi-start fit (counted in ``iterations``; no time cap of their own)
    start_scale: int = 1  #: multi-start fits at 1/start_scale of the resolution (2: 4x cheaper, but chose the wrong basin for glossy tiles at 256^2)
    start_select: str = "global"  #: multi-start choice: "global" (best whole map) or "texel" (per-texel best)
    progress: bool = True  #: tqdm progress bar
    fused: bool = True  #: texel path: the objective and its gradient in one Dr.Jit kernel (same loss; False: PyTorch autograd)

    def __post_init__(self) -> None:
        starts = tuple(self.roughness_starts)
        counts = ("iterations", "schedule_steps", "start_iterations", "start_scale", "levels")
        check_fields([
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in counts),
            ("budget_s", self.budget_s > 0, "seconds > 0", self.budget_s),
            ("tv_weight", self.tv_weight >= 0, "a weight >= 0", self.tv_weight),
            ("lr", self.lr > 0, "a learning rate > 0", self.lr),
            ("tol", self.tol >= 0, "a tolerance >= 0", self.tol),
            ("roughness_starts", bool(starts) and all(0 < r < 1 for r in starts), "values in (0, 1)",
             self.roughness_starts),
            ("start_select", self.start_select in ("texel", "global"), "'texel' or 'global'", self.start_select),
        ], owner="OptimizeConfig")
        self.roughness_starts = starts

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OptimizeConfig:
        """Build from a dict; unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)


@dataclass
class OptimizeResult:
    """What :func:`optimize` returns."""

    maps: torch.Tensor  #: (1, 10, H, W) recovered maps, finite
    history: list[tuple[float, int, float]] = field(default_factory=list)  #: (seconds, step, loss) per good step
    recoveries: int = 0  #: NaN/Inf or rising-loss recoveries (each restored a good state and halved the lr)
    stop_reason: str = ""  #: "converged", "budget", "iterations" or "recoveries" (of the last level)
    steps: int = 0  #: steps over all levels
    seconds: float = 0.0  #: wall time of the fit

    @property
    def final_loss(self) -> float:
        """Loss of the last recorded step (NaN if none)."""
        return self.history[-1][2] if self.history else math.nan


def initial_maps(spec: CaptureSpec, images: torch.Tensor, roughness: float = 0.5) -> torch.Tensor:
    """The default start ``(1, 10, H, W)`` with a constant ``roughness`` (see the module docstring)."""
    n, _, h, w = images.shape
    rect = [k for k, im in enumerate(spec.images) if im.rectified]
    diffuse = torch.full((1, 3, h, w), 0.5)
    if rect:
        def frontality(k: int) -> float:
            im = spec.images[k]
            lp, cp = torch.tensor(im.light.position), torch.tensor(im.camera.position)
            return float(lp[2] / lp.norm() + cp[2] / cp.norm())
        k = max(rect, key=frontality)
        sub = dataclasses.replace(spec, images=(spec.images[k],))
        irr = TexelForward(sub, (h, w), "torch").irradiance()[0]
        diffuse = (images[k] / (0.96 * irr).clamp_min(1e-6)).clamp(0.01, 0.99)[None]
    normal = torch.zeros(1, 3, h, w)
    normal[:, 2] = 1.0
    return make_maps(normal, diffuse, torch.full((1, 1, h, w), roughness), torch.full((1, 3, h, w), 0.04))


def optimize(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor | None = None, *,
             config: OptimizeConfig | None = None, init_maps: torch.Tensor | None = None,
             forward: ForwardModel | None = None,
             grad_hook: Callable[[int, torch.Tensor], None] | None = None) -> OptimizeResult:
    """Fit SVBRDF maps to calibrated photos.

    Args:
        spec: the capture (per photo light, camera, encoding, rectified flag).
        images: ``(N, 3, H, W)`` linear photos (:func:`mi_svbrdf.io.calibrated_photos.load_capture`).
        valid: ``(N, 1, H, W)`` bool, False at saturated pixels; None: all valid.
        config: settings (defaults: :class:`OptimizeConfig`).
        init_maps: ``(1, 10, h, w)`` starting maps (resized to ``H x W``), e.g. a network's
            prediction; None: :func:`initial_maps`.
        forward: a forward model at full resolution overriding :func:`forward_for` (then
            ``levels`` must be 1).
        grad_hook: ``grad_hook(step, grad)`` before each Adam step (fault injection in tests).

    Returns:
        :class:`OptimizeResult` with the maps ``(1, 10, H, W)`` and the loss history.
    """
    cfg = config or OptimizeConfig()
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[:2] != (spec.n_images, 3):
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"images: expected shape (N={spec.n_images}, 3, H, W), got {shape}")
    images = images.detach().to(torch.float32)
    n, _, h, w = images.shape
    if valid is None:
        valid = torch.ones(n, 1, h, w, dtype=torch.bool)
    if tuple(valid.shape) != (n, 1, h, w):
        raise ValueError(f"valid: expected shape ({n}, 1, {h}, {w}), got {tuple(valid.shape)}")
    if forward is not None and cfg.levels != 1:
        raise ValueError(f"levels: expected 1 with a given forward model, got {cfg.levels}")
    lo, hi = target_bounds(images, valid, [im.encoding for im in spec.images])
    result = OptimizeResult(maps=torch.empty(0))
    start = time.perf_counter()
    if init_maps is None:
        if len(cfg.roughness_starts) == 1:
            init_maps = initial_maps(spec, images, cfg.roughness_starts[0])
        else:
            init_maps = _multi_start(spec, images, lo, hi, cfg, forward, result, grad_hook, start)
    check_maps(init_maps, "init_maps")
    if init_maps.shape[0] != 1:
        raise ValueError(f"init_maps: expected a single material (1, 10, H, W), got {tuple(init_maps.shape)}")
    variables = resize_variables(from_maps(init_maps.detach().to(torch.float32)), (h, w))
    for level in reversed(range(cfg.levels)):
        size = (max(h >> level, 1), max(w >> level, 1))
        elapsed = time.perf_counter() - start
        share = 1.0 / (level + 1) if level else 1.0  # coarse levels get a fraction of what is left
        left_iter = max(1, cfg.iterations - result.steps)
        loop_cfg = LoopConfig(loss=cfg.loss, tv_weight=cfg.tv_weight, lr=cfg.lr, schedule=cfg.schedule,
                              schedule_steps=max(1, int(cfg.schedule_steps * (0.5 * share if level else 1.0))),
                              iterations=max(1, int(left_iter * (0.5 * share if level else 1.0))),
                              budget_s=max(1e-3, (cfg.budget_s - elapsed) * (0.5 * share if level else 1.0)),
                              window=cfg.window, tol=cfg.tol, rise_factor=cfg.rise_factor,
                              max_recoveries=max(1, cfg.max_recoveries - result.recoveries),
                              progress=cfg.progress, fused=cfg.fused)
        if level:
            lvl_lo = F.adaptive_avg_pool2d(lo, size)
            lvl_hi = F.adaptive_avg_pool2d(hi, size)  # a saturated texel (inf) keeps its coarse texel open
        else:
            lvl_lo, hi_full = lo, hi
            lvl_hi = hi_full
        fwd = forward if forward is not None else forward_for(spec, size, cfg.path, cfg.backend)
        res = run(fwd, lvl_lo, lvl_hi, resize_variables(variables, size), loop_cfg, time_offset=elapsed,
                  step_offset=result.steps, grad_hook=grad_hook, desc=f"optimize {size[0]}x{size[1]}")
        variables = res.variables
        result.history += res.history
        result.recoveries += res.recoveries
        result.steps += res.steps
        result.stop_reason = res.stop_reason
        if res.stop_reason == "recoveries":
            break
    variables = resize_variables(variables, (h, w))
    maps = to_maps(variables).detach()
    if not bool(torch.isfinite(maps).all()):  # cannot happen (run keeps a good state); never return NaN
        raise RuntimeError("optimize: the maps became non-finite despite the recovery guard")
    result.maps = maps
    result.seconds = time.perf_counter() - start
    return result


def _multi_start(spec: CaptureSpec, images: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, cfg: OptimizeConfig,
                 forward: ForwardModel | None, result: OptimizeResult,
                 grad_hook: Callable[[int, torch.Tensor], None] | None, start: float) -> torch.Tensor:
    """Multi-start: a short fit from each roughness start, keep the best (whole map or per texel).

    Measured (128^2, N = 10, 300 steps; held-out re-rendering RMSE, trivial baseline in brackets):
    a single start is right for one kind of material only. Glossy tiles (true r ~ 0.2) from
    r = 0.3 reach 0.19 (0.42) but from 0.7 fall into the "rough and dull" basin (r -> 0.8,
    s -> 0.01; 0.38); the rough stone (r ~ 0.8) from 0.3 stays glossy (its lobe is too narrow
    for any photo to pull on it; r RMSE 0.56, 0.24 (0.15): *worse than the baseline*), from 0.7
    reaches r RMSE 0.035, 0.015. In both cases the right basin has the lower training loss,
    already after 50 steps: ``start_select="global"`` keeps the start with the lower mean
    re-rendering error (stone: r RMSE 0.042, held-out 0.014); a per-texel choice
    (``"texel"``) after 50 steps was noisier (stone 0.10, tiles 0.31). The steps are recorded
    in ``result`` (history, steps, recoveries). Starts are limited by steps only (a time cap
    stopped them after a few steps under load). ``start_scale=2`` (half-resolution starts)
    measured at 256^2, N = 10: stone fine (r RMSE 0.035) but glossy tiles chose the rough
    basin (r RMSE 0.66, held-out 0.49 vs baseline 0.52): hence full resolution by default.
    """
    h, w = images.shape[-2:]
    size = (h, w)
    if forward is None and cfg.start_scale > 1:  # coarse starts: cheaper, but blurred highlights favour rough
        size = (max(h // cfg.start_scale, 1), max(w // cfg.start_scale, 1))
        lo = F.adaptive_avg_pool2d(lo, size)
        hi = F.adaptive_avg_pool2d(hi, size)  # a saturated texel (inf) keeps its coarse texel open
    fwd = forward if forward is not None else forward_for(spec, size, cfg.path, cfg.backend)
    best_vars, best_err = None, None
    for r in cfg.roughness_starts:
        # Limited by steps only: a time cap stopped them after a few steps under load and made
        # the choice wrong. The overall budget (a safety cap) still applies.
        loop_cfg = LoopConfig(loss=cfg.loss, tv_weight=cfg.tv_weight, lr=cfg.lr, schedule="constant",
                              iterations=cfg.start_iterations, window=cfg.start_iterations + 1,
                              budget_s=max(1e-3, cfg.budget_s - (time.perf_counter() - start)),
                              rise_factor=cfg.rise_factor, max_recoveries=cfg.max_recoveries,
                              progress=cfg.progress, fused=cfg.fused)
        init = resize_variables(from_maps(initial_maps(spec, images, r)), size)
        res = run(fwd, lo, hi, init, loop_cfg,
                  time_offset=time.perf_counter() - start, step_offset=result.steps, grad_hook=grad_hook,
                  desc=f"start r={r:g}")
        result.history += res.history
        result.recoveries += res.recoveries
        result.steps += res.steps
        with torch.no_grad():
            err = residual(fwd(to_maps(res.variables)), lo, hi, cfg.loss).mean(dim=(0, 1))  # (H, W)
        if best_vars is None:
            best_vars, best_err = res.variables.clone(), err
        elif cfg.start_select == "global":
            if float(err.mean()) < float(best_err.mean()):
                best_vars, best_err = res.variables.clone(), err
        else:
            better = err < best_err
            best_vars = torch.where(better, res.variables, best_vars)
            best_err = torch.where(better, err, best_err)
    return to_maps(resize_variables(best_vars, (h, w))).detach()
