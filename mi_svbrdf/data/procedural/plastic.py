"""Plastic: a printed two-colour pattern under a clear coat over a moulded surface texture."""
from __future__ import annotations

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="plastic",
    params={
        "pattern": Param(0, 0, 3, "printed pattern: 0 camouflage blobs, 1 stripes, 2 dots, 3 checker", integer=True),
        "pattern_scale": Param(4.0, 1.0, 16.0, "pattern repeats across the sample's width"),
        "pattern_angle": Param(0.0, 0.0, 180.0, "pattern orientation, degrees"),
        "hue": Param(0.0, 0.0, 1.0, "first ink hue (sRGB HSV, turns)"),
        "saturation": Param(0.7, 0.0, 1.0, "ink saturation"),
        "value": Param(0.75, 0.1, 0.95, "first ink brightness (sRGB HSV value)"),
        "hue_shift": Param(0.5, 0.0, 0.5, "hue of the second ink relative to the first (turns)"),
        "value2": Param(0.3, 0.05, 0.95, "second ink brightness (sRGB HSV value)"),
        "texture": Param(0.4, 0.0, 1.0, "strength of the moulded stipple texture"),
        "texture_scale": Param(50.0, 10.0, 120.0, "stipple bumps across the sample's width"),
        "relief": Param(0.8, 0.0, 2.0, "stipple relief, in thousandths of the sample width"),
        "roughness": Param(0.15, 0.02, 0.6, "roughness of the clear coat"),
    },
    doc=("Moulded plastic with a printed two-colour pattern (camouflage blobs, stripes, dots or "
         "checker) under a clear coat. The print has no relief and the moulded stipple texture "
         "has no colour: albedo and relief are decorrelated by construction (a printed pattern "
         "under a clear coat). Roughness follows the stipple slightly."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.0, 0.75), "specular": (0.05, 0.05)},
    decorrelated=True,
)


def build(ctx: Context) -> Surface:
    """The plastic of a batch (see :data:`CLASS`)."""
    p = ctx.p
    aa = 2.0 / ctx.size * p["pattern_scale"] * 0.5  # one texel in pattern units
    angle = degrees(p["pattern_angle"])
    u, v = noise.rotate(ctx.x, ctx.y, angle)
    pu, pv = (u + 1.0) * (0.5 * p["pattern_scale"]), (v + 1.0) * (0.5 * p["pattern_scale"])
    camo_field = noise.fbm(ctx.gens, ctx.x, ctx.y, p["pattern_scale"], octaves=3, gain=0.45, angle=angle)
    camo = smoothstep(0.5 - aa, 0.5 + aa, camo_field)
    fu, fv = pu - torch.floor(pu), pv - torch.floor(pv)
    stripes = smoothstep(-aa, aa, 0.25 - (fu - 0.5).abs())
    dist = torch.sqrt((fu - 0.5) * (fu - 0.5) + (fv - 0.5) * (fv - 0.5))
    dots = smoothstep(0.3 + aa, 0.3 - aa, dist)
    checker = torch.remainder(torch.floor(pu) + torch.floor(pv), 2.0)
    edge = torch.minimum(torch.minimum(fu, 1.0 - fu), torch.minimum(fv, 1.0 - fv))
    checker = mix(0.5, checker, smoothstep(0.0, aa, edge))
    pattern = p["pattern"]
    ink = sum(field * (pattern == k).float() for k, field in enumerate((camo, stripes, dots, checker)))
    first = colour(p["hue"], p["saturation"], p["value"])
    second = colour(p["hue"] + p["hue_shift"], p["saturation"], p["value2"])
    diffuse = mix(first, second, ink)

    stipple = noise.fbm(ctx.gens, ctx.x, ctx.y, p["texture_scale"], octaves=2, gain=0.4, period=128)
    xc, yc = ctx.coarse(34)
    wave = ctx.upsample(noise.value_noise(ctx.gens, xc, yc, 3.0))
    tex = p["texture"] * (stipple - 0.5)
    height = permille(p["relief"]) * (2.0 * tex + 0.5 * (wave - 0.5))
    roughness = p["roughness"] * (1.0 + 0.6 * tex)
    specular = torch.full_like(roughness, 0.05)
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
