"""A material as a folder of maps: ``normal``, ``diffuse``, ``roughness``, ``specular`` + ``material.json``.

Encodings on disk (recorded per map in ``material.json``):

- ``"normal_01"``: normals stored as ``(n + 1) / 2``, decoded as ``2 v - 1`` and renormalised
  (a zero-length decoded normal becomes ``(0, 0, 1)``). 8-bit PNG cannot store 0.5, so a flat
  normal reads back tilted by up to 0.3 degrees; 16-bit PNG or EXR avoid this.
- ``"srgb"``: albedos encoded with colour-science's sRGB transfer functions
  (``colour.cctf_encoding`` / ``cctf_decoding``, IEC 61966-2-1). The default for PNG.
- ``"linear"``: values as they are. Always for roughness and for EXR.

``material.json`` (format version 1) names each map's file, encoding and bit depth (the bit depth
is informational; the file's own depth is what is read). Without ``material.json`` the folder
must hold exactly one of ``<map>.png`` / ``<map>.exr`` per map, and PNG albedos are taken as sRGB,
EXR albedos as linear, roughness as linear, normals as ``(n + 1) / 2``.

The BRDF model the maps are meant for is ``material.json``'s ``"distribution"``: ``"ggx"`` (the
thesis's) or ``"beckmann"`` (e.g. a Beckmann fit, thesis ch. 6.1.1); a roughness means a different
lobe in each. :func:`read_distribution` returns it, ``"ggx"`` for folders written before it was
recorded (or without ``material.json``).

Roughness files may be grey or RGB; RGB is averaged (like :func:`mi_svbrdf.core.maps.make_maps`).

Examples:
    >>> import tempfile
    >>> from mi_svbrdf.core import maps as M
    >>> folder = tempfile.mkdtemp()
    >>> _ = write_material(folder, M.constant_maps(1, 4, 4, diffuse=0.5), fmt="exr")
    >>> m = read_material(folder)
    >>> tuple(m.shape), float(M.diffuse(m)[0, 0, 0, 0])
    ((1, 10, 4, 4), 0.5)
"""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core.maps import MAP_CHANNELS, MAP_NAMES, SLICES, check_maps
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.image_io import read_image, select_channels, write_image
from mi_svbrdf.plugins.model import DISTRIBUTIONS

#: Version written to, and the newest understood in, ``material.json``.
FORMAT_VERSION = 1
#: Name of the metadata file.
METADATA_NAME = "material.json"
#: Encodings allowed per map.
ENCODINGS: dict[str, tuple[str, ...]] = {"normal": ("normal_01",), "diffuse": ("srgb", "linear"),
                                         "roughness": ("linear", "srgb"), "specular": ("srgb", "linear")}
_ALBEDOS = ("diffuse", "specular")
#: The BRDF model of a folder that does not record one (written before it was recorded).
DEFAULT_DISTRIBUTION = "ggx"


