"""The Mitsuba forward model of the optimiser: each calibrated photo re-rendered by ``mi.render``.

:class:`MitsubaForward` renders every image of a capture description differentiably with
Mitsuba: the material on the ``[-1, 1]^2`` plane (:func:`mi_svbrdf.scenes.plane_scene`, the
``svbrdf_*`` plugin with bitmap textures ``material.{normal,diffuse,roughness,specular}.data``),
a perspective camera, a point light of Mitsuba intensity ``pi * I`` (so a pixel equals the core's
flash input rendering ``f * pi * I * c(n . wL) / |P_L - P|^2``) and the ``direct`` integrator
with one emitter sample and no BSDF sample (exact for a flat plane up to pixel jitter).
Gradients reach the torch map tensor through ``dr.wrap(source="torch", target="drjit")``.

Cameras, per image:

* **unrectified** (``rectified=False``): a perspective camera at ``camera_position`` looking at
  the plane centre, up ``+y``, horizontal field of view ``fov_deg``; the photo is
  ``image_size`` pixels (default: the map size).
* **rectified** (``rectified=True``): the photo is the sample plane resampled to the map grid,
  pixel ``(i, j)`` on texel ``(i, j)``, seen from ``camera_position``. That is exactly a camera at
  ``camera_position`` whose image plane is parallel to the sample (looking down ``-z``) with field of
  view ``2 atan(1 / z_c)`` and its principal point shifted by ``(-x_c / 2, y_c / 2)`` film widths:
  it covers ``[-1, 1]^2`` exactly, like the texel renderer with ``view = camera_position``.
  One difference remains: a Mitsuba pixel averages the radiance over its footprint, the texel
  path shades the pixel centre, so highlights sharper than a pixel differ (e.g. 4 % of the
  image mean for a glaze of roughness 0.12 at 24 px; ~0.1 % for smooth lobes).

Cone (``c(wL . a)^e``, ``a`` the unit vector from the cone target to the light): Mitsuba's
point light has none, so the factor is applied to the rendered image per pixel, evaluated at
the point of the plane seen through the pixel centre (computed once with ``scene.ray_intersect``).
The cone varies slowly across a pixel, so this differs from the per-sample factor only at
second order in the pixel footprint (tested against the texel path to Monte-Carlo noise).
Extra (ambient) lights, which have no fall-off, are rendered in a scene of their own and their
image multiplied by ``|P_L - P|^2`` at the pixel centre's plane point in the same way.

Design: one scene per image and light (each with its own sensor and point light: one scene
with N sensors would light every image with all N lights), all loaded once; the map tensors are
written into every scene's textures, then one ``mi.render`` per image. A step costs about as
much as with a single scene whose sensor and light are updated through ``mi.traverse`` before
each image (``docs/design-notes.md``). Seeds are passed as opaque ``UInt32`` so a new seed per step does not recompile the
kernels (``dr.kernel_history``: all cache hits from the second call on).

Examples:
    >>> import mi_svbrdf
    >>> from mi_svbrdf.io.calibrated_photos import CaptureSpec
    >>> spec = CaptureSpec.from_dict({"version": 1, "images": [{"file": "a.png", "encoding": "srgb8",
    ...     "rectified": False, "camera": {"position": [0.5, 0.3, 2.0], "fov_deg": 50},
    ...     "light": {"position": [0, 0, 2], "intensity": [1, 1, 1], "cone": None}}]})
    >>> fwd = MitsubaForward(spec, size=8, spp=2)
    >>> tuple(fwd(mi_svbrdf.core.maps.constant_maps(1, 8, 8)).shape)
    (1, 3, 8, 8)
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import torch

from mi_svbrdf import scenes
from mi_svbrdf.core import maps as M
from mi_svbrdf.variant import scene_variant

#: Traversed texture keys, in the order of :func:`_texture_tensors`.
TEXTURE_KEYS = tuple(f"material.{name}.data" for name in M.MAP_NAMES)
#: The integrator: one light sample per path, exact for a flat plane lit by a point light.
INTEGRATOR = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}


def _images(spec: Any) -> list[Any]:
    images = getattr(spec, "images", None)
    if images is None:
        raise ValueError(f"spec: expected a CaptureSpec (with .images), got {type(spec).__name__}")
    images = list(images)
    if not images:
        raise ValueError("spec.images: expected at least one image, got none")
    return images


def _square_size(size: int | Sequence[int]) -> int:
    if isinstance(size, (int, np.integer)):
        h = w = int(size)
    else:
        h, w = (int(v) for v in size)
    if h < 1 or h != w:
        raise ValueError(f"size: expected a positive int or square (H, W) for the Mitsuba path, got {size!r}")
    return h


def _image_size(image_size: int | Sequence[int] | None, size: int) -> tuple[int, int]:
    if image_size is None:
        return size, size
    if isinstance(image_size, (int, np.integer)):
        w = h = int(image_size)
    else:
        w, h = (int(v) for v in image_size)
    if w < 1 or h < 1:
        raise ValueError(f"image_size: expected positive (width, height), got {image_size!r}")
    return w, h


def _sensor(im: Any, size: int, res: tuple[int, int], spp: int) -> dict:
    """The sensor dict of one image (see the module docstring for both camera kinds)."""
    cam = [float(v) for v in im.camera.position]
    if im.rectified:
        fov = math.degrees(2.0 * math.atan(1.0 / cam[2]))
        sensor = scenes.capture_sensor(size, fov=fov, origin=cam, target=(cam[0], cam[1], 0.0), spp=spp)
        sensor["principal_point_offset_x"] = -cam[0] / 2.0
        sensor["principal_point_offset_y"] = cam[1] / 2.0
        return sensor
    direction = np.asarray(cam) / np.linalg.norm(cam)
    up = (0.0, 1.0, 0.0) if abs(direction[1]) < 0.999 else (0.0, 0.0, 1.0)
    return scenes.capture_sensor(res, fov=float(im.camera.fov_deg), origin=cam, target=(0.0, 0.0, 0.0),
                                 up=up, spp=spp)


def _emitter(light: Any) -> dict:
    return {"type": "point", "position": [float(v) for v in light.position],
            "intensity": {"type": "rgb", "value": [math.pi * float(v) for v in light.intensity]}}


def _pixel_points(scene: mi.Scene, res: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Plane points ``(H*W, 3)`` seen through the pixel centres, and which pixels see the plane."""
    w, h = res
    jj, ii = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
    film = mi.Point2f(jj.ravel().astype(np.float32), ii.ravel().astype(np.float32))
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    return np.array(si.p, dtype=np.float64).T.reshape(-1, 3), np.array(si.is_valid(), dtype=bool)  # (3, n) -> (n, 3)


