"""Figures: matplotlib without a display, PNGs written atomically, labelled contact sheets, and the small helpers
every chart shares: a colour scale that shows the data (:func:`robust_top`), point labels that do not pile up
(:func:`label_points`) and plain integer ticks on a log axis (:func:`integer_ticks`). One home for each.

matplotlib is imported on first use (it costs ~0.5 s), with the non-interactive ``Agg`` backend,
so plotting works on a machine without a display and never opens a window.

Examples:
    >>> import tempfile, pathlib
    >>> plt = pyplot()
    >>> fig, ax = plt.subplots()
    >>> _ = ax.plot([0, 1], [1, 0])
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = pathlib.Path(folder) / "line.png"
    ...     save_figure(fig, path)
    ...     path.read_bytes()[:4] == b"\\x89PNG"
    True
    >>> import numpy as np
    >>> labelled_row([("a", np.zeros((8, 8, 3), np.uint8)), ("b", np.zeros((8, 4, 3), np.uint8))]).shape
    (26, 12, 3)
    >>> robust_top(np.array([0.0, 0.011, 0.012, 0.013, 5.0]), percentile=75)
    0.015
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


#: The steps of :func:`nice_ceil` within a decade.
NICE_STEPS = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)


def nice_ceil(value: float) -> float:
    """The smallest number of :data:`NICE_STEPS` times a power of ten that is >= ``value`` (> 0): a colour bar's
    top that reads well.

    Examples:
        >>> nice_ceil(0.0137), nice_ceil(7.2), nice_ceil(20.0)
        (0.015, 8.0, 20.0)
    """
    if not (value > 0 and np.isfinite(value)):
        raise ValueError(f"value: expected a finite number > 0, got {value}")
    decade = 10.0 ** np.floor(np.log10(value))
    step = next(s for s in NICE_STEPS if s * decade >= value * (1 - 1e-9))
    return float(f"{step * decade:.6g}")


def robust_top(values: np.ndarray, percentile: float = 99.0, floor: float = 1e-6) -> float:
    """The top of a colour scale that shows the data: the ``percentile`` of the finite ``values`` rounded up by
    :func:`nice_ceil` (a few outliers do not squash the rest into the bottom of the scale; they are drawn at the top,
    a colour bar ``extend="max"`` says so). Values all zero (or none finite) give ``floor``.
    """
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    top = float(np.percentile(finite, percentile)) if finite.size else 0.0
    if top <= floor and finite.size:  # a spike over a zero field: the largest value, not nothing
        top = float(finite.max())
    return nice_ceil(max(top, floor))


def label_points(ax: Any, xs: Sequence[float], ys: Sequence[float], texts: Sequence[str], *,
                 colors: Sequence[Any] | None = None, fontsize: float = 7.0, marker: float = 5.0) -> list[Any]:
    """Label points of ``ax`` so that no two labels overlap: each label goes to the first of a few places around its
    point (right-above, right-below, left-above, left-below, then further up and down, with a thin line back to the
    point) where its box stays inside the axes and meets no label placed before and no point's marker (``marker``:
    its radius in points); where every place meets something, the one that meets the fewest. Call it once the
    axes' limits and scales are final and the figure's layout is set (``tight_layout``): the places are measured in
    the figure's pixels.

    Returns:
        The annotations (``matplotlib.text.Annotation``), in the order of ``texts``.
    """
    from matplotlib.transforms import Bbox

    if not (len(xs) == len(ys) == len(texts)):
        raise ValueError(f"xs, ys, texts: expected one length, got {len(xs)}, {len(ys)}, {len(texts)}")
    renderer = ax.figure.canvas.get_renderer()
    points = ax.transData.transform(np.column_stack([xs, ys])) if len(xs) else np.zeros((0, 2))
    radius = marker * ax.figure.dpi / 72.0
    markers = [Bbox.from_extents(x - radius, y - radius, x + radius, y + radius) for x, y in points]
    gap, line = marker + 1.0, fontsize * 1.3
    places = [(gap, 0, "left", "bottom"), (gap, 0, "left", "top"), (-gap, 0, "right", "bottom"),
              (-gap, 0, "right", "top")]
    places += [(side * gap, s * k * line, "left" if side > 0 else "right", "bottom" if s > 0 else "top")
               for k in range(1, 6) for side in (1, -1) for s in (1, -1)]
    inside = ax.get_window_extent(renderer)
    placed: list[Any] = []
    annotations = []
    for i, text in enumerate(texts):
        ann = ax.annotate(text, (xs[i], ys[i]), textcoords="offset points", xytext=places[0][:2], fontsize=fontsize,
                          color=colors[i] if colors is not None else "k")
        best, best_hits, best_box = places[0], None, None
        for place in places:
            ann.xyann = place[:2]
            ann.set_ha(place[2])
            ann.set_va(place[3])
            box = ann.get_window_extent(renderer).padded(1.0)
            hits = sum(box.overlaps(b) for b in placed) + sum(box.overlaps(m) for m in markers)
            hits += 0 if inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1) else 1  # off the axes
            if best_hits is None or hits < best_hits:
                best, best_hits, best_box = place, hits, box
            if hits == 0:
                break
        ann.remove()
        colour = colors[i] if colors is not None else "k"
        lead = ({"arrowprops": {"arrowstyle": "-", "lw": 0.5, "color": colour, "shrinkA": 1, "shrinkB": marker,
                                "relpos": (0.0, 0.5) if best[2] == "left" else (1.0, 0.5)}}
                if best[1] else {})  # moved up or down from its point: a thin line leads back to it
        ann = ax.annotate(text, (xs[i], ys[i]), textcoords="offset points", xytext=best[:2], fontsize=fontsize,
                          color=colour, ha=best[2], va=best[3], **lead)
        placed.append(best_box)  # the text's box: its leader line may cross others
        annotations.append(ann)
    return annotations


def integer_ticks(axis: Any, values: Sequence[float]) -> None:
    """Ticks at ``values`` only, written as plain integers (``1``, ``3``, ``10``), on a linear or log ``axis``
    (``ax.xaxis``): a log axis of a few N otherwise writes ``2×10⁰`` at its minor ticks."""
    from matplotlib.ticker import FixedLocator, NullLocator, StrMethodFormatter

    ticks = sorted({float(v) for v in values})
    axis.set_major_locator(FixedLocator(ticks))
    axis.set_major_formatter(StrMethodFormatter("{x:.0f}"))
    axis.set_minor_locator(NullLocator())
