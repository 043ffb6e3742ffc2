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

__all__ = [
    "Configurations", "MixedLoss", "RenderingLoss", "direction", "ensure_variant", "flash", "map_l1",
    "maps", "mixed_loss", "point", "render", "rendering_loss", "require_ad_rgb", "sample_configurations",
    "texel_positions", "transforms",
]
