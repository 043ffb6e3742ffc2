"""What every generator builds: a height field, colour fields and per-texel roughness/specular,
turned into the canonical maps by :func:`finish`.

Generators work on a grid one texel wider than the map on each side (``Context.x``,
``Context.y``), so the normals at the map's border come from true central differences of
the height field, not from a padded copy.

Colours are chosen in sRGB HSV (what a person would pick) and converted to linear albedo.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from mi_svbrdf.core.maps import NUM_CHANNELS, SLICES
from mi_svbrdf.data.procedural import noise

#: Margin (texels) of the generator grid around the map.
MARGIN = 1


@dataclass
class Context:
    """Per-batch inputs of a generator.

    Attributes:
        gens: one ``torch.Generator`` per element, seeded from (class, seed).
        size: map resolution (the generator grid is ``size + 2 MARGIN``).
        x, y: ``(1, 1, size + 2, size + 2)`` plane coordinates of the grid (y up).
        p: per-element parameters, each ``(B, 1, 1, 1)`` float32.
    """

    gens: list[torch.Generator]
    size: int
    x: torch.Tensor
    y: torch.Tensor
    p: dict[str, torch.Tensor]

    @property
    def batch(self) -> int:
        """Number of materials B."""
        return len(self.gens)

    def uniform(self, *shape: int) -> torch.Tensor:
        """Per-element uniform [0, 1) numbers ``(B, *shape)``."""
        return noise.uniform(self.gens, *shape)

    def coarse(self, points: int) -> tuple[torch.Tensor, torch.Tensor]:
        """A coarser grid over the same extent: ``(x, y)``, each ``(1, 1, n, n)``, n = min(S, points).

        Its first and last points are the margin grid's, so :meth:`upsample` maps it back
        exactly. Smooth, low-frequency fields are computed on it at a fraction of the cost;
        ``points`` is fixed per use (never derived from the batch), so results stay
        batch-independent.
        """
        n = min(self.x.shape[-1], points)
        first, last = float(self.x[0, 0, 0, 0]), float(self.x[0, 0, 0, -1])
        c = torch.linspace(first, last, n)
        return c.view(1, 1, 1, n).expand(1, 1, n, n), (-c).view(1, 1, n, 1).expand(1, 1, n, n)

    def upsample(self, t: torch.Tensor, mode: str = "bicubic") -> torch.Tensor:
        """A field of a :meth:`coarse` grid ``(B, C, n, n)`` on the margin grid ``(B, C, S, S)``.

        ``"bicubic"`` keeps heights smooth (C1); ``"bilinear"`` is cheaper, for colours.
        """
        size = self.x.shape[-1]
        if t.shape[-1] == size:
            return t
        return F.interpolate(t, size=(size, size), mode=mode, align_corners=True)


@dataclass
class Surface:
    """A generator's output on the margin grid (``S = size + 2 MARGIN``).

    Attributes:
        height: ``(B, 1, S, S)`` height in plane units (the sample is 2 units wide).
        diffuse: ``(B, 3, S, S)`` linear diffuse albedo (clipped to [0, 1] by :func:`finish`).
        roughness: ``(B, 1, S, S)`` roughness (clipped to [0, 1]).
        specular: ``(B, 3, S, S)`` or ``(B, 1, S, S)`` (grey) linear specular albedo.
    """

    height: torch.Tensor
    diffuse: torch.Tensor
    roughness: torch.Tensor
    specular: torch.Tensor


#: A generator: builds the surface of a batch from its context.
Builder = Callable[[Context], Surface]


def make_context(gens: list[torch.Generator], size: int, params: dict[str, torch.Tensor]) -> Context:
    """A context with the plane grid of ``size`` plus the margin."""
    x, y = noise.plane_grid(size, MARGIN)
    return Context(gens=gens, size=size, x=x, y=y, p=params)


def crop(t: torch.Tensor) -> torch.Tensor:
    """The map's texels of a margin-grid field."""
    return t[..., MARGIN:-MARGIN, MARGIN:-MARGIN]


def normals(height: torch.Tensor, size: int) -> torch.Tensor:
    """Unit normals ``(B, 3, S - 2, S - 2)`` of a margin-grid height field ``(B, 1, S, S)``.

    ``normalize(-dh/dx, -dh/dy, 1)`` with central differences over the texel spacing
    ``2 / size`` (x right, y up: row 0 is the top). The same formula as
    ``examples.normals_from_height(height, strength=size / 2)`` on the interior, with an
    elementwise norm (``Tensor.norm`` over the channel dimension is much slower on CPU).
    """
    k = size / 4.0  # 1 / (2 * spacing)
    dx = (height[..., 1:-1, 2:] - height[..., 1:-1, :-2]) * k
    dy = (height[..., :-2, 1:-1] - height[..., 2:, 1:-1]) * k
    inv = torch.rsqrt(dx * dx + dy * dy + 1.0)
    return torch.cat([-dx * inv, -dy * inv, inv], dim=1)


def finish(surface: Surface, size: int, ranges: dict[str, tuple[float, float]] | None = None) -> torch.Tensor:
    """The canonical maps ``(B, 10, size, size)`` of a surface.

    Normals come from :func:`normals`; diffuse, roughness and specular are clipped to
    ``ranges[map]`` (a class's documented value ranges; [0, 1] for a map not listed).
    """
    ranges = ranges or {}
    b = surface.height.shape[0]
    out = torch.empty(b, NUM_CHANNELS, size, size)
    out[:, SLICES["normal"]] = normals(surface.height, size)
    fields = (("diffuse", surface.diffuse), ("roughness", surface.roughness), ("specular", surface.specular))
    for key, field in fields:
        low, high = ranges.get(key, (0.0, 1.0))
        out[:, SLICES[key]] = crop(field).clamp(max(0.0, low), min(1.0, high))
    return out


def permille(value: torch.Tensor | float) -> torch.Tensor | float:
    """A height given in thousandths of the sample's width, in plane units (width = 2)."""
    return value * 0.002


def degrees(value: torch.Tensor) -> torch.Tensor:
    """Degrees to radians."""
    return value * (math.pi / 180.0)


def hsv(h: torch.Tensor | float, s: torch.Tensor | float, v: torch.Tensor | float) -> torch.Tensor:
    """sRGB colour from hue (turns, wraps), saturation and value: ``(B, 3, ...)``.

    Each argument is a float or a ``(B, 1, H, W)`` tensor (H, W may be 1); they broadcast.
    """
    h, s, v = (torch.as_tensor(t, dtype=torch.float32) for t in (h, s, v))
    k = torch.remainder(torch.tensor([5.0, 3.0, 1.0]).view(1, 3, 1, 1) + h * 6.0, 6.0)
    ramp = torch.minimum(torch.minimum(k, 4.0 - k), torch.ones_like(k)).clamp_min(0.0)
    return v - v * s * ramp


def srgb_to_linear(c: torch.Tensor) -> torch.Tensor:
    """The sRGB decoding curve (IEC 61966-2-1), elementwise, for c in [0, 1]."""
    c = c.clamp(0.0, 1.0)
    # exp(2.4 log(.)) rather than ** 2.4: pow's vectorised and scalar kernels differ in the last bit.
    curve = torch.exp(2.4 * torch.log((c + 0.055) / 1.055))
    return torch.where(c <= 0.04045, c / 12.92, curve)


def colour(h: torch.Tensor | float, s: torch.Tensor | float, v: torch.Tensor | float) -> torch.Tensor:
    """Linear albedo of an sRGB HSV colour: ``srgb_to_linear(hsv(h, s, v))``."""
    return srgb_to_linear(hsv(h, s, v))

