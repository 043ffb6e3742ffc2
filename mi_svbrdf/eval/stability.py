"""Stability of the methods: valid outputs, and how far their maps move under noise, reordering and repetition.

Measures of one method (any ``method(inputs (B, N, 3, H, W) linear photos, captures) -> maps
(B, 10, H, W)``, e.g. :func:`~mi_svbrdf.eval.methods.make_method`):

* :func:`finite_and_in_range`: the contract every output must meet, even on the failure cases
  of :mod:`mi_svbrdf.eval.failure_cases`.
* :func:`perturbation_sensitivity`: how much the maps move when every photo gets noise of
  1/255 (max and mean absolute change per map).
* :func:`permutation_invariance`: how much they move when the N photos (and their captures)
  are reordered; 0 up to float error for the multi-image net (max-pooling over photos).

The evaluation's **stability table** (:func:`run_stability`, ``stability.csv``): for some
held-out materials with ``n`` photos, every method of the evaluation (the optimiser-based ones,
the uncalibrated refinement among them, at a budget) is run, through
:func:`~mi_svbrdf.eval.harness.run_and_score`, once on the photos (its re-render RMSE there is
recorded beside the changes) and then

* again on the same photos: the **repeat** change, the method's own run-to-run floor (0 for the
  trivial baseline and the nets; for a time-budgeted fit (optimize, refine, uncalibrated), the steps
  it manages vary with the machine's load, so its maps do too);
* on ``trials`` perturbed copies (:func:`perturbation_sensitivity`: uniform noise in
  ``[-noise, noise]``, clipped): the **noise** change, to be read against the repeat floor;
* on the photos in reversed order: the **permutation** change (0 up to float error for the
  multi-image net and the trivial baseline; the single-image net sees only photo 0, so a
  reordering changes its input; the uncalibrated refinement takes photo 0 as the flash at the
  camera, so a reordering changes what it assumes).

The optimiser-based methods (the uncalibrated refinement's fit too) also report their recoveries
(NaN/Inf or rising loss) and whether every output was finite and in range. :func:`run_stability`
writes ``stability.csv`` (one row per method and material) atomically; :func:`stability_table` is
the report's Markdown table.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core import maps as M
    >>> from mi_svbrdf.eval.stability import finite_and_in_range
    >>> finite_and_in_range(M.constant_maps(1, 4, 4)), finite_and_in_range(M.constant_maps(1, 4, 4, roughness=1.5))
    (True, False)
"""
from __future__ import annotations

import csv
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.metrics import eval_lights
from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.eval.harness import Dataset, run_and_score
from mi_svbrdf.eval.methods import Method, check_inputs, make_method
from mi_svbrdf.io.atomic import atomic_path
from mi_svbrdf.io.tables import markdown_table

#: ``method(inputs (B, N, 3, H, W), captures) -> maps (B, 10, H, W)``: what the measures call.
MethodFn = Callable[[torch.Tensor, Captures], torch.Tensor]
#: Tolerances of :func:`finite_and_in_range`: on the unit length of normals, and outside [0, 1].
NORMAL_TOL, RANGE_TOL = 1e-3, 1e-6

CSV_NAME = "stability.csv"
#: Per-map columns: max absolute change under noise, per map of mi_svbrdf.core.maps, and over all.
CHANGE_KEYS = (*M.MAP_NAMES, "all")
COLUMNS: tuple[str, ...] = ("method", "budget_s", "material", "n", "noise", "repeat_max",
                            *[f"noise_max_{m}" for m in CHANGE_KEYS], "noise_mean_all", "permutation_max",
                            "recoveries", "finite", "rmse_render")


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
    return all(bool(((m >= -RANGE_TOL) & (m <= 1.0 + RANGE_TOL)).all())
               for m in (M.diffuse(maps), M.roughness(maps), M.specular(maps)))


