"""What a dataset render job is: :class:`RenderJob`, its :class:`ShotRanges` and the draws of each shot.

Each SVBRDF of a material folder (a bank of :mod:`mi_svbrdf.data.bank` or any folder
:class:`mi_svbrdf.io.material_sets.MaterialSet` reads) is rendered ``renders_per_material`` times
through a Mitsuba scene file (:mod:`mi_svbrdf.data.dataset.renderer`), as the thesis rendered its
training set (ch. 3.2): a fronto-parallel camera with a 50 degree field of view filling the frame
with the sample, a small flash (point light) in the camera's plane at a random offset from the
camera, and the material at a random orientation and scale. The material is rotated and scaled
*in map space* (:func:`mi_svbrdf.data.augment.transform_maps`, normals rotated with it) before it
is put on the plane, so the maps written beside the render are the ones seen in the image: pixel
``(i, j)`` shows texel ``(i, j)``, normals in screen space (x right, y up).

**The shot of render i** (:class:`Shot`: where the flash is, how strong, and how the material
lies under the camera). All draws come from ``numpy.random.SeedSequence([seed, i])``, in this
order, so they depend on ``(seed, i)`` only, never on the worker count or order; ranges in
:class:`ShotRanges`:

====================  ===========================================================================
``angle``             material rotation, counter-clockwise, uniform in ``angle`` (default a full turn)
``zoom``              the image shows ``1 / zoom`` of the material's width; log-uniform in ``zoom``
                      (default [1, 2])
``translation``       window centre, uniform per axis within the bound that keeps the rotated
                      window inside the material (:func:`mi_svbrdf.data.augment.max_translation`; 0
                      when it cannot fit: then ``padding`` mirrors the material at its edges)
``light``             ``(ox, oy, cam_z)``: ``ox, oy`` uniform in ``[-light_offset, light_offset]``
                      (default 0.75 sample half-widths, inside the camera's footprint), i.e. in the
                      plane of the camera, parallel to the sample
``exposure``          flash strength k, log-uniform in ``exposure`` (default [1, 3]); the point
                      light's Mitsuba intensity is ``k * pi * cam_z^2``, so ``k`` is the radiance of
                      a white Lambertian texel lit from the camera's distance at normal incidence
                      (the authors' 2019 flash, I = 13 at 2.197, is k ~ 2.7)
``mitsuba_seed``      the ``seed`` of ``mi.render`` (32 bits)
====================  ===========================================================================

The camera is fixed: ``fov`` (default 50 degrees, horizontal) at ``cam_z = 1 / tan(fov / 2)``
looking down -z, so the [-1, 1]^2 sample fills the image.

Examples:
    >>> shot = draw_shot(0, 3, ShotRanges(), size=64, material_size=64)
    >>> shot.index, 1.0 <= shot.zoom <= 2.0, shot.light[2] == ShotRanges().cam_z
    (3, True, True)
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.core.maps import MAP_NAMES
from mi_svbrdf.data.augment import PADDINGS, max_translation, transform_maps

#: Scene parameters (``$name`` in the XML) set at load time.
SCENE_PARAMETERS = ("res", "spp", "fov", "cam_z")
#: Parameters of the bundled scene that the renderer sets: not for ``RenderJob.params``.
RESERVED_PARAMETERS = SCENE_PARAMETERS + MAP_NAMES + ("light_x", "light_y", "light_z", "light_intensity")


@dataclass(frozen=True)
class ShotRanges:
    """Ranges of the random shot of each render: camera field of view, flash offset and strength,
    material rotation, zoom and padding (see the module doc for the draw order)."""

    fov: float = 50.0  # horizontal field of view of the camera, degrees (the thesis: 50)
    light_offset: float = 0.75  # flash offset from the camera axis, x and y ~ U(-v, v), sample half-widths
    exposure: tuple[float, float] = (1.0, 3.0)  # flash strength k (radiance of a white Lambertian texel), log-uniform
    angle: tuple[float, float] = (-180.0, 180.0)  # material rotation in degrees (counter-clockwise), uniform
    zoom: tuple[float, float] = (1.0, 2.0)  # material width / image width, log-uniform
    padding: str = "reflection"  # where the window leaves the material: "reflection" (mirror) or "wrap" (tile)

    def __post_init__(self) -> None:
        check_fields([("fov", 0.0 < self.fov < 180.0, "degrees in (0, 180)", self.fov),
                      ("light_offset", self.light_offset >= 0.0, "a value >= 0", self.light_offset),
                      ("exposure", _is_range(self.exposure, positive=True), "(low, high), 0 < low <= high",
                       self.exposure),
                      ("angle", _is_range(self.angle), "(low, high) degrees, low <= high", self.angle),
                      ("zoom", _is_range(self.zoom, positive=True), "(low, high), 0 < low <= high", self.zoom),
                      ("padding", self.padding in PADDINGS, f"one of {PADDINGS}", self.padding)], "ShotRanges")

    @property
    def cam_z(self) -> float:
        """Camera height at which the ``fov`` camera sees exactly the [-1, 1]^2 sample."""
        return 1.0 / math.tan(math.radians(self.fov / 2.0))


@dataclass(frozen=True)
class RenderJob:
    """What to render; everything here is recorded in ``manifest.json`` (a resume must match it)."""

    materials: str  # folder of materials (strips and/or material folders, see MaterialSet)
    out: str  # output folder
    scene: str = "flash_capture"  # bundled scene name or path of an XML scene (see the renderer module)
    renders_per_material: int = 10  # renders of each material
    seed: int = 0  # job seed: render i's randomness comes from (seed, i) only
    size: int = 256  # image and map resolution (square)
    spp: int = 4  # samples per pixel: jittered, box pixel filter (antialiasing; see the renderer module)
    shard_size: int = 1000  # renders per shard folder
    params: Mapping[str, str] = field(default_factory=dict)  # other $parameters of the scene
    shots: ShotRanges = field(default_factory=ShotRanges)  # ranges of each render's random shot

    def __post_init__(self) -> None:
        check_fields([("renders_per_material", is_int(self.renders_per_material, 1), "an integer >= 1",
                       self.renders_per_material),
                      ("seed", is_int(self.seed, 0), "an integer >= 0", self.seed),
                      ("size", is_int(self.size, 1), "an integer >= 1", self.size),
                      ("spp", is_int(self.spp, 1), "an integer >= 1", self.spp),
                      ("shard_size", is_int(self.shard_size, 1), "an integer >= 1", self.shard_size),
                      ("shots", isinstance(self.shots, ShotRanges), "a ShotRanges", self.shots)], "RenderJob")
        reserved = sorted(set(self.params) & set(RESERVED_PARAMETERS))
        if reserved:
            raise ValueError(f"params: expected other scene parameters than {list(RESERVED_PARAMETERS)} "
                             f"(set from size, spp, shots.fov, and per render: the maps and the light), "
                             f"got {reserved}")
        object.__setattr__(self, "params", {str(k): str(v) for k, v in dict(self.params).items()})


def is_int(value: Any, low: int) -> bool:
    """``value`` is an integer (not a bool) ``>= low``."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low


