"""Scene-file driven dataset rendering (thesis ch. 3.2): ``mi-svbrdf dataset render``.

Each SVBRDF of a material folder (a bank of :mod:`mi_svbrdf.data.bank` or any folder
:class:`mi_svbrdf.io.material_sets.MaterialSet` reads) is rendered ``renders_per_material`` times
through a Mitsuba scene file with the ``svbrdf_ggx`` plugin, as the thesis rendered its training
set: a fronto-parallel camera with a 50 degree field of view filling the frame with the sample,
a small flash (point light) in the camera's plane at a random offset from the camera, and the
material at a random orientation and scale. The material is rotated and scaled *in map space*
(:func:`mi_svbrdf.data.augment.transform_maps`, normals rotated with it) before it is put on the
plane, so the maps written beside the render are the ones seen in the image: pixel ``(i, j)``
shows texel ``(i, j)``, normals in screen space (x right, y up).

**Capture of render i** (all draws from ``numpy.random.SeedSequence([seed, i])``, in this order,
so they depend on ``(seed, i)`` only, never on the worker count or order; ranges in
:class:`CaptureRanges`):

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

**The photo.** The render (linear radiance; ``spp`` jittered samples per pixel, default 4, with a
box pixel filter: each pixel averages its footprint, i.e. antialiased; 4 keeps a 256² image near
0.05 CPU·s, 8 halves the aliasing variance for ~20 ms more) becomes an 8-bit phone-like photo as
in the authors' pipeline
(:func:`mi_svbrdf.core.flash.photo_pipeline`): clip to [0, 1], encode ``x^(1/2.2)``, quantise
``trunc(255.5 x)``. The strip stores these 8-bit *gamma codes* (like the thesis dataset's
inputs); the linear LDR image, "a gamma-inverted phone photo", is ``(png / 255)^2.2``
(:func:`decode_photo`; equal to ``photo_pipeline`` of the render).

**Scene contract.** Any XML scene works that

- uses the parameters ``$res`` (square film size), ``$spp`` (samples per pixel), ``$fov``
  (horizontal field of view, degrees) and ``$cam_z`` (camera height; a fronto-parallel camera at
  ``(0, 0, cam_z)`` looking at the origin, y up): they are set when the scene is loaded, once per
  worker;
- has a BSDF with ``id="material"`` whose ``normal``, ``diffuse``, ``roughness`` and ``specular``
  are bitmap textures (traverse keys ``material.<map>.data``; normal stored ``(n + 1) / 2``, all
  ``raw``, with the ``to_uv`` flip ``v -> 1 - v`` that puts row 0 at the top, see
  ``scenes/flash_capture.xml``): their data are replaced per render, any resolution;
- has a point emitter with ``id="light"`` (traverse keys ``light.position``,
  ``light.intensity.value``): set per render.

The bundled ``flash_capture`` scene is the reference. Textures are updated in place
(``mi.traverse`` + ``update``) and the light through opaque Dr.Jit values, so the scene is never
re-parsed and no kernel is recompiled after the first render. Other ``$parameters`` of the scene
are passed with ``params`` (``--param KEY=VALUE``, e.g. ``distribution=beckmann``), but not those
the renderer sets (:data:`RESERVED_PARAMETERS`: ``light_x`` etc. are drawn per render); the texture
parameters ``$normal`` etc., if the scene has them, point to the bundled placeholder textures (the
scene must load; its textures are replaced before the first render).

**Output** (``out/``)::

    manifest.json                 the job (scene and its hash, materials, counts, seed, ranges);
                                  written at the start; a run refuses an ``out`` whose manifest differs
    shard_0000/000000.png         strip: input (8-bit gamma codes) | normal | diffuse | roughness | specular
    shard_0000/000000.json        everything used for this render (material, light, camera, transform, seeds)

Render ``i`` (material ``i // renders_per_material``) is in ``shard_{i // shard_size:04d}``. Both
files are written atomically (temporary name, then rename), the PNG first: a render counts as
done only when its JSON exists, so a killed run resumes where it stopped (stray temporary files
are removed, a PNG without its JSON is rendered again) and gives the same bytes as an
uninterrupted run.

Execution (:mod:`mi_svbrdf.data.dataset.workers`): in this process (``workers=1``), in local
processes (``workers=N``) or on a Ray cluster (``ray="auto" | ADDRESS | "local"``); each worker
loads the scene once and renders with one Dr.Jit thread (the least CPU per image).

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.io import strip
    >>> from mi_svbrdf.core import maps as M
    >>> bank = pathlib.Path(tempfile.mkdtemp())
    >>> strip.write_strip(bank / "grey.png", M.constant_maps(1, 16, 16))
    >>> job = RenderJob(materials=str(bank), out=tempfile.mkdtemp(), renders_per_material=2, size=16, spp=2)
    >>> summary = render_dataset(job, progress=False)
    >>> summary.rendered, sorted(p.name for p in (pathlib.Path(job.out) / "shard_0000").iterdir())
    (2, ['000000.json', '000000.png', '000001.json', '000001.png'])
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import re
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch


from mi_svbrdf.data.dataset.output import (MANIFEST_NAME, default_compressor, done_renders, prepare_out,
                                      render_paths, write_json, write_strip_codes)

#: Scene parameters (``$name`` in the XML) set at load time.
SCENE_PARAMETERS = ("res", "spp", "fov", "cam_z")
#: Texture maps of the material, in ``mi.traverse`` as ``material.<map>.data``.
TEXTURE_MAPS = ("normal", "diffuse", "roughness", "specular")
#: Parameters of the bundled capture scene that the renderer sets: not for ``RenderJob.params``.
RESERVED_PARAMETERS = SCENE_PARAMETERS + TEXTURE_MAPS + ("light_x", "light_y", "light_z", "light_intensity")
#: ``mi.traverse`` keys updated per render.
TRAVERSE_KEYS = tuple(f"material.{m}.data" for m in TEXTURE_MAPS) + ("light.position", "light.intensity.value")
#: ``format`` of ``manifest.json``.
MANIFEST_FORMAT = "mi_svbrdf rendered dataset"
#: Version of ``manifest.json`` and of the per-render JSON.
MANIFEST_VERSION = 1
#: Gamma of the 8-bit photo encoding (the authors' plain power law).
GAMMA = 2.2
#: CPU seconds per image of the thesis's renderer (200 000 images in 16 h on 40 CPUs).
THESIS_CPU_SECONDS_PER_IMAGE = 16 * 3600 * 40 / 200_000
_PADDINGS = ("reflection", "wrap")


# ------------------------------------------------------------------------------------- config

@dataclass(frozen=True)
class CaptureRanges:
    """Ranges of the random capture of each render (see the module doc for the draw order)."""

    fov: float = 50.0  # horizontal field of view of the camera, degrees (the thesis: 50)
    light_offset: float = 0.75  # flash offset from the camera axis, x and y ~ U(-v, v), sample half-widths
    exposure: tuple[float, float] = (1.0, 3.0)  # flash strength k (radiance of a white Lambertian texel), log-uniform
    angle: tuple[float, float] = (-180.0, 180.0)  # material rotation in degrees (counter-clockwise), uniform
    zoom: tuple[float, float] = (1.0, 2.0)  # material width / image width, log-uniform
    padding: str = "reflection"  # where the window leaves the material: "reflection" (mirror) or "wrap" (tile)

    def __post_init__(self) -> None:
        checks = [("fov", 0.0 < self.fov < 180.0, "degrees in (0, 180)", self.fov),
                  ("light_offset", self.light_offset >= 0.0, "a value >= 0", self.light_offset),
                  ("exposure", _is_range(self.exposure, positive=True), "(low, high), 0 < low <= high", self.exposure),
                  ("angle", _is_range(self.angle), "(low, high) degrees, low <= high", self.angle),
                  ("zoom", _is_range(self.zoom, positive=True), "(low, high), 0 < low <= high", self.zoom),
                  ("padding", self.padding in _PADDINGS, f"one of {_PADDINGS}", self.padding)]
        _raise_first(checks, "CaptureRanges")

    @property
    def cam_z(self) -> float:
        """Camera height at which the ``fov`` camera sees exactly the [-1, 1]^2 sample."""
        return 1.0 / math.tan(math.radians(self.fov / 2.0))


@dataclass(frozen=True)
class RenderJob:
    """What to render; everything here is recorded in ``manifest.json`` (a resume must match it)."""

    materials: str  # folder of materials (strips and/or material folders, see MaterialSet)
    out: str  # output folder
    scene: str = "flash_capture"  # bundled scene name or path of an XML scene (see the module doc)
    renders_per_material: int = 10  # renders of each material
    seed: int = 0  # job seed: render i's randomness comes from (seed, i) only
    size: int = 256  # image and map resolution (square)
    spp: int = 4  # samples per pixel: jittered, box pixel filter (antialiasing; see the module doc)
    shard_size: int = 1000  # renders per shard folder
    params: Mapping[str, str] = field(default_factory=dict)  # other $parameters of the scene
    capture: CaptureRanges = field(default_factory=CaptureRanges)  # random capture ranges

    def __post_init__(self) -> None:
        checks = [("renders_per_material", _is_int(self.renders_per_material, 1), "an integer >= 1",
                   self.renders_per_material),
                  ("seed", _is_int(self.seed, 0), "an integer >= 0", self.seed),
                  ("size", _is_int(self.size, 1), "an integer >= 1", self.size),
                  ("spp", _is_int(self.spp, 1), "an integer >= 1", self.spp),
                  ("shard_size", _is_int(self.shard_size, 1), "an integer >= 1", self.shard_size),
                  ("capture", isinstance(self.capture, CaptureRanges), "a CaptureRanges", self.capture)]
        _raise_first(checks, "RenderJob")
        reserved = sorted(set(self.params) & set(RESERVED_PARAMETERS))
        if reserved:
            raise ValueError(f"params: expected other scene parameters than {list(RESERVED_PARAMETERS)} "
                             f"(set from size, spp, capture.fov, and per render: the maps and the light), "
                             f"got {reserved}")
        object.__setattr__(self, "params", {str(k): str(v) for k, v in dict(self.params).items()})


def _is_int(value: Any, low: int) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low


def _is_range(value: Any, positive: bool = False) -> bool:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        return False
    return math.isfinite(lo) and math.isfinite(hi) and lo <= hi and (lo > 0 or not positive)


def _raise_first(checks: list[tuple[str, bool, str, Any]], owner: str) -> None:
    for name, ok, want, got in checks:
        if not ok:
            raise ValueError(f"{owner}.{name}: expected {want}, got {got!r}")


# --------------------------------------------------------------------------------- the scene

def resolve_scene(scene: str | os.PathLike) -> Path:
    """Path of a bundled scene name (``flash_capture``) or of an XML file.

    Raises:
        ValueError: neither a bundled scene nor an existing ``.xml`` file.
    """
    from mi_svbrdf import scenes

    text = str(scene)
    path = Path(text).expanduser()
    if path.is_file():
        return path.resolve()
    if text.removesuffix(".xml") in scenes.scene_names():
        return scenes.scene_path(text)
    raise ValueError(f"scene: expected a bundled scene {scenes.scene_names()} or an XML file, "
                     f"got {text!r} (no such file)")


def scene_references(path: Path) -> set[str]:
    """The ``$parameters`` an XML scene uses."""
    return set(re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", path.read_text(encoding="utf-8")))


def check_scene_file(path: Path, params: Mapping[str, str]) -> set[str]:
    """Check that the XML uses every parameter of :data:`SCENE_PARAMETERS` and each of ``params``.

    Returns:
        The ``$parameters`` the scene uses.

    Raises:
        ValueError: naming the file and the missing parameters.
    """
    used = scene_references(path)
    missing = [p for p in SCENE_PARAMETERS if p not in used]
    if missing:
        raise ValueError(f"{path}: expected a capture scene using the parameters "
                         f"{['$' + p for p in SCENE_PARAMETERS]} (film size, samples per pixel, field of "
                         f"view, camera height; see mi_svbrdf.data.dataset.job), got none of "
                         f"{['$' + p for p in missing]} in the file")
    unknown = sorted(set(params) - used)
    if unknown:
        raise ValueError(f"params: expected parameters the scene {path.name} uses ({sorted(used)}), got {unknown}")
    return used


class SceneRenderer:
    """A capture scene loaded once; material, light and seed change per :meth:`render`.

    Args:
        scene: bundled scene name or XML path (see the module doc for the contract).
        size: film size (square) in pixels.
        spp: samples per pixel.
        fov: horizontal field of view in degrees (the camera goes to ``1 / tan(fov / 2)``).
        params: other ``$parameters`` of the scene (strings).

    Attributes:
        path: the XML file.
        cam_z: camera height.
        scene_parameters: the ``$parameter`` values passed to ``mi.load_file`` (but the
            placeholder textures).

    Raises:
        ValueError: naming the file and what is missing when the scene breaks the contract.
    """

    def __init__(self, scene: str | os.PathLike = "flash_capture", *, size: int = 256, spp: int = 4,
                 fov: float = 50.0, params: Mapping[str, str] | None = None) -> None:
        import mitsuba as mi

        from mi_svbrdf import scenes
        from mi_svbrdf.variant import ensure_variant

        ensure_variant()
        params = dict(params or {})
        self.path = resolve_scene(scene)
        used = check_scene_file(self.path, params)
        self.size, self.spp, self.fov = int(size), int(spp), float(fov)
        self.cam_z = 1.0 / math.tan(math.radians(self.fov / 2.0))
        values = {"res": str(self.size), "spp": str(self.spp), "fov": repr(self.fov), "cam_z": repr(self.cam_z)}
        values.update(params)
        self.scene_parameters = dict(values)
        bundled = scenes.scene_path("flash_capture").parent / "textures"
        for name in TEXTURE_MAPS:  # placeholders: replaced per render, but the file must load
            if name in used and name not in params:
                values[name] = str(bundled / f"{name}.exr")
        try:
            self.scene = mi.load_file(str(self.path), **values)
        except RuntimeError as err:
            raise ValueError(f"{self.path}: expected a scene Mitsuba loads with {values}, got: {err}") from err
        self.params = mi.traverse(self.scene)
        missing = [k for k in TRAVERSE_KEYS if k not in self.params.keys()]
        if missing:
            raise ValueError(f"{self.path}: expected a capture scene exposing {list(TRAVERSE_KEYS)} "
                             f"(a BSDF id='material' with bitmap textures normal/diffuse/roughness/specular "
                             f"and a point emitter id='light'), got no {missing}")
        film = self.scene.sensors()[0].film().size()
        if (int(film[0]), int(film[1])) != (self.size, self.size):
            raise ValueError(f"{self.path}: expected a film of $res x $res = {self.size}x{self.size} pixels, "
                             f"got {int(film[0])}x{int(film[1])}")

    def render(self, maps: torch.Tensor, light: Sequence[float], intensity: float | Sequence[float],
               seed: int) -> np.ndarray:
        """Render ``maps`` under a point light at ``light``.

        Args:
            maps: ``(1, 10, S, S)`` or ``(10, S, S)`` canonical maps, ``S`` the film size.
            light: light position ``(x, y, z)``.
            intensity: Mitsuba point-light intensity (W/sr), one value or RGB.
            seed: ``mi.render`` seed (unsigned 32-bit).

        Returns:
            ``(S, S, 3)`` float32 linear radiance.
        """
        import drjit as dr
        import mitsuba as mi

        m = maps[0] if maps.dim() == 4 else maps
        if tuple(m.shape) != (10, self.size, self.size):
            raise ValueError(f"maps: expected shape (10, {self.size}, {self.size}) (the film size), "
                             f"got {tuple(maps.shape)}")
        m = m.detach().to("cpu", torch.float32)
        panels = {"normal": (m[0:3] + 1.0) * 0.5, "diffuse": m[3:6], "roughness": m[6:7], "specular": m[7:10]}
        for name, t in panels.items():
            self.params[f"material.{name}.data"] = mi.TensorXf(np.ascontiguousarray(t.permute(1, 2, 0).numpy()))
        rgb = [float(intensity)] * 3 if np.ndim(intensity) == 0 else [float(v) for v in intensity]
        # Opaque values: a new light is a new kernel input, not a new kernel.
        self.params["light.position"] = dr.opaque(mi.Point3f, [float(v) for v in light])
        self.params["light.intensity.value"] = dr.opaque(mi.Color3f, rgb)
        self.params.update()
        image = mi.render(self.scene, seed=int(seed) & 0xFFFFFFFF)
        return np.array(image, dtype=np.float32)[..., :3]


# ------------------------------------------------------------------------------- the capture

@dataclass(frozen=True)
class Capture:
    """The random capture of one render (see the module doc)."""

    index: int  # render index in the job
    angle: float  # material rotation, radians, counter-clockwise
    zoom: float  # material width / image width
    scale: float  # transform_maps scale: output texels per input texel, zoom * size / material size
    translation: tuple[float, float]  # window centre in material-plane units
    light: tuple[float, float, float]  # point-light position
    exposure: float  # radiance of a white Lambertian texel at distance cam_z, normal incidence
    intensity: float  # Mitsuba point-light intensity, exposure * pi * cam_z^2
    mitsuba_seed: int  # seed of mi.render


def draw_capture(seed: int, index: int, ranges: CaptureRanges, *, size: int, material_size: int) -> Capture:
    """The capture of render ``index`` of a job with ``seed`` (a function of both only)."""
    from mi_svbrdf.data.augment import max_translation

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
    return Capture(int(index), angle, zoom, scale, translation, light, exposure,
                   exposure * math.pi * cam_z**2, mitsuba_seed)


def _log_uniform(bounds: tuple[float, float], u: float) -> float:
    lo, hi = math.log(bounds[0]), math.log(bounds[1])
    return math.exp(lo + (hi - lo) * u)


def capture_maps(material: torch.Tensor, capture: Capture, size: int, padding: str) -> torch.Tensor:
    """The material as the render sees it: ``(10, M, M)`` -> ``(1, 10, size, size)`` screen-space maps."""
    from mi_svbrdf.data.augment import transform_maps

    return transform_maps(material[None], capture.angle, capture.scale, capture.translation, size,
                          padding=padding)


def photo_codes(linear: torch.Tensor) -> torch.Tensor:
    """The 8-bit photo of a linear image: codes ``trunc(255.5 clip(x)^(1/2.2))`` in 0..255 (float), same shape."""
    x = linear.clamp(0.0, 1.0) ** (1.0 / GAMMA)
    return torch.trunc((255.5 * x).clamp(0.0, 255.0))


def decode_photo(stored: torch.Tensor) -> torch.Tensor:
    """The linear LDR image of a stored photo (``codes / 255``, as read from the strip): ``stored^2.2``."""
    return stored.clamp(0.0, 1.0) ** GAMMA


# ------------------------------------------------------------------------------ one render

def render_record(job: RenderJob, renderer: SceneRenderer, capture: Capture, material: str,
                  material_index: int, material_size: int) -> dict[str, Any]:
    """The per-render JSON: every scene parameter used."""
    return {
        "format_version": MANIFEST_VERSION,
        "index": capture.index,
        "material": material,
        "material_index": material_index,
        "material_size": material_size,
        "render": capture.index - material_index * job.renders_per_material,
        "seed": job.seed,
        "mitsuba_seed": capture.mitsuba_seed,
        "scene": job.scene,
        "scene_file": str(renderer.path),
        "scene_parameters": renderer.scene_parameters,
        "spp": job.spp,
        "size": job.size,
        "camera": {"position": [0.0, 0.0, renderer.cam_z], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                   "fov": renderer.fov, "fov_axis": "x"},
        "light": {"type": "point", "position": list(capture.light), "intensity": [capture.intensity] * 3,
                  "exposure": capture.exposure},
        "material_transform": {"angle": capture.angle, "angle_degrees": math.degrees(capture.angle),
                               "zoom": capture.zoom, "scale": capture.scale,
                               "translation": list(capture.translation), "padding": job.capture.padding},
        "input": {"encoding": "8-bit codes of clip(x)^(1/2.2), trunc(255.5 v)", "gamma": GAMMA,
                  "linear": "(png / 255) ** 2.2"},
    }


def render_one(job: RenderJob, renderer: SceneRenderer, material: torch.Tensor, name: str,
               material_index: int, index: int) -> tuple[torch.Tensor, np.ndarray, dict[str, Any]]:
    """Render ``index`` of ``material`` ``(10, M, M)`` without writing it.

    Returns:
        ``(maps, linear, record)``: the screen-space maps ``(1, 10, S, S)``, the linear render
        ``(S, S, 3)`` before the photo pipeline, and the JSON record.
    """
    size_in = material.shape[-1]
    capture = draw_capture(job.seed, index, job.capture, size=job.size, material_size=size_in)
    maps = capture_maps(material, capture, job.size, job.capture.padding)
    linear = renderer.render(maps, capture.light, capture.intensity, capture.mitsuba_seed)
    return maps, linear, render_record(job, renderer, capture, name, material_index, size_in)


def write_render(out: Path, job: RenderJob, index: int, maps: torch.Tensor, linear: np.ndarray,
                 record: Mapping[str, Any], compressor: str = "zlib") -> None:
    """Write render ``index``: the strip PNG (deflated by ``compressor``), then its JSON (each atomically)."""
    png, js = render_paths(out, index, job.shard_size)
    png.parent.mkdir(parents=True, exist_ok=True)
    write_strip_codes(png, maps, photo_codes(torch.from_numpy(linear).permute(2, 0, 1)), compressor)
    write_json(js, record)


def square_material(material: torch.Tensor) -> torch.Tensor:
    """A ``(10, H, W)`` material cropped to its centred square."""
    h, w = material.shape[-2:]
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    return material[:, top:top + side, left:left + side]


# ------------------------------------------------------------------------------- the job

def manifest(job: RenderJob, names: Sequence[str], compressor: str) -> dict[str, Any]:
    """The ``manifest.json`` of ``job`` over the materials ``names`` (in job order), PNGs by ``compressor``."""
    path = resolve_scene(job.scene)
    return {
        "format": MANIFEST_FORMAT,
        "format_version": MANIFEST_VERSION,
        "scene": job.scene,
        "scene_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "params": dict(sorted(job.params.items())),
        "materials": {"root": job.materials, "count": len(names),
                      "names_sha256": hashlib.sha256("\n".join(names).encode()).hexdigest()},
        "renders_per_material": job.renders_per_material,
        "count": len(names) * job.renders_per_material,
        "seed": job.seed,
        "size": job.size,
        "spp": job.spp,
        "shard_size": job.shard_size,
        "capture": json.loads(json.dumps(dataclasses.asdict(job.capture))),
        "png_compressor": compressor,
        "layout": "shard_{i // shard_size:04d}/{i:06d}.png (strip: input | normal | diffuse | roughness | "
                  "specular) + .json; material = i // renders_per_material",
    }


# ----------------------------------------------------------------------------------- the run

@dataclass
class RenderSummary:
    """What :func:`render_dataset` did."""

    out: Path  # output folder
    total: int  # renders of the job
    already_done: int  # renders found done at the start
    rendered: int  # renders made by this run
    remaining: int  # renders still missing after this run (failed materials, limit)
    failed: list[tuple[str, str]]  # (material, reason) of materials that could not be read
    skipped_at_scan: list[tuple[str, str]]  # (path, reason) of entries the material scan skipped
    seconds: float  # wall time of the run
    cpu_seconds: float  # CPU time of this process and of every worker process (their start-up included)
    render_cpu_seconds: float  # CPU time of the workers' tasks only (read, transform, render, write)
    workers: int  # workers started: processes or Ray actors (1: this process; 0: nothing to do)
    executor: str  # "serial", "processes" or "ray"

    @property
    def images_per_second(self) -> float:
        """Renders made per wall-clock second."""
        return self.rendered / max(self.seconds, 1e-9)

    @property
    def cpu_per_image(self) -> float:
        """CPU seconds per render, everything included."""
        return self.cpu_seconds / max(self.rendered, 1)

    @property
    def render_cpu_per_image(self) -> float:
        """CPU seconds per render in the workers' tasks (start-up excluded)."""
        return self.render_cpu_seconds / max(self.rendered, 1)

    def line(self) -> str:
        """The one-line summary printed at the end of a run."""
        ratio = THESIS_CPU_SECONDS_PER_IMAGE / max(self.cpu_per_image, 1e-12)
        return (f"rendered {self.rendered} images ({self.already_done} already done, {self.remaining} missing, "
                f"{len(self.failed)} materials failed) in {self.seconds:.2f} s with {self.workers} "
                f"{self.executor} worker(s): {self.images_per_second:.2f} images/s, "
                f"{self.cpu_per_image:.4f} CPU·s per image ({self.render_cpu_per_image:.4f} in render tasks; "
                f"thesis {THESIS_CPU_SECONDS_PER_IMAGE:.1f}: {ratio:.0f}x less)")


