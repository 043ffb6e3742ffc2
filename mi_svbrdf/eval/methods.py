"""The evaluated methods behind one signature, with their wall time and peak memory.

Every method is a :class:`Method`: ``method(inputs (B, N, 3, H, W) linear photos, captures) ->
maps (B, 10, H, W)``, with what it did (optimiser steps, recoveries, stop reason, net used) in
``method.info`` after each call. :func:`make_method` builds one by name:

* ``"trivial"``: :func:`mi_svbrdf.eval.baseline.trivial_baseline` (the thesis's baseline) with
  the exact captures, or (``calibrated=False``) from the photos alone, as the nets see them;
* ``"single"``: the single-image net on image 0 (the fronto-parallel flash photo);
* ``"multi"``: the multi-image net on the N photos;
* ``"optimize"``: :func:`mi_svbrdf.optimize` on the N calibrated photos (8-bit sRGB encoding,
  as the held-out photos are) with a wall-time budget;
* ``"refine"``: the multi-image net's maps (the single-image net's when no multi weights are
  bundled) as the optimiser's start, same budget; the fit is pulled towards them with a weight
  falling as N grows (``OptimizeConfig.prior_weight / N**prior_falloff``, :mod:`mi_svbrdf.optim.fit`
  "Priors"), so that it does not end worse than the net where photos are few;
* ``"uncalibrated"``: the same start refined against the photos with each photo's camera, light
  and gain estimated from the photos themselves (:func:`mi_svbrdf.optim.refine.refine`: photo 0
  taken as a flash at its camera, photos that hold no measurement dropped), with a wall-time
  budget (``RefineConfig.budget_s``: the light search and the fit). It is **never given the
  captures**: it sees the photos as ``mi-svbrdf capture`` does, so it runs on uncalibrated sets
  (the strips) too.

Which methods read what: :data:`NEEDS_CALIBRATION` (optimize, refine) read every photo's camera and
light from the captures; trivial reads photo 0's (``calibrated=False``: the nominal flash); single,
multi and uncalibrated read the photos only.

The nets of a weights folder see the photos resized to their training resolution (as
:func:`mi_svbrdf.predict` does) and their maps are resized back to ``H x W`` (normals
renormalised); a net passed in (``net=``) sees the photos at their own size. The bundled nets run
as :func:`mi_svbrdf.predict` runs them, as a symmetry ensemble of 8 (:mod:`mi_svbrdf.nets.ensemble`;
``symmetries=1``: the net alone); a net passed in runs alone unless ``symmetries`` says otherwise.

**Measuring** (:func:`measure`): wall time with ``time.perf_counter`` around the call (net
loading is cached and done before, in :func:`make_method`; data loading is not timed). Peak
memory is the **peak resident set size above the RSS at the call's start**. On Linux the
kernel's high-water mark is reset to the current RSS before the call (``5`` written to
``/proc/self/clear_refs``) and read after it (``VmHWM`` in ``/proc/self/status``): exact,
however short the spike. Why not the two usual tools: ``tracemalloc`` only sees allocations
made through Python's allocator, not PyTorch's or Dr.Jit's native buffers (the bulk of a
method's memory), and the un-reset ``ru_maxrss`` is the process's high-water mark, so its delta
is 0 for every method that stays below an earlier method's peak. Where the reset is refused
(some sandboxes), the RSS is sampled every 2 ms from ``/proc/self/statm`` by a background
thread instead, which can miss a spike shorter than that. Both count memory freed by Python
but kept by the C allocator. Where ``/proc/self/statm`` is missing (not Linux) the
``ru_maxrss`` delta is reported.
"""
from __future__ import annotations

import math
import os
import resource
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from mi_svbrdf.core import maps as M
from mi_svbrdf.data.photo_setups import Captures
from mi_svbrdf.eval.baseline import trivial_baseline
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.io.photos import resize
from mi_svbrdf.nets.ensemble import DEFAULT_SYMMETRIES, SymmetryEnsemble
from mi_svbrdf.nets.inference import load, weights_folder
from mi_svbrdf.nets.weights import MANIFEST, available
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.refine import RefineConfig, refine

#: Method names, in report order.
METHODS: tuple[str, ...] = ("trivial", "single", "multi", "optimize", "refine", "uncalibrated")
#: Methods that need network weights.
NET_METHODS = ("single", "multi", "refine", "uncalibrated")
#: Methods that start from a net's maps: the multi-image net's, the single-image net's without multi weights.
START_NET_METHODS = ("refine", "uncalibrated")
#: Methods with a wall-time budget.
BUDGET_METHODS = ("optimize", "refine", "uncalibrated")
#: Methods that read every photo's camera and light from the captures (not run on uncalibrated sets).
NEEDS_CALIBRATION = ("optimize", "refine")

