"""The capture guide's figure: each step's output, from the printed sheet to ``optimize``, for both frames.

Runs the guide's commands on the synthetic examples (``mi-svbrdf frame``, ``rectify example``,
``optimize``) into a temporary folder and puts one row per frame together: the sheet (``frame``'s
preview), a photo with what ``rectify`` found (its overlay), that photo rectified, and the
diffuse and normal maps ``optimize`` fitted.

Run: ``python benchmarks/capture_guide_figure.py [-o docs/images/capture_steps.jpg] [--budget-s 20]``.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from mi_svbrdf import cli

ROOT = Path(__file__).resolve().parent.parent
#: Height of every panel, pixels.
PANEL = 300


def _panel(path: Path, label: str) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"{path}: expected an image, got none")
    img = cv2.resize(img, (round(img.shape[1] * PANEL / img.shape[0]), PANEL), interpolation=cv2.INTER_AREA)
    img = cv2.copyMakeBorder(img, 0, 0, 0, 8, cv2.BORDER_CONSTANT, value=(255, 255, 255))
    cv2.putText(img, label, (8, PANEL - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, label, (8, PANEL - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def _row(work: Path, kind: str, budget: float) -> np.ndarray:
    frame, rect, fit = work / f"{kind}_frame", work / f"{kind}_rect", work / f"{kind}_fit"
    sheet = "tags" if kind == "tags" else "a4"
    extra = ["--frame", "tags"] if kind == "tags" else []
    for argv in (["frame", sheet, "-o", str(frame)], ["rectify", "example", *extra, "--size", "128", "-o", str(rect)],
                 ["optimize", "--capture", str(rect / "capture.json"), "--budget-s", str(budget), "--no-progress",
                  "-o", str(fit)]):
        if cli.main(argv) != 0:
            raise SystemExit(f"mi-svbrdf {' '.join(argv)}: failed")
    panels = [_panel(frame / "sheet.png", f"1. frame {sheet}"), _panel(rect / "overlay_000.png", "2. photo, rectify"),
              _panel(rect / "000.png", "3. rectified"),
              _panel(fit / "material" / "diffuse.png", "4. optimize: diffuse"),
              _panel(fit / "material" / "normal.png", "normal")]
    return np.concatenate(panels, axis=1)


def main() -> None:
    """Write the figure."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--out", type=Path, default=ROOT / "docs" / "images" / "capture_steps.jpg")
    parser.add_argument("--budget-s", type=float, default=20.0, help="optimize's budget per frame (default 20)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [_row(Path(tmp), kind, args.budget_s) for kind in ("tags", "paper")]
    width = max(r.shape[1] for r in rows)
    rows = [cv2.copyMakeBorder(r, 0, 8, 0, width - r.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255))
            for r in rows]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.concatenate(rows, axis=0), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
