"""The thesis's ablations at equal compute: short CPU trainings that differ in one setting, scored on one held-out set.

**Design.** Every ablation compares a *baseline arm* with an *ablated arm*: two trainings
(:func:`mi_svbrdf.nets.train.train`) from scratch with the same seed (so the same stream of
simulated batches, :mod:`mi_svbrdf.data.simulator`: batch ``i`` is a pure function of
``(seed, i)``), the same number of steps, batch size, resolution, learning-rate schedule and
the same small architecture (:data:`ABLATION_NET`, the ``compact`` preset narrowed to fit the
budget), differing in the one ablated setting. Each arm's final net is then scored on the
same fixed held-out set (:class:`mi_svbrdf.data.heldout.HeldOutSet`: held-out parameter
ranges and seed, with the preset's *perturbed* captures) by
:func:`mi_svbrdf.eval.harness.run_and_score` under the fixed evaluation lights: the
single-image arms on ``single_flash`` photos at N = 1, the multi-image arms on ``multiview``
photos at each N of ``n_values`` (the first N photos of each material). The arms come in two
groups, each with its baseline (:data:`ARMS`):

* single-image group (``single_flash`` simulator, the CPU recipe's loss: rendering loss + 1 x map L1):
  ``single/render+l1`` (baseline), ``single/render`` (rendering loss only, the thesis's 2018
  setting), ``single/l1`` (map L1 only, Fig. 3.6's alternative), ``single/no-global`` (the
  global-features track off);
* multi-image group (``multiview`` simulator, 1-5 photos, roughness remap, same loss):
  ``multi/max`` (baseline, max pooling), ``multi/mean`` (mean pooling), ``multi/no-perturb``
  (every capture perturbation off: a clean, nominal capture; still scored on the perturbed
  held-out photos).

**The ablations and what the thesis says** (:data:`COMPARISONS`; verdicts on the re-rendering RMSE,
``rmse_render`` of :func:`mi_svbrdf.core.metrics.evaluate_maps`, lower is better):

* *rendering loss vs map L1* (ch. 3.1.3, Fig. 3.6): the rendering loss gives better
  re-renderings than an L1 loss on the maps; L1 gives blurrier, less consistent maps
  (``single/render`` vs ``single/l1``; also ``single/render+l1`` vs ``single/l1``: adding the
  rendering loss to the L1). A third comparison, ``single/render+l1`` vs ``single/render``,
  checks the CPU recipes' own choice (:data:`mi_svbrdf.nets.train.RECIPES`: at a few thousand
  steps the map L1 gives the direct gradient the rendering loss lacks early on), not a thesis claim;
* *global-features track on/off* (ch. 3.1.2): the track improves consistency over the whole
  image (removes low-frequency artefacts, better albedo and specular colour);
* *capture perturbations on/off* (ch. 4.4.1): training on perturbed, realistic capture
  simulation makes the net robust to real capture conditions (here: the held-out photos'
  jittered flash, white balance, cone, positions, ambient light and noise);
* *max vs mean pooling* (ch. 4.2.2): max pooling outperforms mean pooling (order independent
  as well, it keeps the strongest cue, e.g. a highlight, from any photo).

**Verdicts** (:func:`verdict`): the difference ``ablated - baseline`` of the headline
re-rendering RMSE (single: N = 1; multi: the mean over ``n_values``) agrees with the thesis
when positive (the thesis's setting is better), disagrees when negative, and is *within
noise* when its magnitude is at most the noise threshold (:func:`noise_threshold`), the
larger of two figures:

* 2 x the standard error of the paired per-material differences (about a 95 % interval of
  the mean over the held-out materials: the figure another draw of materials would move);
* the combined spread (``hypot`` of the standard deviations) of the two arms' last
  :data:`CURVE_POINTS` validation points: how much one run's metric moves between nearby
  checkpoints, a proxy for what another stopping step or seed would give (it includes the
  curve's remaining trend, so it errs on the cautious side).

Short runs at equal compute are not the thesis's 400 k-step GPU trainings: a verdict here says
what holds *at this compute* and the Markdown says so.

**Budget.** :func:`estimate_seconds` prices an arm's steps at :data:`SECONDS_PER_STEP` (the defaults:
64^2, batch 4, :data:`ABLATION_NET`, one torch thread, bf16 autocast, on a 2-core CPU shared with another
job): 800 steps per arm and the 7 arms come to about half an hour with validation and scoring. One torch
thread (``threads = 1``): on a loaded CPU a second one makes the steps many times slower (OpenMP threads
spin against the other job and Dr.Jit's pool). Per-step figures: ``docs/design-notes.md``.

**Files** (:func:`run_ablations`, each written atomically, after every arm): ``runs/GROUP/VARIANT/``
(each arm's run folder: ``checkpoint.pt``, ``log.csv``, ``curve.png``; a finished arm is not
retrained, an interrupted one resumes from its checkpoint), ``ablations.json`` (per arm: its
TrainConfig, steps, seconds, held-out metrics per N, validation curve; per comparison: the
metric deltas, noise threshold, verdict and sentence), ``ablations.md`` (:func:`ablations_markdown`)
and ``ablations.png`` (:func:`plot_ablations`).

Examples:
    >>> verdict(0.091, 0.102, noise=0.004)
    'agrees'
    >>> verdict(0.091, 0.092, noise=0.004)
    'within noise'
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core.metrics import METRIC_KEYS, eval_lights
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.data.heldout import MAX_PHOTOS, HeldOutSet
from mi_svbrdf.eval.harness import Dataset, load_heldout, run_and_score
from mi_svbrdf.eval.methods import make_method
from mi_svbrdf.io.atomic import json_safe, write_json, write_text
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.network import PRESETS, SVBRDFNet, build_network
from mi_svbrdf.nets.train import TrainConfig, load_state, train

#: The groups of arms, in order: (name, simulator preset of its held-out set).
GROUPS: dict[str, str] = {"single": "single_flash", "multi": "multiview"}
#: Every capture perturbation of :class:`mi_svbrdf.data.photo_setups.CaptureConfig`, off: a clean,
#: nominal capture (the hemisphere positions of photos 2..N are the set-up, not a perturbation).
CLEAN_CAPTURE: dict[str, bool] = {k: False for k in (
    "intensity_jitter", "white_balance", "cone_exponent_jitter", "cone_target_jitter", "light_offset", "view_offset",
    "fov_jitter", "ambient", "noise")}
_SINGLE: dict[str, Any] = {"kind": "single", "simulator": {"preset": "single_flash"}, "render_weight": 1.0,
                           "map_weight": 1.0}
_MULTI: dict[str, Any] = {"kind": "multi", "render_weight": 1.0, "map_weight": 1.0,
                          "simulator": {"preset": "multiview", "n_images": [1, 5], "remap_roughness": True}}
#: The training arms: TrainConfig overrides (on top of :func:`arm_config`'s common settings). The
#: first arm of each group is its baseline; every other arm differs from it in one setting.
ARMS: dict[str, dict[str, Any]] = {
    "single/render+l1": _SINGLE,  # the CPU recipe's loss (RECIPES["single"])
    "single/render": {**_SINGLE, "map_weight": 0.0},  # rendering loss only: the thesis's 2018 training
    "single/l1": {**_SINGLE, "render_weight": 0.0},  # map L1 only (Fig. 3.6)
    "single/no-global": {**_SINGLE, "net": {"global_track": False}},  # ch. 3.1.2 off
    "multi/max": _MULTI,  # the thesis's max pooling (ch. 4.2.2), perturbed captures (ch. 4.4.1)
    "multi/mean": {**_MULTI, "net": {"pooling": "mean"}},
    "multi/no-perturb": {**_MULTI, "simulator": {**_MULTI["simulator"], "capture": dict(CLEAN_CAPTURE)}},
}
#: What each arm changes, for the tables.
ARM_NOTES: dict[str, str] = {
    "single/render+l1": "baseline: rendering loss + 1 x map L1 (the CPU recipe)",
    "single/render": "rendering loss only (map_weight 0; the thesis's 2018 loss)",
    "single/l1": "map L1 only (render_weight 0)",
    "single/no-global": "global-features track off",
    "multi/max": "baseline: max pooling, perturbed captures",
    "multi/mean": "mean pooling across photos",
    "multi/no-perturb": "capture perturbations off (clean nominal captures)",
}
#: TrainConfig fields set per arm or by the study: not overridable through ``AblationConfig.train``.
MANAGED = ("kind", "simulator", "net", "render_weight", "map_weight", "name", "out", "preset", "init")
#: The small architecture of the ablations (``compact`` preset overrides; depth 5: a 2 x 2 bottleneck at 64^2).
ABLATION_NET: dict[str, Any] = {"encoder_features": [16, 32, 64, 128, 128], "last_features": 16}
#: Validation points at the end of a curve whose spread enters the noise threshold.
CURVE_POINTS = 3
#: The metric of the verdicts and its name in the sentences.
PRIMARY = "rmse_render"
#: Seconds per training step at the defaults (64^2, batch 4, ABLATION_NET, 1 thread; the upper end of
#: timings on a loaded 2-core CPU, module docstring), for :func:`estimate_seconds`.
SECONDS_PER_STEP = {"single": 0.27, "multi": 0.34}


@dataclass(frozen=True)
class AblationComparison:
    """One ablation: a baseline arm (the thesis's setting) against an ablated arm."""

    key: str  #: short id, e.g. "loss"
    title: str  #: e.g. "rendering loss vs map L1"
    baseline: str  #: arm of the setting the source expects to be better
    ablated: str  #: arm without it
    chapter: str  #: where the claim is made
    claim: str  #: what the source says
    better: str  #: how the sentence names the baseline's setting ("the rendering loss")
    worse: str  #: how it names the ablated setting ("the map L1")
    source: str = "the thesis"  #: whose claim it is


#: The comparisons (each run when both its arms are).
COMPARISONS: tuple[AblationComparison, ...] = (
    AblationComparison("loss", "rendering loss vs map L1", "single/render", "single/l1", "ch. 3.1.3, Fig. 3.6",
               "the rendering loss gives better re-renderings than an L1 loss on the maps, "
               "which gives blurrier, less consistent maps", "the rendering loss", "the map L1"),
    AblationComparison("loss+l1", "rendering loss + map L1 vs map L1", "single/render+l1", "single/l1", "ch. 3.1.3",
               "adding the rendering loss to a map L1 improves the re-renderings", "rendering + L1",
               "the map L1 alone"),
    AblationComparison("l1-term", "rendering loss + map L1 vs rendering loss", "single/render+l1", "single/render",
               "nets/train.py RECIPES", "at a few thousand CPU steps the map L1 gives the direct gradient the "
               "rendering loss lacks early on", "rendering + L1", "the rendering loss alone",
               source="the CPU recipe's choice"),
    AblationComparison("global", "global-features track on vs off", "single/render+l1", "single/no-global", "ch. 3.1.2",
               "the global-features track improves consistency over the whole image: fewer low-frequency "
               "artefacts, better albedo and specular colour", "the global track", "no global track"),
    AblationComparison("perturb", "perturbed vs clean capture simulation", "multi/max", "multi/no-perturb", "ch. 4.4.1",
               "training on perturbed, realistic captures makes the net robust to real capture conditions",
               "perturbed training", "clean training"),
    AblationComparison("pooling", "max vs mean pooling", "multi/max", "multi/mean", "ch. 4.2.2",
               "max pooling outperforms mean pooling: it keeps the strongest cue, e.g. a highlight, from any photo",
               "max pooling", "mean pooling"),
)


def group_of(arm: str) -> str:
    """``"single"`` or ``"multi"``: the group of ``arm``."""
    return arm.split("/", 1)[0]


@dataclass(frozen=True)
class AblationConfig:
    """What :func:`run_ablations` trains and scores; :meth:`from_dict` rejects unknown keys."""

    steps: int = 800  #: optimiser steps per arm (every arm the same; ~30 min for all 7 at the defaults)
    size: int = 64  #: training, validation and held-out resolution (a multiple of 2**depth of the net)
    batch_size: int = 4  #: samples per step, every arm
    seed: int = 0  #: data stream and initialisation seed, every arm (training seeds are 0-999)
    lr: float = 2e-4  #: Adam learning rate (the CPU recipes'), cosine-decayed over steps
    warmup: int = 50  #: linear warm-up steps
    heldout_materials: int = 16  #: materials of the held-out set every arm is scored on
    n_values: tuple[int, ...] = (1, 3, 5)  #: photos per material the multi-image arms are scored at
    arms: tuple[str, ...] = tuple(ARMS)  #: arms to run (names of ARMS, or "a,b"); comparisons need both their arms
    net: dict[str, Any] = field(default_factory=lambda: dict(ABLATION_NET))  #: NetConfig overrides of the compact preset
    validate_every: int = 100  #: steps between validations (the curves; >= 2 points needed for the noise spread)
    val_materials: int = 8  #: held-out materials of the validation curves (a prefix of the held-out set)
    train: dict[str, Any] = field(default_factory=dict)  #: further TrainConfig overrides for every arm (e.g. bf16)
    out: str = "ablations"  #: output folder (run_ablations' out_dir when that is None)
    threads: int = 1  #: torch intra-op threads (1: a second thread only contends on a loaded 2-core CPU)

    def __post_init__(self) -> None:
        arms = tuple(a.strip() for a in self.arms.split(",")) if isinstance(self.arms, str) else self.arms  # "a,b"
        object.__setattr__(self, "arms", tuple(arms) if isinstance(arms, (list, tuple)) else arms)
        object.__setattr__(self, "n_values", tuple(self.n_values) if isinstance(self.n_values, (list, tuple))
                           else self.n_values)
        ints = ("steps", "batch_size", "heldout_materials", "validate_every", "val_materials", "threads")
        depth = len(self.net.get("encoder_features", PRESETS["compact"]["encoder_features"])) \
            if isinstance(self.net, dict) else 0
        unknown = ([a for a in self.arms if not isinstance(a, str) or a not in ARMS]
                   if isinstance(self.arms, tuple) else [self.arms])
        managed = sorted(set(self.train) & set(MANAGED)) if isinstance(self.train, dict) else []
        check_fields([
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ints),
            ("seed", isinstance(self.seed, int) and 0 <= self.seed < 1000, "a training seed in 0-999", self.seed),
            ("warmup", isinstance(self.warmup, int) and self.warmup >= 0, "an int >= 0", self.warmup),
            ("lr", isinstance(self.lr, (int, float)) and self.lr > 0, "a learning rate > 0", self.lr),
            ("arms", isinstance(self.arms, tuple) and bool(self.arms) and not unknown,
             f"names among {list(ARMS)} (unknown: {unknown})", self.arms),
            ("n_values", isinstance(self.n_values, tuple) and bool(self.n_values)
             and all(isinstance(n, int) and 1 <= n <= MAX_PHOTOS for n in self.n_values),
             f"photo counts in [1, {MAX_PHOTOS}]", self.n_values),
            ("net", isinstance(self.net, dict), "a dict of NetConfig overrides", self.net),
            ("size", isinstance(self.size, int) and depth > 0 and self.size >= 8 and self.size % 2 ** depth == 0,
             f"an int >= 8, a multiple of 2**depth = {2 ** depth} of the ablation net", self.size),
            ("train", isinstance(self.train, dict) and not managed,
             f"a dict of TrainConfig overrides other than {list(MANAGED)} (got {managed})", self.train),
        ], owner="AblationConfig")
        object.__setattr__(self, "n_values", tuple(sorted(set(self.n_values))))
        for arm in self.arms:  # every arm's TrainConfig and NetConfig are valid (unknown keys, bad values ...)
            _ = arm_config(self, arm, Path(self.out)).net_config

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AblationConfig:
        """Build from a dict (e.g. JSON); unknown keys raise ``ValueError``."""
        return from_dict(cls, data)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return json.loads(json.dumps(dataclasses.asdict(self)))


