"""``mi-svbrdf capture``: maps from flash photo(s) with the bundled networks, a contact sheet and a relit GIF.

Run ``mi-svbrdf capture --help`` for the options; :data:`HELP` documents what is written and how
photos are converted. The work is :func:`mi_svbrdf.nets.inference.predict_details`; this module writes
its result (:func:`write_capture`), draws the contact sheet (:func:`contact_sheet`) and renders
the animation (:func:`relit_frames`).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.cli.common import (
    add_command,
    budget_seconds,
    expand_photos,
    int_at_least,
    int_between,
    material_outputs,
    replace_outputs,
    standalone,
)
from mi_svbrdf.cli.optimize import RMSE_NAME, stop_words
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.core.maps import preview_panels
from mi_svbrdf.core.metrics import display, eval_lights, rerender
from mi_svbrdf.core.render import render
from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode, write_material
from mi_svbrdf.io.photos import exposure_notes, parse_crop
from mi_svbrdf.io.viewer import PAGE_NAME, page_title, write_viewer
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES
from mi_svbrdf.nets.inference import load, predict_details
from mi_svbrdf.optim.refine import RefineConfig, refine
from mi_svbrdf.eval.diffuse_highlight import highlight_in_diffuse
from mi_svbrdf.eval.evidence import MAX_FOLDS, TIE, Judgement, judge_photos, with_refinement
from mi_svbrdf.io.figures import labelled_row

DESCRIPTION = f"""\
Recover the four SVBRDF maps of a flat sample from flash photo(s) with the bundled networks.

