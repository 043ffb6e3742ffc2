"""``mi-svbrdf rectify``: find the paper frame in flash photos, rectify them, recover each camera.

The work is :func:`mi_svbrdf.geometry.rectify.rectify_photos`; this module parses the options.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mi_svbrdf.cli.common import (
    add_command,
    expand_photos,
    float_at_least,
    float_between,
    replace_outputs,
    standalone,
)
from mi_svbrdf.geometry.frame import DEFAULT_FRAME
from mi_svbrdf.cli.rectify_tags import SIZE_HELP, error_line, options_size, photo_size, said_size, size_type
from mi_svbrdf.geometry.rectify import RectifyOptions, capture_notes, rectify_photos

DESCRIPTION = f"""\
Rectify flash photos of a sample lying in a light paper frame on a darker table: find the
frame's four inner corners in each photo (or take them from --corners), warp the window to a
square image seen from above (+y up: the frame's widest margin is the bottom), recover each
camera from the corners and the intrinsics (--fov, or the EXIF 35 mm-equivalent focal
length), and write a capture file that `mi-svbrdf optimize --capture OUT/capture.json` and
`mi-svbrdf capture OUT/0*.png` take as it is.

The frame (default): an A4 sheet (210 x 297 mm) with a {DEFAULT_FRAME.window_mm[0]:g} x
{DEFAULT_FRAME.window_mm[1]:g} mm window cut 30 mm from its left, right and top edges (the
117 mm bottom margin tells which way is up). --frame-size W,H sets the window's inner size in
mm: the window's inside is the sample plane [-1, 1]^2. A frame with all margins alike (a
symmetric frame) cannot tell which way is up: when no photo shows a widest margin, each photo
keeps its own orientation (the window's side nearest the photo's bottom edge is the bottom), so
take every photo with the same side of the sample towards its bottom edge; a note says so. When
some photos show a widest margin, it orients the set and the others fail.

The flash is at the camera plus --flash-offset (mm; x right, y up in the upright photo, z
forward), isotropic, with intensity |flash|^2 in the capture's units (an auto-exposed photo:
a white Lambertian texel at the centre facing the flash would read 1) unless --intensity.

A photo that fails (no frame, several candidate frames, frame cut by the image border, photo
or window too small, too blurry, no FOV) is reported with the reason and its overlay; the
others are still processed. Exit code 0: all rectified; 1: some failed; 2: none.

PHOTO 'example' renders three synthetic framed photos as a phone takes them (Mitsuba: a
procedural leather in the paper frame on a table, tilted cameras, 4032x3024 JPEG with the EXIF
focal length; rendered once into the cache MI_SVBRDF_CACHE, then copied) into
OUT/example_photos/ and rectifies them.

