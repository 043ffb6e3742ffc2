"""Benchmark: CPU seconds per rendered dataset image, against the thesis's 11.5, measured in one run.

Makes a small procedural bank (``mi_svbrdf.data.bank.make_bank``, ``--materials`` materials at
``--size``²), then renders ``--renders-per-material`` images of each through the bundled
``flash_capture`` scene with ``mi_svbrdf.data.dataset.workers.render_dataset`` (``--workers`` local
processes, the default spp unless ``--spp``), and prints:

- images, wall time, images/s;
- CPU·s per image over everything: this process and every worker process for its whole life
  (interpreter start-up, imports, scene loading included), and the same for the render tasks
  only (read, transform, render, encode, write: what a long run converges to);
- the ratio to the thesis's 11.5 CPU·s per image (200 000 images in 16 h on 40 CPUs);
- a per-stage breakdown measured in this process on a few renders (one Dr.Jit thread):
  map transform, Mitsuba render, photo + strip PNG encoding (ISA-L deflate when ``isal`` is
  installed, else zlib), file writes.

Target: <= 0.05 CPU·s per antialiased 256² image (>= 200x cheaper than the thesis).

Usage:
    python benchmarks/bench_dataset.py [--materials 8] [--renders-per-material 8] [--size 256]
        [--spp N] [--workers 2] [--out DIR]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def breakdown(job, count: int) -> dict[str, float]:
    """Median CPU seconds of each stage over ``count`` renders in this process (1 Dr.Jit thread)."""
    import drjit as dr
    import torch

    from mi_svbrdf.data.dataset import job as D
    from mi_svbrdf.data.dataset import output as DO
    from mi_svbrdf.data.dataset import renderer as R
    from mi_svbrdf.io.atomic import write_json
    from mi_svbrdf.io.material_sets import MaterialSet

    materials = MaterialSet(job.materials, size=None)
    renderer = R.SceneRenderer(job.scene, size=job.size, spp=job.spp, fov=job.shots.fov)
    threads, torch_threads = dr.thread_count(), torch.get_num_threads()
    dr.set_thread_count(1)
    torch.set_num_threads(1)
    stages: dict[str, list[float]] = {"transform": [], "render": [], "encode": [], "write": []}
    try:
        out = Path(tempfile.mkdtemp(prefix="bench_dataset_stages_"))
        for i in range(count + 1):  # the first is a warm-up
            name, material = materials[i % len(materials)]
            t0 = time.process_time()
            shot = D.draw_shot(job.seed, i, job.shots, size=job.size, material_size=material.shape[-1])
            maps = D.shot_maps(material, shot, job.size, job.shots.padding)
            t1 = time.process_time()
            linear = renderer.render(maps, shot.light, shot.intensity, shot.mitsuba_seed)
            t2 = time.process_time()
            codes = DO.photo_codes(torch.from_numpy(linear).permute(2, 0, 1))
            data = DO.png_bytes(DO.strip_codes(maps, codes), DO.default_compressor())
            t3 = time.process_time()
            (out / f"{i:06d}.png").write_bytes(data)
            write_json(out / f"{i:06d}.json", {"index": i, "material": name}, indent=1, fsync=False)
            t4 = time.process_time()
            if i:
                for key, value in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                    stages[key].append(value)
    finally:
        dr.set_thread_count(threads)
        torch.set_num_threads(torch_threads)
    return {k: statistics.median(v) for k, v in stages.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--materials", type=int, default=8, help="materials in the bank (default: 8)")
    parser.add_argument("--renders-per-material", type=int, default=8, help="renders per material (default: 8)")
    parser.add_argument("--size", type=int, default=256, help="image and map size (default: 256)")
    parser.add_argument("--spp", type=int, default=None, help="samples per pixel (default: RenderJob's)")
    parser.add_argument("--workers", type=int, default=2, help="local worker processes (default: 2)")
    parser.add_argument("--out", default=None, help="work folder (default: a new temporary folder)")
    args = parser.parse_args()

    import mi_svbrdf  # noqa: F401  (variant, plugins)
    from mi_svbrdf.data import bank
    from mi_svbrdf.data.dataset import job as D
    from mi_svbrdf.data.dataset import workers as W

    root = Path(args.out or tempfile.mkdtemp(prefix="bench_dataset_"))
    t0 = time.perf_counter()
    bank.make_bank(root / "bank", args.materials, size=args.size, seed=0, progress=False, sheet=0)
    print(f"bank: {args.materials} procedural materials of {args.size}² in {time.perf_counter() - t0:.1f} s "
          f"({root / 'bank'})")
    spp = {} if args.spp is None else {"spp": args.spp}
    job = D.RenderJob(materials=str(root / "bank"), out=str(root / "data"),
                      renders_per_material=args.renders_per_material, size=args.size, **spp)
    summary = W.render_dataset(job, workers=args.workers, progress=False)
    thesis = W.THESIS_CPU_SECONDS_PER_IMAGE
    print(f"dataset: {summary.rendered} images of {job.size}² at {job.spp} spp (box filter), {summary.workers} "
          f"{summary.executor} workers: {summary.seconds:.1f} s, {summary.images_per_second:.2f} images/s")
    print(f"CPU·s per image, everything (workers' start-up included): {summary.cpu_per_image:.4f} "
          f"-> {thesis / summary.cpu_per_image:.0f}x less than the thesis's {thesis:.1f}")
    print(f"CPU·s per image, render tasks (read, transform, render, encode, write): "
          f"{summary.render_cpu_per_image:.4f} -> {thesis / summary.render_cpu_per_image:.0f}x less "
          f"(target <= 0.05, >= 200x)")
    stages = breakdown(job, count=8)
    parts = ", ".join(f"{k} {v * 1000:.1f}" for k, v in stages.items())
    print(f"stages in this process, median CPU ms per image: {parts} (sum {sum(stages.values()) * 1000:.1f})")


if __name__ == "__main__":
    main()
