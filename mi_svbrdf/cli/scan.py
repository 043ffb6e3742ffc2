"""``mi-svbrdf scan``: photos of the AprilTag print or the paper frame to a material, in one command.

It runs ``rectify``, ``optimize``, ``export`` and ``view`` as those commands run (their own parsers and
functions, each into its own sub-folder of -o/--out, which that command owns: :data:`STEPS`), then writes
``index.html``, one static page of every step's pictures with relative links (:func:`index_html`).
"""
from __future__ import annotations

import argparse
import html
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

from mi_svbrdf.cli import export as export_cli
from mi_svbrdf.cli import interrupt
from mi_svbrdf.cli import optimize as optimize_cli
from mi_svbrdf.cli import rectify as rectify_cli
from mi_svbrdf.cli import rectify_tags as rectify_tags_cli
from mi_svbrdf.cli.common import (
    INPUT_ERRORS,
    INTERRUPTED,
    OWNER_FILE,
    add_command,
    bars_for_terminals,
    budget_seconds,
    check_out,
    expand_photos,
    float_at_least,
    float_between,
    floats,
    one_line,
    record_written,
    release_unused,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core.device import DEVICE_HELP
from mi_svbrdf.optim.fit import DEFAULT_BUDGET_S, LADDER_BASE, MAX_DEFAULT_BUDGET_S
from mi_svbrdf.io.atomic import atomic_path, write_json, write_text
from mi_svbrdf.io.viewer import PAGE_NAME

#: The steps in the order they run: (command, its sub-folder or file under -o/--out).
STEPS = (("rectify", "rectified"), ("optimize", "fit"), ("export", "export"), ("view", PAGE_NAME))
#: The page of every step's pictures, and the run's record.
INDEX_NAME, SUMMARY_NAME = "index.html", "summary.json"
#: The photos' small copies the page shows (long side in pixels, JPEG quality).
THUMB_FOLDER, THUMB_SIDE, THUMB_QUALITY = "photos", 640, 85
#: The small copies of the steps' larger pictures the page shows (each links its full picture): folder, long side.
SMALL_FOLDER, SMALL_SIDE = "small", 512

DESCRIPTION = """\
From flash photos of a sample under the AprilTag print (--frame tags --frame-size S) or in the
paper frame (the default) to a material, in one command: it runs

  1. mi-svbrdf rectify PHOTO ... -o OUT/rectified     (find the frame, rectify, recover the cameras)
  2. mi-svbrdf optimize --capture OUT/rectified/capture.json -o OUT/fit [--budget-s B]
  3. mi-svbrdf export OUT/fit/material --format gltf -o OUT/export
  4. mi-svbrdf view OUT/fit/material -o OUT/view.html

as those commands do (the same code, in this process), then writes OUT/index.html: one static page
that shows the photos, the rectified views, the maps, the selection chart, the uncertainty maps and
the re-renderings, with a relative link to every file (copy OUT anywhere: the page still works).

Each step's folder belongs to that step's command, which you can run again on its own (e.g.
optimize with a longer --budget-s into OUT/fit). OUT belongs to scan: run again, scan replaces its
own previous outputs; a folder of another command, or one holding files with scan's output names
that no command recorded (your own), is refused before any work (--force: they are replaced).

The options of rectify pass through (--frame, --frame-size, --depth, --size, --fov,
--flash-offset, --intensity, --corners: see mi-svbrdf rectify --help); --budget-s is the fit's
time budget. A photo rectify cannot use is reported and left out; when none is rectified, scan
stops after step 1 (OUT/index.html shows why). PHOTO 'example' renders synthetic photos (five of the
tag print with --frame tags, three in the paper frame; 4032x3024 JPEG as a phone takes them, rendered
once into the cache MI_SVBRDF_CACHE) into OUT/rectified/example_photos/.

A line on stderr says when each step starts; each step prints its own lines. Exit code 0: every
photo was rectified and every step ran; 1: some photos were left out; 2: bad input, or no photo
rectified.
"""
OUTPUTS = f"""\
Writes to -o/--out:
  index.html        the page: photos, rectified views, maps, selection, uncertainty, re-renderings,
                    links to every file (relative; pictures a step did not write are not shown)
  photos/NNN.jpg    a small copy of photo NNN (upright, long side {THUMB_SIDE} px), for the page
  small/*.png       small copies (long side {SMALL_SIDE} px) of the steps' larger pictures, for the page
  rectified/        mi-svbrdf rectify's folder: NNN.png, overlay_NNN.png, rectify.json,
                    capture.json, summary.json (example_photos/ with PHOTO example)
  fit/              mi-svbrdf optimize's folder: material/ (the maps + material.json), renders/NNN.png,
                    selection.png, uncertainty/*.png, loss.png, history.csv, view.html, summary.json
  export/           mi-svbrdf export's folder: material.gltf, material.bin, textures/*.png, export.json
  view.html         mi-svbrdf view's page of the material: drag the light
  summary.json      each step: its command line, folder, exit code and seconds; the photos
"""
EXAMPLES = ("mi-svbrdf scan example --frame tags -o out/scan",
            "mi-svbrdf scan IMG_*.jpg --frame tags --frame-size 180 -o out/scan",
            "mi-svbrdf scan photos/ --budget-s 120 -o out/scan_frame")
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"


def _under(folder: str, patterns: Sequence[str]) -> tuple[str, ...]:
    return tuple(f"{folder}/{p}" for p in patterns)


#: The files under -o/--out (patterns relative to it): scan's own and its steps' (a new run replaces a previous
#: one's; each step's folder also records its own command).
OWNED = (INDEX_NAME, SUMMARY_NAME, PAGE_NAME, f"{SMALL_FOLDER}/*.png", f"{THUMB_FOLDER}/[0-9][0-9][0-9].jpg",
         f"{THUMB_FOLDER}/[0-9][0-9][0-9][0-9].jpg",
         *_under("rectified", rectify_cli.OWNED + rectify_cli.OWNED_EXAMPLE),
         *_under("fit", optimize_cli.OWNED), *_under("export", export_cli.OWNED))


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``scan`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "scan", help="photos of the tag print or paper frame to a material: rectify, "
                                             "optimize, export, view, one index.html",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("photos", nargs="+", metavar="PHOTO",
                   help="flash photos (any orientation, EXIF honoured) or folders of them; 'example': synthetic ones")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--frame", choices=("paper-frame", "tags"), default="paper-frame",
                   help="what surrounds the sample: the paper frame (default) or the AprilTag print")
    p.add_argument("--frame-size", metavar="W,H|S", default=None, type=rectify_cli._frame_size,
                   help="paper frame: the window's inner size in mm (W,H); tags: the ring's outer size S in mm "
                        "(required with your own photos)")
    p.add_argument("--depth", type=float_at_least(0.0, unit="mm"), default=None, metavar="MM",
                   help="--frame tags: height of the tag plane above the sample in mm (default 0)")
    p.add_argument("--size", type=rectify_tags_cli.size_type, default="auto", metavar="auto|N",
                   help=f"rectify's --size: {rectify_tags_cli.SIZE_HELP}")
    p.add_argument("--fov", type=float_between(0.0, 180.0, open_ends=True, unit="degrees"), default=None,
                   metavar="DEG", help="field of view across the photo's long side (rectify's --fov)")
    p.add_argument("--flash-offset", metavar="X,Y,Z", default=None, type=floats(3),
                   help="flash position from the lens in mm: x right, y up, z forward (default 0,0,0; as rectify's)")
    p.add_argument("--intensity", type=float_at_least(0.0, inclusive=False), default=None,
                   help="flash intensity written to capture.json (default: |flash|^2 per photo)")
    p.add_argument("--corners", metavar="FILE.json", default=None,
                   help="paper frame: the corners of some photos (rectify's --corners)")
    p.add_argument("--budget-s", "--budget", dest="budget_s", default=None, metavar="SECONDS",
                   type=budget_seconds,
                   help=f"the fit's wall-time limit in seconds (optimize's --budget-s; default: optimize's, "
                        f"{DEFAULT_BUDGET_S:g} for rectified photos of {LADDER_BASE} px or less, in proportion to their "
                        f"side above, at most {MAX_DEFAULT_BUDGET_S:g}; 0 or inf: no limit)")
    p.add_argument("--device", default="cpu", help=f"the fit's device (optimize's --device). {DEVICE_HELP}")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def _number(value: float) -> str:
    """``value`` as a command line writes it: ``60``, ``0.5``, ``inf`` (every digit kept)."""
    text = f"{value:g}"
    return text if float(text) == value else repr(value)


def step_argv(args: argparse.Namespace, out: Path) -> dict[str, list[str]]:
    """The command line of each step (:data:`STEPS`; without ``mi-svbrdf``) for the options of ``args``."""
    rectify = ["--frame", args.frame, "--size", str(args.size), "-o", str(out / "rectified")]
    for flag, value in (("--frame-size", args.frame_size), ("--depth", args.depth), ("--fov", args.fov),
                        ("--flash-offset", args.flash_offset), ("--intensity", args.intensity),
                        ("--corners", args.corners)):
        if value is not None:
            rectify += [flag, ",".join(_number(v) for v in value) if isinstance(value, tuple) else _number(value)]
    dashed = any(p.startswith("-") for p in args.photos)  # a file named like an option: after "--"
    rectify = [*args.photos, *rectify] if not dashed else [*rectify, "--", *args.photos]
    optimize = ["--capture", str(out / "rectified" / "capture.json"), "-o", str(out / "fit"),
                *(["--budget-s", _number(args.budget_s)] if args.budget_s is not None else []), "--device", args.device]
    material = str(out / "fit" / "material")
    steps = {"rectify": rectify, "optimize": optimize + (["--no-progress"] if args.no_progress else []),
             "export": [material, "--format", "gltf", "-o", str(out / "export")],
             "view": [material, "-o", str(out / PAGE_NAME), "--title", f"scan: {out.resolve().name}"]}
    if args.force:
        for argv in steps.values():
            argv.append("--force")
    return steps


def parse_step(name: str, argv: Sequence[str]) -> argparse.Namespace:
    """The parsed arguments of the step ``name`` (``mi-svbrdf NAME ARGV``), by the command's own parser."""
    from mi_svbrdf.cli import build_parser

    step = build_parser([name]).parse_args([name, *argv])
    bars_for_terminals(step)
    return step


def check_step(name: str, step: argparse.Namespace) -> None:
    """Whether the step may write where it will, before any work (the folder rules of each command)."""
    if name == "view":
        from mi_svbrdf.cli.view import check_page

        check_page(Path(step.out), step.force)
    else:
        check_out(step)


def run_step(step: argparse.Namespace) -> int:
    """Run one step as :func:`mi_svbrdf.cli.common.run` runs its command (its folder claimed and recorded), but
    its errors and Ctrl-C go to scan's own handling; its exit code."""
    try:
        check_out(step)
        return step.func(step)
    except BaseException:
        release_unused(step)
        raise
    finally:
        record_written(step)


def check_rectify_options(args: argparse.Namespace) -> None:
    """The options rectify would refuse, refused before scan touches -o/--out."""
    example = args.photos == ["example"]
    if args.frame == "tags":
        if args.corners:
            raise ValueError("--corners: expected with the paper frame only (--frame tags finds the tags' corners)")
        if args.frame_size is None and not example:
            raise ValueError("--frame-size: expected the tag ring's outer size S in mm with --frame tags (measure it "
                             "on the print, outer edge to outer edge of the tags), got none")
    elif args.depth is not None:
        raise ValueError("--depth: expected with --frame tags only (the paper frame lies on the sample)")


def write_thumbnails(out: Path, photos: Sequence[str], inputs: Sequence[str]) -> dict[int, str]:
    """A small upright sRGB copy of each photo (``photos/NNN.jpg``) that can be read: ``{index: relative path}``.
    A photo that cannot be read has none (rectify's report says why)."""
    import numpy as np
    from PIL import Image

    from mi_svbrdf.io.material_io import srgb_encode
    from mi_svbrdf.io.photos import load_photo

    kept = {Path(p).resolve() for p in inputs}
    written = {}
    for i, photo in enumerate(photos):
        rel = f"{THUMB_FOLDER}/{i:03d}.jpg"
        target = out / rel
        if target.resolve() in kept:
            raise ValueError(f"PHOTO: expected photos outside {out / THUMB_FOLDER}/, where scan writes its copies, "
                             f"got {photo}")
        thumb = _jpeg_thumbnail(Path(photo))
        if thumb is None:
            try:
                image = load_photo(photo, square=False).image
            except (ValueError, OSError):
                continue
            codes = (np.clip(srgb_encode(image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
            thumb = Image.fromarray(codes)
            thumb.thumbnail((THUMB_SIDE, THUMB_SIDE), Image.Resampling.LANCZOS)
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(target) as tmp:
            thumb.save(tmp, format="JPEG", quality=THUMB_QUALITY)
        written[i] = rel
    return written


def _jpeg_thumbnail(path: Path) -> Any:
    """The thumbnail of an 8-bit RGB JPEG straight from Pillow (decoded at a reduced scale, upright, the sRGB codes
    kept): a 12 MP phone photo in a fraction of a second, without decoding it to linear and back. None for any other
    file (:func:`~mi_svbrdf.io.photos.load_photo` reads those)."""
    from PIL import Image, ImageOps

    if path.suffix.lower() not in (".jpg", ".jpeg"):
        return None
    try:
        with Image.open(path) as img:
            if img.format != "JPEG" or img.mode != "RGB":
                return None
            img.draft("RGB", (THUMB_SIDE, THUMB_SIDE))
            thumb = ImageOps.exif_transpose(img)
            thumb.thumbnail((THUMB_SIDE, THUMB_SIDE), Image.Resampling.LANCZOS)
            return thumb
    except (OSError, SyntaxError, ValueError):
        return None


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


# --- the index page ---------------------------------------------------------------------------------

#: The page's style (no script, no request: a static page).
STYLE = """\
body { font: 14px/1.45 system-ui, sans-serif; margin: 24px auto; max-width: 1320px; padding: 0 16px;
       color: #222; background: #fafafa; }
h1 { font-size: 22px; margin-bottom: 4px; } h2 { font-size: 17px; margin: 28px 0 6px;
  border-bottom: 1px solid #ddd; padding-bottom: 3px; }
p.lead { color: #555; margin-top: 0; } p.note { color: #555; font-size: 13px; margin: 4px 0 8px; }
nav a { margin-right: 14px; }
.grid { display: flex; flex-wrap: wrap; gap: 12px; }
figure { margin: 0; background: #fff; border: 1px solid #e2e2e2; padding: 6px; }
figure img { display: block; width: 100%; height: auto; }
figcaption { font-size: 12px; color: #444; margin-top: 4px; overflow-wrap: anywhere; }
figure.photo { width: 240px; } figure.rect, figure.map { width: 200px; } figure.unc { width: 296px; }
figure.render { width: 620px; } figure.wide img { width: auto; max-width: 100%; }
.rect img, .map img { image-rendering: pixelated; }
.bad { color: #a11; }
table { border-collapse: collapse; font-size: 13px; } td, th { border: 1px solid #ddd; padding: 3px 8px;
  text-align: left; } code { font-size: 12px; }
"""


def _href(rel: str) -> str:
    return html.escape(quote(rel), quote=True)


def _link(rel: str, text: str | None = None) -> str:
    return f'<a href="{_href(rel)}">{html.escape(text or rel)}</a>'


class _Page:
    """The index page's parts, pictures and links only to files that exist under ``out``."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.parts: list[str] = []

    def has(self, rel: str) -> bool:
        return (self.out / rel).is_file()

    def figure(self, rel: str, caption: str, css: str = "", link: str | None = None) -> str:
        """A picture with its caption, linked to ``link`` (default: itself); empty when the picture is missing."""
        if not self.has(rel):
            return ""
        target = link if link and (self.out / link).exists() else rel
        shown = self.small(rel)
        return (f'<figure class="{css}"><a href="{_href(target)}"><img src="{_href(shown)}" alt="{html.escape(rel)}" '
                f'loading="lazy"></a><figcaption>{caption}</figcaption></figure>')

    def small(self, rel: str) -> str:
        """``rel`` itself when its long side is at most :data:`SMALL_SIDE` (or it is not a PNG), else its small copy
        ``small/NAME.png`` (written once per page, area-averaged; the page links the full picture)."""
        from PIL import Image

        path = self.out / rel
        if path.suffix.lower() != ".png":
            return rel
        small = f"{SMALL_FOLDER}/{rel.replace('/', '_')}"
        made = self.out / small
        if made.is_file() and made.stat().st_mtime >= path.stat().st_mtime:  # the page is written after every step
            return small
        with Image.open(path) as im:
            if max(im.size) <= SMALL_SIDE:
                return rel
            scale = SMALL_SIDE / max(im.size)
            copy = im.convert("RGB").resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))),
                                            Image.Resampling.BOX)
        (self.out / SMALL_FOLDER).mkdir(exist_ok=True)
        with atomic_path(self.out / small) as tmp:
            copy.save(tmp, format="PNG")
        return small

    def section(self, title: str, figures: Sequence[str], note: str = "") -> None:
        shown = [f for f in figures if f]
        if shown:
            lead = f'<p class="note">{note}</p>' if note else ""
            self.parts.append(f"<h2>{html.escape(title)}</h2>{lead}<div class=\"grid\">{''.join(shown)}</div>")


def index_html(out: Path, summary: dict[str, Any], thumbs: dict[int, str]) -> str:
    """The text of ``index.html`` for the scan folder ``out`` (what its steps wrote there, and ``summary``)."""
    page = _Page(out)
    report = _read_json(out / "rectified" / "rectify.json")
    photos = report.get("photos") or []
    fit = _read_json(out / "fit" / "summary.json")
    exported = _read_json(out / "export" / export_cli.E.SUMMARY_NAME)
    rectified = [p for p in photos if p.get("status") == "ok" and page.has(f"rectified/{p.get('output', '')}")]

    lines = [f"{len(photos)} photo{'s' if len(photos) != 1 else ''}, {len(rectified)} rectified "
             f"({summary.get('frame', '')})"]
    selection = fit.get("selection") or {}
    if fit:
        chosen = f"; chosen: {selection['choice']}" if selection.get("choice") else ""
        rmse = fit.get("rerender_rmse")
        lines.append(f"fit: {fit.get('steps')} steps in {fit.get('seconds', 0):.1f} s "
                     f"({optimize_cli.stop_words(fit.get('stop_reason', ''))}){chosen}"
                     + (f"; {optimize_cli.rmse_words(rmse)}" if rmse is not None else ""))
    seconds = ", ".join(f"{s['name']} {s['seconds']:.1f} s" for s in summary.get("steps", [])
                        if s.get("seconds") is not None)
    if seconds:
        lines.append(f"time: {seconds}")
    nav = [_link(rel, text) for rel, text in ((PAGE_NAME, "relight in the browser (view.html)"),
                                               ("export/material.gltf", "glTF (export/material.gltf)"),
                                               ("fit/material/", "maps (fit/material/)"),
                                               ("rectified/", "rectified/"), ("fit/", "fit/"), ("export/", "export/"),
                                               (SUMMARY_NAME, SUMMARY_NAME)) if (out / rel).exists()]
    failure = summary.get("error")
    notes = [f"rectify: {n}" for n in report.get("notes") or []] + [f"optimize: {n}" for n in fit.get("notes") or []]
    head = (f"<h1>{html.escape(summary.get('title', 'scan'))}</h1>"
            f"<p class=\"lead\">{html.escape('. '.join(lines))}</p>"
            + (f'<p class="bad">stopped: {html.escape(failure)}</p>' if failure else "")
            + "".join(f'<p class="note">note: {html.escape(str(n))}</p>' for n in notes)
            + f"<nav>{''.join(nav)}</nav>")
    page.parts.append(head)

    figures = []
    for i, p in enumerate(photos):
        name = html.escape(Path(str(p.get("photo", ""))).name)
        if p.get("status") == "ok":
            caption = f"{i:03d}: {name} (" + _link(f"rectified/{p.get('overlay', '')}", "frame found") + ")" \
                if page.has(f"rectified/{p.get('overlay', '')}") else f"{i:03d}: {name}"
        else:
            caption = f"{i:03d}: {name} <span class=\"bad\">left out: {html.escape(str(p.get('error', '')))}</span>"
        rel = thumbs.get(i) or f"rectified/{p.get('overlay', '')}"
        figures.append(page.figure(rel, caption, "photo", link=f"rectified/{p.get('overlay', '')}"))
    page.section("Photos", figures, "each linked to its overlay: the frame (or tags) rectify found, drawn on it")
    page.section("Rectified views", [page.figure(f"rectified/{p['output']}", f"{html.escape(p['output'])}", "rect")
                                     for p in rectified],
                 "the sample seen from above, as the fit sees it (" + _link("rectified/capture.json", "capture.json")
                 + ", " + _link("rectified/rectify.json", "rectify.json") + ")"
                 if page.has("rectified/capture.json") else "")
    maps = [page.figure(f"fit/material/{m}.png", m, "map") for m in ("normal", "diffuse", "roughness", "specular")]
    page.section("Maps", maps, "the recovered material (" + _link("fit/material/", "fit/material/")
                 + ": PNG and material.json); relight it in " + _link(PAGE_NAME) if page.has(PAGE_NAME) else "")
    why = selection.get("why")
    if page.has("fit/selection.png"):
        note = html.escape(f"chosen: {selection.get('choice')}; why: {why}" if why else "")
    else:
        note = html.escape(f"no selection ran: {why}" if why else "no selection ran (see fit/summary.json)")
    page.section("Selection and the fit", [
        page.figure("fit/selection.png", "each candidate's error on the left-out photos; the chosen one's along "
                                         "its length", "wide"),
        page.figure("fit/loss.png", "the whole run against time (" + _link("fit/history.csv", "history.csv") + ")",
                    "wide")], note)
    unc = [page.figure(f"fit/uncertainty/{n}.png", n.replace("_deg", ""), "unc")
           for n in ("normal_deg", "diffuse", "roughness", "specular")]
    page.section("Uncertainty", unc, "the spread of the chosen candidate's fold fits, per texel")
    renders = sorted((out / "fit" / "renders").glob("[0-9][0-9][0-9].png")) if (out / "fit" / "renders").is_dir() \
        else []
    page.section("Re-renderings", [page.figure(f"fit/renders/{r.name}", f"photo {r.stem}", "render")
                                   for r in renders],
                 "photo | re-rendering of the maps under its camera and flash | difference x4 (grey: explained)")
    approx = (exported.get("approximation") or {}).get("exported") or {}
    gltf_note = (f"; glTF approximation of the BRDF: display RMSE {approx['rmse_display']:.4f}"
                 if isinstance(approx.get("rmse_display"), float) else "")
    textures = [page.figure(f"export/textures/{t}.png", t.replace("_", " "), "map")
                for t in ("base_color", "metallic_roughness", "specular_color", "normal")]
    page.section("glTF", textures, ("the material as glTF 2.0: " + _link("export/material.gltf") + gltf_note)
                 if page.has("export/material.gltf") else "")
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                   if p.is_file() and not p.name.startswith(".") and p.name != INDEX_NAME)
    if files:
        rows = "".join(f"<li>{_link(f)}</li>" for f in files)
        page.parts.append(f"<h2>Files</h2><details><summary>{len(files)} files</summary><ul>{rows}</ul></details>")
    title = html.escape(summary.get("title", "scan"))
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><style>\n{STYLE}</style></head>"
            f"<body>\n" + "\n".join(page.parts) + "\n</body></html>\n")


def _step_line(i: int, name: str, argv: Sequence[str]) -> str:
    return f"mi-svbrdf scan: step {i} of {len(STEPS)}: {shlex.join(['mi-svbrdf', name, *argv])}"


def interrupted_line(out: Path, current: int, done: Sequence[str]) -> str:
    """The one line of a Ctrl-C after scan started writing: the step it stopped in (``current``, from 1; past the
    last: the page) and what ``out`` holds (the folders of the steps in ``done`` are complete)."""
    if current <= len(STEPS):
        where = f"in step {current} of {len(STEPS)}, {STEPS[current - 1][0]}"
    else:
        where = f"while writing {INDEX_NAME}"
    folders = dict(STEPS)
    parts = [f"{folders[name]}{'' if '.' in folders[name] else '/'} (complete)" for name in done]
    if current <= len(STEPS):
        folder = STEPS[current - 1][1]
        if (out / folder).is_dir() and any(p.name != OWNER_FILE for p in (out / folder).iterdir()):
            parts.append(f"{folder}/ (incomplete; each file in it is whole)")
    if (out / THUMB_FOLDER).is_dir():
        parts.append(f"{THUMB_FOLDER}/")
    holds = f"{out}/ holds {', '.join(parts)}" if parts else f"nothing of this run is in {out}/"
    return f"mi-svbrdf scan: interrupted {where}; {holds}; no {INDEX_NAME} yet (re-run the command)"


def run_cli(args: argparse.Namespace) -> int:
    """Run ``mi-svbrdf scan``; returns the exit code (0: every photo rectified, 1: some left out)."""
    out = Path(args.out).expanduser()
    check_rectify_options(args)
    example = args.photos == ["example"]
    inputs = [] if example else expand_photos(args.photos)
    argvs = step_argv(args, out)
    steps = {name: parse_step(name, argv) for name, argv in argvs.items()}
    for name, step in steps.items():  # every step's folder can take its results: before any work
        check_step(name, step)
    replace_outputs(args, out, OWNED, keep=[*inputs, *([args.corners] if args.corners else [])])
    summary: dict[str, Any] = {"title": f"scan: {out.resolve().name}", "frame": args.frame,
                               "photos": list(args.photos), "steps": []}
    thumbs: dict[int, str] = {}
    done: list[str] = []
    code, current = 0, 0
    try:
        for current, (name, folder) in enumerate(STEPS, start=1):
            print(_step_line(current, name, argvs[name]), file=sys.stderr, flush=True)
            start = time.perf_counter()
            try:
                step_code = run_step(steps[name])
            except INPUT_ERRORS as exc:  # one line naming the step
                raise ValueError(f"{name}: {one_line(exc)}") from exc
            record = {"name": name, "command": shlex.join(["mi-svbrdf", name, *argvs[name]]), "out": folder,
                      "exit_code": step_code, "seconds": round(time.perf_counter() - start, 2)}
            summary["steps"].append(record)
            done.append(name)
            if name == "rectify":
                photos = [p.get("photo") for p in _read_json(out / "rectified" / "rectify.json").get("photos", [])]
                thumbs = write_thumbnails(out, [str(p) for p in photos], inputs)
                if step_code == 2:
                    raise ValueError(f"rectify: expected at least one photo rectified, got none of {len(photos)} "
                                     f"(see {out / INDEX_NAME}, {out / 'rectified'}/overlay_*.png)")
                code = step_code
        current += 1
        _write_index(out, summary, thumbs)
    except BaseException as exc:
        if interrupt.is_interruption(exc):  # one line of what the folder holds, in place of run()'s
            interrupt.stop_raising()
            release_unused(args)
            print(interrupted_line(out, current, done), file=sys.stderr)
            return INTERRUPTED
        if isinstance(exc, ValueError):
            summary["error"] = one_line(exc)
            _write_index(out, summary, thumbs)
        raise
    print(f"mi-svbrdf scan: wrote {out}/: {INDEX_NAME}, {THUMB_FOLDER}/, {SMALL_FOLDER}/, rectified/, fit/, export/, {PAGE_NAME}, "
          f"{SUMMARY_NAME}; open {(out / INDEX_NAME).resolve().as_uri()}")
    return code


def _write_index(out: Path, summary: dict[str, Any], thumbs: dict[int, str]) -> None:
    write_json(out / SUMMARY_NAME, {k: v for k, v in summary.items() if k != "title"})
    write_text(out / INDEX_NAME, index_html(out, summary, thumbs))


def main(argv: list[str] | None = None) -> int:
    """Entry point for tests and ``python -m mi_svbrdf.cli.scan``: ``scan`` arguments only."""
    return standalone(add_parser, ["scan", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
