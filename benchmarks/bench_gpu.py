"""Benchmark: the figures GPU users ask for, on a CUDA device, beside the same run's CPU figures where they make sense.

* the rendering loss (forward + backward, 256^2, K = 9) at B = 8, 32, 128: the fused Dr.Jit kernels against torch
  eager on the device, and the fused loss on the CPU at B = 8;
* the per-call floor: the loss at B = 1, 16^2 (no arithmetic to speak of), forward and forward + backward;
* training: steps/s of ``full-single`` (batch 8, 256^2) and ``full-multi`` (batch 2, 1-5 photos) with the recipes'
  mixed precision, and where a step's time goes (simulator, forward, loss, backward, optimiser step; the device
  synchronised between phases);
* the optimiser: the bundled example capture with the defaults, a 256^2 fit of 10 photos (fixed steps) on the
  device and on the CPU, and a 1024^2 fit of 10 photos on the device.

It writes ``docs/benchmarks/gpu.md`` (device, driver, versions, every table) and takes about 6 minutes on one recent
GPU. Where no CUDA device exists it refuses with one line. ``--device cpu`` runs the same measurements on the CPU at
small sizes (a check of the script, written to ``--out``, never to ``docs/``).

Usage:
    python benchmarks/bench_gpu.py [--out docs/benchmarks/gpu.md]
    python benchmarks/bench_gpu.py --device cpu --out /tmp/gpu_dry.md    # the script on the CPU, small sizes
"""
from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "benchmarks" / "gpu.md"


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def median_ms(fn: Callable[[], None], device: torch.device, repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` in ms (the device synchronised around each call)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        fn()
        sync(device)
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def random_pair(batch: int, size: int, device: torch.device, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    from mi_svbrdf.core.maps import normalize_normals

    gen = torch.Generator().manual_seed(seed)

    def one() -> torch.Tensor:
        m = torch.rand(batch, 10, size, size, generator=gen)
        m[:, 2] += 0.5
        return normalize_normals(m).to(device)

    return one(), one()


def loss_call(batch: int, size: int, device: torch.device, backend: str, backward: bool) -> Callable[[], None]:
    """A loss call on fixed maps with new configurations every call."""
    import mi_svbrdf as ms

    pred, target = random_pair(batch, size, device)
    gen = torch.Generator().manual_seed(1)

    def call() -> None:
        p = pred.clone().requires_grad_(backward)
        loss = ms.rendering_loss(p, target, generator=gen, backend=backend)
        if backward:
            loss.backward()
        else:
            float(loss)

    return call


def loss_table(device: torch.device, batches: tuple[int, ...], size: int, repeats: int) -> tuple[list, list]:
    """Rows ``B | fused on device | torch eager on device | ratio | fused on the CPU`` (CPU at the smallest B)."""
    rows = []
    cpu = torch.device("cpu")
    for b in batches:
        fused = median_ms(loss_call(b, size, device, "mitsuba", True), device, repeats)
        eager = median_ms(loss_call(b, size, device, "torch", True), device, max(3, repeats // 2))
        on_cpu = (f"{median_ms(loss_call(b, size, cpu, 'mitsuba', True), cpu, 3):.1f}"
                  if b == batches[0] and device.type == "cuda" else "")
        rows.append([b, f"{fused:.2f}", f"{eager:.2f}", f"{eager / fused:.1f}x", on_cpu])
        print(f"loss B={b} {size}^2: fused {fused:.2f} ms, torch eager {eager:.2f} ms", flush=True)
    floor = []
    for label, backward in (("forward", False), ("forward + backward", True)):
        here = median_ms(loss_call(1, 16, device, "mitsuba", backward), device, repeats * 3)
        there = (median_ms(loss_call(1, 16, cpu, "mitsuba", backward), cpu, repeats * 3)
                 if device.type == "cuda" else None)
        floor.append([label, f"{here:.3f}", "" if there is None else f"{there:.3f}"])
        print(f"per-call floor (B=1, 16^2) {label}: {here:.3f} ms", flush=True)
    return rows, floor


def training(device: torch.device, recipe: str, steps: int, size: int | None) -> dict[str, Any]:
    """Steps/s of ``recipe`` on ``device`` and the mean ms of each phase of a step (after 3 warm-up steps)."""
    from mi_svbrdf.nets import train as T

    overrides: dict[str, Any] = {"device": str(device), "validate_every": 0}
    if size is not None:
        overrides["sizes"] = [[0, size]]
    cfg = T.load_config(recipe, overrides)
    scaler = T.grad_scaler(cfg, device)
    net, opt, _, _, _ = T._start(cfg, None, device, scaler)
    sim = T.make_simulator(cfg, cfg.size_at(0), device)  # the simulator on the training device
    totals: dict[str, float] = {}
    counted = 0
    t_start = None
    for step in range(steps + 3):
        if step == 3:
            sync(device)
            t_start = time.perf_counter()
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        batch = sim.batch(step)
        times["simulator"] = time.perf_counter() - t0
        T._train_step(cfg, net, net, opt, batch, step, step, Path("/dev/null"), device, scaler, times)
        if step >= 3:
            counted += 1
            for k, v in times.items():
                totals[k] = totals.get(k, 0.0) + v
    sync(device)
    elapsed = time.perf_counter() - t_start
    phases = {k: 1e3 * v / counted for k, v in totals.items()}
    out = {"recipe": recipe, "batch": cfg.batch_size, "size": cfg.size_at(0), "steps_per_s": counted / elapsed,
           **phases}
    print(f"train {recipe} on {device}: {out['steps_per_s']:.2f} steps/s; "
          + ", ".join(f"{k} {v:.1f} ms" for k, v in phases.items()), flush=True)
    return out


def optimiser(device: torch.device, sizes: tuple[int, ...], iterations: int) -> list[list[Any]]:
    """Rows ``fit | device | seconds | steps | held-out map RMSE``."""
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_optimize import capture, map_rmse, material

    from mi_svbrdf.assets import EXAMPLE_CAPTURE
    from mi_svbrdf.io.calibrated_photos import load_capture
    from mi_svbrdf.optim import OptimizeConfig, optimize

    rows = []
    spec, images, valid = load_capture(EXAMPLE_CAPTURE)
    for dev in dict.fromkeys([device, torch.device("cpu")]):
        t0 = time.perf_counter()
        res = optimize(spec, images, valid, config=OptimizeConfig(device=str(dev), progress=False))
        rows.append(["example capture, defaults", str(dev), f"{time.perf_counter() - t0:.1f}", res.steps, ""])
        print(f"optimize example on {dev}: {rows[-1][2]} s, {res.steps} steps", flush=True)
    for size in sizes:
        gt = material("tiles", size)
        spec, images = capture(gt, 10, seed=0)
        devices = [device] + ([torch.device("cpu")] if size <= 256 else [])
        for dev in dict.fromkeys(devices):
            cfg = OptimizeConfig(device=str(dev), iterations=iterations, budget_s=float("inf"), progress=False,
                                 roughness_starts=(0.5,), validate_photo=False)
            t0 = time.perf_counter()
            res = optimize(spec, images, config=cfg)
            seconds = time.perf_counter() - t0
            rmse = map_rmse(res.maps.cpu(), gt)
            rows.append([f"{size}^2, 10 photos, {iterations} steps", str(dev), f"{seconds:.1f}", res.steps,
                         " / ".join(f"{v:.4f}" for v in rmse.values())])
            print(f"optimize {size}^2 N=10 on {dev}: {seconds:.1f} s", flush=True)
    return rows


def environment(device: torch.device) -> list[str]:
    import drjit
    import mitsuba

    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu"
    lines = [f"- device: {name}",
             f"- torch {torch.__version__} (CUDA {torch.version.cuda}), Mitsuba {mitsuba.__version__}, "
             f"Dr.Jit {drjit.__version__}, Python {platform.python_version()}"]
    if device.type == "cuda":
        try:
            driver = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                    capture_output=True, text=True, timeout=10, check=False).stdout.strip()
        except OSError:
            driver = "unknown (no nvidia-smi)"
        lines.append(f"- driver: {driver}; CPU side: {torch.get_num_threads()} torch threads")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda", help="cuda (default), cuda:N, or cpu for a small dry run")
    parser.add_argument("--out", default=None, help=f"the page (default {PAGE.relative_to(ROOT)}; --device cpu: "
                                                    "required, never docs/)")
    parser.add_argument("--repeats", type=int, default=15, help="timed calls per loss figure")
    args = parser.parse_args(argv)
    device = torch.device(args.device)
    dry = device.type == "cpu"
    if not dry and not torch.cuda.is_available():
        print("bench_gpu: expected a CUDA device (torch.cuda.is_available() is False); nothing measured. "
              "Run it on a GPU machine, or with --device cpu --out FILE for a dry run.", file=sys.stderr)
        return 2
    if dry and (args.out is None or Path(args.out).resolve().is_relative_to(ROOT / "docs")):
        print("bench_gpu: --device cpu is a dry run: give --out outside docs/", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else PAGE
    import mi_svbrdf  # noqa: F401

    t0 = time.perf_counter()
    batches, size = ((1, 2), 64) if dry else ((8, 32, 128), 256)
    loss_rows, floor_rows = loss_table(device, batches, size, 5 if dry else args.repeats)
    recipes = (("single", None), ("multi", None)) if dry else (("full-single", None), ("full-multi", None))
    train_rows = [training(device, r, 3 if dry else 40, s) for r, s in recipes]
    opt_rows = optimiser(device, (64,) if dry else (256, 1024), 30 if dry else 300)
    minutes = (time.perf_counter() - t0) / 60

    from mi_svbrdf.io.atomic import write_text
    from mi_svbrdf.io.tables import markdown_table

    phases = ("simulator", "forward", "loss", "backward", "optimiser")
    text = "\n".join([
        "# GPU benchmark" + (" (dry run on the CPU, small sizes)" if dry else ""), "",
        f"Written by `python benchmarks/bench_gpu.py` in {minutes:.1f} min.", "", *environment(device), "",
        f"## The rendering loss, forward + backward, {size}², K = 9 (ms, median)", "",
        markdown_table(["B", f"fused Dr.Jit on {device}", f"torch eager on {device}", "ratio", "fused on the CPU"],
                       loss_rows), "",
        "## The per-call floor: the loss at B = 1, 16² (ms, median)", "",
        markdown_table(["call", str(device), "CPU (same run)"], floor_rows), "",
        "## Training: steps/s and where a step's time goes (mean ms per step)", "",
        markdown_table(["recipe", "batch", "size", "steps/s", *phases],
                       [[r["recipe"], r["batch"], r["size"], f"{r['steps_per_s']:.2f}",
                         *(f"{r.get(k, 0.0):.1f}" for k in phases)] for r in train_rows]), "",
        "## The optimiser", "",
        markdown_table(["fit", "device", "seconds", "steps", "map RMSE n / d / r / s"], opt_rows), ""])
    write_text(out, text)
    print(f"bench_gpu: wrote {out} ({minutes:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
