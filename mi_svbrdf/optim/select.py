"""Per-capture choice of the map model, the recipe and the fit's length: cross-validation on the capture's own photos.

No single recipe of :func:`~mi_svbrdf.optim.fit.optimize` wins on every capture (the field's plain per-pixel
Adam on one, a slow schedule run long on another, stronger priors on a third), the right length of a fit
differs per capture (one keeps improving for thousands of steps, another fits its photos' noise after a few
hundred), and a capture of a matte or uniformly glossy sample supports fewer maps than the full SVBRDF. So
:func:`select_and_fit` lets the photos decide, among the candidates of :data:`LADDER` (named configurations:
overrides of :class:`~mi_svbrdf.optim.fit.OptimizeConfig`, simplest first):

1. **The plan** (:func:`plan_folds`), made before the first fit from the capture (photos, size), the budget and,
   coarsely, a short measured step (:func:`measure_pace`): the fold fits' size, their steps and the candidates that
   run them, so that ``folds`` folds (always three by default, none skipped) fit ``budget_share`` of the budget at the
   pace planned for. Where the budget cannot buy the largest folds, the size shrinks, then candidates are dropped in a
   fixed order (:data:`DROP_ORDER`, measured); where even the smallest cannot fit, :data:`FALLBACK` (measured) is
   fitted and the notes say why. The clock moves the plan only through a coarse rule (:func:`pace_level`: whole factors of
   :data:`SLOW_PACE` over a reference step), so a machine twice as slow (one core instead of two) makes the same plan
   and the same choice. The plan is said in one line before the folds run, and is ``selection["plan"]``.
2. **Folds that see the capture as the final fit sees it.** ``folds`` photos, spread over the capture, are left out
   in turn; a fold fits **every other photo** (a full SVBRDF that 4 photos barely determine over-fits them where 20
   determine it: folds of fewer photos than the capture's rank simpler models too high) on a **window of the photos
   at their own resolution** (:meth:`~mi_svbrdf.io.calibrated_photos.CaptureSpec.window`, exact for the texel
   renderer; each fold another part of the sample, :func:`fold_windows`: grain a downsampled whole would average
   away stays), for the plan's steps (a scheduled recipe's schedule, starts and calibration delay shortened alike,
   so it anneals within them), and the left-out photo is scored every ``every`` steps along the way
   (:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`: display RMSE after the left-out photo's own exposure is
   fitted, robust to texels that render above the clip: a shot's exposure error, which no recipe can predict, is
   not held against the recipe whose brightness drifts the other way). Fold fits are capped by steps, not by the
   clock, so a rerun makes the same fits. ``SelectConfig(view="whole")`` fits the whole sample downsampled instead
   (every fold the same texels: their spread gives the uncertainty maps).
3. **The length.** A candidate's folds give its held-out error against the fit's length (under a decaying
   schedule, the lengths after it has decayed); the lowest mean over its folds, at one length, is its score:
   each recipe is judged at the length that suits it, the plain recipe's early stop included.
4. **Successive halving.** Every candidate runs the first fold; the better ``keep`` fraction runs the
   others (a hopeless candidate costs one fold fit, not ``folds``).
5. **The choice.** Of the candidates that ran every fold, the one with the lowest score is the best; a
   simpler one (earlier in :data:`LADDER`) is taken instead only when it is within noise of it (one standard
   error of the paired fold differences) **and** within ``tie`` (2 %) of its score: a simpler model that is
   worse by more than that is not "as good", however few folds measured it. Candidates within ``tie`` of the
   choice are reported as near-ties.
6. **The final fit.** The choice is fitted on all photos at full resolution as ``--select NAME`` fits it (its
   early stop choosing the length on a left-out photo), with what is left of ``budget_s``. When the folds fitted the
   whole sample, a multi-start recipe starts from the mean of the choice's fold fits (:func:`warm_start`,
   :func:`continues`; with 4 or more photos): it continues their work rather than restarts.

When the folds fitted the whole sample, the chosen candidate's fold fits also give **uncertainty maps**
(:func:`fold_spread`): the per-texel spread over the folds of the normal (degrees), diffuse, roughness and specular.
Texels that only one photo's highlight constrains move when that photo is left out; texels the photos agree on do
not. Windows of other parts of the sample give none (``selection["uncertainty_absent"]`` says so).

Selection needs at least three photos (each fold fits two or more) and the texel path (rectified
photos); otherwise the default recipe is fitted and the result's notes say why.

Examples:
    >>> [c.name for c in LADDER][:5]
    ['plain', 'lambertian', 'uniform', 'uniform_specular', 'full']
    >>> fold_photos(7, 3)
    [0, 3, 6]
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

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.io.calibrated_photos import CaptureSpec, window_texels
from mi_svbrdf.optim.fit import METHODS, OptimizeConfig, OptimizeResult, optimize
from mi_svbrdf.optim.scoring import EXPOSURES, HeldOutScorer, exposure_scale, held_out_rmse
from mi_svbrdf.optim.loop import Monitor
from mi_svbrdf.optim.params import from_maps, resize_variables, to_maps

__all__ = ["FALLBACK", "FOLD_VIEWS", "LADDER", "SELECT_MODES", "Candidate", "Plan", "SelectConfig", "candidate_config", "choose",
           "continues", "exposure_scale", "fit_photos", "fold_photos", "fold_spread", "fold_windows", "held_out_rmse",
           "lattice_window", "length_curve", "measure_pace", "pace_level", "plan_folds", "select_and_fit", "warm_start", "window_shape"]


@dataclass(frozen=True)
class Candidate:
    """A named configuration of :func:`optimize`: overrides of :class:`OptimizeConfig`."""

    name: str  #: the name ``--select`` takes
    overrides: dict[str, Any]  #: fields of OptimizeConfig set on top of the user's
    about: str  #: one line for the summary and the guide


#: Smallest capture whose final fit starts from the fold fits (with fewer, the pulls towards the default start
#: and the held-out shrinkage of a validated fit keep their meaning).
WARM_MIN_IMAGES = 4

#: The candidates, simplest first (the order breaks near-ties). Recipes: the field's plain per-pixel fit (no
#: priors, no TV, one start, a constant lr), then the project's; models: the maps tied or fixed
#: (:data:`~mi_svbrdf.optim.params.MODELS`); then stronger priors, a slower lr run long, self-calibration.
LADDER: tuple[Candidate, ...] = (
    Candidate("plain", dict(METHODS["pixel"]),
              "every map per texel, the field's plain recipe: L2 on gamma-encoded photos, Adam at a constant lr "
              "0.03, one start, no priors, no TV"),
    Candidate("lambertian", {"model": "lambertian"}, "normals and diffuse; no specular"),
    Candidate("uniform", {"model": "uniform"}, "normals and diffuse per texel, one roughness and specular"),
    Candidate("uniform_specular", {"model": "uniform_specular"},
              "normals, diffuse and roughness per texel, one specular"),
    Candidate("full", {}, "every map per texel, the default recipe (log-L1, lr 0.1, cosine, multi-start, TV)"),
    Candidate("full_priors", {"prior_falloff": 2.0, "chroma_weight": 0.1},
              "every map per texel, pulls towards the start falling as 1/N^2 and a 10x grey-specular prior"),
    Candidate("full_slow", {"lr": 0.03, "tol": 0.0},
              "every map per texel, lr 0.03 run long (no convergence stop)"),
    Candidate("full_calibrated", {"calibrate": "on"},
              "every map per texel, with self-calibration of exposures, flash offset and poses"),
)
#: ``--select``: ``auto`` (validate the ladder), ``off`` (the configuration as given), or a candidate's name.
SELECT_MODES = ("auto", "off", *(c.name for c in LADDER))


#: Steps a default fit of a capture typically takes to converge (multi-start included); fold fits shorten the
#: schedule, the starts and the calibration's delay by ``steps`` / this, so a scheduled recipe anneals in its fold.
TYPICAL_STEPS = 450
#: What a fold fits (:attr:`SelectConfig.view`): ``"windows"``, each fold a window of the photos at their own
#: resolution, another part of the sample each (:func:`fold_windows`): the texels the final fit sees, with every
#: photo's evidence; ``"whole"``, the whole sample downsampled to the fold's size: every fold the same texels, so
#: their spread gives the uncertainty maps, but grain finer than the fold's texels is averaged away; ``"lattice"``,
#: every k-th texel of the photos in each direction (:func:`lattice_window`): texels of the photos at their resolution,
#: none averaged, spread over the whole sample, the same in every fold (uncertainty maps and a start for the final fit).
FOLD_VIEWS = ("windows", "lattice", "whole")


def _shortened(cfg: OptimizeConfig, steps: int, budget_s: float, texels: float = 1.0) -> OptimizeConfig:
    """``cfg`` for a fold fit of ``steps`` steps: its schedule, starts and calibration delay scaled alike; the
    calibration's texels per step scaled by ``texels``, the fold's fraction of the photos' texels (the same share of
    each photo as the final fit's, at least 256)."""
    f = min(1.0, steps / TYPICAL_STEPS)
    return dataclasses.replace(
        cfg, iterations=steps, schedule_steps=max(1, int(cfg.schedule_steps * f)),
        start_iterations=max(5, int(cfg.start_iterations * f)), window=max(10, int(cfg.window * f)),
        calibrate_after=int(cfg.calibrate_after * f), budget_s=max(1e-3, budget_s), progress=False, levels=1,
        early_stop="off", calibrate_texels=max(min(256, cfg.calibrate_texels), int(cfg.calibrate_texels * texels)))


