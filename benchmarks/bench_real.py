"""Benchmark: methods on real flash captures of other labs, judged on photos they did not see.

For each capture folder (the MaterialGAN / svbrdf-diff-renderer layout, read with
``mi-svbrdf capture-file import``'s code, photos resized to ``--size``), every method fits all
photos but a held-out pair (``--held-out``, default 4 and 7), then re-renders the held-out photos.
The error is the display-space RMSE (``clip(x, 0, 1)^(1/2.2)``) of the held-out photos after one
global exposure scale fitted on the fit photos (least squares in linear light over unsaturated
pixels): a method's absolute albedo scale is not held against it.

Methods, each with the same wall time (``--budget-s``, 60 s by default):

* ``trivial``: the optimiser's start (the most frontal photo over its flat irradiance, roughness 0.5);
* ``pixel``: the field's per-pixel baseline (``optimize --method pixel``: Adam, L2 on gamma-encoded photos);
* ``optimize``: ``optimize``'s defaults; ``optimize+calibrate``: the same with ``--calibrate on``;
* ``net``: the bundled single-image network on the most frontal fit photo;
* ``optimize x10``: ``optimize``'s defaults with 10x the budget (``--reference-factor``), the
  reference of convergence (the defaults should come within 2 % of it);
* with ``--ablate``: ``optimize`` with one default component removed at a time;
* with ``--candidates``: each candidate of ``optimize --select`` (:data:`mi_svbrdf.optim.select.LADDER`) fitted
  alone, the selection (``select auto``: the choice made on the fit photos alone, folds and final fit within the
  same budget), and the oracle (the candidate that did best on the held-out pair, which no method can know).

The reference and the ablations run on the first capture only unless ``--study-all``. ``--synthetic
3,13`` adds realistic simulated 9-photo captures of those materials (:mod:`mi_svbrdf.data.realistic`:
per-photo exposure and white balance, flash offset, pose errors, vignetting, an unstated light,
JPEG), the first also as its clean twin, with the ablations: what each default costs and gains
there too.

Residual panels (``photo | re-rendering | difference x4`` of the first held-out photo, 128 px) go
to ``docs/benchmarks/real/``; the table to ``docs/benchmarks/real.md`` and ``real.json``.

Usage::

    python benchmarks/bench_real.py ../shared/real/yellow_box ../shared/real/bath_tile --ablate
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.cli.optimize import residual_panel
from mi_svbrdf.data.realistic import RealisticSet
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.capture_import import foreign_photos, read_foreign_capture
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.optim import initial_maps, method_config, optimize
from mi_svbrdf.optim.fit import ladder_levels
from mi_svbrdf.optim.fit import frontality
from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.optim.loop import Monitor
from mi_svbrdf.optim.scoring import HeldOutScorer, channel_bias, exposure_scale
from mi_svbrdf.optim.select import LADDER, SelectConfig, select_and_fit

ROOT = Path(__file__).resolve().parents[1]
#: Components of optimize's default path and the overrides that remove each (``--ablate``).
ABLATIONS: dict[str, dict[str, Any]] = {
    "no multi-start": {"roughness_starts": (0.5,)},
    "no priors": {"start_prior_weight": 0.0, "prior_weight": 0.0, "chroma_weight": 0.0, "clip_chroma": 0.0},
    "no TV": {"tv_weight": 0.0},
    "no convergence stop": {"tol": 0.0},
}


def held_out_error(maps: torch.Tensor, spec: Any, images: torch.Tensor, fit: list[int], held: list[int],
                   size: int) -> dict[str, Any]:
    """How ``maps`` predict the held-out photos (:class:`~mi_svbrdf.optim.scoring.HeldOutScorer`, one render of
    each photo): the display RMSE, the exposure, the held-out renders, each fit photo's own exposure in stops
    relative to their geometric mean, the per-channel bias on the held-out photos and the display RMSE on the
    fit photos themselves (how well the maps explain what they were fitted to)."""
    scorer = HeldOutScorer(spec, images, fit, held)
    err = scorer(maps)
    r_fit, photos = scorer.render_fit(maps), images[fit]
    own = torch.tensor([math.log2(max(exposure_scale(r_fit[i:i + 1], photos[i:i + 1]), 1e-12))
                        for i in range(len(fit))])
    fit_rmse = float((gamma_encode(r_fit * scorer.exposure) - gamma_encode(photos)).pow(2).mean().sqrt())
    return {"held_out_rmse": err, "exposure": scorer.exposure, "renders": scorer.renders,
            "photo_stops": [round(float(v), 3) for v in own - own.mean()],
            "bias_rgb": [round(v, 4) for v in channel_bias(scorer.renders, images[held])], "fit_rmse": fit_rmse}


def net_maps(spec: Any, images: torch.Tensor, fit: list[int]) -> tuple[torch.Tensor, float]:
    """The bundled single-image net on the most frontal fit photo: ``(maps (1, 10, S, S), seconds)``."""
    from mi_svbrdf.nets.inference import predict

    lights = torch.tensor([spec.images[k].light.position for k in fit])
    views = torch.tensor([spec.images[k].camera.position for k in fit])
    k = fit[int(frontality(lights, views).argmax())]
    t0 = time.perf_counter()
    maps = predict(images[k][None, None], kind="single", linear=True)
    return maps, time.perf_counter() - t0


def slug(name: str) -> str:
    """A method's name as a file name."""
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def load_folder(folder: Path, size: int, resample: int = 0) -> dict[str, Any]:
    """A capture folder of another lab at ``size``: its spec, photos, unclipped pixels and description.

    ``resample``: 0 the importer's resampling; 1 bilinear (antialiased) from the photos' own size; 2 the importer's
    to ``size + 8``, then area-averaged to ``size``: near-identical inputs, for the selection's stability."""
    foreign = read_foreign_capture(folder)
    spec, images, _ = foreign_photos(foreign, {0: size, 1: None, 2: size + 8}[resample])
    if images.shape[-1] != size:
        mode = {"mode": "bilinear", "antialias": True, "align_corners": False} if resample == 1 else {"mode": "area"}
        images = torch.nn.functional.interpolate(images, size=(size, size), **mode).clamp(0.0, 1.0)
    return {"name": folder.name, "spec": spec, "images": images,
            "valid": (images < 254.5 / 255.0).all(dim=1, keepdim=True),
            "about": f"{foreign.width_cm:g} cm, {foreign.source.name}", "real": True}


