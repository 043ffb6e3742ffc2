"""Benchmark: forward + backward of ``rendering_loss`` on the two backends, measured in one run.

For B = 2 and 8 at 256^2 with the 9 configurations of the loss (new random configurations
each call) it prints the median time of each backend, the ratio torch/mitsuba, the per-call
floor (B = 1 at 16^2, where the arithmetic is nothing and a call costs its overhead: the two
backends interleaved, call by call, so that a busy machine slows both alike), the first-call
time of the mitsuba backend in a fresh process (with an empty and with a warm Dr.Jit kernel
cache), and the number of Dr.Jit kernels compiled after warm-up (expected 0: new
configurations and a new batch size reuse the kernels). Writes ``docs/benchmarks/loss.md``
(``--out``).

Targets: ratio >= 10 at B = 8 and >= 3 at B = 2; the floor's ratio >= 3; first call <= 1 s; no recompilation.

With ``--baseline PATH`` (a checkout of another commit, e.g. a ``git worktree``) the same calls are timed again on
that tree's :mod:`mi_svbrdf` in the same run (this script in a subprocess importing the package from ``PATH``,
after this tree's), and the page shows both.

Usage:
    python benchmarks/bench_loss.py [--repeats 7] [--size 256] [--floor-only] [--baseline PATH]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mi_svbrdf  # noqa: F401  (first: it sets how OpenMP's threads wait before torch loads)
import torch

ROOT = Path(__file__).resolve().parents[1]

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


def floor(repeats: int, gen: torch.Generator) -> tuple[float, float]:
    """Median ms of a B = 1, 16^2 call (forward + backward) of each backend, the two interleaved call by call on the
    same maps (new configurations every call)."""
    import mi_svbrdf as ms

    pred, target = random_pair(1, 16, gen)
    times: dict[str, list[float]] = {"mitsuba": [], "torch": []}
    for i in range(repeats + 10):
        for backend in times:
            p = pred.detach().clone().requires_grad_()
            t0 = time.perf_counter()
            ms.rendering_loss(p, target, generator=gen, backend=backend).backward()
            if i >= 10:  # the first calls warm up
                times[backend].append(time.perf_counter() - t0)
    return statistics.median(times["mitsuba"]) * 1e3, statistics.median(times["torch"]) * 1e3


def first_call(size: int, cold: bool) -> float:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as home:
        if cold:
            env["HOME"] = home  # Dr.Jit keeps its kernel cache in ~/.drjit
        out = subprocess.run([sys.executable, "-c", FIRST_CALL_SNIPPET.format(size=size)], env=env,
                             capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def baseline_rows(path: Path, args: argparse.Namespace) -> list[list]:
    """The rows measured on the tree at ``path``: this script in a subprocess importing :mod:`mi_svbrdf` from
    there."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--repeats", str(args.repeats), "--size", str(args.size),
               "--floor-repeats", str(args.floor_repeats), "--rows-json", str(out)]
        subprocess.run(cmd + (["--floor-only"] if args.floor_only else []), env=dict(os.environ, PYTHONPATH=str(path)),
                       check=True)
        return json.loads(out.read_text())