@dataclass
class SelectConfig:
    """Settings of the selection (:func:`select_and_fit`)."""

    folds: int = 3  #: photos left out in turn, spread over the capture, >= 2
    size: int = 64  #: texels per side of a fold fit, the largest the plan may take (at most the photos'), >= 8
    steps: int = 300  #: steps of a fold fit (a recipe's schedule shortened to fit them; 150 ranked worse), >= 10
    every: int = 10  #: steps between two scores of a fold's left-out photo (the lengths compared), >= 1
    keep: float = 0.4  #: fraction of the candidates that run the folds after the first (4 of 8), in (0, 1]
    budget_share: float = 0.5  #: of OptimizeConfig.budget_s, what the plan's folds may take at the reference pace, in (0, 1)
    photos: int | None = None  #: most photos a fold fits (None: every photo but the left-out one), >= 2
    view: str = "lattice"  #: what a fold fits (FOLD_VIEWS): "lattice", "windows" or "whole"
    warm_start: bool = True  #: the final fit starts from the chosen candidate's fold fits (4+ photos; :func:`continues`)
    tie: float = 0.02  #: a simpler candidate is chosen within this fraction of the best's score (and one SE), >= 0
    exposure: str = "held"  #: the left-out photo's exposure: "held" its own, "fit" from the fold's photos (scoring)

    def __post_init__(self) -> None:
        check_fields([
            ("folds", isinstance(self.folds, int) and self.folds >= 2, "an int >= 2", self.folds),
            ("size", isinstance(self.size, int) and self.size >= 8, "an int >= 8", self.size),
            ("steps", isinstance(self.steps, int) and self.steps >= 10, "an int >= 10", self.steps),
            ("every", isinstance(self.every, int) and self.every >= 1, "an int >= 1", self.every),
            ("keep", 0 < self.keep <= 1, "a fraction in (0, 1]", self.keep),
            ("photos", self.photos is None or (isinstance(self.photos, int) and self.photos >= 2),
             "None or an int >= 2", self.photos),
            ("view", self.view in FOLD_VIEWS, f"one of {FOLD_VIEWS}", self.view),
            ("budget_share", 0 < self.budget_share < 1, "a fraction in (0, 1)", self.budget_share),
            ("tie", self.tie >= 0, "a fraction >= 0", self.tie),
            ("exposure", self.exposure in EXPOSURES, f"one of {EXPOSURES}", self.exposure),
        ], owner="SelectConfig")


