"""``mi-svbrdf render``: a material through a Mitsuba scene -- maps, the render, the texel image, loss values."""
from __future__ import annotations

import argparse
import pathlib
import time
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import torch

from mi_svbrdf import scenes
from mi_svbrdf.cli.common import (
    add_command,
    int_at_least,
    material_from_spec,
    material_outputs,
    parse_params,
    replace_outputs,
    standalone,
)
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.loss import rendering_loss
from mi_svbrdf.core.render import render
from mi_svbrdf.io import material_io
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.variant import PREFERRED_VARIANTS, variant_context, variant_for

DESCRIPTION = """\
Render a material through a Mitsuba scene: its maps, the render, the texel renderer's image of
the same capture and rendering-loss values. The material is a built-in example (example:tiles,
example:metal_plate), a material folder (normal/diffuse/roughness/specular .png or .exr) or a
thesis-dataset strip PNG; the scene a bundled one or your own .xml, its $parameters set with
--param KEY=VALUE.
"""
OUTPUTS = """\
Writes to -o/--out:
  material/      the maps as linear EXR + material.json (what the scene reads)
  maps.png       normal | diffuse | roughness | specular, side by side (sRGB preview)
  render.exr     the scene's render, linear;  render.png  the same, sRGB-encoded
  texel.png      the texel renderer's image of the same capture (flash_capture only)
  summary.json   scene parameters, timings, the texel-vs-Mitsuba difference (linear radiance: the
                 texel image samples each pixel's centre once, Mitsuba integrates the pixel's area
                 with --spp samples, so a glossy highlight that varies within a pixel differs; with
                 the texel image averaged over 4x4 points per pixel the rest is Mitsuba's pixel
                 filter and noise) and the
                 rendering loss of a trivial estimate (render as diffuse, flat normal,
                 specular 0.04, roughness 0.5) against the material, on both backends
"""
EXAMPLES = ("mi-svbrdf render --material example:metal_plate --size 64 -o out/render",
            "mi-svbrdf render --scene relight --param env_rotation=90 -o out/relight")
#: Parameters of the bundled scenes that are integers, with their smallest value.
INT_PARAMS = {"res": 1, "spp": 1, "max_depth": -1}
#: The full help text, as ``--help`` shows it around the options.
RENDER_HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of :data:`OUTPUTS` (patterns relative to -o/--out): a new render replaces a previous one's.
OWNED = (*material_outputs("material"), "maps.png", "render.exr", "render.png", "texel.png", "summary.json")


def check_scene_params(params: dict[str, str], defaults: dict[str, str]) -> None:
    """``--param`` values of a bundled scene: integers where :data:`INT_PARAMS` says so, numbers where
    the default is a number; a ``ValueError`` names the parameter."""
    for key, value in params.items():
        if key not in defaults:
            raise ValueError(f"--param {key}: expected a parameter of the scene ({', '.join(defaults)}), got {key!r}")
        if key in INT_PARAMS:
            try:
                ok = int(value) >= INT_PARAMS[key]
            except ValueError:
                ok = False
            if not ok:
                raise ValueError(f"--param {key}: expected an integer >= {INT_PARAMS[key]}, got {value!r}")
            continue
        try:
            float(defaults[key])
        except ValueError:
            continue  # a string parameter (a file, a distribution name): Mitsuba checks it
        try:
            ok = np.isfinite(float(value))
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"--param {key}: expected a number (default {defaults[key]}), got {value!r}")


def load_scene_checked(scene: str, params: dict[str, Any]) -> mi.Scene:
    """Load a bundled scene by name or an .xml file; Mitsuba's errors become one-line ``ValueError``."""
    try:
        if scene.endswith(".xml"):
            return mi.load_file(scene, **{k: str(v) for k, v in params.items()})
        return scenes.load_scene(scene, **params)
    except RuntimeError as err:
        raise ValueError(f"--scene {scene} with --param: Mitsuba could not load it: {err}") from err


def _srgb_png(path: pathlib.Path, linear: np.ndarray) -> None:
    write_image(path, material_io.srgb_encode(np.clip(linear, 0.0, 1.0)).astype(np.float32), 8, srgb=True)


