"""Per-capture choice of the map model, the recipe and the fit's length: cross-validation on the capture's own photos.

No single recipe of :func:`~mi_svbrdf.optim.fit.optimize` wins on every capture (the field's plain per-pixel
Adam on one, a slow schedule run long on another, stronger priors on a third), the right length of a fit
differs per capture (one keeps improving for thousands of steps, another fits its photos' noise after a few
hundred), and a capture of a matte or uniformly glossy sample supports fewer maps than the full SVBRDF. So
:func:`select_and_fit` lets the photos decide, among the candidates of :data:`LADDER` (named configurations:
overrides of :class:`~mi_svbrdf.optim.fit.OptimizeConfig`, simplest first):

1. **Folds.** ``folds`` photos, spread over the capture, are left out in turn; a candidate is fitted on the
   others at ``size``² for ``steps`` steps (a scheduled recipe's schedule, starts and calibration delay shortened
   alike, so it anneals within them) and the left-out photo is scored every ``every`` steps along the way
   (:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`: display RMSE after the left-out photo's own exposure is
   fitted, robust to texels that render above the clip: a shot's exposure error, which no recipe can predict, is
   not held against the recipe whose brightness drifts the other way). Fold fits are capped by steps, not by the clock, so a rerun
   makes the same fits; when the time for the folds runs out, the later folds are skipped instead.
2. **The length.** A candidate's folds give its held-out error against the fit's length (under a decaying
   schedule, the lengths after it has decayed); the lowest mean over its folds, at one length, is its score:
   each recipe is judged at the length that suits it, the plain recipe's early stop included.
3. **Successive halving.** Every candidate runs the first fold; the better ``keep`` fraction runs the
   others (a hopeless candidate costs one fold fit, not ``folds``).
4. **The choice.** Of the candidates that ran every fold, the one with the lowest score is the best; a
   simpler one (earlier in :data:`LADDER`) is taken instead only when it is within noise of it (one standard
   error of the paired fold differences) **and** within ``tie`` (2 %) of its score: a simpler model that is
   worse by more than that is not "as good", however few folds measured it. Candidates within ``tie`` of the
   choice are reported as near-ties.
5. **The final fit.** The choice is fitted on all photos at full resolution as ``--select NAME`` fits it (its
   early stop choosing the length on a left-out photo), with what is left of ``budget_s``.

The chosen candidate's fold fits also give **uncertainty maps** (:func:`fold_spread`): the per-texel
spread over the folds of the normal (degrees), diffuse, roughness and specular. Texels that only one
photo's highlight constrains move when that photo is left out; texels the photos agree on do not.

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
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.fit import METHODS, OptimizeConfig, OptimizeResult, optimize
from mi_svbrdf.optim.scoring import EXPOSURES, HeldOutScorer, exposure_scale, held_out_rmse
from mi_svbrdf.optim.loop import Monitor
from mi_svbrdf.optim.params import from_maps, resize_variables, to_maps

__all__ = ["LADDER", "SELECT_MODES", "Candidate", "SelectConfig", "candidate_config", "choose", "exposure_scale",
           "fold_photos", "fold_spread", "held_out_rmse", "length_curve", "select_and_fit"]


@dataclass(frozen=True)
class Candidate:
    """A named configuration of :func:`optimize`: overrides of :class:`OptimizeConfig`."""

    name: str  #: the name ``--select`` takes
    overrides: dict[str, Any]  #: fields of OptimizeConfig set on top of the user's
    about: str  #: one line for the summary and the guide


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


def _shortened(cfg: OptimizeConfig, steps: int, budget_s: float) -> OptimizeConfig:
    """``cfg`` for a fold fit of ``steps`` steps: its schedule, starts and calibration delay scaled alike."""
    f = min(1.0, steps / TYPICAL_STEPS)
    return dataclasses.replace(
        cfg, iterations=steps, schedule_steps=max(1, int(cfg.schedule_steps * f)),
        start_iterations=max(5, int(cfg.start_iterations * f)), window=max(10, int(cfg.window * f)),
        calibrate_after=int(cfg.calibrate_after * f), budget_s=max(1e-3, budget_s), progress=False, levels=1,
        early_stop="off")


@dataclass
class SelectConfig:
    """Settings of the selection (:func:`select_and_fit`)."""

    folds: int = 3  #: photos left out in turn, spread over the capture, >= 2
    size: int = 128  #: texels per side of the fold fits (at most half the photos', at least 32), >= 8
    steps: int = 300  #: steps of a fold fit (a recipe's schedule shortened to fit them; 150 ranked worse), >= 10
    every: int = 10  #: steps between two scores of a fold's left-out photo (the lengths compared), >= 1
    keep: float = 0.4  #: fraction of the candidates that run the folds after the first (3 of 8), in (0, 1]
    budget_share: float = 0.65  #: of OptimizeConfig.budget_s, what the folds may take (the final fit: the rest), in (0, 1)
    tie: float = 0.02  #: a simpler candidate is chosen within this fraction of the best's score (and one SE), >= 0
    exposure: str = "held"  #: the left-out photo's exposure: "held" its own, "fit" from the fold's photos (scoring)

    def __post_init__(self) -> None:
        check_fields([
            ("folds", isinstance(self.folds, int) and self.folds >= 2, "an int >= 2", self.folds),
            ("size", isinstance(self.size, int) and self.size >= 8, "an int >= 8", self.size),
            ("steps", isinstance(self.steps, int) and self.steps >= 10, "an int >= 10", self.steps),
            ("every", isinstance(self.every, int) and self.every >= 1, "an int >= 1", self.every),
            ("keep", 0 < self.keep <= 1, "a fraction in (0, 1]", self.keep),
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
                   settings: SelectConfig | None = None) -> SelectedFit:
    """Fit the maps with the candidate of :data:`LADDER` that the capture's own photos support best.

    Args:
        spec: the capture; images: ``(N, 3, H, W)`` linear photos; valid: ``(N, 1, H, W)`` unsaturated pixels.
        config: the user's settings (budget, loss, device, ...); candidates override some of them.
        select: ``"auto"`` (module docstring), ``"off"`` (``config`` as given) or a candidate's name (forced).
        settings: the selection's own settings.

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
    s = (min(sel.size, max(32, h // 2), h), min(sel.size, max(32, w // 2), w))  # folds rank; the final fit is sharp
    small = F.interpolate(images, size=s, mode="area") if s != (h, w) else images
    small_valid = (F.interpolate(valid.float(), size=s, mode="area") > 0.999) if s != (h, w) else valid
    folds = fold_photos(n, sel.folds)
    keep = max(2, math.ceil(sel.keep * len(LADDER)))
    total = len(LADDER) + keep * (len(folds) - 1)
    fold_budget = sel.budget_share * cfg.budget_s
    steps = min(sel.steps, max(10, cfg.iterations))  # a capped fit caps its folds too
    rows = {c.name: {"name": c.name, "about": c.about, "fold_errors": {}, "fold_seconds": {}, "fold_curves": {},
                     "fold_scored": {}, "seconds": 0.0, "eliminated": False} for c in LADDER}
    fold_maps: dict[str, list[torch.Tensor]] = {c.name: [] for c in LADDER}
    skipped: list[int] = []  # folds the time for the folds could not afford
    done = 0  # fold fits made (a disabled bar does not count)
    runs: list[list[Any]] = []  # [candidate, fold] of each fold fit, in the order they ran
    bar = tqdm(total=total, desc="selection: fold fits", unit="fit", disable=not cfg.progress, leave=False)

    def fold_fit(c: Candidate, k: int) -> None:
        nonlocal done
        fit = [i for i in range(n) if i != k]
        # Capped by steps, not by the clock (a fit cut by a clock would differ from run to run): the whole
        # budget is its only time limit; a slow machine skips later folds instead (below).
        seconds = cfg.budget_s - (time.perf_counter() - start)
        monitor = Monitor(HeldOutScorer(spec, small, fit, [k], cfg.distribution, exposure=sel.exposure), every=sel.every,
                          patience=10**9)  # the whole fold fit is scored: its length is chosen afterwards
        fold_cfg = _shortened(candidate_config(c.name, cfg), steps, seconds)
        t0 = time.perf_counter()
        res = optimize(spec.subset(fit), small[fit], small_valid[fit], config=fold_cfg, held_out=monitor)
        took = time.perf_counter() - t0
        # The lengths a fit may end at: under a decaying schedule, once it has decayed (as the early stop).
        curve = [(length, err) for _, length, err in monitor.curve if length >= monitor.eligible_from]
        if not curve:  # a fit too short to be scored on its way: its end
            curve = [(res.steps, monitor.score(res.maps))]
        row = rows[c.name]
        row["fold_curves"][k] = curve
        row["fold_scored"][k] = [(length, err) for _, length, err in monitor.curve]  # the whole run, for the charts
        row["eligible_from"] = monitor.eligible_from
        row["fold_seconds"][k] = took
        runs.append([c.name, k])
        row["seconds"] += took
        fold_maps[c.name].append(res.maps)
        done += 1
        bar.update(1)
        bar.set_postfix(candidate=c.name, error=f"{min(e for _, e in curve):.4f}")

    try:
        for c in LADDER:  # every candidate: the first fold
            fold_fit(c, folds[0])
        ranked = sorted(LADDER, key=lambda c: length_curve(list(rows[c.name]["fold_curves"].values()))[1])
        survivors = [c for c in LADDER if c in ranked[:keep]]  # ladder order: simplest first
        for c in LADDER:
            rows[c.name]["eliminated"] = c not in survivors
        for k in folds[1:]:
            spent = time.perf_counter() - start
            pace = spent / max(done, 1)  # seconds of a fold fit so far
            if math.isfinite(fold_budget) and spent + len(survivors) * pace > fold_budget:
                skipped.append(k)  # the final fit keeps its share of the budget
                continue
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
        why = (f"{choice_name}: the lowest mean held-out error ({chosen['mean']:.4f} over "
               f"{len(chosen['fold_errors'])} fold(s), "
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
    # The final fit: the choice as --select NAME fits it (its early stop chooses its length), in the rest of the budget.
    final_cfg = dataclasses.replace(candidate_config(choice_name, cfg),
                                    budget_s=max(1e-3, cfg.budget_s - folds_seconds))
    t0 = time.perf_counter()
    result = optimize(spec, images, valid, config=final_cfg)
    if result.stop_reason == "budget":
        result.notes.insert(0, f"the selection's fold fits took {folds_seconds:.1f} s of the {cfg.budget_s:g} s budget; "
                               f"the final fit of {choice_name} had the rest (--select {choice_name} skips the folds)")
    selection = {"mode": "auto", "folds": [k for k in folds if k not in skipped], "folds_skipped": skipped,
                 "fold_size": list(s), "fold_steps": steps, "every": sel.every, "runs": runs,
                 "candidates": list(rows.values()), "choice": choice_name, "best": best_name, "near_ties": near,
                 "why": why,
                 "seconds_folds": folds_seconds, "seconds_final": time.perf_counter() - t0}
    spread = None
    if len(fold_maps[choice_name]) >= 2:  # the folds were all skipped but the first: no spread to measure
        spread = fold_spread(fold_maps[choice_name], (h, w), measured=valid.any(dim=0, keepdim=True))
        selection["uncertainty"] = {name: float(v.mean()) for name, v in spread.items()}
    result.seconds = time.perf_counter() - start
    return SelectedFit(result, choice_name, selection, spread)
