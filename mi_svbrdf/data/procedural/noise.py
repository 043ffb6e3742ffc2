"""Vectorised noise primitives for the procedural materials (torch, CPU, float32).

Every function works on a batch of B materials at once. Randomness comes from one
``torch.Generator`` per batch element (``gens``): each element draws its own random lattice
tables, in a fixed order, so an element's result never depends on the other elements of the
batch, and a batch equals its elements generated one by one, bit for bit.

Fields are evaluated at continuous plane coordinates ``x, y`` (the sample spans ``[-1, 1]^2``,
y up; see :func:`plane_grid`), so per-element frequencies, rotations and domain warps are just
coordinate arithmetic. ``frequency`` is always in cycles (or cells) across the sample's width.
Lattice tables are periodic (``period`` cells), so coordinates may take any value without a
seam; the materials are not made tileable.

Only operations whose results do not depend on a tensor's length are used (no non-integer
``**``, ``atan2`` or ``sigmoid``: their vectorised and scalar CPU kernels differ in the last bit,
which would make an element's value depend on where it sits in the batch).

Examples:
    >>> import torch
    >>> gens = [torch.Generator().manual_seed(s) for s in (0, 1)]
    >>> x, y = plane_grid(32)
    >>> n = fbm(gens, x, y, torch.tensor([4.0, 8.0]).view(2, 1, 1, 1), octaves=3)
    >>> tuple(n.shape), bool(n.min() > -0.5 and n.max() < 1.5)
    ((2, 1, 34, 34), True)
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

#: One random generator per batch element.
Generators = Sequence[torch.Generator]
#: A per-element scalar: a float, or a ``(B, 1, 1, 1)`` tensor.
Scalar = float | torch.Tensor


def uniform(gens: Generators, *shape: int) -> torch.Tensor:
    """Uniform [0, 1) numbers ``(B, *shape)``, element b drawn from ``gens[b]``."""
    return torch.stack([torch.rand(shape, generator=g) for g in gens])


def plane_grid(size: int, margin: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Texel centres of a ``size``² map plus ``margin`` texels on each side.

    Returns:
        ``(x, y)``, each ``(1, 1, size + 2 margin, size + 2 margin)``: texel (i, j) of the map
        (row 0 at the top) is at x = -1 + (2j + 1)/size, y = 1 - (2i + 1)/size; the margin
        continues the grid outside ``[-1, 1]^2``.
    """
    idx = torch.arange(-margin, size + margin, dtype=torch.float32)
    c = (2.0 * idx + 1.0) / size
    n = size + 2 * margin
    x = (c - 1.0).view(1, 1, 1, n).expand(1, 1, n, n)
    y = (1.0 - c).view(1, 1, n, 1).expand(1, 1, n, n)
    return x, y


def rotate(x: torch.Tensor, y: torch.Tensor, angle: Scalar) -> tuple[torch.Tensor, torch.Tensor]:
    """Coordinates in a frame rotated by ``angle`` radians (counter-clockwise): ``(u, v)``.

    A pattern aligned with ``u`` in the new frame appears rotated by ``angle`` on the plane.
    """
    c, s = (torch.cos(angle), torch.sin(angle)) if isinstance(angle, torch.Tensor) else \
        (math.cos(angle), math.sin(angle))
    return x * c + y * s, y * c - x * s


def smoothstep(edge0: Scalar, edge1: Scalar, x: torch.Tensor) -> torch.Tensor:
    """Hermite step: 0 below ``edge0``, 1 above ``edge1``, ``3t² - 2t³`` between."""
    t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def mix(a: torch.Tensor | float, b: torch.Tensor | float, t: torch.Tensor | float) -> torch.Tensor:
    """Linear interpolation ``a + (b - a) t`` (broadcasting)."""
    return a + (b - a) * t  # type: ignore[operator, return-value]


def _lattice_grid(x: torch.Tensor, y: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor,
                  period: int) -> torch.Tensor:
    """``grid_sample`` grid of the lattice coordinates ``x a + y b + c``, wrapped to the period.

    Args:
        x, y: ``(B or 1, 1, H, W)`` plane coordinates.
        a, b, c: ``(B, K, 1, 1, 2)`` factors (u and v last) of K coordinate frames.
        period: lattice period L (the table is padded by 2 cells before sampling).

    Returns:
        ``(B * K, H, W, 2)`` normalised coordinates into the padded table.
    """
    scale = 2.0 / (period + 3)
    grid = torch.addcmul(c * scale, x[..., None], a * scale)  # (B, K, H, W, 2)
    grid.addcmul_(y[..., None], b * scale)
    wraps = torch.floor(grid * (1.0 / (period * scale)))  # whole periods to remove: u mod L
    grid.sub_(wraps.mul_(period * scale).sub_(2.0 * scale - 1.0))
    return grid.view(-1, *grid.shape[2:])


