"""The evaluation report: a Markdown summary, CSVs and PNG charts from the runner's rows.

Files written by :func:`write_evaluation_report` into the report folder (each atomically):

* ``summary.md`` -- the main table (mean over held-out materials per method, N and budget),
  the optimiser-vs-network table (chart c) and the failure-case table (chart e);
* ``summary.csv`` -- the main table as CSV (``results.csv``, one row per material, is the runner's);
* ``sets.csv`` and the summary's "Generalisation" tables -- the held-out set and the foreign
  captures (and the strips) side by side per method, N and budget, with the gap (foreign − held-out)
  per row and per method (:func:`compare_sets`, :func:`method_gaps`);
* ``a_speed_accuracy.png`` -- (a) error against wall time on a log time axis, every method, one
  panel for the re-rendering RMSE and one per map, each point labelled with its N and budget (labels placed
  apart); the Pareto front (no other point is both faster and more accurate) drawn as a step line with ringed
  points; one legend under the panels;
* ``b_ssim_vs_images.png`` -- (b) re-render SSIM and per-map SSIM against N (thesis Fig. 4.4), ticks at the N
  run, for the multi-image net and the optimiser (each budget), refinement, the uncalibrated refinement, the
  single-image net (one point, N = 1) and the baseline for reference;
* ``c_images_to_match.png`` -- (c) per material, the fewest calibrated images with which the
  optimiser (largest budget) is at least as good as the N-image net (thesis Fig. 4.8);
* ``d_gallery_mM.png`` -- (d) per gallery material: inputs, then per method its maps and two
  re-renderings, then the ground truth;
* ``e_failure_cases.png`` -- (e) per failure case and method, the re-rendering RMSE minus that of
  the clean twin (how far the method degrades);
* the stability table of ``stability.csv`` (:mod:`~mi_svbrdf.eval.stability`), when the
  runner wrote one;
* the "Real-style checks" section after "Generalisation", with ``f_real_examples.png`` and
  ``g_real_highlights.png`` (:mod:`~mi_svbrdf.eval.studies.real_checks`), when the runner wrote
  ``real_checks.json``;
* the "Ablations" section (:mod:`~mi_svbrdf.eval.studies.ablations`), when given the folder of a
  ``mi-svbrdf ablations`` run.
"""
from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.maps import MAP_NAMES, preview_panels
from mi_svbrdf.core.metrics import display, eval_lights, rerender
from mi_svbrdf.eval import stability
from mi_svbrdf.eval.methods import BUDGET_METHODS, METHODS
from mi_svbrdf.eval.runner import COLUMNS, EvalConfig
from mi_svbrdf.eval.studies import ablations, real_checks
from mi_svbrdf.io.atomic import write_text
from mi_svbrdf.io.figures import integer_ticks, label_points, pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table

#: Columns of the summary table: (key, header, format).
TABLE = (("rmse_normal", "normal", ".4f"), ("rmse_diffuse", "diffuse", ".4f"), ("rmse_roughness", "rough.", ".4f"),
         ("rmse_specular", "specular", ".4f"), ("rmse_diffuse_scaled", "diffuse×k", ".4f"),
         ("rmse_render", "render RMSE", ".4f"), ("ssim_render", "render SSIM", ".3f"))
COLOURS = {"trivial": "tab:gray", "single": "tab:orange", "multi": "tab:blue", "optimize": "tab:green",
           "refine": "tab:red", "uncalibrated": "tab:purple"}
#: The methods drawn against N (chart b; the single-image net as one point, at N = 1).
CURVE_METHODS = ("trivial", "single", "multi", "optimize", "refine", "uncalibrated")
#: The paired comparisons (:func:`paired_differences`): ``(method, reference, same budget)``; a reference
#: without a budget is compared at the method's N, one with a budget at the method's N and budget.
PAIRS = (("single", "trivial", False), ("multi", "trivial", False), ("optimize", "trivial", False),
         ("refine", "multi", False), ("uncalibrated", "multi", False), ("uncalibrated", "refine", True))


def label(method: str, budget: float | None) -> str:
    """``"optimize 15s"`` or ``"multi"``."""
    return f"{method} {budget:g}s" if budget is not None else method