def _pixel_factor(points: np.ndarray, valid: np.ndarray, light: Any, res: tuple[int, int],
                  extra: bool) -> torch.Tensor | None:
    """``(H, W)`` per-pixel factor: the cone ``c(wL . a)^e`` of a flash, ``|P_L - P|^2`` of an extra light."""
    pos = np.asarray(light.position, dtype=np.float64)
    to_light = pos[None, :] - points
    if extra:  # undo Mitsuba's 1/d^2: an extra (ambient) light has no fall-off
        factor = (to_light ** 2).sum(axis=1)
    elif light.cone is None:
        return None
    else:
        axis = pos - np.asarray(light.cone.target, dtype=np.float64)
        norm = np.linalg.norm(axis)
        if norm == 0.0:
            raise ValueError("light.cone.target: expected a point different from the light position")
        wl = to_light / np.maximum(np.linalg.norm(to_light, axis=1, keepdims=True), 1e-12)
        factor = np.maximum(wl @ (axis / norm), 0.0) ** float(light.cone.exponent)
    factor[~valid] = 0.0
    w, h = res
    return torch.from_numpy(factor.reshape(h, w).astype(np.float32))


def _texture_tensors(maps: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``(1, 10, H, W)`` maps -> the four ``(H, W, C)`` texture tensors (normal encoded ``(n+1)/2``)."""
    textures = {name: maps[0, M.SLICES[name]] for name in M.MAP_NAMES}
    textures["normal"] = (textures["normal"] + 1.0) * 0.5
    return tuple(textures[name].permute(1, 2, 0).contiguous() for name in M.MAP_NAMES)


class MitsubaForward:
    """Differentiable Mitsuba re-rendering of a calibrated capture: maps ``(1,10,H,W)`` -> ``(N,3,h,w)``.

    Args:
        spec: the capture (:class:`mi_svbrdf.io.calibrated_photos.CaptureSpec`): per image ``rectified``,
            ``camera.position``/``camera.fov_deg``, ``light.position``/``intensity``/``cone`` and
            ``extra_lights``. Positions in the sample frame ([-1, 1]^2 at z = 0, y up).
        size: map size ``H = W`` (an int or a square ``(H, W)``); rectified images are ``size^2``.
        spp: samples per pixel of each rendering (and of its gradient pass).
        seed: base seed; every call draws new seeds.
        image_size: size ``w`` or ``(w, h)`` of unrectified images (default ``size``); mixing
            rectified and unrectified images needs ``image_size == size``.
        distribution: ``"ggx"`` or ``"beckmann"``.
        filter_type: texture lookups, ``"nearest"`` (default; rectified pixels then equal the
            texel path) or ``"bilinear"`` (smoother gradients for oblique views).
        device: the maps' device; the scenes are built for its Mitsuba variant
            (:func:`mi_svbrdf.variant.scene_variant`), which every call enters (free when it is active,
            e.g. inside :func:`mi_svbrdf.optim.optimize`, which enters it once for the whole fit).

    Extra (ambient) lights of an image get their own scene, rendered with the image's camera; the
    ``1/d^2`` Mitsuba applies is undone per pixel like the cone (see the module docstring).

    Raises:
        ValueError: for a bad size or spec (naming the argument).
    """

    def __init__(self, spec: Any, size: int | Sequence[int], spp: int = 4, seed: int = 0, *,
                 image_size: int | Sequence[int] | None = None, distribution: str = "ggx",
                 filter_type: str = "nearest", device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        with scene_variant(self.device):
            self._build(spec, size, spp, seed, image_size, distribution, filter_type)

    def _build(self, spec: Any, size: int | Sequence[int], spp: int, seed: int,
               image_size: int | Sequence[int] | None, distribution: str, filter_type: str) -> None:
        if not isinstance(spp, (int, np.integer)) or spp < 1:
            raise ValueError(f"spp: expected a positive int, got {spp!r}")
        self.size, self.spp, self.seed = _square_size(size), int(spp), int(seed)
        images = _images(spec)
        res = _image_size(image_size, self.size)
        kinds = {bool(im.rectified) for im in images}
        if kinds == {True, False} and res != (self.size, self.size):
            raise ValueError(f"image_size: expected {self.size} (the map size) when rectified and "
                             f"unrectified images are mixed, got {image_size!r}")
        self.resolution = (self.size, self.size) if kinds == {True} else res
        self.n_images = len(images)
        init = M.constant_maps(1, self.size, self.size)
        self.scenes: list[mi.Scene] = []
        owners: list[int] = []
        factors: list[torch.Tensor | None] = []
        for k, im in enumerate(images):
            sensor = _sensor(im, self.size, self.resolution, self.spp)
            points = None
            for light, extra in [(im.light, False)] + [(e, True) for e in im.extra_lights]:
                scene = scenes.plane_scene(init, sensor=sensor, emitter=_emitter(light),
                                           integrator=dict(INTEGRATOR), distribution=distribution,
                                           filter_type=filter_type)
                if points is None:
                    points = _pixel_points(scene, self.resolution)
                self.scenes.append(scene)
                owners.append(k)
                factors.append(_pixel_factor(*points, light, self.resolution, extra))
        self.params = [mi.traverse(s) for s in self.scenes]
        for p in self.params:
            p.keep(list(TEXTURE_KEYS))
        self.owner = torch.tensor(owners, dtype=torch.long, device=self.device)  # image of each scene
        w, h = self.resolution
        self.factor: torch.Tensor | None = None  # (S, 1, h, w) per-pixel factor of each scene
        if any(f is not None for f in factors):
            self.factor = torch.stack([f if f is not None else torch.ones(h, w) for f in factors])[:, None]
            self.factor = self.factor.to(self.device)
        self.calls = 0
        self._render = self._make_render()

    def __len__(self) -> int:
        return self.n_images

    def _make_render(self):  # noqa: ANN202  (a dr.wrap-ed closure)
        scenes_, params_, spp = self.scenes, self.params, self.spp

        @dr.wrap(source="torch", target="drjit")
        def render_all(normal, diffuse, roughness, specular, seed: int):  # noqa: ANN001, ANN202
            out = []
            for k, (scene, params) in enumerate(zip(scenes_, params_)):
                for key, value in zip(TEXTURE_KEYS, (normal, diffuse, roughness, specular)):
                    params[key] = value
                params.update()
                # Opaque seeds: a new seed per call must not recompile the kernels.
                s = dr.opaque(mi.UInt32, seed + 2 * k)
                sg = dr.opaque(mi.UInt32, seed + 2 * k + 1)
                out.append(mi.render(scene, params, spp=spp, spp_grad=spp, seed=s, seed_grad=sg))
            return tuple(out)

        return render_all

    def __call__(self, maps: torch.Tensor) -> torch.Tensor:
        """Render every image of the capture.

        Args:
            maps: ``(1, 10, size, size)`` canonical maps (differentiable).

        Returns:
            ``(N, 3, h, w)`` float32 linear radiance; gradients flow back to ``maps``.
        """
        M.check_maps(maps)
        if tuple(maps.shape) != (1, 10, self.size, self.size):
            raise ValueError(f"maps: expected shape (1, 10, {self.size}, {self.size}), got {tuple(maps.shape)}")
        if maps.device != self.device:
            raise ValueError(f"maps: expected a tensor on the forward model's device {self.device}, got {maps.device}")
        seed = self.seed + 2 * self.calls * len(self.scenes)
        self.calls += 1
        with scene_variant(self.device):
            rendered = self._render(*_texture_tensors(maps.to(torch.float32)), seed)
        out = torch.stack([im[..., :3].permute(2, 0, 1) for im in rendered])  # (S, 3, h, w)
        if self.factor is not None:
            out = out * self.factor
        if len(self.scenes) == self.n_images:
            return out
        w, h = self.resolution
        return out.new_zeros(self.n_images, 3, h, w).index_add(0, self.owner, out)
