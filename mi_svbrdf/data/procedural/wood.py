"""Wood: planks with growth rings (flat-sawn cathedral figure), fibre streaks and pores."""
from __future__ import annotations

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, colour, degrees, permille

CLASS = MaterialClass(
    name="wood",
    params={
        "planks": Param(3, 1, 8, "planks across the sample (perpendicular to the grain)", integer=True),
        "ring_frequency": Param(14.0, 3.0, 60.0, "growth rings per sample width, across the grain"),
        "ring_contrast": Param(0.5, 0.0, 1.0, "darkness of the latewood band of each ring"),
        "latewood": Param(0.3, 0.1, 0.6, "fraction of each ring that is (dark) latewood"),
        "figure": Param(0.5, 0.0, 1.0, "inclination of the log's axis: 0 straight lines, 1 strong arches"),
        "warp": Param(0.4, 0.0, 1.0, "irregularity of the rings"),
        "grain": Param(0.5, 0.0, 1.0, "strength of the fibre streaks and pores along the grain"),
        "angle": Param(90.0, 0.0, 180.0, "grain direction, degrees from the x axis"),
        "gap": Param(0.015, 0.0, 0.06, "groove between planks, as a fraction of the plank width"),
        "hue": Param(0.075, 0.0, 0.15, "wood hue (sRGB HSV, turns: 0 red, 0.08 orange, 0.15 yellow)"),
        "saturation": Param(0.6, 0.2, 0.9, "wood saturation"),
        "value": Param(0.65, 0.1, 0.95, "wood brightness (sRGB HSV value)"),
        "plank_variation": Param(0.4, 0.0, 1.0, "colour difference between planks"),
        "varnish": Param(0.3, 0.0, 1.0, "0 raw matte wood, 1 glossy varnish"),
        "relief": Param(0.6, 0.0, 3.0, "grain relief, in thousandths of the sample width"),
    },
    doc=("Wooden planks side by side along the grain, each cut from its own log: growth rings "
         "with light earlywood and dark latewood form straight lines or cathedral arches, with "
         "fine fibre streaks and dark pores along the grain and grooves between planks. Raw wood "
         "is matte, varnished wood glossy. Relief follows the rings (latewood stands out, as in "
         "brushed wood) and the pores, so albedo and relief are correlated."),
    metal=False,
    ranges={"diffuse": (0.0, 1.0), "roughness": (0.08, 0.95), "specular": (0.03, 0.05)},
)


def build(ctx: Context) -> Surface:
    """The wood of a batch (see :data:`CLASS`)."""
    p = ctx.p
    texel = 2.0 / ctx.size
    angle = degrees(p["angle"])
    s, t = noise.rotate(ctx.x, ctx.y, angle)  # s along the grain, t across
    # The sample's extent across the grain is 2 (|cos| + |sin|): the planks divide exactly that.
    extent = torch.cos(angle).abs() + torch.sin(angle).abs()
    planks = p["planks"]
    plank_width = 2.0 * extent / planks
    tp = (t + extent) / plank_width
    plank = torch.floor(tp)
    ft = tp - plank
    pv = p["plank_variation"]

    def plank_attributes(v: torch.Tensor) -> torch.Tensor:
        """Per plank: log centre offset, log depth, axis inclination, ring phase (4), then the
        linear earlywood (3) and latewood (3) colours."""
        hue = p["hue"] + pv * 0.03 * (v[:, 3:4] - 0.5)
        val = (p["value"] * (1.0 + pv * 0.5 * (v[:, 3:4] - 0.5))).clamp(0.0, 1.0)
        light = colour(hue, p["saturation"], val)
        dark = colour(hue - 0.01, (p["saturation"] * 1.15).clamp(max=1.0), val * (1.0 - 0.65 * p["ring_contrast"]))
        return torch.cat([v[:, 0:3], v[:, 4:5], light, dark], dim=1)

    log = noise.cell_values(ctx.gens, torch.zeros_like(plank), plank, 5, attributes=plank_attributes)
    across = (ft - 0.5 + (log[:, 0:1] - 0.5) * 1.5) * plank_width
    depth = (0.15 + 0.6 * log[:, 1:2]) * plank_width + s * (p["figure"] * 0.25 * (log[:, 2:3] - 0.5))
    xc, yc = ctx.coarse(66)
    warp = ctx.upsample(noise.fbm(ctx.gens, xc, yc, 1.5, octaves=3, stretch=4.0, angle=angle)) - 0.5
    radius = torch.sqrt(across * across + depth * depth) + warp * (p["warp"] * 0.08)
    phase = radius * (0.5 * p["ring_frequency"]) + log[:, 3:4]
    ring = phase - torch.floor(phase)
    late = smoothstep(1.0 - p["latewood"], 1.0 - 0.3 * p["latewood"], ring)
    streak = noise.fbm(ctx.gens, s, t, 2.0, octaves=2, stretch=60.0, period=256, channels=2)
    pores = smoothstep(0.62, 0.8, streak[:, 1:2])
    fibres = (streak[:, 0:1] - 0.5) * 2.0

    border = torch.minimum(ft, 1.0 - ft) * plank_width  # distance to the plank edge
    groove = 1.0 - smoothstep(p["gap"] * plank_width * 0.5, p["gap"] * plank_width * 0.5 + texel, border)
    groove = groove * (p["gap"] > 0).float()

    g = p["grain"]
    diffuse = mix(log[:, 4:7], log[:, 7:10], late) * (1.0 + 0.25 * g * fibres) * (1.0 - 0.45 * g * pores)
    diffuse = diffuse * (1.0 - 0.15 * p["varnish"]) * (1.0 - 0.7 * groove)
    relief = permille(p["relief"])
    height = relief * (0.6 * late + 0.2 * g * fibres - 0.6 * g * pores) - groove * permille(2.0)
    rough_raw = 0.7 + 0.15 * g * pores + 0.05 * fibres
    rough = mix(rough_raw, 0.12 + 0.05 * pores, p["varnish"])
    rough = mix(rough, 0.9, groove)
    spec = mix(0.035, 0.045, p["varnish"])
    return Surface(height=height, diffuse=diffuse, roughness=rough, specular=spec.expand_as(rough))
