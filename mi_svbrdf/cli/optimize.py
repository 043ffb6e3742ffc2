"""``mi-svbrdf optimize``: fit SVBRDF maps to a calibrated capture file and write the results.

Writes to ``-o OUT`` the files of :data:`OUTPUTS`: ``material/`` (the maps,
:func:`mi_svbrdf.io.material_io.write_material`), ``history.csv``, ``loss.png``, ``renders/NNN.png``,
``view.html`` (:mod:`mi_svbrdf.io.viewer`) and ``summary.json``.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.assets import EXAMPLE_CAPTURE
from mi_svbrdf.cli.capture_file import smaller_photos_advice
from mi_svbrdf.cli.common import (
    add_command,
    float_at_least,
    int_at_least,
    material_outputs,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.calibrated_photos import CAPTURE_NAME, load_capture
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import read_material, srgb_encode, write_material
from mi_svbrdf.io.photos import exposure_notes
from mi_svbrdf.io.viewer import PAGE_NAME, page_title, write_viewer
from mi_svbrdf.optim import METHODS, OptimizeConfig, method_config, optimize
from mi_svbrdf.optim.fused_loss import LOSSES
from mi_svbrdf.optim.forward import forward_for
from mi_svbrdf.optim.select import SELECT_MODES, select_and_fit
from mi_svbrdf.plugins.model import DISTRIBUTIONS

DESCRIPTION = """\
Fit normal, diffuse, roughness and specular maps to N calibrated photos: a capture file
(capture.json, version 1: each photo with its camera and flash; images found relative to it) by
inverse rendering, on the texel path for rectified photos and through Mitsuba for perspective
ones. --capture example is the bundled capture: 6 photos (128 px) of a held-out procedural
leather. Make a capture file from your photos with `mi-svbrdf capture-file make` (you state the
camera and the flash) or `mi-svbrdf rectify` (photos of the sample in a paper frame).

The fit stops when it has converged: its learning rate follows a cosine schedule over the first
{sched} steps (compressed to fit --budget-s when that ends first); after the schedule it stops
once the loss's last {window}-step window improved on the window before by less than {tol:g} x
all the fit has gained since its first window (with --calibrate, counted from the step the
calibration starts, and not before it has run two windows); otherwise at --iterations or on the --budget-s time limit, which
summary.json's notes then report with what to do.

A photo (nearly) all black or all saturated holds no measurement: optimize says so, and
summary.json's notes say what the maps are then worth.

With 3 or more rectified photos, --select auto (the default) chooses per capture the map model
(Lambertian; uniform specular and roughness; uniform specular; the full SVBRDF) and the recipe
(the defaults, stronger priors, a slower learning rate, self-calibration) that predict left-out
photos best: each candidate is fitted with one photo left out in turn at a lower resolution, the
simplest within one standard error of the best wins, and is then fitted on all photos in what is
left of --budget-s. The spread of its fold fits gives uncertainty maps. --select NAME forces a
candidate; --select off fits the default recipe alone.

