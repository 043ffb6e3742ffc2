"""Benchmark: the single-image net away from its training size (``mi-svbrdf capture --full-resolution``).

The nets are fully convolutional, so they run at any size, but they were trained at 256^2 and
the thesis shows quality degrades away from it. For each size S (default 256, 384, 512) this
renders held-out procedural materials (:class:`mi_svbrdf.data.heldout.HeldOutSet`, ``single_flash``
preset: the photo the single-image net is trained on) at S^2 and compares, against the S^2
ground truth, the map RMSE (:func:`mi_svbrdf.core.metrics.map_rmse`) of:

* **native**: the net run on the S^2 photo (``--full-resolution``);
* **resized**: the photo resized to 256^2 (antialiased, as ``capture`` does by default), the net
  at 256^2, the maps upsampled bilinearly to S^2 (normals renormalised).

It prints one row per size and map with both RMSEs and their ratio native / resized (> 1: the
full-resolution run is worse), and the net's seconds per photo at each size, measured in the
same run. Writes ``bench_capture_resolution.csv`` to ``--out``.

Pause any background training before running (timings), e.g.
``kill -STOP $(cat /tmp/train.pid); trap 'kill -CONT $(cat /tmp/train.pid)' EXIT``.

Usage:
    python benchmarks/bench_capture_resolution.py [--sizes 256,384,512] [--materials 9]
        [--weights DIR] [--out /tmp/bench_capture_resolution]
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import torch
import torch.nn.functional as F

import mi_svbrdf  # noqa: F401  (selects the Mitsuba variant)
from mi_svbrdf.core.maps import MAP_NAMES, normalize_normals
from mi_svbrdf.core.metrics import map_rmse
from mi_svbrdf.data.heldout import HeldOutSet
from mi_svbrdf.io.photos import resize
from mi_svbrdf.nets.inference import load


def upsample(maps: torch.Tensor, size: int) -> torch.Tensor:
    """Bilinear upsampling of maps ``(B, 10, R, R)`` to ``size``, normals renormalised."""
    return normalize_normals(F.interpolate(maps, size=(size, size), mode="bilinear", align_corners=False))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="256,384,512", help="photo sizes (default 256,384,512)")
    parser.add_argument("--materials", type=int, default=9, help="held-out materials per size (default 9)")
    parser.add_argument("--weights", default=None, help="weights folder (default: the bundled weights)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_capture_resolution"))
    args = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    net, entry = load("single", args.weights)
    res = net.config.resolution
    print(f"single-image net {entry['file']} (steps {entry['steps']}), trained at {res} px; "
          f"{args.materials} held-out materials per size")
    rows = []
    for size in sizes:
        gt, photos, _ = HeldOutSet(size=size, materials=args.materials, n_images=1, preset="single_flash").load(
            progress=False)
        native, resized, seconds = [], [], []
        with torch.inference_mode():
            for m in range(gt.shape[0]):
                t0 = time.perf_counter()
                native.append(net(photos[m:m + 1]))
                seconds.append(time.perf_counter() - t0)
                resized.append(upsample(net(resize(photos[m:m + 1], res)), size))
        e_native = map_rmse(torch.cat(native), gt)
        e_resized = map_rmse(torch.cat(resized), gt)
        for name in MAP_NAMES:
            a, b = float(e_native[name].mean()), float(e_resized[name].mean())
            rows.append({"size": size, "map": name, "rmse_native": a, "rmse_resized": b, "ratio": a / b,
                         "seconds_native": sum(seconds) / len(seconds)})
    print(f"{'size':>5} {'map':>10} {'native':>8} {'resized':>8} {'ratio':>6} {'s/photo':>8}")
    for r in rows:
        print(f"{r['size']:>5} {r['map']:>10} {r['rmse_native']:8.4f} {r['rmse_resized']:8.4f} "
              f"{r['ratio']:6.2f} {r['seconds_native']:8.2f}")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "bench_capture_resolution.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {args.out / 'bench_capture_resolution.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
