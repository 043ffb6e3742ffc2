"""``mi-svbrdf capture-file make`` / ``import``: a capture file (``capture.json``) from photos and the camera
and flash you state, or from another lab's capture folder (:mod:`mi_svbrdf.io.capture_import`).

The capture file is :mod:`mi_svbrdf.io.calibrated_photos`'s (version 1); ``mi-svbrdf optimize
--capture`` reads it. This command converts the photos (:func:`mi_svbrdf.io.photos.load_photo`:
EXIF orientation, sRGB decoding, crop, centre square; then one size) and writes them beside the
file with the calibration the options state, the same for every photo unless an option is
repeated once per photo.
"""
from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mi_svbrdf.cli.common import (
    add_command,
    command_group,
    expand_photos,
    float_at_least,
    float_between,
    floats,
    int_at_least,
    replace_outputs,
    standalone,
)
from mi_svbrdf.io.calibrated_photos import (
    CAPTURE_NAME,
    DEFAULT_MAX_SIDE,
    ENCODINGS,
    CameraSpec,
    CaptureSpec,
    ImageSpec,
    LightSpec,
    save_capture,
)
from mi_svbrdf.io.photos import MIN_SIZE, check_consistent, exposure_notes, load_photo, parse_crop, prepare

DESCRIPTION = """\
Write a capture file (capture.json, version 1) for `mi-svbrdf optimize` from your photos and the
camera and flash you state, with the photos converted beside it.

Positions are in the sample's frame: the sample is the square [-1, 1]^2 at z = 0 (x right, y up
in the photo, z towards the camera), so the unit is half the sample's width; with
--sample-width MM they are in millimetres instead (the sample's width in mm). Give --camera
and --flash once (every photo) or once per photo, in the order of the photos. The flash is
isotropic (no cone), at the camera unless --flash; its intensity is |flash|^2 in the capture's
units (a white matte sample facing the flash at the centre would read 1) unless --intensity:
the fit's albedos scale with it.

Rectified photos (the default) show exactly the sample, square-on or warped to it (what
`mi-svbrdf rectify` writes): the fit renders them texel by texel. --perspective: each photo is
what a pinhole camera at --camera, aimed at the sample's centre with field of view --fov, sees
(rendered through Mitsuba). Each photo is turned upright (EXIF), decoded from sRGB (--linear
for linear files), cropped (--crop x,y,w,h, then the centre square) and resized to --size.
Check the printed camera and flash of each photo, edit capture.json where they differ, then
run `mi-svbrdf optimize --capture OUT -o FIT`.
"""
OUTPUTS = """\
Writes to -o/--out:
  capture.json   version 1: each photo's file, encoding, rectified, camera (position, fov) and flash
  000.png ...    the converted photos (8-bit sRGB; --encoding srgb16: 16-bit; linear_exr: NNN.exr)
"""
EXAMPLES = ("mi-svbrdf capture-file make example --camera 0,0,2.1445 --fov 50 -o out/capture-file",
            ("mi-svbrdf capture-file make photos/ --sample-width 150 --camera 0,0,400 --flash 20,0,400 "
             "--fov 65 -o out/my-capture"))
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new capture file replaces a previous one's.
OWNED = (CAPTURE_NAME, *(f"{digits}.{ext}" for digits in ("[0-9]" * 3, "[0-9]" * 4) for ext in ("png", "exr")))
#: Largest default side of the converted photos (--size).
DEFAULT_MAX_SIZE = DEFAULT_MAX_SIDE


def _per_photo(values: Sequence[tuple[float, ...]] | None, n: int, option: str) -> list[tuple[float, ...]] | None:
    """One value per photo from an option given once or ``n`` times (None when not given)."""
    if not values:
        return None
    if len(values) not in (1, n):
        raise ValueError(f"{option}: expected one value or one per photo ({n}), got {len(values)}")
    return list(values) * n if len(values) == 1 else list(values)


