"""The online capture simulator (thesis ch. 4.3): new SVBRDFs and their photos at every step.

:class:`CaptureSimulator` is a ``torch.utils.data.IterableDataset`` of whole batches. Each
batch is made from scratch:

1. **Materials** at ``source_size`` texels: procedural ones
   (:func:`mi_svbrdf.data.procedural.generate_batch` with :func:`~mi_svbrdf.data.procedural.sample_parameters`:
   a random class, random parameters, a random seed), materials of a bank
   (:class:`mi_svbrdf.io.material_sets.MaterialSet`, each resampled to ``source_size``: a 256²
   bank is magnified by ``source_size / 256``; set ``source_size=256`` to keep its texel
   density, rotated windows then reach past its edges, filled by mirroring), or both
   (``"mixed"``, a fraction from the bank).
   Procedural materials come from a sliding **pool**: batch ``i`` picks them among the pool
   ids ``[i r, i r + P)`` (``P = pool_size``, ``r = pool_refresh``); pool material ``m`` is a
   pure function of ``(seed, m)`` and is generated once per process, when first picked, then
   kept until it leaves the pool. Every batch still holds new SVBRDFs (new mixes, rotations,
   crops and captures) while a procedural material costs a fraction of a batch: with the
   defaults (P = 32, r = 1) ~1 new material per batch instead of ~12, each material serving
   ~12 samples over its 32 batches (the thesis served its 1 850 variants for the whole
   training). ``pool_size=0`` makes every procedural material fresh; the pool costs
   ``P * 10 * source_size^2 * 4`` bytes (170 MB at 363^2) per process.
   With ``holdout`` ``"train"`` / ``"test"`` each procedural material's held-out parameter
   (:data:`mi_svbrdf.data.parameter_split.HELD_OUT_RANGES`) is remapped out of / into its held-out slice
   (:func:`mi_svbrdf.data.parameter_split.apply_holdout`: same random draws, so the stream keeps its
   determinism; bank materials are not affected).
2. **Mixing**: with probability ``mix_probability`` a sample is α-blended with a second material
   from the same source rule, ``alpha ~ U(0.1, 0.9)`` (:func:`mi_svbrdf.data.augment.random_mix`,
   the authors' 2019 rule).
3. **Rotation, scale, crop** (:func:`mi_svbrdf.data.augment.random_transform`): a random angle,
   log-uniform scale and translation, cropped to ``size``; normals turn with the maps. The
   default ``source_size`` is the smallest one in which every rotated, scaled window fits.
4. Optionally a per-sample normal strength ``k`` (``normal_strength``: slopes times ``k``, ``k``
   log-uniform; steeper or flatter reliefs than the procedural classes make), a per-sample
   specular factor (``specular_scale``, log-uniform, clipped to 1), then the 2019
   roughness remap ``r' = 0.9 r + 0.1``.
5. **Photos**: N (drawn per batch from ``n_images``) captures per sample from the preset's
   :class:`~mi_svbrdf.data.photo_setups.CaptureConfig` (:func:`~mi_svbrdf.data.photo_setups.sample_captures`),
   rendered with the texel renderer (:func:`~mi_svbrdf.data.photo_setups.render_captures`; inputs are
   rectified, no perspective is simulated) and passed through the photo pipeline
   (:func:`~mi_svbrdf.data.photo_setups.photograph`).

**Device** (``device``): every step above runs on it (:func:`mi_svbrdf.core.device.made_on`; the
texel renderer's Dr.Jit kernels on the backend of the tensors' device, no Mitsuba variant involved),
so a CUDA training step never leaves the GPU. The random choices are drawn from the same CPU
generators on every device: a seed gives the same materials, transforms and captures on the CPU and
on a GPU (equal up to float rounding of the arithmetic).

Each batch is a :class:`SimulatedBatch`: ``inputs (B, N, 3, H, W)`` (linear, after the 8-bit
pipeline), ``maps (B, 10, H, W)``, the exact ``captures`` (for calibrated optimisation) and
a JSON-ready description of every material.

**Determinism.** Batch ``i`` is a pure function of ``(seed, i)``: its generator is seeded from
``numpy.random.SeedSequence([seed, i])``. In a ``DataLoader`` with k workers, worker ``w``
(``torch.utils.data.get_worker_info()``) makes the batches ``i = start + w, start + w + k, ...``,
and the loader returns them in the order ``start, start + 1, ...``: the stream is the same for
any number of workers, workers never repeat each other, and ``start`` resumes a stream. Use
``DataLoader(simulator, batch_size=None, num_workers=k)`` (the simulator already batches).

Examples:
    >>> from mi_svbrdf.data.simulator import CaptureSimulator, SimulatorConfig
    >>> sim = CaptureSimulator(SimulatorConfig(size=32, batch_size=2, n_images=(2, 2), steps=1))
    >>> batch = next(iter(sim))
    >>> tuple(batch.inputs.shape), tuple(batch.maps.shape), batch.captures.n_images
    ((2, 2, 3, 32, 32), (2, 10, 32, 32), 2)
"""
from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.device import DEVICE_PATTERN, made_on, resolve_device
from mi_svbrdf.core.settings import from_dict
from mi_svbrdf.core.render import BACKENDS
from mi_svbrdf.data import augment, procedural
from mi_svbrdf.data.parameter_split import HOLDOUT_MODES, apply_holdout
from mi_svbrdf.data.photo_setups import (
    PRESETS,
    CaptureConfig,
    Captures,
    capture_config,
    jpeg,
    photograph,
    render_captures,
    sample_captures,
)
from mi_svbrdf.io.material_sets import MaterialSet

