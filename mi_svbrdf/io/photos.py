"""Real photos for the networks: load, orient, linearise, crop to a square, resize.

What :func:`load_photo` does to a file, in order (each a documented conversion, not an error):

1. **Decode.** PNG through :func:`mi_svbrdf.io.image_io.read_image` (8 *and 16-bit* at full
   precision: Pillow would truncate 16-bit RGB to 8 bits); EXR (linear floats) likewise; every
   other format Pillow opens (JPEG, TIFF, WebP, BMP ...) through Pillow. 8-bit codes are divided
   by 255, 16-bit ones by 65535.
2. **EXIF orientation** (tag 0x0112) applied: ``PIL.ImageOps.exif_transpose`` for Pillow-decoded
   files, the same eight transforms on the array for PNG (:func:`orient`).
3. **Channels.** Grey (L, I;16, 1-bit) is replicated to RGB (a grey photo gives grey albedos);
   an alpha channel is dropped whatever its values; palettes, CMYK and YCbCr become RGB.
4. **Linearise.** sRGB-encoded values are decoded with colour-science's sRGB curve
   (:func:`mi_svbrdf.io.material_io.srgb_decode`), unless ``linear=True`` (inputs already linear,
   e.g. a raw conversion). EXR files are always taken as linear.
5. **Crop.** ``crop=(x, y, w, h)`` (pixels of the upright photo) selects a region first; then
   the centre square of the photo (or region) is kept. The networks see a square sample.

Then :func:`prepare` resizes every square to one size (antialiased bilinear, on linear values).
Because each photo is cropped to a square first, photos of different pixel sizes are fine when
they have the same aspect ratio (they are resized to a common size); photos whose aspect ratios
differ (before the crop) are an error, since their centre squares would frame the sample
differently. Errors (``ValueError`` naming the file): not an image, a crop outside the photo, a
square smaller than :data:`MIN_SIZE`, mixed aspect ratios, or (at full resolution, where nothing
is resized) mixed sizes.

Examples:
    >>> import numpy as np
    >>> a = np.arange(6, dtype=np.float32).reshape(2, 3, 1)
    >>> orient(a, 6)[:, :, 0].tolist()  # EXIF 6: the camera was turned 90 degrees clockwise
    [[3.0, 0.0], [4.0, 1.0], [5.0, 2.0]]
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mi_svbrdf.io.image_io import read_image
from mi_svbrdf.io.material_io import srgb_decode

#: Smallest side (pixels) of the square a photo is cropped to.
MIN_SIZE = 64
#: Relative tolerance on aspect ratios of photos taken together.
ASPECT_TOLERANCE = 0.01
#: EXIF tag of the orientation.
ORIENTATION_TAG = 0x0112
#: Suffixes decoded by :mod:`mi_svbrdf.io.image_io` rather than Pillow.
_IMAGE_IO_SUFFIXES = (".png", ".exr")
#: Suffixes of the photos :func:`photo_files` finds in a folder.
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".exr", ".webp", ".bmp")
#: A pixel is dark when its brightest linear channel is below this (about sRGB code 12 of 255).
DARK_LEVEL = 0.004
#: A pixel is saturated when a linear channel is at or above this (sRGB code 255 of 255; 254 is 0.991).
SATURATED_LEVEL = 0.995
#: A photo is called black (or saturated) when at least this fraction of its pixels is dark (or saturated).
UNUSABLE_FRACTION = 0.95


@dataclass
class Photo:
    """A loaded photo: linear RGB, upright and cropped, with what was done to it.

    Attributes:
        path: the file.
        image: ``(S, S, 3)`` float32 linear values (the square crop).
        original_size: ``(H, W)`` of the upright photo before any crop.
        conversions: human-readable list of what was converted (EXIF, grey, alpha, 16-bit ...).
    """

    path: Path
    image: np.ndarray
    original_size: tuple[int, int]
    conversions: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, object]:
        """JSON-ready description."""
        return {"path": str(self.path), "original_size_hw": list(self.original_size),
                "square": int(self.image.shape[0]), "conversions": self.conversions}


def orient(image: np.ndarray, orientation: int) -> np.ndarray:
    """Apply EXIF ``orientation`` (1-8) to ``image (H, W, C)`` like ``PIL.ImageOps.exif_transpose``."""
    ops = {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.transpose(1, 0, 2), 6: lambda a: np.rot90(a, -1),
           7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),
           8: lambda a: np.rot90(a, 1)}
    if orientation not in ops:
        return image
    return np.ascontiguousarray(ops[orientation](image))


def _read_pillow(path: Path, notes: list[str]) -> tuple[np.ndarray, bool]:
    """``(image (H, W, C) float32 in [0, 1] upright, is_linear)`` through Pillow."""
    from PIL import Image, ImageOps, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            img.load()
            orientation = img.getexif().get(ORIENTATION_TAG, 1)
            upright = ImageOps.exif_transpose(img)
    except UnidentifiedImageError as exc:
        raise ValueError(f"{path}: expected an image file (JPEG, PNG, TIFF, EXR ...), "
                         "got a file that no image reader understands") from exc
    except (OSError, SyntaxError, ValueError) as exc:
        reason = " ".join(str(exc).replace(str(path), "").split()) or type(exc).__name__
        raise ValueError(f"{path}: expected an image file (JPEG, PNG, TIFF, EXR ...), "
                         f"got a damaged one ({reason})") from exc
    if orientation not in (1, None):
        notes.append(f"EXIF orientation {orientation} applied")
    mode = upright.mode
    if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
        notes.append("16-bit grey replicated to RGB")
        a = np.asarray(upright, dtype=np.float32) / 65535.0
        return np.repeat(a[:, :, None], 3, axis=2), False
    if mode == "F":
        notes.append("float grey replicated to RGB, taken as linear")
        a = np.asarray(upright, dtype=np.float32)
        return np.repeat(a[:, :, None], 3, axis=2), True
    if mode == "I":
        raise ValueError(f"{path}: expected 8- or 16-bit image data, got 32-bit integer pixels (mode 'I')")
    if mode in ("1", "L", "LA", "La"):
        notes.append("grey replicated to RGB" + ("; alpha dropped" if "A" in mode or "a" in mode else ""))
        upright = upright.convert("L").convert("RGB")
    elif mode in ("RGBA", "RGBa", "PA") or (mode == "P" and "transparency" in upright.info):
        notes.append("alpha dropped")
        upright = upright.convert("RGBA").convert("RGB")
    elif mode != "RGB":
        notes.append(f"mode {mode} converted to RGB")
        upright = upright.convert("RGB")
    return np.asarray(upright, dtype=np.float32) / 255.0, False


def _read_image_io(path: Path, notes: list[str]) -> tuple[np.ndarray, bool]:
    """PNG/EXR through :mod:`mi_svbrdf.io.image_io` (16-bit kept), oriented with the EXIF tag Pillow reads."""
    image, info = read_image(path)  # its errors name the file and what was expected
    if info.format == "png":
        from PIL import Image

        try:
            with Image.open(path) as img:
                orientation = img.getexif().get(ORIENTATION_TAG, 1)
        except Exception:  # noqa: BLE001 - the pixels were read; missing EXIF means upright
            orientation = 1
        if orientation not in (1, None):
            notes.append(f"EXIF orientation {orientation} applied")
            image = orient(image, int(orientation))
    if info.bit_depth == 16 and info.format == "png":
        notes.append("16-bit PNG read at full precision")
    if image.shape[2] in (2, 4):
        notes.append("alpha dropped")
        image = image[:, :, :-1]
    if image.shape[2] == 1:
        notes.append("grey replicated to RGB")
        image = np.repeat(image, 3, axis=2)
    return image.astype(np.float32), info.format == "exr"


def parse_crop(text: str) -> tuple[int, int, int, int]:
    """``"x,y,w,h"`` -> ints (``--crop``); ``ValueError`` otherwise."""
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or values[0] < 0 or values[1] < 0 or values[2] < 1 or values[3] < 1:
        raise ValueError(f"--crop: expected x,y,w,h (pixels, x, y >= 0, w, h >= 1), got {text!r}")
    return values  # type: ignore[return-value]


def square_crop(image: np.ndarray) -> np.ndarray:
    """The centre square of ``image (H, W, C)``: side ``min(H, W)``."""
    h, w = image.shape[:2]
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    return image[top:top + s, left:left + s]


def load_photo(path: str | os.PathLike, *, linear: bool = False,
               crop: tuple[int, int, int, int] | None = None, square: bool = True) -> Photo:
    """Load one photo as a linear, upright, square RGB array (see the module docstring).

    Args:
        path: an image file.
        linear: the file's values are linear already (no sRGB decoding).
        crop: ``(x, y, w, h)`` region of the upright photo, taken before the centre square.
        square: keep the centre square (step 5); False: the whole photo (or crop), any aspect ratio
            (``mi-svbrdf large-scale``).

    Returns:
        A :class:`Photo` with ``image`` ``(S, S, 3)`` float32, ``S >= MIN_SIZE`` (``square=False``:
        ``(H, W, 3)``, ``min(H, W) >= MIN_SIZE``).

    Raises:
        FileNotFoundError: no such file.
        IsADirectoryError: ``path`` is a folder.
        ValueError: naming the file: not an image, crop outside the photo, too small.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: expected a photo file, got a folder (photo_files() lists the photos "
                                "in a folder; mi-svbrdf capture takes a folder as it is)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected a photo file, got no such file")
    notes: list[str] = []
    reader = _read_image_io if path.suffix.lower() in _IMAGE_IO_SUFFIXES else _read_pillow
    image, is_linear = reader(path, notes)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{path}: expected an RGB or grey image, got array shape {image.shape}")
    original = (int(image.shape[0]), int(image.shape[1]))
    if not np.isfinite(image).all():
        raise ValueError(f"{path}: expected finite pixel values, got NaN or Inf")
    if not (linear or is_linear):
        image = srgb_decode(np.clip(image, 0.0, 1.0))
        notes.append("sRGB decoded to linear")
    elif is_linear and not linear:
        notes.append("EXR taken as linear")
    if crop is not None:
        x, y, w, h = crop
        if x + w > original[1] or y + h > original[0]:
            raise ValueError(f"{path}: expected --crop x,y,w,h inside the upright photo of {original[1]}x"
                             f"{original[0]} (W x H), got {x},{y},{w},{h}")
        image = image[y:y + h, x:x + w]
        notes.append(f"cropped to x={x} y={y} w={w} h={h}")
    if not square:
        if min(image.shape[:2]) < MIN_SIZE:
            raise ValueError(f"{path}: expected a photo (or crop) whose sides are at least {MIN_SIZE} px, "
                             f"got {image.shape[1]}x{image.shape[0]} px (W x H)")
        return Photo(path=path, image=np.ascontiguousarray(np.clip(image, 0.0, None), dtype=np.float32),
                     original_size=original, conversions=notes)
    if image.shape[0] != image.shape[1]:
        notes.append(f"centre square {min(image.shape[:2])} px of {image.shape[1]}x{image.shape[0]}")
    image = square_crop(image)
    if image.shape[0] < MIN_SIZE:
        raise ValueError(f"{path}: expected a photo (or crop) whose square is at least {MIN_SIZE} px, "
                         f"got {image.shape[0]} px (upright photo {original[1]}x{original[0]}, W x H)")
    return Photo(path=path, image=np.ascontiguousarray(np.clip(image, 0.0, None), dtype=np.float32),
                 original_size=original, conversions=notes)


