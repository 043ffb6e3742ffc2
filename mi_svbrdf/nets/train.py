"""Training of the single-image, multi-image and large-scale networks on online data (``mi-svbrdf train``).

Reads top to bottom: a :class:`TrainConfig` (one dataclass, unknown keys rejected), the data (the
capture simulator, :mod:`mi_svbrdf.data.simulator`, batch ``i`` of the stream is a pure function of
``(seed, i)``), the loss (rendering loss + ``map_weight`` x map L1: the thesis's 0 for the
single-image net and 0.1 for the multi-image net, ch. 4.2.3; the CPU recipes use 1, see RECIPES),
Adam, and a loop with checkpoints, validation, a CSV log and a PNG curve.

* **Checkpoints** (``run_dir/checkpoint.pt``: weights, optimiser, step, RNG, config, log) are
  written atomically every ``checkpoint_every_s`` seconds, at the end and on Ctrl-C / SIGTERM;
  ``--resume`` continues exactly: the data stream is indexed by the step, so the resumed run
  sees the batches the uninterrupted one would have seen.
* **Validation** every ``validate_every`` steps on a fixed held-out set (:mod:`mi_svbrdf.data.heldout`:
  separate seeds and held-out parameter ranges; training draws with ``holdout="train"``).
* **Devices** (``device``: ``cpu``, ``cuda``, ``cuda:N``): the network, Adam's state, every batch,
  the loss (its Dr.Jit kernels on the CUDA backend for CUDA tensors), validation and the capture
  simulator (materials, augmentation, rendering, photo pipeline: ``SimulatorConfig.device``) run on
  it; the large-scale data are made on the CPU and moved. Mixed
  precision (``bf16``): bf16 autocast on CPU; on CUDA bf16 or fp16 (``cuda_amp``; fp16 with a
  GradScaler). Checkpoints load onto the CPU first (``map_location``), so a GPU run resumes on a
  CPU and vice versa.
* **Multi-GPU / multi-node**: under ``torchrun`` the loop runs DistributedDataParallel (NCCL when
  ``device`` is CUDA, each process on ``cuda:LOCAL_RANK``; gloo on CPU); rank ``r`` of ``w`` trains
  on batches ``step * w + r`` (``batch_size`` is per process).
* **Resolution schedule** (``sizes``): a CPU run trains mostly at 128² and finishes at 256²
  (the nets are fully convolutional; the global track and instance norm carry over).
* **bf16 autocast** (``bf16``) pays off on CPUs with AVX-512 bf16 (roughly 2x faster steps, docs/guides/training.md).
* **Large-scale net** (``kind="large"``, ch. 5): the data are :mod:`mi_svbrdf.data.large_scale`'s
  (``simulator`` holds :class:`~mi_svbrdf.data.large_scale.LargeScaleConfig` overrides; the exemplar size
  is the net's), the loss is map L1 + rendering loss + MS-SSIM of the same renderings
  (``map_weight``, ``render_weight``, ``ms_ssim_weight``: 1, 1, 1 by default), validation uses
  :class:`~mi_svbrdf.data.large_scale.LargeScaleHeldOut` (``val_exemplars`` exemplars per sample) and
  the log's ``n_exemplars`` is E of the batch (0 to 3).

The thesis's learning rates (2e-5 single-image; 2e-4, beta1 = 0.5 multi-image) were chosen
for ~400 k-step GPU runs; a CPU run has a few thousand steps, so the default is 2e-4 with
beta1 = 0.5 for both, decayed by a cosine to ``lr * min_lr_factor`` over ``steps``. The GPU
recipes ``full-single`` and ``full-multi`` (RECIPES) use the thesis's settings.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import random
import signal
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser, as a package
    import tomli as tomllib

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.device import DEVICE_PATTERN, resolve_device
from mi_svbrdf.core.loss import map_l1, rendering_loss, rendering_ms_ssim_loss, resolve_preset
from mi_svbrdf.core.metrics import evaluate_maps
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.data.large_scale import LargeScaleConfig, LargeScaleData, LargeScaleHeldOut
from mi_svbrdf.data.simulator import CaptureSimulator, SimulatorConfig
from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.nets import weights as pretrained
from mi_svbrdf.nets.curve import plot_curve
from mi_svbrdf.nets.network import NetConfig, SVBRDFNet, build_network, network_config
from mi_svbrdf.plugins.model import DISTRIBUTIONS

CACHE = Path(os.environ.get("MI_SVBRDF_CACHE", Path.home() / ".cache" / "mi_svbrdf"))


@dataclass
class TrainConfig:
    """What ``mi-svbrdf train`` does; :meth:`from_dict` rejects unknown keys."""

    name: str = "single_compact"  #: run name; the run folder is ``out / name``
    out: str = str(CACHE / "runs")  #: folder of run folders (checkpoints stay out of git)
    preset: str = "compact"  #: network preset (mi_svbrdf.nets.network.PRESETS)
    kind: str = "single"  #: "single", "multi" or "large" (the by-example large-scale net, ch. 5)
    net: dict[str, Any] = field(default_factory=dict)  #: NetConfig overrides on top of the preset
    simulator: dict[str, Any] = field(default_factory=dict)  #: SimulatorConfig overrides (large: LargeScaleConfig's)
    #: capture settings taken in turn: batch i adds alternate[i % k] to the simulator's "capture" (none: one stream)
    alternate: list[dict[str, Any]] = field(default_factory=list)
    batch_size: int = 8  #: samples per step (per process under torchrun)
    sizes: list[list[int]] = field(default_factory=lambda: [[0, 256]])  #: [[from_step, size], ...] resolution schedule
    steps: int = 20000  #: total optimiser steps (the cosine schedule spans them)
    lr: float = 2e-4  #: Adam learning rate (see the module docstring)
    betas: tuple[float, float] = (0.5, 0.999)  #: Adam betas
    min_lr_factor: float = 0.1  #: final lr of the cosine decay, as a fraction of lr
    warmup: int = 200  #: linear warm-up steps
    loss_preset: str | None = None  #: rendering-loss preset (None: "2018" single, "2019" multi)
    map_weight: float | None = None  #: weight of the map L1 (None: 0 single, 0.1 multi, 1 large)
    normal_weight: float = 0.0  #: weight of an extra L1 on the normal map alone (on top of map_weight's), >= 0
    render_weight: float = 1.0  #: weight of the rendering loss (0: map L1 only, the ablation of ch. 3.1.3)
    ms_ssim_weight: float | None = None  #: weight of 1 - MS-SSIM of the loss's renderings (None: 1 large; else 0)
    grad_clip: float = 1.0  #: clip the gradient norm (0: off)
    bf16: bool = True  #: mixed precision for the network: bf16 autocast on CPU (AVX-512 bf16), ``cuda_amp`` on CUDA
    cuda_amp: str = "bf16"  #: autocast dtype on CUDA: "bf16" (Ampere and later) or "fp16" (with a GradScaler)
    device: str = "cpu"  #: "cpu", "cuda" or "cuda:N" (under torchrun "cuda" is cuda:LOCAL_RANK); net, batches, loss and validation run on it
    seed: int = 0  #: data stream and initialisation seed (training seeds are 0-999)
    init: str | None = None  #: warm start: a checkpoint, a weights file or "bundled:single" (matching tensors are copied)
    base: str | None = None  #: fused multi net (net.fusion): its frozen single-image branch's weights ("bundled:single")
    freeze: list[str] = field(default_factory=list)  #: parameter-name prefixes held fixed (e.g. "trunk."), kept in eval mode
    checkpoint_every_s: float = 300.0  #: seconds between checkpoints
    validate_every: int = 500  #: steps between validations (0: never)
    val_materials: int = 16  #: held-out materials for validation
    val_size: int = 128  #: resolution of the validation set
    val_images: int = 3  #: photos per validation material (multi); single always 1
    val_exemplars: int = 2  #: exemplars per validation sample (large)
    log_every: int = 10  #: steps between CSV log lines
    threads: int = 0  #: torch intra-op threads (0: torch's default)
    distribution: str = "ggx"  #: output BRDF model, "ggx" or "beckmann", in loss and validation (ground truth: GGX)

    def __post_init__(self) -> None:
        self.betas = tuple(self.betas)
        self.sizes = sorted([list(s) for s in self.sizes])
        check_fields([
            ("kind", self.kind in ("single", "multi", "large"), "'single', 'multi' or 'large'", self.kind),
            ("ms_ssim_weight", self.ms_ssim_weight is None or self.ms_ssim_weight >= 0, "None or a weight >= 0",
             self.ms_ssim_weight),
            ("val_exemplars", isinstance(self.val_exemplars, int) and self.val_exemplars >= 0, "an int >= 0",
             self.val_exemplars),
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ("batch_size", "steps")),
            ("lr", self.lr > 0, "a learning rate > 0", self.lr),
            ("net", isinstance(self.net, dict), "a dict of NetConfig fields", self.net),
            ("simulator", isinstance(self.simulator, dict), "a dict of SimulatorConfig fields", self.simulator),
            ("render_weight", self.render_weight >= 0 and (self.render_weight > 0 or bool(self.map_weight)),
             "a weight >= 0 (0 only with a map_weight > 0)", self.render_weight),
            ("normal_weight", self.normal_weight >= 0, "a weight >= 0", self.normal_weight),
            ("device", isinstance(self.device, str) and DEVICE_PATTERN.match(self.device) is not None,
             "cpu, cuda or cuda:N", self.device),
            ("cuda_amp", self.cuda_amp in ("bf16", "fp16"), "'bf16' or 'fp16'", self.cuda_amp),
            ("distribution", self.distribution in DISTRIBUTIONS, f"one of {DISTRIBUTIONS}", self.distribution),
            ("alternate", isinstance(self.alternate, list) and all(isinstance(a, dict) for a in self.alternate)
             and (not self.alternate or self.kind != "large"),
             "a list of CaptureConfig overrides (not for kind 'large')", self.alternate),
            ("freeze", isinstance(self.freeze, list) and all(isinstance(f, str) and f for f in self.freeze),
             "a list of parameter-name prefixes", self.freeze),
            ("base", self.base is None or self.net.get("fusion", False),
             "None unless net.fusion is on (the single-image branch of the fused multi-image net)", self.base),
            ("sizes", bool(self.sizes) and self.sizes[0][0] == 0 and all(len(s) == 2 and s[1] >= 8 for s in self.sizes),
             "[[0, size], [step, size], ...] with sizes >= 8", self.sizes),
        ], owner="TrainConfig")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """Build from a dict (a JSON config file); unknown keys raise ``ValueError``."""
        return from_dict(cls, data)

    @property
    def net_config(self) -> NetConfig:
        return network_config(self.preset, self.kind, **self.net)

    @property
    def run_dir(self) -> Path:
        """The run folder, ``out / name``: checkpoint.pt, config.json, log.csv, curve.png."""
        return Path(self.out).expanduser() / self.name

    def size_at(self, step: int) -> int:
        """Training resolution at ``step``."""
        return [s for start, s in self.sizes if start <= step][-1]


#: The file of training recipes, package data of :mod:`mi_svbrdf.nets`: one TOML table per recipe, its
#: ``description`` (one line) and the :class:`TrainConfig` fields it sets.
RECIPES_FILE = "recipes.toml"


def load_recipes(path: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """The training recipes (``name -> TrainConfig fields``) of ``path`` (default: the package's
    :data:`RECIPES_FILE`), without their descriptions (:func:`recipe_descriptions`), in the file's order."""
    return _fields(_read_recipes(path))


