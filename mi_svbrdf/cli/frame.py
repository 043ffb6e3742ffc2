"""``mi-svbrdf frame``: a printable capture frame at true scale (the AprilTag print or the paper frame).

The drawing is :mod:`mi_svbrdf.geometry.sheets`; this module parses the options and says how to use the sheet.
"""
from __future__ import annotations

import argparse
import sys

from mi_svbrdf.cli.common import add_command, float_at_least, replace_outputs, standalone

DESCRIPTION = """\
Write a printable capture frame at true scale, as PDFs on A4 and Letter (print at actual size,
no fit-to-page) and a preview, and say how to use it:

  tags   the AprilTag print of the field's capture kit (MaterialGAN's): 16 tag36h11 tags, IDs
         0-15 clockwise from the top left around a window to cut (side 2S/3), a ruler line to
         measure S (the ring's outer size) and the orientation mark; rectify it with
         `mi-svbrdf rectify PHOTO... --frame tags --frame-size S`. --size S in mm (default 180).
  a4     the paper frame: a square window to cut 30 mm from the sheet's left and top edges (the
         wide bottom margin tells which way is up); rectify it with
         `mi-svbrdf rectify PHOTO... --frame-size W,H`. --size: the window's side in mm (default 150).

Printers scale: measure the printed size with a ruler and pass what you measure.
"""
OUTPUTS = """\
Writes to -o/--out:
  sheet_a4.pdf      the sheet on A4 (210 x 297 mm), true scale
  sheet_letter.pdf  the sheet on US Letter (8.5 x 11 in), true scale
  sheet.png         a preview of the A4 sheet
"""
EXAMPLES = ("mi-svbrdf frame tags -o out/frame", "mi-svbrdf frame a4 --size 150 -o out/paper_frame")
#: The files of :data:`OUTPUTS` (a new run replaces a previous one's).
OWNED = ("sheet_a4.pdf", "sheet_letter.pdf", "sheet.png")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``frame`` on a subparsers object (``func(args) -> int``)."""
    from mi_svbrdf.geometry.sheets import KINDS

    p = add_command(subparsers, "frame", help="a printable capture frame (AprilTag print or paper frame), true scale",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("kind", choices=KINDS, help="tags: the AprilTag print; a4: the paper frame")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--size", type=float_at_least(0.0, inclusive=False, unit="mm"), default=None, metavar="MM",
                   help="tags: the ring's outer size S (default 180); a4: the window's side (default 150)")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf frame``; returns the exit code."""
    from mi_svbrdf.geometry.sheets import DEFAULT_SIZE_MM, sheet_figure, write_sheets

    size = DEFAULT_SIZE_MM[args.kind] if args.size is None else args.size
    for paper in ("a4", "letter"):
        sheet_figure(args.kind, paper, size)  # a size that does not fit: one line before anything is written
    replace_outputs(args, args.out, OWNED)
    for path in write_sheets(args.kind, args.out, size):
        print(f"wrote {path}")
    if args.kind == "tags":
        print(f"Print sheet_a4.pdf or sheet_letter.pdf at actual size, measure S (the ruler line, the tag ring's outer "
              f"edges; printed at {size:g} mm), cut out the window (side {2 * size / 3:.1f} mm) and lay the sheet on "
              f"the material. Take 5-10 flash photos from different angles, then:\n"
              f"  mi-svbrdf rectify IMG_*.jpg --frame tags --frame-size S -o rect\n"
              f"  mi-svbrdf optimize --capture rect/capture.json -o fit")
    else:
        print(f"Print sheet_a4.pdf or sheet_letter.pdf at actual size, cut out the {size:g} mm window (measure it), "
              f"lay the sheet on the material on a darker table. Take 5-10 flash photos from different angles, "
              f"then:\n  mi-svbrdf rectify IMG_*.jpg --frame-size W,H -o rect\n"
              f"  mi-svbrdf optimize --capture rect/capture.json -o fit")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.frame``: ``frame`` arguments only."""
    return standalone(add_parser, ["frame", *(argv or [])])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
