"""Figures: matplotlib without a display, PNGs written atomically, and labelled contact sheets (one home for each).

matplotlib is imported on first use (it costs ~0.5 s), with the non-interactive ``Agg`` backend,
so plotting works on a machine without a display and never opens a window.

Examples:
    >>> import tempfile, pathlib
    >>> plt = pyplot()
    >>> fig, ax = plt.subplots()
    >>> _ = ax.plot([0, 1], [1, 0])
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "line.png"
    >>> save_figure(fig, path)
    >>> path.read_bytes()[:4] == b"\\x89PNG"
    True
    >>> import numpy as np
    >>> labelled_row([("a", np.zeros((8, 8, 3), np.uint8)), ("b", np.zeros((8, 4, 3), np.uint8))]).shape
    (26, 12, 3)
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from mi_svbrdf.io.atomic import atomic_path


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the ``Agg`` backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | os.PathLike, dpi: int = 90) -> None:
    """Write ``fig`` as a PNG to ``path`` atomically (a temporary name, then a rename) and close it."""
    with atomic_path(path, fsync=False) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    pyplot().close(fig)


#: Height in pixels of the label band above each panel of :func:`labelled_row`.
LABEL_PX = 18


def labelled_row(panels: Sequence[tuple[str, np.ndarray]], *, label_px: int = LABEL_PX) -> np.ndarray:
    """Panels side by side on white, each with its name in black in a band above it (a contact sheet's row).

    Args:
        panels: ``(name, image)`` pairs, images ``(H, W_i, 3)`` uint8 of one height ``H``.
        label_px: height of the label band.

    Returns:
        ``(H + label_px, sum W_i, 3)`` uint8.

    Raises:
        ValueError: no panel, a panel that is not ``(H, W, 3)`` uint8, or panels of different heights.
    """
    from PIL import Image, ImageDraw

    if not panels:
        raise ValueError("panels: expected at least one (name, image) pair, got none")
    h = panels[0][1].shape[0]
    for name, img in panels:
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3 or img.shape[0] != h:
            raise ValueError(f"panels[{name!r}]: expected a ({h}, W, 3) uint8 image, got {img.shape} {img.dtype}")
    sheet = Image.new("RGB", (sum(img.shape[1] for _, img in panels), h + label_px), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    x = 0
    for name, img in panels:
        sheet.paste(Image.fromarray(img), (x, label_px))
        draw.text((x + 4, 3), name, fill=(0, 0, 0))
        x += img.shape[1]
    return np.asarray(sheet)
