"""The evaluation's stability table: how far each method's maps move under 1/255 input noise,
under a reordering of the photos, and between two identical calls (issue 6 §2).

For ``materials`` held-out materials with ``n`` photos, every method of the evaluation
(:func:`~mi_svbrdf.eval.methods.make_method`, the optimiser-based ones at a budget) is run

* twice on the same photos: the **repeat** change, the method's own run-to-run floor (0 for the
  trivial baseline and the nets; for a time-budgeted fit, the steps it manages vary with the
  machine's load, so its maps do too);
* on ``trials`` perturbed copies (:func:`mi_svbrdf.eval.stability.perturbation_sensitivity`: uniform
  noise in ``[-noise, noise]``, clipped): the **noise** change, to be read against the repeat floor;
* on the photos in reversed order: the **permutation** change (0 up to float error for the
  multi-image net and the trivial baseline; the single-image net sees only photo 0, so a
  reordering changes its input).

The optimiser-based methods also report their recoveries (NaN/Inf or rising loss) and whether
every output was finite and in range (:func:`mi_svbrdf.eval.stability.finite_and_in_range`).
:func:`run_sensitivity` writes ``stability.csv`` (one row per method and material) atomically;
:func:`sensitivity_table` is the report's Markdown table.
"""
from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.eval.methods import Method, make_method

CSV_NAME = "stability.csv"
#: Per-map columns: max absolute change under noise, per map of mi_svbrdf.core.maps.SLICES, and over all.
MAPS = ("normal", "diffuse", "roughness", "specular", "all")
COLUMNS: tuple[str, ...] = ("method", "budget_s", "material", "n", "noise", "repeat_max",
                            *[f"noise_max_{m}" for m in MAPS], "noise_mean_all", "permutation_max",
                            "recoveries", "finite")


def _measure(method: Method, inputs: torch.Tensor, captures: Captures, noise: float, trials: int,
             seed: int) -> dict[str, Any]:
    from mi_svbrdf.eval.stability import finite_and_in_range, perturbation_sensitivity

    outputs, recoveries = [], 0

    def call(x: torch.Tensor, c: Captures) -> torch.Tensor:
        nonlocal recoveries
        maps = method(x, c)
        recoveries += int(method.info.get("recoveries", 0))
        outputs.append(maps)
        return maps

    first = call(inputs, captures)
    repeat = float((call(inputs, captures) - first).abs().max())
    sens = perturbation_sensitivity(call, inputs, captures, noise=noise, trials=trials, seed=seed)
    perm = torch.arange(inputs.shape[1] - 1, -1, -1)
    permuted = float((call(inputs[:, perm], captures.images(perm)) - first).abs().max())
    return {"repeat_max": repeat, **{f"noise_max_{m}": sens[m]["max"] for m in MAPS},
            "noise_mean_all": sens["all"]["mean"], "permutation_max": permuted, "recoveries": recoveries,
            "finite": all(finite_and_in_range(o) for o in outputs)}


def run_sensitivity(methods: Sequence[tuple[str, float | None]], inputs: torch.Tensor, captures: Captures,
                    out: str | os.PathLike, *, weights_dir: str | os.PathLike | None = None,
                    noise: float = 1 / 255, trials: int = 2, seed: int = 0) -> list[dict[str, Any]]:
    """Measure every ``(method, budget_s)`` on each material of ``inputs`` and write ``out/stability.csv``.

    Args:
        methods: ``(name, budget_s)`` pairs (budget None for trivial, single, multi).
        inputs: ``(B, N, 3, H, W)`` linear photos (B materials, N >= 2 for a permutation).
        captures: their exact captures ``(B, N)``.
        out: the report folder.
        weights_dir: the nets' weights (None: bundled).
        noise, trials, seed: as :func:`mi_svbrdf.eval.stability.perturbation_sensitivity`.

    Returns:
        The rows written (keys :data:`COLUMNS`).
    """
    from mi_svbrdf.io.atomic import atomic_path
    from mi_svbrdf.eval.stability import check_inputs

    check_inputs(inputs, captures)
    if inputs.shape[1] < 2:
        raise ValueError(f"inputs: expected N >= 2 photos (a permutation needs two), got N = {inputs.shape[1]}")
    rows = []
    for name, budget in methods:
        method = make_method(name, weights_dir=weights_dir, budget_s=budget)
        for m in range(inputs.shape[0]):
            res = _measure(method, inputs[m:m + 1], captures.take(m), noise, trials, seed + m)
            rows.append({"method": name, "budget_s": budget, "material": m, "n": inputs.shape[1],
                         "noise": noise, **res})
    path = Path(out) / CSV_NAME
    with atomic_path(path, fsync=False) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=COLUMNS)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: ("" if row[k] is None else f"{row[k]:.6g}" if isinstance(row[k], float)
                                     else row[k]) for k in COLUMNS})
    return rows


def read_sensitivity(out: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of ``out/stability.csv`` ([] when absent), numbers parsed."""
    path = Path(out) / CSV_NAME
    if not path.is_file():
        return []
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            row: dict[str, Any] = dict(r)
            for k in COLUMNS[1:]:
                if k == "finite":
                    row[k] = r[k] == "True"
                elif r[k] != "":
                    row[k] = float(r[k])
                else:
                    row[k] = None
            rows.append(row)
    return rows


def sensitivity_table(rows: Sequence[dict[str, Any]]) -> list[str]:
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
             "reversal replaces).", "",
             "| method | repeat | noise: normal | diffuse | roughness | specular | all (mean) | permutation "
             "| recoveries | finite |", "|---" * 10 + "|"]
    for (name, budget), rs in groups.items():
        label = name + (f" {float(budget):g} s" if budget not in (None, "") else "")
        worst = {k: max(float(r[k]) for r in rs) for k in ["repeat_max", "permutation_max", "noise_mean_all",
                                                             *[f"noise_max_{m}" for m in MAPS]]}
        lines.append(f"| {label} | {worst['repeat_max']:.4f} | " +
                     " | ".join(f"{worst[f'noise_max_{m}']:.4f}" for m in MAPS[:4]) +
                     f" | {worst['noise_max_all']:.4f} ({worst['noise_mean_all']:.5f}) | "
                     f"{worst['permutation_max']:.4f} | {int(sum(float(r['recoveries']) for r in rs))} | "
                     f"{'yes' if all(r['finite'] for r in rs) else '**no**'} |")
    return lines
