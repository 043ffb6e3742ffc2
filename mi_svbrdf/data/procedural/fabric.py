"""Fabric: woven threads (plain, twill or basket weave) with fibre twist and fuzz."""
from __future__ import annotations

import math

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="fabric",
    params={
        "weave_frequency": Param(40.0, 8.0, 120.0, "threads across the sample's width, in each direction"),
        "pattern": Param(0, 0, 2, "weave: 0 plain, 1 twill (2/2, diagonal ribs), 2 basket (2x2)", integer=True),
        "angle": Param(0.0, 0.0, 180.0, "direction of the warp threads, degrees from the y axis"),
        "gap": Param(0.15, 0.0, 0.5, "space between neighbouring threads, as a fraction of the pitch"),
        "thread_height": Param(2.0, 0.0, 6.0, "thread thickness, in thousandths of the sample width"),
        "fuzz": Param(0.3, 0.0, 1.0, "loose fibres and yarn irregularity"),
        "hue": Param(0.6, 0.0, 1.0, "warp thread hue (sRGB HSV, turns)"),
        "saturation": Param(0.5, 0.0, 1.0, "warp thread saturation"),
        "value": Param(0.5, 0.05, 0.95, "warp thread brightness (sRGB HSV value)"),
        "weft_hue_shift": Param(0.0, 0.0, 0.5, "hue of the weft threads relative to the warp (turns)"),
        "weft_value": Param(0.8, 0.3, 1.0, "brightness of the weft threads relative to the warp"),
        "roughness": Param(0.85, 0.5, 1.0, "roughness of the threads"),
    },
    doc=("Woven cloth: warp and weft threads of possibly different colours cross over and under "
         "each other in a plain, twill or basket weave, each thread rounded, twisted (diagonal "
         "fibre shading) and slightly fuzzy, with dark gaps between threads. Rough and weakly "
         "specular. Albedo and relief are correlated (thread shading and gaps)."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.45, 1.0), "specular": (0.03, 0.045)},
)


def _over(i: torch.Tensor, j: torch.Tensor, pattern: torch.Tensor) -> torch.Tensor:
    """1 where the warp thread i passes over the weft thread j, else 0 (float)."""
    plain = torch.remainder(i + j, 2.0)
    twill = (torch.remainder(i + j, 4.0) < 2.0).float()
    basket = torch.remainder(torch.floor(i * 0.5) + torch.floor(j * 0.5), 2.0)
    return plain * (pattern == 0).float() + twill * (pattern == 1).float() + basket * (pattern == 2).float()


def _thread(across: torch.Tensor, along: torch.Tensor, over: torch.Tensor, gap: torch.Tensor) -> torch.Tensor:
    """Height profile (0..1) of a thread: round across, arching up where it passes over."""
    half = (1.0 - gap) * 0.5
    r = ((across - 0.5) / half).clamp(-1.0, 1.0)
    round_ = torch.sqrt((1.0 - r * r).clamp_min(0.0))
    arch = torch.sin(along * math.pi)  # 0 at the crossings' edges, 1 in the middle
    lift = mix(0.35 - 0.25 * arch, 0.55 + 0.45 * arch, over)
    return round_ * lift


def build(ctx: Context) -> Surface:
    """The fabric of a batch (see :data:`CLASS`)."""
    p = ctx.p
    u, v = noise.rotate(ctx.x, ctx.y, degrees(p["angle"]))
    f = p["weave_frequency"]
    xc, yc = ctx.coarse(130)
    wobble = ctx.upsample(noise.fbm(ctx.gens, xc, yc, f * 0.15, octaves=2, channels=3)) - 0.5
    a = (u + 1.0) * (0.5 * f) + p["fuzz"] * 0.3 * wobble[:, 0:1]
    b = (v + 1.0) * (0.5 * f) + p["fuzz"] * 0.3 * wobble[:, 1:2]
    i, j = torch.floor(a), torch.floor(b)
    fa, fb = a - i, b - j
    over = _over(i, j, p["pattern"])
    warp_h = _thread(fa, fb, over, p["gap"])
    weft_h = _thread(fb, fa, 1.0 - over, p["gap"])
    warp_on_top = (warp_h >= weft_h).float()
    profile = torch.maximum(warp_h, weft_h)
    # Twisted yarn: diagonal fibre bands along each thread.
    twist = torch.sin((mix(fb, fa, 1.0 - warp_on_top) * 4.0 + mix(fa, fb, 1.0 - warp_on_top) * 1.5) * (2.0 * math.pi))
    fuzz = noise.value_noise(ctx.gens, ctx.x, ctx.y, f * 3.0, period=256, mode="bilinear")
    fibre = 0.08 * twist + p["fuzz"] * 0.4 * (fuzz - 0.5)
    height = permille(p["thread_height"]) * (profile + 0.15 * fibre)

    warp_col = colour(p["hue"], p["saturation"], p["value"])
    weft_col = colour(p["hue"] + p["weft_hue_shift"], p["saturation"], p["value"] * p["weft_value"])
    yarn = mix(weft_col, warp_col, warp_on_top) * (1.0 + 0.25 * wobble[:, 2:3])
    shade = (0.45 + 0.55 * profile.clamp(0.0, 1.0)) * (1.0 + fibre)
    diffuse = yarn * shade
    roughness = p["roughness"] + 0.1 * (0.5 - profile) + 0.05 * fibre
    specular = mix(0.03, 0.04, profile.clamp(0.0, 1.0))
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