def check_consistent(photos: Sequence[Photo], *, crop: bool, full_resolution: bool) -> None:
    """Photos taken together must frame the sample alike; ``ValueError`` naming the files otherwise.

    Without an explicit crop the upright photos must share their aspect ratio (within
    :data:`ASPECT_TOLERANCE`); at full resolution their squares must also have one size.
    """
    first = photos[0]
    for p in photos[1:]:
        (h0, w0), (h, w) = first.original_size, p.original_size
        if not crop and abs(w / h - w0 / h0) > ASPECT_TOLERANCE * (w0 / h0):
            raise ValueError(f"photos: expected the same aspect ratio for every photo, got {first.path} "
                             f"{w0}x{h0} and {p.path} {w}x{h} (W x H); crop them alike (--crop) first")
        if full_resolution and p.image.shape[0] != first.image.shape[0]:
            raise ValueError(f"photos: expected squares of one size at full resolution, got {first.path} "
                             f"{first.image.shape[0]} px and {p.path} {p.image.shape[0]} px; "
                             "drop --full-resolution to resize them")


def resize(images: torch.Tensor, size: int) -> torch.Tensor:
    """Antialiased bilinear resize of ``(..., 3, S, S)`` linear values to ``(..., 3, size, size)``."""
    if images.shape[-1] == size and images.shape[-2] == size:
        return images
    lead = images.shape[:-3]
    flat = images.reshape(-1, *images.shape[-3:])
    out = F.interpolate(flat, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return out.clamp_min(0.0).reshape(*lead, 3, size, size)


def prepare(photos: Sequence[Photo], size: int | None) -> torch.Tensor:
    """Stack squares ``(1, N, 3, S, S)``, resized to ``size`` (None: keep their common size)."""
    tensors = [torch.from_numpy(p.image).permute(2, 0, 1) for p in photos]
    if size is None:
        return torch.stack(tensors)[None].contiguous()
    return torch.stack([resize(t, size) for t in tensors])[None].contiguous()


def photo_files(folder: str | os.PathLike) -> list[Path]:
    """The photos of ``folder`` (files with a :data:`PHOTO_SUFFIXES` suffix, not hidden), sorted by name."""
    return sorted(p for p in Path(folder).iterdir()
                  if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES and not p.name.startswith("."))


def exposure_notes(images: torch.Tensor, names: Sequence[str], *, saturated: torch.Tensor | None = None,
                   result: str = "the maps") -> list[str]:
    """Warnings about photos that are (almost) all black or all saturated, and what ``result`` is then worth.

    Args:
        images: ``(N, 3, H, W)`` linear photos.
        names: a name per photo (its file), for the messages.
        saturated: ``(N, 1, H, W)`` bool, True where a pixel is saturated (e.g. a channel at the top
            code of its file); None: a channel >= :data:`SATURATED_LEVEL`.
        result: what was made from the photos, for the verdict ("the maps", "the fit" ...).

    Returns:
        One line per black or saturated photo (at least :data:`UNUSABLE_FRACTION` of its pixels
        dark or saturated), then a verdict line; empty when every photo is usable.
    """
    images = images.detach().float().cpu()
    if saturated is None:
        saturated = (images >= SATURATED_LEVEL).any(dim=1, keepdim=True)
    dark = (images.amax(dim=1, keepdim=True) < DARK_LEVEL).flatten(1).float().mean(1)
    clipped = saturated.cpu().flatten(1).float().mean(1)
    notes = []
    for name, d, c in zip(names, dark.tolist(), clipped.tolist()):
        if d >= UNUSABLE_FRACTION:
            notes.append(f"warning: {name}: {d:.0%} of the pixels are black (under-exposed, lens covered or flash "
                         "not fired): the photo holds no measurement")
        elif c >= UNUSABLE_FRACTION:
            notes.append(f"warning: {name}: {c:.0%} of the pixels are saturated (over-exposed): the photo holds "
                         "no measurement")
    bad, n = len(notes), len(names)
    if bad == n:
        notes.append(f"warning: every photo is black or saturated: {result} are not a measurement of the material "
                     "(only the method's prior or starting point); do not use them, retake the photos with a "
                     "correct exposure")
    elif bad:
        notes.append(f"warning: {bad} of {n} photos are black or saturated: {result} rest on the other {n - bad}")
    return notes
