"""What every subcommand shares: ``KEY=VALUE`` parameters, command groups, running a parser.

Domain modules hold no argparse code; each subcommand lives in its own module of :mod:`mi_svbrdf.cli`
with an ``add_parser(subparsers)`` that registers it.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.data import examples
from mi_svbrdf.io import material_io, strip


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


def material_from_spec(spec: str, size: int = 256, arg: str = "MATERIAL") -> torch.Tensor:
    """The ``(1, 10, H, W)`` maps of a material argument: ``example:NAME`` (a built-in example at
    ``size``), a material folder or a thesis strip ``.png``; errors name ``arg``."""
    if spec.startswith("example:"):
        return examples.example_material(spec.split(":", 1)[1], size=size)
    path = Path(spec)
    if path.is_dir():
        return material_io.read_material(path)
    if path.is_file() and path.suffix.lower() == ".png":
        return strip.read_strip(path)[1]
    raise FileNotFoundError(f"{arg}: expected a material folder, a strip .png or example:NAME "
                            f"({', '.join(sorted(examples.EXAMPLES))}), got {spec!r}")


def command_group(subparsers: Any, name: str, help: str, description: str) -> Any:
    """Add a command that only groups subcommands (``mi-svbrdf NAME SUBCOMMAND``); returns their subparsers.

    Run without a subcommand, the group prints its help and exits with code 2.
    """
    group = subparsers.add_parser(name, help=help, description=description)
    group.set_defaults(func=help_command(group))
    return group.add_subparsers(dest=f"{name}_command", metavar="SUBCOMMAND")


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