One photo runs the single-image net, several the multi-image net (--kind to force one). The
single-image net expects a fronto-parallel flash photo: camera square-on to the sample, flash
next to the lens (a phone's flash), the sample filling the frame, no other strong light.
Extra photos for the multi-image net: the same sample from other angles, each with its flash.
The bundled multi-image net is fused with the single-image net (mi_svbrdf.nets.fusion): the
single-image net reads the flash photo, the multi-image net all of them, and a trained head
blends the two, so that adding photos starts from the single-image maps. The flash photo is the
first unless its light peaks outside the frame and another photo's inside (--flash-photo K to
say which); summary.json 'path' records which photo and why.
With 2 photos or more the photos then choose the maps (--no-choose: the fused net's, as is):
the single-image net's on the flash photo, the multi-image net's alone, or the fused net's. Each
is scored on photos it never saw: photos 2..N (up to {MAX_FOLDS} of them), the multi-image and fused
nets run again without the photo scored; each photo's light is estimated as --refine starts,
under the fused net's maps from all photos, then every candidate re-renders the photo under it,
its exposure fitted, and is compared with it in display space (mi_svbrdf.eval.evidence). The
multi-image and fused nets (the lower of the two) replace the single net's maps only with a mean
lower by more than {100 * TIE:g} %, and a refinement replaces those the same way. One line
prints the choice and every score; summary.json 'choice' records them.
PHOTO may be a folder (every photo in it, by name), 'example' (the bundled flash photo) or
'example:multi' (three bundled views).

--refine (2 photos or more) then refines the chosen maps against the photos. Nobody measured the
lights, so each photo's light and camera are estimated from the photos under the net's maps
(photo 0 must be the flash photo, its light at the lens; each other photo lit by one light, its
own flash or a lamp, and no room light), then fitted with the maps for --budget-s seconds, the
maps pulled towards the net's (mi_svbrdf.optim.refine). A photo whose light cannot be estimated
(black, clipped, or unexplained) is left out with a note. The refined maps are a candidate of the
choice where the refinement validated on a held-out photo: kept only when clearly better there.
It is off by default: on foreign captures it has not yet re-rendered better than the net alone
at N = 10 (docs/benchmarks/uncalibrated.md).
"""
OUTPUTS = """\
Writes to -o/--out:
  normal.png diffuse.png roughness.png specular.png + material.json   (8-bit; albedos sRGB)
  exr/normal.exr ... + exr/material.json                               (linear float, exact)
  contact_sheet.png   inputs (with 2 photos or more: each held photo labelled with the candidate that
                      explains it best) | normal | diffuse | roughness | specular | re-renderings under 3 lights,
                      each labelled with where its light is (seen from above, +y up: e.g. "right 16°" is a
                      light on the right 16° above the sample; "flash": the camera beside it) and, when
                      darkened so that its highlights are not white, by how much (EV)
  relit.gif           a point light circling over the sample (--frames frames)
  view.html           the maps in a self-contained WebGL2 page: drag the light (mi-svbrdf view)
  summary.json        inputs and their conversions, the net (weights, checksum), the path taken (net: the
                      network run; flash photo) and why, 'maps': the maps written (kept: single, multi,
                      fused or refined; what they are and how they were chosen), notes, timings; with 2
                      photos or more 'choice': the candidate kept, why, each candidate's score and per-photo errors;
                      with --refine: each photo's estimated light, camera, gain and ambient, the
                      fit's steps and stop reason, each photo's RMSE against the photo before and after
"""
EXAMPLES = ("mi-svbrdf capture example -o out/capture",
            "mi-svbrdf capture example:multi -o out/capture-multi",
            "mi-svbrdf capture photos/ --crop 200,100,1600,1600 -o out/my-capture")
#: The full help text, as ``--help`` shows it around the options.
HELP = f"{DESCRIPTION}\n{OUTPUTS}"

#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new capture replaces a previous one's.
OWNED = (*material_outputs(), *material_outputs("exr"), "contact_sheet.png", "relit.gif", PAGE_NAME, "summary.json")
#: Lights of the contact sheet's re-renderings (from :func:`mi_svbrdf.core.metrics.eval_lights`).
SHEET_LIGHTS = 3
#: Map panels stored sRGB-encoded (the albedos, as :func:`mi_svbrdf.io.material_io.write_material` writes them).
SRGB_PANELS = ("diffuse", "specular")


def _srgb_u8(linear: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` linear -> uint8 sRGB (colour-science)."""
    return np.round(srgb_encode(np.clip(linear, 0.0, 1.0)) * 255.0).astype(np.uint8)


def _display_u8(image: torch.Tensor) -> np.ndarray:
    """``(3, H, W)`` linear radiance -> uint8 with the authors' display gamma (:func:`mi_svbrdf.core.metrics.display`)."""
    return np.round(display(image).permute(1, 2, 0).numpy() * 255.0).astype(np.uint8)


def map_panels(maps: torch.Tensor) -> list[tuple[str, np.ndarray]]:
    """``(1, 10, H, W)`` -> ``[(name, (H, W, 3) uint8)]`` as stored in PNG: the
    :func:`~mi_svbrdf.core.maps.preview_panels` (normals (n+1)/2), albedos sRGB-encoded."""
    panels = preview_panels(maps[:1].detach().float())
    return [(name, _srgb_u8(image) if name in SRGB_PANELS else np.round(image * 255).astype(np.uint8))
            for name, image in ((name, panel[0].permute(1, 2, 0).numpy()) for name, panel in panels.items())]


#: A relit panel is darkened (in half stops) until this quantile of its brightest channel is at most RELIT_WHITE.
RELIT_QUANTILE, RELIT_WHITE = 0.99, 0.9
#: Azimuth words of a light seen from above (+x right, +y up), from 0° (right) counter-clockwise in 45° steps.
AZIMUTHS = ("right", "upper right", "top", "upper left", "left", "lower left", "bottom", "lower right")


def light_label(light: Sequence[float], view: Sequence[float]) -> str:
    """Where a point light is, in words: its side seen from above and its elevation, ``flash`` when the camera is
    beside it (the evaluation lights' flash-like ones).

    Examples:
        >>> light_label((2.93, 1.20, 0.95), (-2.2, 0.5, 1.5)), light_label((1.5, 0.6, 1.6), (1.8, 0.8, 1.92))
        ('right 17°', 'right 45° flash')
    """
    x, y, z = (float(v) for v in light)
    side = AZIMUTHS[round(math.degrees(math.atan2(y, x)) / 45.0) % 8]
    elevation = math.degrees(math.atan2(z, math.hypot(x, y)))
    cosine = sum(a * b for a, b in zip(light, view)) / (math.dist(light, (0, 0, 0)) * math.dist(view, (0, 0, 0)))
    return f"{side} {elevation:.0f}°" + (" flash" if cosine > 0.999 else "")


def relit_stops(image: torch.Tensor) -> float:
    """0, or the negative half stops that bring a relit panel's highlights (quantile :data:`RELIT_QUANTILE` of its
    brightest channel) to at most :data:`RELIT_WHITE` (a glossy real sample under a grazing light blows out)."""
    top = float(torch.quantile(image.float().amax(dim=0).flatten(), RELIT_QUANTILE))
    return 0.0 if not math.isfinite(top) or top <= RELIT_WHITE else -math.ceil(2.0 * math.log2(top / RELIT_WHITE)) / 2


def contact_sheet(photos: torch.Tensor, maps: torch.Tensor, *, lights: int = SHEET_LIGHTS,
                  distribution: str = "ggx", best: dict[int, str] | None = None) -> np.ndarray:
    """One row, labelled: inputs | 4 maps | re-renderings under ``lights`` evaluation lights.

    Args:
        photos: ``(1, N, 3, H, W)`` linear photos the net saw.
        maps: ``(1, 10, H, W)`` predicted maps.
        lights: number of re-rendering lights (:func:`mi_svbrdf.core.metrics.eval_lights`).
        distribution: the maps' BRDF model (``"ggx"`` or ``"beckmann"``), which the relit panels use.
        best: per photo (0-based), the candidate of the choice that explains it best
            (:meth:`mi_svbrdf.eval.evidence.Judgement.best_per_photo`), added to its label.

    Returns:
        ``(H + label, W * (N + 4 + lights), 3)`` uint8 image. A relit panel is labelled with where its light is
        (:func:`light_label`) and, when darkened so that its highlights are not white, by how much
        (:func:`relit_stops`, in EV).
    """
    h, w = maps.shape[-2:]
    photos = torch.nn.functional.interpolate(photos[0].float(), size=(h, w), mode="bilinear", antialias=True)
    best = best or {}
    panels = [(f"input {i + 1}" + (f": {best[i]} best" if i in best else ""), _srgb_u8(p.permute(1, 2, 0).numpy()))
              for i, p in enumerate(photos)]
    panels += map_panels(maps)
    where = eval_lights(lights)
    with torch.inference_mode():
        renders = rerender(maps.float(), where, distribution=distribution)[0]
    for k, r in enumerate(renders):
        stops = relit_stops(r)
        label = f"relit: {light_label(where.light[k].tolist(), where.view[k].tolist())}"
        panels.append((label + (f" {stops:+g} EV" if stops else ""), _display_u8(r * 2.0 ** stops)))
    return labelled_row(panels)


def relit_frames(maps: torch.Tensor, frames: int = 24, *, radius: float = 1.2, height: float = 1.5,
                 camera: float = 2.75, distribution: str = "ggx") -> torch.Tensor:
    """``(frames, 3, H, W)`` linear renders of ``maps (1, 10, H, W)`` under a point light circling the sample.

    The light moves on a circle of ``radius`` at ``height`` (half sample widths), seen from a
    camera straight above at ``camera``; its intensity is ``d^2`` (unit irradiance at the centre
    at normal incidence, like :func:`mi_svbrdf.core.metrics.eval_lights`), with 1/d^2 fall-off.
    """
    t = torch.arange(frames, dtype=torch.float32) * (2.0 * math.pi / frames)
    light = torch.stack([radius * torch.cos(t), radius * torch.sin(t), torch.full_like(t, height)], dim=-1)[None]
    view = torch.tensor([0.0, 0.0, camera]).expand(1, frames, 3)
    intensity = light.square().sum(-1, keepdim=True).expand(1, frames, 3)
    with torch.inference_mode():
        return render(maps.float(), light, view, intensity=intensity, distance_falloff=True,
                      distribution=distribution)[0]


def write_gif(path: Path, frames: torch.Tensor, duration_ms: int = 80) -> None:
    """Write linear ``(F, 3, H, W)`` frames (display gamma) as a looping GIF, atomically.

    One 256-colour palette (median cut of every frame, subsampled) is shared by all frames and
    applied with Floyd-Steinberg dithering: ~20x faster than Pillow's per-frame quantisation and
    no palette flicker.
    """
    from PIL import Image

    rgb = [_display_u8(f) for f in frames]
    step = max(1, rgb[0].shape[0] // 64)
    palette = Image.fromarray(np.concatenate([a[::step, ::step] for a in rgb], axis=0)).quantize(
        colors=256, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(a).quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG) for a in rgb]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)