--distribution beckmann fits maps of the Beckmann model (the thesis's ch. 6.1.1: another output
model) instead of GGX, whatever model made the photos; material.json records it.
""".format(sched=OptimizeConfig.schedule_steps, window=OptimizeConfig.window, tol=OptimizeConfig.tol)
OUTPUTS = """\
Writes to -o/--out:
  material/         the maps (normal.png diffuse.png roughness.png specular.png + material.json,
                    which records the BRDF model: ggx or beckmann)
  history.csv       seconds, step, loss and fit (its run: start, validation, fit) of every good step
  loss.png          the loss against time
  renders/NNN.png   photo | re-rendering | difference x4, labelled (sRGB; grey: explained)
  view.html         the maps in a self-contained WebGL2 page: drag the light (mi-svbrdf view);
                    with --select auto, an "uncertainty" toggle shows the uncertainty maps
  selection.png     with --select auto: each candidate's held-out error (mean +- paired standard
                    error over the folds) against its time; the choice marked
  uncertainty/      with --select auto: normal_deg.png, diffuse.png, roughness.png, specular.png,
                    the per-texel spread of the chosen candidate's fold fits (colour scale in
                    summary.json's uncertainty)
  summary.json      steps, seconds, final loss, recoveries, stop reason, the RMSE against the photos
                    (rerender_rmse: the re-renderings vs the photos fitted), model, self-calibration
                    estimates, selection (every candidate's fold errors, mean, standard error,
                    seconds; the choice and why), notes (e.g. a fit stopped by its budget)
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
#: Colour scale of the uncertainty maps: the spread drawn at the top of the scale.
UNCERTAINTY_SCALE = {"normal_deg": 20.0, "diffuse": 0.2, "roughness": 0.2, "specular": 0.2}


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``optimize`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "optimize", help="fit SVBRDF maps to a calibrated capture (capture.json)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("--capture", required=True, metavar="CAPTURE",
                   help="capture.json (version 1), a folder holding one, or 'example' (the bundled capture)")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--budget-s", type=float_at_least(0.0, unit="seconds", allow_inf=True), default=60.0,
                   help="wall-time limit in seconds (default 60; 0 or inf: none, the fit stops when converged); a fit "
                        "it stops is not final and summary.json's notes say so")
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
    p.add_argument("--levels", type=int_at_least(1), default=1, help="coarse-to-fine levels (default 1)")
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
    p.add_argument("--device", default="cpu", help=DEVICE_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def _srgb(image: torch.Tensor) -> np.ndarray:
    return srgb_encode(image.detach().permute(1, 2, 0).numpy())


def write_outputs(out: Path, result: object, spec: object, images: torch.Tensor, renders: torch.Tensor,
                  uncertainty: dict[str, tuple[np.ndarray, str]] | None = None) -> None:
    """Write maps, history, loss curve, photo | re-render pairs and the viewer page of a fit to ``out``
    (``uncertainty``: :func:`uncertainty_images`, a toggle of the page)."""
    plt = pyplot()
    out.mkdir(parents=True, exist_ok=True)
    write_material(out / "material", result.maps, distribution=getattr(result, "distribution", "ggx"))
    phases = fit_phases(result)
    lines = ["seconds,step,loss,fit"] + [f"{t:.6f},{s},{v:.8g},{name}" for name, rows in phases for t, s, v in rows]
    write_text(out / "history.csv", "\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, rows in phases:  # one line per fit: a validation fit then the full fit is not one line that climbs
        if rows:
            ax.semilogy([h[0] for h in rows], [h[2] for h in rows], label=name)
    if len(phases) > 1:
        ax.legend(fontsize=7)
    ax.set_xlabel("seconds")
    ax.set_ylabel("loss")
    ax.set_title(f"optimize: {result.steps} steps, {result.recoveries} recoveries")
    fig.tight_layout()
    save_figure(fig, out / "loss.png", dpi=100)
    (out / "renders").mkdir(exist_ok=True)
    for k in range(images.shape[0]):
        write_image(out / "renders" / f"{k:03d}.png", residual_panel(images[k], renders[k]), srgb=True)
    write_viewer(out / PAGE_NAME, result.maps, title=page_title("optimize", out),
                 distribution=result.distribution, uncertainty=uncertainty)


def uncertainty_images(selected: object) -> dict[str, tuple[np.ndarray, str]] | None:
    """The uncertainty maps of a selected fit drawn with a colour scale: ``{name: ((H, W, 3) in [0, 1], caption)}``."""
    if getattr(selected, "uncertainty", None) is None:
        return None
    cmap = pyplot().get_cmap("magma")
    unit = {"normal_deg": "°"}
    images = {}
    for name, spread in selected.uncertainty.items():
        level = (spread[0, 0].cpu() / UNCERTAINTY_SCALE[name]).clamp(0.0, 1.0).numpy()
        caption = (f"spread of {name.replace('_deg', '')} over the fold fits: black 0, yellow-white "
                   f"{UNCERTAINTY_SCALE[name]:g}{unit.get(name, '')} or more (texels clipped in every photo: top)")
        images[name] = (np.ascontiguousarray(cmap(level)[..., :3], dtype=np.float32), caption)
    return images


def write_selection(out: Path, selected: object, uncertainty: dict[str, tuple[np.ndarray, str]] | None) -> None:
    """``selection.png`` (each candidate's held-out error against its time) and ``uncertainty/*.png``."""
    plt = pyplot()
    sel = selected.selection
    first = str(sel["folds"][0])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for i, row in enumerate(sel["candidates"]):  # left: every candidate on the first fold (where the halving is decided)
        offset = (6, -10 + 9 * (i % 3))  # neighbours' labels apart
        chosen = row["name"] == sel["choice"]
        colour = "C3" if chosen else ("0.6" if row["eliminated"] else "C0")
        ax1.plot(row["fold_seconds"][first], row["fold_errors"][first], "x" if row["eliminated"] else "o",
                 color=colour, ms=9 if chosen else 6)
        ax1.annotate(row["name"], (row["fold_seconds"][first], row["fold_errors"][first]),
                     textcoords="offset points", xytext=offset, fontsize=7)
        if not row["eliminated"]:  # right: the survivors over every fold
            ax2.errorbar(row["seconds"], row["mean"], yerr=row["se"], fmt="o", color=colour, ms=9 if chosen else 6,
                         capsize=3)
            ax2.annotate(row["name"] + (" (chosen)" if chosen else ""), (row["seconds"], row["mean"]),
                         textcoords="offset points", xytext=offset, fontsize=7)
    ax1.set_title(f"every candidate, photo {first} left out (x: eliminated)", fontsize=9)
    ax1.set_xlabel("seconds of the fold fit")
    ax1.set_ylabel("held-out photo's display RMSE")
    ax2.set_title(f"the best {sum(not r['eliminated'] for r in sel['candidates'])}: mean over photos "
                  f"{', '.join(str(k) for k in sel['folds'])} left out (bars: paired SE)", fontsize=9)
    ax2.set_xlabel("seconds of all its fold fits")
    fig.suptitle(f"selection: {sel['choice']}", fontsize=10)
    fig.tight_layout()
    save_figure(fig, out / "selection.png", dpi=100)
    if uncertainty is None:
        return
    (out / "uncertainty").mkdir(exist_ok=True)
    for name, (image, _) in uncertainty.items():
        write_image(out / "uncertainty" / f"{name}.png", image)


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
    chosen = {k: v for k, v in (("loss", args.loss), ("tv_weight", args.tv)) if v is not None}
    chosen["fewer_texels"] = smaller_photos_advice(path / CAPTURE_NAME if path.is_dir() else path)  # budget note
    cfg = method_config(args.method, iterations=args.iterations,
                        budget_s=args.budget_s if args.budget_s > 0 else math.inf, levels=args.levels,
                        path=args.path, progress=not args.no_progress, device=str(device),
                        distribution=args.distribution, calibrate=args.calibrate, **chosen)
    select = "off" if args.select == "auto" and (init is not None or args.method != "default") else args.select
    if select == "off":
        result, selected = optimize(spec, images, valid, config=cfg, init_maps=init), None
    else:
        selected = select_and_fit(spec, images, valid, config=cfg, select=select)
        result = selected.result
    result.maps = result.maps.cpu()
    for note in result.notes:
        print(f"mi-svbrdf optimize: {note}", file=sys.stderr)
    notes += result.notes
    rendered_spec = result.calibrated_spec or spec  # the photos as the fit explains them
    with torch.no_grad():
        renders = forward_for(rendered_spec, tuple(images.shape[-2:]), args.path,
                              distribution=result.distribution)(result.maps).clamp(0.0, 1.0)
    out = Path(args.out)
    capture_file = path / CAPTURE_NAME if path.is_dir() else path  # the inputs stay, wherever they are
    inputs = [capture_file, *(capture_file.parent / im.file for im in spec.images), *([args.init] if args.init else [])]
    replace_outputs(args, out, OWNED, keep=inputs)
    uncertainty = uncertainty_images(selected)
    write_outputs(out, result, spec, images, renders, uncertainty)
    if selected is not None and selected.selection.get("candidates"):
        write_selection(out, selected, uncertainty)
    summary = {"capture": str(path), "photos": spec.n_images, "steps": result.steps, "seconds": result.seconds,
               "final_loss": result.final_loss, "recoveries": result.recoveries, "stop_reason": result.stop_reason,
               "distribution": result.distribution,
               "rerender_rmse": float(((renders - images.clamp(0, 1)) ** 2).mean().sqrt()),
               "saturated_fraction": round(float((~valid).float().mean()), 4),
               "calibration": result.calibration,
               "selection": selected.selection if selected is not None else {"mode": "off"},
               "notes": notes}
    if selected is not None and selected.uncertainty is not None:
        summary["uncertainty"] = {"mean": selected.selection["uncertainty"], "png_top_of_scale": UNCERTAINTY_SCALE}
    write_json(out / "summary.json", summary)
    if selected is not None and selected.choice:
        print(f"selected {selected.selection.get('why', selected.choice)}")
    print(f"{spec.n_images} photo(s): {result.steps} steps in {result.seconds:.1f} s ({result.stop_reason}), RMSE "
          f"against the photos {summary['rerender_rmse']:.4f}; wrote {out}/: material/, history.csv, loss.png, "
          f"renders/, {PAGE_NAME}, summary.json" + (", selection.png, uncertainty/" if uncertainty else ""))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.optimize``: ``optimize`` arguments only."""
    return standalone(add_parser, ["optimize", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
