"""Settings, checked: dataclass configs built from dicts (unknown keys rejected) and field checks.

Every config of mi_svbrdf (training, simulator, photo setups, optimiser, evaluation, dataset jobs)
is a dataclass built with :func:`from_dict` and validated with :func:`check_fields`, so a bad
setting always fails the same way: ``"Owner.field: expected <what>, got <value>"``.

Examples:
    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class Job:
    ...     count: int = 1
    >>> from_dict(Job, {"count": 3})
    Job(count=3)
    >>> from_dict(Job, {"cuont": 3})
    Traceback (most recent call last):
    ...
    ValueError: Job: unknown keys ['cuont']; expected some of ['count']
    >>> check_fields([("count", False, "an int >= 1", 0)], owner="Job")
    Traceback (most recent call last):
    ...
    ValueError: Job.count: expected an int >= 1, got 0
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any, TypeVar

__all__ = ["Check", "check_fields", "from_dict"]

_Config = TypeVar("_Config")

#: One check: ``(field name, passed?, what was expected, the value got)``.
Check = tuple[str, bool, str, Any]


def from_dict(cls: type[_Config], data: dict[str, Any]) -> _Config:
    """Instantiate dataclass ``cls`` from ``data``, rejecting unknown keys with a ``ValueError``."""
    if not isinstance(data, dict):
        raise ValueError(f"{cls.__name__}: expected a dict of fields, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown keys {unknown}; expected some of {sorted(names)}")
    return cls(**data)


def check_fields(checks: Iterable[Check], owner: str | None = None) -> None:
    """Raise ``ValueError("[owner.]name: expected want, got got")`` for the first failed check."""
    for name, ok, want, got in checks:
        if not ok:
            where = f"{owner}.{name}" if owner else name
            raise ValueError(f"{where}: expected {want}, got {got!r}")
