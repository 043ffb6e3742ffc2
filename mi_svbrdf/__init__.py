"""mi_svbrdf: SVBRDF capture from casual flash photos on Mitsuba 3, Dr.Jit and PyTorch.

Importing the package selects a Mitsuba variant if none is set (``cuda_ad_rgb`` where a GPU
exists, else ``llvm_ad_rgb``) and registers the ``svbrdf_ggx`` / ``svbrdf_beckmann`` plugins;
a variant the user already set is kept.
"""
from __future__ import annotations

from mi_svbrdf.variant import ensure_variant, require_ad_rgb

ensure_variant()

from mi_svbrdf import flash, maps, transforms  # noqa: E402
from mi_svbrdf.configurations import Configurations, sample_configurations  # noqa: E402
from mi_svbrdf.loss import (MixedLoss, RenderingLoss, map_l1, mixed_loss,  # noqa: E402
                            rendering_loss)
from mi_svbrdf.render import direction, point, render, texel_positions  # noqa: E402

__version__ = "0.1.0"

#: Lazily imported names (``import mi_svbrdf`` stays fast): name -> module defining it.
_LAZY = {"optimize": "mi_svbrdf.optimization", "OptimizeConfig": "mi_svbrdf.optimization",
         "OptimizeResult": "mi_svbrdf.optimization", "predict": "mi_svbrdf.inference"}


def __getattr__(name: str) -> object:
    """Import the optimisation and inference APIs on first use (``mi_svbrdf.optimize(...)``,
    ``mi_svbrdf.predict(...)``; PEP 562)."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mi_svbrdf' has no attribute {name!r}")

__all__ = [
    "Configurations", "MixedLoss", "OptimizeConfig", "OptimizeResult", "RenderingLoss", "direction",
    "ensure_variant", "flash", "map_l1", "maps", "mixed_loss", "optimize", "point", "predict", "render", "rendering_loss",
    "require_ad_rgb", "sample_configurations", "texel_positions", "transforms",
]
