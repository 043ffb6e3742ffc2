"""The Mitsuba scene of a dataset job: :class:`SceneRenderer`, and rendering one record of the job.

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
the renderer sets (:data:`~mi_svbrdf.data.dataset.job.RESERVED_PARAMETERS`: ``light_x`` etc. are
drawn per render); the texture parameters ``$normal`` etc., if the scene has them, point to the
bundled placeholder textures (the scene must load; its textures are replaced before the first
render).

**The render** is linear radiance: ``spp`` jittered samples per pixel (default 4) with a box
pixel filter, so each pixel averages its footprint (antialiased; 4 keeps a 256² image near
0.05 CPU·s, 8 halves the aliasing variance for ~20 ms more). It is stored as an 8-bit photo
(:func:`mi_svbrdf.data.dataset.output.photo_codes`).

Examples:
    >>> from mi_svbrdf.core import maps as M
    >>> renderer = SceneRenderer("flash_capture", size=8, spp=1)
    >>> image = renderer.render(M.constant_maps(1, 8, 8), (0.0, 0.0, renderer.cam_z), 10.0, seed=0)
    >>> image.shape, bool(image.mean() > 0)
    ((8, 8, 3), True)
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf import scenes
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import GAMMA
from mi_svbrdf.data.dataset.job import SCENE_PARAMETERS, RenderJob, Shot, draw_shot, shot_maps
from mi_svbrdf.data.dataset.output import MANIFEST_VERSION
from mi_svbrdf.variant import scene_variant

#: ``mi.traverse`` keys updated per render.
TRAVERSE_KEYS = tuple(f"material.{m}.data" for m in M.MAP_NAMES) + ("light.position", "light.intensity.value")


def resolve_scene(scene: str | os.PathLike) -> Path:
    """Path of a bundled scene name (``flash_capture``) or of an XML file.

    Raises:
        ValueError: neither a bundled scene nor an existing ``.xml`` file.
    """
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
                         f"view, camera height; see mi_svbrdf.data.dataset.renderer), got none of "
                         f"{['$' + p for p in missing]} in the file")
    unknown = sorted(set(params) - used)
    if unknown:
        raise ValueError(f"params: expected parameters the scene {path.name} uses ({sorted(used)}), got {unknown}")
    return used


class SceneRenderer:
    """A loaded scene (see the module doc) that renders maps under a point light, re-using its kernels.

    Args:
        scene: bundled scene name or XML path.
        size: film size and map resolution.
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
        with scene_variant("cpu"):  # Mitsuba's scenes are bound to a variant; the renders are numpy arrays
            self._load(scene, size, spp, fov, params)

    def _load(self, scene: str | os.PathLike, size: int, spp: int, fov: float,
              params: Mapping[str, str] | None) -> None:
        import mitsuba as mi

        params = dict(params or {})
        self.path = resolve_scene(scene)
        used = check_scene_file(self.path, params)
        self.size, self.spp, self.fov = int(size), int(spp), float(fov)
        self.cam_z = 1.0 / math.tan(math.radians(self.fov / 2.0))
        values = {"res": str(self.size), "spp": str(self.spp), "fov": repr(self.fov), "cam_z": repr(self.cam_z)}
        values.update(params)
        self.scene_parameters = dict(values)
        bundled = scenes.scene_path("flash_capture").parent / "textures"
        for name in M.MAP_NAMES:  # placeholders: replaced per render, but the file must load
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
        with scene_variant("cpu"):  # free when the caller entered it for the whole job
            textures = M.split(m.detach().to("cpu", torch.float32)[None])
            textures["normal"] = (textures["normal"] + 1.0) * 0.5  # the scene's normal texture holds (n + 1) / 2
            for name, t in textures.items():
                texture = np.ascontiguousarray(t[0].permute(1, 2, 0).numpy())
                self.params[f"material.{name}.data"] = mi.TensorXf(texture)
            rgb = [float(intensity)] * 3 if np.ndim(intensity) == 0 else [float(v) for v in intensity]
            # Opaque values: a new light is a new kernel input, not a new kernel.
            self.params["light.position"] = dr.opaque(mi.Point3f, [float(v) for v in light])
            self.params["light.intensity.value"] = dr.opaque(mi.Color3f, rgb)
            self.params.update()
            image = mi.render(self.scene, seed=int(seed) & 0xFFFFFFFF)
            return np.array(image, dtype=np.float32)[..., :3]


# ------------------------------------------------------------------------------ one render

def render_record(job: RenderJob, renderer: SceneRenderer, shot: Shot, material: str,
                  material_index: int, material_size: int) -> dict[str, Any]:
    """The per-render JSON: every scene parameter used."""
    return {
        "format_version": MANIFEST_VERSION,
        "index": shot.index,
        "material": material,
        "material_index": material_index,
        "material_size": material_size,
        "render": shot.index - material_index * job.renders_per_material,
        "seed": job.seed,
        "mitsuba_seed": shot.mitsuba_seed,
        "scene": job.scene,
        "scene_file": str(renderer.path),
        "scene_parameters": renderer.scene_parameters,
        "spp": job.spp,
        "size": job.size,
        "camera": {"position": [0.0, 0.0, renderer.cam_z], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                   "fov": renderer.fov, "fov_axis": "x"},
        "light": {"type": "point", "position": list(shot.light), "intensity": [shot.intensity] * 3,
                  "exposure": shot.exposure},
        "material_transform": {"angle": shot.angle, "angle_degrees": math.degrees(shot.angle),
                               "zoom": shot.zoom, "scale": shot.scale,
                               "translation": list(shot.translation), "padding": job.shots.padding},
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
    shot = draw_shot(job.seed, index, job.shots, size=job.size, material_size=size_in)
    maps = shot_maps(material, shot, job.size, job.shots.padding)
    linear = renderer.render(maps, shot.light, shot.intensity, shot.mitsuba_seed)
    return maps, linear, render_record(job, renderer, shot, name, material_index, size_in)
