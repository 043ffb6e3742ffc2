"""The one place that selects the Mitsuba variant and registers mi_svbrdf's plugins.

Importing :mod:`mi_svbrdf` calls :func:`ensure_variant` once: if the user already set a
variant it is kept (plugins are registered for it), otherwise ``cuda_ad_rgb`` is chosen
where a CUDA device exists and ``llvm_ad_rgb`` elsewhere, so that ``mi.load_dict`` finds the
``svbrdf_*`` plugins right after the import.

The variant does **not** choose where mi_svbrdf's own Dr.Jit kernels run (the texel renderer, the
rendering loss, the optimiser's fused objective): they run on the backend of their tensors' device
(:mod:`mi_svbrdf.core.device`) whatever variant is active, and never switch it. Only Mitsuba's scene
machinery (``mi.load_*``, ``mi.render``, the plugins' classes, ``mi.traverse``) is bound to a
variant: code that renders a scene for tensors of some device enters :func:`scene_variant` at its
one boundary (e.g. for a whole fit through the Mitsuba forward model, not per step);
:func:`use_variant` switches for good, :func:`variant_context` for a ``with`` block.
"""
from __future__ import annotations

import contextlib
from collections.abc import Iterator

import mitsuba as mi
import torch

from mi_svbrdf import plugins

#: Variants tried, in order, when none is set.
PREFERRED_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb")


def _pick_default() -> str:
    available = mi.variants()
    for name in PREFERRED_VARIANTS:
        if name not in available:
            continue
        try:
            mi.set_variant(name)
            if name.startswith("cuda"):
                # set_variant succeeds without a device; touching the backend tells.
                mi.Float(1.0).numpy()
            return name
        except Exception:  # noqa: BLE001 - no device / no driver: try the next variant
            continue
    raise RuntimeError(f"mi_svbrdf needs one of the Mitsuba variants {PREFERRED_VARIANTS}; "
                       f"this Mitsuba build has {available}")


def variant_for(device: torch.device | str) -> str:
    """The Mitsuba variant whose Dr.Jit backend is that of tensors on ``device`` (for scene rendering).

    Examples:
        >>> variant_for("cpu")
        'llvm_ad_rgb'
    """
    return "cuda_ad_rgb" if torch.device(device).type == "cuda" else "llvm_ad_rgb"


def ensure_variant() -> str:
    """Return the active variant, choosing a default if none is set, and register plugins."""
    variant = mi.variant()
    if variant is None:
        variant = _pick_default()
    plugins.register()
    return variant


def require_ad_rgb() -> str:
    """Return the active variant; raise if it is not an ``*_ad_rgb`` variant (needed for AD)."""
    variant = ensure_variant()
    if not (variant.endswith("_ad_rgb")):
        raise RuntimeError(
            f"mi_svbrdf's differentiable rendering needs an '*_ad_rgb' Mitsuba variant "
            f"(llvm_ad_rgb or cuda_ad_rgb); the active variant is {variant!r}. "
            f"Call mi.set_variant('llvm_ad_rgb') before using the 'mitsuba' backend.")
    return variant


def use_variant(name: str) -> str:
    """Make ``name`` the active variant (plugins registered); returns it.

    Raises:
        RuntimeError: the variant is not in this Mitsuba build, or its backend cannot start
            (``cuda_ad_rgb`` without a CUDA driver / device).
    """
    if mi.variant() == name:
        plugins.register()
        return name
    if name not in mi.variants():
        raise RuntimeError(f"variant: expected one of this Mitsuba build's variants {mi.variants()}, got {name!r}")
    previous = mi.variant()
    try:
        mi.set_variant(name)
        if name.startswith("cuda"):
            mi.Float(1.0).numpy()  # set_variant succeeds without a device; touching the backend tells
    except Exception as exc:  # re-raised with the variant named
        if previous is not None:
            mi.set_variant(previous)
        raise RuntimeError(f"variant: expected a usable {name!r} (its backend failed to start: {exc})") from exc
    plugins.register()
    return name


@contextlib.contextmanager
def scene_variant(device: torch.device | str = "cpu") -> Iterator[str]:
    """Within the ``with`` block the variant of ``device`` (:func:`variant_for`) is active, with the
    plugins registered: Mitsuba's scenes (``mi.load_*``, ``mi.render``, ``mi.traverse``) are bound to a
    variant, unlike mi_svbrdf's kernels. Costs nothing when it is already active; the previous variant
    is restored after the block."""
    with variant_context(variant_for(device)) as name:
        yield name


@contextlib.contextmanager
def variant_context(name: str) -> Iterator[str]:
    """Within the ``with`` block ``name`` is the active variant (:func:`use_variant`); the previous
    one is restored after it. Costs nothing when ``name`` is already active."""
    previous = mi.variant()
    if previous == name:
        plugins.register()
        yield name
        return
    use_variant(name)
    try:
        yield name
    finally:
        if previous is not None:
            mi.set_variant(previous)