Fn = Callable[[torch.Tensor, Captures, dict[str, Any]], torch.Tensor]


def check_inputs(inputs: torch.Tensor, captures: Captures) -> None:
    """``inputs (B, N, 3, H, W)`` and ``captures`` of the same B, N, or a ``ValueError``."""
    if not isinstance(inputs, torch.Tensor) or inputs.dim() != 5 or inputs.shape[2] != 3:
        shape = tuple(inputs.shape) if isinstance(inputs, torch.Tensor) else type(inputs).__name__
        raise ValueError(f"inputs: expected shape (B, N, 3, H, W), got {shape}")
    if (captures.batch_size, captures.n_images) != tuple(inputs.shape[:2]):
        raise ValueError(f"captures: expected B, N = {tuple(inputs.shape[:2])} like inputs, "
                         f"got {(captures.batch_size, captures.n_images)}")


@dataclass
class Method:
    """A named method ``method(inputs, captures) -> maps``; ``info`` describes the last call."""

    name: str  #: one of METHODS
    fn: Fn  #: fn(inputs, captures, info) -> maps, filling info
    budget_s: float | None = None  #: wall-time budget (optimize, refine, uncalibrated), None otherwise
    info: dict[str, Any] = field(default_factory=dict)  #: what the last call did

    def __call__(self, inputs: torch.Tensor, captures: Captures) -> torch.Tensor:
        """Maps ``(B, 10, H, W)`` of ``inputs (B, N, 3, H, W)`` with ``captures`` (B, N)."""
        check_inputs(inputs, captures)
        self.info = {}
        return self.fn(inputs, captures, self.info)


