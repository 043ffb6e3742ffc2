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

Priors (where data is scarce; :class:`~mi_svbrdf.optim.loop.Prior`, PyTorch terms on the
variables added outside the fused kernel): with few photos the re-rendering loss has many
minima (one photo fits a bumpy normal map and any roughness), so refinement from a net ended
worse than the net and the optimiser worse than the trivial baseline at N <= 3. Three terms:

* a pull towards the start, weight ``prior_weight / N**prior_falloff`` (``init_maps`` given,
  e.g. the net's) or ``start_prior_weight / N**prior_falloff`` (the default start, anchored at
  the starts' mean roughness: the trivial baseline's maps), on the squared distance in the
  space of the variables, per map ``prior_maps`` (diffuse 0.1: one photo already measures it).
  The log-L1 data term pulls every texel with a force of order one whatever its residual, so
  the pull balances it at a distance ~ 4.5 / weight: 100 at N = 1 keeps the normals' slopes
  within ~0.05; at N = 10 the weight is 1 (free);
* a grey-specular (chroma) prior ``chroma_weight``, stronger at texels saturated in the photos
  (``clip_chroma``), which hold no colour information (and an 8-bit channel at the top code
  is open above, :func:`~mi_svbrdf.optim.loop.target_bounds`);
* ``smooth_weight``: an extra total variation of roughness and specular (0 by default).