def quick_config(**overrides: Any) -> AblationConfig:
    """``--quick``: a smoke run (6 steps per arm at 32^2, a tiny net, 3 held-out materials, N in {1, 3})."""
    base: dict[str, Any] = {"steps": 6, "size": 32, "batch_size": 2, "warmup": 2, "heldout_materials": 3,
                            "n_values": (1, 3), "net": {"encoder_features": [8, 16, 16], "last_features": 8},
                            "validate_every": 2, "val_materials": 2}
    return AblationConfig.from_dict({**base, **overrides})


def arm_config(config: AblationConfig, arm: str, out_dir: str | os.PathLike) -> TrainConfig:
    """The :class:`~mi_svbrdf.nets.train.TrainConfig` of ``arm``, its run folder ``out_dir/runs/GROUP/VARIANT``.

    Common to every arm: the compact preset with ``config.net`` (resolution ``config.size``), from
    scratch (no warm start), ``config``'s steps, batch, size, seed, lr and warm-up, validation on
    ``val_materials`` held-out materials at ``size``, checkpoints every 2 minutes, then
    ``config.train``; then the arm's overrides (:data:`ARMS`, ``net`` merged).

    Raises:
        ValueError: an unknown arm, or settings TrainConfig rejects.
    """
    if arm not in ARMS:
        raise ValueError(f"arm: expected one of {list(ARMS)}, got {arm!r}")
    group, variant = arm.split("/", 1)
    overrides = dict(ARMS[arm])
    net = {**config.net, "resolution": config.size, **overrides.pop("net", {})}
    common: dict[str, Any] = {
        "name": variant, "out": str(Path(out_dir) / "runs" / group), "preset": "compact", "init": None,
        "batch_size": config.batch_size, "sizes": [[0, config.size]], "steps": config.steps, "lr": config.lr,
        "warmup": config.warmup, "seed": config.seed, "validate_every": config.validate_every,
        "val_materials": config.val_materials, "val_size": config.size, "threads": config.threads,
        "checkpoint_every_s": 120.0, "log_every": 10}
    return TrainConfig.from_dict({**common, **config.train, **overrides, "net": net})


