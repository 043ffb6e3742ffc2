"""Descriptions of the material classes: named parameters with documented ranges, validation
and the thesis's random parameter perturbation."""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import torch


@dataclass(frozen=True)
class Param:
    """One named generator parameter."""

    default: float  # default value
    low: float  # inclusive valid range
    high: float
    doc: str  # what it controls
    integer: bool = False  # only whole numbers are valid (counts, enumerations)

    def __post_init__(self) -> None:
        for name in ("default", "low", "high"):  # Param(4, 1, 16, ...) stores floats
            object.__setattr__(self, name, float(getattr(self, name)))


@dataclass(frozen=True)
class MaterialClass:
    """A procedural material class: its parameters and what its maps look like."""

    name: str  # registry key
    params: dict[str, Param]  # named parameters, in sampling order
    doc: str  # one paragraph: what it looks like, which maps are (de)correlated
    metal: bool  # coloured specular, near-zero diffuse
    #: Value range of each output map over all valid parameters: "diffuse", "roughness",
    #: "specular" -> (low, high) (every channel, every texel; the generator clips to it).
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: True when the albedo is independent of the relief by construction (printed or
    #: painted patterns): the failure case of correlated training data named by the thesis.
    decorrelated: bool = False


def validate(cls: MaterialClass, params: Mapping[str, float] | None) -> dict[str, float]:
    """Check ``params`` against ``cls`` and fill in defaults; see ``procedural.validate_parameters``."""
    params = {} if params is None else params
    if not isinstance(params, Mapping):
        raise ValueError(f"params: expected a dict of parameter values for {cls.name!r}, got {type(params).__name__}")
    unknown = sorted(set(params) - set(cls.params))
    if unknown:
        raise ValueError(f"params: unknown parameter {unknown[0]!r} of class {cls.name!r}; "
                         f"expected one of {sorted(cls.params)}")
    out = {}
    for key, spec in cls.params.items():
        if key not in params:
            out[key] = float(spec.default)
            continue
        raw = params[key]
        try:
            if isinstance(raw, (str, bytes, bool)):
                raise TypeError
            value = float(raw)
        except (TypeError, ValueError):
            raise ValueError(f"{cls.name}.{key}: expected a number in [{spec.low:g}, {spec.high:g}] ({spec.doc}), "
                             f"got {raw!r}") from None
        if not spec.low <= value <= spec.high:
            raise ValueError(f"{cls.name}.{key}: expected a value in [{spec.low:g}, {spec.high:g}] ({spec.doc}), "
                             f"got {value:g}")
        if spec.integer and value != math.floor(value):
            raise ValueError(f"{cls.name}.{key}: expected an integer in [{spec.low:g}, {spec.high:g}] ({spec.doc}), "
                             f"got {value:g}")
        out[key] = value
    return out


def sample(cls: MaterialClass, generator: torch.Generator, spread: float = 1.0) -> dict[str, float]:
    """Random valid parameters of ``cls``; see ``procedural.sample_parameters``."""
    if not isinstance(generator, torch.Generator):
        raise ValueError(f"generator: expected a torch.Generator, got {type(generator).__name__}")
    if not 0.0 <= spread <= 1.0:
        raise ValueError(f"spread: expected a value in [0, 1], got {spread}")
    draws = torch.rand(len(cls.params), generator=generator, dtype=torch.float64).tolist()
    out = {}
    for u, (key, spec) in zip(draws, cls.params.items()):
        if spec.integer:
            target = min(math.floor(spec.low + u * (spec.high - spec.low + 1.0)), spec.high)
            value = float(round(spec.default + spread * (target - spec.default)))
        else:
            target = spec.low + u * (spec.high - spec.low)
            value = spec.default + spread * (target - spec.default)
        out[key] = min(max(value, spec.low), spec.high)
    return out


def check_class(cls: MaterialClass) -> None:
    """Raise ``ValueError`` if a class description is inconsistent (defaults outside ranges)."""
    for key, spec in cls.params.items():
        if not spec.low <= spec.default <= spec.high:
            raise ValueError(f"{cls.name}.{key}: default {spec.default} outside [{spec.low}, {spec.high}]")
        if spec.integer and any(v != math.floor(v) for v in (spec.default, spec.low, spec.high)):
            raise ValueError(f"{cls.name}.{key}: an integer parameter needs integer default and bounds")
