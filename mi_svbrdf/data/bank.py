"""A deterministic bank of procedural SVBRDFs on disk: ``mi-svbrdf materials make``.

:func:`make_bank` writes ``count`` materials made by :mod:`mi_svbrdf.data.procedural` and
:mod:`mi_svbrdf.data.augment`, as the thesis augmented its artist materials (ch. 3.2): for material
``i`` a random generator seeded from ``(seed, i)`` draws, in a fixed order,

1. a class, uniform over ``classes``; its parameters (``procedural.sample_parameters`` with
   ``spread``: 0 gives the defaults, 1 anywhere in the documented ranges); a generator seed;
2. a second class, parameters and seed, and ``u ~ U(0, 1)``: if ``u < mix_fraction`` the
   material is the α-blend (:func:`mi_svbrdf.data.augment.mix`) of the two, ``α ~ U(0.1, 0.9)``;
3. a rotation (``rotation``): ``"any"`` angle in [-π, π) — both materials are generated at
   ``ceil(√2 · size)`` texels and the rotated window keeping the output inside them is cut out,
   so a rotated material shows the central 1/√2 of the sample (its features look √2 larger);
   ``"quarter"`` a multiple of 90° (exact, nothing resampled); ``"none"``.

Everything drawn is recorded in ``index.json`` (and flattened in ``index.csv``). The same
arguments give byte-identical files whatever ``workers`` is; every file is written under a
temporary name and renamed, the index last (a material the index does not list is not part of
the bank; a previous bank's index is removed first, so an interrupted run leaves no index, and
its files that the new index does not list are deleted at the end). Layout of ``out/``::

    000000_wood.png             strip format: normal | diffuse | roughness | specular (linear 8-bit)
    000001_stone+metal.png      a mix of two classes
    000000_wood/                folder format: material_io folders (sRGB 8-bit albedo PNGs)
    index.json, index.csv       what each file is: classes, parameters, seeds, mix alpha, rotation
    contact_sheet.png           the first materials as thumbnails, for a person to look at

:class:`mi_svbrdf.io.material_sets.MaterialSet` reads a bank back through its ``index.json``.

Examples:
    >>> import tempfile
    >>> result = make_bank(tempfile.mkdtemp(), count=3, size=16, classes=["tiles", "wood"], progress=False)
    >>> [m["file"] for m in result.index["materials"]]
    ['000000_wood.png', '000001_wood.png', '000002_wood.png']
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import secrets
import shutil
import sys
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from mi_svbrdf.core.colour import gamma_encode
from mi_svbrdf.core.flash import render_flash
from mi_svbrdf.core.maps import preview_panels
from mi_svbrdf.core.settings import check_fields
from mi_svbrdf.data import augment, procedural
from mi_svbrdf.io.atomic import write_json, write_text
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode, write_material
from mi_svbrdf.io.material_sets import BANK_FORMAT, BANK_INDEX
from mi_svbrdf.io.strip import write_strip

#: Version of ``index.json``.
INDEX_VERSION = 1
#: File formats of a bank.
FORMATS = ("strip", "folder")
#: Rotation modes.
ROTATIONS = ("any", "quarter", "none")
#: Contact-sheet panels per material, in order.
SHEET_PANELS = ("flash render", "diffuse", "specular", "normal", "roughness")
#: Contact-sheet thumbnail size (texels) and materials per row.
THUMB, SHEET_COLUMNS = 64, 4
#: Materials generated together (one class at a time) by one process.
BLOCK = 8
_LABEL, _GAP = 14, 6  # label band height and gap between materials, in pixels


@dataclass
class BankResult:
    """What :func:`make_bank` wrote.

    Attributes:
        out: the bank folder.
        index: the content of ``index.json``.
        contact_sheet: path of ``contact_sheet.png`` (None if not written).
        seconds: wall-clock time of the whole run.
        timings: seconds spent per stage (``generate``, ``write``, ``sheet``: thumbnails and the
            sheet); with workers, ``generate`` is the wall-clock time of the whole parallel part.
    """

    out: Path
    index: dict[str, Any]
    contact_sheet: Path | None
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def materials_per_second(self) -> float:
        """Materials written per second of wall-clock time."""
        return len(self.index["materials"]) / max(self.seconds, 1e-9)


def material_seed(seed: int, index: int) -> int:
    """The random seed of material ``index`` of a bank with ``seed`` (independent streams)."""
    state = np.random.SeedSequence([seed, index]).generate_state(1, np.uint64)[0]
    return int(state) >> 1  # 63 bits: a valid torch seed and procedural seed


def recipe(seed: int, index: int, classes: Sequence[str], size: int, mix_fraction: float = 0.3,
           spread: float = 1.0, rotation: str = "any") -> dict[str, Any]:
    """What material ``index`` of a bank is (its ``index.json`` record, without ``file``).

    The draws are made in the same order whatever ``mix_fraction`` and ``rotation`` are, so
    changing them changes only what they control.

    Returns:
        ``{"classes": [a] or [a, b], "parameters": [...], "seeds": [...], "mix_alpha": float or None,
        "rotation": {"angle", "scale", "translation", "generated_size"} or None}``.
    """
    gen = torch.Generator().manual_seed(material_seed(seed, index))
    parts = []
    for _ in range(2):
        name = classes[int(torch.randint(len(classes), (1,), generator=gen))]
        params = procedural.sample_parameters(name, gen, spread)
        parts.append((name, params, int(torch.randint(2**62, (1,), generator=gen))))
    u_mix, u_alpha, u_angle, u_tx, u_ty = torch.rand(5, generator=gen, dtype=torch.float64).tolist()
    quarter = int(torch.randint(4, (1,), generator=gen))
    mixed = u_mix < mix_fraction
    used = parts if mixed else parts[:1]
    rec: dict[str, Any] = {"classes": [p[0] for p in used], "parameters": [p[1] for p in used],
                           "seeds": [p[2] for p in used],
                           "mix_alpha": augment.MIX_ALPHA_RANGE[0] + (augment.MIX_ALPHA_RANGE[1]
                                                                      - augment.MIX_ALPHA_RANGE[0]) * u_alpha
                           if mixed else None, "rotation": None}
    if rotation == "any":
        generated = math.ceil(math.sqrt(2.0) * size)
        angle = -math.pi + 2.0 * math.pi * u_angle
        scale = size * math.sqrt(2.0) / generated  # the window's half-width is 1/sqrt(2)
        bound = float(augment.max_translation(angle, scale, size, generated)[0])
        rec["rotation"] = {"angle": angle, "scale": scale, "generated_size": generated,
                           "translation": [(2 * u_tx - 1) * bound, (2 * u_ty - 1) * bound]}
    elif rotation == "quarter":
        rec["rotation"] = {"angle": quarter * math.pi / 2, "scale": 1.0, "generated_size": size,
                           "translation": [0.0, 0.0]}
    return rec


def build_materials(recs: Sequence[dict[str, Any]], size: int) -> torch.Tensor:
    """The ``(B, 10, size, size)`` maps of B :func:`recipe` records, generated class by class.

    Materials of one class are generated together (``procedural.generate_batch``, which equals
    one-by-one generation bit for bit), so the result does not depend on how records are grouped.
    """
    generated = {rec["rotation"]["generated_size"] if rec["rotation"] else size for rec in recs}
    if len(generated) != 1:
        raise ValueError(f"recs: expected one generated size per call, got {sorted(generated)}")
    gsize = generated.pop()
    parts: dict[str, list[tuple[int, int]]] = {}  # class -> [(record, part)]
    for r, rec in enumerate(recs):
        for k, name in enumerate(rec["classes"]):
            parts.setdefault(name, []).append((r, k))
    maps = [[torch.empty(0)] * len(rec["classes"]) for rec in recs]
    for name in sorted(parts):
        keys = parts[name]
        batch = procedural.generate_batch(name, [recs[r]["seeds"][k] for r, k in keys], gsize,
                                          [recs[r]["parameters"][k] for r, k in keys])
        for (r, k), m in zip(keys, batch):
            maps[r][k] = m
    first = torch.stack([m[0] for m in maps])
    mixed = [r for r, rec in enumerate(recs) if rec["mix_alpha"] is not None]
    if mixed:
        alpha = torch.tensor([recs[r]["mix_alpha"] for r in mixed], dtype=torch.float64)
        first[mixed] = augment.mix(first[mixed], torch.stack([maps[r][1] for r in mixed]), alpha)
    rotated = [r for r, rec in enumerate(recs) if rec["rotation"]]
    if not rotated:
        return first.contiguous()
    rot = [recs[r]["rotation"] for r in rotated]
    out = first if gsize == size else torch.empty(len(recs), first.shape[1], size, size)
    out[rotated] = augment.transform_maps(
        first[rotated], torch.tensor([x["angle"] for x in rot], dtype=torch.float64),
        torch.tensor([x["scale"] for x in rot], dtype=torch.float64),
        torch.tensor([x["translation"] for x in rot], dtype=torch.float64), size)
    return out.contiguous()


def build_material(rec: dict[str, Any], size: int) -> torch.Tensor:
    """The ``(1, 10, size, size)`` maps of one :func:`recipe` record."""
    return build_materials([rec], size)


def file_name(index: int, classes: Sequence[str], fmt: str) -> str:
    """``000042_wood.png`` (strip) or ``000042_wood+metal`` (folder of a mix)."""
    stem = f"{index:06d}_{'+'.join(classes)}"
    return f"{stem}.png" if fmt == "strip" else stem


def _write_folder(target: Path, maps: torch.Tensor) -> None:
    """Write a material folder under a temporary name, then put it in place of ``target``."""
    tmp = target.with_name(f".{target.name}.tmp{secrets.token_hex(4)}")
    try:
        write_material(tmp, maps, fmt="png")
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def thumbnails(maps: torch.Tensor, thumb: int = THUMB) -> np.ndarray:
    """Display panels of one material: ``(thumb, len(SHEET_PANELS) * thumb, 3)`` float32 in [0, 1].

    The flash render (:func:`mi_svbrdf.core.flash.render_flash`, torch backend, the authors' photo
    pipeline) is gamma-encoded like a photo; albedos are sRGB-encoded; normals show ``(n + 1)/2``
    (:func:`mi_svbrdf.core.maps.preview_panels`).
    """
    if maps.shape[-1] > 2 * thumb:  # render at twice the thumbnail size: 2 x 2 samples per pixel
        maps = augment.transform_maps(maps, scale=2 * thumb / maps.shape[-1], out_size=2 * thumb)
    photo = gamma_encode(render_flash(maps, backend="torch"))
    small = F.interpolate(torch.cat([photo, maps], 1), size=(thumb, thumb), mode="area")
    panels = {"flash render": small[:, :3].clamp(0, 1), **preview_panels(small[:, 3:])}
    rgb = {name: panels[name][0].permute(1, 2, 0).numpy() for name in SHEET_PANELS}
    rgb["diffuse"], rgb["specular"] = srgb_encode(rgb["diffuse"]), srgb_encode(rgb["specular"])
    return np.concatenate(list(rgb.values()), axis=1).astype(np.float32)


def _make_block(task: tuple[list[int], list[dict[str, Any]], int, str, str, int]
                ) -> list[tuple[np.ndarray | None, float, float, float]]:
    """Generate, write and thumbnail a block of materials; per material (thumbnail, gen s, write s, thumb s)."""
    indices, recs, size, fmt, out, sheet = task
    t0 = time.perf_counter()
    maps = build_materials(recs, size)
    t_gen = (time.perf_counter() - t0) / len(recs)
    results = []
    for index, rec, m in zip(indices, recs, maps):
        t1 = time.perf_counter()
        target = Path(out) / file_name(index, rec["classes"], fmt)
        if fmt == "strip":
            write_strip(target, m)
        else:
            _write_folder(target, m)
        t2 = time.perf_counter()
        thumb = thumbnails(m[None]) if index < sheet else None
        results.append((thumb, t_gen, t2 - t1, time.perf_counter() - t2))
    return results


def _worker_init() -> None:
    torch.set_num_threads(1)


def contact_sheet(path: str | os.PathLike, thumbs: Sequence[np.ndarray], labels: Sequence[str],
                  columns: int = SHEET_COLUMNS) -> None:
    """Write a grid of per-material thumbnail rows with a label above each (matplotlib text if available).

    Args:
        path: target PNG.
        thumbs: ``(T, P T, 3)`` arrays from :func:`thumbnails`.
        labels: one per thumbnail.
        columns: materials per row.
    """
    th, tw = thumbs[0].shape[:2]
    rows = math.ceil(len(thumbs) / columns)
    cell_w, cell_h = tw + _GAP, th + _LABEL + _GAP
    header = _LABEL + _GAP
    sheet = np.full((header + rows * cell_h, columns * cell_w + _GAP, 3), 0.12, np.float32)
    spots = []
    for k, thumb in enumerate(thumbs):
        top, left = header + (k // columns) * cell_h + _LABEL, _GAP + (k % columns) * cell_w
        sheet[top:top + th, left:left + tw] = thumb
        spots.append((left, top - _LABEL))
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:  # the labels are in index.json; the sheet stays useful without them
        write_image(path, sheet, 8, srgb=True)
        return
    height, width = sheet.shape[:2]
    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    fig.figimage((sheet * 255 + 0.5).astype(np.uint8), xo=0, yo=0, origin="upper")
    text = dict(color="white", fontsize=7.5, family="DejaVu Sans", va="top", ha="left")
    fig.text(_GAP / width, 1 - 2 / height, "per material: " + " | ".join(SHEET_PANELS), **text)
    for (left, top), label in zip(spots, labels):
        fig.text(left / width, 1 - (top + 1) / height, label, **text)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())[:, :, :3].astype(np.float32) / 255.0
    write_image(path, rgba, 8, srgb=True)


def _index_csv(materials: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["file", "class", "class_b", "seed", "seed_b", "mix_alpha", "angle", "scale",
                     "translation_x", "translation_y", "generated_size", "parameters", "parameters_b"])
    for m in materials:
        two = len(m["classes"]) == 2
        rot = m["rotation"] or {}
        tx, ty = rot.get("translation", ["", ""])
        writer.writerow([m["file"], m["classes"][0], m["classes"][1] if two else "", m["seeds"][0],
                         m["seeds"][1] if two else "", "" if m["mix_alpha"] is None else repr(m["mix_alpha"]),
                         rot.get("angle", ""), rot.get("scale", ""), tx, ty, rot.get("generated_size", ""),
                         json.dumps(m["parameters"][0], sort_keys=True),
                         json.dumps(m["parameters"][1], sort_keys=True) if two else ""])
    return buf.getvalue()


def _remove_stale(out: Path, old_index: dict[str, Any] | None, keep: set[str]) -> None:
    """Delete files a previous bank in ``out`` listed that the new index does not."""
    for m in (old_index or {}).get("materials", []):
        name = str(m.get("file", ""))
        path = out / name
        if name and name not in keep and "/" not in name and path.parent == out:
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()


def make_bank(out: str | os.PathLike, count: int, size: int = 256, seed: int = 0,
              classes: Sequence[str] | None = None, fmt: str = "strip", mix_fraction: float = 0.3,
              spread: float = 1.0, workers: int = 1, *, rotation: str = "any", sheet: int = 64,
              progress: bool = True) -> BankResult:
    """Write a deterministic bank of ``count`` procedural materials to ``out`` (see the module doc).

    Args:
        out: bank folder (created; a previous bank's files not in the new index are removed).
        count: number of materials (>= 1).
        size: resolution of each map (>= 8).
        seed: bank seed: the same arguments give byte-identical files.
        classes: class names to draw from (default: all of ``procedural.CLASSES``).
        fmt: ``"strip"`` (thesis strip PNGs, maps only) or ``"folder"`` (material folders).
        mix_fraction: fraction of materials that are α-blends of two, in [0, 1].
        spread: parameter spread, in [0, 1] (``procedural.sample_parameters``).
        workers: processes generating and writing materials (1: in this process).
        rotation: ``"any"``, ``"quarter"`` or ``"none"``.
        sheet: materials shown in ``contact_sheet.png`` (the first ``sheet``; 0: no sheet).
        progress: show a progress bar.

    Returns:
        A :class:`BankResult` (the index, timings, materials per second).

    Raises:
        ValueError: an argument outside its range or an unknown class.
    """
    classes = list(procedural.CLASSES) if classes is None else list(classes)
    _check_arguments(count, size, seed, classes, fmt, mix_fraction, spread, workers, rotation, sheet)
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    old_index = _forget_index(out)
    materials = []
    for i in range(count):
        rec = recipe(seed, i, classes, size, mix_fraction, spread, rotation)
        materials.append({"file": file_name(i, rec["classes"], fmt), **rec})
    recs = [{k: v for k, v in m.items() if k != "file"} for m in materials]
    tasks = [(list(range(b, min(b + BLOCK, count))), recs[b:b + BLOCK], size, fmt, str(out), sheet)
             for b in range(0, count, BLOCK)]
    bar = tqdm(total=count, desc=f"materials -> {out}", unit="mat", disable=not progress, file=sys.stderr)
    thumbs, timings = _run_blocks(tasks, workers, bar)
    sheet_path = None
    if thumbs:
        t0 = time.perf_counter()
        sheet_path = out / "contact_sheet.png"
        contact_sheet(sheet_path, thumbs, [m["file"].removesuffix(".png") for m in materials[:len(thumbs)]])
        timings["sheet"] += time.perf_counter() - t0
    index = {"format": BANK_FORMAT, "format_version": INDEX_VERSION, "seed": seed, "count": count,
             "size": size, "file_format": fmt, "classes": classes, "mix_fraction": mix_fraction,
             "spread": spread, "rotation": rotation, "materials": materials}
    write_text(out / "index.csv", _index_csv(materials))
    write_json(out / BANK_INDEX, index, indent=1)
    _remove_stale(out, old_index, {m["file"] for m in materials})
    if sheet_path is None:
        (out / "contact_sheet.png").unlink(missing_ok=True)
    return BankResult(out, index, sheet_path, time.perf_counter() - start, timings)


def _check_arguments(count: int, size: int, seed: int, classes: list[str], fmt: str, mix_fraction: float,
                     spread: float, workers: int, rotation: str, sheet: int) -> None:
    """Raise a ``ValueError`` naming the first argument of :func:`make_bank` outside its range."""
    if not classes or any(c not in procedural.CLASSES for c in classes):
        raise ValueError(f"classes: expected names among {list(procedural.CLASSES)}, got {classes!r}")
    check_fields([("count", isinstance(count, int) and count >= 1, "an integer >= 1", count),
                  ("size", isinstance(size, int) and size >= 8, "an integer >= 8", size),
                  ("seed", isinstance(seed, int) and seed >= 0, "an integer >= 0", seed),
                  ("fmt", fmt in FORMATS, f"one of {FORMATS}", fmt),
                  ("rotation", rotation in ROTATIONS, f"one of {ROTATIONS}", rotation),
                  ("mix_fraction", 0.0 <= mix_fraction <= 1.0, "a value in [0, 1]", mix_fraction),
                  ("spread", 0.0 <= spread <= 1.0, "a value in [0, 1]", spread),
                  ("workers", isinstance(workers, int) and workers >= 1, "an integer >= 1", workers),
                  ("sheet", isinstance(sheet, int) and sheet >= 0, "an integer >= 0", sheet)])


def _forget_index(out: Path) -> dict[str, Any] | None:
    """Delete a previous bank's index in ``out`` before its files are touched; return its content (if readable)."""
    path = out / BANK_INDEX
    if not path.is_file():
        return None
    try:
        old_index = json.loads(path.read_text(encoding="utf-8"))
    except ValueError:
        old_index = None
    path.unlink()
    return old_index


def _run_blocks(tasks: list[tuple[Any, ...]], workers: int, bar: Any) -> tuple[list[np.ndarray], dict[str, float]]:
    """Make every block of materials (:func:`_make_block`) in this process or ``workers`` processes.

    Returns:
        The contact-sheet thumbnails in material order and the seconds per stage (with workers,
        ``generate`` is the wall-clock time of the whole parallel part).
    """
    thumbs: list[np.ndarray] = []
    timings = {"generate": 0.0, "write": 0.0, "sheet": 0.0}
    t_loop = time.perf_counter()
    pool = None
    results: Iterable[list[tuple[np.ndarray | None, float, float, float]]]
    if workers == 1:
        results = map(_make_block, tasks)
    else:
        import multiprocessing

        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init)
        results = pool.map(_make_block, tasks)
    try:
        for block in results:
            for thumb, t_gen, t_write, t_thumb in block:
                if thumb is not None:
                    thumbs.append(thumb)
                timings["generate"] += t_gen
                timings["write"] += t_write
                timings["sheet"] += t_thumb
            bar.update(len(block))
    finally:
        bar.close()
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if pool is not None:  # per-material times were measured in the workers
        timings = {"generate": time.perf_counter() - t_loop, "write": 0.0, "sheet": 0.0}
    return thumbs, timings
