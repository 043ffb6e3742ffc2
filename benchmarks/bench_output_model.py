"""Benchmark: another output BRDF model (thesis ch. 6.1.1, issue 17 §3) -- GGX -> Beckmann next to GGX -> GGX.

On the held-out benchmark (:mod:`mi_svbrdf.data.heldout`: GGX ground truth, multiview photos), the
optimiser fits each material twice at equal iterations, with GGX output maps and with Beckmann
output maps (:func:`mi_svbrdf.eval.studies.output_model.compare_optimizer`), and each fit is scored with
its own model under the fixed novel evaluation lights (re-rendering RMSE), plus the maps' RMSE
(roughness also after the equal-width conversion: the raw roughness is not comparable across
models). ``--net LABEL=SPEC`` (repeatable) scores networks the same way
(:func:`~mi_svbrdf.eval.studies.output_model.compare_nets`), SPEC ``bundled:single`` or a ``checkpoint.pt`` of
``mi-svbrdf train`` (its ``distribution`` is the output model), e.g. after the ``single-beckmann`` recipe::

    python benchmarks/bench_output_model.py --no-optimizer --net "single ggx=bundled:single" \\
        --net "single beckmann=$HOME/.cache/mi_svbrdf/runs/single_beckmann/checkpoint.pt"

Outputs (``--out``, default ``/tmp/bench_output_model``): ``output_model.json`` (rows, means, settings),
``output_model.md`` (the tables) and ``output_model.png`` (``output_model_nets.png`` for the nets: bars per
material, and one material under one novel light: truth, each output with its own model, the last
non-GGX output rendered as GGX).

Usage:
    python benchmarks/bench_output_model.py [--materials 4] [--size 128] [--n 3] [--iterations 400]
        [--threads 1] [--no-optimizer] [--net LABEL=SPEC ...] [--out /tmp/bench_output_model]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and write its files; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--materials", type=int, default=4, help="held-out materials (default 4)")
    parser.add_argument("--size", type=int, default=128, help="resolution (default 128)")
    parser.add_argument("--n", type=int, default=3, help="photos per material (default 3)")
    parser.add_argument("--iterations", type=int, default=400, help="optimiser steps per fit (default 400)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--no-optimizer", action="store_true", help="only the nets")
    parser.add_argument("--net", action="append", default=[], metavar="LABEL=SPEC",
                        help="a net to score: bundled:KIND or a training checkpoint.pt (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_output_model"), help="output folder")
    args = parser.parse_args(argv)
    nets = {}
    for item in args.net:
        label, sep, spec = item.partition("=")
        if not sep or not label or not spec:
            parser.error(f"--net: expected LABEL=SPEC, got {item!r}")
        nets[label] = spec
    if args.no_optimizer and not nets:
        parser.error("--no-optimizer: expected at least one --net")
    torch.set_num_threads(args.threads)

    from mi_svbrdf.eval.studies import output_model as om
    from mi_svbrdf.io.atomic import write_json, write_text

    print(f"bench_output_model: writing output_model.json, .md and .png to {args.out} (--out)")
    args.out.mkdir(parents=True, exist_ok=True)
    cfg = om.OutputModelConfig(materials=args.materials, size=args.size, n_images=args.n,
                               iterations=args.iterations, progress=True)
    parts, t0 = [], time.perf_counter()
    if not args.no_optimizer:
        parts.append(("optimiser", om.compare_optimizer(cfg)))
    if nets:
        parts.append(("networks", om.compare_nets(nets, cfg)))
    report, text = {}, []
    for name, comparison in parts:
        table = om.output_model_table(comparison)
        print(f"{name}: {comparison.settings}\n{table}")
        report[name] = {"settings": comparison.settings, "means": comparison.summary(), "rows": comparison.rows}
        text += [f"## {name}", "", f"settings: `{json.dumps(comparison.settings)}`", "", table, ""]
        om.plot_comparison(comparison, args.out / ("output_model.png" if name == "optimiser" else
                                                   "output_model_nets.png"))
    report["seconds"] = round(time.perf_counter() - t0, 1)
    write_json(args.out / "output_model.json", report)
    write_text(args.out / "output_model.md", "\n".join(text))
    print(f"done in {report['seconds']} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