def _interpolate(table: torch.Tensor, grid: torch.Tensor, mode: str) -> torch.Tensor:
    """``(N, C, L, L)`` periodic table at a :func:`_lattice_grid` grid -> ``(N, C, H, W)``."""
    if mode not in ("bicubic", "bilinear"):
        raise ValueError(f"mode: expected 'bicubic' or 'bilinear', got {mode!r}")
    padded = F.pad(table, (2, 2, 2, 2), mode="circular")
    return F.grid_sample(padded, grid, mode=mode, padding_mode="border", align_corners=True)


#: Fixed per-octave rotations (radians) and offsets (cells): octaves never share lattice axes.
_OCTAVE_ANGLES = (0.0, 1.1, 2.3, 0.7, 1.9, 2.9, 0.4, 1.5)
_OCTAVE_OFFSETS = (0.0, 17.3, 41.9, 7.7, 29.1, 53.3, 11.9, 37.7)


def layers(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar, *, count: int = 1,
           lacunarity: float = 2.0, channels: int = 1, period: int = 64, stretch: Scalar = 1.0,
           angle: Scalar | None = None, spin: bool = True, mode: str = "bicubic") -> torch.Tensor:
    """``count`` independent value-noise layers ``(B, count, channels, H, W)``, values about [0, 1].

    Layer k is a random periodic lattice (its own table) interpolated at the lattice
    coordinates ``u = (x' + 1) f_k / 2 + o_k``, ``v = (y' + 1) f_k stretch / 2 + o_k``, where
    ``(x', y') = rotate(x, y, angle_k)`` (see :func:`rotate`), ``f_k = frequency * lacunarity^k``
    and ``o_k`` a fixed offset. The rotation costs nothing: it is folded into the lattice map.

    Args:
        gens: one generator per element (draws ``count * channels * period²`` numbers each).
        x, y: ``(B or 1, 1, H, W)`` plane coordinates.
        frequency: lattice cells across the sample's width (float or ``(B, 1, 1, 1)``).
        count: number of layers (1 to 8).
        lacunarity: frequency ratio between successive layers.
        channels: independent channels sharing the coordinates.
        period: lattice period in cells (the noise repeats after ``period / frequency`` widths).
        stretch: frequency multiplier along y' (> 1 elongates features along x').
        angle: rotation in radians: a float, ``(B, 1, 1, 1)`` (every layer) or ``(B, count, 1, 1)``.
        spin: add a fixed, different rotation to each layer (hides lattice axes in fBm);
            set False for anisotropic noise whose layers must stay aligned.
        mode: ``"bicubic"`` (C1-smooth: use for heights) or ``"bilinear"`` (~4x cheaper).
    """
    if not 1 <= count <= len(_OCTAVE_ANGLES):
        raise ValueError(f"count: expected 1 to {len(_OCTAVE_ANGLES)}, got {count}")
    b = len(gens)
    table = uniform(gens, count, channels, period, period).view(b * count, channels, period, period)
    f = torch.as_tensor(frequency, dtype=torch.float32).reshape(-1, 1, 1, 1)
    st = torch.as_tensor(stretch, dtype=torch.float32).reshape(-1, 1, 1, 1)
    scale = torch.tensor([0.5 * lacunarity**k for k in range(count)]).view(1, count, 1, 1)
    theta = torch.tensor([_OCTAVE_ANGLES[k] if spin else 0.0 for k in range(count)]).view(1, count, 1, 1)
    if angle is not None:
        ang = torch.as_tensor(angle, dtype=torch.float32)
        theta = theta + (ang if ang.dim() == 4 and ang.shape[1] == count else ang.reshape(-1, 1, 1, 1))
    cos, sin = torch.cos(theta), torch.sin(theta)
    offset = torch.tensor(_OCTAVE_OFFSETS[:count]).view(1, count, 1, 1)
    fu = (f * scale).expand(b, count, 1, 1)
    fv = (f * scale * st).expand(b, count, 1, 1)
    cos, sin = cos.expand(b, count, 1, 1), sin.expand(b, count, 1, 1)
    # u = (x cos + y sin + 1) fu + o, v = (y cos - x sin + 1) fv + o, written as x a + y b + c.
    a = torch.stack([cos * fu, -sin * fv], dim=-1)  # (B, count, 1, 1, 2)
    bb = torch.stack([sin * fu, cos * fv], dim=-1)
    c = torch.stack([fu + offset, fv + offset], dim=-1)
    grid = _lattice_grid(x, y, a, bb, c, period)
    return _interpolate(table, grid, mode).view(b, count, channels, *x.shape[-2:])


