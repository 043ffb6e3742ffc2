"""The optimisation loop: Adam on unconstrained variables, re-rendering loss + TV, stability guard.

Loss (thesis ch. 4.4.2): the re-rendering error between the forward model's renders and the
photos, plus ``tv_weight`` times the total variation of the maps. Each stored pixel stands
for an *interval* of radiance ``[lo, hi]``: an 8/16-bit value for ``+-0.5`` code (the
quantisation dead-band, in the encoded domain), and a saturated pixel (``valid`` False) for
``[lo, inf)``: the clip ``min(render, 1)`` equals the stored value whenever the render is at or
above the clip level, so such a pixel only penalises a render that falls *below* it. The
residual is the render's distance to its interval::

    log_l1:      |log(r + 0.01) - log(clamp(r, lo, hi) + 0.01)|      (default)
    l2:          (r - clamp(r, lo, hi))^2
    l2_display:  (g(r) - g(clamp(r, lo, hi)))^2,  g(x) = clip(x, 1e-4, 1)^(1/2.2)
                 (the per-pixel baseline of the field: L2 on gamma-encoded photos)

averaged over photos, pixels and channels. Linear EXR photos have ``lo = hi`` (plain loss).

**Clipping**: a pixel channel stored at the top code of an 8/16-bit photo (``srgb8``,
``srgb16``) is saturated in that channel: it stands for ``[lo, inf)`` like an invalid pixel
(:func:`target_bounds`), so a highlight clipped in red but not in blue no longer forces the
render's red down to the clip level (which coloured the specular of clipped highlights).

**Priors** (:class:`Prior`, added outside the fused kernel as PyTorch terms on the variables,
so the fused path keeps its speed): a pull towards the start (``anchor``; the net's maps when
refining) with weight ``anchor_weight`` (per map: ``map_weights``) on the squared distance in the
space of the variables; a chroma term pulling the specular towards grey (the variance of its
three logits, weighted per texel by ``chroma_texel``: more where the photos are saturated and
hold no colour information); a total variation of roughness and specular (``smooth_weight``).

Guard: a step whose loss is NaN/Inf, or above ``rise_factor`` times the best loss so far,
restores the last good variables (and calibration), restarts Adam (its moments may hold the bad
step's NaN; a snapshot of them would double the optimiser's memory, 300 MB at 2048^2), halves the
learning rate and counts a recovery; maps are therefore always finite.
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import GAMMA, linear_to_srgb, srgb_to_linear
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.optim.forward import ForwardModel
from mi_svbrdf.optim.fused_loss import DISPLAY_EPS, LOSSES
from mi_svbrdf.optim.params import MODELS, tie_gradient, tie_variables, to_maps, total_variation

SCHEDULES = ("cosine", "step", "constant")
LOG_EPS = 0.01


class Calibration(Protocol):
    """What :func:`run` needs of a self-calibration (:class:`~mi_svbrdf.optim.selfcal.SelfCalibration`)."""

    def step(self, maps: torch.Tensor | Callable[[torch.Tensor], torch.Tensor], lo: torch.Tensor, hi: torch.Tensor,
             kind: str, lr_factor: float = 1.0) -> float: ...  # pragma: no cover - protocol

    def apply(self, forward: Any) -> None: ...  # pragma: no cover - protocol

    def state(self) -> dict[str, Any]: ...  # pragma: no cover - protocol

    def load_state(self, state: dict[str, Any]) -> None: ...  # pragma: no cover - protocol


@dataclass
class LoopConfig:
    """Settings of one :func:`run` (one resolution level)."""

    loss: str = "log_l1"  #: "log_l1" (thesis, eps 0.01) or "l2"
    tv_weight: float = 1e-3  #: weight of the total variation of the maps, >= 0
    lr: float = 0.1  #: Adam learning rate on the unconstrained variables, > 0
    schedule: str = "cosine"  #: "cosine" (to lr * min_lr_factor), "step" (x0.5 every quarter) or "constant"; over schedule_steps or budget_s, whichever ends first
    schedule_steps: int | None = None  #: steps the schedule spans (then it stays at its final lr); None: iterations
    min_lr_factor: float = 0.05  #: final lr of the cosine schedule, as a fraction of lr
    iterations: int = 1000  #: maximum steps, >= 1
    budget_s: float = math.inf  #: wall-time budget in seconds, > 0
    window: int = 50  #: convergence window (steps), at least
    window_fraction: float = 0.0  #: the window grows to this fraction of the steps taken (a run-scaled window; 0: fixed), in [0, 0.5]
    tol: float = 1e-2  #: stop when the last window's mean loss improved on the previous one by < tol x the run's improvement since its first window (0: never)
    rise_factor: float = 2.0  #: a loss above rise_factor * best loss triggers a recovery
    checkpoint_every: int = 10  #: steps between snapshots of the last good state
    max_recoveries: int = 20  #: give up (stop) after this many recoveries
    progress: bool = True  #: tqdm progress bar with the current loss
    fused: bool = True  #: use the forward model's fused loss kernel when it has one (same loss, faster)
    model: str = "full"  #: map model (:data:`~mi_svbrdf.optim.params.MODELS`): which maps are tied or fixed


@dataclass
class Prior:
    """Prior terms of the objective (module docstring); all zero weights: no term."""

    anchor: torch.Tensor | None = None  #: (1, 9, H, W) variables the fit is pulled towards (None: no pull)
    anchor_weight: float = 0.0  #: weight of the mean squared distance to ``anchor``, >= 0
    map_weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)  #: normal, diffuse, roughness, specular
    chroma_weight: float = 0.0  #: weight of the specular logits' variance over RGB (grey prior), >= 0
    chroma_texel: torch.Tensor | None = None  #: (1, 1, H, W) per-texel factor of the chroma term (None: 1)
    smooth_weight: float = 0.0  #: weight of the total variation of roughness and specular, >= 0

    @property
    def active(self) -> bool:
        """Whether any term has a positive weight."""
        return ((self.anchor is not None and self.anchor_weight > 0) or self.chroma_weight > 0
                or self.smooth_weight > 0)

    def resized(self, size: tuple[int, int]) -> Prior:
        """This prior at another resolution (anchor and per-texel factor resampled)."""
        def rs(t: torch.Tensor | None) -> torch.Tensor | None:
            if t is None or tuple(t.shape[-2:]) == tuple(size):
                return t
            return torch.nn.functional.interpolate(t, size=size, mode="bilinear", align_corners=False,
                                                   antialias=size[0] < t.shape[-2])
        return dataclasses.replace(self, anchor=rs(self.anchor), chroma_texel=rs(self.chroma_texel))

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """The prior of variables ``x`` ``(1, 9, H, W)`` (scalar, differentiable).

        The pull and the chroma term are quadratics of ``x``: their value and gradient are computed
        in one pass (:class:`_Quadratic`, checked against :meth:`reference` by autograd), without a
        graph of a dozen full-size operations per step.
        """
        total = x.new_zeros(())
        if (self.anchor is not None and self.anchor_weight > 0) or self.chroma_weight > 0:
            total = total + _Quadratic.apply(x, self)
        if self.smooth_weight > 0:
            maps = to_maps(x)
            total = total + self.smooth_weight * total_variation(torch.cat([M.roughness(maps), M.specular(maps)], 1))
        return total

    def fold_quadratic(self, fused: Any) -> Prior:
        """Hand the pull and the chroma term to a fused objective (its ``set_quadratic``: computed in its kernel
        with the rendering loss, no PyTorch pass over the variables); returns the rest of this prior (the
        smoothness term), to add as a PyTorch term."""
        pull = self.anchor is not None and self.anchor_weight > 0
        wn, wd, wr, ws = self.map_weights
        weights = tuple(w * self.anchor_weight / 9.0 for w in (wn, wn, wd, wd, wd, wr, ws, ws, ws))
        fused.set_quadratic(self.anchor if pull else None, weights, self.chroma_weight,
                            self.chroma_texel if self.chroma_weight > 0 else None)
        return dataclasses.replace(self, anchor=None, anchor_weight=0.0, chroma_weight=0.0, chroma_texel=None)

    def quadratic(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Value (scalar) and gradient ``(1, 9, H, W)`` of the pull and the chroma term at ``x`` (no autograd)."""
        count = x.shape[0] * x.shape[2] * x.shape[3]
        value = x.new_zeros(())
        grad = torch.zeros_like(x)
        if self.anchor is not None and self.anchor_weight > 0:
            wn, wd, wr, ws = self.map_weights
            w = x.new_tensor([wn, wn, wd, wd, wd, wr, ws, ws, ws]).view(1, 9, 1, 1) * (self.anchor_weight / 9.0)
            d = x - self.anchor.to(x)
            wd_ = w * d
            value = value + (wd_ * d).sum() / count
            grad = grad + wd_ * (2.0 / count)
        if self.chroma_weight > 0:
            spec = x[:, 6:9]
            dev = spec - spec.mean(dim=1, keepdim=True)
            factor = self.chroma_weight / count
            if self.chroma_texel is not None:
                dev_t = dev * self.chroma_texel.to(x)
                value = value + factor * (dev_t * dev).sum() / 3.0
            else:
                dev_t = dev
                value = value + factor * dev.square().sum() / 3.0
            grad[:, 6:9] += dev_t * (2.0 * factor / 3.0)  # d/ds_c mean_k (s_k - m)^2 = 2/3 (s_c - m)
        return value, grad

    def reference(self, x: torch.Tensor) -> torch.Tensor:
        """The pull and the chroma term written plainly in PyTorch (autograd), the reference of :meth:`quadratic`."""
        total = x.new_zeros(())
        if self.anchor is not None and self.anchor_weight > 0:
            wn, wd, wr, ws = self.map_weights
            w = x.new_tensor([wn, wn, wd, wd, wd, wr, ws, ws, ws]).view(1, 9, 1, 1)
            total = total + self.anchor_weight * ((x - self.anchor.to(x)) ** 2 * w).sum(dim=1).mean() / 9.0
        if self.chroma_weight > 0:
            spec = x[:, 6:9]
            chroma = (spec - spec.mean(dim=1, keepdim=True)).square().mean(dim=1, keepdim=True)
            if self.chroma_texel is not None:
                chroma = chroma * self.chroma_texel.to(x)
            total = total + self.chroma_weight * chroma.mean()
        return total