def _changes(a: torch.Tensor, b: torch.Tensor) -> dict[str, dict[str, float]]:
    """Max and mean absolute change of each map (and of all channels, ``"all"``)."""
    diff = (a - b).abs()
    out = {k: {"max": float(diff[:, s].max()), "mean": float(diff[:, s].mean())} for k, s in M.SLICES.items()}
    out["all"] = {"max": float(diff.max()), "mean": float(diff.mean())}
    return out


def perturbation_sensitivity(method: MethodFn, inputs: torch.Tensor, captures: Captures, noise: float = 1 / 255,
                             trials: int = 3, seed: int = 0) -> dict[str, dict[str, float]]:
    """Change of ``method``'s maps when the photos get a small perturbation.

    Each trial adds independent noise uniform in ``[-noise, noise]`` to every photo value and
    clips to [0, 1] (so no value moves by more than ``noise``), and compares the maps with
    those of the unperturbed photos.

    Args:
        method: see :data:`MethodFn`.
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


def permutation_invariance(method: MethodFn, inputs: torch.Tensor, captures: Captures,
                           permutation: torch.Tensor | None = None, base: torch.Tensor | None = None) -> float:
    """Max absolute difference of ``method``'s maps when the N photos and their captures are reordered.

    Args:
        method, inputs, captures: as :func:`perturbation_sensitivity`.
        permutation: a permutation of ``range(N)``; default the reversed order.
        base: ``method(inputs, captures)`` when already computed (it is not called again).
    """
    check_inputs(inputs, captures)
    n = inputs.shape[1]
    perm = torch.arange(n - 1, -1, -1) if permutation is None else torch.as_tensor(permutation)
    if sorted(perm.tolist()) != list(range(n)):
        raise ValueError(f"permutation: expected a permutation of range({n}), got {perm.tolist()}")
    if base is None:
        base = method(inputs, captures)
    return float((base - method(inputs[:, perm], captures.images(perm))).abs().max())


# ----------------------------------------------------------------------------- the stability table
def _measure(method: Method, data: Dataset, material: int, n: int, lights: Any, noise: float, trials: int,
             seed: int) -> dict[str, Any]:
    """One row of the table (without its identity columns): see the module docstring."""
    outputs, recoveries = [], 0

    def call(x: torch.Tensor, c: Captures) -> torch.Tensor:
        nonlocal recoveries
        maps = method(x, c)
        recoveries += int(method.info.get("recoveries", 0))
        outputs.append(maps)
        return maps

    res, metrics = run_and_score(method, data, n, lights, material)
    recoveries += int(res.info.get("recoveries", 0))
    first = res.maps
    outputs.append(first)
    inputs, captures = data.photos(material, n)
    repeat = float((call(inputs, captures) - first).abs().max())
    sens = perturbation_sensitivity(call, inputs, captures, noise=noise, trials=trials, seed=seed)
    permuted = permutation_invariance(call, inputs, captures, base=first)
    return {"repeat_max": repeat, **{f"noise_max_{m}": sens[m]["max"] for m in CHANGE_KEYS},
            "noise_mean_all": sens["all"]["mean"], "permutation_max": permuted, "recoveries": recoveries,
            "finite": all(finite_and_in_range(o) for o in outputs), "rmse_render": metrics["rmse_render"]}


def run_stability(methods: Sequence[tuple[str, float | None]], data: Dataset, n: int, out: str | os.PathLike, *,
                  materials: int | None = None, weights_dir: str | os.PathLike | None = None,
                  lights: Any = None, noise: float = 1 / 255, trials: int = 2, seed: int = 0,
                  method_options: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """Measure every ``(method, budget_s)`` on the first materials of ``data`` and write ``out/stability.csv``.

    Args:
        methods: ``(name, budget_s)`` pairs (budget None for trivial, single, multi).
        data: the materials (ground truth, photos, captures).
        n: photos per material (>= 2: a permutation needs two).
        out: the report folder.
        materials: how many of ``data``'s materials (None: all).
        weights_dir: the nets' weights (None: bundled).
        lights: re-rendering lights of the RMSE column (None: :func:`~mi_svbrdf.core.metrics.eval_lights`).
        noise, trials, seed: as :func:`perturbation_sensitivity`.
        method_options: further :func:`~mi_svbrdf.eval.methods.make_method` arguments.

    Returns:
        The rows written (keys :data:`COLUMNS`).
    """
    if not 2 <= n <= data.inputs.shape[1]:
        raise ValueError(f"n: expected 2 <= N <= {data.inputs.shape[1]} photos (a permutation needs two), got {n}")
    count = data.maps.shape[0] if materials is None else min(materials, data.maps.shape[0])
    lights = eval_lights() if lights is None else lights
    rows = []
    for name, budget in methods:
        method = make_method(name, weights_dir=weights_dir, budget_s=budget, **(method_options or {}))
        for m in range(count):
            res = _measure(method, data, m, n, lights, noise, trials, seed + m)
            rows.append({"method": name, "budget_s": budget, "material": m, "n": n, "noise": noise, **res})
    path = Path(out) / CSV_NAME
    with atomic_path(path, fsync=False) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=COLUMNS)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: ("" if row[k] is None else f"{row[k]:.6g}" if isinstance(row[k], float)
                                     else row[k]) for k in COLUMNS})
    return rows


def read_stability(out: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of ``out/stability.csv`` ([] when absent), numbers parsed (a column the file lacks: None)."""
    path = Path(out) / CSV_NAME
    if not path.is_file():
        return []
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            row: dict[str, Any] = dict(r)
            for k in COLUMNS[1:]:
                value = r.get(k) or ""
                if k == "finite":
                    row[k] = value == "True"
                else:
                    row[k] = float(value) if value != "" else None
            rows.append(row)
    return rows


