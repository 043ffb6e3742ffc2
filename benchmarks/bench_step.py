"""Benchmark: the time of one step of a fit, by map size, texel backend and PyTorch's thread count.

A fit's step renders every photo from the current maps, takes the loss's gradient and moves the maps (Adam). On
the texel path the rendering and the loss's gradient are either one fused Dr.Jit kernel (backend ``mitsuba``, with
its own thread pool) or PyTorch autograd through the texel renderer (backend ``torch``); PyTorch's own ops (the
map parameterisation, priors, Adam) run on its intra-op pool either way. For each map size (the selection's fold
fits run at 64² or 128², a final fit at 256²), each backend and each PyTorch thread count (1, and the cores), it
times ``--steps`` steps of the default recipe and of ``--method pixel`` on a realistic simulated capture (7 photos
of the tune split's material 13, :mod:`mi_svbrdf.data.realistic`), without a time budget, a convergence stop or an
early stop, and prints the median of ``--repeats`` runs in milliseconds per step, with each row's ratio to the
fused kernel at the machine's thread count (the default) measured in the same run.

With ``--baseline PATH`` (a checkout of another commit, e.g. a ``git worktree``) each fused cell is measured
again on that tree's :mod:`mi_svbrdf` right after this tree's: this script runs itself in a subprocess that
imports the package from ``PATH`` (``PYTHONPATH``) and times that one cell, so the two trees take turns on the
machine cell by cell (on a shared machine both see the same load); the page then shows both and their ratio.

Writes ``docs/benchmarks/step.md`` and ``.json`` (``--out``).

Usage::

    python benchmarks/bench_step.py                       # 8² to 256², about 4 min on 2 cores
    python benchmarks/bench_step.py --sizes 256 --steps 300
    python benchmarks/bench_step.py --sizes 32,128,256 --baseline /tmp/base   # beside a worktree of another commit
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import mi_svbrdf  # noqa: F401  (first: it sets how OpenMP's threads wait before torch loads)
import torch

from mi_svbrdf.data.realistic import RealisticSet
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.optim import method_config, optimize
from mi_svbrdf.threads import cpu_count

ROOT = Path(__file__).resolve().parents[1]
#: The tune split's material the capture shows (a wood, spatially varying roughness), and its photos.
MATERIAL, PHOTOS = 13, 7


def step_ms(spec: Any, images: torch.Tensor, valid: torch.Tensor, method: str, backend: str, steps: int,
            repeats: int) -> tuple[float, float]:
    """Median milliseconds per step of ``repeats`` fits of ``steps`` steps (the first, warming the kernels, not
    counted): wall time, and the process's CPU time (all its threads; on a machine shared with other work the
    wall time also counts the waits for a core)."""
    times, cpu = [], []
    for _ in range(repeats + 1):
        cfg = method_config(method, budget_s=1e9, iterations=steps, progress=False, early_stop="off", tol=0.0,
                            backend=backend)
        t0, c0 = time.perf_counter(), time.process_time()
        res = optimize(spec, images, valid, config=cfg)
        times.append((time.perf_counter() - t0) / max(res.steps, 1) * 1e3)
        cpu.append((time.process_time() - c0) / max(res.steps, 1) * 1e3)
    return statistics.median(times[1:]), statistics.median(cpu[1:])


def measure(size: int, steps: int, repeats: int, autograd_max: int, threads: list[int],
            methods: tuple[str, ...] = ("default", "pixel"), baseline: Path | None = None) -> list[dict[str, Any]]:
    """The rows of one map size: every recipe, PyTorch thread count and backend (autograd up to ``autograd_max``);
    with ``baseline``, each fused cell then timed on that tree too (:func:`baseline_cell`, the row's ``baseline``)."""
    rows: list[dict[str, Any]] = []
    cap = RealisticSet(split="tune", size=size, materials=(MATERIAL,), n_images=(PHOTOS,),
                       realism="clean").capture(MATERIAL, PHOTOS)
    label = _revision(baseline) if baseline is not None else ""
    for method in methods:
        cells: dict[tuple[str, int], tuple[float, float]] = {}
        other: dict[int, tuple[float, float]] = {}
        for n in threads:
            torch.set_num_threads(n)
            for backend in ("mitsuba", "torch") if size <= autograd_max else ("mitsuba",):
                cells[(backend, n)] = step_ms(cap.stated, cap.images, cap.valid, method, backend, steps, repeats)
                if backend == "mitsuba" and baseline is not None:
                    other[n] = baseline_cell(baseline, size, method, n, steps, repeats)
        torch.set_num_threads(threads[-1])
        base = cells[("mitsuba", threads[-1])][0]
        for (backend, n), (ms, cpu_ms) in cells.items():
            row = {"size": size, "method": method, "backend": backend, "torch_threads": n, "ms": ms,
                   "cpu_ms": cpu_ms, "ratio": ms / base}
            if backend == "mitsuba" and n in other:
                row["baseline"] = {"commit": label, "ms": other[n][0], "cpu_ms": other[n][1]}
            rows.append(row)
    return rows


def baseline_cell(path: Path, size: int, method: str, threads: int, steps: int, repeats: int) -> tuple[float, float]:
    """One fused cell (wall and CPU ms per step) measured on the tree at ``path``: this script in a subprocess
    importing :mod:`mi_svbrdf` from there."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        env = dict(os.environ, PYTHONPATH=str(path))
        subprocess.run([sys.executable, str(Path(__file__).resolve()), "--sizes", str(size), "--steps", str(steps),
                        "--repeats", str(repeats), "--autograd-max", "0", "--cell", f"{method},{threads}",
                        "--rows-json", str(out)], env=env, check=True)
        (row,) = json.loads(out.read_text())
        return row["ms"], row["cpu_ms"]


def _revision(path: Path) -> str:
    """The short commit of the checkout at ``path`` (its folder name where git cannot tell)."""
    try:
        return subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return path.name


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=lambda v: [int(s) for s in v.split(",")], default=[8, 32, 64, 128, 256],
                   help="map sizes (default 8,32,64,128,256)")
    p.add_argument("--steps", type=int, default=150, help="steps of each timed fit (default 150)")
    p.add_argument("--autograd-max", type=int, default=128,
                   help="largest size at which the autograd backend is timed too (default 128: at 256² it takes "
                        "about 0.3 s a step)")
    p.add_argument("--repeats", type=int, default=3, help="timed fits per cell, the median kept (default 3)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "step.md", help="the page written")
    p.add_argument("--baseline", type=Path, default=None,
                   help="a checkout of another commit: its fused cells measured in the same run, size by size")
    p.add_argument("--rows-json", type=Path, default=None, help=argparse.SUPPRESS)  # the baseline's subprocess
    p.add_argument("--cell", default=None, help=argparse.SUPPRESS)  # its one cell: "method,threads"
    args = p.parse_args(argv)
    if args.steps < 1 or args.repeats < 1 or min(args.sizes) < 4:
        p.error(f"--steps, --repeats: expected >= 1, --sizes >= 4; got {args.steps}, {args.repeats}, {args.sizes}")
    cores = cpu_count()
    load = "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())
    threads = sorted({1, torch.get_num_threads()})
    rows: list[dict[str, Any]] = []
    if args.rows_json is not None:  # the baseline's subprocess: the rows (of one cell) only
        method, n = args.cell.split(",") if args.cell else ("", "")
        for size in args.sizes:
            rows += measure(size, args.steps, args.repeats, args.autograd_max, [int(n)] if n else threads,
                            (method,) if method else ("default", "pixel"))
        write_json(args.rows_json, rows)
        return 0
    base_label = _revision(args.baseline) if args.baseline is not None else ""
    for size in args.sizes:
        new = measure(size, args.steps, args.repeats, args.autograd_max, threads, baseline=args.baseline)
        for r in new:
            b = r.get("baseline")
            print(f"{size:>4}² {r['method']:<8} {r['backend']:<8} torch threads {r['torch_threads']}: "
                  f"{r['ms']:7.2f} ms/step, CPU {r['cpu_ms']:7.2f} ms ({r['ratio']:.2f}x the fused kernel at "
                  f"{threads[-1]} threads)" + (f"; {base_label}: {b['ms']:7.2f} ms/step, CPU {b['cpu_ms']:7.2f} ms"
                                                if b is not None else ""), flush=True)
        rows += new
    load_after = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    command = shlex.join(["python", "benchmarks/bench_step.py", *(sys.argv[1:] if argv is None else argv)])
    lines = ["# The time of a fit's step", "",
             f"Written by `{command}` ({platform.machine()}, {cores} cores, torch "
             f"{torch.__version__}): {PHOTOS} photos of a simulated capture, {args.steps} steps per fit, the median "
             f"of {args.repeats} fits (after one that warms the kernels), no time budget or stop; a fit's time "
             "includes its setup (bounds, the multi-start's scoring). `fused`: the "
             "texel backend `mitsuba` (the loss and its gradient in one Dr.Jit kernel, `auto`'s choice); `torch`: "
             "PyTorch autograd through the texel renderer. Ratio: to the fused kernel with PyTorch's default thread "
             "count, in the same run. CPU: the process's CPU time per step, all its threads (on a shared machine the "
             "wall time also counts the waits for a core; `uptime` before the run: "
             f"{load}; after: {load_after}).", ""]
    if args.baseline is not None:
        lines += [f"`{base_label}`: the same fused cell measured on that commit's tree in the same run, right after "
                  "this tree's (this script in a subprocess importing its `mi_svbrdf`: the two trees take turns cell "
                  "by cell); CPU speed-up: its CPU ms per step over this tree's.", ""]
    head = "| size | recipe | backend | PyTorch threads | ms per step | CPU ms per step | ratio |"
    rule = "|---|---|---|---|---|---|---|"
    if args.baseline is not None:
        head += f" {base_label} ms per step | {base_label} CPU ms per step | CPU speed-up |"
        rule += "---|---|---|"
    lines += [head, rule]
    for r in rows:
        line = (f"| {r['size']}² | {r['method']} | {'fused' if r['backend'] == 'mitsuba' else 'torch'} | "
                f"{r['torch_threads']} | {r['ms']:.2f} | {r['cpu_ms']:.2f} | {r['ratio']:.2f} |")
        if args.baseline is not None:
            b = r.get("baseline")
            line += (f" {b['ms']:.2f} | {b['cpu_ms']:.2f} | {b['cpu_ms'] / r['cpu_ms']:.2f}x |" if b is not None
                     else " | | |")
        lines.append(line)
    write_json(args.out.with_suffix(".json"), rows)
    write_text(args.out, "\n".join(lines) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