def cmd_render(args: argparse.Namespace) -> int:
    """Run ``render``: check the inputs, then write the files of :data:`OUTPUTS`; returns 0."""
    if args.scene.endswith(".xml") and not pathlib.Path(args.scene).is_file():
        raise FileNotFoundError(f"--scene: expected a bundled scene name or an .xml file, got no such file "
                                f"{args.scene!r}")
    if not args.scene.endswith(".xml") and args.scene not in scenes.scene_names():
        raise ValueError(f"--scene: expected a bundled scene ({', '.join(scenes.scene_names())}) or an .xml file, "
                         f"got {args.scene!r}")
    user_params = parse_params(args.param)
    defaults: dict[str, str] = {} if args.scene.endswith(".xml") else scenes.scene_parameters(args.scene)
    if defaults:  # a bundled scene: check --param before anything is written
        check_scene_params({k: str(v) for k, v in {"spp": args.spp, **user_params}.items()}, defaults)
    maps, source = material_from_spec(args.material, args.size, "--material"), args.material
    # The BRDF model a material folder records (material.json; ggx otherwise); --param distribution=... overrides it.
    model = material_io.read_distribution(args.material) if pathlib.Path(args.material).is_dir() else "ggx"
    model = str(user_params.get("distribution", model))
    out = pathlib.Path(args.out)
    maps = M.normalize_normals(maps)
    M.check_maps(maps, "material")
    replace_outputs(args, out, OWNED, keep=[args.material, *([args.scene] if args.scene.endswith(".xml") else [])])
    out.mkdir(parents=True, exist_ok=True)
    size = maps.shape[-1]
    material_dir = out / "material"
    material_io.write_material(material_dir, maps, fmt="exr", distribution=model)
    _srgb_png(out / "maps.png", M.preview(maps)[0].permute(1, 2, 0).numpy())

    params = {"res": size, "spp": args.spp, **user_params}
    if "distribution" in defaults:
        params["distribution"] = model
    tex = {k: str((material_dir / f"{k}.exr").resolve()) for k in M.MAP_NAMES}
    if not defaults:
        params.update(tex)
    else:
        params.update({k: v for k, v in tex.items() if k in defaults})
        params = {k: v for k, v in params.items() if k in defaults or k not in ("res", "spp")}
    # Mitsuba's scenes need a JIT variant: the active one when it is ours (cuda_ad_rgb on a GPU), else the CPU's.
    variant = mi.variant() if mi.variant() in PREFERRED_VARIANTS else variant_for("cpu")
    with variant_context(variant):
        scene = load_scene_checked(args.scene, params)
        t0 = time.perf_counter()
        image = mi.render(scene, seed=args.seed)
        dr.eval(image)
        render_s = time.perf_counter() - t0
        image = np.asarray(image, dtype=np.float32)[..., :3]
    write_image(out / "render.exr", image)
    _srgb_png(out / "render.png", image)

    summary: dict[str, Any] = {"material": source, "scene": args.scene, "scene_parameters":
                               {k: str(v) for k, v in params.items()}, "variant": variant,
                               "render_seconds": round(render_s, 3), "distribution": model}
    if args.scene == "flash_capture" and image.shape[0] == size:
        # The same capture on the texel path: pixel (i, j) sees texel (i, j).
        p = {k: float(v) for k, v in {**defaults, **params}.items()
             if k in ("cam_z", "light_x", "light_y", "light_z", "light_intensity", "fov")}
        if abs(p["fov"] - scenes.CAPTURE_FOV) < 1e-6 and abs(p["cam_z"] - scenes.CAPTURE_DISTANCE) < 1e-4:
            light = torch.tensor([[[p["light_x"], p["light_y"], p["light_z"]]]])
            view = torch.tensor([[[0.0, 0.0, p["cam_z"]]]])
            texel = render(maps, light, view, intensity=p["light_intensity"] / np.pi, distance_falloff=True,
                           distribution=model)
            texel = texel[0, 0].permute(1, 2, 0).numpy()
            _srgb_png(out / "texel.png", texel)
            summary["texel_vs_mitsuba_mean_abs_diff"] = float(np.abs(texel - image).mean())
            summary["mean_radiance"] = float(image.mean())
            summary["fraction_above_1"] = float((image > 1.0).mean())  # highlights brighter than the display's white
            if size <= SUPERSAMPLED_MAX:  # the same over each pixel's area: what the rest of the difference is
                fine = texel_over_pixels(maps, light, view, p["light_intensity"] / np.pi, model)
                summary["texel_4x4_vs_mitsuba_mean_abs_diff"] = float(np.abs(fine - image).mean())

    # Rendering loss of a trivial estimate against the material, on both backends.
    photo = torch.from_numpy(image).permute(2, 0, 1)[None].clamp(0, 1)
    if photo.shape[-2:] == maps.shape[-2:]:
        trivial = M.make_maps(torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, size, size),
                                    photo, torch.full((1, 1, size, size), 0.5),
                                    torch.full((1, 3, size, size), 0.04))
        losses = {}
        for backend in ("mitsuba", "torch"):
            gen = torch.Generator().manual_seed(args.seed)
            losses[backend] = float(rendering_loss(trivial, maps, generator=gen, target_distribution=model,
                                                   backend=backend))
        summary["rendering_loss_trivial_estimate"] = losses
    write_json(out / "summary.json", summary)
    print(summary_line(summary, out))
    return 0