def recipe_descriptions(path: str | Path | None = None) -> dict[str, str]:
    """Each recipe's one-line description (``name -> text``) from ``path`` (default: :data:`RECIPES_FILE`)."""
    return _descriptions(_read_recipes(path))


def _fields(tables: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {name: {k: v for k, v in recipe.items() if k != "description"} for name, recipe in tables.items()}


def _descriptions(tables: dict[str, dict[str, Any]]) -> dict[str, str]:
    return {name: recipe["description"] for name, recipe in tables.items()}


def _read_recipes(path: str | Path | None) -> dict[str, dict[str, Any]]:
    text = (Path(path).read_text() if path is not None
            else resources.files("mi_svbrdf.nets").joinpath(RECIPES_FILE).read_text())
    recipes = tomllib.loads(text)
    for name, recipe in recipes.items():
        if not isinstance(recipe, dict) or not isinstance(recipe.get("description"), str):
            raise ValueError(f"{path or RECIPES_FILE}: recipe {name!r}: expected a table with a one-line "
                             f"'description', got {recipe!r}")
    return recipes


#: Training recipes (:data:`RECIPES_FILE`): ``single`` / ``multi`` / ``large`` made the bundled (compact, CPU)
#: weights; ``full-single`` / ``full-multi`` / ``full-large`` are the thesis's GPU settings for the ``full``
#: nets (run them with ``--device cuda``); the others fine-tune the bundled nets. History: docs/guides/training.md.
_RECIPE_TABLES = _read_recipes(None)  # the package's file, read once
RECIPES: dict[str, dict[str, Any]] = _fields(_RECIPE_TABLES)
#: One-line description of each recipe of :data:`RECIPES`.
RECIPE_DESCRIPTIONS: dict[str, str] = _descriptions(_RECIPE_TABLES)


def load_config(spec: str, overrides: dict[str, Any] | None = None) -> TrainConfig:
    """A recipe name (:data:`RECIPES`: ``"single"``, ``"multi"``, ``"large"``, ``"full-single"``, ``"full-multi"``,
    ``"full-large"`` ...) or a JSON file, with ``overrides``."""
    if spec in RECIPES:
        data = dict(RECIPES[spec])
    else:
        path = Path(spec)
        if not path.is_file():
            raise ValueError(f"config: expected a recipe {sorted(RECIPES)} or a JSON file, got {spec!r}")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: expected a JSON object, got invalid JSON ({exc})") from exc
    return TrainConfig.from_dict({**data, **(overrides or {})})


# --- data -------------------------------------------------------------------------------------

class _Alternating:
    """Capture simulators taken in turn: batch ``i`` is ``streams[i % k].batch(i)`` (still a pure function of ``i``)."""

    def __init__(self, streams: list[CaptureSimulator]) -> None:
        self.streams = streams

    def batch(self, index: int) -> Any:
        return self.streams[index % len(self.streams)].batch(index)


def make_simulator(cfg: TrainConfig, size: int, device: torch.device | None = None):
    """The training stream at ``size``: held-out parameter ranges excluded (large: :class:`LargeScaleData`,
    its exemplars at the net's ``exemplar_size``, made on the CPU). The capture simulator makes its
    batches on ``device`` (None: the CPU) unless ``cfg.simulator`` names a ``device``; with
    ``cfg.alternate``, one simulator per entry (its capture settings added), taken in turn."""
    if cfg.alternate:
        base = dict(cfg.simulator.get("capture", {}))
        return _Alternating([make_simulator(dataclasses.replace(cfg, alternate=[], simulator={
            **cfg.simulator, "capture": {**base, **extra}}), size, device) for extra in cfg.alternate])
    if cfg.kind == "large":
        return LargeScaleData(LargeScaleConfig.from_dict({"exemplar_size": cfg.net_config.exemplar_size,
                                                          "holdout": "train", **cfg.simulator, "size": size,
                                                          "batch_size": cfg.batch_size, "seed": cfg.seed}))
    sim = {"holdout": "train", "device": str(device or "cpu"), **cfg.simulator}
    if "n_images" in sim:
        sim["n_images"] = tuple(sim["n_images"])
    return CaptureSimulator(SimulatorConfig.from_dict({**sim, "size": size, "batch_size": cfg.batch_size,
                                                       "seed": cfg.seed}))


# --- loss -------------------------------------------------------------------------------------

def training_loss(cfg: TrainConfig, pred: torch.Tensor, maps: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Rendering loss (+ map L1, + 1 - MS-SSIM of the same renderings) with configurations drawn from ``gen``."""
    preset = cfg.loss_preset or ("2018" if cfg.kind == "single" else "2019")
    weight = cfg.map_weight if cfg.map_weight is not None else {"single": 0.0, "multi": 0.1}.get(cfg.kind, 1.0)
    ms_weight = cfg.ms_ssim_weight if cfg.ms_ssim_weight is not None else (1.0 if cfg.kind == "large" else 0.0)
    p = resolve_preset(preset)  # the draws rendering_loss makes from gen, shared with the MS-SSIM term
    configs = sample_configurations(pred.shape[0], p.n_diffuse, p.n_specular, r1_max=p.r1_max, generator=gen,
                                    device=pred.device)
    loss = (cfg.render_weight * rendering_loss(pred, maps, preset=preset, configurations=configs,
                                               distribution=cfg.distribution, target_distribution="ggx")
            if cfg.render_weight else 0.0)
    if ms_weight:
        loss = loss + ms_weight * rendering_ms_ssim_loss(pred, maps, configs, preset=preset,
                                                         distribution=cfg.distribution, target_distribution="ggx")
    if cfg.normal_weight:
        normal = M.SLICES["normal"]
        loss = loss + cfg.normal_weight * (pred[:, normal] - maps[:, normal]).abs().mean()
    return loss + weight * map_l1(pred, maps) if weight else loss


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up, then cosine decay to ``lr * min_lr_factor`` at ``steps``."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = min(1.0, (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup))
    return cfg.lr * (cfg.min_lr_factor + (1 - cfg.min_lr_factor) * 0.5 * (1 + math.cos(math.pi * t)))


# --- checkpoints ------------------------------------------------------------------------------

def save_checkpoint(path: Path, net: SVBRDFNet, opt: torch.optim.Optimizer, step: int, cfg: TrainConfig,
                    log: list[dict[str, Any]], seconds: float, scaler: torch.amp.GradScaler | None = None) -> None:
    """Everything needed to resume, written atomically (tensors as they are; :func:`load_state` maps
    them to the CPU)."""
    state = {"model": net.state_dict(), "optimizer": opt.state_dict(), "step": step, "seconds": seconds,
             "config": dataclasses.asdict(cfg), "net_config": net.config.to_dict(), "log": log,
             "rng": _rng_state(), "scaler": scaler.state_dict() if scaler is not None and scaler.is_enabled() else None}
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def _rng_state() -> dict[str, Any]:
    """The torch, numpy and Python random states (a checkpoint's ``"rng"``)."""
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def _set_rng_state(rng: dict[str, Any]) -> None:
    """Restore the states of :func:`_rng_state`."""
    torch.set_rng_state(rng["torch"])
    np.random.set_state(rng["numpy"])
    random.setstate(rng["python"])


def load_state(path: str | Path) -> dict[str, Any]:
    """A checkpoint or weights file, its tensors on the CPU (``map_location``: a checkpoint written on
    a GPU loads on a CPU-only machine; the caller moves the net to its device)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise ValueError(f"init/resume: expected a checkpoint file, got {str(path)!r} (not found)")
    return torch.load(path, map_location="cpu", weights_only=False)


def warm_start(net: SVBRDFNet, path: str | Path) -> int:
    """Copy every tensor of ``path`` whose name and shape match into ``net``; from a net of another
    kind, only the shared U-Net trunk (e.g. the single-image trunk into the multi-image net: the
    extra coordinate input channels start at zero), and from a single-image net into a large-scale
    one its head too (the exemplar columns of the decoder start at zero: the warm-started large-scale
    net is the single-image net). Returns how many tensors were copied."""
    kind = None
    if str(path).startswith("bundled:"):
        entry = pretrained.manifest_entry(str(path).split(":", 1)[1], pretrained.WEIGHTS_DIR)
        state: dict[str, Any] = pretrained.read_weights(pretrained.WEIGHTS_DIR / entry["file"])
        kind = entry["net_config"]["kind"]  # a bundled file is a bare state dict: its kind is in the manifest
    else:
        state = load_state(path)
    source = state.get("model", state.get("state_dict", state))
    if kind is None:
        kind = state.get("net_config", {}).get("kind") or (
            "large" if any(k.startswith("exemplar_encoder.") for k in source)
            else "multi" if any(k.startswith("fuse.") for k in source) else "single")
    same_kind = kind == net.config.kind
    head_too = kind == "single" and net.config.kind == "large"
    own = net.state_dict()
    copied = 0
    for name, value in source.items():
        if name not in own or not (same_kind or name.startswith("trunk.") or (head_too and name.startswith("head."))):
            continue
        target = own[name]
        value = value.to(target.dtype)
        if value.shape == target.shape:
            own[name] = value
            copied += 1
        elif value.dim() == 4 and value.shape[0] == target.shape[0] and value.shape[1] < target.shape[1]:
            own[name] = torch.cat([value, torch.zeros_like(target[:, value.shape[1]:])], dim=1)
            copied += 1
    net.load_state_dict(own)
    return copied


def freeze(net: torch.nn.Module, prefixes: list[str]) -> int:
    """Hold the parameters whose names start with one of ``prefixes`` fixed (``requires_grad=False``); an
    :class:`~mi_svbrdf.nets.network.SVBRDFNet` keeps a submodule left with no trainable parameter in
    eval mode (no dropout).
    Returns how many tensors were frozen.

    Raises:
        ValueError: a prefix that names no parameter.
    """
    names = [name for name, _ in net.named_parameters()]
    for prefix in prefixes:
        if not any(name.startswith(prefix) for name in names):
            raise ValueError(f"freeze: expected prefixes of parameter names (e.g. {names[0]!r}), got {prefix!r}")
    count = 0
    for name, p in net.named_parameters():
        if any(name.startswith(prefix) for prefix in prefixes):
            p.requires_grad_(False)
            count += 1
    net.train(net.training)  # an SVBRDFNet puts its fully frozen submodules in eval mode
    return count


# --- validation -------------------------------------------------------------------------------

def autocast(cfg: TrainConfig, device: torch.device) -> torch.autocast:
    """The network's mixed precision on ``device``: bf16 on CPU, ``cfg.cuda_amp`` on CUDA (off unless ``cfg.bf16``)."""
    fp16 = device.type == "cuda" and cfg.cuda_amp == "fp16"
    return torch.autocast(device.type, dtype=torch.float16 if fp16 else torch.bfloat16, enabled=cfg.bf16)


def grad_scaler(cfg: TrainConfig, device: torch.device) -> torch.amp.GradScaler:
    """A GradScaler, enabled only for fp16 autocast on CUDA (bf16 needs none)."""
    enabled = cfg.bf16 and device.type == "cuda" and cfg.cuda_amp == "fp16"
    return torch.amp.GradScaler("cuda", enabled=enabled)


def validate(net: SVBRDFNet, cfg: TrainConfig, data: tuple[torch.Tensor, torch.Tensor, Any]) -> dict[str, float]:
    """Held-out metrics (:func:`mi_svbrdf.core.metrics.evaluate_maps`) of ``net`` in eval mode.

    The net runs on its own device (the held-out inputs are moved there in chunks of 4); the
    predictions come back to the CPU, where the held-out maps live, for the metrics.
    """
    maps, inputs, extra = data  # large: (maps, photos, exemplars)
    device = next(net.parameters()).device

    def run(i: int) -> torch.Tensor:
        args = (inputs[i:i + 4].to(device),) + ((extra[i:i + 4].to(device),) if cfg.kind == "large" else ())
        return net(*args).float().to(maps.device)

    net.eval()
    with torch.no_grad(), autocast(cfg, device):
        pred = torch.cat([run(i) for i in range(0, inputs.shape[0], 4)])
    net.train()
    # core.metrics.eval_lights makes its lights on the default device: pin it to the maps' one
    with torch.device(maps.device):
        return {f"val_{k}": v for k, v in evaluate_maps(pred, maps, distribution=cfg.distribution).items()}


def validation_set(cfg: TrainConfig, progress: bool = True) -> tuple[torch.Tensor, torch.Tensor, Any]:
    """The fixed held-out set of ``cfg`` (:class:`mi_svbrdf.data.heldout.HeldOutSet`): ``(maps, inputs, captures)``;
    large: ``(maps, photos, exemplars)`` of :class:`~mi_svbrdf.data.large_scale.LargeScaleHeldOut` with the
    run's data settings; ``progress``: a bar while it is built (the first time, when not cached)."""
    if cfg.kind == "large":
        return LargeScaleHeldOut.for_training({"exemplar_size": cfg.net_config.exemplar_size, **cfg.simulator},
                                              size=cfg.val_size, materials=cfg.val_materials,
                                              n_exemplars=cfg.val_exemplars).load(progress)
    n = 1 if cfg.kind == "single" else cfg.val_images
    preset = cfg.simulator.get("preset", "single_flash" if cfg.kind == "single" else "multiview")
    return HeldOutSet(size=cfg.val_size, materials=cfg.val_materials, n_images=n, preset=preset).load(progress)


def write_log(log: list[dict[str, Any]], path: Path) -> None:
    keys = sorted({k for r in log for k in r}, key=lambda k: (k != "step", k != "seconds", k))
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(log)


# --- the loop ---------------------------------------------------------------------------------

def _start(cfg: TrainConfig, ckpt_path: Path | None, device: torch.device | None = None,
           scaler: torch.amp.GradScaler | None = None) -> tuple[SVBRDFNet, torch.optim.Optimizer, int, float,
                                                                list[dict[str, Any]]]:
    """The seeded network on ``device`` (None: the CPU) and its Adam: ``(net, opt, step, seconds, log)``.

    Resumed from ``ckpt_path`` when given and present (weights, Adam state, step, time, log, RNG
    states and ``scaler``'s state: the run continues exactly), else fresh and warm-started from
    ``cfg.init``. The net is initialised on the CPU (the same weights for every device) and then
    moved; Adam is built after the move, so its resumed state lands on ``device`` too.
    """
    device = torch.device("cpu") if device is None else device
    torch.manual_seed(cfg.seed)
    net = build_network(cfg.net_config)
    state = None
    if ckpt_path is not None and ckpt_path.is_file():
        state = load_state(ckpt_path)
        if state["net_config"] != cfg.net_config.to_dict():
            raise ValueError(f"--resume: {ckpt_path} was trained with {state['net_config']}, "
                             f"expected {cfg.net_config.to_dict()}")
        net.load_state_dict(state["model"])
    else:
        if cfg.init:
            warm_start(net, cfg.init)
        if cfg.base:
            warm_start(net.single, cfg.base)
    freeze(net, cfg.freeze)
    net.to(device)
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=cfg.lr, betas=cfg.betas)
    if state is None:
        return net, opt, 0, 0.0, []
    opt.load_state_dict(state["optimizer"])  # Adam's moments follow the parameters' device
    if scaler is not None and state.get("scaler"):
        scaler.load_state_dict(state["scaler"])
    _set_rng_state(state["rng"])
    return net, opt, state["step"], state["seconds"], state["log"]


class _StopRequest:
    """While installed, Ctrl-C / SIGTERM only set :attr:`requested`: the loop finishes its step,
    checkpoints and returns."""

    def __init__(self) -> None:
        self.requested = False
        self._old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def _on_signal(self, signum: int, frame: Any) -> None:
        self.requested = True

    def restore(self) -> None:
        """Put back the handlers that were installed before."""
        for s, handler in self._old.items():
            signal.signal(s, handler)


#: The phases of a training step :func:`_train_step` times (seconds each; the simulator's batch is timed by the loop).
STEP_PHASES = ("forward", "loss", "backward", "optimiser")


class _PhaseClock:
    """Wall time of consecutive phases of a step, the device synchronised at each boundary (CUDA runs
    asynchronously: without it a phase would be charged to the next one that waits)."""

    def __init__(self, device: torch.device, times: dict[str, float] | None) -> None:
        self.times, self.cuda = times, device.type == "cuda"
        self.last = self._now()

    def _now(self) -> float:
        if self.times is not None and self.cuda:
            torch.cuda.synchronize()
        return time.perf_counter()

    def lap(self, phase: str) -> None:
        if self.times is not None:
            now = self._now()
            self.times[phase] = self.times.get(phase, 0.0) + now - self.last
            self.last = now


def _train_step(cfg: TrainConfig, model: torch.nn.Module, net: SVBRDFNet, opt: torch.optim.Optimizer, batch: Any,
                step: int, index: int, ckpt_path: Path, device: torch.device | None = None,
                scaler: torch.amp.GradScaler | None = None,
                times: dict[str, float] | None = None) -> tuple[float, int]:
    """One Adam step on ``batch`` (stream index ``index``) at the scheduled lr on ``device`` (None: the
    net's); returns the loss and the photos per sample (large: the exemplars per sample).

    The batch is moved to ``device``, where the loss's Dr.Jit kernels run (whatever Mitsuba variant is
    active). ``scaler`` (fp16 on CUDA) scales the loss; None or a disabled one is a plain step. ``times``:
    a dict the seconds of each of :data:`STEP_PHASES` are added to (the device synchronised between them);
    None: not timed. The loss's phase holds its forward and its backward to the net's output (the rendering
    loss's kernels); the backward phase holds the net's.
    """
    device = next(net.parameters()).device if device is None else device
    clock = _PhaseClock(device, times)
    for group in opt.param_groups:
        group["lr"] = learning_rate(cfg, step)
    if cfg.kind == "large":  # an ambient photo and its exemplars (E per sample, possibly 0)
        inputs = (batch.photo.to(device, non_blocking=True), batch.exemplars.to(device, non_blocking=True))
        count = batch.n_exemplars
    else:
        photos = batch.inputs[:, :1] if cfg.kind == "single" else batch.inputs
        inputs, count = (photos.to(device, non_blocking=True),), int(photos.shape[1])
    maps = batch.maps.to(device, non_blocking=True)
    with autocast(cfg, device):
        pred = model(*inputs)
    clock.lap("forward")
    gen = torch.Generator().manual_seed(cfg.seed * 1_000_003 + index)  # configurations: drawn on the CPU, moved
    out = pred.float().detach().requires_grad_()  # the loss's own graph ends at the net's output
    loss = training_loss(cfg, out, maps, gen)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"step {step}: the training loss is {float(loss)}; "
                                 f"resume from {ckpt_path} with a lower lr")
    scaled = scaler.scale(loss) if scaler is not None and scaler.is_enabled() else loss
    (grad_out,) = torch.autograd.grad(scaled, out)
    clock.lap("loss")
    opt.zero_grad(set_to_none=True)
    pred.float().backward(grad_out)  # the same gradients as scaled.backward() through pred
    clock.lap("backward")
    if scaler is not None and scaler.is_enabled():  # CUDA fp16 only
        if cfg.grad_clip:
            scaler.unscale_(opt)
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
        scaler.step(opt)
        scaler.update()
    else:
        norm = torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip or math.inf)
        if not torch.isfinite(norm):  # a NaN gradient would turn every weight (and the next checkpoint) into NaN
            warnings.warn(f"train: step {step}: non-finite gradient norm; step skipped (weights unchanged)",
                          RuntimeWarning, stacklevel=2)
            opt.zero_grad(set_to_none=True)
            return loss.item(), count
        opt.step()
    clock.lap("optimiser")
    return loss.item(), count


