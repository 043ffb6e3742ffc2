"""Measured BRDFs as models: tables and scattered samples looked up at any (ω_i, ω_o).

The BRDF models behind measurement files (reading and writing the files: :mod:`mi_svbrdf.io.measured`).
Everything here is one homogeneous, isotropic BRDF in the sample's frame: z is the macroscopic
normal, x the azimuth φ = 0; ω_i points towards the light, ω_o towards the viewer, both unit
vectors ``(sin θ cos φ, sin θ sin φ, cos θ)``. Values are the BRDF f itself (1/sr, **no cosine**),
linear RGB. :meth:`MeasuredBRDF.lookup` is vectorised (any batch shape, torch float64) and says
where the measurement has no data.

**MERL tables** (:class:`MerlBRDF`, Matusik et al. 2003): ``(3, 90, 90, 180)`` values (RGB,
θ_h, θ_d, φ_d), negative where there is no data, in Rusinkiewicz's half/difference angles:
``h = normalize(ω_i + ω_o)``, ``θ_h = acos(h.z)``, ``φ_h = atan2(h.y, h.x)``; ``d = R_y(−θ_h) R_z(−φ_h) ω_i``
(ω_i seen from the half vector's frame), ``θ_d = acos(d.z)``, ``φ_d = atan2(d.y, d.x)`` taken modulo π:
an isotropic, reciprocal BRDF has ``f(θ_h, θ_d, φ_d) = f(θ_h, θ_d, φ_d + π)``, so the table stores φ_d
over [0, π) only. Continuous table indices:

- ``u_h = sqrt(θ_h / (π/2)) · 90`` (the square-root mapping: entries crowd near the specular peak),
- ``u_d = θ_d / (π/2) · 90`` (linear over [0, π/2)),
- ``u_φ = φ_d / π · 180`` (linear over [0, π)).

MERL's reference reader truncates each to an integer and clamps it to ``[0, n − 1]``: entry ``i``
therefore holds the BRDF at ``u = i`` exactly, i.e. at ``θ_h = (i/90)² π/2``, ``θ_d = i π/180``,
``φ_d = i π/180``. :func:`merl_table` samples a BRDF there and :meth:`MerlBRDF.lookup` interpolates
between those points (``"linear"``: trilinear in ``(u_h, u_d, u_φ)``, cyclic in φ_d with period 180
entries, clamped at the last θ entries) or truncates as the reference does (``"nearest"``).
Entries without data are left out of the interpolation (the other corners' weights are
renormalised); a point with no valid corner is ``valid = False`` with value 0.

**Scattered samples** (:class:`TabulatedBRDF`, e.g. a gonioreflectometer's scan), read as an
isotropic BRDF: only ``θ_i``, ``θ_o`` and ``Δφ = φ_o − φ_i`` matter, and ``Δφ`` and ``−Δφ`` are the
same (the specular direction is at ``Δφ = 180°``). Samples are grouped by incidence (θ_i equal
within 1e-3°). Within an incidence:

- when its samples fill a grid of θ_o values × |Δφ| values (a gonioreflectometer's usual scan;
  repeated cells averaged, samples at θ_o = 0 standing for every azimuth): bilinear in (θ_o, |Δφ|),
  valid up to half a grid step beyond the grid;
- otherwise: inverse-distance weighting (power 2, exact at the samples) of the 4 nearest samples
  in the azimuthal-equidistant plane ``θ_o (cos|Δφ|, sin|Δφ|)`` (degrees, the conoscopic plot's
  layout), valid where the nearest sample is within ``max_gap`` degrees (default: three times that
  incidence's median nearest-neighbour spacing, at least 1°);

between incidences linear in θ_i, valid when θ_i lies within the measured incidences (±0.5°) and
both incidences drawn on are valid there. Outside, values are extrapolated from the nearest data
and flagged invalid.

Examples:
    >>> import math, torch
    >>> lambert = lambda wi, wo: torch.full(wi.shape[:-1] + (3,), 0.5 / math.pi, dtype=torch.float64)
    >>> brdf = MerlBRDF(merl_table(lambert))
    >>> wi = torch.tensor([[0.3, 0.1, 0.95]]); wo = torch.tensor([[-0.5, 0.2, 0.84]])
    >>> f, valid = brdf.lookup(wi, wo)
    >>> [round(float(v) * math.pi, 6) for v in f[0]], bool(valid[0])
    ([0.5, 0.5, 0.5], True)
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np
import torch

#: The MERL table's dimensions ``(n_θh, n_θd, n_φd)``.
MERL_DIMS: tuple[int, int, int] = (90, 90, 180)
#: Interpolation modes of :meth:`MerlBRDF.lookup`.
INTERPOLATIONS = ("linear", "nearest")

BRDFFunction = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


# ----------------------------------------------------------------------------------------------- directions


def direction(theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Unit vectors ``(..., 3)`` ``(sin θ cos φ, sin θ sin φ, cos θ)`` of angles in radians (shapes broadcast)."""
    theta, phi = torch.broadcast_tensors(torch.as_tensor(theta), torch.as_tensor(phi))
    return torch.stack([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], -1)