def aggregate(rows: Sequence[dict[str, Any]], dataset: str = "heldout") -> list[dict[str, Any]]:
    """Mean over materials per (method, n, budget) of the rows of ``dataset``; sorted by method order, N, budget.

    Returns:
        Dicts with method, n, budget_s, materials (count), seconds (mean), peak_mb (max),
        recoveries (sum), the mean of every metric and its standard error over the materials
        (``se_`` + the metric's key; NaN for one material).
    """
    groups: dict[tuple[str, int, float | None], list[dict[str, Any]]] = {}
    for r in rows:
        if r["dataset"] == dataset:
            groups.setdefault((r["method"], r["n"], r["budget_s"]), []).append(r)
    out = []
    for (method, n, budget), rs in groups.items():
        agg: dict[str, Any] = {"method": method, "n": n, "budget_s": budget, "materials": len(rs),
                               "seconds": sum(r["seconds"] for r in rs) / len(rs),
                               "peak_mb": max(r["peak_mb"] for r in rs),
                               "recoveries": sum(int(r["recoveries"]) for r in rs)}
        for k in rs[0]:
            if k.startswith(("rmse_", "ssim_")):
                mean = agg[k] = sum(r[k] for r in rs) / len(rs)
                var = sum((r[k] - mean) ** 2 for r in rs) / (len(rs) - 1) if len(rs) > 1 else math.nan
                agg[f"se_{k}"] = math.sqrt(var / len(rs))  # standard error of the mean over materials
        out.append(agg)
    order = {m: i for i, m in enumerate(METHODS)}
    return sorted(out, key=lambda a: (order.get(a["method"], 99), a["n"], a["budget_s"] or 0.0))


#: Metrics of the side-by-side tables: (key, header, format).
GAP_METRICS = (("rmse_render", "render RMSE", ".4f"), ("ssim_render", "render SSIM", ".3f"))
#: Names of the evaluation sets in the summary.
SET_TITLES = {"heldout": "held-out", "foreign": "foreign", "strips": "strips"}


def compare_sets(rows: Sequence[dict[str, Any]], sets: Sequence[str] = ("heldout", "foreign", "strips"),
                 metrics: Sequence[str] = ("rmse_render", "ssim_render")) -> list[dict[str, Any]]:
    """Per (method, N, budget) run on the held-out set, each set's mean of ``metrics`` and the gaps.

    Args:
        rows: the runner's rows.
        sets: the sets to compare (those without rows are left out); the first is the reference.
        metrics: metric keys.

    Returns:
        Dicts with method, n, budget_s, ``materials_SET``, ``METRIC_SET`` (NaN when the set has no
        such row) and ``gap_METRIC_SET`` = ``METRIC_SET − METRIC_REFERENCE`` for every other set;
        ordered like :func:`aggregate`.
    """
    present = [s for s in sets if any(r["dataset"] == s for r in rows)]
    if not present or present[0] != sets[0]:
        return []
    per_set = {s: {(a["method"], a["n"], a["budget_s"]): a for a in aggregate(rows, s)} for s in present}
    ref = sets[0]
    out = []
    for key, a in per_set[ref].items():
        entry: dict[str, Any] = {"method": key[0], "n": key[1], "budget_s": key[2]}
        for s in present:
            b = per_set[s].get(key)
            entry[f"materials_{s}"] = b["materials"] if b else 0
            for k in metrics:
                entry[f"{k}_{s}"] = b[k] if b else math.nan
        for s in present[1:]:
            for k in metrics:
                entry[f"gap_{k}_{s}"] = entry[f"{k}_{s}"] - entry[f"{k}_{ref}"]
        out.append(entry)
    return out


def method_gaps(comparison: Sequence[dict[str, Any]], other: str = "foreign", reference: str = "heldout",
                metric: str = "rmse_render") -> dict[str, dict[str, float]]:
    """Per method, the mean of ``metric`` on both sets over its (N, budget) rows run on both, and the gap.

    Returns:
        ``{method: {"reference": mean, "other": mean, "gap": other − reference, "rows": count}}``
        (methods without a row on ``other`` are left out).
    """
    out: dict[str, dict[str, float]] = {}
    for method in dict.fromkeys(c["method"] for c in comparison):
        both = [c for c in comparison if c["method"] == method and not math.isnan(c.get(f"{metric}_{other}", math.nan))]
        if both:
            ref = sum(c[f"{metric}_{reference}"] for c in both) / len(both)
            oth = sum(c[f"{metric}_{other}"] for c in both) / len(both)
            out[method] = {"reference": ref, "other": oth, "gap": oth - ref, "rows": len(both)}
    return out


def comparison_table(comparison: Sequence[dict[str, Any]], sets: Sequence[str]) -> list[str]:
    """Markdown lines of :func:`compare_sets`: per method, N and budget, each set's render RMSE and SSIM
    side by side, and each other set's gap from the first (held-out)."""
    ref, others = sets[0], list(sets[1:])
    head = ["method", "N", "budget"]
    for key, title, _ in GAP_METRICS:
        head += [f"{SET_TITLES.get(s, s)} {title}" for s in sets]
        head += [f"gap {title} ({SET_TITLES.get(s, s)} − {SET_TITLES.get(ref, ref)})" for s in others]
    rows = []
    for c in comparison:
        cells = [c["method"], str(c["n"]), f"{c['budget_s']:g} s" if c["budget_s"] is not None else ""]
        for key, _, f in GAP_METRICS:
            cells += [_cell(c[f"{key}_{s}"], f) for s in sets]
            cells += [_cell(c[f"gap_{key}_{s}"], "+" + f) for s in others]
        rows.append(cells)
    return markdown_table(head, rows).split("\n")


