"""The canonical SVBRDF tensor: ``(B, 10, H, W)`` float32.

Channels, in the thesis dataset's order::

    0:3  normal    unit xyz, OpenGL tangent space (x right, y up, z out of the surface)
    3:6  diffuse   linear RGB albedo in [0, 1]
    6:7  roughness in [0, 1]; the renderer squares it (alpha = r^2)
    7:10 specular  linear RGB albedo in [0, 1]

Examples:
    >>> import torch
    >>> from mi_svbrdf.core import maps as M
    >>> m = M.constant_maps(2, 8, 8, diffuse=(0.5, 0.4, 0.3), roughness=0.3)
    >>> tuple(m.shape), tuple(M.normal(m).shape), float(M.roughness(m)[0, 0, 0, 0])
    ((2, 10, 8, 8), (2, 3, 8, 8), 0.30000001192092896)
"""
from __future__ import annotations

from collections.abc import Sequence

import torch

#: Number of channels of the canonical tensor.
NUM_CHANNELS = 10
#: Channel slices by map name.
SLICES: dict[str, slice] = {
    "normal": slice(0, 3),
    "diffuse": slice(3, 6),
    "roughness": slice(6, 7),
    "specular": slice(7, 10),
}
#: Map names in channel order.
MAP_NAMES: tuple[str, ...] = ("normal", "diffuse", "roughness", "specular")
#: Channels of each map.
MAP_CHANNELS: dict[str, int] = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}


