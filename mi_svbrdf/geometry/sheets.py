"""Printable sheets of the capture frames at true scale: the AprilTag print and the paper frame.

:func:`draw_sheet` draws one sheet on a matplotlib figure whose size is the paper's (inches), with
axes spanning the whole page in millimetres (origin at the page's bottom-left corner, y up), so
a PDF of the figure prints at true scale ("actual size", no fit-to-page). :func:`write_sheets`
writes the PDFs on A4 and Letter and a PNG preview.

* ``tags``: the 16 tag36h11 tags of :mod:`~mi_svbrdf.geometry.tags` as vector cells (each turned by
  180 degrees from OpenCV's drawing, as the field's print), the window to cut (dashed, side
  ``2 S / 3``), the ruler line to measure ``S`` (the ring's outer edges), the orientation mark
  (``TOP``, tag 0 at the top left) and how to use it.
* ``a4``: the paper frame of :data:`~mi_svbrdf.geometry.frame.DEFAULT_FRAME` (a window of
  ``size`` mm, 30 mm from the left and top edges, the widest margin at the bottom), its cut line
  and how to use it.

Examples:
    >>> layout = tag_layout("a4", 180.0)
    >>> round(layout.ring_mm[2] - layout.ring_mm[0], 6)
    180.0
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mi_svbrdf.geometry.frame import DEFAULT_FRAME
from mi_svbrdf.geometry.tags import RING_UNITS, TAG_CELLS, TAG_UNITS, WINDOW_HALF_UNITS, tag_centres, tag_image

#: Paper sizes (width, height) in mm.
PAPERS = {"a4": (210.0, 297.0), "letter": (215.9, 279.4)}
#: Sheet kinds: the AprilTag print and the paper frame.
KINDS = ("tags", "a4")
#: Default sizes, mm: the tag ring's outer size S; the paper frame's window side.
DEFAULT_SIZE_MM = {"tags": 180.0, "a4": DEFAULT_FRAME.window_mm[0]}
#: Smallest margin (mm) between what is drawn and the paper's edge (printers do not print there).
PRINT_MARGIN_MM = 8.0
#: Preview resolution, dots per inch.
PREVIEW_DPI = 60
MM_PER_INCH = 25.4


@dataclass(frozen=True)
class TagLayout:
    """Where the tag print lies on a page (mm from the bottom-left corner, y up).

    Attributes:
        paper: ``(W, H)`` of the page.
        centre: the ring's (and window's) centre.
        unit_mm: one sheet unit (``S / 18``).
    """

    paper: tuple[float, float]
    centre: tuple[float, float]
    unit_mm: float

    @property
    def ring_mm(self) -> tuple[float, float, float, float]:
        """The ring's outer edges ``(x0, y0, x1, y1)``."""
        h = 0.5 * RING_UNITS * self.unit_mm
        return (self.centre[0] - h, self.centre[1] - h, self.centre[0] + h, self.centre[1] + h)

    def to_page(self, units: np.ndarray) -> np.ndarray:
        """Sheet units ``(..., 2)`` (origin at the ring's centre, +y up) -> page mm."""
        return np.asarray(self.centre) + np.asarray(units, float) * self.unit_mm


def tag_layout(paper: str, size_mm: float) -> TagLayout:
    """The tag print of ring size ``size_mm`` on ``paper`` (``"a4"``, ``"letter"``): centred across, high enough
    to leave room for the ruler and the notes below.

    Raises:
        ValueError: an unknown paper, or a ring that does not fit.
    """
    if paper not in PAPERS:
        raise ValueError(f"paper: expected one of {sorted(PAPERS)}, got {paper!r}")
    w, h = PAPERS[paper]
    unit = size_mm / RING_UNITS
    need = size_mm + 2.0 * PRINT_MARGIN_MM
    if not (size_mm > 0 and need <= w):
        raise ValueError(f"--size: expected a ring size S in (0, {w - 2.0 * PRINT_MARGIN_MM:g}] mm to fit {paper}, "
                         f"got {size_mm:g}")
    top = h - PRINT_MARGIN_MM - 12.0  # room for the orientation mark above the ring
    return TagLayout((w, h), (0.5 * w, top - 0.5 * size_mm), unit)


