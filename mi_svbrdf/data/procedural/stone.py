"""Stone: irregular cobbles or flagstones (Voronoi cells) set in mortar."""
from __future__ import annotations

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, permille

CLASS = MaterialClass(
    name="stone",
    params={
        "stone_count": Param(5.0, 2.0, 16.0, "stones across the sample's width"),
        "jitter": Param(0.85, 0.0, 1.0, "irregularity of the layout: 0 square setts, 1 random cobbles"),
        "gap": Param(0.08, 0.0, 0.3, "mortar joint width, as a fraction of a stone's size"),
        "roundness": Param(0.5, 0.0, 1.0, "0 flat flagstones with a narrow chamfer, 1 domed cobbles"),
        "height": Param(15.0, 0.0, 40.0, "stone relief above the mortar, thousandths of the sample width"),
        "detail": Param(0.5, 0.0, 1.0, "bumps, chips and speckles on each stone"),
        "veins": Param(0.2, 0.0, 1.0, "marbling veins in the stone"),
        "hue": Param(0.08, 0.0, 1.0, "stone hue (sRGB HSV, turns)"),
        "saturation": Param(0.12, 0.0, 0.3, "stone saturation"),
        "value": Param(0.5, 0.1, 0.9, "stone brightness (sRGB HSV value)"),
        "color_variation": Param(0.5, 0.0, 1.0, "colour difference between stones"),
        "mortar_value": Param(0.6, 0.1, 0.9, "mortar brightness (sRGB)"),
        "roughness": Param(0.7, 0.3, 0.95, "roughness of the stone surface"),
    },
    doc=("Natural stones — domed cobbles or flat flagstones with chamfered edges — of irregular "
         "shape (warped Voronoi cells) set in recessed, sandy mortar. Each stone has its own "
         "colour, speckles, bumps and optional light marbling veins. Albedo, roughness and relief "
         "are correlated (mortar lower, rougher and of a different colour)."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.2, 1.0), "specular": (0.03, 0.045)},
)


def build(ctx: Context) -> Surface:
    """The stones of a batch (see :data:`CLASS`)."""
    p = ctx.p
    count = p["stone_count"]
    cell_size = 2.0 / count
    xw, yw = noise.domain_warp(ctx.gens, ctx.x, ctx.y, count * 1.5, cell_size * 0.12, octaves=1)
    cv = p["color_variation"]

    def stone_colours(v: torch.Tensor) -> torch.Tensor:
        """Per stone: linear colour (3) and a height factor (1)."""
        hue = p["hue"] + cv * 0.08 * (v[:, 0:1] - 0.5)
        sat = (p["saturation"] * (1.0 + cv * 1.5 * (v[:, 1:2] - 0.5))).clamp(0.0, 1.0)
        val = (p["value"] * (1.0 + cv * 0.7 * (v[:, 2:3] - 0.5))).clamp(0.0, 1.0)
        return torch.cat([colour(hue, sat, val), v[:, 3:4]], dim=1)

    cells = noise.voronoi(ctx.gens, xw, yw, count, jitter=p["jitter"], values=4, attributes=stone_colours)
    texel_cells = (2.0 / ctx.size) / cell_size
    inside = cells.edge - p["gap"] * 0.5  # cell units, positive on the stone
    stone = smoothstep(-texel_cells, texel_cells, inside)
    bevel = 0.04 + 0.4 * p["roundness"]
    d = 1.0 - (inside / bevel).clamp(0.0, 1.0)
    profile = torch.sqrt((1.0 - d * d).clamp_min(0.0))
    detail = noise.fbm(ctx.gens, ctx.x, ctx.y, count * 4.0, octaves=3, gain=0.6, channels=2)
    sand = noise.value_noise(ctx.gens, ctx.x, ctx.y, 160.0, period=256, mode="bilinear")
    xc, yc = ctx.coarse(130)
    vein = ctx.upsample(noise.gradient_noise(ctx.gens, xc, yc, count * 0.8), "bilinear")
    vein = (1.0 - smoothstep(0.0, 0.04, vein.abs())) * p["veins"]
    relief = permille(p["height"])
    bumps = p["detail"] * (detail[:, 0:1] - 0.5)
    stone_height = relief * (profile * (0.75 + 0.25 * cells.values[:, 3:4]) + 0.5 * bumps)
    mortar_height = relief * 0.05 * sand
    height = mix(mortar_height, stone_height, stone)

    speckle = 1.0 + p["detail"] * 0.6 * (detail[:, 1:2] - 0.5) + 0.15 * (sand - 0.5)
    rock = cells.values[:, 0:3] * speckle
    rock = mix(rock, rock * 0.5 + 0.45, vein * 0.8)  # pale veins
    mortar = colour(0.1, 0.1, p["mortar_value"]) * (0.8 + 0.4 * sand)
    diffuse = mix(mortar, rock, stone)
    rough_stone = p["roughness"] - 0.15 * bumps - 0.1 * vein
    roughness = mix(0.92 + 0.05 * sand, rough_stone, stone)
    specular = mix(0.03, 0.04, stone)
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
