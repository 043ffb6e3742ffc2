"""Mitsuba scenes of mi_svbrdf: the bundled XML scenes and scenes built from map tensors.

This package is the repository's ``scenes/`` directory, installed as ``mi_svbrdf.scenes``: the
XML files and their small generated assets (``generate_assets.py``) ship as its package data,
and this module is its Python API. Each scene's parameters and defaults are documented at the
top of its file:

=====================  ======================================================================
``flash_capture``      fronto-parallel 50 degree camera covering the [-1, 1]^2 plane, point
                       light (flash) at the camera (thesis ch. 3)
``multiview_capture``  camera and light positions as parameters (ch. 4)
``ambient_capture``    environment lighting, no flash (ch. 5 guidance images)
``relight``            oblique preview under an environment map, ``path`` integrator
=====================  ======================================================================

Orientation (verified by ``tests/test_scenes.py``): the default ``rectangle`` spans
[-1, 1]^2 at z = 0 with normal +z and local shading frame (+X, +Y, +Z); its ``uv`` is
``((x + 1)/2, (y + 1)/2)`` and a Mitsuba bitmap's row 0 sits at ``v = 0``. Every material
bitmap therefore gets the ``to_uv`` transform ``v -> 1 - v``, which puts map row ``i``,
column ``j`` at ``x = -1 + (2j + 1)/W``, ``y = 1 - (2i + 1)/H`` (row 0 at the top), and the
tangent-space normal ``(x, y, z)`` equals the world normal. The fronto-parallel sensor of
:func:`capture_sensor` images that plane with pixel ``(i, j)`` on map texel ``(i, j)``.

Examples:
    >>> import mitsuba as mi
    >>> from mi_svbrdf import scenes
    >>> from mi_svbrdf.core import maps as M
    >>> scenes.scene_names()
    ['ambient_capture', 'flash_capture', 'multiview_capture', 'relight']
    >>> scene = scenes.load_scene("flash_capture", res=16, spp=1, light_x=0.2)
    >>> m = M.constant_maps(1, 8, 8, roughness=0.3)
    >>> scene = scenes.plane_scene(m, sensor=scenes.capture_sensor(8, spp=4),
    ...                            emitter={"type": "point", "position": [0, 0, 2.1445],
    ...                                     "intensity": {"type": "rgb", "value": 14.45}})
    >>> "material.diffuse.data" in mi.traverse(scene).keys()
    True
"""
from __future__ import annotations

import math
import os
import pathlib
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import Any

import mitsuba as mi
import numpy as np
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.plugins.model import DISTRIBUTIONS
from mi_svbrdf.variant import ensure_variant

#: Field of view (degrees) of the capture camera.
CAPTURE_FOV = 50.0
#: Distance at which a ``CAPTURE_FOV`` camera sees exactly the [-1, 1]^2 plane: 1/tan(25 deg).
CAPTURE_DISTANCE = 1.0 / math.tan(math.radians(CAPTURE_FOV / 2.0))
#: Texture filters accepted by :func:`material_bsdf` (distributions: ``model.DISTRIBUTIONS``).
FILTER_TYPES = ("bilinear", "nearest")


def flip_v() -> mi.ScalarTransform4f:
    """The bitmap ``to_uv`` transform ``v -> 1 - v`` that puts image row 0 at y = +1."""
    return mi.ScalarTransform4f().translate([0.0, 1.0, 0.0]).scale([1.0, -1.0, 1.0])


def _scenes_dir() -> pathlib.Path:
    """The directory of the bundled scenes: this package's own (``scenes/`` in the repository)."""
    return pathlib.Path(__file__).resolve().parent


def scene_names() -> list[str]:
    """Names of the bundled XML scenes (file stems), sorted."""
    return sorted(p.stem for p in _scenes_dir().glob("*.xml"))


