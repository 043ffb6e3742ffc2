"""The synthetic phone photos of ``mi-svbrdf rectify example`` and ``scan example``: rendered once, then cached.

Two sets of Mitsuba photos of the same procedural leather (:data:`MATERIAL`), taken as a phone takes
them (:data:`PHOTO_SIZE`: 4032 x 3024, landscape; 8-bit sRGB JPEG at :data:`JPEG_QUALITY`):

* ``"tags"`` (``--frame tags``): :data:`TAG_PHOTOS` photos of the sample under the AprilTag print
  (:func:`mi_svbrdf.data.tag_photos.render_tag_photo`; ring :data:`TAG_SHEET_MM` mm, FOV :data:`TAG_FOV`
  across the long side), the tags filling the frame, tilted 15-35 degrees (:func:`tag_cameras`); no EXIF:
  the camera is calibrated from the tags.
* ``"frame"`` (the paper frame): :data:`FRAME_PHOTOS` photos of the sample in the A4 paper frame
  (:func:`mi_svbrdf.data.frame_photos.render_frame_photo`), the sheet's long side along the photo's, tilted
  up to 30 degrees (:func:`frame_poses`), with the EXIF 35 mm-equivalent focal length ``rectify`` reads (a
  property of the FOV and the aspect ratio, not of the pixel count).

The sample spans 1250-1550 pixels along its shortest side in every photo, so a rectification to
1024 x 1024 holds real detail; the material is generated at :data:`MATERIAL_TEXELS` texels across the
sample (its pebbled grain: about 30 texels a cell), so the photos are no upsampled blur.

Cache: a set is rendered once into ``$MI_SVBRDF_CACHE/scan_examples/KIND-KEY/`` (or
``~/.cache/mi_svbrdf/...``: :func:`~mi_svbrdf.data.cached_set.default_cache_dir`), ``KEY`` a hash of
:data:`VERSION` and every setting (:func:`settings`), each photo written atomically (an interrupted
render keeps the photos it finished), and copied from there into the output folder. Bump
:data:`VERSION` whenever the photos' code changes.

Examples:
    >>> settings("tags")["photo_size"], settings("tags")["material_texels"], settings("tags")["spp"]
    ([4032, 3024], 2048, 4)
    >>> settings("frame", (640, 480))["material_texels"], settings("frame", (640, 480))["spp"]
    (384, 32)
"""
from __future__ import annotations

import math
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mi_svbrdf.io.atomic import atomic_path

if TYPE_CHECKING:
    import torch

#: The version of the photos' code: part of the cache key (bump it when the photos change).
VERSION = 1
#: A 12 MP phone photo ``(W, H)``, landscape: the size the settings below are for (smaller photos scale them).
PHONE_SIZE = (4032, 3024)
#: The photos' size ``(W, H)`` (the tests set a smaller one).
PHOTO_SIZE = PHONE_SIZE
#: JPEG quality, as a phone writes its photos.
JPEG_QUALITY = 92
#: The material: procedural class, seed, parameters (a 2 mm pebbled grain on a 15 cm sample).
MATERIAL: tuple[str, int, dict[str, float]] = ("leather", 2, {"grain": 70.0})
#: Texels of the material across the sample at :data:`PHONE_SIZE` (at least the photos' pixels across it).
MATERIAL_TEXELS = 2048
#: Samples per pixel at :data:`PHONE_SIZE` (smaller photos: as many per unit of the sample's area, up to
#: :data:`MAX_SPP`).
SPP, MAX_SPP = 4, 32
#: Tag-print texture pixels per tag cell at :data:`PHONE_SIZE` (about one per photo pixel at the nearest tags).
TAG_CELL_PX = 32
#: ``--frame tags``: photos, FOV across the long side (degrees), the ring's size S (mm).
TAG_PHOTOS, TAG_FOV, TAG_SHEET_MM = 5, 60.0, 180.0
#: The paper frame: photos.
FRAME_PHOTOS = 3
#: The kinds of photo sets.
KINDS = ("tags", "frame")
#: The seeds of the cameras' draws (chosen among the first dozen for a sample of at least 1250 px in each photo).
_TAG_SEED, _FRAME_SEED = 2, 8


def _size(size: tuple[int, int] | None) -> tuple[int, int]:
    w, h = PHOTO_SIZE if size is None else size
    return int(w), int(h)


def _scaled(value: float, size: tuple[int, int], floor: int, multiple: int = 1) -> int:
    """``value`` (at :data:`PHONE_SIZE`) scaled with the photo's width, up to a ``multiple``, at least ``floor``."""
    scaled = value * size[0] / PHONE_SIZE[0]
    return max(int(floor), math.ceil(scaled / multiple - 1e-9) * multiple)


def tag_cameras(count: int = TAG_PHOTOS, size: tuple[int, int] | None = None) -> list:
    """The true cameras (:class:`~mi_svbrdf.data.tag_photos.TrueCamera`) of the ``"tags"`` photos at ``size``
    (default :data:`PHOTO_SIZE`; another size: the same cameras, the focal length in pixels scaled)."""
    from mi_svbrdf.data.tag_photos import sample_camera
    from mi_svbrdf.geometry.poses import focal_px_of_fov
    from mi_svbrdf.geometry.tags import RING_UNITS

    w, h = _size(size)
    rng = np.random.default_rng(_TAG_SEED)
    return [sample_camera(rng, focal=focal_px_of_fov(TAG_FOV, w, h), size=(w, h), tilt_deg=(15.0, 35.0),
                          margin=0.03, extra_distance=(1.0, 1.05), roll_deg=10.0,
                          framed_units=RING_UNITS / 2.0 + 1.0) for _ in range(count)]


