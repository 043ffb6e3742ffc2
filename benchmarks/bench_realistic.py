"""Benchmark: the calibrated optimiser on realistic captures (stated calibration wrong as a real one is).

The captures are :class:`mi_svbrdf.data.realistic.RealisticSet`'s: held-out materials photographed
with per-photo exposure and white balance, a flash beside the lens, poses off by up to 3 %,
vignetting, an unmodelled light, JPEG and clipping, while the capture file states what a user
would have. Each capture has a *clean twin* (the same material and true cameras, stated exactly).
Defaults are tuned on the ``tune`` split and reported on the ``test`` split (``--split``).

For every capture (material x N) and realism (``real``, ``clean``) it fits, each for the same
wall-time budget (``--budget-s``):

* ``defaults``: :func:`mi_svbrdf.optim.optimize` with its default settings (self-calibration
  ``"auto"``: on from ``calibrate_min_images`` photos);
* ``calibrated``: the same with self-calibration on at every N (``calibrate="on"``);
* ``true_calibration``: the defaults fed the true calibration, self-calibration off (real captures
  only: the fit's floor when the calibration is right; vignetting and the unmodelled light are
  still unknown);
* ``true_devignetted`` (on request): the same on photos divided by their true vignetting (what
  modelling vignetting could gain at most);
* ``adam``: the reference baseline, a plain per-pixel Adam (lr 0.02, L2 on gamma-encoded photos,
  no priors, the trivial start) given the whole budget;
* ``best_lr_x10`` (``--reference``): the best of lr in {0.01, 0.03, 0.1} with 10x the steps
  ``defaults`` took, a cosine schedule over them and no early stop.

A method may carry settings for tuning: ``defaults+lr=0.03+window_fraction=0.25`` fits with those
:class:`~mi_svbrdf.optim.OptimizeConfig` fields changed (a separate row and table column).

and records the held-out error (display RMSE of the maps re-rendered under 8 held-out lights and
views against the truth: :meth:`RealisticCapture.heldout_error`), the per-map RMSE, steps, seconds,
stop reason, and, for calibrated fits, the recovered flash offset and gains against the injected ones.

Outputs (``--out``, default ``/tmp/bench_realistic``): ``rows.csv`` (one row per fit, appended as it
goes; a re-run skips the fits already there), ``summary.md`` (the tables) and ``heldout.png``.

Usage:
    python benchmarks/bench_realistic.py [--split test] [--size 256] [--n 3,5,10] [--materials 4]
        [--budget-s 60] [--methods defaults,calibrated,true_calibration,adam] [--reference]
        [--realism real,clean] [--quick] [--out /tmp/bench_realistic]
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import time
from pathlib import Path
from typing import Any

import torch

METHODS = ("defaults", "calibrated", "true_calibration", "adam")
REFERENCE_LRS = (0.01, 0.03, 0.1)
FIELDS = ["split", "realism", "material", "cls", "n", "size", "method", "lr", "seconds", "steps", "stop_reason",
          "heldout", "rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "flash_true_mm",
          "flash_est_mm", "flash_rel_error", "gain_max_rel_error", "calibration"]


def _settings(method: str) -> tuple[str, dict[str, Any]]:
    """``"defaults+lr=0.03+window_fraction=0.25"`` -> ("defaults", {"lr": 0.03, ...}): a method with
    OptimizeConfig overrides (values parsed as JSON where they parse, else strings), for tuning."""
    base, *pairs = method.split("+")
    kw: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            kw[key] = json.loads(value)
        except json.JSONDecodeError:
            kw[key] = value
    return base, kw


def adam_baseline(spec: Any, images: torch.Tensor, seconds: float, lr: float = 0.02) -> tuple[torch.Tensor, int]:
    """The reference baseline: per-pixel Adam on the maps' variables, L2 between gamma-encoded
    (clipped) re-renderings and photos, no priors, from the trivial start, for ``seconds``."""
    from mi_svbrdf.core.colour import gamma_encode
    from mi_svbrdf.optim import initial_maps
    from mi_svbrdf.optim.forward import TexelForward
    from mi_svbrdf.optim.params import from_maps, to_maps

    fwd = TexelForward(spec, tuple(images.shape[-2:]))
    floor = 1e-4  # gamma encoding's slope is infinite at 0: clamp both sides just above it
    target = gamma_encode(images.clamp(floor, 1.0))
    x = from_maps(initial_maps(spec, images)).requires_grad_(True)
    opt = torch.optim.Adam([x], lr=lr)
    start, steps = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        opt.zero_grad(set_to_none=True)
        loss = (gamma_encode(fwd(to_maps(x)).clamp(floor, 1.0)) - target).square().mean()
        loss.backward()
        opt.step()
        steps += 1
    return to_maps(x.detach()), steps


def _calibration_errors(cap: Any, cal: dict[str, Any] | None) -> dict[str, Any]:
    """Recovered flash offset (mm) and gains against the injected ones."""
    if not cal or cap.realism != "real":
        return {}
    from mi_svbrdf.data.realistic import MM_PER_UNIT

    out: dict[str, Any] = {"calibration": json.dumps(cal)}
    true_flash = torch.tensor(cap.errors["flash_offset_units"][:2], dtype=torch.float64)
    out["flash_true_mm"] = float(true_flash.norm()) * MM_PER_UNIT
    if cal.get("flash_offset") is not None:
        est = torch.tensor(cal["flash_offset"], dtype=torch.float64)
        out["flash_est_mm"] = float(est.norm()) * MM_PER_UNIT
        out["flash_rel_error"] = float((est - true_flash).norm() / true_flash.norm())
    gains = torch.tensor(cap.errors["gains"], dtype=torch.float64)
    out["gain_max_rel_error"] = float((torch.tensor(cal["gain"], dtype=torch.float64) / gains - 1).abs().max())
    return out


def fit_row(cap: Any, method: str, budget_s: float, defaults_row: dict[str, Any] | None,
            lr: float | None = None) -> dict[str, Any]:
    """One fit of ``cap`` by ``method``: its CSV row."""
    from mi_svbrdf.optim import OptimizeConfig, optimize

    t0 = time.perf_counter()
    cal, steps, stop = None, 0, ""
    if method == "adam":
        maps, steps = adam_baseline(cap.stated, cap.images, budget_s)
        stop = "time"
    else:
        base, overrides = _settings(method)
        kw: dict[str, Any] = {"budget_s": budget_s, "progress": False, **overrides}
        spec, images = cap.stated, cap.images
        if base == "calibrated":
            kw["calibrate"] = "on"
        elif base == "true_calibration":
            spec, kw["calibrate"] = cap.true, "off"
        elif base == "true_devignetted":
            spec, images, kw["calibrate"] = cap.true, (cap.images / cap.vignetting()).float(), "off"
        elif base == "best_lr_x10":
            steps10 = 10 * int(defaults_row["steps"])
            kw = {"lr": lr, "iterations": steps10, "schedule_steps": steps10, "tol": 0.0, "budget_s": math.inf,
                  "progress": False}
        res = optimize(spec, images, cap.valid, config=OptimizeConfig(**kw))
        maps, steps, stop, cal = res.maps, res.steps, res.stop_reason, res.calibration
    row = {"split": cap.split, "realism": cap.realism, "material": cap.material, "cls": cap.cls, "n": cap.n_images,
           "size": cap.images.shape[-1], "method": method, "lr": lr if lr is not None else "",
           "seconds": round(time.perf_counter() - t0, 3), "steps": steps, "stop_reason": stop,
           "heldout": cap.heldout_error(maps), **{f"rmse_{k}": v for k, v in cap.map_errors(maps).items()},
           **_calibration_errors(cap, cal)}
    return row


def _key(row: dict[str, Any]) -> tuple:
    return (row["split"], row["realism"], int(row["material"]), int(row["n"]), int(row["size"]), row["method"],
            str(row.get("lr", "")))


def read_rows(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    with path.open() as f:
        return list(csv.DictReader(f))


def append_row(path: Path, row: dict[str, Any]) -> None:
    new = not path.is_file()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, "") for k in FIELDS})
        f.flush()


def summary(rows: list[dict[str, Any]]) -> str:
    """Markdown tables: held-out error per capture and method; calibration recovery."""
    from mi_svbrdf.io.tables import markdown_table

    methods = list(dict.fromkeys(r["method"] for r in rows))
    caps = sorted({(r["realism"], int(r["material"]), r["cls"], int(r["n"])) for r in rows})
    table = []
    for realism, m, cls, n in caps:
        line = [realism, f"{m} {cls}", str(n)]
        for method in methods:
            vals = [float(r["heldout"]) for r in rows if r["realism"] == realism and int(r["material"]) == m
                    and int(r["n"]) == n and r["method"] == method]
            line.append(f"{min(vals):.4f}" if vals else "")
        table.append(line)
    out = ["## Held-out display RMSE (lower is better; best_lr_x10: the best of its learning rates)", "",
           markdown_table(["realism", "material", "N", *methods], table), ""]
    cal = [r for r in rows if r["realism"] == "real" and r.get("gain_max_rel_error")]
    if cal:
        out += ["## Self-calibration recovery (real captures)", "",
                markdown_table(["method", "material", "N", "flash true mm", "flash est mm", "flash rel. error", "gain max rel. error"],
                               [[r["method"], f"{r['material']} {r['cls']}", r["n"], f"{float(r['flash_true_mm']):.1f}",
                                 f"{float(r['flash_est_mm']):.1f}" if r.get("flash_est_mm") else "",
                                 f"{float(r['flash_rel_error']):.2f}" if r.get("flash_rel_error") else "",
                                 f"{float(r['gain_max_rel_error']):.3f}"] for r in cal]), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--split", choices=("tune", "test"), default="test")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--n", default="3,5,10", help="photo counts")
    p.add_argument("--materials", type=int, default=None, help="materials of the split (default 4; --quick: 2)")
    p.add_argument("--budget-s", type=float, default=60.0)
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--realism", default="real,clean")
    p.add_argument("--reference", action="store_true", help="also best_lr_x10 (10x the steps: slow)")
    p.add_argument("--quick", action="store_true", help="128^2, N = 3 and 10, 2 materials, 15 s budgets")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", default="/tmp/bench_realistic")
    args = p.parse_args(argv)
    if args.quick:
        args.size, args.n, args.budget_s = 128, "3,10", 15.0
    args.materials = args.materials or (2 if args.quick else 4)
    torch.set_num_threads(args.threads)
    from mi_svbrdf.data.realistic import RealisticSet

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"outputs in {out}")
    csv_path = out / "rows.csv"
    rows = read_rows(csv_path)
    ns = tuple(int(v) for v in args.n.split(","))
    methods = [m for m in args.methods.split(",") if m]
    for realism in args.realism.split(","):
        dataset = RealisticSet(split=args.split, size=args.size, materials=args.materials, n_images=ns,
                               realism=realism)
        for cap in dataset.captures():
            defaults_row = None
            for method in methods + (["best_lr_x10"] if args.reference else []):
                if method.startswith("true_") and realism != "real":
                    continue
                for lr in (REFERENCE_LRS if method == "best_lr_x10" else (None,)):
                    probe = {"split": args.split, "realism": realism, "material": cap.material, "n": cap.n_images,
                             "size": args.size, "method": method, "lr": lr if lr is not None else ""}
                    existing = [r for r in rows if _key(r) == _key(probe)]
                    if method == "best_lr_x10" and defaults_row is None:
                        defaults_row = next((r for r in rows if _key(r) == _key({**probe, "method": "defaults",
                                                                                   "lr": ""})), None)
                        if defaults_row is None:
                            continue
                    if existing:
                        row = existing[0]
                    else:
                        row = fit_row(cap, method, args.budget_s, defaults_row, lr)
                        append_row(csv_path, row)
                        rows.append({k: str(v) for k, v in row.items()})
                        print(f"{realism:5s} {cap.material} {cap.cls:8s} N={cap.n_images:2d} {method:16s} "
                              f"{'' if lr is None else f'lr={lr:g} '}held-out {float(row['heldout']):.4f} "
                              f"steps {row['steps']} {row['stop_reason']} {float(row['seconds']):.1f} s", flush=True)
                    if method == "defaults":
                        defaults_row = row
    text = summary(rows)
    (out / "summary.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