def load_synthetic(m: int, realism: str, size: int, photos: int = 9) -> dict[str, Any]:
    """Realistic capture (or its clean twin) of the tune split's material ``m`` in ``photos`` photos
    (:mod:`mi_svbrdf.data.realistic`); its true maps are kept (``truth``) for the per-map errors."""
    cap = RealisticSet(split="tune", size=size, materials=(m,), n_images=(photos,), realism=realism).capture(m, photos)
    suffix = "" if photos == 9 else f"_{photos}"
    return {"name": f"synthetic_{cap.cls}_{m}_{realism}{suffix}", "spec": cap.stated, "images": cap.images,
            "valid": cap.valid, "about": f"simulated {cap.cls}, {realism}", "real": False, "truth": cap}


def sharpness(renders: torch.Tensor, photos: torch.Tensor) -> float:
    """High-pass energy of the re-renderings over the photos' (``(K, 3, H, W)`` each, display space): the mean square
    of an image minus its 4x4 box blur. 1: as sharp as the photos; below: blurrier (an upsampled fit), above:
    noisier."""
    def high(x: torch.Tensor) -> torch.Tensor:
        d = x.clamp(0.0, 1.0) ** (1.0 / 2.2)
        blur = torch.nn.functional.avg_pool2d(d, 4, stride=1, padding=2, count_include_pad=False)[..., :d.shape[-2], :d.shape[-1]]
        return (d - blur).pow(2).mean()
    return float(high(renders.detach().cpu().float()) / high(photos.detach().cpu().float()).clamp_min(1e-12))


