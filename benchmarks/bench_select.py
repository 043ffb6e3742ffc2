"""Benchmark: does the per-capture selection (``optimize --select auto``) recover the model that made the photos?

Simulated captures whose right model is known, each photo with noise (std 0.005, linear) and 8-bit sRGB
quantisation, fitted with :func:`mi_svbrdf.optim.select.select_and_fit`:

* ``lambertian``: a procedural material with its specular set to zero -> the ``lambertian`` candidate;
* ``uniform``: a procedural material's normals and diffuse with one roughness and one grey specular ->
  ``uniform`` (a uniform-specular-and-roughness candidate);
* ``full``: a procedural material as drawn (spatially varying roughness and specular) -> a ``full*`` candidate.

The procedural class and the capture change with the seed. Prints each choice and the recovery rate per kind, the
correlation over texels between the uncertainty maps (the spread of the chosen candidate's fold fits) and the final
maps' actual error against the truth (normal angle; diffuse and roughness absolute error), and writes
``docs/benchmarks/select.md`` and ``.json``.

Usage::

    python benchmarks/bench_select.py --seeds 10
"""
from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.maps import make_maps
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.calibrated_photos import CaptureSpec, capture_from_simulator
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode
from mi_svbrdf.optim import OptimizeConfig
from mi_svbrdf.optim.select import SelectConfig, select_and_fit

ROOT = Path(__file__).resolve().parents[1]
#: The kinds of material simulated, and the candidates that count as recovering each.
KINDS: dict[str, tuple[str, ...]] = {"lambertian": ("lambertian",), "uniform": ("uniform",),
                                     "full": ("full", "full_priors", "full_slow", "full_calibrated")}
#: Procedural classes drawn in turn (seed modulo their count).
CLASSES = ("tiles", "metal", "leather", "wood", "stone")


def material(kind: str, seed: int, size: int) -> torch.Tensor:
    """``(1, 10, size, size)`` maps of ``kind`` (module docstring)."""
    gt = procedural.generate(CLASSES[seed % len(CLASSES)], seed, size)[None]
    n, d = gt[:, 0:3], gt[:, 3:6]
    g = torch.Generator().manual_seed(seed)
    if kind == "lambertian":
        return make_maps(n, d, torch.full_like(gt[:, 6:7], 0.5), torch.zeros_like(gt[:, 7:10]))
    if kind == "uniform":
        r = 0.25 + 0.35 * float(torch.rand((), generator=g))
        s = 0.08 + 0.3 * float(torch.rand((), generator=g))
        return make_maps(n, d, torch.full_like(gt[:, 6:7], r), torch.full_like(gt[:, 7:10], s))
    return gt


def simulated_capture(maps: torch.Tensor, n_photos: int, seed: int,
                      noise: float = 0.005) -> tuple[CaptureSpec, torch.Tensor, torch.Tensor]:
    """A rectified 8-bit capture of ``maps``: ``(spec, linear photos (N, 3, H, W), unclipped (N, 1, H, W))``."""
    cfg = capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=4.0)
    cap = sample_captures(1, n_photos, cfg, torch.Generator().manual_seed(1000 + seed))
    radiance = render_captures(maps, cap, backend="torch")[0]
    g = torch.Generator().manual_seed(2000 + seed)
    noisy = (radiance + noise * torch.randn(radiance.shape, generator=g)).clamp(0.0, 1.0)
    codes = torch.round(torch.from_numpy(srgb_encode(noisy.numpy())) * 255.0) / 255.0
    images = torch.from_numpy(srgb_decode(codes.numpy())).float()
    spec, images = capture_from_simulator(cap, 0, images)
    return spec, images, (codes < 1.0).all(dim=1, keepdim=True)


