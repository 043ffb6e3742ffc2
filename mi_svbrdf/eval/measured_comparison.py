"""Compare a recovered SVBRDF with a measured BRDF and calibrate it (thesis ch. 6.2).

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

:func:`correct_material` applies a factor to a material's maps (what ``--apply`` writes). The grid
and the error figures are :mod:`mi_svbrdf.core.conoscopic`'s; the direct fit of our model to a
measured BRDF is :mod:`mi_svbrdf.optim.fit_measured`; the report (figures, Markdown) is
:mod:`mi_svbrdf.eval.measured_report`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.brdf_measured import MeasuredBRDF, merl_table
from mi_svbrdf.core.conoscopic import (
    FACTOR_METHODS,
    ConoscopicGrid,
    abs_error,
    conoscopic_grid,
    rel_error,
    scale_factor,
)
from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.measured import write_merl
from mi_svbrdf.plugins.model import DISTRIBUTIONS

#: Ways to reduce the maps to one BRDF.
AVERAGING = ("reflectance", "parameters")
#: Corrections applied for the ``*_corrected`` errors.
CORRECTIONS = ("global", "per-incidence")


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


# ----------------------------------------------------------------------------------------------- comparison


@dataclass
class MeasuredComparison:
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
            factor_method: str = "l1", correction: str = "global") -> MeasuredComparison:
    """Evaluate both BRDFs on the grid and compute the factors (see the module docstring).

    Args:
        measured: the measured BRDF (:mod:`mi_svbrdf.io.measured`).
        material: our material, reduced by :func:`average_material`.
        grid: the conoscopic grid (default :func:`conoscopic_grid` at the thesis's incidences).
        factor_method: ``"l1"`` (default), ``"energy"`` or ``"lsq"``.
        correction: ``"global"`` (default) or ``"per-incidence"``: which factors the corrected
            errors use.

    Returns:
        A :class:`MeasuredComparison`.

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
    return MeasuredComparison(grid, m, ours, ours_p, valid, weight, s_m, s_o, s_valid, factor_method, correction,
                      factor, per_inc, material, measured.name)


def _rgb(t: torch.Tensor, digits: int = 6) -> list[float]:
    return [float(f"{float(v):.{digits}g}") for v in t]


def comparison_summary(cmp: MeasuredComparison) -> dict[str, Any]:
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
