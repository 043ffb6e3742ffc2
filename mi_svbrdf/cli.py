"""The ``mi-svbrdf`` command line.

Subcommands:
    render          render a material through a bundled (or your own) Mitsuba scene and write
                    the maps, the render and rendering-loss values to an output folder.
    materials make  write a deterministic bank of procedural SVBRDFs (strips or folders), with
                    an index and a contact sheet.
    dataset render  render a bank through a Mitsuba capture scene into a resumable dataset of
                    strips (local processes or a Ray cluster).
    optimize        fit the four maps to calibrated photos (capture.json) by inverse rendering
                    (texel path for rectified images, Mitsuba for perspective ones).
    train           train the single- or multi-image network on the online capture simulator.
    capture         recover the four maps from flash photo(s) with the bundled networks
                    (maps, contact sheet, relit GIF).
    evaluate        learned vs optimised on the fixed held-out set: tables, speed/accuracy and
                    images-vs-accuracy charts, a gallery, the failure-case suite (--cases).

Run ``mi-svbrdf render --help`` for the options.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

RENDER_HELP = """\
Render a material through a Mitsuba scene and write, to --out:
  material/      the maps as linear EXR + material.json (what the scene reads)
  maps.png       normal | diffuse | roughness | specular, side by side (sRGB preview)
  render.exr     the scene's render, linear;  render.png  the same, sRGB-encoded
  texel.png      the texel renderer's image of the same capture (flash_capture only)
  summary.json   scene parameters, timings, the texel-vs-Mitsuba difference and the
                 rendering loss of a trivial estimate (render as diffuse, flat normal,
                 specular 0.04, roughness 0.5) against the material, on both backends.