def estimate_seconds(config: AblationConfig) -> float:
    """Rough wall time of ``config``'s training: :data:`SECONDS_PER_STEP` scaled by pixels and batch."""
    scale = (config.size / 64) ** 2 * config.batch_size / 4
    return sum(SECONDS_PER_STEP[group_of(a)] * scale * config.steps for a in config.arms) * 1.1


# --- verdicts ----------------------------------------------------------------------------------

def verdict(baseline: float, ablated: float, noise: float) -> str:
    """``"agrees"`` when the baseline (the thesis's setting) has the lower error by more than ``noise``,
    ``"disagrees"`` when the ablated arm has, ``"within noise"`` otherwise (``noise`` NaN: no threshold).

    Args:
        baseline: the baseline arm's error (lower is better).
        ablated: the ablated arm's error.
        noise: the noise threshold (:func:`noise_threshold`), >= 0.
    """
    diff = ablated - baseline
    if math.isfinite(noise) and abs(diff) <= noise:
        return "within noise"
    return "agrees" if diff > 0 else "disagrees"


def curve_spread(curve: Sequence[Sequence[float]], points: int = CURVE_POINTS) -> float:
    """Standard deviation (ddof 1) of the last ``points`` values of a validation curve ``[[step, value], ...]``;
    NaN with fewer than 2 points."""
    values = [float(v) for _, v in curve][-points:]
    return float(np.std(values, ddof=1)) if len(values) >= 2 else math.nan


