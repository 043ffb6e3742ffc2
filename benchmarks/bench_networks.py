"""Benchmark: network inference latency and training throughput, compact vs full preset.

Measured in the same run, on random weights (speed does not depend on them):

* inference latency at 256^2 (batch 1, ``torch.inference_mode``): the single-image net on one
  photo and the multi-image net on N = 10 photos, fp32 and bf16 autocast, for the ``compact``
  preset (targets on this CPU: single < 0.15 s, multi N = 10 < 1.5 s) and the ``full`` preset;
* training steps per second (batch 8, forward + rendering loss + backward + Adam, synthetic
  data) at 128^2 and 256^2, fp32 and bf16 autocast, both presets.

The ratio full / compact is printed for each. Median of ``--repeats`` after one warm-up.

Usage:
    python benchmarks/bench_networks.py [--repeats 5] [--train-repeats 3] [--full-train-sizes 256]
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch

from mi_svbrdf.core.loss import rendering_loss
from mi_svbrdf.core.maps import constant_maps
from mi_svbrdf.nets.network import build_network, network_config, parameter_count

TARGETS = {("compact", "single"): 0.15, ("compact", "multi"): 1.5}


def median_time(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def inference(preset: str, kind: str, bf16: bool, repeats: int) -> float:
    net = build_network(network_config(preset, kind)).eval()
    photos = torch.rand(1, 10 if kind == "multi" else 1, 3, 256, 256)

    def run() -> None:
        with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            net(photos)
    return median_time(run, repeats)


def train_step(preset: str, size: int, bf16: bool, repeats: int) -> float:
    torch.manual_seed(0)
    net = build_network(network_config(preset, "single"))
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    photos = torch.rand(8, 1, 3, size, size)
    target = constant_maps(8, size, size)
    gen = torch.Generator().manual_seed(0)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            pred = net(photos)
        loss = rendering_loss(pred.float(), target, generator=gen)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return median_time(step, repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--train-repeats", type=int, default=3)
    parser.add_argument("--full-train-sizes", default="256",
                        help="sizes at which the (slow) full-preset training step is measured (>= 256: depth 8; '': none)")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    for preset in ("compact", "full"):
        for kind in ("single", "multi"):
            print(f"{preset:8s} {kind:6s}: {parameter_count(build_network(network_config(preset, kind))) / 1e6:.1f} M parameters")
    print("\ninference latency at 256^2, batch 1 (single: 1 photo, multi: 10 photos), median:")
    lat: dict[tuple[str, str, bool], float] = {}
    for kind in ("single", "multi"):
        for bf16 in (False, True):
            for preset in ("compact", "full"):
                lat[preset, kind, bf16] = inference(preset, kind, bf16, args.repeats)
            c, f = lat["compact", kind, bf16], lat["full", kind, bf16]
            target = TARGETS["compact", kind]
            print(f"  {kind:6s} {'bf16' if bf16 else 'fp32'}: compact {c:.3f} s, full {f:.3f} s, "
                  f"ratio full/compact {f / c:.1f}; target compact < {target} s: {'met' if c < target else 'MISSED'}")
    print("\ntraining step (batch 8, single-image net, rendering loss), median s/step and steps/s:")
    for size in (128, 256):
        for bf16 in (False, True):
            c = train_step("compact", size, bf16, args.train_repeats)
            line = f"  {size}^2 {'bf16' if bf16 else 'fp32'}: compact {c:.2f} s ({1 / c:.2f} it/s)"
            if str(size) in args.full_train_sizes.split(","):
                f = train_step("full", size, bf16, args.train_repeats)
                line += f", full {f:.2f} s ({1 / f:.3f} it/s), ratio full/compact {f / c:.1f}"
            print(line)


if __name__ == "__main__":
    main()
