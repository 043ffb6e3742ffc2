"""Benchmark: the symmetry ensemble of the bundled flash nets (:mod:`mi_svbrdf.nets.ensemble`) -- accuracy and cost.

Each bundled flash net (single, multi) is scored on the fixed held-out set (:mod:`mi_svbrdf.data.heldout`,
drawn like training) and on the foreign captures (:mod:`mi_svbrdf.data.foreign`, nothing drawn like
training), alone and as an ensemble of k of the 8 flips and rotations (:func:`mi_svbrdf.eval.accuracy.
held_out_accuracy` with ``symmetries``): per-map RMSE and re-rendering RMSE, as ratios to the net alone in
the same run, judged against :data:`TARGETS` for each k. The cost: the network's wall time on one capture at the
net's resolution (single: 1 photo, multi: 10 photos), median of ``--repeats``, as a ratio to the net alone.

Outputs (``--out``, default ``/tmp/bench_ensemble``): ``ensemble.json`` (every table, the timings, the
settings), ``ensemble.md`` and ``ensemble.png`` (re-rendering RMSE against k, per net and set; the
multi net at N = 1 and 10).

Usage:
    python benchmarks/bench_ensemble.py [--materials 16] [--size 256] [--symmetries 1,8] [--threads 1]
        [--repeats 5] [--no-timing | --timing-only] [--out /tmp/bench_ensemble]
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import torch

#: The generalisation targets the bundled nets were trained towards: held-out re-rendering RMSE of the
#: single-image net and of the multi-image net at N = 10, and how far below N = 1 the foreign set's N = 10 must be.
TARGETS = {"max_single_render": 0.085, "max_multi_render": 0.075, "min_foreign_gain": 0.10}


def _counts(text: str) -> tuple[int, ...]:
    try:
        counts = tuple(sorted({int(v) for v in text.split(",")}))
    except ValueError:
        counts = ()
    if not counts or counts[0] != 1 or counts[-1] > 8:
        raise argparse.ArgumentTypeError(f"expected comma-separated ints in [1, 8] including 1, got {text!r}")
    return counts


def _network_seconds(net: torch.nn.Module, photos: torch.Tensor, k: int, repeats: int) -> float:
    from mi_svbrdf.nets.ensemble import symmetry_ensemble

    times = []
    with torch.inference_mode():
        symmetry_ensemble(net, photos, k)  # warm-up
        for _ in range(repeats):
            t0 = time.perf_counter()
            symmetry_ensemble(net, photos, k)
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _plot(results: dict[str, Any], counts: tuple[int, ...], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mi_svbrdf.eval.accuracy import row_name
    from mi_svbrdf.io.atomic import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=False)
    for ax, set_name in zip(axes, ("held-out", "foreign")):
        for kind, res in results.items():
            keys = ["single"] if kind == "single" else ["N=1", "N=10"]
            for key in keys:
                table = res[set_name]
                ys = [table[row_name(key, k)]["rmse_render"] for k in counts]
                label = f"{kind} net" + ("" if kind == "single" else f" {key}")
                line, = ax.plot(counts, ys, marker="o", label=label)
                ax.axhline(table[f"baseline {key}"]["rmse_render"], color=line.get_color(), ls=":", lw=0.8)
        ax.set_title(f"{set_name} set (dotted: trivial baseline)")
        ax.set_xlabel("symmetries averaged")
        ax.set_xticks(counts)
        ax.set_ylabel("re-rendering RMSE")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write its files; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--materials", type=int, default=16, help="materials per set (default 16)")
    parser.add_argument("--size", type=int, default=256, help="resolution (default 256)")
    parser.add_argument("--symmetries", type=_counts, default=(1, 8),
                        help="ensemble sizes, comma-separated, including 1 (default 1,8)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--repeats", type=int, default=5, help="timed network calls per size (default 5)")
    parser.add_argument("--no-timing", action="store_true",
                        help="skip the network timings (the accuracy does not depend on the machine's load)")
    parser.add_argument("--timing-only", action="store_true", help="only the network timings (no held-out sets)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_ensemble"), help="output folder")
    args = parser.parse_args(argv)
    if args.no_timing and args.timing_only:
        parser.error("--no-timing, --timing-only: expected at most one of them, got both")
    for name in ("materials", "size", "threads", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}: expected an int >= 1, got {getattr(args, name)}")
    torch.set_num_threads(args.threads)

    from mi_svbrdf.eval.accuracy import (
        accuracy_table,
        foreign_accuracy,
        generalisation_targets,
        held_out_accuracy,
        row_name,
    )
    from mi_svbrdf.io.atomic import dumps_json, write_json, write_text
    from mi_svbrdf.nets.inference import PHOTO_KINDS
    from mi_svbrdf.nets.weights import available, load_network

    counts = args.symmetries
    print(f"bench_ensemble: writing ensemble.json, .md and .png to {args.out} (--out)")
    results: dict[str, Any] = {}
    md = [(f"# Symmetry ensemble of the bundled flash nets ({args.materials} materials at {args.size}^2, "
          f"{args.threads} thread(s))"), ""]
    for kind in [k for k in available() if k in PHOTO_KINDS]:
        net = load_network(kind).eval()
        res: dict[str, Any] = {}
        for set_name, fn in () if args.timing_only else (("held-out", held_out_accuracy), ("foreign", foreign_accuracy)):
            t0 = time.perf_counter()
            table = fn(net, materials=args.materials, size=args.size, symmetries=counts, progress=False)
            res[set_name] = table
            print(f"{kind} net, {set_name} set ({time.perf_counter() - t0:.0f} s):")
            print(accuracy_table(table))
            md += [f"## {kind} net, {set_name} set", "", accuracy_table(table), ""]
            keys = ["single"] if kind == "single" else [k for k in table if k.startswith("N=") and "," not in k]
            ratios = {row_name(key, k): {m: round(table[row_name(key, k)][m] / table[key][m], 4)
                                         for m in table[key] if m.startswith("rmse_")}
                      for key in keys for k in counts if k > 1}
            res[f"{set_name} ratios"] = ratios
            for name, r in ratios.items():
                line = f"  {name} / net alone: " + ", ".join(f"{m[5:]} {v:.3f}" for m, v in r.items())
                print(line)
                md.append(f"- {line.strip()}")
            md.append("")
        if not args.timing_only:
            res["targets"] = {str(k): generalisation_targets(res["held-out"], res["foreign"], symmetries=k,
                                                             **TARGETS)
                              for k in counts}
            print(f"{kind} net, generalisation targets:", dumps_json(res["targets"], indent=1))
            md += [f"## {kind} net, generalisation targets", "", "```", dumps_json(res["targets"], indent=1), "```", ""]
        results[kind] = res
        if args.no_timing:
            continue
        n = 1 if kind == "single" else 10
        photos = torch.rand(1, n, 3, net.config.resolution, net.config.resolution)
        seconds = {k: _network_seconds(net, photos, k, args.repeats) for k in counts}
        res["network_seconds"] = {str(k): round(v, 4) for k, v in seconds.items()}
        cost = ", ".join(f"k={k} {v:.3f} s (x{v / seconds[1]:.2f})" for k, v in seconds.items())
        print(f"{kind} net, network time on {n} photo(s) at {net.config.resolution}^2: {cost}")
        md += [f"{kind} net, network time on {n} photo(s) at {net.config.resolution}^2: {cost}", ""]
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "ensemble.json", {"settings": {k: (list(v) if isinstance(v, tuple) else
                                                             str(v) if isinstance(v, Path) else v)
                                                         for k, v in vars(args).items()}, "results": results})
    write_text(args.out / "ensemble.md", "\n".join(md))
    if not args.timing_only:
        _plot(results, counts, args.out / "ensemble.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