def _cell(value: float, fmt: str) -> str:
    return "–" if math.isnan(value) else format(value, fmt)


def generalisation_section(rows: Sequence[dict[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    """The summary's "Generalisation" section (Markdown lines) and the comparison behind it ([] without
    foreign or strips rows)."""
    sets = [s for s in ("heldout", "foreign", "strips") if any(r["dataset"] == s for r in rows)]
    if len(sets) < 2 or sets[0] != "heldout":
        return [], []
    comparison = compare_sets(rows, sets)
    md = ["## Generalisation: held-out vs " + " and ".join(SET_TITLES[s] for s in sets[1:]), "",
          "Means over each set's materials. **held-out**: procedural materials of held-out parameter slices, "
          "photographed with the training's capture distribution. **foreign**: materials of classes and "
          "ranges training never draws, photographed with every capture parameter outside the training "
          "ranges (`mi_svbrdf/data/foreign.py`: wide-angle close-up, off-centre camera, off-camera flash "
          "close to the sample, weak flash, colour cast, wide cone aimed beside the sample, two raking "
          "lamps, high noise, JPEG). Gap = the other set's value minus the held-out one (RMSE: > 0 is "
          "worse; SSIM: < 0 is worse).", ""]
    if "strips" in sets:
        md += ["**strips**: the user's folder of the thesis's 2019 test strips (10 inputs + 4 maps, inputs "
               "decoded with x^2.2, resized to the run's size). They carry no calibration: optimize and "
               "refine are not run on them (–); trivial assumes photo 0 is the authors' un-augmented flash "
               "photo (light (0, 0, 2.197), camera (0, 0, 2.75), I = 13, cone e = 5); uncalibrated runs as "
               "everywhere, estimating every photo's light from the photos.", ""]
    md += [*comparison_table(comparison, sets), ""]
    for other in sets[1:]:
        gaps = method_gaps(comparison, other)
        if not gaps:
            continue
        t = SET_TITLES[other]
        md += [f"Gap per method ({t} − held-out), render RMSE averaged over the method's N and budgets run on "
               "both sets:", "",
               markdown_table(["method", "held-out", t, "gap", "rows"],
                              [[m, f"{g['reference']:.4f}", f"{g['other']:.4f}", f"{g['gap']:+.4f}", g["rows"]]
                               for m, g in gaps.items()]), ""]
    return md, comparison


def pareto_front(times: Sequence[float], errors: Sequence[float]) -> list[bool]:
    """Which points are Pareto-optimal: no other point has time <= and error <= with one strictly less.

    Args:
        times: wall time of each point.
        errors: error of each point (lower is better).

    Returns:
        One bool per point.
    """
    if len(times) != len(errors):
        raise ValueError(f"errors: expected {len(times)} values like times, got {len(errors)}")
    pts = list(zip(times, errors))
    return [not any(t2 <= t and e2 <= e and (t2 < t or e2 < e) for t2, e2 in pts) for t, e in pts]


def images_to_match(rows: Sequence[dict[str, Any]], *, reference: tuple[str, int] = ("multi", 5),
                    method: str = "optimize", metric: str = "rmse_render",
                    budget: float | None = None) -> dict[int, int | None]:
    """Per held-out material, the fewest images with which ``method`` matches ``reference`` (thesis Fig. 4.8).

    Args:
        rows: the runner's rows (per material).
        reference: (method, N) to match, e.g. the 5-image multi net.
        method: the method that must match it (the optimiser).
        metric: a metric key; RMSEs must be <=, SSIMs >= the reference's.
        budget: the method's budget (None: the largest one in ``rows``).

    Returns:
        ``{material: N or None}`` (None: no N in ``rows`` matches); materials without a reference row are left out.
    """
    higher = metric.startswith("ssim")
    held = [r for r in rows if r["dataset"] == "heldout"]
    if not any(r["method"] == method for r in held):  # e.g. --methods trivial,multi: nothing to match with
        return {}
    if budget is None:
        budgets = [r["budget_s"] for r in held if r["method"] == method and r["budget_s"] is not None]
        budget = max(budgets) if budgets else None
    ref = {r["material"]: r[metric] for r in held if (r["method"], r["n"]) == reference}
    out: dict[int, int | None] = {}
    for m, target in sorted(ref.items()):
        cands = sorted(r["n"] for r in held if r["material"] == m and r["method"] == method
                       and r["budget_s"] == budget and (r[metric] >= target if higher else r[metric] <= target))
        out[m] = cands[0] if cands else None
    return out


def paired_differences(rows: Sequence[dict[str, Any]], metric: str = "rmse_render") -> list[dict[str, Any]]:
    """The headline comparisons on the held-out set, paired per material: ``a − b`` of ``metric``.

    Pairs (:data:`PAIRS`): single vs trivial (N = 1), multi vs trivial, optimize vs trivial, refine vs
    multi and uncalibrated vs multi (each N and budget), uncalibrated vs refine (each N, at the same budget:
    what the captures are worth). Each dict: ``a``, ``b`` (labels), ``materials``, ``diff`` (mean over the
    materials both have), ``se`` (its standard error; NaN for one material) and ``resolved`` (``|diff| > 2 se``).
    """
    held = {(r["method"], r["n"], r["budget_s"], r["material"]): r[metric] for r in rows if r["dataset"] == "heldout"}
    keys = sorted({k[:3] for k in held}, key=lambda k: (METHODS.index(k[0]) if k[0] in METHODS else 99, k[1],
                                                        k[2] or 0.0))
    out = []
    for method, n, budget in keys:
        for _, reference, same_budget in (p for p in PAIRS if p[0] == method):
            ref = (reference, n, budget if same_budget else None)
            if ref not in keys:
                continue
            diffs = [held[(method, n, budget, m)] - held[(*ref, m)] for (mm, nn, bb, m) in held
                     if (mm, nn, bb) == (method, n, budget) and (*ref, m) in held]
            if not diffs:
                continue
            mean = sum(diffs) / len(diffs)
            se = math.sqrt(sum((d - mean) ** 2 for d in diffs) / (len(diffs) - 1) / len(diffs)) if len(diffs) > 1 \
                else math.nan
            out.append({"a": f"{label(method, budget)} N={n}", "b": f"{label(*ref[::2])} N={n}",
                        "materials": len(diffs), "diff": mean, "se": se, "resolved": bool(abs(mean) > 2 * se)})
    return out


def small_run_section(rows: Sequence[dict[str, Any]], size: int | None) -> list[str]:
    """Markdown lines saying what a run smaller than the full one (:class:`~mi_svbrdf.eval.runner.EvalConfig`'s
    defaults: 16 materials at 256^2, budgets up to 30 s) can and cannot show; [] for a full-size run.

    Args:
        rows: the runner's rows.
        size: the run's resolution (``settings.json``), None when unknown.
    """
    full = EvalConfig()
    held = [r for r in rows if r["dataset"] == "heldout"]
    materials = len({r["material"] for r in held})
    budgets = [r["budget_s"] for r in held if r["budget_s"] is not None]
    small = []
    if materials < full.materials:
        small.append(f"{materials} held-out material{'s' if materials != 1 else ''} (full run: {full.materials})")
    if size is not None and size < full.size:
        small.append(f"{size}^2 (full run: {full.size}^2)")
    if budgets and max(budgets) < max(full.budgets):
        small.append(f"optimiser budgets up to {max(budgets):g} s (full run: up to {max(full.budgets):g} s)")
    if not small:
        return []
    pairs = paired_differences(rows)
    fits = [r for r in held if r["method"] in BUDGET_METHODS]
    cut = sum(r.get("stop_reason") == "budget" for r in fits)
    plural = "s" if materials != 1 else ""
    bullets = [(f"- **Noise.** With {materials} material{plural} a method's mean render RMSE has the standard "
                "error given after ± in the table; the comparisons below are paired per material, and one within "
                "twice its standard error does not say which method is better.")]
    if size is not None and size < full.size:
        bullets.append(f"- **Size.** The nets were trained at {full.size}^2: at {size}^2 their photos are resized "
                       "up to that and their maps back down, and every error is measured on fewer texels, so "
                       "the full run's ranking need not hold here.")
    if fits:
        uncal = [r for r in fits if r["method"] == "uncalibrated"]
        of_uncal = (f" (the uncalibrated refinement's: {sum(r.get('stop_reason') == 'budget' for r in uncal)} of "
                    f"{len(uncal)})") if uncal else ""
        bullets.append(f"- **Budgets.** {cut} of {len(fits)} optimiser and refinement fits{of_uncal} stopped on their "
                       "budget rather than on convergence: their errors are those of cut-short fits.")
    md = ["## What this run can and cannot show", "",
          (f"This is a reduced run: {', '.join(small)}. It shows that every method runs end to end on each set, "
           "what each costs at this size, and differences larger than their noise. It is not the full result "
           "(`mi-svbrdf evaluate` without `--quick`; docs/results.md gives its figures):"), "",
          *bullets, ""]
    table = []
    for p in pairs:
        if math.isnan(p["se"]):
            reading = "cannot tell (one material)"
        elif p["resolved"]:
            reading = f"{p['a']} {'better' if p['diff'] < 0 else 'worse'}"
        else:
            reading = "within noise"
        table.append([f"{p['a']} − {p['b']}", p["materials"], f"{p['diff']:+.4f}", _cell(2 * p["se"], ".4f"), reading])
    md.append(markdown_table(["comparison (held-out, render RMSE)", "materials", "difference", "± 2 SE", "reading"],
                             table))
    noise = [p for p in pairs if not p["resolved"] and not math.isnan(p["se"])]
    if noise:
        md += ["", f"{len(noise)} of {len(pairs)} comparisons are within noise at this size."]
    return md + [""]


def degradation(rows: Sequence[dict[str, Any]], metric: str = "rmse_render") -> dict[str, dict[str, float]]:
    """``{case: {method: metric(case) - metric(clean)}}`` of the failure-case rows (cases with a clean twin)."""
    val = {(r["dataset"], r["method"]): r[metric] for r in rows if r["dataset"].startswith(("case:", "clean:"))}
    out: dict[str, dict[str, float]] = {}
    for (ds, method), v in val.items():
        if ds.startswith("case:") and ("clean:" + ds[5:], method) in val:
            out.setdefault(ds[5:], {})[method] = v - val[("clean:" + ds[5:], method)]
    return out


#: What each metric of charts (a) and (b) measures, as its axis title.
METRIC_TITLES = {"rmse_render": "re-render RMSE (display values)", "rmse_normal": "normal RMSE ((n + 1) / 2)",
                 "rmse_diffuse": "diffuse albedo RMSE (linear)", "rmse_roughness": "roughness RMSE",
                 "rmse_specular": "specular albedo RMSE (linear)", "ssim_render": "re-render SSIM",
                 "ssim_normal": "normal map SSIM", "ssim_diffuse": "diffuse map SSIM",
                 "ssim_roughness": "roughness map SSIM", "ssim_specular": "specular map SSIM"}


def metric_title(key: str) -> str:
    """A metric's axis title in words (:data:`METRIC_TITLES`; the key itself when it has none).

    Examples:
        >>> metric_title("rmse_render"), metric_title("ssim_normal")
        ('re-render RMSE (display values)', 'normal map SSIM')
    """
    return METRIC_TITLES.get(key, key)


def _label_panel(ax: Any, key: str, xlabel: str, title: str) -> None:
    """Log x axis and labels of one panel of charts (a) and (b)."""
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(metric_title(key))
    ax.set_title(title)


def _shared_legend(fig: Any, axes: Sequence[Any]) -> None:
    """One legend for every panel, under them (each panel draws the same methods): its entries from every panel,
    once each."""
    handles: dict[str, Any] = {}
    for ax in axes:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(text, handle)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(len(handles), 8), fontsize=8,
                   frameon=False)


def point_label(a: dict[str, Any]) -> str:
    """A point of chart (a) in words: ``"N=5"``, ``"N=5, 15 s"`` for a run with a budget.

    Examples:
        >>> point_label({"n": 5, "budget_s": 15.0}), point_label({"n": 1, "budget_s": None})
        ('N=5, 15 s', 'N=1')
    """
    return f"N={a['n']}" + (f", {a['budget_s']:g} s" if a.get("budget_s") is not None else "")


#: Wall times below this are drawn at it in chart (a) (a log axis has no place for 0 s).
MIN_SECONDS = 1e-3


def chart_speed_accuracy(agg: Sequence[dict[str, Any]], path: Path) -> None:
    """(a): error against wall time (log axis), Pareto front per panel; each point labelled with its photos N and
    budget (:func:`point_label`, placed apart: :func:`~mi_svbrdf.io.figures.label_points`); one legend for every
    panel, under them."""
    plt = pyplot()
    keys = ("rmse_render",) + tuple(f"rmse_{k}" for k in MAP_NAMES)
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 4.4))
    times = [max(a["seconds"], MIN_SECONDS) for a in agg]
    xlabel = "wall time per material (s, log)"
    if any(a["seconds"] < MIN_SECONDS for a in agg):
        xlabel = f"wall time per material (s, log; under {MIN_SECONDS * 1e3:g} ms: at {MIN_SECONDS * 1e3:g} ms)"
    for ax, key in zip(axes, keys):
        for method in dict.fromkeys(a["method"] for a in agg):
            pts = [(t, a) for t, a in zip(times, agg) if a["method"] == method]
            ax.scatter([t for t, _ in pts], [a[key] for _, a in pts], color=COLOURS.get(method), label=method,
                       s=18 + 4 * min(a["n"] for _, a in pts), alpha=0.8)
        errs = [a[key] for a in agg]
        front = sorted((t, e) for t, e, f in zip(times, errs, pareto_front(times, errs)) if f)
        if front:
            ax.step([t for t, _ in front], [e for _, e in front], where="post", color="k", lw=1,
                    label="Pareto front (ringed: no other point is both faster and more accurate)")
            ax.scatter([t for t, _ in front], [e for _, e in front], facecolors="none", edgecolors="k", s=90)
        _label_panel(ax, key, xlabel, metric_title(key).split(" (")[0] + " vs time")
        ax.margins(x=0.25, y=0.15)  # room for the labels of the points at the edges
    _shared_legend(fig, axes)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    for ax, key in zip(axes, keys):  # which run each point is (its photos, its budget), placed once the layout is set
        label_points(ax, times, [a[key] for a in agg], [point_label(a) for a in agg],
                     colors=[COLOURS.get(a["method"], "k") for a in agg])
    save_figure(fig, path)


