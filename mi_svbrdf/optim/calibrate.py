"""Compare a recovered SVBRDF with a measured BRDF and calibrate it (thesis ch. 6.2), and fit our model
to a measured BRDF directly (ch. 6.1.1).

**What is compared.** An industrial gonioreflectometer measures one homogeneous region of a
sample; the network recovers per-texel maps. The maps are first reduced to one BRDF over a mask
(:func:`average_material`), two ways:

- ``"reflectance"`` (what is compared): the area-average of every texel's reflected light,
  ``f̄(ω_i, ω_o) = mean_t f_t(ω_i, ω_o) · c(n_t·ω_i) / ω_i.z`` — the BRDF an instrument sees on a
  flat sample whose texels have normals ``n_t`` (the texel renderer's shading, no shadowing);
- ``"parameters"``: the BRDF of the averaged parameters (mean normal renormalised, mean albedos
  and roughness), reported beside it as ``parameters_vs_reflectance``: how much the cheaper
  average differs (the same relative error as below, parameters against reflectance).

The parameter average uses every texel of the mask; the reflectance average ``max_texels`` of
them (all when fewer; else a seeded random subset: evaluating every texel in every direction
costs texels × directions BRDF evaluations).

**The quantity compared** is the cosine-weighted BRDF ``f · cos θ_o`` (1/sr), as the thesis's
conoscopic figures plot it: the reflected radiance per unit irradiance, which integrated over the
outgoing hemisphere gives the directional albedo. It is evaluated on a conoscopic grid
(:func:`conoscopic_grid`): per incidence θ_i (light at azimuth 0), cell centres of a polar grid
of outgoing directions (θ_o up to ``theta_max_deg``, φ_o over 360°; the mirror direction is at
φ_o = 180°), each cell weighted by its solid angle ``w`` and by whether the measurement has data
there. Over all incidences, every incidence counts once (same grid).

**Error figures** per colour channel, with m the measured and o our cosine-weighted values:

- ``abs_error = Σ w |o − m| / Σ w`` (the solid-angle mean absolute difference, 1/sr);
- ``rel_error = Σ w |o − m| / Σ w |m|`` (the difference's share of the measured reflected light;
  robust where m is near 0, unlike a mean of per-direction ratios);
- ``factor``: the scale k with ``m ≈ k · o`` that minimises ``Σ w |k o − m|``, i.e. the corrected
  absolute (and relative) error: the weighted median of the ratios ``m/o`` with weights ``w o``.
  Chosen so that the corrected errors are the best any single scale achieves (what is left is
  a difference of shape, not of scale), and because a median ignores the few directions where a
  slightly shifted highlight makes ratios explode. ``factor_alternatives`` also gives the
  energy ratio ``Σ w m / Σ w o`` (equal directional albedos) and the least-squares scale
  ``Σ w m o / Σ w o²`` (dominated by the highlight). For a pure scale, ``m = k o``, all three are k.
- ``*_corrected``: the same errors of ``k · o`` — one global k (default) or, with
  ``correction="per-incidence"``, each incidence's own k.

:func:`correct_material` applies a factor to a material's maps (what ``--apply`` writes), and
:func:`fit_measured` fits a homogeneous material of our model to a measured BRDF with the rendering
loss (the measured BRDF renders the target): the error that remains is what our model cannot
represent of that material.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.loss import LossPreset, resolve_preset
from mi_svbrdf.core.render import texel_positions
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.measured import MeasuredBRDF, direction, merl_table, write_merl
from mi_svbrdf.plugins.model import DISTRIBUTIONS

#: The thesis's incidences (degrees) of the conoscopic comparison.
DEFAULT_INCIDENCES: tuple[float, ...] = (10.0, 22.0, 45.0, 60.0, 69.0)
#: Ways to reduce the maps to one BRDF.
AVERAGING = ("reflectance", "parameters")
#: Scale factors: the one reported as ``factor`` is chosen among these.
FACTOR_METHODS = ("l1", "energy", "lsq")
#: Corrections applied for the ``*_corrected`` errors.
CORRECTIONS = ("global", "per-incidence")


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


# ----------------------------------------------------------------------------------------------- our BRDF


def model_brdf(texels: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, *, distribution: str = "ggx",
               dtype: torch.dtype = torch.float32, chunk_elements: int = 1 << 21) -> torch.Tensor:
    """The area-averaged BRDF of texels: ``mean_t f_t(ω_i, ω_o) · c(n_t·ω_i) / ω_i.z``.

    Args:
        texels: ``(N, 10)`` texel parameters in the maps' channel order (one texel: a homogeneous
            material; normals renormalised, roughness clipped to [1e-3, 1] as the renderer does).
        wi: ``(..., 3)`` unit directions towards the light, in the sample's frame.
        wo: ``(..., 3)`` unit directions towards the viewer, broadcastable with ``wi``.
        distribution: ``"ggx"`` (the thesis) or ``"beckmann"``.
        dtype: precision of the evaluation (float32: fast, ~1e-5 relative at a sharp highlight).
        chunk_elements: texel × direction pairs evaluated at once (memory bound).

    Returns:
        ``(..., 3)`` float64 BRDF (1/sr, no cosine); 0 where ω_i.z <= 0.
    """
    if texels.dim() != 2 or texels.shape[1] != M.NUM_CHANNELS:
        raise ValueError(f"texels: expected shape (N, 10), got {tuple(texels.shape)}")
    wi, wo = torch.broadcast_tensors(wi.to(torch.float64), wo.to(torch.float64))
    shape = wi.shape[:-1]
    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    t = texels.to(dtype)
    n = t[:, M.SLICES["normal"]]
    n = n / n.norm(dim=1, keepdim=True).clamp_min(1e-12)
    d, s = t[:, M.SLICES["diffuse"]], t[:, M.SLICES["specular"]]
    r = t[:, M.SLICES["roughness"]].clamp(brdf_torch.ROUGHNESS_MIN, 1.0)
    out = torch.empty(wi.shape[0], 3, dtype=torch.float64)
    step = max(1, chunk_elements // t.shape[0])
    for a in range(0, wi.shape[0], step):
        li = wi[a:a + step, None].to(dtype)
        lo = wo[a:a + step, None].to(dtype)
        f = brdf_torch.eval_brdf(n[None], li, lo, d[None], s[None], r[None], distribution=distribution, dim=-1)
        shade = (n[None] * li).sum(-1, keepdim=True).clamp_min(0.0) / li[..., 2:3].clamp_min(1e-6)
        out[a:a + step] = (f * shade).mean(1).to(torch.float64)
    out = torch.where(wi[:, 2:3] > 0, out, torch.zeros((), dtype=torch.float64))
    return out.reshape(*shape, 3)


@dataclass(frozen=True)
class AveragedMaterial:
    """A material reduced to what the comparison needs.

    Attributes:
        texels: ``(N, 10)`` float32 texels of the mask the reflectance average uses.
        n_mask: texels in the mask (N <= n_mask).
        parameters: ``(10,)`` the parameter average over the whole mask (normal renormalised).
        distribution: the material's BRDF model, ``"ggx"`` or ``"beckmann"`` (a material folder's
            :func:`~mi_svbrdf.io.material_io.read_distribution`).
    """

    texels: torch.Tensor
    n_mask: int
    parameters: torch.Tensor
    distribution: str = "ggx"

    def brdf(self, wi: torch.Tensor, wo: torch.Tensor, averaging: str = "reflectance") -> torch.Tensor:
        """The averaged BRDF ``(..., 3)`` (see the module docstring for the two ``averaging`` modes)."""
        if averaging not in AVERAGING:
            raise ValueError(f"averaging: expected one of {AVERAGING}, got {averaging!r}")
        texels = self.texels if averaging == "reflectance" else self.parameters[None]
        return model_brdf(texels, wi, wo, distribution=self.distribution)

    def parameter_dict(self) -> dict[str, Any]:
        """The parameter average by map name (lists of floats)."""
        p = self.parameters.tolist()
        return {name: [round(v, 6) for v in p[sl]] for name, sl in M.SLICES.items()}


def average_material(maps: torch.Tensor, mask: torch.Tensor | None = None, max_texels: int = 1024,
                     seed: int = 0, distribution: str = "ggx") -> AveragedMaterial:
    """Reduce a material's maps over a mask (see the module docstring).

    Args:
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` maps.
        mask: ``(H, W)`` bool (True: in the homogeneous region); None: the whole sample.
        max_texels: texels kept for the reflectance average (a seeded random subset when the mask
            holds more).
        seed: of that subset.
        distribution: the maps' BRDF model (``"ggx"`` or ``"beckmann"``).

    Returns:
        An :class:`AveragedMaterial`.
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if maps.dim() == 3:
        maps = maps[None]
    M.check_maps(maps)
    if maps.shape[0] != 1:
        raise ValueError(f"maps: expected one material (1, 10, H, W), got batch {maps.shape[0]}")
    h, w = maps.shape[2:]
    if mask is None:
        mask = torch.ones(h, w, dtype=torch.bool)
    if tuple(mask.shape) != (h, w):
        raise ValueError(f"mask: expected shape (H, W) = ({h}, {w}) like the maps, got {tuple(mask.shape)}")
    texels = maps[0].permute(1, 2, 0)[mask.to(torch.bool)].to(torch.float32)
    if texels.shape[0] == 0:
        raise ValueError("mask: expected at least one texel in the region, got an empty mask")
    n_mask = texels.shape[0]
    params = texels.to(torch.float64).mean(0)
    if n_mask > max_texels:
        pick = torch.randperm(n_mask, generator=torch.Generator().manual_seed(seed))[:max_texels]
        texels = texels[pick.sort().values]
    nrm = params[M.SLICES["normal"]]
    params[M.SLICES["normal"]] = nrm / nrm.norm().clamp_min(1e-12)
    return AveragedMaterial(texels, n_mask, params.to(torch.float32), distribution)


def read_mask(path: str | os.PathLike, height: int, width: int) -> torch.Tensor:
    """A mask image (PNG/EXR; white = the homogeneous region) as ``(H, W)`` bool: mean of channels > 0.5."""
    image, _ = read_image(path)
    if image.shape[:2] != (height, width):
        raise ValueError(f"{path}: expected a mask of {height}x{width} (H x W) like the material, "
                         f"got {image.shape[0]}x{image.shape[1]}")
    mask = torch.from_numpy(np.ascontiguousarray(image[..., :3].mean(-1) > 0.5))
    if not mask.any():
        raise ValueError(f"{path}: expected white (> 0.5) texels marking the region, got an all-black mask")
    return mask


# ----------------------------------------------------------------------------------------------- figures


def _flat(x: torch.Tensor) -> torch.Tensor:
    return x.reshape(-1, x.shape[-1])


def scale_factor(measured: torch.Tensor, ours: torch.Tensor, weight: torch.Tensor, method: str = "l1") -> torch.Tensor:
    """The per-channel scale k with ``measured ≈ k · ours`` (see the module docstring for ``method``).

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


# ----------------------------------------------------------------------------------------------- comparison


@dataclass
class Comparison:
    """A measured BRDF against our averaged material on a conoscopic grid (values are ``f · cos θ_o``).

    Attributes:
        grid: the :class:`ConoscopicGrid`.
        measured: ``(I, T, P, 3)`` measured values (0 where invalid).
        ours: ``(I, T, P, 3)`` ours, reflectance average.
        ours_parameters: ``(I, T, P, 3)`` ours, parameter average.
        valid: ``(I, T, P)`` the measurement has data there.
        weight: ``(I, T, P)`` solid angle × valid.
        slice_measured, slice_ours: ``(I, S, 3)`` the in-plane slice; ``slice_valid`` ``(I, S)``.
        factor_method, correction: as chosen (see the module docstring).
        factor: ``(3,)`` the global factor; ``factor_per_incidence`` ``(I, 3)``.
        material: the :class:`AveragedMaterial` compared.
        measured_name: the measurement's file or label.
    """

    grid: ConoscopicGrid
    measured: torch.Tensor
    ours: torch.Tensor
    ours_parameters: torch.Tensor
    valid: torch.Tensor
    weight: torch.Tensor
    slice_measured: torch.Tensor
    slice_ours: torch.Tensor
    slice_valid: torch.Tensor
    factor_method: str
    correction: str
    factor: torch.Tensor
    factor_per_incidence: torch.Tensor
    material: AveragedMaterial
    measured_name: str
    extra: dict[str, Any] = field(default_factory=dict)

    def scale(self, correction: str | None = None) -> torch.Tensor:
        """``(I, 1, 1, 3)`` the factor each incidence is corrected with."""
        correction = correction or self.correction
        if correction == "global":
            return self.factor.view(1, 1, 1, 3).expand(len(self.grid.incidences_deg), 1, 1, 3)
        return self.factor_per_incidence.view(-1, 1, 1, 3)

    def corrected(self, correction: str | None = None) -> torch.Tensor:
        """``(I, T, P, 3)`` ours times the correction's factors."""
        return self.ours * self.scale(correction)

    def slice_corrected(self, correction: str | None = None) -> torch.Tensor:
        """``(I, S, 3)`` the in-plane slice of ours, corrected."""
        return self.slice_ours * self.scale(correction)[:, 0]

    def figures(self) -> dict[str, Any]:
        """The report's numbers (RGB lists), see :func:`comparison_summary`."""
        return comparison_summary(self)


def compare(measured: MeasuredBRDF, material: AveragedMaterial, *, grid: ConoscopicGrid | None = None,
            factor_method: str = "l1", correction: str = "global") -> Comparison:
    """Evaluate both BRDFs on the grid and compute the factors (see the module docstring).

    Args:
        measured: the measured BRDF (:mod:`mi_svbrdf.io.measured`).
        material: our material, reduced by :func:`average_material`.
        grid: the conoscopic grid (default :func:`conoscopic_grid` at the thesis's incidences).
        factor_method: ``"l1"`` (default), ``"energy"`` or ``"lsq"``.
        correction: ``"global"`` (default) or ``"per-incidence"``: which factors the corrected
            errors use.

    Returns:
        A :class:`Comparison`.

    Raises:
        ValueError: no grid direction has measured data.
    """
    if factor_method not in FACTOR_METHODS:
        raise ValueError(f"factor_method: expected one of {FACTOR_METHODS}, got {factor_method!r}")
    if correction not in CORRECTIONS:
        raise ValueError(f"correction: expected one of {CORRECTIONS}, got {correction!r}")
    grid = grid or conoscopic_grid()
    n_inc = len(grid.incidences_deg)
    wi = grid.wi.view(n_inc, 1, 1, 3)
    wo = grid.wo[None]
    cos_o = wo[..., 2:3]
    m, valid = measured.lookup(wi, wo)
    m = torch.where(valid[..., None], m, torch.zeros((), dtype=torch.float64)) * cos_o
    ours = material.brdf(wi, wo, "reflectance") * cos_o
    ours_p = material.brdf(wi, wo, "parameters") * cos_o
    if not valid.any():
        raise ValueError(f"{measured.name}: expected measured data on the comparison grid "
                         f"(incidences {list(grid.incidences_deg)}), got none")
    weight = grid.solid_angle[None] * valid
    s_wi = grid.wi.view(n_inc, 1, 3)
    s_wo = grid.slice_wo[None]
    s_m, s_valid = measured.lookup(s_wi, s_wo)
    s_cos = s_wo[..., 2:3]
    s_m = torch.where(s_valid[..., None], s_m, torch.zeros((), dtype=torch.float64)) * s_cos
    s_o = material.brdf(s_wi, s_wo, "reflectance") * s_cos
    factor = scale_factor(m, ours, weight, factor_method)
    per_inc = torch.stack([scale_factor(m[i], ours[i], weight[i], factor_method) for i in range(n_inc)])
    return Comparison(grid, m, ours, ours_p, valid, weight, s_m, s_o, s_valid, factor_method, correction,
                      factor, per_inc, material, measured.name)


def _rgb(t: torch.Tensor, digits: int = 6) -> list[float]:
    return [float(f"{float(v):.{digits}g}") for v in t]


def comparison_summary(cmp: Comparison) -> dict[str, Any]:
    """The numbers of a comparison as a JSON-ready dict.

    Keys ``factor``, ``abs_error``, ``rel_error``, ``abs_error_corrected``, ``rel_error_corrected``
    (each RGB), ``distribution`` (the BRDF model of the maps compared, ``"ggx"`` or ``"beckmann"``),
    ``factor_method``, ``correction``, ``factor_alternatives``, ``factor_per_incidence``,
    ``per_incidence`` (per incidence: its factor and errors before and after each correction),
    ``averaging`` (the parameter average and how far it is from the reflectance average),
    ``valid_fraction`` and ``definitions``.
    """
    m, o, w = cmp.measured, cmp.ours, cmp.weight
    corr = cmp.corrected()
    out: dict[str, Any] = {
        "factor": _rgb(cmp.factor),
        "abs_error": _rgb(abs_error(m, o, w)),
        "rel_error": _rgb(rel_error(m, o, w)),
        "abs_error_corrected": _rgb(abs_error(m, corr, w)),
        "rel_error_corrected": _rgb(rel_error(m, corr, w)),
        "distribution": cmp.material.distribution,
        "factor_method": cmp.factor_method,
        "correction": cmp.correction,
        "factor_alternatives": {meth: _rgb(scale_factor(m, o, w, meth)) for meth in FACTOR_METHODS},
        "factor_per_incidence": [_rgb(f) for f in cmp.factor_per_incidence],
        "incidences_deg": list(cmp.grid.incidences_deg),
        "valid_fraction": round(float(cmp.valid.double().mean()), 6),
    }
    glob, own = cmp.corrected("global"), cmp.corrected("per-incidence")
    for name, corrected in (("global", glob), ("per_incidence", own)):
        out[f"abs_error_corrected_{name}"] = _rgb(abs_error(m, corrected, w))
        out[f"rel_error_corrected_{name}"] = _rgb(rel_error(m, corrected, w))
    out["per_incidence"] = [{
        "theta_i": cmp.grid.incidences_deg[i],
        "factor": _rgb(cmp.factor_per_incidence[i]),
        "abs_error": _rgb(abs_error(m[i], o[i], w[i])),
        "rel_error": _rgb(rel_error(m[i], o[i], w[i])),
        "abs_error_corrected_global": _rgb(abs_error(m[i], glob[i], w[i])),
        "rel_error_corrected_global": _rgb(rel_error(m[i], glob[i], w[i])),
        "abs_error_corrected_own": _rgb(abs_error(m[i], own[i], w[i])),
        "rel_error_corrected_own": _rgb(rel_error(m[i], own[i], w[i])),
        "valid_fraction": round(float(cmp.valid[i].double().mean()), 6),
    } for i in range(len(cmp.grid.incidences_deg))]
    op = cmp.ours_parameters
    k_p = scale_factor(m, op, w, cmp.factor_method)
    out["averaging"] = {
        "compared": "reflectance",
        "texels_used": int(cmp.material.texels.shape[0]),
        "texels_in_mask": int(cmp.material.n_mask),
        "parameter_average": cmp.material.parameter_dict(),
        "parameters_vs_reflectance": _rgb(rel_error(o, op, w)),
        "with_parameter_average": {"factor": _rgb(k_p), "rel_error": _rgb(rel_error(m, op, w)),
                                   "rel_error_corrected": _rgb(rel_error(m, op * k_p, w))},
    }
    g = cmp.grid
    out["grid"] = {"n_theta": int(g.theta_o.shape[0]), "n_phi": int(g.phi_o.shape[0]),
                   "theta_max_deg": g.theta_max_deg, "mirror_azimuth_deg": 180.0}
    out["definitions"] = {
        "value": "f(wi, wo) * cos(theta_o): the cosine-weighted BRDF (1/sr), per RGB channel",
        "abs_error": "sum w |o - m| / sum w, w = cell solid angle where the measurement has data",
        "rel_error": "sum w |o - m| / sum w |m|",
        "factor": {"l1": "weighted median of m/o with weights w*o: minimises sum w |k o - m|",
                   "energy": "sum w m / sum w o (equal directional albedo)",
                   "lsq": "sum w m o / sum w o^2"}[cmp.factor_method] + "; measured ~ factor * ours",
        "corrected": "errors of factor * ours (global factor, or each incidence's own with "
                     "correction = per-incidence)",
        "ours": "reflectance average over the mask: mean_t f_t(wi, wo) c(n_t.wi) / wi.z",
    }
    out.update(cmp.extra)
    return out


# ----------------------------------------------------------------------------------------------- correction


def correct_material(maps: torch.Tensor, factor: torch.Tensor | list[float]) -> tuple[torch.Tensor, dict[str, Any]]:
    """Scale a material's BRDF by a per-channel factor k, as far as its parameters allow.

    The specular albedo becomes ``s' = clip(k s, 0, 1)`` and the diffuse albedo
    ``d' = clip(k d (1 − s) / (1 − s'), 0, 1)``, so the diffuse term ``d (1 − s)/π`` is scaled by k
    exactly and the specular term ``F G D / 4`` by k up to Fresnel's grazing part
    (``(1 − s) 2^(…)`` becomes ``(1 − k s) 2^(…)`` instead of ``k (1 − s) 2^(…)``). Clipped texels
    cannot take the full factor; re-comparing the corrected material measures what is left.

    Args:
        maps: ``(1, 10, H, W)`` maps.
        factor: ``(3,)`` per-channel k > 0.

    Returns:
        ``(maps', info)``: the corrected maps and ``{"factor", "clipped_diffuse", "clipped_specular"}``
        (fractions of texel channels that hit 1).
    """
    M.check_maps(maps)
    k = torch.as_tensor(factor, dtype=maps.dtype).reshape(-1)
    if k.shape != (3,) or not torch.isfinite(k).all() or (k <= 0).any():
        raise ValueError(f"factor: expected three positive numbers, got {k.tolist()}")
    k = k.view(1, 3, 1, 1)
    d, s = M.diffuse(maps), M.specular(maps)
    s_new_raw = k * s
    s_new = s_new_raw.clamp(0.0, 1.0)
    d_new_raw = k * d * (1.0 - s) / (1.0 - s_new).clamp_min(1e-6)
    d_new = d_new_raw.clamp(0.0, 1.0)
    out = M.make_maps(M.normal(maps), d_new, M.roughness(maps), s_new)
    info = {"factor": _rgb(k.view(3)), "clipped_diffuse": round(float((d_new_raw > 1.0).double().mean()), 6),
            "clipped_specular": round(float((s_new_raw > 1.0).double().mean()), 6)}
    return out, info


def write_synthetic_merl(maps: torch.Tensor, path: str | os.PathLike, scale: float | tuple[float, ...] = 1.0,
                         mask: torch.Tensor | None = None, distribution: str = "ggx") -> torch.Tensor:
    """Write a MERL file "measured" from a material: the BRDF of its averaged parameters times ``scale``.

    For trying ``mi-svbrdf calibrate`` without a measurement, and for its tests: comparing the same
    material with the file finds ``factor ≈ scale`` (exactly for a homogeneous material with
    normal (0, 0, 1); otherwise the reflectance average differs from the parameter average).

    Args:
        maps: ``(1, 10, H, W)`` maps.
        path: the ``.binary`` file written.
        scale: one number or RGB: measured = scale × ours.
        mask: ``(H, W)`` region averaged (None: all).
        distribution: ``"ggx"`` or ``"beckmann"`` (a model ours cannot match exactly).

    Returns:
        ``(3, 90, 90, 180)`` the table written (BRDF units, -1 below the horizon).
    """
    k = torch.as_tensor(scale, dtype=torch.float64).reshape(-1).expand(3)
    params = average_material(maps, mask, max_texels=1).parameters[None]
    table = merl_table(lambda wi, wo: model_brdf(params, wi, wo, distribution=distribution, dtype=torch.float64) * k)
    write_merl(path, table)
    return table


# ----------------------------------------------------------------------------------------------- direct fit


@dataclass
class DirectFit:
    """Our model fitted to a measured BRDF (:func:`fit_measured`).

    Attributes:
        maps: ``(1, 10, 1, 1)`` the fitted homogeneous material (normal (0, 0, 1)).
        loss: the rendering loss on held-out configurations (a different draw).
        loss_train: the rendering loss on the configurations fitted.
        rel_error, abs_error: ``(3,)`` the fit against the measurement on the conoscopic grid (no factor).
        seconds: fitting time; steps: Adam steps of the kept start.
        valid_fraction: share of the loss's direction pairs where the measurement has data.
    """

    maps: torch.Tensor
    loss: float
    loss_train: float
    rel_error: torch.Tensor
    abs_error: torch.Tensor
    seconds: float
    steps: int
    valid_fraction: float

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers."""
        p = self.maps[0, :, 0, 0].tolist()
        return {"diffuse": [round(v, 5) for v in p[3:6]], "roughness": round(p[6], 5),
                "specular": [round(v, 5) for v in p[7:10]], "rendering_loss": round(self.loss, 6),
                "rendering_loss_train": round(self.loss_train, 6), "rel_error": _rgb(self.rel_error),
                "abs_error": _rgb(self.abs_error), "seconds": round(self.seconds, 2), "steps": self.steps,
                "valid_fraction": round(self.valid_fraction, 6)}


def _loss_directions(batches: int, texels: int, cfg: LossPreset, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(wl, wv)``, each ``(B, K, H, W, 3)`` unnormalised, of the loss's configurations over a texel grid."""
    conf = sample_configurations(batches, cfg.n_diffuse, cfg.n_specular, r1_max=cfg.r1_max,
                                 generator=torch.Generator().manual_seed(seed))
    p = texel_positions(texels, texels, dtype=torch.float64).permute(1, 2, 0)  # (H, W, 3)

    def towards(q: torch.Tensor) -> torch.Tensor:
        q = q.to(torch.float64)[:, :, None, None, :]
        return q[..., :3] - q[..., 3:4] * p

    return towards(conf.light), towards(conf.view)


class _Target:
    """The measured BRDF rendered as the rendering loss renders (normal z, no fall-off, ω_L.z division)."""

    def __init__(self, measured: MeasuredBRDF, wl: torch.Tensor, wv: torch.Tensor, cfg: LossPreset) -> None:
        self.wl = wl / wl.norm(dim=-1, keepdim=True)
        self.wv = wv / wv.norm(dim=-1, keepdim=True)
        f, self.valid = measured.lookup(self.wl, self.wv)
        self.light = math.pi * cfg.intensity * self.wl[..., 2:3].clamp_min(0.0) / self.wl[..., 2:3].clamp_min(1e-3)
        self.radiance = f * self.light
        self.eps = cfg.eps
        self.log_target = torch.log(self.radiance.clamp_min(0.0) + self.eps)

    def loss(self, d: torch.Tensor, s: torch.Tensor, r: torch.Tensor, distribution: str) -> torch.Tensor:
        n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        f = brdf_torch.eval_brdf(n, self.wl, self.wv, d, s, r, distribution=distribution, dim=-1)
        err = (torch.log((f * self.light).clamp_min(0.0) + self.eps) - self.log_target).abs()
        v = self.valid[..., None].to(err.dtype)
        return (err * v).sum() / (3.0 * v.sum()).clamp_min(1.0)


def fit_measured(measured: MeasuredBRDF, *, preset: str | LossPreset = "2018", batches: int = 16, texels: int = 6,
                 steps: int = 300, start_steps: int = 40, starts: tuple[float, ...] = (0.2, 0.45, 0.7),
                 lr: float = 0.05, seed: int = 0, distribution: str = "ggx",
                 grid: ConoscopicGrid | None = None) -> DirectFit:
    """Fit a homogeneous material of our model to a measured BRDF with the rendering loss (ch. 6.1.1).

    The loss's configurations (``batches`` draws of the preset's 3 far-field and 6 near-field
    mirror configurations, over a ``texels`` × ``texels`` grid of the plane, so the near-field ones
    reach many direction pairs) are rendered with the measured BRDF as the target and our model as
    the prediction, both with the loss's light model ``f · π · I · c(n·ω_L) / max(ω_L.z, 1e-3)``
    and normal (0, 0, 1); the loss is the preset's ``mean |log(R_m + ε) − log(R + ε)|`` over the
    direction pairs where the measurement has data. Diffuse and specular albedos (sigmoids) and
    roughness (``1e-3 + 0.999 sigmoid``) are fitted by Adam: each roughness in ``starts`` for
    ``start_steps`` (a low start alone stalls: the lobe's gradient vanishes as r -> 0), then the
    best start until ``steps`` with the learning rate decaying (cosine) to 1 %.

    Args:
        measured: the target BRDF.
        preset: the loss preset (``"2018"``: I = 1, ε = 0.01).
        batches: configuration draws fitted (each 9 configurations).
        texels: the texel grid's side.
        steps: Adam steps of the kept start, start steps included.
        start_steps: steps of each start.
        starts: initial roughness values.
        lr: Adam's learning rate.
        seed: configurations fitted (the held-out loss uses ``seed + 1``).
        distribution: our model's microfacet distribution (``"ggx"``: the thesis).
        grid: for the fit's conoscopic errors (default :func:`conoscopic_grid`).

    Returns:
        A :class:`DirectFit`.
    """
    t0 = time.perf_counter()
    cfg = resolve_preset(preset)
    train = _Target(measured, *_loss_directions(batches, texels, cfg, seed), cfg)
    held = _Target(measured, *_loss_directions(batches, texels, cfg, seed + 1), cfg)
    if not train.valid.any():
        raise ValueError(f"{measured.name}: expected measured data at the rendering loss's directions, got none")

    def unpack(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return torch.sigmoid(x[0:3]), torch.sigmoid(x[3:6]), 1e-3 + 0.999 * torch.sigmoid(x[6:7])

    def logit(v: float) -> float:
        return math.log(v / (1.0 - v))

    runs = []
    for r0 in starts:
        x = torch.tensor([logit(0.3)] * 3 + [logit(0.05)] * 3 + [logit((r0 - 1e-3) / 0.999)],
                         dtype=torch.float64, requires_grad=True)
        opt = torch.optim.Adam([x], lr=lr)
        for _ in range(start_steps):
            opt.zero_grad()
            loss = train.loss(*unpack(x), distribution)
            loss.backward()
            opt.step()
        runs.append((float(loss.detach()), x, opt))
    _, x, opt = min(runs, key=lambda run: run[0])
    rest = max(0, steps - start_steps)
    for i in range(rest):
        for group in opt.param_groups:  # cosine decay to 1 % of lr: Adam settles instead of hovering
            group["lr"] = lr * (0.01 + 0.99 * 0.5 * (1.0 + math.cos(math.pi * i / max(1, rest))))
        opt.zero_grad()
        loss = train.loss(*unpack(x), distribution)
        loss.backward()
        opt.step()
    with torch.no_grad():
        d, s, r = unpack(x)
        loss_train = float(train.loss(d, s, r, distribution))
        loss_held = float(held.loss(d, s, r, distribution))
        maps = torch.cat([torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), d, r, s]).view(1, 10, 1, 1)
        g = grid or conoscopic_grid()
        n_inc = len(g.incidences_deg)
        wi, wo = g.wi.view(n_inc, 1, 1, 3), g.wo[None]
        m, valid = measured.lookup(wi, wo)
        n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        ours = brdf_torch.eval_brdf(n, wi, wo, d, s, r, distribution=distribution, dim=-1)
        cos_o = wo[..., 2:3]
        m = torch.where(valid[..., None], m, torch.zeros((), dtype=torch.float64)) * cos_o
        w = g.solid_angle[None] * valid
        rel, ab = rel_error(m, ours * cos_o, w), abs_error(m, ours * cos_o, w)
    return DirectFit(maps.to(torch.float32), loss_held, loss_train, rel, ab, time.perf_counter() - t0,
                     max(steps, start_steps), float(train.valid.double().mean()))
