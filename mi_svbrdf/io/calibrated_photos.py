"""Capture files (version 1): N photos of a flat sample and the calibration of each, as JSON.

A capture file lists, per image, the photo's file and encoding, whether it is rectified to
the sample plane, the camera and the flash. Positions are in the sample's frame: the sample
spans ``[-1, 1]^2`` at z = 0, y up (:mod:`mi_svbrdf.core.render`). A pixel's value is modelled as
the core's flash input rendering::

    L = f * pi * I * c(n . wl) / |P_L - P|^2 * c(wl . a)^e      (a: unit vector target -> light)

so the albedo scale is defined by the stated intensity ``I`` (RGB). Schema::

    {"version": 1,
     "images": [{"file": "000.png",                      # relative to the capture file
                 "encoding": "srgb8" | "srgb16" | "linear_exr",
                 "rectified": true,                      # false: a perspective photo (Mitsuba path)
                 "camera": {"position": [x, y, z], "fov_deg": 40},
                 "light": {"position": [x, y, z], "intensity": [r, g, b],
                           "cone": {"target": [x, y, z], "exponent": 5} | null},
                 "extra_lights": [{"position": [x, y, z], "intensity": [r, g, b]}]   # optional
                }, ...]}

``extra_lights`` (optional, default none) are further point lights rendered like the capture
simulator's ambient lights: no distance fall-off and no cone, ``L = f * pi * I * c(n . wl)``.
``fov_deg`` is the full field of view of the frame (needed for unrectified photos; for a
rectified one it is informative). sRGB encodings use colour-science's sRGB curve; a pixel
with a channel at the top code of an 8/16-bit file is *saturated* (its true radiance may be
higher): :func:`load_capture` marks it invalid.

Examples:
    >>> spec = CaptureSpec.from_dict({"version": 1, "images": [{"file": "a.png", "encoding": "srgb8",
    ...     "rectified": True, "camera": {"position": [0, 0, 2.75], "fov_deg": 40},
    ...     "light": {"position": [0, 0, 2.2], "intensity": [13, 13, 13], "cone": None}}]})
    >>> spec.images[0].light.intensity
    (13.0, 13.0, 13.0)
"""
from __future__ import annotations

import json
import math
import os
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.image_io import read_image, select_channels, write_image
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode

#: The capture-file version written and the newest understood.
CAPTURE_VERSION = 1
#: The file name of a capture in a folder (what ``rectify`` and ``capture-file make`` write).
CAPTURE_NAME = "capture.json"
#: The largest side rectified photos are written at by default (``rectify``, ``scan``, ``capture-file``): the maps
#: artists use; photos that resolve less keep their own resolution.
DEFAULT_MAX_SIDE = 1024
#: Image encodings: sRGB 8-bit PNG, sRGB 16-bit PNG, linear float EXR.
ENCODINGS = ("srgb8", "srgb16", "linear_exr")
_BITS = {"srgb8": 8, "srgb16": 16}


