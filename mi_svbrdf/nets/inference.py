"""``predict(images) -> maps``: the bundled networks on photos (the user-facing inference path).

``mi_svbrdf.predict`` is this module's :func:`predict`, exported lazily by the package (the
module is called ``inference`` so that the package attribute ``predict`` is the function, never
the module).

The **single-image net** expects one fronto-parallel flash photo: the camera looks straight at
the sample and the flash sits next to the lens (a phone's flash), the sample filling the frame.
The **multi-image net** takes any N >= 1 photos of the same sample (the first such a flash photo,
the others from other angles, each lit by its own flash). A *fused* multi-image net
(``NetConfig.fusion``, :mod:`mi_svbrdf.nets.fusion`) also runs the single-image net on the flash
photo and blends both nets' maps, so the order matters: the flash photo is put first
(``flash_photo``, else :func:`mi_svbrdf.core.highlight.choose_flash_photo`), and
:attr:`Prediction.path` records which photo, which net and why.

Which net: ``kind=None`` picks the single-image net for one photo and the multi-image net for
more. When the chosen weights are not bundled the other net is used if it can be (the multi net
on one photo; the single net on the *first* of several photos) and a warning says so.

Resolution: the photos are resized (antialiased) to the net's training resolution
(``config.resolution``, 256) and the maps come out at that size; ``full_resolution=True`` runs
the fully convolutional net on the photos as they are (quality degrades away from the training
size: see ``benchmarks/bench_capture_resolution.py``).

Symmetry ensemble: the net runs on the 8 flips and rotations of the photos and the maps, turned back, are
averaged (:mod:`mi_svbrdf.nets.ensemble`; ``symmetries=1``: the net alone, 8x faster). Measured on the
held-out and foreign sets (``benchmarks/bench_ensemble.py``, docs/history.md "Symmetry ensemble"), the re-rendering
error falls for both nets at every N, on both sets.

Device: ``device="cuda"`` (or ``"cuda:N"``) runs the net on that GPU; the photos are moved there and
the maps come back on it (default: the CPU). The network is pure PyTorch: no Mitsuba variant is
involved.

Examples:
    >>> import mi_svbrdf  # doctest: +SKIP
    >>> maps = mi_svbrdf.predict("photo.jpg")  # doctest: +SKIP
    >>> tuple(maps.shape)  # doctest: +SKIP
    (1, 10, 256, 256)
"""
from __future__ import annotations

import functools
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np
import torch

from mi_svbrdf.core.device import resolve_device
from mi_svbrdf.core.highlight import FlashChoice, choose_flash_photo
from mi_svbrdf.io.material_io import srgb_decode
from mi_svbrdf.io.photos import MIN_SIZE, Photo, check_consistent, load_photo, prepare, resize
from mi_svbrdf.nets import weights as bundled
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES, symmetry_ensemble
from mi_svbrdf.nets.network import KINDS, SVBRDFNet

#: The nets :func:`predict` runs on flash photos (the large-scale net takes an ambient photo and exemplars,
#: tile by tile: ``mi-svbrdf large-scale``).
PHOTO_KINDS = tuple(k for k in KINDS if k != "large")

#: What ``predict`` accepts: path(s), a tensor or numpy array ``(N, 3, H, W)`` / ``(B, N, 3, H, W)``,
#: or a list of ``(H, W, 3)`` arrays.
Images = Union[str, os.PathLike, Sequence[Union[str, os.PathLike]], torch.Tensor, np.ndarray,
               Sequence[np.ndarray]]


@dataclass
class Prediction:
    """Everything :func:`predict_details` did.

    Attributes:
        maps: ``(B, 10, R, R)`` canonical maps.
        photos: ``(B, N, 3, R, R)`` the linear photos the net saw (after crop and resize).
        kind: the net used, ``"single"`` or ``"multi"``.
        notes: what was decided for the user (fallbacks, photos ignored).
        inputs: per file: path, original size, conversions (empty for tensors).
        network: the manifest entry of the weights (file, sha256, config, steps ...).
        seconds: ``{"load": ..., "network": ...}`` wall time.
        symmetries: the symmetry ensemble's size (1: the net alone).
        path: which path made the maps and why (``summary.json``'s ``path``): ``net`` (``"single"``, ``"multi"``,
            ``"fused"``), ``why``, and ``flash_photo`` (:meth:`mi_svbrdf.core.highlight.FlashChoice.summary`:
            the photo taken as the fronto-parallel flash photo, 0-based in the order given, and why).
        distribution: the BRDF model of ``maps``, the net's output model (``"ggx"`` or ``"beckmann"``,
            :func:`mi_svbrdf.nets.weights.entry_distribution`): a material folder written from them
            records it.
    """

    maps: torch.Tensor
    photos: torch.Tensor
    kind: str
    notes: list[str] = field(default_factory=list)
    inputs: list[dict[str, Any]] = field(default_factory=list)
    network: dict[str, Any] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    distribution: str = bundled.DEFAULT_DISTRIBUTION
    symmetries: int = 1
    path: dict[str, Any] = field(default_factory=dict)