def check_maps(maps: torch.Tensor, name: str = "maps") -> None:
    """Raise a ``ValueError`` unless ``maps`` is a ``(B, 10, H, W)`` floating tensor without NaN/Inf."""
    if not isinstance(maps, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor of shape (B, 10, H, W), got {type(maps).__name__}")
    if maps.dim() != 4 or maps.shape[1] != NUM_CHANNELS:
        raise ValueError(f"{name}: expected shape (B, 10, H, W) "
                         f"(normal 3 | diffuse 3 | roughness 1 | specular 3), got {tuple(maps.shape)}")
    if not maps.is_floating_point():
        raise ValueError(f"{name}: expected a floating-point tensor, got {maps.dtype}")
    # A sum is ~3x cheaper than an elementwise test and is non-finite whenever an element is
    # (or, for values near the float limit, on overflow: then the exact test decides).
    if not torch.isfinite(maps.sum()) and not torch.isfinite(maps).all():
        raise ValueError(f"{name}: contains NaN or Inf values")


def normal(maps: torch.Tensor) -> torch.Tensor:
    """Normal map ``(B, 3, H, W)``."""
    return maps[:, SLICES["normal"]]


def diffuse(maps: torch.Tensor) -> torch.Tensor:
    """Diffuse albedo ``(B, 3, H, W)``."""
    return maps[:, SLICES["diffuse"]]


def roughness(maps: torch.Tensor) -> torch.Tensor:
    """Roughness ``(B, 1, H, W)``."""
    return maps[:, SLICES["roughness"]]


def specular(maps: torch.Tensor) -> torch.Tensor:
    """Specular albedo ``(B, 3, H, W)``."""
    return maps[:, SLICES["specular"]]


def split(maps: torch.Tensor) -> dict[str, torch.Tensor]:
    """The four maps by name (views, no copy)."""
    return {k: maps[:, s] for k, s in SLICES.items()}


def preview_panels(maps: torch.Tensor) -> dict[str, torch.Tensor]:
    """The four maps as images to look at: ``{name: (B, 3, H, W)}`` in :data:`MAP_NAMES` order.

    Normals as ``(n + 1) / 2``, roughness repeated to 3 channels, albedos as they are (linear);
    every panel clipped to [0, 1]. Encode for display where the result is written.
    """
    return {"normal": ((normal(maps) + 1.0) * 0.5).clamp(0.0, 1.0), "diffuse": diffuse(maps).clamp(0.0, 1.0),
            "roughness": roughness(maps).expand(-1, 3, -1, -1).clamp(0.0, 1.0),
            "specular": specular(maps).clamp(0.0, 1.0)}


def preview(maps: torch.Tensor) -> torch.Tensor:
    """``(B, 3, H, 4W)``: :func:`preview_panels` side by side (normal | diffuse | roughness | specular)."""
    return torch.cat(list(preview_panels(maps).values()), dim=-1)


def make_maps(normal: torch.Tensor, diffuse: torch.Tensor, roughness: torch.Tensor,
              specular: torch.Tensor) -> torch.Tensor:
    """Concatenate the four maps (each ``(B, C, H, W)``) into the canonical tensor.

    Roughness may have 1 or 3 channels (3 are averaged: the model has one roughness).
    """
    parts = {"normal": normal, "diffuse": diffuse, "roughness": roughness, "specular": specular}
    shape = None
    for key, t in parts.items():
        if t.dim() != 4:
            raise ValueError(f"{key}: expected shape (B, C, H, W), got {tuple(t.shape)}")
        if key == "roughness" and t.shape[1] == 3:
            parts[key] = t = t.mean(dim=1, keepdim=True)
        if t.shape[1] != MAP_CHANNELS[key]:
            raise ValueError(f"{key}: expected {MAP_CHANNELS[key]} channels, got {t.shape[1]}")
        if shape is None:
            shape = (t.shape[0], t.shape[2], t.shape[3])
        elif (t.shape[0], t.shape[2], t.shape[3]) != shape:
            raise ValueError(f"{key}: expected batch and size (B, H, W) = {shape} like the normal map, "
                             f"got {(t.shape[0], t.shape[2], t.shape[3])}")
    return torch.cat([parts[k] for k in MAP_NAMES], dim=1)


def constant_maps(batch: int, height: int, width: int, *,
                  normal: Sequence[float] = (0.0, 0.0, 1.0),
                  diffuse: Sequence[float] | float = 0.5,
                  roughness: float = 0.5,
                  specular: Sequence[float] | float = 0.04,
                  dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> torch.Tensor:
    """A spatially constant material (normal is normalised)."""
    def rgb(v: Sequence[float] | float) -> list[float]:
        return [float(v)] * 3 if isinstance(v, (int, float)) else [float(x) for x in v]

    n = torch.tensor([float(x) for x in normal], dtype=torch.float64)
    n = (n / n.norm()).tolist()
    values = torch.tensor(n + rgb(diffuse) + [float(roughness)] + rgb(specular), dtype=dtype, device=device)
    return values.view(1, NUM_CHANNELS, 1, 1).expand(batch, NUM_CHANNELS, height, width).contiguous()


def normalize_normals(maps: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Return a copy of ``maps`` whose normals have unit length."""
    n = normal(maps)
    n = n / n.square().sum(dim=1, keepdim=True).clamp_min(eps).sqrt()
    return torch.cat([n, maps[:, 3:]], dim=1)


def from_network_output(output: torch.Tensor, *, normal_scale: float = 1.0,
                        activation: str = "tanh") -> torch.Tensor:
    """Convert a network's 9-channel output to the canonical ``(B, 10, H, W)`` tensor.

    The 9 channels are ``normal xy (2) | diffuse (3) | specular (3) | roughness (1)``. The
    normal is ``normalize(s x, s y, 1)`` with ``s = normal_scale`` (1 in the 2018 code,
    3 in the 2019 code, "giving space to directions beyond 45 degrees"); the other maps
    are mapped from the activation's range to [0, 1].

    Args:
        output: ``(B, 9, H, W)`` network output.
        normal_scale: factor on x and y before normalising.
        activation: ``"tanh"`` (values in [-1, 1], the authors' code) or ``"sigmoid"``
            (values in [0, 1]; normal xy is decoded as ``2 v - 1``).

    Returns:
        ``(B, 10, H, W)`` maps.
    """
    if output.dim() != 4 or output.shape[1] != 9:
        raise ValueError("output: expected shape (B, 9, H, W) (normal xy | diffuse | specular | roughness), "
                         f"got {tuple(output.shape)}")
    if activation == "tanh":
        xy, rest = output[:, 0:2], (output[:, 2:] + 1.0) * 0.5
    elif activation == "sigmoid":
        xy, rest = output[:, 0:2] * 2.0 - 1.0, output[:, 2:]
    else:
        raise ValueError(f"activation: expected 'tanh' or 'sigmoid', got {activation!r}")
    n = torch.cat([xy * normal_scale, torch.ones_like(xy[:, :1])], dim=1)
    n = n / n.square().sum(dim=1, keepdim=True).sqrt()
    return torch.cat([n, rest[:, 0:3], rest[:, 6:7], rest[:, 3:6]], dim=1)


def to_network_layout(maps: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`from_network_output` for ``activation="sigmoid"``, ``normal_scale=1``.

    Returns ``(B, 9, H, W)`` in [0, 1]: ``(xy/z + 1)/2 | diffuse | specular | roughness``.
    """
    check_maps(maps)
    n = normal(maps)
    xy = n[:, 0:2] / n[:, 2:3].clamp_min(1e-2)
    return torch.cat([(xy + 1.0) * 0.5, diffuse(maps), specular(maps), roughness(maps)], dim=1)


def project_valid(maps: torch.Tensor, min_normal_z: float = 1e-3) -> torch.Tensor:
    """Nearest valid maps: albedos and roughness clipped to [0, 1], normals with ``z >= min_normal_z``
    renormalised (a zero normal becomes (0, 0, 1)). Useful after an optimiser step."""
    n = normal(maps)
    n = torch.cat([n[:, 0:2], n[:, 2:3].clamp_min(min_normal_z)], dim=1)
    n = n / n.square().sum(dim=1, keepdim=True).sqrt()
    return torch.cat([n, maps[:, 3:].clamp(0.0, 1.0)], dim=1)


#: The 8 symmetries of the square (the dihedral group D4) as ``(transpose, flip_rows, flip_columns)``,
#: applied in that order; index 0 is the identity.
SYMMETRIES: tuple[tuple[bool, bool, bool], ...] = tuple(
    (bool(t), bool(fh), bool(fw)) for t in (0, 1) for fh in (0, 1) for fw in (0, 1))


def _check_symmetry(k: int) -> tuple[bool, bool, bool]:
    if not isinstance(k, int) or not 0 <= k < len(SYMMETRIES):
        raise ValueError(f"k: expected an int in [0, {len(SYMMETRIES) - 1}] (an index of SYMMETRIES), got {k!r}")
    return SYMMETRIES[k]


def symmetry_image(images: torch.Tensor, k: int) -> torch.Tensor:
    """Symmetry ``k`` of :data:`SYMMETRIES` applied to the last two (H, W) dimensions of ``images``
    (photos ``(..., C, H, W)``; for maps use :func:`symmetry_maps`, which also turns the normals)."""
    t, fh, fw = _check_symmetry(k)
    if t:
        images = images.transpose(-1, -2)
    if fh:
        images = images.flip(-2)
    if fw:
        images = images.flip(-1)
    return images


def symmetry_maps(maps: torch.Tensor, k: int, *, inverse: bool = False) -> torch.Tensor:
    """Maps ``(B, 10, H, W)`` under symmetry ``k`` of :data:`SYMMETRIES` (or its inverse): the texels move
    as :func:`symmetry_image` moves pixels and the normals turn with them, so the maps of a transformed
    photo of a surface are the transformed maps of the surface.

    In OpenGL tangent space (x right, y up, rows top to bottom): flipping the columns negates n_x,
    flipping the rows negates n_y, and transposing (texel (i, j) <- (j, i)) maps (n_x, n_y) to
    (-n_y, -n_x).

    Examples:
        >>> m = constant_maps(1, 4, 4, normal=(0.48, 0.36, 0.8))
        >>> [tuple(round(float(v), 2) for v in normal(symmetry_maps(m, k))[0, :2, 0, 0]) for k in (0, 1, 2, 4)]
        [(0.48, 0.36), (-0.48, 0.36), (0.48, -0.36), (-0.36, -0.48)]
        >>> bool(torch.equal(symmetry_maps(symmetry_maps(m, 5), 5, inverse=True), m))
        True
    """
    check_maps(maps)
    t, fh, fw = _check_symmetry(k)
    n, rest = normal(maps), maps[:, 3:]
    steps = [("t", t), ("h", fh), ("w", fw)]
    for op, on in (reversed(steps) if inverse else steps):
        if not on:
            continue
        if op == "t":
            n, rest = n.transpose(-1, -2), rest.transpose(-1, -2)
            n = torch.cat([-n[:, 1:2], -n[:, 0:1], n[:, 2:3]], dim=1)
        elif op == "h":
            n, rest = n.flip(-2), rest.flip(-2)
            n = torch.cat([n[:, 0:1], -n[:, 1:2], n[:, 2:3]], dim=1)
        else:
            n, rest = n.flip(-1), rest.flip(-1)
            n = torch.cat([-n[:, 0:1], n[:, 1:3]], dim=1)
    return torch.cat([n, rest], dim=1)
