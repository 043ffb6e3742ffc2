"""The glTF 2.0 metallic-roughness BRDF (+ ``KHR_materials_specular``) in PyTorch, and how our maps map to it.

What a glTF viewer renders (glTF 2.0 specification, appendix B, and the ``KHR_materials_specular``
extension), with c(x) = max(x, 0), alpha = r^2 (glTF squares its roughness exactly as we do)::

    D   = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)                               (GGX, as ours)
    Vis = 0.5 / (n.l sqrt((n.v)^2 (1 - alpha^2) + alpha^2) + n.v sqrt((n.l)^2 (1 - alpha^2) + alpha^2))
                                                                  (Smith, height-correlated)
    f0_d = min(0.04 * specularColor, 1) * specular,  f90_d = specular
    F_d  = f0_d + (f90_d - f0_d) (1 - |v.h|)^5                                       (Schlick)
    dielectric = F_d Vis D + (1 - max_rgb(F_d)) baseColor / pi
    metal      = (baseColor + (1 - baseColor) (1 - |v.h|)^5) Vis D
    f          = mix(dielectric, metal, metallic)

Ours (docs/conventions.md): ``F G D / 4 + d (1 - s) / pi`` with the separable Smith-Schlick
``G/4 = 1 / (4 (n.l (1 - k) + k) (n.v (1 - k) + k))``, k = alpha/2, and the spherical-Gaussian
Schlick Fresnel ``F = s + (1 - s) 2^((-5.55473 v.h - 6.98316) v.h)``.

**The conversion** (:func:`from_svbrdf`, ``mode="matched"``): metallic = 0, specular = 1,
roughness = r, the same normal, ``specularColor = s / 0.04`` (so ``f0_d = s`` exactly while
``s <= 1``), and ``baseColor = d (1 - s) / (1 - max_rgb(s))`` clipped to [0, 1]: glTF weights the
diffuse term by ``1 - max_rgb(F_d)``, which at normal incidence (v.h = 1, the flash
configuration) is ``1 - max_rgb(s)``, so this choice makes both models' diffuse terms equal
there. What remains (the approximation, measured by :func:`compare`):

* visibility: height-correlated Smith vs separable Smith-Schlick (equal at n.l = n.v = 1,
  they drift apart at grazing angles and high roughness);
* Fresnel: ``(1 - v.h)^5`` vs the spherical-Gaussian fit (nearly equal), and glTF's
  diffuse weight ``1 - max_rgb(F)`` falls with the angle while ours is the constant ``1 - s``;
* coloured specular: ``max_rgb`` couples the channels, so for strongly coloured ``s`` the
  base colour needed exceeds 1 and is clipped;
* the GGX denominator floor (1e-3) of ours, and 8-bit textures when exported.

``mode="naive"`` (baseColor = d) is the obvious mapping, kept to show what the matching buys;
:func:`fallback` is what a viewer without ``KHR_materials_specular`` shows (f0 = 0.04 grey).

**Beckmann materials** (``distribution="beckmann"``: maps fitted with the Beckmann D, thesis
ch. 6.1.1): glTF has only GGX, so the lobe changes shape. :func:`ggx_roughness` chooses the GGX
roughness: ``"peak"`` (the default) keeps r, i.e. the same alpha: both D's peak at
``1 / (pi alpha^2)`` and at the flash configuration (n = l = v) G/4 = Vis = 1/4 in both, so the
highlight's peak under a flash is exact (as the base colour is matched at normal incidence);
GGX's core is narrower and its tails longer. ``"width"`` matches the half-maximum widths of
``D cos^4`` (r_GGX = r / 0.879, as :func:`mi_svbrdf.eval.studies.output_model.equivalent_roughness`), which
widens GGX's core and lengthens its tails further. Measured with :func:`compare`
(display RMSE under ``eval_lights()``, 64 x 64 examples): metal_plate 0.204 with ``"peak"``,
0.251 with ``"width"`` (its GGX export: 0.010); tiles 0.028 / 0.037 (GGX: 0.002); random maps
(r in [0.2, 0.9], s mostly dielectric) 0.037 / 0.048 (GGX: 0.012). ``"peak"`` was lower on every
material and light set tried, including a flash at the camera and an oblique light; the error is
largest on glossy metals (r ~0.3, s ~0.65), where the lobes' tails dominate most pixels.

All tensors broadcast; vectors have their 3 components in dimension ``dim`` (default -3).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core.maps import SLICES, check_maps
from mi_svbrdf.core.metrics import EvalLights, display, eval_lights
from mi_svbrdf.core.render import render as render_svbrdf
from mi_svbrdf.core.render import texel_positions
from mi_svbrdf.plugins.model import DISTRIBUTIONS

#: F0 of glTF's default dielectric (IOR 1.5): ``((1.5 - 1) / (1.5 + 1))^2``.
DIELECTRIC_F0 = 0.04
#: Roughness floor of the glTF evaluation (as ours: a zero roughness is a delta lobe).
ROUGHNESS_MIN = brdf_torch.ROUGHNESS_MIN
#: Conversion modes of :func:`from_svbrdf`.
MODES = ("matched", "naive")
#: Rules of :func:`ggx_roughness` for a Beckmann material: equal peak (same r) or equal half-maximum width.
ROUGHNESS_RULES = ("peak", "width")
#: ``tan(theta_h)`` at which ``D(h) cos^4(theta_h)`` falls to half its peak, per unit alpha (as
#: :func:`mi_svbrdf.eval.studies.output_model.equivalent_roughness` converts with it): GGX ``sqrt(sqrt(2) - 1)``, Beckmann ``sqrt(ln 2)``.
HALF_WIDTH: dict[str, float] = {"ggx": math.sqrt(math.sqrt(2.0) - 1.0), "beckmann": math.sqrt(math.log(2.0))}


@dataclass(frozen=True)
class GltfMaterial:
    """Per-texel glTF material parameters (all linear), ``(B, C, H, W)`` tensors.

    Attributes:
        base_color: ``(B, 3, H, W)`` baseColor (linear; stored sRGB-encoded in glTF).
        metallic: ``(B, 1, H, W)``.
        roughness: ``(B, 1, H, W)`` perceptual roughness (glTF's alpha = roughness^2).
        normal: ``(B, 3, H, W)`` unit tangent-space normals (OpenGL: +Y up, as glTF).
        specular_color: ``(B, 3, H, W)`` ``KHR_materials_specular`` specularColor
            (factor x texture, may exceed 1).
        specular: ``(B, 1, H, W)`` ``KHR_materials_specular`` specular (strength).
    """

    base_color: torch.Tensor
    metallic: torch.Tensor
    roughness: torch.Tensor
    normal: torch.Tensor
    specular_color: torch.Tensor
    specular: torch.Tensor


def eval_brdf(n: torch.Tensor, wl: torch.Tensor, wv: torch.Tensor, base_color: torch.Tensor,
              metallic: torch.Tensor, roughness: torch.Tensor, specular_color: torch.Tensor,
              specular: torch.Tensor, *, dim: int = -3) -> torch.Tensor:
    """The glTF BRDF value f (no cosine), see the module docstring.

    Args:
        n: unit normals ``(..., 3, H, W)``.
        wl: directions towards the light (normalised here), broadcastable to ``n``.
        wv: directions towards the viewer (normalised here).
        base_color: ``(..., 3, H, W)`` linear baseColor.
        metallic: ``(..., 1, H, W)``.
        roughness: ``(..., 1, H, W)`` perceptual roughness, floored at :data:`ROUGHNESS_MIN`.
        specular_color: ``(..., 3, H, W)`` KHR specularColor (1 without the extension).
        specular: ``(..., 1, H, W)`` KHR specular strength (1 without the extension).
        dim: the vector dimension.

    Returns:
        f with the broadcast shape ``(..., 3, H, W)``. Dot products are clamped at 0, as in the
        Khronos glTF sample viewer (and ours): a normal facing away from the viewer is not masked.
    """
    wl = brdf_torch.normalize(wl, dim)
    wv = brdf_torch.normalize(wv, dim)
    h = brdf_torch.normalize(wl + wv, dim)
    n_l = brdf_torch.dot(n, wl, dim).clamp_min(0.0)
    n_v = brdf_torch.dot(n, wv, dim).clamp_min(0.0)
    n_h = brdf_torch.dot(n, h, dim).clamp_min(0.0)
    v_h = brdf_torch.dot(wv, h, dim).abs()
    alpha = roughness.clamp(ROUGHNESS_MIN, 1.0) ** 2
    a2 = alpha * alpha
    d_term = a2 / (math.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)
    vis_den = n_l * torch.sqrt(n_v * n_v * (1.0 - a2) + a2) + n_v * torch.sqrt(n_l * n_l * (1.0 - a2) + a2)
    vis = torch.where(vis_den > 0.0, 0.5 / vis_den.clamp_min(1e-12), torch.zeros_like(vis_den))
    spec_brdf = vis * d_term
    w = (1.0 - v_h) ** 5
    f0 = (DIELECTRIC_F0 * specular_color).clamp(max=1.0) * specular
    f_diel = f0 + (specular - f0) * w
    dielectric = f_diel * spec_brdf + (1.0 - f_diel.amax(dim=dim, keepdim=True)) * base_color / math.pi
    metal = (base_color + (1.0 - base_color) * w) * spec_brdf
    return (1.0 - metallic) * dielectric + metallic * metal


def ggx_roughness(roughness: torch.Tensor, distribution: str = "ggx", rule: str = "peak") -> torch.Tensor:
    """glTF's (GGX) roughness for our ``roughness`` of model ``distribution`` (see the module docstring).

    Args:
        roughness: any shape, our r (alpha = r^2).
        distribution: ``"ggx"`` (returned as it is) or ``"beckmann"``.
        rule: for Beckmann, ``"peak"`` (r kept: equal D peak, the flash highlight exact) or
            ``"width"`` (equal half-maximum width of ``D cos^4``: r / 0.879, clipped to [0, 1]).

    Returns:
        The same shape.

    Examples:
        >>> round(float(ggx_roughness(torch.tensor(0.5), "beckmann", "width")), 4)
        0.5687
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if rule not in ROUGHNESS_RULES:
        raise ValueError(f"rule: expected one of {ROUGHNESS_RULES}, got {rule!r}")
    if distribution == "ggx" or rule == "peak":
        return roughness
    return (roughness * math.sqrt(HALF_WIDTH["beckmann"] / HALF_WIDTH["ggx"])).clamp(0.0, 1.0)


def from_svbrdf(maps: torch.Tensor, mode: str = "matched", *, distribution: str = "ggx",
                rule: str = "peak") -> GltfMaterial:
    """glTF parameters approximating our maps (see the module docstring for the choice).

    Args:
        maps: ``(B, 10, H, W)`` maps.
        mode: ``"matched"`` (baseColor = d (1 - s) / (1 - max_rgb s), clipped) or ``"naive"``
            (baseColor = d).
        distribution: the maps' microfacet model, ``"ggx"`` or ``"beckmann"``.
        rule: :func:`ggx_roughness`'s rule for a Beckmann material.

    Returns:
        The :class:`GltfMaterial`: metallic 0, specular 1, specularColor = s / 0.04,
        roughness = :func:`ggx_roughness` of r (r itself for GGX and the default rule), the
        maps' (renormalised) normals.
    """
    check_maps(maps)
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    n = brdf_torch.normalize(maps[:, SLICES["normal"]], -3)
    d = maps[:, SLICES["diffuse"]].clamp(0.0, 1.0)
    r = maps[:, SLICES["roughness"]].clamp(0.0, 1.0)
    s = maps[:, SLICES["specular"]].clamp(0.0, 1.0)
    if mode == "matched":
        base = (d * (1.0 - s) / (1.0 - s.amax(dim=1, keepdim=True)).clamp_min(1e-3)).clamp(0.0, 1.0)
    else:
        base = d
    return GltfMaterial(base_color=base, metallic=torch.zeros_like(r), roughness=ggx_roughness(r, distribution, rule),
                        normal=n, specular_color=s / DIELECTRIC_F0, specular=torch.ones_like(r))


def fallback(material: GltfMaterial) -> GltfMaterial:
    """What a viewer without ``KHR_materials_specular`` renders: specularColor 1, specular 1."""
    return replace(material, specular_color=torch.ones_like(material.specular_color),
                   specular=torch.ones_like(material.specular))


def render(material: GltfMaterial, light: torch.Tensor, view: torch.Tensor,
           intensity: torch.Tensor) -> torch.Tensor:
    """Texel rendering of a glTF material on the [-1, 1]^2 plane, as our capture model does.

    ``L = f_glTF * pi * I * c(n . wl) / |P_L - P|^2`` for point lights: the radiance formula of
    :func:`mi_svbrdf.core.render.render` with ``distance_falloff=True``, our BRDF swapped for glTF's.

    Args:
        material: ``(B, C, H, W)`` parameters.
        light: ``(B, K, 3)`` point-light positions.
        view: ``(B, K, 3)`` viewer positions.
        intensity: ``(B, K, 3)`` RGB intensities.

    Returns:
        ``(B, K, 3, H, W)`` linear radiance.
    """
    h, w = material.normal.shape[-2:]
    p = texel_positions(h, w, dtype=material.normal.dtype, device=material.normal.device)[None, None]
    wl = light[..., :, None, None] - p
    wv = view[..., :, None, None] - p

    def per_k(t: torch.Tensor) -> torch.Tensor:
        return t[:, None]

    n = per_k(material.normal)
    f = eval_brdf(n, wl, wv, per_k(material.base_color), per_k(material.metallic), per_k(material.roughness),
                  per_k(material.specular_color), per_k(material.specular))
    cos = brdf_torch.dot(n, brdf_torch.normalize(wl, -3), -3).clamp_min(0.0)
    return f * math.pi * intensity[..., None, None] * cos / brdf_torch.dot(wl, wl, -3).clamp_min(1e-12)


def _rmse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b) ** 2).mean().sqrt())