def candidate_config(name: str, config: OptimizeConfig | None = None) -> OptimizeConfig:
    """``config`` (default: :class:`OptimizeConfig`) with the overrides of the candidate ``name``.

    Examples:
        >>> candidate_config("full_slow").lr
        0.03
    """
    by_name = {c.name: c for c in LADDER}
    if name not in by_name:
        raise ValueError(f"select: expected one of {SELECT_MODES}, got {name!r}")
    return dataclasses.replace(config or OptimizeConfig(), **by_name[name].overrides)


def fold_photos(n: int, folds: int) -> list[int]:
    """The photos left out in turn: ``folds`` of ``n``, spread evenly from the first to the last."""
    k = min(folds, n)
    return sorted({round(i * (n - 1) / (k - 1)) for i in range(k)}) if k > 1 else [0]


def length_curve(curves: list[list[tuple[int, float]]]) -> tuple[int, float, list[float], bool]:
    """The length at which the mean of fold curves is lowest.

    Args:
        curves: one ``[(length, error), ...]`` per fold, lengths increasing; a curve that ended early (its fold
            stopped) keeps its last error at the lengths after it.

    Returns:
        ``(length, mean error there, each fold's error there, whether that is the last length any fold
        reached)``: the last means the folds were still improving when they stopped.

    Examples:
        >>> length_curve([[(10, 0.3), (20, 0.2), (30, 0.25)], [(10, 0.4), (20, 0.3)]])
        (20, 0.25, [0.2, 0.3], False)
    """
    if not curves or not all(curves):
        raise ValueError(f"curves: expected one or more non-empty curves, got {curves!r}")
    lengths = sorted({k for c in curves for k, _ in c})

    def at(curve: list[tuple[int, float]], length: int) -> float:
        before = [e for k, e in curve if k <= length]
        return before[-1] if before else curve[0][1]

    best = min(lengths, key=lambda k: (sum(at(c, k) for c in curves), k))
    errors = [at(c, best) for c in curves]
    return best, sum(errors) / len(errors), errors, best == lengths[-1]


def choose(rows: dict[str, dict[str, Any]], survivors: list[str], tie: float) -> tuple[str, str, list[str]]:
    """The choice among ``survivors`` (names, simplest first) from their ``mean`` and paired ``se``.

    The best (lowest mean) unless a simpler survivor is within one paired standard error **and** within ``tie``
    (a fraction) of its mean. Returns ``(choice, the best, near-ties)``: the near-ties are the other survivors
    whose mean is within ``tie`` of the choice's.

    Examples:
        >>> rows = {"a": {"mean": 0.101, "se": 0.01}, "b": {"mean": 0.100, "se": 0.0}, "c": {"mean": 0.2, "se": 0.1}}
        >>> choose(rows, ["a", "b", "c"], 0.02)
        ('a', 'b', ['b'])
        >>> choose({**rows, "a": {"mean": 0.110, "se": 0.02}}, ["a", "b", "c"], 0.02)[0]
        'b'
    """
    best = min(survivors, key=lambda c: rows[c]["mean"])
    bound = rows[best]["mean"]
    choice = next(c for c in survivors if c == best or (
        rows[c]["mean"] <= bound * (1.0 + tie) and rows[c]["mean"] <= bound + (rows[c]["se"] or 0.0)))
    near = [c for c in survivors if c != choice and abs(rows[c]["mean"] - rows[choice]["mean"])
            <= tie * rows[choice]["mean"]]
    return choice, best, near


#: The spread of a texel no photo measures (clipped in every photo): the largest a map can have (a value in
#: [0, 1] split between its bounds; a normal anywhere on the hemisphere).
UNMEASURED = {"normal_deg": 90.0, "diffuse": 0.5, "roughness": 0.5, "specular": 0.5}


