"""``mi-svbrdf rectify --frame tags``: the options of the AprilTag print, its example, the terminal lines.

The parser is :mod:`mi_svbrdf.cli.rectify`'s (``--frame tags`` dispatches here); the work is
:func:`mi_svbrdf.geometry.tag_rectify.rectify_tag_photos`.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mi_svbrdf.cli.common import expand_photos, int_at_least, replace_outputs
from mi_svbrdf.geometry.rectify import AUTO_MIN, AUTO_STEP
from mi_svbrdf.io.calibrated_photos import DEFAULT_MAX_SIDE
from mi_svbrdf.data import scan_examples

#: The synthetic example (:mod:`mi_svbrdf.data.scan_examples`): photos, their size (W, H), FOV across the long side
#: (degrees), the print's size S (mm).
EXAMPLE_PHOTOS, EXAMPLE_PHOTO_SIZE, EXAMPLE_FOV, EXAMPLE_SHEET_MM = (scan_examples.TAG_PHOTOS, scan_examples.PHOTO_SIZE,
                                                                    scan_examples.TAG_FOV, scan_examples.TAG_SHEET_MM)


def example_cameras(count: int = EXAMPLE_PHOTOS, size: tuple[int, int] | None = None) -> list:
    """The true cameras (:class:`~mi_svbrdf.data.tag_photos.TrueCamera`) of the example's photos (at ``size``,
    default :data:`EXAMPLE_PHOTO_SIZE`)."""
    return scan_examples.tag_cameras(count, size)


def example_tag_photos(folder: Path) -> list[Path]:
    """The Mitsuba photos of a material under the print (:func:`example_cameras`) in ``folder``: rendered once and
    cached (:func:`mi_svbrdf.data.scan_examples.example_photos`; JPEG, no EXIF: the camera is calibrated from the
    tags)."""
    return scan_examples.example_photos("tags", folder)


def photo_size(path: str) -> str:
    """``WxH`` of a photo file."""
    from PIL import Image

    with Image.open(path) as img:
        return f"{img.width}x{img.height}"


def error_line(result: Any) -> str:
    """The terminal line of a photo that failed (a :class:`~mi_svbrdf.geometry.rectify.PhotoResult`): its error and,
    when one was drawn, its overlay."""
    overlay = result.entry.get("overlay")
    return f"mi-svbrdf rectify: error: {result.error}" + (f" (see {overlay})" if overlay else "")


#: ``--size``'s help, rectify's and scan's.
SIZE_HELP = (f"side of the rectified images in pixels; auto (default): what the photos resolve across the sample (the "
             f"median over the photos of the window's shortest side in photo pixels, fewer for blurry edges), rounded "
             f"down to a multiple of {AUTO_STEP}, at least {AUTO_MIN}, at most {DEFAULT_MAX_SIDE}")


def size_type(text: str) -> str | int:
    """``--size``: ``auto`` or an int >= 16."""
    return "auto" if text == "auto" else int_at_least(16)(text)


def options_size(size: str | int) -> int | None:
    """:attr:`RectifyOptions.size` of a ``--size`` value (None: auto)."""
    return None if size == "auto" else int(size)


def said_size(out: str | Path) -> None:
    """Say on stderr what ``--size auto`` chose (``rectify.json``'s ``size_auto``), when it chose."""
    report = Path(out) / "rectify.json"
    words = json.loads(report.read_text(encoding="utf-8")).get("size_auto") if report.is_file() else None
    if words:
        print(f"mi-svbrdf rectify: {words}", file=sys.stderr)


def run_tags(args: argparse.Namespace, owned: Sequence[str]) -> int:
    """``mi-svbrdf rectify --frame tags``; the exit code (0 all rectified, 1 some failed, 2 none)."""
    from mi_svbrdf.geometry.rectify import RectifyOptions
    from mi_svbrdf.geometry.tag_rectify import rectify_tag_photos, terminal_line
    from mi_svbrdf.geometry.tags import TagSheet

    example = args.photos == ["example"]
    if args.corners:
        raise ValueError("--corners: expected with the paper frame only (--frame tags finds the tags' corners)")
    if args.frame_size is None and not example:
        raise ValueError("--frame-size: expected the tag ring's outer size S in mm with --frame tags (measure it on "
                         "the print, outer edge to outer edge of the tags), got none")
    if args.frame_size is not None and len(args.frame_size) != 1:
        raise ValueError(f"--frame-size: expected one number with --frame tags (the ring's outer size S in mm), got "
                         f"{','.join(f'{v:g}' for v in args.frame_size)}")
    size_mm = EXAMPLE_SHEET_MM if args.frame_size is None else args.frame_size[0]
    sheet = TagSheet(size_mm, args.depth or 0.0)
    options = RectifyOptions(size=options_size(args.size), fov_deg=args.fov, flash_offset_mm=tuple(args.flash_offset),
                             intensity=args.intensity)
    photos = [] if example else expand_photos(args.photos)
    outputs = owned if example else [o for o in owned if not o.startswith("example_")]

    def claim() -> None:  # once the photos are read, right before the first write (Ctrl-C before: nothing written)
        replace_outputs(args, args.out, outputs, keep=photos)

    if example:
        claim()
        photos = [str(p) for p in example_tag_photos(Path(args.out) / "example_photos")]
        print(f"example: {len(photos)} synthetic photos of the tag print (S = {size_mm:g} mm, {photo_size(photos[0])} "
              f"JPEG) in {Path(args.out) / 'example_photos'}/")
    results = rectify_tag_photos(photos, args.out, options, sheet, before_writing=None if example else claim)
    said_size(args.out)
    for r in results:
        if r.ok:
            print(terminal_line(r))
    for note in json.loads((Path(args.out) / "rectify.json").read_text(encoding="utf-8")).get("notes", []):
        print(f"mi-svbrdf rectify: note: {note}", file=sys.stderr)
    failed = [r for r in results if not r.ok]
    for r in failed:
        print(error_line(r), file=sys.stderr)
    if len(failed) == len(results):
        return 2
    return 1 if failed else 0