def _intensity(text: str) -> tuple[float, float, float]:
    """``I`` or ``R,G,B`` (values >= 0) -> RGB (an argparse type)."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) == 1:
        values *= 3
    if len(values) != 3 or not all(math.isfinite(v) and v >= 0 for v in values) or max(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected I or R,G,B (numbers >= 0, not all 0), got {text!r}")
    return values  # type: ignore[return-value]


def make_spec(n: int, args: argparse.Namespace, suffix: str) -> CaptureSpec:
    """The :class:`CaptureSpec` of ``n`` photos named ``000.SUFFIX`` ... from the options."""
    scale = 2.0 / args.sample_width if args.sample_width else 1.0
    cameras = _per_photo(args.camera, n, "--camera")
    flashes = _per_photo(args.flash, n, "--flash") or cameras
    intensities = _per_photo(args.intensity, n, "--intensity")
    images = []
    for k in range(n):
        camera = tuple(v * scale for v in cameras[k])
        flash = tuple(v * scale for v in flashes[k])
        intensity = intensities[k] if intensities else (sum(v * v for v in flash),) * 3
        images.append(ImageSpec(f"{k:03d}.{suffix}", args.encoding, not args.perspective,
                                CameraSpec(camera, args.fov), LightSpec(flash, tuple(intensity))))
    return CaptureSpec(tuple(images))


def cmd_make(args: argparse.Namespace) -> int:
    """Run ``capture-file make``: convert the photos, write them and ``capture.json``; returns 0."""
    files = expand_photos(args.photos)
    crop = parse_crop(args.crop) if args.crop else None
    photos = [load_photo(f, linear=args.linear, crop=crop) for f in files]
    check_consistent(photos, crop=crop is not None, full_resolution=False)
    size = args.size or min(DEFAULT_MAX_SIZE, min(p.image.shape[0] for p in photos))
    spec = make_spec(len(photos), args, "exr" if args.encoding == "linear_exr" else "png")
    images = prepare(photos, size)[0]
    if args.encoding != "linear_exr":
        images = images.clamp(0.0, 1.0)
    out = Path(args.out)
    replace_outputs(args, out, OWNED, keep=files)
    save_capture(out / CAPTURE_NAME, spec, images)
    for note in exposure_notes(images, files, result="a fit of this capture"):
        print(f"mi-svbrdf capture-file make: {note}", file=sys.stderr)
    for src, im in zip(files, spec.images):
        light = im.light
        print(f"{im.file} <- {src}: camera {_fmt(im.camera.position)}, flash {_fmt(light.position)}, "
              f"intensity {_fmt(light.intensity)}")
    print(f"wrote {out / CAPTURE_NAME} ({len(photos)} photos, {size} px, {args.encoding}, "
          f"{'perspective' if args.perspective else 'rectified'}); check each camera and flash, then: "
          f"mi-svbrdf optimize --capture {out} -o FIT")
    return 0


IMPORT_DESCRIPTION = """\
Write a capture file (capture.json, version 1) for `mi-svbrdf optimize` from a capture folder of
another lab's tools: the MaterialGAN / svbrdf-diff-renderer layout (parameters.json or optim.json
with image_size or im_size, camera_pos, light_pos, light_pow, idx, target_dir; or the older
camera_pos.txt, light_pos.txt, image_size.txt, light_power.txt), rectified photos 00.png, 01.png ...
The photos are looked for in target_dir first, then beside the JSON file (as such data sets are
often unpacked); the command says which folder it used.

Positions in cm become the project's units (x_cm * 2 / width_cm: the sample is [-1, 1]^2) and the
flash power its intensity (light_pow * (2 / width_cm)^2 / pi). The photos are converted beside
capture.json (sRGB decoded, resized to --size).
"""
IMPORT_OUTPUTS = """\
Writes to -o/--out (or beside FILE.json):
  capture.json   version 1: each photo's file, encoding, rectified, camera (position, fov) and flash
  000.png ...    the converted photos (8-bit sRGB)