def fold_spread(fold_maps: list[torch.Tensor], size: tuple[int, int],
                measured: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Per-texel spread of maps fitted on different photos: ``{name: (1, 1, H, W)}`` at ``size``.

    ``normal_deg``: the mean angle (degrees) between each fold's normal and their mean direction;
    ``diffuse``, ``specular``: the standard deviation over the folds, averaged over RGB; ``roughness``: its
    standard deviation. Needs two or more maps ``(1, 10, h, w)``. ``measured`` ``(1, 1, H, W)`` bool: False
    where no photo measures the texel (clipped in all): every fold then meets the same bound and agrees, so the
    spread says nothing there and :data:`UNMEASURED` is written instead.
    """
    if len(fold_maps) < 2:
        raise ValueError(f"fold_maps: expected two or more fits, got {len(fold_maps)}")
    stack = torch.cat([to_maps(resize_variables(from_maps(m), size)) for m in fold_maps])  # (K, 10, H, W)
    n = M.normal(stack)
    mean_n = F.normalize(n.mean(dim=0, keepdim=True), dim=1)
    sin = torch.linalg.cross(n, mean_n.expand_as(n), dim=1).norm(dim=1, keepdim=True)  # atan2: exact near 0
    angle = torch.rad2deg(torch.atan2(sin, (n * mean_n).sum(dim=1, keepdim=True))).mean(0, keepdim=True)
    spread = {"normal_deg": angle,
              "diffuse": M.diffuse(stack).std(dim=0, keepdim=True).mean(dim=1, keepdim=True),
              "roughness": M.roughness(stack).std(dim=0, keepdim=True),
              "specular": M.specular(stack).std(dim=0, keepdim=True).mean(dim=1, keepdim=True)}
    if measured is not None:
        spread = {k: torch.where(measured.to(v.device), v, torch.full_like(v, UNMEASURED[k])) for k, v in spread.items()}
    return spread


#: The plan's reference pace: a fold fit's step costs ``STEP_FIXED_S + STEP_TEXEL_S x photos x texels`` seconds
#: (the fused kernel, the left-out photo's scores and the starts included): fold fits on one core of a busy 2-core
#: x86 machine, so that one or two free cores run the plan within its share.
STEP_FIXED_S = 5.0e-3
STEP_TEXEL_S = 1.4e-7
#: Self-calibration renders a share of its texels again at each step and steps its own Adam: its fold fits cost this
#: factor more.
CALIBRATION_COST = 2.0
#: The coarse rule, the clock's only say in the plan: a measured step ``SLOW_PACE`` x (or more) slower than the
#: reference plans for a machine slower by ``SLOW_PACE ** level`` (the folds' share divided by it), ``level`` the
#: whole number of factors of ``SLOW_PACE`` the measured step is slower; a faster or up to 2x slower machine makes
#: the reference plan, and so the same choice.
SLOW_PACE = 2.0
#: Steps of the pace's measurement (after as many that compile the kernels and are not counted).
PACE_STEPS = 20
#: The measurement's step costs this factor over a fold fit's mean step at the same size and photos (a short fit:
#: its set-up is spread over fewer steps), measured on the machine of the reference figures.
PACE_PROBE_COST = 1.0
#: Fold-fit sizes the plan may take (texels per side of a window, or of the downsampled whole), largest first.
PLAN_SIZES = (128, 96, 64, 48, 32)
#: The plan shrinks the fold size down to this before it drops a candidate, then below it, per view: a window keeps
#: the photos' resolution (a smaller one sees less of the sample, each texel as well), the downsampled whole loses
#: detail with every step down.
PLAN_FLOOR = {"windows": 32, "lattice": 32, "whole": 48}
#: Candidates dropped, in this order, when the folds cannot afford them all: the furthest from the best candidate on
#: average first, when every candidate was fitted alone at full size (docs/benchmarks/select_oracle.md: held-out error
#: over the best's, mean over 2 real and 10 realistic simulated captures of 5 to 20 photos: full_slow 1.36, uniform
#: 1.34, full_priors 1.34, full 1.34, uniform_specular 1.29; kept: full_calibrated 1.12, lambertian 1.28, the field's
#: plain recipe 1.36, the baseline every selection must beat).
DROP_ORDER = ("full_slow", "uniform", "full_priors", "full", "uniform_specular")
#: The candidate fitted when the budget buys no folds: the one closest to the best on average when every candidate
#: was fitted alone at full size (the same page: 1.12 x the best's held-out error, within 5 % of it on 5 of 12 captures).
FALLBACK = "full_calibrated"


@dataclass(frozen=True)
class Plan:
    """The selection's plan, made before its first fit (:func:`plan_folds`)."""

    folds: tuple[int, ...]  #: photos left out in turn
    size: tuple[int, int]  #: texels of the fold fits (H, W): a window's, or the downsampled whole's
    photos: int  #: photos each fold fits (every other photo unless SelectConfig.photos caps them: :func:`fit_photos`)
    steps: int  #: steps of a fold fit
    candidates: tuple[str, ...]  #: the candidates that run the first fold, simplest first
    keep: int  #: candidates that run the other folds
    fold_fits: int  #: fold fits in all
    seconds: float  #: the folds' seconds at the pace planned for (the reference pace x SLOW_PACE ** level)
    share_s: float  #: seconds the folds may take: budget_share of the budget
    level: int  #: the coarse rule's level (0: the reference pace)
    pace: float | None  #: the measured step over the reference step (None: not measured, no budget)
    fallback: str = ""  #: why no plan fits and FALLBACK is fitted instead ("": a plan fits)
    view: str = "lattice"  #: what a fold fits (:data:`FOLD_VIEWS`)
    windows: tuple[tuple[int, int, int, int], ...] = ()  #: per fold, its window (top, left, height, width); () for "whole"
    photo_size: tuple[int, int] = (0, 0)  #: the photos' texels (H, W)
    step: int = 1  #: "lattice": every step-th texel of the windows in each direction (1: every texel)

    @property
    def whole(self) -> bool:
        """Whether every fold fits the whole sample (downsampled, or a window as large as the photos)."""
        return self.view in ("whole", "lattice") or all(win[2:] == self.photo_size for win in self.windows)

    def line(self) -> str:
        """The plan in one line (printed before the folds run)."""
        if self.fallback:
            return f"selection plan: none; {self.fallback}"
        hw = f"{self.size[0]}x{self.size[1]}"
        if self.view == "lattice" and self.step > 1:
            nth = {2: "2nd", 3: "3rd"}.get(self.step, f"{self.step}th")
            where = (f"every {nth} texel of the photos in each direction ({hw} texels of the photos at their "
                     "resolution, over the whole sample)")
        elif self.view in ("whole", "lattice") or self.whole:
            where = (f"the whole sample at {hw} texels" if self.size == self.photo_size
                     else f"the whole sample downsampled to {hw} texels")
        else:
            where = f"a {hw} window of the photos at their resolution (another part of the sample for each fold)"
        time_ = ""
        if math.isfinite(self.share_s):
            slow = "a slow machine" if self.level == 0 else f"a machine {SLOW_PACE ** self.level:g}x slower than a slow one"
            time_ = f", planned within the {self.share_s:.0f} s the folds may take: about {self.seconds:.0f} s on {slow}"
            if self.pace is not None:
                ratio = self.pace / SLOW_PACE ** self.level
                expect = "less" if ratio < 0.8 else "more" if ratio > 1.25 else "about that"
                time_ += f"; this machine's first steps took {ratio:.2g}x as long as that one's, so expect {expect}"
        return (f"selection plan: {len(self.folds)} folds, each leaving out one photo "
                f"({', '.join(f'{k:03d}' for k in self.folds)}) and fitting {self.photos} others on {where} for "
                f"{self.steps} steps; {len(self.candidates)} candidates on the first fold, the best {self.keep} on the "
                f"others: {self.fold_fits} fold fits{time_}")

    def as_dict(self) -> dict[str, Any]:
        """The plan for ``summary.json`` (strict JSON)."""
        d = dataclasses.asdict(self)
        d.update(folds=list(self.folds), size=list(self.size), candidates=list(self.candidates),
                 windows=[list(win) for win in self.windows], photo_size=list(self.photo_size),
                 seconds=round(self.seconds, 2), share_s=round(self.share_s, 2) if math.isfinite(self.share_s) else None,
                 pace=None if self.pace is None else round(self.pace, 3), line=self.line())
        return d


def fit_photos(n: int, left_out: int, most: int | None = None) -> list[int]:
    """The photos a fold fits: all but ``left_out``, or ``most`` of them spread evenly over the capture.

    Examples:
        >>> fit_photos(5, 2)
        [0, 1, 3, 4]
        >>> fit_photos(20, 0, 8)
        [1, 4, 6, 9, 11, 14, 16, 19]
    """
    others = [i for i in range(n) if i != left_out]
    if most is None or len(others) <= most:
        return others
    return [others[round(i * (len(others) - 1) / (most - 1))] for i in range(most)]


#: The low-discrepancy sequence that places the folds' windows (the plastic number's R2 sequence: every prefix is
#: spread over the square).
_R2 = (0.7548776662466927, 0.5698402909980532)


def window_shape(h: int, w: int, side: int) -> tuple[int, int]:
    """The largest window of ``h x w`` photos with their aspect and its short side at most ``side`` (at least one
    aspect unit: the whole photo when ``h:w`` has no smaller whole-texel multiple).

    Examples:
        >>> window_shape(256, 256, 48), window_shape(384, 512, 48), window_shape(40, 40, 64), window_shape(31, 32, 16)
        ((48, 48), (48, 64), (40, 40), (31, 32))
    """
    g = math.gcd(h, w)
    uh, uw = h // g, w // g
    m = max(1, min(g, side // min(uh, uw)))
    return m * uh, m * uw


def fold_windows(h: int, w: int, shape: tuple[int, int], folds: int) -> list[tuple[int, int, int, int]]:
    """The folds' windows ``(top, left, height, width)`` of ``shape`` in ``h x w`` photos: the first centred, the
    others at the next points of a low-discrepancy sequence (:data:`_R2`), so together they spread over the sample.

    Examples:
        >>> fold_windows(256, 256, (48, 48), 3)
        [(104, 104, 48, 48), (15, 53, 48, 48), (133, 2, 48, 48)]
    """
    wh, ww = shape
    out = []
    for i in range(folds):
        u, v = (0.5 + i * _R2[0]) % 1.0, (0.5 + i * _R2[1]) % 1.0
        out.append((round(v * (h - wh)), round(u * (w - ww)), wh, ww))
    return out


def lattice_window(h: int, w: int, step: int) -> tuple[int, int, int, int]:
    """The largest window ``(top, left, height, width)`` of ``h x w`` photos, centred, with their aspect and whole
    ``step`` x ``step`` blocks: every ``step``-th texel of it (:meth:`CaptureSpec.window`) is a lattice over the sample.

    Examples:
        >>> lattice_window(256, 256, 6), lattice_window(384, 512, 5), lattice_window(40, 40, 1)
        ((2, 2, 252, 252), (4, 6, 375, 500), (0, 0, 40, 40))
    """
    g = math.gcd(h, w)
    uh, uw = h // g, w // g
    m = next((m for m in range(g, 0, -1) if (m * uh) % step == 0 and (m * uw) % step == 0), 0)
    if m == 0:
        raise ValueError(f"step: expected a lattice step that whole windows of the {h}x{w} photos hold, got {step}")
    wh, ww = m * uh, m * uw
    return (h - wh) // 2, (w - ww) // 2, wh, ww


def step_seconds(photos: int, size: tuple[int, int]) -> float:
    """A fold fit's step at the reference pace (:data:`STEP_FIXED_S`, :data:`STEP_TEXEL_S`)."""
    return STEP_FIXED_S + STEP_TEXEL_S * photos * size[0] * size[1]


def pace_level(pace: float | None) -> int:
    """The coarse rule (:data:`SLOW_PACE`): 0 up to ``SLOW_PACE`` x the reference step, then one per factor.

    Examples:
        >>> [pace_level(p) for p in (None, 0.3, 1.0, 1.9, 2.0, 3.9, 4.0, 9.0)]
        [0, 0, 0, 0, 1, 1, 2, 3]
    """
    if pace is None or not math.isfinite(pace) or pace < SLOW_PACE:
        return 0
    return int(math.floor(math.log(pace) / math.log(SLOW_PACE) + 1e-9))


def plan_folds(n: int, h: int, w: int, budget_s: float, sel: SelectConfig, steps: int,
               pace: float | None = None) -> Plan:
    """The folds of a capture of ``n`` photos of ``h x w`` with ``budget_s`` seconds, before any fit.

    Always :attr:`SelectConfig.folds` folds, none skipped, each fitting every photo but its left-out one (at most
    :attr:`SelectConfig.photos`). The largest fold fits (size, every candidate of :data:`LADDER`) whose seconds at the
    planned pace fit ``budget_share`` of the budget: the size shrinks first (down to :data:`PLAN_FLOOR`), then
    candidates are dropped (:data:`DROP_ORDER`), then the size shrinks below the floor. With ``view="windows"`` a fold
    fits a window of the photos at their resolution (:func:`window_shape`, :func:`fold_windows`; the largest is the
    photos' whole), with ``"whole"`` the whole sample downsampled (at most half the photos' side). The pace planned
    for is the reference's (:func:`step_seconds`) times ``SLOW_PACE ** pace_level(pace)``, so a machine up to
    ``SLOW_PACE`` x slower than the reference makes the same plan. When no plan fits, :attr:`Plan.fallback` says why.
    The final fit has the rest of the budget.

    Examples:
        >>> p = plan_folds(7, 256, 256, 60.0, SelectConfig(), 300)
        >>> p.folds, p.size, p.photos, len(p.candidates), p.fold_fits, p.seconds <= p.share_s
        ((0, 3, 6), (32, 32), 6, 6, 12, True)
        >>> plan_folds(7, 256, 256, 60.0, SelectConfig(), 300, pace=1.9) == dataclasses.replace(p, pace=1.9)
        True
    """
    folds = tuple(fold_photos(n, sel.folds))
    level = pace_level(pace)
    share = sel.budget_share * budget_s
    photos = n - 1 if sel.photos is None else min(sel.photos, n - 1)
    steps_of: dict[tuple[int, int], int] = {}  # "lattice": the step of each fold size
    if sel.view == "windows":
        shapes = [window_shape(h, w, s) for s in (sel.size, *(s for s in PLAN_SIZES if s < sel.size))]
    elif sel.view == "lattice":
        shapes = []
        for side in (sel.size, *(s for s in PLAN_SIZES if s < sel.size)):
            k = max(1, math.ceil(min(h, w) / side))
            win = lattice_window(h, w, k)
            shapes.append((win[2] // k, win[3] // k))
            steps_of.setdefault(shapes[-1], k)
    else:
        def clamp(side: int, s: int) -> int:
            return min(s, max(32, side // 2), side)

        top = min(sel.size, max(32, min(h, w) // 2))
        shapes = [(clamp(h, top), clamp(w, top)), *((clamp(h, s), clamp(w, s)) for s in PLAN_SIZES if s < top)]
    sizes = list(dict.fromkeys(shapes))
    floor = [s for s in sizes if min(s) >= min(PLAN_FLOOR[sel.view], min(sizes[0]))]
    by_name = {c.name: c for c in LADDER}

    def cost(names: tuple[str, ...], size: tuple[int, int]) -> tuple[int, int, float]:
        keep = min(len(names), max(3, math.ceil(sel.keep * len(names))))  # 3 or more: a choice among several
        fits = [(steps * step_seconds(photos, size) + steps / sel.every * step_seconds(1, size))
                * (CALIBRATION_COST if by_name[c].overrides.get("calibrate") == "on" else 1.0) for c in names]
        seconds = sum(fits) + (len(folds) - 1) * sum(sorted(fits)[-keep:])  # the costliest survive, at most
        return keep, len(names) + keep * (len(folds) - 1), seconds * SLOW_PACE ** level

    def plan(names: tuple[str, ...], size: tuple[int, int], fallback: str = "") -> Plan:
        keep, fits, seconds = cost(names, size)
        k = steps_of.get(size, 1)
        windows = (tuple(fold_windows(h, w, size, len(folds))) if sel.view == "windows" else
                   (lattice_window(h, w, k),) * len(folds) if sel.view == "lattice" else ())
        return Plan(folds, size, photos, steps, names, keep, fits, seconds, share, level, pace, fallback, sel.view,
                    windows, (h, w), k)

    ladders = [tuple(c.name for c in LADDER if c.name not in DROP_ORDER[:d]) for d in range(len(DROP_ORDER) + 1)]
    tiers = [(ladders[0], s) for s in floor] + [(names, s) for names in ladders[1:] for s in floor] + [
        (ladders[-1], s) for s in sizes if s not in floor]
    for names, size in tiers:
        if cost(names, size)[2] <= share:
            return plan(names, size)
    names, size = tiers[-1]
    keep, fits, seconds = cost(names, size)
    why = (f"the smallest selection ({fits} fold fits of {photos} photos at {size[0]}x{size[1]}) needs about "
           f"{seconds:.0f} s, more than {sel.budget_share:.0%} of the {budget_s:g} s budget: {FALLBACK} was fitted, the "
           "candidate closest to the best on average when each was fitted alone (a larger --budget-s selects)")
    return plan(names, size, why)


def measure_pace(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor, cfg: OptimizeConfig) -> float:
    """A short fit's step over the reference step (:func:`step_seconds`) of the same photos and size.

    ``images`` ``(N, 3, H, W)``: the photos a fold fits, at the fold size. The default recipe's loss and kernel,
    one start, :data:`PACE_STEPS` steps timed after as many that compile the kernels. Also warms the kernels of the
    fold fits.
    """
    probe = dataclasses.replace(cfg, iterations=2 * PACE_STEPS, roughness_starts=(0.5,), tol=0.0, levels=1,
                                early_stop="off", validate_photo=False, calibrate="off", budget_s=math.inf,
                                progress=False, schedule="constant")
    res = optimize(spec, images, valid, config=probe)
    times = [t for t, _, _ in res.history]
    if len(times) < PACE_STEPS + 2:
        return 1.0  # a fit cut short (recoveries): no measure, the reference plan
    per_step = (times[-1] - times[PACE_STEPS - 1]) / (len(times) - PACE_STEPS)
    return per_step / (PACE_PROBE_COST * step_seconds(images.shape[0], tuple(images.shape[-2:])))


def continues(cfg: OptimizeConfig) -> bool:
    """Whether the final fit of a candidate continues from its fold fits (:func:`warm_start`): a recipe that starts
    from several roughnesses (its fold fits chose the basin, and the final fit skips the starts). A one-start recipe
    (the plain one, the Lambertian model) starts as ``--select NAME`` does: continued from upsampled fold maps, its early
    stop ended the plain recipe before the detail the folds could not see (wood 13: held-out 0.0350 against 0.0305;
    bath_tile 0.1706 against 0.1676), where self-calibration gained (yellow_box 0.0683 against 0.1049)."""
    return len(cfg.roughness_starts) > 1 and cfg.model != "lambertian"


def warm_start(fold_maps: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
    """The final fit's start from a candidate's fold fits: the mean of their variables, resized to ``size``.

    Examples:
        >>> m = M.constant_maps(1, 8, 8, roughness=0.4)
        >>> tuple(warm_start([m, m], (16, 16)).shape)
        (1, 10, 16, 16)
    """
    mean = torch.cat([from_maps(m) for m in fold_maps]).mean(dim=0, keepdim=True)
    return to_maps(resize_variables(mean, size)).detach()


@dataclass
class SelectedFit:
    """What :func:`select_and_fit` returns: the final fit, and how it was chosen."""

    result: OptimizeResult  #: the chosen candidate's fit on all photos
    choice: str  #: the candidate fitted ("" when the configuration was fitted as given)
    selection: dict[str, Any] = field(default_factory=dict)  #: every candidate's fold errors, mean, SE, seconds; why
    uncertainty: dict[str, torch.Tensor] | None = None  #: fold_spread of the chosen candidate's fold fits, at full size


def _why_not(spec: CaptureSpec, cfg: OptimizeConfig) -> str:
    """Why this capture is fitted without selection ("" when it can be selected)."""
    n = spec.n_images
    if n < 3:
        instead = ("the held-out photo chooses how far the fit moves from its start" if n == 2
                   else "the pulls towards the start hold the maps where one photo cannot tell")
        return (f"selection needs 3 or more photos (each fold fits 2 or more), got {n}: the default recipe was "
                f"fitted ({instead})")
    if cfg.path == "mitsuba" or not all(im.rectified for im in spec.images):
        return ("selection runs on the texel path (rectified photos), got perspective photos: the default recipe "
                "was fitted")
    return ""


def select_and_fit(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor | None = None, *,
                   config: OptimizeConfig | None = None, select: str = "auto",
                   settings: SelectConfig | None = None, say: Callable[[str], None] | None = None) -> SelectedFit:
    """Fit the maps with the candidate of :data:`LADDER` that the capture's own photos support best.

    Args:
        spec: the capture; images: ``(N, 3, H, W)`` linear photos; valid: ``(N, 1, H, W)`` unsaturated pixels.
        config: the user's settings (budget, loss, device, ...); candidates override some of them.
        select: ``"auto"`` (module docstring), ``"off"`` (``config`` as given) or a candidate's name (forced).
        settings: the selection's own settings.
        say: called with the plan's line before the folds run (None: written above the progress bars when they
            are drawn).

    Returns:
        :class:`SelectedFit`; with ``"auto"``, ``selection`` holds each candidate's ``fold_errors``, ``mean``,
        ``se``, ``seconds`` and whether it was ``eliminated``, the ``choice`` and ``why``, and the seconds of the
        folds and of the final fit.
    """
    cfg = config or OptimizeConfig()
    sel = settings or SelectConfig()
    if select not in SELECT_MODES:
        raise ValueError(f"select: expected one of {SELECT_MODES}, got {select!r}")
    if select == "off":
        return SelectedFit(optimize(spec, images, valid, config=cfg), "", {"mode": "off"})
    if select != "auto":
        result = optimize(spec, images, valid, config=candidate_config(select, cfg))
        return SelectedFit(result, select, {"mode": "forced", "choice": select})
    why_not = _why_not(spec, cfg)
    if why_not:
        result = optimize(spec, images, valid, config=cfg)
        result.notes.insert(0, why_not)
        return SelectedFit(result, "", {"mode": "auto", "choice": "", "why": why_not})

    start = time.perf_counter()
    n, _, h, w = images.shape
    dev = cfg.device or images.device
    images = images.detach().to(device=dev, dtype=torch.float32)
    valid = (torch.ones(n, 1, h, w, dtype=torch.bool, device=images.device) if valid is None
             else valid.to(images.device))
    steps = min(sel.steps, max(10, cfg.iterations))  # a capped fit caps its folds too

    def seen(p: Plan, i: int) -> tuple[CaptureSpec, torch.Tensor, torch.Tensor]:
        """What fold ``i`` of plan ``p`` sees: its window of the capture at the photos' resolution, or the whole."""
        if p.view in ("windows", "lattice"):
            win = p.windows[i]
            return (spec.window(*win, (h, w), p.step), window_texels(images, *win, p.step).contiguous(),
                    window_texels(valid, *win, p.step).contiguous())
        if p.size == (h, w):
            return spec, images, valid
        return (spec, F.interpolate(images, size=p.size, mode="area"),
                F.interpolate(valid.float(), size=p.size, mode="area") > 0.999)

    # The plan, before the first fit: from the capture, the budget and (coarsely) a short measured step.
    plan = plan_folds(n, h, w, cfg.budget_s, sel, steps)
    if math.isfinite(cfg.budget_s):
        probe = fit_photos(n, plan.folds[0], plan.photos)
        seen_spec, seen_images, seen_valid = seen(plan, 0)
        pace = measure_pace(seen_spec.subset(probe), seen_images[probe], seen_valid[probe], cfg)
        plan = plan_folds(n, h, w, cfg.budget_s, sel, steps, pace)  # the probe is part of the folds
    if say is not None:
        say(plan.line())
    elif cfg.progress:
        tqdm.write(plan.line())
    if plan.fallback:  # no folds: the candidate a measured rule names
        result = optimize(spec, images, valid, config=candidate_config(FALLBACK, cfg))
        result.notes.insert(0, plan.fallback)
        return SelectedFit(result, FALLBACK, {"mode": "auto", "choice": FALLBACK, "why": plan.fallback,
                                              "plan": plan.as_dict()})
    s = plan.size
    ladder = [c for c in LADDER if c.name in plan.candidates]
    folds = list(plan.folds)
    rows = {c.name: {"name": c.name, "about": c.about, "fold_errors": {}, "fold_seconds": {}, "fold_curves": {},
                     "fold_scored": {}, "seconds": 0.0, "eliminated": False} for c in ladder}
    fold_maps: dict[str, list[torch.Tensor]] = {c.name: [] for c in ladder}
    runs: list[list[Any]] = []  # [candidate, fold] of each fold fit, in the order they ran
    bar = tqdm(total=plan.fold_fits, desc="selection: fold fits", unit="fit", disable=not cfg.progress, leave=False)

    def fold_fit(c: Candidate, k: int) -> None:
        fit = fit_photos(n, k, plan.photos)
        fold_spec, fold_images, fold_valid = seen(plan, folds.index(k))
        # Capped by steps, not by the clock (a fit cut by a clock would differ from run to run): the whole
        # budget is its only time limit, a safety cap the plan does not reach.
        seconds = cfg.budget_s - (time.perf_counter() - start)
        monitor = Monitor(HeldOutScorer(fold_spec, fold_images, fit, [k], cfg.distribution, exposure=sel.exposure),
                          every=sel.every, patience=10**9)  # the whole fold fit is scored: its length is chosen afterwards
        fold_cfg = _shortened(candidate_config(c.name, cfg), plan.steps, seconds, s[0] * s[1] / (h * w))
        t0 = time.perf_counter()
        res = optimize(fold_spec.subset(fit), fold_images[fit], fold_valid[fit], config=fold_cfg, held_out=monitor)
        took = time.perf_counter() - t0
        # The lengths a fit may end at: under a decaying schedule, once it has decayed (as the early stop).
        curve = [(length, err) for _, length, err in monitor.curve if length >= monitor.eligible_from]
        scored = [(length, err) for _, length, err in monitor.curve]  # the whole run, for the charts
        if not curve:  # a fit too short to be scored on its way: its end
            curve = [(res.steps, monitor.score(res.maps))]
            scored = [*(e for e in scored if e[0] < res.steps), curve[0]]  # the length chosen is one the chart draws
        row = rows[c.name]
        row["fold_curves"][k] = curve
        row["fold_scored"][k] = scored
        row["eligible_from"] = monitor.eligible_from
        row["fold_seconds"][k] = took
        runs.append([c.name, k])
        row["seconds"] += took
        fold_maps[c.name].append(res.maps)
        bar.update(1)
        bar.set_postfix(candidate=c.name, error=f"{min(e for _, e in curve):.4f}")

    try:
        for c in ladder:  # every candidate: the first fold
            fold_fit(c, folds[0])
        ranked = sorted(ladder, key=lambda c: length_curve(list(rows[c.name]["fold_curves"].values()))[1])
        survivors = [c for c in ladder if c in ranked[:plan.keep]]  # ladder order: simplest first
        for c in ladder:
            rows[c.name]["eliminated"] = c not in survivors
        for k in folds[1:]:
            for c in survivors:
                fold_fit(c, k)
    finally:
        bar.close()
    for row in rows.values():
        ks = list(row["fold_curves"])
        length, mean, errors, still = length_curve([row["fold_curves"][k] for k in ks])
        row.update(mean=mean, length=length, still_improving=still, fold_errors=dict(zip(ks, errors)))
    best_name = min((c.name for c in survivors), key=lambda name: rows[name]["mean"])
    for row in rows.values():  # paired with the best over the folds both ran: the photos' own spread cancels
        diffs = [e - rows[best_name]["fold_errors"][k] for k, e in row["fold_errors"].items()
                 if k in rows[best_name]["fold_errors"]]
        row["se"] = float(torch.tensor(diffs).std()) / math.sqrt(len(diffs)) if len(diffs) > 1 else None
    choice_name, best_name, near = choose(rows, [c.name for c in survivors], sel.tie)
    chosen = rows[choice_name]
    if choice_name == best_name:
        why = (f"{choice_name}: the lowest mean error on the folds' left-out photos ({chosen['mean']:.4f} over "
               f"{len(chosen['fold_errors'])} folds, "
               f"at {chosen['length']} steps)")
    else:
        why = (f"{choice_name}: simpler than the best and within noise of it ({choice_name} {chosen['mean']:.4f}, "
               f"{best_name} {rows[best_name]['mean']:.4f}: within one paired standard error, "
               f"{chosen['se']:.4f}, and within {sel.tie:.0%})")
    if near:
        why += (f"; a near-tie with {', '.join(near)} (within {sel.tie:.0%}): a rerun on other photos of the same "
                "sample may choose it, with maps as good on these photos")
    for row in rows.values():
        row["fold_errors"] = {str(k): v for k, v in row["fold_errors"].items()}
        row["fold_seconds"] = {str(k): v for k, v in row["fold_seconds"].items()}
        row["fold_curves"] = {str(k): [[length, round(err, 6)] for length, err in curve if math.isfinite(err)]
                              for k, curve in row.pop("fold_scored").items()}  # lengths >= eligible_from count
    folds_seconds = time.perf_counter() - start
    # The final fit: the choice as --select NAME fits it (its early stop chooses its length), in the rest of the
    # budget, continuing from the chosen candidate's fold fits (they chose its basin: no multi-start).
    final_cfg = dataclasses.replace(candidate_config(choice_name, cfg),
                                    budget_s=max(1e-3, cfg.budget_s - folds_seconds),
                                    budget_of=f"the final fit's share of the {cfg.budget_s:g} s budget"
                                    if math.isfinite(cfg.budget_s) else "")
    chosen_cfg = candidate_config(choice_name, cfg)
    # Fold fits of windows are of other parts of the sample: they give no start of the whole. A lattice's, upsampled
    # from every k-th texel, started yellow_box's full_calibrated worse than a fresh start (held-out 0.110 against
    # 0.087): only fold fits of the whole sample, downsampled or every texel, start the final fit.
    whole = plan.view == "whole" or (plan.whole and plan.step == 1)
    warm = sel.warm_start and whole and n >= WARM_MIN_IMAGES and continues(chosen_cfg)
    t0 = time.perf_counter()
    result = optimize(spec, images, valid, config=final_cfg,
                      init_maps=warm_start(fold_maps[choice_name], (h, w)) if warm else None)
    if result.stop_reason == "budget":
        result.notes.insert(0, f"the selection's fold fits took {folds_seconds:.1f} s of the {cfg.budget_s:g} s budget; "
                               f"the final fit of {choice_name} had the rest (--select {choice_name} skips the folds)")
    selection = {"mode": "auto", "plan": plan.as_dict(), "folds": folds, "fit_photos": {
                     str(k): fit_photos(n, k, plan.photos) for k in folds},
                 "fold_size": list(s), "fold_view": plan.view, "fold_windows": [list(win) for win in plan.windows],
                 "fold_steps": plan.steps, "every": sel.every, "runs": runs,
                 "candidates": list(rows.values()), "choice": choice_name, "best": best_name, "near_ties": near,
                 "why": why, "final_start": "fold fits" if warm else "fresh",
                 "seconds_folds": folds_seconds, "seconds_final": time.perf_counter() - t0}
    spread = None
    if plan.whole:
        spread = fold_spread(fold_maps[choice_name], (h, w), measured=valid.any(dim=0, keepdim=True))
        selection["uncertainty"] = {name: float(v.mean()) for name, v in spread.items()}
    else:
        selection["uncertainty"] = None
        selection["uncertainty_absent"] = (
            "the folds fitted windows of the sample, another part each, so no texel has two fold fits to compare "
            "(SelectConfig(view='whole') fits the whole sample downsampled in every fold and gives them)")
    result.seconds = time.perf_counter() - start
    return SelectedFit(result, choice_name, selection, spread)