#: The largest --size at which the texel image is also averaged over 4x4 points per pixel (a 4x larger render).
SUPERSAMPLED_MAX = 512


def texel_over_pixels(maps: torch.Tensor, light: torch.Tensor, view: torch.Tensor, intensity: float,
                      distribution: str, k: int = 4) -> np.ndarray:
    """The texel renderer's image averaged over ``k x k`` points per pixel (maps upsampled bilinearly, normals
    renormalised), as Mitsuba's samples cover each pixel's area: ``(H, W, 3)`` linear."""
    fine = M.normalize_normals(torch.nn.functional.interpolate(maps, scale_factor=k, mode="bilinear",
                                                                align_corners=False))
    image = render(fine, light, view, intensity=intensity, distance_falloff=True, distribution=distribution)
    h, w = maps.shape[-2:]
    return image[0, 0].reshape(3, h, k, w, k).mean(dim=(2, 4)).permute(1, 2, 0).numpy()


def summary_line(summary: dict[str, Any], out: pathlib.Path) -> str:
    """One line: what was rendered, how long it took and the files written to ``out`` (the details stay in
    ``summary.json``)."""
    texel = "texel_vs_mitsuba_mean_abs_diff" in summary
    files = ["material/", "maps.png", "render.exr", "render.png", *(["texel.png"] if texel else []), "summary.json"]
    diff = ""
    if texel:
        diff = (f", texel vs Mitsuba mean |diff| {summary['texel_vs_mitsuba_mean_abs_diff']:.4f} of mean radiance "
                f"{summary['mean_radiance']:.4f} (linear; the texel image samples each pixel's centre, Mitsuba its area")
        if "texel_4x4_vs_mitsuba_mean_abs_diff" in summary:
            diff += f": {summary['texel_4x4_vs_mitsuba_mean_abs_diff']:.4f} with the texel image over 4x4 points"
        if summary.get("fraction_above_1", 0.0) > 0.01:
            diff += f"; {summary['fraction_above_1']:.0%} of the values are highlights above 1"
        diff += ")"
    return (f"rendered {summary['material']} through {summary['scene']} ({summary['distribution']}) in "
            f"{summary['render_seconds']:.2f} s{diff}; wrote {out}/: {', '.join(files)}")


def add_parser(subparsers: Any) -> None:
    """Add the ``render`` command to ``subparsers``."""
    p = add_command(subparsers, "render", help="render a material through a Mitsuba scene (maps, render, loss)",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("--material", default="example:tiles",
                   help="example:NAME, a material folder or a strip .png (default: example:tiles)")
    p.add_argument("--scene", default="flash_capture",
                   help="a bundled scene name (flash_capture, multiview_capture, ambient_capture, relight) "
                        "or the path of your own .xml (default: flash_capture)")
    p.add_argument("--size", type=int_at_least(16), default=256, help="resolution of example materials (default: 256)")
    p.add_argument("--spp", type=int_at_least(1), default=16, help="samples per pixel (default: 16)")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="seed of the render and of the loss configurations")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene parameter, e.g. --param light_x=0.3 (repeatable)")
    p.add_argument("--out", "-o", default="out/render", help="output folder (default: out/render)")
    p.set_defaults(func=cmd_render, _replaces=True, _owns=OWNED)


def main(argv: list[str] | None = None) -> int:
    """Run ``render`` on its own: ``main(["render", "--out", "out/render"])``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
