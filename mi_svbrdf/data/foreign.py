"""Foreign captures: a held-out set whose every capture parameter lies outside the training distribution.

The held-out benchmark (:mod:`mi_svbrdf.data.heldout`) holds out materials but photographs them
with the training's own capture distribution. **Foreign captures** (:class:`ForeignSet`) measure
generalisation: materials of classes and parameter ranges training never draws, photographed
with cameras, lights, exposures, white balances, noise and compression training never draws.

**Training ranges** (:func:`training_ranges`) are computed from every capture preset of
:data:`mi_svbrdf.data.photo_setups.PRESETS` (their union: ``multiview`` and ``single_flash``
train the nets, ``ambient`` and ``clean`` are included to be safe); a Gaussian or log-normal
draw counts as its ±4σ interval (all but 6e-5 of the draws). The foreign ranges
(:data:`FOREIGN_RANGES`) are disjoint from them, parameter by parameter (``tests/test_foreign.py``
checks it on the computed ranges and on thousands of draws):

=========================  ==============================  =========================================
parameter                  training (±4σ, all presets)     foreign
=========================  ==============================  =========================================
field of view (degrees)    30 to 55                        64 to 80 (a phone's wide-angle lens)
camera distance            1.92 to 3.73 (= 1/tan(FOV/2))   1.19 to 1.60 (close-up; tied to the FOV)
photo 0 camera offset      max(|x|, |y|) <= 0.25           0.32 to 0.55 (the phone off-centre)
flash distance |P_L|       1.92 to 2.45                    1.0 to 1.7 (a flash close to the sample)
flash angle off the lens   single_flash <= 4.2 degrees;    15 to 35 degrees (an off-camera flash)
                           multiview: independent
flash RGB intensity        1.6 to 116 (I x exposure x WB)  0.28 to 1.4 (under-exposed: weak flash)
white balance (per ch.)    0.88 to 1.12                    0.70 to 0.85 or 1.15 to 1.30 (a colour cast)
cone exponent              1.23 to 20.3                    0.4 to 0.9 (a diffused, wide flash)
cone target max(|x|,|y|)   <= 1.0                          1.06 to 2.0 (aimed beside the sample)
extra lights (count)       0, 1 or 3                       2 (several lights)
extra light elevation      >= 26.57 degrees                4 to 10 degrees (low, raking lamps)
extra light distance       16.5 to 54.7                    4 to 10 (lamps in the room)
extra light RGB intensity  0.011 to 4.03                   4.2 to 5.0 (bright; raking, so not clipped)
noise std                  0.0015 to 0.0166                0.025 to 0.04 (a phone at high ISO)
JPEG quality               never (lossless 8-bit)          40 to 75 (every photo compressed)
=========================  ==============================  =========================================

Not foreign: the directions of photos 1..N-1 (training's hemisphere covers every direction above
8.13 degrees; only grazing views remain, which a rectified photo cannot take), so their camera
positions are foreign by their distance only (elevation 45 to 80 degrees here); the photo
pipeline (clip, gamma 1/2.2, 8 bits) is the same (a phone's), JPEG added after it. The extra
lights are the captures' ambient lights (no fall-off, no cone): the calibration stays exact, so a
calibrated method is told every light, as on the held-out set.

**Materials** (:data:`FOREIGN_CLASSES`, material ``m`` of class ``FOREIGN_CLASSES[m % 4]``): a
procedural base material of a class drawn in its held-out slice (:func:`mi_svbrdf.data.parameter_split.apply_holdout`
``"test"``: never drawn in training), then one transform that takes it outside every class's
ranges (:data:`MATERIAL_RANGES`):

====================  ======================================  ===========================================
class                 foreign parameter                       training (the nine classes)
====================  ======================================  ===========================================
``glazed_tiles``      tiles with a grey specular 0.12-0.22    dielectrics 0.02-0.08, metals >= 0.45
``anodised_metal``    metal relief, dyed diffuse (max channel  metal diffuse <= 0.05; coloured specular
                      0.15-0.35) and a tinted specular with    only on metals, max channel >= 0.45
                      max channel 0.25-0.40
``embossed_leather``  normal slopes x 2.5-3.5 (n = norm(k nx,  slopes as generated (k = 1)
                      k ny, nz))
``micro_weave``       fabric minified by 2-3 (200-360          magnified by 1-1.25 (weave <= 120)
                      threads across the sample)
====================  ======================================  ===========================================

Training's α-mixing of two materials (``mix_probability``) can interpolate between a metal and a
dielectric, so a mix may reach the specular values of ``glazed_tiles`` and ``anodised_metal`` (not
their combination with a bright dye or a glaze over tiles); the slopes of ``embossed_leather`` and
the feature size of ``micro_weave`` are beyond anything a mix makes.

**Regimes** (:data:`REGIMES`, :attr:`ForeignSet.regime`). ``"flash"`` (the default) is the set
above: every photo lit by its own off-camera flash, calibrated. ``"lights"`` tests uncalibrated
multi-image capture, the thesis's own test protocol: photo 0 is a flash at the camera (the light
at photo 0's camera position, its cone as drawn), photos 1..N-1 are lit by lights nobody measured,
an isotropic point light each (cone exponent 0) at elevation :data:`LIGHTS_ELEVATION`, azimuth
U(0, 2π) and distance :data:`LIGHTS_DISTANCE` from the sample centre, its RGB intensity the
flash's (intensity x white balance) times ``(distance / LIGHTS_REFERENCE_DISTANCE)^2``, so that
the exposure stays that of a flash at the foreign flash distance. The room's extra lights are
off (drawn, intensity 0): each photo is lit by its one light. The cameras, white balances, JPEG
qualities and noise are the ``"flash"`` regime's draws (the lights are drawn after them), so the
two regimes photograph the same materials from the same cameras; the lights of photos 1..N-1 (and
so their RGB intensities) are not foreign, only unknown to the method.

**Determinism.** Material ``m`` is a pure function of ``(seed, m, size, n_images, backend, regime)``:
the material and its sample-level draws (extra lights, noise level) come from
``SeedSequence([seed, m, 0])``, photo ``k``'s capture from ``SeedSequence([seed, m, 1, k])`` and
its noise and JPEG from ``SeedSequence([seed, m, 2, k])``, so a set of 4 materials is the prefix
of a set of 16, and a set with 3 photos the prefix of one with 10. Image 0 is the (off-centre)
fronto-parallel photo.

Examples:
    >>> from mi_svbrdf.data.foreign import FOREIGN_RANGES, overlaps, training_ranges
    >>> train = training_ranges()
    >>> [name for name in FOREIGN_RANGES if overlaps(FOREIGN_RANGES[name], train[name])]
    []
"""
from __future__ import annotations

