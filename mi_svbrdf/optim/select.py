"""Per-capture choice of the map model and the recipe: leave-one-photo-out validation on the capture's own photos.

No single recipe of :func:`~mi_svbrdf.optim.fit.optimize` wins on every capture (a fast schedule
with a convergence stop on one, a slow one run to the budget on another), and a capture of a matte
or uniformly glossy sample supports fewer maps than the full SVBRDF: spare maps then fit noise. So
:func:`select_and_fit` lets the photos decide, among the candidates of :data:`LADDER` (named
configurations: overrides of :class:`~mi_svbrdf.optim.fit.OptimizeConfig`, simplest first):

1. **Folds.** ``folds`` photos, spread over the capture, are left out in turn; a candidate is fitted
   on the others at ``size``² for ``steps`` steps, and the left-out photo is re-rendered. Its error is
   the display-space RMSE (gamma 2.2) after one exposure scale fitted on the fold's own photos
   (:func:`held_out_rmse`): a candidate's absolute albedo scale is not held against it.
2. **Successive halving.** Every candidate runs the first fold; the better ``keep`` fraction runs the
   others (a hopeless candidate costs one fold fit, not ``folds``).
3. **The choice.** Of the candidates that ran every fold, the one with the lowest mean error is the
   best; among those whose mean is within one standard error of it, the simplest (first in
   :data:`LADDER`) wins: model no more than the photos support. The standard error is that of a
   candidate's fold errors minus the best's (paired: how well each photo can be predicted at all
   varies far more between photos than between candidates, and cancels in the difference).
4. **The final fit.** The winner is fitted on all photos at full resolution with what is left of
   ``budget_s``.

The chosen candidate's fold fits also give **uncertainty maps** (:func:`fold_spread`): the per-texel
spread over the folds of the normal (degrees), diffuse, roughness and specular. Texels that only one
photo's highlight constrains move when that photo is left out; texels the photos agree on do not.

Selection needs at least three photos (each fold fits two or more) and the texel path (rectified
photos); otherwise the default recipe is fitted and the result's notes say why.

Examples:
    >>> [c.name for c in LADDER][:4]
    ['lambertian', 'uniform', 'uniform_specular', 'full']
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
from tqdm.auto import tqdm

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.fit import OptimizeConfig, OptimizeResult, optimize
from mi_svbrdf.optim.forward import TexelForward
from mi_svbrdf.optim.params import from_maps, resize_variables, to_maps

__all__ = ["LADDER", "SELECT_MODES", "Candidate", "SelectConfig", "candidate_config", "exposure_scale", "fold_photos",
           "fold_spread", "held_out_rmse", "select_and_fit"]


@dataclass(frozen=True)
class Candidate:
    """A named configuration of :func:`optimize`: overrides of :class:`OptimizeConfig`."""

    name: str  #: the name ``--select`` takes
    overrides: dict[str, Any]  #: fields of OptimizeConfig set on top of the user's
    about: str  #: one line for the summary and the guide


#: The candidates, simplest first (the order breaks ties within one standard error). Models: the maps tied or
#: fixed (:data:`~mi_svbrdf.optim.params.MODELS`); recipes: the defaults, a slower learning rate run to the
#: budget, stronger priors, self-calibration of exposures and poses.
LADDER: tuple[Candidate, ...] = (
    Candidate("lambertian", {"model": "lambertian"}, "normals and diffuse; no specular"),
    Candidate("uniform", {"model": "uniform"}, "normals and diffuse per texel, one roughness and specular"),
    Candidate("uniform_specular", {"model": "uniform_specular"},
              "normals, diffuse and roughness per texel, one specular"),
    Candidate("full", {}, "every map per texel, the default recipe (lr 0.1, cosine, convergence stop)"),
    Candidate("full_priors", {"prior_falloff": 2.0, "chroma_weight": 0.1},
              "every map per texel, pulls towards the start falling as 1/N^2 and a 10x grey-specular prior"),
    Candidate("full_slow", {"lr": 0.03, "tol": 0.0},
              "every map per texel, lr 0.03 run to the budget (no convergence stop)"),
    Candidate("full_calibrated", {"calibrate": "on"},
              "every map per texel, with self-calibration of exposures, flash offset and poses"),
)
#: ``--select``: ``auto`` (validate the ladder), ``off`` (the configuration as given), or a candidate's name.
SELECT_MODES = ("auto", "off", *(c.name for c in LADDER))
#: Steps a default fit of a capture typically takes to converge (multi-start included); fold fits shorten the
#: schedule, the starts and the calibration's delay by ``steps`` / this.
TYPICAL_STEPS = 450


@dataclass
class SelectConfig:
    """Settings of the selection (:func:`select_and_fit`)."""

    folds: int = 3  #: photos left out in turn, spread over the capture, >= 2
    size: int = 128  #: texels per side of the fold fits (the photos' own when smaller), >= 8
    steps: int = 300  #: steps of each fold fit (multi-start included; 150 ranked the candidates worse), >= 10
    keep: float = 0.4  #: fraction of the candidates that run the folds after the first (3 of 7), in (0, 1]
    budget_share: float = 0.65  #: of OptimizeConfig.budget_s, what the folds may take (the final fit gets the rest), in (0, 1)

    def __post_init__(self) -> None:
        check_fields([
            ("folds", isinstance(self.folds, int) and self.folds >= 2, "an int >= 2", self.folds),
            ("size", isinstance(self.size, int) and self.size >= 8, "an int >= 8", self.size),
            ("steps", isinstance(self.steps, int) and self.steps >= 10, "an int >= 10", self.steps),
            ("keep", 0 < self.keep <= 1, "a fraction in (0, 1]", self.keep),
            ("budget_share", 0 < self.budget_share < 1, "a fraction in (0, 1)", self.budget_share),
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


def _subset(spec: CaptureSpec, keep: list[int]) -> CaptureSpec:
    return dataclasses.replace(spec, images=tuple(spec.images[k] for k in keep))


def exposure_scale(renders: torch.Tensor, photos: torch.Tensor) -> float:
    """Least-squares scale of ``renders`` onto ``photos`` (linear) over pixels no channel of which is clipped."""
    ok = (photos < 254.5 / 255.0).all(dim=1, keepdim=True).expand_as(photos)
    r, p = renders[ok], photos[ok]
    return float((r * p).sum() / (r * r).sum().clamp_min(1e-12))


def held_out_rmse(maps: torch.Tensor, spec: CaptureSpec, images: torch.Tensor, fit: list[int], held: list[int],
                  distribution: str = "ggx") -> tuple[float, float, torch.Tensor]:
    """How well ``maps`` predict photos they were not fitted to.

    Args:
        maps: ``(1, 10, H, W)`` maps fitted to the photos ``fit``.
        spec: the rectified capture; images: its ``(N, 3, H, W)`` linear photos.
        fit, held: indices of the fitted and of the held-out photos.
        distribution: the BRDF model of ``maps``.

    Returns:
        ``(display RMSE of the held-out photos, the exposure scale, the held-out renders (len(held), 3, H, W))``:
        the renders are scaled by one exposure fitted (least squares, linear, unclipped pixels) on the fit photos,
        then compared gamma-encoded (2.2).
    """
    size = tuple(images.shape[-2:])
    maps = maps.to(images)
    with torch.no_grad():
        r_fit = TexelForward(_subset(spec, fit), size, "auto", distribution)(maps)
        r_held = TexelForward(_subset(spec, held), size, "auto", distribution)(maps)
    k = exposure_scale(r_fit, images[fit])
    r_held = r_held * k
    err = float((gamma_encode(r_held) - gamma_encode(images[held])).pow(2).mean().sqrt())
    return err, k, r_held


def _shortened(cfg: OptimizeConfig, steps: int, budget_s: float) -> OptimizeConfig:
    """``cfg`` for a fold fit of ``steps`` steps: its schedule, starts and calibration delay scaled alike."""
    f = steps / TYPICAL_STEPS
    return dataclasses.replace(
        cfg, iterations=steps, schedule_steps=max(1, int(cfg.schedule_steps * f)),
        start_iterations=max(5, int(cfg.start_iterations * f)), window=max(10, int(cfg.window * f)),
        calibrate_after=int(cfg.calibrate_after * f), budget_s=max(1e-3, budget_s), progress=False, levels=1)


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
    s = (min(sel.size, h), min(sel.size, w))
    small = F.interpolate(images, size=s, mode="area") if s != (h, w) else images
    small_valid = (F.interpolate(valid.float(), size=s, mode="area") > 0.999) if s != (h, w) else valid
    folds = fold_photos(n, sel.folds)
    steps = min(sel.steps, max(10, cfg.iterations))  # a capped fit caps its folds too
    keep = max(2, math.ceil(sel.keep * len(LADDER)))
    total = len(LADDER) + keep * (len(folds) - 1)
    fold_budget = sel.budget_share * cfg.budget_s
    rows = {c.name: {"name": c.name, "about": c.about, "fold_errors": {}, "fold_seconds": {}, "seconds": 0.0,
                     "eliminated": False} for c in LADDER}
    fold_maps: dict[str, list[torch.Tensor]] = {c.name: [] for c in LADDER}
    bar = tqdm(total=total, desc="selection: fold fits", unit="fit", disable=not cfg.progress, leave=False)

    def fold_fit(c: Candidate, k: int) -> None:
        fit = [i for i in range(n) if i != k]
        left = max(1, total - bar.n)
        cap = (fold_budget - (time.perf_counter() - start)) / left if math.isfinite(fold_budget) else math.inf
        t0 = time.perf_counter()
        res = optimize(_subset(spec, fit), small[fit], small_valid[fit],
                       config=_shortened(candidate_config(c.name, cfg), steps, cap))
        err, _, _ = held_out_rmse(res.maps, spec, small, fit, [k], cfg.distribution)
        row = rows[c.name]
        row["fold_errors"][k] = err
        row["fold_seconds"][k] = time.perf_counter() - t0
        row["seconds"] += row["fold_seconds"][k]
        fold_maps[c.name].append(res.maps)
        bar.update(1)
        bar.set_postfix(candidate=c.name, error=f"{err:.4f}")

    try:
        for c in LADDER:  # every candidate: the first fold
            fold_fit(c, folds[0])
        ranked = sorted(LADDER, key=lambda c: rows[c.name]["fold_errors"][folds[0]])
        survivors = [c for c in LADDER if c in ranked[:keep]]  # ladder order: simplest first
        for c in LADDER:
            rows[c.name]["eliminated"] = c not in survivors
        for k in folds[1:]:
            for c in survivors:
                fold_fit(c, k)
    finally:
        bar.close()
    for row in rows.values():
        errs = list(row["fold_errors"].values())
        row["mean"] = sum(errs) / len(errs)
    best = min(survivors, key=lambda c: rows[c.name]["mean"])
    for row in rows.values():  # paired with the best over the folds both ran: the photos' own spread cancels
        diffs = [e - rows[best.name]["fold_errors"][k] for k, e in row["fold_errors"].items()]
        row["se"] = float(torch.tensor(diffs).std()) / math.sqrt(len(diffs)) if len(diffs) > 1 else math.nan
    bound = rows[best.name]["mean"]
    choice = next(c for c in survivors if c is best or rows[c.name]["mean"] <= bound + rows[c.name]["se"])
    why = (f"{choice.name}: the lowest mean held-out error ({rows[best.name]['mean']:.4f} over {len(folds)} folds)"
           if choice is best else
           f"{choice.name}: the simplest candidate within one standard error of the best ({choice.name} "
           f"{rows[choice.name]['mean']:.4f}, {best.name} {rows[best.name]['mean']:.4f}, paired standard error "
           f"{rows[choice.name]['se']:.4f})")
    for row in rows.values():
        row["fold_errors"] = {str(k): v for k, v in row["fold_errors"].items()}
        row["fold_seconds"] = {str(k): v for k, v in row["fold_seconds"].items()}
    folds_seconds = time.perf_counter() - start
    final_cfg = dataclasses.replace(candidate_config(choice.name, cfg),
                                    budget_s=max(1e-3, cfg.budget_s - folds_seconds))
    t0 = time.perf_counter()
    result = optimize(spec, images, valid, config=final_cfg)
    if result.stop_reason == "budget":
        result.notes.insert(0, f"the selection's fold fits took {folds_seconds:.1f} s of the {cfg.budget_s:g} s budget; "
                               f"the final fit of {choice.name} had the rest (--select {choice.name} skips the folds)")
    selection = {"mode": "auto", "folds": folds, "fold_size": list(s), "fold_steps": steps,
                 "candidates": list(rows.values()), "choice": choice.name, "best": best.name, "why": why,
                 "seconds_folds": folds_seconds, "seconds_final": time.perf_counter() - t0}
    spread = fold_spread(fold_maps[choice.name], (h, w), measured=valid.any(dim=0, keepdim=True))
    selection["uncertainty"] = {name: float(v.mean()) for name, v in spread.items()}
    result.seconds = time.perf_counter() - start
    return SelectedFit(result, choice.name, selection, spread)