--frame tags: the AprilTag print instead (`mi-svbrdf frame tags` draws it; the field's
MaterialGAN print works as it is): 16 tag36h11 tags around a cut window; --frame-size S is the
ring's outer size in mm (measure it on the print; the window's side is 2S/3), --depth the tag
plane's height above the sample in mm. The tags are found in each photo (from 4 of 16); without
--fov the camera (focal length, principal point, radial distortion) is calibrated from all
photos' tags (the EXIF focal length is used instead for 1-2 photos that all have one, or when
the photos do not determine the calibration). Each photo's line says how many tags were used
and the reprojection error (also in summary.json). PHOTO 'example' renders five photos of the
print (4032x3024 JPEG, no EXIF; cached as the paper frame's).
"""
OUTPUTS = """\
Writes to -o/--out:
  NNN.png           the rectified photo of input NNN (sRGB 8-bit, --size^2), so that no paper shows at
                    its edges: cropped just inside the frame's window (--frame tags: the window's edge
                    texels within the paper's reach repeat the nearest one seen clear of it)
  overlay_NNN.png   the photo with the found corners (TL red) and the frame drawn
  rectify.json      per photo: corners, homography, reprojection errors, how found and oriented,
                    camera, errors; notes on the set (e.g. oriented by the photos)
  capture.json      version 1, rectified: true, cameras and flashes of the photos that succeeded
  summary.json      --frame tags: per photo tags used, reprojection error, camera; the intrinsics
  example_photos/   the synthetic photos (PHOTO example only)
"""
EXAMPLES = ("mi-svbrdf rectify example -o out/rectify",
            "mi-svbrdf rectify IMG_*.jpg --flash-offset 10,0,0 -o out/rect",
            "mi-svbrdf rectify IMG_*.jpg --frame tags --frame-size 180 -o out/rect")
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new run replaces a previous one's
#: (``example_photos/`` only when PHOTO is example).
OWNED = ("[0-9][0-9][0-9].png", "[0-9][0-9][0-9][0-9].png", "overlay_[0-9][0-9][0-9].png",
         "overlay_[0-9][0-9][0-9][0-9].png", "rectify.json", "capture.json", "summary.json")
#: The synthetic photos of PHOTO example, under -o/--out.
OWNED_EXAMPLE = ("example_photos/IMG_[0-9][0-9][0-9][0-9].jpg",)


def example_photos(folder: Path) -> list[Path]:
    """The synthetic framed photos of ``rectify example`` in ``folder`` (JPEG with the EXIF focal length): rendered
    once and cached (:func:`mi_svbrdf.data.scan_examples.example_photos`)."""
    from mi_svbrdf.data import scan_examples

    return scan_examples.example_photos("frame", folder)


def frame_size(text: str) -> tuple[float, ...]:
    """``--frame-size``: ``W,H`` (paper frame) or one number ``S`` (the tag ring; a square paper window).

    Raises:
        ValueError: anything else (one line, as every other error of the command).
    """
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in (1, 2):
        raise ValueError(f"--frame-size: expected 2 comma-separated numbers (W,H) or one (S), got {text!r}")
    return values


def _frame_size(text: str) -> tuple[float, ...]:
    """:func:`frame_size` as an argparse type (for commands that pass the option on to rectify)."""
    try:
        return frame_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--frame-size: ")) from exc


def flash_offset(text: str) -> tuple[float, ...]:
    """``--flash-offset``: ``X,Y,Z`` mm.

    Raises:
        ValueError: anything else (one line).
    """
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise ValueError(f"--flash-offset: expected 3 comma-separated numbers (X,Y,Z mm), got {text!r}")
    return values


def parse_options(args: argparse.Namespace) -> None:
    """``--frame-size`` and ``--flash-offset`` from their text to numbers, in ``args`` (a ValueError is one line)."""
    if isinstance(args.frame_size, str):
        args.frame_size = frame_size(args.frame_size)
    if isinstance(args.flash_offset, str):
        args.flash_offset = flash_offset(args.flash_offset)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``rectify`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "rectify", help="rectify framed flash photos into a calibrated capture",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("photos", nargs="+", metavar="PHOTO",
                   help="flash photos (any orientation, EXIF honoured) or folders of them; 'example': synthetic ones")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--corners", metavar="FILE.json", default=None,
                   help="JSON mapping a photo's file name to four [x, y] pixel points of the upright photo "
                        "(OpenCV pixels: top-left pixel centre at 0,0), top-left first, clockwise; "
                        "photos it does not list are detected")
    p.add_argument("--frame", choices=("paper-frame", "tags"), default="paper-frame",
                   help="what surrounds the sample: the paper frame (default) or the AprilTag print")
    p.add_argument("--frame-size", metavar="W,H|S", default=None,
                   help=f"paper frame: inner size of the window in mm (default "
                        f"{DEFAULT_FRAME.window_mm[0]:g},{DEFAULT_FRAME.window_mm[1]:g}); tags: the ring's outer "
                        "size S in mm (required)")
    p.add_argument("--depth", type=float_at_least(0.0, unit="mm"), default=None, metavar="MM",
                   help="--frame tags: height of the tag plane above the sample in mm (default 0)")
    p.add_argument("--size", type=size_type, default="auto", metavar="auto|N",
                   help=SIZE_HELP)
    p.add_argument("--fov", type=float_between(0.0, 180.0, open_ends=True, unit="degrees"), default=None, metavar="DEG",
                   help="field of view across the photo's long side, a pinhole (default: paper frame, from EXIF "
                        "FocalLengthIn35mmFilm; --frame tags, calibrated from the tags, or from EXIF for 1-2 "
                        "photos that have it)")
    p.add_argument("--flash-offset", metavar="X,Y,Z", default=(0.0, 0.0, 0.0),
                   help="flash position from the lens in mm (x right, y up, z forward; default 0,0,0)")
    p.add_argument("--intensity", type=float_at_least(0.0, inclusive=False), default=None,
                   help="flash intensity written to capture.json (default: |flash|^2 per photo)")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf rectify``; returns the exit code (0 all rectified, 1 some failed, 2 none)."""
    parse_options(args)
    if getattr(args, "frame", "paper-frame") == "tags":
        from mi_svbrdf.cli.rectify_tags import run_tags

        return run_tags(args, OWNED + OWNED_EXAMPLE)
    if args.depth is not None:
        raise ValueError("--depth: expected with --frame tags only (the paper frame lies on the sample)")
    size = args.frame_size if args.frame_size is None or len(args.frame_size) == 2 else args.frame_size * 2
    frame = DEFAULT_FRAME if size is None else DEFAULT_FRAME.with_window(*size)
    options = RectifyOptions(size=options_size(args.size), fov_deg=args.fov, frame=frame,
                             flash_offset_mm=tuple(args.flash_offset), intensity=args.intensity)
    example = args.photos == ["example"]
    photos = [] if example else expand_photos(args.photos)
    replace_outputs(args, args.out, OWNED + (OWNED_EXAMPLE if example else ()),
                    keep=[*photos, *([args.corners] if args.corners else [])])
    if example:
        photos = [str(p) for p in example_photos(Path(args.out) / "example_photos")]
        print(f"example: {len(photos)} synthetic framed photos ({photo_size(photos[0])} JPEG) in "
              f"{Path(args.out) / 'example_photos'}/")
    results = rectify_photos(photos, args.out, options, corners_file=args.corners)
    said_size(args.out)
    failed = [r for r in results if not r.ok]
    for note in capture_notes(results):
        print(f"mi-svbrdf rectify: note: {note}", file=sys.stderr)
    for r in results:
        if r.ok:
            err = r.entry["reprojection_error_px"]
            print(f"{r.photo} -> {r.entry['output']}: camera {r.entry['camera_position']}, "
                  f"edges rms {err.get('edges_rms')} px, {r.entry['found_by'].split(' (')[0]}")
    for r in failed:
        print(error_line(r), file=sys.stderr)
    if len(failed) == len(results):
        return 2
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.rectify``: ``rectify`` arguments only."""
    return standalone(add_parser, ["rectify", *(argv or [])])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