def frame_poses(count: int = FRAME_PHOTOS, size: tuple[int, int] | None = None) -> list:
    """The cameras (:class:`~mi_svbrdf.data.frame_photos.FramePose`) of the ``"frame"`` photos at ``size``."""
    from mi_svbrdf.data.frame_photos import sample_pose

    w, h = _size(size)
    rng = np.random.default_rng(_FRAME_SEED)
    return [sample_pose(rng, width=w, height=h, integer_focal_35mm=True, max_tilt_deg=30.0, margin=0.03,
                        extra_distance=(1.0, 1.05), roll_deg=(75.0, 105.0)) for _ in range(count)]


def settings(kind: str, size: tuple[int, int] | None = None) -> dict[str, Any]:
    """Every setting of a photo set at ``size`` (the cache key's content, with :data:`VERSION`).

    Raises:
        ValueError: an unknown ``kind``.
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    size = _size(size)
    cls, seed, params = MATERIAL
    spp = min(MAX_SPP, max(SPP, round(SPP * (PHONE_SIZE[0] / size[0]) ** 2)))
    common = {"version": VERSION, "kind": kind, "photo_size": list(size), "jpeg_quality": JPEG_QUALITY,
              "material": [cls, seed, params], "material_texels": _scaled(MATERIAL_TEXELS, size, 128, 64),
              "spp": spp}
    if kind == "tags":
        return {**common, "photos": TAG_PHOTOS, "fov": TAG_FOV, "seed": _TAG_SEED,
                "cell_px": _scaled(TAG_CELL_PX, size, 8)}
    return {**common, "photos": FRAME_PHOTOS, "seed": _FRAME_SEED}


def cache_folder(kind: str, size: tuple[int, int] | None = None) -> Path:
    """The cache folder of a photo set: ``default_cache_dir("scan_examples") / KIND-KEY``."""
    from mi_svbrdf.data.cached_set import default_cache_dir, settings_key

    return default_cache_dir("scan_examples") / f"{kind}-{settings_key(settings(kind, size))}"


def photo_names(kind: str) -> list[str]:
    """The photos' file names: ``IMG_0000.jpg``, ..."""
    count = TAG_PHOTOS if kind == "tags" else FRAME_PHOTOS
    return [f"IMG_{k:04d}.jpg" for k in range(count)]


def material(size: tuple[int, int] | None = None) -> torch.Tensor:
    """``(1, 10, N, N)`` maps of :data:`MATERIAL` at the texels of the photos at ``size`` (:func:`settings`)."""
    import torch

    from mi_svbrdf.data import procedural

    cls, seed, params = MATERIAL
    with torch.no_grad():
        return procedural.generate(cls, seed, settings("tags", size)["material_texels"], **params)[None]


def render_photo(kind: str, index: int, path: str | os.PathLike, maps: torch.Tensor,
                 size: tuple[int, int] | None = None) -> Path:
    """Render photo ``index`` of the set ``kind`` at ``size`` of the material ``maps`` (:func:`material`) into
    ``path`` (JPEG at :data:`JPEG_QUALITY`; the paper frame's with its EXIF focal length), atomically."""
    from mi_svbrdf.data.frame_photos import render_frame_photo, save_photo
    from mi_svbrdf.data.tag_photos import render_tag_photo
    from mi_svbrdf.geometry.poses import focal_35mm_of

    s = settings(kind, size)
    w, h = s["photo_size"]
    if kind == "tags":
        camera = tag_cameras(index + 1, (w, h))[index]
        save_photo(path, render_tag_photo(maps, camera, spp=s["spp"], seed=index, cells_px=s["cell_px"]),
                   quality=JPEG_QUALITY)
    else:
        pose = frame_poses(index + 1, (w, h))[index]
        photo = render_frame_photo(maps, pose, seed=index, spp=s["spp"])
        save_photo(path, photo.image, focal_35mm=focal_35mm_of(pose.fov_deg, w, h), quality=JPEG_QUALITY)
    return Path(path)


def render_set(kind: str, folder: str | os.PathLike, size: tuple[int, int] | None = None) -> list[Path]:
    """Render the photos of ``kind`` at ``size`` into ``folder`` (no cache); those already there are kept (the
    renders are deterministic: an interrupted set is finished). Returns the photos' paths."""
    settings(kind, size)  # an unknown kind: a ValueError before any work
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / name for name in photo_names(kind)]
    missing = [k for k, p in enumerate(paths) if not p.is_file()]
    if missing:
        from mi_svbrdf.core.device import release_memory

        maps = material(size)
        for k in missing:
            render_photo(kind, k, paths[k], maps, size)
        del maps
        release_memory()
    return paths


def example_photos(kind: str, folder: str | os.PathLike, size: tuple[int, int] | None = None, *,
                   cache: bool = True) -> list[Path]:
    """The photos of ``kind`` (``"tags"`` or ``"frame"``) at ``size`` (default :data:`PHOTO_SIZE`) in ``folder``
    as ``IMG_NNNN.jpg``: copied from the cache (:func:`cache_folder`; rendered into it first when missing), or
    rendered straight into ``folder`` with ``cache=False`` or a cache that cannot be written. Returns their
    paths."""
    folder = Path(folder)
    cached = None
    if cache:
        try:
            cached = render_set(kind, cache_folder(kind, size), size)
        except OSError:  # a cache that cannot be written: the photos go straight to the folder
            cached = None
    if cached is None:
        return render_set(kind, folder, size)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for path in cached:
        target = folder / path.name
        with atomic_path(target) as tmp:
            shutil.copyfile(path, tmp)
        paths.append(target)
    return paths
