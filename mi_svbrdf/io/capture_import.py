"""Capture folders of other labs, read into the project's capture file (``capture.json``, version 1).

The layout of the MaterialGAN authors' capture code (svbrdf-diff-renderer; the MaterialGAN
datasets use it too): a folder with rectified flash photos ``00.png``, ``01.png`` ... and their
calibration, either in one JSON file, ``parameters.json`` or ``optim.json``:

==============================  ============================================================
key                             meaning
==============================  ============================================================
``image_size`` or ``im_size``   width of the photographed square, in cm (the photos cover it)
``camera_pos``, ``light_pos``   one ``[x, y, z]`` per photo, cm, origin at the square's centre,
                                x right, y up in the photo, z towards the camera
``light_pow``                   the flash's power, one number or ``[r, g, b]``: a texel
                                receives ``light_pow * cos(theta) / d^2`` (``d`` in cm)
``idx``                         (optional) the photos' numbers, ``idx[k]`` -> ``NN.png``
``target_dir``                  (optional) the photos' folder, relative to the file; when the photos
                                are not there but beside the file (as such data sets are often unpacked),
                                those are used and :attr:`ForeignCapture.photo_note` says so
==============================  ============================================================

or in the older text files ``camera_pos.txt`` and ``light_pos.txt`` (one ``x,y,z`` line per
photo), ``image_size.txt`` (one number) and ``light_power.txt`` (``r,g,b`` or one number).

Units: the project's sample is the square ``[-1, 1]^2``, so a position in cm becomes
``x_cm * 2 / width_cm``. Their renderer's diffuse term is ``albedo / pi`` times ``light_pow *
cos / d^2``; ours reads ``albedo * I * cos / d^2`` (a white matte sample at distance ``d`` facing
a flash of intensity ``d^2`` reads 1), so the intensity is ``light_pow * (2 / width_cm)^2 / pi``.

Examples:
    >>> import json, tempfile, numpy as np
    >>> from pathlib import Path
    >>> from mi_svbrdf.io.image_io import write_image
    >>> d = Path(tempfile.mkdtemp())
    >>> write_image(d / "00.png", np.full((16, 16, 3), 0.5, np.float32), 8)
    >>> _ = (d / "parameters.json").write_text(json.dumps({"image_size": 10.0, "camera_pos": [[0, 0, 25]],
    ...     "light_pos": [[0, 0, 25]], "light_pow": 1500}))
    >>> spec = read_foreign_capture(d).spec
    >>> spec.images[0].light.position, round(spec.images[0].light.intensity[0], 3)
    ((0.0, 0.0, 5.0), 19.099)
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.io.atomic import atomic_path, write_json
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, ImageSpec, LightSpec
from mi_svbrdf.io.photos import check_consistent, load_photo, prepare

#: The JSON files of the format, in the order they are looked for.
JSON_NAMES = ("parameters.json", "optim.json")
#: The text files of the older layout: (file, what it holds).
TEXT_FILES = {"camera_pos.txt": "one x,y,z line per photo", "light_pos.txt": "one x,y,z line per photo",
              "image_size.txt": "one number (cm)", "light_power.txt": "r,g,b or one number"}
#: The field of view written for the (rectified) photos; the texel path does not use it.
RECTIFIED_FOV_DEG = 40.0


@dataclass(frozen=True)
class ForeignCapture:
    """A capture folder as read: the calibration in the project's units and the photo files."""

    spec: CaptureSpec  #: positions and intensities in the project's units; ``file`` = the photo's path
    photos: tuple[Path, ...]  #: the photo files, in the order of ``spec.images``
    source: Path  #: the file the calibration was read from (``parameters.json``, ``optim.json`` or a .txt)
    width_cm: float  #: the sample's width in cm
    photo_dir: Path | None = None  #: the folder the photos were read from
    photo_note: str | None = None  #: which folder was used when ``target_dir`` names one (None: no target_dir)


def _number(value: Any, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and value <= 0):
        raise ValueError(f"{where}: expected a {'positive ' if positive else ''}finite number, got {value!r}")
    return float(value)


def _positions(value: Any, where: str) -> list[tuple[float, float, float]]:
    if not isinstance(value, list) or not value:
        raise ValueError(f"{where}: expected a non-empty list of [x, y, z] positions (cm), got {value!r}")
    out = []
    for k, p in enumerate(value):
        if not isinstance(p, (list, tuple)) or len(p) != 3:
            raise ValueError(f"{where}[{k}]: expected [x, y, z] (cm), got {p!r}")
        xyz = tuple(_number(v, f"{where}[{k}]") for v in p)
        if xyz[2] <= 0:
            raise ValueError(f"{where}[{k}]: expected z > 0 (above the sample), got {xyz[2]}")
        out.append(xyz)
    return out  # type: ignore[return-value]


