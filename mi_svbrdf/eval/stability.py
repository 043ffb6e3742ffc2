"""Stability measures of SVBRDF recovery methods (issue 6 §2): finiteness, noise sensitivity, permutations.

A *method* is a function ``method(inputs (B, N, 3, H, W) linear photos, captures) -> maps
(B, 10, H, W)``; :func:`baseline_method`, :func:`network_method` and :func:`optimizer_method`
wrap the toolkit's four methods (trivial baseline, single net, multi net, optimiser) that way.

* :func:`finite_and_in_range`: the contract every output must meet, even on the failure cases
  of :mod:`mi_svbrdf.eval.failure_cases`.
* :func:`perturbation_sensitivity`: how much the maps move when every photo gets noise of
  1/255 (max and mean absolute change per map).
* :func:`permutation_invariance`: how much they move when the N photos (and their captures)
  are reordered; 0 up to float error for the multi-image net (max-pooling over photos).
* :func:`run_optimizer`: :func:`mi_svbrdf.optimize` per sample, reporting its recoveries and
  whether it ended finite.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core import maps as M
    >>> from mi_svbrdf.eval.stability import finite_and_in_range
    >>> finite_and_in_range(M.constant_maps(1, 4, 4)), finite_and_in_range(M.constant_maps(1, 4, 4, roughness=1.5))
    (True, False)
"""
from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.data.photo_setups import Captures

#: ``method(inputs (B, N, 3, H, W), captures) -> maps (B, 10, H, W)``.
Method = Callable[[torch.Tensor, Captures], torch.Tensor]
#: Tolerances of :func:`finite_and_in_range`: on the unit length of normals, and outside [0, 1].
NORMAL_TOL, RANGE_TOL = 1e-3, 1e-6


def finite_and_in_range(maps: torch.Tensor) -> bool:
    """Whether ``maps`` is a valid output.

    Definition: a ``(B, 10, H, W)`` floating tensor, every value finite; normals of unit length
    (``| |n| - 1 | <= NORMAL_TOL``) facing out of the surface (``n.z >= 0``); diffuse,
    roughness and specular in ``[0, 1]`` (within ``RANGE_TOL``).
    """
    if not isinstance(maps, torch.Tensor) or maps.dim() != 4 or maps.shape[1] != M.NUM_CHANNELS:
        return False
    if not maps.is_floating_point() or not bool(torch.isfinite(maps).all()):
        return False
    n = M.normal(maps)
    if not bool(((n.norm(dim=1) - 1.0).abs() <= NORMAL_TOL).all()) or not bool((n[:, 2] >= 0).all()):
        return False
    rest = maps[:, 3:]
    return bool(((rest >= -RANGE_TOL) & (rest <= 1.0 + RANGE_TOL)).all())


def check_inputs(inputs: torch.Tensor, captures: Captures) -> None:
    """``inputs (B, N, 3, H, W)`` and ``captures`` of the same B, N, or a ``ValueError``."""
    if not isinstance(inputs, torch.Tensor) or inputs.dim() != 5 or inputs.shape[2] != 3:
        shape = tuple(inputs.shape) if isinstance(inputs, torch.Tensor) else type(inputs).__name__
        raise ValueError(f"inputs: expected shape (B, N, 3, H, W), got {shape}")
    if (captures.batch_size, captures.n_images) != tuple(inputs.shape[:2]):
        raise ValueError(f"captures: expected B, N = {tuple(inputs.shape[:2])} like inputs, "
                         f"got {(captures.batch_size, captures.n_images)}")


def _changes(a: torch.Tensor, b: torch.Tensor) -> dict[str, dict[str, float]]:
    """Max and mean absolute change of each map (and of all channels, ``"all"``)."""
    diff = (a - b).abs()
    out = {k: {"max": float(diff[:, s].max()), "mean": float(diff[:, s].mean())} for k, s in M.SLICES.items()}
    out["all"] = {"max": float(diff.max()), "mean": float(diff.mean())}
    return out


