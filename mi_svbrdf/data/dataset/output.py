"""The on-disk layout of a rendered dataset: shards, strips, per-render JSON, manifest, resume.

::

    out/manifest.json             the job; written first, checked by every later run
    out/shard_0000/000000.png     strip: input | normal | diffuse | roughness | specular (8-bit RGB)
    out/shard_0000/000000.json    the render's parameters

Render ``i`` lives in ``shard_{i // shard_size:04d}``. Every file is written under a temporary
name (``.<stem>.tmp<hex><suffix>``, :func:`mi_svbrdf.io.atomic.atomic_path`) and renamed, the PNG
before the JSON: a render is *done* when its JSON exists (:func:`done_renders`), so a killed run
leaves at most stray temporary files (removed on resume) and PNGs without JSON (rendered again).

**Strip encoding.** :func:`write_strip_codes` writes the same 8-bit codes as
:func:`mi_svbrdf.io.strip.write_strip` (maps: ``rint(255 clip(v))`` of linear albedos, ``(n + 1)/2``
normals, roughness in 3 channels; the input panel: the photo's codes as they are) but encodes the
PNG itself, for speed: PNG filter "up" on every row, then deflate at level 1 by ISA-L (the ``isal``
package, ~3 ms per 256 x 1280 strip on our CPUs) or, without it, zlib with the run-length strategy
(~15 ms). The image_io writer (libpng's adaptive filters, level 6) takes ~60 ms for files ~15 %
smaller. Any PNG reader reads either; the compressor is recorded in the manifest because the bytes
(not the pixels) depend on it.

**The photo.** The linear render becomes an 8-bit phone-like photo as in the authors' pipeline
(:func:`mi_svbrdf.core.flash.photo_pipeline`): clip to [0, 1], encode ``x^(1/2.2)``, quantise
``trunc(255.5 x)`` (:func:`photo_codes`). The strip stores these 8-bit *gamma codes* (like the
thesis dataset's inputs); the linear LDR image, "a gamma-inverted phone photo", is
``(png / 255)^2.2`` (:func:`decode_photo`; equal to ``photo_pipeline`` of the render).

Examples:
    >>> import tempfile, pathlib, torch
    >>> from mi_svbrdf.core import maps as M
    >>> from mi_svbrdf.io import strip
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "000000.png"
    >>> write_strip_codes(path, M.constant_maps(1, 4, 4), torch.full((3, 4, 4), 128.0))
    >>> inputs, maps = strip.read_strip(path, crop=None)
    >>> round(float(inputs[0, 0, 0, 0]) * 255), tuple(maps.shape)
    (128, (1, 10, 4, 4))
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import struct
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.core.colour import gamma_decode, gamma_encode
from mi_svbrdf.core.maps import check_maps, preview
from mi_svbrdf.data.dataset.job import RenderJob
from mi_svbrdf.io.atomic import atomic_path, write_json

#: Name of the manifest file.
MANIFEST_NAME = "manifest.json"
#: ``format`` of ``manifest.json``.
MANIFEST_FORMAT = "mi_svbrdf rendered dataset"
#: Version of ``manifest.json`` and of the per-render JSON.
MANIFEST_VERSION = 1
#: Deflate implementations of :func:`png_bytes`.
COMPRESSORS = ("isal", "zlib")
_TMP_NAME = re.compile(r"^\..+\.tmp[0-9a-f]+(\.[A-Za-z]+)?$")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def shard_dir(out: Path, index: int, shard_size: int) -> Path:
    """Folder of render ``index``."""
    return out / f"shard_{index // shard_size:04d}"


def render_paths(out: Path, index: int, shard_size: int) -> tuple[Path, Path]:
    """``(strip PNG, JSON)`` of render ``index``."""
    folder = shard_dir(out, index, shard_size)
    return folder / f"{index:06d}.png", folder / f"{index:06d}.json"


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` as JSON (indent 1), atomically, without fsync (resume re-validates; see atomic_path)."""
    write_json(path, data, indent=1, fsync=False)


# --------------------------------------------------------------------------------- the photo