def stability_table(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Markdown lines: per method (worst over materials) the repeat, noise and permutation changes."""
    if not rows:
        return []
    groups: dict[tuple[str, Any], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], r["budget_s"]), []).append(r)
    first, k = rows[0], len({r["material"] for r in rows})
    lines = [f"## Stability: {k} held-out material{'s' if k != 1 else ''}, N = {int(first['n'])}, "
             f"noise ±{float(first['noise']) * 255:g}/255", "",
             "Largest absolute change of any map value over the materials: between two identical calls "
             "(repeat: the run-to-run floor of a time-budgeted fit), under input noise (per map and over all; "
             "mean over all values in brackets), and with the photos in reversed order (0 expected for the "
             "trivial baseline and the multi-image net; the single-image net sees photo 0 only, which the "
             "reversal replaces, and the uncalibrated refinement takes photo 0 as its flash photo). Render RMSE: "
             "the method's error on the unperturbed photos (mean over the materials), the scale the changes "
             "compare to.", ""]
    table = []
    for (name, budget), rs in groups.items():
        label = name + (f" {float(budget):g} s" if budget not in (None, "") else "")
        worst = {k: max(float(r[k]) for r in rs) for k in ["repeat_max", "permutation_max", "noise_mean_all",
                                                             *[f"noise_max_{m}" for m in CHANGE_KEYS]]}
        rmse = [float(r["rmse_render"]) for r in rs if r.get("rmse_render") is not None]
        table.append([label, f"{worst['repeat_max']:.4f}", *(f"{worst[f'noise_max_{m}']:.4f}" for m in M.MAP_NAMES),
                      f"{worst['noise_max_all']:.4f} ({worst['noise_mean_all']:.5f})", f"{worst['permutation_max']:.4f}",
                      int(sum(float(r['recoveries']) for r in rs)), "yes" if all(r["finite"] for r in rs) else "**no**",
                      f"{sum(rmse) / len(rmse):.4f}" if rmse else "–"])
    headers = ["method", "repeat", "noise: normal", "diffuse", "roughness", "specular", "all (mean)", "permutation",
               "recoveries", "finite", "render RMSE"]
    return lines + markdown_table(headers, table).split("\n")