def fbm(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar, *, octaves: int = 4,
        gain: Scalar = 0.5, lacunarity: float = 2.0, channels: int = 1, period: int = 64,
        stretch: Scalar = 1.0, angle: Scalar | None = None, mode: str = "bicubic") -> torch.Tensor:
    """Fractal Brownian motion: a sum of ``octaves`` value-noise layers, ``(B, channels, H, W)``.

    Octave k is layer k of :func:`layers` (frequency ``frequency * lacunarity^k``) weighted by
    ``gain^k``; isotropic fBm (``stretch == 1``) also spins each octave, so no lattice axis
    shows, anisotropic fBm keeps its octaves aligned. The sum is divided by the total
    amplitude: values stay about [0, 1] (mean 0.5).

    Args:
        gens: one generator per element (draws ``octaves * channels * period²`` numbers each).
        x, y: ``(B or 1, 1, H, W)`` plane coordinates.
        frequency: base frequency (cycles across the sample), float or ``(B, 1, 1, 1)``.
        octaves: number of layers (1 to 8).
        gain: amplitude ratio between octaves (float or ``(B, 1, 1, 1)``); higher is rougher.
        lacunarity: frequency ratio between octaves.
        channels: independent channels sharing the coordinates.
        period: lattice period in cells.
        stretch: frequency multiplier along y' (anisotropy: > 1 elongates features along x').
        angle: rotation of the noise in radians (float or ``(B, 1, 1, 1)``).
        mode: ``"bicubic"`` (C1-smooth: use for heights) or ``"bilinear"`` (~4x cheaper).
    """
    isotropic = not isinstance(stretch, torch.Tensor) and stretch == 1.0
    lay = layers(gens, x, y, frequency, count=octaves, lacunarity=lacunarity, channels=channels, period=period,
                 stretch=stretch, angle=angle, spin=isotropic, mode=mode)
    total = None
    norm = 0.0
    amp: Scalar = 1.0
    for k in range(octaves):
        term = (lay[:, k] - 0.5) * amp
        total = term if total is None else total + term
        norm = norm + amp
        amp = amp * gain
    return total / norm + 0.5  # type: ignore[operator]


def value_noise(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar, *,
                channels: int = 1, period: int = 64, stretch: Scalar = 1.0, angle: Scalar | None = None,
                mode: str = "bicubic") -> torch.Tensor:
    """Smooth random noise ``(B, channels, H, W)``, values about [0, 1] (mean 0.5, sd ~0.17).

    One layer of :func:`layers` (lattice cells across the sample's width = ``frequency``).
    """
    return layers(gens, x, y, frequency, channels=channels, period=period, stretch=stretch, angle=angle,
                  spin=False, mode=mode)[:, 0]