def _revision(path: Path) -> str:
    """The short commit of the checkout at ``path`` (its folder name where git cannot tell)."""
    try:
        return subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return path.name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per backend and batch size")
    parser.add_argument("--size", type=int, default=256, help="map resolution")
    parser.add_argument("--floor-repeats", type=int, default=200, help="timed calls per backend of the floor")
    parser.add_argument("--floor-only", action="store_true", help="only the per-call floor (B = 1, 16^2)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks" / "loss.md", help="the page written")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="a checkout of another commit: the same calls timed on its tree in the same run")
    parser.add_argument("--rows-json", type=Path, default=None, help=argparse.SUPPRESS)  # the baseline's subprocess
    args = parser.parse_args()

    import drjit as dr

    import mi_svbrdf as ms  # noqa: F401

    head = f"torch {torch.__version__}, {torch.get_num_threads()} threads; drjit {dr.__version__}"
    print(head)
    gen = torch.Generator().manual_seed(0)
    rows = []
    if not args.floor_only:
        for batch in (2, 8):
            results = {}
            for backend in ("mitsuba", "torch"):
                step(backend, batch, args.size, gen)  # warm-up
                times = [step(backend, batch, args.size, gen) for _ in range(args.repeats)]
                results[backend] = statistics.median(times) * 1e3
            ratio = results["torch"] / results["mitsuba"]
            target = 10 if batch == 8 else 3
            rows.append((f"B = {batch}, {args.size}²", results["mitsuba"], results["torch"], ratio, target))
            print(f"B={batch} {args.size}^2 K=9 fwd+bwd median: mitsuba {results['mitsuba']:.1f} ms, "
                  f"torch {results['torch']:.1f} ms, ratio torch/mitsuba {ratio:.1f} (target >= {target})")
    fused, eager = floor(args.floor_repeats, gen)
    rows.append(("B = 1, 16² (the per-call floor)", fused, eager, eager / fused, 3))
    print(f"per-call floor B=1 16^2 K=9 fwd+bwd median: mitsuba {fused:.3f} ms, torch {eager:.3f} ms, "
          f"ratio torch/mitsuba {eager / fused:.1f} (target >= 3)")
    if args.rows_json is not None:  # the baseline's subprocess: the rows only
        args.rows_json.write_text(json.dumps(rows, allow_nan=False))
        return
    base = baseline_rows(args.baseline, args) if args.baseline is not None else None
    label = _revision(args.baseline) if args.baseline is not None else ""
    notes = []
    if not args.floor_only:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clear
        for batch in (2, 8, 3, 5):  # new configurations every call, and batch sizes never seen
            step("mitsuba", batch, args.size, gen)
        hist = [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
        compiled = sum(1 for h in hist if not h["cache_hit"])
        notes.append(f"kernels launched after warm-up: {len(hist)}, compiled: {compiled} (target 0)")
        cold = first_call(args.size, cold=True)
        warm = first_call(args.size, cold=False)
        notes.append(f"first call (B=8, fresh process): {cold:.2f} s with an empty kernel cache, "
                     f"{warm:.2f} s with a warm one (target <= 1 s)")
        for n in notes:
            print(n)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    command = " ".join(["python", "benchmarks/bench_loss.py", *sys.argv[1:]])
    lines = ["# The rendering loss: the fused kernel against PyTorch eager", "",
             f"Written by `{command}` ({platform.machine()}, {os.cpu_count()} cores, {head}): "
             "forward + backward of `rendering_loss` with its 9 configurations (new random configurations every "
             "call), the median time of each backend and their ratio, measured in one run. The floor (B = 1, 16²) "
             f"interleaves the two backends call by call. Load average at the end of the run: {load}.", ""]
    if base is not None:
        lines += [f"`{label}`: the same calls timed on that commit's tree in the same run (this script in a "
                  "subprocess importing its `mi_svbrdf`, after this tree's calls), each ratio within its own "
                  "process.", "",
                  f"| call | fused (ms) | torch eager (ms) | ratio | {label} fused (ms) | {label} torch eager (ms) | "
                  f"{label} ratio | target |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {name} | {a:.3f} | {b:.3f} | {r:.1f}x | {ba:.3f} | {bb:.3f} | {br:.1f}x | ≥ {t}x |"
                  for (name, a, b, r, t), (_, ba, bb, br, _) in zip(rows, base)]
    else:
        lines += ["| call | fused (ms) | torch eager (ms) | ratio | target |", "|---|---|---|---|---|"]
        lines += [f"| {name} | {a:.3f} | {b:.3f} | {r:.1f}x | ≥ {t}x |" for name, a, b, r, t in rows]
    if notes:
        lines += [""] + [f"- {n}" for n in notes]
    from mi_svbrdf.io.atomic import write_text

    write_text(args.out, "\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
