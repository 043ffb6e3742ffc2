"""Benchmark: forward + backward of ``rendering_loss`` on the two backends, measured in one run.

For B = 2 and 8 at 256^2 with the 9 configurations of the loss (new random configurations
each call) it prints the median time of each backend, the ratio torch/mitsuba, the first-call
time of the mitsuba backend in a fresh process (with an empty and with a warm Dr.Jit kernel
cache), and the number of Dr.Jit kernels compiled after warm-up (expected 0: new
configurations and a new batch size reuse the kernels).

Targets: ratio >= 10 at B = 8 and >= 3 at B = 2; first call <= 1 s; no recompilation.

Usage:
    python benchmarks/bench_loss.py [--repeats 7] [--size 256]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import torch

FIRST_CALL_SNIPPET = r"""
import time, torch
import mi_svbrdf as ms
g = torch.Generator().manual_seed(0)
pred = torch.rand(8, 10, {size}, {size}, generator=g); pred[:, 2] += 0.5
target = torch.rand(8, 10, {size}, {size}, generator=g); target[:, 2] += 0.5
pred.requires_grad_()
t0 = time.perf_counter()
ms.rendering_loss(pred, target, generator=g).backward()
print(time.perf_counter() - t0)
"""


def random_pair(batch: int, size: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    import mi_svbrdf as ms

    def one() -> torch.Tensor:
        m = torch.rand(batch, 10, size, size, generator=gen)
        m[:, 2] += 0.5
        return ms.maps.normalize_normals(m)

    return one().requires_grad_(), one()


def step(backend: str, batch: int, size: int, gen: torch.Generator) -> float:
    import mi_svbrdf as ms

    pred, target = random_pair(batch, size, gen)
    t0 = time.perf_counter()
    loss = ms.rendering_loss(pred, target, generator=gen, backend=backend)
    loss.backward()
    return time.perf_counter() - t0


def first_call(size: int, cold: bool) -> float:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as home:
        if cold:
            env["HOME"] = home  # Dr.Jit keeps its kernel cache in ~/.drjit
        out = subprocess.run([sys.executable, "-c", FIRST_CALL_SNIPPET.format(size=size)], env=env,
                             capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per backend and batch size")
    parser.add_argument("--size", type=int, default=256, help="map resolution")
    args = parser.parse_args()

    import drjit as dr

    import mi_svbrdf as ms  # noqa: F401

    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; drjit {dr.__version__}")
    gen = torch.Generator().manual_seed(0)
    results = {}
    for batch in (2, 8):
        for backend in ("mitsuba", "torch"):
            step(backend, batch, args.size, gen)  # warm-up
            times = [step(backend, batch, args.size, gen) for _ in range(args.repeats)]
            results[batch, backend] = statistics.median(times)
        ratio = results[batch, "torch"] / results[batch, "mitsuba"]
        target = 10 if batch == 8 else 3
        print(f"B={batch} {args.size}^2 K=9 fwd+bwd median: mitsuba {results[batch, 'mitsuba'] * 1e3:.1f} ms, "
              f"torch {results[batch, 'torch'] * 1e3:.1f} ms, ratio torch/mitsuba {ratio:.1f} (target >= {target})")

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    for batch in (2, 8, 3, 5):  # new configurations every call, and batch sizes never seen
        step("mitsuba", batch, args.size, gen)
    hist = [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
    compiled = sum(1 for h in hist if not h["cache_hit"])
    print(f"kernels launched after warm-up: {len(hist)}, compiled: {compiled} (target 0)")

    cold = first_call(args.size, cold=True)
    warm = first_call(args.size, cold=False)
    print(f"first call (B=8, fresh process): {cold:.2f} s with an empty kernel cache, "
          f"{warm:.2f} s with a warm one (target <= 1 s)")


if __name__ == "__main__":
    main()
