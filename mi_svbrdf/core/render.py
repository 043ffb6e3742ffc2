"""The texel renderer: the thesis model evaluated once per texel of a flat, rectified sample.

A rectified photo of a flat sample needs no ray tracing: every texel is a point of the
``[-1, 1]^2`` plane at z = 0 whose radiance towards the viewer is the BRDF times the light.
:func:`render` evaluates it for K light/view configurations per sample, on two backends that
must agree: ``"mitsuba"`` (default; the plugin's Dr.Jit code through ``dr.wrap``) and
``"torch"`` (an independent plain-PyTorch reference). ``tests/test_texel_vs_mitsuba.py``
proves it equals a full ``mi.render`` of the plane under a point light.

Radiance of a texel at P with normal n (every factor but the first is an explicit switch)::

    L = f(n, wl, wv) * pi * I * c(n . wl)
        * 1/|P_L - P|^2          if distance_falloff (point lights only)
        / max(wl.z, 1e-3)        if light_z_division (the loss's low-angle compensation)
        * c(wl . a)^e            if a cone is given (a = unit vector from cone target to light)

Who uses which: the rendering loss uses ``light_z_division=True, distance_falloff=False``
(also for its near-field configurations, as the authors' code); the flash input rendering
uses ``distance_falloff=True`` and a cone; the Mitsuba plugin corresponds to
``distance_falloff=True`` with the pi folded into the emitter's intensity.

Examples:
    >>> import torch, mi_svbrdf
    >>> maps = mi_svbrdf.core.maps.constant_maps(1, 4, 4, diffuse=0.5, specular=0.04, roughness=0.5)
    >>> light = mi_svbrdf.point(torch.tensor([[[0.0, 0.0, 2.0]]]))
    >>> view = mi_svbrdf.direction(torch.tensor([[[0.0, 0.0, 1.0]]]))
    >>> img = mi_svbrdf.core.render(maps, light, view, distance_falloff=True)
    >>> tuple(img.shape)
    (1, 1, 3, 4, 4)
"""
from __future__ import annotations

from typing import Literal

import torch

from mi_svbrdf.core import brdf_torch, render_drjit
from mi_svbrdf.core.maps import check_maps
from mi_svbrdf.plugins.model import DISTRIBUTIONS

Backend = Literal["mitsuba", "torch"]
BACKENDS = ("mitsuba", "torch")


def texel_positions(height: int, width: int, *, dtype: torch.dtype = torch.float32,
                    device: torch.device | str = "cpu") -> torch.Tensor:
    """Texel centres on the plane: ``(3, H, W)`` with x = -1 + (2j+1)/W, y = 1 - (2i+1)/H, z = 0."""
    xs = -1.0 + (2.0 * torch.arange(width, dtype=dtype, device=device) + 1.0) / width
    ys = 1.0 - (2.0 * torch.arange(height, dtype=dtype, device=device) + 1.0) / height
    return torch.stack([xs[None, :].expand(height, width), ys[:, None].expand(height, width),
                        torch.zeros(height, width, dtype=dtype, device=device)])


def point(position: torch.Tensor) -> torch.Tensor:
    """Homogeneous form ``(..., 4)`` (w = 1) of positions ``(..., 3)``: a near-field light or viewer."""
    return torch.cat([position, torch.ones_like(position[..., :1])], dim=-1)


def direction(dir_: torch.Tensor) -> torch.Tensor:
    """Homogeneous form ``(..., 4)`` (w = 0) of directions ``(..., 3)``: a light or viewer at infinity."""
    return torch.cat([dir_, torch.zeros_like(dir_[..., :1])], dim=-1)


