"""External SVBRDF sets on disk: thesis-format strip PNGs and folders of per-material map folders.

:class:`MaterialSet` is a ``torch.utils.data.Dataset`` of ``(name, maps)`` pairs over a root
folder holding any mix of

- **strips** ``*.png``: the thesis dataset's ``input(s) | normal | diffuse | roughness |
  specular`` images (read with :func:`mi_svbrdf.io.strip.read_strip`; inputs are ignored), and
- **material folders**: subfolders with ``normal``, ``diffuse``, ``roughness``, ``specular``
  ``.png``/``.exr`` (+ optional ``material.json``; read with
  :func:`mi_svbrdf.io.material_io.read_material`).

A root holding an ``index.json`` written by :func:`mi_svbrdf.data.bank.make_bank` is read through its
index (the files it lists, in its order; a listed file that is missing is reported). Otherwise the
root is scanned in sorted order; subfolders that are not material folders are scanned too
(``recursive``). Names starting with ``.`` (hidden files, the temporary files of interrupted
atomic writes) and files other than ``.png`` at the strip level are not materials and are passed
over.

**Bad entries are reported and skipped, never silently.** The scan checks every entry cheaply
from file headers: PNG signature, header chunk and the closing ``IEND`` chunk (a truncated file
lacks it), EXR magic number and header, strip layout (width a multiple >= 4 of the height, RGB),
all four maps present and of one size, and the size policy (below). Skipped entries are listed in
:attr:`MaterialSet.skipped` as ``(path, reason)`` and announced with one ``warnings.warn`` giving
the count and the names (and one ``logging`` line each). ``validate="full"`` also decodes every
entry at scan time (catches corrupt pixel data and NaN in EXR; costs a full read). An entry that
passes the scan but fails when read (``validate="header"``) is, with ``on_error="skip"``, reported
the same way and replaced by the next readable entry (the item count stays fixed, as a
``DataLoader`` needs); ``on_error="raise"`` raises a ``ValueError`` naming the file instead.

**Size.** ``size=None`` returns maps at their own resolution. Otherwise every item is
``(10, size, size)``: ``fit="crop"`` takes the centred ``size``-texel window (the thesis crops
its 288-px panels to 256; maps smaller than ``size`` are skipped), ``fit="resize"`` crops the
centred square and resamples it to ``size`` (area average down, bilinear up, normals
renormalised).

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.core import maps as M
    >>> from mi_svbrdf.io import strip
    >>> root = pathlib.Path(tempfile.mkdtemp())
    >>> strip.write_strip(root / "a.png", M.constant_maps(1, 8, 8, diffuse=0.5))
    >>> (root / "broken.png").write_bytes(b"not a png")
    9
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     s = MaterialSet(root, size=8)
    >>> len(s), s[0][0], tuple(s[0][1].shape), [p.name for p, _ in s.skipped], len(caught)
    (1, 'a.png', (10, 8, 8), ['broken.png'], 1)
"""
from __future__ import annotations

import json
import logging
import os
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import OpenEXR
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from mi_svbrdf.core.maps import MAP_NAMES, check_maps, normalize_normals
from mi_svbrdf.io import material_io
from mi_svbrdf.io.strip import MAP_PANELS, read_strip

logger = logging.getLogger(__name__)

#: Size policies.
FITS = ("crop", "resize")
#: Scan-time validation levels.
VALIDATIONS = ("header", "full")
#: What :meth:`MaterialSet.__getitem__` does when an entry fails to read.
ON_ERROR = ("skip", "raise")
#: Index file of a material bank (see :mod:`mi_svbrdf.data.bank`).
BANK_INDEX = "index.json"
#: ``format`` field of a bank index.
BANK_FORMAT = "mi_svbrdf material bank"
#: Names listed per skipped entry in the warning before "and N more".
WARN_NAMES = 10

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_PNG_RGB_TYPES = (2, 3, 6)  # RGB, palette, RGBA
_READ_ERRORS = (ValueError, OSError, RuntimeError)  # FileNotFoundError is an OSError


