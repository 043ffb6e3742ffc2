"""The held-out large-scale benchmark and the exemplar-influence check of the by-example net (thesis ch. 5, Fig. 5.6-5.7).

**Surfaces** (:func:`load_surfaces`). ``surfaces`` procedural surfaces of the held-out parameter slices
(:mod:`mi_svbrdf.data.parameter_split`, ``holdout="test"``: training never draws them), each the blend of two
materials of one class (classes in turn, :data:`~mi_svbrdf.data.heldout.CLASS_ORDER`), made by
:class:`~mi_svbrdf.data.large_scale.LargeScaleHeldOut` with its own seed :data:`LARGE_BENCH_SEED` (not the
validation set's): generated at ``material_size`` = 2048² texels (the thesis's), photographed whole under a
held-out ambient environment (:func:`~mi_svbrdf.core.ambient.sample_environment` drawn from the surface's own
generator) through the training camera (:func:`~mi_svbrdf.data.large_scale.camera`: white balance, exposure,
noise, 8-bit sRGB; lights and camera settings are the net's training data's), with ``n_exemplars`` = 2
exemplars cut at random places of the same surface. Cached under ``~/.cache/mi_svbrdf/heldout/`` as the other
held-out sets (:func:`~mi_svbrdf.data.cached_set.load_or_build`, atomic write).

**Scale** (:func:`surface_scale`). The procedural materials are defined on the plane: their features
(tile counts, ring frequencies, stones ...) are fractions of the material, whatever its texel count, so what
the net learnt is a *fraction of the material per photo pixel*, not a texel density. Training (compact
preset) shows a crop of ``c`` in 128-256 texels of a 512² material on a tile of 128 px: the whole material
would span ``512 * 128 / c`` = 256-512 px. The benchmark photographs the 2048² surface whole at
``photo_size = train.material_size * tile / train.crop[0]`` = **512 px** (the end of that range where a
training crop is 1 texel per pixel; every photo pixel averages 4 x 4 texels: the antialiased resize of
training's crops), i.e. 4 x 4 tile widths, 7 x 7 tiles of 128 px at overlap 64. The exemplars cover what
training's do, 1/8 of the material's side (64 of 512 texels): **256² patches** of the 2048² surface
(``exemplar_size * material_size / train.material_size``), resized (antialiased, normals renormalised) to
the net's 64 px. With the full preset's data (2048² materials, crops 512-1024, tiles 512, exemplars 256)
the same rules give the thesis's setting: a 2048 px photo and 256 px exemplars, no resize. (A 1024 px
photo of the 2048² surface would match training's texels per pixel, but its features would be twice the
largest the net saw.)

**Methods** (:func:`make_methods`), each on the whole photo, tile by tile with the same tiling
(:func:`~mi_svbrdf.nets.tiling.tiled_predict`, the net's training tile, overlap half a tile):

* ``large``: the large-scale net with the surface's exemplars (:func:`~mi_svbrdf.nets.tiling.predict_large_scale`);
* ``no_exemplar``: the same net without exemplars (the baseline of Fig. 5.7);
* ``single``: the bundled single-image net (trained on *flash* photos: the thesis's comparison with the
  wrong capture model) on the same tiles;
* ``trivial``: the photo as diffuse (:func:`ambient_trivial`, the ambient counterpart of
  :func:`mi_svbrdf.eval.baseline.trivial_baseline`, with its flat normal, roughness and specular).

**Figures** (:func:`large_scale_benchmark`): per method, the map RMSEs and the re-rendering RMSE of
:func:`mi_svbrdf.core.metrics.evaluate_maps` (maps in the thesis's domains, re-rendered under the fixed novel
evaluation lights, as displayed), averaged over the surfaces; the seam ratio of ``large``
(:func:`~mi_svbrdf.nets.tiling.seam_ratio`, ~1: no seam); :func:`exemplar_influence`. :func:`large_scale_table`,
:func:`plot_surface` and :func:`write_large_scale_report` make the table and the figure.

**Exemplar influence** (Fig. 5.6, :func:`exemplar_influence`): the same photo with the surface's own
exemplars whose roughness map is replaced by a constant, low (shiny, 0.15) then high (rough, 0.75). Only the
gloss cue changes (relief, colours and the layout of the patches stay; the exemplars' render channels are
recomputed), so a change of the predicted roughness is the exemplars' doing; exemplars cut from another
material would change colour and relief too and confound the check. It holds when the mean predicted
roughness is lower with the shiny exemplars.

Run it with ``python -m mi_svbrdf.cli.bundle CHECKPOINT --dry-run --report OUT`` (bundling a large net measures
it and records it in the manifest).

Examples:
    >>> from mi_svbrdf.data.large_scale import LargeScaleConfig
    >>> scale = surface_scale(LargeScaleConfig(size=128, exemplar_size=64), material_size=2048)
    >>> scale["photo_size"], scale["exemplar_cut"], scale["training_surface_px"]
    (512, 256, [256, 512])
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.metrics import METRIC_KEYS, EvalLights, display, eval_lights, evaluate_maps, rerender
from mi_svbrdf.core.progress import tqdm
from mi_svbrdf.core.settings import check_fields, from_dict
from mi_svbrdf.data import augment
from mi_svbrdf.data.heldout import CLASS_ORDER
from mi_svbrdf.data.large_scale import STREAM_ONLY, LargeScaleConfig, LargeScaleHeldOut
from mi_svbrdf.eval.baseline import BASELINE_ROUGHNESS, BASELINE_SPECULAR
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.material_io import srgb_encode
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.network import NetConfig
from mi_svbrdf.nets.tiling import plan_tiles, predict_large_scale, seam_ratio, tiled_predict

__all__ = ["BENCH_VERSION", "LARGE_BENCH_SEED", "METHODS", "LargeBenchConfig", "LargeScaleBenchmark", "LargeSurfaces",
           "Method", "ambient_trivial", "exemplar_influence", "heldout_set", "large_scale_benchmark", "load_surfaces",
           "make_methods", "large_scale_table", "plot_surface", "score_methods", "surface_scale",
           "training_data_config", "write_large_scale_report"]

#: Seed of the benchmark's surfaces (training seeds are 0-999; the large-scale validation set and the flash
#: benchmark use HELD_OUT_SEED = 2026_1122, the foreign set 2026_1207).
LARGE_BENCH_SEED = 2026_1216
#: Version of the benchmark's construction (recorded with its figures).
BENCH_VERSION = 1
#: The methods, by key, with the label of the table.
METHODS: dict[str, str] = {"large": "large-scale net + exemplars", "no_exemplar": "same net, no exemplar",
                           "single": "single-image flash net on tiles", "trivial": "trivial (photo as diffuse)"}
#: Scores of the table, in order (keys of :func:`mi_svbrdf.core.metrics.evaluate_maps`).
TABLE_KEYS = ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_render", "ssim_render")
#: Roughness of the shiny and the rough exemplars of :func:`exemplar_influence` (both inside every dielectric
#: class's range but plastic's top, 0.75).
INFLUENCE_ROUGHNESS = (0.15, 0.75)


@dataclass(frozen=True)
class LargeBenchConfig:
    """Settings of :func:`large_scale_benchmark`; :meth:`from_dict` rejects unknown keys."""

    surfaces: int = 4  #: held-out surfaces (classes in turn: paint, plastic, leather, metal, ...), >= 1
    material_size: int = 2048  #: texels of the generated surfaces (the thesis's 2048), >= 8
    photo_size: int | None = None  #: photo side in px (None: surface_scale's, 512 for the compact net), <= material_size
    n_exemplars: int = 2  #: exemplars cut from each surface, >= 1
    tile: int | None = None  #: tile side (None: the net's training tile, config.resolution)
    overlap: int | None = None  #: minimum tile overlap (None: half a tile)
    methods: tuple[str, ...] = tuple(METHODS)  #: methods to score, keys of METHODS
    influence: tuple[float, float] | None = INFLUENCE_ROUGHNESS  #: (shiny, rough) exemplar roughness; None: no check
    figure_surface: int = 0  #: the surface whose maps the figure shows (kept in memory), in [0, surfaces)
    seed: int = LARGE_BENCH_SEED  #: seed of the surfaces, >= 1000 (0-999 are training seeds)
    cache: bool = True  #: keep the surfaces in cache_dir
    cache_dir: str | None = None  #: None: ~/.cache/mi_svbrdf/heldout (default_cache_dir)
    progress: bool = True  #: a progress bar over surfaces and methods

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", tuple(self.methods))
        if self.influence is not None:
            object.__setattr__(self, "influence", tuple(self.influence))
        positive = ("surfaces", "n_exemplars")
        check_fields([
            *((name, isinstance(getattr(self, name), int) and getattr(self, name) >= 1, "an int >= 1",
               getattr(self, name)) for name in positive),
            ("material_size", isinstance(self.material_size, int) and self.material_size >= 8, "an int >= 8",
             self.material_size),
            ("photo_size", self.photo_size is None or (isinstance(self.photo_size, int)
                                                       and 8 <= self.photo_size <= self.material_size),
             f"None or an int in [8, material_size = {self.material_size}]", self.photo_size),
            ("tile", self.tile is None or (isinstance(self.tile, int) and self.tile >= 1), "None or an int >= 1",
             self.tile),
            ("overlap", self.overlap is None or (isinstance(self.overlap, int) and 0 <= self.overlap
                                                 and (self.tile is None or self.overlap < self.tile)),
             "None or an int in [0, tile)", self.overlap),
            ("methods", bool(self.methods) and all(m in METHODS for m in self.methods)
             and len(set(self.methods)) == len(self.methods), f"distinct keys of {list(METHODS)}", self.methods),
            ("influence", self.influence is None or (len(self.influence) == 2
                                                     and 0.0 <= self.influence[0] < self.influence[1] <= 1.0),
             "None or (shiny, rough) with 0 <= shiny < rough <= 1", self.influence),
            ("figure_surface", isinstance(self.figure_surface, int) and 0 <= self.figure_surface < self.surfaces,
             f"an int in [0, surfaces = {self.surfaces})", self.figure_surface),
            ("seed", isinstance(self.seed, int) and self.seed >= 1000, "an int >= 1000 (0-999 are training seeds)",
             self.seed),
        ], owner="LargeBenchConfig")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LargeBenchConfig:
        """Build from a dict (lists become tuples); unknown keys raise a ``ValueError``."""
        return from_dict(cls, {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def training_data_config(net_config: NetConfig, simulator: dict[str, Any] | None = None) -> LargeScaleConfig:
    """The training stream's :class:`~mi_svbrdf.data.large_scale.LargeScaleConfig` of a large-scale net: its
    ``simulator`` overrides (a checkpoint's ``config["simulator"]``, a manifest entry's
    ``training["simulator"]``) with the net's exemplar size and its tile as ``size`` (as
    :func:`mi_svbrdf.nets.train.make_simulator` builds it)."""
    if net_config.kind != "large":
        raise ValueError(f"net_config.kind: expected 'large' (the large-scale net), got {net_config.kind!r}")
    data = {"exemplar_size": int(net_config.exemplar_size), **(simulator or {}), "size": int(net_config.resolution)}
    return LargeScaleConfig.from_dict(data)


def surface_scale(train: LargeScaleConfig, material_size: int, photo_size: int | None = None) -> dict[str, Any]:
    """The benchmark's photo and exemplar sizes for a net trained on ``train`` (module docstring, **Scale**).

    Args:
        train: the training data (:func:`training_data_config`: ``size`` is the net's tile, ``exemplar_size``
            its exemplar side).
        material_size: texels of the benchmark's surfaces.
        photo_size: override of the photo side (None: ``train.material_size * train.size / train.crop[0]``).

    Returns:
        JSON-ready ``{"photo_size", "exemplar_cut" (texels cut from the surface), "exemplar_size" (the net's),
        "texels_per_pixel" (of the surface in the photo), "training_surface_px" ([low, high] px a whole training
        material would span), "exemplar_fraction" (of the surface's side)}``.

    Raises:
        ValueError: a photo or exemplar larger than the surface, or an exemplar cut under 1 texel.
    """
    photo = round(train.material_size * train.size / train.crop[0]) if photo_size is None else int(photo_size)
    cut = round(train.exemplar_size * material_size / train.material_size)
    if not 8 <= photo <= material_size:
        raise ValueError(f"photo_size: expected 8 to material_size = {material_size} px (at least a texel per "
                         f"pixel), got {photo} (train.material_size {train.material_size} * tile {train.size} / "
                         f"crop {train.crop[0]} when derived)")
    if not 1 <= cut <= material_size:
        raise ValueError(f"material_size: expected exemplar cuts of 1 to {material_size} texels, got {cut} "
                         f"(exemplar_size {train.exemplar_size} * {material_size} / train.material_size "
                         f"{train.material_size})")
    low, high = (round(train.material_size * train.size / c) for c in (train.crop[1], train.crop[0]))
    return {"photo_size": photo, "exemplar_cut": cut, "exemplar_size": int(train.exemplar_size),
            "texels_per_pixel": round(material_size / photo, 4), "training_surface_px": [low, high],
            "exemplar_fraction": round(cut / material_size, 6)}


@dataclass
class LargeSurfaces:
    """The benchmark's surfaces (:func:`load_surfaces`), or any constructed set of the same shapes."""

    maps: torch.Tensor  #: (M, 10, P, P) ground truth at the photo's resolution
    photo: torch.Tensor  #: (M, 3, P, P) linear ambient-lit photos (decoded 8-bit sRGB)
    exemplars: torch.Tensor  #: (M, E, 10, s, s) exemplar maps at the net's exemplar size
    classes: list[str] = field(default_factory=list)  #: class of each surface
    info: dict[str, Any] = field(default_factory=dict)  #: JSON-ready description of the set

    def __post_init__(self) -> None:
        M.check_maps(self.maps, "maps")
        m, _, h, w = self.maps.shape
        if tuple(self.photo.shape) != (m, 3, h, w):
            raise ValueError(f"photo: expected shape {(m, 3, h, w)} (one photo per surface), got "
                             f"{tuple(self.photo.shape)}")
        if self.exemplars.dim() != 5 or self.exemplars.shape[0] != m or self.exemplars.shape[2] != M.NUM_CHANNELS:
            raise ValueError(f"exemplars: expected shape ({m}, E, 10, s, s), got {tuple(self.exemplars.shape)}")
        if not self.classes:
            self.classes = [CLASS_ORDER[i % len(CLASS_ORDER)] for i in range(m)]

    @property
    def count(self) -> int:
        """M, the number of surfaces."""
        return int(self.maps.shape[0])


def heldout_set(cfg: LargeBenchConfig, train: LargeScaleConfig) -> LargeScaleHeldOut:
    """The :class:`~mi_svbrdf.data.large_scale.LargeScaleHeldOut` making the surfaces of ``cfg`` for a net trained on
    ``train``: its lights and camera, the whole surface (crop = ``cfg.material_size``) resized to the photo size and
    exemplar cuts of :func:`surface_scale`, the seed ``cfg.seed`` (``.info()`` describes the materials)."""
    scale = surface_scale(train, cfg.material_size, cfg.photo_size)
    own = ("material_size", "crop", "exemplar_size")
    data = {k: v for k, v in dataclasses.asdict(train).items() if k not in STREAM_ONLY and k not in own}
    data.update(material_size=cfg.material_size, crop=(cfg.material_size, cfg.material_size),
                exemplar_size=scale["exemplar_cut"])
    return LargeScaleHeldOut(size=scale["photo_size"], materials=cfg.surfaces, n_exemplars=cfg.n_exemplars, data=data,
                             seed=cfg.seed, cache=cfg.cache, cache_dir=cfg.cache_dir)


def load_surfaces(cfg: LargeBenchConfig, train: LargeScaleConfig) -> LargeSurfaces:
    """The held-out surfaces of ``cfg`` for a net trained on ``train`` (module docstring), cached, deterministic.

    Surface ``m`` is a pure function of ``(cfg.seed, m)`` and the settings (a set of 4 is the prefix of a set
    of 9); its two materials have the held-out parameter slices (``holdout="test"``).
    """
    scale = surface_scale(train, cfg.material_size, cfg.photo_size)
    held = heldout_set(cfg, train)
    maps, photo, exemplars = held.load(cfg.progress)
    info = held.info(cfg.progress)
    s, cut = scale["exemplar_size"], scale["exemplar_cut"]
    ex = exemplars[:, :, :M.NUM_CHANNELS]
    if cut != s:  # the training exemplars' fraction of the surface at the net's exemplar size (antialiased)
        flat = ex.reshape(-1, M.NUM_CHANNELS, cut, cut)
        ex = augment.transform_maps(flat, scale=s / cut, out_size=s).reshape(*ex.shape[:2], M.NUM_CHANNELS, s, s)
    classes = [d["materials"][0]["class"] for d in info]
    description = {"name": "held-out large-scale surfaces", "surfaces": cfg.surfaces, "classes": classes,
                   "material_size": cfg.material_size, **scale, "n_exemplars": cfg.n_exemplars, "seed": cfg.seed,
                   "holdout": "test", "n_lights": train.n_lights, "exposure": list(train.exposure),
                   "version": BENCH_VERSION, "cache_key": held.key()}
    return LargeSurfaces(maps=maps, photo=photo, exemplars=ex.contiguous(), classes=classes, info=description)


def ambient_trivial(photo: torch.Tensor, level: float) -> torch.Tensor:
    """The trivial baseline on an ambient-lit photo: the photo as diffuse, everything else constant.

    Flat normal, roughness :data:`~mi_svbrdf.eval.baseline.BASELINE_ROUGHNESS`, specular
    :data:`~mi_svbrdf.eval.baseline.BASELINE_SPECULAR` (as :func:`mi_svbrdf.eval.baseline.trivial_baseline`), and
    diffuse ``photo / (level (1 - s))`` clipped to [0, 1]: a flat Lambertian sample of albedo ``d`` photographs as
    ``d (1 - s) level`` when a white one's level is ``level`` (the camera's exposure,
    :func:`mi_svbrdf.data.large_scale.camera`), so it gives back ``d`` at the right exposure.

    Args:
        photo: ``(B, 3, H, W)`` linear photo.
        level: the white Lambertian sample's level assumed (the benchmark: the geometric mean of the camera's
            exposure range: it does not know the photo's).

    Returns:
        ``(B, 10, H, W)`` maps.

    Examples:
        >>> maps = ambient_trivial(torch.full((1, 3, 4, 4), 0.48), level=0.5)
        >>> round(float(maps[0, 3, 0, 0]), 4), float(maps[0, 6, 0, 0])
        (1.0, 0.5)
    """
    if not isinstance(photo, torch.Tensor) or photo.dim() != 4 or photo.shape[1] != 3:
        shape = tuple(photo.shape) if isinstance(photo, torch.Tensor) else type(photo).__name__
        raise ValueError(f"photo: expected shape (B, 3, H, W), got {shape}")
    if not (isinstance(level, (int, float)) and level > 0):
        raise ValueError(f"level: expected a number > 0, got {level!r}")
    b, _, h, w = photo.shape
    out = M.constant_maps(b, h, w, roughness=BASELINE_ROUGHNESS, specular=BASELINE_SPECULAR, device=photo.device)
    out[:, M.SLICES["diffuse"]] = (photo.float() / (level * (1.0 - BASELINE_SPECULAR))).clamp(0.0, 1.0)
    return out


class Method(NamedTuple):
    """A method of the benchmark: ``predict(photo (1, 3, H, W), exemplars (E, 10, s, s)) -> maps (1, 10, H, W)``
    and the BRDF model of its maps (re-rendered with it)."""

    predict: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    distribution: str = "ggx"


def _tiling(net: nn.Module, cfg: LargeBenchConfig) -> tuple[int, int]:
    tile = int(net.config.resolution) if cfg.tile is None else cfg.tile
    overlap = tile // 2 if cfg.overlap is None else cfg.overlap
    if overlap >= tile:
        raise ValueError(f"overlap: expected an int in [0, tile) = [0, {tile}), got {overlap}")
    return tile, overlap


def make_methods(net: nn.Module, cfg: LargeBenchConfig, train: LargeScaleConfig, *, single: nn.Module | None = None,
                 distribution: str = "ggx", single_distribution: str = "ggx") -> tuple[dict[str, Method], list[str]]:
    """The methods of ``cfg.methods`` (module docstring), tiled as ``cfg`` says.

    Args:
        net: the large-scale net (eval mode).
        cfg: the settings.
        train: its training data (:func:`training_data_config`: the trivial baseline's exposure level).
        single: the single-image net; None: the bundled one (``mi_svbrdf.nets.inference.load("single")``), the
            method skipped with a note when none is bundled. A tile under its smallest input
            (``2**(depth - 1) + 1`` px) is enlarged to that, with a note.
        distribution: the BRDF model of ``net``'s maps.
        single_distribution: that of ``single``'s (ignored when the bundled net is loaded: its manifest's).

    Returns:
        ``({key: Method}, notes)``.
    """
    tile, overlap = _tiling(net, cfg)
    methods: dict[str, Method] = {}
    notes: list[str] = []
    for key in cfg.methods:
        if key == "large":
            methods[key] = Method(lambda p, e: predict_large_scale(net, p, e, tile=tile, overlap=overlap,
                                                                   progress=False), distribution)
        elif key == "no_exemplar":
            methods[key] = Method(lambda p, e: predict_large_scale(net, p, None, tile=tile, overlap=overlap,
                                                                   progress=False), distribution)
        elif key == "single":
            flash, model = single, single_distribution
            if flash is None:
                from mi_svbrdf.nets import inference
                from mi_svbrdf.nets import weights as bundled

                if "single" not in bundled.available():
                    notes.append("single: no bundled single-image net: method skipped")
                    continue
                flash, entry = inference.load("single")
                model = bundled.entry_distribution(entry)
            smallest = 2 ** (flash.config.depth - 1) + 1
            t, o = (tile, overlap) if tile >= smallest else (smallest, min(overlap * smallest // tile, smallest - 1))
            if t != tile:
                notes.append(f"single: tiles of {t} px (overlap {o}), the single-image net's smallest input "
                             f"(the large net's tile is {tile} px)")

            def run_single(p: torch.Tensor, e: torch.Tensor, _net: nn.Module = flash, _t: int = t,
                           _o: int = o) -> torch.Tensor:
                with torch.no_grad():
                    return tiled_predict(lambda x: _net(x), p, tile=_t, overlap=_o, progress=False)

            methods[key] = Method(run_single, model)
        elif key == "trivial":
            level = math.sqrt(train.exposure[0] * train.exposure[1])
            methods[key] = Method(lambda p, e, _level=level: ambient_trivial(p, _level), "ggx")
    return methods, notes


def score_methods(methods: dict[str, Method], surfaces: LargeSurfaces, *, lights: EvalLights | None = None,
                  keep: int | None = None, progress: bool = True,
                  extra: Callable[[str, int, torch.Tensor], dict[str, Any]] | None = None
                  ) -> tuple[list[dict[str, Any]], dict[str, torch.Tensor]]:
    """Run every method on every surface and score it against the ground truth.

    Args:
        methods: ``{key: Method}``.
        surfaces: the surfaces.
        lights: re-rendering lights (default :func:`~mi_svbrdf.core.metrics.eval_lights`).
        keep: the surface whose predicted maps are returned (None: none).
        progress: a progress bar.
        extra: ``extra(key, m, maps) -> dict`` merged into the row (e.g. seam ratios).

    Returns:
        ``(rows, kept)``: one row per method and surface (``method``, ``surface``, ``class``, ``seconds`` and
        every key of :func:`~mi_svbrdf.core.metrics.evaluate_maps`); ``kept``: ``{key: (1, 10, H, W)}``.
    """
    lights = lights or eval_lights()
    rows: list[dict[str, Any]] = []
    kept: dict[str, torch.Tensor] = {}
    bar = tqdm(total=surfaces.count * len(methods), desc="large-scale benchmark", disable=not progress)
    try:
        for m in range(surfaces.count):
            truth = surfaces.maps[m:m + 1].float()
            for key, method in methods.items():
                start = time.perf_counter()
                pred = method.predict(surfaces.photo[m:m + 1].float(), surfaces.exemplars[m].float())
                seconds = time.perf_counter() - start
                if not isinstance(pred, torch.Tensor) or tuple(pred.shape) != tuple(truth.shape):
                    got = tuple(pred.shape) if isinstance(pred, torch.Tensor) else type(pred).__name__
                    raise ValueError(f"methods[{key!r}]: expected maps of shape {tuple(truth.shape)}, got {got}")
                pred = pred.detach().float().cpu()
                row = {"method": key, "surface": m, "class": surfaces.classes[m], "seconds": round(seconds, 3),
                       **evaluate_maps(pred, truth, lights, distribution=method.distribution)}
                if extra is not None:
                    row.update(extra(key, m, pred))
                rows.append(row)
                if keep == m:
                    kept[key] = pred
                bar.update(1)
    finally:
        bar.close()
    return rows, kept


def _mean_roughness(maps: torch.Tensor) -> float:
    return float(M.roughness(maps).double().mean())


def exemplar_influence(net: nn.Module, surfaces: LargeSurfaces, *,
                       roughness: tuple[float, float] = INFLUENCE_ROUGHNESS, tile: int | None = None,
                       overlap: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Fig. 5.6's check: the same photo with shiny and with rough exemplars moves the predicted roughness down / up.

    Each surface's photo is run twice through ``net`` (tiled, :func:`~mi_svbrdf.nets.tiling.predict_large_scale`)
    with its own exemplars whose roughness map is replaced by ``roughness[0]`` (shiny), then ``roughness[1]``
    (rough); nothing else changes (module docstring).

    Args:
        net: a large-scale net (or any module with its ``config.resolution``, ``exemplar_features`` and
            ``forward(tile, features=...)``).
        surfaces: the photos and exemplars.
        roughness: ``(shiny, rough)``, ``0 <= shiny < rough <= 1``.
        tile: tile side (None: ``net.config.resolution``).
        overlap: minimum overlap (None: half a tile).
        progress: a progress bar.

    Returns:
        JSON-ready ``{"exemplar_roughness": {"shiny", "rough"}, "predicted": {"shiny", "rough"}`` (mean predicted
        roughness over surfaces), ``"truth"`` (mean true roughness), ``"per_surface"`` (class, shiny, rough,
        truth), ``"holds"`` (mean shiny < mean rough), ``"surfaces_holding"``, ``"surfaces"}``.

    Examples:
        >>> from mi_svbrdf.core.maps import constant_maps
        >>> from mi_svbrdf.nets.network import build_network, network_config
        >>> net = build_network(network_config("compact", "large", encoder_features=(8, 16, 16), last_features=8,
        ...                                    exemplar_features=(4, 8, 8), resolution=32, exemplar_size=16)).eval()
        >>> s = LargeSurfaces(constant_maps(1, 40, 40), torch.rand(1, 3, 40, 40), constant_maps(2, 16, 16)[None])
        >>> sorted(exemplar_influence(net, s, progress=False)["predicted"])
        ['rough', 'shiny']
    """
    shiny, rough = (float(v) for v in roughness)
    if not 0.0 <= shiny < rough <= 1.0:
        raise ValueError(f"roughness: expected (shiny, rough) with 0 <= shiny < rough <= 1, got {roughness!r}")
    if surfaces.exemplars.shape[1] == 0:
        raise ValueError("surfaces.exemplars: expected at least one exemplar per surface, got E = 0")
    tile = int(net.config.resolution) if tile is None else tile
    overlap = tile // 2 if overlap is None else overlap
    per_surface = []
    for m in tqdm(range(surfaces.count), desc="exemplar influence", disable=not progress):
        row: dict[str, Any] = {"surface": m, "class": surfaces.classes[m],
                               "truth": round(_mean_roughness(surfaces.maps[m:m + 1]), 5)}
        for name, value in (("shiny", shiny), ("rough", rough)):
            ex = surfaces.exemplars[m].float().clone()
            ex[:, M.SLICES["roughness"]] = value
            maps = predict_large_scale(net, surfaces.photo[m:m + 1].float(), ex, tile=tile, overlap=overlap,
                                       progress=False)
            row[name] = round(_mean_roughness(maps), 5)
        per_surface.append(row)
    mean = {k: sum(r[k] for r in per_surface) / len(per_surface) for k in ("shiny", "rough", "truth")}
    return {"exemplar_roughness": {"shiny": shiny, "rough": rough},
            "predicted": {"shiny": round(mean["shiny"], 5), "rough": round(mean["rough"], 5)},
            "truth": round(mean["truth"], 5), "per_surface": per_surface,
            "holds": bool(mean["shiny"] < mean["rough"]),
            "surfaces_holding": sum(r["shiny"] < r["rough"] for r in per_surface), "surfaces": len(per_surface)}


@dataclass
class LargeScaleBenchmark:
    """What :func:`large_scale_benchmark` returns."""

    summary: dict[str, Any]  #: JSON-ready figures (the manifest's ``accuracy``): set, methods, seams, influence ...
    rows: list[dict[str, Any]]  #: one per method and surface
    surfaces: LargeSurfaces  #: the surfaces measured
    figure_maps: dict[str, torch.Tensor]  #: method key -> (1, 10, P, P) maps of surface cfg.figure_surface


def large_scale_benchmark(net: nn.Module, cfg: LargeBenchConfig | None = None, *, train: LargeScaleConfig | None = None,
                          single: nn.Module | None = None, distribution: str = "ggx",
                          single_distribution: str = "ggx", surfaces: LargeSurfaces | None = None
                          ) -> LargeScaleBenchmark:
    """The held-out large-scale benchmark of a large-scale net (module docstring).

    Args:
        net: the large-scale net (put in eval mode here).
        cfg: the settings (default :class:`LargeBenchConfig`).
        train: the net's training data (default: :func:`training_data_config` of ``net.config`` without
            overrides: the compact preset's data).
        single: the single-image net of the ``single`` method (None: the bundled one).
        distribution: the BRDF model of ``net``'s maps.
        single_distribution: that of ``single``.
        surfaces: measure these instead of :func:`load_surfaces`' (constructed cases).

    Returns:
        A :class:`LargeScaleBenchmark`; its ``summary``: ``{"set", "methods": {key: {"label", metric means ...}},
        "seam_ratio": {map: mean over surfaces}, "seam_ratio_max", "exemplar_influence", "tiling", "notes",
        "seconds"}``.
    """
    cfg = cfg or LargeBenchConfig()
    net.eval()
    train = train or training_data_config(net.config)
    start = time.perf_counter()
    surfaces = surfaces if surfaces is not None else load_surfaces(cfg, train)
    if cfg.figure_surface >= surfaces.count:
        raise ValueError(f"cfg.figure_surface: expected an index below the {surfaces.count} surfaces, got "
                         f"{cfg.figure_surface}")
    methods, notes = make_methods(net, cfg, train, single=single, distribution=distribution,
                                  single_distribution=single_distribution)
    tile, overlap = _tiling(net, cfg)

    def seams(key: str, m: int, maps: torch.Tensor) -> dict[str, Any]:
        if key != "large":
            return {}
        return {f"seam_{k}": v for k, v in seam_ratio(maps, tile, overlap).items()}

    rows, kept = score_methods(methods, surfaces, keep=cfg.figure_surface, progress=cfg.progress, extra=seams)
    summary: dict[str, Any] = {"set": surfaces.info, "methods": {}}
    for key in methods:
        mine = [r for r in rows if r["method"] == key]
        means = {k: sum(float(r[k]) for r in mine) / len(mine) for k in (*METRIC_KEYS, "seconds")}
        summary["methods"][key] = {"label": METHODS[key], "distribution": methods[key].distribution, **means}
    seam_keys = sorted({k for r in rows for k in r if k.startswith("seam_")})
    summary["seam_ratio"] = {}
    for k in seam_keys:
        values = [r[k] for r in rows if k in r and math.isfinite(r[k])]
        summary["seam_ratio"][k[5:]] = sum(values) / len(values) if values else None
    finite = [r[k] for r in rows for k in seam_keys if k in r and math.isfinite(r[k])]
    summary["seam_ratio_max"] = max(finite) if finite else None
    plan = plan_tiles(*surfaces.maps.shape[-2:], tile=tile, overlap=overlap)
    summary["tiling"] = {"tile": tile, "overlap": overlap, "tiles": plan.count, "grid": list(plan.grid)}
    if cfg.influence is not None:
        summary["exemplar_influence"] = exemplar_influence(net, surfaces, roughness=cfg.influence, tile=tile,
                                                           overlap=overlap, progress=cfg.progress)
    summary["figure_surface"] = cfg.figure_surface
    summary["notes"] = notes
    summary["seconds"] = round(time.perf_counter() - start, 1)
    return LargeScaleBenchmark(summary=summary, rows=rows, surfaces=surfaces, figure_maps=kept)


def large_scale_table(summary: dict[str, Any]) -> str:
    """The benchmark's Markdown table: one row per method (means over the surfaces), then the seam ratio and the
    exemplar-influence figures, and a line describing the set."""
    keys = [k for k in TABLE_KEYS if all(k in row for row in summary["methods"].values())]
    lines = markdown_table(["method", *(k.replace("rmse_", "").replace("_", " ") for k in keys), "s / surface"],
                           [[row["label"], *(f"{row[k]:.4f}" for k in keys), f"{row['seconds']:.1f}"]
                            for row in summary["methods"].values()]).split("\n")
    s = summary["set"]
    cut, size = s.get("exemplar_cut", "?"), s.get("exemplar_size", "?")
    lines.append("")
    lines.append(f"{s.get('surfaces', '?')} held-out surfaces ({', '.join(s.get('classes', []))}) of "
                 f"{s.get('material_size', '?')}² texels, photographed at {s.get('photo_size', '?')}², "
                 f"{s.get('n_exemplars', '?')} exemplars of {cut}² texels each"
                 f"{f' resized to {size}²' if cut != size else ''}; map RMSE (normals as (n + 1) / 2), re-rendering RMSE under "
                 f"{eval_lights().count} novel lights (displayed); tiles {summary['tiling']['tile']} px, overlap "
                 f"{summary['tiling']['overlap']} ({summary['tiling']['tiles']} per photo).")
    if summary.get("seam_ratio"):
        ratios = ", ".join(f"{k} {v:.3f}" for k, v in summary["seam_ratio"].items() if v is not None)
        lines.append(f"Seam ratio of the large-scale net (1: no seam): {ratios} (max {summary['seam_ratio_max']:.3f}).")
    inf = summary.get("exemplar_influence")
    if inf:
        lines.append(f"Exemplar influence: mean predicted roughness {inf['predicted']['shiny']:.4f} with shiny "
                     f"exemplars (r = {inf['exemplar_roughness']['shiny']}) vs {inf['predicted']['rough']:.4f} with "
                     f"rough ones (r = {inf['exemplar_roughness']['rough']}), truth {inf['truth']:.4f}: "
                     f"{'holds' if inf['holds'] else 'does NOT hold'} (shiny < rough on {inf['surfaces_holding']} of "
                     f"{inf['surfaces']} surfaces).")
    for note in summary.get("notes", []):
        lines.append(f"Note: {note}")
    return "\n".join(lines)


def _small(maps: torch.Tensor, side: int) -> torch.Tensor:
    """``(1, 10, H, W)`` maps with the longest side at most ``side`` (antialiased; normals renormalised)."""
    h, w = maps.shape[-2:]
    scale = min(1.0, side / max(h, w))
    if scale == 1.0:
        return maps
    out = F.interpolate(maps.float(), size=(max(1, round(h * scale)), max(1, round(w * scale))), mode="bilinear",
                        align_corners=False, antialias=True)
    return M.normalize_normals(out)


def _panels(maps: torch.Tensor, distribution: str, lights: EvalLights) -> list[np.ndarray]:
    """The four maps as displayed (albedos sRGB-encoded) and a relit render under the first light: (h, w, 3)."""
    out = []
    for name, panel in M.preview_panels(maps).items():
        image = panel[0].permute(1, 2, 0).numpy()
        out.append(srgb_encode(image) if name in ("diffuse", "specular") else image)
    with torch.no_grad():
        relit = display(rerender(maps, lights, distribution=distribution))[0, 0]
    out.append(relit.permute(1, 2, 0).numpy())
    return out


def plot_surface(bench: LargeScaleBenchmark, path: str | os.PathLike, *, side: int = 192) -> None:
    """The figure: for surface ``figure_surface``, a row of the truth (photo | normal | diffuse | roughness |
    specular | relit under a novel light beside the viewer), then one row per method (its exemplars in the first
    column for the large-scale net), each titled with its re-rendering RMSE on that surface."""
    plt = pyplot()
    keys = list(bench.figure_maps)
    if not keys:
        raise ValueError("bench.figure_maps: expected the maps of at least one method, got none")
    m = _figure_index(bench)
    lights = eval_lights(1)
    truth = _small(bench.surfaces.maps[m:m + 1], side)
    h, w = truth.shape[-2:]
    photo = F.interpolate(bench.surfaces.photo[m:m + 1].float(), size=(h, w), mode="bilinear", align_corners=False,
                          antialias=True)[0].permute(1, 2, 0).numpy()
    models = {r["method"]: r for r in bench.rows if r["surface"] == m}
    titles = ["normal", "diffuse", "roughness", "specular", "relit (novel light)"]
    fig, axes = plt.subplots(len(keys) + 1, 6, figsize=(6 * 1.9, (len(keys) + 1) * 2.05), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    axes[0, 0].imshow(srgb_encode(photo))
    axes[0, 0].set_title(f"photo ({bench.surfaces.classes[m]})", fontsize=8)
    for j, image in enumerate(_panels(truth, "ggx", lights)):
        axes[0, j + 1].imshow(np.clip(image, 0.0, 1.0))
        axes[0, j + 1].set_title(f"truth: {titles[j]}", fontsize=8)
    for i, key in enumerate(keys, start=1):
        row = models[key]
        if key == "large":
            ex = bench.surfaces.exemplars[m]
            grid = np.concatenate([M.preview_panels(ex[e:e + 1].float())["diffuse"][0].permute(1, 2, 0).numpy()
                                   for e in range(ex.shape[0])], axis=1)
            axes[i, 0].imshow(srgb_encode(grid))
            axes[i, 0].set_title("exemplars (diffuse)", fontsize=8)
        maps = _small(bench.figure_maps[key], side)
        model = bench.summary["methods"].get(key, {}).get("distribution", "ggx")
        for j, image in enumerate(_panels(maps, model, lights)):
            axes[i, j + 1].imshow(np.clip(image, 0.0, 1.0))
        axes[i, 1].set_title(f"{METHODS[key]}\nrender RMSE {row['rmse_render']:.4f}", fontsize=8, loc="left")
    fig.tight_layout()
    save_figure(fig, Path(path), dpi=90)


def _figure_index(bench: LargeScaleBenchmark) -> int:
    """The surface whose maps ``bench.figure_maps`` holds (the config's ``figure_surface``)."""
    return int(bench.summary.get("figure_surface", 0))


def write_large_scale_report(bench: LargeScaleBenchmark, out: str | os.PathLike) -> list[Path]:
    """Write ``large_scale.json`` (summary and rows), ``large_scale.md`` (the table) and ``large_scale.png``
    (:func:`plot_surface`) to ``out`` (atomic writes); returns their paths."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "large_scale.json", folder / "large_scale.md", folder / "large_scale.png"]
    write_json(paths[0], {"summary": bench.summary, "rows": bench.rows})
    write_text(paths[1], "# Held-out large-scale benchmark\n\n" + large_scale_table(bench.summary) + "\n")
    plot_surface(bench, paths[2])
    return paths