def domain_warp(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar,
                amount: Scalar, *, octaves: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """Displace coordinates by a 2-channel fBm: ``x + amount * (2 n0 - 1)``, same for y.

    Args:
        amount: largest typical displacement in plane units (float or ``(B, 1, 1, 1)``).

    Returns:
        Warped ``(x, y)``, each ``(B, 1, H, W)``.
    """
    n = fbm(gens, x, y, frequency, octaves=octaves, channels=2) * 2.0 - 1.0
    return x + n[:, 0:1] * amount, y + n[:, 1:2] * amount


def _padded_flat(table: torch.Tensor) -> torch.Tensor:
    """``(B, C, L, L)`` -> ``(B, C, (L + 2)²)``: wrapped by one cell on each side, flattened."""
    return F.pad(table, (1, 1, 1, 1), mode="circular").flatten(2)


def _gather(flat: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Values of a flat table ``(B, C, N)`` at ``index`` ``(B, 1, H, W)`` -> ``(B, C, H, W)``."""
    b, c = flat.shape[:2]
    out = torch.gather(flat, 2, index.flatten(2).expand(b, c, -1))
    return out.view(b, c, *index.shape[-2:])


def _cells(x: torch.Tensor, y: torch.Tensor, frequency: Scalar, period: int, batch: int
           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Lattice cell of each point: (index into a padded flat table, fraction u, fraction v)."""
    u = ((x + 1.0) * (0.5 * frequency)).expand(batch, -1, -1, -1)
    v = ((y + 1.0) * (0.5 * frequency)).expand(batch, -1, -1, -1)
    iu, iv = torch.floor(u), torch.floor(v)
    wu = iu - torch.floor(iu * (1.0 / period)) * period  # iu mod period (exact for integers)
    wv = iv - torch.floor(iv * (1.0 / period)) * period
    index = (wv + 1.0) * (period + 2) + (wu + 1.0)
    return index.long(), u - iu, v - iv


def gradient_noise(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar, *,
                   period: int = 64) -> torch.Tensor:
    """Perlin gradient noise ``(B, 1, H, W)``, values about [-0.7, 0.7], zero at lattice points.

    Random unit gradients on a periodic lattice, quintic fade between the four corners.
    Compared with :func:`value_noise` it has less energy at low frequencies (no blobs).
    """
    b = len(gens)
    angle = uniform(gens, 1, period, period) * (2.0 * math.pi)
    flat = _padded_flat(torch.cat([torch.cos(angle), torch.sin(angle)], dim=1))
    index, fu, fv = _cells(x, y, frequency, period, b)
    row = period + 2
    corners = []
    for dj in (0, 1):
        for di in (0, 1):
            g = _gather(flat, index + (dj * row + di))
            corners.append(g[:, 0:1] * (fu - di) + g[:, 1:2] * (fv - dj))
    su = fu * fu * fu * (fu * (fu * 6.0 - 15.0) + 10.0)
    sv = fv * fv * fv * (fv * (fv * 6.0 - 15.0) + 10.0)
    return mix(mix(corners[0], corners[1], su), mix(corners[2], corners[3], su), sv)


@dataclass
class Cells:
    """A Voronoi (cellular) field: every texel's nearest feature point and its cell.

    Distances are in cell units (1 = the lattice spacing, ``2 / frequency`` plane units).

    Attributes:
        f1: ``(B, 1, H, W)`` distance to the nearest feature point (the cell's centre).
        edge: ``(B, 1, H, W)`` distance to the nearest cell border (bisector to a neighbour),
            or None when not asked for.
        dx, dy: ``(B, 1, H, W)`` vector from the texel to its cell's centre (x right, y up).
        values: ``(B, K, H, W)`` K uniform [0, 1) random values per cell (or the per-cell
            attributes computed from them, see :func:`voronoi`).
    """

    f1: torch.Tensor
    edge: torch.Tensor | None
    dx: torch.Tensor
    dy: torch.Tensor
    values: torch.Tensor


#: The 3x3 neighbour offsets (di, dj) searched by :func:`voronoi`, in candidate order.
_NEIGHBOURS = tuple((di, dj) for dj in (-1, 0, 1) for di in (-1, 0, 1))


def voronoi(gens: Generators, x: torch.Tensor, y: torch.Tensor, frequency: Scalar, *,
            jitter: Scalar = 1.0, values: int = 1, period: int = 128, edges: bool = True,
            attributes: Callable[[torch.Tensor], torch.Tensor] | None = None) -> Cells:
    """Jittered-grid Voronoi cells (Worley noise) with the distance to the cell border.

    One feature point per lattice cell at ``0.5 + jitter * (U(0, 1) - 0.5)`` within the cell;
    the 3x3 neighbouring cells are searched (the usual approximation: near jitter 1 a rare
    nearer point two cells away is missed). The border distance is the distance to the
    nearest bisector between the texel's feature point and another candidate, so a threshold
    on it gives even grout or crack widths.

    Args:
        gens: one generator per element (draws ``(2 + values) * period²`` numbers each).
        x, y: ``(B or 1, 1, H, W)`` plane coordinates.
        frequency: cells across the sample's width (float or ``(B, 1, 1, 1)``).
        jitter: 0 = regular grid of squares, 1 = fully random points.
        values: random values per cell to return.
        period: lattice period (cells) before the pattern repeats.
        edges: compute ``Cells.edge`` (about half the cost).
        attributes: maps the per-cell random values ``(B, values, L, L)`` to per-cell
            attributes ``(B, C, L, L)`` (e.g. colours), returned in ``Cells.values`` instead:
            computed once per cell rather than once per texel.
    """
    b = len(gens)
    table = uniform(gens, 2 + values, period, period)
    points = _padded_flat((table[:, 0:2] - 0.5) * jitter + 0.5)
    index, fu, fv = _cells(x, y, frequency, period, b)
    row = period + 2
    # Pass 1: the nearest candidate. Its number k rides in the low bits of a quantised squared
    # distance (exact in float32: the nearest point is closer than sqrt(2) cells), so a plain
    # running minimum finds it (torch.where is ~10x slower than torch.minimum on CPU).
    cand = []
    key = None
    for k, (di, dj) in enumerate(_NEIGHBOURS):
        p = _gather(points, index + (dj * row + di))
        dx = p[:, 0:1].add_(di).sub_(fu)
        dy = p[:, 1:2].add_(dj).sub_(fv)
        d2 = dx * dx
        d2.addcmul_(dy, dy)
        cand.append((dx, dy, d2))
        kk = torch.floor(d2.clamp(max=2.0) * 2.0**18).mul_(16.0).add_(float(k))
        key = kk if key is None else torch.minimum(key, kk)
    best = key - torch.floor(key * (1.0 / 16.0)) * 16.0  # the nearest candidate's number
    bi = torch.remainder(best, 3.0)
    bj = torch.floor(best * (1.0 / 3.0))
    best_index = index + ((bj - 1.0) * row + (bi - 1.0)).long()
    p = _gather(points, best_index)
    bdx = p[:, 0:1].add_(bi - 1.0).sub_(fu)
    bdy = p[:, 1:2].add_(bj - 1.0).sub_(fv)
    best_d2 = bdx * bdx
    best_d2.addcmul_(bdy, bdy)  # the same operations as the candidate's d2: bit-identical
    edge = None
    if edges:
        # Pass 2: distance to the bisector with each other candidate, (d2_k - d2_best) / (2 |p_k - p_best|).
        # For the nearest candidate itself (0 + 1e-30) * rsqrt(0) = inf drops out of the minimum.
        for dx, dy, d2 in cand:
            ex, ey = dx - bdx, dy - bdy
            sep2 = ex.mul_(ex).addcmul_(ey, ey)
            dist = (d2 - best_d2).add_(1e-30).mul_(sep2.rsqrt_())
            edge = dist if edge is None else torch.minimum(edge, dist)
        edge = edge.mul_(0.5).clamp_(min=0.0)  # ties in the quantised search can leave -1e-6
    per_cell = table[:, 2:] if attributes is None else attributes(table[:, 2:])
    vals = _gather(_padded_flat(per_cell), best_index)
    return Cells(f1=torch.sqrt(best_d2), edge=edge, dx=bdx, dy=bdy, values=vals)


def grid_cells(x: torch.Tensor, y: torch.Tensor, columns: Scalar, rows: Scalar, *,
               row_offset: Scalar = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A regular grid of rectangular cells (tiles, bricks), rows counted from the top.

    Args:
        x, y: plane coordinates.
        columns, rows: cells across the sample's width and height.
        row_offset: shift of every other row, in cell widths (0.5: running bond).

    Returns:
        ``(column, row, fu, fv)``: integer-valued cell coordinates (float tensors) and the
        position inside the cell in [0, 1) (fu from the left, fv from the top).
    """
    v = (1.0 - y) * (0.5 * rows)
    row = torch.floor(v)
    odd = torch.remainder(row, 2.0)
    u = (x + 1.0) * (0.5 * columns) + odd * row_offset
    col = torch.floor(u)
    return col, row, u - col, v - row


def cell_values(gens: Generators, column: torch.Tensor, row: torch.Tensor, values: int, *,
                period: int = 64, attributes: Callable[[torch.Tensor], torch.Tensor] | None = None
                ) -> torch.Tensor:
    """K uniform random values per integer cell ``(column, row)``: ``(B, K, H, W)``.

    With ``attributes``, the per-cell values ``(B, K, L, L)`` are first mapped to per-cell
    attributes ``(B, C, L, L)`` (computed once per cell), and those are returned per texel.
    """
    b = len(gens)
    table = uniform(gens, values, period, period)
    table = (table if attributes is None else attributes(table)).flatten(2)
    index = (torch.remainder(row, period) * period + torch.remainder(column, period)).long()
    return _gather(table, index.expand(b, -1, -1, -1))
