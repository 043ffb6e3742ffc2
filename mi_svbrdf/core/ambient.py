"""Ambient lighting: an environment of many distant lights, and a flat sample rendered under it.

A photo of a wall or floor taken under ambient light (thesis ch. 5) shows soft shading from a
large part of the hemisphere -- sky, ceiling, window -- and no flash highlight. It is modelled as
an :class:`Environment` of L distant lights (far field: no distance fall-off, no cone, no
``1/wl.z`` division), and rendered with the texel renderer as the sum of its lights::

    L_out(texel) = sum_l f(n, w_l, w_v) * pi * I_l * max(n . w_l, 0)

:func:`render_environment` evaluates that sum on the two backends of :func:`mi_svbrdf.core.render`:
``"mitsuba"`` accumulates the lights inside the Dr.Jit kernels (memory O(B*H*W) whatever L,
gradients to the maps) and ``"torch"`` is the plain reference (lights in chunks, recomputed chunk
by chunk in the backward pass, so no ``(B, L, 3, H, W)`` tensor exists). ``tests/test_ambient.py``
proves the two agree and equal a full ``mi.render`` of the plane under Mitsuba ``directional``
emitters of irradiance ``pi * I_l`` (max relative error 5e-5). Measured at 512^2, L = 64, one
thread (``benchmarks/bench_ambient.py``): ``"mitsuba"`` 0.35 s forward, 0.8-0.9 s forward +
backward, +70 MB peak; ``"torch"`` 2-4 s and 7-15 s, +340 MB.

:func:`sample_environment` draws random environments (:class:`AmbientConfig` holds the ranges):

* **Directions**: a jittered spherical Fibonacci set, randomly rotated about z: L directions
  uniform in solid angle over the hemisphere above ``min_elevation_deg`` (light ``l`` has
  ``z = 1 - (1 - z_min) (l + u_l) / L``, ``u_l ~ U(0, 1)``, azimuth ``l * golden angle + phi_0``).
* **Radiance** of the sky at ``w``: a uniform fill plus a broad dominant lobe
  ``exp(kappa (w . d - 1))`` (von Mises-Fisher shape; angular width about ``1/sqrt(kappa)`` rad)
  around a direction ``d`` of azimuth ``U(0, 2 pi)`` and elevation ``U(lobe_elevation_deg)``;
  the lobe's share of the irradiance of a flat sample is ``U(lobe_fraction)``.
* **Colour**: the fill has a colour temperature uniform in mired (1e6 / K) over
  ``temperature_range`` (warm indoor ~3000 K to daylight ~6500 K), the lobe one within
  ``lobe_mired_spread`` mired of it; each colour gets a small per-channel log-normal tint
  (``tint_sigma``). A light's colour mixes the two by its share of fill and lobe.
* **Normalisation**: an ideal white Lambertian flat sample (diffuse 1, no specular term) renders
  to the radiance ``sum_l I_l z_l``, whose mean over R, G, B is exactly ``white_level`` (0.6)
  times a brightness factor, log-uniform over ``brightness_range`` (0.7 to 1.4). The model's
  diffuse 1, specular 0 material is within 0.5 % of it (the Fresnel term at specular 0).

Few lights and smooth materials: each light makes its own small highlight, which a continuous
environment would not. Measured on a bumpy sample (normals tilted up to 0.5 rad, specular 0.5),
the median over environments of the 99th percentile / median of its radiance -- 1.9 to 2.1 in the
continuous limit (L = 512) -- is 5.2 at roughness 0.25 and 21 at 0.15 with L = 32, 2.2 and 5.3 with
L = 128; at roughness 0.4 L = 32 is smooth (1.8, limit 1.7). Use L >= 128 where materials are glossy.

Examples:
    >>> import torch
    >>> from mi_svbrdf.core import maps as M
    >>> from mi_svbrdf.core.ambient import render_environment, sample_environment
    >>> env = sample_environment(2, 32, generator=torch.Generator().manual_seed(0))
    >>> tuple(env.directions.shape), bool((env.directions[..., 2] > 0).all())
    ((2, 32, 3), True)
    >>> white = M.constant_maps(2, 4, 4, diffuse=1.0, specular=0.0, roughness=1.0)
    >>> img = render_environment(white, env)
    >>> tuple(img.shape), 0.6 * 0.7 < float(img[0].mean()) < 0.6 * 1.4 * 1.005
    ((2, 3, 4, 4), True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch.autograd.function import once_differentiable

from mi_svbrdf.core import brdf_torch, render_drjit
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.core.maps import check_maps
from mi_svbrdf.core.render import BACKENDS, Backend, direction, texel_positions
from mi_svbrdf.plugins.model import DISTRIBUTIONS

__all__ = ["AmbientConfig", "Environment", "render_environment", "sample_environment", "temperature_rgb"]

#: Light-texel products (B * lights * H * W) per chunk of the torch backend (~6 MB per float32 RGB tensor).
TORCH_CHUNK = 1 << 19
#: Tolerance of the unit-length check of :attr:`Environment.directions`.
UNIT_TOLERANCE = 1e-3
#: Validity range (K) of the Planckian-locus approximation of :func:`temperature_rgb`.
TEMPERATURE_LIMITS = (1667.0, 25000.0)
#: The golden angle (radians): azimuth step of the spherical Fibonacci set.
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
#: CIE XYZ -> linear sRGB (Rec. 709 primaries, D65 white).
_XYZ_TO_RGB = torch.tensor([[3.2404542, -1.5371385, -0.4985314],
                            [-0.9692660, 1.8760108, 0.0415560],
                            [0.0556434, -0.2040259, 1.0572252]], dtype=torch.float64)


@dataclass(frozen=True)
class Environment:
    """L distant lights per batch element, the far-field lights of :func:`mi_svbrdf.core.render`.

    Raises:
        ValueError: shapes other than two equal ``(B, L, 3)``, NaN/Inf, directions not unit
            (within :data:`UNIT_TOLERANCE`) or not above the plane, negative intensities.
    """

    directions: torch.Tensor  #: (B, L, 3) unit vectors towards each distant light, z > 0 (upper hemisphere)
    intensities: torch.Tensor  #: (B, L, 3) linear RGB intensity I of each light (render()'s far-field intensity)

    def __post_init__(self) -> None:
        for name in ("directions", "intensities"):
            t = getattr(self, name)
            if not isinstance(t, torch.Tensor):
                raise TypeError(f"{name}: expected a torch.Tensor of shape (B, L, 3), got {type(t).__name__}")
            if t.dim() != 3 or t.shape[2] != 3 or t.shape[0] < 1 or t.shape[1] < 1:
                raise ValueError(f"{name}: expected shape (B, L, 3) with B, L >= 1, got {tuple(t.shape)}")
            if not t.is_floating_point():
                raise ValueError(f"{name}: expected a floating-point tensor, got {t.dtype}")
            if not torch.isfinite(t).all():
                raise ValueError(f"{name}: contains NaN or Inf values")
        if self.intensities.shape != self.directions.shape:
            raise ValueError(f"intensities: expected the shape of directions {tuple(self.directions.shape)}, "
                             f"got {tuple(self.intensities.shape)}")
        d = self.directions.detach()
        err = float((d.norm(dim=-1) - 1.0).abs().max())
        if err > UNIT_TOLERANCE:
            raise ValueError(f"directions: expected unit vectors (|norm - 1| <= {UNIT_TOLERANCE}), "
                             f"got a norm off by {err:.3g}")
        if not bool((d[..., 2] > 0).all()):
            raise ValueError(f"directions: expected z > 0 (lights above the plane), "
                             f"got min z {float(d[..., 2].min()):.3g}")
        if not bool((self.intensities.detach() >= 0).all()):
            raise ValueError(f"intensities: expected values >= 0, got min {float(self.intensities.min()):.3g}")

    @property
    def batch(self) -> int:
        """B, the number of environments."""
        return self.directions.shape[0]

    @property
    def count(self) -> int:
        """L, the number of lights per environment."""
        return self.directions.shape[1]


@dataclass(frozen=True)
class AmbientConfig:
    """Ranges of :func:`sample_environment` (see the module docstring). Unknown keys are rejected by
    :meth:`from_dict`; ``(low, high)`` ranges are drawn uniformly unless said otherwise."""

    temperature_range: tuple[float, float] = (3000.0, 6500.0)  #: fill colour temperature (K), uniform in mired
    lobe_mired_spread: float = 50.0  #: lobe temperature = fill's + U(-x, x) mired (clipped to the range), >= 0
    tint_sigma: float = 0.03  #: std of a per-channel log-normal tint of each colour, in [0, 0.5]
    lobe_fraction: tuple[float, float] = (0.3, 0.8)  #: the lobe's share of a flat sample's irradiance, in [0, 1]
    lobe_elevation_deg: tuple[float, float] = (20.0, 75.0)  #: elevation of the lobe's centre, in [0, 90] degrees
    lobe_concentration: tuple[float, float] = (2.0, 6.0)  #: kappa of the lobe (width ~1/sqrt(kappa) rad), [0, 100]
    min_elevation_deg: float = 5.0  #: lights cover elevations [this, 90] degrees, in (0, 90)
    white_level: float = 0.6  #: mean RGB radiance of an ideal white Lambertian flat sample before brightness, > 0
    brightness_range: tuple[float, float] = (0.7, 1.4)  #: total brightness factor, log-uniform, 0 < low <= high

    def __post_init__(self) -> None:
        t_lo, t_hi = self.temperature_range
        f_lo, f_hi = self.lobe_fraction
        e_lo, e_hi = self.lobe_elevation_deg
        k_lo, k_hi = self.lobe_concentration
        b_lo, b_hi = self.brightness_range
        check_fields([
            ("temperature_range", TEMPERATURE_LIMITS[0] <= t_lo <= t_hi <= TEMPERATURE_LIMITS[1],
             f"{TEMPERATURE_LIMITS[0]:g} <= low <= high <= {TEMPERATURE_LIMITS[1]:g} K", self.temperature_range),
            ("lobe_mired_spread", self.lobe_mired_spread >= 0, "a value >= 0", self.lobe_mired_spread),
            ("tint_sigma", 0.0 <= self.tint_sigma <= 0.5, "a value in [0, 0.5]", self.tint_sigma),
            ("lobe_fraction", 0.0 <= f_lo <= f_hi <= 1.0, "0 <= low <= high <= 1", self.lobe_fraction),
            ("lobe_elevation_deg", 0.0 <= e_lo <= e_hi <= 90.0, "0 <= low <= high <= 90", self.lobe_elevation_deg),
            ("lobe_concentration", 0.0 <= k_lo <= k_hi <= 100.0, "0 <= low <= high <= 100",
             self.lobe_concentration),
            ("min_elevation_deg", 0.0 < self.min_elevation_deg < 90.0, "a value in (0, 90)", self.min_elevation_deg),
            ("white_level", self.white_level > 0, "a value > 0", self.white_level),
            ("brightness_range", 0.0 < b_lo <= b_hi, "0 < low <= high", self.brightness_range),
        ], owner="AmbientConfig")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AmbientConfig:
        """Build from a dict (e.g. parsed JSON; lists become tuples); unknown keys raise a ``ValueError``."""
        if isinstance(data, dict):
            data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return from_dict(cls, data)


def temperature_rgb(kelvin: torch.Tensor) -> torch.Tensor:
    """Linear sRGB colour ``(..., 3)`` of a black body at ``kelvin`` ``(...)``, scaled to a mean of 1 over R, G, B.

    The chromaticity is Kang et al.'s (2002) cubic approximation of the Planckian locus (valid
    1667-25000 K, within ~1e-3 in x, y), converted to Rec. 709 primaries; negative components
    (below ~1900 K) are clipped to 0.

    Examples:
        >>> rgb = temperature_rgb(torch.tensor([3000.0, 6500.0]))
        >>> bool(rgb[0, 0] > rgb[0, 1] > rgb[0, 2]), bool((rgb[1] - 1).abs().max() < 0.1)
        (True, True)
    """
    t = torch.as_tensor(kelvin, dtype=torch.float64)
    if not bool(((t >= TEMPERATURE_LIMITS[0]) & (t <= TEMPERATURE_LIMITS[1])).all()):
        raise ValueError(f"kelvin: expected values in [{TEMPERATURE_LIMITS[0]:g}, {TEMPERATURE_LIMITS[1]:g}], "
                         f"got {t.min().item():g} to {t.max().item():g}")
    i1, i2, i3 = 1e3 / t, 1e6 / t**2, 1e9 / t**3
    x = torch.where(t <= 4000.0,
                    -0.2661239 * i3 - 0.2343589 * i2 + 0.8776956 * i1 + 0.179910,
                    -3.0258469 * i3 + 2.1070379 * i2 + 0.2226347 * i1 + 0.240390)
    y = torch.where(t <= 2222.0, -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683,
                    torch.where(t <= 4000.0, -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867,
                                3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483))
    xyz = torch.stack([x / y, torch.ones_like(x), (1.0 - x - y) / y], dim=-1)
    rgb = (xyz @ _XYZ_TO_RGB.T).clamp_min(0.0)
    return rgb / rgb.mean(dim=-1, keepdim=True)


def _uniform(shape: tuple[int, ...], bounds: tuple[float, float], gen: torch.Generator | None) -> torch.Tensor:
    lo, hi = bounds
    return lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=torch.float64)


def _tinted(kelvin: torch.Tensor, sigma: float, gen: torch.Generator | None) -> torch.Tensor:
    """``(B, 3)`` colours of temperature ``kelvin`` ``(B,)`` with a log-normal tint, mean 1 over R, G, B."""
    rgb = temperature_rgb(kelvin) * torch.exp(sigma * torch.randn(kelvin.shape + (3,), generator=gen,
                                                                   dtype=torch.float64))
    return rgb / rgb.mean(dim=-1, keepdim=True)


def sample_environment(batch: int, n_lights: int = 32, *, generator: torch.Generator | None = None,
                       device: torch.device | str = "cpu", config: AmbientConfig | None = None) -> Environment:
    """Draw ``batch`` random ambient environments of ``n_lights`` distant lights each.

    The distributions are those of the module docstring, with the ranges of ``config``. The draws
    happen on the CPU in float64 (a given ``generator`` state gives the same environments on any
    device) and the result is float32 on ``device``.

    Args:
        batch: B, >= 1.
        n_lights: L, >= 1 (more lights: smoother highlights on shiny materials, slower rendering).
        generator: a seeded CPU generator for reproducible draws.
        device: device of the result.
        config: the ranges; default :class:`AmbientConfig`.

    Returns:
        :class:`Environment` whose white Lambertian flat sample renders to ``white_level * brightness``
        (mean over R, G, B) exactly, in float64 before the float32 cast.

    Examples:
        >>> env = sample_environment(1, 8, generator=torch.Generator().manual_seed(1))
        >>> white = (env.intensities * env.directions[..., 2:]).sum(dim=1)  # ideal white Lambertian, (1, 3)
        >>> 0.6 * 0.7 <= float(white.mean()) <= 0.6 * 1.4
        True
    """
    if not (isinstance(batch, int) and batch >= 1):
        raise ValueError(f"batch: expected an int >= 1, got {batch!r}")
    if not (isinstance(n_lights, int) and n_lights >= 1):
        raise ValueError(f"n_lights: expected an int >= 1, got {n_lights!r}")
    cfg = AmbientConfig() if config is None else config
    if not isinstance(cfg, AmbientConfig):
        raise TypeError(f"config: expected an AmbientConfig or None, got {type(cfg).__name__}")
    g = generator

    # Directions: jittered spherical Fibonacci set, uniform in solid angle above z_min, rotated about z.
    z_min = math.sin(math.radians(cfg.min_elevation_deg))
    index = torch.arange(n_lights, dtype=torch.float64)
    z = 1.0 - (1.0 - z_min) * (index + torch.rand(batch, n_lights, generator=g, dtype=torch.float64)) / n_lights
    phi = index * GOLDEN_ANGLE + _uniform((batch, 1), (0.0, 2.0 * math.pi), g)
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)  # (B, L, 3)

    # The dominant lobe: centre, concentration, share of the irradiance.
    azimuth = _uniform((batch,), (0.0, 2.0 * math.pi), g)
    elevation = torch.deg2rad(_uniform((batch,), cfg.lobe_elevation_deg, g))
    kappa = _uniform((batch,), cfg.lobe_concentration, g)
    fraction = _uniform((batch,), cfg.lobe_fraction, g)
    centre = torch.stack([torch.cos(elevation) * torch.cos(azimuth), torch.cos(elevation) * torch.sin(azimuth),
                          torch.sin(elevation)], dim=-1)
    lobe = torch.exp(kappa[:, None] * ((dirs * centre[:, None]).sum(-1) - 1.0))  # (B, L), in (0, 1]

    # Colours: fill temperature uniform in mired, the lobe's near it; small tints.
    mired_lo, mired_hi = 1e6 / cfg.temperature_range[1], 1e6 / cfg.temperature_range[0]
    fill_mired = _uniform((batch,), (mired_lo, mired_hi), g)
    lobe_mired = (fill_mired + _uniform((batch,), (-cfg.lobe_mired_spread, cfg.lobe_mired_spread), g)
                  ).clamp(mired_lo, mired_hi)
    fill_rgb = _tinted(1e6 / fill_mired, cfg.tint_sigma, g)
    lobe_rgb = _tinted(1e6 / lobe_mired, cfg.tint_sigma, g)

    log_b = _uniform((batch,), (math.log(cfg.brightness_range[0]), math.log(cfg.brightness_range[1])), g)
    scale = cfg.white_level * torch.exp(log_b)

    # Irradiance of a flat sample from each part: sum_l weight_l z_l; normalise each to its share.
    fill_irr = z.sum(dim=1)
    lobe_irr = (lobe * z).sum(dim=1)
    fill_w = ((1.0 - fraction) * scale / fill_irr)[:, None, None] * fill_rgb[:, None]  # (B, 1, 3)
    lobe_w = (fraction * scale / lobe_irr)[:, None, None] * lobe_rgb[:, None]
    intensities = fill_w + lobe[..., None] * lobe_w  # (B, L, 3)
    return Environment(directions=dirs.to(device=device, dtype=torch.float32),
                       intensities=intensities.to(device=device, dtype=torch.float32))


def _check_view(view: torch.Tensor | None, batch: int, like: torch.Tensor) -> torch.Tensor:
    """``(B, 3)`` view directions (default: straight above), checked."""
    if view is None:
        return torch.tensor([0.0, 0.0, 1.0], dtype=like.dtype, device=like.device).expand(batch, 3)
    if not isinstance(view, torch.Tensor):
        raise TypeError(f"view: expected a torch.Tensor (B, 3) or None, got {type(view).__name__}")
    if view.shape != (batch, 3):
        raise ValueError(f"view: expected shape (B={batch}, 3) directions towards the viewer, got {tuple(view.shape)}")
    if not torch.isfinite(view).all():
        raise ValueError("view: contains NaN or Inf values")
    if not bool((view[:, 2] > 0).all()):
        raise ValueError(f"view: expected directions above the plane (z > 0), got min z {float(view[:, 2].min()):.3g}")
    return view.to(like)


def _torch_chunk(maps: torch.Tensor, positions: torch.Tensor, light: torch.Tensor, view: torch.Tensor,
                 intensity: torch.Tensor, distribution: str) -> torch.Tensor:
    """Sum over a chunk of lights of the reference renderer, ``(B, 3, H, W)``."""
    return brdf_torch.render(maps, positions, light, view, intensity, None, None, distance_falloff=False,
                             light_z_division=False, include_diffuse=True, normalize_normals=True,
                             distribution=distribution).sum(dim=1)


class _ChunkedSum(torch.autograd.Function):
    """Sum of :func:`_torch_chunk` over chunks of lights; the backward pass recomputes one chunk at a time.

    Plain autograd would keep every chunk's intermediates (O(L*H*W)); ``torch.utils.checkpoint``
    keeps only the inputs but, measured at 512^2 and L = 64, still left ~1.5 GB of fragmented heap
    resident. Here the forward pass builds no graph and the backward pass holds one chunk's graph.
    """

    @staticmethod
    def forward(ctx: Any, maps: torch.Tensor, positions: torch.Tensor, light: torch.Tensor, view: torch.Tensor,
                intensity: torch.Tensor, distribution: str, per_chunk: int) -> torch.Tensor:
        """The sum over the chunks, without a graph."""
        ctx.save_for_backward(maps, positions, light, view, intensity)
        ctx.distribution, ctx.per_chunk = distribution, per_chunk
        total = None
        for start in range(0, light.shape[1], per_chunk):
            part = slice(start, start + per_chunk)
            value = _torch_chunk(maps, positions, light[:, part], view[:, part], intensity[:, part], distribution)
            total = value if total is None else total + value
        return total

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        """Recompute each chunk with a graph, pull ``grad`` through it, accumulate; then drop it."""
        maps, positions, light, view, intensity = ctx.saved_tensors
        needs = ctx.needs_input_grad
        grads = [torch.zeros_like(t) if needs[i] else None for i, t in enumerate((maps, positions, light, view,
                                                                                    intensity))]
        for start in range(0, light.shape[1], ctx.per_chunk):
            part = slice(start, start + ctx.per_chunk)
            inputs = [maps, positions, light[:, part], view[:, part], intensity[:, part]]
            inputs = [t.detach().requires_grad_(bool(needs[i])) for i, t in enumerate(inputs)]
            with torch.enable_grad():
                value = _torch_chunk(*inputs, ctx.distribution)
                wanted = [t for t in inputs if t.requires_grad]
                chunk_grads = iter(torch.autograd.grad(value, wanted, grad))
            for i in range(5):
                if needs[i]:
                    target = grads[i] if i < 2 else grads[i][:, part]
                    target += next(chunk_grads)
        return (*grads, None, None)


def render_environment(maps: torch.Tensor, env: Environment, *, view: torch.Tensor | None = None,
                       distribution: str = "ggx", backend: Backend = "mitsuba") -> torch.Tensor:
    """Render ``maps`` under the ambient environment ``env``: the sum of its far-field lights.

    Equals ``render(maps, direction(env.directions), direction(view), intensity=env.intensities)``
    summed over the L configurations (no distance fall-off, no ``light_z_division``, no cone,
    diffuse included, normals renormalised), without ever holding the L renderings.

    Args:
        maps: ``(B, 10, H, W)`` SVBRDF.
        env: :class:`Environment` with B environments (one per material).
        view: ``(B, 3)`` directions towards the viewer (far field, z > 0), or None: an orthographic
            camera straight above, ``(0, 0, 1)`` for every texel.
        distribution: ``"ggx"`` or ``"beckmann"``.
        backend: ``"mitsuba"`` (lights summed inside the Dr.Jit kernels) or ``"torch"`` (reference).

    Returns:
        ``(B, 3, H, W)`` linear radiance, float32 for ``"mitsuba"``, ``maps.dtype`` for ``"torch"``.
        Gradients flow to ``maps`` on both backends; only the torch backend also differentiates
        ``env`` and ``view``.

    Examples:
        >>> from mi_svbrdf.core import maps as M
        >>> up = torch.tensor([[[0.0, 0.0, 1.0]]])
        >>> env = Environment(directions=up, intensities=torch.full((1, 1, 3), 0.5))
        >>> img = render_environment(M.constant_maps(1, 2, 2, diffuse=0.8, specular=0.0), env, backend="torch")
        >>> round(float(img[0, 0, 0, 0]), 3)  # f * pi * I * cos = (0.8 / pi + tiny specular) * pi * 0.5
        0.4
    """
    check_maps(maps)
    if not isinstance(env, Environment):
        raise TypeError(f"env: expected an Environment, got {type(env).__name__}")
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    batch, _, height, width = maps.shape
    if env.batch != batch:
        raise ValueError(f"env: expected B={batch} environments (one per material in maps), got {env.batch}")
    view3 = _check_view(view, batch, maps)
    count = env.count
    light = direction(env.directions.to(maps))  # (B, L, 4), w = 0
    view_h = direction(view3[:, None].expand(batch, count, 3))
    intensity = env.intensities.to(maps)

    if backend == "mitsuba":
        flags = render_drjit.Flags(distance_falloff=False, light_z_division=False, cone=False,
                                   include_diffuse=True, normalize_normals=True, distribution=distribution)
        cfg = render_drjit.pack_configurations(light, view_h, intensity, None, None)
        return render_drjit.render_sum(maps, cfg, count, flags)

    positions = texel_positions(height, width, dtype=maps.dtype, device=maps.device)
    per_chunk = max(1, TORCH_CHUNK // (batch * height * width))
    if count <= per_chunk:  # one chunk: plain autograd (also twice differentiable)
        return _torch_chunk(maps, positions, light, view_h, intensity, distribution)
    return _ChunkedSum.apply(maps, positions, light, view_h, intensity, distribution, per_chunk)
