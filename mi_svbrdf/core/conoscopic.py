"""The conoscopic grid of a BRDF comparison and its error figures (thesis ch. 6.2).

A measured BRDF and ours are compared as the cosine-weighted BRDF ``f · cos θ_o`` (1/sr), as the
thesis's conoscopic figures plot it, on a grid (:func:`conoscopic_grid`): per incidence θ_i (light
at azimuth 0), cell centres of a polar grid of outgoing directions (θ_o up to ``theta_max_deg``,
φ_o over 360°; the mirror direction is at φ_o = 180°), each cell weighted by its solid angle ``w``
and by whether the measurement has data there.

**Error figures** per colour channel, with m the measured and o our cosine-weighted values:

- :func:`abs_error` ``= Σ w |o − m| / Σ w`` (the solid-angle mean absolute difference, 1/sr);
- :func:`rel_error` ``= Σ w |o − m| / Σ w |m|`` (the difference's share of the measured reflected
  light; robust where m is near 0, unlike a mean of per-direction ratios);
- :func:`scale_factor`: the scale k with ``m ≈ k · o`` that minimises ``Σ w |k o − m|`` (``"l1"``:
  the weighted median of the ratios ``m/o`` with weights ``w o``), the energy ratio
  ``Σ w m / Σ w o`` (``"energy"``) or the least-squares scale ``Σ w m o / Σ w o²`` (``"lsq"``).
  For a pure scale, ``m = k o``, all three are k.

Used by the comparison with a measured BRDF (:mod:`mi_svbrdf.eval.measured_comparison`) and the
direct fit of our model to one (:mod:`mi_svbrdf.optim.fit_measured`).

Examples:
    >>> import torch
    >>> g = conoscopic_grid((10.0, 45.0), n_theta=8, n_phi=16)
    >>> g.wi.shape, g.wo.shape, g.solid_angle.shape
    (torch.Size([2, 3]), torch.Size([8, 16, 3]), torch.Size([8, 16]))
    >>> ours = torch.rand(2, 8, 16, 3, dtype=torch.float64)
    >>> [round(float(k), 6) for k in scale_factor(1.7 * ours, ours, g.solid_angle.expand(2, 8, 16))]
    [1.7, 1.7, 1.7]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from mi_svbrdf.core.brdf_measured import direction

#: The thesis's incidences (degrees) of the conoscopic comparison.
DEFAULT_INCIDENCES: tuple[float, ...] = (10.0, 22.0, 45.0, 60.0, 69.0)
#: Scale factors: the one reported as ``factor`` is chosen among these.
FACTOR_METHODS = ("l1", "energy", "lsq")


# ----------------------------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class ConoscopicGrid:
    """Incidences and a polar grid of outgoing directions (cell centres).

    Attributes:
        incidences_deg: ``(I,)`` incidence angles θ_i in degrees; the light is at azimuth 0.
        theta_o: ``(T,)`` outgoing polar angles of the cell centres, radians.
        phi_o: ``(P,)`` outgoing azimuths of the cell centres, radians (π: the mirror direction).
        theta_max_deg: the grid's outer θ_o edge.
        slice_deg: ``(S,)`` signed angles of the in-plane slice: ω_o = (−sin s, 0, cos s), s > 0 on
            the mirror side (φ_o = 180°), s < 0 on the light's side (φ_o = 0).
    """

    incidences_deg: tuple[float, ...]
    theta_o: torch.Tensor
    phi_o: torch.Tensor
    theta_max_deg: float
    slice_deg: torch.Tensor

    @property
    def wi(self) -> torch.Tensor:
        """``(I, 3)`` directions towards the light."""
        inc = torch.deg2rad(torch.tensor(self.incidences_deg, dtype=torch.float64))
        return direction(inc, torch.zeros_like(inc))

    @property
    def wo(self) -> torch.Tensor:
        """``(T, P, 3)`` outgoing directions."""
        return direction(self.theta_o[:, None], self.phi_o[None, :])

    @property
    def solid_angle(self) -> torch.Tensor:
        """``(T, P)`` solid angle of each cell (sr)."""
        dt = math.radians(self.theta_max_deg) / self.theta_o.shape[0]
        band = torch.cos(self.theta_o - dt / 2) - torch.cos(self.theta_o + dt / 2)
        return (band * (2 * math.pi / self.phi_o.shape[0]))[:, None].expand(-1, self.phi_o.shape[0])

    @property
    def slice_wo(self) -> torch.Tensor:
        """``(S, 3)`` outgoing directions of the in-plane slice."""
        s = torch.deg2rad(self.slice_deg)
        return torch.stack([-torch.sin(s), torch.zeros_like(s), torch.cos(s)], -1)


def conoscopic_grid(incidences_deg: tuple[float, ...] | list[float] = DEFAULT_INCIDENCES, n_theta: int = 32,
                    n_phi: int = 72, theta_max_deg: float = 80.0, n_slice: int = 161) -> ConoscopicGrid:
    """The comparison's grid: ``n_theta`` × ``n_phi`` cells over θ_o ∈ [0, theta_max_deg], φ_o ∈ [0, 360°)."""
    inc = tuple(float(a) for a in incidences_deg)
    if not inc or any(not 0.0 <= a < 90.0 for a in inc):
        raise ValueError(f"incidences: expected angles in [0, 90) degrees, got {list(inc)}")
    if not 0.0 < theta_max_deg < 90.0:
        raise ValueError(f"theta_max_deg: expected a value in (0, 90), got {theta_max_deg}")
    if n_theta < 1 or n_phi < 1 or n_slice < 2:
        raise ValueError(f"expected n_theta, n_phi >= 1 and n_slice >= 2, got {n_theta}, {n_phi}, {n_slice}")
    dt = math.radians(theta_max_deg) / n_theta
    theta = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * dt
    phi = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * (2 * math.pi / n_phi)
    slice_deg = torch.linspace(-theta_max_deg, theta_max_deg, n_slice, dtype=torch.float64)
    return ConoscopicGrid(inc, theta, phi, float(theta_max_deg), slice_deg)