def photo_codes(linear: torch.Tensor) -> torch.Tensor:
    """The 8-bit photo of a linear image: codes ``trunc(255.5 clip(x)^(1/2.2))`` in 0..255 (float), same shape."""
    return torch.trunc((255.5 * gamma_encode(linear)).clamp(0.0, 255.0))


def decode_photo(stored: torch.Tensor) -> torch.Tensor:
    """The linear LDR image of a stored photo (``codes / 255``, as read from the strip): ``stored^2.2``."""
    return gamma_decode(stored)


# --------------------------------------------------------------------------------- the strip

def strip_codes(maps: torch.Tensor, codes: torch.Tensor) -> np.ndarray:
    """The 8-bit strip ``(S, 5 S, 3)`` uint8 of maps ``(1, 10, S, S)`` and photo codes ``(3, S, S)``.

    ``codes`` holds integers in [0, 255] (:func:`photo_codes`). The map panels
    (:func:`mi_svbrdf.core.maps.preview`) get the codes :func:`mi_svbrdf.io.strip.write_strip` writes.
    """
    check_maps(maps)
    size = maps.shape[-1]
    if maps.shape[0] != 1 or maps.shape[-2] != size or tuple(codes.shape) != (3, size, size):
        raise ValueError(f"maps, codes: expected (1, 10, S, S) square maps and (3, S, S) codes, "
                         f"got {tuple(maps.shape)} and {tuple(codes.shape)}")
    # float32 and round-half-even, as image_io's PNG writer does: the same codes.
    panels = preview(maps.detach().to("cpu", torch.float32))[0].mul_(255.0).round_()
    strip = np.empty((size, 5 * size, 3), np.uint8)
    strip[:, :size] = codes.detach().to("cpu", torch.float32).clamp(0.0, 255.0).permute(1, 2, 0).numpy()
    strip[:, size:] = panels.permute(1, 2, 0).numpy()
    return strip


def default_compressor() -> str:
    """``"isal"`` when the ``isal`` package is installed, else ``"zlib"``."""
    try:
        import isal.isal_zlib  # noqa: F401
    except ImportError:
        return "zlib"
    return "isal"


def _deflate(data: bytes, compressor: str) -> bytes:
    if compressor == "isal":
        try:
            from isal import isal_zlib
        except ImportError as err:
            raise ValueError("compressor: expected the isal package for 'isal' (pip install isal; the dataset's "
                             "manifest asks for it), got no module 'isal'") from err
        return isal_zlib.compress(data, 1)
    if compressor == "zlib":
        deflate = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_RLE)
        return deflate.compress(data) + deflate.flush()
    raise ValueError(f"compressor: expected one of {COMPRESSORS}, got {compressor!r}")


