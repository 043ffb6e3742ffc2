"""Metal: brushed, hammered or polished metal with scratches and tarnish; coloured specular."""
from __future__ import annotations

import math

import torch

from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.noise import mix, smoothstep
from mi_svbrdf.data.procedural.spec import MaterialClass, Param
from mi_svbrdf.data.procedural.surface import Context, Surface, degrees, permille

#: Linear specular albedo (F0) of the palette, in ``palette`` order.
PALETTE = {
    "steel": (0.56, 0.57, 0.58),
    "aluminium": (0.91, 0.92, 0.92),
    "silver": (0.95, 0.93, 0.88),
    "gold": (1.00, 0.71, 0.29),
    "copper": (0.95, 0.64, 0.54),
    "brass": (0.91, 0.78, 0.42),
    "titanium": (0.54, 0.50, 0.45),
}
#: Scratch directions per material (each a layer of parallel line segments).
SCRATCH_LAYERS = 3

CLASS = MaterialClass(
    name="metal",
    params={
        "palette": Param(0, 0, len(PALETTE) - 1, "metal: " + ", ".join(f"{i} {k}" for i, k in enumerate(PALETTE)),
                         integer=True),
        "roughness": Param(0.25, 0.05, 0.7, "base roughness (polished 0.05 to satin 0.7)"),
        "brushed": Param(0.5, 0.0, 1.0, "strength of the brushing streaks"),
        "angle": Param(0.0, 0.0, 180.0, "brushing direction, degrees from the x axis"),
        "hammered": Param(0.0, 0.0, 1.0, "depth of hammer dents"),
        "dent_size": Param(0.1, 0.03, 0.3, "hammer dent diameter, as a fraction of the sample's width"),
        "scratch_density": Param(0.3, 0.0, 1.0, "number of scratches (1: the most)"),
        "tarnish": Param(0.1, 0.0, 1.0, "oxidised patches: darker, rougher, slightly diffuse"),
    },
    doc=("Bare metal: coloured specular from a palette of real metals (steel, aluminium, silver, "
         "gold, copper, brass, titanium) and near-zero diffuse. Brushing streaks along a "
         "direction, optional hammer dents, straight scratches (rougher grooves) and tarnished "
         "patches (darker, rougher, up to 0.05 diffuse). Roughness and relief are correlated "
         "(dents, scratches); the diffuse albedo is almost nil everywhere."),
    metal=True,
    ranges={"diffuse": (0.0, 0.05), "roughness": (0.03, 1.0), "specular": (0.15, 1.0)},
)


def _scratches(ctx: Context, density: torch.Tensor) -> torch.Tensor:
    """Straight scratches ``(B, 1, S, S)`` in [0, 1] (1 on a scratch's axis).

    Each of :data:`SCRATCH_LAYERS` layers is a strongly stretched bilinear value noise at a
    random angle: along a lattice line its value peaks where the line's random values are
    high, so thresholding it leaves thin, straight segments of random length; ``density``
    lowers the threshold.
    """
    angle = ctx.uniform(SCRATCH_LAYERS, 1, 1) * math.pi  # (B, layers, 1, 1)
    lines = noise.layers(ctx.gens, ctx.x, ctx.y, 4.0, count=SCRATCH_LAYERS, lacunarity=1.0, stretch=15.0,
                         angle=angle, spin=False, mode="bilinear")[:, :, 0]
    threshold = 1.0 - 0.12 * density
    scratch = ((lines - threshold) / (1.0 - threshold)).clamp(0.0, 1.0).amax(dim=1, keepdim=True)
    return smoothstep(0.0, 0.3, scratch)


def build(ctx: Context) -> Surface:
    """The metal of a batch (see :data:`CLASS`)."""
    p, x, y = ctx.p, ctx.x, ctx.y
    streaks = noise.fbm(ctx.gens, x, y, 2.0, octaves=2, stretch=60.0, period=256, angle=degrees(p["angle"]))
    xc, yc = ctx.coarse(66)
    patches = ctx.upsample(noise.fbm(ctx.gens, xc, yc, 3.0, octaves=3, gain=0.55, channels=2))
    dents = noise.voronoi(ctx.gens, x, y, 1.0 / p["dent_size"], jitter=0.9, values=1, edges=False)
    dent = (1.0 - dents.f1 * dents.f1 / 0.6).clamp_min(0.0) * (0.7 + 0.3 * dents.values)
    dent_depth = p["dent_size"] * 0.12 * p["hammered"]
    scratched = _scratches(ctx, p["scratch_density"])
    brushed = p["brushed"]
    height = (permille(0.15) * brushed * (streaks - 0.5) - dent_depth * dent - permille(0.3) * scratched
              + permille(0.5) * (patches[:, 1:2] - 0.5))

    tarnish = smoothstep(0.55, 0.75, patches[:, 0:1]) * p["tarnish"]
    index = p["palette"].long().view(-1)
    f0 = torch.tensor(list(PALETTE.values()), dtype=torch.float32)[index].view(-1, 3, 1, 1)
    specular = f0 * (0.93 + 0.14 * (patches[:, 1:2] - 0.5)) * (1.0 - 0.45 * tarnish)
    specular = specular * (1.0 - 0.1 * scratched)
    diffuse = torch.tensor([0.045, 0.035, 0.025]).view(1, 3, 1, 1) * tarnish + 0.005
    rough = p["roughness"] * (1.0 + 0.3 * brushed * (streaks - 0.5) * 2.0) + 0.35 * tarnish
    rough = mix(rough, (rough + 0.15).clamp(max=0.9), scratched * 0.7)
    return Surface(height=height, diffuse=diffuse, roughness=rough, specular=specular)
