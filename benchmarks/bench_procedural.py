"""Benchmark: procedural SVBRDFs per second, per class and overall, and a contact sheet.

For every class it generates, after one warm-up batch, ``--repeats`` batches of ``--batch``
materials at ``--size``² with random parameters (``sample_parameters(spread=1)``), and prints
SVBRDFs/s (wall clock) and CPU seconds per SVBRDF (process time, all threads). The overall
figure is the total count over the total time (the average over classes, weighting each class
equally). Target: >= 20 SVBRDFs/s at 256² on the 2-core development machine.
``--threads 1`` is what a ``DataLoader`` worker runs with (and is faster on a busy machine,
where torch's two intra-op threads wait for each other); the default is torch's choice.

With ``--sheet PATH`` it also writes a contact sheet: one row per class, ``--seeds`` materials
per row (the first at default parameters, the others random), each shown as
``flash photo | normal | diffuse | roughness | specular``. The photo is
``flash.render_flash(maps, pipeline=True)``; photo, diffuse and specular are gamma-encoded
(x^(1/2.2)) for viewing, normals stored as (n + 1)/2.

Usage:
    python benchmarks/bench_procedural.py [--size 256] [--batch 8] [--repeats 2] [--threads 1]
        [--classes wood,metal] [--sheet /tmp/procedural_sheet.png] [--sheet-size 128] [--seeds 3]
        [--no-timing]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def _batch_params(name: str, batch: int, seed: int) -> list[dict[str, float]]:
    from mi_svbrdf.data import procedural

    gen = torch.Generator().manual_seed(seed)
    return [procedural.sample_parameters(name, gen, spread=1.0) for _ in range(batch)]


def time_class(name: str, size: int, batch: int, repeats: int) -> tuple[float, float]:
    """(wall seconds, CPU seconds) to generate ``repeats`` batches of ``name``."""
    from mi_svbrdf.data import procedural

    procedural.generate_batch(name, list(range(batch)), size, _batch_params(name, batch, 10**6))  # warm-up
    wall = cpu = 0.0
    for r in range(repeats):
        params = _batch_params(name, batch, r)
        seeds = [r * batch + i for i in range(batch)]
        t0, c0 = time.perf_counter(), time.process_time()
        procedural.generate_batch(name, seeds, size, params)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
    return wall, cpu


def _view(t: torch.Tensor) -> np.ndarray:
    """(3 or 1, H, W) tensor in [0, 1] -> (H, W, 3) array."""
    t = t.clamp(0.0, 1.0)
    if t.shape[0] == 1:
        t = t.expand(3, -1, -1)
    return t.permute(1, 2, 0).numpy()


def contact_sheet(path: str, classes: list[str], size: int, seeds: int) -> None:
    """Write the contact sheet described in the module docstring."""
    from mi_svbrdf.core import colour, flash
    from mi_svbrdf.core.maps import preview_panels
    from mi_svbrdf.data import procedural
    from mi_svbrdf.io.image_io import write_image

    rows = []
    for row, name in enumerate(classes):
        params = [{}] + _batch_params(name, seeds - 1, 1000 + row)
        maps = procedural.generate_batch(name, list(range(seeds)), size, params)
        photo = colour.gamma_encode(flash.render_flash(maps, pipeline=True))
        view = preview_panels(maps)
        panels = []
        for i in range(seeds):
            panels += [_view(photo[i]), _view(view["normal"][i]), _view(colour.gamma_encode(view["diffuse"][i])),
                       _view(view["roughness"][i]), _view(colour.gamma_encode(view["specular"][i]))]
            panels.append(np.ones((size, 4, 3), np.float32))  # white separator between materials
        rows.append(np.concatenate(panels[:-1], axis=1))
        rows.append(np.ones((4, rows[-1].shape[1], 3), np.float32))
    write_image(path, np.concatenate(rows[:-1], axis=0).astype(np.float32))


def main() -> None:
    import mi_svbrdf  # noqa: F401  (variant)
    from mi_svbrdf.data import procedural

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--classes", default=",".join(procedural.CLASSES))
    ap.add_argument("--sheet", default=None, help="write a contact sheet PNG here")
    ap.add_argument("--sheet-size", type=int, default=128)
    ap.add_argument("--seeds", type=int, default=3, help="materials per class on the sheet")
    ap.add_argument("--no-timing", action="store_true", help="only write the sheet")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    classes = [c for c in args.classes.split(",") if c]
    for c in classes:
        if c not in procedural.CLASSES:
            raise SystemExit(f"--classes: expected names from {sorted(procedural.CLASSES)}, got {c!r}")
    if not args.no_timing:
        print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, batch {args.batch}, "
              f"{args.size}x{args.size}, {args.repeats} timed batches per class after a warm-up")
        total_wall = total_cpu = 0.0
        count = args.batch * args.repeats
        for name in classes:
            wall, cpu = time_class(name, args.size, args.batch, args.repeats)
            total_wall += wall
            total_cpu += cpu
            print(f"  {name:<8} {count / wall:7.1f} SVBRDFs/s   {cpu / count * 1000:6.1f} CPU-ms per SVBRDF")
        n = count * len(classes)
        print(f"  {'overall':<8} {n / total_wall:7.1f} SVBRDFs/s   {total_cpu / n * 1000:6.1f} CPU-ms per SVBRDF "
              f"(target >= 20 SVBRDFs/s)")
    if args.sheet:
        contact_sheet(args.sheet, classes, args.sheet_size, args.seeds)
        print(f"contact sheet: {args.sheet} (rows: {', '.join(classes)}; per material: "
              f"flash photo | normal | diffuse | roughness | specular; first column default parameters)")


if __name__ == "__main__":
    main()