MATERIAL_SOURCES = ("procedural", "bank", "mixed")
_POOL_TAG = 0x706F6F6C  # "pool": keeps material seeds apart from batch seeds
#: Default number of photos per sample for each preset.
PRESET_IMAGES: dict[str, tuple[int, int]] = {"multiview": (1, 5), "single_flash": (1, 1), "ambient": (1, 1),
                                             "clean": (1, 1)}


@dataclass(frozen=True)
class SimulatorConfig:
    """What :class:`CaptureSimulator` makes. Unknown keys are rejected by :meth:`from_dict`."""

    size: int = 256  #: output resolution H = W of maps and photos, >= 8
    batch_size: int = 8  #: B, samples per batch, >= 1
    n_images: tuple[int, int] | None = None  #: (low, high) photos per sample, drawn per batch; None: preset's
    preset: str = "multiview"  #: capture preset (mi_svbrdf.data.photo_setups.PRESETS)
    capture: dict[str, Any] = field(default_factory=dict)  #: CaptureConfig overrides on top of the preset
    materials: str = "procedural"  #: "procedural", "bank" (a MaterialSet at bank) or "mixed"
    bank: str | None = None  #: root of the material bank (materials "bank" or "mixed")
    bank_fraction: float = 0.5  #: "mixed": probability that a material comes from the bank, [0, 1]
    classes: tuple[str, ...] | None = None  #: procedural classes to draw from uniformly (None: all nine)
    parameter_spread: float = 1.0  #: spread passed to procedural.sample_parameters, [0, 1]
    holdout: str = "none"  #: procedural hold-out (mi_svbrdf.data.parameter_split): "none", "train" (never held-out) or "test" (only)
    pool_size: int = 32  #: procedural materials shared by consecutive batches (0: every material fresh)
    pool_refresh: int = 1  #: procedural materials entering (and leaving) the pool per batch, >= 1
    mix_probability: float = 0.5  #: probability that a sample is an alpha-blend of two materials, [0, 1]
    mix_alpha: tuple[float, float] = (0.1, 0.9)  #: alpha range of the blend (authors: 0.1 to 0.9)
    rotation: tuple[float, float] = (-180.0, 180.0)  #: rotation range in degrees before the crop
    scale: tuple[float, float] = (1.0, 1.25)  #: magnification range (log-uniform; > 1 zooms in), 0 < low
    source_size: int | None = None  #: texels of the materials before the crop (None: smallest that fits)
    remap_roughness: bool = False  #: 2019 training remap r' = 0.9 r + 0.1 (no pure mirrors)
    normal_strength: tuple[float, float] = (1.0, 1.0)  #: slope factor k, log-uniform per sample: n = norm(k nx, k ny, nz)
    specular_scale: tuple[float, float] = (1.0, 1.0)  #: specular albedo factor, log-uniform per sample (result clipped to 1)
    #: JPEG every photo at a quality drawn uniformly in [low, high] per photo, after the photo pipeline (None: lossless)
    jpeg_quality: tuple[int, int] | None = None
    seed: int = 0  #: seed of the stream (batch i depends on (seed, i) only), >= 0
    start: int = 0  #: first batch index of the stream (resume a stream), >= 0
    steps: int | None = None  #: batches in one pass over the dataset (None: endless)
    backend: str = "mitsuba"  #: texel renderer backend: "mitsuba" (fused Dr.Jit) or "torch"
    device: str = "cpu"  #: where materials, augmentation, rendering and the photo pipeline run: cpu, cuda or cuda:N

    def __post_init__(self) -> None:
        if not (isinstance(self.size, int) and self.size >= 8):
            raise ValueError(f"size: expected an int >= 8, got {self.size!r}")
        if not (isinstance(self.batch_size, int) and self.batch_size >= 1):
            raise ValueError(f"batch_size: expected an int >= 1, got {self.batch_size!r}")
        if self.preset not in PRESETS:
            raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {self.preset!r}")
        if self.n_images is not None:
            lo, hi = self.n_images
            if not (isinstance(lo, int) and isinstance(hi, int) and 1 <= lo <= hi):
                raise ValueError(f"n_images: expected (low, high) ints with 1 <= low <= high, got {self.n_images!r}")
        if self.materials not in MATERIAL_SOURCES:
            raise ValueError(f"materials: expected one of {MATERIAL_SOURCES}, got {self.materials!r}")
        if self.materials != "procedural" and not self.bank:
            raise ValueError(f"bank: expected a material bank root with materials={self.materials!r}, "
                             f"got {self.bank!r}")
        for name in ("bank_fraction", "mix_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name}: expected a probability in [0, 1], got {getattr(self, name)!r}")
        if not 0.0 <= self.mix_alpha[0] <= self.mix_alpha[1] <= 1.0:
            raise ValueError(f"mix_alpha: expected 0 <= low <= high <= 1, got {self.mix_alpha!r}")
        if not self.rotation[0] <= self.rotation[1]:
            raise ValueError(f"rotation: expected low <= high degrees, got {self.rotation!r}")
        if not 0.0 < self.scale[0] <= self.scale[1]:
            raise ValueError(f"scale: expected 0 < low <= high, got {self.scale!r}")
        for name in ("normal_strength", "specular_scale"):
            lo, hi = getattr(self, name)
            if not 0.0 < lo <= hi:
                raise ValueError(f"{name}: expected 0 < low <= high, got {getattr(self, name)!r}")
        if self.jpeg_quality is not None:
            q = tuple(self.jpeg_quality)
            if not (len(q) == 2 and all(isinstance(v, int) for v in q) and 1 <= q[0] <= q[1] <= 100):
                raise ValueError(f"jpeg_quality: expected None or (low, high) ints with 1 <= low <= high <= 100, "
                                 f"got {self.jpeg_quality!r}")
            object.__setattr__(self, "jpeg_quality", q)
        if not 0.0 <= self.parameter_spread <= 1.0:
            raise ValueError(f"parameter_spread: expected a value in [0, 1], got {self.parameter_spread!r}")
        if not (isinstance(self.pool_size, int) and self.pool_size >= 0):
            raise ValueError(f"pool_size: expected an int >= 0, got {self.pool_size!r}")
        if not (isinstance(self.pool_refresh, int) and self.pool_refresh >= 1):
            raise ValueError(f"pool_refresh: expected an int >= 1, got {self.pool_refresh!r}")
        if self.source_size is not None and not (isinstance(self.source_size, int) and self.source_size >= self.size):
            raise ValueError(f"source_size: expected None or an int >= size ({self.size}), got {self.source_size!r}")
        for name in ("seed", "start"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise ValueError(f"{name}: expected an int >= 0, got {getattr(self, name)!r}")
        if self.steps is not None and not (isinstance(self.steps, int) and self.steps >= 0):
            raise ValueError(f"steps: expected None or an int >= 0, got {self.steps!r}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {self.backend!r}")
        if not (isinstance(self.device, str) and DEVICE_PATTERN.match(self.device)):
            raise ValueError(f"device: expected cpu, cuda or cuda:N, got {self.device!r}")
        if self.holdout not in HOLDOUT_MODES:
            raise ValueError(f"holdout: expected one of {HOLDOUT_MODES}, got {self.holdout!r}")
        if self.classes is not None:
            unknown = sorted(set(self.classes) - set(procedural.CLASSES))
            if unknown or not self.classes:
                raise ValueError(f"classes: expected a non-empty subset of {sorted(procedural.CLASSES)}, "
                                 f"got {list(self.classes)}")
        capture_config(self.preset, **self.capture)  # validates the overrides

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimulatorConfig:
        """Build from a dict (e.g. parsed JSON; lists become tuples); unknown keys raise a ``ValueError``."""
        data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return from_dict(cls, data)

    @property
    def capture_config(self) -> CaptureConfig:
        """The preset with the ``capture`` overrides."""
        return capture_config(self.preset, **self.capture)

    @property
    def image_range(self) -> tuple[int, int]:
        """``n_images``, or the preset's default."""
        return self.n_images if self.n_images is not None else PRESET_IMAGES[self.preset]

    @property
    def material_size(self) -> int:
        """Texels of the materials before rotation, scale and crop: the smallest size in which
        every window fits (``size * max(|cos| + |sin|) / scale_low``), unless ``source_size`` is set."""
        if self.source_size is not None:
            return self.source_size
        lo, hi = (math.radians(a) for a in self.rotation)
        angles = [lo, hi] + [k * math.pi / 4 for k in range(-8, 9) if lo <= k * math.pi / 4 <= hi]
        spread = max(abs(math.cos(a)) + abs(math.sin(a)) for a in angles)
        return max(self.size, math.ceil(self.size * spread / self.scale[0] - 1e-9))


@dataclass
class SimulatedBatch:
    """One batch of the simulator."""

    inputs: torch.Tensor  #: (B, N, 3, H, W) photos, linear after the photo pipeline
    maps: torch.Tensor  #: (B, 10, H, W) the SVBRDFs the photos show
    captures: Captures  #: the exact capture parameters of every photo
    materials: list[dict[str, Any]]  #: per sample: source, class/name, parameters, seed, mix and transform
    index: int  #: batch index in the stream (-1 for CaptureSimulator.sample)
    seconds: dict[str, float] = field(default_factory=dict)  #: wall time of materials, captures, render, photo


def batch_generator(seed: int, index: int) -> torch.Generator:
    """The generator of batch ``index`` of the stream ``seed`` (``SeedSequence([seed, index])``)."""
    state = np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(state))