def _write_png_u8(path: Path, image: np.ndarray) -> None:
    write_image(path, image.astype(np.float32) / 255.0, 8, srgb=True)


#: What each candidate's maps are, in summary.json's ``maps``.
MAPS_FROM = {"single": "the single-image net's, on the flash photo",
             "multi": "the multi-image net's alone, on every photo",
             "fused": "the fused net's: the single- and multi-image nets blended per texel by its fusion head"}


def maps_kept(net: str, chosen: str | None, refined: bool) -> dict[str, str]:
    """summary.json's ``maps``: which maps were written, whatever network ran (``path.net``).

    Args:
        net: the network run (``path.net``: single, multi or fused).
        chosen: the candidate the photos chose before any refinement (None: no choice ran, the net's maps).
        refined: whether the refined maps were kept.

    Examples:
        >>> maps_kept("fused", "multi", False)["kept"]
        'multi'
        >>> maps_kept("fused", "multi", True)["from"]
        "the multi-image net's alone, on every photo, refined against the photos"
    """
    base = chosen or net
    how = ("chosen by the photos' own evidence: see 'choice'" if chosen is not None else
           f"the {net} net's maps as they are: no choice ran (one photo, --no-choose or a net that is not fused)")
    return {"kept": "refined" if refined else base,
            "from": MAPS_FROM.get(base, f"the {base} net's") + (", refined against the photos" if refined else ""),
            "how": how}