def noise_threshold(per_material_baseline: Sequence[float], per_material_ablated: Sequence[float],
                    spread_baseline: float, spread_ablated: float) -> dict[str, float]:
    """The noise threshold of a comparison (module docstring, "Verdicts").

    Args:
        per_material_baseline: ``(M,)`` the baseline's error per held-out material.
        per_material_ablated: ``(M,)`` the ablated arm's, same materials in the same order.
        spread_baseline: :func:`curve_spread` of the baseline's validation curve (NaN: unknown).
        spread_ablated: the ablated arm's.

    Returns:
        ``{"paired_se": SE of the mean paired difference, "curve_spread": hypot of the spreads,
        "noise": max(2 * paired_se, curve_spread)}`` (NaN components are left out; NaN when both are).
    """
    d = np.asarray(per_material_ablated, dtype=float) - np.asarray(per_material_baseline, dtype=float)
    se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size >= 2 else math.nan
    spreads = [s for s in (spread_baseline, spread_ablated) if math.isfinite(s)]
    spread = math.hypot(*spreads) if spreads else math.nan
    parts = [x for x in (2 * se, spread) if math.isfinite(x)]
    return {"paired_se": se, "curve_spread": spread, "noise": max(parts) if parts else math.nan}


def sentence(comparison: AblationComparison, baseline: float, ablated: float, noise: float, n_label: str) -> str:
    """The comparison's one-sentence finding from its numbers (:func:`verdict` decides the wording)."""
    v = verdict(baseline, ablated, noise)
    head = (f"{comparison.title[0].upper()}{comparison.title[1:]} ({comparison.chapter}): re-render RMSE "
            f"{baseline:.4f} ({comparison.baseline}) vs {ablated:.4f} ({comparison.ablated}){n_label}")
    noise_text = f"noise threshold {noise:.4f}" if math.isfinite(noise) else "no noise estimate"
    if v == "within noise":
        return (f"{head}: the difference {abs(ablated - baseline):.4f} is within the {noise_text}, so this run "
                f"neither confirms nor contradicts {comparison.source}, which says {comparison.claim}.")
    winner, loser, worse_value = ((comparison.better, comparison.worse, ablated) if v == "agrees"
                                  else (comparison.worse, comparison.better, baseline))
    pct = 100 * abs(ablated - baseline) / worse_value if worse_value > 0 else math.nan
    return (f"{head}: {winner} is better than {loser} by {pct:.0f} % ({noise_text}), so this run "
            f"{'agrees' if v == 'agrees' else 'disagrees'} with {comparison.source}, which says {comparison.claim}.")


