"""Benchmark (the proof of ``mi-svbrdf rectify``): synthetic real-world photos -> rectify -> optimize.

For ``--photos`` random camera poses (:func:`mi_svbrdf.data.frame_photos.sample_pose`: tilt up to
40 degrees, any azimuth and in-plane rotation, FOV 40-70 degrees with a whole-mm 35 mm focal
length written to EXIF, the whole A4 sheet in view), Mitsuba renders a procedural material in
the paper frame on a darker table, flash at the camera, as 8-bit sRGB PNG with noise. Then:

1. ``rectify`` (the library call behind ``mi-svbrdf rectify``; FOV from EXIF): median and
   max corner error (pixels) against the projected ground truth, and the camera position
   error in % of the camera's distance (targets: median corner error < 1 px, every camera
   within 3 %).
2. ``optimize`` (same config, same seed) on the rectified capture and on the "ideally
   rectified" one: the capture simulator's texel renders of the same maps from the same
   cameras and flashes (:func:`mi_svbrdf.data.frame_photos.ideal_captures`); the held-out
   re-rendering RMSE of each fit against the ground-truth maps
   (:func:`mi_svbrdf.core.metrics.rerender_rmse` under :func:`~mi_svbrdf.core.metrics.eval_lights`)
   and their ratio (target: rectified <= 1.25 x ideal).

Run: ``python benchmarks/bench_rectify.py`` (``--quick``: 3 smaller photos, a short fit).
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import mi_svbrdf  # noqa: F401  (variant, plugins)
from mi_svbrdf.core.metrics import eval_lights, rerender_rmse
from mi_svbrdf.data import procedural
from mi_svbrdf.data.frame_photos import (
    ideal_captures,
    render_frame_photo,
    sample_pose,
    save_photo,
)
from mi_svbrdf.data.photo_setups import simulate
from mi_svbrdf.geometry.poses import focal_35mm_of
from mi_svbrdf.geometry.rectify import RectifyOptions, rectify_photos
from mi_svbrdf.io.atomic import dumps_json
from mi_svbrdf.io.calibrated_photos import (
    capture_from_simulator,
    load_capture,
    save_capture,
)
from mi_svbrdf.optim import OptimizeConfig, optimize


def make_photos(folder: Path, maps: torch.Tensor, count: int, width: int, height: int, seed: int) -> list:
    """Render and save ``count`` framed photos; returns their :class:`FramePhoto` ground truth."""
    rng = np.random.default_rng(seed)
    photos = []
    for k in range(count):
        pose = sample_pose(rng, width=width, height=height, integer_focal_35mm=True)
        photo = render_frame_photo(maps, pose, seed=seed * 100 + k)
        save_photo(folder / f"photo_{k}.png", photo.image, focal_35mm=focal_35mm_of(pose.fov_deg, width, height))
        photos.append(photo)
    return photos


def rectify_figures(photos: list, results: list) -> dict:
    """Corner errors (px) and camera position errors (% of distance) against the ground truth."""
    corner_err, cam_err = [], []
    for photo, r in zip(photos, results):
        if not r.ok:
            raise SystemExit(f"rectify failed: {r.error}")
        corner_err.extend(np.linalg.norm(np.asarray(r.entry["corners_px"]) - photo.corners, axis=1).tolist())
        true = np.asarray(photo.pose.camera)
        window = np.asarray(r.entry["camera_position"]) * r.entry["window_covered"]  # in the window's half-widths
        cam_err.append(100.0 * np.linalg.norm(window - true) / np.linalg.norm(true))
    return {"corner_error_px_median": float(np.median(corner_err)), "corner_error_px_max": float(np.max(corner_err)),
            "camera_error_pct_median": float(np.median(cam_err)), "camera_error_pct_max": float(np.max(cam_err))}


def covered_region(maps: torch.Tensor, covered: float) -> torch.Tensor:
    """The maps of the window's centre ``[-covered, covered]^2`` (what the rectified photos show: rectify crops
    inside the frame's edge), at the maps' size; normals renormalised."""
    theta = torch.tensor([[covered, 0.0, 0.0], [0.0, covered, 0.0]], dtype=maps.dtype)[None].expand(len(maps), 2, 3)
    grid = torch.nn.functional.affine_grid(theta, list(maps.shape), align_corners=False)
    out = torch.nn.functional.grid_sample(maps, grid, mode="bilinear", align_corners=False)
    return torch.cat([torch.nn.functional.normalize(out[:, :3], dim=1), out[:, 3:]], dim=1)


def fit_error(capture_json: Path, gt: torch.Tensor, cfg: OptimizeConfig) -> tuple[float, float]:
    """``(held-out re-rendering RMSE, seconds)`` of an optimize run on a capture file."""
    spec, images, valid = load_capture(capture_json)
    torch.manual_seed(0)
    result = optimize(spec, images, valid, config=cfg)
    return float(rerender_rmse(result.maps, gt, eval_lights())[0]), result.seconds


def run(quick: bool, material: str, seed: int, count: int, size: int, budget: float) -> dict:
    """The whole proof; returns the figures."""
    width, height = (640, 480) if quick else (1024, 768)
    gt = procedural.generate(material, seed, size)[None]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "photos").mkdir()
        t0 = time.perf_counter()
        photos = make_photos(tmp / "photos", gt, count, width, height, seed)
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        results = rectify_photos(sorted((tmp / "photos").glob("*.png")), tmp / "rect", RectifyOptions(size=size))
        t_rect = time.perf_counter() - t0
        figures = rectify_figures(photos, results)
        # Ideal captures: the simulator's texel renders from the same cameras and flashes.
        caps = ideal_captures(photos)
        sim = simulate(gt, caps, torch.Generator().manual_seed(seed))
        spec, images = capture_from_simulator(caps, 0, sim)
        save_capture(tmp / "ideal" / "capture.json", spec, images)
        cfg = OptimizeConfig(budget_s=budget, iterations=2000, progress=False)
        covered = next(r.entry["window_covered"] for r in results if r.ok)  # one crop for the set
        rect_err, rect_s = fit_error(tmp / "rect" / "capture.json", covered_region(gt, covered), cfg)
        ideal_err, ideal_s = fit_error(tmp / "ideal" / "capture.json", gt, cfg)
    figures.update({"material": f"{material}:{seed}", "photos": count, "photo_size": [width, height],
                    "rectified_size": size, "render_s": round(t_render, 1),
                    "rectify_s_per_photo": round(t_rect / count, 2),
                    "rerender_rmse_rectified": rect_err, "rerender_rmse_ideal": ideal_err,
                    "rerender_ratio": rect_err / ideal_err, "fit_s": [round(rect_s, 1), round(ideal_s, 1)]})
    return figures


def main() -> None:
    """Print the proof's figures (JSON) and whether each target is met."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="3 photos of 640x480, 64^2, short fits")
    parser.add_argument("--material", default="leather", help="procedural class (default leather)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--photos", type=int, default=8)
    parser.add_argument("--size", type=int, default=128, help="rectified size = map size (default 128)")
    parser.add_argument("--budget-s", type=float, default=60.0)
    args = parser.parse_args()
    if args.quick:
        args.photos, args.size, args.budget_s = 3, 64, 15.0
    f = run(args.quick, args.material, args.seed, args.photos, args.size, args.budget_s)
    print(dumps_json(f, indent=2))
    print(f"median corner error {f['corner_error_px_median']:.3f} px (target < 1): "
          f"{'ok' if f['corner_error_px_median'] < 1 else 'MISSED'}")
    print(f"camera position error max {f['camera_error_pct_max']:.2f} % (target < 3): "
          f"{'ok' if f['camera_error_pct_max'] < 3 else 'MISSED'}")
    print(f"re-rendering RMSE rectified {f['rerender_rmse_rectified']:.4f} vs ideal {f['rerender_rmse_ideal']:.4f}: "
          f"ratio {f['rerender_ratio']:.3f} (target <= 1.25): {'ok' if f['rerender_ratio'] <= 1.25 else 'MISSED'}")


if __name__ == "__main__":
    main()