def perturbation_sensitivity(method: Method, inputs: torch.Tensor, captures: Captures, noise: float = 1 / 255,
                             trials: int = 3, seed: int = 0) -> dict[str, dict[str, float]]:
    """Change of ``method``'s maps when the photos get a small perturbation.

    Each trial adds independent noise uniform in ``[-noise, noise]`` to every photo value and
    clips to [0, 1] (so no value moves by more than ``noise``), and compares the maps with
    those of the unperturbed photos.

    Args:
        method: see :data:`Method`.
        inputs: ``(B, N, 3, H, W)`` linear photos in [0, 1].
        captures: their captures.
        noise: the amplitude (default one 8-bit step, 1/255), >= 0.
        trials: perturbations drawn, >= 1.
        seed: seed of the perturbations.

    Returns:
        ``{map: {"max": ..., "mean": ...}}`` for normal, diffuse, roughness, specular and
        ``"all"``: max over trials of the max absolute change, mean over trials of the mean.
    """
    check_inputs(inputs, captures)
    if not (noise >= 0 and isinstance(trials, int) and trials >= 1):
        raise ValueError(f"noise, trials: expected >= 0 and an int >= 1, got {noise!r}, {trials!r}")
    gen = torch.Generator().manual_seed(seed)
    base = method(inputs, captures)
    runs = []
    for _ in range(trials):
        delta = (torch.rand(inputs.shape, generator=gen) * 2.0 - 1.0) * noise
        runs.append(_changes(method((inputs + delta.to(inputs)).clamp(0.0, 1.0), captures), base))
    return {k: {"max": max(r[k]["max"] for r in runs), "mean": sum(r[k]["mean"] for r in runs) / trials}
            for k in runs[0]}


def permutation_invariance(method: Method, inputs: torch.Tensor, captures: Captures,
                           permutation: torch.Tensor | None = None) -> float:
    """Max absolute difference of ``method``'s maps when the N photos and their captures are reordered.

    Args:
        method, inputs, captures: as :func:`perturbation_sensitivity`.
        permutation: a permutation of ``range(N)``; default the reversed order.
    """
    check_inputs(inputs, captures)
    n = inputs.shape[1]
    perm = torch.arange(n - 1, -1, -1) if permutation is None else torch.as_tensor(permutation)
    if sorted(perm.tolist()) != list(range(n)):
        raise ValueError(f"permutation: expected a permutation of range({n}), got {perm.tolist()}")
    return float((method(inputs, captures) - method(inputs[:, perm], captures.images(perm))).abs().max())


# ----------------------------------------------------------------------------- the methods
def baseline_method() -> Method:
    """The thesis's trivial baseline (:func:`mi_svbrdf.eval.baseline.trivial_baseline`, calibrated)."""
    from mi_svbrdf.eval.baseline import trivial_baseline

    return lambda inputs, captures: trivial_baseline(inputs, captures)


def network_method(kind: str, weights_dir: str | os.PathLike | None = None) -> Method:
    """The ``"single"`` (image 0 only) or ``"multi"`` net of ``weights_dir`` (default: the bundled weights)."""
    from mi_svbrdf.nets.inference import load

    if kind not in ("single", "multi"):
        raise ValueError(f"kind: expected 'single' or 'multi', got {kind!r}")
    net, _ = load(kind, weights_dir)

    def run(inputs: torch.Tensor, captures: Captures) -> torch.Tensor:
        with torch.inference_mode():
            return net(inputs[:, :1] if kind == "single" else inputs).clone()

    return run


@dataclass
class OptimizerReport:
    """What :func:`run_optimizer` returns."""

    maps: torch.Tensor  #: (B, 10, H, W) recovered maps
    recoveries: list[int]  #: per sample: NaN/Inf or rising-loss recoveries of the optimiser
    stop_reasons: list[str]  #: per sample: "converged", "budget", "iterations" or "recoveries"
    steps: list[int]  #: per sample: optimiser steps
    finite: bool  #: every map value and every recorded loss finite


