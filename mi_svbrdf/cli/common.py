"""What every subcommand shares: help texts, number options, ``KEY=VALUE`` parameters, command groups,
example inputs, running a parser with one-line errors.

Domain modules hold no argparse code; each subcommand lives in its own module of :mod:`mi_svbrdf.cli`
with an ``add_parser(subparsers)`` that registers it, usually through :func:`add_command` (the
description on top, then the options, then the files it writes and a runnable example).

This module imports no torch, Mitsuba or domain module at its top (those that need them import them
when called): ``mi-svbrdf --help`` and the start of every command read it before the heavy imports.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, NoReturn

from mi_svbrdf.assets import EXAMPLE_FLASH, EXAMPLE_VIEWS
from mi_svbrdf.io.atomic import clear_owned, owned_files, write_json, written_outputs

if TYPE_CHECKING:
    import torch

#: Exceptions that mean bad input: :func:`run` prints them as one line and exits with code 2.
INPUT_ERRORS = (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)
#: The headings of the examples at the end of a command's help (:func:`add_command`): one, several.
EXAMPLE_HEADINGS = ("Example:", "Examples:")
#: Exit code of a command stopped by Ctrl-C (128 + SIGINT), as shells report it.
INTERRUPTED = 130
#: What to do after Ctrl-C stopped a command that resumes (``set_defaults(_resume=RESUME_HINT)``).
RESUME_HINT = "re-run the same command to resume"
#: Photo arguments standing for bundled photos (:func:`expand_photos`).
EXAMPLE_PHOTOS = {"example": (EXAMPLE_FLASH,), "example:flash": (EXAMPLE_FLASH,), "example:multi": EXAMPLE_VIEWS}

_ROLE = re.compile(r":(?:py:)?(?:class|func|mod|data|meth|attr|obj|exc|const|ref|doc):`([^`]+)`")
_LITERAL = re.compile(r"``(.+?)``", re.DOTALL)
_STRONG = re.compile(r"\*\*(\S(?:.*?\S)?)\*\*")


def _role_text(match: re.Match[str]) -> str:
    text = match.group(1)
    title = re.match(r"(.+?)\s*<[^>]+>$", text)
    if title:
        return title.group(1)
    return text[1:].rsplit(".", 1)[-1] if text.startswith("~") else text


def terminal_text(text: str | None) -> str | None:
    """``text`` (a docstring) for a terminal: reStructuredText roles, double backticks and ``**`` removed.

    ``:class:`~a.b.C``` becomes ``C``, ``:func:`a.b``` becomes ``a.b``, ````x```` becomes ``x``.
    """
    if not text:
        return text
    return _STRONG.sub(r"\1", _LITERAL.sub(r"\1", _ROLE.sub(_role_text, text)))


def terminal_help(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Render every help text of ``parser`` and its subcommands with :func:`terminal_text`; returns ``parser``."""
    parser.description = terminal_text(parser.description)
    parser.epilog = terminal_text(parser.epilog)
    for action in parser._actions:
        if action.help and action.help is not argparse.SUPPRESS:
            action.help = terminal_text(action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                choice.help = terminal_text(choice.help)
            for child in action.choices.values():
                terminal_help(child)
    return parser


def epilog(outputs: str | None, example_lines: Sequence[str]) -> str:
    """The end of a command's help: the files it writes (``outputs``), then ``Example(s):`` and the command lines."""
    parts = [outputs.rstrip()] if outputs else []
    if example_lines:
        heading = EXAMPLE_HEADINGS[len(example_lines) > 1]
        parts.append("\n".join([heading, *(f"  {line}" for line in example_lines)]))
    return "\n\n".join(parts)


def add_command(subparsers: Any, name: str, *, help: str, description: str, outputs: str | None,
                example_lines: Sequence[str]) -> argparse.ArgumentParser:
    """Add the subcommand ``name``: its help reads description, options, then the files it writes and examples.

    Args:
        subparsers: the ``add_subparsers()`` object of the parent.
        name: the subcommand's name.
        help: one line for the parent's list of commands.
        description: what the command does (docstring markup is rendered by :func:`terminal_text`).
        outputs: the files it writes (``Writes to -o/--out:`` and one line per file), or None.
        example_lines: runnable command lines (``mi-svbrdf ...``), the first one small enough for a test.

    Returns:
        The new parser (add its arguments and ``set_defaults(func=...)``).
    """
    parser = subparsers.add_parser(name, help=help, description=terminal_text(description),
                                   epilog=terminal_text(epilog(outputs, example_lines)),
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.set_defaults(_prog=parser.prog)
    return parser


def _number(kind: type, what: str, check: Callable[[float], bool]) -> Callable[[str], Any]:
    """An argparse type: ``kind(text)`` when ``check`` accepts it, else an error saying ``expected {what}``."""
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            value = None
        if value is None or math.isnan(value) or not check(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value
    parse.__name__ = what  # argparse names the type in some messages
    return parse


def budget_seconds(text: str) -> float:
    """An argparse type: a wall-time budget in seconds, a number >= 0; ``0`` and ``inf`` both mean no limit and give
    ``inf`` (every command's ``--budget-s`` reads it, so that one flag accepts and refuses the same values
    everywhere)."""
    value = _number(float, "seconds >= 0 (0 or inf: no limit)", lambda v: v >= 0)(text)
    return math.inf if value == 0 else value


def int_at_least(low: int) -> Callable[[str], int]:
    """An argparse type: an int >= ``low``."""
    return _number(int, f"an integer >= {low}", lambda v: v >= low)


def int_between(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an int in ``[low, high]``."""
    return _number(int, f"an integer in [{low}, {high}]", lambda v: low <= v <= high)


def float_at_least(low: float, *, inclusive: bool = True, unit: str = "a number",
                   allow_inf: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite float >= ``low`` (> ``low`` unless ``inclusive``; ``inf`` too with ``allow_inf``)."""
    return _number(float, f"{unit} {'>=' if inclusive else '>'} {low:g}",
                   lambda v: (v >= low if inclusive else v > low) and (allow_inf or math.isfinite(v)))


def float_between(low: float, high: float, *, open_ends: bool = False, unit: str = "a number") -> Callable[[str], float]:
    """An argparse type: a float in ``[low, high]`` (``(low, high)`` with ``open_ends``)."""
    what = f"{unit} in {'(' if open_ends else '['}{low:g}, {high:g}{')' if open_ends else ']'}"
    return _number(float, what, lambda v: low < v < high if open_ends else low <= v <= high)


def finite_float(text: str) -> float:
    """An argparse type: any finite number."""
    return _number(float, "a finite number", math.isfinite)(text)


def floats(count: int, *, positive_z: bool = False) -> Callable[[str], tuple[float, ...]]:
    """An argparse type: ``count`` comma-separated finite numbers (``positive_z``: the third > 0)."""
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers, got {text!r}")
        if positive_z and values[2] <= 0:
            raise argparse.ArgumentTypeError(f"expected z > 0 (above the sample), got {text!r}")
        return values
    parse.__name__ = f"{count} numbers"
    return parse


def parse_params(items: Sequence[str], option: str = "--param") -> dict[str, str]:
    """``["KEY=VALUE", ...]`` (repeated ``option``) -> dict; a malformed item is a ValueError naming ``option``."""
    params = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"{option}: expected KEY=VALUE, got {item!r}")
        params[key.strip()] = value.strip()
    return params


def parse_settings(items: Sequence[str], option: str = "--set") -> dict[str, Any]:
    """``["KEY=VALUE", ...]`` -> dict, each value parsed as JSON when it is JSON, else kept as a string
    (``--set lr=1e-4``, ``--set sizes=[[0,128]]``, ``--set name=run``)."""
    settings: dict[str, Any] = {}
    for key, value in parse_params(items, option).items():
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            settings[key] = value
    return settings


def help_command(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], int]:
    """A ``func`` for a command group run without its subcommand: print its help, exit code 2."""
    def show(args: argparse.Namespace) -> int:
        parser.print_help()
        return 2
    return show


def material_from_spec(spec: str, size: int = 256, arg: str = "MATERIAL") -> torch.Tensor:
    """The ``(1, 10, H, W)`` maps of a material argument: ``example:NAME`` (a built-in example at
    ``size``), a material folder or a thesis strip ``.png``; errors name ``arg``."""
    from mi_svbrdf.data import examples
    from mi_svbrdf.io import material_io, strip

    expected = f"a material folder, a strip .png or example:NAME ({', '.join(sorted(examples.EXAMPLES))})"
    if spec.startswith("example:"):
        name = spec.split(":", 1)[1]
        if name not in examples.EXAMPLES:
            raise ValueError(f"{arg}: expected one of example:{', example:'.join(sorted(examples.EXAMPLES))}, "
                             f"got {spec!r}")
        return examples.example_material(name, size=size)
    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(f"{arg}: expected {expected}, got no such file or folder {spec!r}")
    if path.is_dir():
        return material_io.read_material(path)
    if path.suffix.lower() == ".png":
        return strip.read_strip(path)[1]
    raise ValueError(f"{arg}: expected {expected}, got the file {spec!r}")


def expand_photos(items: Sequence[str], arg: str = "PHOTO") -> list[str]:
    """Photo arguments as files: ``example`` / ``example:flash`` (the bundled flash photo) and
    ``example:multi`` (its three views) by their paths, a folder by its photos (sorted by name)."""
    from mi_svbrdf.io.photos import photo_files

    files: list[str] = []
    for item in items:
        if item in EXAMPLE_PHOTOS:
            files += [str(p) for p in EXAMPLE_PHOTOS[item]]
        elif Path(item).is_dir():
            found = photo_files(item)
            if not found:
                raise ValueError(f"{arg}: expected photos in the folder {item!r} (.jpg, .png, .tif, .exr ...), "
                                 "got none")
            files += [str(p) for p in found]
        else:
            files.append(item)
    return files


def command_group(subparsers: Any, name: str, help: str, description: str) -> Any:
    """Add a command that only groups subcommands (``mi-svbrdf NAME SUBCOMMAND``); returns their subparsers.

    Run without a subcommand, the group prints its help and exits with code 2.
    """
    group = subparsers.add_parser(name, help=help, description=terminal_text(description))
    group.set_defaults(func=help_command(group))
    return group.add_subparsers(dest=f"{name}_command", metavar="SUBCOMMAND")


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line: whitespace collapsed, Mitsuba's ``[file.cpp:N]`` tags dropped;
    an OS error with a file name as ``FILE: reason``."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror.lower()}"
    else:
        text = str(exc) or type(exc).__name__
    text = re.sub(r"\[[\w.]+\.(?:cpp|h|py):\d+\]\s*", "", text)
    return " ".join(text.split())


def material_outputs(folder: str = "") -> tuple[str, ...]:
    """The files :func:`mi_svbrdf.io.material_io.write_material` writes into ``folder`` (relative, ``""``:
    the output folder itself), as :func:`replace_outputs` patterns."""
    from mi_svbrdf.io import material_io

    prefix = f"{folder.rstrip('/')}/" if folder else ""
    maps = [f"{prefix}{name}.{ext}" for name in material_io.MAP_NAMES for ext in ("png", "exr")]
    return (*maps, f"{prefix}{material_io.METADATA_NAME}")


# --- Output folders: each belongs to the command that wrote it ---------------------------------------
#
# A command that writes a folder (-o/--out) records itself in the folder's OWNER_FILE when it starts
# writing there (claim_folder; replace_outputs does it for the commands that replace their outputs), and
# when it ends, the files it wrote (record_written, called by run): a re-run of the same command replaces
# its own files and keeps the user's; another command's folder, or a folder that no command recorded and
# that holds files with the command's output names (the user's own), is refused before any work (check_out,
# called by run) unless --force, which removes those files first.
# A command writes a folder when its defaults say so: _replaces (it replaces its outputs, replace_outputs),
# _resume (it resumes in the folder) or _owns (the patterns of the files it writes, which every command that
# writes a folder sets); _out_file (a bool or a function of args) says when -o names one file instead (no
# ownership then).

#: The hidden file of an output folder that records the command that wrote it: ``{"command": "mi-svbrdf
#: capture", "outputs": [what it wrote: file names, and the glob patterns of numbered files that match one]}``,
#: written atomically.
OWNER_FILE = ".mi-svbrdf.json"
#: The help of ``--force``, which every command that writes a folder takes (:func:`add_force_options`).
FORCE_HELP = ("write into a folder that holds another mi-svbrdf command's results, or files with this command's "
              "output names that no command recorded: remove those first (without --force such a folder is "
              "refused before any work; files with other names stay either way)")
#: How many file names the refusal of a folder holding the user's own files (:func:`check_folder`) lists.
LISTED_FILES = 4


def folder_owner(out: str | Path) -> dict[str, Any] | None:
    """What :data:`OWNER_FILE` of the folder ``out`` records (``{"command": ..., "outputs": [...]}``), or None
    (no such folder or file, or one that does not parse)."""
    try:
        record = json.loads((Path(out) / OWNER_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or not isinstance(record.get("command"), str):
        return None
    outputs = record.get("outputs")
    record["outputs"] = [str(o) for o in outputs] if isinstance(outputs, list) else []
    return record


def writes_folder(args: argparse.Namespace) -> bool:
    """Whether the command of ``args`` writes a folder (its defaults: ``_replaces``, ``_resume`` or ``_owns``)
    and, this run, -o/--out names that folder rather than one file (``_out_file``)."""
    if not (getattr(args, "_replaces", False) or getattr(args, "_resume", None) or getattr(args, "_owns", None)):
        return False
    out_file = getattr(args, "_out_file", False)
    return not (out_file(args) if callable(out_file) else out_file)


def unrecorded_files(args: argparse.Namespace, out: str | Path, patterns: Sequence[str] = (), *,
                     keep: Sequence[str | Path] = ()) -> list[Path]:
    """The files of the folder ``out`` that the command of ``args`` would write (``patterns``, and the
    ``_owns`` of its defaults) when no command recorded the folder (:data:`OWNER_FILE`): the user's own files
    with its output names, not the paths of ``keep`` (its inputs). Empty for a folder a command recorded."""
    if folder_owner(out) is not None:
        return []
    owns = [*patterns, *(getattr(args, "_owns", None) or ())]
    return [p for p in owned_files(out, owns, keep=keep) if p.name != OWNER_FILE]


def _listed(files: Sequence[Path], out: Path) -> str:
    """``a.png, b.json`` (at most :data:`LISTED_FILES` names relative to ``out``, then ``and N more``)."""
    names = [f.relative_to(out).as_posix() for f in files]
    more = len(names) - LISTED_FILES
    return ", ".join(names[:LISTED_FILES]) + (f" and {more} more" if more > 0 else "")


def check_folder(args: argparse.Namespace, out: str | Path, option: str = "-o/--out", *,
                 patterns: Sequence[str] = (), keep: Sequence[str | Path] = ()) -> dict[str, Any] | None:
    """Whether the command of ``args`` may write into the folder ``out``: a ``ValueError`` naming ``option``
    when ``out`` is an existing file, a folder another command wrote (:data:`OWNER_FILE`), or a folder no
    command recorded that holds files the command would write (``patterns`` and its ``_owns``, not the paths
    of ``keep``: :func:`unrecorded_files`), each without ``--force``; otherwise what the folder records
    (None: nothing)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{option}: expected an output folder (a new one, or one this command wrote), "
                         f"got the existing file {out}")
    owner = folder_owner(out)
    prog = _prog(args)
    if getattr(args, "force", False):
        return owner
    if owner and owner["command"] != prog:
        raise ValueError(f"{option}: expected a new folder or one `{prog}` wrote, got {out}/, which holds the "
                         f"results of `{owner['command']}` (choose another folder, or --force to replace them)")
    mine = unrecorded_files(args, out, patterns, keep=keep)
    if mine:
        raise ValueError(f"{option}: expected a new folder or one `{prog}` wrote, got {out}/, which holds files "
                         f"with its output names that no mi-svbrdf command recorded: {_listed(mine, out)} "
                         "(choose another folder, or --force to replace them)")
    return owner


def check_out(args: argparse.Namespace) -> None:
    """Before a command does any work: its -o/--out folder can take its results (:func:`check_folder`)."""
    out = getattr(args, "out", None)
    if out is not None and writes_folder(args):
        check_folder(args, Path(out).expanduser())


def claim_folder(args: argparse.Namespace, out: str | Path, outputs: Sequence[str], *,
                 keep: Sequence[str | Path] = ()) -> list[Path]:
    """Make ``out`` the folder of the command of ``args``, right before it writes there: record it in
    :data:`OWNER_FILE` with the patterns of its files (``outputs``, relative to ``out``).

    A folder another command wrote, or one that no command recorded and that holds files matching
    ``outputs`` (the user's own), is refused (:func:`check_folder`) unless ``--force``: then that command's
    recorded files, or those files, are removed first (not the paths of ``keep``, nor unrelated files), and
    one line says so. A re-run of the same command keeps the folder (its patterns are merged). When the
    command ends, :func:`record_written` narrows the record to what it wrote.

    Returns:
        The files removed (``--force`` only).
    """
    out = Path(out)
    owner = check_folder(args, out, patterns=outputs, keep=keep)
    prog = _prog(args)
    removed: list[Path] = []
    args._out_folder = out
    if owner and owner["command"] != prog:  # --force
        removed = clear_owned(out, [*owner["outputs"], *outputs], keep=keep)
        print(f"{prog}: --force: replacing the results of `{owner['command']}` in {out}/ ({len(removed)} file"
              f"{'s' if len(removed) != 1 else ''} removed)", file=sys.stderr)
        owner = None
    elif owner is None and getattr(args, "force", False):
        mine = unrecorded_files(args, out, outputs, keep=keep)
        removed = clear_owned(out, [f.relative_to(out).as_posix() for f in mine])
        if removed:
            print(f"{prog}: --force: replacing {len(removed)} file{'s' if len(removed) != 1 else ''} in {out}/ "
                  f"that no command recorded: {_listed(removed, out)}", file=sys.stderr)
    record = {"command": prog, "outputs": sorted(set(owner["outputs"] if owner else ()) | set(outputs))}
    if owner != record:
        if not out.is_dir():
            out.mkdir(parents=True)
            args._created = out
        write_json(out / OWNER_FILE, record)
        args._claimed = out
    return removed


def record_written(args: argparse.Namespace) -> None:
    """When a command ends (done, failed or stopped): the :data:`OWNER_FILE` of the folder it claimed
    (:func:`claim_folder`) lists what it wrote there (:func:`mi_svbrdf.io.atomic.written_outputs` of the
    recorded patterns), not what it might have written."""
    out = getattr(args, "_out_folder", None)
    owner = folder_owner(out) if out is not None else None
    if owner is None:
        return
    written = written_outputs(out, [o for o in owner["outputs"] if o != OWNER_FILE])
    if written != owner["outputs"]:
        write_json(Path(out) / OWNER_FILE, {**owner, "outputs": written})


def release_unused(args: argparse.Namespace) -> None:
    """After a command failed: a folder it claimed (:func:`claim_folder`) and wrote nothing else into is as it
    was again (its :data:`OWNER_FILE` removed, and the folder when the command created it)."""
    out = getattr(args, "_claimed", None)
    if out is None or not out.is_dir() or any(p.name != OWNER_FILE for p in out.iterdir()):
        return
    (out / OWNER_FILE).unlink(missing_ok=True)
    if getattr(args, "_created", None) == out:
        out.rmdir()


def add_force_options(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``--force`` (:data:`FORCE_HELP`) to every command of ``parser`` that writes a folder (its defaults:
    :func:`writes_folder`); returns ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                add_force_options(child)
    defaults = parser._defaults
    folder = defaults.get("_replaces") or defaults.get("_resume") or defaults.get("_owns")
    if folder and "func" in defaults and not any(a.dest == "force" for a in parser._actions):
        parser.add_argument("--force", action="store_true", help=FORCE_HELP)
    return parser


def replace_outputs(args: argparse.Namespace, out: str | Path, patterns: Sequence[str], *,
                    keep: Sequence[str | Path] = ()) -> list[Path]:
    """Before a command writes into ``out``: claim the folder, remove its previous run's files there
    (``patterns``), say so.

    The folder becomes the command's (:func:`claim_folder`: another command's folder, or the user's own
    files with its output names, are refused, or with ``--force`` removed; the record lists ``patterns``
    and ``_owns`` of the command's defaults when it writes more than it replaces). The files matching
    ``patterns`` (relative to ``out``; see :func:`mi_svbrdf.io.atomic.clear_owned`) are the command's own
    outputs: removing them first means ``out`` never mixes two runs (a fit of 3 photos never sits next to
    ``renders/005.png`` of an earlier fit of 6). Unrelated files and the paths of ``keep`` (inputs that may
    lie in ``out``) stay. Prints one line to stderr when something was removed, and records in ``args`` that
    writing started (for the Ctrl-C message of :func:`run`). Call it once the inputs are read, right before
    the first write.

    Returns:
        The removed files.
    """
    check_folder(args, out, patterns=patterns, keep=keep)
    args._writing = True
    removed = claim_folder(args, out, [*patterns, *(getattr(args, "_owns", None) or ())], keep=keep)
    again = clear_owned(out, patterns, keep=keep)  # after --force: nothing left to remove
    if again:  # the folder records this command (else check_folder refused it): these files are its own
        files = f"{len(again)} file{'s' if len(again) != 1 else ''}"
        print(f"{_prog(args)}: replacing the previous results in {Path(out)}/ ({files} of the last run removed)",
              file=sys.stderr)
    return removed + again


def _prog(args: argparse.Namespace, parser: argparse.ArgumentParser | None = None) -> str:
    """``mi-svbrdf COMMAND`` of the parsed ``args``."""
    prog = getattr(args, "_prog", None)
    if prog:
        return prog
    base = parser.prog if parser is not None else "mi-svbrdf"
    return f"{base} {getattr(args, 'command', None) or ''}".strip()


def interrupted_message(args: argparse.Namespace, prog: str, detail: str = "") -> str:
    """The one line printed when Ctrl-C stops a command: what its output folder holds, what to do
    (``detail``: what the command said when it stopped, if anything).

    A command that resumes (``_resume`` set in its defaults) keeps its partial results; one that
    replaces its outputs (:func:`replace_outputs`) either had not started writing (the folder is
    as it was) or had (its results are incomplete); every file is written atomically, so each
    completed file is whole.
    """
    out = getattr(args, "out", None)
    where = "the output folder" if not out else str(out) if Path(out).suffix else f"{out}/"
    prog = f"{prog}: interrupted" + (f" ({detail})" if detail else "")
    if getattr(args, "_resume", None):
        return f"{prog}; partial results in {where} ({args._resume})"
    if not out:
        return f"{prog}; completed files are whole (each is written atomically)"
    if Path(out).suffix:  # one file
        return f"{prog}; {where} is either whole or as it was (it is written atomically)"
    if getattr(args, "_replaces", False) and not getattr(args, "_writing", False):
        return f"{prog} before writing; nothing of this run was written to {where} (re-run the command)"
    if getattr(args, "_writing", False):
        return (f"{prog} while writing; the results in {where} are incomplete, but completed "
                f"files are whole (each is written atomically): re-run the command")
    return f"{prog}; completed files in {where} are whole (each is written atomically)"


#: The command that the line of :func:`_interrupted_while_starting` names (:func:`starting`).
_STARTING = {"prog": "mi-svbrdf"}


def _interrupted_while_starting(signum: int, frame: FrameType | None) -> None:
    """SIGINT while the ``mi-svbrdf`` process starts: one line, then the process ends at once with exit code
    :data:`INTERRUPTED` (``os._exit``: no ``KeyboardInterrupt`` inside a half-imported extension module, which
    some catch and turn into another error or a crash at exit; nothing was written yet)."""
    sys.stderr.write(f"{_STARTING['prog']}: interrupted while starting; nothing was written\n")
    sys.stderr.flush()
    os._exit(INTERRUPTED)


def guard_start() -> None:
    """Make Ctrl-C one line and exit code 130 while the ``mi-svbrdf`` process starts (imports torch, Mitsuba and
    the subcommand's modules, parses its arguments), until :func:`command_starts`. The :mod:`mi_svbrdf` facade
    calls it first thing in that process (:func:`mi_svbrdf.started_as_command`), before any heavy import."""
    try:
        signal.signal(signal.SIGINT, _interrupted_while_starting)
    except ValueError:  # not the main thread: nothing to guard
        pass


def starting(prog: str) -> None:
    """Name the command (``mi-svbrdf capture``) in the line of a Ctrl-C while it starts (:func:`guard_start`)."""
    _STARTING["prog"] = prog


def command_starts() -> None:
    """The command's own work begins: Ctrl-C raises ``KeyboardInterrupt`` again (which :func:`run` reports with
    what the output folder holds), if :func:`guard_start` had taken it; in that process the command's handler
    (:mod:`mi_svbrdf.cli.interrupt`) makes sure that no library loses or turns it into another error."""
    if signal.getsignal(signal.SIGINT) is _interrupted_while_starting:
        from mi_svbrdf.cli import interrupt

        interrupt.install()


#: The options that turn a command's progress bars off; :func:`run` sets them when stderr is no terminal.
PROGRESS_OFF = ("no_progress", "quiet")


def bars_for_terminals(args: argparse.Namespace, stream: Any = None) -> None:
    """No progress bars unless ``stream`` (default: stderr, where they go) is a terminal: a bar written to a
    file or pipe would fill it with carriage returns. Sets the options of :data:`PROGRESS_OFF` that the
    command of ``args`` has."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    try:
        terminal = bool(isatty()) if callable(isatty) else False
    except (OSError, ValueError):  # a closed stream
        terminal = False
    if not terminal:
        for dest in PROGRESS_OFF:
            if hasattr(args, dest):
                setattr(args, dest, True)


#: ``name=value`` in a library's message (``kind='multi'``, ``size=64``), with an optional `` or None`` after it.
_PY_ASSIGN = re.compile(r"\b(?P<name>[a-z][a-z0-9_]*)=(?P<q>['\"]?)(?P<value>[^'\"\s,;)]*)(?P=q)(?P<none> or None)?")
#: A tuple or list of quoted strings in a library's message: ``('trivial', 'single')``, ``['foo']``.
_PY_STRINGS = re.compile(r"[(\[]\s*('[^']*'(?:\s*,\s*'[^']*')*)\s*,?\s*[)\]]")


def flag_terms(message: str, parser: argparse.ArgumentParser) -> str:
    """A library's error ``message`` as the command line says it: the Python argument names of ``parser``'s
    options (an option's ``dest``) become their flags, ``name=value`` becomes ``--flag value`` (the library's
    ``None`` the option's default, the value that stands for it, e.g. ``auto``), and in a message about an
    option, tuples and lists of names their comma-separated list. Other text is kept.

    Examples:
        >>> p = argparse.ArgumentParser()
        >>> _ = p.add_argument("--kind", default="auto")
        >>> _ = p.add_argument("--methods")
        >>> flag_terms("kind: expected 1 photo, got 3 (use kind='multi' or None)", p)
        '--kind: expected 1 photo, got 3 (use --kind multi or --kind auto)'
        >>> flag_terms("methods: expected some of ('trivial', 'single'), got ('foo',)", p)
        '--methods: expected some of trivial, single, got foo'
    """
    flags = {a.dest: a for a in parser._actions if a.option_strings and a.dest not in ("help", "force")}

    def flag(action: argparse.Action) -> str:
        return max(action.option_strings, key=len)

    said: list[str] = []  # the options named as name=value

    def assign(m: re.Match[str]) -> str:
        action = flags.get(m["name"])
        if action is None:
            return m[0]
        said.append(m["name"])
        text = f"{flag(action)} {m['value']}" if m["value"] != "None" or action.default is None else \
            f"{flag(action)} {action.default}"
        if m["none"]:
            text += f" or {flag(action)} {action.default}" if action.default is not None else f" or no {flag(action)}"
        return text

    head = re.match(r"(?P<name>[a-z][a-z0-9_]*):", message)
    about_option = bool(head and head["name"] in flags)
    if about_option:
        message = flag(flags[head["name"]]) + message[len(head["name"]):]  # type: ignore[index]
    message = _PY_ASSIGN.sub(assign, message)
    if about_option or said:
        message = _PY_STRINGS.sub(lambda m: ", ".join(v.strip().strip("'") for v in m[1].split(",")), message)
    return message


def chosen_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The parser of the (sub)command that ``args`` (parsed by ``parser``) chose: ``mi-svbrdf capture-file
    import`` for ``capture-file import ...``, ``parser`` itself when none."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            name = getattr(args, action.dest, None)
            if name in action.choices:
                return chosen_parser(action.choices[name], args)
    return parser


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen subcommand; bad input -> a one-line error on stderr and exit code 2.

    First :func:`check_out`: -o/--out naming an existing file, a folder another command wrote, or one holding
    the user's own files with the command's output names (without ``--force``), is bad input before any work;
    when the command ends, :func:`record_written` records what it wrote. ``ValueError`` and the file errors
    of :data:`INPUT_ERRORS` are bad input: printed as
    ``mi-svbrdf COMMAND: error: MESSAGE`` (one line, no traceback). argparse's own errors (an
    option's value out of range, a missing argument) also exit with code 2. Ctrl-C prints one line
    (:func:`interrupted_message`) and exits with code :data:`INTERRUPTED` (130), no traceback, also where a
    library turned the interrupt into an error of its own or lost it (:mod:`mi_svbrdf.cli.interrupt`). An unknown
    option is an error of the subcommand that got it, with that subcommand's usage (:func:`chosen_parser`).
    Progress bars are drawn only on a terminal (:func:`bars_for_terminals`).
    """
    args, extra = parser.parse_known_args(argv)
    if extra:  # argparse would name the top level's usage: the (sub)command's own instead
        chosen_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from mi_svbrdf.cli import interrupt  # here, not at the top: ``mi-svbrdf --help`` imports no more than it needs

    bars_for_terminals(args)
    prog = _prog(args, parser)
    starting(prog)
    try:
        try:
            command_starts()
            check_out(args)  # -o names a file, another command's folder or the user's files: one line before any work
            code = args.func(args)
        finally:
            record_written(args)
        interrupt.stop_raising(code)  # raises when Ctrl-C came and a library lost it: the command does not succeed
    except BaseException as exc:
        interrupt.stop_raising()  # the outcome is being reported: a Ctrl-C now is only recorded
        release_unused(args)
        if interrupt.is_interruption(exc):  # also a library's error around it, or any error after it
            print(interrupted_message(args, prog, interrupt.interruption_detail(exc)), file=sys.stderr)
            code = INTERRUPTED
        elif isinstance(exc, INPUT_ERRORS):
            # a library's message in the command line's terms (its options' flags, not Python's argument names)
            print(f"{prog}: error: {flag_terms(one_line(exc), chosen_parser(parser, args))}", file=sys.stderr)
            code = 2
        elif interrupt.settle(1, interrupted_message(args, prog)) == INTERRUPTED:  # Ctrl-C while it was reported
            return INTERRUPTED
        else:
            raise
    return interrupt.settle(code, f"{prog}: interrupted as it ended (the lines above say what it did)")


class CommandParser(argparse.ArgumentParser):
    """argparse's parser, whose error about one argument's value (``argument --budget-s: expected seconds >= 0,
    got '-5'``) is one line, without the usage block before it: the line names the option and what it takes. Other
    errors (an unknown option, a missing argument) keep the usage, which shows the options' spelling. Its
    subcommands' parsers are of the same class (``add_subparsers`` makes them of its parser's class)."""

    def error(self, message: str) -> NoReturn:
        """Print the error (one line for an argument's value, the usage then the line otherwise); exit with 2."""
        if message.startswith("argument "):
            self.exit(2, f"{self.prog}: error: {message}\n")
        super().error(message)


def standalone(add_parser: Callable[[Any], None], argv: list[str] | None = None) -> int:
    """Run one command module on its own (its ``add_parser``), as ``python -m`` entry points do."""
    parser = CommandParser(prog="mi-svbrdf")
    add_parser(parser.add_subparsers(dest="command", metavar="COMMAND"))
    return run(terminal_help(add_force_options(parser)), argv)


def asset_script(argv: list[str] | None, prog: str, description: str | None, default_out: Path,
                 write: Callable[[Path], list[Path]]) -> int:
    """``main`` of a maintainer script that re-makes bundled assets: ``-o/--out`` (default ``default_out``),
    ``write(out)`` -> the files written, each printed with its size, then the total."""
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--out", type=Path, default=default_out,
                        help=f"output folder (default: the package's assets/{default_out.name}/)")
    args = parser.parse_args(argv)
    files = write(args.out)
    for path in files:
        print(f"wrote {path} ({path.stat().st_size / 1024:.1f} KB)")
    print(f"total {sum(p.stat().st_size for p in files) / 1024:.0f} KB")
    return 0