def run_capture(capture: dict[str, Any], args: argparse.Namespace, figures: Path, studied: bool) -> dict[str, Any]:
    spec, images, valid = capture["spec"], capture["images"], capture["valid"]
    size, n, label = images.shape[-1], spec.n_images, capture["name"]
    held = [k for k in args.held_out if k < n]
    fit = [k for k in range(n) if k not in held]
    fit_spec, fit_images, fit_valid = spec.subset(fit), images[fit], valid[fit]
    rows: list[dict[str, Any]] = []

    def record(name: str, maps: torch.Tensor, seconds: float, **info: Any) -> None:
        scored = held_out_error(maps, spec, images, fit, held, size)
        renders, err = scored.pop("renders"), scored["held_out_rmse"]
        scored["sharpness"] = round(sharpness(renders, images[held]), 4)
        if capture.get("truth") is not None:  # a simulated capture: how far the maps are from its true ones
            scored["normal_rmse"] = capture["truth"].map_errors(maps.detach().cpu())["normal"]
        rows.append({"method": name, **scored, "seconds": seconds, **info})
        if "," not in name:  # the ablations' panels look like the default's
            panel = residual_panel(images[held[0]], renders[0])
            small = torch.nn.functional.interpolate(torch.from_numpy(panel).permute(2, 0, 1)[None],
                                                    scale_factor=0.5, mode="area")[0].permute(1, 2, 0).numpy()
            write_image(figures / f"{label}_{slug(name)}.png", np.ascontiguousarray(small), 8)
        extra = ", ".join(f"{a} {b}" for a, b in info.items())
        normal = f", normal {scored['normal_rmse']:.4f}" if "normal_rmse" in scored else ""
        print(f"{label}: {name:<28} held-out {err:.4f}{normal}  ({seconds:6.1f} s{', ' + extra if extra else ''})",
              flush=True)

    def fit_with(name: str, method: str, budget: float, monitor: Monitor | None = None, **fields: Any) -> None:
        if method == "default" and args.levels == "auto":  # optimize's default ladder (1 level at 256^2 and below)
            fields = {"levels": ladder_levels(size, size), **fields}
        cfg = method_config(method, budget_s=budget, iterations=10**6 if method == "pixel" else args.iterations,
                            progress=False, **fields)
        t0 = time.perf_counter()
        res = optimize(fit_spec, fit_images, fit_valid, config=cfg, held_out=monitor)
        info = {"steps": res.steps, "stop": res.stop_reason}
        if res.held_out and "then" in res.held_out:
            info["length"] = f"{res.held_out['best_length']} ({res.held_out['then']})"
        if res.calibration is not None:
            info["exposure_stops"] = res.calibration.get("exposure_stops")
        record(name, res.maps, time.perf_counter() - t0, **info)

    def selection(name: str) -> None:
        t0 = time.perf_counter()
        sel = select_and_fit(fit_spec, fit_images, fit_valid,
                             config=method_config("default", budget_s=args.budget_s, iterations=args.iterations,
                                                  progress=False),
                             settings=SelectConfig(warm_start=not args.fresh_final))
        plan = sel.selection.get("plan", {})
        print(f"{label}: {plan.get('line', 'no plan')}", flush=True)
        folds = {len(c["fold_errors"]) for c in sel.selection.get("candidates", []) if not c["eliminated"]}
        record(name, sel.result.maps, time.perf_counter() - t0, steps=sel.result.steps, choice=sel.choice,
               folds_s=round(sel.selection.get("seconds_folds", 0.0), 1),
               final_s=round(sel.selection.get("seconds_final", 0.0), 1), folds=min(folds) if folds else 0,
               stop=sel.result.stop_reason, start=sel.selection.get("final_start", ""))
        rows[-1]["plan"] = plan
        rows[-1]["fold_means"] = {c["name"]: round(c["mean"], 4) for c in sel.selection.get("candidates", [])}
        rows[-1]["fold_seconds"] = {c["name"]: round(c["seconds"], 1) for c in sel.selection.get("candidates", [])}
        rows[-1]["near_ties"] = sel.selection.get("near_ties", [])

    if args.selection_only:  # the selection's stability on reruns and resamplings
        for r in range(args.reruns):
            selection("selection" if r == 0 else f"selection, rerun {r}")
        return {"capture": label, "about": capture["about"], "photos": n, "held_out": held, "size": size,
                "resample": args.resample, "rows": rows}
    t0 = time.perf_counter()
    record("trivial", initial_maps(fit_spec, fit_images), time.perf_counter() - t0)
    if "net" not in args.skip:
        maps, seconds = net_maps(spec, images, fit)
        record("net", maps, seconds)
    for name, method, fields in (("pixel", "pixel", {}), ("pixel, to the budget", "pixel", {"early_stop": "off"}),
                                 ("plain Adam (lr 0.02, least-squares start)", "pixel",
                                  {"lr": 0.02, "start": "lstsq", "early_stop": "off"}),
                                 ("optimize", "default", {}),
                                 ("optimize+calibrate", "default", {"calibrate": "on"})):
        if name.split(",")[0].split(" (")[0] not in args.skip:
            fit_with(name, method, args.budget_s, **fields)
    if "pixel" not in args.skip:  # the baseline at its best: stopped where the held-out pair itself is best
        oracle = Monitor(HeldOutScorer(spec, images, fit, held), every=10, patience=400, patience_fraction=0.5)
        fit_with("pixel, oracle length", "pixel", args.budget_s, monitor=oracle, early_stop="off")
        rows[-1]["length"] = oracle.best_length
    if args.candidates:
        for c in LADDER:
            fit_with(f"candidate {c.name}", "default", args.budget_s, **c.overrides)
            if args.both_stops:
                fit_with(f"candidate {c.name}, no early stop", "default", args.budget_s,
                         **{**c.overrides, "early_stop": "off"})
        selection("selection")
        for r in range(1, args.reruns):
            selection(f"selection, rerun {r}")
        cands = [r for r in rows if r["method"].startswith("candidate ")]
        best = min(cands, key=lambda r: r["held_out_rmse"])
        sel_row = next(r for r in rows if r["method"] == "selection")
        rows.append({**best, "method": f"oracle ({best['method'][len('candidate '):]})"})
        print(f"{label}: oracle {best['method']} {best['held_out_rmse']:.4f}; selection {sel_row['held_out_rmse']:.4f} "
              f"({sel_row['held_out_rmse'] / best['held_out_rmse'] - 1:+.1%})", flush=True)
    if args.ablate and studied:
        for name, fields in ABLATIONS.items():
            fit_with(f"optimize, {name}", "default", args.budget_s, **fields)
    if args.reference_factor > 0 and studied and capture["real"]:
        fit_with(f"optimize x{args.reference_factor:g}", "default", args.budget_s * args.reference_factor)
    return {"capture": label, "about": capture["about"], "photos": n, "held_out": held, "size": size, "rows": rows}


