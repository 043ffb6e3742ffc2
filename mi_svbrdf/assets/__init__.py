"""Bundled examples: flash photos and a calibrated capture, renders of held-out procedural materials.

Files (made from the code: see :mod:`mi_svbrdf.data.example_photos` and :mod:`mi_svbrdf.cli.example_capture`):

- ``example_flash.png``: one fronto-parallel flash photo, for the single-image net;
- ``example_view1.png`` .. ``example_view3.png``: three photos of another material, for the
  multi-image net (256 x 256, 8-bit sRGB PNG);
- ``example_capture/``: ``capture.json`` and its photos ``000.png`` .. (128 x 128, 8-bit sRGB),
  a calibrated capture for ``mi-svbrdf optimize --capture example``, and ``truth.json``: which
  held-out material it photographs (to score a fit against its maps).
"""
from __future__ import annotations

from pathlib import Path

#: Folder of the bundled photos.
ASSETS_DIR = Path(__file__).parent
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