def _figure(paper: str):  # noqa: ANN202 - a matplotlib Figure (imported lazily)
    from matplotlib.figure import Figure

    w, h = PAPERS[paper]
    fig = Figure(figsize=(w / MM_PER_INCH, h / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0.0, w)
    ax.set_ylim(0.0, h)
    ax.set_axis_off()
    return fig, ax


def _notes(ax, x: float, y: float, lines: list[str]) -> None:  # noqa: ANN001
    for k, line in enumerate(lines):
        ax.text(x, y - 5.0 * k, line, fontsize=8.5, va="top", ha="left", family="DejaVu Sans")


def draw_tags(ax, layout: TagLayout) -> None:  # noqa: ANN001 - a matplotlib Axes in page mm
    """The 16 tags (vector cells), the window's cut line, the ruler and the orientation mark on ``ax``."""
    from matplotlib.patches import Rectangle

    cell = TAG_UNITS * layout.unit_mm / TAG_CELLS
    for tag_id, centre in enumerate(tag_centres()):
        img = tag_image(tag_id, 1)  # (8, 8), row 0 at the top, as printed
        x0, y1 = layout.to_page(centre + np.array([-0.5 * TAG_UNITS, 0.5 * TAG_UNITS]))
        for r, c in zip(*np.nonzero(img < 128)):
            ax.add_patch(Rectangle((x0 + c * cell, y1 - (r + 1) * cell), cell, cell, facecolor="black",
                                   edgecolor="black", linewidth=0.05, antialiased=False))
    # the window to cut
    (wx0, wy0), (wx1, wy1) = layout.to_page(np.array([[-WINDOW_HALF_UNITS] * 2, [WINDOW_HALF_UNITS] * 2]))
    ax.add_patch(Rectangle((wx0, wy0), wx1 - wx0, wy1 - wy0, fill=False, linestyle=(0, (4, 3)), linewidth=0.6,
                           edgecolor="0.35"))
    ax.text(0.5 * (wx0 + wx1), 0.5 * (wy0 + wy1) + 4.0, "cut out this window", ha="center", va="center",
            fontsize=10, color="0.35")
    ax.text(0.5 * (wx0 + wx1), 0.5 * (wy0 + wy1) - 4.0,
            f"(side {wx1 - wx0:.1f} mm = 2S/3, along the dashed line)", ha="center", va="center",
            fontsize=8, color="0.35")
    # the orientation mark
    x0, y0, x1, y1 = layout.ring_mm
    ax.annotate("", xy=(0.5 * (x0 + x1), y1 + 10.0), xytext=(0.5 * (x0 + x1), y1 + 3.0),
                arrowprops={"arrowstyle": "-|>", "color": "black", "linewidth": 0.8})
    ax.text(0.5 * (x0 + x1) + 3.0, y1 + 6.5, "TOP (tag 0 at the top left, IDs clockwise)", fontsize=8, va="center")
    # the ruler line: the ring's outer edges
    ry = y0 - 7.0
    ax.plot([x0, x1], [ry, ry], color="black", linewidth=0.6)
    for x in (x0, x1):
        ax.plot([x, x], [ry - 2.5, y0 - 1.0], color="black", linewidth=0.6)
    ax.text(0.5 * (x0 + x1), ry - 1.5, f"S: measure this distance (printed at {x1 - x0:g} mm) and pass it as "
            "--frame-size S", ha="center", va="top", fontsize=8)


def draw_paper_frame(ax, paper: str, window_mm: float) -> None:  # noqa: ANN001 - a matplotlib Axes in page mm
    """The paper frame's window (30 mm from the left and top edges, dashed cut line) and its notes on ``ax``."""
    from matplotlib.patches import Rectangle

    w, h = PAPERS[paper]
    left, top = DEFAULT_FRAME.window_offset_mm
    if not (0 < window_mm <= w - 2.0 * left and h - top - window_mm > 1.6 * max(left, w - left - window_mm)):
        raise ValueError(f"--size: expected a window side that fits {paper} 30 mm from its left and top edges with "
                         f"the bottom margin the widest (the default {DEFAULT_SIZE_MM['a4']:g} mm fits A4 and Letter), "
                         f"got {window_mm:g}")
    x0, y1 = left, h - top
    ax.add_patch(Rectangle((x0, y1 - window_mm), window_mm, window_mm, fill=False, linestyle=(0, (4, 3)),
                           linewidth=0.6, edgecolor="0.35"))
    ax.text(x0 + 0.5 * window_mm, y1 - 0.5 * window_mm, f"cut out this window\n{window_mm:g} x {window_mm:g} mm",
            ha="center", va="center", fontsize=10, color="0.35")


def _tag_notes(layout: TagLayout) -> list[str]:
    s = layout.ring_mm[2] - layout.ring_mm[0]
    return [
        "1. Print at actual size (no 'fit to page'); check the ruler line with a ruler: S is what you measure.",
        "2. Cut out the window along the dashed line; lay the sheet flat on the material (on cardboard: measure",
        "    the height of the tags above the material, --depth MM). Keep the tags clean and uncovered.",
        "3. Take 5-10 flash photos from different angles (20-40 degrees from above), each showing most tags.",
        f"4. mi-svbrdf rectify IMG_*.jpg --frame tags --frame-size {s:g} -o rect",
        "5. mi-svbrdf optimize --capture rect/capture.json -o fit",
    ]


def _frame_notes(window_mm: float) -> list[str]:
    return [
        "1. Print at actual size; cut out the window along the dashed line (the wide margin stays at the bottom).",
        "2. Lay the sheet flat on the material, on a darker table; keep its edges in every photo.",
        "3. Take 5-10 flash photos from different angles (up to 40 degrees from above).",
        f"4. mi-svbrdf rectify IMG_*.jpg --frame-size {window_mm:g},{window_mm:g} -o rect   (measure the window)",
        "5. mi-svbrdf optimize --capture rect/capture.json -o fit",
    ]


def sheet_figure(kind: str, paper: str, size_mm: float | None = None):  # noqa: ANN201 - a matplotlib Figure
    """The figure of one sheet (``kind`` in :data:`KINDS`) on ``paper``, at true scale (see the module docstring)."""
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    size = DEFAULT_SIZE_MM[kind] if size_mm is None else float(size_mm)
    fig, ax = _figure(paper)
    if kind == "tags":
        layout = tag_layout(paper, size)
        draw_tags(ax, layout)
        _notes(ax, PRINT_MARGIN_MM + 4.0, layout.ring_mm[1] - 20.0, _tag_notes(layout))
    else:
        draw_paper_frame(ax, paper, size)
        h = PAPERS[paper][1]
        _notes(ax, DEFAULT_FRAME.window_offset_mm[0], h - DEFAULT_FRAME.window_offset_mm[1] - size - 15.0,
               _frame_notes(size))
    return fig


def write_sheets(kind: str, out: str | os.PathLike, size_mm: float | None = None) -> list[Path]:
    """Write ``sheet_a4.pdf``, ``sheet_letter.pdf`` (true scale) and ``sheet.png`` (an A4 preview) into ``out``.

    Returns:
        The files written.
    """
    from mi_svbrdf.io.atomic import atomic_path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for paper in PAPERS:
        path = out / f"sheet_{paper}.pdf"
        with atomic_path(path) as tmp:
            sheet_figure(kind, paper, size_mm).savefig(tmp, format="pdf")
        written.append(path)
    path = out / "sheet.png"
    with atomic_path(path) as tmp:
        sheet_figure(kind, "a4", size_mm).savefig(tmp, format="png", dpi=PREVIEW_DPI)
    written.append(path)
    return written
