"""Benchmark: ``mi-svbrdf large-scale`` on a 4K photo (3840 x 2160) with 2 exemplars, the compact preset.

The whole command runs in a child process (``python -m mi_svbrdf.cli large-scale ...``: reading the JPEG,
the exemplars' pyramid, every tile, the blend, the PNG + EXR maps, the contact sheet, view.html and
summary.json), so that its wall time and its peak memory (the child's resident-set high-water mark,
``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``: the kernel's own maximum, which no sampling misses)
are the command's alone. Targets (issue 16): <= 5 minutes and <= 4 GB on this CPU.

Baseline measured in the same run, in this process: the net on one tile (its training tile, with the
exemplar features bound; median of ``--repeats`` after a warm-up). ``tiles x one tile`` is the time the
network alone needs; the ratios say what the rest (reading, blending, writing) costs.

Seams: the command's ``summary.json`` seam ratio (:func:`mi_svbrdf.nets.tiling.seam_ratio`, ~1: none) is
printed; ``--naive-control`` also pastes the same net's tiles without blending, the control that shows
what a seam scores on this net and photo. With random weights the blended ratio is a little above 1
(measured 1.03-1.11 at 960 x 540, the control 1.45-1.7): an untrained U-Net's tiles disagree in their
fine texture (blocky patterns of its upsampled deep levels, aligned with each tile), so where two tiles
mix in equal parts the texture averages down and the borders, where one tile dominates, look busier.

Weights: the bundled ``large`` entry when there is one; otherwise (none trained yet) a randomly initialised
compact net, exported to a temporary weights folder: speed and memory do not depend on the weights' values,
and the output says so. Inputs: a synthetic ambient-lit photo (smooth colour field and fine texture,
8-bit sRGB JPEG) and two built-in example materials (``example_material``, 256 px, resized by the
command to the net's exemplar size) written as material folders.

Pause any background training before a real run (timings), e.g.
``kill -STOP $(cat /tmp/train.pid); trap 'kill -CONT $(cat /tmp/train.pid)' EXIT``. ``--quick`` runs a
960 x 540 photo (a smoke run: the targets are not judged).

Usage:
    python benchmarks/bench_large_scale.py [--quick] [--width 3840] [--height 2160] [--weights FILE_OR_DIR]
        [--tile N] [--overlap N] [--repeats 5] [--naive-control] [--out /tmp/bench_large_scale]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

import mi_svbrdf  # noqa: F401  (selects the Mitsuba variant)
from mi_svbrdf.cli.large_scale import load_exemplars, load_large_net
from mi_svbrdf.data.examples import example_material
from mi_svbrdf.data.large_scale import exemplar_input
from mi_svbrdf.io.material_io import write_material
from mi_svbrdf.io.photos import load_photo
from mi_svbrdf.nets import weights as bundled
from mi_svbrdf.nets.network import build_network, network_config
from mi_svbrdf.nets.tiling import plan_tiles, seam_ratio

#: Targets of issue 16 for the 4K photo with the compact preset.
TARGET_SECONDS, TARGET_GB = 300.0, 4.0
#: The photo of the real run and of --quick.
FULL_SIZE, QUICK_SIZE = (3840, 2160), (960, 540)


def ambient_photo(width: int, height: int, seed: int = 0) -> np.ndarray:
    """``(height, width, 3)`` uint8 sRGB: a smooth colour field (bicubic from a coarse grid) plus fine texture."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, 6, 10, generator=g)
    field = torch.nn.functional.interpolate(coarse, size=(height, width), mode="bicubic", align_corners=False)
    texture = torch.rand(1, 1, height, width, generator=g)
    image = (0.25 + 0.5 * field) * (0.85 + 0.3 * texture)
    return np.round(image[0].permute(1, 2, 0).clamp(0, 1).numpy() * 255).astype(np.uint8)


def random_weights(folder: Path) -> Path:
    """A randomly initialised compact large-scale net exported like trained weights; returns the folder."""
    torch.manual_seed(0)
    cfg = network_config("compact", "large")
    folder.mkdir(parents=True, exist_ok=True)
    ckpt = folder / "large_checkpoint.pt"
    torch.save({"net_config": cfg.to_dict(), "model": build_network(cfg).state_dict(),
                "config": {"preset": "compact"}, "step": 0, "seconds": 0.0}, ckpt)
    bundled.export_weights(ckpt, folder=folder, note="random initialisation (bench_large_scale: timing only)")
    return folder