def _homogeneous(t: torch.Tensor, name: str, batch: int) -> torch.Tensor:
    if not isinstance(t, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor (B, K, 3) or (B, K, 4), got {type(t).__name__}")
    if t.dim() != 3 or t.shape[0] != batch or t.shape[2] not in (3, 4):
        raise ValueError(f"{name}: expected shape (B={batch}, K, 3) positions or (B={batch}, K, 4) "
                         f"homogeneous (w=0: direction), got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name}: contains NaN or Inf")
    if t.shape[2] == 3:
        t = point(t)
    elif not bool(((t[..., 3] == 0) | (t[..., 3] == 1)).all()):
        raise ValueError(f"{name}: the homogeneous w must be 0 (direction) or 1 (position)")
    return t


def _per_config(value: torch.Tensor | float, name: str, shape: tuple[int, ...], like: torch.Tensor) -> torch.Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    try:
        return torch.broadcast_to(t, shape)
    except RuntimeError:
        raise ValueError(f"{name}: expected a value broadcastable to {shape}, got shape {tuple(t.shape)}") from None


def render(maps: torch.Tensor, light: torch.Tensor, view: torch.Tensor, *,
           intensity: torch.Tensor | float = 1.0,
           distance_falloff: bool = False,
           light_z_division: bool = False,
           cone_target: torch.Tensor | None = None,
           cone_exponent: torch.Tensor | float | None = None,
           include_diffuse: bool = True,
           normalize_normals: bool = True,
           distribution: str = "ggx",
           backend: Backend = "mitsuba") -> torch.Tensor:
    """Render each texel of ``maps`` under K light/view configurations.

    Args:
        maps: ``(B, 10, H, W)`` SVBRDF (see :mod:`mi_svbrdf.core.maps`).
        light: ``(B, K, 3)`` light positions, or ``(B, K, 4)`` homogeneous (w = 0: a direction
            towards the light, far field). The plane spans ``[-1, 1]^2`` at z = 0, y up.
        view: ``(B, K, 3)`` or ``(B, K, 4)`` viewer positions / directions, as ``light``.
        intensity: light intensity I, broadcastable to ``(B, K, 3)`` (RGB).
        distance_falloff: multiply by ``1/|P_L - P|^2`` for point lights.
        light_z_division: divide by ``max(wl.z, 1e-3)`` (the rendering loss's compensation).
        cone_target: ``(B, K, 3)`` point the light's cone is aimed at, or None for no cone.
        cone_exponent: cone exponent e, broadcastable to ``(B, K)`` (needed with ``cone_target``).
        include_diffuse: add the diffuse term ``d (1 - s) / pi``.
        normalize_normals: renormalise the normal map before shading (the 2019 code does).
        distribution: ``"ggx"`` (the thesis) or ``"beckmann"``.
        backend: ``"mitsuba"`` (Dr.Jit, fused kernel) or ``"torch"`` (reference).

    Returns:
        ``(B, K, 3, H, W)`` linear radiance, float32 for ``"mitsuba"``, ``maps.dtype`` for ``"torch"``.
        Gradients flow to ``maps`` on both backends; only the torch backend also differentiates
        the configuration tensors.
    """
    check_maps(maps)
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    batch = maps.shape[0]
    light = _homogeneous(light, "light", batch).to(maps)
    view = _homogeneous(view, "view", batch).to(maps)
    if light.shape[1] != view.shape[1]:
        raise ValueError(f"view: expected K = {light.shape[1]} configurations like light, got {view.shape[1]}")
    k_count = light.shape[1]
    inten = _per_config(intensity, "intensity", (batch, k_count, 3), maps)
    if (cone_target is None) != (cone_exponent is None):
        raise ValueError("cone_target and cone_exponent: expected both or neither, got one")
    cone_e = None
    if cone_target is not None:
        cone_target = _per_config(cone_target, "cone_target", (batch, k_count, 3), maps)
        cone_e = _per_config(cone_exponent, "cone_exponent", (batch, k_count), maps)

    if backend == "torch":
        positions = texel_positions(maps.shape[2], maps.shape[3], dtype=maps.dtype, device=maps.device)
        return brdf_torch.render(maps, positions, light, view, inten, cone_target, cone_e,
                                 distance_falloff=distance_falloff, light_z_division=light_z_division,
                                 include_diffuse=include_diffuse, normalize_normals=normalize_normals,
                                 distribution=distribution)
    flags = render_drjit.Flags(distance_falloff, light_z_division, cone_target is not None,
                               include_diffuse, normalize_normals, distribution)
    cfg = render_drjit.pack_configurations(light, view, inten, cone_target, cone_e)
    return render_drjit.render(maps, cfg, k_count, flags)
