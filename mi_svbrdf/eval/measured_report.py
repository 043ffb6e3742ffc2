"""The report of ``mi-svbrdf calibrate``: conoscopic maps, in-plane slices, the error figures, JSON and Markdown.

Every plot shows the cosine-weighted BRDF ``f · cos θ_o`` (1/sr) of :mod:`mi_svbrdf.eval.measured_comparison`.
Conoscopic maps are polar: the radius is θ_o (degrees, 0 at the centre), the angle φ_o, with the
light at φ_o = 0 (right) and the mirror direction at φ_o = 180° (left, marked ×); colour maps
show the luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` of the values (log scale shared by the
measurement and ours), the relative error ``|o − m| / m`` of Y (0–100 %, cells where m is below
1e-3 of its maximum left blank) and the absolute error ``|o − m|`` of Y; cells without measured
data are blank. Files written by :func:`write_measured_report`:

- ``report.json`` -- :func:`mi_svbrdf.eval.measured_comparison.comparison_summary` (with the BRDF model of
  the maps compared, ``distribution``) plus the measurement, the material, the direct fit and the
  applied correction;
- ``summary.md`` -- the same as tables, with the plots;
- ``conoscopic.png`` -- per incidence: measured | ours | relative error | absolute error;
- ``conoscopic_corrected.png`` -- the same with ours times the correction's factor;
- ``inplane.png`` -- the in-plane slice per incidence, per channel: measured, ours, ours corrected;
- ``errors.png`` -- the thesis's three figures per channel: factor, absolute and relative error,
  before and after the corrections.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core.colour import luminance
from mi_svbrdf.core.conoscopic import ConoscopicGrid
from mi_svbrdf.eval.measured_comparison import MeasuredComparison, comparison_summary
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.optim.fit_measured import DirectFit

#: Files :func:`write_measured_report` writes.
REPORT_FILES = ("report.json", "summary.md", "conoscopic.png", "conoscopic_corrected.png", "inplane.png",
                "errors.png")
_CHANNELS = ("R", "G", "B")
_COLOURS = ("tab:red", "tab:green", "tab:blue")


def _luminance(values: torch.Tensor) -> np.ndarray:
    """``(..., 3)`` RGB -> ``(...)`` numpy luminance (:func:`mi_svbrdf.core.colour.luminance`)."""
    return luminance(values.to(torch.float64), dim=-1).numpy()


def polar_image(grid: ConoscopicGrid, values: np.ndarray, size: int = 161) -> np.ndarray:
    """A ``(T, P)`` polar-grid map as a ``(size, size)`` image (x right = φ_o 0, y up = φ_o 90°; radius θ_o).

    Each pixel takes its cell's value (nearest cell); pixels beyond ``theta_max_deg`` are NaN.
    """
    lim = grid.theta_max_deg
    c = np.linspace(-lim, lim, size)
    x, y = np.meshgrid(c, c[::-1])
    r = np.hypot(x, y)
    phi = np.mod(np.arctan2(y, x), 2 * np.pi)
    n_t, n_p = values.shape
    it = np.clip((r / lim * n_t).astype(int), 0, n_t - 1)
    ip = np.clip((phi / (2 * np.pi) * n_p).astype(int), 0, n_p - 1)
    return np.where(r <= lim, values[it, ip], np.nan)


def _polar_axes(ax: Any, lim: float) -> None:
    from matplotlib.patches import Circle

    for radius in (30.0, 60.0):
        if radius < lim:
            ax.add_patch(Circle((0, 0), radius, fill=False, color="0.7", lw=0.5))
            ax.text(radius * 0.71, radius * 0.71, f"{radius:g}°", fontsize=6, color="0.7")
    ax.add_patch(Circle((0, 0), lim, fill=False, color="0.3", lw=0.8))
    ax.axhline(0, color="0.7", lw=0.4)
    ax.axvline(0, color="0.7", lw=0.4)
    ax.set_xlim(-lim * 1.02, lim * 1.02)
    ax.set_ylim(-lim * 1.02, lim * 1.02)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for side in ax.spines.values():
        side.set_visible(False)


def plot_conoscopic(cmp: MeasuredComparison, path: str | os.PathLike, corrected: bool = False) -> None:
    """Conoscopic maps per incidence: measured | ours | relative error | absolute error (see the module docstring)."""
    from matplotlib.colors import LogNorm, Normalize

    plt = pyplot()
    grid = cmp.grid
    lim = grid.theta_max_deg
    n_inc = len(grid.incidences_deg)
    ours = cmp.corrected() if corrected else cmp.ours
    valid = cmp.valid.numpy()
    # map columns 0, 1, 3, 5; colour bars in 2 (measured and ours share the row's log scale), 4, 6
    fig, cells = plt.subplots(n_inc, 7, figsize=(14, 3.0 * n_inc), squeeze=False,
                              gridspec_kw={"width_ratios": [1, 1, 0.05, 1, 0.05, 1, 0.05]})
    axes = cells[:, [0, 1, 3, 5]]
    bars = {1: cells[:, 2], 2: cells[:, 4], 3: cells[:, 6]}
    label = "ours × factor" if corrected else "ours"
    for i, theta_i in enumerate(grid.incidences_deg):
        m, o = _luminance(cmp.measured[i]), _luminance(ours[i])
        top = max(float(m[valid[i]].max()) if valid[i].any() else 0.0, float(o.max()), 1e-12)
        norm = LogNorm(vmin=top * 1e-3, vmax=top)
        rel = np.abs(o - m) / np.where(m > top * 1e-3, m, np.nan)
        absd = np.where(valid[i], np.abs(o - m), np.nan)
        panels = [(np.where(valid[i], m, np.nan), norm, "magma", "measured"),
                  (o, norm, "magma", label),
                  (np.where(valid[i], rel, np.nan), Normalize(0.0, 1.0), "viridis", "relative error"),
                  (absd, Normalize(0.0, max(float(np.nanmax(absd)) if np.isfinite(absd).any() else 0.0, 1e-12)),
                   "viridis", "absolute error (1/sr)")]
        for j, (data, nrm, cmap, title) in enumerate(panels):
            ax = axes[i, j]
            image = polar_image(grid, np.clip(data, nrm.vmin, None) if isinstance(nrm, LogNorm) else data)
            shown = ax.imshow(np.ma.masked_invalid(image), extent=(-lim, lim, -lim, lim), norm=nrm, cmap=cmap,
                              interpolation="nearest")
            _polar_axes(ax, lim)
            ax.plot([-theta_i], [0.0], "x", color="white" if j < 2 else "black", ms=6)
            ax.set_title(f"θi = {theta_i:g}°: {title}", fontsize=8)
            if j == 0:
                continue
            bar = fig.colorbar(shown, cax=bars[j][i], extend="max" if j == 2 else "neither")
            bar.ax.minorticks_off()
            bar.ax.tick_params(labelsize=6)
            if j == 2:
                bar.set_ticks([0, 0.5, 1.0])
                bar.set_ticklabels(["0", "50 %", "100 %"])
    which = f" × factor ({cmp.correction})" if corrected else ""
    fig.suptitle(f"f·cos θo (luminance), measured vs ours{which}. Radius θo (circles 30°, 60°, rim "
                 f"{lim:g}°); light at φo = 0 (right), × the mirror direction; blank: no measured data", fontsize=9)
    fig.subplots_adjust(left=0.01, right=0.96, bottom=0.02, top=1.0 - 0.25 / n_inc, wspace=0.3, hspace=0.25)
    save_figure(fig, path)


def plot_inplane(cmp: MeasuredComparison, path: str | os.PathLike) -> None:
    """The in-plane slice per incidence and channel: measured (solid), ours (dashed), ours corrected (dotted)."""
    plt = pyplot()
    grid = cmp.grid
    n_inc = len(grid.incidences_deg)
    cols = min(n_inc, 3)
    rows = (n_inc + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    x = grid.slice_deg.numpy()
    corr = cmp.slice_corrected()
    for i, theta_i in enumerate(grid.incidences_deg):
        ax = axes[i // cols, i % cols]
        valid = cmp.slice_valid[i].numpy()
        for c in range(3):
            m = np.where(valid, cmp.slice_measured[i, :, c].numpy(), np.nan)
            ax.plot(x, m, "-", color=_COLOURS[c], lw=1.4, label=f"measured {_CHANNELS[c]}" if i == 0 else None)
            ax.plot(x, cmp.slice_ours[i, :, c].numpy(), "--", color=_COLOURS[c], lw=1.0,
                    label=f"ours {_CHANNELS[c]}" if i == 0 else None)
            ax.plot(x, corr[i, :, c].numpy(), ":", color=_COLOURS[c], lw=1.4,
                    label=f"ours × factor {_CHANNELS[c]}" if i == 0 else None)
        ax.axvline(theta_i, color="0.6", lw=0.8)
        ax.set_yscale("log")
        ax.set_title(f"θi = {theta_i:g}° (mirror at +{theta_i:g}°)", fontsize=9)
        ax.set_xlabel("θo in the plane of incidence (°; > 0: mirror side)", fontsize=8)
        ax.set_ylabel("f·cos θo (1/sr)", fontsize=8)
        ax.tick_params(labelsize=7)
    for j in range(n_inc, rows * cols):
        axes[j // cols, j % cols].axis("off")
    fig.legend(loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.1 if rows == 1 else 0.06, 1, 1))
    save_figure(fig, path)


def plot_errors(summary: dict[str, Any], path: str | os.PathLike) -> None:
    """The thesis's three figures per channel: factor, absolute error, relative error (before/after correction)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    x = np.arange(3)
    ax = axes[0]
    ax.bar(x, summary["factor"], width=0.5, color=_COLOURS, alpha=0.7, label="global factor")
    for i, f in enumerate(summary["factor_per_incidence"]):
        ax.plot(x + 0.3, f, "o", ms=4, color=f"C{i % 10}",
                label=f"θi = {summary['incidences_deg'][i]:g}°")
    ax.axhline(1.0, color="0.5", lw=0.8)
    ax.set_title(f"Factor (measured ≈ factor × ours; {summary['factor_method']})", fontsize=9)
    ax.legend(fontsize=6)
    for ax, key, scale, unit in ((axes[1], "abs_error", 1.0, "1/sr"), (axes[2], "rel_error", 100.0, "%")):
        before = np.asarray(summary[key]) * scale
        glob = np.asarray(summary[f"{key}_corrected_global"]) * scale
        own = np.asarray(summary[f"{key}_corrected_per_incidence"]) * scale
        ax.bar(x - 0.25, before, width=0.25, color="0.6", label="before")
        ax.bar(x, glob, width=0.25, color="tab:blue", label="global factor")
        ax.bar(x + 0.25, own, width=0.25, color="tab:orange", label="factor per incidence")
        for xs, vals in ((x - 0.25, before), (x, glob), (x + 0.25, own)):
            for xv, v in zip(xs, vals):
                ax.text(xv, v, f"{v:.3g}", ha="center", va="bottom", fontsize=6)
        ax.set_title(("Absolute" if key == "abs_error" else "Relative") + f" error ({unit})", fontsize=9)
        ax.legend(fontsize=7)
    for ax in axes:
        ax.set_xticks(x)
        ax.set_xticklabels(_CHANNELS)
    fig.tight_layout()
    save_figure(fig, path)


