"""mi_svbrdf: SVBRDF capture from casual flash photos on Mitsuba 3, Dr.Jit and PyTorch.

Importing the package selects a Mitsuba variant if none is set (``cuda_ad_rgb`` where a GPU
exists, else ``llvm_ad_rgb``) and registers the ``svbrdf_ggx`` / ``svbrdf_beckmann`` plugins;
a variant the user already set is kept.

Importing the package first makes OpenMP's waiting threads sleep unless the environment says how they
wait (:mod:`mi_svbrdf.threads`: PyTorch's pool beside Dr.Jit's on a CPU that other programs share).

The package is layered; each subpackage imports only from those before it
(``tests/test_architecture.py`` enforces it):

    threads, variant, plugins, assets -> core -> io, scenes -> data -> nets, optim -> eval -> cli

This module is the public face: it re-exports the rendering-loss API and keeps the modules
users know at their old names (``mi_svbrdf.maps``, ``flash``, ``transforms``,
``material_io``, ``strip``; ``scenes`` is a subpackage of its own).

One process is the exception: the ``mi-svbrdf`` command starting (its console script, or ``python -m
mi_svbrdf.cli``; :func:`started_as_command`). There Ctrl-C is made one line first
(:func:`mi_svbrdf.cli.common.guard_start`), and the set-up (the variant, the plugins, the re-exported API,
which load torch and Mitsuba) waits: :func:`mi_svbrdf.cli.main` selects the variant
(:func:`mi_svbrdf.variant.ensure_variant`) before it imports the subcommand it runs, and ``mi-svbrdf
--help`` loads neither. A re-exported name used there sets up then.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

from mi_svbrdf.threads import set_wait_policy, share_cores

if set_wait_policy() is None:  # before torch loads OpenMP: its waiting threads sleep on a shared CPU
    share_cores()  # torch came first (its threads spin): PyTorch's and Dr.Jit's pools split the cores

if TYPE_CHECKING:
    from mi_svbrdf.core import flash, maps, transforms
    from mi_svbrdf.core.configurations import Configurations, sample_configurations
    from mi_svbrdf.core.loss import MixedLoss, RenderingLoss, map_l1, mixed_loss, rendering_loss
    from mi_svbrdf.core.render import direction, point, render, texel_positions
    from mi_svbrdf.variant import ensure_variant, require_ad_rgb

__version__ = "0.1.0"

#: The names of the set-up (:func:`_set_up`): name -> module defining it (or the module itself: :data:`_MODULES`).
_SET_UP = {"ensure_variant": "mi_svbrdf.variant", "require_ad_rgb": "mi_svbrdf.variant",
           "flash": "mi_svbrdf.core.flash", "maps": "mi_svbrdf.core.maps", "transforms": "mi_svbrdf.core.transforms",
           "Configurations": "mi_svbrdf.core.configurations", "sample_configurations": "mi_svbrdf.core.configurations",
           "MixedLoss": "mi_svbrdf.core.loss", "RenderingLoss": "mi_svbrdf.core.loss", "map_l1": "mi_svbrdf.core.loss",
           "mixed_loss": "mi_svbrdf.core.loss", "rendering_loss": "mi_svbrdf.core.loss",
           "direction": "mi_svbrdf.core.render", "point": "mi_svbrdf.core.render", "render": "mi_svbrdf.core.render",
           "texel_positions": "mi_svbrdf.core.render"}
#: The names of :data:`_SET_UP` that are modules.
_MODULES = ("flash", "maps", "transforms")
#: The names the ``mi-svbrdf`` console script runs under (pip's launchers on every platform).
COMMAND_NAMES = ("mi-svbrdf", "mi-svbrdf.exe", "mi-svbrdf-script.py")


def started_as_command() -> bool:
    """Whether this process is the ``mi-svbrdf`` command starting: its console script, or ``python -m mi_svbrdf.cli``
    (``python -m mi_svbrdf.cli.COMMAND`` runs one module on its own and is not, nor is a worker process the command
    started, which the ``spawn`` start method begins with the command's script and arguments)."""
    process = sys.modules.get("multiprocessing.process")
    if process is not None and process.parent_process() is not None:
        return False
    if Path(sys.argv[0]).name in COMMAND_NAMES:
        return True
    argv = list(getattr(sys, "orig_argv", ()))
    return "-m" in argv and argv[argv.index("-m") + 1:argv.index("-m") + 2] == ["mi_svbrdf.cli"]


def _set_up() -> None:
    """Select the Mitsuba variant (unless one is set), register the plugins, import the re-exported API."""
    from mi_svbrdf.variant import ensure_variant

    ensure_variant()
    for name, module in _SET_UP.items():
        if name not in globals():
            loaded = importlib.import_module(module)
            globals()[name] = loaded if name in _MODULES else getattr(loaded, name)


if started_as_command():  # Ctrl-C is one line from here on (mi_svbrdf.cli.main sets up)
    from mi_svbrdf.cli.common import guard_start

    guard_start()
else:
    _set_up()

#: Lazily imported names (``import mi_svbrdf`` stays fast): name -> module defining it.
_LAZY = {"optimize": "mi_svbrdf.optim.fit", "OptimizeConfig": "mi_svbrdf.optim.fit",
         "OptimizeResult": "mi_svbrdf.optim.fit", "predict": "mi_svbrdf.nets.inference",
         "refine": "mi_svbrdf.optim.refine", "RefineConfig": "mi_svbrdf.optim.refine"}

#: Public modules kept at their pre-layering names: ``mi_svbrdf.NAME`` -> where it lives now.
#: ``import mi_svbrdf.material_io`` and ``from mi_svbrdf.strip import read_strip`` keep working.
MODULE_ALIASES = {"maps": "mi_svbrdf.core.maps", "flash": "mi_svbrdf.core.flash",
                  "transforms": "mi_svbrdf.core.transforms", "material_io": "mi_svbrdf.io.material_io",
                  "strip": "mi_svbrdf.io.strip"}


class _AliasLoader(importlib.abc.Loader):
    """Loads ``mi_svbrdf.NAME`` as the module it names in :data:`MODULE_ALIASES`."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(self.target)
        self.target_spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """The target is already executed; give it back its own spec (the import system set the alias's)."""
        module.__spec__ = self.target_spec


class _AliasFinder(importlib.abc.MetaPathFinder):
    """Finds the public module aliases of :data:`MODULE_ALIASES` (and nothing else)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        prefix, _, name = fullname.rpartition(".")
        if prefix != __name__ or name not in MODULE_ALIASES:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(MODULE_ALIASES[name]))


if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
    sys.meta_path.insert(0, _AliasFinder())


def __getattr__(name: str) -> object:
    """Import the optimisation and inference APIs and the io modules on first use
    (``mi_svbrdf.optimize(...)``, ``mi_svbrdf.predict(...)``, ``mi_svbrdf.material_io``; PEP 562)."""
    if name in _SET_UP:  # only in the mi-svbrdf command, before it set up
        _set_up()
        return globals()[name]
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name in MODULE_ALIASES:
        value = importlib.import_module(MODULE_ALIASES[name])
    else:
        raise AttributeError(f"module 'mi_svbrdf' has no attribute {name!r}")
    globals()[name] = value
    return value


__all__ = [
    "Configurations", "MixedLoss", "OptimizeConfig", "OptimizeResult", "RenderingLoss", "direction",
    "ensure_variant", "flash", "map_l1", "maps", "material_io", "mixed_loss", "optimize", "point", "predict",
    "render", "rendering_loss", "require_ad_rgb", "sample_configurations", "strip", "texel_positions",
    "transforms",
]