def chart_ssim_vs_images(agg: Sequence[dict[str, Any]], path: Path) -> None:
    """(b): re-render SSIM and per-map SSIM against N (thesis Fig. 4.4), ticks at the N run; the single-image net,
    run at N = 1 only, as one point."""
    plt = pyplot()
    keys = ("ssim_render",) + tuple(f"ssim_{k}" for k in MAP_NAMES)
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 4.2))
    series = dict.fromkeys((a["method"], a["budget_s"]) for a in agg)
    top_budget = max([b for _, b in series if b] or [1])
    ns = sorted({a["n"] for a in agg})
    for ax, key in zip(axes, keys):
        for method, budget in series:
            pts = sorted((a["n"], a[key]) for a in agg if (a["method"], a["budget_s"]) == (method, budget))
            style = "--" if method == "trivial" else "-"
            name = label(method, budget) + (" (N = 1 only)" if method == "single" else "")
            ax.plot([n for n, _ in pts], [v for _, v in pts], style, marker="D" if method == "single" else "o",
                    ms=6 if method == "single" else 3, color=COLOURS.get(method),
                    alpha=0.5 + 0.5 * (budget or 0) / top_budget if budget else 1.0, label=name)
        _label_panel(ax, key, "number of images N (log)", metric_title(key) + " vs N")
        integer_ticks(ax.xaxis, ns)
    _shared_legend(fig, axes)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    save_figure(fig, path)