import colorsys
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.render import BACKENDS
from mi_svbrdf.data import procedural
from mi_svbrdf.data.cached_set import CachedSet
from mi_svbrdf.data.parameter_split import apply_holdout
from mi_svbrdf.data.photo_setups import PRESETS, CaptureConfig, Captures, jpeg, photograph, render_captures

#: Seed of the foreign set (training seeds are 0-999; the held-out set's is 2026_1122).
FOREIGN_SEED = 2026_1207
#: Photos drawn per material at most (a set with N photos holds the first N).
MAX_PHOTOS = 50
#: Version of the construction (part of the cache key).
VERSION = 1
#: Foreign material classes, in turn (material m has class FOREIGN_CLASSES[m % 4]), and their base class.
FOREIGN_CLASSES: dict[str, str] = {"glazed_tiles": "tiles", "anodised_metal": "metal",
                                   "embossed_leather": "leather", "micro_weave": "fabric"}
#: Sigmas of a Gaussian (or log-normal) draw that count as its training range.
K_SIGMA = 4.0
#: Number of extra lights of every foreign capture.
EXTRA_LIGHTS = 2

Range = tuple[float, float]
#: Foreign capture ranges (closed intervals; see the module docstring). Each is one interval, except
#: white balance (two: a warm or a cool cast per channel) and the extra light count (a set of ints).
FOREIGN_RANGES: dict[str, Any] = {
    "fov": (64.0, 80.0),
    "camera_distance": (1.0 / math.tan(math.radians(40.0)), 1.0 / math.tan(math.radians(32.0))),
    "view_offset": (0.32, 0.55),
    "light_distance": (1.0, 1.7),
    "light_angle": (15.0, 35.0),
    "flash_intensity": (0.4, 1.1),  # before the white balance; per channel: 0.28 to 1.43
    "flash_rgb": (0.4 * 0.70, 1.1 * 1.30),
    "white_balance": ((0.70, 0.85), (1.15, 1.30)),
    "cone_exponent": (0.4, 0.9),
    "cone_target": (1.5 / math.sqrt(2.0), 2.0),  # max(|x|, |y|) of a target at 1.5-2.0 from the centre
    "extra_lights": (EXTRA_LIGHTS,),
    "extra_elevation": (4.0, 10.0),
    "extra_distance": (4.0, 10.0),
    "extra_rgb": (4.2, 5.0),
    "noise_std": (0.025, 0.04),
    "jpeg_quality": (40, 75),
}
#: Camera elevation of photos 1..N-1 (degrees): not foreign (see the module docstring).
CAMERA_ELEVATION = (45.0, 80.0)
#: Foreign material parameters: {class: (parameter, foreign range, training ranges of the nine classes)}.
MATERIAL_RANGES: dict[str, tuple[str, Range, tuple[Range, ...]]] = {
    "glazed_tiles": ("specular", (0.12, 0.22), ((0.02, 0.08), (0.45, 1.0))),
    "anodised_metal": ("specular_max", (0.25, 0.40), ((0.02, 0.08), (0.45, 1.0))),
    "embossed_leather": ("slope_scale", (2.5, 3.5), ((1.0, 1.0),)),
    "micro_weave": ("scale", (1 / 3, 1 / 2), ((1.0, 1.25),)),
}
#: Dye of anodised_metal: max channel of the linear diffuse albedo (training metals: <= 0.05).
DYE_VALUE = (0.15, 0.35)
#: Capture regimes (see the module docstring): calibrated off-camera flashes, or a flash at the
#: camera (photo 0) and unmeasured point lights (photos 1..N-1).
REGIMES = ("flash", "lights")
#: Elevation (degrees) of the point lights of photos 1..N-1 in the ``"lights"`` regime.
LIGHTS_ELEVATION = (15.0, 75.0)
#: Distance from the sample centre of the point lights of photos 1..N-1 in the ``"lights"`` regime.
LIGHTS_DISTANCE = (1.0, 3.0)
#: A ``"lights"`` light's intensity is the flash's times (distance / this)^2: the foreign flash
#: distance (centre of FOREIGN_RANGES["light_distance"]), so the exposure stays comparable.
LIGHTS_REFERENCE_DISTANCE = 1.35


