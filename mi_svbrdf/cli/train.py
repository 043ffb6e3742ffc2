"""``mi-svbrdf train``: train the single- or multi-image network on the online capture simulator."""
from __future__ import annotations

import argparse
import json
import math
from typing import Any

from mi_svbrdf.cli.common import parse_params, standalone
from mi_svbrdf.nets import train as training
from mi_svbrdf.nets.train import RECIPES, load_config

TRAIN_HELP = training.__doc__

def add_parser(subparsers: Any) -> None:
    """``mi-svbrdf train CONFIG [--resume] [--set key=value ...]``."""
    p = subparsers.add_parser("train", help="train a network on the online capture simulator",
                              description=TRAIN_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", help=f"a recipe ({', '.join(RECIPES)}) or a JSON TrainConfig file")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config field (value parsed as JSON, else a string)")
    p.add_argument("--max-minutes", type=float, default=math.inf, help="stop (with a checkpoint) after this long")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    overrides: dict[str, Any] = {}
    for key, value in parse_params(args.set).items():
        try:
            overrides[key] = json.loads(value)
        except json.JSONDecodeError:
            overrides[key] = value
    cfg = load_config(args.config, overrides)
    run = training.train(cfg, resume=args.resume, max_seconds=args.max_minutes * 60, progress=not args.no_progress)
    print(f"run folder: {run}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return standalone(add_parser, argv)



if __name__ == "__main__":
    raise SystemExit(main())