def _is_range(value: Any, positive: bool = False) -> bool:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        return False
    return math.isfinite(lo) and math.isfinite(hi) and lo <= hi and (lo > 0 or not positive)


# -------------------------------------------------------------------------------- the shot

@dataclass(frozen=True)
class Shot:
    """The random shot of one render: material placement, flash and render seed (see the module doc)."""

    index: int  # render index in the job
    angle: float  # material rotation, radians, counter-clockwise
    zoom: float  # material width / image width
    scale: float  # transform_maps scale: output texels per input texel, zoom * size / material size
    translation: tuple[float, float]  # window centre in material-plane units
    light: tuple[float, float, float]  # point-light position
    exposure: float  # radiance of a white Lambertian texel at distance cam_z, normal incidence
    intensity: float  # Mitsuba point-light intensity, exposure * pi * cam_z^2
    mitsuba_seed: int  # seed of mi.render


def draw_shot(seed: int, index: int, ranges: ShotRanges, *, size: int, material_size: int) -> Shot:
    """The shot of render ``index`` of a job with ``seed`` (a function of both only)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))
    u = rng.random(7)
    mitsuba_seed = int(rng.integers(0, 2**32))
    angle = math.radians(ranges.angle[0] + (ranges.angle[1] - ranges.angle[0]) * u[0])
    zoom = _log_uniform(ranges.zoom, u[1])
    scale = zoom * size / material_size
    bound = float(max_translation(angle, scale, size, material_size)[0])
    translation = ((2.0 * u[2] - 1.0) * bound, (2.0 * u[3] - 1.0) * bound)
    cam_z = ranges.cam_z
    light = ((2.0 * u[4] - 1.0) * ranges.light_offset, (2.0 * u[5] - 1.0) * ranges.light_offset, cam_z)
    exposure = _log_uniform(ranges.exposure, u[6])
    return Shot(int(index), angle, zoom, scale, translation, light, exposure,
                exposure * math.pi * cam_z**2, mitsuba_seed)


def _log_uniform(bounds: tuple[float, float], u: float) -> float:
    lo, hi = math.log(bounds[0]), math.log(bounds[1])
    return math.exp(lo + (hi - lo) * u)


def square_material(material: torch.Tensor) -> torch.Tensor:
    """A ``(10, H, W)`` material cropped to its centred square."""
    h, w = material.shape[-2:]
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    return material[:, top:top + side, left:left + side]


def shot_maps(material: torch.Tensor, shot: Shot, size: int, padding: str) -> torch.Tensor:
    """The material as the shot sees it: ``(10, M, M)`` -> ``(1, 10, size, size)`` screen-space maps."""
    return transform_maps(material[None], shot.angle, shot.scale, shot.translation, size, padding=padding)