def write_capture(out: Path, result: Any, *, frames: int = 24, extra: dict[str, Any] | None = None,
                  best: dict[int, str] | None = None) -> dict[str, Any]:
    """Write maps (PNG + EXR), contact sheet, relit GIF, ``view.html`` and ``summary.json`` of a prediction; returns the summary.

    Args:
        out: output folder (created).
        result: a :class:`mi_svbrdf.nets.inference.Prediction` with batch size 1.
        frames: frames of ``relit.gif`` (0: no GIF).
        extra: more fields for ``summary.json``.
        best: per photo, the candidate that explains it best (the contact sheet's input labels).
    """
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    model = getattr(result, "distribution", "ggx")  # the net's output BRDF model, recorded in material.json
    write_material(out, result.maps, fmt="png", distribution=model)
    write_material(out / "exr", result.maps, fmt="exr", distribution=model)
    t1 = time.perf_counter()
    _write_png_u8(out / "contact_sheet.png", contact_sheet(result.photos, result.maps, distribution=model, best=best))
    t2 = time.perf_counter()
    if frames > 0:
        write_gif(out / "relit.gif", relit_frames(result.maps, frames, distribution=model))
    t3 = time.perf_counter()
    write_viewer(out / PAGE_NAME, result.maps, title=page_title("capture", out), distribution=model)
    t4 = time.perf_counter()
    net = {k: v for k, v in result.network.items() if k in ("kind", "file", "sha256", "steps", "net_config")}
    summary = {"inputs": result.inputs, "net": net, "path": getattr(result, "path", {}), "distribution": model,
               "resolution": int(result.maps.shape[-1]), "notes": result.notes, **(extra or {}),
               "seconds": {**result.seconds, "write_maps": round(t1 - t0, 4), "contact_sheet": round(t2 - t1, 4),
                           "relit_gif": round(t3 - t2, 4), "view_html": round(t4 - t3, 4)},
               "outputs": ["normal.png", "diffuse.png", "roughness.png", "specular.png", "material.json", "exr/",
                           "contact_sheet.png"] + (["relit.gif"] if frames > 0 else []) + [PAGE_NAME, "summary.json"]}
    write_json(out / "summary.json", summary)
    return summary


