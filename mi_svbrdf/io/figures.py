"""Figures: matplotlib without a display, and PNGs written atomically (one home for both).

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
"""
from __future__ import annotations

import os
from typing import Any

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
