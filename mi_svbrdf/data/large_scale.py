"""Training data of the by-example large-scale network (thesis ch. 5.1.4): an ambient-lit photo of a
crop of a large surface, 0-3 exemplar SVBRDF patches cut from the same surface, and the crop's maps.

**A sample** (:meth:`LargeScaleData.batch`), sizes in texels (the thesis's in brackets; the compact
defaults divide every size by 4):

1. **Material**: two large procedural materials (``material_size`` = 512 [2048], the nine classes
   of :mod:`mi_svbrdf.data.procedural`, parameters drawn with ``holdout="train"``: the held-out
   slices of :mod:`mi_svbrdf.data.parameter_split` never appear) α-blended, ``α ~ U(mix_alpha)``, with the
   authors' 2019 rule (:func:`mi_svbrdf.data.augment.mix`, as the bank and the simulator mix).
2. **Crop**: a square of side ``c``, log-uniform in ``crop`` = 128-256 [512-1024], at a random
   position, resized to the network's input ``size`` = 128 [512] with an antialiased
   (supersampled) filter that renormalises the normals (:func:`mi_svbrdf.data.augment.transform_maps`).
   Its maps are the target.
3. **Exemplars**: ``E`` patches of ``exemplar_size`` = 64 [256] cut at random positions of the
   same blended material at its own texel density (they may overlap the crop, as close-ups of
   the same wall would). ``E`` is drawn once per batch: 0 with probability ``no_exemplar`` (the
   Fig. 5.7 baseline must be meaningful), else uniform in ``n_exemplars`` = 1-3. Each becomes
   the network's 13 channels by :func:`exemplar_input` (its maps and a render under a random
   distant light).
4. **Photo**: the crop rendered under an environment of ``n_lights`` distant lights
   (:func:`mi_svbrdf.core.ambient.sample_environment`, :func:`~mi_svbrdf.core.ambient.render_environment`:
   soft light, no flash highlight), then what a camera does to it (:func:`camera`): white balance
   (the gains that make a white Lambertian sample grey, times a residual error per channel,
   ``exp(N(0, white_balance))``), exposure (that white sample's level log-uniform in ``exposure``),
   Gaussian noise (std ``exp(N(log noise_median, noise_log_std))``, the authors' 2019 law), clip,
   sRGB encoding quantised to 8 bits (``round(255 v)``: the sRGB curve of
   :mod:`mi_svbrdf.io.material_io`, the one :func:`mi_svbrdf.io.photos.load_photo` decodes real
   photos with), and decoded back to linear for the network.

**Cost** (the materials). Large materials come from a sliding **pool**, as the capture
simulator's: batch ``i`` draws its materials among the pool ids ``[i r, i r + P)`` (``P =
pool_size``, ``r = pool_refresh``); pool material ``m`` is a pure function of ``(seed, m)``,
generated when first drawn and dropped when it leaves the window, so a batch costs ~``r`` new
materials instead of ``2 B`` while every sample is still a new pair, blend, crop and photo.

**Determinism.** Batch ``i`` is a pure function of ``(seed, i)`` (its generator is
:func:`~mi_svbrdf.data.simulator.batch_generator`), whatever batches were made before.

**Held-out variant** (:class:`LargeScaleHeldOut`): fixed samples of held-out materials
(``holdout="test"``: only the held-out parameter slices), a separate seed, no pool, ``E`` fixed.

Examples:
    >>> import torch
    >>> data = LargeScaleData(LargeScaleConfig(size=32, material_size=96, crop=(32, 64), exemplar_size=16,
    ...                                        batch_size=2, n_lights=4, pool_size=4))
    >>> b = data.batch(0)
    >>> tuple(b.photo.shape), tuple(b.maps.shape), b.exemplars.shape[2:]
    ((2, 3, 32, 32), (2, 10, 32, 32), torch.Size([13, 16, 16]))
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.ambient import AmbientConfig, Environment, render_environment, sample_environment
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.core.configurations import cosine_directions
from mi_svbrdf.core.render import BACKENDS, direction, render
from mi_svbrdf.data import augment, procedural
from mi_svbrdf.data.cached_set import CachedSet
from mi_svbrdf.data.heldout import CLASS_ORDER, HELD_OUT_SEED
from mi_svbrdf.data.parameter_split import HELD_OUT_RANGES, HOLDOUT_MODES, apply_holdout
from mi_svbrdf.data.simulator import batch_generator, material_generator
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode

__all__ = ["EXEMPLAR_CHANNELS", "LargeScaleBatch", "LargeScaleConfig", "LargeScaleData", "LargeScaleHeldOut",
           "camera", "exemplar_input", "white_level"]

#: Channels of an exemplar as the network reads it: its 10 maps and a render under a distant light.
EXEMPLAR_CHANNELS = 13
#: The fixed light of :func:`exemplar_input` at inference (no ``light``, no ``generator``): from the upper
#: left at ~50 degrees of elevation, a light a person would place to show relief and gloss.
DEFAULT_EXEMPLAR_LIGHT = (-0.45, 0.45, 0.77)
#: Intensity of the exemplar's distant light: a white Lambertian texel renders to cos(elevation angle from
#: the normal) <= 1 (the renderer's ``L = f pi I c(n.l)``).
EXEMPLAR_LIGHT_INTENSITY = 1.0
#: Upper bound of r1 of the random exemplar lights (:func:`~mi_svbrdf.core.configurations.cosine_directions`,
#: the 2019 loss's sampler): elevations above ~18 degrees.
EXEMPLAR_R1_MAX = 0.9
#: LargeScaleConfig fields the held-out set fixes itself: held-out slices, classes in turn, fresh materials,
#: its own size and seed.
HELD_OUT_FIXED = ("holdout", "classes", "pool_size", "size", "seed")
#: LargeScaleConfig fields the held-out set does not take from a training stream: its own, and those that only
#: shape a stream.
STREAM_ONLY = (*HELD_OUT_FIXED, "batch_size", "n_exemplars", "no_exemplar", "pool_refresh")
#: Version of the held-out set's construction (part of its cache key).
HELD_OUT_VERSION = 1
_HELD_OUT_TAG = 0x6C617267  # "larg": keeps the held-out large-scale samples apart from the flash benchmark's


def exemplar_input(maps: torch.Tensor, *, light: torch.Tensor | None = None,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """An exemplar as the large-scale network reads it: its maps and a render under a distant light.

    The render is the texel renderer's (torch backend: plain PyTorch, differentiable), viewed from
    straight above, one distant light of intensity :data:`EXEMPLAR_LIGHT_INTENSITY` (a white
    Lambertian texel facing it renders to 1), linear, not clipped.

    Args:
        maps: ``(E, 10, h, w)`` or ``(B, E, 10, h, w)`` canonical maps (E may be 0).
        light: direction towards the light, ``(3,)`` for every exemplar or one per exemplar
            (``(E, 3)`` / ``(B, E, 3)``), z > 0; normalised here. None: random per exemplar from
            ``generator`` (cosine-weighted, elevation above ~18 degrees, as in training), or,
            without a generator, the fixed :data:`DEFAULT_EXEMPLAR_LIGHT` (inference).
        generator: source of the random lights.

    Returns:
        ``(..., 13, h, w)``: the maps (channels 0-9) and the linear render (10-12).

    Raises:
        ValueError: bad shapes, non-finite values, a light below the horizon.

    Examples:
        >>> from mi_svbrdf.core.maps import constant_maps
        >>> x = exemplar_input(constant_maps(2, 8, 8, diffuse=1.0, specular=0.0), light=torch.tensor([0.0, 0.0, 1.0]))
        >>> tuple(x.shape), round(float(x[0, 10, 4, 4]), 2)  # white Lambertian facing the light (+ Fresnel at s = 0)
        ((2, 13, 8, 8), 1.0)
    """
    if not isinstance(maps, torch.Tensor) or maps.dim() not in (4, 5) or maps.shape[-3] != M.NUM_CHANNELS:
        shape = tuple(maps.shape) if isinstance(maps, torch.Tensor) else type(maps).__name__
        raise ValueError(f"maps: expected shape (E, 10, h, w) or (B, E, 10, h, w), got {shape}")
    lead, (h, w) = tuple(maps.shape[:-3]), tuple(maps.shape[-2:])
    flat = maps.reshape(-1, M.NUM_CHANNELS, h, w)
    n = flat.shape[0]
    if n == 0:
        return maps.new_zeros(*lead, EXEMPLAR_CHANNELS, h, w)
    M.check_maps(flat, "maps")
    if light is None:
        if generator is None:
            d = torch.tensor(DEFAULT_EXEMPLAR_LIGHT, dtype=flat.dtype).expand(n, 3)
        else:
            d = cosine_directions((n,), r1_max=EXEMPLAR_R1_MAX, generator=generator)
    else:
        light = torch.as_tensor(light, dtype=flat.dtype)
        if light.shape != (3,) and tuple(light.shape) != lead + (3,):
            raise ValueError(f"light: expected shape (3,) or {lead + (3,)}, got {tuple(light.shape)}")
        if not torch.isfinite(light).all() or not bool((light[..., 2] > 0).all()):
            raise ValueError(f"light: expected finite directions with z > 0, got {light.tolist()}")
        d = light.expand(*lead, 3).reshape(n, 3)
    d = (d / d.norm(dim=-1, keepdim=True)).to(flat)
    view = torch.tensor([0.0, 0.0, 1.0], dtype=flat.dtype, device=flat.device).expand(n, 1, 3)
    radiance = render(flat, direction(d[:, None]), direction(view), intensity=EXEMPLAR_LIGHT_INTENSITY,
                      backend="torch")[:, 0]
    return torch.cat([flat, radiance], dim=1).reshape(*lead, EXEMPLAR_CHANNELS, h, w)


def white_level(env: Environment) -> torch.Tensor:
    """``(B, 3)`` linear radiance of a flat white Lambertian sample (diffuse 1, specular 0) under ``env``:
    ``sum_l I_l max(d_l.z, 0)`` (the renderer's ``f pi I c(n.l)`` with ``f = 1/pi``), what white balance
    and exposure are set from."""
    return (env.intensities * env.directions[..., 2:3].clamp_min(0.0)).sum(dim=1)


def camera(radiance: torch.Tensor, env: Environment, generator: torch.Generator, *, exposure: tuple[float, float],
           white_balance: float, noise_median: float, noise_log_std: float) -> tuple[torch.Tensor, dict[str, Any]]:
    """What a camera makes of linear ``radiance (B, 3, H, W)`` lit by ``env``: an 8-bit sRGB photo, returned linear.

    Per sample, in this order of draws from ``generator``: white-balance errors ``(B, 3)`` ~ N(0, white_balance)
    (log gains), exposure levels ``(B,)`` log-uniform in ``exposure``, noise stds ``(B,)`` =
    ``exp(N(log noise_median, noise_log_std))``, then the noise ``(B, 3, H, W)``. The gains make the white
    Lambertian sample of :func:`white_level` grey at the exposure level (times the white-balance error).

    Returns:
        ``(photo, settings)``: ``photo (B, 3, H, W)`` linear, every value the sRGB decoding of a code
        ``k / 255``; ``settings``: ``{"gains" (B, 3), "noise_std" (B,)}``.
    """
    b = radiance.shape[0]
    wb = torch.randn(b, 3, generator=generator) * white_balance
    lo, hi = (math.log(v) for v in exposure)
    level = torch.exp(lo + (hi - lo) * torch.rand(b, generator=generator))
    sigma = noise_median * torch.exp(noise_log_std * torch.randn(b, generator=generator))
    noise = torch.randn(radiance.shape, generator=generator, dtype=radiance.dtype)
    white = white_level(env).to(radiance).clamp_min(1e-6)
    gains = level[:, None] * torch.exp(wb) / white
    x = (radiance * gains[:, :, None, None] + noise * sigma.view(-1, 1, 1, 1)).clamp(0.0, 1.0)
    codes = np.round(srgb_encode(x.detach().cpu().numpy()) * 255.0)
    photo = torch.from_numpy(srgb_decode(codes / 255.0)).to(radiance)
    return photo, {"gains": gains, "noise_std": sigma}


@dataclass(frozen=True)
class LargeScaleConfig:
    """What :class:`LargeScaleData` makes (compact sizes: the thesis's divided by 4). Unknown keys are
    rejected by :meth:`from_dict`."""

    size: int = 128  #: S, side of the network input the crop is resized to (thesis 512), >= 8
    batch_size: int = 8  #: B, samples per batch, >= 1
    material_size: int = 512  #: texels of the large procedural materials (thesis 2048)
    crop: tuple[int, int] = (128, 256)  #: (low, high) side of the crop in texels, log-uniform (thesis 512-1024)
    exemplar_size: int = 64  #: s, side of the exemplar patches in texels (thesis 256)
    n_exemplars: tuple[int, int] = (1, 3)  #: (low, high) exemplars per batch when there are any, uniform
    no_exemplar: float = 0.1  #: probability that a batch has no exemplar (E = 0), [0, 1]
    classes: tuple[str, ...] | None = None  #: procedural classes, uniform (None: all nine)
    parameter_spread: float = 1.0  #: spread of procedural.sample_parameters, [0, 1]
    holdout: str = "train"  #: procedural hold-out (mi_svbrdf.data.parameter_split): "train" never draws held-out slices
    mix_alpha: tuple[float, float] = (0.1, 0.9)  #: alpha range of the two-material blend (authors: 0.1 to 0.9)
    pool_size: int = 16  #: large materials shared by consecutive batches (0: every material fresh)
    pool_refresh: int = 1  #: materials entering (and leaving) the pool per batch, >= 1
    # 128, not 32: with 32 lights a glossy sample shows one small highlight per light (99th percentile /
    # median radiance 21 at roughness 0.15, 5.3 with 128, 2.1 in the smooth limit; tests/test_ambient.py)
    n_lights: int = 128  #: distant lights of each environment
    ambient: dict[str, Any] = field(default_factory=dict)  #: AmbientConfig overrides (mi_svbrdf.core.ambient)
    exposure: tuple[float, float] = (0.5, 1.0)  #: level of a white Lambertian sample in the photo, log-uniform
    white_balance: float = 0.05  #: std of the residual white-balance error (log gain per channel)
    noise_median: float = 0.005  #: median std of the photo noise (linear; authors' 2019 pipeline)
    noise_log_std: float = 0.3  #: std of the log of the noise std
    seed: int = 0  #: stream seed: batch i is a pure function of (seed, i), >= 0
    backend: str = "mitsuba"  #: renderer backend of the ambient photos: "mitsuba" or "torch"

    def __post_init__(self) -> None:
        ints = ("size", "batch_size", "material_size", "exemplar_size", "pool_refresh", "n_lights")
        check_fields([
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in ints),
            ("size", self.size >= 8, "an int >= 8", self.size),
            ("crop", len(self.crop) == 2 and all(isinstance(c, int) for c in self.crop)
             and 1 <= self.crop[0] <= self.crop[1] <= self.material_size,
             f"(low, high) ints with 1 <= low <= high <= material_size ({self.material_size})", self.crop),
            ("exemplar_size", self.exemplar_size <= self.material_size,
             f"at most material_size ({self.material_size})", self.exemplar_size),
            ("n_exemplars", len(self.n_exemplars) == 2 and all(isinstance(n, int) for n in self.n_exemplars)
             and 1 <= self.n_exemplars[0] <= self.n_exemplars[1], "(low, high) ints with 1 <= low <= high",
             self.n_exemplars),
            ("no_exemplar", 0.0 <= self.no_exemplar <= 1.0, "a probability in [0, 1]", self.no_exemplar),
            ("classes", self.classes is None or (bool(self.classes) and set(self.classes) <= set(procedural.CLASSES)),
             f"None or a non-empty subset of {sorted(procedural.CLASSES)}", self.classes),
            ("parameter_spread", 0.0 <= self.parameter_spread <= 1.0, "a value in [0, 1]", self.parameter_spread),
            ("holdout", self.holdout in HOLDOUT_MODES, f"one of {HOLDOUT_MODES}", self.holdout),
            ("mix_alpha", 0.0 <= self.mix_alpha[0] <= self.mix_alpha[1] <= 1.0, "0 <= low <= high <= 1",
             self.mix_alpha),
            ("pool_size", isinstance(self.pool_size, int) and self.pool_size >= 0, "an int >= 0", self.pool_size),
            ("exposure", 0.0 < self.exposure[0] <= self.exposure[1], "0 < low <= high", self.exposure),
            ("white_balance", self.white_balance >= 0.0, "a std >= 0", self.white_balance),
            ("noise_median", self.noise_median >= 0.0, "a std >= 0", self.noise_median),
            ("noise_log_std", self.noise_log_std >= 0.0, "a std >= 0", self.noise_log_std),
            ("seed", isinstance(self.seed, int) and self.seed >= 0, "an int >= 0", self.seed),
            ("backend", self.backend in BACKENDS, f"one of {BACKENDS}", self.backend),
            ("ambient", isinstance(self.ambient, dict), "a dict of AmbientConfig fields", self.ambient),
        ], owner="LargeScaleConfig")
        _ = self.ambient_config  # validates the overrides

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LargeScaleConfig:
        """Build from a dict (e.g. parsed JSON; lists become tuples); unknown keys raise a ``ValueError``."""
        return from_dict(cls, {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    @property
    def ambient_config(self) -> AmbientConfig:
        """The environment sampler's settings (its defaults with the ``ambient`` overrides)."""
        return AmbientConfig.from_dict(dict(self.ambient))


@dataclass
class LargeScaleBatch:
    """One batch of :class:`LargeScaleData`."""

    photo: torch.Tensor  #: (B, 3, S, S) ambient-lit photo of the crop, linear (decoded 8-bit sRGB)
    exemplars: torch.Tensor  #: (B, E, 13, s, s) exemplar_input of the exemplar patches (E may be 0)
    maps: torch.Tensor  #: (B, 10, S, S) the crop's maps (the target)
    exemplar_maps: torch.Tensor  #: (B, E, 10, s, s) the exemplar patches' maps
    materials: list[dict[str, Any]]  #: per sample: the two materials, alpha, crop, exemplar positions, camera
    index: int  #: batch index in the stream (-1 outside a stream)
    seconds: dict[str, float] = field(default_factory=dict)  #: wall time of materials, crops, photo, exemplars

    @property
    def n_exemplars(self) -> int:
        """E, the exemplars per sample."""
        return int(self.exemplars.shape[1])


class LargeScaleData:
    """The stream of :class:`LargeScaleBatch` (see the module docstring).

    Args:
        config: a :class:`LargeScaleConfig`, a dict of its fields, or None for the defaults.
        **overrides: fields replacing those of ``config``.
    """

    def __init__(self, config: LargeScaleConfig | dict[str, Any] | None = None, **overrides: Any) -> None:
        base = config if isinstance(config, dict) else dataclasses.asdict(config or LargeScaleConfig())
        self.config = LargeScaleConfig.from_dict({**base, **overrides})
        self._classes = tuple(self.config.classes or procedural.CLASSES)
        self._ambient = self.config.ambient_config
        self._pool: dict[int, torch.Tensor] = {}  # pool members made so far, by pool id

    def batch(self, index: int) -> LargeScaleBatch:
        """Batch ``index`` (>= 0) of the stream: a pure function of ``(config.seed, index)``."""
        if not (isinstance(index, int) and index >= 0):
            raise ValueError(f"index: expected an int >= 0, got {index!r}")
        gen = batch_generator(self.config.seed, index)
        return self.make(self.config.batch_size, self._count(gen), gen, index)

    def exemplar_count(self, index: int) -> int:
        """E of batch ``index`` (its first draws), without making the batch."""
        return self._count(batch_generator(self.config.seed, index))

    def _count(self, gen: torch.Generator) -> int:
        lo, hi = self.config.n_exemplars
        none = bool(torch.rand(1, generator=gen) < self.config.no_exemplar)
        n = int(torch.randint(lo, hi + 1, (1,), generator=gen))
        return 0 if none else n

    # --- materials ---

    def _spec(self, gen: torch.Generator) -> dict[str, Any]:
        """A procedural material: class, parameters (held-out rule applied) and generator seed."""
        cls = self._classes[int(torch.randint(len(self._classes), (1,), generator=gen))]
        params = procedural.sample_parameters(cls, gen, spread=self.config.parameter_spread)
        params = apply_holdout(cls, params, self.config.holdout)
        return {"class": cls, "params": params, "seed": int(torch.randint(2**31 - 1, (1,), generator=gen))}

    def _generate(self, spec: dict[str, Any]) -> torch.Tensor:
        maps = procedural.generate(spec["class"], spec["seed"], self.config.material_size, **spec["params"])
        if not bool(torch.isfinite(maps).all()):
            raise ValueError(f"procedural.generate: expected finite maps, got NaN/Inf for {spec}")
        return maps

    def _pair(self, gen: torch.Generator,
              window: int | None) -> tuple[torch.Tensor, torch.Tensor, list[dict[str, Any]]]:
        """Two distinct materials ``(10, M, M)`` (pool members, or fresh when ``window`` is None) and their specs."""
        if window is None:
            specs = [self._spec(gen), self._spec(gen)]
            return self._generate(specs[0]), self._generate(specs[1]), specs
        pool = self.config.pool_size
        a = int(torch.randint(pool, (1,), generator=gen))
        b = (a + 1 + int(torch.randint(pool - 1, (1,), generator=gen))) % pool if pool > 1 else a
        out, specs = [], []
        for pool_id in (window + a, window + b):
            spec = {**self._spec(material_generator(self.config.seed, pool_id)), "pool_id": pool_id}
            if pool_id not in self._pool:
                self._pool[pool_id] = self._generate(spec)
            out.append(self._pool[pool_id])
            specs.append(spec)
        return out[0], out[1], specs

    # --- batches ---

    def make(self, batch: int, n_exemplars: int, gen: torch.Generator, index: int = -1) -> LargeScaleBatch:
        """A batch of ``batch`` samples with ``n_exemplars`` exemplars each, every draw from ``gen``.

        Args:
            batch: B >= 1.
            n_exemplars: E >= 0.
            gen: source of every random choice.
            index: the batch index in the stream: with ``pool_size > 0`` the materials are drawn
                among the pool ids ``[index * pool_refresh, ... + pool_size)``; -1: fresh materials.
        """
        if not (isinstance(batch, int) and batch >= 1):
            raise ValueError(f"batch: expected an int >= 1, got {batch!r}")
        if not (isinstance(n_exemplars, int) and n_exemplars >= 0):
            raise ValueError(f"n_exemplars: expected an int >= 0, got {n_exemplars!r}")
        cfg = self.config
        marks = [time.perf_counter()]
        window = None
        if index >= 0 and cfg.pool_size > 0:
            window = index * cfg.pool_refresh
            for key in [k for k in self._pool if k < window]:  # members that left the pool
                del self._pool[key]
        size, ex, big = cfg.size, cfg.exemplar_size, cfg.material_size
        log_lo, log_hi = math.log(cfg.crop[0]), math.log(cfg.crop[1])
        crops, patches, info = [], [], []
        for _ in range(batch):
            a, b, specs = self._pair(gen, window)
            alpha = cfg.mix_alpha[0] + (cfg.mix_alpha[1] - cfg.mix_alpha[0]) * float(
                torch.rand(1, generator=gen, dtype=torch.float64))
            side = min(cfg.crop[1], max(cfg.crop[0], round(math.exp(log_lo + (log_hi - log_lo) * float(
                torch.rand(1, generator=gen, dtype=torch.float64))))))
            y, x = (int(v) for v in torch.randint(big - side + 1, (2,), generator=gen))
            corners = torch.randint(big - ex + 1, (n_exemplars, 2), generator=gen).tolist()

            crops.append(augment.transform_maps(_blend(a, b, alpha, y, x, side), scale=size / side, out_size=size))
            patches.append(torch.cat([_blend(a, b, alpha, t, l, ex) for t, l in corners]) if corners
                           else torch.zeros(0, M.NUM_CHANNELS, ex, ex))
            info.append({"materials": specs, "alpha": alpha, "crop": {"top": y, "left": x, "side": side},
                         "exemplars": [{"top": t, "left": l} for t, l in corners]})
        marks.append(time.perf_counter())
        maps = torch.cat(crops).contiguous()
        exemplar_maps = torch.stack(patches)
        env = sample_environment(batch, cfg.n_lights, generator=gen, config=self._ambient)
        radiance = render_environment(maps, env, backend=cfg.backend)
        photo, settings = camera(radiance, env, gen, exposure=cfg.exposure, white_balance=cfg.white_balance,
                                 noise_median=cfg.noise_median, noise_log_std=cfg.noise_log_std)
        marks.append(time.perf_counter())
        exemplars = exemplar_input(exemplar_maps, generator=gen)
        marks.append(time.perf_counter())
        for d, g, s in zip(info, settings["gains"].tolist(), settings["noise_std"].tolist()):
            d["camera"] = {"gains": g, "noise_std": s}
        seconds = {k: t1 - t0 for k, t0, t1 in zip(("materials", "photo", "exemplars"), marks, marks[1:])}
        return LargeScaleBatch(photo=photo, exemplars=exemplars, maps=maps, exemplar_maps=exemplar_maps,
                               materials=info, index=index, seconds=seconds)


def _blend(a: torch.Tensor, b: torch.Tensor, alpha: float, top: int, left: int, width: int) -> torch.Tensor:
    """``(1, 10, width, width)``: the blend of materials ``a`` and ``b`` on one window (mixing is pointwise)."""
    win = (slice(None), slice(top, top + width), slice(left, left + width))
    return augment.mix(a[win][None], b[win][None], alpha)


@dataclass(frozen=True)
class LargeScaleHeldOut(CachedSet):
    """The fixed held-out set of the large-scale network (validation): ``load()`` returns its tensors.

    Sample ``m`` blends two fresh materials of class ``CLASS_ORDER[m % 9]`` (of :mod:`mi_svbrdf.data.heldout`)
    drawn with ``holdout="test"`` (only the held-out parameter slices), and is a pure function of
    ``(seed, m)`` and the settings: a set of 8 is the prefix of a set of 16. ``E = n_exemplars`` for
    every sample. Cached as ``.pt`` under ``cache_dir`` (atomic write), keyed by every setting.
    """

    kind: ClassVar[str] = "heldout"
    label: ClassVar[str] = "held-out large-scale set"
    json_info: ClassVar[bool] = True

    size: int = 128  #: S, side of the photos and maps
    materials: int = 16  #: number of samples (classes in turn), >= 1
    n_exemplars: int = 2  #: E, exemplars per sample, >= 0
    data: dict[str, Any] = field(default_factory=dict)  #: LargeScaleConfig overrides (sizes, camera, ...)
    seed: int = HELD_OUT_SEED  #: sample m draws from SeedSequence([seed, tag, m]); >= 1000 (0-999 are training seeds)
    cache: bool = True  #: keep the tensors in cache_dir
    cache_dir: str | None = None  #: None: ~/.cache/mi_svbrdf/heldout (cached_set.default_cache_dir)

    def __post_init__(self) -> None:
        check_fields([
            ("materials", isinstance(self.materials, int) and self.materials >= 1, "an int >= 1", self.materials),
            ("n_exemplars", isinstance(self.n_exemplars, int) and self.n_exemplars >= 0, "an int >= 0",
             self.n_exemplars),
            ("seed", isinstance(self.seed, int) and self.seed >= 1000, "an int >= 1000 (0-999 are training seeds)",
             self.seed),
            ("data", isinstance(self.data, dict) and not set(HELD_OUT_FIXED) & set(self.data),
             f"a dict of LargeScaleConfig fields other than {', '.join(HELD_OUT_FIXED)}", self.data),
        ], owner="LargeScaleHeldOut")
        self.data_config(CLASS_ORDER[0])  # validates the overrides

    @classmethod
    def for_training(cls, overrides: dict[str, Any], **fields: Any) -> LargeScaleHeldOut:
        """The held-out set matching a training stream's :class:`LargeScaleConfig` ``overrides``: their sizes,
        lights and camera, without what the held-out set fixes itself or what only a stream uses
        (:data:`STREAM_ONLY`); ``fields``: the set's own (size, materials, n_exemplars ...)."""
        return cls(data={k: v for k, v in overrides.items() if k not in STREAM_ONLY}, **fields)

    def data_config(self, cls: str) -> LargeScaleConfig:
        """The :class:`LargeScaleConfig` making the samples of class ``cls``."""
        return LargeScaleConfig.from_dict({**self.data, "size": self.size, "batch_size": 1, "classes": (cls,),
                                           "holdout": "test", "pool_size": 0, "seed": self.seed})

    def key_extras(self) -> dict[str, Any]:
        """The construction's version, the held-out ranges, torch's version and the resolved data config."""
        return {"version": HELD_OUT_VERSION, "ranges": HELD_OUT_RANGES, "torch": torch.__version__.split("+")[0],
                "config": dataclasses.asdict(self.data_config(CLASS_ORDER[0]))}

    def file_name(self, key: str) -> str:
        """``heldout_large_SIZEpx_Mm_Ee_KEY.pt``."""
        return f"heldout_large_{self.size}px_{self.materials}m_{self.n_exemplars}e_{key}.pt"

    def sample(self, m: int) -> LargeScaleBatch:
        """Sample ``m`` (>= 0) alone, a batch of one."""
        if not (isinstance(m, int) and m >= 0):
            raise ValueError(f"m: expected an int >= 0, got {m!r}")
        cls = CLASS_ORDER[m % len(CLASS_ORDER)]
        state = np.random.SeedSequence([self.seed, _HELD_OUT_TAG, m]).generate_state(1, dtype=np.uint64)[0]
        gen = torch.Generator().manual_seed(int(state))
        return LargeScaleData(self.data_config(cls)).make(1, self.n_exemplars, gen)

    def build(self, progress: bool) -> dict[str, Any]:
        """The samples stacked: maps, photos, exemplars and their maps, ``info`` as JSON text."""
        start = time.perf_counter()
        parts = [self.sample(m) for m in tqdm(range(self.materials), desc="held-out large-scale set",
                                              disable=not progress)]
        return {"maps": torch.cat([p.maps for p in parts]), "photo": torch.cat([p.photo for p in parts]),
                "exemplars": torch.cat([p.exemplars for p in parts]),
                "exemplar_maps": torch.cat([p.exemplar_maps for p in parts]),
                "info": json.dumps([p.materials[0] for p in parts]), "seconds": time.perf_counter() - start}

    def load(self, progress: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(maps (M, 10, S, S), photo (M, 3, S, S), exemplars (M, E, 13, s, s))``, identical at every call."""
        data = self.tensors(progress)
        return data["maps"], data["photo"], data["exemplars"]

