"""Benchmark: maps at the photos' resolution (the ladder) against a 256^2 fit upsampled and the per-pixel fit.

Simulated captures of held-out materials with detail finer than a 256^2 texel (``RealisticSet``,
test split: phone-like nuisances, 9 photos), rendered at each size. Every fit is ``mi-svbrdf optimize``
as a user runs it, in its own process under ``/usr/bin/time -v`` (peak memory), on the saved capture:

* ``ladder``: the defaults (``--levels auto``: 256^2, then 512^2, then 1024^2, each from the one below);
* ``one level``: ``--levels 1``, the whole fit at the photos' size;
* ``pixel``: ``--method pixel``, the field's per-pixel Adam, with the same ``--budget-s`` (its early stop may end it
  first); ``pixel, to the budget``: the same with ``--early-stop off``;
* ``256 upsampled``: the same material captured at 256^2, fitted with the defaults in ``--budget-s-256``
  seconds, its maps upsampled bilinearly (normals renormalised) to the size of the comparison.

Scored at the capture's size: the held-out display RMSE (:meth:`RealisticCapture.heldout_error`, 8 new
views and lights) and the map RMSEs. ``--sizes`` adds the time and peak memory of the default fit at each
size (one material). Results go to ``--out``/resolution.{json,md}; a (size, material, method) already in the
JSON is not run again.

Pause background work first: the fits are timed by their budget, so a loaded machine fits less.

Usage:
    python benchmarks/bench_resolution.py [--size 1024] [--materials 13 14] [--budget-s 300]
        [--sizes 256 512 2048] [--out docs/benchmarks]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core.maps import normalize_normals
from mi_svbrdf.data.realistic import RealisticSet
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.material_io import read_material
from mi_svbrdf.io.tables import markdown_table

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks"
N_PHOTOS = 9
METHODS = {"ladder": [], "one level": ["--levels", "1"], "pixel": ["--method", "pixel"],
           "pixel, to the budget": ["--method", "pixel", "--early-stop", "off"]}


def capture(size: int, m: int, cache: Path) -> Any:
    return RealisticSet(split="test", size=size, materials=(m,), n_images=(N_PHOTOS,), cache_dir=str(cache)).capture(
        m, N_PHOTOS)


def upsample(maps: torch.Tensor, size: int) -> torch.Tensor:
    """Bilinear upsampling of ``(1, 10, R, R)`` maps to ``size``, normals renormalised."""
    return normalize_normals(F.interpolate(maps, size=(size, size), mode="bilinear", align_corners=False))


def fit(folder: Path, out: Path, budget: float, extra: list[str]) -> dict[str, Any]:
    """One ``mi-svbrdf optimize`` in its own process: its summary, wall seconds and peak memory (MB)."""
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "mi_svbrdf.cli", "optimize", "--capture", str(folder),
           "--budget-s", f"{budget:g}", "--no-progress", "-o", str(out), *extra]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    peak = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr).group(1)) / 1024
    summary = json.loads((out / "summary.json").read_text())
    return {"wall_s": round(wall, 1), "fit_s": round(summary["seconds"], 1), "steps": summary["steps"],
            "stop": summary["stop_reason"], "peak_mb": round(peak), "ladder": summary.get("ladder", {}).get("words"),
            "lines": [line for line in proc.stderr.splitlines() if line.startswith("mi-svbrdf optimize:")][:6]}


def score(cap: Any, maps: torch.Tensor) -> dict[str, Any]:
    return {"heldout": round(cap.heldout_error(maps), 5),
            "maps": {k: round(v, 5) for k, v in cap.map_errors(maps).items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1024, help="size of the comparison (default 1024)")
    parser.add_argument("--materials", type=int, nargs="+", default=[13, 14],
                        help="held-out test materials (default 13 wood, 14 fabric)")
    parser.add_argument("--methods", nargs="+", default=[*METHODS, "256 upsampled"],
                        choices=[*METHODS, "256 upsampled"])
    parser.add_argument("--budget-s", type=float, default=300.0, help="each fit's budget at --size (default 300)")
    parser.add_argument("--budget-s-256", type=float, default=60.0, help="the 256^2 fit's budget (default 60)")
    parser.add_argument("--sizes", type=int, nargs="*", default=[],
                        help="also the default fit's time and memory at these sizes (first material)")
    parser.add_argument("--size-budget", type=float, nargs="*", default=[],
                        help="the budget at each of --sizes (default: 60 s x (size / 256))")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "mi_svbrdf_resolution")
    parser.add_argument("--out", type=Path, default=DOCS)
    parser.add_argument("--note", default=None, help="how the run went (kept in the JSON, shown on the page)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "resolution.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    results.setdefault("quality", {})
    results.setdefault("scaling", {})
    results["machine"] = {"cpus": os.cpu_count(), "threads": torch.get_num_threads()}
    if args.note is not None:
        results["note"] = args.note
    work = args.cache / "runs"
    for m in args.materials:
        big = capture(args.size, m, args.cache)
        folder = work / f"m{m}_{args.size}"
        if not (folder / "capture.json").is_file():
            big.save(folder)
        entry = results["quality"].setdefault(f"{args.size}/{m}", {"class": big.cls, "budget_s": args.budget_s})
        for method in args.methods:
            if method in entry:
                continue
            if method == "256 upsampled":
                small = capture(256, m, args.cache)
                small_folder = work / f"m{m}_256"
                if not (small_folder / "capture.json").is_file():
                    small.save(small_folder)
                run = fit(small_folder, work / f"fit_m{m}_256", args.budget_s_256, [])
                maps = upsample(read_material(work / f"fit_m{m}_256" / "material"), args.size)
                run["budget_s"] = args.budget_s_256
            else:
                out = work / f"fit_m{m}_{args.size}_{method.replace(' ', '_')}"
                run = fit(folder, out, args.budget_s, METHODS[method])
                run["budget_s"] = args.budget_s
                maps = read_material(out / "material")
            entry[method] = {**run, **score(big, maps)}
            write_json(path, results)
            print(f"{args.size}/{m} {big.cls} {method}: held-out {entry[method]['heldout']:.4f}, "
                  f"{run['steps']} steps in {run['fit_s']} s, peak {run['peak_mb']} MB", flush=True)
    budgets = args.size_budget or [60.0 * s / 256 for s in args.sizes]
    for size, budget in zip(args.sizes, budgets):
        if str(size) in results["scaling"]:
            continue
        m = args.materials[0]
        cap = capture(size, m, args.cache)
        folder = work / f"m{m}_{size}"
        if not (folder / "capture.json").is_file():
            cap.save(folder)
        run = fit(folder, work / f"fit_m{m}_{size}_scaling", budget, [])
        run.update(budget_s=budget, **score(cap, read_material(work / f"fit_m{m}_{size}_scaling" / "material")))
        results["scaling"][str(size)] = run
        write_json(path, results)
        print(f"scaling {size}: {run['steps']} steps in {run['fit_s']} s, peak {run['peak_mb']} MB", flush=True)
    write_text(args.out / "resolution.md", page(results))
    return 0


def page(results: dict[str, Any]) -> str:
    lines = ["# Maps at the photos' resolution", "",
             "Generated by `python benchmarks/bench_resolution.py`; do not edit by hand. Simulated captures of "
             "held-out materials (`RealisticSet`, test split, 9 photos with phone-like nuisances), each fit "
             "`mi-svbrdf optimize` in its own process; held-out: display RMSE over 8 new views and lights at the "
             "capture's size. Machine: " + json.dumps(results.get("machine", {}), allow_nan=False) + ".", "",
             *([f"Note: {results['note']}", ""] if results.get("note") else [])]
    rows = []
    for key, entry in results.get("quality", {}).items():
        size, m = key.split("/")
        best_other = {}
        for method, run in entry.items():
            if not isinstance(run, dict):
                continue
            rows.append([f"{size}^2, material {m} ({entry['class']})", method, f"{run['budget_s']:g}",
                         f"{run['fit_s']:g}", str(run["steps"]), run["stop"], f"{run['heldout']:.4f}",
                         *(f"{run['maps'][k]:.4f}" for k in ("normal", "diffuse", "roughness", "specular")),
                         str(run["peak_mb"])])
            best_other[method] = run["heldout"]
        if "ladder" in best_other:
            for other in ("256 upsampled", "pixel", "pixel, to the budget", "one level"):
                if other in best_other:
                    rows.append(["", f"ladder / {other}", "", "", "", "", f"{best_other['ladder'] / best_other[other]:.3f}",
                                 "", "", "", "", ""])
    lines += ["## At the photos' size, against the 256^2 fit upsampled and the per-pixel fit", "",
              markdown_table(["capture", "method", "budget s", "fit s", "steps", "stopped", "held-out",
                              "normal", "diffuse", "roughness", "specular", "peak MB"], rows), ""]
    if results.get("scaling"):
        srows = [[f"{s}^2", f"{r['budget_s']:g}", f"{r['fit_s']:g}", str(r["steps"]), r["stop"], r.get("ladder") or "",
                  f"{r['heldout']:.4f}", str(r["peak_mb"])] for s, r in sorted(results["scaling"].items(),
                                                                                key=lambda kv: int(kv[0]))]
        lines += ["## The default fit at each size", "",
                  markdown_table(["size", "budget s", "fit s", "steps", "stopped", "ladder", "held-out", "peak MB"],
                                 srows), ""]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
