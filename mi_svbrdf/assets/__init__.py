"""Bundled examples: flash photos, a calibrated capture and an ambient-lit wall, renders of held-out procedural materials.

Files (made from the code: see :mod:`mi_svbrdf.data.example_photos`, :mod:`mi_svbrdf.cli.example_capture` and
:mod:`mi_svbrdf.cli.example_wall`):

- ``example_flash.png``: one fronto-parallel flash photo, for the single-image net;
- ``example_view1.png`` .. ``example_view3.png``: three photos of another material, for the
  multi-image net (256 x 256, 8-bit sRGB PNG);
- ``example_capture/``: ``capture.json`` and its photos ``000.png`` .. (128 x 128, 8-bit sRGB),
  a calibrated capture for ``mi-svbrdf optimize --capture example``, and ``truth.json``: which
  held-out material it photographs (to score a fit against its maps).
- ``example_wall/``: ``photo.png``, one photo under ambient light (512 x 512, 8-bit sRGB) of a
  held-out surface of the large-scale benchmark's sequence (surface 7, a tiled wall of 2048²
  texels; the benchmark scores surfaces 0-3), and two exemplars cut from it, ``exemplar_1/`` and
  ``exemplar_2/`` (material folders of 64 px, the compact net's exemplar size), for
  ``mi-svbrdf large-scale example``; ``truth.json``: which surface it is (to score a result
  against its maps). Re-made by ``python -m mi_svbrdf.cli.example_wall``.

Find them through the package, from any working folder: the constants below are absolute paths inside the
installed package (a clone's ``mi_svbrdf/assets/...`` is relative to the clone's root and found only from there).

Examples:
    >>> from mi_svbrdf.assets import EXAMPLE_FLASH
    >>> EXAMPLE_FLASH.is_absolute() and EXAMPLE_FLASH.is_file()
    True
"""
from __future__ import annotations

from pathlib import Path

#: Folder of the bundled photos (absolute: found from any working folder).
ASSETS_DIR = Path(__file__).resolve().parent
#: The single flash photo.
EXAMPLE_FLASH = ASSETS_DIR / "example_flash.png"
#: The three multi-view photos.
EXAMPLE_VIEWS = tuple(ASSETS_DIR / f"example_view{i}.png" for i in (1, 2, 3))
#: Folder of the bundled calibrated capture.
EXAMPLE_CAPTURE_DIR = ASSETS_DIR / "example_capture"
#: The bundled capture file (``mi-svbrdf optimize --capture example``).
EXAMPLE_CAPTURE = EXAMPLE_CAPTURE_DIR / "capture.json"
#: The held-out material the bundled capture photographs (JSON: set settings and material index).
EXAMPLE_CAPTURE_TRUTH = EXAMPLE_CAPTURE_DIR / "truth.json"
#: Folder of the bundled large-scale example (``mi-svbrdf large-scale example``).
EXAMPLE_WALL_DIR = ASSETS_DIR / "example_wall"
#: The ambient-lit photo of the example wall.
EXAMPLE_WALL = EXAMPLE_WALL_DIR / "photo.png"
#: The example wall's exemplars (material folders).
EXAMPLE_WALL_EXEMPLARS = tuple(EXAMPLE_WALL_DIR / f"exemplar_{i}" for i in (1, 2))
#: The held-out surface the example wall photographs (JSON: settings and surface index).
EXAMPLE_WALL_TRUTH = EXAMPLE_WALL_DIR / "truth.json"
