"""Real-style checks: the nets on the bundled example photos, and on clipped flash highlights.

Users photographing glossy materials (leather, varnished metal) with a phone found that the nets
bake the flash highlight into the diffuse map. Two checks put that in the evaluation report
(:func:`real_checks` writes the figures and ``real_checks.json``, :func:`real_checks_markdown`
the section):

**Example photos** (``f_real_examples.png``): the single-image net on ``example_flash.png``, the
multi-image net on the same photo alone and on ``example_view1..3.png`` (:mod:`mi_svbrdf.assets`),
one row per (net, input): the photo(s), then normal, diffuse, roughness, specular and a
re-rendering under a light the photos do not have (evaluation light 0 of
:func:`mi_svbrdf.core.metrics.eval_lights`: oblique, the viewer beside it). The examples are
renders of held-out materials (:mod:`mi_svbrdf.data.example_photos`), so their ground truth is
known: it is regenerated, a ground-truth row follows each material's predictions, and the table
gives each prediction's map and re-rendering RMSE (as :func:`mi_svbrdf.core.metrics.evaluate_maps`:
:func:`~mi_svbrdf.core.metrics.map_rmse`, :func:`~mi_svbrdf.core.metrics.rerender_rmse` under the 9
evaluation lights), with the calibrated trivial baseline (told the examples' exact captures)
for reference.

**Highlight leak** (``g_real_highlights.png``): the glossy materials of :data:`GLOSSY` (a glossy
held-out leather, a lacquered foreign anodised metal, a polished gold), each photographed once by
the capture simulator with the flash at the camera (:func:`highlight_photos`): the
``single_flash`` preset, camera centred, every perturbation off but the flash's offset from the
lens and the photo noise, and the flash **metered like a phone**: the intensity that puts the
median luminance of the (linear, unclipped) photo at :data:`METER_TARGET` (mid-grey), kept
inside the training's flash intensities; the specular highlight clips at 1 in the 8-bit photo.
The single net, the multi net (N = 1) and the calibrated trivial baseline see that photo;
:func:`highlight_leak` measures how much brighter each method's diffuse map is in the clipped
highlight than around it, next to the same ratio of the true diffuse map:

* mask ``H`` (:func:`highlight_mask`): the pixels where at least one channel of the linear photo
  is at the 8-bit maximum (``>= 1 - 1e-6``: clipped);
* outside ``O``: the pixels farther than ``r = max(1, round(W / 32))`` pixels (Chebyshev
  distance) from every pixel of ``H``, i.e. the complement of ``H`` dilated by a ``(2r + 1)^2``
  square (the highlight's unclipped halo is in neither);
* ``Y``: the luminance ``0.2126 R + 0.7152 G + 0.0722 B`` of the linear diffuse albedo;
* **leak** = ``mean_H(Y) / mean_O(Y)``; NaN when ``H`` or ``O`` is empty or ``mean_O(Y) <= 1e-6``;
* **relative leak** = leak(method) / leak(truth): 1.0 = no more highlight in the diffuse map than
  the true diffuse has there; the highlight baked in gives > 1.

Everything is deterministic: the materials, captures and noise come from fixed seeds
(:data:`SEED`) and the nets run in inference mode. The section's reading is computed from the
numbers (:func:`verdict`: a mean relative leak above :data:`BAKED` bakes the highlight in, below
:data:`DARKENED` darkens it).
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from mi_svbrdf.assets import EXAMPLE_FLASH, EXAMPLE_VIEWS
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import gamma_encode, luminance
from mi_svbrdf.core.metrics import EvalLights, display, eval_lights, map_rmse, rerender, rerender_rmse
from mi_svbrdf.data import procedural
from mi_svbrdf.data.example_photos import FLASH_MATERIAL, MULTI_MATERIAL
from mi_svbrdf.data.example_photos import SIZE as EXAMPLE_SIZE
from mi_svbrdf.data.foreign import foreign_material, training_ranges
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.data.parameter_split import apply_holdout
from mi_svbrdf.data.photo_setups import Captures, capture_config, photograph, render_captures, sample_captures
from mi_svbrdf.eval.methods import Method, available_nets, make_method, resize_maps
from mi_svbrdf.io.atomic import json_safe, write_json
from mi_svbrdf.io.figures import pyplot, save_figure
from mi_svbrdf.io.tables import markdown_table
from mi_svbrdf.nets.inference import load_inputs, weights_folder

#: Result file written by :func:`real_checks`.
JSON_NAME = "real_checks.json"
#: The example-photo panel.
EXAMPLES_PNG = "f_real_examples.png"
#: The highlight panel.
HIGHLIGHTS_PNG = "g_real_highlights.png"
#: The nets, in report order.
NETS = ("single", "multi")
#: Methods of the highlight check, in column order (the trivial baseline for reference).
LEAK_METHODS = ("single", "multi", "trivial")
#: Seed of the glossy materials, their captures and photo noise (training seeds are 0-999).
SEED = 2026_1215
#: Flash intensity before metering: the training's median (|N(10, s)| x exposure 1.5).
FLASH_INTENSITY = 15.0
#: Median luminance of the metered photo (linear mid-grey, a phone's averaging meter).
METER_TARGET = 0.18
#: Clipped: a photo channel at least this (the 8-bit maximum decodes to exactly 1).
CLIPPED = 1.0 - 1e-6
#: Mean relative leak above which a method "bakes the highlight into diffuse".
BAKED = 1.25
#: Mean relative leak below which a method "darkens the highlight in diffuse".
DARKENED = 0.8
#: Metrics of the example table: (key, header).
EXAMPLE_METRICS = (("rmse_normal", "normal"), ("rmse_diffuse", "diffuse"), ("rmse_roughness", "roughness"),
                   ("rmse_specular", "specular"), ("rmse_render", "render"))
#: Largest side of a figure cell in pixels (larger maps are shown downsampled).
CELL = 128
#: Colour of the highlight outline in the figures (cyan).
OUTLINE = (0.0, 1.0, 1.0)


# ----------------------------------------------------------------------------- the glossy materials
def _glossy_leather(size: int) -> torch.Tensor:
    """Held-out leather (grain in its held-out slice) with polished, glossy cell tops (roughness ~0.11)."""
    params = procedural.validate_parameters("leather", {"roughness": 0.2, "polish": 1.0, "value": 0.5,
                                                        "grain": 100.0, "wrinkles": 0.6})
    return procedural.generate_batch("leather", [SEED % 1000 + 1], size, [apply_holdout("leather", params, "test")])


def _lacquered_metal(size: int) -> torch.Tensor:
    """Foreign ``anodised_metal`` (dyed diffuse, tinted specular) under a lacquer: roughness x 0.3."""
    maps, _ = foreign_material("anodised_metal", size, torch.Generator().manual_seed(SEED + 2))
    return M.make_maps(M.normal(maps), M.diffuse(maps), M.roughness(maps) * 0.3, M.specular(maps))


def _polished_gold(size: int) -> torch.Tensor:
    """Polished, lightly brushed gold (roughness ~0.08) with tarnished patches (diffuse up to 0.05)."""
    params = {"palette": 3.0, "roughness": 0.08, "brushed": 0.3, "tarnish": 0.4, "scratch_density": 0.3}
    return procedural.generate_batch("metal", [SEED % 1000 + 3], size, [params])


@dataclass(frozen=True)
class Glossy:
    """A glossy material of the highlight check."""

    name: str  #: short name (table, figure)
    description: str  #: what it is
    make: Callable[[int], torch.Tensor]  #: size -> maps (1, 10, size, size)


#: The glossy materials of the highlight check, in row order.
GLOSSY: tuple[Glossy, ...] = (
    Glossy("glossy leather", "held-out leather (finest grain), polished cell tops, roughness ~0.11", _glossy_leather),
    Glossy("lacquered metal", "foreign anodised metal (dyed diffuse, tinted specular), roughness x 0.3",
           _lacquered_metal),
    Glossy("polished gold", "gold, roughness 0.08, tarnished patches (diffuse <= 0.05)", _polished_gold),
)


def highlight_captures(count: int) -> Captures:
    """``count`` flash-at-camera captures ``(count, 1)`` before metering: the ``single_flash`` preset with
    the flash intensity :data:`FLASH_INTENSITY`, the camera centred at 50 degrees FOV, no white balance,
    cone or FOV jitter; the flash's offset from the lens (up to 0.1) and the photo noise are drawn from
    :data:`SEED`."""
    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count: expected an int >= 1, got {count!r}")
    cfg = capture_config("single_flash", intensity_jitter=False, intensity=FLASH_INTENSITY, white_balance=False,
                         cone_exponent_jitter=False, cone_target_jitter=False, fov_jitter=False, view_offset=False)
    return sample_captures(count, 1, cfg, torch.Generator().manual_seed(SEED))


def highlight_photos(size: int) -> tuple[torch.Tensor, torch.Tensor, Captures]:
    """The :data:`GLOSSY` materials and their metered flash photos (module docstring).

    The flash is the only light, so the radiance scales with its intensity: the photo at
    :data:`FLASH_INTENSITY` is rendered once and scaled by ``k = I / FLASH_INTENSITY``, ``I`` the
    intensity putting its median luminance at :data:`METER_TARGET`, clamped to the training's flash
    intensities (:func:`mi_svbrdf.data.foreign.training_ranges`); the captures carry ``I``.

    Returns:
        ``(maps (G, 10, S, S), photos (G, 1, 3, S, S) linear, captures (G, 1))``, G = len(GLOSSY).
    """
    maps = torch.cat([g.make(size) for g in GLOSSY])
    captures = highlight_captures(len(GLOSSY))
    radiance = render_captures(maps, captures)
    median = luminance(radiance[:, 0]).flatten(1).median(dim=1).values.double()
    lo, hi = training_ranges()["flash_intensity"]
    intensity = (FLASH_INTENSITY * METER_TARGET / median.clamp_min(1e-9)).clamp(lo, hi)
    k = (intensity / FLASH_INTENSITY).float()
    captures = dataclasses.replace(captures, intensity=captures.intensity * k.view(-1, 1, 1))
    photos = photograph(radiance * k.view(-1, 1, 1, 1, 1), captures, torch.Generator().manual_seed(SEED + 1))
    return maps, photos, captures


# ----------------------------------------------------------------------------- the metric
def highlight_mask(photo: torch.Tensor) -> torch.Tensor:
    """Clipped pixels of linear photos ``(B, 3, H, W)``: ``(B, H, W)`` bool, a channel ``>=`` :data:`CLIPPED`."""
    if not isinstance(photo, torch.Tensor) or photo.dim() != 4 or photo.shape[1] != 3:
        shape = tuple(photo.shape) if isinstance(photo, torch.Tensor) else type(photo).__name__
        raise ValueError(f"photo: expected shape (B, 3, H, W), got {shape}")
    return (photo >= CLIPPED).any(dim=1)


def halo_radius(width: int) -> int:
    """``r = max(1, round(width / 32))``: pixels around the clipped highlight left out of "outside"."""
    return max(1, round(width / 32))


def highlight_leak(diffuse: torch.Tensor, mask: torch.Tensor, halo: int | None = None) -> torch.Tensor:
    """The highlight leak of diffuse maps (module docstring): ``mean_H(Y) / mean_O(Y)`` per sample.

    Args:
        diffuse: ``(B, 3, H, W)`` linear diffuse albedo.
        mask: ``(B, H, W)`` bool, the clipped highlight ``H`` (:func:`highlight_mask`).
        halo: ``r``, the dilation of ``H`` whose complement is ``O`` (None: :func:`halo_radius` of W).

    Returns:
        ``(B,)`` float64 leak ratios; NaN where ``H`` or ``O`` is empty or ``mean_O(Y) <= 1e-6``.
    """
    if not isinstance(diffuse, torch.Tensor) or diffuse.dim() != 4 or diffuse.shape[1] != 3:
        shape = tuple(diffuse.shape) if isinstance(diffuse, torch.Tensor) else type(diffuse).__name__
        raise ValueError(f"diffuse: expected shape (B, 3, H, W), got {shape}")
    want = (diffuse.shape[0], *diffuse.shape[2:])
    if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or tuple(mask.shape) != want:
        got = f"{tuple(mask.shape)} {mask.dtype}" if isinstance(mask, torch.Tensor) else type(mask).__name__
        raise ValueError(f"mask: expected a bool tensor of shape {want}, got {got}")
    r = halo_radius(diffuse.shape[-1]) if halo is None else halo
    if isinstance(r, bool) or not isinstance(r, int) or r < 0:
        raise ValueError(f"halo: expected None or an int >= 0, got {halo!r}")
    y = luminance(diffuse.double())
    inside = mask.double()
    near = F.max_pool2d(inside[:, None], 2 * r + 1, stride=1, padding=r)[:, 0] if r else inside
    outside = 1.0 - near
    n_in, n_out = inside.sum(dim=(1, 2)), outside.sum(dim=(1, 2))
    mean_in = (y * inside).sum(dim=(1, 2)) / n_in.clamp_min(1.0)
    mean_out = (y * outside).sum(dim=(1, 2)) / n_out.clamp_min(1.0)
    ok = (n_in > 0) & (n_out > 0) & (mean_out > 1e-6)
    return torch.where(ok, mean_in / mean_out.clamp_min(1e-6), torch.full_like(mean_in, math.nan))


def verdict(relative: float) -> str:
    """What a mean relative leak says (:data:`BAKED`, :data:`DARKENED`)."""
    if not math.isfinite(relative):
        return "could not be measured (no clipped highlight)"
    if relative > BAKED:
        return "bakes the highlight into diffuse"
    if relative < DARKENED:
        return "darkens the highlight in diffuse"
    return "keeps the highlight out of diffuse"


# ----------------------------------------------------------------------------- figures
def _cell(img: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """``(3, S, S)`` display values at most :data:`CELL` px, the outline of ``mask (S, S)`` drawn in."""
    x = img.detach().float().cpu().clamp(0.0, 1.0)[None]
    if x.shape[-1] > CELL:
        x = F.interpolate(x, size=(CELL, CELL), mode="bilinear", antialias=True, align_corners=False)
    if mask is not None:
        m = mask.float()[None, None]
        if m.shape[-1] != x.shape[-1]:
            m = (F.interpolate(m, size=x.shape[-2:], mode="area") > 0).float()
        edge = (m - -F.max_pool2d(-m, 3, stride=1, padding=1)) > 0  # mask minus its erosion
        x = torch.where(edge, torch.tensor(OUTLINE).view(1, 3, 1, 1), x)
    return x[0]


def _grid_figure(cells: Sequence[Sequence[tuple[torch.Tensor | None, str]]], title: str, path: Path) -> None:
    """One image of rows of ``(image (3, s, s) or None, label)`` cells, labels above them, saved as PNG."""
    plt = pyplot()
    s = max(img.shape[-1] for row in cells for img, _ in row if img is not None)
    gap, band, top = 6, 22, 24
    ncol = max(len(row) for row in cells)
    width, height = ncol * (s + gap) + gap, top + len(cells) * (s + band) + gap
    canvas = np.ones((height, width, 3), dtype=np.float32)
    dpi = 100
    fig = plt.figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.axis("off")
    for i, row in enumerate(cells):
        y = top + i * (s + band) + band
        for j, (img, text) in enumerate(row):
            x = gap + j * (s + gap)
            if img is not None:
                canvas[y:y + img.shape[-2], x:x + img.shape[-1]] = img.permute(1, 2, 0).numpy()
            if text:
                ax.text(x + s / 2, y - 2, text, ha="center", va="bottom", fontsize=5.5, linespacing=1.0)
    ax.imshow(canvas, interpolation="nearest")
    ax.text(width / 2, 4, title, ha="center", va="top", fontsize=7)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    save_figure(fig, path, dpi=dpi)


def _map_cells(maps: torch.Tensor, light: EvalLights) -> list[torch.Tensor]:
    """Normal, diffuse, roughness, specular (albedos gamma-encoded) and the re-rendering, ``(3, S, S)`` each."""
    panels = M.preview_panels(maps.float())
    for name in ("diffuse", "specular"):
        panels[name] = gamma_encode(panels[name])
    return [panels[k][0] for k in M.MAP_NAMES] + [display(rerender(maps.float(), light))[0, 0]]


def example_figure(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """One row per (net, input) and per ground truth: the photos, the four maps, the re-rendering."""
    n_photos = max(r["photos"].shape[0] for r in rows)
    titles = ("normal", "diffuse", "roughness", "specular", "new light")
    keys = ("rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_render")
    light = eval_lights(1)
    cells = []
    for r in rows:
        photos = [(_cell(gamma_encode(p)), f"{r['label']}:\n{f}" if k == 0 else f"\n{f}")
                  for k, (p, f) in enumerate(zip(r["photos"], r["files"]))]
        photos += [(None, "")] * (n_photos - len(photos))
        maps = []
        for k, (img, name, key) in enumerate(zip(_map_cells(r["maps"], light), titles, keys)):
            score = f"RMSE {r['rmse'][key]:.3f}" if key in r.get("rmse", {}) else ""
            head = r["label"] if not r["files"] and k == 0 else ""  # a truth row: its label on the first map
            maps.append((_cell(img), f"{head}\n{name}" if head else f"{name}\n{score}"))
        cells.append(photos + maps)
    _grid_figure(cells, "example photos: each net's maps (RMSE against the truth) and a re-rendering under a new "
                        "light; truth rows follow each material", path)


def highlight_figure(materials: Sequence[dict[str, Any]], path: Path) -> None:
    """Rows = materials: the photo (the clipped highlight outlined), the true diffuse, each method's diffuse."""
    methods = [m for m in LEAK_METHODS if any(m in mat["diffuse"] for mat in materials)]
    cells = []
    for mat in materials:
        mask = mat["mask"]
        row = [(_cell(gamma_encode(mat["photo"]), mask),
                f"{mat['name']}: photo, I = {mat['flash_intensity']:.0f}\n{mat['clipped_percent']:.1f} % clipped"),
               (_cell(gamma_encode(mat["truth"])), f"true diffuse\nleak {_num(mat['leak']['truth'])}")]
        row += [(_cell(gamma_encode(mat["diffuse"][m])),
                 f"{m} diffuse\nleak {_num(mat['leak'][m])} (x{_num(mat['relative'][m])} truth)") for m in methods]
        cells.append(row)
    _grid_figure(cells, "flash photos (clipped highlight outlined in cyan) and the diffuse maps; leak = mean "
                        "diffuse luminance inside the highlight / outside", path)