class _Quadratic(torch.autograd.Function):
    """The quadratic terms of a :class:`Prior`: value and gradient from :meth:`Prior.quadratic` in one pass."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor, prior: Prior) -> torch.Tensor:  # type: ignore[override]
        value, grad = prior.quadratic(x.detach())
        ctx.save_for_backward(grad)
        return value

    @staticmethod
    def backward(ctx: Any, out: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        (grad,) = ctx.saved_tensors
        return out * grad, None


@dataclass
class Monitor:
    """An early stop: the maps are scored on photos the fit does not see, and the best maps are kept.

    ``score(maps)`` (e.g. a :class:`~mi_svbrdf.optim.scoring.HeldOutScorer`) runs after every ``every``-th
    update; the run stops when the score has not improved for ``max(patience, patience_fraction x the best
    length)`` updates (a curve that is still falling slowly late in a long fit keeps going), and returns the
    variables at the best score, not the last ones. Under a decaying learning-rate schedule the lengths before it
    has decayed are scored but not kept, and the run is not stopped before (a fit stopped mid-schedule is at a
    high learning rate: its maps carry the step size's noise, and a refit to that length would too). Lengths count
    updates from the start of the whole fit
    (the step offsets of multi-start and coarse levels included).
    """

    score: Callable[[torch.Tensor], float]  #: maps (1, 10, H, W) -> held-out error (lower is better)
    every: int = 10  #: updates between two scores, >= 1
    patience: int = 150  #: updates without improvement that stop the run, at least, >= 1
    patience_fraction: float = 0.5  #: the patience grows to this fraction of the best length, >= 0
    curve: list[tuple[float, int, float]] = field(default_factory=list)  #: (seconds, length, score) of every score
    best: float = math.inf  #: the lowest score so far
    best_length: int = 0  #: updates of the fit at the lowest score
    best_variables: torch.Tensor | None = None  #: variables at the lowest score
    eligible_from: int = 0  #: lengths below this are scored but never kept (run: before a schedule has decayed)

    def __post_init__(self) -> None:
        check_fields([("every", isinstance(self.every, int) and self.every >= 1, "an int >= 1", self.every),
                      ("patience", isinstance(self.patience, int) and self.patience >= 1, "an int >= 1", self.patience),
                      ("patience_fraction", self.patience_fraction >= 0, "a fraction >= 0", self.patience_fraction)],
                     owner="Monitor")

    def observe(self, x: torch.Tensor, length: int, seconds: float) -> bool:
        """Score variables ``x`` after ``length`` updates; returns whether the run should stop."""
        if length % self.every:
            return False
        err = self.score(to_maps(x.detach()))
        self.curve.append((seconds, length, err))
        if math.isfinite(err) and err < self.best and length >= self.eligible_from:
            self.best_variables = None  # the last best's memory goes first (150 MB at 2048^2)
            self.best, self.best_length, self.best_variables = err, length, x.detach().clone()
        return length - self.best_length >= max(self.patience, int(self.patience_fraction * self.best_length))


@dataclass
class LoopResult:
    """What :func:`run` returns."""

    variables: torch.Tensor  #: (1, 9, H, W) final unconstrained variables (finite)
    history: list[tuple[float, int, float]] = field(default_factory=list)  #: (seconds, step, loss)
    recoveries: int = 0  #: NaN/Inf or rising-loss recoveries
    stop_reason: str = ""  #: "converged", "held-out" (the monitor's early stop), "budget", "iterations" or "recoveries"
    steps: int = 0  #: steps taken


def target_bounds(images: torch.Tensor, valid: torch.Tensor, encodings: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Radiance interval ``[lo, hi]`` each stored pixel stands for: ``(N, 3, H, W)`` twice.

    Args:
        images: ``(N, 3, H, W)`` linear photos.
        valid: ``(N, 1, H, W)`` bool, False at saturated pixels (``hi = inf``).
        encodings: per photo ``"srgb8"``, ``"srgb16"`` or ``"linear_exr"``; a channel of an 8/16-bit
            photo at the top code is saturated in that channel (``hi = inf``; module docstring).
    """
    lo, hi = images.detach().clone(), images.detach().clone()
    for k, enc in enumerate(encodings):
        if enc in ("srgb8", "srgb16"):
            half = 0.5 / (255.0 if enc == "srgb8" else 65535.0)
            code = linear_to_srgb(lo[k])
            lo[k] = srgb_to_linear((code - half).clamp(0.0, 1.0))
            up = srgb_to_linear((code + half).clamp(0.0, 1.0))
            hi[k] = torch.where(code >= 1.0 - half, math.inf, up)  # the top code: clipped channel
    hi.masked_fill_(~valid.to(hi.device).expand_as(hi), math.inf)
    return lo, hi


def _display(x: torch.Tensor) -> torch.Tensor:
    """The gamma-encoded value the ``l2_display`` loss compares (finite gradient at 0: clipped at DISPLAY_EPS)."""
    return x.clamp(DISPLAY_EPS, 1.0).pow(1.0 / GAMMA)


def residual(render: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, kind: str = "log_l1") -> torch.Tensor:
    """Per-value distance of ``render`` ``(N, 3, H, W)`` to the intervals ``[lo, hi]`` (module docstring)."""
    target = torch.minimum(torch.maximum(render, lo), hi).detach()
    if kind == "log_l1":
        return (torch.log(render.clamp_min(0.0) + LOG_EPS) - torch.log(target + LOG_EPS)).abs()
    if kind == "l2":
        return (render - target) ** 2
    if kind == "l2_display":
        return (_display(render) - _display(target)) ** 2
    raise ValueError(f"loss: expected one of {LOSSES}, got {kind!r}")


def rerender_loss(render: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, kind: str = "log_l1") -> torch.Tensor:
    """Mean of :func:`residual` over photos, pixels and channels (scalar)."""
    return residual(render, lo, hi, kind).mean()


def _lr_at(cfg: LoopConfig, step: int, elapsed: float) -> float:
    """The scheduled lr; progress is the larger of the step (of ``schedule_steps``) and time-budget fractions.

    With an infinite or generous budget the schedule spans ``schedule_steps``, then stays at its
    final lr until the convergence test or ``iterations`` stops the run; a budget that would
    end first compresses it (a safety cap: the run still ends at a low lr).
    """
    if cfg.schedule == "constant":
        return cfg.lr
    span = cfg.schedule_steps if cfg.schedule_steps is not None else cfg.iterations
    t = min(max(step / max(span, 1), elapsed / cfg.budget_s), 1.0)
    if cfg.schedule == "step":
        return cfg.lr * 0.5 ** min(int(4 * t), 3)
    return cfg.lr * (cfg.min_lr_factor + (1.0 - cfg.min_lr_factor) * 0.5 * (1.0 + math.cos(math.pi * t)))


class _LastGood:
    """The last good state (the variables and the calibration's), restored by a recovery, which restarts Adam."""

    def __init__(self, x: torch.Tensor, calibration: Calibration | None = None) -> None:
        self.calibration = calibration
        self.x: torch.Tensor | None = None
        self.save(x)

    def save(self, x: torch.Tensor) -> None:
        """Snapshot ``x``: into the last snapshot's memory (a snapshot every few steps allocates nothing)."""
        if self.x is None or self.x.shape != x.shape:
            self.x = x.detach().clone()
        else:
            self.x.copy_(x.detach())
        self.calibration_state = self.calibration.state() if self.calibration is not None else None

    def restore(self, x: torch.Tensor, opt: torch.optim.Optimizer) -> None:
        with torch.no_grad():
            x.copy_(self.x)
        opt.state.clear()  # fresh moments at the next step
        if self.calibration is not None:
            self.calibration.load_state(self.calibration_state)


def _objective(forward: ForwardModel, lo: torch.Tensor, hi: torch.Tensor,
               cfg: LoopConfig, prior: Prior | None = None) -> Callable[[torch.Tensor], torch.Tensor]:
    """``variables -> loss``: re-rendering loss + TV (the forward model's fused kernel when it has
    one) + ``prior`` (PyTorch terms on the variables, outside the kernel)."""
    # A forward model may offer the whole objective as one kernel (TexelForward.fused_objective).
    make_fused = getattr(forward, "fused_objective", None) if cfg.fused else None
    fused = make_fused(lo, hi, cfg.loss, cfg.tv_weight) if make_fused is not None else None
    if fused is not None:
        if prior is not None and prior.active:
            rest = prior.fold_quadratic(fused)
            if rest.active:  # the smoothness term stays a PyTorch term
                def with_rest(x: torch.Tensor) -> torch.Tensor:
                    return fused(x) + rest(x)

                with_rest.checks_finite = fused.checks_finite  # type: ignore[attr-defined]  (a NaN term stays NaN)
                return with_rest
        return fused

    def objective(x: torch.Tensor) -> torch.Tensor:
        maps = to_maps(x)
        loss = rerender_loss(forward(maps), lo, hi, cfg.loss)
        if cfg.tv_weight > 0:
            loss = loss + cfg.tv_weight * total_variation(maps)
        if prior is not None and prior.active:
            loss = loss + prior(x)
        return loss

    return objective


def adam(params: list[torch.Tensor], lr: float) -> torch.optim.Adam:
    """PyTorch's Adam, fused into one kernel over each tensor where the build has it (one pass over the
    variables instead of a dozen: the step's largest cost after the rendering at 256²), else per-op."""
    try:
        return torch.optim.Adam(params, lr=lr, fused=True)
    except (RuntimeError, ValueError):  # a device or dtype without the fused kernel
        return torch.optim.Adam(params, lr=lr)


def _guarded_step(x: torch.Tensor, opt: torch.optim.Optimizer, objective: Callable[[torch.Tensor], torch.Tensor],
                  good: _LastGood, cfg: LoopConfig, step: int, best: float,
                  grad_hook: Callable[[int, torch.Tensor], None] | None) -> tuple[float, bool]:
    """Evaluate the loss at ``x`` and take an Adam step unless the step is bad; returns ``(loss, ok)``.

    Bad (module docstring): a NaN/Inf loss, a loss above ``rise_factor`` x ``best`` after the
    first window, or non-finite variables (read with the loss, before the step: a step that made them
    non-finite is undone at the next one, or by :func:`run`'s final check; an objective with a true
    ``checks_finite`` attribute is itself NaN at such variables, and they are not read). A good loss every
    ``checkpoint_every`` steps first snapshots ``x`` and the Adam state into ``good``.
    """
    opt.zero_grad(set_to_none=True)
    loss = objective(x)
    loss.backward()
    # One read from the device per step: the loss, and whether the variables it was computed at (the last step's
    # result) are finite -- a sum is finite iff every entry is (short of overflow: then a recovery).
    if getattr(objective, "checks_finite", False):
        value, total = loss.item(), 0.0
    else:
        value, total = torch.stack([loss.detach().double(), x.detach().sum().double()]).tolist()
    if cfg.model != "full":
        tie_gradient(x.grad, cfg.model)
    if grad_hook is not None:
        grad_hook(step, x.grad)
    if not (math.isfinite(value) and math.isfinite(total)) or (value > cfg.rise_factor * best and step > cfg.window):
        return value, False
    if step % cfg.checkpoint_every == 0:  # x is finite and has just rendered to a finite, non-rising loss
        good.save(x)
    opt.step()
    return value, True


def _limit_reached(cfg: LoopConfig, step: int, elapsed: float) -> str:
    """``"iterations"`` or ``"budget"`` when that limit is reached, else ``""``."""
    if step >= cfg.iterations:
        return "iterations"
    if elapsed >= cfg.budget_s:
        return "budget"
    return ""


def _converged(losses: list[float], cfg: LoopConfig) -> bool:
    """No longer improving: the last window gained less than ``tol`` of all the run has gained.

    The gain of the last window is measured against the one before; the run's against its first
    window. Oscillating at the final lr counts. Relative to the loss itself (the former test) it
    never fired: the loss floor (noise, TV) is far above the last windows' gains. With
    ``window_fraction`` f > 0 the window is ``max(window, f x steps)``: the test compares the last
    f of the run with the f before it, so a slow but steady descent late in a long run (what a
    fixed 50-step window reads as a plateau) keeps the fit going.
    """
    w = max(cfg.window, int(cfg.window_fraction * len(losses)))
    if cfg.tol <= 0 or len(losses) < 2 * w:
        return False
    first = sum(losses[:cfg.window]) / cfg.window
    recent, before = sum(losses[-w:]) / w, sum(losses[-2 * w:-w]) / w
    return before - recent < cfg.tol * max(first - recent, 0.0)


def _schedule_done(cfg: LoopConfig, steps: int) -> bool:
    """Whether the learning-rate schedule has reached its final rate after ``steps`` steps."""
    span = cfg.schedule_steps if cfg.schedule_steps is not None else cfg.iterations
    return cfg.schedule == "constant" or steps >= span


def _may_stop(cfg: LoopConfig, steps: int, calibrating: bool, calibration_after: int) -> bool:
    """Whether the convergence test may run after ``steps`` steps.

    Not while the schedule still decays (a plateau at a high learning rate is the step size's
    noise floor, not the fit's), and, when a calibration joins at ``calibration_after``, not
    before it has run two windows: its corrections change what the loss can reach, so the test
    then reads only the losses since it started.
    """
    span = cfg.schedule_steps if cfg.schedule_steps is not None else cfg.iterations
    if cfg.schedule != "constant" and steps < span:
        return False
    return not calibrating or steps >= calibration_after + 2 * cfg.window


def run(forward: ForwardModel, lo: torch.Tensor, hi: torch.Tensor, variables: torch.Tensor, cfg: LoopConfig, *,
        time_offset: float = 0.0, step_offset: int = 0,
        grad_hook: Callable[[int, torch.Tensor], None] | None = None, desc: str = "optimize",
        prior: Prior | None = None, calibration: Calibration | None = None,
        calibration_after: int = 0, monitor: Monitor | None = None, take: bool = False) -> LoopResult:
    """Fit ``variables`` so that ``forward(to_maps(variables))`` falls in ``[lo, hi]``.

    Args:
        forward: the forward model at the variables' resolution.
        lo, hi: ``(N, 3, H, W)`` target intervals (:func:`target_bounds`).
        variables: ``(1, 9, H, W)`` initial unconstrained variables (not modified, unless ``take``).
        cfg: loop settings.
        time_offset, step_offset: added to the recorded times and steps (coarse-to-fine levels).
        grad_hook: called as ``grad_hook(step, variables.grad)`` before each Adam step (tests
            use it to inject faults).
        desc: progress-bar label.
        prior: prior terms added to the objective (:class:`Prior`, at the variables' resolution;
            None: none).
        calibration: a :class:`~mi_svbrdf.optim.selfcal.SelfCalibration` at the variables'
            resolution stepped after every good step of the maps (its lr follows the schedule) and
            handed to ``forward``; None: the stated calibration.
        calibration_after: steps of the maps alone before the calibration starts (it would
            otherwise explain the start's errors away by moving lights and gains).
        monitor: an early stop on held-out photos (:class:`Monitor`): the run may stop with reason
            ``"held-out"``, and returns the variables at the monitor's best score; None: none.
        take: the caller hands ``variables`` over: a ``"full"`` model steps them in place instead of a copy (one
            copy of the variables at 2048^2 is 150 MB).
    """
    check_fields([("loss", cfg.loss in LOSSES, f"one of {LOSSES}", cfg.loss),
                  ("schedule", cfg.schedule in SCHEDULES, f"one of {SCHEDULES}", cfg.schedule),
                  ("model", cfg.model in MODELS, f"one of {MODELS}", cfg.model)])
    objective = _objective(forward, lo, hi, cfg, prior)
    if monitor is not None and cfg.schedule != "constant":  # a length is a choice once the schedule has decayed
        span = cfg.schedule_steps if cfg.schedule_steps is not None else cfg.iterations
        monitor.eligible_from = max(monitor.eligible_from, step_offset + span)
    x = (variables.detach() if take and cfg.model == "full" else tie_variables(variables.detach(), cfg.model))
    x.requires_grad_(True)
    opt = adam([x], cfg.lr)
    good = _LastGood(x, calibration)
    result = LoopResult(variables=variables)  # replaced by the final variables
    start = time.perf_counter()
    # The bar counts steps against a total only when the step cap is what ends the run; a budget or the
    # convergence test ends it at a step no one knows in advance, so it shows steps and time without one.
    capped = math.isinf(cfg.budget_s) and cfg.tol <= 0
    bar = tqdm(total=cfg.iterations if capped else None, desc=desc, unit="step", disable=not cfg.progress,
               leave=False)
    try:
        best, lr_scale, losses = math.inf, 1.0, []
        step = 0
        while True:
            elapsed = time.perf_counter() - start
            # the budget ends a run after its first step: a fit whose set-up (a cold kernel cache's compilation)
            # spent a small budget still takes one step rather than return its start as a fit
            result.stop_reason = _limit_reached(cfg, step, elapsed if step else 0.0)
            if result.stop_reason:
                break
            for group in opt.param_groups:
                group["lr"] = _lr_at(cfg, step, elapsed) * lr_scale
            value, ok = _guarded_step(x, opt, objective, good, cfg, step, best, grad_hook)
            if not ok:  # recovery: back to the last good state at half the learning rate
                result.recoveries += 1
                good.restore(x, opt)
                if calibration is not None:
                    calibration.apply(forward)
                lr_scale *= 0.5
                bar.set_postfix(loss=f"{value:.4g}", recoveries=result.recoveries)
                if result.recoveries >= cfg.max_recoveries:
                    result.stop_reason = "recoveries"
                    break
                step += 1
                continue
            best = min(best, value)
            losses.append(value)
            if calibration is not None and step >= calibration_after:
                calibration.step(lambda index: to_maps(x.detach().reshape(1, 9, 1, -1)[..., index]), lo, hi, cfg.loss,
                                 _lr_at(cfg, step, elapsed) * lr_scale / cfg.lr)  # the sampled texels' maps only
                calibration.apply(forward)
            result.history.append((time_offset + time.perf_counter() - start, step_offset + step, value))
            step += 1
            bar.update(1)
            bar.set_postfix(loss=f"{value:.4g}")
            # The early stop scores every run's steps, but stops none before its schedule has decayed (as the
            # convergence test, _may_stop: a rise at a high learning rate is the step size's noise, not overfitting).
            seconds = time_offset + time.perf_counter() - start
            if monitor is not None and monitor.observe(x, step_offset + step, seconds) and _schedule_done(cfg, step):
                result.stop_reason = "held-out"
                break
            if _may_stop(cfg, step, calibration is not None, calibration_after) and _converged(
                    losses[calibration_after if calibration is not None else 0:], cfg):
                result.stop_reason = "converged"
                break
        final = x.detach()
        if monitor is not None and monitor.best_variables is not None and monitor.best_length > step_offset:
            final = monitor.best_variables  # the maps at the lowest held-out error, from this run
        if not bool(torch.isfinite(final).all()):
            final = good.x
        result.variables = final  # no copy: the run's own tensors (x, the snapshot, the monitor's) end here
        result.steps = step
        return result
    finally:
        bar.close()  # cleared before anything else is printed (a Ctrl-C line would land on the bar's line)
