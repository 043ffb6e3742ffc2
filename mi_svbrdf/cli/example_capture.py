"""``python -m mi_svbrdf.cli.example_capture``: re-make the bundled calibrated capture in ``mi_svbrdf/assets/``.

The capture (``mi-svbrdf optimize --capture example``) photographs held-out material
:data:`MATERIAL` of the held-out benchmark (:class:`mi_svbrdf.data.heldout.HeldOutSet`: class
``CLASS_ORDER[2]`` = leather, a held-out parameter slice, the benchmark's seed, never seen in
training) with the ``multiview`` capture preset: its first :data:`PHOTOS` photos (a
fronto-parallel flash photo, then cameras and flashes over the hemisphere, ambient lights,
noise, the 8-bit photo pipeline) at :data:`SIZE` px, rectified to the sample. The exact
calibration of each photo is in ``capture.json`` (:func:`mi_svbrdf.io.calibrated_photos.capture_from_simulator`);
the photos are 8-bit sRGB PNG. ``truth.json`` records the set's settings and the material, so
:func:`truth_maps` regenerates the ground-truth maps a fit is scored against.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.assets import EXAMPLE_CAPTURE_DIR, EXAMPLE_CAPTURE_TRUTH
from mi_svbrdf.cli.common import asset_script
from mi_svbrdf.data.heldout import CLASS_ORDER, HELD_OUT_SEED, VERSION, HeldOutSet
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.calibrated_photos import CAPTURE_NAME, CaptureSpec, capture_from_simulator, save_capture

#: Held-out material index of the example capture (class CLASS_ORDER[2] = leather; 7 and 13 are the example photos').
MATERIAL = 2
#: Photos of the capture (the first of the material's held-out captures).
PHOTOS = 6
#: Side of the photos and maps, pixels.
SIZE = 128
#: Capture preset of the held-out set.
PRESET = "multiview"


def heldout_set(truth: dict[str, Any] | None = None) -> HeldOutSet:
    """The held-out set the example is drawn from (``truth``: a ``truth.json``'s ``heldout`` entry; None: the defaults)."""
    h = truth or {"size": SIZE, "n_images": PHOTOS, "preset": PRESET, "seed": HELD_OUT_SEED}
    return HeldOutSet(size=h["size"], materials=1, n_images=h["n_images"], preset=h["preset"], seed=h["seed"],
                      cache=False)


def render_example_capture() -> tuple[CaptureSpec, torch.Tensor, dict[str, Any]]:
    """``(spec, images (N, 3, SIZE, SIZE) linear, truth)`` of the example capture."""
    material = heldout_set().material(MATERIAL)
    spec, images = capture_from_simulator(material["captures"], 0, material["inputs"], encoding="srgb8")
    truth = {"material": f"held-out material {MATERIAL} ({CLASS_ORDER[MATERIAL % len(CLASS_ORDER)]})",
             "made_by": "python -m mi_svbrdf.cli.example_capture",
             "heldout": {"index": MATERIAL, "class": CLASS_ORDER[MATERIAL % len(CLASS_ORDER)], "size": SIZE,
                         "n_images": PHOTOS, "preset": PRESET, "seed": HELD_OUT_SEED, "version": VERSION},
             "info": material["info"]}
    return spec, images, truth


def truth_maps(path: Path = EXAMPLE_CAPTURE_TRUTH) -> torch.Tensor:
    """The ``(1, 10, H, W)`` ground-truth maps of the capture whose ``truth.json`` is ``path``."""
    truth = json.loads(Path(path).read_text(encoding="utf-8"))["heldout"]
    return heldout_set(truth).material(truth["index"])["maps"]


def write_example_capture(folder: Path = EXAMPLE_CAPTURE_DIR) -> list[Path]:
    """Render and write the capture (``capture.json``, ``NNN.png``, ``truth.json``, atomic); returns the files."""
    spec, images, truth = render_example_capture()
    save_capture(folder / CAPTURE_NAME, spec, images)
    write_json(folder / "truth.json", truth)
    return [folder / CAPTURE_NAME, *(folder / im.file for im in spec.images), folder / "truth.json"]


def main(argv: list[str] | None = None) -> int:
    """Re-make the bundled example capture (or write it to ``--out``)."""
    return asset_script(argv, "python -m mi_svbrdf.cli.example_capture", __doc__, EXAMPLE_CAPTURE_DIR, write_example_capture)


if __name__ == "__main__":
    raise SystemExit(main())