def _power(value: Any, where: str) -> tuple[float, float, float]:
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if len(values) == 1:
        values *= 3
    if len(values) != 3:
        raise ValueError(f"{where}: expected a number or [r, g, b], got {value!r}")
    power = tuple(_number(v, where) for v in values)
    if min(power) < 0 or max(power) <= 0:
        raise ValueError(f"{where}: expected values >= 0, not all 0, got {value!r}")
    return power  # type: ignore[return-value]


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: expected JSON, got invalid JSON ({err})") from err
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(data).__name__}")
    width_key = next((k for k in ("image_size", "im_size") if k in data), None)
    for key in (width_key or "image_size", "camera_pos", "light_pos", "light_pow"):
        if key not in data:
            alt = " (or im_size)" if key == "image_size" else ""
            raise ValueError(f"{path}: expected the key {key!r}{alt}, got none")
    return {"width": _number(data[width_key], f"{path}: {width_key}", positive=True),
            "camera": _positions(data["camera_pos"], f"{path}: camera_pos"),
            "light": _positions(data["light_pos"], f"{path}: light_pos"),
            "power": _power(data["light_pow"], f"{path}: light_pow"),
            "idx": data.get("idx"), "dir": data.get("target_dir")}


def _read_text(folder: Path) -> dict[str, Any]:
    values: dict[str, list[list[float]]] = {}
    for name, holds in TEXT_FILES.items():
        path = folder / name
        if not path.is_file():
            raise ValueError(f"{path}: expected the file ({holds}), got no such file")
        rows = []
        for line_no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if line.strip():
                try:
                    rows.append([float(v) for v in line.replace(",", " ").split()])
                except ValueError:
                    raise ValueError(f"{path}: line {line_no}: expected {holds}, got {line.strip()!r}") from None
        values[name] = rows
    width = values["image_size.txt"]
    if len(width) != 1 or len(width[0]) != 1:
        raise ValueError(f"{folder / 'image_size.txt'}: expected one number (cm), got {width!r}")
    power = values["light_power.txt"]
    if len(power) != 1:
        raise ValueError(f"{folder / 'light_power.txt'}: expected one line r,g,b or one number, got {len(power)} lines")
    return {"width": _number(width[0][0], f"{folder / 'image_size.txt'}", positive=True),
            "camera": _positions(values["camera_pos.txt"], f"{folder / 'camera_pos.txt'}"),
            "light": _positions(values["light_pos.txt"], f"{folder / 'light_pos.txt'}"),
            "power": _power(power[0], f"{folder / 'light_power.txt'}"), "idx": None, "dir": None}


def _photo(folder: Path, number: int) -> Path | None:
    """Photo ``number`` (``NN.png``, ``.jpg`` or ``.jpeg``) in ``folder``, or None."""
    for name in (f"{number:02d}.png", f"{number:02d}.jpg", f"{number:02d}.jpeg"):
        if (folder / name).is_file():
            return folder / name
    return None


def _photo_folder(folders: Sequence[Path], idx: Sequence[int], source: Path) -> Path:
    """The first of ``folders`` that holds every photo of ``idx``; else a ValueError naming the first photo
    missing from the first folder (and that the others do not hold them either)."""
    for folder in folders:
        if all(_photo(folder, i) is not None for i in idx):
            return folder
    first = folders[0]
    missing = next(i for i in idx if _photo(first, i) is None)
    others = "".join(f" (or all the photos in {f})" for f in folders[1:])
    raise ValueError(f"{source}: expected photo {missing:02d}.png in {first}{others}, got no such file")