@dataclass(frozen=True)
class MaterialEntry:
    """One usable material of a :class:`MaterialSet`.

    Attributes:
        name: path relative to the root, ``/``-separated (a strip keeps its ``.png`` suffix).
        path: the strip file or the material folder.
        kind: ``"strip"`` or ``"folder"``.
        height: map height in texels (a strip's panel size), from the headers.
        width: map width in texels.
    """

    name: str
    path: Path
    kind: str
    height: int
    width: int


def png_size(path: Path, *, rgb: bool = False) -> tuple[int, int]:
    """``(height, width)`` of a PNG from its header, after checking it is complete.

    Args:
        path: a PNG file.
        rgb: also require a colour PNG (RGB, RGBA or palette).

    Raises:
        ValueError: naming the file: not a PNG, a damaged header, no ``IEND`` at the end
            (truncated), or grey when ``rgb``.
    """
    with open(path, "rb") as f:
        head = f.read(26)
        f.seek(0, os.SEEK_END)
        length = f.tell()
        f.seek(max(0, length - len(_PNG_IEND)))
        tail = f.read()
    if head[:8] != _PNG_SIGNATURE:
        raise ValueError(f"{path}: expected a PNG file (PNG signature), got {head[:8]!r}")
    if len(head) < 26 or head[12:16] != b"IHDR":
        raise ValueError(f"{path}: expected a PNG header chunk (IHDR), got a damaged header")
    width, height = struct.unpack(">II", head[16:24])
    depth, colour = head[24], head[25]
    if tail != _PNG_IEND:
        raise ValueError(f"{path}: expected a complete PNG ending with an IEND chunk, "
                         f"got a truncated or damaged file ({length} bytes)")
    if width == 0 or height == 0 or depth not in (1, 2, 4, 8, 16):
        raise ValueError(f"{path}: expected a valid PNG header, got {width}x{height} at {depth} bits")
    if rgb and colour not in _PNG_RGB_TYPES:
        raise ValueError(f"{path}: expected an RGB PNG, got PNG colour type {colour} (grey)")
    return height, width


def exr_size(path: Path) -> tuple[int, int]:
    """``(height, width)`` of an EXR's data window from its header.

    Raises:
        ValueError: naming the file: not an OpenEXR file or an unreadable header.
    """
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != _EXR_MAGIC:
        raise ValueError(f"{path}: expected an OpenEXR file (magic number), got {magic!r}")
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            low, high = exr.header()["dataWindow"]
    except (RuntimeError, KeyError) as err:
        raise ValueError(f"{path}: expected a readable OpenEXR header, got {err}") from err
    return int(high[1] - low[1] + 1), int(high[0] - low[0] + 1)


def _image_size(path: Path) -> tuple[int, int]:
    return exr_size(path) if path.suffix.lower() == ".exr" else png_size(path)


def _is_material_folder(folder: Path) -> bool:
    """A folder holding ``material.json`` or any ``<map>.png`` / ``<map>.exr``."""
    if (folder / material_io.METADATA_NAME).is_file():
        return True
    return any((folder / f"{m}{ext}").is_file() for m in MAP_NAMES for ext in (".png", ".exr"))


def _fit(maps: torch.Tensor, size: int | None, fit: str) -> torch.Tensor:
    """``(1, 10, H, W)`` -> ``(1, 10, size, size)`` by the size policy (see the module doc)."""
    if size is None:
        return maps
    h, w = maps.shape[-2:]
    if fit == "crop":
        top, left = (h - size) // 2, (w - size) // 2
        return maps[..., top:top + size, left:left + size].contiguous()
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    maps = maps[..., top:top + side, left:left + side]
    if side != size:
        mode = "area" if side > size else "bilinear"
        maps = F.interpolate(maps, size=(size, size), mode=mode,
                             **({"align_corners": False} if mode == "bilinear" else {}))
    return normalize_normals(maps)