And a held-out photo (``validate_photo``, 2 <= N <= ``validate_max_images``, :func:`_validated`):
the first N - 1 photos are fitted, the last one chooses how far to move from the start
(``start + t (fit - start)``, ``t`` in ``shrink_grid``; 0 keeps the start: the net's maps when
refining, the trivial baseline's otherwise), then all N photos are fitted and moved that far.
So a fit that explains the photos but not a new light is not returned; it costs a second fit.

What the priors change on held-out materials is asserted in ``tests/test_priors.py``.

Early stop (``early_stop``, N >= ``early_stop_min_images`` rectified photos, :func:`_early_stopped`): how
long to fit differs per capture (one keeps improving for thousands of steps, another fits its photos' noise
after a few hundred), and neither a plateau of the training loss nor the budget looks at a photo the fit did
not see. So a first fit leaves one photo out (:func:`stop_photos`), scores it every ``stop_every`` steps
(:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`: display RMSE after one exposure fitted on the fitted photos)
and stops when it has not improved for ``stop_patience`` steps (or ``stop_patience_fraction`` of the best
length); then all photos are fitted to the length at its minimum, or, when the error was still falling,
the first fit's maps go on with every photo for the rest of the budget. The curve is
:attr:`OptimizeResult.held_out` (``summary.json``, ``loss.png``).

Output model (thesis ch. 6.1.1): ``distribution`` (``"ggx"``, the thesis's, or ``"beckmann"``) is the
BRDF model the fitted maps are rendered with; the photos keep whatever model made them (a
Beckmann fit to photos of a GGX material is a cross-model fit through the re-rendering loss).
The result records it (:attr:`OptimizeResult.distribution`), and so does the material folder
written from it (:func:`mi_svbrdf.io.material_io.write_material`). Held-out figures of GGX -> Beckmann
vs GGX -> GGX: :mod:`mi_svbrdf.eval.studies.output_model`.

Examples:
    >>> import torch
    >>> from mi_svbrdf.data import procedural
    >>> from mi_svbrdf.data.photo_setups import sample_captures, capture_config, render_captures
    >>> from mi_svbrdf.io.calibrated_photos import capture_from_simulator
    >>> gt = procedural.generate("tiles", 1, 32)[None]
    >>> cap = sample_captures(1, 4, capture_config(ambient=False, noise=False), torch.Generator().manual_seed(0))
    >>> spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="linear_exr")
    >>> res = optimize(spec, images, config=OptimizeConfig(iterations=20, roughness_starts=(0.5,), progress=False))
    >>> tuple(res.maps.shape), res.steps
    ((1, 10, 32, 32), 20)
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.core.device import RELEASE_TEXELS, release_memory, resolve_device
from mi_svbrdf.core.maps import check_maps, make_maps
from mi_svbrdf.io.calibrated_photos import CaptureSpec
from mi_svbrdf.optim.forward import ForwardModel, TexelForward, forward_for
from mi_svbrdf.optim.mitsuba_forward import MitsubaForward
from mi_svbrdf.optim.scoring import HeldOutScorer
from mi_svbrdf.optim.loop import LOG_EPS, LoopConfig, Monitor, Prior, residual, run, target_bounds
from mi_svbrdf.optim.params import MODELS, from_maps, resize_variables, tie_variables, to_maps
from mi_svbrdf.optim.selfcal import CORRECTIONS, SelfCalibration
from mi_svbrdf.plugins.model import DISTRIBUTIONS
from mi_svbrdf.variant import scene_variant

__all__ = ["METHODS", "OptimizeConfig", "OptimizeResult", "initial_maps", "method_config", "optimize", "stop_photos",
           "stops_early"]

#: Default pull towards ``init_maps`` at N = 1 (measured: module docstring "Priors").
PRIOR_WEIGHT = 100.0
#: Default pull towards the default start at N = 1.
START_PRIOR_WEIGHT = 100.0
#: Default fall-off exponent of the pulls: weight / N**PRIOR_FALLOFF.
PRIOR_FALLOFF = 5.0  # the pulls fade as 1/N^5: decisive at N = 1-2 (100, 3.1), 0.4 at N = 3, ~0.01 at N = 6
#: Self-calibration modes (OptimizeConfig.calibrate).
CALIBRATE_MODES = ("auto", "on", "off")
#: Default starts' diffuse albedo (OptimizeConfig.start, initial_maps).
STARTS = ("frontal", "lstsq")
#: Early-stop modes (OptimizeConfig.early_stop).
EARLY_STOP_MODES = ("auto", "off")
#: Default grey-specular prior weight.
CHROMA_WEIGHT = 0.01
#: Default extra chroma factor at texels saturated in every photo.
CLIP_CHROMA = 4.0


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
    budget_of: str = ""  #: what budget_s is, for the note of a fit it stopped (e.g. a share of a larger budget; "": its own)
    tol: float = 1e-2  #: convergence: the last window improved by < tol x the improvement since the first window (0: never)
    window: int = 50  #: convergence window, steps (at least)
    window_fraction: float = 0.0  #: the window grows to this fraction of the fit's steps (0: fixed), in [0, 0.5]
    levels: int = 1  #: coarse-to-fine levels (1: full resolution only; 2: half then full; ...)
    fewer_texels: str = ""  #: how to fit fewer texels, for the note of a fit stopped by its budget ("": generic advice)
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
    # Priors where data is scarce (module docstring "Priors"): weights fall with the photo count N.
    prior_weight: float = PRIOR_WEIGHT  #: pull towards ``init_maps`` (e.g. the net's: refinement) at N = 1, >= 0
    start_prior_weight: float = START_PRIOR_WEIGHT  #: pull towards the default start (no ``init_maps``) at N = 1, >= 0
    prior_falloff: float = PRIOR_FALLOFF  #: the pulls' weights are weight / N**prior_falloff, >= 0
    prior_maps: tuple[float, float, float, float] = (10.0, 0.1, 1.0, 1.0)  #: per-map factors of the pull: normal, diffuse, roughness, specular
    chroma_weight: float = CHROMA_WEIGHT  #: grey-specular prior (variance of the specular logits over RGB), >= 0
    clip_chroma: float = CLIP_CHROMA  #: chroma weight x (1 + clip_chroma x fraction of photos saturated at the texel), >= 0
    smooth_weight: float = 0.0  #: extra total variation of roughness and specular, >= 0
    validate_photo: bool = True  #: 2 <= N <= validate_max_images: choose the shrinkage towards the start on a held-out photo
    validate_max_images: int = 3  #: largest N validated (each validated fit costs two fits), >= 2
    shrink_grid: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)  #: shrinkages tried (0: the start, 1: the fit)
    validated_pull: float = 1.0  #: validated fits: factor on the pulls towards the start (1: as unvalidated; see _validated), >= 0
    device: str | None = None  #: torch device of the fit (cpu, cuda, cuda:N); None: the images' device
    distribution: str = "ggx"  #: output BRDF model of the fit, "ggx" (thesis) or "beckmann"; the photos keep theirs
    model: str = "full"  #: map model (optim.params.MODELS: lambertian, uniform, uniform_specular, full): maps tied or fixed
    start: str = "frontal"  #: default start's diffuse: "frontal" (the most frontal photo) or "lstsq" (all photos, initial_maps)
    # Self-calibration (mi_svbrdf.optim.selfcal): gains, flash offset and poses estimated with the maps.
    calibrate: str = "off"  #: "auto" (rectified captures of >= calibrate_min_images photos), "on" (rectified only) or "off"
    calibrate_min_images: int = 4  #: smallest photo count "auto" calibrates, >= 1
    calibrate_what: tuple[str, ...] = CORRECTIONS  #: corrections estimated: "gain", "flash", "pose"
    trust_exposure_stops: float = 1.0  #: prior width of a photo's exposure (stops), > 0
    trust_white_balance: float = 0.1  #: prior width of a channel's gain relative to its photo's exposure, > 0
    trust_flash: float = 0.1  #: prior width of the flash's offset from the lens, fraction of the camera distance, > 0
    trust_pose: float = 0.03  #: prior width of a camera or light correction, fraction of its distance, > 0
    calibrate_prior: float = 0.01  #: weight of the calibration priors (sum of squared widths / N), >= 0
    calibrate_lr: float = 0.02  #: Adam lr of the calibration (prior widths per step; follows the schedule), > 0
    calibrate_texels: int = 4096  #: texels per photo rendered for each calibration step, >= 1
    calibrate_after: int = 100  #: full-resolution steps of the maps alone before the calibration starts, >= 0
    # The early stop (module docstring "Early stop"): photos left out of a first fit choose how long to fit.
    early_stop: str = "auto"  #: "auto" (rectified captures of >= early_stop_min_images photos) or "off"
    early_stop_min_images: int = 4  #: smallest N stopped early (one photo out leaves >= 3 fitted), >= 3
    stop_every: int = 10  #: steps between two scores of the left-out photos, >= 1
    stop_patience: int = 150  #: steps without a better score that end the first fit, at least, >= 1
    stop_patience_fraction: float = 0.5  #: the patience grows to this fraction of the best length, >= 0
    stop_share: float = 0.5  #: of budget_s and of iterations, what the first fit may take, in (0, 1)

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
            ("window_fraction", 0 <= self.window_fraction <= 0.5, "a fraction in [0, 0.5]", self.window_fraction),
            ("roughness_starts", bool(starts) and all(0 < r < 1 for r in starts), "values in (0, 1)",
             self.roughness_starts),
            ("start_select", self.start_select in ("texel", "global"), "'texel' or 'global'", self.start_select),
            *((name, getattr(self, name) >= 0, "a value >= 0", getattr(self, name))
              for name in ("prior_weight", "start_prior_weight", "prior_falloff", "chroma_weight", "clip_chroma",
                           "smooth_weight", "validated_pull")),
            ("validate_max_images", isinstance(self.validate_max_images, int) and self.validate_max_images >= 2,
             "an int >= 2", self.validate_max_images),
            ("shrink_grid", bool(tuple(self.shrink_grid)) and all(0 <= t <= 1 for t in self.shrink_grid),
             "a non-empty tuple of values in [0, 1]", self.shrink_grid),
            ("prior_maps", len(tuple(self.prior_maps)) == 4 and all(v >= 0 for v in self.prior_maps),
             "four factors >= 0 (normal, diffuse, roughness, specular)", self.prior_maps),
            ("distribution", self.distribution in DISTRIBUTIONS, f"one of {DISTRIBUTIONS}", self.distribution),
            ("model", self.model in MODELS, f"one of {MODELS}", self.model),
            ("calibrate", self.calibrate in CALIBRATE_MODES, f"one of {CALIBRATE_MODES}", self.calibrate),
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ("calibrate_min_images", "calibrate_texels")),
            ("calibrate_what", set(self.calibrate_what) <= set(CORRECTIONS), f"a subset of {CORRECTIONS}",
             self.calibrate_what),
            *((name, getattr(self, name) > 0, "a value > 0", getattr(self, name))
              for name in ("trust_exposure_stops", "trust_white_balance", "trust_flash", "trust_pose",
                           "calibrate_lr")),
            ("calibrate_prior", self.calibrate_prior >= 0, "a weight >= 0", self.calibrate_prior),
            ("calibrate_after", isinstance(self.calibrate_after, int) and self.calibrate_after >= 0, "an int >= 0",
             self.calibrate_after),
            ("start", self.start in STARTS, f"one of {STARTS}", self.start),
            ("early_stop", self.early_stop in EARLY_STOP_MODES, f"one of {EARLY_STOP_MODES}", self.early_stop),
            ("early_stop_min_images", isinstance(self.early_stop_min_images, int) and self.early_stop_min_images >= 3,
             "an int >= 3", self.early_stop_min_images),
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ("stop_every", "stop_patience")),
            ("stop_patience_fraction", self.stop_patience_fraction >= 0, "a fraction >= 0",
             self.stop_patience_fraction),
            ("stop_share", 0 < self.stop_share < 1, "a fraction in (0, 1)", self.stop_share),
        ], owner="OptimizeConfig")
        self.calibrate_what = tuple(self.calibrate_what)
        self.roughness_starts = starts
        self.prior_maps = tuple(float(v) for v in self.prior_maps)  # type: ignore[assignment]
        self.shrink_grid = tuple(float(v) for v in self.shrink_grid)
        if self.device is not None:
            self.device = str(resolve_device(self.device))

    def pull_weight(self, n_images: int, given_init: bool) -> float:
        """The weight of the pull towards the start for ``n_images`` photos (module docstring "Priors")."""
        base = self.prior_weight if given_init else self.start_prior_weight
        return base / max(n_images, 1) ** self.prior_falloff

    def prior(self, n_images: int, given_init: bool, anchor: torch.Tensor | None,
              valid_hi: torch.Tensor | None = None) -> Prior:
        """The :class:`~mi_svbrdf.optim.loop.Prior` of a fit on ``n_images`` photos.

        Args:
            n_images: N.
            given_init: whether the start is ``init_maps`` (``prior_weight``) or the default one
                (``start_prior_weight``).
            anchor: ``(1, 9, H, W)`` variables of the start.
            valid_hi: ``(N, 3, H, W)`` upper bounds of the photos (``inf`` where saturated), for the
                clipping-aware chroma weight; None: uniform.
        """
        texel = None
        if valid_hi is not None and self.clip_chroma > 0:
            clipped = torch.isinf(valid_hi).any(dim=1, keepdim=True).float().mean(dim=0, keepdim=True)
            texel = 1.0 + self.clip_chroma * clipped
        return Prior(anchor=anchor, anchor_weight=self.pull_weight(n_images, given_init),
                     map_weights=self.prior_maps, chroma_weight=self.chroma_weight, chroma_texel=texel,
                     smooth_weight=self.smooth_weight)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OptimizeConfig:
        """Build from a dict; unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)


#: Named fits (:func:`method_config`): the project's default, and the field's plain per-pixel baseline
#: (MaterialGAN's "pixel" optimisation): Adam at a constant lr on the same GGX maps, an L2 loss on
#: gamma-encoded photos, one start, no prior, no smoothness, no validation, no convergence stop (it
#: runs until its budget or ``iterations``), no calibration.
METHODS: dict[str, dict[str, Any]] = {
    "default": {},
    "pixel": {"loss": "l2_display", "tv_weight": 0.0, "lr": 0.03, "schedule": "constant", "tol": 0.0,
              "roughness_starts": (0.5,), "prior_weight": 0.0, "start_prior_weight": 0.0, "chroma_weight": 0.0,
              "clip_chroma": 0.0, "smooth_weight": 0.0, "validate_photo": False, "calibrate": "off", "levels": 1},
}


def method_config(method: str = "default", **fields: Any) -> OptimizeConfig:
    """The :class:`OptimizeConfig` of a named fit (:data:`METHODS`), with ``fields`` on top.

    Examples:
        >>> cfg = method_config("pixel", budget_s=60.0)
        >>> cfg.loss, cfg.tv_weight, cfg.tol, cfg.budget_s
        ('l2_display', 0.0, 0.0, 60.0)
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {sorted(METHODS)}, got {method!r}")
    return OptimizeConfig(**{**METHODS[method], **fields})


#: The resolution ladder's first rung: a fit of larger photos starts at this side or below (the size the
#: defaults are tuned and judged at), then doubles up to the photos' own (:func:`ladder_levels`).
LADDER_BASE = 256


def ladder_levels(height: int, width: int, base: int = LADDER_BASE) -> int:
    """The coarse-to-fine levels (``OptimizeConfig.levels``) of a fit of ``height x width`` photos whose
    coarsest level's long side is at most ``base``: each level halves the one above it.

    Examples:
        >>> ladder_levels(256, 256), ladder_levels(512, 512), ladder_levels(1024, 1024), ladder_levels(600, 800)
        (1, 2, 3, 3)
    """
    if not (isinstance(base, int) and base >= 1):
        raise ValueError(f"base: expected an int >= 1, got {base!r}")
    side = max(int(height), int(width))
    if side < 1:
        raise ValueError(f"height, width: expected sizes >= 1, got {height} x {width}")
    return 1 + max(0, math.ceil(math.log2(side / base) - 1e-9))


#: The default time budget of a fit (``optimize`` and ``scan``) of photos of :data:`LADDER_BASE` px or less, seconds;
#: it grows with the photos' side up to :data:`MAX_DEFAULT_BUDGET_S` (:func:`default_budget`).
DEFAULT_BUDGET_S = 60.0
MAX_DEFAULT_BUDGET_S = 240.0


def default_budget(height: int, width: int) -> float:
    """The default time budget of a fit of ``height x width`` photos: :data:`DEFAULT_BUDGET_S` up to
    :data:`LADDER_BASE` px, then in proportion to the long side (each rung of the ladder doubles the side and
    quadruples a step's texels, and needs a fraction of the steps below it), at most :data:`MAX_DEFAULT_BUDGET_S`.

    Examples:
        >>> default_budget(256, 256), default_budget(512, 512), default_budget(1024, 768), default_budget(2048, 2048)
        (60.0, 120.0, 240.0, 240.0)
    """
    side = max(int(height), int(width))
    return min(MAX_DEFAULT_BUDGET_S, DEFAULT_BUDGET_S * max(1.0, side / LADDER_BASE))


def ladder_sizes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """The ``(H, W)`` of each level of a ``levels``-level fit, coarsest first (as :func:`optimize` runs them).

    Examples:
        >>> ladder_sizes(1024, 1024, 3)
        [(256, 256), (512, 512), (1024, 1024)]
    """
    return [(max(height >> k, 1), max(width >> k, 1)) for k in reversed(range(levels))]


@dataclass
class OptimizeResult:
    """What :func:`optimize` returns."""

    maps: torch.Tensor  #: (1, 10, H, W) recovered maps, finite
    history: list[tuple[float, int, float]] = field(default_factory=list)  #: (seconds, step, loss) per good step
    recoveries: int = 0  #: NaN/Inf or rising-loss recoveries (each restored a good state and halved the lr)
    stop_reason: str = ""  #: "converged", "held-out" (the early stop's length), "budget", "iterations" or "recoveries"
    steps: int = 0  #: steps over all levels
    seconds: float = 0.0  #: wall time of the fit
    shrink: float | None = None  #: validated fits: the chosen shrinkage (0: the start kept, 1: the fit); None: not validated
    validation: dict[float, float] = field(default_factory=dict)  #: validated fits: held-out photo error per shrinkage
    distribution: str = "ggx"  #: the BRDF model of ``maps`` (OptimizeConfig.distribution)
    calibration: dict[str, Any] | None = None  #: self-calibration estimates (SelfCalibration.estimates); None: off
    calibrated_spec: CaptureSpec | None = None  #: the capture with the estimated calibration; None: off
    notes: list[str] = field(default_factory=list)  #: what the user should know (e.g. why a fit stopped early)
    phases: list[tuple[str, int]] = field(default_factory=list)  #: (name, index of its first entry in ``history``) of each fit run
    held_out: dict[str, Any] | None = None  #: the early stop: photos left out, their error curve, the length chosen; None: off
    #: each coarse-to-fine level run, in order: {"phase": its name, "size": [H, W], "steps": n, "seconds": t}
    levels: list[dict[str, Any]] = field(default_factory=list)

    @property
    def final_loss(self) -> float:
        """Loss of the last recorded step (NaN if none)."""
        return self.history[-1][2] if self.history else math.nan


def frontality(light: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
    """How head-on a photo is: ``light.z / |light| + view.z / |view|`` of positions ``(..., 3)``: ``(...)``.

    2 for a flash and a camera straight above the sample; the initialisation here and the trivial
    baseline (:mod:`mi_svbrdf.eval.baseline`) start from the photo that maximises it.
    """
    return light[..., 2] / light.norm(dim=-1) + view[..., 2] / view.norm(dim=-1)


def initial_maps(spec: CaptureSpec, images: torch.Tensor, roughness: float = 0.5, start: str = "frontal") -> torch.Tensor:
    """The default start ``(1, 10, H, W)`` with a constant ``roughness`` (see the module docstring).

    ``start``: the diffuse albedo of ``"frontal"``, the most frontal rectified photo over its flat-normal
    irradiance; of ``"lstsq"``, the per-texel least-squares Lambertian albedo over every rectified photo, clipped
    pixels left out and highlights down-weighted (a photo whose ratio to its irradiance lies above 1.5 x the
    texel's median ratio over the photos weighs ``(1.5 median / ratio)^2``).
    """
    if start not in STARTS:
        raise ValueError(f"start: expected one of {STARTS}, got {start!r}")
    n, _, h, w = images.shape
    dev = images.device
    rect = [k for k, im in enumerate(spec.images) if im.rectified]
    diffuse = torch.full((1, 3, h, w), 0.5, device=dev)
    if rect and start == "lstsq":
        irr = 0.96 * TexelForward(spec.subset(rect), (h, w), "torch").irradiance().to(dev)  # (R, 3, H, W)
        photos = images[rect]
        ratio = photos / irr.clamp_min(1e-6)
        median = ratio.median(dim=0, keepdim=True).values.clamp_min(1e-6)
        weight = torch.where(ratio > 1.5 * median, (1.5 * median / ratio.clamp_min(1e-6)) ** 2, torch.ones_like(ratio))
        weight = weight * (photos < 254.5 / 255.0).all(dim=1, keepdim=True)  # clipped pixels say nothing
        den = (weight * irr * irr).sum(dim=0, keepdim=True)
        fallback = median.clamp(0.01, 0.99)  # a texel clipped in every photo
        diffuse = torch.where(den > 1e-12, (weight * irr * photos).sum(dim=0, keepdim=True) / den.clamp_min(1e-12),
                              fallback).clamp(0.01, 0.99)
    elif rect:
        lights = torch.tensor([spec.images[k].light.position for k in rect])
        views = torch.tensor([spec.images[k].camera.position for k in rect])
        k = rect[int(frontality(lights, views).argmax())]
        irr = TexelForward(spec.subset([k]), (h, w), "torch").irradiance()[0].to(dev)
        diffuse = (images[k] / (0.96 * irr).clamp_min(1e-6)).clamp(0.01, 0.99)[None]
    normal = torch.zeros(1, 3, h, w, device=dev)
    normal[:, 2] = 1.0
    return make_maps(normal, diffuse, torch.full((1, 1, h, w), roughness, device=dev),
                     torch.full((1, 3, h, w), 0.04, device=dev))


def optimize(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor | None = None, *,
             config: OptimizeConfig | None = None, init_maps: torch.Tensor | None = None,
             forward: ForwardModel | None = None,
             grad_hook: Callable[[int, torch.Tensor], None] | None = None,
             held_out: Monitor | None = None) -> OptimizeResult:
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
        held_out: an early stop on photos the fit does not see (a :class:`~mi_svbrdf.optim.loop.Monitor`
            scoring, e.g., photos left out of ``spec``): the fit ends at its patience and returns the maps at its
            best score, and the curve is :attr:`OptimizeResult.held_out`. None: the config's own early stop
            (``early_stop``) chooses.

    Returns:
        :class:`OptimizeResult` with the maps ``(1, 10, H, W)`` and the loss history; ``notes`` says
        when the fit stopped before it converged (its budget, step cap or recoveries) and what to do.
    """
    cfg = config or OptimizeConfig()
    # Mitsuba's scenes are bound to a variant: a fit through them enters its device's variant once, here,
    # not at every step. The texel path's kernels follow the tensors and need none.
    scenes = forward is not None and isinstance(forward, MitsubaForward) or forward is None and (
        cfg.path == "mitsuba" or cfg.path == "auto" and not all(im.rectified for im in spec.images))
    device = cfg.device or (images.device if isinstance(images, torch.Tensor) else "cpu")
    with scene_variant(device) if scenes else contextlib.nullcontext():
        result = _fit(spec, images, valid, config=cfg, init_maps=init_maps, forward=forward, grad_hook=grad_hook,
                      monitor=held_out)
    result.notes += stop_notes(result, cfg)
    return result


def _fit(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor | None = None, *,
         config: OptimizeConfig | None = None, init_maps: torch.Tensor | None = None,
         forward: ForwardModel | None = None,
         grad_hook: Callable[[int, torch.Tensor], None] | None = None, label: str = "",
         monitor: Monitor | None = None, photos: list[int] | None = None) -> OptimizeResult:
    """:func:`optimize` without the final stop notes (its inner fits are parts of one fit); ``label``
    prefixes the names of its phases (progress bars, :attr:`OptimizeResult.phases`); ``monitor`` stops the
    full-resolution run early and keeps its best maps (:class:`~mi_svbrdf.optim.loop.Monitor`); ``photos``: fit
    these of ``images`` and ``valid`` (``spec`` is their subset already), a copy held only until the fit's targets
    are set (a caller's copy would be held for the whole fit: 50 MB a photo at 2048^2)."""
    cfg = config or OptimizeConfig()
    if photos is not None and isinstance(images, torch.Tensor):
        images, valid = images[photos], valid[photos] if valid is not None else None
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[:2] != (spec.n_images, 3):
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"images: expected shape (N={spec.n_images}, 3, H, W), got {shape}")
    images = images.detach().to(device=cfg.device or images.device, dtype=torch.float32)
    n, _, h, w = images.shape
    if valid is None:
        valid = torch.ones(n, 1, h, w, dtype=torch.bool, device=images.device)
    valid = valid.to(images.device)
    if tuple(valid.shape) != (n, 1, h, w):
        raise ValueError(f"valid: expected shape ({n}, 1, {h}, {w}), got {tuple(valid.shape)}")
    if forward is not None and cfg.levels != 1:
        raise ValueError(f"levels: expected 1 with a given forward model, got {cfg.levels}")
    if monitor is None and cfg.validate_photo and forward is None and 2 <= n <= cfg.validate_max_images:
        return _validated(spec, images, valid, cfg, init_maps, grad_hook)
    if monitor is None and forward is None and stops_early(spec, cfg):
        return _early_stopped(spec, images, valid, cfg, init_maps, grad_hook)
    lo, hi = target_bounds(images, valid, [im.encoding for im in spec.images])
    result = OptimizeResult(maps=torch.empty(0), distribution=cfg.distribution)
    start = time.perf_counter()
    given_init = init_maps is not None
    if init_maps is None:
        # The pull's anchor: the default start at the starts' mean roughness (0.5 by default: the
        # trivial baseline's), whichever start wins -- a glossy or rough start is a guess the
        # photos must confirm, and with one photo they could not (N = 1 roughness RMSE 0.27 vs 0.20).
        anchor_maps = initial_maps(spec, images, sum(cfg.roughness_starts) / len(cfg.roughness_starts), cfg.start)
        if len(cfg.roughness_starts) == 1 or cfg.model == "lambertian":  # a Lambertian fit has no roughness
            init_maps = anchor_maps
        else:
            init_maps = _multi_start(spec, images, lo, hi, cfg, forward, result, grad_hook, start, anchor_maps, label)
    else:
        check_maps(init_maps, "init_maps")
        anchor_maps = init_maps
    check_maps(init_maps, "init_maps")
    if init_maps.shape[0] != 1:
        raise ValueError(f"init_maps: expected a single material (1, 10, H, W), got {tuple(init_maps.shape)}")
    variables = tie_variables(resize_variables(from_maps(init_maps.detach().to(images)), (h, w)), cfg.model)
    anchor = (variables if anchor_maps is init_maps  # the same start: one copy (neither is written to)
              else tie_variables(resize_variables(from_maps(anchor_maps.detach().to(images)), (h, w)), cfg.model))
    del init_maps, anchor_maps  # the variables hold them now (full-size maps are 16 MB per 1024^2, 10 channels)
    prior = cfg.prior(n, given_init, anchor, hi)
    device = images.device
    calibration = _calibration(spec, cfg, forward, (h, w), device)
    del images, valid  # the bounds stand for them from here on
    for level in reversed(range(cfg.levels)):
        size = (max(h >> level, 1), max(w >> level, 1))
        elapsed = time.perf_counter() - start
        share = 1.0 / (level + 1) if level else 1.0  # coarse levels get a fraction of what is left
        left_iter = max(1, cfg.iterations - result.steps)
        loop_cfg = LoopConfig(loss=cfg.loss, tv_weight=cfg.tv_weight, lr=cfg.lr, schedule=cfg.schedule,
                              schedule_steps=max(1, int(cfg.schedule_steps * (0.5 * share if level else 1.0))),
                              iterations=max(1, int(left_iter * (0.5 * share if level else 1.0))),
                              budget_s=max(1e-3, (cfg.budget_s - elapsed) * (0.5 * share if level else 1.0)),
                              window=cfg.window, window_fraction=cfg.window_fraction, tol=cfg.tol,
                              rise_factor=cfg.rise_factor,
                              max_recoveries=max(1, cfg.max_recoveries - result.recoveries),
                              progress=cfg.progress, fused=cfg.fused, model=cfg.model)
        if level:
            lvl_lo = F.adaptive_avg_pool2d(lo, size)
            lvl_hi = F.adaptive_avg_pool2d(hi, size)  # a saturated texel (inf) keeps its coarse texel open
        else:
            lvl_lo, hi_full = lo, hi
            lvl_hi = hi_full
        fwd = forward if forward is not None else forward_for(spec, size, cfg.path, cfg.backend, cfg.distribution,
                                                                 device=device)
        if calibration is not None:
            calibration.resize(size)
            calibration.apply(fwd)
        # the level's start is handed to run (no copy of it), unless it is the pull's anchor too
        same = tuple(variables.shape[-2:]) == size
        res = run(fwd, lvl_lo, lvl_hi, variables if same else resize_variables(variables, size), loop_cfg,
                  time_offset=elapsed, step_offset=result.steps, grad_hook=grad_hook,
                  desc=_phase(result, f"{label}fit {size[0]}x{size[1]}"),
                  prior=prior.resized(size), calibration=calibration,
                  calibration_after=0 if level else cfg.calibrate_after, monitor=None if level else monitor,
                  take=not same or anchor is not variables)
        variables = res.variables
        if size[0] * size[1] >= RELEASE_TEXELS:
            release_memory()  # the next level asks for arrays 4x larger; the last, for the maps and renders
        result.levels.append({"phase": result.phases[-1][0] if result.phases else "", "size": list(size),
                              "steps": res.steps,
                              "seconds": round((res.history[-1][0] if res.history else elapsed) - elapsed, 3)})
        result.history += res.history
        result.recoveries += res.recoveries
        result.steps += res.steps
        result.stop_reason = res.stop_reason
        if res.stop_reason == "recoveries":
            break
    if tuple(variables.shape[-2:]) != (h, w):  # a run that ended on its recoveries below the top level
        variables = resize_variables(variables, (h, w))
    maps = to_maps(variables).detach()
    if not bool(torch.isfinite(maps).all()):  # cannot happen (run keeps a good state); never return NaN
        raise RuntimeError("optimize: the maps became non-finite despite the recovery guard")
    result.maps = maps
    if monitor is not None:
        result.held_out = {"curve": [[round(t, 4), k, v] for t, k, v in monitor.curve],
                           "best_length": monitor.best_length, "eligible_from": monitor.eligible_from,
                           "best": monitor.best if math.isfinite(monitor.best) else None}
    if calibration is not None:
        result.calibration = calibration.estimates()
        result.calibrated_spec = calibration.calibrated_spec()
    result.seconds = time.perf_counter() - start
    return result


#: A fit whose steps per second in the last third of its last run fell below this fraction of those in the
#: first third was slowed by something else: :func:`stop_notes` names the load on the machine.
SLOWDOWN = 0.6
#: The first steps of a run, left out of its step rate (kernels compile, caches fill).
WARMUP_STEPS = 5


def step_rates(result: OptimizeResult) -> tuple[float, float] | None:
    """Steps per second in the first and the last third (by time) of the fit's last run (its last phase),
    or None when it is too short to tell (fewer than 30 steps after :data:`WARMUP_STEPS`)."""
    start = result.phases[-1][1] if result.phases else 0
    rows = result.history[start + WARMUP_STEPS:]
    if len(rows) < 30:
        return None
    t0, t1 = rows[0][0], rows[-1][0]
    thirds = ([r for r in rows if r[0] <= t0 + (t1 - t0) / 3], [r for r in rows if r[0] >= t1 - (t1 - t0) / 3])

    def rate(part: list[tuple[float, int, float]]) -> float:
        return (part[-1][1] - part[0][1]) / max(part[-1][0] - part[0][0], 1e-9) if len(part) > 1 else math.nan
    return rate(thirds[0]), rate(thirds[1])


def stop_notes(result: OptimizeResult, cfg: OptimizeConfig) -> list[str]:
    """What to tell the user about a fit that stopped before it converged (empty when it converged).

    A fit stopped by its budget is told how to fit fewer texels (``cfg.fewer_texels``: where the capture was
    made) and, when its step rate fell during the fit (:func:`step_rates`, one level only), that the machine
    was busy."""
    if result.stop_reason == "budget":
        fewer = cfg.fewer_texels or "smaller photos: a smaller --size where the capture file was made"
        budget = f"{cfg.budget_s:.1f} s" + (f", {cfg.budget_of}" if cfg.budget_of else "")
        note = (f"the fit stopped on its time budget ({budget}) after {result.steps} steps, before it "
                f"converged: its maps are not final. Give it more time (--budget-s, or 0 for none), fit fewer texels "
                f"({fewer}), or fewer coarse-to-fine --levels")
        rates = step_rates(result) if cfg.levels == 1 else None
        if rates is not None and rates[1] < SLOWDOWN * rates[0]:
            note += (f". Its steps per second fell from {rates[0]:.1f} to {rates[1]:.1f} during the fit: other "
                     "programs were using the machine's CPU (load on the machine); with the CPU free it runs faster")
        return [note]
    if result.stop_reason == "iterations":
        return [f"the fit stopped at its step cap ({cfg.iterations} steps) before it converged: raise --iterations"]
    if result.stop_reason == "recoveries":
        return [f"the fit stopped after {result.recoveries} recoveries from a rising or non-finite loss: its maps "
                "are the last good state; try a smaller learning rate"]
    return []


def _calibrates(cfg: OptimizeConfig, n: int) -> bool:
    """Whether ``cfg`` self-calibrates a capture of ``n`` photos (on the texel path)."""
    return cfg.calibrate != "off" and bool(cfg.calibrate_what) and (
        cfg.calibrate == "on" or n >= cfg.calibrate_min_images)


def _calibration(spec: CaptureSpec, cfg: OptimizeConfig, forward: ForwardModel | None,
                 size: tuple[int, int], device: torch.device) -> SelfCalibration | None:
    """The self-calibration of a fit, or None (``cfg.calibrate``; off on the Mitsuba path)."""
    if not _calibrates(cfg, spec.n_images):
        return None
    texel = (isinstance(forward, TexelForward) if forward is not None
             else cfg.path == "texel" or (cfg.path == "auto" and all(im.rectified for im in spec.images)))
    if not texel:
        if cfg.calibrate == "on":
            raise ValueError("calibrate: expected a rectified capture on the texel path for 'on', got perspective "
                             "photos or path='mitsuba' (self-calibration runs on the texel path only)")
        return None  # "auto": perspective photos are fitted as stated
    return SelfCalibration(spec, size, what=cfg.calibrate_what,
                           exposure_stops=cfg.trust_exposure_stops, white_balance=cfg.trust_white_balance,
                           flash=cfg.trust_flash, pose=cfg.trust_pose, prior_weight=cfg.calibrate_prior,
                           lr=cfg.calibrate_lr, texels=cfg.calibrate_texels, distribution=cfg.distribution,
                           device=device)


def _multi_start(spec: CaptureSpec, images: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, cfg: OptimizeConfig,
                 forward: ForwardModel | None, result: OptimizeResult,
                 grad_hook: Callable[[int, torch.Tensor], None] | None,
                 start: float, anchor_maps: torch.Tensor, label: str = "") -> torch.Tensor:
    """Multi-start: a short fit from each roughness start, keep the best (whole map or per texel).

    Each start is pulled towards ``anchor_maps`` ``(1, 10, H, W)`` as the continued fit is
    (:meth:`OptimizeConfig.prior`).

    A single start is right for one kind of material only: a glossy material started rough falls
    into the "rough and dull" basin (high roughness, near-zero specular), and a rough one started
    glossy stays glossy (its lobe is too narrow for any photo to pull on it). The right basin has
    the lower training loss after a few dozen steps, so ``start_select="global"`` keeps the start
    with the lower mean re-rendering error; a per-texel choice (``"texel"``) is noisier. The steps
    are recorded in ``result`` (history, steps, recoveries). Starts are limited by steps only (a
    time cap stopped them after a few steps under load). Half-resolution starts (``start_scale=2``)
    let glossy materials choose the rough basin: hence full resolution by default, and the first rung of
    a coarse-to-fine ladder (``levels`` > 1: :data:`LADDER_BASE` or below for the ladder's default). Figures:
    ``docs/design-notes.md``.
    """
    h, w = images.shape[-2:]
    size = (h, w)
    # a ladder's starts run on its first rung (the size the starts were tuned at); coarser starts are cheaper,
    # but blurred highlights favour rough
    scale = max(cfg.start_scale, 1 << (cfg.levels - 1))
    if forward is None and scale > 1:
        size = ladder_sizes(h, w, cfg.levels)[0] if cfg.levels > 1 and scale == 1 << (cfg.levels - 1) else (
            max(h // scale, 1), max(w // scale, 1))
        lo = F.adaptive_avg_pool2d(lo, size)
        hi = F.adaptive_avg_pool2d(hi, size)  # a saturated texel (inf) keeps its coarse texel open
    fwd = forward if forward is not None else forward_for(spec, size, cfg.path, cfg.backend, cfg.distribution,
                                                                 device=images.device)
    best_vars, best_err = None, None
    n = images.shape[0]
    anchor = resize_variables(from_maps(anchor_maps), size)
    for r in cfg.roughness_starts:
        # Limited by steps only: a time cap stopped them after a few steps under load and made
        # the choice wrong. The overall budget (a safety cap) still applies.
        loop_cfg = LoopConfig(loss=cfg.loss, tv_weight=cfg.tv_weight, lr=cfg.lr, schedule="constant",
                              iterations=cfg.start_iterations, window=cfg.start_iterations + 1,
                              budget_s=max(1e-3, cfg.budget_s - (time.perf_counter() - start)),
                              rise_factor=cfg.rise_factor, max_recoveries=cfg.max_recoveries,
                              progress=cfg.progress, fused=cfg.fused, model=cfg.model)
        init = resize_variables(from_maps(initial_maps(spec, images, r, cfg.start)), size)
        res = run(fwd, lo, hi, init, loop_cfg,
                  time_offset=time.perf_counter() - start, step_offset=result.steps, grad_hook=grad_hook,
                  desc=_phase(result, f"{label}start r={r:g}"), prior=cfg.prior(n, False, anchor, hi))
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


def _phase(result: OptimizeResult, name: str) -> str:
    """Record that the fit's phase ``name`` starts at the next history entry; returns ``name`` (its bar's label)."""
    result.phases.append((name, len(result.history)))
    return name


def _blend(start: torch.Tensor, fit: torch.Tensor, t: float) -> torch.Tensor:
    """Maps ``(1, 10, H, W)`` a fraction ``t`` of the way from ``start`` to ``fit``, in the variables' space."""
    a, b = from_maps(start), from_maps(fit)
    return to_maps(a + t * (b - a))


def _validated(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor, cfg: OptimizeConfig,
               init_maps: torch.Tensor | None,
               grad_hook: Callable[[int, torch.Tensor], None] | None) -> OptimizeResult:
    """A fit whose distance from its start is chosen on a held-out photo (few photos, 2 <= N <= validate_max_images).

    With a handful of photos the re-rendering loss has minima that explain the photos and not a
    new light (a bumpy normal map, a coloured specular), and a pull towards the start strong
    enough to prevent them also holds back materials that the photos do determine. So: fit the
    first N - 1 photos, re-render the held-out last one from maps ``start + t (fit - start)``
    (variables' space, ``t`` in ``shrink_grid``; the start is ``init_maps`` or the default
    start's anchor, i.e. the trivial baseline's maps) and keep the ``t`` with the lowest error
    on it; then fit all N photos and return ``start + t (fit - start)``. The first fit gets half of
    ``budget_s`` and of ``iterations``, the second what is left; ``history``, ``phases`` and
    ``steps`` are both's, one after the other. Both fits keep the pulls towards the start times ``validated_pull``.

    Without a pull the full fit may leave the basin the held-out choice was made in: the choice is
    made on the N - 1 photo fit, not on the returned one. Hence ``validated_pull`` 1 by default
    (figures per material and pull: ``docs/design-notes.md``).
    """
    n, _, h, w = images.shape
    start_time = time.perf_counter()
    # A capture that self-calibrates does so in its N - 1 photo fit too, and the held-out photo's
    # unknown gain is matched before it is compared (gain_matched).
    calibrating = _calibrates(cfg, n) and "gain" in cfg.calibrate_what
    inner = dataclasses.replace(cfg, validate_photo=False, budget_s=cfg.budget_s / 2,
                                iterations=max(1, cfg.iterations // 2),
                                prior_weight=cfg.prior_weight * cfg.validated_pull,
                                start_prior_weight=cfg.start_prior_weight * cfg.validated_pull,
                                calibrate_min_images=min(cfg.calibrate_min_images, n - 1) if calibrating
                                else cfg.calibrate_min_images)
    keep, out = list(range(n - 1)), n - 1
    sub = spec.subset(keep)

    def start_of(s: CaptureSpec, ims: torch.Tensor) -> torch.Tensor:
        if init_maps is not None:
            return resize_maps_to(init_maps.detach().to(ims), (h, w))
        return initial_maps(s, ims, sum(cfg.roughness_starts) / len(cfg.roughness_starts), cfg.start)

    held = _fit(sub, images[keep], valid[keep], config=inner, init_maps=init_maps, grad_hook=grad_hook,
                label=f"validation ({n - 1} of {n} photos) ")
    one = spec.subset([out])
    lo, hi = target_bounds(images[out:out + 1], valid[out:out + 1], [spec.images[out].encoding])
    fwd = forward_for(one, (h, w), cfg.path, cfg.backend, cfg.distribution, device=images.device)
    s_sub = start_of(sub, images[keep])
    errors: dict[float, float] = {}
    with torch.no_grad():
        for t in cfg.shrink_grid:
            render = fwd(_blend(s_sub, held.maps, t))
            if calibrating:
                render = render * gain_matched(render, lo, hi, 2.0 * cfg.trust_exposure_stops)
            errors[t] = float(residual(render, lo, hi, cfg.loss).mean())
    best = min(errors, key=lambda t: (errors[t], -t))  # ties: the larger step (more of the photos' evidence)
    inner_full = dataclasses.replace(inner, budget_s=max(1e-3, cfg.budget_s - (time.perf_counter() - start_time)),
                                     iterations=max(1, cfg.iterations - held.steps))
    full_start = time.perf_counter() - start_time
    full = _fit(spec, images, valid, config=inner_full, init_maps=init_maps, grad_hook=grad_hook,
                label=f"all {n} photos ")
    maps = _blend(start_of(spec, images), full.maps, best).detach()
    history = held.history + [(t + full_start, s + held.steps, v) for t, s, v in full.history]
    phases = held.phases + [(name, i + len(held.history)) for name, i in full.phases]
    return dataclasses.replace(full, maps=maps, recoveries=held.recoveries + full.recoveries,
                               steps=held.steps + full.steps, history=history, phases=phases,
                               levels=held.levels + full.levels,
                               seconds=time.perf_counter() - start_time, shrink=best, validation=errors)


def stops_early(spec: CaptureSpec, cfg: OptimizeConfig) -> bool:
    """Whether :func:`optimize` stops a fit of ``spec`` early on left-out photos (module docstring "Early stop")."""
    return (cfg.early_stop == "auto" and spec.n_images >= cfg.early_stop_min_images and cfg.path != "mitsuba"
            and all(im.rectified for im in spec.images))


def stop_photos(n: int) -> list[int]:
    """The photos the early stop leaves out of its first fit: one in the middle of the capture (two from 12 photos).

    Examples:
        >>> stop_photos(7), stop_photos(12)
        ([3], [4, 7])
    """
    m = 2 if n >= 12 else 1
    return [round((i + 1) * (n - 1) / (m + 1)) for i in range(m)]


def final_lr(cfg: OptimizeConfig, steps: int) -> float:
    """The learning rate a fit's schedule reaches after ``steps`` full-resolution steps (as in
    :func:`~mi_svbrdf.optim.loop.run`)."""
    if cfg.schedule == "constant":
        return cfg.lr
    t = min(steps / max(cfg.schedule_steps, 1), 1.0)
    if cfg.schedule == "step":
        return cfg.lr * 0.5 ** min(int(4 * t), 3)
    low = LoopConfig().min_lr_factor
    return cfg.lr * (low + (1.0 - low) * 0.5 * (1.0 + math.cos(math.pi * t)))


def _early_stopped(spec: CaptureSpec, images: torch.Tensor, valid: torch.Tensor, cfg: OptimizeConfig,
                   init_maps: torch.Tensor | None,
                   grad_hook: Callable[[int, torch.Tensor], None] | None) -> OptimizeResult:
    """A fit whose length the photos choose (module docstring "Early stop").

    A first fit leaves :func:`stop_photos` out and scores them every ``stop_every`` steps
    (:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`); it stops when their error has not improved for the
    patience, within ``stop_share`` of the budget and of the steps. Then every photo is fitted:

    * the error rose after its minimum: a new fit of all photos, as long as the first fit was at its minimum
      (the recipe is the same, so the length means the same);
    * still falling when the first fit ended (its budget, steps or convergence): the first fit's maps go on
      with every photo for what is left, at the learning rate the schedule had reached.
    """
    n = images.shape[0]
    t0 = time.perf_counter()
    held = stop_photos(n)
    keep = [k for k in range(n) if k not in held]
    first_cfg = dataclasses.replace(cfg, early_stop="off", budget_s=cfg.budget_s * cfg.stop_share,
                                    iterations=max(1, int(cfg.iterations * cfg.stop_share)))
    monitor = Monitor(HeldOutScorer(spec, images, keep, held, cfg.distribution), every=cfg.stop_every,
                      patience=cfg.stop_patience, patience_fraction=cfg.stop_patience_fraction)
    first = _fit(spec.subset(keep), images, valid, config=first_cfg, init_maps=init_maps, grad_hook=grad_hook,
                 label=f"early stop ({len(keep)} of {n} photos) ", monitor=monitor, photos=keep)
    length = monitor.best_length
    monitor.best_variables = None  # in first.maps now
    last = monitor.curve[-1][1] if monitor.curve else 0
    rose = bool(monitor.curve) and last > length
    left_s = max(1e-3, cfg.budget_s - (time.perf_counter() - t0))
    left_steps = max(1, cfg.iterations - first.steps)
    offset = time.perf_counter() - t0
    if rose and length > 0:
        how = "refit"
        second_cfg = dataclasses.replace(cfg, early_stop="off", budget_s=left_s,
                                         iterations=max(1, min(max(length, 1), left_steps)))
        second = _fit(spec, images, valid, config=second_cfg, init_maps=init_maps, grad_hook=grad_hook,
                      label=f"all {n} photos, {second_cfg.iterations} steps ")
    else:
        how = "continued"
        fit_steps = first.steps - (first.phases[-1][1] if first.phases else 0)
        second_cfg = dataclasses.replace(cfg, early_stop="off", budget_s=left_s, iterations=left_steps,
                                         schedule="constant", lr=final_lr(cfg, fit_steps), levels=1,
                                         validate_photo=False)
        # The first fit's maps are handed over as the second's start: not held here beside the second fit's own
        # copy of them (170 MB at 2048^2).
        handed = [first.maps]
        first.maps = torch.empty(0)
        second = _fit(spec, images, valid, config=second_cfg, init_maps=handed.pop(), grad_hook=grad_hook,
                      label=f"all {n} photos, continued ")
    if how == "refit" and second.stop_reason == "iterations" and second.steps >= second_cfg.iterations:
        second.stop_reason = "held-out"  # the refit ended at the length the left-out photo chose: final
    history = first.history + [(t + offset, k + first.steps, v) for t, k, v in second.history]
    phases = first.phases + [(name, i + len(first.history)) for name, i in second.phases]
    held_out = {"photos": held, "every": cfg.stop_every, "curve": first.held_out["curve"] if first.held_out else [],
                "best_length": length, "eligible_from": monitor.eligible_from,
                "best": monitor.best if math.isfinite(monitor.best) else None,
                "first_fit": {"steps": first.steps, "stop": first.stop_reason}, "then": how,
                "final_steps": second.steps}
    return dataclasses.replace(second, history=history, phases=phases, steps=first.steps + second.steps,
                               levels=first.levels + second.levels,
                               recoveries=first.recoveries + second.recoveries, held_out=held_out,
                               seconds=time.perf_counter() - t0)


def gain_matched(render: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, max_stops: float) -> torch.Tensor:
    """Per-photo, per-channel gain ``(N, 3, 1, 1)`` that best matches ``render`` to the photos' intervals.

    The median over unclipped texels of ``log(lo / render)`` (the log-L1 optimum), limited to
    ``max_stops`` stops either way: a photo whose exposure and white balance are unknown is compared
    up to them. Texels rendered black or clipped in the photo do not vote; no vote: gain 1.
    """
    ok = torch.isfinite(hi) & (render > LOG_EPS) & (lo > LOG_EPS)
    ratio = torch.where(ok, torch.log(lo.clamp_min(LOG_EPS)) - torch.log(render.clamp_min(LOG_EPS)),
                        torch.full_like(render, math.nan))
    log_gain = torch.nan_to_num(ratio.flatten(2).nanmedian(dim=2).values, nan=0.0)
    limit = max_stops * math.log(2.0)
    return log_gain.clamp(-limit, limit).exp()[..., None, None]


def resize_maps_to(maps: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Canonical maps ``(1, 10, h, w)`` resampled to ``size`` through the variables (normals stay unit)."""
    return to_maps(resize_variables(from_maps(maps), size))
