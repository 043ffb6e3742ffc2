"""Materials with their simulated photos, and the one loop that runs a method on them and scores it.

A :class:`Dataset` holds ground-truth maps, the photos simulated from them and the photos' exact
captures: the held-out benchmark (:func:`load_heldout`), a failure case or its clean twin
(:func:`case_datasets`). :func:`run_and_score` runs a :class:`~mi_svbrdf.eval.methods.Method` on
the first N photos of some of its materials, timed with peak memory
(:func:`~mi_svbrdf.eval.methods.measure`), and scores the maps against the ground truth with
:func:`mi_svbrdf.core.metrics.evaluate_maps` under the fixed evaluation lights. The runner's rows
(:mod:`~mi_svbrdf.eval.runner`), the stability table (:mod:`~mi_svbrdf.eval.stability`) and the
bundled weights' held-out accuracy (:mod:`~mi_svbrdf.eval.accuracy`) all come from it.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from mi_svbrdf.core.metrics import evaluate_maps
from mi_svbrdf.data.heldout import CLASS_ORDER, HeldOutSet
from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.eval.methods import Measured, Method, measure

#: Materials of a dataset: one index, or a slice (``slice(None)``: all).
Materials = int | slice


def _select(materials: Materials) -> slice:
    return slice(materials, materials + 1) if isinstance(materials, int) else materials


@dataclass
class Dataset:
    """Materials to evaluate on: ``maps (M, 10, H, W)``, ``inputs (M, N, 3, H, W)``, captures, names."""

    name: str  #: "heldout", "case:NAME" or "clean:NAME"
    maps: torch.Tensor  #: (M, 10, H, W) ground truth
    inputs: torch.Tensor  #: (M, N, 3, H, W) linear photos (after the photo pipeline)
    captures: Captures  #: their exact captures (M, N)
    classes: list[str]  #: class of material m: classes[m % len(classes)]

    def photos(self, materials: Materials, n: int) -> tuple[torch.Tensor, Captures]:
        """The first ``n`` photos of ``materials`` and their captures."""
        sel = _select(materials)
        return self.inputs[sel, :n], self.captures.take(sel).images(slice(0, n))


def load_heldout(held: HeldOutSet, progress: bool = True) -> Dataset:
    """The held-out benchmark ``held`` (cached by :class:`~mi_svbrdf.data.heldout.HeldOutSet`) as ``"heldout"``."""
    maps, inputs, captures = held.load(progress=progress)
    classes = [CLASS_ORDER[m % len(CLASS_ORDER)] for m in range(held.materials)]
    return Dataset("heldout", maps, inputs, captures, classes)


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
                  materials: Materials = slice(None)) -> tuple[Measured, dict[str, float]]:
    """Run ``method`` on the first ``n`` photos of ``data``'s ``materials`` and score it.

    Args:
        method: a :class:`~mi_svbrdf.eval.methods.Method` (see :func:`~mi_svbrdf.eval.methods.make_method`).
        data: the materials.
        n: photos per material (the first n).
        lights: re-rendering lights of the metrics (:func:`mi_svbrdf.core.metrics.eval_lights`).
        materials: one material or a slice of them; the metrics are over all of them at once.

    Returns:
        The timed call (maps, seconds, peak memory, ``method.info``) and
        :func:`~mi_svbrdf.core.metrics.evaluate_maps` of its maps against the ground truth.
    """
    inputs, captures = data.photos(materials, n)
    res = measure(method, inputs, captures)
    return res, evaluate_maps(res.maps, data.maps[_select(materials)], lights)