def material_generator(seed: int, pool_id: int) -> torch.Generator:
    """The generator choosing pool material ``pool_id`` of the stream ``seed``."""
    state = np.random.SeedSequence([seed, _POOL_TAG, pool_id]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(state))


class CaptureSimulator(IterableDataset):
    """Endless (or ``steps``-long) stream of :class:`SimulatedBatch` (see the module docstring).

    Args:
        config: a :class:`SimulatorConfig`, a dict of its fields, or None for the defaults.
        **overrides: fields replacing those of ``config``.
    """

    def __init__(self, config: SimulatorConfig | dict[str, Any] | None = None, **overrides: Any) -> None:
        super().__init__()
        base = config if isinstance(config, dict) else dataclasses.asdict(config or SimulatorConfig())
        self.config = SimulatorConfig.from_dict({**base, **overrides})
        self.capture = self.config.capture_config
        self.device = resolve_device(self.config.device)  # a clear error where CUDA is asked for and absent
        self._bank = None
        self._pool: dict[int, torch.Tensor] = {}  # procedural pool members made so far, by pool id
        if self.config.materials != "procedural":
            self._bank = MaterialSet(self.config.bank, self.config.material_size, fit="resize")
            if len(self._bank) == 0:
                raise ValueError(f"bank: expected materials in {self.config.bank!r}, found none")
        if self.config.materials != "bank":
            self._classes = tuple(self.config.classes or procedural.CLASSES)

    def __len__(self) -> int:
        if self.config.steps is None:
            raise TypeError("CaptureSimulator: endless stream (steps=None) has no length")
        return self.config.steps

    def __iter__(self) -> Iterator[SimulatedBatch]:
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        index = self.config.start + worker
        end = None if self.config.steps is None else self.config.start + self.config.steps
        while end is None or index < end:
            yield self.batch(index)
            index += workers

    def batch(self, index: int) -> SimulatedBatch:
        """Batch ``index`` (>= 0) of the stream: a pure function of ``(config.seed, index)``."""
        if not (isinstance(index, int) and index >= 0):
            raise ValueError(f"index: expected an int >= 0, got {index!r}")
        gen = batch_generator(self.config.seed, index)
        lo, hi = self.config.image_range
        n_images = int(torch.randint(lo, hi + 1, (1,), generator=gen))
        return self._make(self.config.batch_size, n_images, gen, index)

    def sample(self, n_images: int, generator: torch.Generator, batch_size: int | None = None) -> SimulatedBatch:
        """A batch with exactly ``n_images`` photos per sample (any N, e.g. for evaluation).

        Args:
            n_images: N >= 1.
            generator: source of every random choice.
            batch_size: B (default ``config.batch_size``).
        """
        if not (isinstance(n_images, int) and n_images >= 1):
            raise ValueError(f"n_images: expected an int >= 1, got {n_images!r}")
        return self._make(batch_size or self.config.batch_size, n_images, generator, -1)

    # --- materials ---

    def _procedural_spec(self, gen: torch.Generator) -> dict[str, Any]:
        """Choose a procedural material: class, parameters and generator seed."""
        cls = self._classes[int(torch.randint(len(self._classes), (1,), generator=gen))]
        params = procedural.sample_parameters(cls, gen, spread=self.config.parameter_spread)
        params = apply_holdout(cls, params, self.config.holdout)
        seed = int(torch.randint(2**31 - 1, (1,), generator=gen))
        return {"source": "procedural", "class": cls, "params": params, "seed": seed}

    def _draw_material(self, gen: torch.Generator, from_bank: bool, window: int | None) -> dict[str, Any]:
        """Choose one material: a bank entry, a pool member (``window`` = first pool id) or a fresh one."""
        if from_bank:
            return {"source": "bank", "index": int(torch.randint(len(self._bank), (1,), generator=gen))}
        if window is None:
            return self._procedural_spec(gen)
        pool_id = window + int(torch.randint(self.config.pool_size, (1,), generator=gen))
        spec = self._procedural_spec(material_generator(self.config.seed, pool_id))
        return {**spec, "pool_id": pool_id}

    def _realise(self, specs: list[dict[str, Any]]) -> torch.Tensor:
        """The maps ``(M, 10, S, S)`` of chosen materials; procedural ones generated together per class."""
        out: list[torch.Tensor | None] = [None] * len(specs)
        by_class: dict[str, list[int]] = {}
        for i, spec in enumerate(specs):
            if spec["source"] == "bank":
                name, maps = self._bank[spec["index"]]
                spec["name"] = name
                out[i] = maps.to(self.device, torch.float32)
            elif spec.get("pool_id") in self._pool:
                out[i] = self._pool[spec["pool_id"]]
            else:
                by_class.setdefault(spec["class"], []).append(i)
        for cls, idx in by_class.items():
            fresh: dict[Any, int] = {}  # a pool member picked twice is generated once
            for i in idx:
                fresh.setdefault(specs[i].get("pool_id", ("fresh", i)), i)
            first = list(fresh.values())
            maps = procedural.generate_batch(cls, [specs[i]["seed"] for i in first], size=self.config.material_size,
                                             params=[specs[i]["params"] for i in first])
            bad = [j for j in range(maps.shape[0]) if not bool(torch.isfinite(maps[j]).all())]
            if bad:
                spec = specs[first[bad[0]]]
                raise ValueError(f"procedural.generate_batch: expected finite maps, got NaN/Inf for {cls} "
                                 f"seed={spec['seed']} params={spec['params']} ({len(bad)} of {len(first)})")
            made = {key: maps[j] for j, key in enumerate(fresh)}
            for i in idx:
                key = specs[i].get("pool_id", ("fresh", i))
                out[i] = made[key]
                if "pool_id" in specs[i]:
                    self._pool[key] = made[key].clone()  # not a view keeping the whole batch alive
        return torch.stack(out)

    def make_materials(self, batch: int, gen: torch.Generator,
                       index: int | None = None) -> tuple[torch.Tensor, list[dict[str, Any]]]:
        """``batch`` new materials, mixed, rotated, scaled and cropped: ``((B, 10, size, size), descriptions)``.

        Args:
            batch: B.
            gen: source of every choice.
            index: the batch index in the stream; with ``pool_size > 0`` procedural materials
                are then picked from the pool ids ``[index * pool_refresh, ... + pool_size)``
                (None: every material fresh).
        """
        with made_on(self.device):
            return self._materials(batch, gen, index)

    def _materials(self, batch: int, gen: torch.Generator, index: int | None) -> tuple[torch.Tensor, list[dict[str, Any]]]:
        cfg = self.config
        window = None
        if index is not None and cfg.pool_size > 0:
            window = index * cfg.pool_refresh
            for key in [k for k in self._pool if k < window]:  # members that left the pool
                del self._pool[key]
        frac = {"procedural": 0.0, "bank": 1.0, "mixed": cfg.bank_fraction}[cfg.materials]
        from_bank = (torch.rand(2, batch, generator=gen) < frac).tolist()
        mixed = (torch.rand(batch, generator=gen) < cfg.mix_probability).tolist()
        specs = [self._draw_material(gen, from_bank[0][b], window) for b in range(batch)]
        partners = [b for b in range(batch) if mixed[b]]
        specs += [self._draw_material(gen, from_bank[1][b], window) for b in partners]
        maps = self._realise(specs)
        out, info = maps[:batch], [dict(d) for d in specs[:batch]]
        if partners:
            idx = torch.tensor(partners)
            blend, alpha = augment.random_mix(out[idx], maps[batch:], gen, *cfg.mix_alpha)
            out = out.index_copy(0, idx, blend)
            for j, b in enumerate(partners):
                info[b] = {"source": "mix", "alpha": float(alpha[j]), "a": info[b], "b": dict(specs[batch + j])}
        out, params = augment.random_transform(
            out, gen, angle_range=(math.radians(cfg.rotation[0]), math.radians(cfg.rotation[1])),
            scale_range=cfg.scale, out_size=cfg.size)
        for b, d in enumerate(info):
            d["transform"] = {"angle_deg": math.degrees(float(params["angle"][b])), "scale": float(params["scale"][b]),
                              "translation": params["translation"][b].tolist()}
        if cfg.normal_strength != (1.0, 1.0):  # steeper or flatter relief: slopes x k, k log-uniform
            lo, hi = (math.log(v) for v in cfg.normal_strength)
            k = torch.exp(lo + (hi - lo) * torch.rand(batch, generator=gen)).view(-1, 1, 1, 1)
            n = M.normal(out)
            out = M.normalize_normals(torch.cat([n[:, :2] * k, n[:, 2:], out[:, 3:]], dim=1))
            for b, d in enumerate(info):
                d["normal_strength"] = float(k[b])
        if cfg.specular_scale != (1.0, 1.0):  # more or less specular than the classes draw
            lo, hi = (math.log(v) for v in cfg.specular_scale)
            k = torch.exp(lo + (hi - lo) * torch.rand(batch, generator=gen)).view(-1, 1, 1, 1)
            out = out.clone()
            out[:, M.SLICES["specular"]] = (M.specular(out) * k).clamp(0.0, 1.0)
            for b, d in enumerate(info):
                d["specular_scale"] = float(k[b])
        if cfg.remap_roughness:
            out = out.clone()
            out[:, M.SLICES["roughness"]] = 0.9 * M.roughness(out) + 0.1
        return out.contiguous(), info

    def _make(self, batch: int, n_images: int, gen: torch.Generator, index: int) -> SimulatedBatch:
        with made_on(self.device):
            return self._make_here(batch, n_images, gen, index)

    def _make_here(self, batch: int, n_images: int, gen: torch.Generator, index: int) -> SimulatedBatch:
        def mark() -> None:  # the phases' wall time (a CUDA device synchronised, so work lands in its phase)
            if self.device.type == "cuda":
                torch.cuda.synchronize(self.device)
            marks.append(time.perf_counter())

        marks: list[float] = []
        mark()
        maps, info = self._materials(batch, gen, None if index < 0 else index)
        mark()
        captures = sample_captures(batch, n_images, self.capture, gen)
        mark()
        radiance = render_captures(maps, captures, backend=self.config.backend)
        mark()
        inputs = photograph(radiance, captures, gen)
        if self.config.jpeg_quality is not None and captures.photo:
            lo, hi = self.config.jpeg_quality
            quality = torch.randint(lo, hi + 1, inputs.shape[:2], generator=gen).tolist()
            inputs = torch.stack([torch.stack([jpeg(p, q) for p, q in zip(ps, qs)])
                                  for ps, qs in zip(inputs, quality)])
        mark()
        seconds = {k: b - a for k, a, b in zip(("materials", "captures", "render", "photo"), marks, marks[1:])}
        return SimulatedBatch(inputs=inputs, maps=maps, captures=captures, materials=info, index=index,
                              seconds=seconds)
