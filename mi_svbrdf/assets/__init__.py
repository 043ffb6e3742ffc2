"""Bundled example photos (flash renders of held-out procedural materials); see :mod:`mi_svbrdf.data.example_photos`.

Files: ``example_flash.png`` (one fronto-parallel flash photo, for the single-image net) and
``example_view1.png`` .. ``example_view3.png`` (three photos of another material, for the
multi-image net), 256 x 256, 8-bit sRGB PNG.
"""
from __future__ import annotations

from pathlib import Path

#: Folder of the bundled photos.
ASSETS_DIR = Path(__file__).parent
#: The single flash photo.
EXAMPLE_FLASH = ASSETS_DIR / "example_flash.png"
#: The three multi-view photos.
EXAMPLE_VIEWS = tuple(ASSETS_DIR / f"example_view{i}.png" for i in (1, 2, 3))