def weights_folder(weights_dir: str | os.PathLike | None) -> Path:
    return bundled.WEIGHTS_DIR if weights_dir is None else Path(weights_dir).expanduser().resolve()


@functools.lru_cache(maxsize=4)
def _cached_network(kind: str, folder: str, sha256: str, device: str = "cpu") -> SVBRDFNet:
    """The loaded net on ``device``, cached per (kind, folder, checksum, device): replaced weights are reloaded."""
    return bundled.load_network(kind, folder=Path(folder)).to(torch.device(device))


def load(kind: str, weights_dir: str | os.PathLike | None = None,
         device: str | torch.device | None = None) -> tuple[SVBRDFNet, dict[str, Any]]:
    """The ``kind`` net of ``weights_dir`` (default: the bundled weights) on ``device`` (default: cpu),
    cached; and its manifest entry."""
    folder = weights_folder(weights_dir)
    entry = bundled.manifest_entry(kind, folder)
    return _cached_network(kind, str(folder), entry["sha256"], str(resolve_device(device))), entry


def choose_kind(n_photos: int, kind: str | None, available: Sequence[str]) -> tuple[str, list[str]]:
    """The net to run on ``n_photos`` photos and the notes explaining a fallback.

    Raises:
        ValueError: a bad ``kind``, ``kind="single"`` with several photos, or no weights at all.
    """
    if kind is not None and kind not in PHOTO_KINDS:
        hint = " (the large-scale net takes an ambient photo and exemplars: mi-svbrdf large-scale)" * (kind == "large")
        raise ValueError(f"kind: expected None or one of {PHOTO_KINDS}, got {kind!r}{hint}")
    available = [k for k in available if k in PHOTO_KINDS]
    if kind == "single" and n_photos != 1:
        raise ValueError(f"kind: expected 1 photo for the single-image net, got {n_photos} "
                         "(use kind='multi' or None)")
    if not available:
        raise ValueError("weights: expected bundled network weights (mi_svbrdf/weights/manifest.json), got none")
    if kind is not None:
        return kind, []
    want = "single" if n_photos == 1 else "multi"
    if want in available:
        return want, []
    other = "multi" if want == "single" else "single"
    if want == "single":
        return other, ["no single-image weights: ran the multi-image net on the one photo"]
    return other, [f"no multi-image weights: ran the single-image net on the first photo only "
                   f"(the other {n_photos - 1} ignored)"]


def _as_batch(images: torch.Tensor | np.ndarray, name: str = "images", linear: bool = True) -> torch.Tensor:
    """A tensor/array ``(3, H, W)``, ``(N, 3, H, W)`` or ``(B, N, 3, H, W)`` -> float32 ``(B, N, 3, H, W)``.

    Float values are linear; uint8 ones are divided by 255 and sRGB-decoded unless ``linear``.
    """
    # a tensor stays on its device; arrays become CPU tensors (not the default device's)
    t = images if isinstance(images, torch.Tensor) else torch.as_tensor(np.asarray(images), device="cpu")
    if t.dtype == torch.uint8:
        t = t.float() / 255.0
        if not linear:
            t = torch.from_numpy(srgb_decode(t.numpy()))
    t = t.float()
    if t.dim() == 3:
        t = t[None]
    if t.dim() == 4:
        t = t[None]
    if t.dim() != 5 or t.shape[2] != 3:
        raise ValueError(f"{name}: expected a tensor (N, 3, H, W) or (B, N, 3, H, W), got shape {tuple(t.shape)}")
    if min(t.shape[-2:]) < MIN_SIZE:
        raise ValueError(f"{name}: expected photos of at least {MIN_SIZE} px, got {tuple(t.shape[-2:])}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name}: expected finite values, got NaN or Inf")
    h, w = t.shape[-2:]
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    return t[..., top:top + s, left:left + s].clamp_min(0.0)