def _colour() -> Any:
    """Import colour-science lazily (1 s) and without its warning about matplotlib."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    return colour


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB-encode ``linear`` (clipped to [0, 1]) with ``colour.cctf_encoding``; float32."""
    return _colour().cctf_encoding(np.clip(linear, 0.0, 1.0), function="sRGB").astype(np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Decode sRGB values to linear with ``colour.cctf_decoding``; float32."""
    return _colour().cctf_decoding(encoded, function="sRGB").astype(np.float32)


def decode_normal(stored: np.ndarray) -> np.ndarray:
    """``(..., 3)`` values ``(n + 1) / 2`` -> unit normals ``2 v - 1`` renormalised; zero -> ``(0, 0, 1)``."""
    n = stored.astype(np.float32) * 2.0 - 1.0
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    flat = np.array([0.0, 0.0, 1.0], dtype=np.float32)
    return np.where(length > 1e-6, n / np.maximum(length, 1e-6), flat).astype(np.float32)


def encode_normal(normal: np.ndarray) -> np.ndarray:
    """``(..., 3)`` normals -> ``(n + 1) / 2`` clipped to [0, 1]."""
    return np.clip((normal + 1.0) * 0.5, 0.0, 1.0).astype(np.float32)


def single_material(maps: torch.Tensor, name: str = "maps") -> np.ndarray:
    """Check a ``(1, 10, H, W)`` or ``(10, H, W)`` tensor and return it as ``(H, W, 10)`` float32 numpy."""
    if isinstance(maps, torch.Tensor) and maps.dim() == 3:
        maps = maps.unsqueeze(0)
    check_maps(maps, name)
    if maps.shape[0] != 1:
        raise ValueError(f"{name}: expected a single material (1, 10, H, W) or (10, H, W), "
                         f"got batch size {maps.shape[0]}; write each material on its own")
    return maps[0].detach().to("cpu", torch.float32).permute(1, 2, 0).numpy()


def write_material(folder: str | os.PathLike, maps: torch.Tensor, fmt: str = "png",
                   bit_depth: int | None = None, albedo_encoding: str | None = None,
                   distribution: str = DEFAULT_DISTRIBUTION) -> dict[str, Any]:
    """Write one material as a folder of four maps and ``material.json``.

    Albedos and roughness are clipped to [0, 1] and normals stored as ``(n + 1) / 2``. Each file
    is replaced atomically and ``material.json`` last: a crash never leaves a half-written file,
    though it may leave some maps old and some new.

    Args:
        folder: target folder (created if missing).
        maps: ``(1, 10, H, W)`` or ``(10, H, W)`` canonical maps.
        fmt: ``"png"`` or ``"exr"``.
        bit_depth: PNG: 8 (default) or 16; EXR: 32 (float, default) or 16 (half).
        albedo_encoding: ``"srgb"`` (PNG default) or ``"linear"``; EXR is always ``"linear"``.
        distribution: the BRDF model of the maps, ``"ggx"`` or ``"beckmann"`` (recorded in ``material.json``).

    Returns:
        The metadata written to ``material.json``.
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {DISTRIBUTIONS}, got {distribution!r}")
    if fmt not in ("png", "exr"):
        raise ValueError(f"fmt: expected 'png' or 'exr', got {fmt!r}")
    if albedo_encoding is None:
        albedo_encoding = "srgb" if fmt == "png" else "linear"
    allowed = ("srgb", "linear") if fmt == "png" else ("linear",)
    if albedo_encoding not in allowed:
        raise ValueError(f"albedo_encoding: expected one of {allowed} for {fmt.upper()}, "
                         f"got {albedo_encoding!r}")
    bit_depth = (8 if fmt == "png" else 32) if bit_depth is None else bit_depth
    valid = (8, 16) if fmt == "png" else (16, 32)
    if bit_depth not in valid:
        raise ValueError(f"bit_depth: expected one of {valid} for {fmt.upper()}, got {bit_depth}")
    data = single_material(maps)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    meta: dict[str, Any] = {"format": "mi_svbrdf material", "format_version": FORMAT_VERSION,
                            "distribution": distribution, "maps": {}}
    for name in MAP_NAMES:
        values = data[:, :, SLICES[name]]
        if name == "normal":
            encoding, values = "normal_01", encode_normal(values)
        elif name in _ALBEDOS and albedo_encoding == "srgb":
            encoding, values = "srgb", srgb_encode(values)
        else:
            encoding, values = "linear", np.clip(values, 0.0, 1.0)
        file = f"{name}.{fmt}"
        write_image(folder / file, values, bit_depth, srgb=(encoding == "srgb"))
        meta["maps"][name] = {"file": file, "encoding": encoding, "bit_depth": bit_depth}
    write_json(folder / METADATA_NAME, meta)
    return meta


def _default_encoding(name: str, suffix: str) -> str:
    """Encoding assumed without ``material.json``: normals (n + 1)/2, PNG albedos sRGB, else linear."""
    if name == "normal":
        return "normal_01"
    return "srgb" if name in _ALBEDOS and suffix == ".png" else "linear"


def _map_files(folder: Path) -> dict[str, tuple[Path, str]]:
    """``{map: (file, encoding)}`` from ``material.json``, or by file name and suffix without it."""
    meta_path = folder / METADATA_NAME
    if not meta_path.is_file():
        found = {}
        for name in MAP_NAMES:
            files = [p for p in (folder / f"{name}.png", folder / f"{name}.exr") if p.is_file()]
            if not files:
                raise FileNotFoundError(f"{folder}: missing map {name!r}: "
                                        f"expected {name}.png or {name}.exr, got neither")
            if len(files) > 1:
                raise ValueError(f"{folder}: expected one file for map {name!r} "
                                 f"(or a {METADATA_NAME} naming it), "
                                 f"got both {name}.png and {name}.exr")
            found[name] = (files[0], _default_encoding(name, files[0].suffix))
        return found
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        version, entries = meta["format_version"], meta["maps"]
        found = {name: (folder / entries[name]["file"], entries[name]["encoding"]) for name in MAP_NAMES}
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"{meta_path}: expected JSON with 'format_version' and 'maps' -> "
                         f"{{normal, diffuse, roughness, specular}} -> {{'file', 'encoding'}}, "
                         f"got {err!r}") from err
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise ValueError(f"{meta_path}: expected format_version <= {FORMAT_VERSION}, got {version!r}")
    for name, (path, encoding) in found.items():
        if encoding not in ENCODINGS[name]:
            raise ValueError(f"{meta_path}: expected encoding of {name!r} in {ENCODINGS[name]}, "
                             f"got {encoding!r}")
        if not path.is_file():
            raise FileNotFoundError(f"{folder}: missing map {name!r}: expected {path.name} "
                                    f"(named in {METADATA_NAME}), got no such file")
    return found