def chart_images_to_match(needed: dict[int, int | None], classes: dict[int, str], n_max: int,
                          reference: tuple[str, int], path: Path) -> None:
    """(c): bar per material of the images the optimiser needs to match the reference net."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(max(4.5, 0.6 * len(needed) + 2), 4.4))
    mats = list(needed)
    vals = [needed[m] if needed[m] is not None else n_max + 1 for m in mats]
    bars = ax.bar(range(len(mats)), vals, color=["tab:green" if needed[m] is not None else "lightgray" for m in mats])
    for bar, m in zip(bars, mats):
        if needed[m] is None:
            bar.set_hatch("//")
            ax.text(bar.get_x() + bar.get_width() / 2, bar.get_height(), f">{n_max}", ha="center", va="bottom",
                    fontsize=7)
    ax.axhline(reference[1], color="tab:blue", ls="--", lw=1,
               label=f"the {reference[0]} net's N = {reference[1]}; hatched: more than {n_max} (not matched)")
    ax.set_xticks(range(len(mats)), [f"{m}\n{classes.get(m, '')}" for m in mats], fontsize=7)
    ax.set_ylabel("images the optimiser needs")
    ax.set_ylim(0, n_max + 2)  # room above the tallest bar and its label
    ax.set_title(f"calibrated images the optimiser needs to match\nthe {reference[0]} net on {reference[1]} photos "
                 "(re-render RMSE)", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2))  # below the axes: it covers no bar
    fig.tight_layout()
    save_figure(fig, path)


def chart_failure_cases(deg: dict[str, dict[str, float]], path: Path) -> None:
    """(e): grouped bars, per failure case, of each method's degradation from the clean case."""
    plt = pyplot()
    cases = sorted(deg)
    methods = [m for m in METHODS if any(m in deg[c] for c in cases)]
    fig, ax = plt.subplots(figsize=(max(5.0, 1.2 * len(cases) + 2), 4))
    width = 0.8 / max(len(methods), 1)
    for i, m in enumerate(methods):
        ax.bar([c + i * width for c in range(len(cases))], [deg[c].get(m, math.nan) for c in cases], width,
               color=COLOURS.get(m), label=m)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks([c + 0.4 - width / 2 for c in range(len(cases))], cases, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("re-render RMSE: case − clean")
    ax.set_title("degradation from the clean case")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def _panels(maps: torch.Tensor, lights: Any) -> list[torch.Tensor]:
    """Normal, diffuse, roughness, specular (albedos gamma-encoded) and two re-renderings: ``(3, H, W)`` each."""
    m = maps.float()
    renders = display(rerender(m, lights))[0]
    panels = preview_panels(m)
    for name in ("diffuse", "specular"):
        panels[name] = gamma_encode(panels[name])
    return [panels[name][0] for name in MAP_NAMES] + [renders[0], renders[1]]


def chart_gallery(gallery: dict[str, Any], predictions: dict[str, torch.Tensor], path: Path) -> None:
    """(d): inputs, then each method's maps and re-renderings, then the ground truth."""
    plt = pyplot()
    lights = eval_lights(2)
    rows = [("ground truth", _panels(gallery["maps"], lights))]
    rows = [(name, _panels(p, lights)) for name, p in predictions.items()] + rows
    inputs = gallery["inputs"][0].float()
    ncol = max(6, inputs.shape[0])  # six panels per method; more columns when more photos
    fig, axes = plt.subplots(len(rows) + 1, ncol, figsize=(1.7 * ncol, 1.8 * (len(rows) + 1)), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for k in range(min(inputs.shape[0], ncol)):
        axes[0, k].imshow(gamma_encode(inputs[k]).permute(1, 2, 0).numpy())
        axes[0, k].set_title(f"input {k}", fontsize=7)
    titles = ("normal", "diffuse", "roughness", "specular", "render 0", "render 1")
    for i, (name, panels) in enumerate(rows, start=1):
        for k, img in enumerate(panels):
            axes[i, k].imshow(img.clamp(0, 1).permute(1, 2, 0).numpy())
            axes[i, k].set_title(f"{name}: {titles[k]}" if k == 0 else titles[k], fontsize=7)
    fig.suptitle(f"gallery: held-out material ({gallery.get('class', '')})", fontsize=9)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.93, wspace=0.05, hspace=0.25)  # fast, no tight_layout
    save_figure(fig, path)


def _prediction_order(name: str) -> tuple[int, int, float]:
    """Sort key ``(method order, N, budget)`` of a saved prediction's name, e.g. ``"optimize_n5_30s"``."""
    method, _, rest = name.partition("_n")
    n, _, budget = rest.partition("_")
    order = METHODS.index(method) if method in METHODS else len(METHODS)
    return order, int(n) if n.isdigit() else 0, float(budget.rstrip("s") or 0.0) if budget else 0.0


def _with_error(a: dict[str, Any], key: str, fmt: str) -> str:
    """``mean ± standard error`` of ``key`` in an :func:`aggregate` row; ``mean (n = 1)`` for one material (no
    error)."""
    se = a.get(f"se_{key}", math.nan)
    if a["materials"] < 2 or not math.isfinite(se):
        return f"{a[key]:{fmt}} (n = {a['materials']})"
    return f"{a[key]:{fmt}} ± {se:{fmt}}"


def aggregate_table(agg: Sequence[dict[str, Any]]) -> list[str]:
    """The lines of the summary table of :func:`aggregate`'s output (Markdown): the re-render RMSE with its
    standard error over the materials (``(n = 1)`` for one material, which has none)."""
    head = ["method", "N", "budget", "materials", "time (s)", "peak MB", *[h for _, h, _ in TABLE], "recoveries"]
    rows = [[a["method"], str(a["n"]), f"{a['budget_s']:g} s" if a["budget_s"] is not None else "",
             str(a["materials"]), f"{a['seconds']:.2f}", f"{a['peak_mb']:.0f}",
             *[_with_error(a, k, f) if k == "rmse_render" else format(a[k], f) for k, _, f in TABLE],
             str(a["recoveries"])] for a in agg]
    return markdown_table(head, rows).split("\n")


def write_evaluation_report(out: str | os.PathLike, rows: Sequence[dict[str, Any]], *, reference_n: int = 5,
                 notes: Sequence[str] = (), ablations_dir: str | os.PathLike | None = None) -> dict[str, Path]:
    """Write the summary, the CSV and the charts (module docstring) into ``out``; returns ``{name: path}``.

    Args:
        out: the report folder (``gallery/`` and ``predictions/`` of the runner are read from it).
        rows: the runner's rows.
        reference_n: N of the multi-image net the optimiser must match (chart c).
        notes: lines added to the summary (skipped methods, settings).
        ablations_dir: a folder written by ``mi-svbrdf ablations`` (:mod:`~mi_svbrdf.eval.studies.ablations`):
            its section "Ablations" goes after the real-style checks (None: none).
    """
    out = Path(out)
    agg = aggregate(rows)
    if not agg:
        raise ValueError(f"rows: expected held-out rows to report, got {len(rows)} rows and none held-out")
    files = {"summary.md": out / "summary.md", "summary.csv": out / "summary.csv"}
    keys = ["method", "n", "budget_s", "materials", "seconds", "peak_mb", "recoveries"] + \
           [k for k in COLUMNS if k.startswith(("rmse_", "ssim_"))]
    write_text(files["summary.csv"], "\n".join([",".join(keys)] + [",".join("" if a[k] is None else f"{a[k]:.6g}"
                                                                           if isinstance(a[k], float) else str(a[k])
                                                                           for k in keys) for a in agg]) + "\n",
               fsync=False)
    files["a"] = out / "a_speed_accuracy.png"
    chart_speed_accuracy(agg, files["a"])
    general, comparison = generalisation_section(rows)
    if comparison:
        files["sets.csv"] = out / "sets.csv"
        keys = list(comparison[0])
        write_text(files["sets.csv"], "\n".join([",".join(keys)] + [
            ",".join("" if c[k] is None else f"{c[k]:.6g}" if isinstance(c[k], float) else str(c[k]) for k in keys)
            for c in comparison]) + "\n", fsync=False)
    settings = out / "settings.json"
    size = json.loads(settings.read_text()).get("size") if settings.is_file() else None
    md = ["# mi-svbrdf evaluate", "", *[f"- {n}" for n in notes], "", *small_run_section(rows, size),
          "Mean over the held-out materials (`results.csv` has one row per material). RMSE of normals as "
          "(n + 1)/2, albedos linear; `diffuse×k` after the best global scale; re-renderings displayed "
          "(clip, 1/2.2) under the fixed evaluation lights (`mi_svbrdf.core.metrics.eval_lights`). Time: wall "
          "seconds per material; peak MB: peak RSS above the start of the call (the kernel's high-water mark, "
          "reset before the call); ± the standard "
          "error of the mean over the materials.", "",
          *aggregate_table(agg), "", "![speed vs accuracy](a_speed_accuracy.png)", "", *general]
    if (out / real_checks.JSON_NAME).is_file():
        real = json.loads((out / real_checks.JSON_NAME).read_text())
        files["real_checks"] = out / real_checks.JSON_NAME
        files.update({f"real_{k}": out / name for k, name in real["figures"].items()})
        md += real_checks.real_checks_markdown(real)
    if ablations_dir is not None:
        files["ablations"] = Path(ablations_dir) / "ablations.json"
        md += ["## Ablations at equal compute (thesis ch. 3.1.2, 3.1.3, 4.2.2, 4.4.1)", "",
               *ablations.ablations_markdown(ablations_dir, relative_to=out), ""]
    curves = [a for a in agg if a["method"] in CURVE_METHODS]
    if len({a["n"] for a in curves}) > 1:
        files["b"] = out / "b_ssim_vs_images.png"
        chart_ssim_vs_images(curves, files["b"])
        md += ["![SSIM vs number of images](b_ssim_vs_images.png)", ""]
    ref_n = max([a["n"] for a in agg if a["method"] == "multi" and a["n"] <= reference_n] or [0])
    needed = images_to_match(rows, reference=("multi", ref_n)) if ref_n else {}
    if not needed:
        missing = [what for what, method in (("multi-image net", "multi"), ("optimiser", "optimize"))
                   if not any(a["method"] == method for a in agg)]
        why = " and ".join(f"no {what} was run" for what in missing) or f"no multi-image net row at N <= {reference_n}"
        md += [f"Chart (c) not drawn: it needs multi-image net rows and optimiser rows ({why}).", ""]
    else:
        classes = {r["material"]: r["class"] for r in rows if r["dataset"] == "heldout"}
        n_max = max(r["n"] for r in rows if r["dataset"] == "heldout" and r["method"] == "optimize")
        files["c"] = out / "c_images_to_match.png"
        chart_images_to_match(needed, classes, n_max, ("multi", ref_n), files["c"])
        md += [f"## Images the optimiser needs to match the {ref_n}-image network", "",
               markdown_table(["material", "class", "N needed"],
                              [[m, classes.get(m, ""), n if n is not None else f"> {n_max}"] for m, n in needed.items()]),
               "", "![images to match](c_images_to_match.png)", ""]
    for g in sorted((out / "gallery").glob("heldout_m*.pt")):
        m = int(g.stem.split("_m")[1])
        preds = {}
        for p in sorted((out / "predictions").glob(f"heldout_m{m}_*.pt")):
            name = p.stem.split(f"heldout_m{m}_", 1)[1]
            preds[name] = torch.load(p, weights_only=True).float()
        preds = dict(sorted(preds.items(), key=lambda kv: _prediction_order(kv[0])))
        gallery = torch.load(g, weights_only=True)
        if preds:  # show the photos the methods saw (the largest N among them)
            gallery["inputs"] = gallery["inputs"][:, :max(_prediction_order(k)[1] for k in preds)]
        files[f"d{m}"] = out / f"d_gallery_m{m}.png"
        chart_gallery(gallery, preds, files[f"d{m}"])
        md += [f"![gallery material {m}](d_gallery_m{m}.png)", ""]
    deg = degradation(rows)
    if deg:
        files["e"] = out / "e_failure_cases.png"
        chart_failure_cases(deg, files["e"])
        methods = [m for m in METHODS if any(m in d for d in deg.values())]
        md += ["## Failure cases: re-render RMSE minus the clean case's", "",
               markdown_table(["case", *methods], [[c, *(f"{deg[c].get(m, math.nan):+.4f}" for m in methods)]
                                                   for c in sorted(deg)]),
               "", "![failure cases](e_failure_cases.png)", ""]
    stab = stability.read_stability(out)
    if stab:
        files["stability"] = out / stability.CSV_NAME
        md += [*stability.stability_table(stab), ""]
    write_text(files["summary.md"], "\n".join(md) + "\n", fsync=False)
    return files