The material is a built-in example (example:tiles, example:metal_plate), a material folder
(normal/diffuse/roughness/specular .png or .exr) or a thesis-dataset strip PNG.
"""


def _load_material(spec: str, size: int) -> tuple[torch.Tensor, str]:
    from mi_svbrdf import examples, material_io, strip

    if spec.startswith("example:"):
        return examples.example_material(spec.split(":", 1)[1], size=size), spec
    path = pathlib.Path(spec)
    if path.is_dir():
        return material_io.read_material(path), str(path)
    if path.is_file() and path.suffix.lower() == ".png":
        return strip.read_strip(path)[1], str(path)
    raise SystemExit(f"--material: expected example:NAME ({', '.join(sorted(examples.EXAMPLES))}), "
                     f"a material folder or a strip .png, got {spec!r}")


def parse_params(items: Sequence[str]) -> dict[str, str]:
    """``["KEY=VALUE", ...]`` (repeated ``--param``) -> dict; a malformed item is a ValueError."""
    params = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--param: expected KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        params[key.strip()] = value.strip()
    return params


def help_command(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], int]:
    """A ``func`` for a command group run without its subcommand: print its help, exit code 2."""
    def show(args: argparse.Namespace) -> int:
        parser.print_help()
        return 2
    return show


def _atomic_json(path: pathlib.Path, data: dict[str, Any]) -> None:
    from mi_svbrdf.image_io import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def _srgb_png(path: pathlib.Path, linear: np.ndarray) -> None:
    from mi_svbrdf.image_io import write_image
    from mi_svbrdf.material_io import srgb_encode

    write_image(path, srgb_encode(np.clip(linear, 0.0, 1.0)).astype(np.float32), 8, srgb=True)


def _maps_preview(maps: torch.Tensor) -> np.ndarray:
    m = maps[0]
    panels = [(m[0:3] + 1) * 0.5, m[3:6], m[6:7].expand(3, -1, -1), m[7:10]]
    return torch.cat(panels, dim=2).permute(1, 2, 0).numpy()


def cmd_render(args: argparse.Namespace) -> int:
    import drjit as dr
    import mitsuba as mi

    import mi_svbrdf as ms
    from mi_svbrdf import material_io, scenes
    from mi_svbrdf.image_io import write_image

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    maps, source = _load_material(args.material, args.size)
    maps = ms.maps.normalize_normals(maps)
    ms.maps.check_maps(maps, "material")
    size = maps.shape[-1]
    material_dir = out / "material"
    material_io.write_material(material_dir, maps, fmt="exr")
    _srgb_png(out / "maps.png", _maps_preview(maps))

    params = {"res": size, "spp": args.spp}
    params.update(parse_params(args.param))
    tex = {k: str((material_dir / f"{k}.exr").resolve()) for k in ("normal", "diffuse", "roughness", "specular")}
    if args.scene.endswith(".xml"):
        params.update(tex)
        scene = mi.load_file(args.scene, **{k: str(v) for k, v in params.items()})
        defaults: dict[str, str] = {}
    else:
        defaults = scenes.scene_parameters(args.scene)
        params.update({k: v for k, v in tex.items() if k in defaults})
        params = {k: v for k, v in params.items() if k in defaults or k not in ("res", "spp")}
        scene = scenes.load_scene(args.scene, **params)
    t0 = time.perf_counter()
    image = mi.render(scene, seed=args.seed)
    dr.eval(image)
    render_s = time.perf_counter() - t0
    image = np.asarray(image, dtype=np.float32)[..., :3]
    write_image(out / "render.exr", image)
    _srgb_png(out / "render.png", image)

    summary: dict[str, Any] = {"material": source, "scene": args.scene, "scene_parameters":
                               {k: str(v) for k, v in params.items()}, "variant": mi.variant(),
                               "render_seconds": round(render_s, 3)}
    if args.scene == "flash_capture" and image.shape[0] == size:
        # The same capture on the texel path: pixel (i, j) sees texel (i, j).
        p = {k: float(v) for k, v in {**defaults, **params}.items()
             if k in ("cam_z", "light_x", "light_y", "light_z", "light_intensity", "fov")}
        if abs(p["fov"] - scenes.CAPTURE_FOV) < 1e-6 and abs(p["cam_z"] - scenes.CAPTURE_DISTANCE) < 1e-4:
            light = torch.tensor([[[p["light_x"], p["light_y"], p["light_z"]]]])
            view = torch.tensor([[[0.0, 0.0, p["cam_z"]]]])
            texel = ms.render(maps, light, view, intensity=p["light_intensity"] / np.pi, distance_falloff=True)
            texel = texel[0, 0].permute(1, 2, 0).numpy()
            _srgb_png(out / "texel.png", texel)
            summary["texel_vs_mitsuba_mean_abs_diff"] = float(np.abs(texel - image).mean())
            summary["mean_radiance"] = float(image.mean())

    # Rendering loss of a trivial estimate against the material, on both backends.
    photo = torch.from_numpy(image).permute(2, 0, 1)[None].clamp(0, 1)
    if photo.shape[-2:] == maps.shape[-2:]:
        trivial = ms.maps.make_maps(torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, size, size),
                                    photo, torch.full((1, 1, size, size), 0.5),
                                    torch.full((1, 3, size, size), 0.04))
        losses = {}
        for backend in ("mitsuba", "torch"):
            gen = torch.Generator().manual_seed(args.seed)
            losses[backend] = float(ms.rendering_loss(trivial, maps, generator=gen, backend=backend))
        summary["rendering_loss_trivial_estimate"] = losses
    _atomic_json(out / "summary.json", summary)
    print(json.dumps(summary, indent=2))
    print(f"wrote {out}/: material/, maps.png, render.exr, render.png"
          + (", texel.png" if "texel_vs_mitsuba_mean_abs_diff" in summary else "") + ", summary.json")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mi-svbrdf", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("render", help="render a material through a Mitsuba scene (maps, render, loss)",
                       description=RENDER_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--material", default="example:tiles",
                   help="example:NAME, a material folder or a strip .png (default: example:tiles)")
    p.add_argument("--scene", default="flash_capture",
                   help="a bundled scene name (flash_capture, multiview_capture, ambient_capture, relight) "
                        "or the path of your own .xml (default: flash_capture)")
    p.add_argument("--size", type=int, default=256, help="resolution of example materials (default: 256)")
    p.add_argument("--spp", type=int, default=16, help="samples per pixel (default: 16)")
    p.add_argument("--seed", type=int, default=0, help="seed of the render and of the loss configurations")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene parameter, e.g. --param light_x=0.3 (repeatable)")
    p.add_argument("--out", "-o", default="out/render", help="output folder (default: out/render)")
    p.set_defaults(func=cmd_render)
    from mi_svbrdf import bank, capture_cli, dataset_render, train
    from mi_svbrdf.evaluation import cli as evaluate_cli
    from mi_svbrdf.optimization import cli as optimize_cli

    bank.add_parser(sub)
    dataset_render.add_parser(sub)
    optimize_cli.add_parser(sub)
    train.add_parser(sub)
    capture_cli.add_parser(sub)
    evaluate_cli.add_parser(sub)
    return parser


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen subcommand; bad input -> a one-line error and exit code 2."""
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"mi-svbrdf {args.command}: error: {exc}", file=sys.stderr)
        return 2


def standalone(add_parser: Callable[[Any], None], argv: list[str] | None = None) -> int:
    """Run one command module on its own (its ``add_parser``), as ``python -m`` entry points do."""
    parser = argparse.ArgumentParser(prog="mi-svbrdf")
    add_parser(parser.add_subparsers(dest="command", metavar="COMMAND"))
    return run(parser, argv)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