def compare(maps: torch.Tensor, material: GltfMaterial, lights: EvalLights | None = None, *,
            distribution: str = "ggx") -> dict[str, float]:
    """RMSE between our model's and the glTF model's renderings under the same lights.

    Both are rendered by texel (ours: :func:`mi_svbrdf.core.render.render` with the torch
    backend, glTF: :func:`render`) under point lights with fall-off, each seen from its own
    viewer (default: :func:`mi_svbrdf.core.metrics.eval_lights`, the held-out re-rendering
    lights: 9 lights, every third flash-like).

    Args:
        maps: ``(1, 10, H, W)`` our maps.
        material: the glTF parameters (e.g. :func:`from_svbrdf` of ``maps``).
        lights: the lights (default ``eval_lights()``).
        distribution: the model ``maps`` are rendered with, ``"ggx"`` or ``"beckmann"``.

    Returns:
        ``{"rmse_display": ..., "rmse_linear": ..., "rmse_display_per_light": [...],
        "mean_display": ...}``: display = ``clip(x, 0, 1)^(1/2.2)`` (the project's display
        encoding, :func:`mi_svbrdf.core.metrics.display`), linear = radiance as it is (a white
        Lambertian texel facing a light has radiance ~1).
    """
    check_maps(maps)
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    lights = eval_lights() if lights is None else lights
    b, k = maps.shape[0], lights.count

    def per_batch(t: torch.Tensor) -> torch.Tensor:
        return t.to(maps.dtype)[None].expand(b, k, 3)

    light, view, inten = per_batch(lights.light), per_batch(lights.view), per_batch(lights.intensity)
    ours = render_svbrdf(maps, light, view, intensity=inten, distance_falloff=True, backend="torch",
                         distribution=distribution)
    theirs = render(material, light, view, inten)
    ours_d, theirs_d = display(ours), display(theirs)
    return {"rmse_display": _rmse(ours_d, theirs_d), "rmse_linear": _rmse(ours, theirs),
            "rmse_display_per_light": [_rmse(ours_d[:, i], theirs_d[:, i]) for i in range(k)],
            "mean_display": float(ours_d.mean())}