def _vec3(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
        raise ValueError(f"{where}: expected a list of 3 finite numbers, got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _fields(data: Any, where: str, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected an object, got {type(data).__name__}")  # noqa: TRY004
    for key in required:
        if key not in data:
            raise ValueError(f"{where}.{key}: expected a value, got a missing field")
    unknown = sorted(set(data) - set(required) - set(optional))
    if unknown:
        raise ValueError(f"{where}: expected fields {sorted(required + optional)}, got unknown {unknown}")
    return data


@dataclass(frozen=True)
class ConeSpec:
    """Angular fall-off ``c(wl . a)^e`` of a flash."""

    target: tuple[float, float, float]  #: point the flash is aimed at (sample frame)
    exponent: float  #: e >= 0


@dataclass(frozen=True)
class LightSpec:
    """A point light."""

    position: tuple[float, float, float]  #: position in the sample frame (z > 0)
    intensity: tuple[float, float, float]  #: RGB intensity I >= 0
    cone: ConeSpec | None = None  #: the flash's cone, or None for an isotropic light


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera aimed at the sample centre."""

    position: tuple[float, float, float]  #: position in the sample frame (z > 0)
    fov_deg: float = 40.0  #: full field of view in degrees, in (0, 180)


def camera_frame(position: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(right, up, forward)`` unit vectors ``(..., 3)`` of cameras at ``position`` ``(..., 3)`` aimed at the sample centre.

    The convention of :class:`CameraSpec`: ``forward`` points from the camera to the origin,
    ``right = normalize(forward x y)`` and ``up = right x forward``: the image's up is the sample's
    +y made orthogonal to the view (+x for a camera looking along y). A phone's flash, rigid to its
    lens, sits at ``position + ox right + oy up`` in every photo.

    Examples:
        >>> r, u, f = camera_frame(torch.tensor([0.0, 0.0, 2.0]))
        >>> r.tolist(), u.tolist(), f.tolist()
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.0, -0.0, -1.0])
    """
    forward = -position / position.norm(dim=-1, keepdim=True)
    y = torch.zeros_like(forward)
    y[..., 1] = 1.0
    x = torch.zeros_like(forward)
    x[..., 0] = 1.0
    along_y = (forward[..., 1].abs() > 0.999)[..., None]
    right = torch.linalg.cross(forward, torch.where(along_y, x, y), dim=-1)
    right = right / right.norm(dim=-1, keepdim=True)
    up = torch.linalg.cross(right, forward, dim=-1)
    return right, up, forward


@dataclass(frozen=True)
class ImageSpec:
    """One photo and its calibration."""

    file: str  #: image file, relative to the capture file
    encoding: str  #: one of ENCODINGS
    rectified: bool  #: True: the photo is rectified to the [-1, 1]^2 sample (texel path)
    camera: CameraSpec  #: the camera
    light: LightSpec  #: the flash (distance fall-off, optional cone)
    extra_lights: tuple[LightSpec, ...] = ()  #: further lights without fall-off or cone (ambient)

    @classmethod
    def from_dict(cls, data: Any, where: str) -> ImageSpec:
        """Parse and validate one ``images[i]`` entry; errors name the field (``where`` prefix)."""
        d = _fields(data, where, ("file", "encoding", "rectified", "camera", "light"), ("extra_lights",))
        if not isinstance(d["file"], str) or not d["file"]:
            raise ValueError(f"{where}.file: expected a non-empty file name, got {d['file']!r}")
        if d["encoding"] not in ENCODINGS:
            raise ValueError(f"{where}.encoding: expected one of {ENCODINGS}, got {d['encoding']!r}")
        if not isinstance(d["rectified"], bool):
            raise ValueError(f"{where}.rectified: expected true or false, got {d['rectified']!r}")  # noqa: TRY004
        cam = _fields(d["camera"], f"{where}.camera", ("position",), ("fov_deg",))
        position = _vec3(cam["position"], f"{where}.camera.position")
        if position[2] <= 0:
            raise ValueError(f"{where}.camera.position: expected z > 0 (above the sample), got {position[2]}")
        fov = cam.get("fov_deg", 40.0)
        if not isinstance(fov, (int, float)) or isinstance(fov, bool) or not 0 < fov < 180:
            raise ValueError(f"{where}.camera.fov_deg: expected degrees in (0, 180), got {fov!r}")
        light = _light(d["light"], f"{where}.light", flash=True)
        extra = d.get("extra_lights", [])
        if not isinstance(extra, list):
            raise ValueError(f"{where}.extra_lights: expected a list, got {type(extra).__name__}")  # noqa: TRY004
        extras = tuple(_light(e, f"{where}.extra_lights[{i}]", flash=False) for i, e in enumerate(extra))
        return cls(d["file"], d["encoding"], d["rectified"], CameraSpec(position, float(fov)), light, extras)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (the schema of the module docstring)."""
        cone = self.light.cone
        out: dict[str, Any] = {
            "file": self.file, "encoding": self.encoding, "rectified": self.rectified,
            "camera": {"position": list(self.camera.position), "fov_deg": self.camera.fov_deg},
            "light": {"position": list(self.light.position), "intensity": list(self.light.intensity),
                      "cone": None if cone is None else {"target": list(cone.target), "exponent": cone.exponent}}}
        if self.extra_lights:
            out["extra_lights"] = [{"position": list(e.position), "intensity": list(e.intensity)}
                                   for e in self.extra_lights]
        return out


def _light(data: Any, where: str, flash: bool) -> LightSpec:
    d = _fields(data, where, ("position", "intensity"), ("cone",) if flash else ())
    position = _vec3(d["position"], f"{where}.position")
    if position[2] <= 0:
        raise ValueError(f"{where}.position: expected z > 0 (above the sample), got {position[2]}")
    intensity = _vec3(d["intensity"], f"{where}.intensity")
    if min(intensity) < 0:
        raise ValueError(f"{where}.intensity: expected values >= 0, got {list(intensity)}")
    cone = None
    if d.get("cone") is not None:
        c = _fields(d["cone"], f"{where}.cone", ("target", "exponent"))
        e = c["exponent"]
        if not isinstance(e, (int, float)) or isinstance(e, bool) or not math.isfinite(e) or e < 0:
            raise ValueError(f"{where}.cone.exponent: expected a finite number >= 0, got {e!r}")
        cone = ConeSpec(_vec3(c["target"], f"{where}.cone.target"), float(e))
    return LightSpec(position, intensity, cone)


@dataclass(frozen=True)
class CaptureSpec:
    """A capture: the calibration of N photos of one flat sample."""

    images: tuple[ImageSpec, ...]  #: one entry per photo, N >= 1
    version: int = CAPTURE_VERSION  #: file version (1)
    root: Path | None = field(default=None, compare=False)  #: folder image files are relative to

    @property
    def n_images(self) -> int:
        """N."""
        return len(self.images)

    def subset(self, keep: Sequence[int]) -> CaptureSpec:
        """The capture of the photos ``keep`` (indices, in that order) only.

        Examples:
            >>> im = {"file": "0.png", "encoding": "srgb8", "rectified": True, "camera": {"position": [0, 0, 2]},
            ...       "light": {"position": [0, 0, 2], "intensity": [1, 1, 1]}}
            >>> spec = CaptureSpec.from_dict({"version": 1, "images": [{**im, "file": f"{k}.png"} for k in range(4)]})
            >>> [im.file for im in spec.subset([3, 1]).images]
            ['3.png', '1.png']
        """
        bad = [k for k in keep if not 0 <= k < len(self.images)]
        if bad or not keep:
            raise ValueError(f"keep: expected a non-empty list of photo indices in [0, {len(self.images)}), "
                             f"got {list(keep)}")
        return dataclasses.replace(self, images=tuple(self.images[k] for k in keep))

    def window(self, top: int, left: int, height: int, width: int, size: tuple[int, int], step: int = 1) -> CaptureSpec:
        """The texels ``[top, top + height) x [left, left + width)`` of the ``size`` = ``(H, W)`` rectified photos, every
        ``step``-th of them (:func:`window_texels`), as a capture of their own, exact for the texel renderer: rendering
        the window's texels of the maps with this capture gives the same texels of the whole capture's renders.

        The window must have the photos' aspect (``height / H == width / W``) and span whole steps: its frame is the
        sample's, moved so that the texels taken sit at the texel centres of a ``height / step x width / step`` grid over
        ``[-1, 1]^2``, and scaled by ``1 / s`` (``s = width / W``, the window's half-width in sample units). Angles and
        normals keep; every distance is divided by ``s``, so a flash's intensity (``1 / d^2`` fall-off) is divided by
        ``s^2``; extra lights (no fall-off) keep theirs. The cameras keep their positions relative to the window; an
        unrectified photo has no texel window.

        Examples:
            >>> im = {"file": "0.png", "encoding": "srgb8", "rectified": True, "camera": {"position": [0, 0, 2]},
            ...       "light": {"position": [0, 0, 2], "intensity": [1, 1, 1]}}
            >>> spec = CaptureSpec.from_dict({"version": 1, "images": [im]})
            >>> w = spec.window(0, 0, 8, 8, (16, 16)).images[0]
            >>> w.camera.position, w.light.intensity
            ((1.0, -1.0, 4.0), (4.0, 4.0, 4.0))
            >>> spec.window(0, 0, 16, 16, (16, 16), step=2).images[0].camera.position  # half a texel off the centre
            (0.0625, -0.0625, 2.0)
        """
        h_all, w_all = int(size[0]), int(size[1])
        if not (0 <= top and 0 <= left and height >= 1 and width >= 1 and top + height <= h_all
                and left + width <= w_all):
            raise ValueError(f"window: expected texels inside the {h_all}x{w_all} photos, got rows "
                             f"[{top}, {top + height}) and columns [{left}, {left + width})")
        if height * w_all != width * h_all:
            raise ValueError(f"window: expected the photos' aspect {h_all}:{w_all} (height / H == width / W), got "
                             f"{height}x{width}")
        if not (isinstance(step, int) and step >= 1 and height % step == 0 and width % step == 0):
            raise ValueError(f"step: expected an int >= 1 dividing the window's {height}x{width} texels, got {step!r}")
        unrectified = [k for k, im in enumerate(self.images) if not im.rectified]
        if unrectified:
            raise ValueError(f"window: expected rectified photos (a texel window), got unrectified photos {unrectified}")
        s = width / w_all
        o = (step - 1) // 2  # the texel taken of each step x step block: its centre's, or the one before it
        cx, cy = -1.0 + (2 * (left + o) + 1 - step + width) / w_all, 1.0 - (2 * (top + o) + 1 - step + height) / h_all

        def moved(p: tuple[float, float, float]) -> tuple[float, float, float]:
            return ((p[0] - cx) / s, (p[1] - cy) / s, p[2] / s)

        def light(lt: LightSpec, falloff: bool) -> LightSpec:
            cone = None if lt.cone is None else ConeSpec(moved(lt.cone.target), lt.cone.exponent)
            gain = 1.0 / (s * s) if falloff else 1.0
            return LightSpec(moved(lt.position), tuple(i * gain for i in lt.intensity), cone)

        images = tuple(dataclasses.replace(
            im, camera=dataclasses.replace(im.camera, position=moved(im.camera.position)),
            light=light(im.light, True), extra_lights=tuple(light(e, False) for e in im.extra_lights))
            for im in self.images)
        return dataclasses.replace(self, images=images)

    @classmethod
    def from_dict(cls, data: Any, root: Path | None = None) -> CaptureSpec:
        """Parse and validate a capture dict; a ``ValueError`` names the faulty field."""
        d = _fields(data, "capture", ("version", "images"))
        if d["version"] != CAPTURE_VERSION:
            raise ValueError(f"capture.version: expected {CAPTURE_VERSION}, got {d['version']!r}")
        if not isinstance(d["images"], list) or not d["images"]:
            raise ValueError(f"capture.images: expected a non-empty list, got {d['images']!r}")
        images = tuple(ImageSpec.from_dict(im, f"images[{i}]") for i, im in enumerate(d["images"]))
        return cls(images, CAPTURE_VERSION, root)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"version": self.version, "images": [im.to_dict() for im in self.images]}


def window_texels(t: torch.Tensor, top: int, left: int, height: int, width: int, step: int = 1) -> torch.Tensor:
    """The texels of ``t`` ``(..., H, W)`` that :meth:`CaptureSpec.window` with the same arguments renders:
    ``(..., height / step, width / step)``, every ``step``-th texel of the window (the centre's of each block, or the
    one before it).

    Examples:
        >>> window_texels(torch.arange(16.0).view(4, 4), 0, 0, 4, 4, 2).tolist()
        [[0.0, 2.0], [8.0, 10.0]]
    """
    o = (step - 1) // 2
    return t[..., top + o:top + height:step, left + o:left + width:step]


def _decode(image: np.ndarray, encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """Stored ``(H, W, 3)`` values -> (linear float32, valid ``(H, W)`` bool: no channel at the top code)."""
    if encoding == "linear_exr":
        return image.astype(np.float32), np.ones(image.shape[:2], dtype=bool)
    top = 1.0 - 0.5 / (2 ** _BITS[encoding] - 1)
    return srgb_decode(image), ~(image >= top).any(axis=2)


def load_capture(path: str | os.PathLike) -> tuple[CaptureSpec, torch.Tensor, torch.Tensor]:
    """Read a capture file and its images.

    Args:
        path: the capture JSON (or a folder holding :data:`CAPTURE_NAME`); image files are relative
            to its folder.

    Returns:
        ``(spec, images, valid)``: ``images`` ``(N, 3, H, W)`` linear float32; ``valid``
        ``(N, 1, H, W)`` bool, False where a pixel is saturated (a channel at the top code).

    Raises:
        ValueError: invalid JSON or schema (naming the field), unreadable image, sizes differ.
        FileNotFoundError: the capture file or an image file is missing.
    """
    path = Path(path)
    if path.is_dir():
        if not (path / CAPTURE_NAME).is_file():
            raise FileNotFoundError(f"{path}: expected a capture JSON file or a folder holding {CAPTURE_NAME}, "
                                    f"got a folder without {CAPTURE_NAME}")
        path = path / CAPTURE_NAME
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected a capture JSON file, got no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: expected a capture file (JSON), got invalid JSON ({err})") from err
    try:
        spec = CaptureSpec.from_dict(data, root=path.parent)
    except ValueError as err:  # it names the field; say which file
        raise ValueError(f"{path}: {err}") from err
    images, valid = [], []
    for i, im in enumerate(spec.images):
        file = path.parent / im.file
        if not file.is_file():
            raise FileNotFoundError(f"images[{i}].file: expected an existing image file, got no such file {file}")
        want = ".exr" if im.encoding == "linear_exr" else ".png"
        if file.suffix.lower() != want:
            raise ValueError(f"images[{i}].file: expected a {want} file for encoding {im.encoding!r}, got {im.file!r}")
        try:
            raw, info = read_image(file)
        except ValueError as err:  # it names the file; say which entry
            raise ValueError(f"images[{i}].file: {err}") from err
        if im.encoding != "linear_exr" and info.bit_depth != _BITS[im.encoding]:
            raise ValueError(f"images[{i}].encoding: expected a {_BITS[im.encoding]}-bit PNG for "
                             f"{im.encoding!r}, got {info.bit_depth}-bit {file}")
        try:
            rgb = select_channels(raw, 3, file)
        except ValueError as err:
            raise ValueError(f"images[{i}].file: {err}") from err
        linear, ok = _decode(rgb, im.encoding)
        if images and linear.shape != images[0].shape:
            raise ValueError(f"images[{i}].file: expected size {images[0].shape[:2]} like images[0], "
                             f"got {linear.shape[:2]}")
        images.append(linear)
        valid.append(ok)
    img = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous()
    return spec, img, torch.from_numpy(np.stack(valid))[:, None]


def save_capture(path: str | os.PathLike, spec: CaptureSpec, images: torch.Tensor) -> None:
    """Write the images (by each entry's ``file`` and ``encoding``) and the capture JSON, atomically.

    Args:
        path: the capture JSON to write; images go beside it (folders created).
        spec: the calibration; ``spec.images[i].file`` names image i.
        images: ``(N, 3, H, W)`` linear radiance (sRGB encodings clip to [0, 1]).
    """
    path = Path(path)
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[:2] != (spec.n_images, 3):
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"images: expected shape (N={spec.n_images}, 3, H, W), got {shape}")
    if not torch.isfinite(images).all():
        raise ValueError("images: expected finite values, got NaN or Inf")
    path.parent.mkdir(parents=True, exist_ok=True)
    data = images.detach().to("cpu", torch.float32).permute(0, 2, 3, 1).numpy()
    for im, pixels in zip(spec.images, data):
        file = path.parent / im.file
        file.parent.mkdir(parents=True, exist_ok=True)
        if im.encoding == "linear_exr":
            write_image(file.with_suffix(".exr") if file.suffix.lower() != ".exr" else file, pixels)
        else:
            write_image(file, srgb_encode(pixels), _BITS[im.encoding], srgb=True)
    write_json(path, spec.to_dict())


def capture_from_simulator(captures: Any, b: int, inputs: torch.Tensor, *,
                           encoding: str = "srgb8") -> tuple[CaptureSpec, torch.Tensor]:
    """One sample of the simulator's :class:`mi_svbrdf.data.photo_setups.Captures` as a capture spec.

    The simulator renders rectified photos with the same flash model as the capture file;
    its ambient lights become each image's ``extra_lights``. Files are named ``NNN.png``
    (``NNN.exr`` for ``linear_exr``).

    Args:
        captures: ``Captures`` of B samples (from :func:`mi_svbrdf.data.photo_setups.sample_captures`).
        b: the sample index, ``0 <= b < B``.
        inputs: ``(N, 3, H, W)`` or ``(B, N, 3, H, W)`` linear photos of the captures.
        encoding: the encoding recorded per image (one of :data:`ENCODINGS`).

    Returns:
        ``(spec, images (N, 3, H, W))``.
    """
    if not 0 <= b < captures.batch_size:
        raise ValueError(f"b: expected a sample index in [0, {captures.batch_size}), got {b}")
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding: expected one of {ENCODINGS}, got {encoding!r}")
    n = captures.n_images
    if isinstance(inputs, torch.Tensor) and inputs.dim() == 5:
        inputs = inputs[b]
    if not isinstance(inputs, torch.Tensor) or inputs.dim() != 4 or inputs.shape[:2] != (n, 3):
        raise ValueError(f"inputs: expected shape (N={n}, 3, H, W) or (B, N, 3, H, W), "
                         f"got {tuple(inputs.shape) if isinstance(inputs, torch.Tensor) else inputs!r}")
    c = captures.take(b)
    extras = tuple(LightSpec(tuple(p), tuple(i)) for p, i in zip(c.ambient_light[0].tolist(),
                                                                 c.ambient_intensity[0].tolist()))
    suffix = "exr" if encoding == "linear_exr" else "png"
    images = []
    for k in range(n):
        cone = ConeSpec(tuple(c.cone_target[0, k].tolist()), float(c.cone_exponent[0, k])) if c.cone else None
        intensity = tuple(c.intensity[0, k].tolist()) if c.flash else (0.0, 0.0, 0.0)
        images.append(ImageSpec(f"{k:03d}.{suffix}", encoding, True,
                                CameraSpec(tuple(c.view[0, k].tolist()), float(c.fov[0, k])),
                                LightSpec(tuple(c.light[0, k].tolist()), intensity, cone), extras))
    return CaptureSpec(tuple(images)), inputs.detach().to(torch.float32)
