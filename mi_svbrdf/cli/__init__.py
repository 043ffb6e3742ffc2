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
    capture-file make / import
                    write a capture.json for optimize from photos and the camera and flash
                    you state, or from another lab's capture folder.
    train           train the single- or multi-image network on the online capture simulator.
    capture         recover the four maps from flash photo(s) with the bundled networks
                    (maps, contact sheet, relit GIF).
    large-scale     the maps of a large surface (wall, floor) of any size from one ambient-lit
                    photo and exemplar materials, tile by tile (thesis ch. 5).
    evaluate        learned vs optimised on the fixed held-out set: tables, speed/accuracy and
                    images-vs-accuracy charts, a gallery, the failure-case suite (--cases).
    ablations       the thesis's ablations at equal compute (loss, global track, capture
                    perturbations, pooling): short trainings scored on the held-out set.
    rectify         find the paper frame (or the AprilTag print) in real photos, warp each to the
                    sample seen from above and recover each camera's pose (capture.json for optimize).
    frame           a printable capture frame at true scale: the AprilTag print or the paper frame
                    (PDFs on A4 and Letter).
    export          a material folder as glTF 2.0, a Blender script or a Mitsuba scene.
    view            a self-contained WebGL2 page that relights a material in the browser.
    calibrate       compare a material with a measured BRDF (MERL or CSV): conoscopic maps,
                    factor and errors, a corrected material.
    scan            photos of the tag print or the paper frame to a material in one command: rectify,
                    optimize, export and view into sub-folders, and one index.html of their pictures.

Every command that writes files takes ``-o/--out`` (its output folder); ``mi-svbrdf COMMAND
--help`` lists the options and the files it writes. A folder belongs to the command that wrote
it: run again into the same folder, a command replaces its own previous outputs there (and leaves
other files alone); the resumable ones (dataset render, train --resume, evaluate, ablations)
continue where they stopped; another command refuses the folder (--force: it removes the first
one's results). A folder that no command recorded and that holds files with a command's output
names (your own) is refused too (--force: they are replaced). Ctrl-C stops a command with one line
saying what its folder holds, exit code 130, also while it starts. Progress bars are drawn on a
terminal only: with stderr redirected to a file or a pipe there are none.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterable
from types import ModuleType

from mi_svbrdf.cli.common import INTERRUPTED, CommandParser, add_force_options, run, starting, terminal_help

#: The subcommands in the order ``mi-svbrdf --help`` lists them: name -> (module of mi_svbrdf.cli, the line of the
#: list; the module's own help, checked by a test). A subcommand's module, and what it imports (torch, Mitsuba,
#: the networks ...), is imported only when that subcommand runs or shows its help.
COMMANDS: dict[str, tuple[str, str]] = {
    "render": ("render", "render a material through a Mitsuba scene (maps, render, loss)"),
    "materials": ("materials", "procedural SVBRDF banks (materials make ...)"),
    "dataset": ("dataset", "training datasets (dataset render ...)"),
    "optimize": ("optimize", "fit SVBRDF maps to a calibrated capture (capture.json)"),
    "capture-file": ("capture_file", "capture files for optimize (capture-file make / import ...)"),
    "train": ("train", "train a network on the online capture simulator"),
    "capture": ("capture", "SVBRDF maps from flash photo(s) with the bundled networks"),
    "large-scale": ("large_scale", "SVBRDF maps of a large surface from one ambient-lit photo and exemplar materials"),
    "evaluate": ("evaluate", "evaluate the methods on the held-out benchmark (report folder)"),
    "ablations": ("ablations", "the thesis's ablations at equal compute (short CPU trainings)"),
    "rectify": ("rectify", "rectify framed flash photos into a calibrated capture"),
    "frame": ("frame", "a printable capture frame (AprilTag print or paper frame), true scale"),
    "export": ("export", "export a material folder as glTF 2.0, a Blender script or a Mitsuba scene"),
    "view": ("view", "a self-contained WebGL2 page of a material (drag the light)"),
    "calibrate": ("calibrate", "compare a material with a measured BRDF (MERL or CSV): conoscopic maps, factor and "
                               "errors, a corrected material"),
    "scan": ("scan", "photos of the tag print or paper frame to a material: rectify, optimize, export, view, "
                     "one index.html"),
}
#: The modules of :data:`COMMANDS` (``mi_svbrdf.cli.NAME`` imports one on first use).
MODULES = tuple(module for module, _ in COMMANDS.values())
#: The commands of :data:`COMMANDS` that group subcommands (``mi-svbrdf dataset render``).
GROUPS = ("materials", "dataset", "capture-file")


def __getattr__(name: str) -> ModuleType:
    """``mi_svbrdf.cli.capture`` and the other subcommand modules, imported on first use (PEP 562)."""
    if name in MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The ``mi-svbrdf`` parser: the subcommands of ``commands`` (default: all) in full, each other one only
    listed (its name and line, enough for ``mi-svbrdf --help`` and to be refused as a choice it is not)."""
    full = set(COMMANDS) if commands is None else set(commands)
    parser = CommandParser(prog="mi-svbrdf", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, line) in COMMANDS.items():
        if name in full:
            importlib.import_module(f"{__name__}.{module}").add_parser(sub)
        else:
            sub.add_parser(name, help=line)
    # --force where a command writes a folder; docstring markup rendered for the terminal, in every help text
    return terminal_help(add_force_options(parser))


def command_of(argv: list[str]) -> str | None:
    """The subcommand ``argv`` names (its first word that is not an option), or None."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in COMMANDS else None


def main(argv: list[str] | None = None) -> int:
    """The ``mi-svbrdf`` entry point: only the chosen subcommand's module is imported, and Ctrl-C at any time
    is one line and exit code :data:`~mi_svbrdf.cli.common.INTERRUPTED` (130): while the process starts, by
    :func:`~mi_svbrdf.cli.common.guard_start`; once the command runs, by :func:`~mi_svbrdf.cli.common.run`.

    Before a subcommand that runs (not one asked for its help) is imported, the Mitsuba variant is selected
    and the plugins registered, as importing :mod:`mi_svbrdf` does elsewhere (the ``mi-svbrdf`` process
    defers that set-up to here: :func:`mi_svbrdf.started_as_command`).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    name = command_of(argv)
    words = [a for a in argv if not a.startswith("-")][:2 if name in GROUPS else 1] if name else []
    starting(" ".join(["mi-svbrdf", *words]))  # the line of a Ctrl-C while it starts
    try:
        if name is not None and not {"-h", "--help"} & set(argv):
            from mi_svbrdf.variant import ensure_variant

            ensure_variant()
        return run(build_parser([name] if name else []), argv)
    except KeyboardInterrupt:  # called from Python (no guard_start): run() answers once the command runs
        print(f"{' '.join(['mi-svbrdf', *words])}: interrupted while starting; nothing was written", file=sys.stderr)
        return INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