def resize_maps(maps: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Antialiased bilinear resize of ``maps (B, 10, h, w)`` to ``size``; normals renormalised."""
    if tuple(maps.shape[-2:]) == tuple(size):
        return maps
    out = F.interpolate(maps, size=size, mode="bilinear", antialias=True, align_corners=False)
    n = M.normal(out)
    return M.make_maps(n / n.norm(dim=1, keepdim=True).clamp_min(1e-12), M.diffuse(out).clamp(0.0, 1.0),
                       M.roughness(out).clamp(0.0, 1.0), M.specular(out).clamp(0.0, 1.0))


def _net(kind: str, weights_dir: str | os.PathLike | None) -> tuple[torch.nn.Module, int]:
    net, entry = load(kind, weights_dir)
    return net, int(entry["net_config"]["resolution"])


def _run_net(net: torch.nn.Module, resolution: int | None, photos: torch.Tensor,
             batch: int | None = None) -> torch.Tensor:
    """``net`` on ``photos (B, N, 3, H, W)`` resized to ``resolution`` (None: as they are), ``batch``
    samples per call (None: all), maps resized back to ``H x W``."""
    h, w = photos.shape[-2:]
    x = photos.float().clamp_min(0.0)
    if resolution is not None:
        x = resize(x, resolution)
    step = batch or x.shape[0]
    with torch.inference_mode():
        maps = torch.cat([net(x[i:i + step]).float() for i in range(0, x.shape[0], step)])
    return resize_maps(maps.clone(), (h, w))


def _optimize_each(inputs: torch.Tensor, captures: Captures, config: OptimizeConfig, info: dict[str, Any],
                   init: torch.Tensor | None = None) -> torch.Tensor:
    """The optimiser on each sample in turn; ``info`` sums steps and recoveries, and records
    whether every recorded loss was finite (``losses_finite``)."""
    out = []
    info.update(steps=0, recoveries=0, stop_reason="", losses_finite=True)
    for b in range(inputs.shape[0]):
        spec, images = capture_from_simulator(captures, b, inputs, encoding="srgb8")
        res = optimize(spec, images, config=config, init_maps=None if init is None else init[b:b + 1])
        out.append(res.maps)
        info["steps"] += res.steps
        info["recoveries"] += res.recoveries
        info["stop_reason"] = res.stop_reason
        info["losses_finite"] &= all(math.isfinite(loss) for _, _, loss in res.history)
    return torch.cat(out)


def _refine_each(inputs: torch.Tensor, init: torch.Tensor, config: RefineConfig,
                 info: dict[str, Any]) -> torch.Tensor:
    """:func:`~mi_svbrdf.optim.refine.refine` of ``init (B, 10, H, W)`` against each sample's photos of
    ``inputs (B, N, 3, H, W)`` in turn (no captures). ``info`` sums steps, recoveries and the photos
    ``dropped``, counts the samples whose net maps were kept unfitted (``unfitted``: photo 0 unusable),
    records the last fit's stop reason (``"unfitted"`` when no fit ran) and whether every recorded loss
    was finite (``losses_finite``)."""
    out = []
    info.update(steps=0, recoveries=0, stop_reason="", losses_finite=True, dropped=0, unfitted=0)
    for b in range(inputs.shape[0]):
        res = refine(inputs[b], init[b:b + 1], config=config)
        out.append(res.maps.to(init.device))
        info["dropped"] += sum(1 for e in res.lights if not e.get("used"))
        if res.fit is None:
            info["unfitted"] += 1
            info["stop_reason"] = info["stop_reason"] or "unfitted"
            continue
        info["steps"] += res.fit.steps
        info["recoveries"] += res.fit.recoveries
        info["stop_reason"] = res.fit.stop_reason
        info["losses_finite"] &= all(math.isfinite(loss) for _, _, loss in res.fit.history)
    return torch.cat(out)


def available_nets(weights_dir: str | os.PathLike | None) -> list[str]:
    """The net kinds with weights in ``weights_dir`` (None: the bundled weights); [] when none."""
    folder = weights_folder(weights_dir)
    return available(folder) if (Path(folder) / MANIFEST).is_file() else []


def _check(name: str, weights_dir: str | os.PathLike | None, budget_s: float | None,
           net: torch.nn.Module | None) -> list[str]:
    """Validate :func:`make_method`'s arguments; returns the net kinds available to it."""
    if name not in METHODS:
        raise ValueError(f"name: expected one of {METHODS}, got {name!r}")
    if name in BUDGET_METHODS and not (budget_s is not None and budget_s > 0):
        raise ValueError(f"budget_s: expected seconds > 0 for {name!r}, got {budget_s!r}")
    if net is not None:
        if name not in ("single", "multi"):
            raise ValueError(f"net: expected only for 'single' or 'multi', got a net for {name!r}")
        return [name]
    nets = available_nets(weights_dir) if name in NET_METHODS else []
    if name in ("single", "multi") and name not in nets:
        raise ValueError(f"weights_dir: expected {name!r} network weights in {weights_dir or 'the bundled folder'}, "
                         f"got {nets or 'none'}")
    if name in START_NET_METHODS and not nets:
        raise ValueError(f"weights_dir: expected network weights for {name!r} in "
                         f"{weights_dir or 'the bundled folder'}, got none")
    return nets


def make_method(name: str, *, weights_dir: str | os.PathLike | None = None, budget_s: float | None = None,
                net: torch.nn.Module | None = None, batch: int | None = None, calibrated: bool = True,
                optimizer: dict[str, Any] | None = None, symmetries: int | None = None,
                refine_options: dict[str, Any] | None = None) -> Method:
    """The method ``name`` (see the module docstring), nets loaded now (not in the timed call).

    Args:
        name: one of :data:`METHODS`.
        weights_dir: folder with ``manifest.json`` and the nets' weights (None: bundled).
        budget_s: wall-time budget in seconds (required for optimize, refine and uncalibrated; uncalibrated:
            ``RefineConfig.budget_s``, the light search and the fit).
        net: single, multi: this network (in memory) instead of the weights folder's; it sees the
            photos at their own size.
        batch: single, multi: samples per network call (None: all at once).
        calibrated: trivial: False ignores the captures (each sample's photo 0 under the nominal
            flash of :func:`~mi_svbrdf.eval.baseline.default_captures`: what the nets know).
        optimizer: optimize, refine: further :class:`~mi_svbrdf.optim.OptimizeConfig` settings
            (the method sets ``budget_s``, ``progress=False`` and, unless given, 100000 iterations);
            uncalibrated: further settings of its fit (``RefineConfig.optimizer``).
        symmetries: single, multi, refine, uncalibrated: the nets' symmetry ensemble
            (:mod:`mi_svbrdf.nets.ensemble`; 1: the net alone). None: as :func:`mi_svbrdf.predict` runs the
            bundled nets (8), and 1 for a net passed in (its own output, as training measures it).
        refine_options: uncalibrated: further :class:`~mi_svbrdf.optim.refine.RefineConfig` settings (the
            light search's grids, the fit's learning rate...); the method sets ``budget_s`` and
            ``progress=False``.

    Raises:
        ValueError: an unknown name, a missing budget, missing weights, or bad optimiser or refinement settings.
    """
    nets = _check(name, weights_dir, budget_s, net)
    count = symmetries if symmetries is not None else (1 if net is not None else DEFAULT_SYMMETRIES)
    if name not in BUDGET_METHODS:
        budget_s = None
    if name == "trivial":
        def fn(inputs: torch.Tensor, captures: Captures, info: dict[str, Any]) -> torch.Tensor:
            return trivial_baseline(inputs, captures) if calibrated else trivial_baseline(inputs)
    elif name in ("single", "multi"):
        res: int | None = None  # a net passed in sees the photos at their own size
        if net is None:
            net, res = _net(name, weights_dir)
        run = SymmetryEnsemble(net, count) if count > 1 else net

        def fn(inputs: torch.Tensor, captures: Captures, info: dict[str, Any]) -> torch.Tensor:
            info.update(net=name, symmetries=count)
            return _run_net(run, res, inputs[:, :1] if name == "single" else inputs, batch)
    elif name == "uncalibrated":
        options = dict(refine_options or {})
        refine_config = RefineConfig.from_dict({**options, "budget_s": float(budget_s), "progress": False,
                                                "optimizer": {**options.get("optimizer", {}), **(optimizer or {})}})
        kind = "multi" if "multi" in nets else "single"
        start_net, res = _net(kind, weights_dir)
        start = SymmetryEnsemble(start_net, count) if count > 1 else start_net

        def fn(inputs: torch.Tensor, captures: Captures, info: dict[str, Any]) -> torch.Tensor:
            del captures  # never read: each photo's light is estimated from the photos (optim.refine)
            init = _run_net(start, res, inputs if kind == "multi" else inputs[:, :1])
            maps = _refine_each(inputs, init, refine_config, info)
            info.update(net=kind, symmetries=count)
            return maps
    else:
        config = OptimizeConfig.from_dict({"iterations": 100_000, **(optimizer or {}), "budget_s": float(budget_s),
                                           "progress": False})
        if name == "optimize":
            def fn(inputs: torch.Tensor, captures: Captures, info: dict[str, Any]) -> torch.Tensor:
                return _optimize_each(inputs, captures, config, info)
        else:
            kind = "multi" if "multi" in nets else "single"
            start_net, res = _net(kind, weights_dir)
            start = SymmetryEnsemble(start_net, count) if count > 1 else start_net

            def fn(inputs: torch.Tensor, captures: Captures, info: dict[str, Any]) -> torch.Tensor:
                init = _run_net(start, res, inputs if kind == "multi" else inputs[:, :1])
                maps = _optimize_each(inputs, captures, config, info, init=init)
                info.update(net=kind, symmetries=count)
                return maps
    return Method(name=name, fn=fn, budget_s=budget_s)


def _rss_bytes() -> int | None:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def _maxrss_bytes() -> int:
    scale = 1 if sys.platform == "darwin" else 1024  # bytes on macOS, KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale


def _reset_high_water_mark() -> bool:
    """Reset the kernel's peak RSS of this process to its current RSS; False where refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _high_water_mark_bytes() -> int | None:
    """``VmHWM`` of ``/proc/self/status``: the peak RSS since the last reset, in bytes."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


@dataclass
class Measured:
    """One timed call of a method."""

    maps: torch.Tensor  #: (B, 10, H, W) the method's output
    seconds: float  #: wall time of the call
    peak_mb: float  #: peak memory above the start, MiB (see the module docstring)
    info: dict[str, Any]  #: method.info after the call


def measure(method: Method, inputs: torch.Tensor, captures: Captures, interval_s: float = 0.002) -> Measured:
    """Call ``method(inputs, captures)`` timing it and measuring its peak RSS (module docstring)."""
    start_rss = _rss_bytes()
    start_max = _maxrss_bytes()
    exact = start_rss is not None and _reset_high_water_mark() and _high_water_mark_bytes() is not None
    peak = [start_rss or 0]
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(interval_s):
            rss = _rss_bytes()
            if rss is not None and rss > peak[0]:
                peak[0] = rss

    thread = threading.Thread(target=sample, daemon=True) if start_rss is not None and not exact else None
    if thread:
        thread.start()
    t0 = time.perf_counter()
    try:
        maps = method(inputs, captures)
    finally:
        seconds = time.perf_counter() - t0
        stop.set()
        if thread:
            thread.join()
    if exact:
        peak_bytes = (_high_water_mark_bytes() or 0) - (start_rss or 0)
    elif start_rss is not None:
        end = _rss_bytes() or 0
        peak_bytes = max(peak[0], end) - start_rss
    else:
        peak_bytes = _maxrss_bytes() - start_max
    return Measured(maps=maps.detach(), seconds=seconds, peak_mb=max(peak_bytes, 0) / 2 ** 20,
                    info=dict(method.info))
