"""``python -m mi_svbrdf.cli.bundle CHECKPOINT``: measure a training run's held-out accuracy and bundle its weights."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import torch
from torch import nn

from mi_svbrdf.eval.accuracy import (
    accuracy_table,
    foreign_accuracy,
    generalisation_targets,
    held_out_accuracy,
)
from mi_svbrdf.eval.studies.large_scale import (
    LargeBenchConfig,
    large_scale_benchmark,
    large_scale_table,
    training_data_config,
    write_large_scale_report,
)
from mi_svbrdf.io.atomic import dumps_json, write_json
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES
from mi_svbrdf.nets.network import build_network, config_from_dict
from mi_svbrdf.nets.train import load_state
from mi_svbrdf.nets.weights import MANIFEST, MAX_BYTES, WEIGHTS_DIR, export_weights, load_network, read_manifest

#: The flash nets are measured alone and as the symmetry ensemble that predict / capture / evaluate run.
MEASURED_SYMMETRIES = (1, DEFAULT_SYMMETRIES)

DESCRIPTION = """\
Measure the held-out accuracy of a training checkpoint (its weights rounded to fp16, as they
will be bundled) and bundle it. Prints the accuracy table (with the thesis's figures).

Files written to --out, by default the package's mi_svbrdf/weights/ (none with --dry-run):
  KIND[_compact].pt.zz                the fp16 state dict, zlib-compressed (_compact: that preset)
  KIND[_compact]_curve.png            the training curve (when the checkpoint has a log)
  manifest.json                       the entry of KIND (replacing an earlier one): architecture,
                                      training recipe, steps and hours, SHA-256, machine,
                                      validation log, the held-out accuracy and the foreign-capture
                                      accuracy (mi_svbrdf.data.foreign), each of the net alone and of
                                      its symmetry ensemble of 8 (mi_svbrdf.nets.ensemble: what
                                      predict, capture and evaluate run)
The compressed weights must stay under 20 MB (refused otherwise).

The large-scale net (kind "large"): its held-out accuracy is the held-out large-scale benchmark
(mi_svbrdf.eval.studies.large_scale: --materials surfaces, default 4, of 2048^2 texels photographed whole
under held-out ambient light at --size px, default from the net's training data, 512 for the
compact preset; the net with exemplars, without, the single-image flash net on the same tiles and
the trivial baseline; map and re-rendering RMSE, seam ratio, exemplar influence). The flash-only
figures (foreign captures, generalisation targets) do not apply and are skipped. --report DIR
also writes its table, JSON and figure (large_scale.md, .json, .png)."""


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.cli.bundle CHECKPOINT [--materials 16] [--size 256] [--dry-run] [--note TEXT]``:
    measure the held-out accuracy of a training checkpoint and bundle it (fp16 + manifest)."""
    parser = argparse.ArgumentParser(prog="python -m mi_svbrdf.cli.bundle", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", help="a checkpoint.pt of mi-svbrdf train")
    parser.add_argument("--materials", type=int, default=None,
                        help="held-out materials (default 16; large: held-out surfaces, default 4)")
    parser.add_argument("--size", type=int, default=None,
                        help="held-out resolution (default 256; large: the photo side, default from the net's "
                             "training data: 512 for the compact preset)")
    parser.add_argument("--dry-run", action="store_true", help="measure and print, do not bundle")
    parser.add_argument("--no-foreign", action="store_true", help="skip the foreign-capture accuracy")
    parser.add_argument("-o", "--out", type=Path, default=WEIGHTS_DIR,
                        help="weights folder (default: the package's bundled weights, mi_svbrdf/weights/)")
    parser.add_argument("--note", default="", help="how the run went beyond its config (kept in the manifest)")
    parser.add_argument("--material-size", type=int, default=2048,
                        help="large: texels of the held-out surfaces (default 2048, the thesis's)")
    parser.add_argument("--report", type=Path, default=None,
                        help="large: write the benchmark's large_scale.md, .json and .png to this folder")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    parser.add_argument("--record-foreign", action="store_true",
                        help="CHECKPOINT is a bundled kind (single, multi): measure that bundled net on the foreign "
                             "captures and record the figures in its manifest entry (weights unchanged)")
    args = parser.parse_args(argv)
    if args.threads is not None:
        if args.threads < 1:
            parser.error(f"--threads: expected an int >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    for name in ("materials", "size", "material_size"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')}: expected an int >= 1, got {value}")
    materials, size = args.materials or 16, args.size or 256
    if args.record_foreign:
        manifest = read_manifest(args.out)
        if args.checkpoint not in manifest:
            parser.error(f"--record-foreign: expected a bundled kind among {sorted(manifest)}, got {args.checkpoint!r}")
        if args.checkpoint == "large":
            parser.error("--record-foreign: expected a flash net (single, multi), got 'large' (the foreign captures are "
                         "flash photos; the large-scale net's accuracy is the held-out large-scale benchmark)")
        net = load_network(args.checkpoint, folder=args.out)
        foreign = foreign_accuracy(net.eval(), materials=materials, size=size, symmetries=MEASURED_SYMMETRIES)
        print(accuracy_table(foreign))
        _print_targets(manifest[args.checkpoint]["accuracy"], foreign)
        if not args.dry_run:
            manifest[args.checkpoint]["foreign_accuracy"] = foreign
            write_json(args.out / MANIFEST, manifest)
        return 0
    if not Path(args.checkpoint).is_file():
        parser.error(f"CHECKPOINT: expected a checkpoint.pt of mi-svbrdf train (with --record-foreign: a bundled "
                     f"kind), got no such file {args.checkpoint!r}")
    state = load_state(args.checkpoint)
    cfg = config_from_dict(state["net_config"])
    if args.report is not None and cfg.kind != "large":
        parser.error(f"--report: expected a checkpoint of the large-scale net (kind 'large'), got kind {cfg.kind!r}")
    net = build_network(cfg)
    # measure the weights as they will be bundled: rounded to fp16
    net.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in state["model"].items()})
    foreign = None
    if cfg.kind == "large":
        accuracy = large_accuracy(net.eval(), state, surfaces=args.materials or 4, photo_size=args.size,
                                  material_size=args.material_size, report=args.report)
        print("foreign captures, generalisation targets: flash-photo figures, skipped for the large-scale net")
    else:
        accuracy = held_out_accuracy(net.eval(), materials=materials, size=size, symmetries=MEASURED_SYMMETRIES)
        print(accuracy_table(accuracy))
        if not args.no_foreign:
            foreign = foreign_accuracy(net, materials=materials, size=size, symmetries=MEASURED_SYMMETRIES)
            print("foreign captures:")
            print(accuracy_table(foreign))
        _print_targets(accuracy, foreign)
    if not args.dry_run:
        entry = export_weights(args.checkpoint, accuracy=accuracy, foreign_accuracy=foreign, folder=args.out,
                               note=args.note)
        print(f"bundled {entry['file']} ({entry['bytes'] / 1e6:.1f} MB < {MAX_BYTES / 1e6:.0f} MB, "
              f"sha256 {entry['sha256'][:12]}...)")
    return 0