def scene_path(name: str) -> pathlib.Path:
    """Path of the bundled scene ``name`` (with or without ``.xml``) in the installed package."""
    stem = name[:-4] if name.endswith(".xml") else name
    names = scene_names()
    if stem not in names:
        raise ValueError(f"scene: unknown scene {name!r}; expected one of {names}")
    return _scenes_dir() / f"{stem}.xml"


def scene_parameters(name: str) -> dict[str, str]:
    """The parameters of scene ``name`` with their default values (as written in the XML)."""
    root = ET.parse(scene_path(name)).getroot()
    return {el.attrib["name"]: el.attrib["value"] for el in root.iter("default")}


def _param_string(key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, os.PathLike):
        return str(pathlib.Path(value).resolve())
    if isinstance(value, str):
        return value
    raise TypeError(f"scene parameter {key!r}: expected a number, bool, str or path, "
                    f"got {type(value).__name__}")


def load_scene(name: str, **params: Any) -> mi.Scene:
    """Load the bundled scene ``name`` with the given parameter overrides.

    Args:
        name: one of :func:`scene_names`.
        **params: overrides of the scene's ``$parameters`` (numbers, bools, strings or paths;
            relative string paths are resolved by Mitsuba against the scene directory first,
            then the working directory; ``pathlib.Path`` values are made absolute).

    Raises:
        ValueError: for an unknown scene or parameter (the message lists the valid
            parameters with their defaults).
    """
    ensure_variant()
    defaults = scene_parameters(name)
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        valid = ", ".join(f"{k}={v}" for k, v in defaults.items())
        raise ValueError(f"load_scene({name!r}): unknown parameter(s) {unknown}; "
                         f"valid parameters (with defaults): {valid}")
    kwargs = {k: _param_string(k, v) for k, v in params.items()}
    return mi.load_file(str(scene_path(name)), **kwargs)


def _hwc(t: torch.Tensor) -> np.ndarray:
    """``(C, H, W)`` tensor -> contiguous float32 ``(H, W, C)`` array."""
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def _bitmap_texture(array: np.ndarray, filter_type: str) -> dict:
    return {"type": "bitmap", "bitmap": mi.Bitmap(array), "raw": True, "filter_type": filter_type,
            "wrap_mode": "clamp", "to_uv": flip_v()}


def material_bsdf(maps: torch.Tensor, distribution: str = "ggx",
                  filter_type: str = "bilinear") -> dict:
    """A ``mi.load_dict``-ready ``svbrdf_<distribution>`` BSDF dict with bitmap textures.

    Args:
        maps: canonical maps ``(1, 10, H, W)`` or ``(10, H, W)`` (see :mod:`mi_svbrdf.core.maps`).
        distribution: ``"ggx"`` or ``"beckmann"``.
        filter_type: ``"bilinear"`` or ``"nearest"`` texture lookups.

    Returns:
        The dict; its textures are linear (``raw``) bitmaps with ``wrap_mode="clamp"`` and the
        ``to_uv`` flip that puts map row 0 at y = +1. The normal bitmap stores ``(n + 1)/2``
        (the plugin decodes and renormalises); roughness has one channel. Their data tensors
        are ``(H, W, C)`` in map row order (``<id>.normal.data`` etc. in ``mi.traverse``).
    """
    ensure_variant()
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if filter_type not in FILTER_TYPES:
        raise ValueError(f"filter_type: expected one of {FILTER_TYPES}, got {filter_type!r}")
    if isinstance(maps, torch.Tensor) and maps.dim() == 3:
        maps = maps.unsqueeze(0)
    M.check_maps(maps)
    if maps.shape[0] != 1:
        raise ValueError(f"maps: expected a single material (1, 10, H, W) or (10, H, W), "
                         f"got batch size {maps.shape[0]}")
    parts = M.split(maps[0:1])
    return {
        "type": f"svbrdf_{distribution}",
        "normal": _bitmap_texture(_hwc((parts["normal"][0] + 1.0) * 0.5), filter_type),
        "diffuse": _bitmap_texture(_hwc(parts["diffuse"][0]), filter_type),
        "roughness": _bitmap_texture(_hwc(parts["roughness"][0]), filter_type),
        "specular": _bitmap_texture(_hwc(parts["specular"][0]), filter_type),
    }