def previous_compressor(out: Path) -> str | None:
    """The PNG compressor of a previous run's manifest in ``out`` (a resume keeps it), if any."""
    try:
        value = json.loads((out / MANIFEST_NAME).read_text(encoding="utf-8")).get("png_compressor")
    except (OSError, ValueError, AttributeError):
        return None
    return value if isinstance(value, str) else None


def absolute_job(job: RenderJob) -> RenderJob:
    """``job`` with absolute ``materials``, ``out`` and scene path (bundled scene names stay names)."""
    from mi_svbrdf import scenes

    scene = job.scene if job.scene in scenes.scene_names() else str(resolve_scene(job.scene))
    return dataclasses.replace(job, scene=scene, materials=str(Path(job.materials).expanduser().resolve()),
                               out=str(Path(job.out).expanduser().resolve()))


def render_dataset(job: RenderJob, *, workers: int = 1, ray: str | None = None, threads: int = 1,
                   limit: int | None = None, progress: bool = True) -> RenderSummary:
    """Render (or resume) the dataset of ``job`` into ``job.out`` (see the module doc).

    Args:
        job: what to render.
        workers: local worker processes (1: this process), or Ray actors with ``ray`` (1: one per
            CPU of the cluster).
        ray: ``None`` (local), ``"auto"`` (the running cluster: ``RAY_ADDRESS`` or ``ray start``),
            an address (``host:6379``, ``ray://host:10001``) or ``"local"`` (start Ray here). An
            already initialised Ray connection is used as it is. ``out`` must be on a file system
            every node sees.
        threads: Dr.Jit threads per worker.
        limit: render at most this many missing images (in index order), then stop; ``None``: all.
        progress: show a progress bar.

    Returns:
        A :class:`RenderSummary`.

    Raises:
        ValueError: bad arguments, a scene breaking the contract, no materials, a manifest mismatch.
    """
    from mi_svbrdf.data.dataset import workers as dataset_workers
    from mi_svbrdf.io.material_sets import MaterialSet

    if not _is_int(workers, 1) or not _is_int(threads, 1):
        raise ValueError(f"workers, threads: expected integers >= 1, got {workers!r}, {threads!r}")
    if limit is not None and not _is_int(limit, 0):
        raise ValueError(f"limit: expected None or an integer >= 0, got {limit!r}")
    start, cpu_start = time.perf_counter(), time.process_time()
    job = absolute_job(job)
    SceneRenderer(job.scene, size=8, spp=1, fov=job.capture.fov, params=job.params)  # fail early on a bad scene
    materials = MaterialSet(job.materials, size=None, on_error="raise")
    if len(materials) == 0:
        raise ValueError(f"materials: expected a folder with at least one readable material, got none in "
                         f"{job.materials} ({len(materials.skipped)} skipped)")
    names = [entry.name for entry in materials.items]
    out = Path(job.out)
    compressor = previous_compressor(out) or default_compressor()
    prepare_out(out, manifest(job, names, compressor))
    total = len(names) * job.renders_per_material
    done = done_renders(out, total, job.shard_size)
    pending = [i for i in range(total) if i not in done]
    if limit is not None:
        pending = pending[:limit]
    tasks = dataset_workers.make_tasks(pending, job.renders_per_material)
    spec = dataset_workers.WorkerSpec(job, materials, threads, compressor)
    from tqdm import tqdm

    bar = tqdm(total=total, initial=len(done), desc=f"dataset -> {out}", unit="img", disable=not progress,
               file=sys.stderr)
    run = dataset_workers.Run(spec, tasks, workers=workers, ray=ray)
    rendered, failed, task_cpu = 0, [], 0.0
    try:
        for result in run:
            rendered += len(result.done)
            task_cpu += result.cpu_task
            if result.failed is not None:
                failed.append(result.failed)
            bar.update(len(result.done))
    finally:
        bar.close()
    cpu = time.process_time() - cpu_start + run.worker_cpu
    executor = "ray" if ray is not None else ("processes" if workers > 1 else "serial")
    remaining = total - len(done_renders(out, total, job.shard_size))
    return RenderSummary(out, total, len(done), rendered, remaining, failed,
                         [(str(p), r) for p, r in materials.skipped], time.perf_counter() - start, cpu,
                         task_cpu, run.workers, executor)
