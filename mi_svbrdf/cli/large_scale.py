"""``mi-svbrdf large-scale``: the maps of a large surface from one ambient-lit photo and exemplar SVBRDFs (ch. 5).

Run ``mi-svbrdf large-scale --help`` for the options; :data:`DESCRIPTION` documents what is done to
the inputs. The work is :func:`mi_svbrdf.nets.tiling.predict_large_scale` (the exemplars' pyramid once,
then :func:`~mi_svbrdf.nets.tiling.tiled_predict`); this module reads the inputs (:func:`load_large_net`,
:func:`load_exemplars`), writes the maps as ``capture`` does (:func:`mi_svbrdf.io.material_io.write_material`),
the contact sheet (:func:`contact_sheet`), the relighting page and ``summary.json``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.assets import EXAMPLE_WALL, EXAMPLE_WALL_DIR, EXAMPLE_WALL_EXEMPLARS
from mi_svbrdf.cli.capture import map_panels
from mi_svbrdf.cli.common import (
    add_command,
    int_at_least,
    material_from_spec,
    material_outputs,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core.device import DEVICE_HELP, resolve_device
from mi_svbrdf.core.maps import normalize_normals
from mi_svbrdf.core.metrics import display, eval_lights, rerender
from mi_svbrdf.io.atomic import json_safe, write_json
from mi_svbrdf.io.figures import labelled_row
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import read_distribution, srgb_encode, write_material
from mi_svbrdf.io.photos import exposure_notes, load_photo
from mi_svbrdf.io.viewer import PAGE_NAME, page_title, write_viewer
from mi_svbrdf.nets import inference
from mi_svbrdf.nets import weights as bundled
from mi_svbrdf.nets.network import build_network, config_from_dict
from mi_svbrdf.nets.tiling import plan_tiles, predict_large_scale, seam_ratio

DESCRIPTION = """\
Recover the four SVBRDF maps of a large flat surface (a wall, a floor, a door) from one photo taken
under ambient light, guided by exemplars: SVBRDFs of small patches of the same or a similar material
(thesis ch. 5). An exemplar is a material folder: 'mi-svbrdf capture' of a flash close-up of the
surface, or any folder of the four maps (swapping exemplars changes the result: the creative workflow
of the thesis's Fig. 5.5-5.6). Any number of exemplars (their order does not matter); --no-exemplar
runs the same net without any (the baseline of Fig. 5.7).

PHOTO 'example' is the bundled example: an ambient-lit photo (512 x 512) of a held-out tiled wall,
used with its two bundled exemplars (cut from the same wall) unless --exemplar or --no-exemplar is
given (mi_svbrdf/assets/example_wall/, re-made by python -m mi_svbrdf.cli.example_wall).

The photo is cut into overlapping tiles of --tile px (default: the tile the net was trained at; 512
for the full preset, 128 for the compact one) overlapping by at least --overlap px (default: half a
tile), spread evenly so that the first and last tiles are flush with the photo's borders. The net
runs on each tile with the same exemplars (their features are computed once) and the tiles' maps
are blended with Gaussian weights (1 at a tile's centre, about 0 at its border), normals
renormalised: no seam (summary.json's seam_ratio, ~1, measures it). Memory is bounded by the tile.

Inputs (documented conversions, not errors):
  - the photo: any size and aspect ratio, read like capture's photos (EXIF orientation applied,
    sRGB decoded to linear, 16-bit PNG at full precision, grey replicated, alpha dropped; EXR is
    linear); a side shorter than the tile is padded by reflection to the tile and the maps cropped
    back (a note says so);
  - an exemplar: a folder (or a thesis strip .png, or example:NAME, a built-in material); a
    non-square one is cut to its centre square and every exemplar is resized (antialiased; normals
    renormalised) to the net's exemplar size (64 px compact, 256 px full); the summary says so.
Errors (naming the file or option): a photo that is not an image or is under 64 px, an exemplar
folder missing a map, --overlap >= --tile, no exemplar without --no-exemplar, no large-scale
weights. Warnings: a photo (nearly) all black or all saturated.
"""
OUTPUTS = """\
Writes to -o/--out (the maps at the photo's resolution):
  normal.png diffuse.png roughness.png specular.png + material.json   (8-bit; albedos sRGB)
  exr/normal.exr ... + exr/material.json                               (linear float, exact)
  contact_sheet.png   photo | exemplars (their 4 maps) | normal | diffuse | roughness | specular | relit
  view.html           the maps in a self-contained WebGL2 page: drag the light (longest side <= 1024 px)
  summary.json        photo, exemplars and their resizing, the net, the tiles, seam ratios, notes, timings
"""
EXAMPLES = ("mi-svbrdf large-scale example -o out/large-scale",
            ("mi-svbrdf capture example -o out/capture && mi-svbrdf large-scale wall.jpg --exemplar out/capture "
             "-o out/large-scale"),
            "mi-svbrdf large-scale wall.jpg --exemplar out/capture --exemplar example:tiles -o out/large-scale",
            "mi-svbrdf large-scale wall.jpg --no-exemplar --tile 512 --overlap 256 -o out/large-scale-baseline")

#: PHOTO naming the bundled example wall (:data:`mi_svbrdf.assets.EXAMPLE_WALL` and its exemplars).
EXAMPLE_PHOTO = "example"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new run replaces a previous one's.
OWNED = (*material_outputs(), *material_outputs("exr"), "contact_sheet.png", PAGE_NAME, "summary.json")
#: Height (px) of the contact sheet's panels.
SHEET_HEIGHT = 256
#: Longest side of the maps embedded in view.html (larger maps are downscaled for the page only: the page
#: embeds them as base64 PNG, ~40 MB at 4K, and a 4K canvas is slow to relight).
VIEW_MAX = 1024


def _resize_maps(maps: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Antialiased bilinear resize of ``(B, 10, H, W)`` maps to ``size``, normals renormalised, the rest in [0, 1]."""
    if tuple(maps.shape[-2:]) == tuple(size):
        return maps
    out = F.interpolate(maps, size=size, mode="bilinear", align_corners=False, antialias=True)
    out = normalize_normals(out)
    return torch.cat([out[:, :3], out[:, 3:].clamp(0.0, 1.0)], dim=1)


def load_large_net(spec: str | None, device: torch.device) -> tuple[nn.Module, dict[str, Any]]:
    """The large-scale net of ``--weights`` (a training checkpoint or a weights folder; None: the bundled one).

    Returns:
        ``(net in eval mode on device, description for summary.json)``.

    Raises:
        ValueError / FileNotFoundError: naming ``--weights``: no such file, not a checkpoint, a net of another
            kind, a folder or the package without a ``large`` entry in its manifest.
    """
    if spec is None or Path(spec).expanduser().is_dir():
        folder = bundled.WEIGHTS_DIR if spec is None else Path(spec).expanduser().resolve()
        kinds = bundled.available(folder)
        if "large" not in kinds:
            if spec is None:
                raise ValueError(f"--weights: expected bundled large-scale weights (a 'large' entry in "
                                 f"{folder / bundled.MANIFEST}), got only {kinds}; pass --weights CHECKPOINT "
                                 "(a 'mi-svbrdf train large' run's checkpoint.pt) or a weights folder")
            raise ValueError(f"--weights: expected a weights folder whose {bundled.MANIFEST} has a 'large' entry, "
                             f"got {folder} with {kinds}")
        net, entry = inference.load("large", None if spec is None else folder, device)
        info = {"kind": "large", "source": "bundled" if spec is None else str(folder),
                **{k: entry[k] for k in ("file", "sha256", "steps", "net_config") if k in entry},
                "distribution": bundled.entry_distribution(entry)}
        return net.eval(), info
    path = Path(spec).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"--weights: expected a checkpoint file or a weights folder, got no such file or "
                                f"folder {spec!r}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
        net_config, model = state["net_config"], state["model"]
    except Exception as exc:  # any failure means the file is not a checkpoint
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise ValueError(f"--weights: expected a training checkpoint (a dict with 'net_config' and 'model') or a "
                         f"weights folder, got {path} ({reason})") from exc
    cfg = config_from_dict(net_config)
    if cfg.kind != "large":
        raise ValueError(f"--weights: expected a checkpoint of the large-scale net (kind 'large'), got kind "
                         f"{cfg.kind!r} in {path}")
    net = build_network(cfg)
    try:
        net.load_state_dict(model)
    except RuntimeError as exc:
        raise ValueError(f"--weights: expected weights of the checkpoint's architecture in {path}, got mismatched "
                         f"tensors ({str(exc).splitlines()[0]})") from exc
    train = state.get("config", {}) if isinstance(state.get("config"), dict) else {}
    info = {"kind": "large", "source": str(path.resolve()), "steps": state.get("step"), "net_config": cfg.to_dict(),
            "distribution": train.get("distribution", bundled.DEFAULT_DISTRIBUTION)}
    return net.to(device).eval(), info


def load_exemplars(specs: list[str], size: int) -> tuple[torch.Tensor, list[dict[str, Any]], list[str]]:
    """Read the ``--exemplar`` materials and fit them to the net's exemplar ``size``.

    Returns:
        ``(maps (E, 10, size, size), per-exemplar descriptions, notes)``: a non-square exemplar is cut
        to its centre square, any other size resized (antialiased; normals renormalised).

    Raises:
        ValueError / FileNotFoundError: ``--exemplar: ...`` naming the folder (and the missing map).
    """
    maps, described, notes = [], [], []
    for spec in specs:
        try:
            m = material_from_spec(spec, size=size, arg="--exemplar")
        except (ValueError, FileNotFoundError) as exc:
            if str(exc).startswith("--exemplar"):
                raise
            raise type(exc)(f"--exemplar: {exc}") from exc
        h, w = m.shape[-2:]
        entry: dict[str, Any] = {"exemplar": spec, "size_hw": [int(h), int(w)]}
        if Path(spec).is_dir() and read_distribution(spec) != "ggx":
            notes.append(f"exemplar {spec} records the {read_distribution(spec)} model: the net reads exemplars "
                         "as GGX maps (its roughness means another lobe)")
        if h != w:
            s = min(h, w)
            top, left = (h - s) // 2, (w - s) // 2
            m = m[..., top:top + s, left:left + s]
            notes.append(f"exemplar {spec}: {w}x{h} (W x H) cut to its centre square {s} px")
        if m.shape[-1] != size:
            notes.append(f"exemplar {spec}: {m.shape[-1]} px resized to the net's exemplar size {size} px")
            m = _resize_maps(m, (size, size))
        entry["resized_to"] = size
        maps.append(m)
        described.append(entry)
    return torch.cat(maps) if maps else torch.zeros(0, 10, size, size), described, notes


def _u8(image: np.ndarray) -> np.ndarray:
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


def contact_sheet(photo: torch.Tensor, exemplars: torch.Tensor, maps: torch.Tensor) -> np.ndarray:
    """One labelled row: photo | each exemplar (its four maps, 2 x 2) | the 4 maps | a relit render.

    Photo, maps and render are downscaled (antialiased) to :data:`SHEET_HEIGHT` px high (at most twice as
    wide); the relit render is the first evaluation light of :func:`mi_svbrdf.core.metrics.eval_lights`
    (a point light beside the viewer: highlights).

    Args:
        photo: ``(1, 3, H, W)`` linear photo.
        exemplars: ``(E, 10, s, s)`` exemplar maps (E may be 0).
        maps: ``(1, 10, H, W)`` predicted maps.

    Returns:
        ``(SHEET_HEIGHT + 18, width, 3)`` uint8 image.
    """
    h, w = maps.shape[-2:]
    scale = min(SHEET_HEIGHT / h, 2 * SHEET_HEIGHT / w)
    ph, pw = max(1, round(h * scale)), max(1, round(w * scale))
    small = _resize_maps(maps.float(), (ph, pw))
    shot = F.interpolate(photo.float(), size=(ph, pw), mode="bilinear", align_corners=False, antialias=True)
    panels = [("photo", _u8(srgb_encode(shot[0].permute(1, 2, 0).numpy())))]
    half = max(1, ph // 2)
    for i, ex in enumerate(exemplars):
        tiles = {name: img for name, img in map_panels(_resize_maps(ex[None].float(), (half, half)))}
        grid = np.concatenate([np.concatenate([tiles["normal"], tiles["diffuse"]], axis=1),
                               np.concatenate([tiles["roughness"], tiles["specular"]], axis=1)], axis=0)
        panels.append((f"exemplar {i + 1}", grid))
    panels += map_panels(small)
    with torch.no_grad():
        relit = display(rerender(small, eval_lights(1)))[0, 0]
    panels.append(("relit", _u8(relit.permute(1, 2, 0).numpy())))
    return labelled_row(panels)


def _inputs(args: argparse.Namespace) -> tuple[str, list[str], list[str]]:
    """``(photo file, exemplar specs, notes)`` of the arguments: PHOTO ``example`` is the bundled wall photo, with
    its bundled exemplars unless ``--exemplar`` or ``--no-exemplar`` is given."""
    if args.photo != EXAMPLE_PHOTO:
        return str(args.photo), list(args.exemplar or []), []
    if args.exemplar or args.no_exemplar:
        return str(EXAMPLE_WALL), list(args.exemplar or []), [f"the bundled example photo {EXAMPLE_WALL}"]
    exemplars = [str(p) for p in EXAMPLE_WALL_EXEMPLARS]
    note = (f"the bundled example photo {EXAMPLE_WALL} with its {len(exemplars)} bundled exemplars "
            f"({EXAMPLE_WALL_DIR}/exemplar_N)")
    return str(EXAMPLE_WALL), exemplars, [note]


def run_cli(args: argparse.Namespace) -> int:
    """The ``large-scale`` command: check every input, predict tile by tile, write, print a summary."""
    t0 = time.perf_counter()
    if args.no_exemplar and args.exemplar:
        raise ValueError("--no-exemplar: expected no --exemplar with it (the baseline runs without exemplars), "
                         f"got {len(args.exemplar)} --exemplar")
    if not args.no_exemplar and not args.exemplar and args.photo != EXAMPLE_PHOTO:
        raise ValueError("--exemplar: expected at least one exemplar material folder (or --no-exemplar for the "
                         "baseline without), got none")
    if args.tile is not None and args.overlap is not None and args.overlap >= args.tile:
        raise ValueError(f"--overlap: expected an int in [0, --tile) = [0, {args.tile}), got {args.overlap}")
    photo_path, exemplar_specs, example_notes = _inputs(args)
    photo_file = load_photo(photo_path, square=False)
    photo = torch.from_numpy(photo_file.image).permute(2, 0, 1)[None].contiguous()
    device = resolve_device(args.device)
    net, net_info = load_large_net(args.weights, device)
    cfg = net.config
    tile = int(cfg.resolution) if args.tile is None else args.tile
    overlap = tile // 2 if args.overlap is None else args.overlap
    if overlap >= tile:
        raise ValueError(f"--overlap: expected an int in [0, --tile) = [0, {tile}), got {overlap}")
    smallest = 2 ** (cfg.depth - 1) + 1
    if tile < smallest:
        raise ValueError(f"--tile: expected at least {smallest} px for this net (depth {cfg.depth}), got {tile}")
    exemplars, exemplar_info, notes = load_exemplars(exemplar_specs, int(cfg.exemplar_size))
    notes = [*example_notes, *notes]
    h, w = photo.shape[-2:]
    plan = plan_tiles(h, w, tile=tile, overlap=overlap)
    notes = [*notes, *plan.notes]
    if tile != cfg.resolution:
        notes.append(f"tiles of {tile} px; the net was trained on tiles of {cfg.resolution} px")
    warnings = exposure_notes(photo, [photo_path], result="the maps")
    for note in notes:
        print(f"note: {note}")
    for note in warnings:
        print(f"mi-svbrdf large-scale: {note}", file=sys.stderr)
    t1 = time.perf_counter()
    maps = predict_large_scale(net, photo, exemplars, tile=tile, overlap=overlap, progress=not args.no_progress)
    t2 = time.perf_counter()
    seams = seam_ratio(maps, tile, overlap)
    model = net_info.get("distribution", bundled.DEFAULT_DISTRIBUTION)
    out = Path(args.out)
    replace_outputs(args, out, OWNED, keep=[photo_path, *exemplar_specs])
    out.mkdir(parents=True, exist_ok=True)
    write_material(out, maps, fmt="png", distribution=model)
    write_material(out / "exr", maps, fmt="exr", distribution=model)
    t3 = time.perf_counter()
    sheet = contact_sheet(photo, exemplars, maps)
    write_image(out / "contact_sheet.png", sheet.astype(np.float32) / 255.0, 8, srgb=True)
    t4 = time.perf_counter()
    view_scale = min(1.0, VIEW_MAX / max(h, w))
    view_size = (max(1, round(h * view_scale)), max(1, round(w * view_scale)))
    if view_scale < 1.0:
        notes.append(f"{PAGE_NAME} shows the maps downscaled to {view_size[1]}x{view_size[0]} (W x H)")
    write_viewer(out / PAGE_NAME, _resize_maps(maps, view_size), title=page_title("large-scale", out))
    t5 = time.perf_counter()
    outputs = ["normal.png", "diffuse.png", "roughness.png", "specular.png", "material.json", "exr/",
               "contact_sheet.png", PAGE_NAME, "summary.json"]
    summary = {"photo": {"path": photo_path, "size_wh": [int(w), int(h)],
                         "conversions": photo_file.conversions},
               "exemplars": exemplar_info, "net": net_info, "distribution": model, "tiles": plan.to_dict(),
               "seam_ratio": json_safe({k: round(v, 4) for k, v in seams.items()}), "notes": [*notes, *warnings],
               "options": {"tile": tile, "overlap": overlap, "no_exemplar": args.no_exemplar, "device": str(device)},
               "seconds": {"load": round(t1 - t0, 4), "tiles": round(t2 - t1, 4), "write_maps": round(t3 - t2, 4),
                           "contact_sheet": round(t4 - t3, 4), "view_html": round(t5 - t4, 4),
                           "total": round(time.perf_counter() - t0, 4)},
               "outputs": outputs}
    write_json(out / "summary.json", summary)
    worst = max(seams.values()) if seams else None
    seam_text = f", seam ratio <= {worst:.3f}" if worst is not None else ""
    print(f"large-scale net on a {w}x{h} photo with {len(exemplars)} exemplar(s): {plan.count} tiles of {tile} px "
          f"(overlap {overlap}) in {t2 - t1:.1f} s{seam_text}; wrote {out}/: {', '.join(outputs)}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``large-scale`` on a subparsers object (``func(args) -> int``)."""
    p = add_command(subparsers, "large-scale",
                    help="SVBRDF maps of a large surface from one ambient-lit photo and exemplar materials",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("photo", metavar="PHOTO", help="the photo of the surface under ambient light (JPEG, PNG, TIFF, "
                                                  "EXR ...), any size and aspect ratio; 'example': the bundled "
                                                  "photo of a wall (with its two exemplars unless --exemplar)")
    p.add_argument("--exemplar", action="append", default=[], metavar="DIR",
                   help="an exemplar: a material folder (mi-svbrdf capture's output or any folder of the four maps), "
                        "a thesis strip .png or example:NAME; repeat for more")
    p.add_argument("--no-exemplar", action="store_true",
                   help="run without exemplars (the no-exemplar baseline of the thesis's Fig. 5.7)")
    p.add_argument("-o", "--out", default="out/large-scale", help="output folder (default: out/large-scale)")
    p.add_argument("--tile", type=int_at_least(1), default=None,
                   help="tile side in px (default: the net's training tile, 512 full / 128 compact)")
    p.add_argument("--overlap", type=int_at_least(0), default=None,
                   help="minimum overlap of neighbouring tiles in px, < --tile (default: half a tile)")
    p.add_argument("--weights", default=None, metavar="FILE_OR_DIR",
                   help="a training checkpoint (checkpoint.pt of mi-svbrdf train large) or a weights folder with "
                        "manifest.json (default: the bundled large-scale weights)")
    p.add_argument("--device", default="cpu", help=f"where the network runs: {DEVICE_HELP}")
    p.add_argument("--no-progress", action="store_true", help="no progress bar over the tiles")
    p.set_defaults(func=run_cli, _replaces=True, _owns=OWNED)


def main(argv: list[str] | None = None) -> int:
    """Run ``large-scale`` on its own: ``main(["large-scale", "wall.jpg", "--exemplar", "out/capture"])``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
