"""Ceramic tiles: glazed tiles on a regular grid (square, rectangular or running bond) with grout."""
from __future__ import annotations

import math

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="tiles",
    params={
        "tile_count": Param(4, 1, 16, "tiles across the sample's width", integer=True),
        "aspect": Param(1.0, 1.0, 4.0, "tile width / tile height (rows = tile_count * aspect)"),
        "row_offset": Param(0.0, 0.0, 0.5, "shift of every other row, in tile widths (0.5: running bond)"),
        "grout_width": Param(0.05, 0.0, 0.2, "grout width, as a fraction of the tile height"),
        "bevel": Param(0.1, 0.0, 0.4, "width of the rounded tile edge, as a fraction of the tile height"),
        "depth": Param(6.0, 0.0, 20.0, "tile surface above the grout, in thousandths of the sample width"),
        "tilt": Param(0.5, 0.0, 3.0, "random tilt of each tile (uneven laying), in degrees"),
        "hue": Param(0.08, 0.0, 1.0, "glaze hue (sRGB HSV, turns)"),
        "saturation": Param(0.3, 0.0, 1.0, "glaze saturation"),
        "value": Param(0.75, 0.1, 0.95, "glaze brightness (sRGB HSV value)"),
        "color_variation": Param(0.3, 0.0, 1.0, "colour difference between tiles"),
        "grout_value": Param(0.55, 0.1, 0.9, "grout brightness (sRGB)"),
        "glaze_roughness": Param(0.12, 0.03, 0.6, "roughness of the glaze"),
        "wear": Param(0.2, 0.0, 1.0, "dirt and micro-scratches on the glaze: darker, rougher patches"),
    },
    doc=("Glazed ceramic tiles laid on a regular grid (square, rectangular, or running bond with "
         "row_offset 0.5) and separated by recessed, rough, sandy grout. Each tile has rounded "
         "edges, a slight random tilt, its own colour variation and a smooth, shiny glaze with "
         "dirty, rougher patches. Albedo, roughness and relief are correlated: the grout is "
         "darker, rougher and lower than the tiles."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.03, 1.0), "specular": (0.03, 0.05)},
)


def build(ctx: Context) -> Surface:
    """The tiles of a batch (see :data:`CLASS`)."""
    p, x, y = ctx.p, ctx.x, ctx.y
    texel = 2.0 / ctx.size
    columns = p["tile_count"]
    rows = columns * p["aspect"]
    col, row, fu, fv = noise.grid_cells(x, y, columns, rows, row_offset=p["row_offset"])
    width, height = 2.0 / columns, 2.0 / rows
    # Distance (plane units) from the tile border, positive inside the tile.
    edge = torch.minimum(torch.minimum(fu, 1.0 - fu) * width, torch.minimum(fv, 1.0 - fv) * height)
    inside = edge - p["grout_width"] * height * 0.5
    tile = smoothstep(-0.5 * texel, 0.5 * texel, inside)
    bevel_width = (p["bevel"] * height).clamp_min(texel)
    t = 1.0 - (inside / bevel_width).clamp(0.0, 1.0)
    profile = torch.sqrt((1.0 - t * t).clamp_min(0.0))  # quarter-circle rounded edge
    cv = p["color_variation"]

    def tile_attributes(v: torch.Tensor) -> torch.Tensor:
        """Per tile: linear glaze colour (3), tilt direction and tilt size (2)."""
        hue = p["hue"] + cv * 0.06 * (v[:, 0:1] - 0.5)
        sat = (p["saturation"] * (1.0 + cv * (v[:, 1:2] - 0.5))).clamp(0.0, 1.0)
        val = (p["value"] * (1.0 + cv * 0.6 * (v[:, 2:3] - 0.5))).clamp(0.0, 1.0)
        return torch.cat([colour(hue, sat, val), v[:, 3:5]], dim=1)

    cell = noise.cell_values(ctx.gens, col, row, 5, attributes=tile_attributes)
    tilt_angle = degrees(p["tilt"])
    slope = torch.sin(tilt_angle) / torch.cos(tilt_angle) * cell[:, 4:5]  # tan, tilt size
    phi = cell[:, 3:4] * (2.0 * math.pi)
    local_x, local_y = (fu - 0.5) * width, (0.5 - fv) * height
    tilt = slope * (torch.cos(phi) * local_x + torch.sin(phi) * local_y)
    fields = noise.fbm(ctx.gens, x, y, columns * 3.0, octaves=3, channels=2, mode="bilinear")  # mottling, dirt
    wavy = noise.fbm(ctx.gens, x, y, columns * 2.0, octaves=2)
    sand = noise.value_noise(ctx.gens, x, y, 180.0, period=256, mode="bilinear")
    depth = permille(p["depth"])
    tile_height = depth * (profile + 0.04 * (wavy - 0.5)) + tilt
    grout_height = depth * 0.08 * sand
    h = mix(grout_height, tile_height, tile)

    glaze = cell[:, 0:3] * (1.0 + 0.15 * (fields[:, 0:1] - 0.5))
    dirt = smoothstep(0.5, 0.75, fields[:, 1:2]) * p["wear"]
    glaze = glaze * (1.0 - 0.35 * dirt)
    grout = colour(0.1, 0.12, p["grout_value"]) * (0.8 + 0.4 * sand)
    diffuse = mix(grout, glaze, tile)
    rough_tile = p["glaze_roughness"] + (0.5 - p["glaze_roughness"]).clamp_min(0.0) * dirt
    roughness = mix(0.8 + 0.15 * sand, rough_tile, tile)
    specular = mix(0.03, 0.045, tile)
    return Surface(height=h, diffuse=diffuse, roughness=roughness, specular=specular)