def _from_arrays(arrays: Sequence[np.ndarray], linear: bool) -> torch.Tensor:
    """A list of ``(H, W, 3)`` arrays (uint8 sRGB unless ``linear``, or float linear) -> ``(1, N, 3, H, W)``."""
    out = []
    for i, a in enumerate(arrays):
        a = np.asarray(a)
        if a.ndim != 3 or a.shape[2] != 3:
            raise ValueError(f"images[{i}]: expected an (H, W, 3) array, got shape {a.shape}")
        if a.dtype == np.uint8:
            a = a.astype(np.float32) / 255.0
            if not linear:
                a = srgb_decode(a)
        elif not np.issubdtype(a.dtype, np.floating):
            raise ValueError(f"images[{i}]: expected a uint8 or float array, got dtype {a.dtype}")
        out.append(torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).permute(2, 0, 1))
    if len({tuple(t.shape) for t in out}) != 1:
        raise ValueError(f"images: expected arrays of one size, got {[tuple(t.shape[1:]) for t in out]}")
    return _as_batch(torch.stack(out))


def load_inputs(images: Images, *, linear: bool = False, crop: tuple[int, int, int, int] | None = None,
                size: int | None = None) -> tuple[torch.Tensor, list[Photo]]:
    """Photos ``(B, N, 3, S, S)`` linear, and the loaded files.

    Paths go through :func:`mi_svbrdf.io.photos.load_photo`; tensors and float arrays are linear
    ``(N, 3, H, W)`` / ``(B, N, 3, H, W)`` (uint8 ones, and lists of uint8 ``(H, W, 3)`` arrays,
    are /255 and sRGB-decoded unless ``linear``), centre-cropped to a square. Squares are
    resized to ``size`` (None: kept at their own size, which must then be common: full resolution).
    """
    if isinstance(images, (str, os.PathLike)):
        images = [images]
    if isinstance(images, (torch.Tensor, np.ndarray)):
        batch = _as_batch(images, linear=linear)
        return (batch if size is None else resize(batch, size)), []
    items = list(images)
    if not items:
        raise ValueError("images: expected at least one photo, got none")
    if all(isinstance(i, np.ndarray) for i in items):
        batch = _from_arrays(items, linear)
        return (batch if size is None else resize(batch, size)), []
    if not all(isinstance(i, (str, os.PathLike)) for i in items):
        raise ValueError(f"images: expected paths, a tensor or arrays, got {[type(i).__name__ for i in items]}")
    photos = [load_photo(p, linear=linear, crop=crop) for p in items]
    check_consistent(photos, crop=crop is not None, full_resolution=size is None)
    return prepare(photos, size), photos


def count_photos(images: Images) -> int:
    """N, the number of photos in ``images`` (without loading files)."""
    if isinstance(images, (str, os.PathLike)):
        return 1
    if isinstance(images, (torch.Tensor, np.ndarray)):
        return int(_as_batch(images).shape[1])
    return len(list(images))


def flash_photo_choice(photos: torch.Tensor, flash_photo: int | None, names: list[str] | None = None) -> FlashChoice:
    """The fronto-parallel flash photo of ``photos (B, N, 3, H, W)``: ``flash_photo`` (0-based) when given,
    else :func:`mi_svbrdf.core.highlight.choose_flash_photo` on the first sample's photos.

    Raises:
        ValueError: ``flash_photo`` outside ``[0, N)``.
    """
    n = int(photos.shape[1])
    if flash_photo is None:
        return choose_flash_photo(photos[0], names)
    if not isinstance(flash_photo, int) or not 0 <= flash_photo < n:
        raise ValueError(f"flash_photo: expected None or a photo index in [0, {n}), got {flash_photo!r}")
    name = (names or [f"photo {i + 1}" for i in range(n)])[flash_photo]
    return FlashChoice(index=flash_photo, positions=(), assumed=False,
                       why=f"{name} is the fronto-parallel flash photo, as asked")


def path_reason(kind: str, config: Any, n_photos: int, notes: list[str]) -> str:
    """One sentence: why the maps come from the net of ``kind`` (``config`` its :class:`NetConfig`) on ``n_photos``."""
    if notes:
        return notes[0]
    if kind == "single":
        return "one photo: the single-image net"
    if getattr(config, "fusion", False):
        return (f"{n_photos} photos: the fused multi-image net, the single-image net on the flash photo and the "
                f"multi-image net on all {n_photos} blended per texel by its fusion head (mi_svbrdf.nets.fusion)")
    return f"{n_photos} photo(s): the multi-image net"