def run_optimizer(inputs: torch.Tensor, captures: Captures, config: object | None = None) -> OptimizerReport:
    """Run :func:`mi_svbrdf.optimize` on each sample's calibrated photos (declared ``srgb8``).

    Args:
        inputs: ``(B, N, 3, H, W)`` linear photos.
        captures: their exact captures.
        config: an :class:`mi_svbrdf.optim.OptimizeConfig` (default: its defaults, no progress bar).
    """
    from mi_svbrdf.io.calibrated_photos import capture_from_simulator
    from mi_svbrdf.optim import OptimizeConfig, optimize

    check_inputs(inputs, captures)
    cfg = config if config is not None else OptimizeConfig(progress=False)
    results = []
    for b in range(inputs.shape[0]):
        spec, images = capture_from_simulator(captures, b, inputs, encoding="srgb8")
        results.append(optimize(spec, images, config=cfg))
    maps = torch.cat([r.maps.detach() for r in results])
    losses = torch.tensor([loss for r in results for _, _, loss in r.history], dtype=torch.float64)
    return OptimizerReport(maps=maps, recoveries=[r.recoveries for r in results],
                           stop_reasons=[r.stop_reason for r in results], steps=[r.steps for r in results],
                           finite=bool(torch.isfinite(maps).all()) and bool(torch.isfinite(losses).all()))


def optimizer_method(config: object | None = None) -> Method:
    """:func:`run_optimizer` as a :data:`Method` (the maps only)."""
    return lambda inputs, captures: run_optimizer(inputs, captures, config).maps


def standard_methods(weights_dir: str | os.PathLike | None = None, optimizer_config: object | None = None
                     ) -> dict[str, Method]:
    """The four methods by name: ``baseline``, ``single``, ``multi``, ``optimizer``."""
    return {"baseline": baseline_method(), "single": network_method("single", weights_dir),
            "multi": network_method("multi", weights_dir), "optimizer": optimizer_method(optimizer_config)}


# ----------------------------------------------------------------------------- degradation from the clean case
def degradation(method: Method, case: object, lights: object | None = None) -> dict[str, float]:
    """:func:`mi_svbrdf.core.metrics.evaluate_maps` of ``method`` on a failure case and on its clean twin.

    Args:
        method: see :data:`Method`.
        case: a :class:`mi_svbrdf.eval.failure_cases.Case` with ``clean``.
        lights: re-rendering lights (default :func:`mi_svbrdf.core.metrics.eval_lights`).

    Returns:
        ``{key: value on the case, key + "_clean": value on the clean twin, key + "_delta": their
        difference}`` for every :data:`mi_svbrdf.core.metrics.METRIC_KEYS` key, plus ``"finite"`` and
        ``"finite_clean"`` (1.0 / 0.0, :func:`finite_and_in_range`).
    """
    from mi_svbrdf.core.metrics import evaluate_maps

    if getattr(case, "clean", None) is None:
        raise ValueError("case: expected a failure case with a clean twin, got one without")
    pred, pred_clean = method(case.inputs, case.captures), method(case.clean.inputs, case.clean.captures)
    out: dict[str, float] = {"finite": float(finite_and_in_range(pred)),
                             "finite_clean": float(finite_and_in_range(pred_clean))}
    if not (out["finite"] and out["finite_clean"]):
        return out
    bad, good = evaluate_maps(pred, case.maps, lights), evaluate_maps(pred_clean, case.clean.maps, lights)
    for key in bad:
        out.update({key: bad[key], f"{key}_clean": good[key], f"{key}_delta": bad[key] - good[key]})
    return out


def plot_degradation(results: dict[str, dict[str, dict[str, float]]], path: str | os.PathLike,
                     key: str = "rmse_render") -> None:
    """Bar chart (PNG, written atomically) of ``results[case][method][key + "_delta"]``: how far each method degrades.

    Args:
        results: ``{case: {method: degradation(...)}}``.
        path: the PNG.
        key: a :data:`mi_svbrdf.core.metrics.METRIC_KEYS` key.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from mi_svbrdf.io.atomic import atomic_path

    cases = list(results)
    methods = sorted({m for r in results.values() for m in r})
    fig, ax = plt.subplots(figsize=(1.0 + 0.9 * len(cases), 4.0))
    width = 0.8 / max(1, len(methods))
    for i, m in enumerate(methods):
        values = [results[c].get(m, {}).get(f"{key}_delta", np.nan) for c in cases]
        ax.bar(np.arange(len(cases)) + (i - (len(methods) - 1) / 2) * width, values, width, label=m)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(np.arange(len(cases)), cases, rotation=30, ha="right")
    ax.set_ylabel(f"{key}: failure case - clean")
    ax.set_title("Degradation from the clean capture (higher: worse)" if key.startswith("rmse")
                 else "Change from the clean capture")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
