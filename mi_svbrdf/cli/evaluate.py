"""``mi-svbrdf evaluate``: the methods on the held-out benchmark, as a report folder.

Writes to ``-o/--out`` the files listed in :data:`OUTPUTS` (see :mod:`mi_svbrdf.eval.runner`,
:mod:`mi_svbrdf.eval.stability` and :mod:`mi_svbrdf.eval.report`).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch

from mi_svbrdf.cli.common import RESUME_HINT, add_command, claim_folder, int_at_least, int_between, replace_outputs
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.eval import failure_cases
from mi_svbrdf.eval.methods import METHODS
from mi_svbrdf.eval.report import generalisation_section, write_evaluation_report
from mi_svbrdf.eval.runner import EvalConfig, quick_config, run_evaluation
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES

DESCRIPTION = """\
Evaluate the trivial baseline, the single- and multi-image nets, the optimiser (a sweep of time
budgets), net-initialised refinement with the captures (refine) and without them (uncalibrated:
each photo's light estimated from the photos, as `mi-svbrdf capture` refines) on the held-out
procedural benchmark (mi_svbrdf.data.heldout) and on the foreign captures (mi_svbrdf.data.foreign:
materials and every capture parameter outside the training ranges; --no-foreign: off), optionally
on a folder of the thesis's 2019 test strips (--strips DIR: 10 inputs + 4 maps each; uncalibrated,
so optimize and refine are skipped there, uncalibrated runs), and write a report folder with the
sets side by side and the gap (foreign - held-out) per method.

