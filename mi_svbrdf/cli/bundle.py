"""``python -m mi_svbrdf.cli.bundle CHECKPOINT``: measure a training run's held-out accuracy and bundle its weights."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from mi_svbrdf.eval.accuracy import accuracy_table, foreign_accuracy, generalisation_targets, held_out_accuracy
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.nets.network import build_network, config_from_dict
from mi_svbrdf.nets.train import load_state
from mi_svbrdf.nets.weights import MANIFEST, WEIGHTS_DIR, export_weights, load_network, read_manifest

DESCRIPTION = """\
Measure the held-out accuracy of a training checkpoint (its weights rounded to fp16, as they
will be bundled) and bundle it. Prints the accuracy table (with the thesis's figures).

Files written to --out, by default the package's mi_svbrdf/weights/ (none with --dry-run):
  KIND[_compact].pt.zz                the fp16 state dict, zlib-compressed (_compact: that preset)
  KIND[_compact]_curve.png            the training curve (when the checkpoint has a log)
  manifest.json                       the entry of KIND (replacing an earlier one): architecture,
                                      training recipe, steps and hours, SHA-256, machine,
                                      validation log, the held-out accuracy and the foreign-capture
                                      accuracy (mi_svbrdf.data.foreign)"""


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.cli.bundle CHECKPOINT [--materials 16] [--size 256] [--dry-run] [--note TEXT]``:
    measure the held-out accuracy of a training checkpoint and bundle it (fp16 + manifest)."""
    parser = argparse.ArgumentParser(prog="python -m mi_svbrdf.cli.bundle", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", help="a checkpoint.pt of mi-svbrdf train")
    parser.add_argument("--materials", type=int, default=16, help="held-out materials (default 16)")
    parser.add_argument("--size", type=int, default=256, help="held-out resolution (default 256)")
    parser.add_argument("--dry-run", action="store_true", help="measure and print, do not bundle")
    parser.add_argument("--no-foreign", action="store_true", help="skip the foreign-capture accuracy")
    parser.add_argument("-o", "--out", type=Path, default=WEIGHTS_DIR,
                        help="weights folder (default: the package's bundled weights, mi_svbrdf/weights/)")
    parser.add_argument("--note", default="", help="how the run went beyond its config (kept in the manifest)")
    parser.add_argument("--record-foreign", action="store_true",
                        help="CHECKPOINT is a bundled kind (single, multi): measure that bundled net on the foreign "
                             "captures and record the figures in its manifest entry (weights unchanged)")
    args = parser.parse_args(argv)
    if args.record_foreign:
        manifest = read_manifest(args.out)
        if args.checkpoint not in manifest:
            parser.error(f"--record-foreign: expected a bundled kind among {sorted(manifest)}, got {args.checkpoint!r}")
        net = load_network(args.checkpoint, folder=args.out)
        foreign = foreign_accuracy(net.eval(), materials=args.materials, size=args.size)
        print(accuracy_table(foreign))
        print(json.dumps(generalisation_targets(manifest[args.checkpoint]["accuracy"], foreign), indent=1))
        if not args.dry_run:
            manifest[args.checkpoint]["foreign_accuracy"] = foreign
            write_json(args.out / MANIFEST, manifest)
        return 0
    state = load_state(args.checkpoint)
    net = build_network(config_from_dict(state["net_config"]))
    # measure the weights as they will be bundled: rounded to fp16
    net.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in state["model"].items()})
    accuracy = held_out_accuracy(net.eval(), materials=args.materials, size=args.size)
    print(accuracy_table(accuracy))
    foreign = None
    if not args.no_foreign:
        foreign = foreign_accuracy(net, materials=args.materials, size=args.size)
        print("foreign captures:")
        print(accuracy_table(foreign))
    print(json.dumps(generalisation_targets(accuracy, foreign), indent=1))
    if not args.dry_run:
        entry = export_weights(args.checkpoint, accuracy=accuracy, foreign_accuracy=foreign, folder=args.out,
                               note=args.note)
        print(f"bundled {entry['file']} ({entry['bytes'] / 1e6:.1f} MB, sha256 {entry['sha256'][:12]}...)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
