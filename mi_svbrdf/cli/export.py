"""``mi-svbrdf export``: a material folder as glTF 2.0, a Blender script or a Mitsuba scene."""
from __future__ import annotations

import argparse
import pathlib
import sys
from typing import Any

from mi_svbrdf.cli.common import add_command, material_from_spec, replace_outputs, standalone
from mi_svbrdf.io import export as E
from mi_svbrdf.io.material_io import read_distribution

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
  --format mitsuba   scene.xml                     svbrdf_ggx (svbrdf_beckmann) with bitmap textures, a flash
                     textures/{normal,diffuse,roughness,specular}.exr   capture (import
                                                   mi_svbrdf, then mi.load_file)
  every format       export.json                   files, notes, the glTF approximation error
"""
EXAMPLES = ("mi-svbrdf export example:tiles --format gltf -o out/gltf",
            "mi-svbrdf export out/optimize/material --format blender --normals directx -o out/blender")
#: The full help text, as ``--help`` shows it around the options.
EXPORT_HELP = f"{DESCRIPTION}\n{OUTPUTS}"
#: The files of every format (patterns relative to -o/--out): an export replaces a previous one's, of any format.
OWNED = ("material.gltf", "material.bin", "material_blender.py", "scene.xml", E.SUMMARY_NAME,
         *(f"textures/{name}" for name in (
             "base_color.png", "metallic_roughness.png", "specular_color.png", "roughness.png", "specular_f0.png",
             "specular_tint.png", "normal.png", "normal.exr", "normal_directx.png", "normal_directx.exr",
             "diffuse.exr", "roughness.exr", "specular.exr")))


def summary_line(summary: dict[str, Any], out: pathlib.Path) -> str:
    """One line: the format, the files written to ``out`` and, for glTF, the approximation's error
    (the details stay in ``export.json``)."""
    files = ", ".join([*summary["files"], E.SUMMARY_NAME])
    line = f"exported {summary.get('format', 'the material')} to {out}/: {files}"
    approx = summary.get("approximation")
    if approx:
        ex = approx["exported"]
        line += (f"; glTF approximation of our BRDF under {len(ex['rmse_display_per_light'])} lights: "
                 f"RMSE display {ex['rmse_display']:.4f} (without KHR_materials_specular "
                 f"{approx['fallback_without_extension']['rmse_display']:.4f})")
    notes = summary.get("notes") or []
    if notes:
        line += f"; {len(notes)} note{'s' if len(notes) != 1 else ''} in {E.SUMMARY_NAME}"
    return line


def cmd_export(args: argparse.Namespace) -> int:
    """Run ``export``: read the material, write the files of :data:`OUTPUTS`; returns 0."""
    out = pathlib.Path(args.out)
    maps = material_from_spec(args.material, arg="MATERIAL")
    replace_outputs(args, out, OWNED, keep=[args.material])
    distribution = read_distribution(args.material) if pathlib.Path(args.material).is_dir() else "ggx"
    summary = E.export_material(maps, out, args.format, normals=args.normals, source=str(args.material),
                                distribution=distribution)
    print(summary_line(summary, out))
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
    p.set_defaults(func=cmd_export, _replaces=True, _owns=OWNED)


def main(argv: list[str] | None = None) -> int:
    """``python -m mi_svbrdf.cli.export``."""
    return standalone(add_parser, argv)


if __name__ == "__main__":
    sys.exit(main())