def overlaps(a: Any, b: Any) -> bool:
    """True when two ranges share a value: closed intervals ``(lo, hi)``, unions of them
    ``((lo, hi), ...)`` or sets of ints ``(k,)`` / ``{k, ...}``."""
    def intervals(r: Any) -> list[Range]:
        if len(r) == 0:
            return []
        if isinstance(r, (set, frozenset)) or (isinstance(r, tuple) and len(r) != 2
                                               and all(isinstance(x, int) for x in r)):
            return [(float(x), float(x)) for x in r]
        if isinstance(r[0], tuple):
            return [tuple(map(float, x)) for x in r]
        return [(float(r[0]), float(r[1]))]

    return any(lo1 <= hi2 and lo2 <= hi1 for lo1, hi1 in intervals(a) for lo2, hi2 in intervals(b))


def within(value: float, r: Any) -> bool:
    """True when ``value`` lies in the range ``r`` (as :func:`overlaps` reads it)."""
    return overlaps((value, value), r)


def training_ranges(k_sigma: float = K_SIGMA, configs: Sequence[CaptureConfig] = ()) -> dict[str, Any]:
    """The ranges every preset of :data:`~mi_svbrdf.data.photo_setups.PRESETS` draws (their union),
    a Gaussian draw counting as its ±``k_sigma`` interval; keys as :data:`FOREIGN_RANGES`.
    ``configs`` adds further capture configs to the union (a training recipe's overrides).

    ``light_angle`` is the single-flash presets' angle between the flash and the lens (``multiview``
    draws the light independently of the camera, at 2.197); ``jpeg_quality`` is ``()``: training
    photos are never JPEG-compressed.
    """
    k = k_sigma
    fovs, offsets, lights, angles, rgb, cones, targets, counts, elev, dist, amb, noise = ([] for _ in range(12))
    wb = []
    for cfg in [*PRESETS.values(), *configs]:
        jit = cfg.fov_jitter_range if cfg.fov_jitter else 0.0
        lo_fov, hi_fov = cfg.fov - jit, cfg.fov + jit
        fovs.append((lo_fov, hi_fov))
        d_lo, d_hi = 1.0 / math.tan(math.radians(hi_fov / 2)), 1.0 / math.tan(math.radians(lo_fov / 2))
        vo = cfg.view_offset_range if cfg.view_offset else 0.0
        offsets.append((0.0, vo))
        wb_lo, wb_hi = ((max(0.0, 1 - k * cfg.white_balance_std), 1 + k * cfg.white_balance_std)
                        if cfg.white_balance else (1.0, 1.0))
        wb.append((wb_lo, wb_hi))
        counts.append(cfg.ambient_lights if cfg.ambient else 0)
        spread = k * cfg.noise_log_std
        noise.append((cfg.noise_median * math.exp(-spread), cfg.noise_median * math.exp(spread))
                     if cfg.noise else (0.0, 0.0))
        if cfg.flash:
            if cfg.flash_at_camera:  # photo 0 only (no hemisphere): light = camera + image-plane offset
                fo = cfg.flash_offset_range
                lights.append((d_lo, math.sqrt(d_hi ** 2 + 2 * (vo + fo) ** 2)))
                angles.append((0.0, math.degrees(math.atan(fo * math.sqrt(2.0) / d_lo))))
            else:
                lo = cfg.light_offset_range if cfg.light_offset else 0.0
                lights.append((cfg.light_height, math.sqrt(cfg.light_height ** 2 + 2 * lo ** 2)))
            if cfg.intensity_jitter:  # |N(10, s)| x exp(N(log 1.5, 0.4)), s = exp(N(-2, 0.5))
                s_hi = math.exp(-2.0 + 0.5 * k)
                i_lo = max(0.0, 10.0 - k * s_hi) * 1.5 * math.exp(-0.4 * k)
                i_hi = (10.0 + k * s_hi) * 1.5 * math.exp(0.4 * k)
            else:
                i_lo = i_hi = cfg.intensity
            rgb.append((i_lo * wb_lo, i_hi * wb_hi))
            e = cfg.cone_exponent
            cones.append((e * math.exp(-k * cfg.cone_exponent_log_std), e * math.exp(k * cfg.cone_exponent_log_std))
                         if cfg.cone_exponent_jitter else (e, e))
            targets.append((0.0, k * cfg.cone_target_std if cfg.cone_target_jitter else 0.0))
        if cfg.ambient:
            elev.append((cfg.ambient_min_elevation, 90.0))
            dist.append((cfg.ambient_distance * math.exp(-k * cfg.ambient_distance_log_std),
                         cfg.ambient_distance * math.exp(k * cfg.ambient_distance_log_std)))
            spread = k * (cfg.ambient_intensity_log_std + cfg.ambient_colour_std)
            amb.append((cfg.ambient_intensity * math.exp(-spread), cfg.ambient_intensity * math.exp(spread)))

    def union(rs: Sequence[Range]) -> Range:
        return (min(r[0] for r in rs), max(r[1] for r in rs))

    fov = union(fovs)
    return {"fov": fov, "camera_distance": (1.0 / math.tan(math.radians(fov[1] / 2)),
                                            1.0 / math.tan(math.radians(fov[0] / 2))),
            "view_offset": union(offsets), "light_distance": union(lights), "light_angle": union(angles),
            "flash_intensity": (union(rgb)[0] / union(wb)[0], union(rgb)[1] / union(wb)[1]),
            "flash_rgb": union(rgb), "white_balance": union(wb), "cone_exponent": union(cones),
            "cone_target": union(targets), "extra_lights": tuple(sorted(set(counts))),
            "extra_elevation": union(elev), "extra_distance": union(dist), "extra_rgb": union(amb),
            "noise_std": union(noise), "jpeg_quality": ()}


