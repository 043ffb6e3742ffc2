"""``mi-svbrdf train``: train the single- or multi-image network on the online capture simulator."""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

from mi_svbrdf.cli.common import add_command, claim_folder, float_at_least, parse_settings, replace_outputs, standalone
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.nets import train as training
from mi_svbrdf.nets.train import RECIPES, load_config

OUTPUTS = """\
Writes to the run folder (-o/--out; default: the config's out/name, ~/.cache/mi_svbrdf/runs/NAME):
  config.json     the TrainConfig of the run
  checkpoint.pt   weights, optimiser, step, RNG, config and log (--resume continues from it)
  log.csv         training loss, learning rate and validation metrics by step
  curve.png       the training curve (loss and held-out RMSE against step)"""
#: What a run writes besides its resumable state (checkpoint.pt, config.json): a new run (no --resume)
#: replaces a previous one's; a resumed run keeps them.
OWNED = ("log.csv", "curve.png")
#: Every file of a run (patterns relative to the run folder), recorded as the folder's (``claim_folder``).
OWNS = ("config.json", "checkpoint.pt", *OWNED)
EXAMPLES = ("mi-svbrdf train single -o out/train-single --max-minutes 10",
            "mi-svbrdf train multi --resume --set lr=1e-4")


def add_parser(subparsers: Any) -> None:
    """``mi-svbrdf train CONFIG [-o RUN] [--resume] [--set key=value ...]``."""
    p = add_command(subparsers, "train", help="train a network on the online capture simulator",
                    description=training.__doc__ or "", outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("config", help=f"a recipe ({', '.join(RECIPES)}) or a JSON TrainConfig file")
    p.add_argument("-o", "--out", default=None, metavar="RUN",
                   help="the run folder (sets the config's out and name to its parent and name; "
                        "default: out/name of the config)")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config field (value parsed as JSON, else a string)")
    p.add_argument("--device", default=None,
                   help=f"{DEVICE_HELP}; sets the config's device (under torchrun, cuda is cuda:LOCAL_RANK)")
    p.add_argument("--max-minutes", type=float_at_least(0.0), default=math.inf,
                   help="stop (with a checkpoint) after this long")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bars (the steps', and the validation set's while it is built)")
    p.set_defaults(func=_main, _resume="re-run with --resume to continue from the last checkpoint", _owns=OWNS)


def _main(args: argparse.Namespace) -> int:
    overrides: dict[str, Any] = parse_settings(args.set)
    if args.out is not None:
        run_dir = Path(args.out).expanduser()
        if not run_dir.name:
            raise ValueError(f"--out: expected a run folder path, got {args.out!r}")
        overrides.update(out=str(run_dir.parent), name=run_dir.name)
    if args.device is not None:
        overrides["device"] = str(resolve_device(args.device))  # fails early, with the devices present
    cfg = load_config(args.config, overrides)
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun, the first process only
        if args.resume:
            claim_folder(args, cfg.run_dir, OWNS)
        else:
            replace_outputs(args, cfg.run_dir, OWNED)
    # the last line: steps done, why the run stopped, where its checkpoint is (also after an error)
    training.train(cfg, resume=args.resume, max_seconds=args.max_minutes * 60, progress=not args.no_progress,
                   report=print)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run ``train`` on its own: ``main(["train", "single", "-o", "runs/single"])`` (also ``python -m``)."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