def read_distribution(folder: str | os.PathLike) -> str:
    """The BRDF model a material folder records (``material.json``'s ``"distribution"``).

    Args:
        folder: a material folder.

    Returns:
        ``"ggx"`` or ``"beckmann"``; ``"ggx"`` (:data:`DEFAULT_DISTRIBUTION`) without ``material.json``
        or without the key (folders written before it was recorded).

    Raises:
        ValueError: naming ``material.json``: invalid JSON or an unknown model.

    Examples:
        >>> import tempfile
        >>> from mi_svbrdf.core import maps as M
        >>> folder = tempfile.mkdtemp()
        >>> _ = write_material(folder, M.constant_maps(1, 4, 4), fmt="exr", distribution="beckmann")
        >>> read_distribution(folder)
        'beckmann'
    """
    meta_path = Path(folder) / METADATA_NAME
    if not meta_path.is_file():
        return DEFAULT_DISTRIBUTION
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except ValueError as err:
        raise ValueError(f"{meta_path}: expected JSON, got {err!r}") from err
    value = meta.get("distribution", DEFAULT_DISTRIBUTION) if isinstance(meta, dict) else DEFAULT_DISTRIBUTION
    if value not in DISTRIBUTIONS:
        raise ValueError(f"{meta_path}: expected 'distribution' in {DISTRIBUTIONS}, got {value!r}")
    return value


def read_material(folder: str | os.PathLike) -> torch.Tensor:
    """Read a material folder written by :func:`write_material` (or four maps named by convention).

    Args:
        folder: folder with ``normal``, ``diffuse``, ``roughness``, ``specular`` as ``.png`` or
            ``.exr``, and optionally ``material.json``.

    Returns:
        ``(1, 10, H, W)`` float32 maps with unit normals.

    Raises:
        FileNotFoundError: the folder or a map is missing.
        ValueError: naming the file: corrupt file, wrong channels or size, NaN/Inf, EXR values
            outside [0, 1], bad ``material.json``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: expected a material folder, got no such directory")
    parts, first = [], None
    for name, (path, encoding) in _map_files(folder).items():
        image, info = read_image(path)
        image = select_channels(image, MAP_CHANNELS[name], path, rgb_to_grey=(name == "roughness"))
        if first is None:
            first = (path, image.shape[:2])
        elif image.shape[:2] != first[1]:
            (h, w), (fh, fw) = image.shape[:2], first[1]
            raise ValueError(f"{path}: expected size {fh}x{fw} (H x W) like {first[0].name}, got {h}x{w}")
        if info.format == "exr" and (image.min() < 0.0 or image.max() > 1.0):
            raise ValueError(f"{path}: expected values in [0, 1] (encoding {encoding!r}), "
                             f"got [{float(image.min()):.6g}, {float(image.max()):.6g}]")
        if encoding == "normal_01":
            image = decode_normal(image)
        elif encoding == "srgb":
            image = srgb_decode(image)
        parts.append(image)
    return torch.from_numpy(np.concatenate(parts, axis=2)).permute(2, 0, 1).unsqueeze(0).contiguous()
