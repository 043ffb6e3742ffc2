"""Low-level image files: PNG (8/16-bit) through ``mitsuba.Bitmap``, EXR through ``OpenEXR``.

Images are numpy arrays ``(H, W, C)`` float32, ``C`` in 1 (Y), 2 (YA), 3 (RGB) or 4 (RGBA).
PNG values are the stored code values divided by 255 or 65535: no colour transform is
applied either way (``mi.Bitmap`` flags every PNG it reads as sRGB, but leaves the codes
alone; this module ignores the flag). EXR values are the stored floats, read as float32.

Every write goes to a temporary file beside the target, named ``.<stem>.tmp<hex><suffix>``
(the suffix is kept so the writer knows the format), and is renamed over the target with
``os.replace``: a crash leaves the old file or the new one, never half of one.

Examples:
    >>> import numpy as np, tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "grey.png"
    >>> write_image(path, np.full((2, 3), 0.5, np.float32), bit_depth=16)
    >>> image, info = read_image(path)
    >>> image.shape, info.bit_depth, round(float(image[0, 0, 0]) * 65535)
    ((2, 3, 1), 16, 32768)
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import mitsuba as mi
import numpy as np
import OpenEXR

from mi_svbrdf.io.atomic import atomic_path

#: Channel names by channel count (PNG pixel formats and EXR channel layouts).
CHANNEL_NAMES: dict[int, tuple[str, ...]] = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"),
                                             4: ("R", "G", "B", "A")}
_PIXEL_FORMATS = {1: mi.Bitmap.PixelFormat.Y, 2: mi.Bitmap.PixelFormat.YA,
                  3: mi.Bitmap.PixelFormat.RGB, 4: mi.Bitmap.PixelFormat.RGBA}
_PNG_DTYPES = {8: np.uint8, 16: np.uint16}
_EXR_DTYPES = {16: np.float16, 32: np.float32}
#: The first bytes of every file of each format.
SIGNATURES = {"png": b"\x89PNG\r\n\x1a\n", "exr": b"\x76\x2f\x31\x01"}


@dataclass(frozen=True)
class ImageInfo:
    """What :func:`read_image` found in a file.

    Attributes:
        path: the file read.
        format: ``"png"`` or ``"exr"``.
        bit_depth: PNG: 8 or 16; EXR: 16 (half) or 32 (float or uint; the widest channel).
        channel_names: ``("Y",)``, ``("Y", "A")``, ``("R", "G", "B")`` or ``("R", "G", "B", "A")``.
    """

    path: Path
    format: str
    bit_depth: int
    channel_names: tuple[str, ...]


def _format_of(path: Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("png", "exr"):
        raise ValueError(f"{path}: expected a .png or .exr file name, got suffix {path.suffix!r}")
    return fmt


def read_image(path: str | os.PathLike, *, check_finite: bool = True) -> tuple[np.ndarray, ImageInfo]:
    """Read a PNG or EXR file (format chosen by the suffix).

    Args:
        path: a ``.png`` (8- or 16-bit, any PNG colour type; palettes and 1/2/4-bit grey are
            expanded by libpng) or ``.exr`` file (first part; channels Y, YA, RGB, RGBA or a
            single channel of any name, which is read as Y).
        check_finite: raise if an EXR holds NaN or Inf.

    Returns:
        ``(image, info)``: ``image`` is ``(H, W, C)`` float32 (PNG in [0, 1], EXR raw).

    Raises:
        FileNotFoundError: no such file.
        IsADirectoryError: ``path`` is a folder.
        ValueError: wrong suffix, not a file of that format (checked before any decoder runs, so
            the message is ours, once, naming the file), corrupt file, unsupported channels, NaN/Inf.
    """
    path = Path(path)
    fmt = _format_of(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path}: expected an image file, got a folder")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: expected an image file, got no such file")
    _check_signature(path, fmt)
    image, info = _read_png(path) if fmt == "png" else _read_exr(path)
    if check_finite and not np.isfinite(image).all():
        raise ValueError(f"{path}: expected finite values, got {int(np.isnan(image).sum())} NaN "
                         f"and {int(np.isinf(image).sum())} Inf")
    return image, info


def _decoder_reason(err: Exception, path: Path) -> str:
    """A decoder's message without the file's name, source locations or line breaks."""
    text = re.sub(r"\[[\w.]+\.(?:cpp|h):\d+\]\s*", "", str(err)).replace(f'"{path}"', "").replace(str(path), "")
    text = re.sub(r"(?i)fatal libpng error:\s*", "", text)
    return " ".join(text.split()).strip(" :") or type(err).__name__


def _unreadable(path: Path, name: str, reason: str) -> ValueError:
    return ValueError(f"{path}: expected a readable {name} file, got an unreadable or corrupt file ({reason})")


def _check_signature(path: Path, fmt: str) -> None:
    """A ``.png`` / ``.exr`` file must start with its format's signature; a PNG must also pass Pillow's check."""
    with open(path, "rb") as f:
        head = f.read(len(SIGNATURES[fmt]))
    name = "PNG" if fmt == "png" else "OpenEXR"
    if head != SIGNATURES[fmt]:
        raise _unreadable(path, name, "an empty file" if not head else
                          f"not {'a' if fmt == 'png' else 'an'} {name} image: it does not start with the {name} "
                          "signature")
    if fmt == "png":
        from PIL import Image

        try:
            with Image.open(path) as img:
                img.verify()  # chunk structure and CRCs, without decoding the pixels
        except Exception as err:  # any failure means a damaged file
            raise _unreadable(path, name, f"damaged: {_decoder_reason(err, path)}") from err


def _read_png(path: Path) -> tuple[np.ndarray, ImageInfo]:
    try:
        bitmap = mi.Bitmap(str(path), mi.Bitmap.FileFormat.PNG)
    except RuntimeError as err:
        raise _unreadable(path, "PNG", f"damaged: {_decoder_reason(err, path)}") from err
    depth = {mi.Struct.Type.UInt8: 8, mi.Struct.Type.UInt16: 16}.get(bitmap.component_format())
    channels = bitmap.channel_count()
    if depth is None or channels not in CHANNEL_NAMES:
        raise ValueError(f"{path}: expected an 8- or 16-bit PNG with 1 to 4 channels, "
                         f"got {bitmap.component_format()} with {channels} channels")
    codes = np.array(bitmap, copy=True).reshape(bitmap.height(), bitmap.width(), channels)
    image = codes.astype(np.float32) / np.float32(2 ** depth - 1)
    return image, ImageInfo(path, "png", depth, CHANNEL_NAMES[channels])


def _read_exr(path: Path) -> tuple[np.ndarray, ImageInfo]:
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = {name: ch.pixels for name, ch in exr.channels().items()}
    except (RuntimeError, ValueError, OSError) as err:
        raise _unreadable(path, "OpenEXR", f"damaged: {_decoder_reason(err, path)}") from err
    names = set(channels)
    for layout in (("R", "G", "B", "A"), ("R", "G", "B"), ("Y", "A"), ("Y",)):
        if names == set(layout):
            break
    else:
        if len(names) != 1:
            raise ValueError(f"{path}: expected EXR channels Y, YA, RGB or RGBA, got {sorted(names)}")
        layout = tuple(names)
    planes = [channels[name] for name in layout]
    shape = planes[0].shape
    if any(p.ndim != 2 or p.shape != shape for p in planes):
        raise ValueError(f"{path}: expected full-resolution channels of one size, "
                         f"got shapes {[p.shape for p in planes]} (subsampled channels are not supported)")
    depth = 16 if all(p.dtype == np.float16 for p in planes) else 32
    image = np.stack([p.astype(np.float32) for p in planes], axis=-1)
    return image, ImageInfo(path, "exr", depth, CHANNEL_NAMES[len(layout)])


def write_image(path: str | os.PathLike, image: np.ndarray, bit_depth: int | None = None, *,
                srgb: bool = False) -> None:
    """Write ``image`` atomically as PNG or EXR (format chosen by the suffix).

    Args:
        path: target ``.png`` or ``.exr`` file; its folder must exist.
        image: ``(H, W)`` or ``(H, W, C)`` floating-point array, ``C`` in 1 to 4
            (Y, YA, RGB, RGBA), finite. PNG values are clipped to [0, 1] and rounded to the
            nearest code; EXR values are written as they are.
        bit_depth: PNG: 8 (default) or 16; EXR: 32 (float, default) or 16 (half).
        srgb: PNG only: tag the file as sRGB (``sRGB``/``gAMA``/``cHRM`` chunks). Untagged
            by default, as data maps should be. Values are never transformed.

    Raises:
        ValueError: wrong suffix, shape, dtype, bit depth or non-finite values.
    """
    path = Path(path)
    fmt = _format_of(path)
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in CHANNEL_NAMES or 0 in image.shape:
        raise ValueError(f"{path}: expected an image of shape (H, W) or (H, W, C) with C in 1..4, "
                         f"got {image.shape}")
    if not np.issubdtype(image.dtype, np.floating):
        raise ValueError(f"{path}: expected a floating-point image, got {image.dtype}")
    if not np.isfinite(image).all():
        raise ValueError(f"{path}: expected finite values to write, got NaN or Inf")
    depths = _PNG_DTYPES if fmt == "png" else _EXR_DTYPES
    bit_depth = (8 if fmt == "png" else 32) if bit_depth is None else bit_depth
    if bit_depth not in depths:
        raise ValueError(f"{path}: expected bit_depth in {sorted(depths)} for {fmt.upper()}, got {bit_depth}")
    if fmt == "exr" and bit_depth == 16 and np.abs(image).max() > np.finfo(np.float16).max:
        raise ValueError(f"{path}: expected values within the half-float range (|x| <= 65504), "
                         f"got max |x| = {float(np.abs(image).max()):.6g}")
    with atomic_path(path) as tmp:
        if fmt == "png":
            _write_png(tmp, image, bit_depth, srgb)
        else:
            _write_exr(tmp, image, bit_depth)


def _write_png(path: Path, image: np.ndarray, bit_depth: int, srgb: bool) -> None:
    top = 2 ** bit_depth - 1
    codes = np.rint(np.clip(image.astype(np.float32), 0.0, 1.0) * np.float32(top)).astype(_PNG_DTYPES[bit_depth])
    bitmap = mi.Bitmap(np.ascontiguousarray(codes), pixel_format=_PIXEL_FORMATS[image.shape[2]])
    bitmap.set_srgb_gamma(srgb)  # only decides whether the sRGB chunks are written
    bitmap.write(str(path), mi.Bitmap.FileFormat.PNG)


def _write_exr(path: Path, image: np.ndarray, bit_depth: int) -> None:
    data = image.astype(_EXR_DTYPES[bit_depth])
    names = CHANNEL_NAMES[image.shape[2]]
    channels = {name: np.ascontiguousarray(data[:, :, i]) for i, name in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))


def select_channels(image: np.ndarray, channels: int, path: str | os.PathLike, *,
                    rgb_to_grey: bool = False) -> np.ndarray:
    """Return ``image`` ``(H, W, C)`` as ``(H, W, channels)``, ``channels`` 1 or 3.

    An alpha channel is dropped if fully opaque (>= 1 - 1e-6) and an error otherwise. With
    ``rgb_to_grey``, RGB is accepted where grey is expected and the 3 channels are averaged
    (exact for the grey RGB most tools write). Grey where RGB is expected is an error.

    Raises:
        ValueError: naming ``path``, e.g. "expected an RGB image (3 channels), got 1 channel".
    """
    if image.shape[2] in (2, 4):
        alpha = image[:, :, -1]
        if alpha.min() < 1.0 - 1e-6:
            raise ValueError(f"{path}: expected no alpha channel or an opaque one, "
                             f"got alpha values down to {float(alpha.min()):.4g}")
        image = image[:, :, :-1]
    got = image.shape[2]
    if got == channels:
        return image
    if channels == 1 and got == 3 and rgb_to_grey:
        return image.mean(axis=2, keepdims=True)
    want = "an RGB image (3 channels)" if channels == 3 else "a grey image (1 channel)"
    have = "a grey image (1 channel)" if got == 1 else f"{got} channels"
    raise ValueError(f"{path}: expected {want}, got {have}")