def capture_sensor(res: int | Sequence[int] = 256, *, fov: float = CAPTURE_FOV,
                   origin: Sequence[float] | None = None, target: Sequence[float] = (0.0, 0.0, 0.0),
                   up: Sequence[float] = (0.0, 1.0, 0.0), spp: int = 16) -> dict:
    """A perspective sensor dict (box pixel filter, RGB ``hdrfilm``, independent sampler).

    By default it is the fronto-parallel capture camera at ``(0, 0, 1/tan(fov/2))`` whose
    ``fov`` (horizontal) covers the [-1, 1]^2 plane exactly, pixel ``(i, j)`` imaging texel
    ``(i, j)`` of a ``res``-sized map.

    Args:
        res: image size ``N`` (square) or ``(width, height)``.
        fov: horizontal field of view in degrees, in (0, 180).
        origin: camera position (default: on +z at the covering distance).
        target, up: look-at target and up vector.
        spp: samples per pixel.
    """
    width, height = (int(res), int(res)) if isinstance(res, (int, np.integer)) else (int(res[0]), int(res[1]))
    if width < 1 or height < 1:
        raise ValueError(f"res: expected positive sizes, got {res!r}")
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov: expected degrees in (0, 180), got {fov!r}")
    if origin is None:
        origin = (0.0, 0.0, 1.0 / math.tan(math.radians(fov / 2.0)))
    return {
        "type": "perspective",
        "fov": float(fov),
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=list(map(float, origin)),
                                                   target=list(map(float, target)),
                                                   up=list(map(float, up))),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb",
                 "rfilter": {"type": "box"}},
    }


def plane_scene(maps: torch.Tensor, *, sensor: dict, emitter: dict | list[dict],
                integrator: dict | None = None, distribution: str = "ggx",
                filter_type: str = "nearest") -> mi.Scene:
    """The material ``maps`` on the default [-1, 1]^2 rectangle, as a loaded scene.

    Args:
        maps: canonical maps ``(1, 10, H, W)`` or ``(10, H, W)``.
        sensor: a sensor dict (e.g. :func:`capture_sensor`), id ``sensor``.
        emitter: an emitter dict (id ``emitter``) or a list of them (ids ``emitter_0``, ...).
        integrator: an integrator dict; default ``{"type": "direct"}``.
        distribution: ``"ggx"`` or ``"beckmann"``.
        filter_type: ``"nearest"`` (default: one texel per pixel at matching resolution) or
            ``"bilinear"``.

    Returns:
        The scene; ``mi.traverse`` exposes ``material.normal.data``, ``material.diffuse.data``,
        ``material.roughness.data`` and ``material.specular.data``.
    """
    ensure_variant()
    if not isinstance(sensor, dict):
        raise TypeError(f"sensor: expected a sensor dict, got {type(sensor).__name__}")
    if isinstance(emitter, dict):
        emitters = {"emitter": emitter}
    else:
        emitters = {f"emitter_{k}": e for k, e in enumerate(emitter)}
        if not emitters:
            raise ValueError("emitter: expected an emitter dict or a non-empty list of them")
    for key, e in emitters.items():
        if not isinstance(e, dict):
            raise TypeError(f"emitter: expected dicts, got {type(e).__name__} for {key!r}")
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": integrator if integrator is not None else {"type": "direct"},
        "sensor": sensor,
        "material": material_bsdf(maps, distribution=distribution, filter_type=filter_type),
        "plane": {"type": "rectangle", "bsdf": {"type": "ref", "id": "material"}},
    }
    scene.update(emitters)
    return mi.load_dict(scene)
