"""``python -m mi_svbrdf.cli.example_wall``: re-make the bundled large-scale example in ``mi_svbrdf/assets/``.

The example (``mi-svbrdf large-scale example``) is surface :data:`SURFACE` of the held-out
large-scale benchmark's sequence (:mod:`mi_svbrdf.eval.studies.large_scale`: seed
:data:`~mi_svbrdf.eval.studies.large_scale.LARGE_BENCH_SEED`, surface ``m`` blends two materials of class
``CLASS_ORDER[m % 9]`` drawn from the held-out parameter slices, never seen in training; the benchmark
scores surfaces 0-3, so this one is not among its figures): a tiled wall of 2048² texels
photographed whole at 512 px under a held-out ambient environment through the training camera
(white balance, exposure, noise, 8-bit sRGB), and two exemplars of 256² texels cut from the same
surface and resized to the compact net's 64 px, exactly as the benchmark builds its inputs for the
compact preset (:func:`~mi_svbrdf.eval.studies.large_scale.heldout_set`, :func:`~mi_svbrdf.eval.studies.large_scale.surface_scale`).

Files: ``photo.png`` (8-bit sRGB PNG, the simulator's 8-bit photo as it is), ``exemplar_1/`` and
``exemplar_2/`` (material folders: 8-bit PNG maps, albedos sRGB, and ``material.json``) and
``truth.json`` (the surface's settings and materials, so :func:`truth_maps` regenerates the
ground truth a result is scored against).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mi_svbrdf.assets import (
    EXAMPLE_WALL,
    EXAMPLE_WALL_DIR,
    EXAMPLE_WALL_EXEMPLARS,
    EXAMPLE_WALL_TRUTH,
)
from mi_svbrdf.cli.common import asset_script
from mi_svbrdf.data import augment
from mi_svbrdf.data.heldout import CLASS_ORDER
from mi_svbrdf.eval.studies.large_scale import (
    BENCH_VERSION,
    LARGE_BENCH_SEED,
    LargeBenchConfig,
    heldout_set,
    surface_scale,
    training_data_config,
)
from mi_svbrdf.io.atomic import write_json
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode, write_material
from mi_svbrdf.nets.network import network_config

#: Surface index in the benchmark's sequence (class CLASS_ORDER[7] = tiles; the benchmark scores 0-3).
SURFACE = 7
#: Exemplars cut from the surface (the benchmark's number).
EXEMPLARS = len(EXAMPLE_WALL_EXEMPLARS)
#: The net preset whose training data set the photo's and exemplars' scale.
PRESET = "compact"


def _settings(truth: dict[str, Any] | None = None) -> tuple[LargeBenchConfig, Any]:
    """``(benchmark config, training data config)`` of the example (``truth``: a ``truth.json``'s ``surface``)."""
    t = truth or {"index": SURFACE, "seed": LARGE_BENCH_SEED, "n_exemplars": EXEMPLARS, "preset": PRESET}
    train = training_data_config(network_config(t["preset"], "large"))
    cfg = LargeBenchConfig(surfaces=t["index"] + 1, n_exemplars=t["n_exemplars"], seed=t["seed"], cache=False,
                           progress=False)
    return cfg, train


def render_example_wall() -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """``(photo (3, 512, 512) linear, exemplars (2, 10, 64, 64), truth)`` of the example (module docstring)."""
    cfg, train = _settings()
    scale = surface_scale(train, cfg.material_size, cfg.photo_size)
    sample = heldout_set(cfg, train).sample(SURFACE)
    s, cut = scale["exemplar_size"], scale["exemplar_cut"]
    exemplars = sample.exemplar_maps[0]
    if cut != s:  # as load_surfaces does: the training exemplars' fraction of the surface at the net's size
        exemplars = augment.transform_maps(exemplars, scale=s / cut, out_size=s)
    info = sample.materials[0]
    cls = CLASS_ORDER[SURFACE % len(CLASS_ORDER)]
    truth = {"surface": f"held-out large-scale surface {SURFACE} ({cls})",
             "made_by": "python -m mi_svbrdf.cli.example_wall",
             "heldout": {"index": SURFACE, "class": cls, "seed": cfg.seed, "n_exemplars": EXEMPLARS, "preset": PRESET,
                         "material_size": cfg.material_size, **scale, "bench_version": BENCH_VERSION},
             "info": info}
    return sample.photo[0], exemplars.contiguous(), truth


def truth_maps(path: Path = EXAMPLE_WALL_TRUTH) -> torch.Tensor:
    """The ``(1, 10, 512, 512)`` ground-truth maps of the example whose ``truth.json`` is ``path`` (a few seconds)."""
    truth = json.loads(Path(path).read_text(encoding="utf-8"))["heldout"]
    cfg, train = _settings(truth)
    return heldout_set(cfg, train).sample(truth["index"]).maps


def write_example_wall(folder: Path = EXAMPLE_WALL_DIR) -> list[Path]:
    """Render and write the example (``photo.png``, ``exemplar_N/``, ``truth.json``, atomic); returns the files."""
    photo, exemplars, truth = render_example_wall()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = [folder / EXAMPLE_WALL.name]
    write_image(files[0], srgb_encode(photo.permute(1, 2, 0).numpy().astype(np.float32)), 8, srgb=True)
    for i, ex in enumerate(exemplars):
        sub = folder / EXAMPLE_WALL_EXEMPLARS[i].name
        write_material(sub, ex[None], fmt="png")
        files += sorted(p for p in sub.iterdir() if p.is_file())
    write_json(folder / EXAMPLE_WALL_TRUTH.name, truth)
    files.append(folder / EXAMPLE_WALL_TRUTH.name)
    return files


def main(argv: list[str] | None = None) -> int:
    """Re-make the bundled large-scale example (or write it to ``--out``)."""
    return asset_script(argv, "python -m mi_svbrdf.cli.example_wall", __doc__, EXAMPLE_WALL_DIR, write_example_wall)


if __name__ == "__main__":
    raise SystemExit(main())
