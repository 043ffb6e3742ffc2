"""Materials with their simulated photos, and the one loop that runs a method on them and scores it.

A :class:`Dataset` holds ground-truth maps, the photos simulated from them and the photos' exact
captures: the held-out benchmark (:func:`load_heldout`), the foreign captures
(:func:`load_foreign`: :mod:`mi_svbrdf.data.foreign`, every capture parameter outside training's),
a folder of the thesis dataset's 2019 test strips (:func:`load_strips`: real inputs, no
calibration, so ``calibrated=False`` and nominal captures), a failure case or its clean twin
(:func:`case_datasets`). :func:`run_and_score` runs a :class:`~mi_svbrdf.eval.methods.Method` on
the first N photos of some of its materials, timed with peak memory
(:func:`~mi_svbrdf.eval.methods.measure`), and scores the maps against the ground truth with
:func:`mi_svbrdf.core.metrics.evaluate_maps` under the fixed evaluation lights. The runner's rows
(:mod:`~mi_svbrdf.eval.runner`), the stability table (:mod:`~mi_svbrdf.eval.stability`) and the
bundled weights' held-out accuracy (:mod:`~mi_svbrdf.eval.accuracy`) all come from it.
"""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from mi_svbrdf.core.colour import gamma_decode
from mi_svbrdf.core.metrics import evaluate_maps
from mi_svbrdf.data.foreign import FOREIGN_CLASSES, ForeignSet
from mi_svbrdf.data.heldout import CLASS_ORDER, HeldOutSet
from mi_svbrdf.data.photo_setups import Captures, capture_config, sample_captures
from mi_svbrdf.eval.methods import Measured, Method, measure, resize_maps
from mi_svbrdf.io.photos import resize
from mi_svbrdf.io.strip import read_strip

#: Panel size of the thesis's strips (some public copies have 288-px panels, centre-cropped here).
STRIP_PANEL = 256

#: Materials of a dataset: one index, or a slice (``slice(None)``: all).
Materials = int | slice


def _select(materials: Materials) -> slice:
    return slice(materials, materials + 1) if isinstance(materials, int) else materials


@dataclass
class Dataset:
    """Materials to evaluate on: ``maps (M, 10, H, W)``, ``inputs (M, N, 3, H, W)``, captures, names."""

    name: str  #: "heldout", "foreign", "strips", "case:NAME" or "clean:NAME"
    maps: torch.Tensor  #: (M, 10, H, W) ground truth
    inputs: torch.Tensor  #: (M, N, 3, H, W) linear photos (after the photo pipeline)
    captures: Captures  #: their exact captures (M, N); nominal ones when not calibrated
    classes: list[str]  #: class of material m: classes[m % len(classes)]
    calibrated: bool = True  #: the captures are the photos' own (False: nominal, see load_strips)

    def photos(self, materials: Materials, n: int) -> tuple[torch.Tensor, Captures]:
        """The first ``n`` photos of ``materials`` and their captures."""
        sel = _select(materials)
        return self.inputs[sel, :n], self.captures.take(sel).images(slice(0, n))


def load_heldout(held: HeldOutSet, progress: bool = True) -> Dataset:
    """The held-out benchmark ``held`` (cached by :class:`~mi_svbrdf.data.heldout.HeldOutSet`) as ``"heldout"``."""
    maps, inputs, captures = held.load(progress=progress)
    classes = [CLASS_ORDER[m % len(CLASS_ORDER)] for m in range(held.materials)]
    return Dataset("heldout", maps, inputs, captures, classes)


def load_foreign(foreign: ForeignSet, progress: bool = True) -> Dataset:
    """The foreign captures ``foreign`` (cached by :class:`~mi_svbrdf.data.foreign.ForeignSet`) as ``"foreign"``."""
    maps, inputs, captures = foreign.load(progress=progress)
    return Dataset("foreign", maps, inputs, captures, list(FOREIGN_CLASSES))


def nominal_captures(batch: int, n_images: int) -> Captures:
    """The nominal capture assumed for uncalibrated photos: the authors' un-augmented 2019 flash photo
    (preset ``"clean"``: light (0, 0, 2.197), camera (0, 0, 2.75), I = 13, cone e = 5 aimed at the
    centre, no ambient light, no noise) for every photo. Right for photo 0 of a 2019 test strip
    (the fronto-parallel flash photo); photos 1..9 were taken from unrecorded hemisphere positions,
    so a method that needs their calibration cannot run on them."""
    return sample_captures(batch, n_images, capture_config("clean"), torch.Generator().manual_seed(0))


def strip_files(folder: str | os.PathLike) -> list[Path]:
    """The ``*.png`` strips of ``folder``, sorted by name; a ``ValueError`` when there is none."""
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"strips: expected a folder of strip PNGs, got {str(folder)!r}")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() == ".png")
    if not files:
        raise ValueError(f"strips: expected *.png strips (10 inputs | normal | diffuse | roughness | specular) "
                         f"in {str(folder)!r}, got none")
    return files