# ----------------------------------------------------------------------------- draws
def _generator(*entropy: int) -> torch.Generator:
    state = np.random.SeedSequence(list(entropy)).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(state))


def _u(gen: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=gen))


def _unit(elevation_deg: float, azimuth: float) -> torch.Tensor:
    e = math.radians(elevation_deg)
    return torch.tensor([math.cos(e) * math.cos(azimuth), math.cos(e) * math.sin(azimuth), math.sin(e)])


def _tilt(direction: torch.Tensor, angle_deg: float, around: float) -> torch.Tensor:
    """``direction`` (unit) turned by ``angle_deg`` towards the side at angle ``around`` about it."""
    ref = torch.tensor([0.0, 0.0, 1.0]) if abs(float(direction[2])) < 0.9 else torch.tensor([1.0, 0.0, 0.0])
    a = torch.linalg.cross(direction, ref)
    a = a / a.norm()
    b = torch.linalg.cross(direction, a)
    side = math.cos(around) * a + math.sin(around) * b
    t = math.radians(angle_deg)
    out = math.cos(t) * direction + math.sin(t) * side
    return out / out.norm()


def _check_regime(regime: Any) -> None:
    if regime not in REGIMES:
        raise ValueError(f"regime: expected one of {REGIMES}, got {regime!r}")


