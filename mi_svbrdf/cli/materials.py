"""``mi-svbrdf materials make``: a deterministic bank of procedural SVBRDFs on disk."""
from __future__ import annotations

import argparse
from typing import Any

from mi_svbrdf.cli.common import add_command, claim_folder, command_group, float_between, int_at_least, standalone
from mi_svbrdf.data import procedural
from mi_svbrdf.data.bank import FORMATS, ROTATIONS, make_bank
from mi_svbrdf.io.material_sets import BANK_INDEX

DESCRIPTION = """\
Write a deterministic bank of procedural SVBRDFs (the same --seed gives identical files), drawn
from the nine material classes with their parameters, rotations and alpha-mixes of two classes;
the training data of `mi-svbrdf dataset render`, readable by mi_svbrdf.io.material_sets.
"""
OUTPUTS = """\
Writes to -o/--out:
  000000_<class>.png   thesis strips: normal | diffuse | roughness | specular (--format strip)
  000000_<class>/      material folders (--format folder); mixes are named <class>+<class>
  index.json/.csv      class(es), parameters, seeds, mix alpha and rotation of every file
  contact_sheet.png    thumbnails (flash render, diffuse, specular, normal, roughness)
"""
EXAMPLES = ("mi-svbrdf materials make --count 8 --size 128 -o out/bank",
            "mi-svbrdf materials make --count 64 --classes paint,wood --format folder -o out/bank-folders")
#: The full help text, as ``--help`` shows it around the options.
MAKE_HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out), recorded as the folder's (``claim_folder``).
OWNS = ("index.json", "index.csv", "contact_sheet.png", "[0-9][0-9][0-9][0-9][0-9][0-9]*_*.png",
        "[0-9][0-9][0-9][0-9][0-9][0-9]*_*/*")


def cmd_make(args: argparse.Namespace) -> int:
    """Run ``materials make``; prints a summary; returns 0."""
    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    unknown = [c for c in classes or [] if c not in procedural.CLASSES]
    if unknown or classes == []:
        raise ValueError(f"--classes: expected names among {list(procedural.CLASSES)} (comma-separated), "
                         f"got {args.classes!r}")
    claim_folder(args, args.out, OWNS)
    result = make_bank(args.out, args.count, size=args.size, seed=args.seed, classes=classes, fmt=args.format,
                       mix_fraction=args.mix_fraction, spread=args.spread, workers=args.workers,
                       rotation=args.rotation, sheet=args.sheet, progress=not args.quiet)
    n = len(result.index["materials"])
    mixes = sum(m["mix_alpha"] is not None for m in result.index["materials"])
    print(f"wrote {n} materials ({mixes} mixes) of {args.size}x{args.size} to {result.out}/ "
          f"in {result.seconds:.2f} s: {result.materials_per_second:.1f} materials/s "
          f"(generate {result.timings['generate']:.2f} s, write {result.timings['write']:.2f} s, "
          f"contact sheet {result.timings['sheet']:.2f} s)")
    print(f"index: {result.out / BANK_INDEX}, {result.out / 'index.csv'}"
          + (f"; contact sheet: {result.contact_sheet}" if result.contact_sheet else ""))
    return 0


def add_parser(subparsers: Any) -> None:
    """Add the ``materials`` command (with its ``make`` subcommand) to ``subparsers``."""
    sub = command_group(subparsers, "materials", "procedural SVBRDF banks (materials make ...)",
                        "Procedural SVBRDF material banks.")
    p = add_command(sub, "make", help="write a deterministic bank of procedural materials",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("--count", type=int_at_least(1), required=True, help="number of materials")
    p.add_argument("--size", type=int_at_least(8), default=256, help="map resolution (default: 256)")
    p.add_argument("--out", "-o", required=True, help="bank folder")
    p.add_argument("--classes", default=None,
                   help="comma-separated classes to draw from, e.g. paint,wood (default: all nine)")
    p.add_argument("--format", choices=FORMATS, default="strip", help="strip PNGs or material folders (default: strip)")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="bank seed (default: 0)")
    p.add_argument("--mix-fraction", type=float_between(0.0, 1.0), default=0.3,
                   help="fraction of materials that mix two, alpha ~ U(0.1, 0.9) (default: 0.3)")
    p.add_argument("--spread", type=float_between(0.0, 1.0), default=1.0,
                   help="parameter spread: 0 defaults, 1 anywhere in the ranges (default: 1)")
    p.add_argument("--rotation", choices=ROTATIONS, default="any",
                   help="random rotation: any angle, multiples of 90 degrees, or none (default: any)")
    p.add_argument("--workers", type=int_at_least(1), default=1, help="worker processes (default: 1)")
    p.add_argument("--sheet", type=int_at_least(0), default=64, help="materials in contact_sheet.png, 0 for none (default: 64)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_make, _owns=OWNS)


def main(argv: list[str] | None = None) -> int:
    """Run ``materials ...`` on its own: ``main(["materials", "make", "--count", "4", ...])``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
