"""Another output BRDF model (thesis ch. 6.1.1): GGX -> Beckmann next to GGX -> GGX, held out.

The rendering loss only compares renderings, so the model a net or a fit outputs need not be the
one that made its ground truth: here the photos of the held-out benchmark
(:mod:`mi_svbrdf.data.heldout`) are rendered from GGX ground truth, and

* the optimiser (:func:`mi_svbrdf.optim.optimize`, ``OptimizeConfig.distribution``) fits them twice
  at equal iterations (the convergence stop off), once with GGX output maps and once with
  Beckmann output maps (:func:`compare_optimizer`);
* networks (a checkpoint of ``mi-svbrdf train`` with ``TrainConfig.distribution``, or bundled weights)
  are run on the same photos, each with the model it was trained for (:func:`compare_nets`).

**Scoring** (:func:`score`): as the rest of the evaluation (:func:`mi_svbrdf.core.metrics.evaluate_maps`,
the fixed evaluation lights of :func:`~mi_svbrdf.core.metrics.eval_lights`: novel lights and views,
displayed re-renderings), except that each material is re-rendered with *its own* model: the
output maps with the output model, the ground truth with GGX. Map RMSEs of normals, diffuse and
specular are comparable across models; the **roughness is not** (the same r is a different lobe),
so the table also gives ``rmse_roughness_equiv``: the roughness converted to GGX's by equal lobe
width (:func:`equivalent_roughness`) before the RMSE. ``rmse_render_as_ggx`` re-renders the
output maps with GGX instead of their own model (the same maps, the other lobe).

A cross-model fit matches the GGX tail as much as the core: Beckmann cannot make GGX's long tail
(on rough metals the fit moves specular albedo into the diffuse map), and the Beckmann fits'
roughness stays near the GGX fits' rather than at the equal-width ratio, so
``rmse_roughness_equiv`` is a convention for comparing maps, not what a cross-model fit finds.
Figures: ``docs/design-notes.md``.

Run it with ``benchmarks/bench_output_model.py`` (the table and the figure :func:`plot_comparison`).

Examples:
    >>> round(float(equivalent_roughness(torch.tensor(0.5), "ggx", "beckmann")), 4)
    0.4396
    >>> round(float(equivalent_roughness(equivalent_roughness(torch.tensor(0.3), "ggx", "beckmann"),
    ...                                  "beckmann", "ggx")), 6)
    0.3
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.brdf_gltf import HALF_WIDTH
from mi_svbrdf.core.metrics import display, eval_lights, evaluate_maps, rerender
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.data.heldout import HELD_OUT_SEED, HeldOutSet
from mi_svbrdf.eval.harness import Dataset, load_heldout
from mi_svbrdf.eval.methods import make_method, measure
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets import weights as pretrained
from mi_svbrdf.nets.network import SVBRDFNet, build_network, config_from_dict
from mi_svbrdf.nets.train import load_state
from mi_svbrdf.plugins.model import DISTRIBUTIONS, ROUGHNESS_MIN

#: Ground truth model of the held-out photos (the capture simulator renders GGX).
TRUTH = "ggx"
#: OptimizeConfig settings the comparison sets itself (equal iterations, no convergence stop, the output model).
OWN_SETTINGS = ("distribution", "iterations", "tol")
#: Keys of a row's scores, in table order.
SCORE_KEYS = ("rmse_render", "rmse_render_as_ggx", "rmse_normal", "rmse_diffuse", "rmse_specular",
              "rmse_roughness", "rmse_roughness_equiv", "ssim_render")


def _check_model(name: str, value: str) -> None:
    if value not in DISTRIBUTIONS:
        raise ValueError(f"{name}: expected one of {DISTRIBUTIONS}, got {value!r}")


def equivalent_roughness(roughness: torch.Tensor, source: str, target: str) -> torch.Tensor:
    """Roughness of model ``target`` whose lobe has the width of ``roughness`` in model ``source``.

    Width: the ``tan(theta_h)`` at half the peak of ``D cos^4`` (:data:`HALF_WIDTH`), so
    ``alpha_target = alpha_source * HALF_WIDTH[source] / HALF_WIDTH[target]`` with ``alpha = r^2``:
    a GGX ``r`` is a Beckmann ``0.879 r``. Clipped to ``[ROUGHNESS_MIN, 1]`` (the renderer's range).

    Args:
        roughness: any shape, thesis roughness ``r`` of ``source``.
        source: ``"ggx"`` or ``"beckmann"``.
        target: ``"ggx"`` or ``"beckmann"``.

    Returns:
        The same shape.
    """
    _check_model("source", source)
    _check_model("target", target)
    scale = math.sqrt(HALF_WIDTH[source] / HALF_WIDTH[target])
    return (roughness * scale).clamp(ROUGHNESS_MIN, 1.0)


@dataclass
class OutputModelConfig:
    """Settings of the comparison; :meth:`from_dict` rejects unknown keys."""

    materials: int = 4  #: held-out materials (classes in turn: paint, plastic, leather, metal, ...), >= 1
    size: int = 128  #: resolution of maps and photos, >= 8
    n_images: int = 3  #: photos per material for the optimiser (the multiview set's first N), >= 1
    iterations: int = 300  #: optimiser steps of each fit, the same for every model (convergence stop off), >= 1
    models: tuple[str, ...] = ("ggx", "beckmann")  #: output models compared (the photos stay GGX)
    optimizer: dict[str, Any] = field(default_factory=dict)  #: further OptimizeConfig settings (same for all models)
    seed: int = HELD_OUT_SEED  #: held-out benchmark seed
    cache: bool = True  #: keep the held-out tensors in the cache (HeldOutSet.cache)
    progress: bool = False  #: progress bars

    def __post_init__(self) -> None:
        self.models = tuple(self.models)
        check_fields([
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ("materials", "n_images", "iterations")),
            ("size", isinstance(self.size, int) and self.size >= 8, "an int >= 8", self.size),
            ("models", bool(self.models) and all(m in DISTRIBUTIONS for m in self.models),
             f"a non-empty tuple of {DISTRIBUTIONS}", self.models),
            ("optimizer", isinstance(self.optimizer, dict) and not set(self.optimizer) & set(OWN_SETTINGS),
             f"a dict of OptimizeConfig settings but {', '.join(OWN_SETTINGS)}", self.optimizer),
        ], owner="OutputModelConfig")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OutputModelConfig:
        """Build from a dict; unknown keys raise a ``ValueError``."""
        return from_dict(cls, data)

    def heldout(self, preset: str = "multiview", n_images: int | None = None) -> HeldOutSet:
        """The held-out set of the comparison (``preset`` ``"multiview"``: the optimiser's; ``"single_flash"``)."""
        return HeldOutSet(size=self.size, materials=self.materials, n_images=n_images or self.n_images,
                          preset=preset, seed=self.seed, cache=self.cache)


@dataclass
class OutputModelComparison:
    """What :func:`compare_optimizer` / :func:`compare_nets` return."""

    rows: list[dict[str, Any]] = field(default_factory=list)  #: one per method, model and material
    maps: dict[str, torch.Tensor] = field(default_factory=dict)  #: label -> (M, 10, H, W) output maps
    models: dict[str, str] = field(default_factory=dict)  #: label -> output model
    truths: dict[str, torch.Tensor] = field(default_factory=dict)  #: label -> (M, 10, H, W) its ground truth (GGX)
    settings: dict[str, Any] = field(default_factory=dict)  #: what makes the rows comparable

    def summary(self) -> dict[str, dict[str, float]]:
        """Per label: the mean of each score over materials (and seconds, steps)."""
        out: dict[str, dict[str, float]] = {}
        for label in dict.fromkeys(r["label"] for r in self.rows):
            rows = [r for r in self.rows if r["label"] == label]
            keys = [k for k in (*SCORE_KEYS, "seconds", "steps") if all(k in r for r in rows)]
            out[label] = {k: sum(float(r[k]) for r in rows) / len(rows) for k in keys}
        return out


def score(maps: torch.Tensor, truth: torch.Tensor, distribution: str, lights: Any = None) -> dict[str, float]:
    """Scores of output maps ``(1, 10, H, W)`` of model ``distribution`` against GGX ground truth (module docstring).

    Returns:
        :func:`~mi_svbrdf.core.metrics.evaluate_maps`' keys (the output re-rendered with its own model)
        plus ``rmse_roughness_equiv`` and ``rmse_render_as_ggx``.
    """
    _check_model("distribution", distribution)
    lights = lights or eval_lights()
    out = evaluate_maps(maps, truth, lights, distribution=distribution, gt_distribution=TRUTH)
    with torch.no_grad():
        r = equivalent_roughness(M.roughness(maps), distribution, TRUTH)
        out["rmse_roughness_equiv"] = float((r - M.roughness(truth)).square().mean().sqrt())
        a = display(rerender(maps, lights, distribution=TRUTH))
        b = display(rerender(truth, lights, distribution=TRUTH))
        out["rmse_render_as_ggx"] = float((a - b).square().mean().sqrt())
    return out


def _run(comparison: OutputModelComparison, label: str, model: str, method: Any, data: Dataset, n: int, lights: Any,
         extra: dict[str, Any]) -> None:
    """Run ``method`` on each material of ``data`` (first ``n`` photos) and add its rows and maps."""
    outs = []
    for m in range(data.maps.shape[0]):
        inputs, captures = data.photos(m, n)
        res = measure(method, inputs, captures)
        maps = res.maps.cpu().float()
        outs.append(maps)
        row = {"label": label, "model": model, "material": m, "class": data.classes[m % len(data.classes)],
               "n_images": n, "seconds": round(res.seconds, 3), **extra,
               **{k: v for k, v in res.info.items() if k in ("steps", "recoveries", "stop_reason")},
               **score(maps, data.maps[m:m + 1], model, lights)}
        comparison.rows.append(row)
    comparison.maps[label] = torch.cat(outs)
    comparison.models[label] = model
    comparison.truths[label] = data.maps


def compare_optimizer(cfg: OutputModelConfig | None = None, data: Dataset | None = None) -> OutputModelComparison:
    """The optimiser with each output model of ``cfg.models`` on the held-out photos (GGX ground truth).

    Each fit has ``cfg.iterations`` steps (``tol = 0``: no convergence stop; no time budget) and
    otherwise the default :class:`~mi_svbrdf.optim.OptimizeConfig` (at N = 2-3 a held-out photo
    chooses the shrinkage, as always). Labels ``"optimize ggx"``, ``"optimize beckmann"``.

    Args:
        cfg: the settings (default :class:`OutputModelConfig`).
        data: the materials (default: ``cfg.heldout()``, the multiview held-out set).
    """
    cfg = cfg or OutputModelConfig()
    data = data if data is not None else load_heldout(cfg.heldout(), progress=cfg.progress)
    n = min(cfg.n_images, data.inputs.shape[1])
    comparison = OutputModelComparison(settings={"set": data.name, "materials": data.maps.shape[0],
                                                       "size": int(data.maps.shape[-1]), "n_images": n,
                                                       "iterations": cfg.iterations, "truth": TRUTH})
    lights = eval_lights()
    for model in cfg.models:
        method = make_method("optimize", budget_s=math.inf,
                             optimizer={**cfg.optimizer, "iterations": cfg.iterations, "tol": 0.0,
                                        "distribution": model})
        _run(comparison, f"optimize {model}", model, method, data, n, lights, {"method": "optimize"})
    comparison.settings["roughness_ratio"] = roughness_ratio(comparison)
    return comparison


def roughness_ratio(comparison: OutputModelComparison, source: str = "optimize ggx",
                    target: str = "optimize beckmann") -> float | None:
    """Median over texels of ``r_target / r_source`` of two fits of the same photos (None without both).

    For the optimiser: how a Beckmann fit's roughness relates to a GGX fit's, to compare with the
    equal-width conversion's ``0.879`` (:func:`equivalent_roughness`). Texels where the GGX fit's
    roughness is below 0.05 (no lobe to measure) are left out.
    """
    if source not in comparison.maps or target not in comparison.maps:
        return None
    a, b = M.roughness(comparison.maps[source]), M.roughness(comparison.maps[target])
    keep = a > 0.05
    return round(float((b[keep] / a[keep]).median()), 4) if bool(keep.any()) else None


def load_net(spec: str | os.PathLike) -> tuple[SVBRDFNet, str]:
    """A net and its output model: ``"bundled:KIND"`` (the manifest's ``"distribution"``) or a checkpoint of
    ``mi-svbrdf train`` (its config's ``distribution``; ``"ggx"`` for runs before it existed).

    Raises:
        ValueError: naming ``spec``: no such bundled kind or file.
    """
    text = str(spec)
    if text.startswith("bundled:"):
        kind = text.split(":", 1)[1]
        net = pretrained.load_network(kind)
        return net.eval(), pretrained.entry_distribution(pretrained.manifest_entry(kind))
    state = load_state(spec)
    if "net_config" not in state or "model" not in state:
        raise ValueError(f"{spec}: expected a checkpoint of mi-svbrdf train (net_config, model), "
                         f"got keys {sorted(state)[:8]}")
    net = build_network(config_from_dict(state["net_config"]))
    net.load_state_dict(state["model"])
    model = state.get("config", {}).get("distribution", "ggx")
    _check_model(f"{spec}: config.distribution", model)
    return net.eval(), model


def compare_nets(nets: dict[str, str | os.PathLike], cfg: OutputModelConfig | None = None) -> OutputModelComparison:
    """Networks, each scored with its own output model, on the held-out photos (GGX ground truth).

    A single-image net sees photo 0 of the ``single_flash`` set (as its held-out accuracy does,
    :mod:`mi_svbrdf.eval.accuracy`), a multi-image net the first ``cfg.n_images`` photos of the
    ``multiview`` set, both at ``cfg.size`` (the net runs at the photos' own size).

    Args:
        nets: label -> ``"bundled:KIND"`` or a checkpoint path (:func:`load_net`), e.g.
            ``{"single ggx": "bundled:single", "single beckmann": "runs/single_beckmann/checkpoint.pt"}``.
        cfg: the settings (:class:`OutputModelConfig`; ``iterations`` and ``models`` unused).
    """
    cfg = cfg or OutputModelConfig()
    comparison = OutputModelComparison(settings={"materials": cfg.materials, "size": cfg.size, "truth": TRUTH})
    lights = eval_lights()
    sets: dict[str, Dataset] = {}
    for label, spec in nets.items():
        net, model = load_net(spec)
        kind = net.config.kind
        if kind not in ("single", "multi"):
            raise ValueError(f"nets[{label!r}]: expected a single- or multi-image net, got {kind!r} from {spec}")
        preset, n = ("single_flash", 1) if kind == "single" else ("multiview", cfg.n_images)
        if preset not in sets:
            sets[preset] = load_heldout(cfg.heldout(preset, n), progress=cfg.progress)
        data = sets[preset]
        comparison.settings[label] = {"preset": preset, "n_images": n, "model": model}
        method = make_method(kind, net=net, batch=1)
        _run(comparison, label, model, method, data, n, lights, {"method": kind, "net": str(spec)})
    return comparison


def output_model_table(comparison: OutputModelComparison) -> str:
    """The comparison's mean scores as a Markdown table (one row per label)."""
    summary = comparison.summary()
    keys = [k for k in SCORE_KEYS if all(k in row for row in summary.values())]
    rows = [[label, comparison.models[label], *(f"{row[k]:.4f}" for k in keys), f"{row.get('seconds', float('nan')):.1f}"]
            for label, row in summary.items()]
    return markdown_table(["output", "model", *(k.replace("rmse_", "") for k in keys), "seconds"], rows)


def plot_comparison(comparison: OutputModelComparison, path: str | os.PathLike, *, material: int | None = None,
                    light: int = 0) -> None:
    """The figure: held-out re-rendering RMSE per material and label (bars), and one material under one
    evaluation light (``light``, default 0: flash-like, the highlight in view): the ground truth, then each
    output rendered with its own model (and the last non-GGX output rendered as GGX). ``material`` None: the
    one whose outputs' re-rendering RMSEs differ most."""
    plt = pyplot()
    labels = list(comparison.maps)
    lights = eval_lights()
    n_mat = len({r["material"] for r in comparison.rows})
    if material is None:
        def spread(m: int) -> float:
            values = [r["rmse_render"] for r in comparison.rows if r["material"] == m]
            return max(values) - min(values)
        material = max(range(n_mat), key=spread)
    classes = {r["material"]: r["class"] for r in comparison.rows}
    truth = comparison.truths[labels[0]]  # the first label's set (a single-image and a multi-image net: two sets)
    panels = [(f"truth (GGX), material {material}: {classes[material]}", truth[material:material + 1], TRUTH)]
    panels += [(f"{lab}", comparison.maps[lab][material:material + 1], comparison.models[lab]) for lab in labels]
    others = [lab for lab in labels if comparison.models[lab] != TRUTH]
    if others:
        panels.append((f"{others[-1]}\nrendered as GGX", comparison.maps[others[-1]][material:material + 1], TRUTH))
    fig = plt.figure(figsize=(3.0 * max(len(panels), 3), 6.2))
    grid = fig.add_gridspec(2, len(panels))
    ax = fig.add_subplot(grid[0, :])
    width = 0.8 / max(len(labels), 1)
    for i, lab in enumerate(labels):
        rows = sorted((r for r in comparison.rows if r["label"] == lab), key=lambda r: r["material"])
        ax.bar([r["material"] + (i - (len(labels) - 1) / 2) * width for r in rows], [r["rmse_render"] for r in rows],
               width, label=f"{lab} (mean {sum(r['rmse_render'] for r in rows) / len(rows):.4f})")
    ax.set_xticks(range(n_mat), [f"{m}: {classes[m]}" for m in range(n_mat)])
    ax.set_ylabel("held-out re-rendering RMSE")
    ax.set_title("GGX ground truth; each output re-rendered with its own model under novel lights")
    ax.legend(fontsize=8)
    with torch.no_grad():
        for j, (title, maps, model) in enumerate(panels):
            img = display(rerender(maps.float(), lights, distribution=model))[0, light].permute(1, 2, 0).numpy()
            a = fig.add_subplot(grid[1, j])
            a.imshow(img.clip(0.0, 1.0))
            a.set_title(title, fontsize=8)
            a.axis("off")
    fig.tight_layout()
    save_figure(fig, Path(path), dpi=90)