def one_tile_seconds(weights: str | None, exemplar_dirs: list[str], tile: int | None, repeats: int) -> float:
    """Median seconds of the net on one tile with the exemplar features bound (the baseline)."""
    net, _ = load_large_net(weights, torch.device("cpu"))
    exemplars, _, _ = load_exemplars(exemplar_dirs, int(net.config.exemplar_size))
    side = int(net.config.resolution) if tile is None else tile
    photo = torch.rand(1, 3, side, side, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        features = net.exemplar_features(exemplar_input(exemplars)[None])
        net(photo, features=features)  # warm-up
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            net(photo, features=features)
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def naive_control(weights: str | None, photo_file: Path, exemplar_dirs: list[str], tile: int,
                  overlap: int) -> dict[str, float]:
    """Seam ratios of the same net's tiles pasted over each other (no blending), in this process: the control
    that shows what a seam measures on this net and photo."""
    net, _ = load_large_net(weights, torch.device("cpu"))
    exemplars, _, _ = load_exemplars(exemplar_dirs, int(net.config.exemplar_size))
    photo = torch.from_numpy(load_photo(photo_file, square=False).image).permute(2, 0, 1)[None]
    plan = plan_tiles(photo.shape[-2], photo.shape[-1], tile=tile, overlap=overlap)
    if any(plan.pad):
        raise ValueError("--naive-control: expected a photo at least a tile high and wide")
    out = torch.zeros(1, 10, *photo.shape[-2:])
    with torch.no_grad():
        features = net.exemplar_features(exemplar_input(exemplars)[None])
        for top, left in plan.boxes():
            out[..., top:top + tile, left:left + tile] = net(photo[..., top:top + tile, left:left + tile],
                                                             features=features)
    return {k: round(v, 4) for k, v in seam_ratio(out, tile, overlap).items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help=f"a {QUICK_SIZE[0]}x{QUICK_SIZE[1]} photo (smoke run)")
    parser.add_argument("--width", type=int, default=None, help=f"photo width (default {FULL_SIZE[0]})")
    parser.add_argument("--height", type=int, default=None, help=f"photo height (default {FULL_SIZE[1]})")
    parser.add_argument("--weights", default=None,
                        help="checkpoint or weights folder (default: bundled 'large', else random compact weights)")
    parser.add_argument("--tile", type=int, default=None, help="tile (default: the net's training tile)")
    parser.add_argument("--overlap", type=int, default=None, help="overlap (default: half a tile)")
    parser.add_argument("--repeats", type=int, default=5, help="repeats of the one-tile baseline (median)")
    parser.add_argument("--naive-control", action="store_true",
                        help="also paste the same net's tiles without blending and print their seam ratios "
                             "(runs the net on every tile once more)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_large_scale"))
    args = parser.parse_args(argv)
    width, height = QUICK_SIZE if args.quick else FULL_SIZE
    width, height = args.width or width, args.height or height
    judged = (width, height) == FULL_SIZE and not args.quick
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"output folder {args.out}; torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"{os.cpu_count()} cores ({bundled.cpu_model() or 'unknown CPU'})")

    weights = args.weights
    if weights is None and "large" not in bundled.available():
        weights = str(random_weights(args.out / "random-weights"))
        print("weights: no bundled large-scale weights: a randomly initialised compact net "
              "(speed and memory do not depend on the weights' values)")
    else:
        print(f"weights: {weights or 'bundled large'}")

    from PIL import Image

    photo = args.out / f"wall_{width}x{height}.jpg"
    Image.fromarray(ambient_photo(width, height)).save(photo, quality=92)
    exemplar_dirs = []
    for name in ("tiles", "metal_plate"):
        folder = args.out / f"exemplar_{name}"
        write_material(folder, example_material(name, size=256))
        exemplar_dirs.append(str(folder))

    t_tile = one_tile_seconds(weights, exemplar_dirs, args.tile, args.repeats)
    out = args.out / "large-scale"
    argv_child = [sys.executable, "-m", "mi_svbrdf.cli", "large-scale", str(photo), "--exemplar", exemplar_dirs[0],
                  "--exemplar", exemplar_dirs[1], "--weights", weights or str(bundled.WEIGHTS_DIR), "--no-progress",
                  "-o", str(out)]
    argv_child += ["--tile", str(args.tile)] if args.tile else []
    argv_child += ["--overlap", str(args.overlap)] if args.overlap is not None else []
    print(f"running: {' '.join(argv_child[1:])}")
    t0 = time.perf_counter()
    run = subprocess.run(argv_child, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        print(run.stdout, run.stderr, sep="\n")
        return 1
    peak_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 / 1e9  # Linux: kilobytes
    summary = json.loads((out / "summary.json").read_text())
    tiles = summary["tiles"]["tiles"]
    tile = summary["options"]["tile"]
    assert tiles == plan_tiles(height, width, tile=tile, overlap=summary["options"]["overlap"]).count
    secs = summary["seconds"]
    network_only = tiles * t_tile
    print(f"\nphoto {width}x{height}, 2 exemplars: {tiles} tiles of {tile} px (overlap {summary['options']['overlap']}, "
          f"grid {summary['tiles']['grid'][0]}x{summary['tiles']['grid'][1]})")
    print(f"  wall time (whole command, child process): {wall:.1f} s; its phases: "
          + ", ".join(f"{k} {v:.1f} s" for k, v in secs.items()))
    print(f"  peak memory (child's max RSS): {peak_gb:.2f} GB")
    print(f"  baseline: one tile {t_tile * 1000:.1f} ms -> network alone {network_only:.1f} s for {tiles} tiles; "
          f"tiles phase / network alone = {secs['tiles'] / network_only:.2f}, "
          f"wall / network alone = {wall / network_only:.2f}; {tiles / secs['tiles']:.1f} tiles/s")
    print(f"  seam ratio (border / inside gradients, per map): {summary['seam_ratio']}")
    if args.naive_control:
        naive = naive_control(weights, photo, exemplar_dirs, tile, summary["options"]["overlap"])
        print(f"  control, the same tiles pasted without blending: seam ratio {naive}")
    if judged:
        print(f"  target wall <= {TARGET_SECONDS:.0f} s: {'MET' if wall <= TARGET_SECONDS else 'NOT MET'}; "
              f"target memory <= {TARGET_GB:.0f} GB: {'MET' if peak_gb <= TARGET_GB else 'NOT MET'}")
    else:
        print(f"  targets (<= {TARGET_SECONDS:.0f} s, <= {TARGET_GB:.0f} GB) are for the {FULL_SIZE[0]}x{FULL_SIZE[1]} "
              "photo: not judged by this run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
