"""``mi-svbrdf export``: a material folder as glTF 2.0, a Blender script or a Mitsuba scene."""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
from typing import Any

from mi_svbrdf.cli.common import add_command, material_from_spec, standalone
from mi_svbrdf.io import export as E

DESCRIPTION = """\
Export a material (a folder of normal/diffuse/roughness/specular .png or .exr, as written by
mi-svbrdf capture/optimize/render, a thesis strip .png, or example:NAME) for other tools.

--normals directx writes textures/normal_directx.* (green flipped) for engines that want it:
glTF and Mitsuba also keep (and reference) the OpenGL map they require; the Blender export
writes the DirectX map instead of normal.png and its script flips it back in the node tree.
"""
OUTPUTS = """\
Writes to -o/--out:
  --format gltf      material.gltf, material.bin   glTF 2.0: a 2 x 2 textured square with
                     textures/base_color.png       KHR_materials_specular (specular colour) and
                     textures/metallic_roughness.png   a metallic-roughness fallback; roughness
                     textures/normal.png           in G (glTF also uses alpha = r^2), OpenGL
                     textures/specular_color.png   normals. Prints the approximation's RMSE
                                                   (glTF BRDF vs ours, same lights).
  --format blender   material_blender.py           run: blender --python material_blender.py
                     textures/base_color.png, specular_tint.png (sRGB),
                     textures/roughness.png, normal.png, specular_f0.png (Non-Color)
  --format mitsuba   scene.xml                     svbrdf_ggx with bitmap textures, a flash
                     textures/{normal,diffuse,roughness,specular}.exr   capture (import
                                                   mi_svbrdf, then mi.load_file)
  every format       export.json                   files, notes, the glTF approximation error
"""
EXAMPLES = ("mi-svbrdf export example:tiles --format gltf -o out/gltf",
            "mi-svbrdf export out/optimize/material --format blender --normals directx -o out/blender")
#: The full help text, as ``--help`` shows it around the options.
EXPORT_HELP = f"{DESCRIPTION}\n{OUTPUTS}"


def _print_summary(summary: dict[str, Any], out: pathlib.Path) -> None:
    approx = summary.get("approximation")
    if approx:
        ex = approx["exported"]
        print(f"glTF approximation of the mi_svbrdf BRDF under {len(ex['rmse_display_per_light'])} lights: "
              f"RMSE display {ex['rmse_display']:.4f}, linear {ex['rmse_linear']:.4f} "
              f"(naive baseColor = d: display {approx['naive_base_color_d']['rmse_display']:.4f}; "
              f"viewer without KHR_materials_specular: display "
              f"{approx['fallback_without_extension']['rmse_display']:.4f})")
    print(json.dumps(summary, indent=2))
    print(f"wrote {out}/: " + ", ".join([*summary["files"], E.SUMMARY_NAME]))


def cmd_export(args: argparse.Namespace) -> int:
    """Run ``export``: read the material, write the files of :data:`OUTPUTS`; returns 0."""
    out = pathlib.Path(args.out)
    maps = material_from_spec(args.material, arg="MATERIAL")
    summary = E.export_material(maps, out, args.format, normals=args.normals, source=str(args.material))
    _print_summary(summary, out)
    return 0


def add_parser(subparsers: Any) -> None:
    """Register ``mi-svbrdf export``."""
    p = add_command(subparsers, "export", help="export a material folder as glTF 2.0, a Blender script or a "
                                               "Mitsuba scene",
                    description=DESCRIPTION, outputs=OUTPUTS, example_lines=EXAMPLES)
    p.add_argument("material", metavar="MATERIAL",
                   help="material folder (read by mi_svbrdf.io.material_io), strip .png or example:NAME")
    p.add_argument("--format", "-f", required=True, choices=E.FORMATS, help="what to write")
    p.add_argument("-o", "--out", required=True, help="output folder (created)")
    p.add_argument("--normals", choices=E.NORMAL_CONVENTIONS, default="opengl",
                   help="normal-map convention: opengl (default) or directx (also write a green-flipped map)")
    p.set_defaults(func=cmd_export)


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.cli.export``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    sys.exit(main())
