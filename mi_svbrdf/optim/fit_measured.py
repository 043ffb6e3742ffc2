"""Fit a homogeneous material of our model to a measured BRDF with the rendering loss (thesis ch. 6.1.1).

The measured BRDF renders the target of the rendering loss's configurations and our model the
prediction: the error that remains is what our model cannot represent of that material
(:func:`fit_measured`). The fit is scored on the comparison's conoscopic grid
(:mod:`mi_svbrdf.core.conoscopic`), as :mod:`mi_svbrdf.eval.measured_comparison` scores a
recovered material.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core.brdf_measured import MeasuredBRDF
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.conoscopic import ConoscopicGrid, abs_error, conoscopic_grid, rel_error
from mi_svbrdf.core.loss import LossPreset, resolve_preset
from mi_svbrdf.core.render import texel_positions


def _rgb(t: torch.Tensor, digits: int = 6) -> list[float]:
    return [float(f"{float(v):.{digits}g}") for v in t]


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
