"""``mi-svbrdf view``: a self-contained HTML page that draws a material under a movable point light.

Run ``mi-svbrdf view --help`` for the options; the page is :func:`mi_svbrdf.io.viewer.viewer_html`.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch

from mi_svbrdf.cli.common import add_command, finite_float, float_at_least, floats, material_from_spec, standalone
from mi_svbrdf.data import examples
from mi_svbrdf.io.material_io import read_distribution
from mi_svbrdf.io.viewer import (
    DEFAULT_INTENSITY,
    DEFAULT_LIGHT,
    DEFAULT_VIEW,
    PAGE_NAME,
    SHOW,
    fragment,
    is_viewer_page,
    write_viewer,
)

DESCRIPTION = f"""\
Write one HTML page that draws a material with WebGL2, using the same BRDF model (GGX, or Beckmann for a material folder that records it) and point light
(with 1/d^2 fall-off) as mi_svbrdf's texel renderer. The page is self-contained: the four maps
are embedded (8-bit PNG; albedos sRGB-encoded) and it makes no network request; open it in any
browser with WebGL2.

In the page: drag on the image to move the light over the sample (the wheel or the height
slider sets its height), the exposure slider scales the light (stops), the 'show' buttons
switch between the rendering and each map (normal, diffuse, roughness, specular as stored).
The URL fragment sets and records the state, e.g.
  page.html#light=0.3,0.2,2&exposure=1&show=render
(keys: light, view, intensity, exposure, show, scale, ui=0 for the bare canvas at 1:1).

MATERIAL is a material folder (normal/diffuse/roughness/specular .png or .exr, as written by
capture, optimize or `mi-svbrdf materials make --format folder`), a thesis strip .png, or example:NAME
({', '.join(sorted(examples.EXAMPLES))}).
"""
OUTPUTS = f"""\
Writes:
  -o/--out FILE   the page (default: MATERIAL/{PAGE_NAME} for a folder, else ./{PAGE_NAME}); -o takes a file,
                  not a folder. An existing file there is replaced only when it is a page this command
                  wrote (else refused; --force replaces it)
"""
EXAMPLES = ("mi-svbrdf view example:metal_plate -o out/view.html",
            "mi-svbrdf view out/optimize/material --light 0.5,0.5,1.5 --exposure 1")
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"


def load(spec: str) -> tuple[torch.Tensor, str, Path]:
    """Maps, title and default output path of a ``MATERIAL`` argument (folder, strip .png or example:NAME)."""
    maps = material_from_spec(spec)
    path = Path(spec)
    if spec.startswith("example:"):
        return maps, spec.split(":", 1)[1], Path(PAGE_NAME)
    if path.is_dir():
        return maps, path.resolve().name, path / PAGE_NAME
    return maps, path.stem, Path(PAGE_NAME)


def check_page(out: Path, force: bool, option: str = "-o/--out") -> None:
    """Whether the page may be written to ``out``, before any work: a ValueError naming ``option`` when ``out`` is
    a folder (-o takes a file), or an existing file that is not a page this command wrote (the user's own)
    without ``force`` (the rule of the folders, :func:`mi_svbrdf.cli.common.check_folder`)."""
    if out.is_dir():
        raise ValueError(f"{option}: expected the page's file name (-o takes a file, e.g. {out / PAGE_NAME}), "
                         f"got the folder {out}/")
    if out.exists() and not force and not is_viewer_page(out):
        raise ValueError(f"{option}: expected a new file or a page `mi-svbrdf view` wrote, got the existing file "
                         f"{out}, which is not one (choose another file, or --force to replace it)")


def run_cli(args: argparse.Namespace) -> int:
    """The ``view`` command: read the material, write the page, print where."""
    if args.out:  # before reading the material
        check_page(Path(args.out).expanduser(), args.force)
    maps, title, default_out = load(args.material)
    out = Path(args.out).expanduser() if args.out else default_out
    check_page(out, args.force, "-o/--out" if args.out else "-o/--out (its default)")
    out.parent.mkdir(parents=True, exist_ok=True)
    distribution = read_distribution(args.material) if Path(args.material).is_dir() else "ggx"
    write_viewer(out, maps, title=args.title or title, light=args.light, view=args.view,
                 intensity=args.intensity, exposure=args.exposure, show=args.show, distribution=distribution)
    size = out.stat().st_size
    print(f"wrote {out} ({size / 1024:.0f} KiB, {maps.shape[-1]}x{maps.shape[-2]} texels); open it in a browser, "
          f"e.g. {out.resolve().as_uri()}#{fragment(args.light, exposure=args.exposure, show=args.show)}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``view`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "view", help="a self-contained WebGL2 page of a material (drag the light)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("material", metavar="MATERIAL", help="material folder, strip .png or example:NAME")
    p.add_argument("-o", "--out", default=None, metavar="FILE",
                   help=f"the HTML page to write (default: MATERIAL/{PAGE_NAME} for a folder)")
    p.add_argument("--light", type=floats(3, positive_z=True), default=",".join(f"{v:g}" for v in DEFAULT_LIGHT), metavar="X,Y,Z",
                   help="initial light position, half sample widths (default: %(default)s)")
    p.add_argument("--view", type=floats(3, positive_z=True), default=",".join(f"{v:g}" for v in DEFAULT_VIEW), metavar="X,Y,Z",
                   help="camera position the shading looks from (default: %(default)s)")
    p.add_argument("--intensity", type=float_at_least(0.0), default=DEFAULT_INTENSITY,
                   help="light intensity I (default: %(default)s: unit irradiance at the centre from height 2)")
    p.add_argument("--exposure", type=finite_float, default=None,
                   help="initial exposure in stops (default: 0, or lower where the sample would be white under the "
                        "default light: a bright sample)")
    p.add_argument("--show", choices=SHOW, default="render", help="initial view (default: render)")
    p.add_argument("--title", default=None, help="page title (default: the material's name)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing file at -o/--out that is not a page this command wrote (without "
                        "--force it is refused before any work)")
    p.set_defaults(func=run_cli)


def main(argv: list[str] | None = None) -> int:
    """Entry point for ``python -m mi_svbrdf.cli.view view MATERIAL ...`` (``argv`` starts with ``view``)."""
    return standalone(add_parser, argv)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
