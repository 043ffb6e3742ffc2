"""Regenerate the small bundled assets of :mod:`mi_svbrdf.scenes` (procedural, deterministic).

The XML scenes default to these files; nothing is downloaded. Run from the repository::

    python scenes/generate_assets.py          # rewrite scenes/textures/*.exr, scenes/envmap.exr
    python scenes/generate_assets.py --check  # exit 1 if the shipped files differ

Assets (all linear float32 OpenEXR, each well under 100 KB):

* ``textures/normal.exr`` (64x64 RGB): encoded normals ``(n + 1) / 2`` of a 4x4 grid of
  rounded studs (a height field differentiated analytically); ``n`` in OpenGL tangent space
  (x right, y up), image row 0 at the top (y = +1).
* ``textures/diffuse.exr`` (RGB), ``textures/roughness.exr`` (one channel ``Y``),
  ``textures/specular.exr`` (RGB): terracotta tiles with cream grout and glossy, more
  specular studs.
* ``envmap.exr`` (64x32 RGB latitude-longitude, Mitsuba's ``envmap`` layout: +Y up in the
  map's frame; the scenes rotate it so +Y maps to world +Z): a blue sky gradient, a dim
  ground and a small sun of radiance ~50 at 40 degrees elevation towards world (+x, +y).
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys

import numpy as np

#: Side of the bundled material maps, in pixels.
MAP_SIZE = 64
#: Size (width, height) of the bundled environment map.
ENVMAP_SIZE = (64, 32)
#: Studs per side of the bundled material.
STUDS = 4
#: World direction the sun of the bundled environment comes from.
SUN_DIRECTION = (math.cos(math.radians(40)) * math.sqrt(0.5),
                 math.cos(math.radians(40)) * math.sqrt(0.5),
                 math.sin(math.radians(40)))

HERE = pathlib.Path(__file__).resolve().parent


def pixel_centres(size: int) -> tuple[np.ndarray, np.ndarray]:
    """World ``(x, y)`` of the pixel centres of a ``size``-square map on the [-1, 1]^2 plane.

    Row ``i``, column ``j`` sits at ``x = -1 + (2j + 1)/size``, ``y = 1 - (2i + 1)/size``.
    """
    c = -1.0 + (2.0 * np.arange(size) + 1.0) / size
    x = np.broadcast_to(c[None, :], (size, size))
    y = np.broadcast_to(-c[:, None], (size, size))
    return x, y


def material_maps(size: int = MAP_SIZE, studs: int = STUDS) -> dict[str, np.ndarray]:
    """The bundled material: ``normal`` (encoded), ``diffuse``, ``roughness``, ``specular`` (HxWxC)."""
    x, y = pixel_centres(size)
    cell = 2.0 / studs
    # Local coordinates in each cell, in [-1, 1].
    lx = ((x + 1.0) % cell) / cell * 2.0 - 1.0
    ly = ((y + 1.0) % cell) / cell * 2.0 - 1.0
    radius, height = 0.6, 0.08
    rho2 = (lx * lx + ly * ly) / (radius * radius)
    inside = rho2 < 1.0
    # Height h = height * (1 - rho^2)^2 inside the stud; d/dx through lx (d lx / dx = 2/cell).
    bump = np.where(inside, 1.0 - rho2, 0.0)
    dh_dl = -4.0 * height * bump / (radius * radius)          # dh/dlx = dh_dl * lx
    scale = 2.0 / cell
    dh_dx, dh_dy = dh_dl * lx * scale, dh_dl * ly * scale
    n = np.stack([-dh_dx, -dh_dy, np.ones_like(x)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)

    grout = (np.abs(lx) > 0.92) | (np.abs(ly) > 0.92)
    stud_rgb, tile_rgb, grout_rgb = (0.10, 0.12, 0.14), (0.55, 0.25, 0.15), (0.80, 0.76, 0.68)
    diffuse = np.empty(x.shape + (3,))
    diffuse[:] = tile_rgb
    diffuse[grout] = grout_rgb
    diffuse[inside] = stud_rgb
    # A slow horizontal gradient makes left and right distinguishable.
    diffuse *= (0.8 + 0.2 * (x[..., None] + 1.0) / 2.0)
    roughness = np.where(inside, 0.25, np.where(grout, 0.85, 0.6))[..., None]
    specular = np.empty(x.shape + (3,))
    specular[:] = 0.04
    specular[inside] = (0.6, 0.5, 0.35)
    return {
        "normal": ((n + 1.0) * 0.5).astype(np.float32),
        "diffuse": diffuse.astype(np.float32),
        "roughness": roughness.astype(np.float32),
        "specular": specular.astype(np.float32),
    }


def sky_envmap(width: int = ENVMAP_SIZE[0], height: int = ENVMAP_SIZE[1]) -> np.ndarray:
    """A procedural sky in Mitsuba's latitude-longitude layout (``height x width x 3``).

    Pixel ``(r, c)`` holds direction ``theta = pi (r + 1/2)/height`` from the map's +Y and
    ``phi = 2 pi (c + 1/2)/width`` with ``d = (sin t sin p, cos t, -sin t cos p)``; the scenes'
    ``rotate x=1 angle=90`` maps it to world ``(dx, -dz, dy)``.
    """
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    t, p = np.meshgrid(theta, phi, indexing="ij")
    local = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], axis=-1)
    world = np.stack([local[..., 0], -local[..., 2], local[..., 1]], axis=-1)
    up = world[..., 2:3]
    sky = np.array([0.35, 0.5, 0.85]) * (0.6 + 0.4 * np.clip(up, 0.0, 1.0)) + 0.15
    ground = np.array([0.12, 0.1, 0.08]) * np.ones_like(up)
    env = np.where(up > 0.0, sky, ground)
    cos_sun = np.clip(world @ np.asarray(SUN_DIRECTION), -1.0, 1.0)
    angle = np.arccos(cos_sun)
    env = env + 50.0 * np.exp(-0.5 * (angle / math.radians(5.0)) ** 2)[..., None] * np.array([1.0, 0.95, 0.85])
    return env.astype(np.float32)


def assets() -> dict[str, np.ndarray]:
    """Every bundled asset by its path relative to the scenes directory."""
    out = {f"textures/{k}.exr": v for k, v in material_maps().items()}
    out["envmap.exr"] = sky_envmap()
    return out


def _read_exr(path: pathlib.Path) -> np.ndarray:
    import mitsuba as mi

    import mi_svbrdf.variant

    mi_svbrdf.variant.ensure_variant()
    arr = np.array(mi.Bitmap(str(path)), copy=True)
    return arr if arr.ndim == 3 else arr[..., None]


def write(directory: pathlib.Path = HERE) -> list[pathlib.Path]:
    """Write every asset below ``directory``; returns the written paths."""
    import mitsuba as mi

    import mi_svbrdf.variant

    mi_svbrdf.variant.ensure_variant()
    written = []
    for rel, arr in assets().items():
        path = directory / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        mi.Bitmap(np.ascontiguousarray(arr)).write(str(path))
        written.append(path)
    return written


def check(directory: pathlib.Path = HERE) -> list[str]:
    """Names of the assets below ``directory`` that are missing or differ from :func:`assets`."""
    bad = []
    for rel, arr in assets().items():
        path = directory / rel
        if not path.exists():
            bad.append(f"{rel} (missing)")
            continue
        stored = _read_exr(path)
        if stored.shape != arr.shape or not np.allclose(stored, arr, rtol=0, atol=1e-6):
            bad.append(rel)
    return bad


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    parser.add_argument("--dir", type=pathlib.Path, default=HERE, help="scenes directory")
    args = parser.parse_args(argv)
    if args.check:
        bad = check(args.dir)
        for rel in bad:
            print(f"differs: {rel}", file=sys.stderr)
        return 1 if bad else 0
    for path in write(args.dir):
        print(f"wrote {path} ({path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