class MaterialSet(Dataset):
    """SVBRDFs from strips and material folders under ``root``; bad entries reported and skipped.

    Args:
        root: folder to read (see the module doc for what it may hold).
        size: side of every returned map in texels, or ``None`` for each entry's own size.
        fit: ``"crop"`` (centred window; smaller maps skipped) or ``"resize"``.
        recursive: also scan subfolders that are not material folders.
        validate: ``"header"`` (cheap checks) or ``"full"`` (also decode every entry).
        on_error: for an entry that fails on read: ``"skip"`` (warn, return the next readable
            entry) or ``"raise"``.

    Attributes:
        root: the root folder.
        items: the usable :class:`MaterialEntry` list, in order.
        skipped: ``(path, reason)`` of every entry reported and skipped.

    Items are ``(name, maps)``: ``name`` the entry's :attr:`MaterialEntry.name`, ``maps`` a
    ``(10, S, S)`` float32 tensor (unit normals, values in [0, 1]).
    """

    def __init__(self, root: str | os.PathLike, size: int | None = 256, *, fit: str = "crop",
                 recursive: bool = True, validate: str = "header", on_error: str = "skip") -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"root: expected a folder of strips or material folders, "
                                    f"got no such directory {self.root}")
        if size is not None and (not isinstance(size, int) or size < 1):
            raise ValueError(f"size: expected a positive int or None, got {size!r}")
        for arg, value, allowed in (("fit", fit, FITS), ("validate", validate, VALIDATIONS),
                                    ("on_error", on_error, ON_ERROR)):
            if value not in allowed:
                raise ValueError(f"{arg}: expected one of {allowed}, got {value!r}")
        self.size, self.fit, self.recursive, self.on_error = size, fit, recursive, on_error
        self.items: list[MaterialEntry] = []
        self.skipped: list[tuple[Path, str]] = []
        self._unreadable: set[int] = set()  # items that failed on read (on_error="skip")
        candidates = self._from_index() if (self.root / BANK_INDEX).is_file() else self._scan(self.root)
        for path, kind in candidates:
            try:
                entry = self._check(path, kind)
                if validate == "full":
                    self._load(entry)
            except _READ_ERRORS as err:
                self.skipped.append((path, _reason(err, path)))
                continue
            self.items.append(entry)
        if self.skipped:
            self._report(self.skipped, len(candidates))

    # ----------------------------------------------------------------------------------- scan
    def _from_index(self) -> list[tuple[Path, str]]:
        """Entries listed by a bank's ``index.json``."""
        index_path = self.root / BANK_INDEX
        try:
            index = json.loads(index_path.read_text(encoding="utf-8"))
            if index.get("format") != BANK_FORMAT:
                raise ValueError(f"format {index.get('format')!r}")
            files = [str(m["file"]) for m in index["materials"]]
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{index_path}: expected a bank index (format {BANK_FORMAT!r} with "
                             f"'materials' -> [{{'file': ...}}]), got {err}") from err
        out = []
        for file in files:
            path = self.root / file
            out.append((path, "folder" if path.is_dir() or not file.lower().endswith(".png") else "strip"))
        return out

    def _scan(self, folder: Path) -> list[tuple[Path, str]]:
        """``(path, kind)`` candidates under ``folder`` in sorted order."""
        out: list[tuple[Path, str]] = []
        for child in sorted(folder.iterdir(), key=lambda p: p.name):
            if child.name.startswith("."):
                continue
            if child.is_dir():
                if _is_material_folder(child):
                    out.append((child, "folder"))
                elif self.recursive:
                    out.extend(self._scan(child))
            elif child.suffix.lower() == ".png":
                out.append((child, "strip"))
        return out

    def _check(self, path: Path, kind: str) -> MaterialEntry:
        """Header-level checks of one candidate; raises with the reason."""
        if kind == "strip":
            if not path.is_file():
                raise FileNotFoundError(f"{path}: expected a strip PNG listed in {BANK_INDEX}, got no such file")
            height, width = png_size(path, rgb=True)
            if width % height != 0 or width // height < len(MAP_PANELS):
                raise ValueError(f"{path}: expected a strip of square panels, width a multiple >= 4 "
                                 f"of the height (inputs | normal | diffuse | roughness | specular), "
                                 f"got {width}x{height} (W x H)")
            width = height
        else:
            if not path.is_dir():
                raise FileNotFoundError(f"{path}: expected a material folder listed in {BANK_INDEX}, "
                                        f"got no such directory")
            sizes = {name: _image_size(file) for name, (file, _) in material_io._map_files(path).items()}
            (height, width), first = next(iter(sizes.values())), next(iter(sizes))
            for name, hw in sizes.items():
                if hw != (height, width):
                    raise ValueError(f"{path}: expected all maps of one size, got {first} "
                                     f"{height}x{width} and {name} {hw[0]}x{hw[1]} (H x W)")
        if self.size is not None and self.fit == "crop" and min(height, width) < self.size:
            raise ValueError(f"{path}: expected maps of at least {self.size}x{self.size} texels to crop "
                             f"(size={self.size}, fit='crop'), got {height}x{width}")
        name = path.relative_to(self.root).as_posix()
        return MaterialEntry(name, path, kind, height, width)

    def _report(self, bad: list[tuple[Path, str]], total: int) -> None:
        for path, reason in bad:
            logger.warning("MaterialSet %s: skipped %s: %s", self.root, path, reason)
        names = ", ".join(str(p.relative_to(self.root)) if p.is_relative_to(self.root) else str(p)
                          for p, _ in bad[:WARN_NAMES])
        more = f" and {len(bad) - WARN_NAMES} more" if len(bad) > WARN_NAMES else ""
        warnings.warn(f"MaterialSet {self.root}: skipped {len(bad)} of {total} entries "
                      f"(see .skipped for the reasons): {names}{more}", stacklevel=3)

    # ----------------------------------------------------------------------------------- read
    def _load(self, entry: MaterialEntry) -> torch.Tensor:
        """Read one entry as ``(10, S, S)``; raises ``ValueError`` / ``OSError`` naming the file."""
        if entry.kind == "strip":
            crop = self.size if (self.size is not None and self.fit == "crop") else None
            maps = read_strip(entry.path, crop=crop)[1]
        else:
            maps = material_io.read_material(entry.path)
        check_maps(maps, str(entry.path))
        return _fit(maps, self.size, self.fit)[0]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> tuple[str, torch.Tensor]:
        """``(name, maps)`` of entry ``index``, maps ``(10, S, S)`` float32."""
        count = len(self.items)
        if not -count <= index < count:
            raise IndexError(f"index: expected -{count} <= index < {count}, got {index}")
        index %= count
        for step in range(count):
            i = (index + step) % count
            if i in self._unreadable:
                continue
            entry = self.items[i]
            try:
                return entry.name, self._load(entry)
            except _READ_ERRORS as err:
                if self.on_error == "raise":
                    raise ValueError(_reason(err, entry.path)) from err
                self._unreadable.add(i)
                self.skipped.append((entry.path, _reason(err, entry.path)))
                self._report(self.skipped[-1:], count)
        raise ValueError(f"{self.root}: expected at least one readable material, got none of {count}")

    def __repr__(self) -> str:
        return (f"MaterialSet({str(self.root)!r}, size={self.size}, fit={self.fit!r}: "
                f"{len(self.items)} materials, {len(self.skipped)} skipped)")


def _reason(err: BaseException, path: Path) -> str:
    """The error message, prefixed with the path unless it already names it."""
    text = str(err)
    return text if str(path) in text else f"{path}: {text}"