def draw_image(gen: torch.Generator, first: bool, *, regime: str = "flash") -> dict[str, Any]:
    """One photo's foreign capture parameters (JSON-ready; see the module docstring).

    Positions (``view``, ``light``, ``cone_target``, ``forward``) are 3-lists on the sample's frame.

    Args:
        gen: the photo's generator (every draw is made whatever ``first`` and ``regime`` are).
        first: photo 0 (off-centre fronto-parallel camera) or one of photos 1..N-1 (camera on
            the hemisphere at elevation :data:`CAMERA_ELEVATION`).
        regime: one of :data:`REGIMES`. ``"lights"`` draws the ``"flash"`` regime's parameters,
            then (after them) a point light at :data:`LIGHTS_ELEVATION` and :data:`LIGHTS_DISTANCE`:
            photo 0's light is moved to its camera, photo k >= 1's light is the point light (cone
            exponent 0, cone aimed at the centre); the photo gets ``light_elevation`` (degrees),
            ``light_azimuth`` (radians), ``light_distance`` and ``intensity_scale`` (the factor
            :func:`foreign_captures` applies to ``flash_intensity x white_balance``; 1 for photo 0).
    """
    _check_regime(regime)
    R = FOREIGN_RANGES
    fov = _u(gen, *R["fov"])
    distance = 1.0 / math.tan(math.radians(fov / 2))
    off_mag, off_angle = _u(gen, *R["view_offset"]), _u(gen, 0.0, 2 * math.pi)
    elevation, azimuth = _u(gen, *CAMERA_ELEVATION), _u(gen, 0.0, 2 * math.pi)
    light_angle, light_side = _u(gen, *R["light_angle"]), _u(gen, 0.0, 2 * math.pi)
    light_distance = _u(gen, *R["light_distance"])
    flash = _u(gen, *R["flash_intensity"])
    casts = [R["white_balance"][int(torch.randint(2, (), generator=gen))] for _ in range(3)]
    balance = [_u(gen, *c) for c in casts]
    exponent = _u(gen, *R["cone_exponent"])
    target_r, target_angle = _u(gen, 1.5, 2.0), _u(gen, 0.0, 2 * math.pi)
    quality = int(torch.randint(R["jpeg_quality"][0], R["jpeg_quality"][1] + 1, (), generator=gen))
    if first:  # the square offset's larger coordinate is off_mag: outside training's box
        c, s = math.cos(off_angle), math.sin(off_angle)
        scale = off_mag / max(abs(c), abs(s))
        view = torch.tensor([c * scale, s * scale, distance])
        forward = torch.tensor([0.0, 0.0, 1.0])
    else:
        forward = _unit(elevation, azimuth)
        view = forward * distance
    to_camera = view / view.norm()
    light = _tilt(to_camera, light_angle, light_side) * light_distance
    if float(light[2]) <= 0.1:  # cannot happen with these ranges; kept as a guard
        raise ValueError(f"light: expected above the sample, got {light.tolist()}")
    c, s = math.cos(target_angle), math.sin(target_angle)
    t_scale = target_r / math.hypot(c, s)
    out = {"fov": fov, "distance": distance, "view": view.tolist(), "light": light.tolist(),
           "light_angle": math.degrees(math.acos(max(-1.0, min(1.0, float(light @ to_camera) / light_distance)))),
           "flash_intensity": flash, "white_balance": balance, "cone_exponent": exponent,
           "cone_target": [c * t_scale, s * t_scale, 0.0], "jpeg_quality": quality,
           "forward": forward.tolist()}
    if regime == "lights":
        out.update(_lights_regime(gen, first, view, to_camera))
    return out