def _process_device(cfg: TrainConfig, distributed: bool) -> torch.device:
    """This process's device: ``cfg.device``; under torchrun a CUDA device is ``cuda:LOCAL_RANK``."""
    device = resolve_device(cfg.device)
    if distributed and device.type == "cuda":
        device = resolve_device(f"cuda:{int(os.environ.get('LOCAL_RANK', '0'))}")
        torch.cuda.set_device(device)
    return device


def breakdown_line(times: dict[str, float], steps: int, device: torch.device) -> str:
    """Where a step's time went: the mean ms of the simulator and each of :data:`STEP_PHASES` over ``steps``
    timed steps, and the steps per second they add up to.

    Examples:
        >>> breakdown_line({"simulator": 0.2, "forward": 0.1, "loss": 0.05, "backward": 0.1, "optimiser": 0.05},
        ...                2, torch.device("cpu"))  # doctest: +ELLIPSIS
        'train: a step on cpu (mean of 2 timed steps): simulator 100.0 ms, forward 50.0 ms, ...; 4.00 steps/s'
    """
    parts = {k: 1e3 * times.get(k, 0.0) / steps for k in ("simulator", *STEP_PHASES)}
    total = sum(parts.values())
    text = ", ".join(f"{k} {v:.1f} ms" for k, v in parts.items())
    return (f"train: a step on {device} (mean of {steps} timed steps): {text}; "
            f"{1e3 / total if total > 0 else float('inf'):.2f} steps/s")