def errors(maps: torch.Tensor, truth: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-texel error of ``maps`` against ``truth`` ``(1, 10, H, W)``: ``{name: (H, W)}`` as the uncertainty maps."""
    cos = (M.normal(maps) * M.normal(truth)).sum(dim=1).clamp(-1.0, 1.0)
    return {"normal_deg": torch.rad2deg(torch.acos(cos))[0],
            "diffuse": (M.diffuse(maps) - M.diffuse(truth)).abs().mean(dim=1)[0],
            "roughness": (M.roughness(maps) - M.roughness(truth)).abs()[0, 0]}


def correlation(a: torch.Tensor, b: torch.Tensor) -> float:
    """Pearson correlation of two maps over their texels (NaN when one is constant)."""
    a, b = a.flatten().double(), b.flatten().double()
    a, b = a - a.mean(), b - b.mean()
    den = float(a.norm() * b.norm())
    return float((a * b).sum()) / den if den > 0 else float("nan")


def run(kind: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    truth = material(kind, seed, args.size)
    spec, images, valid = simulated_capture(truth, args.photos, seed)
    t0 = time.perf_counter()
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False, budget_s=args.budget_s),
                         settings=SelectConfig(size=args.size, steps=args.steps))
    means = {c["name"]: round(c["mean"], 5) for c in fit.selection["candidates"]}
    err = errors(fit.result.maps, truth)
    corr = {name: round(correlation(fit.uncertainty[name][0, 0], e), 3) for name, e in err.items()}
    return {"kind": kind, "seed": seed, "class": CLASSES[seed % len(CLASSES)], "choice": fit.choice,
            "recovered": fit.choice in KINDS[kind], "seconds": time.perf_counter() - t0, "means": means,
            "uncertainty_error_correlation": corr}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=10, help="captures per kind (default 10)")
    p.add_argument("--size", type=int, default=64, help="texels per side (default 64)")
    p.add_argument("--photos", type=int, default=7, help="photos per capture (default 7)")
    p.add_argument("--steps", type=int, default=SelectConfig.steps,
                   help=f"steps of each fold fit (default {SelectConfig.steps}, the selection's)")
    p.add_argument("--budget-s", type=float, default=60.0, help="budget of each selection (default 60)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "select.md", help="the page written")
    args = p.parse_args(argv)
    rows = []
    for kind in KINDS:
        for seed in range(args.seeds):
            row = run(kind, seed, args)
            rows.append(row)
            print(f"{kind:<10} seed {seed} ({row['class']:<7}): chose {row['choice']:<16} "
                  f"{'ok' if row['recovered'] else 'MISSED'}  ({row['seconds']:.1f} s; uncertainty-error "
                  f"correlation {row['uncertainty_error_correlation']})", flush=True)
    lines = ["# Model selection on simulated captures", "",
             "Generated by `python benchmarks/bench_select.py " + " ".join(sys.argv[1:]) + "` "
             f"({platform.machine()}, {torch.get_num_threads()} threads). {args.photos} photos of {args.size}² "
             f"texels, noise 0.005 and 8-bit sRGB; fold fits of {args.steps} steps.", "",
             "| material | recovered | choices |", "|---|---|---|"]
    for kind, ok in KINDS.items():
        mine = [r for r in rows if r["kind"] == kind]
        counts: dict[str, int] = {}
        for r in mine:
            counts[r["choice"]] = counts.get(r["choice"], 0) + 1
        lines.append(f"| {kind} (right: {', '.join(ok)}) | {sum(r['recovered'] for r in mine)} / {len(mine)} | "
                     + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + " |")
    lines += ["", "Correlation over texels between the uncertainty map and the final maps' actual error (mean over the "
              "captures where the chosen model fits that map per texel; NaN where the map was uniform):", "",
              "| map | mean correlation | captures |", "|---|---|---|"]
    for name in ("normal_deg", "diffuse", "roughness"):
        vals = [r["uncertainty_error_correlation"][name] for r in rows
                if r["uncertainty_error_correlation"][name] == r["uncertainty_error_correlation"][name]]
        mean = sum(vals) / len(vals) if vals else float("nan")
        lines.append(f"| {name} | {mean:.3f} | {len(vals)} |")
    write_text(args.out, "\n".join(lines) + "\n")
    write_json(args.out.with_suffix(".json"), rows)
    print("\n".join(lines[-13:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