# ----------------------------------------------------------------------------------------------- figures


def _flat(x: torch.Tensor) -> torch.Tensor:
    return x.reshape(-1, x.shape[-1])


def scale_factor(measured: torch.Tensor, ours: torch.Tensor, weight: torch.Tensor, method: str = "l1") -> torch.Tensor:
    """The per-channel scale k with ``measured ≈ k · ours`` (:mod:`mi_svbrdf.core.conoscopic`).

    Args:
        measured: ``(..., 3)`` cosine-weighted measured values.
        ours: ``(..., 3)`` ours, same shape.
        weight: ``(...)`` solid angle × validity.
        method: ``"l1"`` (weighted median of m/o, minimises Σ w |k o − m|), ``"energy"``
            (Σ w m / Σ w o) or ``"lsq"`` (Σ w m o / Σ w o²).

    Returns:
        ``(3,)`` float64; 1 for a channel where ours is 0 wherever there is weight.
    """
    if method not in FACTOR_METHODS:
        raise ValueError(f"method: expected one of {FACTOR_METHODS}, got {method!r}")
    m, o = _flat(measured.to(torch.float64)), _flat(ours.to(torch.float64))
    w = weight.to(torch.float64).reshape(-1, 1).expand_as(m)
    if method == "energy":
        den = (w * o).sum(0)
        return torch.where(den > 0, (w * m).sum(0) / den.clamp_min(1e-300), torch.ones(3, dtype=torch.float64))
    if method == "lsq":
        den = (w * o * o).sum(0)
        return torch.where(den > 0, (w * m * o).sum(0) / den.clamp_min(1e-300), torch.ones(3, dtype=torch.float64))
    out = torch.ones(3, dtype=torch.float64)
    for c in range(3):
        keep = (w[:, c] > 0) & (o[:, c] > 0)
        if not keep.any():
            continue
        ratio = m[keep, c] / o[keep, c]
        wt = w[keep, c] * o[keep, c]
        order = torch.argsort(ratio)
        cum = torch.cumsum(wt[order], 0)
        k = int(torch.searchsorted(cum, 0.5 * cum[-1]))
        out[c] = ratio[order][min(k, ratio.shape[0] - 1)]
    return out


def abs_error(measured: torch.Tensor, ours: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``Σ w |o − m| / Σ w`` per channel, ``(3,)`` float64 (1/sr)."""
    m, o = _flat(measured.to(torch.float64)), _flat(ours.to(torch.float64))
    w = weight.to(torch.float64).reshape(-1, 1)
    return (w * (o - m).abs()).sum(0) / w.sum().clamp_min(1e-300)


def rel_error(measured: torch.Tensor, ours: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``Σ w |o − m| / Σ w |m|`` per channel, ``(3,)`` float64 (1 = 100 %)."""
    m, o = _flat(measured.to(torch.float64)), _flat(ours.to(torch.float64))
    w = weight.to(torch.float64).reshape(-1, 1)
    return (w * (o - m).abs()).sum(0) / (w * m.abs()).sum(0).clamp_min(1e-300)
