"""The bundled example photos, re-made from the code: ``python -m mi_svbrdf.cli.example_photos [--out DIR]``.

Each photo is a render of a *held-out* procedural material (:class:`mi_svbrdf.data.heldout.HeldOutSet`:
a class's held-out parameter slice, the benchmark's seed, never seen in training) through the
capture simulator, so the files are a pure function of the code:

- ``example_flash.png``: held-out material :data:`FLASH_MATERIAL` under the ``single_flash``
  preset (fronto-parallel camera, flash beside the lens, the authors' photo pipeline).
- ``example_view{1,2,3}.png``: held-out material :data:`MULTI_MATERIAL` under the
  ``multiview`` preset (first a fronto-parallel flash photo, then two from the hemisphere).

The simulator's photos are linear (decoded from its 8-bit gamma-2.2 pipeline); they are written
sRGB-encoded (colour-science) as 8-bit PNG, which is what a camera JPEG/PNG holds and what
``mi-svbrdf capture`` decodes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mi_svbrdf.assets import ASSETS_DIR
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode

#: Held-out material index of the single flash photo (class CLASS_ORDER[7] = tiles).
FLASH_MATERIAL = 7
#: Held-out material index of the multi-view photos (class CLASS_ORDER[13 % 9] = wood; set v2: index 4
#: photographs a wood that the v2 captures clip over half its pixels).
MULTI_MATERIAL = 13
#: Side of the photos.
SIZE = 256


def render_examples(size: int = SIZE, which: tuple[str, ...] = ("flash", "multi")) -> dict[str, torch.Tensor]:
    """``{file name: (3, size, size) linear photo}`` of the bundled examples (``which``: "flash", "multi")."""
    out = {}
    if "flash" in which:
        single = HeldOutSet(size=size, materials=1, n_images=1, preset="single_flash", cache=False)
        out["example_flash.png"] = single.material(FLASH_MATERIAL)["inputs"][0, 0]
    if "multi" in which:
        multi = HeldOutSet(size=size, materials=1, n_images=3, preset="multiview", cache=False)
        views = multi.material(MULTI_MATERIAL)["inputs"][0]
        out.update({f"example_view{i + 1}.png": views[i] for i in range(3)})
    return out


def encode(photo: torch.Tensor) -> np.ndarray:
    """``(3, H, W)`` linear photo -> ``(H, W, 3)`` sRGB-encoded float32 (what the PNG stores)."""
    return srgb_encode(photo.permute(1, 2, 0).numpy().astype(np.float32))


def write_examples(folder: Path = ASSETS_DIR, size: int = SIZE) -> list[Path]:
    """Render and write the example photos (8-bit sRGB PNG, atomic); returns the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, photo in render_examples(size).items():
        path = folder / name
        write_image(path, encode(photo), 8, srgb=True)
        paths.append(path)
    return paths