def _print_targets(accuracy: dict[str, Any], foreign: dict[str, Any] | None) -> None:
    """How the net generalises, alone and as a symmetry ensemble (rows not measured are left out): the figures,
    unjudged (the thresholds are the benchmarks', ``benchmarks/bench_ensemble.py``)."""
    for s in MEASURED_SYMMETRIES:
        print(f"generalisation, {'the net alone' if s == 1 else f'{s} symmetries'}:")
        print(dumps_json(generalisation_targets(accuracy, foreign, symmetries=s), indent=1))


def large_accuracy(net: nn.Module, state: dict[str, Any], *, surfaces: int = 4, photo_size: int | None = None,
                   material_size: int = 2048, report: Path | None = None) -> dict[str, Any]:
    """The held-out large-scale benchmark of a large-scale net (:func:`mi_svbrdf.eval.studies.large_scale.large_scale_benchmark`)
    with its checkpoint's training data and output model; prints the table, writes ``report`` when given, returns
    the summary (the manifest entry's ``accuracy``)."""
    train_config = state.get("config") if isinstance(state.get("config"), dict) else {}
    train = training_data_config(net.config, train_config.get("simulator") or {})
    cfg = LargeBenchConfig(surfaces=surfaces, photo_size=photo_size, material_size=material_size)
    bench = large_scale_benchmark(net, cfg, train=train, distribution=train_config.get("distribution", "ggx"))
    print(large_scale_table(bench.summary))
    if report is not None:
        paths = write_large_scale_report(bench, report)
        print(f"wrote {', '.join(str(p) for p in paths)}")
    return bench.summary


if __name__ == "__main__":
    raise SystemExit(main())