def _lights_regime(gen: torch.Generator, first: bool, view: torch.Tensor, to_camera: torch.Tensor) -> dict[str, Any]:
    """The ``"lights"`` regime's overrides of a photo's parameters (see :func:`draw_image`).

    ``view`` ``(3,)`` is the camera position, ``to_camera`` ``(3,)`` its unit direction.
    """
    elevation, azimuth = _u(gen, *LIGHTS_ELEVATION), _u(gen, 0.0, 2 * math.pi)  # drawn for photo 0 too
    distance = _u(gen, *LIGHTS_DISTANCE)
    if first:  # a flash at the camera: its cone and intensity as drawn
        x, y, z = view.tolist()
        at_camera = math.sqrt(x * x + y * y + z * z)
        return {"light": view.tolist(), "light_angle": 0.0,
                "light_elevation": math.degrees(math.asin(z / at_camera)),
                "light_azimuth": math.atan2(y, x) % (2 * math.pi), "light_distance": at_camera,
                "intensity_scale": 1.0}
    light = _unit(elevation, azimuth) * distance
    cos_angle = float(light @ to_camera) / float(light.norm())
    return {"light": light.tolist(), "light_angle": math.degrees(math.acos(max(-1.0, min(1.0, cos_angle)))),
            "cone_exponent": 0.0, "cone_target": [0.0, 0.0, 0.0], "light_elevation": elevation,
            "light_azimuth": azimuth, "light_distance": distance,
            "intensity_scale": (distance / LIGHTS_REFERENCE_DISTANCE) ** 2}


def draw_sample(gen: torch.Generator) -> dict[str, Any]:
    """A sample's foreign parameters shared by its photos: the extra lights and the noise level."""
    R = FOREIGN_RANGES
    lights = []
    for _ in range(EXTRA_LIGHTS):
        elevation, azimuth = _u(gen, *R["extra_elevation"]), _u(gen, 0.0, 2 * math.pi)
        distance = _u(gen, *R["extra_distance"])
        rgb = [_u(gen, *R["extra_rgb"]) for _ in range(3)]
        lights.append({"position": (_unit(elevation, azimuth) * distance).tolist(), "elevation": elevation,
                       "distance": distance, "intensity": rgb})
    return {"extra_lights": lights, "noise_std": _u(gen, *R["noise_std"])}