def compare(comparison: AblationComparison, arms: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The comparison's entry of ``ablations.json`` from the two arms' entries (:func:`evaluate_arm` + curve).

    Returns:
        A dict with the comparison's fields, ``deltas`` (per N label and metric: ablated - baseline),
        the headline values (``baseline_value``, ``ablated_value``: :data:`PRIMARY` of the arms'
        ``summary``), the noise components, ``verdict`` and ``sentence``.
    """
    a, b = arms[comparison.baseline], arms[comparison.ablated]
    deltas = {n: {k: b["metrics"][n][k] - a["metrics"][n][k] for k in METRIC_KEYS} for n in a["metrics"]}
    noise = noise_threshold(a["per_material"][PRIMARY], b["per_material"][PRIMARY],
                            curve_spread(a["curve"]), curve_spread(b["curve"]))
    base, abl = a["summary"][PRIMARY], b["summary"][PRIMARY]
    ns = list(a["metrics"])
    n_label = f", mean over {', '.join(ns)}" if len(ns) > 1 else ""
    return {**dataclasses.asdict(comparison), "n": ns, "deltas": deltas,
            "summary_deltas": {k: b["summary"][k] - a["summary"][k] for k in METRIC_KEYS},
            "baseline_value": base, "ablated_value": abl, **noise, "verdict": verdict(base, abl, noise["noise"]),
            "sentence": sentence(comparison, base, abl, noise["noise"], n_label)}


# --- training and scoring ------------------------------------------------------------------------

def _comparable(cfg: dict[str, Any]) -> dict[str, Any]:
    """The settings that change a run's result (not its folder, threads or checkpoint period), JSON-normalised."""
    skip = ("out", "name", "threads", "checkpoint_every_s")
    return json.loads(json.dumps({k: v for k, v in cfg.items() if k not in skip}))


def _state(cfg: TrainConfig, arm: str) -> dict[str, Any] | None:
    """The arm's checkpoint (None when absent); a ``ValueError`` when it was trained with other settings."""
    path = cfg.run_dir / "checkpoint.pt"
    if not path.is_file():
        return None
    state = load_state(path)
    saved, wanted = _comparable(state["config"]), _comparable(dataclasses.asdict(cfg))
    diff = sorted(k for k in set(saved) | set(wanted) if saved.get(k) != wanted.get(k))
    if diff:
        raise ValueError(f"{arm}: {cfg.run_dir} was trained with other settings ({', '.join(diff)}); "
                         f"use another --out or delete that folder")
    return state


def train_arm(config: AblationConfig, arm: str, out_dir: Path, progress: bool = True) -> dict[str, Any]:
    """Train ``arm`` to ``config.steps`` unless its run already has (resuming an interrupted run);
    returns its final checkpoint state.

    Raises:
        ValueError: the run folder holds a run of other settings.
        KeyboardInterrupt: training stopped early (Ctrl-C / SIGTERM; the checkpoint is saved).
    """
    cfg = arm_config(config, arm, out_dir)
    state = _state(cfg, arm)
    if state is None or state["step"] < cfg.steps:
        train(cfg, resume=True, progress=progress)
        state = _state(cfg, arm)
        if state is None or state["step"] < cfg.steps:
            step = 0 if state is None else state["step"]
            raise KeyboardInterrupt(f"{arm}: stopped at step {step} of {cfg.steps}; rerun to resume")
    return state


def final_net(cfg: TrainConfig, state: dict[str, Any]) -> SVBRDFNet:
    """The net of a checkpoint ``state`` in eval mode."""
    net = build_network(cfg.net_config)
    net.load_state_dict(state["model"])
    return net.eval()


def heldout(config: AblationConfig, group: str) -> HeldOutSet:
    """The held-out set of ``group``: ``single_flash`` (N = 1) or ``multiview`` (max(n_values) photos), at ``size``."""
    n = 1 if group == "single" else max(config.n_values)
    return HeldOutSet(size=config.size, materials=config.heldout_materials, n_images=n, preset=GROUPS[group])


def evaluate_arm(net: SVBRDFNet, data: Dataset, n_values: Sequence[int], lights: Any) -> dict[str, Any]:
    """Score ``net`` on every material of ``data`` at each N of ``n_values``.

    Args:
        net: a trained single- or multi-image net (it sees the photos at their own size).
        data: the held-out set (:func:`mi_svbrdf.eval.harness.load_heldout`), M materials.
        n_values: photo counts (the first N photos; ``(1,)`` for a single-image net).
        lights: the re-rendering lights (:func:`mi_svbrdf.core.metrics.eval_lights`).

    Returns:
        ``{"metrics": {"N=n": {key: mean over materials}}, "summary": {key: mean over N},
        "per_material": {PRIMARY: (M,) list, mean over N}}``.
    """
    method = make_method(net.config.kind, net=net)
    metrics, per_n = {}, []
    for n in n_values:
        rows = [run_and_score(method, data, n, lights, materials=m)[1] for m in range(data.maps.shape[0])]
        metrics[f"N={n}"] = {k: float(np.mean([r[k] for r in rows])) for k in METRIC_KEYS}
        per_n.append([r[PRIMARY] for r in rows])
    summary = {k: float(np.mean([m[k] for m in metrics.values()])) for k in METRIC_KEYS}
    return {"metrics": metrics, "summary": summary,
            "per_material": {PRIMARY: [float(v) for v in np.mean(per_n, axis=0)]}}


def validation_curve(log: Sequence[dict[str, Any]], key: str = f"val_{PRIMARY}") -> list[list[float]]:
    """``[[step, value], ...]`` of a run log's validation rows of ``key``."""
    return [[int(r["step"]), float(r[key])] for r in log if key in r]


def run_ablations(config: AblationConfig, out_dir: str | os.PathLike | None = None,
                  progress: bool = True) -> dict[str, Any]:
    """Train every arm of ``config`` (resumable), score it on the held-out set and write the results.

    Args:
        config: the study.
        out_dir: output folder (None: ``config.out``); run folders go to ``out_dir/runs/GROUP/VARIANT``.
        progress: progress bars (over arms, and each training's).

    Returns:
        The content of ``ablations.json`` (module docstring, "Files"), rewritten with
        ``ablations.md`` and ``ablations.png`` after every arm.

    Raises:
        ValueError: a run folder trained with other settings.
        KeyboardInterrupt: an arm's training was stopped (its checkpoint is saved; rerun to resume).
    """
    out = Path(config.out if out_dir is None else out_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    lights = eval_lights()
    data: dict[str, Dataset] = {}
    result: dict[str, Any] = {"config": config.to_dict(), "heldout": {}, "arms": {}, "comparisons": []}
    try:
        for arm in tqdm(config.arms, desc="ablations", disable=not progress):
            group = group_of(arm)
            state = train_arm(config, arm, out, progress=progress)
            if group not in data:
                held = heldout(config, group)
                data[group] = load_heldout(held, progress=progress)
                result["heldout"][group] = {k: v for k, v in dataclasses.asdict(held).items()
                                            if k not in ("cache", "cache_dir")}
            cfg = arm_config(config, arm, out)
            n_values = (1,) if group == "single" else config.n_values
            scores = evaluate_arm(final_net(cfg, state), data[group], n_values, lights)
            result["arms"][arm] = {"group": group, "note": ARM_NOTES[arm], "config": dataclasses.asdict(cfg),
                                   "run": str(cfg.run_dir), "steps": int(state["step"]),
                                   "seconds": float(state["seconds"]), **scores,
                                   "curve": validation_curve(state["log"])}
            result["comparisons"] = [compare(c, result["arms"]) for c in COMPARISONS
                                     if c.baseline in result["arms"] and c.ablated in result["arms"]]
            write_results(out, result)
    finally:
        torch.set_num_threads(threads)
    return result


# --- outputs --------------------------------------------------------------------------------------

def write_results(out: Path, result: dict[str, Any]) -> None:
    """``ablations.json``, ``ablations.md`` and ``ablations.png`` of ``result`` in ``out`` (atomically)."""
    write_json(out / "ablations.json", json_safe(result))
    plot_ablations(result, out / "ablations.png")
    write_text(out / "ablations.md", "\n".join(["# Ablations at equal compute", "", *ablations_markdown(out)]) + "\n")




#: Columns of the Markdown tables: (metric key, header, format).
TABLE = (("rmse_normal", "normal", ".4f"), ("rmse_diffuse", "diffuse", ".4f"), ("rmse_roughness", "rough.", ".4f"),
         ("rmse_specular", "specular", ".4f"), ("rmse_diffuse_scaled", "diffuse×k", ".4f"),
         ("rmse_render", "render RMSE", ".4f"), ("ssim_render", "render SSIM", ".3f"))


def _num(x: float | None, fmt: str) -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def ablations_markdown(result_dir: str | os.PathLike, relative_to: str | os.PathLike | None = None) -> list[str]:
    """The ablations section (Markdown lines, no title) from ``result_dir/ablations.json``.

    Args:
        result_dir: the folder :func:`run_ablations` wrote.
        relative_to: folder of the document the lines go into (the figure path is relative to it;
            None: ``result_dir``).

    Raises:
        FileNotFoundError: no ``ablations.json`` in ``result_dir``.
    """
    root = Path(result_dir)
    path = root / "ablations.json"
    if not path.is_file():
        raise FileNotFoundError(f"result_dir: expected {path} (run `mi-svbrdf ablations -o {root}`), got none")
    res = json.loads(path.read_text())
    cfg, arms = res["config"], res["arms"]
    figure = os.path.relpath(root / "ablations.png", Path(relative_to) if relative_to is not None else root)
    n_values = ", ".join(str(n) for n in cfg["n_values"])
    intro = (
        f"{len(arms)} arms trained from scratch for {cfg['steps']} steps each at {cfg['size']}² (batch "
        f"{cfg['batch_size']}, seed {cfg['seed']}, the same simulated batches within a group, net "
        f"`{json.dumps(cfg['net'])}`), then scored on the fixed held-out set ({cfg['heldout_materials']} materials at "
        f"{cfg['size']}², perturbed captures): single-image arms at N = 1, multi-image arms at N = {n_values} "
        f"(headline: the mean over N). Verdicts on the re-rendering RMSE (lower is better); a difference "
        f"below the noise threshold, max(2 × the paired standard error over the materials, the spread of "
        f"both arms' last {CURVE_POINTS} validation points), is called within noise. These are short CPU runs, "
        f"not the thesis's 400 k-step trainings: a verdict holds at this compute.")
    def took(a: dict[str, Any]) -> str:
        return f"{a['seconds']:.0f} s" if a["seconds"] < 120 else f"{a['seconds'] / 60:.1f} min"

    lines = [intro, "", markdown_table(
        ["arm", "setting", "steps", "train time", *(h for _, h, _ in TABLE)],
        [[name, a["note"], a["steps"], took(a), *(_num(a["summary"][k], f) for k, _, f in TABLE)]
         for name, a in arms.items()])]
    for c in res["comparisons"]:
        a, b = arms[c["baseline"]], arms[c["ablated"]]
        rows = [[h, _num(a["summary"][k], f), _num(b["summary"][k], f), _num(c["summary_deltas"][k], "+" + f)]
                for k, h, f in TABLE]
        if len(c["n"]) > 1:
            rows += [[f"render RMSE, {n}", _num(a["metrics"][n][PRIMARY], ".4f"), _num(b["metrics"][n][PRIMARY], ".4f"),
                      _num(c["deltas"][n][PRIMARY], "+.4f")] for n in c["n"]]
        rows.append(["noise threshold", "", "", f"{_num(c['noise'], '.4f')} (2 × SE {_num(c['paired_se'], '.4f')}, "
                                                f"curves {_num(c['curve_spread'], '.4f')})"])
        lines += ["", f"**{c['verdict'].capitalize()}.** {c['sentence']}", "",
                  markdown_table(["metric", c["baseline"], c["ablated"], "Δ (ablated − baseline)"], rows)]
    if not res["comparisons"]:
        lines += ["", "No comparison: each needs its baseline and ablated arm (see `--arms`)."]
    lines += ["", f"![ablations: validation curves and final per-map RMSE]({figure})"]
    return lines


def _colour(arm: str) -> str:
    """The arm's colour, the same in every panel."""
    return f"C{list(ARMS).index(arm) % 10}" if arm in ARMS else "k"


def plot_ablations(result: dict[str, Any], path: Path) -> None:
    """Validation re-render RMSE against step, one panel per group, and a bar chart of the final per-map RMSE."""
    plt = pyplot()
    arms = result["arms"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4), gridspec_kw={"width_ratios": [1, 1, 1.5]})
    for ax, group in zip(axes[:2], GROUPS):
        for name, a in arms.items():
            if a["group"] == group and a["curve"]:
                steps, values = zip(*a["curve"])
                ax.plot(steps, values, "o-", ms=3, label=name, color=_colour(name))
        if not ax.get_legend_handles_labels()[0]:
            ax.text(0.5, 0.5, "no validation curve (arms not run)", ha="center", va="center", transform=ax.transAxes)
        ax.set_title(f"{group}-image arms: validation")
        ax.set_xlabel("step")
        ax.set_ylabel("held-out re-render RMSE")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    keys = [k for k, _, _ in TABLE if k.startswith("rmse_") and not k.endswith("_scaled")]
    names = list(arms)
    width = 0.8 / max(1, len(names))
    x = np.arange(len(keys))
    for i, name in enumerate(names):
        axes[2].bar(x + (i - (len(names) - 1) / 2) * width, [arms[name]["summary"][k] for k in keys], width,
                    label=name, color=_colour(name))
    axes[2].set_xticks(x, [k.replace("rmse_", "") for k in keys])
    axes[2].set_ylabel("held-out RMSE (multi: mean over N)")
    axes[2].set_title("final nets")
    if names:
        axes[2].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    save_figure(fig, path)