# ----------------------------------------------------------------------------- the checks
def _example_truth(size: int) -> dict[str, dict[str, Any]]:
    """The examples' materials, regenerated (:mod:`mi_svbrdf.data.example_photos`): maps at ``size``, captures."""
    flash = HeldOutSet(size=EXAMPLE_SIZE, materials=1, n_images=1, preset="single_flash",
                       cache=False).material(FLASH_MATERIAL)
    multi = HeldOutSet(size=EXAMPLE_SIZE, materials=1, n_images=len(EXAMPLE_VIEWS), preset="multiview",
                       cache=False).material(MULTI_MATERIAL)
    return {name: {"maps": resize_maps(d["maps"], (size, size)), "captures": d["captures"],
                   "class": d["info"].get("class", "")} for name, d in (("flash", flash), ("views", multi))}


def example_check(methods: dict[str, Method], size: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The nets (and the trivial baseline, table only) on the example photos.

    Args:
        methods: ``{name: Method}`` among ``"single"``, ``"multi"``, ``"trivial"``.
        size: the photos are resized to ``size`` (the maps come out at that size).

    Returns:
        ``(figure rows, table rows)``: figure rows hold ``label, files, photos (N, 3, S, S), maps (1, 10, S, S),
        rmse``; table rows ``method, input, material, n`` and the RMSEs of :data:`EXAMPLE_METRICS`.
    """
    truth = _example_truth(size)
    flash, _ = load_inputs(EXAMPLE_FLASH, size=size)
    views, _ = load_inputs(list(EXAMPLE_VIEWS), size=size)
    inputs = {"flash": (flash, [EXAMPLE_FLASH.name]), "views": (views, [p.name for p in EXAMPLE_VIEWS])}
    plan = {"flash": ("single", "multi", "trivial"), "views": ("multi", "trivial")}
    lights = eval_lights()
    figure: list[dict[str, Any]] = []
    table: list[dict[str, Any]] = []
    for material, names in plan.items():
        (photos, files), gt = inputs[material], truth[material]["maps"]
        for name in (n for n in names if n in methods):
            with torch.no_grad():
                maps = methods[name](photos, truth[material]["captures"]).float()
                rmse = {f"rmse_{k}": float(v[0]) for k, v in map_rmse(maps, gt).items()}
                rmse["rmse_render"] = float(rerender_rmse(maps, gt, lights)[0])
            table.append({"method": name, "input": ", ".join(files), "material": truth[material]["class"],
                          "n": int(photos.shape[1]), **rmse})
            if name in NETS:
                figure.append({"label": name, "files": files, "photos": photos[0], "maps": maps, "rmse": rmse})
        figure.append({"label": f"truth ({truth[material]['class']})", "files": [], "photos": photos[0, :0],
                       "maps": gt, "rmse": {}})
    return figure, table


def highlight_check(methods: dict[str, Method], size: int) -> list[dict[str, Any]]:
    """The methods on the metered flash photos of the :data:`GLOSSY` materials (:func:`highlight_photos`).

    Args:
        methods: ``{name: Method}`` among :data:`LEAK_METHODS` (each sees the one photo per material).
        size: H = W of the materials and photos.

    Returns:
        Per material: ``name, description, flash_intensity, clipped_percent, leak {"truth", method...},
        relative {method...}`` and, for the figure, ``photo (3, S, S), mask (S, S), truth (3, S, S),
        diffuse {method: (3, S, S)}``.
    """
    maps, photos, captures = highlight_photos(size)
    mask = highlight_mask(photos[:, 0])
    truth = M.diffuse(maps)
    leak = {"truth": highlight_leak(truth, mask)}
    diffuse = {}
    for name in (n for n in LEAK_METHODS if n in methods):
        with torch.no_grad():
            diffuse[name] = M.diffuse(methods[name](photos, captures).float())
        leak[name] = highlight_leak(diffuse[name], mask)
    out = []
    for b, glossy in enumerate(GLOSSY):
        lk = {k: float(v[b]) for k, v in leak.items()}
        out.append({"name": glossy.name, "description": glossy.description,
                    "flash_intensity": float(captures.intensity[b, 0].mean()),
                    "clipped_percent": 100.0 * float(mask[b].float().mean()), "leak": lk,
                    "relative": {k: v / lk["truth"] if lk["truth"] > 0 else math.nan
                                 for k, v in lk.items() if k != "truth"},
                    "photo": photos[b, 0], "mask": mask[b], "truth": truth[b],
                    "diffuse": {k: v[b] for k, v in diffuse.items()}})
    return out


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return sum(finite) / len(finite) if finite else math.nan




def _check_args(out_dir: Any, weights_dir: Any, size: Any) -> None:
    if not isinstance(out_dir, (str, os.PathLike)) or Path(out_dir).is_file():
        raise ValueError(f"out_dir: expected a folder path, got {out_dir!r}")
    if weights_dir is not None and (not isinstance(weights_dir, (str, os.PathLike))
                                    or not weights_folder(weights_dir).is_dir()):
        raise ValueError(f"weights_dir: expected None (the bundled weights) or an existing folder, got {weights_dir!r}")
    if isinstance(size, bool) or not isinstance(size, int) or size < 16:
        raise ValueError(f"size: expected an int >= 16, got {size!r}")


def real_checks(out_dir: str | os.PathLike, weights_dir: str | os.PathLike | None = None, size: int = 256,
                progress: bool = True) -> dict[str, Any]:
    """Run both checks (module docstring); write the two figures and ``real_checks.json`` into ``out_dir``.

    Args:
        out_dir: the report folder (created if missing).
        weights_dir: the nets' weights folder (None: bundled). A net without weights is skipped (noted).
        size: H = W of the example photos (resized), of their maps and of the glossy materials, >= 16.
        progress: print what runs.

    Returns:
        The JSON-ready numbers (NaN as None): ``size``, ``nets`` (those run), ``notes``, ``examples`` (table
        rows: method, input, material, n, RMSEs), ``highlight`` (per material: name, description,
        flash_intensity, clipped_percent, leak, relative), ``mean_leak`` and ``mean_relative`` (per method,
        over the materials with a finite value), ``halo_radius``, ``figures`` (file names), ``seconds``.

    Raises:
        ValueError: naming ``out_dir``, ``weights_dir`` or ``size``.
    """
    _check_args(out_dir, weights_dir, size)
    start = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    nets = [k for k in NETS if k in available_nets(weights_dir)]
    notes = [f"no {k!r} network weights in {weights_dir or 'the bundled folder'}: {k} skipped"
             for k in NETS if k not in nets]
    methods = {k: make_method(k, weights_dir=weights_dir) for k in nets}
    methods["trivial"] = make_method("trivial")
    if progress:
        print(f"real-style checks: {', '.join(nets) or 'no nets'} on the example photos and "
              f"{len(GLOSSY)} glossy materials at {size}^2")
    fig_rows, table = example_check(methods, size)
    example_figure(fig_rows, out / EXAMPLES_PNG)
    materials = highlight_check(methods, size)
    highlight_figure(materials, out / HIGHLIGHTS_PNG)
    names = ["truth", *[k for k in LEAK_METHODS if k in methods]]
    result = json_safe({
        "size": size, "nets": nets, "notes": notes, "examples": table,
        "highlight": [{k: mat[k] for k in ("name", "description", "flash_intensity", "clipped_percent", "leak",
                                           "relative")} for mat in materials],
        "mean_leak": {k: _mean([mat["leak"][k] for mat in materials]) for k in names},
        "mean_relative": {k: _mean([mat["relative"][k] for mat in materials]) for k in names[1:]},
        "halo_radius": halo_radius(size), "meter_target": METER_TARGET,
        "figures": {"examples": EXAMPLES_PNG, "highlights": HIGHLIGHTS_PNG},
        "seconds": round(time.perf_counter() - start, 2),
    })
    write_json(out / JSON_NAME, result, fsync=False)
    return result


# ----------------------------------------------------------------------------- the report section
def _num(value: float | None, fmt: str = ".2f") -> str:
    return "–" if value is None or not math.isfinite(value) else format(value, fmt)


def reading(result: dict[str, Any]) -> list[str]:
    """One sentence per method of the highlight check, computed from ``result``'s leaks."""
    truth = result["mean_leak"].get("truth")
    lines = []
    for name, rel in result["mean_relative"].items():
        per = [(m["relative"].get(name), m["name"]) for m in result["highlight"]
               if m["relative"].get(name) is not None]
        worst = f"; most on {max(per)[1]}: {max(per)[0]:.2f}" if per else ""
        who = "the trivial baseline (photo as diffuse, for reference)" if name == "trivial" else f"**{name}**"
        lines.append(f"- {who} {verdict(math.nan if rel is None else float(rel))}: leak "
                     f"{_num(result['mean_leak'].get(name))} vs {_num(truth)} in the truth (relative leak "
                     f"{_num(rel)}, mean over {len(per)} materials{worst}).")
    return lines


def real_checks_markdown(result: dict[str, Any]) -> list[str]:
    """The report's "Real-style checks" section (Markdown lines) of :func:`real_checks`' result."""
    if not isinstance(result, dict) or not {"examples", "highlight", "mean_leak", "mean_relative"} <= result.keys():
        got = sorted(result) if isinstance(result, dict) else type(result).__name__
        raise ValueError(f"result: expected the dict of real_checks() (examples, highlight, mean_leak, "
                         f"mean_relative), got {got}")
    figs = result.get("figures", {"examples": EXAMPLES_PNG, "highlights": HIGHLIGHTS_PNG})
    md = ["## Real-style checks", ""]
    if result.get("notes"):
        md += [*[f"- {n}" for n in result["notes"]], ""]
    md += [("**Example photos** (`mi_svbrdf/assets/`: renders of held-out materials, so the truth is known): "
            f"the nets' maps at {result.get('size', '?')}² and a re-rendering under a light the photos do not have. "
            "RMSE as in the main table (normals (n + 1)/2, albedos linear, re-renderings displayed, 9 lights); "
            "trivial: the calibrated baseline, for reference."), "",
           markdown_table(["method", "input", "material", "N", *(h for _, h in EXAMPLE_METRICS)],
                          [[r["method"], r["input"], r["material"], r["n"], *(_num(r.get(k), ".4f") for k, _ in EXAMPLE_METRICS)]
                           for r in result["examples"]])]
    md += ["", f"![example photos]({figs['examples']})", "",
           ("**Highlight leak**: glossy materials photographed with the flash at the camera, metered like a phone "
            f"(the median of the photo at {_num(result.get('meter_target'))}, linear), the highlight clipped at 1. "
            "Leak = mean diffuse luminance inside the clipped highlight / mean outside it (pixels more than "
            f"{result.get('halo_radius', '?')} px from the highlight); relative = the method's leak / the truth's "
            "(1.0: no more highlight in the diffuse map than the truth has there; `mi_svbrdf/eval/studies/real_checks.py`)."),
           ""]
    methods = list(result["mean_relative"])
    rows = [[mat["name"], _num(mat.get("flash_intensity"), ".1f"), _num(mat["clipped_percent"], ".1f"),
             _num(mat["leak"].get("truth")), *(_num(mat["leak"].get(m)) for m in methods),
             *(_num(mat["relative"].get(m)) for m in methods)] for mat in result["highlight"]]
    rows.append(["mean", "", "", _num(result["mean_leak"].get("truth")),
                 *(_num(result["mean_leak"].get(m)) for m in methods),
                 *(_num(result["mean_relative"].get(m)) for m in methods)])
    md.append(markdown_table(["material", "flash I", "clipped %", "truth", *methods,
                              *(f"{m} relative" for m in methods)], rows))
    md += ["", *reading(result), "", f"![highlight leak]({figs['highlights']})", ""]
    return md
