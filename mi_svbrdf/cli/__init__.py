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
    capture-file make
                    write a capture.json for optimize from photos and the camera and flash
                    you state.
    train           train the single- or multi-image network on the online capture simulator.
    capture         recover the four maps from flash photo(s) with the bundled networks
                    (maps, contact sheet, relit GIF).
    large-scale     the maps of a large surface (wall, floor) of any size from one ambient-lit
                    photo and exemplar materials, tile by tile (thesis ch. 5).
    evaluate        learned vs optimised on the fixed held-out set: tables, speed/accuracy and
                    images-vs-accuracy charts, a gallery, the failure-case suite (--cases).
    ablations       the thesis's ablations at equal compute (loss, global track, capture
                    perturbations, pooling): short trainings scored on the held-out set.
    rectify         find the paper frame in real photos, warp each to the sample seen from
                    above and recover each camera's pose (capture.json for optimize).
    export          a material folder as glTF 2.0, a Blender script or a Mitsuba scene.
    view            a self-contained WebGL2 page that relights a material in the browser.
    calibrate       compare a material with a measured BRDF (MERL or CSV): conoscopic maps,
                    factor and errors, a corrected material.

Every command that writes files takes ``-o/--out`` (its output folder); ``mi-svbrdf COMMAND
--help`` lists the options and the files it writes. Run again into the same folder, a command
replaces its own previous outputs there (and leaves other files alone); the resumable ones
(dataset render, train --resume, evaluate, ablations) continue where they stopped. Ctrl-C stops a
command with one line saying what its folder holds, exit code 130.
"""
from __future__ import annotations

import argparse
import sys

from mi_svbrdf.cli import (
    ablations,
    calibrate,
    capture,
    capture_file,
    dataset,
    evaluate,
    export,
    large_scale,
    materials,
    optimize,
    rectify,
    render,
    train,
    view,
)
from mi_svbrdf.cli.common import add_force_options, run, terminal_help

#: The subcommand modules, in the order ``mi-svbrdf --help`` lists them.
COMMANDS = (render, materials, dataset, optimize, capture_file, train, capture, large_scale, evaluate, ablations, rectify,
            export, view, calibrate)


def build_parser() -> argparse.ArgumentParser:
    """The ``mi-svbrdf`` parser with every subcommand."""
    parser = argparse.ArgumentParser(prog="mi-svbrdf", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    # --force where a command writes a folder; docstring markup rendered for the terminal, in every help text
    return terminal_help(add_force_options(parser))


def main(argv: list[str] | None = None) -> int:
    """The ``mi-svbrdf`` entry point."""
    return run(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
