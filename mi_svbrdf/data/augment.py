"""Material augmentation as in the thesis (ch. 3.2, 4.3): mixing, rotation/scale/crop, parameter perturbation.

All functions take and return canonical ``(B, 10, H, W)`` maps (see :mod:`mi_svbrdf.core.maps`) and are
vectorised over the batch; the random ones take a seeded ``torch.Generator`` and draw from it in a
fixed order, so the same generator state gives the same result.

**Mixing** (:func:`mix`) follows the authors' 2019 code: normals are projected to slopes
``n / max(0.01, n.z)``, mixed linearly and renormalised; the other maps are mixed linearly. With
``alpha`` in [0, 1] every non-normal value lies between the two inputs' values, and the mixed
normal's slopes ``(x/z, y/z)`` are the same convex combination of the inputs' slopes (exactly so
where both ``n.z >= 0.01``): mixing two height fields' normals gives the normals of the mixed
height field.

**Geometric transforms** (:func:`transform_maps`) resample the maps on a rotated, scaled and
translated window of the sample plane (x right, y up, ``[-1, 1]^2``; docs/conventions.md):

- ``angle`` θ (radians): the material turns counter-clockwise by θ as seen in the image (y up).
  Normals turn with it: their xy is rotated by θ, ``n'.xy = R(θ) n.xy``. This is what rotating
  the height field does: if ``h'(p) = h(R(-θ) p)`` then ``∇h'(p) = R(θ) ∇h(R(-θ) p)``, and a normal
  is ``(-∇h, 1)`` normalised.
- ``scale`` s: magnification, output texels per input texel (s > 1 zooms in). The output shows a
  window of half-width ``out_size / (H s)`` of the input plane. Normals are resampled, **not**
  re-sloped: the whole surface is scaled uniformly in 3D (heights with the width), which is what a
  camera moving closer sees and what the thesis's resampling of the maps does. (Stretching only
  x and y of a height field would divide the slopes by s; we do not do that.)
- ``translation`` t: centre of the window in input-plane units ([-1, 1] spans the input).
- ``out_size``: output resolution (default: the input's). With ``scale = 1`` a smaller
  ``out_size`` is a crop at the input's texel density.

Sampling is bilinear (``grid_sample``, ``align_corners=False``, texel centres as in docs/conventions.md);
samples that fall outside the input are handled by ``padding``:

- ``"reflection"`` (default): the plane is mirrored about the input's edges, so non-tiling
  procedural materials continue without a seam; in a mirrored copy the normal's x (or y)
  component is negated, as mirroring the height field requires.
- ``"wrap"``: the input is repeated periodically (right for tiling materials; a seam otherwise).

When the output is minified by more than 10 % (``s < 1/1.1``), each output texel averages
``k x k`` samples, ``k = ceil(1/s - 0.1)`` (the batch's smallest scale), against aliasing. Normals
are renormalised after interpolation and averaging; roughness is not widened for the filtered
normal variation.

Examples:
    >>> import math, torch
    >>> from mi_svbrdf.core import maps as M
    >>> a = M.constant_maps(2, 16, 16, diffuse=0.2)
    >>> b = M.constant_maps(2, 16, 16, diffuse=0.6, normal=(0.3, 0.0, 1.0))
    >>> m = mix(a, b, torch.tensor([0.25, 0.75]))
    >>> [round(float(v), 3) for v in M.diffuse(m)[:, 0, 0, 0]]
    [0.5, 0.3]
    >>> r = transform_maps(b, angle=math.pi / 2)          # slope along +x becomes slope along +y
    >>> [round(float(v), 3) for v in M.normal(r)[0, :, 8, 8]]
    [0.0, 0.287, 0.958]
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.maps import check_maps
from mi_svbrdf.data import procedural

#: Floor on ``n.z`` when projecting normals to slopes for mixing (the authors' 2019 value).
MIX_MIN_Z = 0.01
#: ``alpha`` range of the authors' random mixing.
MIX_ALPHA_RANGE = (0.1, 0.9)
#: Padding modes of :func:`transform_maps`.
PADDINGS = ("reflection", "wrap")
#: Largest supersampling factor per axis of :func:`transform_maps`.
MAX_SUPERSAMPLING = 8

Scalars = float | torch.Tensor


def _per_sample(value: Scalars, batch: int, name: str) -> torch.Tensor:
    """A float or a 0-d / ``(B,)`` tensor as a ``(B,)`` float64 tensor (raises ``ValueError`` otherwise)."""
    t = torch.as_tensor(value, dtype=torch.float64).detach().cpu()
    if t.dim() == 0:
        t = t.expand(batch)
    if t.shape != (batch,):
        raise ValueError(f"{name}: expected a number or a tensor of shape ({batch},), got shape {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name}: expected finite values, got {t.tolist()}")
    return t


def _unit_normals(n: torch.Tensor) -> torch.Tensor:
    """Normalise ``(B, 3, H, W)`` vectors; near-zero vectors become ``(0, 0, 1)``."""
    length = n.square().sum(dim=1, keepdim=True).sqrt()
    flat = torch.zeros_like(n)
    flat[:, 2] = 1.0
    return torch.where(length > 1e-8, n / length.clamp_min(1e-8), flat)


def mix(a: torch.Tensor, b: torch.Tensor, alpha: Scalars) -> torch.Tensor:
    """α-blend two materials: ``alpha * a + (1 - alpha) * b`` (normals through their slopes).

    Args:
        a: ``(B, 10, H, W)`` maps.
        b: ``(B, 10, H, W)`` maps, same shape as ``a``.
        alpha: weight of ``a`` in [0, 1]: a number, or a ``(B,)`` tensor (one weight per sample).

    Returns:
        ``(B, 10, H, W)`` mixed maps with unit normals. Normals are projected as
        ``n / max(0.01, n.z)``, mixed linearly and renormalised (the authors' 2019 rule); the
        other maps are mixed linearly.

    Raises:
        ValueError: shapes differ, ``alpha`` has the wrong shape or lies outside [0, 1].
    """
    check_maps(a, "a")
    check_maps(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"b: expected the shape of a {tuple(a.shape)}, got {tuple(b.shape)}")
    w = _per_sample(alpha, a.shape[0], "alpha")
    if (w < 0).any() or (w > 1).any():
        raise ValueError(f"alpha: expected values in [0, 1], got {w.tolist()}")
    w = w.to(a.dtype).to(a.device).view(-1, 1, 1, 1)
    na, nb = M.normal(a), M.normal(b)
    pa = na / na[:, 2:3].clamp_min(MIX_MIN_Z)
    pb = nb / nb[:, 2:3].clamp_min(MIX_MIN_Z)
    normal = _unit_normals(w * pa + (1 - w) * pb)
    rest = w * a[:, 3:] + (1 - w) * b[:, 3:]
    return torch.cat([normal, rest], dim=1)


def random_mix(a: torch.Tensor, b: torch.Tensor, generator: torch.Generator,
               low: float = MIX_ALPHA_RANGE[0], high: float = MIX_ALPHA_RANGE[1]) -> tuple[torch.Tensor, torch.Tensor]:
    """Mix each pair ``(a[i], b[i])`` with its own ``alpha ~ U(low, high)`` (default: the authors' U(0.1, 0.9)).

    Args:
        a: ``(B, 10, H, W)`` maps.
        b: ``(B, 10, H, W)`` maps.
        generator: source of the weights (``B`` uniform draws).
        low: smallest weight, in [0, 1].
        high: largest weight, in [low, 1].

    Returns:
        ``(mixed, alpha)``: ``(B, 10, H, W)`` maps and the ``(B,)`` float32 weights of ``a``.
    """
    if not 0.0 <= low <= high <= 1.0:
        raise ValueError(f"low, high: expected 0 <= low <= high <= 1, got low={low}, high={high}")
    alpha = low + (high - low) * torch.rand(a.shape[0], generator=generator, dtype=torch.float64)
    return mix(a, b, alpha), alpha.float()


def _fold(coord: torch.Tensor, padding: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Fold plane coordinates into the input ``[-1, 1]``; also return where the copy is mirrored."""
    u = (coord + 1.0) * 0.5
    if padding == "wrap":
        return torch.remainder(u, 1.0) * 2.0 - 1.0, torch.zeros_like(coord, dtype=torch.bool)
    m = torch.remainder(u, 2.0)
    mirrored = m > 1.0
    return torch.where(mirrored, 2.0 - m, m) * 2.0 - 1.0, mirrored


def transform_maps(maps: torch.Tensor, angle: Scalars = 0.0, scale: Scalars = 1.0,
                   translation: Sequence[float] | torch.Tensor = (0.0, 0.0), out_size: int | None = None, *,
                   padding: str = "reflection", antialias: bool = True) -> torch.Tensor:
    """Rotate, scale and crop/translate maps, rotating the normals consistently (see the module doc).

    Args:
        maps: ``(B, 10, H, H)`` square maps.
        angle: counter-clockwise rotation θ in radians: a number or ``(B,)``.
        scale: magnification s > 0 (output texels per input texel): a number or ``(B,)``.
        translation: centre of the window in input-plane units: ``(2,)`` (x, y) or ``(B, 2)``.
        out_size: output resolution ``S`` (default ``H``).
        padding: ``"reflection"`` (mirror about the edges, normals mirrored too) or ``"wrap"``.
        antialias: supersample minifications by more than 10 %.

    Returns:
        ``(B, 10, S, S)`` maps, normals unit length. Output texel ``p`` (plane position) samples
        the input at ``t + out_size / (H s) · R(-θ) p``.

    Raises:
        ValueError: bad shapes, non-square maps, ``scale <= 0``, unknown ``padding``.
    """
    check_maps(maps)
    batch, _, height, width = maps.shape
    if height != width:
        raise ValueError(f"maps: expected square maps (B, 10, H, H), got {height}x{width} (H x W)")
    if padding not in PADDINGS:
        raise ValueError(f"padding: expected one of {PADDINGS}, got {padding!r}")
    out = height if out_size is None else int(out_size)
    if out < 1:
        raise ValueError(f"out_size: expected a positive size, got {out_size}")
    theta = _per_sample(angle, batch, "angle")
    s = _per_sample(scale, batch, "scale")
    if (s <= 0).any():
        raise ValueError(f"scale: expected values > 0, got {s.tolist()}")
    t = torch.as_tensor(translation, dtype=torch.float64).detach().cpu()
    if t.shape == (2,):
        t = t.expand(batch, 2)
    if t.shape != (batch, 2) or not torch.isfinite(t).all():
        raise ValueError(f"translation: expected finite (x, y) of shape (2,) or ({batch}, 2), "
                         f"got shape {tuple(t.shape)}")
    k = 1
    if antialias:
        k = min(MAX_SUPERSAMPLING, max(1, math.ceil(1.0 / float(s.min()) - 0.1)))
    n = out * k
    # Sample positions in output-plane units (texel centres; row 0 at y = +1), in float64.
    c = (torch.arange(n, dtype=torch.float64) * 2 + 1) / n - 1
    px, py = c.view(1, 1, n), -c.view(1, n, 1)
    half = (out / (height * s)).view(-1, 1, 1)
    cos, sin = torch.cos(theta).view(-1, 1, 1), torch.sin(theta).view(-1, 1, 1)
    qx = t[:, 0].view(-1, 1, 1) + half * (cos * px + sin * py)
    qy = t[:, 1].view(-1, 1, 1) + half * (-sin * px + cos * py)
    qx, flip_x = _fold(qx, padding)
    qy, flip_y = _fold(qy, padding)
    source = maps
    if padding == "wrap":  # one texel of the opposite edge on each side, for seamless interpolation
        source = F.pad(maps, (1, 1, 1, 1), mode="circular")
        qx, qy = qx * (height / (height + 2)), qy * (height / (height + 2))
    grid = torch.stack([qx, -qy], dim=-1).to(maps.dtype).to(maps.device)  # grid y points down
    sampled = F.grid_sample(source, grid, mode="bilinear", padding_mode="border", align_corners=False)
    sign_x = torch.where(flip_x, -1.0, 1.0).to(maps.dtype).to(maps.device).unsqueeze(1)
    sign_y = torch.where(flip_y, -1.0, 1.0).to(maps.dtype).to(maps.device).unsqueeze(1)
    nx, ny = sampled[:, 0:1] * sign_x, sampled[:, 1:2] * sign_y
    cos_, sin_ = (v.to(maps.dtype).to(maps.device).view(-1, 1, 1, 1) for v in (cos, sin))
    normal = torch.cat([cos_ * nx - sin_ * ny, sin_ * nx + cos_ * ny, sampled[:, 2:3]], dim=1)
    result = torch.cat([normal, sampled[:, 3:]], dim=1)
    if k > 1:
        result = F.avg_pool2d(result, k)
    return torch.cat([_unit_normals(M.normal(result)), result[:, 3:]], dim=1)


def max_translation(angle: Scalars, scale: Scalars, out_size: int, in_size: int) -> torch.Tensor:
    """Largest |t_x| = |t_y| keeping the rotated window inside the input (0 if it never fits).

    Args:
        angle: θ, a number or ``(B,)``.
        scale: s, a number or ``(B,)`` (same batch as ``angle``).
        out_size: output resolution.
        in_size: input resolution.

    Returns:
        ``(B,)`` float64 bound per axis, ``max(0, 1 - w (|cos θ| + |sin θ|))``, ``w = out/(in s)``.
    """
    theta = torch.as_tensor(angle, dtype=torch.float64).reshape(-1)
    s = torch.as_tensor(scale, dtype=torch.float64).reshape(-1)
    w = out_size / (in_size * s)
    return (1.0 - w * (theta.cos().abs() + theta.sin().abs())).clamp_min(0.0)


def random_transform(maps: torch.Tensor, generator: torch.Generator,
                     angle_range: tuple[float, float] = (-math.pi, math.pi),
                     scale_range: tuple[float, float] = (1.0, 1.0), out_size: int | None = None, *,
                     translate: bool = True, padding: str = "reflection",
                     antialias: bool = True) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Random rotation, scale and translation per sample, then :func:`transform_maps`.

    Draws, per sample and in this order, ``angle ~ U(angle_range)``, ``scale`` log-uniform in
    ``scale_range`` and, if ``translate``, each translation axis ``~ U(-m, m)`` with ``m`` the
    :func:`max_translation` that keeps the window inside the input (0 when it cannot fit: then
    the window is centred and ``padding`` fills the rest).

    Args:
        maps: ``(B, 10, H, H)`` maps.
        generator: source of the parameters (``4 B`` uniform draws).
        angle_range: ``(low, high)`` radians.
        scale_range: ``(low, high)``, ``0 < low <= high``.
        out_size: output resolution (default ``H``).
        translate: draw a translation (else centred windows).
        padding: see :func:`transform_maps`.
        antialias: see :func:`transform_maps`.

    Returns:
        ``(maps, params)``: ``(B, 10, S, S)`` maps and ``{"angle": (B,), "scale": (B,),
        "translation": (B, 2)}`` float64 tensors, which :func:`transform_maps` accepts as they are.
    """
    check_maps(maps)
    batch, size = maps.shape[0], maps.shape[-1]
    lo, hi = (float(v) for v in scale_range)
    if not 0 < lo <= hi:
        raise ValueError(f"scale_range: expected 0 < low <= high, got {scale_range}")
    if not float(angle_range[0]) <= float(angle_range[1]):
        raise ValueError(f"angle_range: expected low <= high, got {angle_range}")
    u = torch.rand(4, batch, generator=generator, dtype=torch.float64)
    angle = angle_range[0] + (angle_range[1] - angle_range[0]) * u[0]
    scale = torch.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * u[1])
    out = size if out_size is None else int(out_size)
    bound = max_translation(angle, scale, out, size) if translate else torch.zeros(batch, dtype=torch.float64)
    translation = (u[2:4].T * 2.0 - 1.0) * bound.view(-1, 1)
    params = {"angle": angle, "scale": scale, "translation": translation}
    return transform_maps(maps, angle, scale, translation, out, padding=padding, antialias=antialias), params


def perturb_parameters(name: str, params: Mapping[str, float], generator: torch.Generator,
                       amount: float = 0.1) -> dict[str, float]:
    """A variant of a procedural material's parameters (the thesis's ~1 850 variants of 155 materials).

    Each parameter of class ``name`` (missing ones take their default) moves by
    ``amount · (high − low) · N(0, 1)``, is clipped to its documented ``[low, high]`` and rounded
    if it is an integer; one normal draw per parameter, in the class's parameter order.

    Args:
        name: a class of :data:`mi_svbrdf.data.procedural.CLASSES`.
        params: the parameters to perturb (validated first).
        generator: source of the perturbation.
        amount: size of the perturbation as a fraction of each range (0: unchanged).

    Returns:
        Validated parameters (``procedural.validate_parameters``).
    """
    if amount < 0:
        raise ValueError(f"amount: expected a fraction >= 0, got {amount}")
    base = procedural.validate_parameters(name, dict(params))
    specs = procedural.CLASSES[name].params
    noise = torch.randn(len(specs), generator=generator, dtype=torch.float64).tolist()
    out: dict[str, float] = {}
    for z, (key, spec) in zip(noise, specs.items()):
        value = min(max(float(base.get(key, spec.default)) + amount * (spec.high - spec.low) * z, spec.low), spec.high)
        out[key] = float(round(value)) if spec.integer else value
    return procedural.validate_parameters(name, out)
