"""``mi-svbrdf dataset render``: render a bank through a Mitsuba scene file into a resumable dataset."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from mi_svbrdf.cli.common import (
    RESUME_HINT,
    add_command,
    command_group,
    float_at_least,
    float_between,
    int_at_least,
    claim_folder,
    parse_params,
    standalone,
)
from mi_svbrdf.data.dataset.job import PADDINGS, RenderJob, ShotRanges
from mi_svbrdf.data.dataset.workers import render_dataset

DESCRIPTION = """\
Render each material of --materials (a bank of `mi-svbrdf materials make`, or any folder of
strips and material folders) --renders-per-material times through a Mitsuba scene: random
flash position, exposure, material rotation and zoom per render (thesis ch. 3.2). Resumable:
run the same command again after a kill. Deterministic per --seed whatever the number of
workers. The linear photo is (png / 255) ** 2.2.
"""
OUTPUTS = """\
Writes to -o/--out:
  manifest.json                      the job (a resume must match it)
  shard_0000/000000.png              strip: input (8-bit gamma photo) | normal | diffuse | roughness | specular
  shard_0000/000000.json             every scene parameter of the render
"""
EXAMPLES = (("mi-svbrdf materials make --count 4 --size 64 -o out/bank && "
             "mi-svbrdf dataset render --materials out/bank --renders-per-material 2 --size 64 -o out/dataset"),
            "mi-svbrdf dataset render --materials out/bank --workers 2 --param distribution=beckmann -o out/beckmann")
#: The full help text, as ``--help`` shows it around the options.
RENDER_HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out), recorded as the folder's (``claim_folder``).
OWNS = ("manifest.json", "shard_[0-9][0-9][0-9][0-9]/*")


def _pair(text: str) -> tuple[float, float]:
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or not all(math.isfinite(v) for v in parts) or parts[0] > parts[1]:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH (LOW <= HIGH) or one value, got {text!r}")
    return parts[0], parts[1]


def _positive_pair(text: str) -> tuple[float, float]:
    low, high = _pair(text)
    if low <= 0:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH with 0 < LOW <= HIGH, got {text!r}")
    return low, high


def cmd_render(args: argparse.Namespace) -> int:
    """Run ``dataset render``; prints the summary; 0 if every render exists, 1 otherwise."""
    if not Path(args.materials).is_dir():
        what = "the file" if Path(args.materials).exists() else "no such folder"
        raise FileNotFoundError(f"--materials: expected a folder of strips or material folders (mi-svbrdf materials "
                                f"make writes one), got {what} {args.materials!r}")
    defaults = ShotRanges()
    shots = ShotRanges(fov=args.fov, light_offset=args.light_offset,
                       exposure=args.exposure or defaults.exposure, angle=args.angle or defaults.angle,
                       zoom=args.zoom or defaults.zoom, padding=args.padding)
    job = RenderJob(materials=args.materials, out=args.out, scene=args.scene,
                    renders_per_material=args.renders_per_material, seed=args.seed, size=args.size, spp=args.spp,
                    shard_size=args.shard_size, params=parse_params(args.param), shots=shots)
    claim_folder(args, args.out, OWNS)
    summary = render_dataset(job, workers=args.workers, ray=args.ray, threads=args.threads, limit=args.limit,
                             progress=not args.quiet)
    for name, reason in summary.skipped_at_scan:
        print(f"skipped at scan: {name}: {reason}", file=sys.stderr)
    for name, reason in summary.failed:
        print(f"failed material: {name}: {reason}", file=sys.stderr)
    print(summary.line())
    print(f"dataset: {summary.out}/ ({summary.total - summary.remaining} of {summary.total} images)")
    complete = summary.remaining == 0 or (args.limit is not None and not summary.failed)
    return 0 if complete else 1


def add_parser(subparsers: Any) -> None:
    """Add the ``dataset`` command (with its ``render`` subcommand) to ``subparsers``."""
    sub = command_group(subparsers, "dataset", "training datasets (dataset render ...)", "Rendered training datasets.")
    p = add_command(sub, "render", help="render materials through a Mitsuba scene file into a dataset",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    d = ShotRanges()  # the ranges of each render's random shot
    p.add_argument("--scene", default="flash_capture",
                   help="bundled scene name or path of an XML capture scene (default: flash_capture)")
    p.add_argument("--materials", required=True, help="folder of strips and/or material folders (e.g. a bank)")
    p.add_argument("--renders-per-material", type=int_at_least(1), default=10, help="renders per material (default: 10)")
    p.add_argument("--out", "-o", required=True, help="dataset folder")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="job seed (default: 0)")
    p.add_argument("--size", type=int_at_least(8), default=256, help="image and map size in pixels (default: 256)")
    p.add_argument("--spp", type=int_at_least(1), default=RenderJob.spp,
                   help=f"samples per pixel, antialiasing (default: {RenderJob.spp})")
    p.add_argument("--shard-size", type=int_at_least(1), default=1000, help="renders per shard folder (default: 1000)")
    p.add_argument("--workers", type=int_at_least(1), default=1,
                   help="local worker processes; with --ray, actors (default 1: this process / one per Ray CPU)")
    p.add_argument("--ray", default=None, metavar="auto|ADDRESS|local",
                   help="run on Ray: auto (running cluster), ADDRESS, or local (start one); needs `pip install ray`")
    p.add_argument("--threads", type=int_at_least(1), default=1, help="Dr.Jit threads per worker (default: 1)")
    p.add_argument("--limit", type=int_at_least(0), default=None, help="render at most this many missing images, then stop")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="another $parameter of the scene, e.g. --param distribution=beckmann (repeatable)")
    p.add_argument("--fov", type=float_between(0.0, 180.0, open_ends=True, unit="degrees"), default=d.fov, help=f"camera field of view, degrees (default: {d.fov:g})")
    p.add_argument("--light-offset", type=float_at_least(0.0), default=d.light_offset,
                   help=f"flash offset range from the camera axis, sample half-widths (default: {d.light_offset:g})")
    p.add_argument("--exposure", type=_positive_pair, default=None, metavar="LOW,HIGH",
                   help=f"flash strength range, log-uniform (default: {d.exposure[0]:g},{d.exposure[1]:g})")
    p.add_argument("--angle", type=_pair, default=None, metavar="LOW,HIGH",
                   help="material rotation range, degrees; write --angle=-90,90 for a negative low "
                        f"(default: {d.angle[0]:g},{d.angle[1]:g})")
    p.add_argument("--zoom", type=_positive_pair, default=None, metavar="LOW,HIGH",
                   help=f"material width / image width range, log-uniform (default: {d.zoom[0]:g},{d.zoom[1]:g})")
    p.add_argument("--padding", choices=PADDINGS, default=d.padding,
                   help="outside the material: mirror or tile (default: reflection)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render, _resume=RESUME_HINT, _owns=OWNS)


def main(argv: list[str] | None = None) -> int:
    """Run ``dataset ...`` on its own: ``main(["dataset", "render", "--materials", ...])``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    sys.exit(main())