def _pct(values: list[float]) -> str:
    return " / ".join(f"{100 * v:.1f} %" for v in values)


def _num(values: list[float]) -> str:
    return " / ".join(f"{v:.4g}" for v in values)


def markdown_summary(report: dict[str, Any]) -> str:
    """``summary.md``: the figures of a report (see :func:`write_measured_report`) as Markdown tables, with the plots."""
    r = report
    lines = ["# Comparison with a measured BRDF", "",
             f"Measured: `{r['measured']['file']}` ({r['measured']['format']}); material: `{r['material']}`"
             + (f" ({r['distribution']} model)" if r.get("distribution") else "")
             + (f", mask `{r['mask']}`" if r.get("mask") else ", whole sample") + ".", "",
             ("Values compared: the cosine-weighted BRDF f·cos θo on a conoscopic grid "
              f"({r['grid']['n_theta']} × {r['grid']['n_phi']} cells, θo ≤ {r['grid']['theta_max_deg']:g}°) at "
              f"incidences {', '.join(f'{a:g}°' for a in r['incidences_deg'])}; measured data on "
              f"{100 * r['valid_fraction']:.1f} % of it. Ours: {r['definitions']['ours']}."), "",
             markdown_table(["figure (R / G / B)", "before", "after correction"],
                            [[f"factor ({r['factor_method']})", _num(r["factor"]), ""],
                             ["absolute error (1/sr)", _num(r["abs_error"]), _num(r["abs_error_corrected"])],
                             ["relative error", _pct(r["rel_error"]), _pct(r["rel_error_corrected"])]]), "",
             f"Correction: {r['correction']} factor. Relative error with one factor per incidence: "
             f"{_pct(r['rel_error_corrected_per_incidence'])}; with the global factor: "
             f"{_pct(r['rel_error_corrected_global'])}. Other factors: "
             + "; ".join(f"{k} {_num(v)}" for k, v in r["factor_alternatives"].items()) + ".", "",
             markdown_table(["θi", "factor", "rel. error", "corrected (global)", "corrected (own factor)", "data"],
                            [[f"{p['theta_i']:g}°", _num(p["factor"]), _pct(p["rel_error"]),
                              _pct(p["rel_error_corrected_global"]), _pct(p["rel_error_corrected_own"]),
                              f"{100 * p['valid_fraction']:.0f} %"] for p in r["per_incidence"]])]
    a = r["averaging"]
    lines += ["", f"**Averaging.** {a['texels_used']} of the mask's {a['texels_in_mask']} texels. The BRDF of the "
              f"averaged parameters differs from the averaged reflectance by {_pct(a['parameters_vs_reflectance'])} "
              f"(relative error, parameters vs reflectance); compared with the measurement it would give factor "
              f"{_num(a['with_parameter_average']['factor'])} and relative errors "
              f"{_pct(a['with_parameter_average']['rel_error'])} before, "
              f"{_pct(a['with_parameter_average']['rel_error_corrected'])} after. Parameter average: "
              + ", ".join(f"{k} {v}" for k, v in a["parameter_average"].items()) + "."]
    if r.get("direct_fit"):
        f = r["direct_fit"]
        lines += ["", (f"**Our model fitted to the measurement directly** (rendering loss, measured BRDF as the "
                       f"target): held-out rendering loss {f['rendering_loss']:.4f}, relative error "
                       f"{_pct(f['rel_error'])} (no factor): the part of this material our model cannot represent. "
                       f"Fitted: diffuse {f['diffuse']}, specular {f['specular']}, roughness {f['roughness']}.")]
    if r.get("applied"):
        ap = r["applied"]
        lines += ["", (f"**Applied.** `{ap['folder']}`: the material with factor {_num(ap['factor'])} "
                       f"(clipped: diffuse {100 * ap['clipped_diffuse']:.1f} %, specular "
                       f"{100 * ap['clipped_specular']:.1f} % of texel channels); compared again, relative error "
                       f"{_pct(ap['rel_error'])}.")]
    lines += ["", "Definitions: " + "; ".join(f"**{k}** {v}" for k, v in r["definitions"].items()) + ".", ""]
    lines += ["![conoscopic maps](conoscopic.png)", "", "![conoscopic maps, corrected](conoscopic_corrected.png)", "",
              "![in-plane slices](inplane.png)", "", "![error figures](errors.png)", ""]
    return "\n".join(lines)


