"""Ground: soil with lumps and grit, scattered pebbles and drying cracks."""
from __future__ import annotations

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, permille

CLASS = MaterialClass(
    name="ground",
    params={
        "crack_density": Param(4.0, 0.0, 16.0, "crack cells across the sample's width (0: no cracks)"),
        "crack_width": Param(0.03, 0.005, 0.1, "crack width, as a fraction of a crack cell"),
        "pebble_size": Param(0.06, 0.02, 0.15, "pebble diameter, as a fraction of the sample's width"),
        "pebble_density": Param(0.3, 0.0, 1.0, "fraction of pebble sites that hold a pebble"),
        "moisture": Param(0.15, 0.0, 1.0, "wetness: darker, smoother soil"),
        "relief": Param(10.0, 0.0, 30.0, "soil bumpiness, in thousandths of the sample width"),
        "grit": Param(0.5, 0.0, 1.0, "fine granular detail of the soil"),
        "hue": Param(0.07, 0.0, 0.15, "soil hue (sRGB HSV, turns: 0 red clay, 0.07 brown, 0.15 ochre)"),
        "saturation": Param(0.4, 0.05, 0.7, "soil saturation"),
        "value": Param(0.4, 0.1, 0.8, "soil brightness (sRGB HSV value)"),
    },
    doc=("Bare ground: lumpy soil with fine grit, scattered rounded pebbles of varied colours, "
         "and a network of drying cracks (warped Voronoi borders). Wet soil is darker and smoother. "
         "Albedo, roughness and relief are correlated (dark deep cracks, raised pebbles)."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.3, 1.0), "specular": (0.03, 0.045)},
)


def build(ctx: Context) -> Surface:
    """The ground of a batch (see :data:`CLASS`)."""
    p, x, y = ctx.p, ctx.x, ctx.y
    texel = 2.0 / ctx.size
    xc, yc = ctx.coarse(130)
    lumps = ctx.upsample(noise.fbm(ctx.gens, xc, yc, 3.0, octaves=4, gain=0.55, channels=2))
    grit = noise.value_noise(ctx.gens, x, y, 140.0, period=256, channels=2, mode="bilinear")
    relief = permille(p["relief"])
    soil_h = relief * ((lumps[:, 0:1] - 0.5) * 2.0 + 0.15 * p["grit"] * (grit[:, 0:1] - 0.5))

    crack_freq = p["crack_density"].clamp_min(1.0)
    crack_cell = 2.0 / crack_freq
    cx, cy = noise.domain_warp(ctx.gens, x, y, crack_freq * 2.0, crack_cell * 0.15, octaves=1)
    cracks = noise.voronoi(ctx.gens, cx, cy, crack_freq, jitter=0.9)
    half = p["crack_width"] * 0.5
    crack = 1.0 - smoothstep(half, half + texel / crack_cell, cracks.edge)
    crack = crack * smoothstep(0.0, 1.0, p["crack_density"])  # fades out towards 0 cracks
    crack_depth = relief * 0.8 + permille(3.0)
    # Plates between cracks curl up slightly towards their edges.
    curl = (1.0 - smoothstep(0.0, 0.25, cracks.edge)) * smoothstep(0.0, 1.0, p["crack_density"])

    pebble_cells = 1.0 / p["pebble_size"]
    px, py = noise.domain_warp(ctx.gens, x, y, pebble_cells * 2.0, p["pebble_size"] * 0.3, octaves=1)

    def pebble_attributes(v: torch.Tensor) -> torch.Tensor:
        """Per pebble site: presence draw, radius draw (2), linear colour (3)."""
        col = colour(p["hue"] + 0.15 * (v[:, 2:3] - 0.5), 0.05 + 0.25 * v[:, 3:4], 0.3 + 0.45 * v[:, 2:3])
        return torch.cat([v[:, 0:2], col], dim=1)

    peb = noise.voronoi(ctx.gens, px, py, pebble_cells, jitter=0.8, values=4, edges=False,
                        attributes=pebble_attributes)
    present = (peb.values[:, 0:1] < p["pebble_density"]).float()
    radius = 0.25 + 0.15 * peb.values[:, 1:2]  # cell units
    aa = texel * pebble_cells * 0.5
    pebble = (1.0 - smoothstep(radius - aa, radius + aa, peb.f1)) * present
    dome = torch.sqrt((1.0 - (peb.f1 / radius) * (peb.f1 / radius)).clamp_min(0.0))
    pebble_h = dome * radius * (2.0 / pebble_cells) * 0.5

    soil_height = soil_h + relief * 0.3 * curl - crack_depth * crack
    height = mix(soil_height, soil_h + pebble_h, pebble)  # pebbles rest on the soil, over cracks
    wet = p["moisture"]
    soil = colour(p["hue"], p["saturation"], p["value"]) * (1.0 + 0.5 * (lumps[:, 1:2] - 0.5))
    soil = soil * (1.0 + 0.5 * p["grit"] * (grit[:, 1:2] - 0.5)) * (1.0 - 0.45 * wet)
    soil = soil * (1.0 - 0.6 * crack)
    stone_col = peb.values[:, 2:5] * (1.0 - 0.3 * wet)
    diffuse = mix(soil, stone_col, pebble)
    rough_soil = 0.95 - 0.45 * wet + 0.05 * (grit[:, 0:1] - 0.5)
    roughness = mix(rough_soil, 0.55 - 0.2 * wet, pebble)
    specular = mix(0.03 + 0.01 * wet, 0.04, pebble)
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