Full run: 16 materials at 256^2, N = 1..10 (and 20, 50 for the optimiser), budgets 1, 3, 30 s
(refinement 3, 30 s; uncalibrated 3, 10 s; the estimate is printed first). --quick: 4 materials at
128^2, N in {1, 3}, 4 s budgets; both with the foreign set (as many materials as the held-out set)."""

OUTPUTS = """\
Files written to -o/--out:
  results.csv             one row per material, method, N and budget: metrics, wall time, peak
                          memory, optimiser steps and recoveries (a rerun with the same --out
                          skips finished rows)
  settings.json           what makes rows comparable (size, lights, held-out seed); checked on resume
  summary.md              the tables (main, images to match, failure cases, stability) and charts
  summary.csv             the main table (mean over materials per method, N and budget)
  sets.csv                held-out, foreign (and strips) side by side per method, N and budget, and the gaps
  stability.csv           how far each method's maps move under 1/255 input noise, between two
                          identical calls and with the photos reordered, and its render RMSE
  a_speed_accuracy.png    (a) error vs wall time, with the Pareto front
  b_ssim_vs_images.png    (b) SSIM vs number of images (when more than one N is run)
  c_images_to_match.png   (c) images the optimiser needs to match the 5-image net
  d_gallery_mM.png        (d) per gallery material: inputs, each method's maps, the ground truth
  e_failure_cases.png     (e) failure-case degradation (with --cases)
  real_checks.json        real-style checks (--no-real-checks: off): the nets on the bundled example
                          photos (RMSE against their known truth) and the highlight leak into the
                          diffuse map on flash photos of glossy materials with a clipped highlight
  f_real_examples.png     the example photos and each net's maps, side by side with the truth
  g_real_highlights.png   the glossy photos (clipped highlight outlined) and each method's diffuse map
  gallery/, predictions/  the gallery materials and their predictions (.pt) the charts are drawn from"""

#: The report's files, drawn again from every row of results.csv by each run (patterns relative to
#: -o/--out): a run replaces a previous one's before drawing them. The rows, settings, predictions, the
#: stability table and the real-style checks are resumable state and stay.
OWNED = ("summary.md", "summary.csv", "sets.csv", "a_speed_accuracy.png", "b_ssim_vs_images.png",
         "c_images_to_match.png", "d_gallery_m*.png", "e_failure_cases.png")

#: Every file of :data:`OUTPUTS` (patterns relative to -o/--out), recorded as the folder's (``claim_folder``).
OWNS = (*OWNED, "results.csv", "settings.json", "stability.csv", "real_checks.json", "f_real_examples.png",
        "g_real_highlights.png", "gallery/*", "predictions/*")
EXAMPLES = ("mi-svbrdf evaluate --quick -o out/report", "mi-svbrdf evaluate -o out/report --cases all",
            "mi-svbrdf evaluate --quick -o out/report --ablations out/ablations")


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``evaluate`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "evaluate", help="evaluate the methods on the held-out benchmark (report folder)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("--quick", action="store_true", help="the reduced run (about 10 minutes on 2 cores; the estimate is printed first)")
    p.add_argument("-o", "--out", default="report", help="report folder (default report/)")
    p.add_argument("--weights", default=None, metavar="DIR", help="network weights folder (default: bundled)")
    p.add_argument("--materials", type=int_at_least(1), default=None, help="held-out materials (default 16; quick 4)")
    p.add_argument("--size", type=int_at_least(8), default=None, help="resolution (default 256; quick 128)")
    p.add_argument("--n", type=_ints, default=None, metavar="N,N", help="numbers of images (default 1..10)")
    p.add_argument("--optimizer-n", type=_ints, default=None, metavar="N,N",
                   help="extra numbers of images for the optimiser (default 20,50)")
    p.add_argument("--budgets", type=_floats, default=None, metavar="S,S", help="optimiser budgets in s (1,3,30)")
    p.add_argument("--refine-budgets", type=_floats, default=None, metavar="S,S", help="refinement budgets (3,30)")
    p.add_argument("--uncalibrated-budgets", type=_floats, default=None, metavar="S,S",
                   help="budgets of the uncalibrated refinement: light search and fit (3,10)")
    p.add_argument("--methods", default=None, help="comma-separated subset of " + ",".join(METHODS))
    p.add_argument("--cases", default=None, help="failure cases (mi_svbrdf.eval.failure_cases): 'all' or NAME,NAME")
    p.add_argument("--stability-materials", type=int, default=None,
                   help="held-out materials of the stability table (1/255 noise, repeat, permutation; "
                        "default 2, quick 1; 0: none)")
    p.add_argument("--foreign", action=argparse.BooleanOptionalAction, default=True,
                   help="also evaluate on the foreign captures (default on; --no-foreign: held-out only)")
    p.add_argument("--foreign-materials", type=int, default=None,
                   help="materials of the foreign set (default: as many as the held-out set)")
    p.add_argument("--real-checks", action=argparse.BooleanOptionalAction, default=True,
                   help="run the real-style checks: the nets on the example photos and on clipped flash "
                        "highlights (default on; --no-real-checks: off)")
    p.add_argument("--ablations", default=None, metavar="DIR",
                   help="add the section of a finished `mi-svbrdf ablations -o DIR` run to the report")
    p.add_argument("--strips", default=None, metavar="DIR",
                   help="also evaluate on a folder of the thesis's 2019 test strips (10 inputs | 4 maps)")
    p.add_argument("--device", default="cpu", help=DEVICE_HELP)
    p.add_argument("--symmetries", type=int_between(1, 8), default=DEFAULT_SYMMETRIES,
                   help="run the nets as a symmetry ensemble of this many flips and rotations, as capture does "
                        f"(1: the nets alone; default {DEFAULT_SYMMETRIES})")
    p.add_argument("--case-size", type=int, default=128, help="failure-case resolution (default 128)")
    p.add_argument("--threads", type=int_at_least(1), default=None,
                   help="torch CPU threads (default: torch's; 1 is faster on a loaded machine)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run_cli, _resume=RESUME_HINT, _owns=OWNS)


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    """The :class:`~mi_svbrdf.eval.runner.EvalConfig` of the command line."""
    overrides = {k: v for k, v in {"materials": args.materials, "size": args.size, "n_images": args.n,
                                   "optimizer_n": args.optimizer_n, "budgets": args.budgets,
                                   "refine_budgets": args.refine_budgets,
                                   "uncalibrated_budgets": args.uncalibrated_budgets,
                                   "methods": tuple(args.methods.split(",")) if args.methods else None}.items()
                 if v is not None}
    if args.stability_materials is not None:
        overrides["stability_materials"] = args.stability_materials
    overrides["sets"] = ("heldout", "foreign") if args.foreign else ("heldout",)
    if args.foreign_materials is not None:
        overrides["foreign_materials"] = args.foreign_materials
    if args.strips is not None:
        overrides["strips"] = args.strips
    overrides["device"] = str(resolve_device(args.device))
    overrides["real_checks"] = args.real_checks
    overrides["symmetries"] = args.symmetries
    if args.n is not None:
        overrides.setdefault("gallery_n", max(args.n))
        overrides.setdefault("reference_n", max(n for n in args.n if n <= 5) if min(args.n) <= 5 else min(args.n))
    return quick_config(**overrides) if args.quick else EvalConfig.from_dict(overrides)


def _cases(spec: str | None, size: int, n_images: int) -> list[object]:
    if not spec:
        return []
    names = list(failure_cases.CASES) if spec == "all" else spec.split(",")
    bad = [n for n in names if n not in failure_cases.CASES]
    if bad:
        raise ValueError(f"--cases: expected 'all' or names among {sorted(failure_cases.CASES)}, got {bad}")
    return [failure_cases.make_case(n, size=size, n_images=n_images) for n in names]


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf evaluate``; returns the exit code (bad input: ``ValueError``, exit 2 by ``common.run``)."""
    config = config_from_args(args)
    cases = _cases(args.cases, args.case_size, max(config.n_images))
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    if args.ablations is not None and not (Path(args.ablations) / "ablations.json").is_file():
        raise ValueError(f"--ablations: expected a folder with ablations.json (from `mi-svbrdf ablations -o DIR`), "
                         f"got {args.ablations!r}")
    notes = [f"settings: {config}", f"weights: {args.weights or 'bundled'}",
             f"torch threads: {torch.get_num_threads()}"]
    claim_folder(args, args.out, OWNS)
    rows = run_evaluation(config, args.out, weights_dir=args.weights, cases=cases,
                          progress=not args.no_progress, log=lambda s: (print(s), notes.append(s)))
    replace_outputs(args, args.out, OWNED)
    files = write_evaluation_report(args.out, rows, reference_n=config.reference_n, notes=notes, ablations_dir=args.ablations)
    general, _ = generalisation_section(rows)
    if general:
        print("\n".join(general))
    print(f"evaluate: {len(rows)} rows; report in {args.out}: {', '.join(sorted(p.name for p in files.values()))}")
    return 0
