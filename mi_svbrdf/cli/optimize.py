"""``mi-svbrdf optimize``: fit SVBRDF maps to a calibrated capture file and write the results.

Writes to ``-o OUT`` the files of :data:`OUTPUTS`: ``material/`` (the maps,
:func:`mi_svbrdf.io.material_io.write_material`), ``history.csv``, ``loss.png``, ``renders/NNN.png``,
``view.html`` (:mod:`mi_svbrdf.io.viewer`) and ``summary.json``.
"""
from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.assets import EXAMPLE_CAPTURE
from mi_svbrdf.cli.capture_file import smaller_photos_advice
from mi_svbrdf.cli.common import (
    add_command,
    budget_seconds,
    float_at_least,
    int_at_least,
    material_outputs,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.calibrated_photos import CAPTURE_NAME, load_capture
from mi_svbrdf.io.figures import nice_ceil, pyplot, robust_top, save_figure
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import read_material, srgb_encode, write_material
from mi_svbrdf.io.photos import exposure_notes
from mi_svbrdf.io.viewer import PAGE_NAME, page_title, write_viewer
from mi_svbrdf.optim import METHODS, OptimizeConfig, method_config, optimize
from mi_svbrdf.optim.fit import (
    DEFAULT_BUDGET_S,
    EARLY_STOP_MODES,
    LADDER_BASE,
    MAX_DEFAULT_BUDGET_S,
    default_budget,
    ladder_levels,
    ladder_sizes,
)
from mi_svbrdf.optim.fused_loss import LOSSES
from mi_svbrdf.optim.forward import forward_for
from mi_svbrdf.optim.scoring import measured_rmse
from mi_svbrdf.optim.select import SELECT_MODES, select_and_fit
from mi_svbrdf.plugins.model import DISTRIBUTIONS

DESCRIPTION = """\
Fit normal, diffuse, roughness and specular maps to N calibrated photos: a capture file
(capture.json, version 1: each photo with its camera and flash; images found relative to it) by
inverse rendering, on the texel path for rectified photos and through Mitsuba for perspective
ones. --capture example is the bundled capture: 6 photos (128 px) of a held-out procedural
leather. Make a capture file from your photos with `mi-svbrdf capture-file make` (you state the
camera and the flash) or `mi-svbrdf rectify` (photos of the sample in a paper frame).

How long to fit is decided by the photos: with 4 or more rectified photos a first fit leaves one
out and scores it every few steps; the length at which it is predicted best is the fit's, and every
photo is then fitted that long (or, when the error was still falling, the first fit goes on with
every photo). Otherwise the fit stops when it has converged: its learning rate follows a cosine
schedule over the first {sched} steps (compressed to fit --budget-s when that ends first); after the
schedule it stops once the loss's last {window}-step window improved on the window before by less
than {tol:g} x all the fit has gained since its first window; or at --iterations or on the --budget-s
time limit, which summary.json's notes then report with what to do.

A photo (nearly) all black or all saturated holds no measurement: optimize says so, and
summary.json's notes say what the maps are then worth.

With 3 or more rectified photos, --select auto (the default) chooses per capture the recipe (the
field's plain per-pixel fit; the defaults, stronger priors, a slower learning rate,
self-calibration), the map model (Lambertian; uniform specular and roughness; uniform specular;
the full SVBRDF) and the length of the fit that predict left-out photos best: each candidate is
fitted with one photo left out in turn at a lower resolution and scored along the way; a simpler
candidate wins only within noise (one paired standard error) and 2 % of the best; the choice is
then fitted on all photos to its length in what is left of --budget-s. The spread of its fold fits
gives uncertainty maps. --select NAME forces a candidate; --select off fits the default recipe alone.

--distribution beckmann fits maps of the Beckmann model (the thesis's ch. 6.1.1: another output
model) instead of GGX, whatever model made the photos; material.json records it.
""".format(sched=OptimizeConfig.schedule_steps, window=OptimizeConfig.window, tol=OptimizeConfig.tol)
OUTPUTS = """\
Writes to -o/--out:
  material/         the maps (normal.png diffuse.png roughness.png specular.png + material.json,
                    which records the BRDF model: ggx or beckmann)
  history.csv       seconds, step, loss and fit (its run: start, validation, fit) of every good step
  loss.png          the whole run against time: the training loss of each fit, and the error on the
                    photos left out (the selection's fold fits, the early stop) with the length chosen
  renders/NNN.png   photo | re-rendering | difference x4, labelled (sRGB; grey: explained)
  view.html         the maps in a self-contained WebGL2 page: drag the light (mi-svbrdf view);
                    with --select auto, an "uncertainty" toggle shows the uncertainty maps
  selection.png     with --select auto: each candidate's held-out error (mean +- paired standard
                    error over the folds), the choice and why; the chosen one's error against length
  uncertainty/      with --select auto and 2 or more fold fits of the chosen candidate: normal_deg.png,
                    diffuse.png, roughness.png, specular.png, the per-texel spread of those fits, each
                    on its own scale (to its 99th percentile rounded up) with a colour bar in its unit; without
                    them, optimize and summary.json's uncertainty say why none was written
  summary.json      steps, seconds, final loss, recoveries, stop reason, the display RMSE against the
                    photos (rerender_rmse: the re-renderings vs the photos fitted, gamma-encoded as on a
                    screen, over their unclipped pixels), model, self-calibration
                    estimates, held_out (the early stop's curve and the length chosen), selection
                    (every candidate's fold errors and curves, mean, standard error, length, seconds;
                    the choice, near-ties and why), uncertainty (each map's mean spread and colour
                    scale, or why there is none), notes (e.g. a fit stopped by its budget)
"""
EXAMPLES = ("mi-svbrdf optimize --capture example -o out/optimize",
            "mi-svbrdf optimize --capture example --select full -o out/optimize_full",
            "mi-svbrdf optimize --capture rect/capture.json -o out/fit --budget-s 120",
            "mi-svbrdf optimize --capture example --distribution beckmann -o out/optimize_beckmann")
#: The full help text (description, outputs, examples), as ``--help`` shows it after the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new fit replaces a previous one's.
OWNED = (*material_outputs("material"), "history.csv", "loss.png", "renders/[0-9][0-9][0-9].png",
         "renders/[0-9][0-9][0-9][0-9].png", PAGE_NAME, "summary.json", "selection.png", "uncertainty/*.png")
#: A fit whose re-renderings differ from its own photos' unsaturated pixels by more than this display RMSE (gamma
#: 2.2) is reported:
#: about 8 of 255 codes, a difference the residual panels show plainly (the bundled capture's fit: 0.02).
POOR_FIT = 0.03
#: The re-renderings' error against the photos fitted, by the one name every command and page gives it: the RMSE
#: of gamma-encoded values (as a screen shows them) over the photos' unclipped pixels (summary.json's rerender_rmse).
RMSE_NAME = "display RMSE against the photos"
#: Each stop reason (summary.json's stop_reason) in plain words, for the last line and scan's page.
STOP_WORDS = {"converged": "stopped when the loss stopped improving",
              "held-out": "stopped at the length that best predicted a photo left out of the fit",
              "budget": "stopped by its time budget, --budget-s",
              "iterations": "stopped at its step cap, --iterations",
              "recoveries": "stopped after repeated recoveries from a rising loss"}
#: Each uncertainty map's colour scale tops at this percentile of its measured texels' spread (rounded up to a
#: number that reads on the colour bar: :func:`~mi_svbrdf.io.figures.robust_top`): the scale shows this capture's
#: spread, whatever its size; the few texels above it are drawn at the top (the colour bar's arrow).
UNCERTAINTY_PERCENTILE = 99.0
#: Colour of the texels no photo measures (clipped in every photo) in the uncertainty maps: off the colour scale.
UNMEASURED_COLOUR = (0.25, 0.55, 0.95)
#: The unit of each uncertainty map, after a number.
UNCERTAINTY_UNIT = {"normal_deg": "°"}


def stop_words(reason: str) -> str:
    """A fit's stop reason in plain words (:data:`STOP_WORDS`; an unknown one as it is)."""
    return STOP_WORDS.get(reason, reason or "stopped")


def rmse_words(rmse: float | None) -> str:
    """The re-renderings' error against the photos, named as everywhere (:data:`RMSE_NAME`)."""
    return f"{RMSE_NAME} {rmse:.4f}" if rmse is not None else f"{RMSE_NAME}: none (every pixel is clipped)"


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``optimize`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "optimize", help="fit SVBRDF maps to a calibrated capture (capture.json)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("--capture", required=True, metavar="CAPTURE",
                   help="capture.json (version 1), a folder holding one, or 'example' (the bundled capture)")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--budget-s", type=budget_seconds, default=None,
                   help=f"wall-time limit in seconds (default {DEFAULT_BUDGET_S:g} for photos of {LADDER_BASE} px or "
                        f"less, in proportion to their side above, at most {MAX_DEFAULT_BUDGET_S:g}; 0 or inf: none, "
                        "the fit stops when converged); a fit it stops is not final and summary.json's notes say so")
    p.add_argument("--iterations", type=int_at_least(1), default=2000,
                   help="maximum Adam steps (default %(default)s)")
    p.add_argument("--init", default=None, metavar="MAPS_DIR", help="start from these maps (a material folder)")
    p.add_argument("--path", choices=("auto", "texel", "mitsuba"), default="auto",
                   help="forward model (auto: texel when every photo is rectified)")
    p.add_argument("--method", choices=sorted(METHODS), default="default",
                   help="default: the project's fit; pixel: the field's per-pixel baseline (Adam at a constant lr, "
                        "L2 on gamma-encoded photos, no priors, no stop before the budget)")
    p.add_argument("--tv", type=float_at_least(0.0, unit="a weight"), default=None,
                   help="total-variation weight (default: the method's, 1e-3 for default)")
    p.add_argument("--loss", choices=LOSSES, default=None, help="re-rendering error (default: the method's, log_l1 for default)")
    p.add_argument("--levels", type=levels_type, default="auto", metavar="auto|N",
                   help=f"coarse-to-fine levels, each twice the side of the one below, the last at the photos' size; "
                        f"auto (default): the ladder from {LADDER_BASE}x{LADDER_BASE} or below (1 level for photos "
                        f"of {LADDER_BASE} px or less, 3 for 1024 px)")
    p.add_argument("--distribution", choices=DISTRIBUTIONS, default="ggx",
                   help="output BRDF model of the maps (default ggx, the thesis's; the photos keep theirs)")
    p.add_argument("--calibrate", choices=("auto", "on", "off"), default=OptimizeConfig.calibrate,
                   help="self-calibration of per-photo exposure and white balance, the flash's offset from the lens "
                        "and small pose corrections, jointly with the maps (rectified captures only; auto: on from "
                        f"{OptimizeConfig.calibrate_min_images} photos; default %(default)s: the fit trusts the capture file, "
                        "see docs/guides/optimise.md for why); the estimates go to summary.json's calibration")
    p.add_argument("--select", choices=SELECT_MODES, default="auto", metavar="{auto,off,CANDIDATE}",
                   help="auto (default): choose the map model and recipe by leave-one-photo-out validation on the "
                        "capture's photos (3 or more rectified photos, --method default, no --init); off: the default "
                        f"recipe alone; or force a candidate: {', '.join(SELECT_MODES[2:])}")
    p.add_argument("--early-stop", choices=EARLY_STOP_MODES, default=OptimizeConfig.early_stop,
                   help="auto (default): with 4 or more rectified photos, one is left out of a first fit and the "
                        "length at which it is predicted best is the fit's (then every photo is fitted that long); "
                        "off: the fit stops when its loss converges or at the budget")
    p.add_argument("--device", default="cpu", help=DEVICE_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def _srgb(image: torch.Tensor) -> np.ndarray:
    return srgb_encode(image.detach().permute(1, 2, 0).numpy())


def write_outputs(out: Path, result: object, spec: object, images: torch.Tensor, renders: torch.Tensor,
                  uncertainty: dict[str, tuple[np.ndarray, str]] | None = None,
                  selection: dict | None = None) -> None:
    """Write maps, history, loss curve, photo | re-render pairs and the viewer page of a fit to ``out``
    (``uncertainty``: :func:`uncertainty_images`, a toggle of the page; ``selection``: the selection's record,
    whose fold fits ``loss.png`` shows before the final fit)."""
    out.mkdir(parents=True, exist_ok=True)
    write_material(out / "material", result.maps, distribution=getattr(result, "distribution", "ggx"))
    phases = fit_phases(result)
    lines = ["seconds,step,loss,fit"] + [f"{t:.6f},{s},{v:.8g},{name}" for name, rows in phases for t, s, v in rows]
    write_text(out / "history.csv", "\n".join(lines) + "\n")
    write_loss_figure(out / "loss.png", result, selection, photo_names(spec))
    (out / "renders").mkdir(exist_ok=True)
    for k in range(images.shape[0]):
        write_image(out / "renders" / f"{k:03d}.png", residual_panel(images[k], renders[k]), srgb=True)
    write_viewer(out / PAGE_NAME, result.maps, title=page_title("optimize", out),
                 distribution=result.distribution, uncertainty=uncertainty)


def fold_timeline(selection: dict) -> list[dict]:
    """The selection's fold fits in the order they ran, each with its start and end (seconds from the start of the
    run) and its held-out curve: ``[{"name", "fold", "t0", "t1", "curve": [[length, error], ...]}]``."""
    by_name = {r["name"]: r for r in selection.get("candidates") or []}
    order = [(by_name[name], str(k)) for name, k in selection.get("runs", []) if name in by_name]
    t, fits = 0.0, []
    for r, k in order:
        seconds = r["fold_seconds"][k]
        fits.append({"name": r["name"], "fold": k, "t0": t, "t1": t + seconds, "curve": r["fold_curves"].get(k, [])})
        t += seconds
    return fits


#: How every figure shades the lengths a fit may not end at (before its learning-rate schedule has decayed).
SCHEDULE_BAND = {"facecolor": "0.93", "edgecolor": "0.78", "hatch": "///", "linewidth": 0.0}


def schedule_band(ax: object, x0: float, x1: float, eligible_from: int) -> None:
    """Shade ``[x0, x1)`` of ``ax``: the lengths below ``eligible_from`` steps, which a fit may not end at, with
    their meaning in the legend (selection.png along the fold fits' steps, loss.png along the run's seconds)."""
    ax.axvspan(x0, x1, zorder=0, label=_wrap(f"before step {eligible_from}: the learning rate is still decaying, and "
                                             "a fit never ends there"), **SCHEDULE_BAND)


def mean_curve(curves: Sequence[Sequence[Sequence[float]]]) -> list[tuple[int, float]]:
    """The mean of fold curves ``[[length, error], ...]`` at the lengths every one of them scored, in order.

    Examples:
        >>> mean_curve([[[10, 0.3], [20, 0.2]], [[10, 0.1], [20, 0.4], [30, 0.5]]])
        [(10, 0.2), (20, 0.30000000000000004)]
    """
    curves = [{int(k): float(e) for k, e in c} for c in curves if c]
    if not curves:
        return []
    common = sorted(set.intersection(*(set(c) for c in curves)))
    return [(k, sum(c[k] for c in curves) / len(curves)) for k in common]


def length_words(curves: Sequence[Sequence[Sequence[float]]], length: int, error: float, eligible_from: int,
                 still_improving: bool = False) -> tuple[str, tuple[int, float] | None]:
    """Why a fit's length is ``length`` (its error there ``error``), in words a figure's legend can carry, and the
    lowest point before ``eligible_from`` (the lengths a fit may not end at: its learning rate still decaying) of
    the mean of ``curves`` (one ``[(length, error)]`` per fold, lengths increasing: :func:`mean_curve`):
    ``(words, (length, error) or None)``.

    Under a decaying schedule the length is the best of those after ``eligible_from`` only, so the words say that
    it is (or that it is the only one scored there), and "still improving" only where two or more were scored and
    the last was the best.

    Examples:
        >>> length_words([[(10, 0.2), (20, 0.1), (30, 0.15)]], 30, 0.15, 30, True)
        ('30 steps: the only length scored after the schedule decayed (error 0.1500)', (20, 0.1))
        >>> length_words([[(10, 0.2), (20, 0.1), (30, 0.15)]], 20, 0.1, 0)[0]
        '20 steps: the lowest error (0.1000)'
    """
    inside = [(k, e) for k, e in mean_curve(curves) if k < eligible_from and math.isfinite(e)]
    lowest = min(inside, key=lambda c: (c[1], c[0])) if inside else None
    after = _lengths_after(curves, eligible_from, length)
    if not eligible_from:
        words = f"{length} steps: the lowest error ({error:.4f})"
    elif after == 1:
        words = f"{length} steps: the only length scored after the schedule decayed (error {error:.4f})"
    else:
        words = f"{length} steps: the lowest error after the schedule decayed ({error:.4f})"
    if still_improving and after > 1:
        words += ", still falling when the fits ended"
    return words, lowest


def _lengths_after(curves: Sequence[Sequence[Sequence[float]]], eligible_from: int, length: int) -> int:
    """How many lengths a fit may end at were scored: those of ``curves`` from ``eligible_from`` on, and ``length``."""
    return len({int(k) for c in curves for k, _ in c if k >= eligible_from} | {int(length)})


def _wrap(text: str, width: int = 64) -> str:
    """A legend entry's text on lines of at most ``width`` characters."""
    import textwrap

    return textwrap.fill(text, width)


def _length_suffix(row: dict) -> str:
    """After a candidate's length in selection.png's ladder: whether its folds were still improving there (two or
    more lengths scored after the schedule decayed, the last the best) or it was the only length scored there."""
    start = row.get("eligible_from", 0)
    if start and _lengths_after(list(row.get("fold_curves", {}).values()), start, row["length"]) == 1:
        return " (only length after the schedule)"
    return " (still improving)" if row.get("still_improving") else ""


def lowest_inside_words(lowest: tuple[int, float], error: float) -> str:
    """The legend's words for the lowest point before the schedule decayed (``error``: the chosen length's)."""
    return (f"lowest before the schedule decayed: {lowest[1]:.4f} at {lowest[0]} steps"
            + (" (lower, but a fit never ends there)" if lowest[1] < error else ""))


def write_loss_figure(path: Path, result: object, selection: dict | None = None,
                      photos: Sequence[str] | None = None) -> None:
    """``loss.png``: the whole run on one time axis. Above, the training loss of each fit (multi-start, the early
    stop's first fit, the fit of all photos); below, the error on photos the fits did not see: the selection's fold
    fits (each candidate's left-out photo) and the early stop's, with the length chosen (photos by their file names
    in ``photos``). A fit or curve of one point is drawn as a marker: every line the legends list shows."""
    import textwrap

    plt = pyplot()
    fits = fold_timeline(selection) if selection else []
    offset = fits[-1]["t1"] if fits else 0.0
    held = getattr(result, "held_out", None)
    fig, (top, low) = plt.subplots(2, 1, figsize=(7.5, 6.2), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    for name, rows in fit_phases(result):  # one line per fit: a first fit then the full fit is not one line that climbs
        if rows:
            top.semilogy([offset + h[0] for h in rows], [h[2] for h in rows], label=name.strip(),
                         marker="o" if len(rows) < 3 else None, ms=4)
    recoveries = getattr(result, "recoveries", 0)
    title = f"optimize: {result.steps} steps in {getattr(result, 'seconds', 0.0):.1f} s"
    if recoveries:
        title += (f"; {recoveries} recoveries (a rising or non-finite loss: the last good maps restored at half the "
                  "learning rate)")
    top.set_title(title, fontsize=9)
    top.set_ylabel("training loss (fitted photos)")
    from matplotlib.ticker import FuncFormatter, NullFormatter

    low_y, high_y = top.get_ylim()
    within = 0 < low_y < high_y < 10 * low_y  # within a decade the minor ticks are the only ones: label them too
    digits = max(3, math.ceil(-math.log10(high_y / low_y - 1)) + 2) if within else 3  # neighbours differ
    plain = FuncFormatter(lambda v, _: f"{v:.{digits}g}")  # 0.127, not 1.27 x 10^-1
    top.yaxis.set_major_formatter(plain)
    top.yaxis.set_minor_formatter(plain if within else NullFormatter())
    if fits:
        top.axvspan(0.0, offset, color="0.92", zorder=0)
        top.text(offset / 2, 0.97, f"selection: {len(fits)} fold fits", transform=top.get_xaxis_transform(),
                 ha="center", va="top", fontsize=8)
    chosen = selection.get("choice") if selection else None
    shown: set[str] = set()
    for f in fits:  # each fold fit's left-out photo error, drawn across the fit's own time
        curve = f["curve"]
        if not curve:
            continue
        last = max(k for k, _ in curve) or 1
        xs = [f["t0"] + (f["t1"] - f["t0"]) * k / last for k, _ in curve]
        mine = f["name"] == chosen
        label = f"fold fits of {chosen} (chosen)" if mine else "fold fits of the other candidates"
        low.plot(xs, [e for _, e in curve], color="C3" if mine else "0.65", lw=1.4 if mine else 0.8,
                 marker="o" if len(curve) < 3 else None, ms=3, label=None if label in shown else label)
        shown.add(label)
    if held and held.get("curve"):
        start = held.get("eligible_from", 0)
        curve = held["curve"]
        left_out = ", ".join(_photo(photos, k) for k in held["photos"])
        low.plot([offset + t for t, _, _ in curve], [e for _, _, e in curve], color="C0", lw=1.4,
                 marker="o" if len(curve) < 3 else None, ms=3, label=f"early stop: {left_out} left out")
        if start and curve[0][1] < start:  # the band ends where the fit reached the first length it may end at
            end = next((t for t, k, _ in curve if k >= start), curve[-1][0])
            schedule_band(low, offset, offset + end, start)
        best = next((c for c in curve if c[1] == held["best_length"]), None)
        if best is not None:
            then = {"refit": "every photo then fitted that long", "continued": "the fit then went on with every photo"}
            words, lowest = length_words([[(k, e) for _, k, e in curve]], best[1], best[2], start)
            low.plot([offset + best[0]], [best[2]], "o", color="C0", ms=6,
                     label=_wrap(f"the length chosen, {words}; {then.get(held['then'], held['then'])}"))
            if lowest is not None:
                at = next(c for c in curve if c[1] == lowest[0])
                low.plot([offset + at[0]], [at[2]], "o", mfc="none", mec="C0", ms=7,
                         label=_wrap(lowest_inside_words(lowest, best[2])))
    if low.get_legend_handles_labels()[0]:
        low.set_ylabel("error on a photo\nnot fitted (display RMSE)")
        low.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.28), ncol=2, frameon=False)
    else:
        why = "no photo was left out (fewer than 4 photos, or the early stop off)"
        if held and held.get("photos"):
            why = (f"the early stop left {', '.join(_photo(photos, k) for k in held['photos'])} out, but the fit "
                   "stopped (its step cap or its budget) before the error on it was first scored")
        low.text(0.5, 0.5, textwrap.fill(why, 90), transform=low.transAxes, ha="center", va="center", fontsize=8)
        low.set_yticks([])
    low.set_xlabel("seconds since the start of the run")
    if len(fit_phases(result)) > 1:
        top.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=3, frameon=False)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def uncertainty_scales(selected: object, measured: torch.Tensor | None = None) -> dict[str, float] | None:
    """The top of each uncertainty map's colour scale (:data:`UNCERTAINTY_PERCENTILE` of its measured texels'
    spread, :func:`~mi_svbrdf.io.figures.robust_top`): ``{name: top}``, None without uncertainty maps.
    ``measured``: ``(H, W)`` bool, False where no photo measures the texel (left out of the scale)."""
    if getattr(selected, "uncertainty", None) is None:
        return None
    scales = {}
    for name, spread in selected.uncertainty.items():
        values = spread[0, 0].cpu()
        if measured is not None and bool(measured.any()):
            values = values[measured.cpu()]
        value = uniform_spread(values.numpy())
        if value is None:
            scales[name] = robust_top(values.numpy(), UNCERTAINTY_PERCENTILE)
        else:  # one value for the whole map: drawn mid-scale, or at the bottom of a nominal scale when 0
            scales[name] = nice_ceil(2.0 * value) if value > 0 else UNIFORM_TOP[name]
    return scales


#: The colour scale's top of an uncertainty map that is 0 everywhere (a map the chosen model fixes).
UNIFORM_TOP = {"normal_deg": 1.0, "diffuse": 0.01, "roughness": 0.01, "specular": 0.01}


def uniform_spread(values: np.ndarray) -> float | None:
    """The spread's one value when it is the same at every texel (a map the chosen model ties to one value or fixes:
    the fold fits differ by one number for the whole sample, or not at all); None when it varies.

    Examples:
        >>> uniform_spread(np.zeros(4)), uniform_spread(np.full(4, 0.02)), uniform_spread(np.array([0.0, 0.1]))
        (0.0, 0.02, None)
    """
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return 0.0
    low, high = float(values.min()), float(values.max())
    return float(f"{high:.6g}") if high - low <= 1e-6 * max(high, 1e-3) else None


def _uniform_note(name: str, value: float) -> str:
    """What an uncertainty map that is the same everywhere means, in words."""
    if value == 0:
        return "0 at every texel: the fold fits agree exactly (the chosen model fixes this map)"
    return (f"{value:.3g}{UNCERTAINTY_UNIT.get(name, '')} at every texel (the chosen model has one value of this map "
            "for the whole sample)")


def uncertainty_images(selected: object, scales: dict[str, float] | None = None,
                       measured: torch.Tensor | None = None) -> dict[str, tuple[np.ndarray, str]] | None:
    """The uncertainty maps of a selected fit drawn with a colour scale: ``{name: ((H, W, 3) in [0, 1], caption)}``
    (``scales``: :func:`uncertainty_scales`; ``measured``: ``(H, W)`` bool, texels no photo measures drawn in
    :data:`UNMEASURED_COLOUR`)."""
    if getattr(selected, "uncertainty", None) is None:
        return None
    scales = scales or uncertainty_scales(selected, measured)
    cmap = pyplot().get_cmap("magma")
    images = {}
    for name, spread in selected.uncertainty.items():
        level = (spread[0, 0].cpu() / scales[name]).clamp(0.0, 1.0).numpy()
        image = np.ascontiguousarray(cmap(level)[..., :3], dtype=np.float32)
        unmeasured = ""
        if measured is not None and not bool(measured.all()):
            image[~measured.cpu().numpy()] = UNMEASURED_COLOUR
            unmeasured = "; blue: clipped in every photo, nothing measures it"
        caption = (f"spread of {name.replace('_deg', '')} over the fold fits: black 0, yellow-white "
                   f"{scales[name]:g}{UNCERTAINTY_UNIT.get(name, '')} or more{unmeasured}")
        values = spread[0, 0].cpu()
        uniform = uniform_spread((values[measured.cpu()] if measured is not None and bool(measured.any())
                                  else values).numpy())
        if uniform is not None:
            caption += f"; {_uniform_note(name, uniform)}"
        images[name] = (image, caption)
    return images


def uncertainty_absence(selected: object | None, select: str, asked: str = "auto") -> str:
    """Why a run wrote no ``uncertainty/`` ("" when it wrote it): the maps are the spread of the chosen candidate's
    fold fits, so they need two or more of them. ``select``: the selection run (``off`` when ``--init`` or another
    ``--method`` turned ``asked``, the ``--select`` given, off)."""
    if selected is not None and getattr(selected, "uncertainty", None) is not None:
        return ""
    need = "the uncertainty maps need 2 or more fold fits of the chosen candidate"
    sel = selected.selection if selected is not None else {}
    if not sel.get("candidates"):
        if select == "off":
            how = ("--select off fits the default recipe alone" if asked == "off" else
                   "no selection runs with --init or a --method other than default")
        elif select != "auto":
            how = f"--select {select} fits that candidate without folds"
        else:
            how = "no selection ran" + (f": {sel['why']}" if sel.get("why") else "")
        return f"{need}; {how}"
    if sel.get("uncertainty_absent"):
        return f"the uncertainty maps need fold fits of the same texels; {sel['uncertainty_absent']}"
    chosen = next((r for r in sel["candidates"] if r["name"] == sel.get("choice")), None)
    ran = len(chosen["fold_errors"]) if chosen is not None else 0
    why = f"{need}, and {sel.get('choice')} had {ran}"
    skipped = sel.get("folds_skipped") or []
    if skipped:
        why += (f" ({len(skipped)} fold{'s' if len(skipped) != 1 else ''} skipped: the budget's share for the folds "
                "ran out; a larger --budget-s, or --budget-s 0, runs them)")
    return why


#: What a paired standard error is, under the selection chart.
PAIRED_SE = ("bars: paired standard error = the standard error of the candidate's fold errors minus the best's, "
             "over the same left-out photos (how sure the difference is; the photos' own difficulty cancels)")


def photo_names(spec: object) -> list[str]:
    """The capture's photos by their file names (``000.png``), as the user knows them."""
    return [Path(im.file).name for im in spec.images]


def _photo(names: Sequence[str] | None, k: int) -> str:
    """Photo ``k`` by its file's name (its 1-based number when the names are not known)."""
    return names[k] if names is not None and 0 <= k < len(names) else f"{k + 1}"


def write_selection(out: Path, selected: object, uncertainty: dict[str, tuple[np.ndarray, str]] | None,
                    photos: Sequence[str] | None = None, scales: dict[str, float] | None = None,
                    measured: torch.Tensor | None = None) -> None:
    """``selection.png`` (each candidate's held-out error, the choice and why; the chosen candidate's error against
    the fit's length, each fold by its left-out photo's file name in ``photos``) and ``uncertainty/*.png`` (each
    map's spread with a colour bar in its unit up to ``scales``, :func:`uncertainty_scales`; ``measured``: ``(H, W)``
    bool, the texels no photo measures drawn apart)."""
    import textwrap

    plt = pyplot()
    sel = selected.selection
    rows = sel["candidates"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 6.4), gridspec_kw={"width_ratios": [3, 2]})
    ys = list(range(len(rows)))[::-1]  # the ladder top down: simplest first
    bars = 0
    for y, row in zip(ys, rows):
        chosen, best = row["name"] == sel["choice"], row["name"] == sel.get("best")
        colour = "C3" if chosen else ("0.75" if row["eliminated"] else "C0")
        se = row.get("se")
        ax1.barh(y, row["mean"], color=colour, height=0.6)
        end = row["mean"]
        if se is not None and not row["eliminated"] and not best:
            ax1.errorbar(row["mean"], y, xerr=se, fmt="none", ecolor="k", capsize=3, lw=1)
            end, bars = row["mean"] + se, bars + 1  # the label starts after the bar's cap
        folds = len(row["fold_errors"])
        note = f"{row['mean']:.4f}, {folds} fold{'s' if folds != 1 else ''}"
        note += f", {row['length']} steps{_length_suffix(row)}"
        note += "  CHOSEN" if chosen else ("  best" if best else ("  eliminated" if row["eliminated"] else ""))
        ax1.annotate(note, (end, y), xytext=(5, 0), textcoords="offset points", va="center", fontsize=7,
                     fontweight="bold" if chosen else "normal")
    ax1.set_yticks(ys, [r["name"] for r in rows], fontsize=8)
    top = max(r["mean"] + (r.get("se") or 0.0) for r in rows if math.isfinite(r["mean"]))
    ax1.set_xlim(0, top * 2.0)
    ax1.set_xlabel("error on the left-out photo (display RMSE, mean over the folds)")
    ax1.set_title("candidates, simplest first (grey: eliminated after the first fold)", fontsize=9)
    chosen_row = next(r for r in rows if r["name"] == sel["choice"])
    curves = [c for c in chosen_row.get("fold_curves", {}).values() if c]
    for k, curve in chosen_row.get("fold_curves", {}).items():
        if curve:
            ax2.plot([c[0] for c in curve], [c[1] for c in curve], marker="o" if len(curve) == 1 else None, lw=1,
                     label=f"{_photo(photos, int(k))} left out")
    mean = mean_curve(curves)
    if len(curves) > 1 and mean:
        ax2.plot([k for k, _ in mean], [e for _, e in mean], color="k", lw=1.8, marker="o" if len(mean) == 1 else None,
                 label="mean over the folds: the length is chosen on it")
    start = chosen_row.get("eligible_from", 0)
    if start and any(k < start for c in curves for k, _ in c):
        schedule_band(ax2, 0, start, start)
    words, lowest = length_words(curves, chosen_row["length"], chosen_row["mean"], start,
                                 bool(chosen_row.get("still_improving")))
    ax2.axvline(chosen_row["length"], color="C3", ls="--", lw=1)
    ax2.plot([chosen_row["length"]], [chosen_row["mean"]], "o", color="C3", ms=6,
             label=_wrap(f"its length, {words}"))
    if lowest is not None:
        ax2.plot([lowest[0]], [lowest[1]], "o", mfc="none", mec="k", ms=7,
                 label=_wrap(lowest_inside_words(lowest, chosen_row["mean"])))
    ax2.set_xlabel(f"steps of the fold fit ({sel.get('fold_size', ['?'])[0]} px)")
    ax2.set_ylabel("error on the left-out photo")
    ax2.set_title(f"{sel['choice']}: its fold fits along their length", fontsize=9)
    ax2.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1, frameon=False)
    fig.suptitle(f"selection: {sel['choice']}", fontsize=11)
    caption = [textwrap.fill("why: " + sel.get("why", ""), 170)]
    if bars:
        caption.append(textwrap.fill(PAIRED_SE, 170))
    elif max(len(r["fold_errors"]) for r in rows) < 2:
        caption.append(textwrap.fill("one fold ran: no candidate has a standard error, so no error bar is drawn "
                                     "(and no uncertainty map: it needs 2 or more fold fits)", 170))
    fig.text(0.01, 0.01, "\n".join(caption), fontsize=7, va="bottom")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    save_figure(fig, out / "selection.png", dpi=100)
    if uncertainty is None:
        return
    scales = scales or uncertainty_scales(selected, measured)
    (out / "uncertainty").mkdir(exist_ok=True)
    for name, spread in selected.uncertainty.items():
        write_uncertainty_figure(out / "uncertainty" / f"{name}.png", name, spread[0, 0].cpu().numpy(), scales[name],
                                 None if measured is None else measured.cpu().numpy())


#: Unit and meaning of each uncertainty map, for its colour bar.
UNCERTAINTY_UNITS = {"normal_deg": "degrees between the fold fits' normals and their mean",
                     "diffuse": "standard deviation of the diffuse albedo (0-1; mean of RGB)",
                     "roughness": "standard deviation of the roughness (0-1)",
                     "specular": "standard deviation of the specular albedo (0-1; mean of RGB)"}


def scale_words(values: np.ndarray, top: float, name: str = "") -> str:
    """What an uncertainty map's colour scale is, in words: its top ``top`` is the
    :data:`UNCERTAINTY_PERCENTILE` of ``values`` rounded up to a number that reads on the colour bar
    (:func:`~mi_svbrdf.io.figures.robust_top`), so fewer texels than ``100 - percentile`` % lie above it: the
    words give the percentile's own value and the share above the top, measured.

    Examples:
        >>> scale_words(np.linspace(0.0, 1.0, 1001), 1.5)
        'scale 0 to 1.5, its top the 99th percentile (0.99) rounded up: 0.0% of texels above it'
    """
    unit = UNCERTAINTY_UNIT.get(name, "")
    values = np.asarray(values, dtype=np.float64)
    if not values.size:
        return f"scale 0 to {top:g}{unit}"
    level = float(np.percentile(values, UNCERTAINTY_PERCENTILE))
    what = f"the {UNCERTAINTY_PERCENTILE:g}th percentile"
    if level <= 1e-6 < float(values.max()):  # a few texels over a zero field: robust_top's largest value
        level, what = float(values.max()), "the largest spread"
    above = float((values > top).mean())
    return f"scale 0 to {top:g}{unit}, its top {what} ({level:.3g}{unit}) rounded up: {above:.1%} of texels above it"


def write_uncertainty_figure(path: Path, name: str, spread: np.ndarray, top: float,
                             measured: np.ndarray | None = None) -> None:
    """One uncertainty map ``(H, W)`` with a title and a colour bar in its unit from 0 to ``top``
    (:func:`uncertainty_scales`; the texels above it at the top, the bar's arrow); ``measured`` ``(H, W)`` bool: the
    texels no photo measures drawn in :data:`UNMEASURED_COLOUR`, off the scale."""
    import textwrap

    from matplotlib.colors import to_rgba

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 4.6))
    cmap = plt.get_cmap("magma").with_extremes(bad=to_rgba(UNMEASURED_COLOUR))
    shown = np.ma.masked_array(spread, mask=None if measured is None else ~measured)
    im = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=top, interpolation="nearest")
    ax.set_axis_off()
    measured_part = spread if measured is None or not measured.any() else spread[measured]
    uniform = uniform_spread(measured_part)
    lines = [f"uncertainty of the {name.replace('_deg', '')}: spread over the fold fits",
             _uniform_note(name, uniform) if uniform is not None else scale_words(measured_part, top, name)]
    if measured is not None and not measured.all():
        lines.append(f"blue: clipped in every photo, unmeasured ({float((~measured).mean()):.1%} of texels)")
    ax.set_title("\n".join(textwrap.fill(line, 62) for line in lines), fontsize=8)
    bar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, extend="max")
    bar.set_label(UNCERTAINTY_UNITS[name], fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def fit_phases(result: object) -> list[tuple[str, list[tuple[float, int, float]]]]:
    """The history of a fit cut into its runs (multi-start, validation fit, full fit): ``[(name, rows)]``."""
    history = list(getattr(result, "history", []))
    marks = list(getattr(result, "phases", [])) or [("fit", 0)]
    ends = [i for _, i in marks[1:]] + [len(history)]
    return [(name, history[i:end]) for (name, i), end in zip(marks, ends)]


#: Labels of the residual panels, left to right.
PANEL_LABELS = ("photo", "re-rendering", "difference x4")
#: The legend under the residual panels: what the difference's grey levels mean.
DIFFERENCE_LEGEND = ("difference x4: grey = the fit explains the photo, lighter = re-rendering too bright, "
                     "darker = too dark; a colour cast = off in some channels (reddish: too red, bluish: too blue)")


def residual_panel(photo: torch.Tensor, render: torch.Tensor) -> np.ndarray:
    """``photo | re-rendering | difference`` of one photo (``(3, H, W)`` linear each), labelled, with the
    difference's legend (:data:`DIFFERENCE_LEGEND`) below: ``(H', 3W, 3)`` sRGB in [0, 1].

    The difference is ``0.5 + 4 (render - photo)`` in display values, per channel: grey where the model explains
    the photo, bright where the re-rendering is too bright, dark where it is too dark, and tinted where it is off in
    some channels more than in others (a colour cast: reddish where it is too red). The text scales with the panels
    (about 1/24 of a panel's width, at least 11 px), so it reads on large captures too.
    """
    from PIL import Image, ImageDraw, ImageFont

    a, b = _srgb(photo.clamp(0, 1)), _srgb(render.clamp(0, 1))
    diff = np.clip(0.5 + 4.0 * (b - a), 0.0, 1.0)
    strip = (np.concatenate([a, b, diff], axis=1) * 255.0 + 0.5).astype(np.uint8)
    width = strip.shape[1] // 3
    size = max(11, width // 24)  # text height in pixels
    font = ImageFont.load_default(size=size)
    line = size + size // 3
    band = line + 4
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    lines: list[str] = []
    for word in DIFFERENCE_LEGEND.split():  # the legend wrapped to the strip's width
        if lines and measure.textlength(f"{lines[-1]} {word}", font=font) <= strip.shape[1] - 2 * size:
            lines[-1] += f" {word}"
        else:
            lines.append(word)
    canvas = Image.new("RGB", (strip.shape[1], strip.shape[0] + band + line * len(lines) + 6), (0, 0, 0))
    canvas.paste(Image.fromarray(strip), (0, band))
    draw = ImageDraw.Draw(canvas)
    for i, label in enumerate(PANEL_LABELS):
        draw.text((i * width + size // 2, 2), label, fill=(255, 255, 255), font=font)
    for i, text in enumerate(lines):
        draw.text((size // 2, band + strip.shape[0] + 3 + line * i), text, fill=(255, 255, 255), font=font)
    return np.asarray(canvas, dtype=np.float32) / 255.0


def levels_type(text: str) -> str | int:
    """``--levels``: ``auto`` or an int >= 1."""
    return "auto" if text == "auto" else int_at_least(1)(text)


def ladder_line(height: int, width: int, levels: int, chosen: str | int) -> str:
    """The fit's resolution ladder in words, e.g. ``fits 256x256, then 512x512, then 1024x1024 (--levels 3)``."""
    sizes = [f"{h}x{w}" for h, w in ladder_sizes(height, width, levels)]
    how = "auto" if chosen == "auto" else str(chosen)
    if levels == 1:
        return f"fits at the photos' {sizes[0]} (--levels {how}: one level)"
    return (f"fits {sizes[0]}, then {', then '.join(sizes[1:])}, each level started from the one below "
            f"(--levels {how}: {levels} levels)")


def capture_path(spec: str) -> Path:
    """The capture file of a ``--capture`` argument: ``example`` is the bundled one."""
    return EXAMPLE_CAPTURE if spec == "example" else Path(spec)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf optimize``; returns the exit code."""
    device = resolve_device(args.device)
    if args.select not in ("auto", "off") and (args.init or args.method != "default"):
        raise ValueError(f"--select: expected auto or off with --init or --method {args.method}, got {args.select} "
                         "(a candidate is a recipe of --method default from its own start)")
    path = capture_path(args.capture)
    spec, images, valid = load_capture(path)
    init = read_material(args.init) if args.init else None
    notes = exposure_notes(images, [im.file for im in spec.images], saturated=~valid, result="the fitted maps")
    for note in notes:
        print(f"mi-svbrdf optimize: {note}", file=sys.stderr)
    height, width = images.shape[-2:]
    levels = ladder_levels(height, width) if args.levels == "auto" else args.levels
    budget = default_budget(height, width) if args.budget_s is None else args.budget_s
    if levels > 1 or args.levels != "auto":
        said = "" if args.budget_s is not None else f"; --budget-s {budget:g} (the default for {height}x{width} photos)"
        print(f"mi-svbrdf optimize: ladder: {ladder_line(height, width, levels, args.levels)}{said}", file=sys.stderr)
    chosen = {k: v for k, v in (("loss", args.loss), ("tv_weight", args.tv)) if v is not None}
    chosen["fewer_texels"] = smaller_photos_advice(path / CAPTURE_NAME if path.is_dir() else path)  # budget note
    cfg = method_config(args.method, iterations=args.iterations,
                        budget_s=budget if budget > 0 else math.inf, levels=levels,
                        path=args.path, progress=not args.no_progress, device=str(device),
                        distribution=args.distribution, calibrate=args.calibrate, early_stop=args.early_stop,
                        **chosen)
    select = "off" if args.select == "auto" and (init is not None or args.method != "default") else args.select
    if select == "off":
        result, selected = optimize(spec, images, valid, config=cfg, init_maps=init), None
    else:
        selected = select_and_fit(spec, images, valid, config=cfg, select=select,
                                  say=lambda line: print(f"mi-svbrdf optimize: {line}", file=sys.stderr))
        result = selected.result
    result.maps = result.maps.cpu()
    for note in result.notes:
        print(f"mi-svbrdf optimize: {note}", file=sys.stderr)
    notes += result.notes
    rendered_spec = result.calibrated_spec or spec  # the photos as the fit explains them
    with torch.no_grad():
        renders = forward_for(rendered_spec, tuple(images.shape[-2:]), args.path,
                              distribution=result.distribution)(result.maps).clamp(0.0, 1.0)
    display_rmse = measured_rmse(renders, images, valid)
    if display_rmse is not None and display_rmse > POOR_FIT:
        note = (f"the maps explain their own photos poorly: {RMSE_NAME} {display_rmse:.3f} (above "
                f"{POOR_FIT:g}, about {round(POOR_FIT * 255)} of 255 codes: visible in renders/NNN.png). Light the "
                "model cannot represent (glass, subsurface light, a light the capture file does not state), exposure "
                "or white balance that differ between photos (--calibrate on), or cameras and flashes off their "
                "stated positions")
        print(f"mi-svbrdf optimize: {note}", file=sys.stderr)
        notes.append(note)
    out = Path(args.out)
    capture_file = path / CAPTURE_NAME if path.is_dir() else path  # the inputs stay, wherever they are
    inputs = [capture_file, *(capture_file.parent / im.file for im in spec.images), *([args.init] if args.init else [])]
    replace_outputs(args, out, OWNED, keep=inputs)
    measured_texels = valid.any(dim=0)[0]  # (H, W): False where every photo is clipped
    scales = uncertainty_scales(selected, measured_texels)
    uncertainty = uncertainty_images(selected, scales, measured_texels)
    write_outputs(out, result, spec, images, renders, uncertainty,
                  selected.selection if selected is not None else None)
    wrote = ["material/", "history.csv", "loss.png", "renders/", PAGE_NAME, "summary.json"]
    if selected is not None and selected.selection.get("candidates"):
        write_selection(out, selected, uncertainty, photo_names(spec), scales, measured_texels)
        wrote.append("selection.png")
    no_uncertainty = uncertainty_absence(selected, select, args.select)
    if uncertainty is not None:
        wrote.append("uncertainty/")
    summary = {"capture": str(path), "photos": spec.n_images, "steps": result.steps, "seconds": result.seconds,
               "final_loss": result.final_loss if math.isfinite(result.final_loss) else None,
               "recoveries": result.recoveries, "stop_reason": result.stop_reason,
               "distribution": result.distribution,
               "rerender_rmse": display_rmse,
               "saturated_fraction": round(float((~valid).float().mean()), 4),
               "calibration": result.calibration,
               "held_out": result.held_out,
               "ladder": {"levels": levels, "asked": args.levels,
                          "sizes": [list(hw) for hw in ladder_sizes(height, width, levels)],
                          "words": ladder_line(height, width, levels, args.levels), "runs": result.levels},
               "selection": selected.selection if selected is not None else {"mode": "off"},
               "notes": notes}
    if uncertainty is not None:
        summary["uncertainty"] = {"mean": selected.selection["uncertainty"], "png_top_of_scale": scales,
                                  "png_scale": f"0 to the {UNCERTAINTY_PERCENTILE:g}th percentile of the measured "
                                               "texels' spread, rounded up"}
    else:
        summary["uncertainty"] = {"mean": None, "why_none": no_uncertainty}
    write_json(out / "summary.json", summary)
    if selected is not None and selected.choice and selected.selection.get("candidates"):
        print(f"selected {selected.selection.get('why', selected.choice)}")
    elif selected is not None and selected.choice and selected.selection.get("mode") == "auto":
        print(f"fitted {selected.choice} without folds (the budget buys none: see the plan above)")
    elif selected is not None and selected.choice:
        print(f"selected {selected.selection.get('why', selected.choice)}")
    if no_uncertainty:
        print(f"no uncertainty/: {no_uncertainty}")
    print(f"{spec.n_images} photo(s): {result.steps} steps in {result.seconds:.1f} s "
          f"({stop_words(result.stop_reason)}), {rmse_words(display_rmse)}; wrote {out}/: {', '.join(wrote)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.optimize``: ``optimize`` arguments only."""
    return standalone(add_parser, ["optimize", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