def write_measured_report(out: str | os.PathLike, cmp: MeasuredComparison, *, measured: dict[str, Any], material: str,
                 mask: str | None = None, fit: DirectFit | None = None, applied: dict[str, Any] | None = None,
                 plots: bool = True) -> dict[str, Any]:
    """Write a comparison's report to ``out`` (the files in the module docstring).

    Args:
        out: the output folder (created).
        cmp: the comparison.
        measured: ``{"file", "format", ...}`` about the measurement.
        material: the material folder compared.
        mask: the mask file, if any.
        fit: the direct fit of our model to the measurement, if run.
        applied: ``--apply``'s result (``folder``, ``factor``, clipping, ``rel_error`` re-compared).
        plots: write the PNGs.

    Returns:
        The report (what ``report.json`` holds).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {**comparison_summary(cmp), "measured": measured, "material": material, "mask": mask}
    if fit is not None:
        report["direct_fit"] = fit.summary()
    if applied is not None:
        report["applied"] = applied
    files = list(REPORT_FILES if plots else REPORT_FILES[:2])
    report["files"] = files + ([applied["folder"]] if applied else [])
    if plots:
        plot_conoscopic(cmp, out / "conoscopic.png")
        plot_conoscopic(cmp, out / "conoscopic_corrected.png", corrected=True)
        plot_inplane(cmp, out / "inplane.png")
        plot_errors(report, out / "errors.png")
    write_text(out / "summary.md", markdown_summary(report))
    write_json(out / "report.json", report)
    return report