def predict_details(images: Images, *, kind: str | None = None, linear: bool = False,
                    full_resolution: bool = False, weights_dir: str | os.PathLike | None = None,
                    crop: tuple[int, int, int, int] | None = None,
                    device: str | torch.device | None = None, symmetries: int = DEFAULT_SYMMETRIES,
                    flash_photo: int | None = None) -> Prediction:
    """:func:`predict` with everything it decided (net, path, notes, inputs, timing); see :func:`predict`.

    ``maps`` and ``photos`` of the result are on ``device``.
    """
    t0 = time.perf_counter()
    device = resolve_device(device)
    n = count_photos(images)
    if n == 0:
        raise ValueError("images: expected at least one photo, got none")
    folder = weights_folder(weights_dir)
    chosen, notes = choose_kind(n, kind, bundled.available(folder))
    resolution = int(bundled.manifest_entry(chosen, folder)["net_config"]["resolution"])
    photos, loaded = load_inputs(images, linear=linear, crop=crop, size=None if full_resolution else resolution)
    net, entry = load(chosen, weights_dir, device)
    names = [Path(p.path).name for p in loaded] or None
    flash = flash_photo_choice(photos, flash_photo, names)
    if flash.index:  # the flash photo goes first: the single-image net (or branch) reads photo 0
        order = [flash.index, *(i for i in range(photos.shape[1]) if i != flash.index)]
        photos, loaded = photos[:, order], [loaded[i] for i in order] if loaded else loaded
    if chosen == "single" and photos.shape[1] > 1:
        photos = photos[:, :1]
    path = {"net": "fused" if getattr(net.config, "fusion", False) else chosen,
            "why": path_reason(chosen, net.config, photos.shape[1], notes), "flash_photo": flash.summary()}
    photos = photos.to(device)
    t1 = time.perf_counter()
    with torch.inference_mode():
        maps = symmetry_ensemble(net, photos, symmetries)
    if device.type == "cuda":  # untested here (no GPU): time the kernels, not their launch
        torch.cuda.synchronize(device)
    t2 = time.perf_counter()
    for note in notes:
        warnings.warn(note, stacklevel=3)
    return Prediction(maps=maps.clone(), photos=photos, kind=chosen, notes=notes,
                      inputs=[p.summary() for p in loaded], network={"kind": chosen, **entry},
                      seconds={"load": round(t1 - t0, 4), "network": round(t2 - t1, 4)},
                      distribution=bundled.entry_distribution(entry), symmetries=symmetries, path=path)


def predict(images: Images, *, kind: str | None = None, linear: bool = False, full_resolution: bool = False,
            weights_dir: str | os.PathLike | None = None,
            crop: tuple[int, int, int, int] | None = None,
            device: str | torch.device | None = None, symmetries: int = DEFAULT_SYMMETRIES,
            flash_photo: int | None = None) -> torch.Tensor:
    """Recover SVBRDF maps from flash photo(s) with the bundled networks.

    Args:
        images: a path, a list of paths (JPEG, PNG 8/16-bit, TIFF, EXR ...; see
            :mod:`mi_svbrdf.io.photos` for the conversions), a linear tensor/float array
            ``(N, 3, H, W)`` or ``(B, N, 3, H, W)`` in [0, 1], or a list of ``(H, W, 3)`` arrays
            (uint8: sRGB; float: linear). Every photo is centre-cropped to a square.
        kind: ``"single"``, ``"multi"`` or None (single for one photo, multi for more).
        linear: files / uint8 arrays hold linear values (skip the sRGB decoding).
        full_resolution: run at the photos' own size instead of the net's training resolution.
        weights_dir: a folder with ``manifest.json`` and weights (default: the bundled ones).
        crop: ``(x, y, w, h)`` region of each (upright) photo file, before the centre square.
        device: ``"cpu"`` (None), ``"cuda"`` or ``"cuda:N"``: where the net runs and the maps are returned
            (:func:`mi_svbrdf.core.device.resolve_device`).
        symmetries: run the net on this many of the 8 flips and rotations of the photos and average the
            maps (:func:`mi_svbrdf.nets.ensemble.symmetry_ensemble`; 1: the net alone).
        flash_photo: which photo (0-based) is the fronto-parallel flash photo, put first (the single-image
            net reads it); None: the first, unless its light peaks outside the frame and another's inside
            (:func:`mi_svbrdf.core.highlight.choose_flash_photo`).

    Returns:
        ``(B, 10, R, R)`` maps on ``device`` (B = 1 for files), ``R`` the training resolution (or the
        photos' square size with ``full_resolution``).

    Raises:
        ValueError / FileNotFoundError: naming the bad file or argument (or device).
    """
    return predict_details(images, kind=kind, linear=linear, full_resolution=full_resolution,
                           weights_dir=weights_dir, crop=crop, device=device, symmetries=symmetries,
                           flash_photo=flash_photo).maps