def foreign_captures(sample: dict[str, Any], images: Sequence[dict[str, Any]]) -> Captures:
    """The :class:`~mi_svbrdf.data.photo_setups.Captures` (B = 1, N = len(images)) of drawn parameters.

    A photo's RGB intensity is ``flash_intensity x white_balance``, times its ``intensity_scale``
    when it has one (the ``"lights"`` regime).
    """
    def t(key: str) -> torch.Tensor:
        return torch.tensor([[im[key] for im in images]], dtype=torch.float32)

    def rgb_of(im: dict[str, Any]) -> list[float]:
        rgb = [im["flash_intensity"] * w for w in im["white_balance"]]
        return [v * im["intensity_scale"] for v in rgb] if "intensity_scale" in im else rgb

    rgb = torch.tensor([[rgb_of(im) for im in images]])
    extra = sample["extra_lights"]
    return Captures(light=t("light"), view=t("view"), intensity=rgb, cone_target=t("cone_target"),
                    cone_exponent=t("cone_exponent"),
                    ambient_light=torch.tensor([[e["position"] for e in extra]], dtype=torch.float32),
                    ambient_intensity=torch.tensor([[e["intensity"] for e in extra]], dtype=torch.float32),
                    noise_std=torch.tensor([sample["noise_std"]], dtype=torch.float32), fov=t("fov"),
                    distance=t("distance"), flash=True, cone=True, photo=True)


