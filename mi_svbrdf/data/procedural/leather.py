"""Leather: pebbled grain (small rounded cells separated by creases) and wrinkles."""
from __future__ import annotations

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="leather",
    params={
        "grain": Param(35.0, 10.0, 100.0, "grain cells across the sample's width"),
        "crease_width": Param(0.15, 0.03, 0.4, "width of the creases between cells, as a fraction of a cell"),
        "crease_depth": Param(1.2, 0.0, 4.0, "depth of the creases, in thousandths of the sample width"),
        "wrinkles": Param(0.4, 0.0, 1.0, "strength of the large folds and wrinkles"),
        "wrinkle_angle": Param(30.0, 0.0, 180.0, "main direction of the wrinkles, degrees from the x axis"),
        "hue": Param(0.07, 0.0, 1.0, "leather hue (sRGB HSV, turns)"),
        "saturation": Param(0.6, 0.0, 0.9, "leather saturation"),
        "value": Param(0.35, 0.05, 0.8, "leather brightness (sRGB HSV value)"),
        "color_variation": Param(0.3, 0.0, 1.0, "mottling of the dye"),
        "roughness": Param(0.45, 0.2, 0.8, "roughness of the cell tops"),
        "polish": Param(0.4, 0.0, 1.0, "polished, shinier and lighter cell tops"),
    },
    doc=("Dyed leather with a pebbled grain: small irregular rounded cells separated by narrow, "
         "darker and rougher creases, plus larger folds and wrinkles; the dye is mottled and "
         "polished cell tops are shinier. Albedo, roughness and relief are correlated."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.1, 1.0), "specular": (0.035, 0.045)},
)


def build(ctx: Context) -> Surface:
    """The leather of a batch (see :data:`CLASS`)."""
    p, x, y = ctx.p, ctx.x, ctx.y
    cell = 2.0 / p["grain"]
    xw, yw = noise.domain_warp(ctx.gens, x, y, p["grain"] * 0.5, cell * 0.35, octaves=1)
    cells = noise.voronoi(ctx.gens, xw, yw, p["grain"], jitter=0.9, values=1)
    half = p["crease_width"] * 0.5
    top = smoothstep(half * 0.5, half + 0.35, cells.edge)  # 0 in the crease, 1 on the dome
    crease = 1.0 - smoothstep(half * 0.5, half + 0.05, cells.edge)
    xc, yc = ctx.coarse(130)
    folds_c = noise.fbm(ctx.gens, xc, yc, 2.5, octaves=3, stretch=3.0, channels=2, angle=degrees(p["wrinkle_angle"]))
    folds = ctx.upsample(folds_c)
    cv = p["color_variation"]
    mottle = folds_c[:, 1:2] - 0.5  # the dye follows the large folds, on the coarse grid
    base = ctx.upsample(colour(p["hue"] + cv * 0.03 * mottle, p["saturation"],
                               (p["value"] * (1.0 + cv * 0.8 * mottle)).clamp(0, 1)), "bilinear")
    ridge = 1.0 - (folds[:, 0:1] - 0.5).abs() * 2.0
    wrinkle = smoothstep(0.55, 0.95, ridge) * p["wrinkles"]
    depth = permille(p["crease_depth"])
    height = depth * (top * (0.8 + 0.2 * cells.values)) - wrinkle * depth * 2.5 \
        + p["wrinkles"] * depth * 4.0 * (folds[:, 1:2] - 0.5)

    shade = (1.0 - 0.45 * crease) * (1.0 - 0.3 * wrinkle) * (1.0 + 0.2 * p["polish"] * top)
    diffuse = base * shade * (0.95 + 0.1 * cells.values)
    rough_top = p["roughness"] * (1.0 - 0.45 * p["polish"] * top)
    roughness = mix(rough_top, 0.85, crease * 0.8) + 0.1 * wrinkle
    specular = mix(0.04, 0.037, crease)
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