def _unit(v: torch.Tensor, name: str) -> torch.Tensor:
    if not isinstance(v, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor (..., 3), got {type(v).__name__}")
    if v.dim() < 1 or v.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (..., 3), got {tuple(v.shape)}")
    if not torch.isfinite(v).all():
        raise ValueError(f"{name}: contains NaN or Inf")
    v = v.to(torch.float64)
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-300)


def _pair(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    wi, wo = _unit(wi, "wi"), _unit(wo, "wo")
    try:
        return torch.broadcast_tensors(wi, wo)
    except RuntimeError:
        raise ValueError(f"wo: expected a shape broadcastable with wi {tuple(wi.shape)}, got {tuple(wo.shape)}") from None


def half_diff(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rusinkiewicz's ``(θ_h, θ_d, φ_d)`` of direction pairs, φ_d folded to [0, π) (see the module docstring).

    Args:
        wi: ``(..., 3)`` directions towards the light (normalised here).
        wo: ``(..., 3)`` directions towards the viewer, broadcastable with ``wi``.

    Returns:
        Three ``(...)`` float64 tensors in radians.
    """
    wi, wo = _pair(wi, wo)
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    theta_h = torch.acos(h[..., 2].clamp(-1.0, 1.0))
    phi_h = torch.atan2(h[..., 1], h[..., 0])
    # d = R_y(-θ_h) R_z(-φ_h) wi
    c, s = torch.cos(-phi_h), torch.sin(-phi_h)
    x = wi[..., 0] * c - wi[..., 1] * s
    y = wi[..., 0] * s + wi[..., 1] * c
    z = wi[..., 2]
    c, s = torch.cos(-theta_h), torch.sin(-theta_h)
    dx, dy, dz = x * c + z * s, y, z * c - x * s
    theta_d = torch.acos(dz.clamp(-1.0, 1.0))
    phi_d = torch.remainder(torch.atan2(dy, dx), math.pi)
    return theta_h, theta_d, phi_d


def from_half_diff(theta_h: torch.Tensor, theta_d: torch.Tensor, phi_d: torch.Tensor,
                   phi_h: torch.Tensor | float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """The direction pair ``(ω_i, ω_o)`` (each ``(..., 3)``, float64) of half/difference angles (radians).

    The inverse of :func:`half_diff` (``ω_i = R_z(φ_h) R_y(θ_h) d``, ``ω_o`` its mirror about h);
    an isotropic BRDF does not depend on ``φ_h``.
    """
    theta_h, theta_d, phi_d, phi_h = torch.broadcast_tensors(
        *(torch.as_tensor(t, dtype=torch.float64) for t in (theta_h, theta_d, phi_d, phi_h)))
    d = direction(theta_d, phi_d)
    c, s = torch.cos(theta_h), torch.sin(theta_h)
    x, y, z = d[..., 0] * c + d[..., 2] * s, d[..., 1], d[..., 2] * c - d[..., 0] * s
    c, s = torch.cos(phi_h), torch.sin(phi_h)
    wi = torch.stack([x * c - y * s, x * s + y * c, z], -1)
    h = direction(theta_h, phi_h)
    wo = 2.0 * (wi * h).sum(-1, keepdim=True) * h - wi
    return wi, wo


# ----------------------------------------------------------------------------------------------- BRDF objects


class MeasuredBRDF:
    """A measured, isotropic BRDF that can be looked up at any direction pair.

    Attributes:
        name: where it came from (a file name, or a label).
    """

    name: str = "measured"

    def lookup(self, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The BRDF at direction pairs.

        Args:
            wi: ``(..., 3)`` directions towards the light in the sample's frame (normalised here).
            wo: ``(..., 3)`` directions towards the viewer, broadcastable with ``wi``.

        Returns:
            ``(f, valid)``: ``f`` ``(..., 3)`` float64 BRDF values (1/sr, no cosine; 0 where there is no
            data) and ``valid`` ``(...)`` bool, False where the measurement has no data there.
        """
        raise NotImplementedError

    def __call__(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """``lookup(wi, wo)[0]``."""
        return self.lookup(wi, wo)[0]


class MerlBRDF(MeasuredBRDF):
    """A MERL half/difference table (see the module docstring for its conventions).

    Args:
        table: ``(3, n_θh, n_θd, n_φd)`` BRDF values (already multiplied by the channel scales);
            negative entries (and NaN) mean no data.
        name: a label for messages (the file name when read by :func:`read_merl`).
        interpolation: ``"linear"`` (trilinear in the table's indices) or ``"nearest"`` (the
            reference reader's truncation).
    """

    def __init__(self, table: torch.Tensor | np.ndarray, name: str = "merl", interpolation: str = "linear") -> None:
        table = torch.as_tensor(table, dtype=torch.float64)
        if table.dim() != 4 or table.shape[0] != 3 or min(table.shape[1:]) < 2:
            raise ValueError(f"table: expected shape (3, n_theta_h, n_theta_d, n_phi_d) with every n >= 2, "
                             f"got {tuple(table.shape)}")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation: expected one of {INTERPOLATIONS}, got {interpolation!r}")
        self.valid = (table >= 0).all(dim=0)  # NaN compares False: no data
        self.table = torch.where(self.valid[None], table, torch.zeros((), dtype=torch.float64))
        self.dims = tuple(int(n) for n in table.shape[1:])
        self.name = name
        self.interpolation = interpolation
        self._flat = self.table.permute(1, 2, 3, 0).reshape(-1, 3)
        self._flat_valid = self.valid.reshape(-1)

    def indices(self, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Continuous table indices ``(u_h, u_d, u_φ)`` (each ``(...)`` float64) of direction pairs."""
        theta_h, theta_d, phi_d = half_diff(wi, wo)
        n_h, n_d, n_p = self.dims
        u_h = torch.sqrt((theta_h / (math.pi / 2)).clamp_min(0.0)) * n_h
        u_d = theta_d / (math.pi / 2) * n_d
        u_p = phi_d / math.pi * n_p
        return u_h, u_d, u_p

    def lookup(self, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MeasuredBRDF.lookup`; interpolation as chosen at construction."""
        u_h, u_d, u_p = self.indices(wi, wo)
        n_h, n_d, n_p = self.dims
        shape = u_h.shape
        u_h, u_d, u_p = u_h.reshape(-1), u_d.reshape(-1), u_p.reshape(-1)
        if self.interpolation == "nearest":
            i_h = u_h.floor().long().clamp(0, n_h - 1)
            i_d = u_d.floor().long().clamp(0, n_d - 1)
            i_p = u_p.floor().long().clamp(0, n_p - 1)
            flat = i_p + n_p * (i_d + n_d * i_h)
            valid = self._flat_valid[flat]
            return self._flat[flat].reshape(*shape, 3), valid.reshape(shape)

        def axis(u: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            i0 = u.floor().clamp(0, n - 2)
            t = (u - i0).clamp(0.0, 1.0)
            return i0.long(), i0.long() + 1, t

        h0, h1, th = axis(u_h, n_h)
        d0, d1, td = axis(u_d, n_d)
        p0 = torch.remainder(u_p.floor(), n_p).long()
        p1 = torch.remainder(p0 + 1, n_p)
        tp = (u_p - u_p.floor()).clamp(0.0, 1.0)
        acc = torch.zeros(u_h.shape[0], 3, dtype=torch.float64)
        wsum = torch.zeros(u_h.shape[0], dtype=torch.float64)
        for ih, wh in ((h0, 1.0 - th), (h1, th)):
            for id_, wd in ((d0, 1.0 - td), (d1, td)):
                for ip, wp in ((p0, 1.0 - tp), (p1, tp)):
                    flat = ip + n_p * (id_ + n_d * ih)
                    w = wh * wd * wp * self._flat_valid[flat]
                    acc += w[:, None] * self._flat[flat]
                    wsum += w
        valid = wsum > 1e-9
        f = torch.where(valid[:, None], acc / wsum.clamp_min(1e-300)[:, None], torch.zeros((), dtype=torch.float64))
        return f.reshape(*shape, 3), valid.reshape(shape)


def merl_table(brdf: BRDFFunction, dims: tuple[int, int, int] = MERL_DIMS, chunk: int = 1 << 16) -> torch.Tensor:
    """Sample a BRDF on the MERL grid (entry i at u = i, see the module docstring).

    Args:
        brdf: ``f(wi, wo) -> (N, 3)`` for ``(N, 3)`` float64 unit directions (e.g. our model, or a
            :class:`MeasuredBRDF`); its values are cast to float64.
        dims: ``(n_θh, n_θd, n_φd)``; MERL files are ``(90, 90, 180)``.
        chunk: direction pairs evaluated at once.

    Returns:
        ``(3, n_θh, n_θd, n_φd)`` float64 BRDF values, -1 (no data) where ω_i or ω_o is at or below the
        horizon (z <= 1e-6).
    """
    if len(dims) != 3 or min(dims) < 2:
        raise ValueError(f"dims: expected three sizes >= 2, got {dims}")
    n_h, n_d, n_p = dims
    idx = torch.arange(n_h * n_d * n_p)
    i_h, i_d, i_p = idx // (n_d * n_p), (idx // n_p) % n_d, idx % n_p
    theta_h = (i_h.double() / n_h) ** 2 * (math.pi / 2)
    theta_d = i_d.double() / n_d * (math.pi / 2)
    phi_d = i_p.double() / n_p * math.pi
    out = torch.empty(idx.shape[0], 3, dtype=torch.float64)
    for start in range(0, idx.shape[0], chunk):
        sl = slice(start, start + chunk)
        wi, wo = from_half_diff(theta_h[sl], theta_d[sl], phi_d[sl])
        below = (wi[:, 2] <= 1e-6) | (wo[:, 2] <= 1e-6)
        f = torch.as_tensor(brdf(wi, wo)).to(torch.float64).reshape(-1, 3)
        out[sl] = torch.where(below[:, None], torch.full((), -1.0, dtype=torch.float64), f)
    return out.T.reshape(3, n_h, n_d, n_p).contiguous()



class TabulatedBRDF(MeasuredBRDF):
    """Scattered measurements of an isotropic BRDF, grouped by incidence (the CSV format's model).

    Args:
        theta_i: ``(N,)`` incidence angles in degrees, [0, 90].
        phi_i: ``(N,)`` incidence azimuths in degrees.
        theta_o: ``(N,)`` outgoing angles in degrees, [0, 90].
        phi_o: ``(N,)`` outgoing azimuths in degrees.
        values: ``(N, 3)`` BRDF (1/sr, no cosine), finite and >= 0.
        name: a label for messages (the file name when read by :func:`read_tabulated_csv`).
        neighbours: samples weighted per lookup within an incidence.
        max_gap: a lookup farther than this (degrees, in the azimuthal-equidistant plane) from its
            nearest sample is invalid; None: three times the incidence's median nearest-neighbour
            spacing (at least 1°).
    """

    #: Incidences closer than this (degrees) are one group.
    GROUP_TOLERANCE = 1e-3
    #: A lookup's θ_i may lie this far (degrees) outside the measured incidences and stay valid.
    INCIDENCE_MARGIN = 0.5

    def __init__(self, theta_i: np.ndarray | torch.Tensor, phi_i: np.ndarray | torch.Tensor,
                 theta_o: np.ndarray | torch.Tensor, phi_o: np.ndarray | torch.Tensor,
                 values: np.ndarray | torch.Tensor, name: str = "tabulated", neighbours: int = 4,
                 max_gap: float | None = None) -> None:
        cols = [torch.as_tensor(np.asarray(c), dtype=torch.float64).reshape(-1)
                for c in (theta_i, phi_i, theta_o, phi_o)]
        values = torch.as_tensor(np.asarray(values), dtype=torch.float64)
        n = cols[0].shape[0]
        if any(c.shape[0] != n for c in cols) or values.shape != (n, 3) or n == 0:
            raise ValueError(f"{name}: expected N >= 1 rows of theta_i, phi_i, theta_o, phi_o and (N, 3) values, "
                             f"got {[c.shape[0] for c in cols]} and {tuple(values.shape)}")
        if not all(torch.isfinite(c).all() for c in cols) or not torch.isfinite(values).all():
            raise ValueError(f"{name}: expected finite angles and values, got NaN or Inf")
        for label, c in (("theta_i", cols[0]), ("theta_o", cols[2])):
            if c.min() < 0 or c.max() > 90:
                raise ValueError(f"{name}: expected {label} in [0, 90] degrees, got [{float(c.min()):g}, {float(c.max()):g}]")
        if values.min() < 0:
            raise ValueError(f"{name}: expected BRDF values >= 0, got {float(values.min()):g}")
        if neighbours < 1:
            raise ValueError(f"neighbours: expected >= 1, got {neighbours}")
        self.name, self.neighbours = name, neighbours
        order = torch.argsort(cols[0], stable=True)
        ti, pi, to, po = (c[order] for c in cols)
        values = values[order]
        # group by incidence: a new group where the sorted θ_i jumps by more than the tolerance
        starts = [0] + [k for k in range(1, n) if ti[k] - ti[k - 1] > self.GROUP_TOLERANCE] + [n]
        self.incidences = torch.stack([ti[a:b].mean() for a, b in itertools.pairwise(starts)])
        self.points: list[torch.Tensor] = []
        self.values: list[torch.Tensor] = []
        self.gaps: list[float] = []
        self.grids: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None] = []
        for a, b in itertools.pairwise(starts):
            self.grids.append(self._regular_grid(to[a:b], self._fold(po[a:b] - pi[a:b]), values[a:b]))
            xy = self._plane(to[a:b], po[a:b] - pi[a:b])
            self.points.append(xy)
            self.values.append(values[a:b])
            if max_gap is not None:
                self.gaps.append(float(max_gap))
            elif b - a > 1:
                d = torch.cdist(xy, xy)
                d.fill_diagonal_(float("inf"))
                self.gaps.append(max(1.0, 3.0 * float(d.min(dim=1).values.median())))
            else:
                self.gaps.append(float("inf"))

    @staticmethod
    def _fold(delta_phi_deg: torch.Tensor) -> torch.Tensor:
        """``|Δφ|`` folded to [0, 180] degrees (isotropy: Δφ and −Δφ are the same)."""
        return (torch.remainder(delta_phi_deg + 180.0, 360.0) - 180.0).abs()

    @classmethod
    def _plane(cls, theta_o_deg: torch.Tensor, delta_phi_deg: torch.Tensor) -> torch.Tensor:
        """Azimuthal-equidistant coordinates ``θ_o (cos|Δφ|, sin|Δφ|)`` (degrees), isotropy folded in."""
        dphi = torch.deg2rad(cls._fold(delta_phi_deg))
        return torch.stack([theta_o_deg * torch.cos(dphi), theta_o_deg * torch.sin(dphi)], -1)

    @staticmethod
    def _regular_grid(theta_o: torch.Tensor, phi: torch.Tensor, values: torch.Tensor
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """``(θ axis (T,), |Δφ| axis (P,), values (T, P, 3))`` when an incidence's samples fill a θ_o × |Δφ|
        grid (repeats averaged; rows at θ_o = 0 stand for every azimuth), else None."""
        t = torch.round(theta_o * 1e6) / 1e6
        p = torch.round(phi * 1e6) / 1e6
        pole = t <= 0.0
        t_axis, p_axis = torch.unique(t[~pole]), torch.unique(p[~pole])
        if t_axis.numel() < 2 or p_axis.numel() < 2:
            return None
        it = torch.searchsorted(t_axis, t[~pole])
        ip = torch.searchsorted(p_axis, p[~pole])
        flat = it * p_axis.numel() + ip
        cells = t_axis.numel() * p_axis.numel()
        count = torch.zeros(cells, dtype=torch.float64).index_add_(0, flat, torch.ones_like(flat, dtype=torch.float64))
        if (count == 0).any():
            return None
        total = torch.zeros(cells, 3, dtype=torch.float64).index_add_(0, flat, values[~pole])
        table = (total / count[:, None]).reshape(t_axis.numel(), p_axis.numel(), 3)
        if pole.any():
            t_axis = torch.cat([torch.zeros(1, dtype=torch.float64), t_axis])
            table = torch.cat([values[pole].mean(0).expand(1, p_axis.numel(), 3), table])
        return t_axis, p_axis, table

    def _grid_slice(self, s: int, theta_o: torch.Tensor, phi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Bilinear lookup in (θ_o, |Δφ|) of a gridded incidence; valid within half a step of the grid."""
        t_axis, p_axis, table = self.grids[s]  # type: ignore[misc]

        def bracket(axis: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
            i1 = torch.searchsorted(axis, x).clamp(1, axis.numel() - 1)
            i0 = i1 - 1
            w = ((x - axis[i0]) / (axis[i1] - axis[i0])).clamp(0.0, 1.0)
            step = float((axis[1:] - axis[:-1]).max())
            inside = (x >= axis[0] - step / 2) & (x <= axis[-1] + step / 2)
            return i0, i1, w, inside

        t0, t1, wt, in_t = bracket(t_axis, theta_o)
        p0, p1, wp, in_p = bracket(p_axis, phi)
        in_t = in_t | (theta_o <= t_axis[0])  # below the first ring: the azimuths converge
        f = ((1 - wt)[:, None] * ((1 - wp)[:, None] * table[t0, p0] + wp[:, None] * table[t0, p1])
             + wt[:, None] * ((1 - wp)[:, None] * table[t1, p0] + wp[:, None] * table[t1, p1]))
        return f, in_t & in_p

    def _slice(self, s: int, q: torch.Tensor, theta_o: torch.Tensor, phi: torch.Tensor,
               chunk: int = 8192) -> tuple[torch.Tensor, torch.Tensor]:
        if self.grids[s] is not None:
            return self._grid_slice(s, theta_o, phi)
        pts, vals = self.points[s], self.values[s]
        k = min(self.neighbours, pts.shape[0])
        out = torch.empty(q.shape[0], 3, dtype=torch.float64)
        ok = torch.empty(q.shape[0], dtype=torch.bool)
        for a in range(0, q.shape[0], chunk):
            dist, idx = torch.cdist(q[a:a + chunk], pts).topk(k, dim=1, largest=False)
            w = 1.0 / dist.clamp_min(1e-9) ** 2
            w = torch.where(dist[:, :1] < 1e-9, (dist < 1e-9).double(), w)  # exact at a sample
            out[a:a + chunk] = (w[..., None] * vals[idx]).sum(1) / w.sum(1, keepdim=True)
            ok[a:a + chunk] = dist[:, 0] <= self.gaps[s]
        return out, ok

    def lookup(self, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """See :meth:`MeasuredBRDF.lookup` (interpolation as in the module docstring)."""
        wi, wo = _pair(wi, wo)
        shape = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        theta_i = torch.rad2deg(torch.acos(wi[:, 2].clamp(-1.0, 1.0)))
        theta_o = torch.rad2deg(torch.acos(wo[:, 2].clamp(-1.0, 1.0)))
        dphi = torch.rad2deg(torch.atan2(wo[:, 1], wo[:, 0]) - torch.atan2(wi[:, 1], wi[:, 0]))
        q = self._plane(theta_o, dphi)
        phi = self._fold(dphi)
        inc = self.incidences
        n_inc = inc.shape[0]
        hi = torch.searchsorted(inc, theta_i).clamp(0, n_inc - 1)
        lo = (hi - 1).clamp(0, n_inc - 1)
        lo = torch.where(theta_i <= inc[0], hi, lo)
        span = inc[hi] - inc[lo]
        t = torch.where(span > 0, (theta_i - inc[lo]) / span.clamp_min(1e-12), torch.zeros_like(span)).clamp(0, 1)
        v_lo = torch.zeros(q.shape[0], 3, dtype=torch.float64)
        v_hi = torch.zeros_like(v_lo)
        ok_lo = torch.zeros(q.shape[0], dtype=torch.bool)
        ok_hi = torch.zeros_like(ok_lo)
        for s in range(n_inc):
            for sel_idx, v, ok in ((lo == s, v_lo, ok_lo), (hi == s, v_hi, ok_hi)):
                rows = sel_idx.nonzero().squeeze(1)
                if rows.numel():
                    v[rows], ok[rows] = self._slice(s, q[rows], theta_o[rows], phi[rows])
        f = (1.0 - t)[:, None] * v_lo + t[:, None] * v_hi
        inside = (theta_i >= inc[0] - self.INCIDENCE_MARGIN) & (theta_i <= inc[-1] + self.INCIDENCE_MARGIN)
        valid = inside & (ok_lo | (t > 1 - 1e-9)) & (ok_hi | (t < 1e-9)) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return f.reshape(*shape, 3), valid.reshape(shape)



def gonio_samples(brdf: BRDFFunction, incidences_deg: list[float] | tuple[float, ...], theta_o_deg: np.ndarray,
                  delta_phi_deg: np.ndarray) -> tuple[np.ndarray, ...]:
    """Sample a BRDF as a gonioreflectometer would: every incidence (φ_i = 0) × every (θ_o, Δφ) of a grid.

    Returns:
        ``(theta_i, phi_i, theta_o, phi_o, values)``: four ``(N,)`` arrays in degrees and ``(N, 3)``
        values, ready for :func:`write_tabulated_csv` or :class:`TabulatedBRDF`.
    """
    inc = torch.as_tensor(np.asarray(incidences_deg, dtype=np.float64))
    to = torch.as_tensor(np.asarray(theta_o_deg, dtype=np.float64))
    dp = torch.as_tensor(np.asarray(delta_phi_deg, dtype=np.float64))
    ti, tt, pp = torch.meshgrid(inc, to, dp, indexing="ij")
    wi = direction(torch.deg2rad(ti), torch.zeros_like(ti))
    wo = direction(torch.deg2rad(tt), torch.deg2rad(pp))
    f = torch.as_tensor(brdf(wi.reshape(-1, 3), wo.reshape(-1, 3))).to(torch.float64).reshape(-1, 3)
    return (ti.reshape(-1).numpy(), np.zeros(ti.numel()), tt.reshape(-1).numpy(), pp.reshape(-1).numpy(), f.numpy())