# ----------------------------------------------------------------------------- materials
def _minify(maps: torch.Tensor, size: int) -> torch.Tensor:
    """Antialiased resize of ``maps (B, 10, S, S)`` to ``size``; normals renormalised."""
    out = F.interpolate(maps, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return M.normalize_normals(torch.cat([out[:, :3], out[:, 3:].clamp(0.0, 1.0)], dim=1))


def foreign_material(cls: str, size: int, gen: torch.Generator) -> tuple[torch.Tensor, dict[str, Any]]:
    """One material of foreign class ``cls`` (:data:`FOREIGN_CLASSES`): ``((1, 10, size, size), info)``.

    The base class's parameters are drawn over their whole range, then moved into its held-out
    slice (:func:`~mi_svbrdf.data.parameter_split.apply_holdout` ``"test"``); then the foreign transform
    (module docstring). Every draw is made whatever the class.
    """
    if cls not in FOREIGN_CLASSES:
        raise ValueError(f"cls: expected one of {list(FOREIGN_CLASSES)}, got {cls!r}")
    base = FOREIGN_CLASSES[cls]
    params = apply_holdout(base, procedural.sample_parameters(base, gen), "test")
    seed = int(torch.randint(2**31 - 1, (), generator=gen))
    param, (lo, hi), _ = MATERIAL_RANGES[cls]
    value = _u(gen, lo, hi)
    hue, sat, dye = _u(gen, 0.0, 1.0), _u(gen, 0.7, 0.95), _u(gen, *DYE_VALUE)
    gen_size = round(size / value) if cls == "micro_weave" else size
    maps = procedural.generate_batch(base, [seed], size=gen_size, params=[params])
    info: dict[str, Any] = {"class": cls, "base": base, "params": params, "seed": seed, param: value}
    if cls == "glazed_tiles":
        maps = torch.cat([maps[:, :7], torch.full_like(maps[:, 7:], value)], dim=1)
    elif cls == "anodised_metal":
        colour = torch.tensor(colorsys.hsv_to_rgb(hue, sat, 1.0))  # max channel 1
        diffuse = (colour * dye).view(1, 3, 1, 1) * (M.specular(maps).mean(1, keepdim=True) /
                                                      M.specular(maps).mean().clamp_min(1e-6)).clamp(0.6, 1.4)
        tint = 0.5 + 0.5 * colour  # min channel >= 0.5: a tinted, not a metal's, specular
        spec = (tint / tint.max() * value).view(1, 3, 1, 1).expand_as(diffuse)
        diffuse = diffuse / diffuse.amax().clamp_min(1e-6) * dye  # max channel exactly the dye value
        maps = M.make_maps(M.normal(maps), diffuse, M.roughness(maps), spec.contiguous())
        info.update(dye_hue=hue, dye_saturation=sat, dye_value=dye)
    elif cls == "embossed_leather":
        n = M.normal(maps)
        maps = M.normalize_normals(torch.cat([n[:, :2] * value, n[:, 2:], maps[:, 3:]], dim=1))
    else:
        maps = _minify(maps, size)
    return maps.contiguous(), info


# ----------------------------------------------------------------------------- the set
@dataclass(frozen=True)
class ForeignSet(CachedSet):
    """The foreign-capture set (see the module docstring). ``load()`` returns the tensors.

    Defaults are the held-out set's sizes (:class:`mi_svbrdf.data.heldout.HeldOutSet`).
    """

    kind: ClassVar[str] = "foreign"
    label: ClassVar[str] = "foreign set"
    json_info: ClassVar[bool] = True  # nested captures

    size: int = 256  #: H = W of maps and photos, >= 8
    materials: int = 16  #: M, number of materials (FOREIGN_CLASSES in turn), >= 1
    n_images: int = 10  #: N photos per material, 1 to MAX_PHOTOS: the first N of any larger set
    seed: int = FOREIGN_SEED  #: seed (material m uses SeedSequence([seed, m, ...])), >= 1000
    backend: str = "mitsuba"  #: texel renderer backend of the photos
    cache: bool = True  #: keep the tensors in cache_dir as .pt (atomic write), keyed by every setting
    cache_dir: str | None = None  #: None: ~/.cache/mi_svbrdf/foreign (cached_set.default_cache_dir)
    regime: str = "flash"  #: one of REGIMES (module docstring); part of the cache key unless "flash"

    def __post_init__(self) -> None:
        if not (isinstance(self.size, int) and self.size >= 8):
            raise ValueError(f"size: expected an int >= 8, got {self.size!r}")
        self.check_counts(MAX_PHOTOS)
        if self.backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {self.backend!r}")
        _check_regime(self.regime)

    def key_settings(self) -> dict[str, Any]:
        """The settings that change the tensors (``regime`` only when not ``"flash"``, so that the default set
        keeps its key)."""
        settings = super().key_settings()
        if self.regime == "flash":
            del settings["regime"]
        return settings

    def key_extras(self) -> dict[str, Any]:
        """The construction's version, the foreign and material ranges and torch's version."""
        return {"version": VERSION, "ranges": repr(FOREIGN_RANGES), "materials_ranges": repr(MATERIAL_RANGES),
                "torch": torch.__version__.split("+")[0]}

    def file_name(self, key: str) -> str:
        """``foreign_SIZEpx_Mm_Nn_[REGIME_]KEY.pt`` (no regime for ``"flash"``)."""
        regime = "" if self.regime == "flash" else f"{self.regime}_"
        return f"foreign_{self.size}px_{self.materials}m_{self.n_images}n_{regime}{key}.pt"

    def material(self, m: int) -> dict[str, Any]:
        """Material ``m`` (>= 0) alone: ``{"maps" (1, 10, H, W), "inputs" (1, N, 3, H, W), "captures", "info"}``."""
        if not (isinstance(m, int) and m >= 0):
            raise ValueError(f"m: expected an int >= 0, got {m!r}")
        cls = list(FOREIGN_CLASSES)[m % len(FOREIGN_CLASSES)]
        gen = _generator(self.seed, m, 0)
        maps, info = foreign_material(cls, self.size, gen)
        sample = draw_sample(gen)
        if self.regime == "lights":  # the lights of the photos alone: the room's lamps off
            sample = {**sample, "extra_lights": [{**e, "intensity": [0.0, 0.0, 0.0]} for e in sample["extra_lights"]]}
        images = [draw_image(_generator(self.seed, m, 1, k), k == 0, regime=self.regime)
                  for k in range(self.n_images)]
        captures = foreign_captures(sample, images)
        radiance = render_captures(maps, captures, backend=self.backend)
        photos = []
        for k in range(self.n_images):  # each photo's noise from its own generator: a prefix of any larger N
            photo = photograph(radiance[:, k:k + 1], captures.images(k), _generator(self.seed, m, 2, k))[0, 0]
            photos.append(jpeg(photo, images[k]["jpeg_quality"]))
        info = {"index": m, **info, "capture": {**sample, "images": images}}
        return {"maps": maps, "inputs": torch.stack(photos)[None], "captures": captures, "info": info}

    def classes(self) -> list[str]:
        """The class of each material."""
        return [list(FOREIGN_CLASSES)[m % len(FOREIGN_CLASSES)] for m in range(self.materials)]
