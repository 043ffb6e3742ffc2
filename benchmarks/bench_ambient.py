"""Benchmark: the ambient renderer (``render_environment``) on a 512^2 tile with L = 64 lights.

Each backend runs in a fresh process (so its peak memory is its own): after a warm-up call
(kernel compilation), it prints the median time of a forward pass and of a forward + backward
pass (gradients to the maps), and the peak resident memory above the process's level before
the first rendering.

Targets: ``"mitsuba"`` forward + backward <= 2 s and <= 200 MB above the baseline (the lights are
summed inside the kernels: memory O(H*W), not O(L*H*W)); ``"torch"`` (the reference) within ~1 GB.

Usage:
    python benchmarks/bench_ambient.py [--size 512] [--lights 64] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time


def worker(backend: str, size: int, lights: int, repeats: int) -> dict:
    """Time one backend in this process; returns seconds and the peak RSS increase in MB."""
    import torch

    torch.set_num_threads(1)
    from mi_svbrdf.core.ambient import render_environment, sample_environment

    g = torch.Generator().manual_seed(0)
    maps = torch.rand(1, 10, size, size, generator=g)
    maps[:, 2] += 0.5
    maps[:, 0:3] = maps[:, 0:3] / maps[:, 0:3].norm(dim=1, keepdim=True)
    env = sample_environment(1, lights, generator=g)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    m = maps.clone().requires_grad_()
    render_environment(m, env, backend=backend).sum().backward()  # warm-up (compilation)
    forward, both = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        with torch.no_grad():
            render_environment(maps, env, backend=backend)
        forward.append(time.perf_counter() - t0)
        m = maps.clone().requires_grad_()
        t0 = time.perf_counter()
        render_environment(m, env, backend=backend).sum().backward()
        both.append(time.perf_counter() - t0)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"backend": backend, "forward_s": statistics.median(forward), "forward_backward_s": statistics.median(both),
            "peak_mb_above_base": peak - base}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--lights", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", choices=["mitsuba", "torch"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        from mi_svbrdf.io.atomic import dumps_json  # strict JSON, as every JSON the project writes
        print(dumps_json(worker(args.worker, args.size, args.lights, args.repeats), indent=None))
        return
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
    print(f"render_environment, {args.size}^2, L = {args.lights}, B = 1, one torch thread")
    for backend in ("mitsuba", "torch"):
        out = subprocess.run([sys.executable, __file__, "--worker", backend, "--size", str(args.size),
                              "--lights", str(args.lights), "--repeats", str(args.repeats)],
                             capture_output=True, text=True, env=env, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"  {backend:8s} forward {r['forward_s']:.2f} s   forward+backward {r['forward_backward_s']:.2f} s   "
              f"peak +{r['peak_mb_above_base']:.0f} MB")


if __name__ == "__main__":
    main()