def png_bytes(image: np.ndarray, compressor: str = "zlib") -> bytes:
    """An 8-bit RGB PNG of ``image`` ``(H, W, 3)`` uint8: filter "up", deflate level 1 by ``compressor``."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected (H, W, 3) uint8, got {image.shape} {image.dtype}")
    height, width, _ = image.shape
    rows = image.reshape(height, width * 3)
    filtered = np.empty((height, width * 3 + 1), np.uint8)
    filtered[:, 0] = 2  # "up": each byte minus the byte above (modulo 256)
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])
    data = _deflate(filtered.tobytes(), compressor)

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, no interlace
    return _PNG_SIGNATURE + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b"")


def write_strip_codes(path: Path, maps: torch.Tensor, codes: torch.Tensor, compressor: str = "zlib") -> None:
    """Write the strip of maps ``(1, 10, S, S)`` and photo codes ``(3, S, S)`` to ``path``, atomically."""
    data = png_bytes(strip_codes(maps, codes), compressor)
    with atomic_path(path, fsync=False) as tmp:  # resume re-validates PNGs; see atomic_path
        tmp.write_bytes(data)


def write_render(out: Path, job: RenderJob, index: int, maps: torch.Tensor, linear: np.ndarray,
                 record: Mapping[str, Any], compressor: str = "zlib") -> None:
    """Write render ``index``: the strip PNG (deflated by ``compressor``), then its JSON (each atomically)."""
    png, js = render_paths(out, index, job.shard_size)
    png.parent.mkdir(parents=True, exist_ok=True)
    write_strip_codes(png, maps, photo_codes(torch.from_numpy(linear).permute(2, 0, 1)), compressor)
    _write_json(js, record)


# ----------------------------------------------------------------------------- manifest, resume

def manifest(job: RenderJob, names: Sequence[str], compressor: str, scene_file: Path) -> dict[str, Any]:
    """The ``manifest.json`` of ``job`` over the materials ``names`` (in job order), PNGs by ``compressor``.

    ``scene_file`` is the job's XML scene (its hash is recorded). The shot ranges are recorded under
    the key ``"capture"``, their earlier name, so that datasets rendered before the rename resume.
    """
    return {
        "format": MANIFEST_FORMAT,
        "format_version": MANIFEST_VERSION,
        "scene": job.scene,
        "scene_sha256": hashlib.sha256(Path(scene_file).read_bytes()).hexdigest(),
        "params": dict(sorted(job.params.items())),
        "materials": {"root": job.materials, "count": len(names),
                      "names_sha256": hashlib.sha256("\n".join(names).encode()).hexdigest()},
        "renders_per_material": job.renders_per_material,
        "count": len(names) * job.renders_per_material,
        "seed": job.seed,
        "size": job.size,
        "spp": job.spp,
        "shard_size": job.shard_size,
        "capture": json.loads(json.dumps(dataclasses.asdict(job.shots))),
        "png_compressor": compressor,
        "layout": "shard_{i // shard_size:04d}/{i:06d}.png (strip: input | normal | diffuse | roughness | "
                  "specular) + .json; material = i // renders_per_material",
    }


def previous_compressor(out: Path) -> str | None:
    """The PNG compressor of a previous run's manifest in ``out`` (a resume keeps it), if any."""
    try:
        value = json.loads((out / MANIFEST_NAME).read_text(encoding="utf-8")).get("png_compressor")
    except (OSError, ValueError, AttributeError):
        return None
    return value if isinstance(value, str) else None


def prepare_out(out: Path, expected: Mapping[str, Any]) -> None:
    """Create ``out`` with its manifest, or check that a previous run's manifest equals ``expected``.

    Raises:
        ValueError: the manifest differs (naming the differing keys), is unreadable, or ``out``
            holds shard folders without a manifest.
    """
    path = out / MANIFEST_NAME
    if path.is_file():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as err:
            raise ValueError(f"{path}: expected a readable manifest, got {err}") from err
        if old != expected:
            keys = sorted(k for k in set(old) | set(expected) if old.get(k) != expected.get(k))
            diffs = "; ".join(f"{k}: {old.get(k)!r} -> {expected.get(k)!r}" for k in keys)
            raise ValueError(f"{path}: expected the manifest of this job to resume into {out}, got a "
                             f"different job ({diffs}); use another --out or delete {out}")
        return
    out.mkdir(parents=True, exist_ok=True)
    if any(out.glob("shard_*")):
        raise ValueError(f"{out}: expected an empty folder or a previous run with {MANIFEST_NAME}, "
                         f"got shard folders without a manifest")
    _write_json(path, expected)


_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def _complete(png: str, js: str) -> bool:
    """A PNG that ends with its IEND chunk and a non-empty JSON (shards are written without
    fsync, so after an operating-system crash a renamed file could still be incomplete)."""
    try:
        if os.path.getsize(js) == 0:
            return False
        with open(png, "rb") as f:
            f.seek(-len(_PNG_END), os.SEEK_END)
            return f.read() == _PNG_END
    except OSError:
        return False


def done_renders(out: Path, count: int, shard_size: int) -> set[int]:
    """Indices below ``count`` whose PNG and JSON both exist and are complete; deletes stray
    temporary files."""
    done: set[int] = set()
    for shard in sorted(out.glob("shard_*")):
        if not shard.is_dir():
            continue
        names = set()
        for entry in os.scandir(shard):
            if _TMP_NAME.match(entry.name):
                os.unlink(entry.path)
            else:
                names.add(entry.name)
        for name in names:
            stem, _, ext = name.partition(".")
            if ext == "json" and stem.isdigit() and f"{stem}.png" in names:
                index = int(stem)
                if (index < count and shard == shard_dir(out, index, shard_size)
                        and _complete(os.path.join(shard, f"{stem}.png"), os.path.join(shard, name))):
                    done.add(index)
    return done
