"""Benchmark: the online capture simulator against one training step, measured in the same run.

Generator: ``CaptureSimulator`` batches of B = 8 at 256^2 with N drawn in 1..5 (defaults:
preset ``multiview``, procedural materials from the sliding pool, mixing, rotation/scale/crop,
flash + ambient light, noise and the 8-bit pipeline), timed after warm-up batches (kernel
compilation, the pool filling up: steady state, as in a long training); prints samples/s and
the time split (materials, capture draws, rendering, photo pipeline).

The machine may be shared: generator batches and training steps are interleaved (2 batches,
then one step of each precision, per round) so both see the same load, and process CPU
seconds are printed beside wall seconds.

Training step: forward + backward + Adam step of a compact U-Net (width 32, 3x3 convs,
~10 M parameters; :class:`CompactUNet` below is a *reference workload* only — the real
networks are in ``mi_svbrdf.nets``) on a batch of 8 single inputs at 256^2, in float32 and under bf16
autocast. The ratio step time / generator batch time is printed for both; target:
the generator >= 2x faster than the (faster) step.

Usage:
    python benchmarks/bench_generator.py [--rounds 4] [--warmup 8] [--size 256] [--batch 8] [--pool-size P]
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import torch
from torch import nn


class _Block(nn.Sequential):
    """``convs`` x (3x3 conv, GroupNorm(8), LeakyReLU(0.2))."""

    def __init__(self, cin: int, cout: int, convs: int = 2) -> None:
        layers: list[nn.Module] = []
        for i in range(convs):
            layers += [nn.Conv2d(cin if i == 0 else cout, cout, 3, padding=1), nn.GroupNorm(8, cout),
                       nn.LeakyReLU(0.2, inplace=True)]
        super().__init__(*layers)


class CompactUNet(nn.Module):
    """Reference workload: a U-Net of width 32 (32..512 channels, 5 levels, 3x3 convs), ~10 M parameters.

    ``(B, 3, H, W)`` photo -> ``(B, 9, H, W)`` maps (normal xy | diffuse | specular | roughness),
    H and W multiples of 16.
    """

    def __init__(self, in_channels: int = 3, out_channels: int = 9, width: int = 32, levels: int = 5) -> None:
        super().__init__()
        widths = [width * 2**i for i in range(levels)]
        self.down = nn.ModuleList([_Block(in_channels, widths[0])] +
                                  [_Block(widths[i - 1], widths[i], 3 if i == levels - 1 else 2)
                                   for i in range(1, levels)])
        self.up = nn.ModuleList([_Block(widths[i + 1] + widths[i], widths[i]) for i in reversed(range(levels - 1))])
        self.head = nn.Conv2d(widths[0], out_channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else nn.functional.max_pool2d(x, 2))
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = nn.functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return torch.tanh(self.head(x))


class Trainer:
    """One training step of :class:`CompactUNet` (forward, L1 loss, backward, Adam) on fixed data."""

    def __init__(self, batch: int, size: int, bf16: bool) -> None:
        torch.manual_seed(0)
        self.model = CompactUNet()
        self.opt = torch.optim.Adam(self.model.parameters(), lr=1e-4)
        gen = torch.Generator().manual_seed(0)
        self.x = torch.rand(batch, 3, size, size, generator=gen)
        self.y = torch.rand(batch, 9, size, size, generator=gen) * 2 - 1
        self.bf16 = bf16

    def step(self) -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=self.bf16):
            loss = (self.model(self.x).float() - self.y).abs().mean()
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()


def timed(fn: Callable[[], Any]) -> tuple[float, float, Any]:
    """(wall seconds, process CPU seconds, result) of ``fn()``."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - w, time.process_time() - c, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=4,
                        help="rounds of (2 simulator batches, 1 float32 step, 1 bf16 step), interleaved")
    parser.add_argument("--warmup", type=int, default=8, help="untimed simulator batches first (pool fill-up)")
    parser.add_argument("--size", type=int, default=256, help="resolution")
    parser.add_argument("--batch", type=int, default=8, help="batch size of both")
    parser.add_argument("--pool-size", type=int, default=None,
                        help="simulator material pool size (default: SimulatorConfig's; 0: every material fresh)")
    args = parser.parse_args()

    import mi_svbrdf  # noqa: F401  (variant, plugins)
    from mi_svbrdf.data.simulator import CaptureSimulator

    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    pool = {} if args.pool_size is None else {"pool_size": args.pool_size}
    sim = CaptureSimulator(size=args.size, batch_size=args.batch, preset="multiview", seed=0, **pool)
    print(f"simulator: pool_size {sim.config.pool_size}, material size {sim.config.material_size}, "
          f"mix probability {sim.config.mix_probability}")
    for i in range(args.warmup):  # kernel compilation, allocator, the material pool filling up
        sim.batch(i)
    trainers = {"float32": Trainer(args.batch, args.size, False), "bf16 autocast": Trainer(args.batch, args.size, True)}
    for trainer in trainers.values():
        trainer.step()  # warm-up
    gen_wall, gen_cpu, images, split = [], [], [], {}
    step_wall: dict[str, list[float]] = {k: [] for k in trainers}
    step_cpu: dict[str, list[float]] = {k: [] for k in trainers}
    index = args.warmup
    for _ in range(args.rounds):  # interleaved, so that both sides see the same machine load
        for _ in range(2):
            wall, cpu, out = timed(lambda: sim.batch(index))
            index += 1
            gen_wall.append(wall)
            gen_cpu.append(cpu)
            images.append(out.captures.n_images)
            for key, value in out.seconds.items():
                split.setdefault(key, []).append(value)
        for name, trainer in trainers.items():
            wall, cpu, _ = timed(trainer.step)
            step_wall[name].append(wall)
            step_cpu[name].append(cpu)

    med = statistics.median
    g_wall, g_cpu = med(gen_wall), med(gen_cpu)
    params = sum(p.numel() for p in trainers["float32"].model.parameters())
    print(f"generator: {g_wall:.3f} s wall, {g_cpu:.3f} CPU s per batch of {args.batch} at {args.size}^2 "
          f"(median of {len(gen_wall)} after {args.warmup} warm-up batches; mean N = {statistics.mean(images):.1f} "
          f"photos/sample) = {args.batch / g_wall:.1f} samples/s")
    print("  split (median wall s): " + ", ".join(f"{k} {med(v):.3f}" for k, v in split.items()))
    for name in trainers:
        print(f"U-Net step ({params / 1e6:.1f} M parameters, {name}): {med(step_wall[name]):.3f} s wall, "
              f"{med(step_cpu[name]):.3f} CPU s (median of {args.rounds}); step / generator = "
              f"{med(step_wall[name]) / g_wall:.2f} wall, {med(step_cpu[name]) / g_cpu:.2f} CPU")
    best = min(trainers, key=lambda k: med(step_wall[k]))
    ratio = med(step_wall[best]) / g_wall
    print(f"ratio against the faster step ({best}): {ratio:.2f} (target >= 2: {'met' if ratio >= 2 else 'NOT met'})")


if __name__ == "__main__":
    main()
