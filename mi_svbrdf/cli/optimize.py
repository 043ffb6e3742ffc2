"""``mi-svbrdf optimize``: fit SVBRDF maps to a calibrated capture file and write the results.

Writes to ``-o OUT``: ``material/`` (the maps, :func:`mi_svbrdf.io.material_io.write_material`),
``history.csv`` (seconds, step, loss), ``loss.png`` (the loss against time),
``renders/NNN.png`` (each photo beside its re-rendering, sRGB), ``view.html`` (the maps in the
WebGL2 viewer, :mod:`mi_svbrdf.io.viewer`) and ``summary.json``.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.calibrated_photos import load_capture
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import read_material, srgb_encode, write_material
from mi_svbrdf.io.viewer import PAGE_NAME, write_viewer
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.forward import forward_for

HELP = """\
Fit normal, diffuse, roughness and specular maps to N calibrated photos (capture file v1,
images found relative to it).

Writes to -o/--out:
  material/         the maps (normal.png diffuse.png roughness.png specular.png + material.json)
  history.csv       seconds, step, loss of every good step
  loss.png          the loss against time
  renders/NNN.png   each photo beside its re-rendering (sRGB)
  view.html         the maps in a self-contained WebGL2 page: drag the light (mi-svbrdf view)
  summary.json      steps, seconds, final loss, recoveries, stop reason, re-rendering RMSE
"""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``optimize`` on a subparsers object (``func(args) -> int``)."""
    p = subparsers.add_parser("optimize", help="fit SVBRDF maps to a calibrated capture", description=HELP,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--capture", required=True, help="capture JSON (version 1)")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--budget-s", type=float, default=60.0, help="wall-time budget in seconds (default 60)")
    p.add_argument("--iterations", type=int, default=2000, help="maximum Adam steps (default 2000)")
    p.add_argument("--init", default=None, metavar="MAPS_DIR", help="start from these maps (a material folder)")
    p.add_argument("--path", choices=("auto", "texel", "mitsuba"), default="auto",
                   help="forward model (auto: texel when every photo is rectified)")
    p.add_argument("--tv", type=float, default=1e-3, help="total-variation weight (default 1e-3)")
    p.add_argument("--loss", choices=("log_l1", "l2"), default="log_l1", help="re-rendering error")
    p.add_argument("--levels", type=int, default=1, help="coarse-to-fine levels (default 1)")
    p.add_argument("--device", default="cpu", help=DEVICE_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_cli)


def _srgb(image: torch.Tensor) -> np.ndarray:
    return srgb_encode(image.detach().permute(1, 2, 0).numpy())


def write_outputs(out: Path, result: object, spec: object, images: torch.Tensor, renders: torch.Tensor) -> None:
    """Write maps, history, loss curve, photo | re-render pairs and the viewer page of a fit to ``out``."""
    plt = pyplot()
    out.mkdir(parents=True, exist_ok=True)
    write_material(out / "material", result.maps)
    lines = ["seconds,step,loss"] + [f"{t:.6f},{s},{v:.8g}" for t, s, v in result.history]
    write_text(out / "history.csv", "\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(5, 3.5))
    if result.history:
        ax.semilogy([h[0] for h in result.history], [h[2] for h in result.history])
    ax.set_xlabel("seconds")
    ax.set_ylabel("loss")
    ax.set_title(f"optimize: {result.steps} steps, {result.recoveries} recoveries")
    fig.tight_layout()
    save_figure(fig, out / "loss.png", dpi=100)
    (out / "renders").mkdir(exist_ok=True)
    for k in range(images.shape[0]):
        pair = torch.cat([images[k], renders[k]], dim=2)
        write_image(out / "renders" / f"{k:03d}.png", _srgb(pair), srgb=True)
    write_viewer(out / PAGE_NAME, result.maps, title=f"mi-svbrdf optimize {out.name}")


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf optimize``; returns the exit code."""
    device = resolve_device(args.device)
    spec, images, valid = load_capture(args.capture)
    init = read_material(args.init) if args.init else None
    cfg = OptimizeConfig(loss=args.loss, tv_weight=args.tv, iterations=args.iterations,
                         budget_s=args.budget_s if args.budget_s > 0 else math.inf, levels=args.levels,
                         path=args.path, progress=not args.no_progress, device=str(device))
    result = optimize(spec, images, valid, config=cfg, init_maps=init)
    result.maps = result.maps.cpu()
    with torch.no_grad():
        renders = forward_for(spec, tuple(images.shape[-2:]), args.path)(result.maps).clamp(0.0, 1.0)
    out = Path(args.out)
    write_outputs(out, result, spec, images, renders)
    summary = {"steps": result.steps, "seconds": result.seconds, "final_loss": result.final_loss,
               "recoveries": result.recoveries, "stop_reason": result.stop_reason,
               "rerender_rmse": float(((renders - images.clamp(0, 1)) ** 2).mean().sqrt())}
    write_json(out / "summary.json", summary)
    print(json.dumps(summary))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.optimize``: ``optimize`` arguments only."""
    parser = argparse.ArgumentParser(prog="mi-svbrdf")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(["optimize", *(argv or [])])
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