def stop_line(run: Path, first: int, step: int, total: int, reason: str) -> str:
    """The line a run ends with: steps done by this call, why it stopped, where its checkpoint is.

    Args:
        run: the run folder (``checkpoint.pt`` in it).
        first: the step this call started from (0, or the resumed checkpoint's).
        step: the step it stopped at.
        total: ``cfg.steps``.
        reason: why it stopped (``"all steps done"``, ``"time limit (1 min) reached"``, ...).
    """
    resumed = f", resumed from step {first}" if first else ""
    more = "; continue with --resume" if step < total else ""
    return (f"train: stopped at step {step} of {total} ({step - first} steps this run{resumed}): {reason}; "
            f"checkpoint {run / 'checkpoint.pt'}{more}")


def train(cfg: TrainConfig, resume: bool = False, max_seconds: float = math.inf,
          progress: bool = True, report: Callable[[str], None] | None = None) -> Path:
    """Train until ``cfg.steps`` (or ``max_seconds`` of this call) on ``cfg.device``; returns the run folder.

    Args:
        cfg: the run.
        resume: continue from the run folder's checkpoint.
        max_seconds: stop (with a checkpoint) after this long.
        progress: progress bars (the held-out validation set's, when it is built, and the steps').
        report: called on rank 0 with the run's last line (:func:`stop_line`: steps done, why it stopped, the
            checkpoint), also when it stops on an error; None: silent.

    Raises:
        ValueError: a bad ``cfg.device`` (e.g. ``cuda`` on a machine without CUDA).
    """
    import torch.distributed as dist

    distributed = "RANK" in os.environ and "WORLD_SIZE" in os.environ
    device = _process_device(cfg, distributed)
    rank, world = 0, 1
    if distributed:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
        rank, world = dist.get_rank(), dist.get_world_size()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    run = cfg.run_dir
    run.mkdir(parents=True, exist_ok=True)
    ckpt_path = run / "checkpoint.pt"
    scaler = grad_scaler(cfg, device)
    net, opt, step, seconds, log = _start(cfg, ckpt_path if resume else None, device, scaler)
    if rank == 0:
        write_json(run / "config.json", dataclasses.asdict(cfg))
    if distributed:
        ids = [device.index] if device.type == "cuda" else None  # large: E = 0 batches leave the exemplar encoder out
        model = torch.nn.parallel.DistributedDataParallel(net, device_ids=ids,
                                                          find_unused_parameters=cfg.kind == "large")
    else:
        model = net
    val_data = validation_set(cfg, progress) if cfg.validate_every and rank == 0 else None

    stop = _StopRequest()
    sim, sim_size = None, None
    start, last_ckpt = time.perf_counter(), time.perf_counter()
    bar = tqdm(total=cfg.steps, initial=step, disable=not progress or rank != 0, desc=cfg.name, smoothing=0.05)
    window: list[float] = []
    phases = ("simulator", *STEP_PHASES)
    window_times: dict[str, float] = {}
    total_times: dict[str, float] = {}
    timed_steps = [0, 0]  # in the window, in the run
    first, reason = step, "interrupted"
    try:
        while step < cfg.steps and not stop.requested and time.perf_counter() - start < max_seconds:
            size = cfg.size_at(step)
            if size != sim_size:
                sim, sim_size = make_simulator(cfg, size, device), size
            # Timed steps: all on a CPU; on CUDA the last of each log window (timing synchronises the device).
            timed = device.type != "cuda" or (step + 1) % cfg.log_every == 0
            times: dict[str, float] | None = {} if timed else None
            t0 = time.perf_counter()
            batch = sim.batch(step * world + rank)  # made on the training device (large-scale: the CPU)
            t_data = time.perf_counter() - t0
            value, n_images = _train_step(cfg, model, net, opt, batch, step, step * world + rank, ckpt_path,
                                          device, scaler, times)
            if times is not None:
                times["simulator"] = t_data
                for acc in (window_times, total_times):
                    for k, v in times.items():
                        acc[k] = acc.get(k, 0.0) + v
                timed_steps[0] += 1
                timed_steps[1] += 1
            step += 1
            window.append(value)
            bar.update(1)
            bar.set_postfix(loss=f"{value:.4f}", size=size, data=f"{t_data:.2f}s")
            now = time.perf_counter()
            if rank != 0:
                continue
            if step % cfg.log_every == 0:
                log.append({"step": step, "seconds": round(seconds + now - start, 2), "loss": float(np.mean(window)),
                            "lr": learning_rate(cfg, step - 1), "size": size,
                            ("n_exemplars" if cfg.kind == "large" else "n_images"): n_images,
                            **{f"ms_{k}": round(1e3 * window_times.get(k, 0.0) / max(timed_steps[0], 1), 2)
                               for k in phases}})
                window, window_times, timed_steps[0] = [], {}, 0
            if val_data is not None and step % cfg.validate_every == 0:
                log.append({"step": step, "seconds": round(seconds + now - start, 2), **validate(net, cfg, val_data)})
            if now - last_ckpt > cfg.checkpoint_every_s:
                _save_all(run, net, opt, step, cfg, log, seconds + now - start, scaler)
                last_ckpt = time.perf_counter()
        reason = ("all steps done" if step >= cfg.steps else "stop requested (Ctrl-C or SIGTERM)" if stop.requested
                  else f"time limit ({max_seconds / 60:g} min) reached")
    except BaseException as exc:
        reason = f"error: {type(exc).__name__}: {exc}"
        raise
    finally:
        bar.close()
        stop.restore()
        if rank == 0:
            _save_all(run, net, opt, step, cfg, log, seconds + time.perf_counter() - start, scaler)
            if report is not None:
                if timed_steps[1]:
                    report(breakdown_line(total_times, timed_steps[1], device))
                report(stop_line(run, first, step, cfg.steps, reason))
        if distributed:
            dist.destroy_process_group()
    return run


def _save_all(run: Path, net: SVBRDFNet, opt: torch.optim.Optimizer, step: int, cfg: TrainConfig,
              log: list[dict[str, Any]], seconds: float, scaler: torch.amp.GradScaler | None = None) -> None:
    """Checkpoint, and the log as CSV and PNG curve."""
    save_checkpoint(run / "checkpoint.pt", net, opt, step, cfg, log, seconds, scaler)
    if log:
        write_log(log, run / "log.csv")
        plot_curve(log, run / "curve.png")
