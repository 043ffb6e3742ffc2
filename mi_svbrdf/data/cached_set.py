"""Evaluation sets built once and cached: the one base of the held-out, foreign and large-scale sets.

A cached set is a frozen dataclass of settings whose tensors are a pure function of them. It is
built material by material (``material(m)``, a pure function of the settings and ``m``, so a set
of 8 is the prefix of a set of 16), stacked, and kept under its cache folder as a ``.pt`` file
(written atomically) whose name carries a hash of every setting that changes the tensors
(:meth:`CachedSet.key`). ``cache`` and ``cache_dir`` are not part of the key.

Subclasses (:class:`~mi_svbrdf.data.heldout.HeldOutSet`, :class:`~mi_svbrdf.data.foreign.ForeignSet`,
:class:`~mi_svbrdf.data.large_scale.LargeScaleHeldOut`) give:

* :attr:`CachedSet.kind`: the cache sub-folder (``heldout``, ``foreign``) and :attr:`CachedSet.label`,
  the progress bar's;
* :meth:`CachedSet.key_extras`: what else changes the tensors (the construction's version, the
  parameter ranges, torch's version);
* :meth:`CachedSet.file_name`: the cache file's name for a key;
* ``material(m)`` (the default :meth:`CachedSet.build` stacks them) or their own ``build``.

The cache folder is ``$MI_SVBRDF_CACHE/KIND`` or ``~/.cache/mi_svbrdf/KIND`` (:func:`default_cache_dir`).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import torch

from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.io.atomic import atomic_path

#: Settings of every cached set that do not change its tensors.
NOT_IN_KEY = ("cache", "cache_dir")


def default_cache_dir(kind: str = "heldout") -> Path:
    """``$MI_SVBRDF_CACHE/KIND`` or ``~/.cache/mi_svbrdf/KIND`` (``heldout``, ``foreign``, ``realistic``)."""
    root = os.environ.get("MI_SVBRDF_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "mi_svbrdf") / kind


def settings_key(settings: dict[str, Any]) -> str:
    """A 16-hex-digit hash of JSON-able ``settings`` (sorted keys; other values by ``str``)."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


def load_or_build(path: Path, cache: bool, build: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """The set's tensors from the cache file ``path``, else ``build()`` them (and cache them atomically)."""
    if cache and path.exists():
        return torch.load(path, weights_only=True)
    data = build()
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            torch.save(data, tmp)
    return data


def stack_materials(parts: list[dict[str, Any]], start: float) -> dict[str, Any]:
    """One evaluation set from its materials (each ``material(m)``'s dict): maps, inputs and
    captures concatenated over the materials, ``info`` as a list, the build time since ``start``."""
    caps = [p["captures"] for p in parts]
    tensors = {f.name: torch.cat([getattr(c, f.name) for c in caps]) for f in dataclasses.fields(Captures)
               if isinstance(getattr(caps[0], f.name), torch.Tensor)}
    flags = {k: getattr(caps[0], k) for k in ("flash", "cone", "photo")}
    return {"maps": torch.cat([p["maps"] for p in parts]), "inputs": torch.cat([p["inputs"] for p in parts]),
            "captures": {**tensors, **flags}, "info": [p["info"] for p in parts],
            "seconds": time.perf_counter() - start}


def unpack(data: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor, Captures]:
    """``(maps, inputs, captures)`` of a set's tensors."""
    return data["maps"], data["inputs"], Captures(**data["captures"])


class CachedSet:
    """Base of the cached evaluation sets (see the module docstring); subclasses are frozen dataclasses
    with ``materials``, ``cache`` and ``cache_dir`` fields."""

    #: Cache sub-folder (:func:`default_cache_dir`).
    kind: ClassVar[str] = "heldout"
    #: Progress bar label while the set is built.
    label: ClassVar[str] = "evaluation set"
    #: Store ``info`` as JSON text (nested captures: ``torch.load(weights_only=True)`` reads no nested dicts).
    json_info: ClassVar[bool] = False

    materials: int
    cache: bool
    cache_dir: str | None

    def check_counts(self, max_photos: int) -> None:
        """Check ``materials`` (>= 1), ``n_images`` (1 to ``max_photos``) and ``seed`` (>= 1000: 0-999 are the
        training seeds), each a ``ValueError`` naming the field."""
        n_images, seed = getattr(self, "n_images"), getattr(self, "seed")
        if not (isinstance(self.materials, int) and self.materials >= 1):
            raise ValueError(f"materials: expected an int >= 1, got {self.materials!r}")
        if not (isinstance(n_images, int) and 1 <= n_images <= max_photos):
            raise ValueError(f"n_images: expected an int in [1, {max_photos}], got {n_images!r}")
        if not (isinstance(seed, int) and seed >= 1000):
            raise ValueError(f"seed: expected an int >= 1000 (0-999 are training seeds), got {seed!r}")

    def key_extras(self) -> dict[str, Any]:
        """What changes the tensors besides the settings (version, ranges, torch's version)."""
        raise NotImplementedError

    def key_settings(self) -> dict[str, Any]:
        """The settings that change the tensors: every field but :data:`NOT_IN_KEY`."""
        return {k: v for k, v in dataclasses.asdict(self).items() if k not in NOT_IN_KEY}  # type: ignore[call-overload]

    def key(self) -> str:
        """Cache key: a hash of every setting that changes the tensors."""
        return settings_key({**self.key_settings(), **self.key_extras()})

    def file_name(self, key: str) -> str:
        """The cache file's name for ``key``."""
        raise NotImplementedError

    def path(self) -> Path:
        """The cache file."""
        root = Path(self.cache_dir) if self.cache_dir else default_cache_dir(self.kind)
        return root / self.file_name(self.key())

    def material(self, m: int) -> dict[str, Any]:
        """Material ``m`` alone: ``{"maps", "inputs", "captures", "info"}`` (for the default :meth:`build`)."""
        raise NotImplementedError

    def build(self, progress: bool) -> dict[str, Any]:
        """The set's tensors: every :meth:`material` stacked (:func:`stack_materials`)."""
        start = time.perf_counter()
        parts = [self.material(m) for m in tqdm(range(self.materials), desc=self.label, disable=not progress)]
        data = stack_materials(parts, start)
        if self.json_info:
            data["info"] = json.dumps(data["info"])
        return data

    def tensors(self, progress: bool = True) -> dict[str, Any]:
        """The set's tensors, from the cache or built (and cached)."""
        return load_or_build(self.path(), self.cache, lambda: self.build(progress))

    def load(self, progress: bool = True) -> tuple[torch.Tensor, ...]:
        """``(maps (M, 10, H, W), inputs (M, N, 3, H, W) linear photos, captures)``, identical at every call."""
        return unpack(self.tensors(progress))

    def info(self, progress: bool = True) -> list[dict[str, Any]]:
        """JSON-ready description of each material."""
        info = self.tensors(progress)["info"]
        return json.loads(info) if isinstance(info, str) else info