def _num(value: Any, fmt: str) -> str:
    """A figure of the table, or blank where a run did not record it."""
    return format(value, fmt) if isinstance(value, (int, float)) and math.isfinite(value) else ""


def write_page(path: Path, results: list[dict[str, Any]], args: argparse.Namespace) -> None:
    selection = any(r["method"] == "selection" for res in results for r in res["rows"])
    command = (" ".join(sys.argv[1:]) if args.page_from is None else
               "--page-from RUNS.json` (the runs' rows gathered: see the notes below the title) `")
    lines = ["# Real captures: held-out photos" + (", the candidates of optimize --select" if selection else ""), "",
             "Generated by `python benchmarks/bench_real.py " + command + "` "
             f"({platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}).", "",
             f"Each method fits all photos but the held-out pair at {args.size}² with {args.budget_s:g} s of wall time; "
             "the error is the display-space RMSE (gamma 2.2) of the held-out photos after one exposure scale fitted "
             "on the fit photos where neither the photo nor the render clips (`optim.scoring`). `x10`: the same fit "
             "with 10x the time (the reference of convergence). `length (then)`: the early stop's length and whether "
             "all photos were then refitted to it or the first fit went on. Bias: the mean display difference "
             "render - photo per channel on the held-out photos (a colour cast: channels of opposite signs). "
             "Sharpness: the high-pass energy of the held-out re-renderings over the photos' (an image minus its 4x4 "
             "box blur; 1: as sharp as the photos, below: blurrier). `optimize` climbs its resolution ladder "
             f"(`--levels {args.levels}`).", ""]
    if selection:
        lines += ["`candidate NAME`: one candidate of `optimize --select` fitted alone (`candidate full` is `optimize`'s "
                  "default recipe); `selection`: `optimize --select auto`, its choice and the seconds of its fold fits "
                  "(folds and final fit within the same budget); `oracle`: the candidate that did best on the held-out "
                  "pair, which no method can know.", ""]
    for res in results:
        lines += [f"## {res['capture']} ({res['photos']} photos, {res['about']}, held out "
                  f"{', '.join(str(k) for k in res['held_out'])})", "",
                  "| method | held-out RMSE | normal RMSE | seconds | steps | stop | length (then) | exposure | "
                  "bias R, G, B (held-out) | RMSE on the fit photos | sharpness |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in res["rows"]:
            name = r["method"] + (f": {r['choice']} ({r.get('folds', '?')} folds {r['folds_s']} s, final fit "
                                  f"{r.get('final_s', '?')} s from {r.get('start') or 'a fresh start'})"
                                  if r.get("choice") else "")
            bias = ", ".join(f"{v:+.3f}" for v in r.get("bias_rgb", []))
            lines.append(f"| {name} | {r['held_out_rmse']:.4f} | {_num(r.get('normal_rmse'), '.4f')} | "
                         f"{r['seconds']:.1f} | {r.get('steps', '')} | "
                         f"{r.get('stop', '')} | {r.get('length', '')} | {_num(r.get('exposure'), '.3g')} | {bias} | "
                         f"{_num(r.get('fit_rmse'), '.4f')} | {_num(r.get('sharpness'), '.3f')} |")
        plans = list(dict.fromkeys(r["plan"]["line"] for r in res["rows"] if r.get("plan", {}).get("line")))
        if plans:
            lines += [""] + [f"The selection's {line}" for line in plans]
        cal = next((r for r in res["rows"] if r["method"] == "optimize+calibrate" and r.get("exposure_stops")), None)
        if cal:
            lines += ["", f"Self-calibration's exposure per fit photo (stops): {cal['exposure_stops']}"]
        lines += ["", "Residuals of the first held-out photo (photo | re-rendering | difference x4): "
                  + ", ".join(f"[{r['method']}](real/{res['capture']}_{slug(r['method'])}.png)"
                              for r in res["rows"] if "," not in r["method"] and not r["method"].startswith("oracle")), ""]
        ref = next((r for r in res["rows"] if r["method"].startswith("optimize x")), None)
        if ref:
            lines += [f"Each fit photo's own exposure after the reference fit (stops, relative to their mean): "
                      f"{ref['photo_stops']}", ""]
    write_text(path, "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("captures", nargs="*", type=Path, help="capture folders (MaterialGAN layout); none: --synthetic only")
    p.add_argument("--held-out", type=lambda s: [int(v) for v in s.split(",")], default=[4, 7],
                   help="photos held out (default 4,7)")
    p.add_argument("--size", type=int, default=256, help="resolution of the fits (default 256)")
    p.add_argument("--levels", choices=("auto", "1"), default="auto",
                   help="optimize's coarse-to-fine levels: auto (default, optimize's ladder: 1 level at 256^2 and "
                        "below) or 1")
    p.add_argument("--budget-s", type=float, default=60.0, help="wall time per method (default 60)")
    p.add_argument("--reference-factor", type=float, default=10.0, help="budget factor of the reference fits (0: none)")
    p.add_argument("--iterations", type=int, default=10**6, help="step cap of optimize's fits (default: none)")
    p.add_argument("--ablate", action="store_true", help="also optimize with each default component removed")
    p.add_argument("--candidates", action="store_true",
                   help="also each candidate of optimize --select alone, the selection, and the oracle")
    p.add_argument("--both-stops", action="store_true",
                   help="with --candidates: each candidate also without the early stop (early_stop off)")
    p.add_argument("--reruns", type=int, default=1, help="with --candidates: runs of the selection (its stability)")
    p.add_argument("--resample", type=int, default=0,
                   help="resample the photos to --size this way: 0 area (default), 1 bilinear, 2 area from size+8 "
                        "(near-identical inputs: the selection's stability)")
    p.add_argument("--synthetic-photos", type=lambda v: [int(k) for k in v.split(",") if k], default=[9],
                   help="photos of each simulated capture (default 9; e.g. 9,20)")
    p.add_argument("--no-clean", action="store_true", help="no clean twin of the first --synthetic capture")
    p.add_argument("--clean-only", action="store_true", help="only the clean twins of the --synthetic captures")
    p.add_argument("--selection-only", action="store_true", help="only the selection, --reruns times")
    p.add_argument("--fresh-final", action="store_true",
                   help="the selection's final fit from a fresh start, not from the chosen candidate's fold fits")
    p.add_argument("--skip", type=lambda v: [m for m in v.split(",") if m], default=[],
                   help="methods not run (e.g. optimize+calibrate,net)")
    p.add_argument("--study-all", action="store_true",
                   help="ablations and the reference fit on every capture (default: the first one only)")
    p.add_argument("--synthetic", type=lambda v: [int(m) for m in v.split(",") if m], default=[],
                   help="also realistic simulated captures of these tune-split materials (e.g. 3,13; the first also "
                        "as its clean twin), with the ablations")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "real.md", help="the page written")
    p.add_argument("--page-from", type=Path, default=None,
                   help="write the page (--out) from this run's JSON instead of running (a JSON of several runs: a list)")
    args = p.parse_args(argv)
    if args.page_from is not None:
        write_page(args.out, json.loads(args.page_from.read_text()), args)
        print(f"wrote {args.out}")
        return 0
    if not args.captures and not args.synthetic:
        p.error("captures: expected a capture folder or --synthetic, got neither")
    for folder in args.captures:
        if not folder.is_dir():
            p.error(f"{folder}: expected a capture folder, got no such folder")
    figures = args.out.parent / "real"
    figures.mkdir(parents=True, exist_ok=True)
    captures = [(load_folder(folder, args.size, args.resample), i == 0 or args.study_all)
                for i, folder in enumerate(args.captures)]
    results = [run_capture(cap, args, figures, studied) for cap, studied in captures]
    for m in args.synthetic:  # the same protocol on simulated captures (ablations too), and one clean twin
        realisms = ("clean",) if args.clean_only else (
            ("real", "clean") if m == args.synthetic[0] and not args.no_clean else ("real",))
        for realism in realisms:
            for photos in args.synthetic_photos:
                results.append(run_capture(load_synthetic(m, realism, args.size, photos), args, figures, True))
    write_json(args.out.with_suffix(".json"), results)
    write_page(args.out, results, args)
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