def _flash_index(value: str, count: int) -> int:
    """``--flash-photo K`` (1-based) -> a 0-based index; a clear error outside ``[1, count]``."""
    try:
        k = int(value)
    except ValueError:
        k = 0
    if not 1 <= k <= count:
        raise ValueError(f"--flash-photo: expected 'auto' or a photo number in [1, {count}], got {value!r}")
    return k - 1


def run_cli(args: argparse.Namespace) -> int:
    """The ``capture`` command: predict, write, print where."""
    if not args.photos:
        raise ValueError("photos: expected at least one photo file, got none (usage: mi-svbrdf capture "
                         "photo.jpg [more.jpg ...] -o out/)")
    photos = expand_photos(args.photos)
    crop = parse_crop(args.crop) if args.crop else None
    kind = None if args.kind == "auto" else args.kind
    device = resolve_device(args.device)
    flash = None if args.flash_photo == "auto" else _flash_index(args.flash_photo, len(photos))
    result = predict_details(photos, kind=kind, linear=args.linear, full_resolution=args.full_resolution,
                             weights_dir=args.weights, crop=crop, device=device, symmetries=args.symmetries,
                             flash_photo=flash)
    if len(photos) > 1:
        print(f"{result.path['flash_photo']['why']}; {result.path['why']}")
    warnings = exposure_notes(result.photos[0], photos, result="the maps")
    for note in result.notes:
        print(f"note: {note}")
    for note in warnings:
        print(f"mi-svbrdf capture: {note}", file=sys.stderr)
    result.notes = [*result.notes, *warnings]
    # the refinement, the files, the contact sheet and the GIF run on the CPU
    cpu = torch.device("cpu")
    judgement: Judgement | None = None
    chosen: str | None = None
    if args.choose and result.photos.shape[1] >= 2 and result.path.get("net") == "fused":
        t0 = time.perf_counter()
        net, _ = load(result.kind, args.weights, device)
        candidates, judgement = judge_photos(net, result.photos, symmetries=args.symmetries,
                                             config=RefineConfig(distribution=result.distribution, progress=False),
                                             distribution=result.distribution)
        result.maps = candidates[judgement.choice]
        chosen = judgement.choice  # before any refinement: the maps the refinement starts from
        result.seconds = {**result.seconds, "choice": round(time.perf_counter() - t0, 4)}
        print(judgement.line())
    result.maps, result.photos = result.maps.to(cpu), result.photos.to(cpu)
    refined = None
    if args.refine and result.photos.shape[1] < 2:
        print("mi-svbrdf capture: --refine needs 2 photos or more (one photo cannot separate the maps from the "
              "net's prior): the net's maps are kept", file=sys.stderr)
    if args.refine and result.photos.shape[1] >= 2:
        refined = refine(result.photos[0], result.maps,
                         config=RefineConfig(budget_s=args.budget_s, distribution=result.distribution,
                                             progress=not args.no_progress))
        if judgement is None:
            result.maps = refined.maps
        else:
            fit = refined.fit
            judgement = with_refinement(judgement, fit.validation if fit is not None else None,
                                        fit.shrink if fit is not None else None)
            if judgement.choice == "refined":
                result.maps = refined.maps
            print(f"with the refinement: {judgement.line()}")
        for note in refined.notes:
            print(f"mi-svbrdf capture: {note}", file=sys.stderr)
        result.notes = [*result.notes, *refined.notes]
        result.seconds = {**result.seconds, "refine": round(refined.seconds, 4)}
    single = judgement.choice == "single" if judgement is not None else refined is None and result.kind == "single"
    if single:  # the single net's maps are kept: did it leave the flash's highlight in the diffuse map?
        left = highlight_in_diffuse(result.photos[0, 0], result.maps).note(n_photos=int(result.photos.shape[1]))
        if left:
            print(f"mi-svbrdf capture: {left}", file=sys.stderr)
            result.notes = [*result.notes, left]
    out = Path(args.out)
    replace_outputs(args, out, OWNED, keep=photos)
    summary = write_capture(out, result, frames=args.frames,
                            extra={"options": {"linear": args.linear, "crop": args.crop, "kind": args.kind,
                                               "full_resolution": args.full_resolution,
                                               "device": str(device), "symmetries": args.symmetries,
                                               "refine": refined is not None, "budget_s": args.budget_s,
                                               "choose": args.choose},
                                   "maps": maps_kept(result.path.get("net", result.kind), chosen,
                                                     refined is not None and refined.fit is not None
                                                     and (judgement is None or judgement.choice == "refined")),
                                   "refine": refined.summary() if refined is not None else None,
                                   "choice": judgement.summary() if judgement is not None else None},
                            best=judgement.best_per_photo() if judgement is not None else None)
    how = ""
    if refined is not None:
        before = [e for e in refined.error_before if e is not None]
        after = [e for e in refined.error_after if e is not None]
        how = (f", refined against the photos ({refined.steps} steps, {stop_words(refined.stop_reason)}, "
               f"{refined.seconds:.1f} s; mean {RMSE_NAME} {sum(before) / max(len(before), 1):.4f} -> "
               f"{sum(after) / max(len(after), 1):.4f})")
    label = "fused multi-image net" if result.path.get("net") == "fused" else f"{result.kind}-image net"
    if judgement is not None:
        label = f"{label} ({judgement.choice} maps kept)"
    print(f"{label} on {len(photos)} photo(s) at {summary['resolution']} px "
          f"({args.symmetries} symmetr{'y' if args.symmetries == 1 else 'ies'}) in "
          f"{result.seconds['network']:.2f} s{how}; wrote {out}/: {', '.join(summary['outputs'])}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``capture`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "capture", help="SVBRDF maps from flash photo(s) with the bundled networks",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("photos", nargs="*", metavar="PHOTO",
                   help="photo files (JPEG, PNG, TIFF, EXR ...) or folders of them; 'example' is the bundled flash "
                        "photo (a render of a held-out procedural material), 'example:multi' three bundled views")
    p.add_argument("-o", "--out", default="out/capture", help="output folder (default: out/capture)")
    p.add_argument("--kind", choices=("auto", "single", "multi"), default="auto",
                   help="network (auto: single for one photo, multi for more)")
    p.add_argument("--flash-photo", default="auto", metavar="auto|K",
                   help="which photo (1-based, in the order given) is the fronto-parallel flash photo; auto (default): "
                        "the first, unless its light peaks outside the frame and another photo's inside "
                        "(summary.json 'path' says which and why)")
    p.add_argument("--linear", action="store_true", help="the files hold linear values (no sRGB decoding)")
    p.add_argument("--crop", default=None, metavar="X,Y,W,H",
                   help="region of each upright photo (pixels) before the centre square")
    p.add_argument("--full-resolution", action="store_true",
                   help="run at the photos' own (square) size instead of resizing to the net's 256")
    p.add_argument("--frames", type=int_at_least(0), default=24, help="frames of relit.gif (0: no GIF; default 24)")
    p.add_argument("--symmetries", type=int_between(1, 8), default=DEFAULT_SYMMETRIES,
                   help="average the maps of this many flips and rotations of the photos (1: the net alone, "
                        f"8x faster; default {DEFAULT_SYMMETRIES}: lower re-rendering error on held-out and foreign captures)")
    p.add_argument("--device", default="cpu", help=f"where the network runs: {DEVICE_HELP}")
    p.add_argument("--choose", action=argparse.BooleanOptionalAction, default=True,
                   help="2 photos or more: the photos choose the maps among the single-image, multi-image and fused "
                        "nets' (see above; default: on; --no-choose: the fused net's)")
    p.add_argument("--refine", action=argparse.BooleanOptionalAction, default=False,
                   help="refine the net's maps against the photos, each photo's light estimated from them (2 photos or "
                        "more; see above; default: off, --no-refine: the net alone)")
    p.add_argument("--budget-s", type=budget_seconds, default=RefineConfig.budget_s,
                   help="wall time of --refine, seconds (default %(default)g; 0 or inf: no limit, the refinement stops "
                        "when it has converged)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--weights", default=None, metavar="DIR",
                   help="a weights folder with manifest.json (default: the bundled weights)")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def main(argv: list[str] | None = None) -> int:
    """Run ``capture`` on its own: ``main(["capture", "example", "-o", "out/capture"])`` (also ``python -m``)."""
    return standalone(add_parser, argv)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
