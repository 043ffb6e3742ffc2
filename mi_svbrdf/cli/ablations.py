"""``mi-svbrdf ablations``: the thesis's ablations at equal compute (:mod:`mi_svbrdf.eval.studies.ablations`)."""
from __future__ import annotations

import argparse
import sys
from typing import Any

from mi_svbrdf.cli.common import RESUME_HINT, add_command, claim_folder, int_at_least, parse_settings, standalone
from mi_svbrdf.eval.studies.ablations import ARMS, AblationConfig, estimate_seconds, quick_config, run_ablations

DESCRIPTION = f"""\
Train short CPU runs that differ in one setting, from scratch with the same seed, steps, batch and
size, score each final net on the same fixed held-out set, and say per ablation whether the result
agrees with the thesis (a difference within the noise threshold is called so):

  rendering loss vs map L1 only   ch. 3.1.3, Fig. 3.6   single/render, single/l1 (and single/render+l1)
  global-features track on/off    ch. 3.1.2             single/render+l1, single/no-global
  capture perturbations on/off    ch. 4.4.1             multi/max, multi/no-perturb
  max vs mean pooling over images ch. 4.2.2             multi/max, multi/mean

Arms: {', '.join(ARMS)}.
Defaults: 800 steps per arm at 64^2, batch 4, a small compact net, one torch thread: about 30 min
for all 7 arms on a 2-core CPU. Rerunning the same command skips finished arms and resumes an
interrupted one (Ctrl-C saves a checkpoint). `mi-svbrdf evaluate --ablations DIR` puts the result
in the evaluation report."""

OUTPUTS = """\
Files written to -o/--out:
  ablations.json   per arm: TrainConfig, steps, seconds, held-out metrics per N, validation curve;
                   per comparison: metric deltas, noise threshold, verdict and sentence
  ablations.md     a table per comparison and its one-sentence finding
  ablations.png    validation curves (re-render RMSE vs step) per group, final per-map RMSE bars
  runs/GROUP/VARIANT/checkpoint.pt, log.csv, curve.png   each arm's training run"""

EXAMPLES = (
    "mi-svbrdf ablations -o out/ablations                 # the full study (~30 min)",
    "mi-svbrdf ablations -o out/abl-quick --quick         # a smoke run (~20 s)",
    "mi-svbrdf ablations -o out/abl-pool --arms multi/max,multi/mean --steps 400",
    "mi-svbrdf ablations -o out/abl --set batch_size=8 --set 'train={\"bf16\": false}'",
)
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out), recorded as the folder's (``claim_folder``).
OWNS = ("ablations.json", "ablations.md", "ablations.png", "runs/**/*")


def add_parser(subparsers: Any) -> None:
    """``mi-svbrdf ablations -o DIR [--steps N] [--size S] [--arms a,b] [--quick] [--no-progress] [--set K=V]``."""
    p = add_command(subparsers, "ablations", help="the thesis's ablations at equal compute (short CPU trainings)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder (runs/ and the results)")
    p.add_argument("--steps", type=int_at_least(1), default=None, help="training steps per arm (default 800; quick 6)")
    p.add_argument("--size", type=int_at_least(8), default=None,
                   help="training and held-out resolution (default 64; quick 32)")
    p.add_argument("--arms", default=None, metavar="A,B", help="comma-separated arms to run (default: all)")
    p.add_argument("--quick", action="store_true", help="a tiny configuration for smoke runs")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an AblationConfig field (value parsed as JSON, else a string), "
                        "e.g. heldout_materials=8 or net='{\"last_features\": 32}'")
    p.set_defaults(func=_main, _resume=RESUME_HINT, _owns=OWNS)


def config_from_args(args: argparse.Namespace) -> AblationConfig:
    """The :class:`~mi_svbrdf.eval.studies.ablations.AblationConfig` of the command line (``ValueError`` on bad options)."""
    overrides: dict[str, Any] = parse_settings(args.set)
    for key in ("steps", "size"):
        if getattr(args, key) is not None:
            overrides[key] = getattr(args, key)
    if args.arms is not None:
        arms = tuple(a.strip() for a in args.arms.split(",") if a.strip())
        unknown = [a for a in arms if a not in ARMS]
        if unknown or not arms:
            raise ValueError(f"--arms: expected comma-separated names among {', '.join(ARMS)}, got {args.arms!r}")
        overrides["arms"] = arms
    overrides["out"] = args.out
    return quick_config(**overrides) if args.quick else AblationConfig.from_dict(overrides)


def _main(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    print(f"ablations: {len(config.arms)} arms x {config.steps} steps at {config.size}^2 (batch {config.batch_size}), "
          f"roughly {estimate_seconds(config) / 60:.0f} min of training on a 2-core CPU; output in {config.out}")
    claim_folder(args, config.out, OWNS)
    try:
        result = run_ablations(config, progress=not args.no_progress)
    except KeyboardInterrupt as exc:
        print(f"ablations: interrupted ({exc or 'Ctrl-C'}); rerun the same command to resume", file=sys.stderr)
        return 130
    for c in result["comparisons"]:
        print(f"- {c['sentence']}")
    print(f"ablations: {len(result['arms'])} arms; ablations.json, ablations.md, ablations.png in {config.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run ``ablations`` on its own: ``main(["ablations", "-o", "out/abl", "--quick"])`` (also ``python -m``)."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
