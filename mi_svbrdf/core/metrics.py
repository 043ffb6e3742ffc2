"""Evaluation metrics of recovered SVBRDFs (thesis Table 3.1 and Fig. 4.4), pure functions over maps.

Every function takes ``pred`` and ``gt`` maps ``(B, 10, H, W)`` (:mod:`mi_svbrdf.core.maps`) and
returns one value per sample ``(B,)`` (per map: a dict of them); :func:`evaluate_maps`
averages everything over the batch into one flat dict with the stable keys :data:`METRIC_KEYS`.

**Domains** (what makes our figures comparable with the thesis's, which are computed on its
[0, 1] PNG maps):

* normals as stored in images, ``(n + 1) / 2`` (so the error is half the error of the unit
  vectors): the thesis's normal RMSE (0.035) is on those PNGs;
* diffuse, specular and roughness linear, as stored (the thesis's albedos are linear as stored);
* re-renderings as displayed: linear radiance clipped to [0, 1] and encoded ``x^(1/2.2)`` (the
  authors' gamma), the image people look at (thesis: re-render error 0.083 on rendered images
  in [0, 1]).

**Re-rendering lights** (:func:`eval_lights`): K point lights with ``1/d^2`` fall-off, no cone,
each seen from its own viewer, drawn once from a dedicated seed (not the training samplers'
stream). We use the capture model (a physical point light, like the flash photos) rather
than the loss's (no fall-off, ``wl.z`` division), which is a training device rather than an
image anybody sees. The intensity of each light is ``d^2`` (d its distance to the sample
centre), so a white Lambertian texel facing a light has radiance ~``cos``: images are exposed
like the photos, highlights clip.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core import maps as M, metrics
    >>> gt = M.constant_maps(1, 8, 8, diffuse=0.5)
    >>> pred = M.constant_maps(1, 8, 8, diffuse=0.3)
    >>> round(float(metrics.map_rmse(pred, gt)["diffuse"][0]), 6)
    0.2
    >>> round(float(metrics.scaled_albedo_rmse(pred, gt)["diffuse"][0]), 6)
    0.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.maps import MAP_NAMES, SLICES, check_maps
from mi_svbrdf.core.render import Backend, render
from mi_svbrdf.core.ssim import ssim

#: Seed of the default evaluation lights (not a training seed: those are 0-999).
EVAL_LIGHTS_SEED = 2026_1123
#: Keys of :func:`evaluate_maps`, in table order.
METRIC_KEYS: tuple[str, ...] = (
    "rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular",
    "rmse_diffuse_scaled", "rmse_specular_scaled", "rmse_render",
    "ssim_normal", "ssim_diffuse", "ssim_roughness", "ssim_specular", "ssim_render",
)
SCALED_MAPS = ("diffuse", "specular")


def _check_pair(pred: torch.Tensor, gt: torch.Tensor) -> None:
    check_maps(pred, "pred")
    check_maps(gt, "gt")
    if pred.shape != gt.shape:
        raise ValueError(f"pred: expected the shape of gt {tuple(gt.shape)}, got {tuple(pred.shape)}")


def encoded(maps: torch.Tensor, name: str) -> torch.Tensor:
    """Map ``name`` of ``maps (B, 10, H, W)`` in the metric domain: ``(B, C, H, W)``, normals as (n + 1) / 2."""
    x = maps[:, SLICES[name]].float()
    return (x + 1.0) / 2.0 if name == "normal" else x


def _rmse(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a - b).square().flatten(1).mean(dim=1).sqrt()


def map_rmse(pred: torch.Tensor, gt: torch.Tensor) -> dict[str, torch.Tensor]:
    """RMSE of each map per sample.

    Args:
        pred: ``(B, 10, H, W)`` recovered maps.
        gt: ``(B, 10, H, W)`` ground truth.

    Returns:
        ``{"normal", "diffuse", "roughness", "specular"}`` -> ``(B,)``: root of the mean over
        channels and texels of the squared difference; normals as ``(n + 1) / 2`` (the thesis's
        PNG domain; half the RMSE of the unit vectors), the others linear.
    """
    _check_pair(pred, gt)
    return {k: _rmse(encoded(pred, k), encoded(gt, k)) for k in MAP_NAMES}


def scaled_albedo_rmse(pred: torch.Tensor, gt: torch.Tensor) -> dict[str, torch.Tensor]:
    """Albedo RMSE after the best global scale (albedo scale is ambiguous in a photo).

    Per sample and map, the least-squares scale ``k = <p, g> / <p, p>`` (0 when p = 0) over
    all channels and texels, then ``RMSE(k p, g)``; 0 for ``p = c g``, c > 0.

    Args:
        pred: ``(B, 10, H, W)``.
        gt: ``(B, 10, H, W)``.

    Returns:
        ``{"diffuse", "specular"}`` -> ``(B,)``.
    """
    _check_pair(pred, gt)
    out = {}
    for name in SCALED_MAPS:
        p, g = encoded(pred, name).flatten(1).double(), encoded(gt, name).flatten(1).double()
        pp = p.square().sum(dim=1)
        k = torch.where(pp > 0, (p * g).sum(dim=1) / pp.clamp_min(1e-300), torch.zeros_like(pp))
        out[name] = _rmse(k[:, None] * p, g).float()
    return out


def map_ssim(pred: torch.Tensor, gt: torch.Tensor) -> dict[str, torch.Tensor]:
    """SSIM of each map per sample (:func:`mi_svbrdf.core.ssim.ssim`, data range 1, maps as in :func:`map_rmse`).

    Returns:
        ``{"normal", "diffuse", "roughness", "specular"}`` -> ``(B,)``, 1 for identical maps.
    """
    _check_pair(pred, gt)
    return {k: ssim(encoded(pred, k), encoded(gt, k)) for k in MAP_NAMES}


@dataclass(frozen=True)
class EvalLights:
    """K point lights, each with its own viewer, for re-rendering (see the module docstring)."""

    light: torch.Tensor  #: (K, 3) light positions
    view: torch.Tensor  #: (K, 3) viewer positions
    intensity: torch.Tensor  #: (K, 3) RGB intensity (d^2: unit irradiance at the centre, normal incidence)

    @property
    def count(self) -> int:
        """K."""
        return self.light.shape[0]


def _directions(u: torch.Tensor, min_elevation: float) -> torch.Tensor:
    """Cosine-weighted unit directions ``(K, 3)`` above ``min_elevation`` degrees from uniforms ``(K, 2)``."""
    r = (u[:, 0] * math.cos(math.radians(min_elevation)) ** 2).sqrt()
    phi = 2.0 * math.pi * u[:, 1]
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), (1.0 - r * r).clamp_min(0.0).sqrt()], dim=-1)


def eval_lights(count: int = 9, seed: int = EVAL_LIGHTS_SEED) -> EvalLights:
    """A fixed set of held-out point lights and views.

    Light ``k`` comes from a cosine-weighted direction above 15 degrees of elevation at a
    distance log-uniform in [1.5, 4] half sample widths; its viewer from an independent such
    direction at distance 2.75 (the authors' camera), except every third light (k = 0, 3, ...),
    which is flash-like: the viewer beside the light (highlights). All draws come from
    ``torch.Generator().manual_seed(seed)`` in that order, so the set is a pure function of
    ``(count, seed)``, and a smaller count gives a prefix of a larger one (per-light draws).

    Args:
        count: K >= 1.
        seed: the generator seed (default :data:`EVAL_LIGHTS_SEED`).
    """
    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count: expected an int >= 1, got {count!r}")
    gen = torch.Generator().manual_seed(seed)
    lights, views = [], []
    for k in range(count):
        u = torch.rand(5, generator=gen, dtype=torch.float64)
        wl = _directions(u[None, 0:2], 15.0)[0]
        wv = _directions(u[None, 2:4], 15.0)[0]
        dist = math.exp(math.log(1.5) + float(u[4]) * (math.log(4.0) - math.log(1.5)))
        lights.append(wl * dist)
        views.append(wl * 2.75 if k % 3 == 0 else wv * 2.75)
    light = torch.stack(lights).float()
    view = torch.stack(views).float()
    intensity = light.square().sum(dim=-1, keepdim=True).expand(count, 3).contiguous()
    return EvalLights(light=light, view=view, intensity=intensity)


def rerender(maps: torch.Tensor, lights: EvalLights, *, backend: Backend = "mitsuba",
             distribution: str = "ggx") -> torch.Tensor:
    """Linear radiance of ``maps (B, 10, H, W)`` under each evaluation light: ``(B, K, 3, H, W)``, with the
    BRDF model ``distribution`` (``"ggx"``: the thesis's; ``"beckmann"``)."""
    check_maps(maps)
    b, k = maps.shape[0], lights.count

    def per_batch(t: torch.Tensor) -> torch.Tensor:
        return t.to(maps.dtype)[None].expand(b, k, 3)

    return render(maps, per_batch(lights.light), per_batch(lights.view), intensity=per_batch(lights.intensity),
                  distance_falloff=True, distribution=distribution, backend=backend)


def display(radiance: torch.Tensor) -> torch.Tensor:
    """What people look at: ``clip(x, 0, 1)^(1/2.2)``, same shape."""
    return gamma_encode(radiance)


def _rerender_pair(pred: torch.Tensor, gt: torch.Tensor, lights: EvalLights, backend: Backend, distribution: str,
                   gt_distribution: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear re-renderings of ``pred`` (with ``distribution``) and ``gt`` (with ``gt_distribution``), checked as a pair."""
    _check_pair(pred, gt)
    return (rerender(pred, lights, backend=backend, distribution=distribution),
            rerender(gt, lights, backend=backend, distribution=gt_distribution))


def rerender_rmse(pred: torch.Tensor, gt: torch.Tensor, lights: EvalLights, *,
                  backend: Backend = "mitsuba", distribution: str = "ggx",
                  gt_distribution: str = "ggx") -> torch.Tensor:
    """RMSE ``(B,)`` of the displayed re-renderings (:func:`display` of :func:`rerender`) over lights, pixels, channels;
    ``pred`` rendered with ``distribution``, ``gt`` with ``gt_distribution`` (each material with its own model)."""
    a, b = _rerender_pair(pred, gt, lights, backend, distribution, gt_distribution)
    return _rmse(display(a), display(b))


def rerender_rmse_scaled(pred: torch.Tensor, gt: torch.Tensor, lights: EvalLights, *,
                         backend: Backend = "mitsuba", distribution: str = "ggx",
                         gt_distribution: str = "ggx") -> torch.Tensor:
    """:func:`rerender_rmse` after the best per-channel exposure of ``pred``'s re-renderings: ``(B,)``.

    Uncalibrated photos cannot tell an albedo from the light's intensity, nor a colour from the
    white balance (a photo's value is ``I_c`` times the material's response), so a method that
    sees no calibration recovers a material up to one RGB exposure. Per sample and channel ``c``,
    ``k_c = sum(gt radiance_c) / sum(pred radiance_c)`` over lights and texels (linear, before the
    display's clip), then the displayed RMSE of ``k x`` ``pred``'s re-renderings against ``gt``'s:
    0 when ``pred`` renders as ``gt`` under lights of another RGB intensity. (Scaling both albedos
    by ``k`` scales the radiance by ``k`` except in Fresnel's grazing term, ``(1 - F0)`` of it.)

    Examples:
        >>> from mi_svbrdf.core import maps as M
        >>> gt = M.constant_maps(1, 8, 8, diffuse=0.5, specular=0.04)
        >>> pred = M.constant_maps(1, 8, 8, diffuse=0.25, specular=0.02)
        >>> lights = eval_lights()
        >>> scaled = float(rerender_rmse_scaled(pred, gt, lights, backend="torch")[0])
        >>> plain = float(rerender_rmse(pred, gt, lights, backend="torch")[0])
        >>> round(plain, 3), round(scaled, 3)
        (0.149, 0.015)
    """
    a, b = _rerender_pair(pred, gt, lights, backend, distribution, gt_distribution)
    sa, sb = a.double().sum(dim=(1, 3, 4), keepdim=True), b.double().sum(dim=(1, 3, 4), keepdim=True)
    k = torch.where(sa > 0, sb / sa.clamp_min(1e-300), torch.ones_like(sa)).to(a.dtype)
    return _rmse(display(a * k), display(b))


def angle_deg(a: torch.Tensor | list[float], b: torch.Tensor | list[float]) -> float:
    """Angle in degrees between two 3-vectors' directions (e.g. an estimated light's and the true one's, both
    seen from the sample centre); their lengths do not matter.

    Examples:
        >>> round(angle_deg([0.0, 0.0, 2.0], [1.0, 0.0, 1.0]), 6)
        45.0
    """
    u, v = torch.as_tensor(a, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64)
    cos = float((u @ v) / (u.norm() * v.norm()))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def rerender_ssim(pred: torch.Tensor, gt: torch.Tensor, lights: EvalLights, *,
                  backend: Backend = "mitsuba") -> torch.Tensor:
    """SSIM ``(B,)`` of the displayed re-renderings, averaged over the K lights (thesis Fig. 4.4)."""
    _check_pair(pred, gt)
    a, b = display(rerender(pred, lights, backend=backend)), display(rerender(gt, lights, backend=backend))
    bsz, k = a.shape[:2]
    return ssim(a.flatten(0, 1), b.flatten(0, 1)).view(bsz, k).mean(dim=1)


def evaluate_maps(pred: torch.Tensor, gt: torch.Tensor, lights: EvalLights | None = None, *,
                  chunk: int = 4, backend: Backend = "mitsuba", distribution: str = "ggx",
                  gt_distribution: str = "ggx") -> dict[str, float]:
    """Every metric, averaged over the batch: ``{key: float}`` with the keys :data:`METRIC_KEYS`.

    Args:
        pred: ``(B, 10, H, W)`` recovered maps.
        gt: ``(B, 10, H, W)`` ground truth.
        lights: re-rendering lights (default :func:`eval_lights`).
        chunk: samples re-rendered at once (bounds the memory: ``chunk * K * 3 * H * W`` floats).
        backend: renderer backend.
        distribution: the BRDF model ``pred`` is re-rendered with (``"ggx"`` or ``"beckmann"``: a net's
            or fit's output model); the map metrics compare the maps as they are, so a roughness of
            another model is not comparable with the ground truth's.
        gt_distribution: the model ``gt`` is re-rendered with (the simulator's ground truth: ``"ggx"``).
    """
    _check_pair(pred, gt)
    if not (isinstance(chunk, int) and chunk >= 1):
        raise ValueError(f"chunk: expected an int >= 1, got {chunk!r}")
    lights = lights or eval_lights()
    parts: dict[str, list[torch.Tensor]] = {k: [] for k in METRIC_KEYS}
    with torch.no_grad():
        for s in range(0, pred.shape[0], chunk):
            p, g = pred[s:s + chunk].detach(), gt[s:s + chunk].detach()
            for name, v in map_rmse(p, g).items():
                parts[f"rmse_{name}"].append(v)
            for name, v in scaled_albedo_rmse(p, g).items():
                parts[f"rmse_{name}_scaled"].append(v)
            for name, v in map_ssim(p, g).items():
                parts[f"ssim_{name}"].append(v)
            a = display(rerender(p, lights, backend=backend, distribution=distribution))
            b = display(rerender(g, lights, backend=backend, distribution=gt_distribution))
            parts["rmse_render"].append(_rmse(a, b))
            parts["ssim_render"].append(ssim(a.flatten(0, 1), b.flatten(0, 1)).view(a.shape[0], -1).mean(dim=1))
    return {k: float(torch.cat(v).double().mean()) for k, v in parts.items()}
