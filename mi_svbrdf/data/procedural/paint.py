"""Paint: a coat of paint with brush-stroke relief whose colour ignores the strokes."""
from __future__ import annotations

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="paint",
    params={
        "stroke_frequency": Param(6.0, 2.0, 30.0, "brush strokes across the sample, across their direction"),
        "stroke_length": Param(3.0, 1.0, 10.0, "stroke length / stroke width"),
        "stroke_angle": Param(30.0, 0.0, 180.0, "stroke direction, degrees from the x axis"),
        "bristles": Param(90.0, 20.0, 250.0, "bristle furrows across the sample's width"),
        "relief": Param(1.2, 0.0, 4.0, "paint relief, in thousandths of the sample width"),
        "hue": Param(0.58, 0.0, 1.0, "paint hue (sRGB HSV, turns)"),
        "saturation": Param(0.5, 0.0, 1.0, "paint saturation"),
        "value": Param(0.6, 0.1, 0.95, "paint brightness (sRGB HSV value)"),
        "color_variation": Param(0.15, 0.0, 1.0, "large blotchy colour variation, independent of the strokes"),
        "gloss": Param(0.5, 0.0, 1.0, "0 matte emulsion, 1 high-gloss enamel"),
    },
    doc=("A painted surface: overlapping brush strokes with fine bristle furrows give the coat "
         "its relief, and glossy paint is smoother on the ridges. The colour is decorrelated "
         "from the relief by construction: it is uniform up to large blotches drawn from an "
         "independent noise, so the strokes show only in the normals and roughness (painted "
         "relief, the case the thesis names as a failure source for correlated training data)."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.03, 0.9), "specular": (0.04, 0.05)},
    decorrelated=True,
)


def build(ctx: Context) -> Surface:
    """The paint of a batch (see :data:`CLASS`)."""
    p, x, y = ctx.p, ctx.x, ctx.y
    angle = degrees(p["stroke_angle"])
    length = p["stroke_length"]
    along = p["stroke_frequency"] / length
    strokes = noise.fbm(ctx.gens, x, y, along, octaves=3, stretch=length, angle=angle)
    # Low-frequency fields on a coarse grid: 3 colour blotch channels and the bristles' meander.
    xc, yc = ctx.coarse(34)
    blotch = noise.fbm(ctx.gens, xc, yc, 2.0, octaves=3, channels=4) - 0.5
    meander = ctx.upsample(blotch[:, 3:4], "bilinear") * 0.08  # shifts the furrows across the strokes
    xm, ym = x - torch.sin(angle) * meander, y + torch.cos(angle) * meander
    furrows = noise.fbm(ctx.gens, xm, ym, along, octaves=2, stretch=p["bristles"] * length / p["stroke_frequency"],
                        angle=angle, period=256)
    relief = permille(p["relief"])
    ridge = strokes - 0.5
    height = relief * (3.0 * ridge + 0.8 * (furrows - 0.5))

    cv = p["color_variation"]
    hue = p["hue"] + cv * 0.06 * blotch[:, 0:1]
    sat = (p["saturation"] * (1.0 + cv * 0.8 * blotch[:, 1:2])).clamp(0.0, 1.0)
    val = (p["value"] * (1.0 + cv * 0.5 * blotch[:, 2:3])).clamp(0.0, 1.0)
    diffuse = ctx.upsample(colour(hue, sat, val), "bilinear")  # computed on the coarse grid
    base = mix(0.75, 0.06, p["gloss"])
    roughness = base * (1.0 - 0.4 * ridge) + 0.05 * (furrows - 0.5)
    specular = mix(0.04, 0.05, p["gloss"]).expand_as(roughness)
    return Surface(height=height, diffuse=diffuse, roughness=roughness, specular=specular)
