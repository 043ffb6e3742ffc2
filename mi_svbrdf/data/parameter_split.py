"""The held-out parameter ranges: the slice of one parameter per material class that training never draws.

**Held-out parameter ranges.** :data:`HELD_OUT_RANGES` names, for each of the nine classes,
one parameter and a slice of about 15-20 % of its valid range at one end. A training run
(``SimulatorConfig(holdout="train")``) never draws a material whose parameter lies in that
slice; the benchmark (``holdout="test"``) draws only such materials. :func:`apply_holdout`
does it by a deterministic, monotone remap of the drawn value (the number of random draws
never changes, so the rest of the stream is untouched): ``"train"`` squeezes the parameter's
whole range linearly into the training part, ``"test"`` into the held-out slice. A slice is
closed, ``lo <= v <= hi``; training values stay strictly outside it.

Examples:
    >>> from mi_svbrdf.data.parameter_split import apply_holdout, is_held_out
    >>> p = apply_holdout("tiles", {"aspect": 4.0}, "train")
    >>> is_held_out("tiles", p), is_held_out("tiles", apply_holdout("tiles", {"aspect": 1.0}, "test"))
    (False, True)
"""
from __future__ import annotations

import math

from mi_svbrdf.data import procedural

#: Hold-out modes of :class:`mi_svbrdf.data.simulator.SimulatorConfig`.
HOLDOUT_MODES = ("none", "train", "test")
#: One held-out parameter per class: {class: {parameter: (lo, hi)}}, a closed slice at one end.
HELD_OUT_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "paint": {"stroke_frequency": (25.0, 30.0)},  # of [2, 30], 17.9 %: the finest brush strokes
    "plastic": {"texture_scale": (100.0, 120.0)},  # of [10, 120], 18.2 %: the finest stipple
    "leather": {"grain": (85.0, 100.0)},  # of [10, 100], 16.7 %: the finest grain cells
    "metal": {"roughness": (0.6, 0.7)},  # of [0.05, 0.7], 15.4 %: the most satin metals
    "wood": {"ring_frequency": (50.0, 60.0)},  # of [3, 60], 17.5 %: the densest growth rings
    "fabric": {"weave_frequency": (100.0, 120.0)},  # of [8, 120], 17.9 %: the finest weaves
    "stone": {"stone_count": (13.5, 16.0)},  # of [2, 16], 17.9 %: the smallest stones
    "tiles": {"aspect": (3.5, 4.0)},  # of [1, 4], 16.7 %: the longest (plank-like) tiles
    "ground": {"crack_width": (0.005, 0.02)},  # of [0.005, 0.1], 15.8 %: the thinnest cracks
}


def _range(cls: str) -> tuple[str, float, float, float, float]:
    """``(param, low, high, lo, hi)``: the held-out parameter, its valid range and its held-out slice."""
    if cls not in HELD_OUT_RANGES:
        raise ValueError(f"cls: expected one of {sorted(HELD_OUT_RANGES)}, got {cls!r}")
    (param, (lo, hi)), = HELD_OUT_RANGES[cls].items()
    spec = procedural.CLASSES[cls].params[param]
    return param, spec.low, spec.high, lo, hi


def is_held_out(cls: str, params: dict[str, float]) -> bool:
    """True when the held-out parameter of class ``cls`` lies in its held-out slice (closed)."""
    param, _, _, lo, hi = _range(cls)
    return lo <= params[param] <= hi


def apply_holdout(cls: str, params: dict[str, float], mode: str) -> dict[str, float]:
    """Remap the held-out parameter of ``params`` (drawn over its whole valid range) for ``mode``.

    Args:
        cls: the class.
        params: every parameter of the class (e.g. :func:`mi_svbrdf.data.procedural.sample_parameters`).
        mode: ``"none"`` (unchanged), ``"train"`` (linearly into the training part, strictly
            outside the slice) or ``"test"`` (linearly into the held-out slice).

    Returns:
        A new dict; only the held-out parameter changes.
    """
    if mode not in HOLDOUT_MODES:
        raise ValueError(f"holdout: expected one of {HOLDOUT_MODES}, got {mode!r}")
    if mode == "none":
        return dict(params)
    param, low, high, lo, hi = _range(cls)
    t = min(max((params[param] - low) / (high - low), 0.0), 1.0)  # position in the valid range
    top = math.isclose(hi, high)  # the slice is at the top end (else at the bottom)
    if mode == "test":
        value = lo + t * (hi - lo)
        value = min(max(value, lo), hi)
    elif top:
        value = min(low + t * (lo - low), math.nextafter(lo, -math.inf))
    else:
        value = max(hi + t * (high - hi), math.nextafter(hi, math.inf))
    return {**params, param: value}