def read_foreign_capture(folder: str | os.PathLike) -> ForeignCapture:
    """Read a capture folder of the MaterialGAN / svbrdf-diff-renderer layout (see the module docstring).

    Args:
        folder: the capture folder (holding ``parameters.json``, ``optim.json`` or the text files),
            or the JSON file itself.

    Returns:
        The calibration in the project's units (positions ``* 2 / width``, intensity ``light_pow *
        (2 / width)^2 / pi``), rectified photos, each image's ``file`` the photo's path.

    Raises:
        ValueError: a missing or malformed key or file, naming the file and the key.
    """
    path = Path(folder)
    if path.is_file():
        source, path = path, path.parent
        data = _read_json(source)
    elif not path.is_dir():
        raise ValueError(f"{path}: expected a capture folder (with {' or '.join(JSON_NAMES)}), got no such folder")
    else:
        source = next((path / n for n in JSON_NAMES if (path / n).is_file()), None)  # type: ignore[assignment]
        if source is not None:
            data = _read_json(source)
        elif (path / "camera_pos.txt").is_file():
            source, data = path / "camera_pos.txt", _read_text(path)
        else:
            raise ValueError(f"{path}: expected {', '.join(JSON_NAMES)} or camera_pos.txt (MaterialGAN layout), "
                             f"got none of them")
    n = len(data["camera"])
    if len(data["light"]) != n:
        raise ValueError(f"{source}: light_pos: expected {n} positions like camera_pos, got {len(data['light'])}")
    idx = data["idx"]
    if idx is None:
        idx = list(range(n))
    if not isinstance(idx, list) or not idx or not all(isinstance(i, int) and not isinstance(i, bool)
                                                       and 0 <= i < n for i in idx):
        raise ValueError(f"{source}: idx: expected a non-empty list of photo numbers in [0, {n}), got {idx!r}")
    if data["dir"] is not None and not isinstance(data["dir"], str):
        raise ValueError(f"{source}: target_dir: expected a folder name, got {data['dir']!r}")
    # the photos' folder: target_dir first, then beside the calibration (data sets are often unpacked that way)
    folders = [path / data["dir"], path] if data["dir"] else [path]
    photo_dir = _photo_folder(folders, idx, source)
    note = None
    if data["dir"] and photo_dir == folders[0]:
        note = f"photos: in target_dir {data['dir']!r} ({photo_dir})"
    elif data["dir"]:
        why = "not all of them there" if folders[0].is_dir() else "no such folder"
        note = f"photos: beside {source.name} in {photo_dir}, not in target_dir {data['dir']!r} ({why})"
    scale = 2.0 / data["width"]
    intensity = tuple(p * scale * scale / math.pi for p in data["power"])
    photos, images = [], []
    for i in idx:
        photo = _photo(photo_dir, i)
        assert photo is not None  # _photo_folder checked every photo
        camera = tuple(v * scale for v in data["camera"][i])
        light = tuple(v * scale for v in data["light"][i])
        photos.append(photo)
        images.append(ImageSpec(str(photo), "srgb8", True, CameraSpec(camera, RECTIFIED_FOV_DEG),  # type: ignore[arg-type]
                                LightSpec(light, intensity)))  # type: ignore[arg-type]
    return ForeignCapture(CaptureSpec(tuple(images)), tuple(photos), source, data["width"], photo_dir, note)


def write_foreign_capture(spec: CaptureSpec, photos: Sequence[Path], folder: str | os.PathLike, *,
                          width_cm: float, name: str = "parameters.json") -> Path:
    """Write a capture in the MaterialGAN layout (``name`` with cm positions; photos copied as ``NN.png``).

    The inverse of :func:`read_foreign_capture` for rectified captures with one flash intensity:
    used to hand our captures to the other lab's tools, and by the tests.

    Returns:
        The JSON file written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    to_cm = width_cm / 2.0
    power = [v * math.pi * to_cm * to_cm for v in spec.images[0].light.intensity]
    data = {"image_size": width_cm, "idx": list(range(spec.n_images)),
            "camera_pos": [[v * to_cm for v in im.camera.position] for im in spec.images],
            "light_pos": [[v * to_cm for v in im.light.position] for im in spec.images],
            "light_pow": power}
    for k, photo in enumerate(photos):
        with atomic_path(folder / f"{k:02d}.png") as tmp:
            shutil.copyfile(photo, tmp)
    write_json(folder / name, data)
    return folder / name


def foreign_photos(foreign: ForeignCapture, size: int | None = None, *,
                   max_size: int | None = None) -> tuple[CaptureSpec, torch.Tensor, int]:
    """The photos of a read foreign capture, ready for :func:`~mi_svbrdf.io.calibrated_photos.save_capture`.

    Each photo is decoded from sRGB (:func:`mi_svbrdf.io.photos.load_photo`), clipped to [0, 1]
    and resized to ``size`` (None: the smallest photo's side, at most ``max_size``).

    Returns:
        ``(spec, images, size)``: the spec with files ``000.png``, ``001.png`` ...; images
        ``(N, 3, size, size)`` linear.
    """
    photos = [load_photo(f) for f in foreign.photos]
    check_consistent(photos, crop=False, full_resolution=False)
    if size is None:
        size = min(p.image.shape[0] for p in photos)
        size = min(size, max_size) if max_size else size
    images = prepare(photos, size)[0].clamp(0.0, 1.0)
    spec = CaptureSpec(tuple(dataclasses.replace(im, file=f"{k:03d}.png") for k, im in enumerate(foreign.spec.images)))
    return spec, images, int(images.shape[-1])