"""
IMPORT_EXAMPLES = ("mi-svbrdf capture-file import their_capture/ --size 256 -o out/their_capture",)


def cmd_import(args: argparse.Namespace) -> int:
    """Run ``capture-file import``: read a MaterialGAN-layout folder, write ``capture.json`` and the photos; returns 0."""
    from mi_svbrdf.io.capture_import import foreign_photos, read_foreign_capture

    foreign = read_foreign_capture(args.folder)
    target = Path(args.out) if Path(args.out).suffix.lower() == ".json" else Path(args.out) / CAPTURE_NAME
    spec, images, size = foreign_photos(foreign, args.size, max_size=DEFAULT_MAX_SIZE)
    replace_outputs(args, target.parent, (target.name, *OWNED[1:]), keep=foreign.photos)
    save_capture(target, spec, images)
    for note in exposure_notes(images, [str(f) for f in foreign.photos], result="a fit of this capture"):
        print(f"mi-svbrdf capture-file import: {note}", file=sys.stderr)
    light = spec.images[0].light
    if foreign.photo_note:  # which folder the photos came from, when target_dir names one
        print(foreign.photo_note)
    print(f"wrote {target} ({spec.n_images} photos, {size} px) from {foreign.source}: sample "
          f"{foreign.width_cm:g} cm wide, flash intensity {_fmt(light.intensity)}; then: "
          f"mi-svbrdf optimize --capture {target} -o FIT")
    return 0


#: The command that wrote a capture file (its folder's record) -> how to make its photos smaller.
SMALLER_PHOTOS = {"mi-svbrdf rectify": "a smaller --size when rectifying",
                  "mi-svbrdf capture-file make": "a smaller --size in capture-file make",
                  "mi-svbrdf capture-file import": "a smaller --size in capture-file import"}


def smaller_photos_advice(capture_file: str | Path) -> str:
    """How to fit fewer texels of the capture file ``capture_file``: the ``--size`` of the command that wrote it
    (its folder's :data:`~mi_svbrdf.cli.common.OWNER_FILE`, or ``rectify.json`` beside it); ``""`` when unknown."""
    from mi_svbrdf.cli.common import folder_owner

    folder = Path(capture_file).parent
    owner = folder_owner(folder)
    command = owner["command"] if owner else "mi-svbrdf rectify" if (folder / "rectify.json").is_file() else ""
    return SMALLER_PHOTOS.get(command, "")


def _fmt(values: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in values) + ")"


def add_parser(subparsers: Any) -> None:
    """Add the ``capture-file`` command (with its ``make`` subcommand) to ``subparsers``."""
    sub = command_group(subparsers, "capture-file", "capture files for optimize (capture-file make / import ...)",
                        "Capture files (capture.json): photos with their cameras and flashes, for mi-svbrdf optimize.")
    p = add_command(sub, "make", help="write capture.json from photos and the camera and flash you state",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("photos", nargs="+", metavar="PHOTO",
                   help="photo files or folders of them; 'example' / 'example:multi': the bundled photos")
    p.add_argument("-o", "--out", required=True, help="output folder (capture.json and the photos)")
    p.add_argument("--camera", type=floats(3, positive_z=True), action="append", required=True, metavar="X,Y,Z",
                   help="camera position (once, or once per photo)")
    p.add_argument("--flash", type=floats(3, positive_z=True), action="append", metavar="X,Y,Z",
                   help="flash position (once, or once per photo; default: at the camera)")
    p.add_argument("--intensity", type=_intensity, action="append", metavar="I|R,G,B",
                   help="flash intensity (once, or once per photo; default: |flash|^2 in sample units)")
    p.add_argument("--fov", type=float_between(0.0, 180.0, open_ends=True, unit="degrees"), default=40.0,
                   help="the camera's full field of view across the (square) photo, degrees (default 40)")
    p.add_argument("--sample-width", type=float_at_least(0.0, inclusive=False), default=None, metavar="MM",
                   help="the sample's width in mm: --camera and --flash are then in mm")
    p.add_argument("--perspective", action="store_true",
                   help="the photos are perspective views, not rectified to the sample (Mitsuba path)")
    p.add_argument("--crop", default=None, metavar="X,Y,W,H",
                   help="region of each upright photo (pixels) before the centre square")
    p.add_argument("--size", type=int_at_least(MIN_SIZE), default=None,
                   help=f"side of the written photos (default: the smallest photo's square, at most {DEFAULT_MAX_SIZE})")
    p.add_argument("--linear", action="store_true", help="the files hold linear values (no sRGB decoding)")
    p.add_argument("--encoding", choices=ENCODINGS, default="srgb8", help="how the photos are written (default srgb8)")
    p.set_defaults(func=cmd_make, _replaces=True, _owns=OWNED)
    p = add_command(sub, "import", help="write capture.json from a MaterialGAN-layout capture folder",
                    description=IMPORT_DESCRIPTION, outputs=IMPORT_OUTPUTS, example_lines=IMPORT_EXAMPLES)
    p.add_argument("folder", metavar="DIR", help="the capture folder (parameters.json, optim.json or the .txt files)")
    p.add_argument("-o", "--out", required=True,
                   help="output folder (capture.json and the photos), or a FILE.json (the photos beside it)")
    p.add_argument("--size", type=int_at_least(MIN_SIZE), default=None,
                   help=f"side of the written photos (default: the photos' side, at most {DEFAULT_MAX_SIZE})")
    p.set_defaults(func=cmd_import, _replaces=True, _owns=OWNED,
                   _out_file=lambda args: Path(args.out).suffix.lower() == ".json")


def main(argv: list[str] | None = None) -> int:
    """Run ``capture-file ...`` on its own: ``main(["capture-file", "make", ...])`` (also ``python -m``)."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