def load_strips(folder: str | os.PathLike, size: int | None = None, progress: bool = True) -> Dataset:
    """A folder of the thesis dataset's 2019 test strips as the dataset ``"strips"`` (uncalibrated).

    Each strip (:func:`mi_svbrdf.io.strip.read_strip`) holds N inputs then the 4 maps (the 2019
    test format: N = 10). Panels above :data:`STRIP_PANEL` px are centre-cropped to it. The inputs
    are gamma-encoded photos, decoded with ``x^2.2`` (:func:`mi_svbrdf.core.colour.gamma_decode`,
    the 2019 convention); the maps are linear as stored. ``captures`` are
    :func:`nominal_captures` and ``calibrated`` is False: the runner skips the methods that need
    each photo's camera and light (optimize, refine).

    Args:
        folder: folder of ``*.png`` strips (every strip with the same N and panel size).
        size: resize photos (antialiased, linear) and maps (normals renormalised) to ``size``;
            None keeps the panel size.
        progress: unused (reading is fast); kept for the loaders' common signature.

    Raises:
        ValueError: no strips, a strip without inputs, or strips of different N or panel size.
    """
    del progress
    inputs, maps, names = [], [], []
    for path in strip_files(folder):
        photos, m = read_strip(path, crop=None)
        panel = m.shape[-1]
        if panel > STRIP_PANEL:
            top = (panel - STRIP_PANEL) // 2
            photos = photos[..., top:top + STRIP_PANEL, top:top + STRIP_PANEL]
            m = m[..., top:top + STRIP_PANEL, top:top + STRIP_PANEL]
        if photos.shape[0] == 0:
            raise ValueError(f"{path}: expected a 2019 test strip with inputs before the 4 maps, got none")
        if inputs and (photos.shape != inputs[0].shape):
            raise ValueError(f"{path}: expected {inputs[0].shape[0]} inputs of {inputs[0].shape[-1]} px like "
                             f"{names[0]}, got {photos.shape[0]} of {photos.shape[-1]} px")
        photos = gamma_decode(photos.clamp(0.0, 1.0))
        if size is not None:
            photos, m = resize(photos, size), resize_maps(m, (size, size))
        inputs.append(photos)
        maps.append(m)
        names.append(path.stem)
    stacked = torch.stack(inputs)
    return Dataset("strips", torch.cat(maps).contiguous(), stacked.contiguous(),
                   nominal_captures(stacked.shape[0], stacked.shape[1]), names, calibrated=False)


def to_device(captures: Captures, device: torch.device | str) -> Captures:
    """``captures`` with every tensor on ``device``."""
    return dataclasses.replace(captures, **{f.name: getattr(captures, f.name).to(device)
                                            for f in dataclasses.fields(Captures)
                                            if isinstance(getattr(captures, f.name), torch.Tensor)})


def case_datasets(cases: Sequence[Any]) -> list[Dataset]:
    """``case:NAME`` and ``clean:NAME`` datasets of failure cases (``Case`` objects of
    :mod:`mi_svbrdf.eval.failure_cases`: ``name``, ``maps``, ``inputs``, ``captures``, ``clean``)."""
    out = []
    for case in cases:
        out.append(Dataset(f"case:{case.name}", case.maps, case.inputs, case.captures, [case.name]))
        if getattr(case, "clean", None) is not None:
            c = case.clean
            out.append(Dataset(f"clean:{case.name}", c.maps, c.inputs, c.captures, [case.name]))
    return out


def run_and_score(method: Method, data: Dataset, n: int, lights: Any,
                  materials: Materials = slice(None), device: torch.device | str | None = None
                  ) -> tuple[Measured, dict[str, float]]:
    """Run ``method`` on the first ``n`` photos of ``data``'s ``materials`` and score it.

    Args:
        method: a :class:`~mi_svbrdf.eval.methods.Method` (see :func:`~mi_svbrdf.eval.methods.make_method`).
        data: the materials.
        n: photos per material (the first n).
        lights: re-rendering lights of the metrics (:func:`mi_svbrdf.core.metrics.eval_lights`).
        materials: one material or a slice of them; the metrics are over all of them at once.
        device: where the photos and captures go before the call (None: where they are); the
            maps are scored on the CPU.

    Returns:
        The timed call (maps, seconds, peak memory, ``method.info``) and
        :func:`~mi_svbrdf.core.metrics.evaluate_maps` of its maps against the ground truth.
    """
    inputs, captures = data.photos(materials, n)
    if device is not None and torch.device(device) != inputs.device:
        inputs, captures = inputs.to(device), to_device(captures, device)
    res = measure(method, inputs, captures)
    if res.maps.device.type != "cpu":
        res = dataclasses.replace(res, maps=res.maps.cpu())
    return res, evaluate_maps(res.maps, data.maps[_select(materials)], lights)
