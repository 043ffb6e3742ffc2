"""Benchmark: the optimiser and the rendering loss on a shared CPU, alone and beside busy processes, in one run.

A user's machine is rarely idle: a browser, a build or a CI job runs beside ``mi-svbrdf optimize``.
This benchmark measures, in one run and one process:

* ``optimize``: seconds per step of :func:`mi_svbrdf.optim.optimize` on the bundled example capture
  (``mi-svbrdf optimize --capture example``: six 128^2 photos, the default fit), a fixed number of
  steps (no early stop);
* ``loss``: forward + backward of :func:`mi_svbrdf.rendering_loss` (B = 2, 256^2, the default
  backend), the median of ``--repeats`` calls;

each alone, then beside 1 and 2 busy processes (``python -c "while True: pass"``, started before and
killed after each measurement), and the ratio of each to its time alone. With a fair share of the CPU,
K busy processes beside a job that wants all C cores make it about ``(C + K) / C`` times slower (2x
beside 2 busy processes on 2 cores); thread pools that spin or wait on each other make it far slower.

Target: beside 2 busy processes, each at most 4x its time alone.

It imports mi_svbrdf before torch, as an ``mi-svbrdf`` command does (:mod:`mi_svbrdf.threads`: OpenMP's
waiting threads sleep), and prints the thread settings it ran with (PyTorch's intra-op threads, Dr.Jit's
pool, how OpenMP waits): run it with ``OMP_WAIT_POLICY=ACTIVE`` or ``OMP_NUM_THREADS=1`` set to compare
settings, and under ``flock`` so that no other benchmark shares the CPU (the busy processes are the
only load wanted).

Usage:
    python benchmarks/bench_contention.py [--steps 60] [--repeats 9] [--busy 0,1,2] [--out FILE.md]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import mi_svbrdf  # noqa: F401  first, as in an ``mi-svbrdf`` command: OpenMP's wait policy is set before torch loads
import torch

#: The busy process: one core's worth of work that never sleeps.
BUSY = "while True: pass"
#: Seconds the busy processes run before a measurement starts (they are scheduled by then).
SETTLE_S = 0.5
#: Largest ratio to the time alone beside 2 busy processes (the target).
TARGET_RATIO = 4.0


def busy_processes(count: int) -> list[subprocess.Popen]:
    """Start ``count`` busy processes (each keeps one core busy); stop them with :func:`stop`."""
    procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(count)]
    if procs:
        time.sleep(SETTLE_S)
    return procs


def stop(procs: list[subprocess.Popen]) -> None:
    """Stop the processes of :func:`busy_processes`, each by its own handle."""
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


def optimiser_workload(steps: int) -> Callable[[], float]:
    """Seconds per step of the default fit of the bundled example capture, ``steps`` steps (no early stop)."""
    from mi_svbrdf.assets import EXAMPLE_CAPTURE
    from mi_svbrdf.io.calibrated_photos import load_capture
    from mi_svbrdf.optim import method_config, optimize

    spec, images, valid = load_capture(EXAMPLE_CAPTURE)
    cfg = method_config("default", iterations=steps, tol=0.0, progress=False)

    def run() -> float:
        result = optimize(spec, images, valid, config=cfg)
        return result.seconds / max(result.steps, 1)
    return run


def loss_workload(repeats: int, size: int = 256, batch: int = 2) -> Callable[[], float]:
    """Median seconds of forward + backward of the rendering loss (B = ``batch``, ``size``^2), ``repeats`` calls."""
    import mi_svbrdf as ms

    gen = torch.Generator().manual_seed(0)

    def maps() -> torch.Tensor:
        m = torch.rand(batch, 10, size, size, generator=gen)
        m[:, 2] += 0.5
        return ms.maps.normalize_normals(m)

    def run() -> float:
        times = []
        for _ in range(repeats):
            pred, target = maps().requires_grad_(), maps()
            t0 = time.perf_counter()
            ms.rendering_loss(pred, target, generator=gen).backward()
            times.append(time.perf_counter() - t0)
        return statistics.median(times)
    return run


def thread_settings() -> str:
    """PyTorch's and Dr.Jit's thread counts and how OpenMP's threads wait."""
    import drjit as dr

    try:
        from mi_svbrdf.threads import wait_policy
        policy = wait_policy()
    except ImportError:  # a tree before mi_svbrdf.threads: the environment's settings only
        policy = ", ".join(f"{k}={v}" for k, v in os.environ.items() if k.startswith(("OMP_", "GOMP_"))) or \
            "OpenMP's default active wait"
    return (f"{os.cpu_count()} CPUs ({len(os.sched_getaffinity(0))} usable); torch intra-op threads "
            f"{torch.get_num_threads()}, inter-op {torch.get_num_interop_threads()}; Dr.Jit pool {dr.thread_count()}; "
            f"{policy}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=60, help="optimiser steps per measurement (default 60)")
    parser.add_argument("--repeats", type=int, default=9, help="loss calls per measurement (default 9)")
    parser.add_argument("--busy", default="0,1,2", help="busy-process counts, comma-separated (default 0,1,2)")
    parser.add_argument("--out", type=Path, default=None, help="also write the table to this Markdown file")
    args = parser.parse_args(argv)
    counts = [int(c) for c in args.busy.split(",")]
    if counts[0] != 0:
        counts = [0, *counts]

    workloads = {"optimize (s/step)": optimiser_workload(args.steps), "loss (s/call)": loss_workload(args.repeats)}
    for run in workloads.values():  # compile the kernels first: every measurement below reuses them
        run()
    settings = thread_settings()
    print(settings, flush=True)
    times: dict[str, dict[int, float]] = {name: {} for name in workloads}
    for count in counts:
        procs = busy_processes(count)
        try:
            for name, run in workloads.items():
                times[name][count] = run()
                print(f"{name} beside {count} busy: {times[name][count]:.4f}", flush=True)
        finally:
            stop(procs)
    head = "| workload | " + " | ".join(f"{c} busy" for c in counts) + " | " + \
        " | ".join(f"ratio {c} busy" for c in counts if c) + " |"
    lines = [head, "|" + "---|" * (1 + 2 * len(counts) - 1)]
    met = True
    for name, by_count in times.items():
        ratios = {c: by_count[c] / by_count[0] for c in counts if c}
        met &= all(r <= TARGET_RATIO for c, r in ratios.items() if c == 2)
        lines.append(f"| {name} | " + " | ".join(f"{by_count[c]:.4f}" for c in counts) + " | " +
                     " | ".join(f"{r:.2f}x" for r in ratios.values()) + " |")
    verdict = (f"target (beside 2 busy processes at most {TARGET_RATIO:g}x the time alone): "
               f"{'MET' if met else 'NOT MET'}" if 2 in counts
               else "target not judged (no run beside 2 busy processes)")
    text = "\n".join([f"Thread settings: {settings}", "", *lines, "", verdict])
    print(text)
    if args.out is not None:
        from mi_svbrdf.io.atomic import write_text

        write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
